"""Writes BENCHMARKS.md: every figure from one run, with the command behind it.

Run through ``bash benches/run.sh`` (never edit BENCHMARKS.md by hand). In one
run on one machine it

1. builds ``crates/sensaug-core/examples/perf_harness.rs`` (bench profile) and
   times every workload of ``crates/sensaug-core/benches/workloads/mod.rs``
   one call at a time (median and tails),
2. times the peers (filterpy, scipy) and sensaug's Python API on the same
   problems (``benches/compare_oracles.py``), right after the Rust workload
   of the same name, so each ratio comes from neighbouring measurements,
3. counts instructions per call with callgrind (``valgrind --tool=callgrind``;
   the difference of two runs with different call counts, so set-up and
   warm-up cancel): stable where timings are not,
4. times and counts the whole simulated Hi5 trial, from Python (``sensaug.run``)
   and through the core alone (``perf_harness trial``), per tick,
5. runs the robot tick's tail bench (``cargo bench --bench tick_tail``: 1e6
   individually timed ticks per phase, allocations counted),
6. runs the rig tick on the loopback UDP bus (``cargo bench -p sensaug-rt
   --bench rig_tick``, compute split by part) and the bus's floor (``--bench
   bus_floor``: the cost of the system calls alone),
7. compares the loop's wake-up latency with cyclictest in interleaved rounds
   under SCHED_OTHER and SCHED_FIFO, the loop sleeping until each deadline
   and sleeping then spinning 100 us (``benches/loop_jitter.py``),
8. runs the rig loop with and without the live view (a connected and a
   stalled Foxglove client) in interleaved rounds (``benches/live_view.py``),
9. records the machine (``lscpu``), the date, the load average and the commit.
"""
from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benches"))

import compare_oracles  # noqa: E402
import live_view  # noqa: E402
import loop_jitter  # noqa: E402

HARNESS = ROOT / "target" / "release" / "examples" / "perf_harness"
BUILD = ["cargo", "build", "-q", "--profile", "bench", "--example", "perf_harness", "-p", "sensaug-core"]
RUST_CALLS = 20_000
COUNT_CALLS = (200, 1200)

# The robot's tick in each phase (`TICK_WORKLOADS` in workloads/mod.rs) is
# timed and counted like the other workloads; its tail over 1e6 individually
# timed ticks per phase, and the allocations of those ticks, come from this
# bench binary.
TAIL = ["cargo", "bench", "-q", "-p", "sensaug-core", "--bench", "tick_tail", "--"]
TAIL_TICKS = 1_000_000
# The rig tick (drain the feedback, tick, send, log) on the loopback UDP bus:
# the real loop against an in-process drive, 3 s per phase; once where the
# scheduler puts it, once pinned with the drive thread off its CPU, both with
# the drive asleep in `recv` (the demo's virtual rig: each command wakes it);
# once pinned with the drive polling on the other CPU (nothing to wake: the
# closer model of a CAN adapter).
RIG = ["cargo", "bench", "-q", "-p", "sensaug-rt", "--bench", "rig_tick", "--"]
RIG_PHASE_S = 3.0
RIG_MODES = {"not pinned": [], "pinned": ["pinned"], "pinned, drive polling": ["polling"]}
# The bus calls alone, each timed: the kernel's floor under the rig tick.
FLOOR = ["cargo", "bench", "-q", "-p", "sensaug-rt", "--bench", "bus_floor", "--"]
FLOOR_CALLS = 5000
# Interleaved rounds of cyclictest and of the loop (sleep only; sleep then
# spin), per scheduling policy.
JITTER_ROUND_S = 2.0
JITTER_ROUNDS = 5


def run(cmd: list[str], **kw) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, cwd=ROOT, check=True, capture_output=True, text=True, **kw)


def machine() -> dict[str, str]:
    info = {}
    for line in run(["lscpu"]).stdout.splitlines():
        key, _, value = line.partition(":")
        info[key.strip()] = value.strip()
    return {
        "model": info.get("Model name", "?"),
        "cpus": info.get("CPU(s)", "?"),
        "threads_per_core": info.get("Thread(s) per core", "?"),
        "cores_per_socket": info.get("Core(s) per socket", "?"),
        "rustc": run(["rustc", "--version"]).stdout.strip(),
        "python": sys.version.split()[0],
    }


def load_average() -> str:
    return " ".join(Path("/proc/loadavg").read_text().split()[:3])


def commit() -> str:
    sha = run(["git", "rev-parse", "--short", "HEAD"]).stdout.strip()
    dirty = run(["git", "status", "--porcelain", "--untracked-files=no"]).stdout.strip()
    return sha + (" (with uncommitted changes)" if dirty else "")


def rust_timing(name: str) -> dict:
    out = run([str(HARNESS), "time", name, str(RUST_CALLS)]).stdout
    return json.loads(out)


def callgrind_total(cmd: list[str], env: dict[str, str] | None = None) -> int | None:
    res = run(["valgrind", "--tool=callgrind", "--callgrind-out-file=/dev/null", *cmd],
              env=None if env is None else {**os.environ, **env})
    m = re.search(r"Collected\s*:\s*(\d+)", res.stderr)
    return None if m is None else int(m.group(1))


def instructions_per(cmd: list[str], counts: tuple[int, int], per_count: int = 1,
                     env: dict[str, str] | None = None) -> float | None:
    """Instructions per unit: (I(n2) - I(n1)) / ((n2 - n1) per_count) under
    callgrind, for `cmd + [n]` with n in `counts` (set-up and warm-up cancel)."""
    if shutil.which("valgrind") is None:
        return None
    totals = [callgrind_total(cmd + [str(n)], env) for n in counts]
    if None in totals:
        return None
    return (totals[1] - totals[0]) / ((counts[1] - counts[0]) * per_count)


def instructions(name: str) -> float | None:
    """Instructions per call of a workload."""
    return instructions_per([str(HARNESS), "count", name], COUNT_CALLS)


# The whole trial of compare_oracles.sensaug_trial_per_tick_ns through the core
# alone (workloads::trial): timed over TRIAL_REPEATS trials, and counted under
# callgrind with TRIAL_COUNTS trials (the difference over the difference of
# ticks is the instructions of one trial tick), as is the same trial from
# Python (sensaug.run; hash seed fixed and numpy's BLAS on one thread so the
# interpreter's and the idle BLAS threads' instructions do not vary).
TRIAL_REPEATS = 7
TRIAL_COUNTS = (1, 3)
TRIAL_PY = ("import sys, sensaug; from sensaug import presets; "
            "cfg = presets.hi5_experiment(phase_s=20.0); "
            "[sensaug.run(cfg) for _ in range(int(sys.argv[1]))]")
TRIAL_PY_ENV = {"PYTHONHASHSEED": "0", "OPENBLAS_NUM_THREADS": "1"}


def rust_trial() -> dict:
    out = json.loads(run([str(HARNESS), "trial", "time", str(TRIAL_REPEATS)]).stdout)
    out["instructions"] = instructions_per([str(HARNESS), "trial", "count"], TRIAL_COUNTS, out["ticks"])
    return out


def tick_tail() -> list[dict]:
    out = run(TAIL + [str(TAIL_TICKS), "--json"]).stdout
    return [json.loads(line) for line in out.splitlines() if line.startswith("{")]


def json_line(cmd: list[str]) -> dict:
    """The JSON line a bench binary prints."""
    out = run(cmd).stdout
    return json.loads(next(line for line in out.splitlines() if line.startswith("{")))


def rig_tick() -> dict[str, dict]:
    return {mode: json_line(RIG + [str(RIG_PHASE_S), *extra]) for mode, extra in RIG_MODES.items()}


def bus_floor() -> dict:
    return json_line(FLOOR + [str(FLOOR_CALLS)])


def rig_lines(rigs: dict[str, dict], floor: dict) -> list[str]:
    """The rig tick's section: compute and its parts per mode, then the
    bus calls' floor."""
    lines = [
        "## Rig tick on the loopback UDP bus",
        "",
        "The real loop (`Rig::run`: wake, drain the received frames, the robot's tick and the "
        "virtual human, one torque command, the log record) against the minimal in-process drive "
        f"of the tests, through the Hi5 rig protocol with {RIG_PHASE_S:g} s phases; ordinary "
        "thread (SCHED_OTHER, timer slack 1 ns, no mlockall), either where the scheduler puts "
        "it or pinned to the last cpu with the drive and log writer threads off it. The drive "
        "column says how the drive thread waits: `sleeping` in a blocking `recv`, as the demo's "
        "virtual rig does, so every command's send wakes it (on another cpu an inter-processor "
        "interrupt, paid in `actuate`); `polling` spins on the other cpu (the non-blocking "
        "`recv_ready`, then 20 us of busy-waiting when the bus was empty), so the send wakes "
        "no one: the closer model of a CAN adapter, whose hardware "
        "is always listening. The loop's "
        "own 1 us-bin histograms (bin upper edges): `compute` = wake-up to the command sent = "
        "sense (drain the bus: one `recvmmsg` per tick) + decide (safety checks, the robot's tick, "
        "the virtual human) + actuate (one `send`); `record` (the log push) follows. Page faults: "
        "the loop thread's during the run.",
        "",
        f"Command: `{' '.join(RIG)} {RIG_PHASE_S:g} [pinned | polling]` (`polling` implies "
        "`pinned`).",
        "",
        "| loop | drive | ticks | compute p50 / p99 / p99.9 / max (us) | sense p50 / p99 | decide p50 / p99 | "
        "actuate p50 / p99 | record p50 / p99 | page faults | feedback missing | deadline misses |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for rig in rigs.values():
        c, parts = rig["compute"], rig["compute_parts"]
        pair = " | ".join(f"{parts[p]['p50_us']:.0f} / {parts[p]['p99_us']:.0f}"
                          for p in ("sense", "decide", "actuate", "record"))
        loop = "pinned" if rig["loop_cpu"] is not None else "not pinned"
        lines.append(f"| {loop} | {rig['drive_wait']} | {rig['ticks']} | {c['p50_us']:.0f} / {c['p99_us']:.0f} / {c['p999_us']:.0f} / "
                     f"{c['max_us']:.0f} | {pair} | {rig['loop_page_faults']} | "
                     f"{rig['can']['missing_feedback']} | {rig['deadline_misses']} |")
    lines += [
        "",
        "The floor: the bus calls alone, each call timed on its own, the caller pinned to cpu "
        f"{floor['caller_cpu']} (`benches/bus_floor.rs`). The send of the virtual bus delivers to "
        "every peer's socket and wakes the peers sleeping on it (the virtual drive, the bus "
        "capture); on another cpu that wake is an inter-processor interrupt, paid inside the "
        "loop's `send` (its `actuate`). A real CAN adapter has no peer process to wake. The "
        "`paced` rows are the loop's bus calls alone at its pace and in its order: at each 1 ms "
        "deadline one drain (a peer's answer and the own frame's echo) then one send, a peer on "
        "the other cpu polling the bus like the polling drive and answering every frame; the "
        "floor under the `polling` row's `compute`, with no controller between the two calls.",
        "",
        f"Command: `{' '.join(FLOOR)} {FLOOR_CALLS}`.",
        "",
        "| call | calls | p50 (us) | p99 (us) | p99.9 (us) | max (us) |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for case in floor["cases"]:
        lines.append(f"| {case['what']} | {case['calls']} | {case['p50_us']:.2f} | {case['p99_us']:.2f} | "
                     f"{case['p999_us']:.2f} | {case['max_us']:.1f} |")
    paced = next((c for c in floor["cases"] if c["what"].startswith("paced drain + send")), None)
    polling = next((r for r in rigs.values() if r["drive_wait"] == "polling"), None)
    if paced and polling:
        c = polling["compute"]
        above = paced["p50_us"] > 5 or paced["p99_us"] > 10
        lines += [
            "",
            f"The `polling` row's compute, p50 {c['p50_us']:.0f} / p99 {c['p99_us']:.0f} us (1 us "
            f"bins, upper edges), against its bus calls alone at the same pace, p50 "
            f"{paced['p50_us']:.1f} / p99 {paced['p99_us']:.1f} us: the bus calls alone are "
            + ("above" if above else "within")
            + " the rig-tick target of 5 / 10 us (p50 / p99) on this machine; what the loop "
            "adds to them (the safety checks, the controller, the log record's clock reads) is "
            "the difference.",
        ]
    return lines + [""]


def jitter_lines(jitter: dict) -> list[str]:
    """The wake-up latency section: cyclictest and the loop (sleep only, and
    sleep then spin) per policy, pooled over interleaved rounds, with the
    per-round spread."""
    rounds, round_s, spin = jitter["rounds"], jitter["round_s"], jitter["spin_us"]
    lines = [
        "## Loop wake-up latency against cyclictest",
        "",
        f"1 ms period; per policy {rounds} rounds of {round_s:g} s of each of three, interleaved "
        f"(cyclictest, loop, loop with spin, loop with spin, loop, cyclictest, ...), pooled into one "
        "histogram each; the per-round range of p99 and p99.9 shows the spread "
        "(`benches/loop_jitter.py`, `compare`). All three pinned to cpu "
        f"{jitter['cpu']} with memory locked; SCHED_FIFO at priority {loop_jitter.FIFO_PRIORITY} "
        "for all, or the default scheduler for all. The same background for all: the loop's "
        "rounds have the virtual drive, the bus capture and the loop's log writer on the other "
        "cpus; cyclictest's rounds have a whole virtual rig there. `/dev/cpu_dma_latency` (the "
        f"power-management request cyclictest makes): {jitter['cpu_dma_latency']} through all "
        "rounds of all three. Latency in us, 1 us bins, lower edges (cyclictest's convention; the "
        "loop's per-tick values from its log), nearest-rank percentiles; one sample per wake-up "
        "(the ticks the loop runs at once to catch up after a stall never waited: counted apart, "
        "as cyclictest skips those periods).",
        "",
        "The rows: *cyclictest wake-up*, a bare thread's sleep on absolute deadlines; "
        "*sensaug-rt wake-up (sleep only)*, the loop's tick start after its deadline when it "
        "sleeps until the deadline (`rig.realtime.spin_us = 0`, the default): the same quantity "
        f"as cyclictest's; *sensaug-rt wake-up (sleep + {spin} us spin)*, the tick start after "
        f"its deadline when the loop sleeps until {spin} us before it and busy-waits on the clock "
        f"for the rest (`spin_us = {spin}`): what the controller sees, at the cost of a busy cpu "
        f"for {spin} us of every 1 ms period ({spin / 10:g}% of the cpu); *sensaug-rt "
        "sleep_latency (... the OS's part)*, in that same run, the sleep's return after its own "
        f"target ({spin} us before the deadline): the OS timer's latency, cyclictest's quantity "
        "(only ticks whose sleep slept: a tick whose previous tick ended after the sleep's "
        "target spun without sleeping); *tick compute*, wake-up to command sent, per run. The "
        "ratio column divides each loop row by cyclictest's.",
        "",
        *loop_jitter.table(jitter),
        "",
    ]
    irq = lambda d: ", ".join(f"{k} {v:.0f}" for k, v in d.items())  # noqa: E731
    for r in jitter["rows"]:
        runs = "; ".join(
            f"sensaug-rt {lp['name']}: {lp['wake_samples']} wake-ups ({lp['sleep_samples']} that slept), stopped: "
            f"{', '.join(lp['stop_reasons'])}, deadline misses {lp['deadline_misses']}, catch-up ticks "
            f"(not wake-ups) {lp['catch_up_ticks']}, page faults per round {lp['loop_page_faults']}, "
            f"settings granted: {', '.join(lp['granted'])}; interrupts per second on cpu {jitter['cpu']} "
            f"(set-up and the outputs' final fsync included): {irq(lp['irq'])}"
            for lp in r["loops"]
        )
        lines.append(
            f"* {r['policy']}: `{r['cyclictest_command']}` ({r['cyclictest_samples']} samples; background "
            f"rigs stopped: {', '.join(r['background_stop_reasons'])}; interrupts per second on cpu "
            f"{jitter['cpu']}: {irq(r['irq_cyclictest'])}); {runs}."
        )
    return lines + [""]


def live_lines(live: dict) -> list[str]:
    return [
        "",
        "## The rig loop with and without the live view",
        "",
        f"`benches/live_view.py` (its docstring says what each kind is): {live['rounds']} virtual-rig runs of "
        f"{live['round_s']:g} s per kind (the Hi5 protocol, 1 kHz, the virtual drive on the loopback bus), "
        "interleaved A B C C B A; per kind the ticks of its runs pooled. *viewer*: `sensaug-rt --feed` to "
        "`sensaug live` (its own process, 100 Hz per topic) with a Foxglove WebSocket client reading every "
        "channel; *stalled viewer*: the client subscribed and never reading. Compute: wake-up to command "
        "sent (`compute_us`); the loop's tick is the same code in all three (the feed is sent by the log "
        "writer thread), so any difference is the machine's noise or contention for its 2 CPUs.",
        "",
        *live_view.table(live),
        "",
    ]


def us(ns: float) -> str:
    return f"{ns / 1e3:.2f}"


def count_text(count: float | None) -> str:
    return "n/a (no valgrind)" if count is None else f"{count:.0f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "BENCHMARKS.md"))
    ap.add_argument("--peer-calls", type=int, default=3000)
    args = ap.parse_args()

    started = dt.datetime.now(dt.timezone.utc)
    load_before = load_average()
    run(BUILD)
    names = run([str(HARNESS), "list"]).stdout.split()
    peers = compare_oracles.calls()

    rows = []  # (workload, implementation, timing dict, instructions or None)
    rust = {}
    for name in names:
        rust[name] = rust_timing(name)
        rows.append((name, "sensaug (Rust)", rust[name], instructions(name)))
        for wname, impl, fn in peers:
            if wname == name:
                rows.append((name, impl, compare_oracles.per_call_ns(fn, args.peer_calls), None))
    tails = tick_tail()
    trial = compare_oracles.sensaug_trial_per_tick_ns()
    trial["instructions"] = instructions_per([sys.executable, "-c", TRIAL_PY], TRIAL_COUNTS,
                                             trial["ticks"], TRIAL_PY_ENV)
    trial_rust = rust_trial()
    trial_peer = compare_oracles.numpy_filterpy_trial_per_tick_ns()
    rig = rig_tick()
    floor = bus_floor()
    jitter = loop_jitter.compare(JITTER_ROUND_S, JITTER_ROUNDS)
    live = live_view.compare(live_view.ROUND_S, live_view.ROUNDS)
    load_after = load_average()
    m = machine()

    lines = [
        "# Benchmarks",
        "",
        "Generated by `bash benches/run.sh` (`benches/report.py`); do not edit by hand.",
        "",
        f"* Date: {started:%Y-%m-%d %H:%M} UTC; commit {commit()}",
        f"* Machine: {m['model']}, {m['cpus']} CPUs ({m['cores_per_socket']} cores per socket, "
        f"{m['threads_per_core']} threads per core); {m['rustc']}; Python {m['python']}",
        f"* Load average (1, 5, 15 min) before / after: {load_before} / {load_after}. The machine is "
        "shared with other builds, so timings are noisy; the instruction counts are not.",
        "",
        "## Per call, side by side",
        "",
        "Every call timed on its own (a clock read before and after; the median cost of an empty "
        "timed call is in the last column and included in the figures). Ratio = the row's median "
        "over the Rust median of the same workload, both from this run.",
        "",
        "Commands: Rust `target/release/examples/perf_harness time <workload> "
        f"{RUST_CALLS}` (built by `{' '.join(BUILD)}`); peers and the Python API "
        f"`benches/compare_oracles.py` (`per_call_ns`, {args.peer_calls} calls after "
        f"{compare_oracles.WARM_UP_CALLS} warm-up calls).",
        "",
        "| workload | implementation | median (us) | p99 (us) | p99.9 (us) | max (us) | "
        "median / Rust median | timer overhead (us) |",
        "|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for name, impl, t, _ in rows:
        ratio = t["median_ns"] / rust[name]["median_ns"]
        lines.append(
            f"| {name} | {impl} | {us(t['median_ns'])} | {us(t['p99_ns'])} | {us(t['p999_ns'])} | "
            f"{us(t['max_ns'])} | {ratio:.1f} | {us(t['timer_overhead_median_ns'])} |"
        )
    lines += [
        "",
        "## Instructions per call (callgrind)",
        "",
        "Command: `valgrind --tool=callgrind --callgrind-out-file=/dev/null "
        f"target/release/examples/perf_harness count <workload> <calls>` for calls = "
        f"{COUNT_CALLS[0]} and {COUNT_CALLS[1]}; instructions per call = difference of the "
        "totals / difference of the calls. A UKF step is one `update` plus one `predict`.",
        "",
        "| workload | instructions per call |",
        "|---|---:|",
    ]
    for name, impl, _, count in rows:
        if impl == "sensaug (Rust)":
            lines.append(f"| {name} | {count_text(count)} |")
    lines += [
        "",
        "## Robot tick: the tail",
        "",
        "The robot's whole tick (the phase's estimators, the command, the prediction) in each phase "
        "of the Hi5 protocol (10 s phases, target-view noise 1.0 in the integration phase), in "
        "steady state: measurements from a simulated trial of the same robot, the robot brought "
        "to the phase's first tick before timing, ticks wrapping round within the phase. Each "
        "tick timed on its own; allocations counted by a counting global allocator over the "
        "timed ticks. Medians and instruction counts of the same workloads are in the tables "
        "above (`robot_tick/*`).",
        "",
        f"Command: `{' '.join(TAIL)} {TAIL_TICKS} --json` (without `--json`: a histogram).",
        "",
        "| phase | ticks | p50 (us) | p99 (us) | p99.9 (us) | max (us) | allocations |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for t in tails:
        lines.append(
            f"| {t['name']} | {t['ticks']} | {us(t['p50_ns'])} | {us(t['p99_ns'])} | "
            f"{us(t['p999_ns'])} | {us(t['max_ns'])} | {t['allocations']} |"
        )
    lines += [
        "",
        "## Whole simulated trial from Python",
        "",
        f"`sensaug.run(presets.hi5_experiment(phase_s=20.0))`: a {trial['ticks']}-tick Hi5 trial (robot "
        "with its estimators, a virtual human that does not identify the robot, plant, noise, the "
        f"log as numpy arrays), wall time per tick, median of {trial['repeats']} trials after a warm-up "
        "(`benches/compare_oracles.py`, `sensaug_trial_per_tick_ns`). The same trial through the "
        "core alone, without Python and its log arrays: `target/release/examples/perf_harness trial "
        f"time {TRIAL_REPEATS}` (median of {TRIAL_REPEATS} trials after a warm-up; the bench profile, "
        "thin LTO; the extension: Cargo.toml's `extension` profile, thin LTO and one codegen "
        "unit). Instructions per "
        "tick: callgrind totals of "
        f"{TRIAL_COUNTS[0]} and {TRIAL_COUNTS[1]} trials, their difference over the difference of "
        "ticks (`perf_harness trial count <trials>`; from Python the script `TRIAL_PY` of "
        "`benches/report.py` with `PYTHONHASHSEED=0 OPENBLAS_NUM_THREADS=1`). numpy's OpenBLAS runs "
        "on one thread in the bench process (`compare_oracles.py` sets `OPENBLAS_NUM_THREADS=1` "
        "unless it is set): its idle threads otherwise busy-wait while the trial runs. Peer: an independent "
        "numpy + filterpy loop of the gain phase (plant, LQR robot, virtual human, noise, filterpy's "
        f"stage-1 update and predict), median of {trial_peer['ticks']} individually timed ticks "
        "(`numpy_filterpy_trial_per_tick_ns`).",
        "",
        "| implementation | per tick (us) | instructions per tick | peer / sensaug |",
        "|---|---:|---:|---:|",
        f"| sensaug.run | {us(trial['median_ns'])} | {count_text(trial['instructions'])} | 1.0 |",
        f"| the same trial in Rust (`perf_harness trial`) | {us(trial_rust['median_ns_per_tick'])} | "
        f"{count_text(trial_rust['instructions'])} | |",
        f"| numpy + filterpy loop (stage 1 only) | {us(trial_peer['median_ns'])} | | "
        f"{trial_peer['median_ns'] / trial['median_ns']:.0f} |",
        "",
    ]
    lines += rig_lines(rig, floor) + jitter_lines(jitter) + live_lines(live)
    Path(args.out).write_text("\n".join(lines))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
