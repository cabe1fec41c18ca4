"""Batched numpy filters of the prototype (leading axes: seeds, bank members).

* ``PaperStage1``: the paper's stage 1 exactly as the project runs it (UKF,
  Merwe alpha 1 / beta 2 / kappa 0, process of docs/model.md, selection
  update), written with sigma points.
* ``DelayBank``: the delay-aware stage 1 (tests/oracles/delayed_stage1.py) for
  a grid of delays at once; each member a linear Kalman filter with its own
  innovation log-likelihood and its own repair.
* ``Stage2``: stage 2, paper model or delay-aware (the state's target entry is
  ``x - tau_h[k - d_v]``), UKF with sigma points.
* ``Stage3``: goal integration as the project's ``GoalIntegrator`` (own and
  fused linear filters on ``[e, v]``, online partner-channel variance).
"""

from __future__ import annotations

import math

import numpy as np

from settings import Hi5


def merwe(n: int, alpha=1.0, beta=2.0, kappa=0.0):
    lam = alpha * alpha * (n + kappa) - n
    c = n + lam
    Wm = np.full(2 * n + 1, 1.0 / (2 * c))
    Wc = Wm.copy()
    Wm[0] = lam / c
    Wc[0] = lam / c + (1 - alpha * alpha + beta)
    return Wm, Wc, c


def sigma_points(x: np.ndarray, L: np.ndarray) -> np.ndarray:
    """Merwe sigma points ``x``, ``x + L e_i``, ``x - L e_i`` (B, 2n+1, n) from
    the lower factor ``L`` of ``(n + lambda) P``."""
    cols = np.swapaxes(L, 1, 2)  # rows are the columns of L
    return np.concatenate([x[:, None, :], x[:, None, :] + cols, x[:, None, :] - cols], axis=1)


def chol_repair(A: np.ndarray, reset: np.ndarray | None, counter: np.ndarray | None):
    """Lower Cholesky factors of a batch; a member that fails is symmetrised
    and retried, then (``reset`` given) replaced by ``reset``: the core's
    repair path, per member. Returns ``(L, A_used, failed_mask)``."""
    try:
        return np.linalg.cholesky(A), A, np.zeros(A.shape[:-2], bool)
    except np.linalg.LinAlgError:
        pass
    A = A.copy()
    flat = A.reshape(-1, *A.shape[-2:])
    Lf = np.zeros_like(flat)
    failed = np.zeros(flat.shape[0], bool)
    for i in range(flat.shape[0]):
        try:
            Lf[i] = np.linalg.cholesky(flat[i])
            continue
        except np.linalg.LinAlgError:
            pass
        flat[i] = 0.5 * (flat[i] + flat[i].T)
        try:
            Lf[i] = np.linalg.cholesky(flat[i])
            continue
        except np.linalg.LinAlgError:
            failed[i] = True
            if reset is not None:
                flat[i] = reset
                Lf[i] = np.linalg.cholesky(reset)
    failed = failed.reshape(A.shape[:-2])
    if counter is not None:
        counter += failed
    return Lf.reshape(A.shape), A, failed


def sigma_predict(filt, acceleration, dtau, dtau_h, P_reset, Q) -> None:
    """The unscented predict of stages 1 and 2 (state ``[e, v, e_h, Lhx,
    Lhv, Lhh]``, gains a random walk), in place on ``filt`` (``x``, ``P``,
    ``Wm``, ``Wc``, ``c``, ``resets``, ``h``): the handle's step with the
    acceleration ``acceleration(chi)`` on the sigma points ``chi``; ``P``
    repaired to ``P_reset`` first where it is not positive definite."""
    h = filt.h
    L, P, _ = chol_repair(filt.c * filt.P, filt.c * P_reset, filt.resets)
    filt.P = P / filt.c
    chi = sigma_points(filt.x, L)
    e, v, eh, lx, lv, lh = (chi[..., i] for i in range(6))
    a = acceleration(chi)
    dx = h.dt * v + 0.5 * h.dt * h.dt * a
    f = np.stack([e + dx - dtau[:, None], v + h.dt * a, eh + dx - dtau_h[:, None], lx, lv, lh], axis=-1)
    xm = np.einsum("s,bsi->bi", filt.Wm, f)
    d = f - xm[:, None, :]
    filt.x = xm
    filt.P = np.einsum("s,bsi,bsj->bij", filt.Wc, d, d) + Q


class PaperStage1:
    """The paper's stage 1 (the project's GainEstimator), B filters."""

    def __init__(self, h: Hi5, B: int):
        self.h = h
        self.x = np.zeros((B, 6))
        self.P = np.broadcast_to(h.P01, (B, 6, 6)).copy()
        self.Wm, self.Wc, self.c = merwe(6)
        self.resets = np.zeros(B, int)

    def update(self, y: np.ndarray) -> None:
        S = self.P[:, :3, :3] + self.h.R1
        L, S, bad = chol_repair(S, None, None)
        ok = ~bad
        nu = y - self.x[:, :3]
        Pxz = self.P[:, :, :3]
        K = np.linalg.solve(np.where(ok[:, None, None], S, np.eye(3)), np.swapaxes(Pxz, 1, 2)).swapaxes(1, 2)
        xn = self.x + np.einsum("bij,bj->bi", K, nu)
        Pn = self.P - K @ np.swapaxes(Pxz, 1, 2)
        self.x = np.where(ok[:, None], xn, self.x)
        self.P = np.where(ok[:, None, None], Pn, self.h.P01)
        self.resets += bad

    def predict(self, u, dtau, dtau_h) -> None:
        def acceleration(chi):
            e, v, eh, lx, lv, lh = (chi[..., i] for i in range(6))
            return (u[:, None] - lx * e - lv * v - lh * eh - self.h.C * v) / self.h.M

        sigma_predict(self, acceleration, dtau, dtau_h, self.h.P01, self.h.Q1)

    @property
    def gains(self):
        return self.x[:, 3:]


class DelayBank:
    """Delay-aware stage 1 for every (seed, member): ``grid`` is a list of
    ``(dv, dp)`` in ticks (K members). Linear Kalman filters; log-likelihood
    of each member's innovations summed from tick ``from_tick``."""

    def __init__(self, h: Hi5, B: int, grid, from_tick: int = 0):
        self.h = h
        self.grid = np.asarray(grid, int).reshape(-1, 2)
        K = len(self.grid)
        self.x = np.zeros((B, K, 6))
        self.P = np.broadcast_to(h.P01, (B, K, 6, 6)).copy()
        self.loglik = np.zeros((B, K))
        self.resets = np.zeros((B, K), int)
        self.from_tick = from_tick
        self.k = -1
        self.dx_v, self.dx_f, self.v_v, self.v_f = h.step
        self.hist: list[np.ndarray] = []  # y_k, (B, 3)

    def update(self, y: np.ndarray) -> None:
        h = self.h
        self.k += 1
        self.hist.append(y.copy())
        S = self.P[..., :3, :3] + h.R1
        L, S, bad = chol_repair(S, None, None)
        ok = ~bad
        nu = y[:, None, :] - self.x[..., :3]
        Pxz = self.P[..., :, :3]
        Ssafe = np.where(ok[..., None, None], S, np.eye(3))
        K = np.swapaxes(np.linalg.solve(Ssafe, np.swapaxes(Pxz, -1, -2)), -1, -2)
        xn = self.x + np.einsum("bkij,bkj->bki", K, nu)
        Pn = self.P - K @ np.swapaxes(Pxz, -1, -2)
        self.x = np.where(ok[..., None], xn, self.x)
        self.P = np.where(ok[..., None, None], Pn, h.P01)
        self.resets += bad
        Lsafe = np.where(ok[..., None, None], L, np.eye(3))
        w = np.linalg.solve(Lsafe, nu[..., None])[..., 0]
        ll = -0.5 * ((w * w).sum(-1) + 2 * np.log(np.diagonal(Lsafe, axis1=-2, axis2=-1)).sum(-1) + 3 * math.log(2 * math.pi))
        ll = np.where(ok, ll, -1e6)  # a failed member is penalised, the others untouched
        if self.k >= self.from_tick:
            self.loglik += ll
        self.last_ll = ll

    def regressors(self) -> np.ndarray:
        """``phi`` of every (seed, member): (B, K, 3)."""
        k = self.k
        hist = self.hist
        B = hist[0].shape[0]
        phi = np.empty((B, len(self.grid), 3))
        for j, (dv, dp) in enumerate(self.grid):
            yv, yp = hist[max(k - dv, 0)], hist[max(k - dp, 0)]
            phi[:, j, 0], phi[:, j, 1], phi[:, j, 2] = yv[:, 0], yp[:, 1], yv[:, 2]
        return phi

    def predict(self, u, dtau, dtau_h) -> None:
        h = self.h
        phi = self.regressors()
        B, K = phi.shape[:2]
        F = np.broadcast_to(np.eye(6), (B, K, 6, 6)).copy()
        F[..., 0, 1] = F[..., 2, 1] = self.dx_v
        F[..., 1, 1] = self.v_v
        F[..., 0, 3:] = F[..., 2, 3:] = -self.dx_f * phi
        F[..., 1, 3:] = -self.v_f * phi
        b = np.zeros((B, K, 6))
        b[..., 0] = (self.dx_f * u - dtau)[:, None]
        b[..., 1] = (self.v_f * u)[:, None]
        b[..., 2] = (self.dx_f * u - dtau_h)[:, None]
        self.x = np.einsum("bkij,bkj->bki", F, self.x) + b
        self.P = F @ self.P @ np.swapaxes(F, -1, -2) + h.Q1

    @property
    def gains(self):
        return self.x[..., 3:]


class Stage2:
    """Stage 2 for B seeds. ``model = "paper"``: the paper's process.
    ``model = "delayed"``: the partner acts on the measured sample ``d_v``
    (``d_p``) ago; the target entry of the state is ``eta = x - tau_h[k - d_v]``
    and the partner's error term is ``eta - (x_m[k] - x_m[k - d_v])``."""

    def __init__(self, h: Hi5, B: int, model: str, dv=None, dp=None):
        self.h, self.model = h, model
        self.B = B
        self.dv = np.zeros(B, int) if dv is None else np.asarray(dv, int)
        self.dp = np.zeros(B, int) if dp is None else np.asarray(dp, int)
        self.Wm, self.Wc, self.c = merwe(6)
        self.x = np.zeros((B, 6))
        self.P = np.broadcast_to(h.P02, (B, 6, 6)).copy()
        self.R = np.broadcast_to(h.R2, (B, 5, 5)).copy()
        self.resets = np.zeros(B, int)

    def start(self, x0: np.ndarray) -> None:
        self.x = x0.copy()
        self.P = np.broadcast_to(self.h.P02, (self.B, 6, 6)).copy()

    def update(self, y5: np.ndarray) -> None:
        idx = [0, 1, 3, 4, 5]
        S = self.P[:, idx][:, :, idx] + self.R
        L, S, bad = chol_repair(S, None, None)
        ok = ~bad
        nu = y5 - self.x[:, idx]
        Pxz = self.P[:, :, idx]
        Ssafe = np.where(ok[:, None, None], S, np.eye(5))
        K = np.linalg.solve(Ssafe, np.swapaxes(Pxz, 1, 2)).swapaxes(1, 2)
        xn = self.x + np.einsum("bij,bj->bi", K, nu)
        Pn = self.P - K @ np.swapaxes(Pxz, 1, 2)
        self.x = np.where(ok[:, None], xn, self.x)
        self.P = np.where(ok[:, None, None], Pn, self.h.P02)
        self.resets += bad

    def partner_terms(self, chi, ctx):
        """``q`` (the partner's torque without sign) on sigma points (B, S)."""
        e, v, eh, lx, lv, lh = (chi[..., i] for i in range(6))
        if self.model == "paper":
            return lx * e + lv * v + lh * eh
        phi_e, phi_v, dxm = ctx  # (B,), (B,), (B,)
        return lx * phi_e[:, None] + lv * phi_v[:, None] + lh * (eh - dxm[:, None])

    def predict(self, u, dtau, dtau_h, ctx=None) -> None:
        def acceleration(chi):
            return (u[:, None] - self.partner_terms(chi, ctx) - self.h.C * chi[..., 1]) / self.h.M

        sigma_predict(self, acceleration, dtau, dtau_h, self.h.P02, self.h.Q2)

    def partner_torque(self, ctx=None) -> np.ndarray:
        return -self.partner_terms(self.x[:, None, :], ctx)[:, 0]


class Stage3:
    """The project's GoalIntegrator, B seeds: own ``[e, v]`` and fused
    ``[e, v, e]`` linear filters, partner-channel variance by covariance
    matching (EWMA of the channel innovation squared minus the prior
    variance, floored by stage 2's posterior variance)."""

    def __init__(self, h: Hi5, B: int, view_std: float):
        self.h = h
        self.R_own = h.R3.copy()
        self.R_own[0, 0] += view_std * view_std
        self.w = min(h.dt / h.partner_window_s, 1.0)
        self.mean_sq = np.full(B, np.nan)
        dx_v, dx_f, v_v, v_f = h.step
        self.F = np.array([[1.0, dx_v], [0.0, v_v]])
        self.g = np.array([dx_f, v_f])

    def start(self, y: np.ndarray) -> None:
        B = y.shape[0]
        self.xo, self.xf = y.copy(), y.copy()
        self.Po = np.broadcast_to(self.h.P03, (B, 2, 2)).copy()
        self.Pf = self.Po.copy()
        self.mean_sq[:] = np.nan

    @staticmethod
    def _kf_update(x, P, y, R, H):
        S = H @ P @ H.T + R
        Pxz = P @ H.T
        K = np.swapaxes(np.linalg.solve(S, np.swapaxes(Pxz, -1, -2)), -1, -2)
        x = x + np.einsum("bij,bj->bi", K, y - np.einsum("ij,bj->bi", H, x))
        P = P - K @ np.swapaxes(Pxz, -1, -2)
        return x, P

    def update(self, y_own: np.ndarray, channel: np.ndarray, floor: np.ndarray, fixed: float | None = None) -> None:
        """``fixed``: a fixed channel variance instead of the online one."""
        B = y_own.shape[0]
        self.xo, self.Po = self._kf_update(self.xo, self.Po, y_own, np.broadcast_to(self.R_own, (B, 2, 2)), np.eye(2))
        d = channel - self.xf[:, 0]
        d2 = d * d
        self.mean_sq = np.where(np.isnan(self.mean_sq), d2, self.mean_sq + self.w * (d2 - self.mean_sq))
        var = np.maximum(self.mean_sq - self.Pf[:, 0, 0], floor) if fixed is None else np.full(B, fixed)
        R = np.zeros((B, 3, 3))
        R[:, :2, :2] = self.R_own
        R[:, 2, 2] = var
        H = np.array([[1.0, 0], [0, 1.0], [1.0, 0]])
        y = np.column_stack([y_own, channel])
        self.xf, self.Pf = self._kf_update(self.xf, self.Pf, y, R, H)
        self.var = var

    def predict(self, u_total: np.ndarray) -> None:
        b = self.g[None, :] * u_total[:, None]
        for name in ("o", "f"):
            x, P = getattr(self, "x" + name), getattr(self, "P" + name)
            setattr(self, "x" + name, np.einsum("ij,bj->bi", self.F, x) + b)
            setattr(self, "P" + name, self.F @ P @ self.F.T + self.h.Q3)
