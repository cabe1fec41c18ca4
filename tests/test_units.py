"""Physical units wherever a person reads a number (``sensaug.units``): the
log's model symbols (``pos``, ``trq``) become deg or rad, N m/rad, ...
from the configuration's ``rig.position_unit``."""

from __future__ import annotations

import math

import numpy as np
import pytest

import sensaug
from sensaug import presets, units


@pytest.mark.parametrize(
    ("symbol", "deg", "rad"),
    [
        ("pos", "deg", "rad"),
        ("pos/s", "deg/s", "rad/s"),
        ("pos^2", "deg^2", "rad^2"),
        ("trq", "(pi/180) N m", "N m"),
        ("trq/pos", "N m/rad", "N m/rad"),
        ("trq s/pos", "N m s/rad", "N m s/rad"),
        ("(trq/pos)^2", "(N m/rad)^2", "(N m/rad)^2"),
        ("N m", "N m", "N m"),
        ("s", "s", "s"),
        ("us", "us", "us"),
    ],
)
def test_symbols(symbol: str, deg: str, rad: str) -> None:
    assert units.physical(symbol, "deg") == deg
    assert units.physical(symbol, "rad") == rad
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
