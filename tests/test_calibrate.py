"""The handle identified and its friction compensated (issue 21 item 3,
docs/hardware.md "Calibrating the handle").

* The least-squares identifier against an independent oracle: data from the
  closed-form solution of ``M dv/dt = u - C v - F_c sign(v)`` over each
  held-torque step (written here, not sensaug's), and from the core's plant
  (``sensaug.Plant``, with stiction); with white velocity noise its 95%
  intervals cover the truth.
* On the virtual rig: the drive simulates a handle drawn from the seed (its
  parameters given to the drive process only), ``sensaug calibrate``'s
  excitation and identification recover each parameter within the stated
  tolerance. Seeds 0..2 were used while choosing the excitation and the
  speed threshold; the test runs seeds 100..102, never tuned on.
* The compensation in the loop: the ``friction_nm`` column is the formula
  of ``rig.friction`` on the measured velocity, the command stays inside the
  torque limit; off by default (0).
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

import sensaug
from sensaug import ConfigError, presets, rig
from test_rig import RIG_TEST_FIFO_PRIORITY, stall_tolerant

from sensaug.calibrate import (
    calibrated_config,
    drive_handle_args,
    excitation_config,
    identify,
    identify_log,
    including_config,
    run_calibration,
)

DT = 1e-3


def rig_config(**kw) -> sensaug.ScenarioConfig:
    """The hi5_rig preset as the rig tests run it: SCHED_FIFO when allowed,
    the stall-tolerant limits of a loaded 2-core machine (test_rig.py)."""
    cfg = stall_tolerant(presets.hi5_rig(**kw))
    cfg.rig.realtime.fifo_priority = RIG_TEST_FIFO_PRIORITY
    return cfg

#: The virtual-rig tolerances (stated before measuring seeds 100..102; the
#: errors measured are below 1e-4 of these: the virtual drive's velocity
#: report is the plant's to 1e-6 rad/s): M within 0.5%, C within 5e-4
#: N m s/rad, F_c within 5e-4 N m.
MASS_REL_TOL = 5e-3
DAMPING_TOL = 5e-4
COULOMB_TOL = 5e-4


def closed_form_run(M: float, C: float, Fc: float, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Velocities and held torques of a handle under a PD loop on a
    two-sine reference: each step the exact solution of the ODE with the
    torque and the friction's sign held (the step's start velocity never 0
    here: the loop keeps the handle moving through zero in one step)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * DT
    ref = 0.3 * np.sin(2 * np.pi * 0.5 * t) + 0.2 * np.sin(2 * np.pi * 1.7 * t)
    a = math.exp(-C * DT / M)
    b = (1 - a) / C if C > 0 else DT / M
    x = v = 0.0
    vs, us = np.empty(n), np.empty(n)
    for k in range(n):
        u = 2.0 * (ref[k] - x) - 0.02 * v + rng.normal(0.0, 0.01)
        vs[k], us[k] = v, u
        # v(t) = v_ss + (v0 - v_ss) e^{-C t / M}, v_ss = (u - F_c s) / C.
        v_next = a * v + b * (u - Fc * np.sign(v if v != 0.0 else u))
        x += 0.5 * (v + v_next) * DT
        v = v_next
    return vs, us


@pytest.mark.parametrize("M,C,Fc", [(0.005, 0.01, 0.03), (0.0035, 0.0, 0.02), (0.002, 0.02, 0.0)])
def test_identify_recovers_the_closed_form_handle_exactly(M: float, C: float, Fc: float) -> None:
    v, u = closed_form_run(M, C, Fc, 20_000, seed=1)
    est = identify(v, u, DT)
    # Noise-free data fit by the model that made them: round-off only.
    assert est.mass.value == pytest.approx(M, rel=1e-9)
    assert est.damping.value == pytest.approx(C, abs=1e-9)
    assert est.coulomb.value == pytest.approx(Fc, abs=1e-9)


def test_identify_on_the_core_plant_with_stiction() -> None:
    """The core's plant (stiction at rest, rest instead of a reversal) under
    a torque that often stops the handle: the pairs at rest and through a
    reversal are left out and the rest are the model."""
    M, C, Fc = 0.004, 0.008, 0.025
    plant = sensaug.Plant(mass=M, damping=C, coulomb=Fc, dt_s=DT)
    rng = np.random.default_rng(7)
    n = 20_000
    t = np.arange(n) * DT
    u = 0.06 * np.sin(2 * np.pi * 0.7 * t) + 0.03 * np.sin(2 * np.pi * 3.1 * t) + rng.normal(0, 0.005, n)
    v = np.empty(n)
    for k in range(n):
        v[k] = plant.v
        plant.step(float(u[k]))
    assert (v == 0.0).sum() > 100, "the handle should stick at times"
    est = identify(v, u, DT)
    assert est.mass.value == pytest.approx(M, rel=1e-9)
    assert est.damping.value == pytest.approx(C, abs=1e-9)
    assert est.coulomb.value == pytest.approx(Fc, abs=1e-9)


def test_confidence_intervals_cover_the_truth_under_velocity_noise() -> None:
    """White noise of 1e-3 rad/s on the velocity report, 60 draws: each
    parameter's 95% interval covers the truth at least 90% of the time (the
    delta method on the least-squares covariance; with the noise on both
    v[k] and v[k+1] the residuals are negatively correlated and the
    intervals are, if anything, wide)."""
    M, C, Fc = 0.005, 0.01, 0.03
    v, u = closed_form_run(M, C, Fc, 20_000, seed=2)
    rng = np.random.default_rng(3)
    hits = np.zeros(3)
    draws = 60
    for _ in range(draws):
        est = identify(v + rng.normal(0.0, 1e-3, v.size), u, DT)
        hits += [est.mass.covers(M), est.damping.covers(C), est.coulomb.covers(Fc)]
        assert est.mass.high - est.mass.low < 0.02 * M
    assert (hits / draws >= 0.9).all(), hits / draws


def test_identify_refuses_data_that_cannot_determine_the_handle() -> None:
    with pytest.raises(ValueError, match="usable tick pairs"):
        identify(np.zeros(1000), np.zeros(1000), DT)
    v = np.linspace(0.1, 1.0, 1000)  # one way only
    with pytest.raises(ValueError, match="one way only"):
        identify(v, np.ones(1000), DT)


def test_rig_friction_is_checked_by_name() -> None:
    cfg = presets.hi5_rig()
    cfg.rig.friction.coulomb_nm = cfg.rig.torque_limit_nm + 0.5
    with pytest.raises(ConfigError) as e:
        cfg.validate()
    assert e.value.field == "rig.friction.coulomb_nm"
    cfg = presets.hi5_rig()
    cfg.rig.friction.viscous_nm_s_per_rad = 2.0  # 2 * 1e-3 / 0.0035 = 0.57 of the speed per tick
    with pytest.raises(ConfigError) as e:
        cfg.validate()
    assert e.value.field == "rig.friction.viscous_nm_s_per_rad"
    cfg = presets.hi5_rig()
    cfg.rig.friction.coulomb_band_rad_s = 0.0
    with pytest.raises(ConfigError) as e:
        cfg.validate()
    assert e.value.field == "rig.friction.coulomb_band_rad_s"


def test_excitation_keeps_the_rig_limits_and_measures_the_raw_handle() -> None:
    cfg = presets.hi5_person()
    cfg.rig.friction.coulomb_nm = 0.02
    run = excitation_config(cfg, duration_s=12.0)
    assert [p.kind for p in run.phases] == ["gains"] and run.duration_s == 12.0
    assert run.rig.friction.coulomb_nm == 0.0 and run.rig.friction.viscous_nm_s_per_rad == 0.0
    assert run.rig.torque_limit_nm == cfg.rig.torque_limit_nm == 1.0
    assert run.rig.range == cfg.rig.range
    # The target stays inside the soft window with room for the ramp.
    shapes = run.phases[0].robot_target
    reach = abs(shapes[0].value) + abs(shapes[1].amplitude)
    assert reach <= cfg.rig.range.soft_max_deg - cfg.rig.range.ramp_width_deg


def _handle(seed: int) -> tuple[float, float, float]:
    """The hidden handle of a seed: M in [0.002, 0.008] kg m^2, C in [0,
    0.02] N m s/rad, F_c in [0.005, 0.05] N m."""
    rng = np.random.default_rng(seed)
    return float(rng.uniform(0.002, 0.008)), float(rng.uniform(0.0, 0.02)), float(rng.uniform(0.005, 0.05))


@pytest.mark.parametrize("seed", [100, 101, 102])
def test_calibration_identifies_the_hidden_handle_on_the_virtual_rig(seed: int, tmp_path) -> None:
    M, C, Fc = _handle(seed)
    est, run = run_calibration(rig_config(), out=tmp_path, duration_s=10.0, seed=seed, handle=(M, C, Fc))
    # The loop's configuration never saw the handle: its model is the preset's.
    assert run.config.plant.mass == 0.0035 and run.config.rig.friction.coulomb_nm == 0.0
    assert est.mass.value == pytest.approx(M, rel=MASS_REL_TOL), est.summary()
    assert est.damping.value == pytest.approx(C, abs=DAMPING_TOL), est.summary()
    assert est.coulomb.value == pytest.approx(Fc, abs=COULOMB_TOL), est.summary()
    assert est.pairs > 5000
    print(f"seed {seed}: truth M {M:.6g} C {C:.6g} Fc {Fc:.6g}; errors M {est.mass.value / M - 1:+.2e} (rel), "
          f"C {est.damping.value - C:+.2e}, Fc {est.coulomb.value - Fc:+.2e}")


def test_the_loop_compensates_the_friction_inside_the_torque_limit(tmp_path) -> None:
    """A short Hi5 trial on a frictional virtual handle with rig.friction
    set: friction_nm is C v + F_c s (s: the velocity's sign moving, the
    asked torque's at rest, ramped over the two bands) on the measured
    velocity of every commanding tick with fresh feedback, NaN in the
    controlled stop, and the command never beyond the torque limit."""
    handle = (0.0035, 0.01, 0.02)
    cfg = rig_config(phase_s=3.0)
    cfg.rig.friction.coulomb_nm, cfg.rig.friction.viscous_nm_s_per_rad = 0.02, 0.01
    run = rig.run_virtual_rig(cfg, out=tmp_path, capture=None, stop_key=False, drive_args=drive_handle_args(*handle))
    assert run.returncode == 0, run.stats["stop_reason"]
    log = run.log
    assert log.meta["loop"]["friction_coulomb_nm"] == 0.02
    running = (log["phase"] >= 0) & ~log["ramp"].astype(bool)
    fresh = running & log["fresh"].astype(bool)
    v = log["xdot"] * math.pi / 180.0
    asked = (log["u"] + log["u_h"]) * math.pi / 180.0  # model torque units -> N m
    band, torque_band = cfg.rig.friction.coulomb_band_rad_s, cfg.rig.friction.coulomb_torque_band_nm
    moving = np.clip(v / band, -1.0, 1.0)
    sign = moving + (1.0 - np.abs(moving)) * np.clip(asked / torque_band, -1.0, 1.0)
    expected = 0.01 * v + 0.02 * sign
    # The log's u carries the drive's rounding of the torque sent (at most half
    # a step, docs/cia402.md), which the loop's friction did not see: the sign's
    # torque ramp (slope 1 / torque_band) moves by at most that over the band.
    half_step_nm = 0.5 * log.meta["end"]["robot_torque_step"] * math.pi / 180.0
    tol = 0.02 * half_step_nm / torque_band + 1e-12
    np.testing.assert_allclose(log["friction_nm"][fresh], expected[fresh], rtol=0, atol=tol)
    assert np.abs(log["friction_nm"][running]).max() > 0.02  # it moved beyond the band
    assert np.isnan(log["friction_nm"][~running]).all()
    assert np.abs(log["torque_nm"][running]).max() <= cfg.rig.torque_limit_nm
    # That log is a rig log of applied torques: `sensaug calibrate --log`
    # identifies its handle again and writes the fragment, the calibrated
    # configuration and the fit's picture.
    assert identify_log(log).mass.value == pytest.approx(0.0035, rel=MASS_REL_TOL)
    from sensaug import cli

    out = tmp_path / "cal"
    assert cli.main(["calibrate", str(tmp_path / "rig_config.toml"), "--log", str(tmp_path / "rig_log.csv"),
                     "--out", str(out)]) == 0  # fmt: skip
    calibrated = sensaug.ScenarioConfig.from_toml(out / "calibrated_config.toml")
    assert calibrated.plant.mass == pytest.approx(0.0035, rel=MASS_REL_TOL)
    assert calibrated.rig.friction.coulomb_nm == pytest.approx(0.02, abs=COULOMB_TOL)
    assert [Path(i.path) for i in calibrated.included] == [(out / "calibration.toml").resolve()]
    assert (out / "calibration.toml").is_file() and (out / "calibration.png").stat().st_size > 10_000


def test_calibrated_config_carries_the_estimate(tmp_path) -> None:
    from sensaug.calibrate import Estimate, HandleEstimate, write_fragment

    e = HandleEstimate(mass=Estimate(0.0041, 0.004, 0.0042), damping=Estimate(-1e-5, -2e-5, 0.0),
                       coulomb=Estimate(0.021, 0.02, 0.022), pairs=1000, residual_std_rad_s=1e-6, a=1.0, b=0.2,
                       dt_s=DT)  # fmt: skip
    cfg = calibrated_config(presets.hi5_rig(), e)
    assert cfg.plant.mass == 0.0041 and cfg.plant.damping == 0.0
    assert cfg.rig.friction.coulomb_nm == 0.021 and cfg.rig.friction.viscous_nm_s_per_rad == 0.0
    path = write_fragment(tmp_path / "calibration.toml", e, source="test")

    fragment = tomllib.loads(path.read_text())
    assert fragment == {"plant": {"mass": 0.0041, "damping": 0.0},
                        "rig": {"friction": {"coulomb_nm": 0.021, "viscous_nm_s_per_rad": 0.0}}}  # fmt: skip
    assert "compensated as 0" in path.read_text()
    # The rig configuration including the fragment is the calibrated one,
    # and records the fragment with its SHA-256.
    full = including_config(presets.hi5_rig(), None, path, tmp_path / "calibrated_config.toml")
    assert tomllib.loads(full.read_text())["include"] == ["calibration.toml"]
    included = sensaug.ScenarioConfig.from_toml(full)
    assert [i.sha256 for i in included.included] == [hashlib.sha256(path.read_bytes()).hexdigest()]
    assert dataclasses.replace(included, included=None) == cfg


def test_a_lab_configuration_includes_the_handle_calibration(tmp_path) -> None:
    """A lab's rig configuration that included an earlier calibration: the
    one written includes its other files and the new fragment instead of
    the old, from the output folder; one that sets a calibrated value
    itself gets the line to add; a file included deeper that gives the
    values too is refused, naming both files."""
    from sensaug.calibrate import Estimate, HandleEstimate, write_fragment

    e = HandleEstimate(mass=Estimate(0.0041, 0.004, 0.0042), damping=Estimate(0.002, 0.001, 0.003),
                       coulomb=Estimate(0.021, 0.02, 0.022), pairs=1000, residual_std_rad_s=1e-6, a=1.0, b=0.2,
                       dt_s=DT)  # fmt: skip
    lab = tmp_path / "lab"
    (lab / "handles").mkdir(parents=True)
    old = write_fragment(lab / "handles" / "a.toml", dataclasses.replace(e, mass=Estimate(0.003, 0.003, 0.003)),
                         source="last week")  # fmt: skip
    (lab / "limits.toml").write_text("[rig]\ntorque_limit_nm = 0.5\n")
    rig_toml = presets.hi5_rig().to_dict()
    rig_toml.pop("plant")
    rig_toml["rig"].pop("friction")
    rig_toml["rig"].pop("torque_limit_nm")
    import tomli_w

    config_path = lab / "rig.toml"
    config_path.write_text(tomli_w.dumps({"include": ["limits.toml", "handles/a.toml"], **rig_toml}))
    config = sensaug.ScenarioConfig.from_toml(config_path)
    assert config.plant.mass == 0.003 and len(config.included) == 2
    out = tmp_path / "out"
    out.mkdir()
    fragment = write_fragment(out / "calibration.toml", e, source="test")
    full = including_config(config, config_path, fragment, out / "calibrated_config.toml")
    assert tomllib.loads(full.read_text())["include"] == ["../lab/limits.toml", "calibration.toml"]
    cal = sensaug.ScenarioConfig.from_toml(full)
    assert (cal.plant.mass, cal.plant.damping) == (0.0041, 0.0)
    assert (cal.rig.friction.coulomb_nm, cal.rig.friction.viscous_nm_s_per_rad) == (0.021, 0.002)
    assert cal.rig.torque_limit_nm == 0.5
    assert [Path(i.path).name for i in cal.included] == ["limits.toml", "calibration.toml"]
    # Copied over the handle's file, the lab's own configuration runs with it.
    (lab / "handles" / "a.toml").write_text(fragment.read_text())
    assert dataclasses.replace(sensaug.ScenarioConfig.from_toml(config_path), included=None) == \
        dataclasses.replace(cal, included=None)  # fmt: skip
    # A deeper include giving a calibrated value too: refused by name.
    (lab / "limits.toml").write_text("[rig]\ntorque_limit_nm = 0.5\n[plant]\nmass = 0.003\n")
    (lab / "handles" / "a.toml").write_text("[rig.friction]\ncoulomb_nm = 0.01\n")
    config = sensaug.ScenarioConfig.from_toml(config_path)
    with pytest.raises(sensaug.ConfigError, match=r"^plant\.mass: set in both .*limits\.toml and .*calibration\.toml"):
        including_config(config, config_path, fragment, out / "calibrated_config.toml")
    assert not (out / "calibrated_config.toml").exists()
