"""Log file costs on this machine: saving a simulated trial (the Rust writer:
formatting and the rows' chained CRC-32), loading it with every checksum
verified and without (``verify=False``), side by side in one run,
interleaved; and zlib.crc32 over the file alone (the verification's
arithmetic). Prints figures; asserts nothing (docs/logs.md quotes them).

Usage: .venv/bin/python benches/log_io.py [--ticks N] [--repeats R]
"""

from __future__ import annotations

import argparse
import inspect
import statistics
import tempfile
import time
import warnings
import zlib
from pathlib import Path

from sensaug import experiment, load_log, presets


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--ticks", type=int, default=40_000)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    trial = experiment.run(presets.hi5_experiment(phase_s=args.ticks / 3000))
    can_skip = "verify" in inspect.signature(load_log).parameters  # format 1 had no checksums
    times: dict[str, list[float]] = {"save": [], "load, verified": [], "load, verify=False": [], "crc32 of the file": []}
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "trial.csv"
        trial.save(path)  # warm-up
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            trial.save(path)
            times["save"].append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            log = load_log(path)
            times["load, verified"].append(time.perf_counter() - t0)
            if can_skip:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    t0 = time.perf_counter()
                    load_log(path, verify=False)
                    times["load, verify=False"].append(time.perf_counter() - t0)
            raw = path.read_bytes()
            t0 = time.perf_counter()
            zlib.crc32(raw)
            times["crc32 of the file"].append(time.perf_counter() - t0)
        size = path.stat().st_size
    print(f"{len(log)} ticks, {size / 1e6:.1f} MB ({size / len(log):.0f} bytes a tick), "
          f"{args.repeats} interleaved repeats, log format {log.meta.get('format_version')}")
    print(f"{'':>20} {'median s':>9} {'min s':>7} {'max s':>7}")
    for name, ts in times.items():
        if ts:
            print(f"{name:>20} {statistics.median(ts):>9.3f} {min(ts):>7.3f} {max(ts):>7.3f}")


if __name__ == "__main__":
    main()
