"""Physical units wherever a person reads a number (``sensaug.units``): the
log's model symbols (``pos``, ``trq``) become deg or rad, N m/rad, ...
from the configuration's ``rig.position_unit``."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

import sensaug
from sensaug import presets, units


@pytest.mark.parametrize(
    ("symbol", "deg", "rad", "m"),
    [
        ("pos", "deg", "rad", "m"),
        ("pos/s", "deg/s", "rad/s", "m/s"),
        ("pos^2", "deg^2", "rad^2", "m^2"),
        ("trq", "(pi/180) N m", "N m", "N"),
        ("trq/pos", "N m/rad", "N m/rad", "N/m"),
        ("trq s/pos", "N m s/rad", "N m s/rad", "N s/m"),
        ("(trq/pos)^2", "(N m/rad)^2", "(N m/rad)^2", "(N/m)^2"),
        ("N m", "N m", "N m", "N m"),
        ("s", "s", "s", "s"),
        ("us", "us", "us", "us"),
    ],
)
def test_symbols(symbol: str, deg: str, rad: str, m: str) -> None:
    assert units.physical(symbol, "deg") == deg
    assert units.physical(symbol, "rad") == rad
    assert units.physical(symbol, "m") == m
    assert units.physical(symbol, None) == symbol


def test_a_gain_in_trq_per_pos_is_n_m_per_rad_in_either_unit() -> None:
    """The claim behind "N m/rad": a torque unit of (pi/180) N m per degree
    is (pi/180) N m per (pi/180) rad."""
    trq_in_nm, deg_in_rad = math.pi / 180, math.pi / 180
    assert trq_in_nm / deg_in_rad == 1.0


def test_a_trial_says_its_units() -> None:
    cfg = presets.hi5_experiment(2.0)
    for p in cfg.phases:
        p.duration_s = 1.0
    trial = sensaug.run(cfg)
    assert (trial.units["x"], trial.units["u"], trial.units["Lhh_hat"]) == ("deg", "(pi/180) N m", "N m/rad")
    assert trial.model_units["x"] == "pos"
    cfg.rig.position_unit = "rad"
    trial = sensaug.run(cfg)
    assert (trial.units["x"], trial.units["u"], trial.units["Lhv_hat"]) == ("rad", "N m", "N m s/rad")
    assert np.isfinite(trial["x"]).all()


def test_the_simulation_section_is_a_linear_handle_everywhere_a_person_reads(tmp_path) -> None:
    """The simulation-section presets set rig.position_unit = "m": the log
    (in memory and read back), the quick-look plots' axes and the MCAP
    export's schemas say m, N, N/m, N s/m, never deg."""
    from mcap.reader import make_reader

    from sensaug.export import to_mcap

    for cfg in (presets.simulation_section(phase_s=1.0), presets.simulation_integration(phase_s=1.0)):
        assert cfg.rig.position_unit == "m"
    trial = sensaug.run(presets.simulation_section(phase_s=1.0))
    expected = {"x": "m", "xdot": "m/s", "u": "N", "Lhx_hat": "N/m", "Lhv_hat": "N s/m", "Lhh_var": "(N/m)^2"}
    assert {k: trial.units[k] for k in expected} == expected
    path = trial.save(tmp_path / "sim.csv")
    assert {k: sensaug.load_log(path).units[k] for k in expected} == expected
    labels = [ax.get_ylabel() + " " + " ".join(ax.get_legend_handles_labels()[1])
              for fig in (trial.plot("gains"), trial.plot("trajectory")) for ax in fig.axes]
    assert any("N/m" in lb for lb in labels) and any("(m)" in lb for lb in labels), labels
    assert not any("deg" in lb or "rad" in lb for lb in labels), labels
    with open(to_mcap(path, tmp_path / "sim.mcap"), "rb") as f:
        summary = make_reader(f).get_summary()
    found = {}
    for schema in summary.schemas.values():
        for name, prop in json.loads(schema.data).get("properties", {}).items():
            if "unit" in prop:
                found[name] = prop["unit"]
    assert {k: found[k] for k in expected} == expected
    assert not any("deg" in u or "rad" in u for u in found.values()), found


def test_the_rig_refuses_a_linear_unit(tmp_path) -> None:
    """The rig's joint is revolute: sensaug-rt names rig.position_unit for "m"."""
    import subprocess

    from sensaug.rig import find_binary

    cfg = presets.hi5_rig()
    cfg.rig.position_unit = "m"
    cfg.to_toml(tmp_path / "linear.toml")
    proc = subprocess.run([str(find_binary()), "--check", str(tmp_path / "linear.toml")], capture_output=True,
                          text=True, cwd=tmp_path)
    assert proc.returncode == 2 and proc.stderr.startswith("rig.position_unit: \"m\""), proc.stderr
