"""The loop's 1 kHz wake-up latency against cyclictest, under SCHED_OTHER and
SCHED_FIFO, in one run. `bash benches/loop_jitter.sh [seconds]` installs
cyclictest (Debian rt-tests) and prints the table; `benches/report.py` puts
the same table into BENCHMARKS.md.

cyclictest measures the bare wake-up latency of a thread sleeping on
absolute deadlines (clock_nanosleep, TIMER_ABSTIME), which is what the loop's
`wake_latency` measures too; the loop adds its own work (CAN, the
estimators) after waking, reported separately as `compute`. Both run with
the same settings, one after the other: 1 ms period, memory locked, pinned
to the same CPU, and either the default scheduler (SCHED_OTHER) or
SCHED_FIFO at the same priority. The virtual drive (and this script) are
kept off that CPU, as is the loop's log writer, and the loop's stack is
pre-touched; the settings the OS granted are the loop's own
`realtime` notes, quoted in the table.
"""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

from sensaug import presets, rig

#: The CPU both run on: the last one (the first takes most interrupts).
CPU = (os.cpu_count() or 1) - 1
#: SCHED_FIFO priority of both under the FIFO policy.
FIFO_PRIORITY = 80
POLICIES = ("SCHED_OTHER", "SCHED_FIFO")


def cyclictest_command(loops: int, policy: str) -> list[str]:
    """cyclictest: one thread, 1 ms interval, absolute-deadline
    clock_nanosleep (its default), mlockall, pinned to `CPU`, histogram in
    us on stdout; SCHED_FIFO at `FIFO_PRIORITY` or the default scheduler."""
    cmd = ["cyclictest", "-q", "-m", "-t", "1", "-a", str(CPU), "-i", "1000", "-l", str(loops),
           "-h", "20000", "--histfile=/dev/stdout"]
    if policy == "SCHED_FIFO":
        cmd += ["-p", str(FIFO_PRIORITY), "--policy=fifo"]
    else:
        cmd += ["--policy=other"]
    return cmd


def cyclictest(loops: int, policy: str) -> dict[str, float]:
    """cyclictest's wake-up latency percentiles (us) from its histogram."""
    out = subprocess.run(cyclictest_command(loops, policy), capture_output=True, text=True, check=True).stdout
    counts = {}
    for line in out.splitlines():
        m = re.match(r"^(\d+)\s+(\d+)$", line.strip())
        if m:
            counts[int(m.group(1))] = int(m.group(2))
    us = np.array(sorted(counts))
    n = np.array([counts[u] for u in us])
    cum = np.cumsum(n) / n.sum()

    def q(p: float) -> float:
        return float(us[np.searchsorted(cum, p)])

    mx = re.search(r"# Max Latencies:\s+(\d+)", out)
    return {"p50": q(0.5), "p99": q(0.99), "p99.9": q(0.999), "max": float(mx.group(1)) if mx else float(us[-1])}


def sensaug_rt(seconds: float, policy: str, out: Path) -> dict:
    """The Hi5 rig protocol for `seconds` on the virtual rig with the same
    settings: its wake-up latency and compute (us) and granted settings."""
    cfg = presets.hi5_rig(phase_s=seconds / 3)
    cfg.rig.realtime.cpu = CPU
    cfg.rig.realtime.mlockall = True
    cfg.rig.realtime.fifo_priority = FIFO_PRIORITY if policy == "SCHED_FIFO" else None
    # Everything this process starts (the virtual drive, sensaug-rt before
    # it pins itself) inherits an affinity without the loop's CPU, so only
    # the loop runs there, as only cyclictest's thread did.
    before = os.sched_getaffinity(0)
    others = before - {CPU}
    if others:
        os.sched_setaffinity(0, others)
    try:
        run = rig.run_virtual_rig(cfg, out=out)
    finally:
        os.sched_setaffinity(0, before)
    return run.stats


def compare(seconds: float, out: Path = Path("out/jitter")) -> list[dict]:
    """For each policy: cyclictest, then the loop, `seconds` each."""
    if shutil.which("cyclictest") is None:
        raise RuntimeError("cyclictest not found: run `bash benches/loop_jitter.sh` (installs rt-tests)")
    rows = []
    for policy in POLICIES:
        base = cyclictest(int(seconds * 1000), policy)
        stats = sensaug_rt(seconds, policy, out / policy.lower())
        w, c = stats["wake_latency"], stats["compute"]
        rows.append({
            "policy": policy,
            "cyclictest": base,
            "cyclictest_command": " ".join(cyclictest_command(int(seconds * 1000), policy)),
            "wake": {"p50": w["p50_us"], "p99": w["p99_us"], "p99.9": w["p999_us"], "max": w["max_us"]},
            "compute": {"p50": c["p50_us"], "p99": c["p99_us"], "p99.9": c["p999_us"], "max": c["max_us"]},
            "deadline_misses": stats["deadline_misses"],
            "ticks": stats["ticks"],
            "stop_reason": stats["stop_reason"],
            "granted": stats["realtime"],
        })
    return rows


def main() -> None:
    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else 10.0
    rows = compare(seconds)
    print(f"\n1 ms period, {seconds:g} s each, cpu {CPU}, one after the other in this run")
    print(f"{'':44s} {'p50':>7s} {'p99':>7s} {'p99.9':>7s} {'max':>7s}  (us)")
    for r in rows:
        for label, d in (("cyclictest wake-up latency", r["cyclictest"]),
                         ("sensaug-rt wake-up latency", r["wake"]),
                         ("sensaug-rt tick compute", r["compute"])):
            print(f"{r['policy'] + ' ' + label:44s} {d['p50']:7.0f} {d['p99']:7.0f} {d['p99.9']:7.0f} {d['max']:7.0f}")
        print(f"  stopped: {r['stop_reason']} after {r['ticks']} ticks; deadline misses {r['deadline_misses']}; "
              f"settings: {'; '.join(r['granted'])}")


if __name__ == "__main__":
    main()
