"""Stage 3 (goal integration) with a delayed partner, isolated from stage 2:
the partner channel is the *perfect* delay-aware stage-2 output, the
partner's target as it perceived it, ``x_m[k] - tau_h[k - d_v]`` (what a
stage 2 with no estimation error would give), fed to

* ``mehra``: the project's stage 3 (online channel variance by covariance
  matching, 0.2 s window, floored at ``floor``);
* ``select``: a bank of integration filters over fixed channel variances plus
  the own-only filter, the one whose recent one-step predictions of the
  robot's *own* target view were best (EWMA of the squared prediction error,
  0.2 s) driving the command (the direction of issue 22, prototyped here only
  to estimate what such a rule does with a stale channel).

Robot's own view: white noise of std ``view`` (deg) on its target; Hi5
settings; virtual human L_h = [0, 0, Lhh] on delayed measured samples.
Prints own / integrated RMSE of ``x - tau`` (ratio > 1: integration helps).

    .venv/bin/python benches/partner_delay/stage3_delay.py [seeds...]
"""
import sys

import numpy as np

from filters import Stage3
from settings import hi5
from world import HumanSettings, World

VARS = [1e-4, 1e-3, 1e-2, 3e-2, 1e-1, 3e-1, 1.0, 3.0]


def main():
    seeds = [int(s) for s in sys.argv[1:]] or [0]
    h = hi5()
    T = h.ticks
    view = h.target_noise_std
    delays = (0, 50, 100, 150, 200)
    lhh = 1.0
    ps, ss = [], []
    for s in seeds:
        for d in delays:
            ps.append(HumanSettings((0.0, 0.0, lhh), d, d, seed=s))
            ss.append(s)
    w0 = World(h, ps, ss)
    w0.k = 2 * T - 3000  # 3 s of the trajectory phase to fill the partner's history
    w0.run_open(3000)
    B = w0.B
    rows = np.arange(B)
    skip = 2000
    for rule in ("mehra", "select"):
        w = w0.copy()
        K = len(VARS) + 1
        if rule == "mehra":
            s3 = Stage3(h, B, view)
        else:
            bank = [Stage3(h, B, view) for _ in range(K)]
            score = np.zeros((B, K))
        eo, ef = [], []
        for k in range(2 * T, 3 * T):
            xm, vm = w.sense()
            e_meas = xm - (w.tau[k] + view * w.n_view[:, k])
            chan = xm - w.tau_h[np.maximum(k - w.dv, 0)]
            y = np.column_stack([e_meas, vm])
            if rule == "mehra":
                if k == 2 * T:
                    s3.start(y)
                s3.update(y, chan, np.full(B, 1e-4))
                e_own, e_used = s3.xo[:, 0], s3.xf[:, 0]
            else:
                if k == 2 * T:
                    for f in bank:
                        f.start(y)
                pred = np.column_stack([f.xo[:, 0] if j == 0 else f.xf[:, 0] for j, f in enumerate(bank)])
                score += (h.dt / 0.2) * ((e_meas[:, None] - pred) ** 2 - score)
                for j, f in enumerate(bank):
                    f.update(y, chan, None, fixed=1e9 if j == 0 else VARS[j - 1])
                best = score.argmin(1)
                est = np.column_stack([f.xo[:, 0] if j == 0 else f.xf[:, 0] for j, f in enumerate(bank)])
                e_own, e_used = bank[0].xo[:, 0], est[rows, best]
            e_true = w.x - w.tau[k]
            eo.append(e_own - e_true)
            ef.append(e_used - e_true)
            u = np.clip(-(h.kp * e_used + h.kv * vm), -h.torque_limit, h.torque_limit)
            # the partner's torque is known exactly here (perfect stage 2)
            uh = -lhh * (w.rec["xm"][rows, np.maximum(k - w.dv, 0)] - w.tau_h[np.maximum(k - w.dv, 0)])
            if rule == "mehra":
                s3.predict(u + uh)
            else:
                for f in bank:
                    f.predict(u + uh)
            w.step(u)
        eo, ef = np.array(eo)[skip:], np.array(ef)[skip:]
        ro, rf = np.sqrt((eo ** 2).mean(0)), np.sqrt((ef ** 2).mean(0))
        for i, d in enumerate(delays):
            sel = [b for b in range(B) if w.dv[b] == d]
            print(f"{rule:6s} d_v = {d:3d} ms: own {ro[sel].mean():.3f} deg, integrated {rf[sel].mean():.3f} deg, "
                  f"own/integrated {np.mean(ro[sel] / rf[sel]):.2f}  (seeds {seeds})")


if __name__ == "__main__":
    main()
