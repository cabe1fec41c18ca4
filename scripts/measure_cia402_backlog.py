"""Measures the virtual CiA 402 drive against an earlier revision of itself:
its handling time per cycle, and the runs of missing feedback it leaves in
the rig experiment of tests/test_rig_cia402.py (docs/cia402.md, "Backlog",
quotes the output).

Usage: .venv/bin/python scripts/measure_cia402_backlog.py [RUNS] [--baseline REV]

``REV`` (default 9e3d605, before the backlog change) is a git revision whose
``virtual_cia402.py`` is the baseline ("A"); this checkout's is "B".

1. Handling time: one drive of each in this process on the loopback UDP bus,
   NMT started and enabled, handles 3000 RPDO1 + SYNC pairs back to back (a
   peer socket receives the TPDOs); the median over 3 A B B A rounds of the
   time per pair.
2. RUNS times A then B then B then A (interleaved, so both see the same
   load): the 9 s experiment of tests/test_rig_cia402.py on the virtual rig
   (the controller ``sensaug-rt``, the drive a subprocess), one JSON line
   per run: the machine's load, the stop reason, ticks without fresh
   feedback, the three longest runs of them, the partner-target RMSE.

Every process and socket is started and stopped here.
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

import can  # noqa: E402
import numpy as np  # noqa: E402
from sensaug_bridge.udp_bus import free_port  # noqa: E402
from test_rig_cia402 import experiment_config  # noqa: E402

from sensaug import rig  # noqa: E402

MODULE = "firmware_bridge/python/sensaug_bridge/virtual_cia402.py"


def baseline_module(rev: str, into: Path) -> str:
    """Writes ``rev``'s drive module into ``into`` (its EDS path pointed at
    this checkout's) and returns its module name."""
    text = subprocess.run(["git", "-C", str(REPO), "show", f"{rev}:{MODULE}"], capture_output=True, text=True,
                          check=True).stdout
    eds = REPO / "firmware_bridge" / "cia402_drive.eds"
    text = "\n".join(f"EDS_PATH = Path({str(eds)!r})" if line.startswith("EDS_PATH = ") else line
                     for line in text.splitlines())
    (into / "virtual_cia402_baseline.py").write_text(text + "\n")
    return "virtual_cia402_baseline"


def import_path(path: Path, name: str):
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def frame(can_id: int, data: list[int]) -> can.Message:
    return can.Message(arbitration_id=can_id, data=bytes(data), is_extended_id=False)


def cycle_us(module, pairs: int = 3000) -> float:
    """us per RPDO1 + SYNC pair handled by a drive of `module`."""
    port = free_port()
    bus, peer = can.Bus(interface="sensaug_udp", channel=port), can.Bus(interface="sensaug_udp", channel=port)
    try:
        drive = module.VirtualCia402(bus, module.Cia402Config())
        drive.start()
        now = time.monotonic()
        drive.handle(frame(0x601, [0x2F, 0x60, 0x60, 0, 10, 0, 0, 0]), now)  # 0x6060 = 10
        drive.handle(frame(0x000, [0x01, 1]), now)  # NMT start
        for cw in (0x06, 0x07, 0x0F):
            drive.handle(frame(0x201, [cw, 0, 0, 0]), now)
            drive.handle(frame(0x080, [1]), now)
        cycles = [(frame(0x201, [0x0F, 0, 5, 0]), frame(0x080, [k % 240 + 1])) for k in range(pairs)]
        start = time.perf_counter()
        for rpdo, sync in cycles:
            now = time.monotonic()
            drive.handle(rpdo, now)
            drive.handle(sync, now)
            drive.poll(now)
        return (time.perf_counter() - start) / pairs * 1e6
    finally:
        bus.shutdown()
        peer.shutdown()


def missing_runs(fresh: np.ndarray) -> list[int]:
    runs, k = [], 0
    while k < len(fresh):
        if fresh[k]:
            k += 1
            continue
        j = k
        while j < len(fresh) and not fresh[j]:
            j += 1
        runs.append(j - k)
        k = j
    return sorted(runs, reverse=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", type=int, nargs="?", default=2, help="A B B A rounds of the rig experiment")
    ap.add_argument("--baseline", default="9e3d605", help="git revision of the baseline drive (A)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp_path = Path(tmp)
        name = baseline_module(args.baseline, tmp_path)
        modules = {"A": import_path(tmp_path / f"{name}.py", name), "B": import_path(REPO / MODULE, "virtual_cia402_b")}
        per_pair: dict[str, list[float]] = {"A": [], "B": []}
        for _ in range(3):
            for which in "ABBA":
                per_pair[which].append(cycle_us(modules[which]))
        for which, figures in per_pair.items():
            print(json.dumps({"drive": which, "us_per_cycle_median": round(statistics.median(figures), 1),
                              "us_per_cycle": [round(f, 1) for f in figures]}))
        os.environ["PYTHONPATH"] = f"{tmp}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"
        drives = {"A": name, "B": "sensaug_bridge.virtual_cia402"}
        for i, which in enumerate("ABBA" * args.runs):
            rig.virtual_drives = lambda: {"cia402": drives[which]}  # noqa: B023 (this run's drive)
            load = os.getloadavg()[0]
            run = rig.run_virtual_rig(experiment_config("cia402"), out=tmp_path / f"run{i}", capture=None)
            fresh = run.log["fresh"]
            completed = run.stats["stop_reason"] == "completed"
            print(json.dumps({
                "run": i, "drive": which, "load": round(load, 1), "stop": run.stats["stop_reason"][:48],
                "missing": int((~fresh).sum()), "longest_missing_runs": missing_runs(fresh)[:3],
                "partner_target_rmse": round(float(run.partner_target_rmse()), 4) if completed else None,
            }), flush=True)


if __name__ == "__main__":
    main()
