"""The paper's goal-integration claims, reduced (issue 22): the claim table of
``scripts/goal_integration_claims.py`` on two seeds the channel's design never
saw (it was tuned on seeds 1000-1009; the full table in docs/REPORT.md and
docs/model.md is seeds 0-19).

Measured on seeds 0-19 (``scripts/goal_integration_claims.py --seeds 0-19``):
integrated / own RMSE worst seed A 0.915 / 0.917, B 0.706 / 0.711, C 0.463 /
0.947 (robot / human); every seed better. Tracking RMSE(x - x*) with -
without: C -0.40 mm (every seed better), A +0.01 mm, B +0.41 mm (worse: not
asserted, reported). Hi5 at 1 deg: integrated mean 0.072 deg, worst seed
0.084; at 0.01 deg 0.77x own. The bounds below are those measured numbers
with the head-room said per assert.
"""

from __future__ import annotations

import numpy as np
import pytest

from sensaug import experiment, metrics, presets
from sensaug.figures import CONDITIONS

SEEDS = (40, 41)


def _settled(trial) -> np.ndarray:
    return trial.phase_mask(trial.phases_of("integration")[0], skip_s=2.0)


@pytest.fixture(scope="module")
def with_integration():
    return {
        (name, s): experiment.run(presets.simulation_integration(rr, pr, integrate=True, seed=s))
        for name, (rr, pr) in CONDITIONS.items()
        for s in SEEDS
    }


@pytest.mark.parametrize("name", list(CONDITIONS))
def test_integration_lowers_both_agents_target_error_on_every_seed(with_integration, name):
    """fig.integration: worst measured ratio 0.947 (C, human); required < 1
    for both agents on each seed, and < 0.98 / 0.75 / 0.5 for the robot of
    A / B / C (measured worst 0.915 / 0.706 / 0.463)."""
    robot_bound = {"A": 0.98, "B": 0.75, "C": 0.5}[name[0]]
    for s in SEEDS:
        tr = with_integration[(name, s)]
        m = _settled(tr)
        rr, hh = metrics.integration_rmse(tr.data, m), metrics.partner_integration_rmse(tr.data, m)
        assert rr["integrated"] < robot_bound * rr["own"], (s, rr)
        assert hh["integrated"] < hh["own"], (s, hh)


def test_integration_improves_tracking_of_an_inferior_robot_beside_a_superior_human(with_integration):
    """fig.is_tracking C: RMSE(x - x*) (x*: perfect target views) with
    integration below without on each seed; measured 0.25 against 0.66 mm
    (seeds 0-19), required below 0.8x. The paired difference of RMSE(x - tau)
    is ~0.03 mm against ~85 mm (the square wave's steps dominate it)."""
    name = "C: superior human, inferior robot"
    rr, pr = CONDITIONS[name]
    for s in SEEDS:
        on = with_integration[(name, s)]
        off = experiment.run(presets.simulation_integration(rr, pr, integrate=False, seed=s))
        star = experiment.run(presets.simulation_integration(0.0, 0.0, integrate=False, seed=s))
        m = _settled(on)
        with_, without = (float(np.sqrt(np.mean((tr["x"][m] - star["x"][m]) ** 2))) for tr in (on, off))
        assert with_ < 0.8 * without, (s, with_, without)


@pytest.mark.parametrize(("sigma", "bound"), [(0.01, 0.85), (1.0, 0.35)])
def test_hi5_integration_never_raises_the_error(sigma, bound):
    """Hi5, Lhh = 2: integrated / own RMSE measured 0.778 (0.01 deg) and 0.293
    (1 deg) at worst over seeds 0-19; required below 0.85 and 0.35. At 1 deg
    the issue's goal 0.08 deg holds on the mean (0.072) but not on every seed
    (worst 0.084): asserted here on the two seeds' mean, bound 0.08."""
    integrated = []
    for s in SEEDS:
        tr = experiment.run(presets.hi5_experiment(2.0, seed=s, target_noise_std=sigma))
        r = metrics.integration_rmse(tr.data, _settled(tr))
        assert r["integrated"] < bound * r["own"], (s, r)
        integrated.append(r["integrated"])
    if sigma == 1.0:
        assert np.mean(integrated) <= 0.08, integrated
