"""Measures the partner-gain (Lhh) difference between the two drive profiles
and whether it follows the CiA 402 torque resolution (docs/cia402.md quotes
its output).

Usage: .venv/bin/python scripts/measure_cia402_gap.py [RUNS] [--seed S] [--lhh L]
(default 3 runs, seed 0, Lhh 2: the test's configuration)

RUNS times, the configuration of tests/test_rig_cia402.py (3 s per phase,
stall-tolerant; its seeds, so the runs differ only in timing: which ticks
lose their fresh feedback) runs on the virtual rig (loopback UDP bus, 1 kHz)
three times: on the Hi5 drive
(torque field step 1 uN m), on the CiA 402 drive with its default rated
torque 1000 mN m (one per-mille step: 1 mN m) and with 100 mN m
(``--rated-torque-mnm 100 --torque-limit 3``: 0.1 mN m steps, the same 3 N m
limit), and on the standard CiA 402 drive (no 0x2000; ``rig.cia402.freshness =
"standard"``, 1 mN m). Prints one Markdown row per run: the estimated gains,
Lhh minus the Hi5 run's, the partner-target RMSE, the integrated RMSE and the
missing feedbacks; a run that did not complete prints its stop reason. Every
process is started and stopped here. Since issue 21 the loop's estimators use
the torque as the drive applies it (docs/cia402.md, "The Lhh difference").

``--seed S`` runs the same configuration with the preset's trial seed S (the
preset's ``world.seed = S``, ``robot.seed = S + 1000003``; on the virtual rig
that seed draws the robot's target-view noise of the integration phase, the
virtual drive being noise-free); ``--lhh L`` gives the virtual human
``L_h = [0, 0, L]`` (another partner: other torques to round).
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

from test_rig import Processes  # noqa: E402
from test_rig_cia402 import experiment_config  # noqa: E402

from sensaug import rig  # noqa: E402
from sensaug.logs import load_log  # noqa: E402

#: (label, drive profile, the virtual drive's extra options)
VARIANTS = [
    ("hi5 (1 uN m)", "hi5", []),
    ("cia402 (1 mN m)", "cia402", []),
    ("cia402 (0.1 mN m)", "cia402", ["--rated-torque-mnm", "100", "--torque-limit", "3"]),
    ("cia402 standard (1 mN m)", "cia402-standard", []),
]


def configured(drive: str, seed: int, lhh: float):
    """The test's configuration on `drive`, with trial seed `seed` (as
    ``presets.hi5_rig(seed=...)`` sets it) and partner gain `lhh`."""
    cfg = experiment_config(drive)
    cfg.world.seed, cfg.robot.seed = seed, seed + 1_000_003
    cfg.partner.gains = [0.0, 0.0, lhh]
    return cfg


def one_run(drive: str, drive_args: list[str], seed: int, lhh: float) -> rig.RigRun | str:
    """The completed run, or why it did not complete."""
    cfg = configured(drive, seed, lhh)
    with tempfile.TemporaryDirectory() as d:
        pr = Processes(Path(d), cfg, drive_args=drive_args)
        try:
            pr.start_controller()
            code = pr.wait_controller()
            if not pr.stats.exists():
                return f"exit {code} without statistics: {pr.controller.stderr.read().strip()[-200:]}"
            stats = json.loads(pr.stats.read_text())
            log = load_log(pr.log)
        finally:
            pr.close()
    if stats["stop_reason"] != "completed":
        return f"{stats['stop_reason']} (exit {code})"
    return rig.RigRun(config=cfg, log=log, stats=stats, returncode=code, drive_returncode=0, stderr="")


def main(runs: int, seed: int, lhh: float) -> None:
    print(f"seed {seed}, Lhh {lhh}")
    print("| run | drive (torque step) | gains estimate | Lhh - Lhh(hi5) | partner-target RMSE | integrated RMSE | missing feedback |")
    print("|---|---|---|---|---|---|---|")
    for i in range(runs):
        lhh_hi5 = None
        for label, drive, args in VARIANTS:
            run = one_run(drive, args, seed, lhh)
            if isinstance(run, str):
                print(f"| {i} | {label} | not completed: {run} | | | | |", flush=True)
                continue
            est = run.stats["partner_gains_estimate"]
            if drive == "hi5":
                lhh_hi5 = est[2]
            gap = est[2] - lhh_hi5 if lhh_hi5 is not None else float("nan")
            print(f"| {i} | {label} | {[round(g, 4) for g in est]} | {gap:+.4f} | "
                  f"{run.partner_target_rmse():.4f} | {run.integration_rmse()['integrated']:.4f} | "
                  f"{run.stats['can']['missing_feedback']} |", flush=True)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description="The Lhh difference between the drive profiles (docs/cia402.md).")
    ap.add_argument("runs", nargs="?", type=int, default=3, help="repetitions (default 3)")
    ap.add_argument("--seed", type=int, default=0, help="the preset's trial seed (default 0, the test's)")
    ap.add_argument("--lhh", type=float, default=2.0, help="the virtual human's Lhh (default 2, the test's)")
    a = ap.parse_args()
    main(a.runs, a.seed, a.lhh)
