"""The peers (filterpy, scipy) and sensaug's Python API on the problems of
crates/sensaug-core/benches/workloads/mod.rs (same matrices, same settings,
same measurements), timed one call at a time.

``benches/report.py`` imports :func:`calls` and :func:`per_call_ns` and runs
them in the same run as the Rust harness, so every ratio in BENCHMARKS.md is
measured side by side. Run alone, this prints the medians and tails.
"""
from __future__ import annotations

import itertools
import os
import time
from typing import Callable

# Measurement hygiene, set before numpy loads OpenBLAS: after a BLAS call its
# idle worker threads busy-wait for a while, on CPUs the timed code needs
# (callgrind shows them running during a trial). Every problem here is 6 x 6
# at most, which OpenBLAS computes on one thread anyway.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import scipy.linalg  # noqa: E402
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter  # noqa: E402

import sensaug  # noqa: E402

M, DT = 0.0035, 1e-3

WARM_UP_CALLS = 50


def per_call_ns(fn: Callable[[], object], calls: int) -> dict[str, float]:
    """Median, p99, p99.9 and max (ns) of ``calls`` individually timed calls."""
    for _ in range(WARM_UP_CALLS):
        fn()
    samples = np.empty(calls)
    clock = time.perf_counter_ns
    for i in range(calls):
        t0 = clock()
        fn()
        samples[i] = clock() - t0
    empty = np.empty(calls)
    for i in range(calls):
        t0 = clock()
        empty[i] = clock() - t0
    return {
        "calls": calls,
        "median_ns": float(np.median(samples)),
        "p99_ns": float(np.quantile(samples, 0.99)),
        "p999_ns": float(np.quantile(samples, 0.999)),
        "max_ns": float(samples.max()),
        "timer_overhead_median_ns": float(np.median(empty)),
    }


def fx(z, dt, u=0.0, dtau=0.0, dtau_h=0.0):
    """The reference discrete model of docs/model.md (as tests/test_estimators.py)."""
    e, v, eh, lx, lv, lh = z
    a = (u - lx * e - lv * v - lh * eh) / M
    dx = dt * v + 0.5 * dt * dt * a
    return np.array([e + dx - dtau, v + dt * a, eh + dx - dtau_h, lx, lv, lh])


P0 = np.diag([1e-4] * 3 + [1.0] * 3)


def filterpy_ukf(dim_z: int) -> UnscentedKalmanFilter:
    """filterpy's UKF of stage 1 (``dim_z`` 3) or stage 2 (5): Merwe 1/2/0,
    ``Q = 1e-2 I6``, ``R = 1e-7 I``, ``P0``, as the workloads'."""
    pts = MerweScaledSigmaPoints(6, alpha=1.0, beta=2.0, kappa=0.0)
    hx = (lambda z: z[:3]) if dim_z == 3 else (lambda z: z[[0, 1, 3, 4, 5]])
    f = UnscentedKalmanFilter(dim_x=6, dim_z=dim_z, dt=DT, fx=fx, hx=hx, points=pts)
    f.x, f.P = np.zeros(6), P0.copy()
    f.Q, f.R = 1e-2 * np.eye(6), 1e-7 * np.eye(dim_z)
    f.sigmas_f = pts.sigma_points(f.x, f.P)
    return f


def step_inputs(dim_z: int, k: int) -> tuple[np.ndarray, float, float, float]:
    """Step ``k``'s measurement and ``(u, dtau, dtau_h)``, as workloads::ukf_step_3/5."""
    s = np.sin(k * 1e-3)
    if dim_z == 3:
        return np.array([s, 0.1, s]), 0.01 * s, 1e-3, 1e-3
    return np.array([s, 0.1, 0.0, 0.0, 2.0]), 0.01 * s, 1e-3, 0.0


def filterpy_step(dim_z: int) -> Callable[[], None]:
    """update(y) then predict(u, dtau, dtau_h), as workloads::ukf_step_3/5."""
    f = filterpy_ukf(dim_z)
    steps = itertools.count(1)

    def step() -> None:
        y, u, dtau, dtau_h = step_inputs(dim_z, next(steps))
        f.update(y)
        f.predict(u=u, dtau=dtau, dtau_h=dtau_h)

    return step


def sensaug_step_python(dim_z: int) -> Callable[[], None]:
    """The same step through sensaug's Python estimators (one FFI call each)."""
    kw = dict(mass=M, dt=DT, Q=1e-2 * np.eye(6), R=1e-7 * np.eye(dim_z), x0=np.zeros(6), P0=P0)
    est = sensaug.GainEstimator(**kw) if dim_z == 3 else sensaug.TrajectoryEstimator(**kw)
    steps = itertools.count(1)

    def step() -> None:
        y, u, dtau, dtau_h = step_inputs(dim_z, next(steps))
        est.update(y)
        est.predict(u, dtau, dtau_h)

    return step


def sensaug_trial_per_tick_ns(phase_s: float = 20.0, repeats: int = 5) -> dict[str, float]:
    """A whole simulated Hi5 trial from Python (``sensaug.run`` on
    ``presets.hi5_experiment``: three phases, robot with its estimators, a
    virtual human that does not identify the robot, plant, noise, the log as
    a numpy structured array; ``perf_harness trial`` runs the same trial in
    Rust alone), per tick: the median
    over ``repeats`` trials of wall time / ticks (after one warm-up trial)."""
    from sensaug import presets

    cfg = presets.hi5_experiment(phase_s=phase_s)
    ticks = round(3 * phase_s / DT)
    sensaug.run(cfg)
    per_tick = []
    for _ in range(repeats):
        t0 = time.perf_counter_ns()
        sensaug.run(cfg)
        per_tick.append((time.perf_counter_ns() - t0) / ticks)
    return {"ticks": ticks, "repeats": repeats, "median_ns": float(np.median(per_tick)),
            "max_ns": float(max(per_tick))}


def numpy_filterpy_trial_per_tick_ns(ticks: int = 2000) -> dict[str, float]:
    """The peer of a trial: an independent numpy + filterpy loop of the gain
    phase only (plant, LQR robot, virtual human, noise, filterpy's stage-1
    update and predict per tick), median wall time per tick."""
    rng = np.random.default_rng(0)
    f = filterpy_ukf(3)
    k_pos, k_vel, lhh = 1.0, np.sqrt(2.0 * M), 2.0
    x = v = 0.0
    samples = np.empty(ticks)
    clock = time.perf_counter_ns
    for k in range(ticks):
        t0 = clock()
        t = k * DT
        tau, tau_h = 8.0 * np.sin(2 * np.pi * t / 4.0), 8.0 * np.sin(2 * np.pi * t / 4.0)
        dtau = 8.0 * np.sin(2 * np.pi * (t + DT) / 4.0) - tau
        xm, vm = x + 3e-4 * rng.standard_normal(), v + 3e-4 * rng.standard_normal()
        f.update(np.array([xm - tau, vm, xm - tau_h]))
        u = -(k_pos * (xm - tau) + k_vel * vm)
        u_h = -lhh * (xm - tau_h)
        f.predict(u=u, dtau=dtau, dtau_h=dtau)
        a = (u + u_h + 1e-3 * rng.standard_normal()) / M
        x, v = x + DT * v + 0.5 * DT * DT * a, v + DT * a
        samples[k] = clock() - t0
    return {"ticks": ticks, "median_ns": float(np.median(samples)), "max_ns": float(samples.max())}


def problems() -> dict[str, tuple]:
    """(A, B, Q, R) of the Riccati workloads, by workload name."""
    A2 = np.array([[0.0, 1.0], [0.0, -0.5]])
    B2 = np.array([[0.0], [1.0 / M]])
    A3 = np.array([[0.0, 1.0, 0.0], [0.0, -0.1, 1.0], [0.5, 0.0, -1.0]])
    B3 = np.array([[0.0], [0.0], [1.0]])
    R = np.eye(1)
    return {
        "care/2_states": (A2, B2, np.eye(2), R),
        "care/3_states": (A3, B3, np.eye(3), R),
        "dare/2_states": (np.array([[1.0, 1e-3], [0.0, 1.0]]), np.array([[5e-7], [1e-3]]), np.eye(2), R),
        "dare/3_states": (np.eye(3) + 1e-2 * A3, 1e-2 * B3, np.eye(3), R),
    }


def calls() -> list[tuple[str, str, Callable[[], object]]]:
    """(workload, implementation, call) for every peer and Python-API row."""
    rows: list[tuple[str, str, Callable[[], object]]] = [
        ("ukf_step/6_states_3_measurements", "filterpy", filterpy_step(3)),
        ("ukf_step/6_states_5_measurements", "filterpy", filterpy_step(5)),
        ("ukf_step/6_states_3_measurements", "sensaug via Python", sensaug_step_python(3)),
        ("ukf_step/6_states_5_measurements", "sensaug via Python", sensaug_step_python(5)),
    ]
    for name, (A, B, Q, R) in problems().items():
        scipy_solve = scipy.linalg.solve_continuous_are if name.startswith("care") else scipy.linalg.solve_discrete_are
        ours = sensaug.care if name.startswith("care") else sensaug.dare
        rows.append((name, "scipy", lambda f=scipy_solve, a=(A, B, Q, R): f(*a)))
        rows.append((name, "sensaug via Python", lambda f=ours, a=(A, B, Q, R): f(*a)))
    return rows


def main() -> None:
    print(f"{'benchmark':36s} {'implementation':20s} {'median (us)':>12s} {'p99 (us)':>10s}")
    for name, impl, fn in calls():
        t = per_call_ns(fn, 2000)
        print(f"{name:36s} {impl:20s} {t['median_ns'] / 1e3:12.2f} {t['p99_ns'] / 1e3:10.2f}")


if __name__ == "__main__":
    main()
