"""Sweep throughput on this machine: trials per minute with 1 and 2 worker
threads, measured side by side in one run (prints figures; asserts nothing).

Usage: .venv/bin/python benches/sweep_throughput.py [--seeds N] [--phase-s S]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from concurrent.futures import ThreadPoolExecutor

from sensaug import presets
from sensaug.sweep import sweep


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=12)
    ap.add_argument("--phase-s", type=float, default=20.0, help="phase length of the Hi5 preset (s)")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    cfg = presets.hi5_experiment(phase_s=args.phase_s)
    seeds = range(args.seeds)
    sweep(cfg, {}, seeds=range(2), executor=ThreadPoolExecutor(1), progress=False)  # warm-up
    times: dict[int, list[float]] = {1: [], 2: []}
    for _ in range(args.repeats):
        for workers in (1, 2):  # interleaved, so drift on a shared machine hits both
            t0 = time.perf_counter()
            sweep(cfg, {}, seeds=seeds, executor=ThreadPoolExecutor(workers), progress=False)
            times[workers].append(time.perf_counter() - t0)
    print(f"{args.seeds} Hi5 trials of {3 * args.phase_s:g} s simulated each, {os.cpu_count()} CPUs, "
          f"{args.repeats} interleaved repeats")
    print(f"{'workers':>8} {'median s':>9} {'min s':>7} {'max s':>7} {'trials/min':>11}")
    for w, ts in times.items():
        med = statistics.median(ts)
        print(f"{w:>8} {med:>9.2f} {min(ts):>7.2f} {max(ts):>7.2f} {60 * args.seeds / med:>11.0f}")
    print(f"scaling 1 -> 2 workers: {statistics.median(times[1]) / statistics.median(times[2]):.2f}x")


if __name__ == "__main__":
    main()
