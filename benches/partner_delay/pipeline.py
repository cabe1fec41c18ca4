"""One Hi5 trial (gain, trajectory, integration phases) with the human-like
partner, run by the paper's identification and by the delay-aware one, side
by side on the same world and noise; batched over (cell, seed).

Per batch member it returns the table's numbers: gain estimates (mean and
std over the last 8 s of the gain phase), the chosen delay and its evidence,
stage 2's partner-target RMSE (against tau_h now and against the delayed
tau_h the delay-aware state estimates), and stage 3's own / integrated RMSE.
"""

from __future__ import annotations

import numpy as np

from delay_id import DelayIdentifier
from filters import PaperStage1, Stage2, Stage3
from settings import Hi5
from world import World

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests" / "oracles"))


class SwitchingDelayedStage1:
    """The delay-aware stage-1 Kalman filter (oracle equations), batched, with
    a per-seed delay pair that may change from tick to tick (the current
    choice of the delay identifier)."""

    def __init__(self, h: Hi5, B: int):
        self.h = h
        self.x = np.zeros((B, 6))
        self.P = np.broadcast_to(h.P01, (B, 6, 6)).copy()
        self.dx_v, self.dx_f, self.v_v, self.v_f = h.step
        self.resets = np.zeros(B, int)

    def update(self, y):
        h = self.h
        S = self.P[:, :3, :3] + h.R1
        try:
            np.linalg.cholesky(S)
            ok = np.ones(len(y), bool)
        except np.linalg.LinAlgError:
            ok = np.array([np.all(np.linalg.eigvalsh(s) > 0) for s in S])
        Ssafe = np.where(ok[:, None, None], S, np.eye(3))
        Pxz = self.P[:, :, :3]
        K = np.linalg.solve(Ssafe, np.swapaxes(Pxz, 1, 2)).swapaxes(1, 2)
        xn = self.x + np.einsum("bij,bj->bi", K, y - self.x[:, :3])
        Pn = self.P - K @ np.swapaxes(Pxz, 1, 2)
        self.x = np.where(ok[:, None], xn, self.x)
        self.P = np.where(ok[:, None, None], Pn, h.P01)
        self.resets += ~ok

    def predict(self, u, dtau, dtau_h, phi):
        h = self.h
        B = len(u)
        F = np.broadcast_to(np.eye(6), (B, 6, 6)).copy()
        F[:, 0, 1] = F[:, 2, 1] = self.dx_v
        F[:, 1, 1] = self.v_v
        F[:, 0, 3:] = F[:, 2, 3:] = -self.dx_f * phi
        F[:, 1, 3:] = -self.v_f * phi
        b = np.column_stack([self.dx_f * u - dtau, self.v_f * u, self.dx_f * u - dtau_h, np.zeros((B, 3))])
        self.x = np.einsum("bij,bj->bi", F, self.x) + b
        self.P = F @ self.P @ np.swapaxes(F, 1, 2) + h.Q1


def run(h: Hi5, partners, seeds, *, known_delay: bool = False, delay_kw=None, view_std=None,
        q_gain_small: float = 1e-6) -> list[dict]:
    """``known_delay``: the delay-aware filters use the true delays (the
    configured ``robot.partner_delay``) instead of identifying them.

    Stage 1 runs four ways side by side: the paper's model and the
    delay-aware one, each with the preset's Q_k (1e-2 per step on the gains)
    and with ``q_gain_small`` on the gains (the states' Q unchanged). Stages 2
    and 3 run the paper's identification as the project does (paper model,
    preset Q_k) and the proposed one (delay-aware, small gain Q)."""
    import dataclasses

    T = h.ticks
    view_std = h.target_noise_std if view_std is None else view_std
    w = World(h, partners, seeds)
    B = w.B
    rows = np.arange(B)
    last = int(round(h.gain_window_s / h.dt))
    true_d = np.column_stack([w.dv, w.dp])
    hq = dataclasses.replace(h, Q1=np.diag(np.r_[np.diag(h.Q1)[:3], [q_gain_small] * 3]))

    # ---- gain phase: world (independent of the estimates), stage 1 four ways
    s1 = {"paper_Q": PaperStage1(h, B), "paper_q": PaperStage1(hq, B),
          "dl_Q": SwitchingDelayedStage1(h, B), "dl_q": SwitchingDelayedStage1(hq, B)}
    # The search's schedule scales with the gain phase (20 s: coarse grid
    # from 0.3 s, its first choice after 1 s of residuals, fine grid from 6 s,
    # its first choice after 2 s more).
    ph = h.phase_s * 1e3
    kw = dict(fine_ms=0.3 * ph, min_coarse_ms=0.05 * ph, min_fine_ms=0.1 * ph)
    kw.update(delay_kw or {})
    ident = DelayIdentifier(h, B, **kw)
    Y = np.zeros((B, 3 * T, 3))
    gtr = {m: np.zeros((B, last, 3)) for m in s1}
    chosen_trace = np.zeros((B, last, 2), int)
    for k in range(T):
        xm, vm = w.sense()
        w.rec["e_meas"][:, k] = xm - w.tau[k]
        Y[:, k] = np.column_stack([xm - w.tau[k], vm, xm - w.tau_h[k]])
        r_prev = None if k == 0 else h.M / h.dt * (vm - w.rec["vm"][:, k - 1]) - w.rec["u"][:, k - 1]
        ident.tick(Y, k, r_prev, None if k == 0 else c_pred)
        d = true_d if known_delay else (ident.choice if ident.choice is not None else np.zeros((B, 2), int))
        for f in s1.values():
            f.update(Y[:, k])
        if k >= T - last:
            for m, f in s1.items():
                gtr[m][:, k - (T - last)] = f.x[:, 3:]
            chosen_trace[:, k - (T - last)] = d
        u = w.robot_lqr(xm, vm)
        phi = np.column_stack([Y[rows, np.maximum(k - d[:, 0], 0), 0], Y[rows, np.maximum(k - d[:, 1], 0), 1],
                               Y[rows, np.maximum(k - d[:, 0], 0), 2]])
        dtau, dtau_h = np.full(B, w.dtau[k]), np.full(B, w.dtau_h[k])
        c_pred = -(s1["dl_q"].x[:, 3:] * phi).sum(1)  # the partner torque the delay-aware filter predicts
        for m, f in s1.items():
            if m.startswith("paper"):
                f.predict(u, dtau, dtau_h)
            else:
                f.predict(u, dtau, dtau_h, phi)
        w.step(u)
    paper1, dl1 = s1["paper_Q"], s1["dl_q"]
    g_paper, g_dl = gtr["paper_Q"], gtr["dl_q"]
    ev = ident.evidence() if ident.choice is not None else None
    d_final = true_d if known_delay else ev["choice"]
    true_gains = w.rec["gains"][:, T - last:T].mean(1)

    # ---- hand-off to stage 2 (the project's: prior of the first stage-2 tick,
    # gains replaced by the window mean, which stays the pseudo-measurement)
    pseudo = {"paper": g_paper.mean(1), "delayed": g_dl.mean(1)}
    s2 = {"paper": Stage2(h, B, "paper"), "delayed": Stage2(h, B, "delayed", d_final[:, 0], d_final[:, 1])}
    x0p = paper1.x.copy()
    x0p[:, 3:] = pseudo["paper"]
    s2["paper"].start(x0p)
    x0d = dl1.x.copy()
    x0d[:, 3:] = pseudo["delayed"]
    # the state's target entry becomes x - tau_h[k - dv]
    x0d[:, 2] += w.tau_h[T] - w.tau_h[np.maximum(T - d_final[:, 0], 0)]
    s2["delayed"].start(x0d)

    def ctx(k, integration, e_state=None):
        dv, dp = d_final[:, 0], d_final[:, 1]
        dxm = Y[rows, k, 0] + w.tau[k] - (Y[rows, np.maximum(k - dv, 0), 0] + w.tau[np.maximum(k - dv, 0)])
        if integration:
            phi_e = e_state - dxm  # the robot's own target is unknown here
        else:
            phi_e = Y[rows, np.maximum(k - dv, 0), 0]
        return phi_e, Y[rows, np.maximum(k - dp, 0), 1], dxm

    tauh_hat = {m: np.zeros((B, T)) for m in s2}
    for k in range(T, 2 * T):
        xm, vm = w.sense()
        w.rec["e_meas"][:, k] = xm - w.tau[k]
        Y[:, k] = np.column_stack([xm - w.tau[k], vm, xm - w.tau_h[k]])  # y_eh unused by stage 2
        u = w.robot_lqr(xm, vm)
        for m, f in s2.items():
            f.update(np.column_stack([xm - w.tau[k], vm, pseudo[m]]))
            tauh_hat[m][:, k - T] = xm - f.x[:, 2]
            f.predict(u, np.full(B, w.dtau[k]), np.zeros(B), ctx(k, False) if m == "delayed" else None)
        w.step(u)
    skip = int(round(2.0 / h.dt))
    ks = np.arange(T + skip, 2 * T)
    tauh_now = w.tau_h[ks]
    tauh_delayed = w.tau_h[np.maximum(ks[None, :] - d_final[:, :1], 0)]
    rmse2 = {
        "paper": np.sqrt(((tauh_hat["paper"][:, skip:] - tauh_now) ** 2).mean(1)),
        "delayed_vs_now": np.sqrt(((tauh_hat["delayed"][:, skip:] - tauh_now) ** 2).mean(1)),
        "delayed_vs_delayed": np.sqrt(((tauh_hat["delayed"][:, skip:] - tauh_delayed) ** 2).mean(1)),
    }

    # ---- integration phase, once per identification (the command depends on it)
    integ = {}
    for m in ("paper", "delayed"):
        wi = w.copy()
        f2 = s2[m]
        f2 = __import__("copy").deepcopy(f2)
        f2.R = np.broadcast_to(h.R2, (B, 5, 5)).copy()
        f2.R[:, 0, 0] += view_std ** 2
        s3 = Stage3(h, B, view_std)
        Yi = Y.copy()
        err_own, err_fused = [], []
        for k in range(2 * T, 3 * T):
            xm, vm = wi.sense()
            e_meas = xm - (wi.tau[k] + view_std * wi.n_view[:, k])
            Yi[:, k] = np.column_stack([xm - wi.tau[k], vm, xm - wi.tau_h[k]])  # for dxm only (x_m)
            if k == 2 * T:
                s3.start(np.column_stack([e_meas, vm]))
            f2.update(np.column_stack([e_meas, vm, pseudo[m]]))
            s3.update(np.column_stack([e_meas, vm]), f2.x[:, 2], f2.P[:, 2, 2])
            e_true = wi.x - wi.tau[k]
            err_own.append(s3.xo[:, 0] - e_true)
            err_fused.append(s3.xf[:, 0] - e_true)
            u = np.clip(-(h.kp * s3.xf[:, 0] + h.kv * vm), -h.torque_limit, h.torque_limit)
            if m == "delayed":
                dv, dp = d_final[:, 0], d_final[:, 1]
                dxm = xm - (Yi[rows, np.maximum(k - dv, 0), 0] + wi.tau[np.maximum(k - dv, 0)])
                c = (f2.x[:, 0] - dxm, Yi[rows, np.maximum(k - dp, 0), 1], dxm)
            else:
                c = None
            uh_hat = f2.partner_torque(c)
            f2.predict(u, np.zeros(B), np.zeros(B), c)
            s3.predict(u + uh_hat)
            wi.step(u)
        eo, ef = np.array(err_own)[skip:], np.array(err_fused)[skip:]
        integ[m] = (np.sqrt((eo ** 2).mean(0)), np.sqrt((ef ** 2).mean(0)))

    out = []
    for b in range(B):
        p = partners[b]
        res = dict(
            seed=seeds[b], gains_true=true_gains[b], dv_true=int(w.dv[b]), dp_true=int(w.dp[b]),
            lhh=p.gains[2], lhv=p.gains[1], km=p.motor_noise_gain, drift=p.drift_std,
            paper_mean=g_paper[b].mean(0), paper_std=g_paper[b].std(0),
            dl_mean=g_dl[b].mean(0), dl_std=g_dl[b].std(0),
            chosen=d_final[b].tolist(), chosen_switches_last8=int((np.abs(np.diff(chosen_trace[b], axis=0)).sum(1) > 0).sum()),
            rmse2_paper=rmse2["paper"][b], rmse2_dl_now=rmse2["delayed_vs_now"][b],
            rmse2_dl_delayed=rmse2["delayed_vs_delayed"][b],
            s3_paper_own=integ["paper"][0][b], s3_paper_fused=integ["paper"][1][b],
            s3_dl_own=integ["delayed"][0][b], s3_dl_fused=integ["delayed"][1][b],
            resets_paper=int(paper1.resets[b]), resets_dl=int(dl1.resets[b]),
            stage1={m: dict(mean=gtr[m][b].mean(0), std=gtr[m][b].std(0)) for m in gtr},
            max_abs_x=float(np.nanmax(np.abs(w.rec["x"][b, :2 * T]))),
        )
        if ev is not None and not known_delay:
            res.update(gains_ls=ev["gains_ls"][b], noise_s0=ev["noise_s0"][b], noise_kappa2=ev["noise_kappa2"][b], dv_ci=(ev["dv_ci"][0][b], ev["dv_ci"][1][b]),
                       dp_ci=(ev["dp_ci"][0][b], ev["dp_ci"][1][b]), dp_span=ev["dp_span"][b],
                       dp_identified=bool(ev["dp_identified"][b]))
        out.append(res)
    return out
