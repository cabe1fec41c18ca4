"""Measures every safe state of the virtual rig and the time to reach it
(docs/safety.md quotes its output).

Usage: .venv/bin/python scripts/measure_safety.py [REPS] [STARTS] [--only WORD]
       .venv/bin/python scripts/measure_safety.py --brake-model

Runs each fault scenario of tests/test_rig_faults.py REPS times (default 5;
the same code the tests run, with their assertions) on the drive profiles it
names, plus SIGTERM, a dead drive and a killed controller, the controlled
stop requested 10 ms after a target step (8 and 30 deg targets, the virtual
human on and off, both profiles: the handle's travel and speeds on the
drive's own record), the experimenter's stop key typed into `sensaug rig`'s
terminal (a pseudo-terminal), and STARTS (default 30) consecutive starts of a short
trial against one drive for the gaps between the enable and tick 0 (0: none).
``--only WORD`` runs the scenarios whose name contains WORD;
``--brake-model`` prints the brake's travel on the model plant instead
(:func:`brake_model`). Prints median
and maximum of each figure as a Markdown table. Loopback UDP bus only; every
process is started and stopped here.
"""
from __future__ import annotations

import json
import math
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


def reaction(tmp: Path, act, names: set[str], pred=lambda d: True, after_s: float = 0.0, cfg=None) -> float:
    """Starts a 10 s trial, waits for its loop (and ``after_s``), calls
    ``act(processes)`` and returns the ms until the first frame named in
    ``names`` (and matching ``pred``) is seen on the bus. ``cfg``: the
    trial (default: the preset's limits, 10 s gain phase)."""
    pr = f.rig_processes(tmp, cfg or short_config(gain_s=10.0))
    try:
        pr.start_controller()
        f.wait_running(pr)
        time.sleep(after_s)
        f.latest_feedback(pr)
        t0 = time.monotonic()
        act(pr)
        seen = f.first_frame(pr, names, 5.0, pred)
        assert seen is not None, f"no {names} within 5 s"
        return 1e3 * (seen[0] - t0)
    finally:
        pr.close()


def sigterm(tmp: Path) -> dict:
    """SIGTERM 1 s into the run (the handle moving): time to the
    controller's disable on the bus (the controlled stop's braking
    included)."""
    ms = reaction(tmp, lambda pr: pr.controller.send_signal(signal.SIGTERM), {"SetState"},
                  lambda d: not d.message.enable, after_s=1.0, cfg=stall_tolerant(short_config(gain_s=10.0)))
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


def controlled_stop(drive: str, amplitude_deg: float, virtual_human: bool):
    """The controlled stop 10 ms after a target step (SIGTERM), with the
    travel of the stops the loop ran as designed apart (``clean_*``: fresh
    feedback on every braking tick, a one-tick reaction; NaN otherwise)."""

    def run(tmp: Path) -> dict:
        figures = f.scenario_controlled_stop(tmp, drive, amplitude_deg, virtual_human)
        clean = f.clean_stop(figures)
        figures["clean"] = float(clean)
        figures["clean_travel_rad"] = figures["travel_rad"] if clean else math.nan
        figures["clean_rise_after_request_rad_s"] = figures["rise_after_request_rad_s"] if clean else math.nan
        return figures

    return run


def stop_key(tmp: Path) -> dict:
    """`sensaug rig` in a pseudo-terminal, SPACE typed 1.5 s into the
    trial (tests/test_rig_range.py, with its assertions): ms from the key
    written to the terminal to the drive's disable on the bus, and the
    controlled stop's braking ticks."""
    import test_rig_range as r

    run = r.stop_key_run(tmp)
    assert run["stats"]["stop"]["kind"] == "controlled", run["stats"]["stop_reason"]
    assert run["disabled_after_ms"] is not None, "no disable on the bus"
    return {"key_to_disabled_ms": run["disabled_after_ms"],
            "braking_ticks": run["stats"]["stop"]["braking_ticks"]}


def scenarios() -> dict:
    """Every scenario by name: a function of a temporary folder returning
    its figures."""
    out = {
        "second controller (refused)": f.scenario_second_controller,
        "foreign command": f.scenario_foreign_command,
        "SIGTERM": sigterm,
        "dead drive": dead_drive,
        "SIGKILL of the controller": killed_controller,
        "stop key (SPACE in the launcher's terminal)": stop_key,
    }
    for drive in f.PROFILES:
        out |= {
            f"{drive}: forged 0.5 rad feedback": lambda tmp, d=drive: f.scenario_forged_jump(tmp, d),
            f"{drive}: forged velocity, doubled": lambda tmp, d=drive: f.scenario_forged_velocity(tmp, d, "doubled"),
            f"{drive}: forged velocity, oscillating": (
                lambda tmp, d=drive: f.scenario_forged_velocity(tmp, d, "oscillating")),
            f"{drive}: forged velocity, racing the drive": (
                lambda tmp, d=drive: f.scenario_forged_velocity(tmp, d, "doubled", race=True)),
            f"{drive}: velocity reported x1.5": lambda tmp, d=drive: f.scenario_misscaled_velocity(tmp, d, 1.5),
            f"{drive}: replayed and copied feedback": lambda tmp, d=drive: f.scenario_replayed_feedback(tmp, d),
            f"{drive}: stalled drive (degraded)": lambda tmp, d=drive: f.scenario_stalled_drive(tmp, d),
            f"{drive}: SIGHUP, session gone": (
                lambda tmp, d=drive: f.scenario_signal(tmp, d, signal.SIGHUP, session_gone=True)),
            f"{drive}: log write failure (1 MB file-size limit)": (
                lambda tmp, d=drive: f.scenario_log_failure(tmp, drive=d)),
        }
        for amplitude, human in [(8.0, True), (8.0, False), (30.0, True), (30.0, False)]:
            who = "virtual human" if human else "nobody holding"
            out[f"{drive}: stop after a {amplitude:g} deg step, {who}"] = controlled_stop(drive, amplitude, human)
    return out


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


def brake_model(mass: float = 0.0035, dt_s: float = 1e-3, time_constant_s: float = 0.004,
                rest_rad_s: float = 0.01) -> list[str]:
    """The controlled stop's brake on the exact zero-order-hold plant (no
    delay, no one holding the handle): travel (mrad) and ticks to rest from
    1, 2, 5 and 8 rad/s for several torque bounds (docs/safety.md)."""
    speeds = (1.0, 2.0, 5.0, 8.0)
    lines = ["| brake torque bound (N m) | " + " | ".join(f"from {v:g} rad/s" for v in speeds) + " |",
             "| --- |" + " --- |" * len(speeds)]
    for bound in (1.0, 2.0, 2.5, 3.0):
        cells = []
        for v0 in speeds:
            x, v, n = 0.0, v0, 0
            while abs(v) >= rest_rad_s:
                torque = min(max(-mass / time_constant_s * v, -bound), bound)
                a = torque / mass
                x, v, n = x + v * dt_s + 0.5 * a * dt_s**2, v + a * dt_s, n + 1
            cells.append(f"{1e3 * x:.1f} mrad, {n} ticks")
        lines.append(f"| {bound:g} | " + " | ".join(cells) + " |")
    return lines


def main() -> int:
    if "--brake-model" in sys.argv:
        print("\n".join(brake_model()))
        return 0
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    only = sys.argv[sys.argv.index("--only") + 1] if "--only" in sys.argv else ""
    if only:
        args.remove(only)
    reps = int(args[0]) if len(args) > 0 else 5
    starts = int(args[1]) if len(args) > 1 else 30
    lines = measure({name: fn for name, fn in scenarios().items() if only in name}, reps)
    print("\n".join(lines))
    if starts > 0:
        with tempfile.TemporaryDirectory() as d:
            gaps = start_gaps(Path(d), starts)
        print("\n".join(summarize("start (enable -> tick 0)", gaps)))
        bad = [g for g in gaps if g["exit"] != 0]
        print(f"\n{len(gaps)} starts, {len(bad)} not completed: "
              f"{[(g['exit'], g['stop_reason'], g['ticks']) for g in bad]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
