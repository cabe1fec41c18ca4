"""Configuration: validation names the field, TOML round-trips exactly."""
import dataclasses

import numpy as np
import pytest

import sensaug
from sensaug import config as C
from sensaug import experiment, presets


@pytest.mark.parametrize("make", [presets.hi5_experiment, presets.simulation_section])
def test_toml_round_trip_is_exact(make, tmp_path):
    cfg = make()
    path = tmp_path / "trial.toml"
    cfg.to_toml(path)
    back = sensaug.ScenarioConfig.from_toml(path)
    assert back.to_dict() == cfg.to_dict()
    assert back.to_toml() == cfg.to_toml()


def test_round_tripped_config_runs_the_same_trial(tmp_path):
    cfg = presets.hi5_experiment(1.0, seed=5, phase_s=2.0)
    back = sensaug.ScenarioConfig.from_toml(cfg.to_toml())
    a, b = experiment.run(cfg), experiment.run(back)
    np.testing.assert_array_equal(a.data["x"], b.data["x"])


def test_full_covariance_matrices_survive_toml():
    cfg = presets.hi5_experiment(phase_s=1.0)
    Q = np.eye(6) * 1e-2
    Q[3, 4] = Q[4, 3] = 1e-3
    cfg.robot.stage1.Q = Q
    cfg.validate()
    back = sensaug.ScenarioConfig.from_toml(cfg.to_toml())
    np.testing.assert_array_equal(back.robot.stage1.Q, Q)


def _mutate(path, value):
    cfg = presets.hi5_experiment(phase_s=1.0)
    obj = cfg
    *parents, last = path.split(".")
    for p in parents:
        obj = obj[int(p)] if p.isdigit() else getattr(obj, p)
    setattr(obj, last, value)
    return cfg


@pytest.mark.parametrize(
    "path,value,expect",
    [
        ("plant.mass", -1.0, r"plant\.mass: -1 is out of range; it must be > 0"),
        ("plant.dt_s", float("nan"), r"plant\.dt_s: must be a finite number"),
        ("plant.damping", -0.1, r"plant\.damping: -0\.1 is out of range; it must be >= 0"),
        ("world.motor_noise_std", -1.0, r"world\.motor_noise_std"),
        ("world.seed", -3, r"world\.seed"),
        ("robot.q_pos", 0.0, r"robot\.q_pos: 0 is out of range; it must be > 0"),
        ("robot.torque_limit", float("inf"), r"robot\.torque_limit: must be a finite number"),
        ("robot.stage1.Q", [1.0] * 5, r"robot\.stage1\.Q: expected 6 diagonal entries"),
        ("robot.stage1.R", [1e-7, -1e-7, 1e-7], r"robot\.stage1\.R: must be positive definite; raise the diagonal"),
        ("robot.stage2.P0", [[1.0, 2.0], [0.0, 1.0]], r"robot\.stage2\.P0: expected 6"),
        ("robot.stage3.channel.gate", 0.0, r"robot\.stage3\.channel\.gate"),
        ("robot.sigma.alpha", 0.0, r"robot\.sigma\.alpha"),
        ("partner.gains", [0.0, 1.0], r"partner\.gains: has 2 entries; give exactly 3"),
        ("phases.0.duration_s", 0.0, r"phases\[0\]\.duration_s"),
        ("phases.2.target_noise_std", -1.0, r"phases\[2\]\.target_noise_std"),
        ("phases.0.kind", "bogus", r"phases\[0\]\.kind: unknown value \"bogus\"; use one of gains, trajectory, integration"),
    ],
)
def test_validation_names_the_field_and_the_fix(path, value, expect):
    cfg = _mutate(path, value)
    with pytest.raises(C.ConfigError, match=expect):
        cfg.validate()


def test_python_objects_that_are_not_config_values_are_named():
    cfg = presets.hi5_experiment(phase_s=1.0)
    cfg.rig.can = object()
    with pytest.raises(C.ConfigError, match=r"^rig\.can: a object cannot be written"):
        cfg.validate()


def test_rig_can_of_the_wrong_type_is_a_config_error_not_an_attribute_error():
    cfg = presets.hi5_experiment(phase_s=1.0)
    cfg.rig.can = 5
    with pytest.raises(C.ConfigError, match=r"^rig\.can: expected a string, got integer 5"):
        cfg.validate()


def test_written_toml_documents_units_and_reads_back():
    text = presets.hi5_rig().to_toml()
    assert "# Torque limit at the drive (N m)." in text
    assert "# Control period dt (s)" in text
    assert sensaug.ScenarioConfig.from_toml(text).to_dict() == presets.hi5_rig().to_dict()


def test_schema_bounds_the_safety_settings():
    rig = C.schema()["$defs"]["RigSpec"]["properties"]
    # The watchdog's maximum is the safety bound (how long a drive goes on
    # after its controller fell silent). Its minimum, 2 ms whatever the
    # profile (each profile narrows it: Hi5 5, the DBC's), only keeps the
    # drive from tripping between commands, with the check of at least two
    # loop periods (test_the_watchdog_is_bounded_per_drive_profile).
    assert rig["watchdog_ms"]["maximum"] <= 200 and rig["watchdog_ms"]["minimum"] >= 2
    assert rig["stop_time_limit_s"]["maximum"] <= 2.0
    assert rig["stop_torque_limit_nm"]["maximum"] <= 10.0
    assert rig["feedback_timeout_ms"]["maximum"] <= 300.0
    assert rig["torque_limit_nm"]["maximum"] <= 10.0
    assert rig["ring_capacity"]["maximum"] <= 1 << 22


def test_generated_config_types_are_current():
    import subprocess
    import sys
    from pathlib import Path

    script = Path(__file__).resolve().parent.parent / "scripts" / "gen_config_types.py"
    r = subprocess.run([sys.executable, str(script), "--check"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr


def test_phase_order_needs_gains_first():
    cfg = presets.hi5_experiment(phase_s=1.0)
    cfg.phases = cfg.phases[1:]
    with pytest.raises(C.ConfigError, match=r'phases\[0\]\.kind: a "trajectory" or "integration" phase needs an earlier "gains" phase'):
        cfg.validate()
    cfg.robot.prior_partner_gains = [0.0, 0.0, 2.0]
    cfg.validate()
    tr = experiment.run(cfg)
    assert tr.partner_target_rmse(skip_s=0.5) < 0.5


def test_bad_shape_parameters_name_the_part():
    cfg = presets.hi5_experiment(phase_s=1.0)
    cfg.phases[0].robot_target[1] = C.Chirp(amplitude=1.0, f0_hz=-1.0, f1_hz=2.0, duration_s=1.0)
    with pytest.raises(ValueError, match=r"phases\[0\]\.robot_target\[1\]\.f0_hz: -1 is out of range; it must be >= 0"):
        cfg.validate()


@pytest.mark.parametrize(
    "toml,expect",
    [
        ("[plant]\nmass = 1.0\n", r"phases: missing"),
        ("[[phases]]\nkind='gains'\nduration_s=1\nrobot_target=[{kind='wobble'}]\npartner_target=[]\n", r'phases\[0\]\.robot_target\[0\]\.kind: unknown shape "wobble"'),
        ("bogus = 1\n[[phases]]\n", r"^bogus: unknown field; remove it or correct its spelling"),
        ("[[phases]\n", r"not valid TOML"),
        (
            "[[phases]]\nkind='gains'\nduration_s=1\nrobot_target=[{kind='square', amplitude=1}]\npartner_target=[{kind='constant', value=0}]\n",
            r"phases\[0\]\.robot_target\[0\]\.period_s: missing",
        ),
    ],
)
def test_bad_toml_is_reported_by_location(toml, expect):
    with pytest.raises(ValueError, match=expect):
        sensaug.ScenarioConfig.from_toml(toml)


def test_sampled_target_runs_and_matches_closed_form():
    """A sampled copy of the rounded square gives the same trial to within the
    interpolation error (samples every 1 ms, evaluated on the same grid)."""
    cfg = presets.hi5_experiment(2.0, seed=0, phase_s=2.0)
    t = np.arange(0, 6.002, 1e-3)
    samples = tuple(8.0 * np.cbrt(np.sin(0.5 * np.pi * t)))
    sampled = C.Sampled(samples=samples, dt_s=1e-3)
    cfg2 = dataclasses.replace(cfg, phases=[dataclasses.replace(p) for p in cfg.phases])
    cfg2.phases[1].partner_target = [sampled]
    cfg2.phases[1].robot_target = [sampled]
    a, b = experiment.run(cfg), experiment.run(cfg2)
    m = a.phase_mask(1)
    np.testing.assert_allclose(b["tau_h"][m], a["tau_h"][m], atol=1e-9)
