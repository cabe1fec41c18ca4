"""Measures how often a standard CiA 402 run takes a late answer as fresh
(docs/cia402.md, "Freshness without 0x2000", quotes its output).

Usage: .venv/bin/python scripts/measure_standard_freshness.py [RUNS] [--hog]
(default 1 run; ``--hog``: a busy Python loop runs beside each run, as a
second process on one of the two cores). ``SENSAUG_RT=PATH`` runs another
``sensaug-rt`` build (e.g. main's, for a before/after).

Each run is the configuration of tests/test_rig_cia402.py on the standard
virtual drive (no 0x2000; ``rig.cia402.freshness = "standard"``), with the
bus captured (candump log) and the drive's own record of every plant step
(``--log``). The truth: each TPDO1 + TPDO2 pair is matched to the plant step
whose position and velocity it reports (the drive answers a SYNC with the
state after that SYNC's step); its window is the SYNC it follows on the bus
(the capture socket receives in the kernel's order). The loop's log says
which ticks it took as fresh. Prints one Markdown row per run: ticks, fresh
ticks, answers by lag (window minus the SYNC answered), late answers taken
as fresh, and the link's counters.
"""
from __future__ import annotations

import json
import math
import subprocess
import sys
import tempfile
import time
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

from test_rig import Processes  # noqa: E402
from test_rig_cia402 import SYNC, TPDO1, TPDO2, experiment_config  # noqa: E402

from sensaug.capture import BusCapture, read_candump  # noqa: E402
from sensaug.logs import load_log  # noqa: E402
from sensaug_bridge.virtual_cia402 import Cia402Config  # noqa: E402


def one_run(out: Path) -> dict:
    """Runs one trial into ``out``: the statistics, log, capture, drive record."""
    pr = Processes(out, experiment_config("cia402-standard"), drive_args=["--log", str(out / "drive.npz")])
    capture = BusCapture(pr.port, out / "bus.log").start()
    try:
        time.sleep(0.5)
        pr.start_controller()
        pr.wait_controller(timeout=120)
    finally:
        pr.close()
        capture.stop()
    return json.loads(pr.stats.read_text())


def answers(out: Path) -> list[tuple[int, int, int]]:
    """Each TPDO1 + TPDO2 pair on the bus: (window: SYNCs before it, position
    and velocity in increments)."""
    window, tpdo1, pairs = 0, None, []
    for f in read_candump(out / "bus.log"):
        if f.can_id == SYNC:
            window, tpdo1 = window + 1, None
        elif f.can_id == TPDO1:
            tpdo1 = int.from_bytes(f.data[2:6], "little", signed=True)
        elif f.can_id == TPDO2 and tpdo1 is not None:
            pairs.append((window, tpdo1, int.from_bytes(f.data[0:4], "little", signed=True)))
            tpdo1 = None
    return pairs


def lags(out: Path, pairs: list[tuple[int, int, int]]) -> list[int | None]:
    """Each pair's lag (its window minus the SYNC whose step it reports; None:
    no step matches), from the drive's record of its commanded steps."""
    record = np.load(out / "drive.npz")
    stepped = ~record["free"]
    per_rad = Cia402Config().encoder_counts_per_rev / (2 * math.pi)
    steps = defaultdict(list)
    for i, key in enumerate(zip(np.round(record["position_rad"][stepped] * per_rad).astype(int),
                                np.round(record["velocity_rad_s"][stepped] * per_rad).astype(int))):
        steps[key].append(i)
    # The offset between a step's index and its SYNC's window, from the pairs that match one step only.
    offset = int(np.median([w - steps[(x, v)][0] for w, x, v in pairs if len(steps.get((x, v), [])) == 1]))
    out_lags: list[int | None] = []
    for w, x, v in pairs:
        candidates = [i + offset for i in steps.get((x, v), []) if 0 <= w - (i + offset) <= 20]
        out_lags.append(w - max(candidates) if candidates else None)
    return out_lags


def late_taken_as_fresh(out: Path, pairs, pair_lags) -> tuple[int, int, int]:
    """(ticks, fresh ticks, fresh ticks whose window held only late answers)."""
    log = load_log(out / "log.csv")
    per_deg = Cia402Config().encoder_counts_per_rev / 360.0
    x = np.round(log["x_meas"] * per_deg).astype(int)  # the log's positions are in degrees
    fresh = log["fresh"].astype(bool)
    by_window = defaultdict(list)
    for (w, position, _), lag in zip(pairs, pair_lags):
        by_window[w].append((position, lag))
    # Tick k's fresh feedback answers the SYNC of tick k - 1: find that window's offset.
    offset = max(range(12), key=lambda o: sum(
        fresh[k] and any(p == x[k] for p, _ in by_window.get(k - 1 + o, [])) for k in range(1, len(x))))
    late = sum(1 for k in range(1, len(x)) if fresh[k] and any(
        p == x[k] and lag is not None and lag > 0 for p, lag in by_window.get(k - 1 + offset, [])))
    return len(x), int(fresh.sum()), late


def main(runs: int, hog: bool) -> None:
    print("| run | CPU hog | ticks | fresh | answers by lag | late taken as fresh | out_of_step | late | "
          "duplicated | unanswered |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for i in range(runs):
        with tempfile.TemporaryDirectory() as d:
            out = Path(d)
            busy = subprocess.Popen([sys.executable, "-c", "while 1: pass"]) if hog else None
            try:
                stats = one_run(out)
            finally:
                if busy is not None:
                    busy.kill()
                    busy.wait()
            if stats["stop_reason"] != "completed":
                print(f"| {i} | {hog} | not completed: {stats['stop_reason']} |||||||", flush=True)
                continue
            pairs = answers(out)
            pair_lags = lags(out, pairs)
            ticks, fresh, late = late_taken_as_fresh(out, pairs, pair_lags)
            by_lag = sorted(Counter("?" if lag is None else lag for lag in pair_lags).items(), key=str)
            drive = stats["drive"]
            print(f"| {i} | {hog} | {ticks} | {fresh} | {dict(by_lag)} | {late} | "
                  f"{drive.get('feedback_out_of_step', '-')} | {drive['feedback_late']} | "
                  f"{drive['feedback_duplicated']} | {drive['syncs_unanswered']} |", flush=True)


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if a != "--hog"]
    main(int(args[0]) if args else 1, "--hog" in sys.argv)
