"""Measures every safe state of the virtual rig and the time to reach it
(docs/safety.md quotes its output).

Usage: .venv/bin/python scripts/measure_safety.py [REPS] [STARTS]

Runs each fault scenario of tests/test_rig_faults.py REPS times (default 5;
the same code the tests run, with their assertions), plus SIGTERM, a dead
drive and a killed controller, and STARTS (default 30) consecutive starts of
a short trial against one drive for the gaps between the enable and tick 0.
Prints median and maximum of each figure as a Markdown table. Loopback UDP
bus only; every process is started and stopped here.
"""
from __future__ import annotations

import json
import signal
import statistics
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

import test_rig_faults as f  # noqa: E402
from sensaug_bridge.protocol import State  # noqa: E402
from test_rig import short_config, stall_tolerant  # noqa: E402


def reaction(tmp: Path, act, names: set[str], pred=lambda d: True) -> float:
    """Starts a 10 s trial, waits for its loop, calls ``act(processes)``
    and returns the ms until the first frame named in ``names`` (and
    matching ``pred``) is seen on the bus."""
    pr = f.rig_processes(tmp, short_config(gain_s=10.0))
    try:
        pr.start_controller()
        f.wait_running(pr)
        f.latest_feedback(pr)
        t0 = time.monotonic()
        act(pr)
        seen = f.first_frame(pr, names, 5.0, pred)
        assert seen is not None, f"no {names} within 5 s"
        return 1e3 * (seen[0] - t0)
    finally:
        pr.close()


def sigterm(tmp: Path) -> dict:
    """SIGTERM mid-run: time to the controller's disable on the bus."""
    ms = reaction(tmp, lambda pr: pr.controller.send_signal(signal.SIGTERM), {"SetState"},
                  lambda d: not d.message.enable)
    return {"disabled_after_ms": ms}


def dead_drive(tmp: Path) -> dict:
    """The drive killed mid-run: time to the controller's emergency stop."""
    return {"emergency_stop_after_ms": reaction(tmp, lambda pr: pr.drive.kill(), {"EmergencyStop"})}


def killed_controller(tmp: Path) -> dict:
    """SIGKILL of the controller: time to the drive's FAULT(WATCHDOG)."""
    ms = reaction(tmp, lambda pr: pr.controller.kill(), {"Fault", "Heartbeat"},
                  lambda d: d.message.state == State.FAULT)
    return {"drive_fault_after_ms": ms}


def start_gaps(tmp: Path, starts: int) -> list[dict]:
    """``starts`` consecutive short trials (the preset's 50 ms watchdog and
    20 ms feedback timeout) against one drive: the two gaps of each start,
    its exit code and whether the drive tripped before tick 1000."""
    cfg = short_config(gain_s=0.6, other_s=0.1)
    pr = f.rig_processes(tmp, cfg)
    out = []
    try:
        for _ in range(starts):
            pr.start_controller()
            code = pr.wait_controller(timeout=60)
            stats = json.loads(pr.stats.read_text())
            out.append({**stats["start"], "exit": code, "stop_reason": stats["stop_reason"], "ticks": stats["ticks"]})
    finally:
        pr.close()
    return out


def summarize(name: str, runs: list[dict]) -> list[str]:
    rows = []
    for key in runs[0]:
        vals = [r[key] for r in runs if isinstance(r.get(key), (int, float)) and r[key] == r[key]]
        if not vals or key in ("exit", "ticks"):
            continue
        rows.append(f"| {name} | {key} | {len(vals)} | {statistics.median(vals):.4g} | {max(vals):.4g} |")
    return rows


def measure(scenarios: dict, reps: int) -> list[str]:
    """Runs each scenario ``reps`` times (a failed run is reported on
    stderr and left out) and returns the Markdown table of its figures."""
    lines = ["| fault | figure | runs | median | max |", "| --- | --- | --- | --- | --- |"]
    for name, fn in scenarios.items():
        runs = []
        for i in range(reps):
            with tempfile.TemporaryDirectory() as d:
                try:
                    runs.append(fn(Path(d)))
                except AssertionError as e:
                    print(f"{name} run {i}: FAILED {e}", file=sys.stderr)
        print(f"{name}: {len(runs)}/{reps} runs passed", file=sys.stderr)
        if runs:
            lines += summarize(name, runs)
    return lines


def main() -> int:
    reps = int(sys.argv[1]) if len(sys.argv) > 1 else 5
    starts = int(sys.argv[2]) if len(sys.argv) > 2 else 30
    scenarios = {
        "second controller (refused)": f.scenario_second_controller,
        "foreign command": f.scenario_foreign_command,
        "forged 0.5 rad feedback": f.scenario_forged_jump,
        "stale-feedback flood": f.scenario_stale_flood,
        "log write failure (1 MB file-size limit)": f.scenario_log_failure,
        "SIGTERM": sigterm,
        "dead drive": dead_drive,
        "SIGKILL of the controller": killed_controller,
    }
    lines = measure(scenarios, reps)
    with tempfile.TemporaryDirectory() as d:
        gaps = start_gaps(Path(d), starts)
    lines += summarize("start (enable -> tick 0)", gaps)
    bad = [g for g in gaps if g["exit"] != 0]
    print("\n".join(lines))
    print(f"\n{len(gaps)} starts, {len(bad)} not completed: {[(g['exit'], g['stop_reason'], g['ticks']) for g in bad]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
