"""The experiment on the virtual Hi5 rig: the virtual drive (Python,
python-can) and the real-time binary (`sensaug-rt`, Rust) as two processes
on the loopback CAN bus, then the log read back (``sensaug.load_log``: the
same schema as a simulated trial, ``docs/logs.md``).

The real-time binary is found by :func:`find_binary`: ``$SENSAUG_RT``, the
environment's scripts folder or PATH (the ``sensaug-rt`` wheel), else the
checkout's ``target/release`` (``scripts/setup.sh`` builds it).
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sensaug import _resources, metrics
from sensaug.config import ScenarioConfig
from sensaug.logs import Log, load_log

__all__ = ["RigRun", "find_binary", "run_virtual_rig"]


def find_binary() -> Path:
    """The `sensaug-rt` executable (:func:`sensaug._resources.rt_binary`:
    ``$SENSAUG_RT``, the environment, PATH, the checkout's ``target/release``)."""
    return _resources.rt_binary()


@dataclass
class RigRun:
    """What one rig run produced."""

    config: ScenarioConfig
    log: Log
    stats: dict
    returncode: int
    drive_returncode: int
    stderr: str

    def phase_mask(self, kind: str, *, skip_s: float = 0.0, last_s: float | None = None) -> np.ndarray:
        m = self.log["phase"] == self.log.phase_code(kind)
        if not m.any():
            raise ValueError(f"kind: the log has no {kind!r} phase")
        t = self.log["t"]
        t0, t1 = t[m][0], t[m][-1]
        if last_s is not None:
            return m & (t > t1 - last_s)
        return m & (t >= t0 + skip_s)

    def gain_estimate(self, last_s: float | None = None) -> np.ndarray:
        """Mean estimated gains over the last ``last_s`` of the gain phase
        (default: the robot's own window, ``robot.gain_window_s``)."""
        return metrics.gain_estimate(self.log, self.phase_mask("gains", last_s=last_s or self.config.robot.gain_window_s))

    def partner_target_rmse(self, skip_s: float = 2.0) -> float:
        return metrics.partner_target_rmse(self.log, self.phase_mask("trajectory", skip_s=skip_s))

    def integration_rmse(self, skip_s: float = 2.0) -> dict[str, float]:
        """RMSE of the robot's (x - tau) estimate against x - tau, with the
        measured x and the true target (the binary injected the noise)."""
        return metrics.integration_rmse(self.log, self.phase_mask("integration", skip_s=skip_s))


def _free_port() -> int:
    from sensaug_bridge.udp_bus import free_port

    return free_port()


def start_drive(port: int, *, duration_s: float, extra: list[str] | None = None) -> subprocess.Popen:
    """The virtual Hi5 as a subprocess on the loopback bus at ``port``."""
    cmd = [
        sys.executable,
        "-m",
        "sensaug_bridge.virtual_hi5",
        "--channel",
        str(port),
        "--duration",
        f"{duration_s:g}",
        "-q",
        *(extra or []),
    ]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def run_virtual_rig(
    config: ScenarioConfig | str | Path,
    *,
    out: str | Path = "out",
    port: int | None = None,
    timeout_s: float | None = None,
) -> RigRun:
    """Runs one trial on the virtual rig and returns its log and statistics.

    ``config`` is a configuration or a TOML path; its ``[rig]`` table is used
    except for the CAN URL (a free loopback port) and the output paths
    (under ``out``).
    """
    cfg = config if isinstance(config, ScenarioConfig) else ScenarioConfig.from_toml(config)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    port = port or _free_port()
    toml_path = out / "rig_config.toml"
    cfg.to_toml(toml_path)
    log_path, stats_path = out / "rig_log.csv", out / "rig_stats.json"
    binary = find_binary()
    budget = timeout_s or cfg.duration_s + 30.0
    drive = start_drive(port, duration_s=budget + 5.0)
    try:
        time.sleep(0.5)
        proc = subprocess.run(
            [str(binary), str(toml_path), "--can", f"udp:{port}", "--log", str(log_path), "--stats", str(stats_path)],
            capture_output=True,
            text=True,
            timeout=budget,
        )
    finally:
        drive.send_signal(signal.SIGTERM)
        try:
            drive.wait(timeout=10)
        except subprocess.TimeoutExpired:
            drive.kill()
            drive.wait()
    if not stats_path.exists():
        raise RuntimeError(f"sensaug-rt failed (exit {proc.returncode}): {proc.stderr.strip()}")
    return RigRun(
        config=cfg,
        log=load_log(log_path),
        stats=json.loads(stats_path.read_text()),
        returncode=proc.returncode,
        drive_returncode=drive.returncode,
        stderr=proc.stderr,
    )
