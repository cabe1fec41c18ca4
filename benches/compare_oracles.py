"""Times the oracles (scipy, filterpy) on the problems `cargo bench` times.

Run by `benches/run.sh` right after the criterion benches, so both sets of
medians come from one run on the same machine. Prints medians per call.
The same matrices as crates/sensaug-core/benches/numerics.rs.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import scipy.linalg
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

import sensaug

M, DT = 0.0035, 1e-3


def median_us(fn, *, repeat: int = 2000, inner: int = 5) -> float:
    for _ in range(50):
        fn()
    samples = []
    for _ in range(repeat // inner):
        t0 = time.perf_counter_ns()
        for _ in range(inner):
            fn()
        samples.append((time.perf_counter_ns() - t0) / inner / 1e3)
    return float(np.median(samples))


def fx(z, dt, u=0.0, dtau=0.0, dtau_h=0.0):
    e, v, eh, lx, lv, lh = z
    a = (u - lx * e - lv * v - lh * eh) / M
    dx = dt * v + 0.5 * dt * dt * a
    return np.array([e + dx - dtau, v + dt * a, eh + dx - dtau_h, lx, lv, lh])


def filterpy_step(dim_z: int):
    pts = MerweScaledSigmaPoints(6, alpha=1.0, beta=2.0, kappa=0.0)
    hx = (lambda z: z[:3]) if dim_z == 3 else (lambda z: z[[0, 1, 3, 4, 5]])
    f = UnscentedKalmanFilter(dim_x=6, dim_z=dim_z, dt=DT, fx=fx, hx=hx, points=pts)
    f.P = np.diag([1e-4] * 3 + [1.0] * 3)
    f.Q, f.R = 1e-2 * np.eye(6), 1e-7 * np.eye(dim_z)
    f.predict(u=0.0)
    k = [0]

    def step():
        k[0] += 1
        s = np.sin(k[0] * 1e-3)
        f.update(np.array([s, 0.1, s, 0.0, 2.0][:dim_z]) if dim_z == 3 else np.array([s, 0.1, 0.0, 0.0, 2.0]))
        f.predict(u=0.01 * s, dtau=1e-3, dtau_h=1e-3)

    return step


def ours_step_python():
    g = sensaug.GainEstimator(mass=M, Q=1e-2 * np.eye(6), R=1e-7 * np.eye(3), x0=np.zeros(6), P0=np.diag([1e-4] * 3 + [1.0] * 3))
    y = np.array([0.1, 0.1, 0.1])

    def step():
        g.update(y)
        g.predict(0.001, 1e-3, 1e-3)

    return step


def criterion_medians() -> dict[str, float]:
    """Medians (us) from criterion's estimates of the run that just finished."""
    root = Path(__file__).resolve().parents[1] / "target" / "criterion"
    out = {}
    for est in root.glob("**/new/estimates.json"):
        name = json.loads((est.parent / "benchmark.json").read_text())["full_id"]
        out[name] = json.loads(est.read_text())["median"]["point_estimate"] / 1e3
    return out


def main() -> None:
    A2 = np.array([[0.0, 1.0], [0.0, -0.5]])
    B2 = np.array([[0.0], [1.0 / M]])
    A3 = np.array([[0.0, 1.0, 0.0], [0.0, -0.1, 1.0], [0.5, 0.0, -1.0]])
    B3 = np.array([[0.0], [0.0], [1.0]])
    Ad2, Bd2 = np.array([[1.0, 1e-3], [0.0, 1.0]]), np.array([[5e-7], [1e-3]])
    Ad3, Bd3 = np.eye(3) + 1e-2 * A3, 1e-2 * B3
    R = np.eye(1)
    rows = [
        ("ukf_step/6_states_3_measurements", "filterpy", median_us(filterpy_step(3))),
        ("ukf_step/6_states_5_measurements", "filterpy", median_us(filterpy_step(5))),
        ("ukf_step/6_states_3_measurements", "sensaug via Python", median_us(ours_step_python())),
        ("care/2_states", "scipy", median_us(lambda: scipy.linalg.solve_continuous_are(A2, B2, np.eye(2), R))),
        ("care/3_states", "scipy", median_us(lambda: scipy.linalg.solve_continuous_are(A3, B3, np.eye(3), R))),
        ("dare/2_states", "scipy", median_us(lambda: scipy.linalg.solve_discrete_are(Ad2, Bd2, np.eye(2), R))),
        ("dare/3_states", "scipy", median_us(lambda: scipy.linalg.solve_discrete_are(Ad3, Bd3, np.eye(3), R))),
        ("care/3_states", "sensaug via Python", median_us(lambda: sensaug.care(A3, B3, np.eye(3), R))),
    ]
    rows += [(name, "sensaug (Rust)", us) for name, us in criterion_medians().items()]
    rows.sort(key=lambda r: (r[0], r[1]))
    print(f"{'benchmark':36s} {'implementation':20s} {'median (us)':>12s}")
    for name, impl, us in rows:
        print(f"{name:36s} {impl:20s} {us:12.2f}")


if __name__ == "__main__":
    main()
