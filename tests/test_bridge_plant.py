"""The virtual drives' plant (``sensaug_bridge.plant``, which lets the bridge
package stand without importing ``sensaug``) against the core's
(``sensaug.Plant``, sensaug-core's ``plant.rs``): the same state after every
step, bit for bit, over the presets' handles and a spread of others (damping
from none to overdamped per step, Coulomb friction with stiction and
reversals), and the same refusals."""

from __future__ import annotations

import math

import numpy as np
import pytest

import sensaug
from sensaug_bridge.plant import Plant

#: (mass, damping, coulomb, dt_s): the Hi5 presets (deg model units and the
#: vcan preset's 30x mass), the virtual drives' default, and others that
#: exercise each branch of phi1/phi2 (s = 0, s < 1e-3, s >= 1e-3, s >> 1).
HANDLES = [
    (0.0035, 0.0, 0.0, 1e-3),
    (0.105, 0.0, 0.0, 0.1),
    (0.0035, 0.02, 0.01, 1e-3),
    (1.0, 0.5, 0.0, 1e-3),
    (2.0, 5.0, 0.3, 0.01),
    (0.01, 40.0, 0.05, 0.002),
    (0.5, 1e4, 0.0, 0.1),
]


@pytest.mark.parametrize("mass,damping,coulomb,dt_s", HANDLES)
def test_the_bridges_plant_steps_as_the_cores_bit_for_bit(mass, damping, coulomb, dt_s):
    rng = np.random.default_rng(20261127)
    core = sensaug.Plant(mass=mass, damping=damping, coulomb=coulomb, dt_s=dt_s, x0=0.1, v0=0.0)
    ours = Plant(mass=mass, damping=damping, coulomb=coulomb, dt_s=dt_s, x0=0.1, v0=0.0)
    # Torques around the friction level (stiction, reversals), zeros (coasting) and larger pushes.
    scale = max(coulomb, 0.01)
    torques = np.concatenate([rng.normal(0.0, 3 * scale, 2000), np.zeros(300), rng.uniform(-scale, scale, 300)])
    for i, u in enumerate(torques):
        expected = core.step(float(u))
        got = ours.step(float(u))
        assert got == expected, (i, u, got, expected)
        assert (ours.x, ours.v) == (core.x, core.v)


def test_the_bridges_plant_refuses_what_the_core_refuses():
    core = sensaug.Plant(mass=1.0, damping=0.0, coulomb=0.0, dt_s=1e-3, x0=0.0, v0=0.0)
    ours = Plant(mass=1.0, damping=0.0, coulomb=0.0, dt_s=1e-3)
    for bad in (math.nan, math.inf):
        with pytest.raises(ValueError):
            core.step(bad)
        with pytest.raises(ValueError):
            ours.step(bad)
    tiny = Plant(mass=1e-300, damping=0.0, coulomb=0.0, dt_s=1.0)
    with pytest.raises(ValueError, match="not finite"):
        tiny.step(1e300)
    assert (tiny.x, tiny.v) == (0.0, 0.0), "a refused step leaves the state unchanged"
