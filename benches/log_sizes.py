"""Log file sizes: the CSV and the compact Parquet of the same logs
(``Log.save``), with write and read times. Prints a table.

    .venv/bin/python benches/log_sizes.py [RIG_LOG.csv ...]

Simulated: the Hi5 experiment preset (3 x 20 s at 1 kHz) over seeds 0-2;
each rig log given (``sensaug demo`` writes out/rig_log.csv) is read and
saved as Parquet beside a copy in a temporary folder.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import sensaug
from sensaug import presets


def measure(log: sensaug.Log, name: str, folder: Path) -> list[str]:
    row = [name, f"{len(log)}"]
    for suffix in (".csv", ".parquet"):
        path = folder / f"{name}{suffix}"
        t0 = time.perf_counter()
        log.save(path)
        t1 = time.perf_counter()
        sensaug.load_log(path)
        t2 = time.perf_counter()
        row += [f"{path.stat().st_size / 1e6:.1f}", f"{t1 - t0:.2f}", f"{t2 - t1:.2f}"]
    row.append(f"{float(row[2]) / float(row[5]):.1f}x")
    return row


def main() -> None:
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for seed in range(3):
            rows.append(measure(sensaug.run(presets.hi5_experiment(2.0, seed=seed)), f"hi5 sim seed {seed}", folder))
        for i, rig_log in enumerate(sys.argv[1:]):
            rows.append(measure(sensaug.load_log(rig_log), f"rig log {i}", folder))
    head = ["log", "ticks", "CSV MB", "write s", "read s", "Parquet MB", "write s", "read s", "CSV/Parquet"]
    widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(head)]
    print("  ".join(h.rjust(w) for h, w in zip(head, widths)))
    for r in rows:
        print("  ".join(c.rjust(w) for c, w in zip(r, widths)))


if __name__ == "__main__":
    main()
