"""The loop's 1 kHz wake-up latency against cyclictest, side by side, under
SCHED_OTHER and SCHED_FIFO, with and without the loop's sleep-then-spin
wake-up. `bash benches/loop_jitter.sh [round_s] [rounds]` installs
cyclictest (Debian rt-tests), prints the table and writes the pooled
figures to `out/jitter/compare.json`; `benches/report.py` puts the same
table (`table`) into BENCHMARKS.md.

cyclictest measures the bare wake-up latency of a thread sleeping on
absolute deadlines (clock_nanosleep, TIMER_ABSTIME). The loop runs twice
per round beside it:

- *sleep only* (`rig.realtime.spin_us = 0`): it sleeps until the deadline,
  as cyclictest does; its `wake_latency` (the tick's start after the
  deadline) is what cyclictest measures.
- *sleep + `SPIN_US` spin*: it sleeps until `SPIN_US` before the deadline,
  then busy-waits on the clock until the deadline (10% of the cpu at
  1 kHz and 100 us). Two figures: `wake_latency`, the tick's start after
  its deadline (what the controller sees; the spin hides an OS wake-up
  that is less than `SPIN_US` late), and `sleep_latency`, the sleep's
  return after its own target (the OS's part: the quantity cyclictest
  measures, for a sleep that ends `SPIN_US` earlier). Comparing the spin
  run's `wake_latency` with cyclictest compares the controller's timing
  with a bare sleep, not two sleeps: the row says which it is.

The loop adds its own work (CAN, the estimators) after waking, reported
separately as `compute`.

What makes the comparison fair (the machines are shared and noisy):

- Interleaved rounds: per policy, `rounds` short rounds of each of the
  three, in the order cyclictest, loop, loop with spin, loop with spin,
  loop, cyclictest, cyclictest, ... (A B C C B A: a drift in the machine's
  load hits all three alike); the table pools each one's rounds into one
  histogram and gives the spread of the per-round figures.
- The same settings: 1 ms period, memory locked, pinned to the same CPU
  (`CPU`), either the default scheduler or SCHED_FIFO at `FIFO_PRIORITY`;
  the loop's timer slack is 1 ns and under SCHED_OTHER it asks for a short
  fair-scheduler slice (its `realtime` notes, quoted); cyclictest's
  SCHED_OTHER median ~50 us above its SCHED_FIFO one suggests it keeps a
  normal thread's default 50 us slack. The two loop runs differ only in
  `spin_us`.
- The same background: the loop's rounds (both kinds) have the virtual
  drive, the bus capture and the loop's log writer on the other CPUs;
  cyclictest's rounds have a whole virtual rig there (drive, capture, a
  loop not pinned, its writer), so the same processes and bus traffic run
  beside all three.
- The same power-management request: cyclictest holds
  `/dev/cpu_dma_latency` at 0 us while it runs (it keeps idle CPUs out of
  deep idle states: an idle cpu polls); this script holds the same request
  through every round of all three, so none gets it alone.
- The same binning: all in 1 us bins, the lower edge (cyclictest truncates
  to whole us; the loop's per-tick values come from its log, truncated
  alike), percentiles by nearest rank.
- The same samples: one per wake-up. After a stall, cyclictest moves its
  next deadline past the present and sleeps again (one sample for the
  stall); the loop runs every tick it missed at once, and those catch-up
  ticks never waited: their latencies (the stall, less one period per tick)
  are counted apart (`catch_up_ticks`), not as wake-ups. With the spin, a
  tick whose previous tick ended after its sleep's target but before its
  deadline spun without sleeping: a wake-up (its `wake_latency` counts),
  but not a sample of the OS timer (its `sleep_latency` is counted apart,
  `spin_only_ticks`).

Per round it also reads `/proc/interrupts` on `CPU`: the interrupts the
measured thread's CPU took (local timer, reschedule and function-call
IPIs, TLB shootdowns, device completions...), a cause of wake-up delay. The
window is not quite the same: a loop round's includes its set-up and its
end (the outputs' final `fsync`, whose block-device completions may land on
`CPU`), a cyclictest round's only cyclictest's run.
"""
from __future__ import annotations

import json
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
#: The spin (us) of the loop's sleep-then-spin run.
SPIN_US = 100
#: The two loop runs of a round: their names in the table, and spin_us.
LOOPS = {"sleep only": 0, f"sleep + {SPIN_US} us spin": SPIN_US}
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


def rig_config(seconds: float, policy: Optional[str], cpu: Optional[int], spin_us: int = 0):
    """The Hi5 rig protocol for `seconds`; the loop pinned to `cpu` with
    memory locked under `policy`, or (cpu None) an ordinary process; its
    sleep-then-spin `spin_us` (0: sleep only)."""
    cfg = presets.hi5_rig(phase_s=seconds / 3)
    cfg.rig.realtime.cpu = cpu
    cfg.rig.realtime.mlockall = cpu is not None
    cfg.rig.realtime.fifo_priority = FIFO_PRIORITY if policy == "SCHED_FIFO" else None
    cfg.rig.realtime.spin_us = spin_us
    return cfg


def waited(wake_us: np.ndarray, compute_us: np.ndarray, before_deadline_us: float) -> np.ndarray:
    """Which ticks waited before running: tick 0, and every tick whose
    previous tick ended (its wake-up latency plus its compute, after its own
    deadline) more than `before_deadline_us` before this tick's deadline,
    one period after the previous one. With the period: the ticks that
    waited for their deadline (slept or spun); with the period less the
    spin: the ticks whose sleep slept."""
    mask = np.ones(len(wake_us), dtype=bool)
    mask[1:] = wake_us[:-1] + compute_us[:-1] < before_deadline_us
    return mask


def whole_us(values: np.ndarray) -> Counter:
    """A histogram of whole us (truncated, as cyclictest's)."""
    return Counter(np.floor(values).astype(int).tolist())


def loop_round(seconds: float, policy: str, out: Path, spin_us: int) -> dict:
    """One loop round with `spin_us`: its wake-up latencies (ticks that
    waited for their deadline), sleep latencies (ticks whose sleep slept)
    and compute times (all ticks), whole us from the log; the ticks counted
    apart; its statistics and the interrupts on `CPU`."""
    cfg = rig_config(seconds, policy, CPU, spin_us)
    before = interrupts_on(CPU)
    with others_only():
        run = rig.run_virtual_rig(cfg, out=out)
    irq = interrupts_on(CPU) - before
    wake, compute = np.asarray(run.log["wake_latency_us"]), np.asarray(run.log["compute_us"])
    sleep = np.asarray(run.log["sleep_latency_us"])
    t = np.asarray(run.log["t"])
    period_us = (t[1] - t[0]) * 1e6
    woke = waited(wake, compute, period_us)
    slept = waited(wake, compute, period_us - spin_us)
    return {
        "wake": whole_us(wake[woke]),
        "sleep": whole_us(sleep[slept]),
        "catch_up_ticks": int((~woke).sum()),
        "spin_only_ticks": int((woke & ~slept).sum()),
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


def pooled(rounds: list[dict], key: str) -> tuple[dict[str, float], dict[str, list[float]], int]:
    """The percentiles of the rounds' `key` histograms pooled, their
    per-round spread and the pooled sample count."""
    total = sum((r[key] for r in rounds), Counter())
    return quantiles(total), spread(rounds, key), sum(total.values())


def loop_summary(name: str, spin_us: int, rounds: list[dict], round_s: float) -> dict:
    """One loop run's rounds, pooled: wake-up, sleep and compute latencies,
    the ticks counted apart, and what its statistics said."""
    wake, wake_spread, wake_samples = pooled(rounds, "wake")
    sleep, sleep_spread, sleep_samples = pooled(rounds, "sleep")
    last = rounds[-1]["stats"]
    return {
        "name": name,
        "spin_us": spin_us,
        "wake": wake, "wake_spread": wake_spread, "wake_samples": wake_samples,
        "sleep": sleep, "sleep_spread": sleep_spread, "sleep_samples": sleep_samples,
        "compute": pooled(rounds, "compute")[0],
        "compute_parts_last_round": last.get("compute_parts"),
        "deadline_misses": sum(r["stats"]["deadline_misses"] for r in rounds),
        "catch_up_ticks": sum(r["catch_up_ticks"] for r in rounds),
        "spin_only_ticks": sum(r["spin_only_ticks"] for r in rounds),
        "loop_page_faults": [r["stats"].get("loop_page_faults") for r in rounds],
        "stop_reasons": sorted({r["stats"]["stop_reason"] for r in rounds}),
        "granted": last["realtime"],
        "irq": irq_per_s(rounds, round_s),
    }


def compare(round_s: float = 2.0, rounds: int = 5, out: Path = Path("out/jitter")) -> dict:
    """Per policy, `rounds` interleaved rounds of `round_s` seconds of
    cyclictest and of each loop run (`LOOPS`), in the order A B C, C B A."""
    if shutil.which("cyclictest") is None:
        raise RuntimeError("cyclictest not found: run `bash benches/loop_jitter.sh` (installs rt-tests)")
    kinds = ["cyclictest", *LOOPS]
    rows = []
    with cpu_dma_latency_zero() as qos:
        for policy in POLICIES:
            done: dict[str, list[dict]] = {k: [] for k in kinds}
            for i in range(rounds):
                for what in kinds if i % 2 == 0 else kinds[::-1]:
                    where = out / policy.lower() / f"{what.replace(' ', '_')}{i}"
                    if what == "cyclictest":
                        done[what].append(cyclictest_round(round_s, policy, where))
                    else:
                        done[what].append(loop_round(round_s, policy, where, LOOPS[what]))
            ct = done["cyclictest"]
            wake, wake_spread, samples = pooled(ct, "wake")
            rows.append({
                "policy": policy,
                "cyclictest": wake,
                "cyclictest_spread": wake_spread,
                "cyclictest_samples": samples,
                "cyclictest_command": " ".join(cyclictest_command(int(round_s * 1000), policy)),
                "background_stop_reasons": sorted({(r["background"] or {}).get("stop_reason", "did not report")
                                                   for r in ct}),
                "irq_cyclictest": irq_per_s(ct, round_s),
                "loops": [loop_summary(name, spin, done[name], round_s) for name, spin in LOOPS.items()],
            })
    return {"round_s": round_s, "rounds": rounds, "cpu": CPU, "cpu_dma_latency": qos, "spin_us": SPIN_US,
            "rows": rows}


def ratio(loop: float, base: float) -> float:
    """loop / cyclictest; infinite when cyclictest's figure is 0 us."""
    return loop / base if base else float("inf")


def table(res: dict) -> list[str]:
    """The comparison as a markdown table: per policy, cyclictest, each loop
    run's wake-up latency, the spin run's sleep latency, and each loop run's
    tick compute; the loop rows' p99 and p99.9 over cyclictest's."""
    lines = [
        "| policy | what | p50 | p99 | p99.9 | max | per-round p99 | per-round p99.9 | "
        "loop / cyclictest at p99, p99.9 |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|",
    ]

    def row(policy: str, what: str, q: dict, s: Optional[dict], base: Optional[dict]) -> str:
        rng = (lambda p: "") if s is None else (lambda p: f"{s[p][0]:.0f}-{s[p][1]:.0f}")
        vs = "" if base is None else f"{ratio(q['p99'], base['p99']):.2f}, {ratio(q['p99.9'], base['p99.9']):.2f}"
        return (f"| {policy} | {what} | {q['p50']:.0f} | {q['p99']:.0f} | {q['p99.9']:.0f} | {q['max']:.0f} | "
                f"{rng('p99')} | {rng('p99.9')} | {vs} |")

    for r in res["rows"]:
        base = r["cyclictest"]
        lines.append(row(r["policy"], "cyclictest wake-up", base, r["cyclictest_spread"], None))
        for lp in r["loops"]:
            lines.append(row(r["policy"], f"sensaug-rt wake-up ({lp['name']})", lp["wake"], lp["wake_spread"], base))
            if lp["spin_us"]:
                lines.append(row(r["policy"], f"sensaug-rt sleep_latency ({lp['name']}: the OS's part)",
                                 lp["sleep"], lp["sleep_spread"], base))
        for lp in r["loops"]:
            lines.append(row(r["policy"], f"sensaug-rt tick compute ({lp['name']})", lp["compute"], None, None))
    return lines


def main() -> None:
    round_s = float(sys.argv[1]) if len(sys.argv) > 1 else 2.0
    rounds = int(sys.argv[2]) if len(sys.argv) > 2 else 5
    out = Path("out/jitter")
    res = compare(round_s, rounds, out)
    # The pooled figures as data too (benches/report.py's input shape).
    (out / "compare.json").write_text(json.dumps(res, indent=1))
    print(f"\n1 ms period, cpu {res['cpu']}, {rounds} interleaved rounds of {round_s:g} s of each per policy "
          f"(cyclictest, {', '.join(LOOPS)}); cpu_dma_latency {res['cpu_dma_latency']}; us, 1 us bins, "
          "lower edges, pooled over the rounds\n")
    print("\n".join(table(res)))
    for r in res["rows"]:
        print(f"\n{r['policy']}: cyclictest {r['cyclictest_samples']} samples; "
              f"interrupts/s on cpu {res['cpu']}: {r['irq_cyclictest']}")
        for lp in r["loops"]:
            print(f"  {lp['name']}: {lp['wake_samples']} wake-ups, {lp['sleep_samples']} sleeps; "
                  f"catch-up ticks {lp['catch_up_ticks']}; spin-only ticks {lp['spin_only_ticks']}; "
                  f"deadline misses {lp['deadline_misses']}; page faults {lp['loop_page_faults']}; "
                  f"stopped: {', '.join(lp['stop_reasons'])}")
            print(f"    interrupts/s on cpu {res['cpu']}: {lp['irq']}")
            print(f"    settings: {'; '.join(lp['granted'])}")


if __name__ == "__main__":
    main()
