"""The loop's 1 kHz wake-up latency against cyclictest, side by side, under
SCHED_OTHER and SCHED_FIFO. `bash benches/loop_jitter.sh [round_s] [rounds]`
installs cyclictest (Debian rt-tests) and prints the table;
`benches/report.py` puts the same table into BENCHMARKS.md.

cyclictest measures the bare wake-up latency of a thread sleeping on
absolute deadlines (clock_nanosleep, TIMER_ABSTIME), which is what the loop's
`wake_latency` measures too; the loop adds its own work (CAN, the
estimators) after waking, reported separately as `compute`.

What makes the comparison fair (the machines are shared and noisy):

- Interleaved rounds: per policy, `rounds` short rounds of each, in the
  order cyclictest, loop, loop, cyclictest, cyclictest, ... (ABBA: a drift
  in the machine's load hits both alike); the table pools each one's rounds
  into one histogram and gives the spread of the per-round figures.
- The same settings: 1 ms period, memory locked, pinned to the same CPU
  (`CPU`), either the default scheduler or SCHED_FIFO at `FIFO_PRIORITY`;
  the loop's timer slack is 1 ns and under SCHED_OTHER it asks for a short
  fair-scheduler slice (its `realtime` notes, quoted); cyclictest's
  SCHED_OTHER median ~50 us above its SCHED_FIFO one suggests it keeps a
  normal thread's default 50 us slack.
- The same background: the loop's rounds have the virtual drive, the bus
  capture and the loop's log writer on the other CPUs; cyclictest's rounds
  have a whole virtual rig there (drive, capture, a loop not pinned, its
  writer), so the same processes and bus traffic run beside both.
- The same power-management request: cyclictest holds
  `/dev/cpu_dma_latency` at 0 us while it runs (it keeps idle CPUs out of
  deep idle states); this script holds the same request through every
  round of both, so neither gets it alone.
- The same binning: both in 1 us bins, the lower edge (cyclictest truncates
  to whole us; the loop's per-tick values come from its log, truncated
  alike), percentiles by nearest rank.
- The same samples: one per wake-up. After a stall, cyclictest moves its
  next deadline past the present and sleeps again (one sample for the
  stall); the loop runs every tick it missed at once, and those catch-up
  ticks never slept: their latencies (the stall, less one period per tick)
  are counted apart (`catch_up_ticks`), not as wake-ups.

Per round it also reads `/proc/interrupts` on `CPU`: the interrupts the
measured thread's CPU took (local timer, reschedule and function-call
IPIs, TLB shootdowns, device completions...), a cause of wake-up delay. The
window is not quite the same: a loop round's includes its set-up and its
end (the outputs' final `fsync`, whose block-device completions may land on
`CPU`), a cyclictest round's only cyclictest's run.
"""
from __future__ import annotations

import os
import re
import shutil
import struct
import subprocess
import sys
import threading
import time
from collections import Counter
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator, Optional

import numpy as np

from sensaug import presets, rig

#: The CPU both run on: the last one (the first takes most interrupts).
CPU = (os.cpu_count() or 1) - 1
#: SCHED_FIFO priority of both under the FIFO policy.
FIFO_PRIORITY = 80
POLICIES = ("SCHED_OTHER", "SCHED_FIFO")
#: Seconds the background rig of a cyclictest round runs before cyclictest
#: starts (the drive boots, the loop's set-up listens and enables).
BACKGROUND_LEAD_S = 2.0
PERCENTILES = {"p50": 0.5, "p99": 0.99, "p99.9": 0.999}


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


def quantiles(counts: Counter) -> dict[str, float]:
    """p50, p99, p99.9 (nearest rank) and the max of a histogram of whole us."""
    us = np.array(sorted(counts))
    cum = np.cumsum([counts[u] for u in us])
    q = {name: float(us[np.searchsorted(cum, p * cum[-1])]) for name, p in PERCENTILES.items()}
    q["max"] = float(us[-1])
    return q


def cyclictest_counts(out: str) -> Counter:
    """cyclictest's histogram (whole us -> samples) from its output; the
    overflow (beyond -h) at its reported maximum."""
    counts: Counter = Counter()
    for line in out.splitlines():
        m = re.match(r"^(\d+)\s+(\d+)$", line.strip())
        if m and int(m.group(2)):
            counts[int(m.group(1))] = int(m.group(2))
    over = re.search(r"# Histogram Overflows:\s+(\d+)", out)
    mx = re.search(r"# Max Latencies:\s+(\d+)", out)
    if over and int(over.group(1)) and mx:
        counts[int(mx.group(1))] += int(over.group(1))
    return counts


def interrupts_on(cpu: int) -> Counter:
    """Interrupts `cpu` has taken since boot, per /proc/interrupts row."""
    counts: Counter = Counter()
    with open("/proc/interrupts") as f:
        ncpu = len(f.readline().split())
        for line in f:
            name, _, rest = line.partition(":")
            fields = rest.split()
            if len(fields) > cpu and all(x.isdigit() for x in fields[:ncpu]):
                what = " ".join(fields[ncpu:])
                counts[f"{name.strip()}: {what}" if what else name.strip()] += int(fields[cpu])
    return counts


@contextmanager
def others_only() -> Iterator[None]:
    """This process (and what it starts) off `CPU`, so only the measured
    thread runs there."""
    before = os.sched_getaffinity(0)
    others = before - {CPU}
    if others:
        os.sched_setaffinity(0, others)
    try:
        yield
    finally:
        os.sched_setaffinity(0, before)


@contextmanager
def cpu_dma_latency_zero() -> Iterator[str]:
    """Holds the PM QoS request cyclictest makes by default (0 us) while
    open; yields what was granted."""
    try:
        fd = os.open("/dev/cpu_dma_latency", os.O_WRONLY)
    except OSError as e:
        yield f"not held ({e.strerror})"
        return
    try:
        os.write(fd, struct.pack("i", 0))
        yield "held at 0 us"
    finally:
        os.close(fd)


def rig_config(seconds: float, policy: Optional[str], cpu: Optional[int]):
    """The Hi5 rig protocol for `seconds`; the loop pinned to `cpu` with
    memory locked under `policy`, or (cpu None) an ordinary process."""
    cfg = presets.hi5_rig(phase_s=seconds / 3)
    cfg.rig.realtime.cpu = cpu
    cfg.rig.realtime.mlockall = cpu is not None
    cfg.rig.realtime.fifo_priority = FIFO_PRIORITY if policy == "SCHED_FIFO" else None
    return cfg


def slept(wake_us: np.ndarray, compute_us: np.ndarray, period_us: float) -> np.ndarray:
    """Which ticks slept before running: tick 0, and every tick whose
    deadline came after the previous tick's end (its wake-up latency plus
    its compute within one period)."""
    mask = np.ones(len(wake_us), dtype=bool)
    mask[1:] = wake_us[:-1] + compute_us[:-1] < period_us
    return mask


def whole_us(values: np.ndarray) -> Counter:
    """A histogram of whole us (truncated, as cyclictest's)."""
    return Counter(np.floor(values).astype(int).tolist())


def loop_round(seconds: float, policy: str, out: Path) -> dict:
    """One loop round: its wake-up latencies (ticks that slept) and compute
    times (all ticks), whole us from the log; the catch-up ticks; its
    statistics and the interrupts on `CPU`."""
    cfg = rig_config(seconds, policy, CPU)
    before = interrupts_on(CPU)
    with others_only():
        run = rig.run_virtual_rig(cfg, out=out)
    irq = interrupts_on(CPU) - before
    wake, compute = np.asarray(run.log["wake_latency_us"]), np.asarray(run.log["compute_us"])
    t = np.asarray(run.log["t"])
    woke = slept(wake, compute, (t[1] - t[0]) * 1e6)
    return {
        "wake": whole_us(wake[woke]),
        "catch_up_ticks": int((~woke).sum()),
        "compute": whole_us(compute),
        "stats": run.stats,
        "irq": irq,
    }


def cyclictest_round(seconds: float, policy: str, out: Path) -> dict:
    """One cyclictest round beside a virtual rig on the other CPUs (started
    `BACKGROUND_LEAD_S` before it, running past its end)."""
    background: dict = {}

    def run_background() -> None:
        cfg = rig_config(seconds + BACKGROUND_LEAD_S + 1.0, None, None)
        background["stats"] = rig.run_virtual_rig(cfg, out=out, capture="bus.log").stats

    with others_only():
        thread = threading.Thread(target=run_background)
        thread.start()
    time.sleep(BACKGROUND_LEAD_S)
    before = interrupts_on(CPU)
    proc = subprocess.run(cyclictest_command(int(seconds * 1000), policy), capture_output=True, text=True, check=True)
    irq = interrupts_on(CPU) - before
    thread.join()
    return {"wake": cyclictest_counts(proc.stdout), "irq": irq, "background": background.get("stats")}


def spread(rounds: list[dict], key: str) -> dict[str, list[float]]:
    """Each percentile's smallest and largest per-round value."""
    per = [quantiles(r[key]) for r in rounds]
    return {name: [min(p[name] for p in per), max(p[name] for p in per)] for name in (*PERCENTILES, "max")}


def irq_per_s(rounds: list[dict], seconds: float) -> dict[str, float]:
    """Interrupts per second on `CPU` over the rounds, the busiest kinds."""
    total: Counter = Counter()
    for r in rounds:
        total.update(r["irq"])
    return {k: v / (seconds * len(rounds)) for k, v in total.most_common(6) if v}


def compare(round_s: float = 2.0, rounds: int = 5, out: Path = Path("out/jitter")) -> dict:
    """Per policy, `rounds` interleaved rounds of `round_s` seconds of each."""
    if shutil.which("cyclictest") is None:
        raise RuntimeError("cyclictest not found: run `bash benches/loop_jitter.sh` (installs rt-tests)")
    rows = []
    with cpu_dma_latency_zero() as qos:
        for policy in POLICIES:
            ct, lp = [], []
            for i in range(rounds):
                order = ("cyclictest", "loop") if i % 2 == 0 else ("loop", "cyclictest")
                for what in order:
                    where = out / policy.lower() / f"{what}{i}"
                    if what == "cyclictest":
                        ct.append(cyclictest_round(round_s, policy, where))
                    else:
                        lp.append(loop_round(round_s, policy, where))
            pooled_ct = sum((r["wake"] for r in ct), Counter())
            pooled_wake = sum((r["wake"] for r in lp), Counter())
            pooled_compute = sum((r["compute"] for r in lp), Counter())
            last = lp[-1]["stats"]
            rows.append({
                "policy": policy,
                "cyclictest": quantiles(pooled_ct),
                "cyclictest_spread": spread(ct, "wake"),
                "cyclictest_samples": sum(pooled_ct.values()),
                "cyclictest_command": " ".join(cyclictest_command(int(round_s * 1000), policy)),
                "wake": quantiles(pooled_wake),
                "wake_spread": spread(lp, "wake"),
                "wake_samples": sum(pooled_wake.values()),
                "compute": quantiles(pooled_compute),
                "compute_parts_last_round": last.get("compute_parts"),
                "deadline_misses": sum(r["stats"]["deadline_misses"] for r in lp),
                "catch_up_ticks": sum(r["catch_up_ticks"] for r in lp),
                "loop_page_faults": [r["stats"].get("loop_page_faults") for r in lp],
                "stop_reasons": sorted({r["stats"]["stop_reason"] for r in lp}),
                "background_stop_reasons": sorted({(r["background"] or {}).get("stop_reason", "did not report")
                                                   for r in ct}),
                "granted": last["realtime"],
                "irq_cyclictest": irq_per_s(ct, round_s),
                "irq_loop": irq_per_s(lp, round_s),
            })
    return {"round_s": round_s, "rounds": rounds, "cpu": CPU, "cpu_dma_latency": qos, "rows": rows}


def ratio(loop: float, base: float) -> float:
    """loop / cyclictest; infinite when cyclictest's figure is 0 us."""
    return loop / base if base else float("inf")


def main() -> None:
    round_s = float(sys.argv[1]) if len(sys.argv) > 1 else 2.0
    rounds = int(sys.argv[2]) if len(sys.argv) > 2 else 5
    res = compare(round_s, rounds)
    print(f"\n1 ms period, cpu {res['cpu']}, {rounds} interleaved rounds of {round_s:g} s each per policy; "
          f"cpu_dma_latency {res['cpu_dma_latency']}")
    print(f"{'':40s} {'p50':>6s} {'p99':>6s} {'p99.9':>6s} {'max':>6s}  (us, pooled; per-round range)")
    for r in res["rows"]:
        for label, d, s in (("cyclictest wake-up", r["cyclictest"], r["cyclictest_spread"]),
                            ("sensaug-rt wake-up", r["wake"], r["wake_spread"]),
                            ("sensaug-rt tick compute", r["compute"], None)):
            rng = "" if s is None else "  p99 {:.0f}-{:.0f}, p99.9 {:.0f}-{:.0f}".format(*s["p99"], *s["p99.9"])
            print(f"{r['policy'] + ' ' + label:40s} {d['p50']:6.0f} {d['p99']:6.0f} {d['p99.9']:6.0f} {d['max']:6.0f}{rng}")
        print(f"  loop/cyclictest: p99 {ratio(r['wake']['p99'], r['cyclictest']['p99']):.2f}, "
              f"p99.9 {ratio(r['wake']['p99.9'], r['cyclictest']['p99.9']):.2f}; "
              f"deadline misses {r['deadline_misses']}; catch-up ticks {r['catch_up_ticks']}; "
              f"page faults {r['loop_page_faults']}")
        print(f"  interrupts/s on cpu {res['cpu']}: cyclictest {r['irq_cyclictest']}")
        print(f"  interrupts/s on cpu {res['cpu']}: loop       {r['irq_loop']}")
        print(f"  settings: {'; '.join(r['granted'])}")


if __name__ == "__main__":
    main()
