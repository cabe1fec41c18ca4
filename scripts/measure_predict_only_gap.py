"""How long the robot's stage-2 estimator survives without feedback
(docs/cia402.md, "Backlog", quotes the output; a reproduction for the
controller, not a test).

Usage: .venv/bin/python scripts/measure_predict_only_gap.py

1. The 9 s configuration of tests/test_rig_cia402.py, simulated
   (``sensaug.run``, no feedback lost), is replayed (``sensaug.replay``: the
   core's own ``Robot::tick_at``) with the ``fresh`` flag cleared for one run
   of G consecutive ticks, at 8 starts in the trajectory phase (ticks
   3000-5999) and 8 in the integration phase (6000-8999). The handle's
   motion is the recorded one (open loop), so only the estimator differs.
   Prints, per gap length, the largest |tau_h_hat - tau_h| in the gap and the
   200 ticks after it (the target moves within +-8 deg).
2. The same predict-only run in the core's TrajectoryEstimator and in
   filterpy's UnscentedKalmanFilter (the oracle of tests/test_estimators.py)
   from one converged state: the two agree, so the growth is the unscented
   predict of this model, not an implementation fault; and filterpy with the
   gains' pseudo-measurement fused every tick (the update a tick without
   feedback could still make) stays bounded.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

import sensaug  # noqa: E402
from sensaug import Log  # noqa: E402
from test_rig_cia402 import experiment_config  # noqa: E402

M, DT = 0.0035, 1e-3


def gaps_in_replay() -> None:
    trial = sensaug.run(experiment_config("cia402"))
    log = Log(data=trial.data.copy(), meta=dict(trial.meta))
    print("| gap (ticks) | phase | largest abs(tau_h_hat - tau_h) over 8 starts, deg | starts above 8 deg |")
    print("| --- | --- | --- | --- |")
    for gap in (10, 20, 30, 40, 50, 60, 80, 95):
        for phase, first in (("trajectory", 3000), ("integration", 6000)):
            worst = []
            for start in np.linspace(first + 200, first + 2600, 8).astype(int):
                d = log.data.copy()
                d["fresh"][start:start + gap] = False
                r = sensaug.replay(Log(data=d, meta=log.meta))
                seg = slice(start, start + gap + 200)
                worst.append(float(np.nanmax(np.abs(r["tau_h_hat"][seg] - r["tau_h"][seg]))))
            above = sum(w > 8.0 for w in worst)
            print(f"| {gap} | {phase} | {max(worst):.3g} | {above} of 8 |")


def fx(z, dt, u, dtau, dtau_h):
    """docs/model.md's extended model (tests/test_estimators.py's reference)."""
    e, v, eh, lx, lv, lh = z
    a = (u - lx * e - lv * v - lh * eh) / M
    dx = dt * v + 0.5 * dt * dt * a
    return np.array([e + dx - dtau, v + dt * a, eh + dx - dtau_h, lx, lv, lh])


def predict_only_against_filterpy() -> None:
    Q, R = 1e-2 * np.eye(6), 1e-7 * np.eye(5)
    gains = np.array([0.0, 0.0, 2.0])
    x0 = np.concatenate([[0.05, 0.0, 0.1], gains])
    ours = sensaug.TrajectoryEstimator(mass=M, dt=DT, Q=Q, R=R, x0=x0, P0=np.diag([1e-4] * 3 + [1.0] * 3))
    y = np.concatenate([[0.05, 0.0], gains])
    for _ in range(500):  # converge on a still handle
        ours.update(y)
        ours.predict(0.0, 0.0, 0.0)
    pts = MerweScaledSigmaPoints(6, alpha=1.0, beta=2.0, kappa=0.0)

    def oracle(dim_z, hx):
        f = UnscentedKalmanFilter(dim_x=6, dim_z=dim_z, dt=DT, fx=fx, hx=hx, points=pts)
        f.x, f.P, f.Q, f.R = ours.x.copy(), ours.P.copy(), Q, 1e-7 * np.eye(dim_z)
        return f

    core = sensaug.TrajectoryEstimator(mass=M, dt=DT, Q=Q, R=R, x0=ours.x, P0=ours.P)
    plain = oracle(5, lambda z: z[[0, 1, 3, 4, 5]])
    pinned = oracle(3, lambda z: z[3:])
    print("\n| ticks predict-only | var(e_h) core | var(e_h) filterpy | var(e_h) filterpy, gains fused each tick |")
    print("| --- | --- | --- | --- |")
    for k in range(1, 101):
        core.predict(0.0, 0.0, 0.0)
        plain.predict(u=0.0, dtau=0.0, dtau_h=0.0)
        pinned.sigmas_f = pts.sigma_points(pinned.x, pinned.P)
        pinned.update(gains)
        pinned.predict(u=0.0, dtau=0.0, dtau_h=0.0)
        if k in (10, 40, 60, 80, 90, 100):
            print(f"| {k} | {core.P[2, 2]:.4g} | {plain.P[2, 2]:.4g} | {pinned.P[2, 2]:.4g} |")


if __name__ == "__main__":
    gaps_in_replay()
    predict_only_against_filterpy()
