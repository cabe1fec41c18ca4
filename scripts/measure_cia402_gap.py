"""Measures the partner-gain (Lhh) difference between the two drive profiles
and whether it follows the CiA 402 torque resolution (docs/cia402.md quotes
its output).

Usage: .venv/bin/python scripts/measure_cia402_gap.py [RUNS]   (default 3)

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
"""
from __future__ import annotations

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


def one_run(drive: str, drive_args: list[str]) -> rig.RigRun | str:
    """The completed run, or why it did not complete."""
    cfg = experiment_config(drive)
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


def main(runs: int) -> None:
    print("| run | drive (torque step) | gains estimate | Lhh - Lhh(hi5) | partner-target RMSE | integrated RMSE | missing feedback |")
    print("|---|---|---|---|---|---|---|")
    for i in range(runs):
        lhh_hi5 = None
        for label, drive, args in VARIANTS:
            run = one_run(drive, args)
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
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 3)
