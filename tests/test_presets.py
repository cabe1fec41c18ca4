"""The presets are the schema's defaults plus the paper's differences only
(issue 18): each preset, and the committed rig configurations, differ from
a default configuration in exactly the fields listed here. A changed
default therefore shows up here (the presets follow the schema), and a
preset cannot grow a second copy of a default unnoticed in review."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from sensaug import presets
from sensaug.config import ScenarioConfig

ROOT = Path(__file__).resolve().parents[1]
#: The motor noise's velocity variance at the Hi5 defaults, (1e-3 s * 1e-3 / 0.0035)^2.
HI5_QV = presets.motor_velocity_variance(1e-3, 1e-3, 0.0035)


def differences(cfg: ScenarioConfig) -> dict[str, object]:
    """Dotted field -> value wherever ``cfg`` differs from the defaults (phases aside)."""
    out: dict[str, object] = {}

    def walk(obj: object, default: object, path: str) -> None:
        if dataclasses.is_dataclass(obj) and type(obj) is type(default):
            for f in dataclasses.fields(obj):
                walk(getattr(obj, f.name), getattr(default, f.name), f"{path}.{f.name}".lstrip("."))
        elif obj != default:
            out[path] = obj

    base = ScenarioConfig(phases=cfg.phases)
    for f in dataclasses.fields(cfg):
        if f.name != "phases":
            walk(getattr(cfg, f.name), getattr(base, f.name), f.name)
    return out


HI5 = {"robot.seed": 1_000_003, "robot.stage3.Q": [1e-2, HI5_QV]}
HI5_RIG = {**HI5, "robot.gain_window_s": 4.0}
SIMULATION = {
    "plant.mass": 6.0,
    "rig.position_unit": "m",
    "world.motor_noise_std": 1.0,
    "world.position_noise_std": 1e-5,
    "world.velocity_noise_std": 1e-5,
    "robot.q_pos": 20000.0,
    "robot.q_vel": 2.0,
    "robot.integrate": False,
    "robot.torque_limit": 1e6,
    "robot.seed": 1_000_003,
    "robot.stage1.Q": [1e-10] * 6,
    "robot.stage1.R": [1e-10] * 3,
    "robot.stage1.P0": [1e-6] * 3 + [1e4] * 3,
    "robot.stage2.Q": [1e-10] * 6,
    "robot.stage2.R": [1e-10] * 5,
    "robot.stage2.P0": [1e-6] * 3 + [1e-2] * 3,
    "partner.gains": None,
    "partner.q_pos": 20000.0,
    "partner.q_vel": 2.0,
    "partner.torque_limit": 1e6,
    "partner.estimates_robot": True,
}


@pytest.mark.parametrize(
    "name,cfg,expected",
    [
        ("hi5_experiment", presets.hi5_experiment(), HI5),
        ("hi5_rig", presets.hi5_rig(), HI5_RIG),
        ("configs/hi5_rig.toml", ScenarioConfig.from_toml(ROOT / "configs" / "hi5_rig.toml"), HI5_RIG),
        ("simulation_section", presets.simulation_section(), SIMULATION),
    ],
)
def test_a_preset_is_the_defaults_plus_the_papers_differences(name, cfg, expected):
    got = differences(cfg)
    assert got.keys() == expected.keys(), (name, sorted(got.keys() ^ expected.keys()))
    for key, value in expected.items():
        assert got[key] == (value if value is None or isinstance(value, str) else pytest.approx(value, rel=1e-15)), (name, key)
