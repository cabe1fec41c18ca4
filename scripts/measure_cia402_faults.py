"""Measures the drive-side faults of issue 17 on the virtual rig (docs/safety.md
quotes its output): a drive reset on both profiles (real and forged report),
a lost CiA 402 drive heartbeat, the CiA 402 stale-TPDO flood.

Usage: .venv/bin/python scripts/measure_cia402_faults.py [REPS]   (default 5)

Each scenario of tests/test_rig_faults.py named below runs REPS times (the
same code the tests run, with their assertions); the times are differences
of the kernel's receive stamps of frames on the bus (a sniffer socket,
``KernelTimedFrames``), not of a Python reader's clock. Prints median and
maximum of each figure as a Markdown table. Loopback UDP bus only; every
process is started and stopped here.
"""
from __future__ import annotations

import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))
sys.path.insert(0, str(REPO / "scripts"))

import test_rig_faults as f  # noqa: E402
from measure_safety import measure  # noqa: E402


def main() -> int:
    reps = int(sys.argv[1]) if len(sys.argv) > 1 else 5
    scenarios = {
        "drive reset, CiA 402 (SIGUSR1: boot-up)": lambda d: f.scenario_drive_reset(d, "cia402", "restart"),
        "drive reset, Hi5 (SIGUSR1: BOOT)": lambda d: f.scenario_drive_reset(d, "hi5", "restart"),
        "forged reset report, CiA 402 (boot-up)": lambda d: f.scenario_drive_reset(d, "cia402", "forged"),
        "forged reset report, Hi5 (BOOT)": lambda d: f.scenario_drive_reset(d, "hi5", "forged"),
        "drive frozen, CiA 402 (SIGSTOP; heartbeat consumer 100 ms)": f.scenario_heartbeat_lost,
        "stale-TPDO flood, CiA 402 (discarded)": lambda d: f.scenario_stale_flood(d, "cia402"),
    }
    lines = measure(scenarios, reps)
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
