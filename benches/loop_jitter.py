"""Loop-jitter baseline: cyclictest and sensaug-rt on the same machine, one
after the other, same period (1 ms) and length, medians/percentiles side by
side. `bash benches/loop_jitter.sh` installs cyclictest (Debian rt-tests).

cyclictest measures the bare wake-up latency of a thread sleeping on
absolute deadlines (clock_nanosleep, TIMER_ABSTIME), which is what the
loop's `wake_latency` measures too; the loop adds its own work (CAN, the
estimators) after waking, reported separately as `compute`.
"""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np

from sensaug import presets, rig


def cyclictest(loops: int) -> dict[str, float]:
    """cyclictest with a 1 ms interval, one thread, histogram in us."""
    out = subprocess.run(
        ["cyclictest", "-q", "-m", "-i", "1000", "-l", str(loops), "-h", "20000", "--histfile=/dev/stdout"],
        capture_output=True, text=True, check=True,
    ).stdout
    counts = {}
    for line in out.splitlines():
        m = re.match(r"^(\d+)\s+(\d+)$", line.strip())
        if m:
            counts[int(m.group(1))] = int(m.group(2))
    us = np.array(sorted(counts))
    n = np.array([counts[u] for u in us])
    cum = np.cumsum(n) / n.sum()
    q = lambda p: float(us[np.searchsorted(cum, p)])  # noqa: E731
    mx = re.search(r"# Max Latencies:\s+(\d+)", out)
    return {"p50": q(0.5), "p99": q(0.99), "p99.9": q(0.999), "max": float(mx.group(1)) if mx else float(us[-1])}


def main() -> None:
    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else 10.0
    base = cyclictest(int(seconds * 1000))
    cfg = presets.hi5_rig(phase_s=seconds / 3)
    run = rig.run_virtual_rig(cfg, out=Path("out/jitter"))
    w, c = run.stats["wake_latency"], run.stats["compute"]
    print(f"\n1 ms period, {seconds:g} s each, run one after the other on this machine")
    print(f"{'':34s} {'p50':>7s} {'p99':>7s} {'p99.9':>7s} {'max':>7s}  (us)")
    print(f"{'cyclictest wake-up latency':34s} {base['p50']:7.0f} {base['p99']:7.0f} {base['p99.9']:7.0f} {base['max']:7.0f}")
    print(f"{'sensaug-rt wake-up latency':34s} {w['p50_us']:7.0f} {w['p99_us']:7.0f} {w['p999_us']:7.0f} {w['max_us']:7.0f}")
    print(f"{'sensaug-rt tick compute':34s} {c['p50_us']:7.0f} {c['p99_us']:7.0f} {c['p999_us']:7.0f} {c['max_us']:7.0f}")
    print(f"deadline misses {run.stats['deadline_misses']} of {run.stats['ticks']}; settings: {'; '.join(run.stats['realtime'])}")


if __name__ == "__main__":
    main()
