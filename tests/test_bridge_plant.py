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


@pytest.mark.parametrize("drive", ["hi5", "cia402"])
def test_the_virtual_rig_gives_its_drive_the_configurations_handle(drive):
    """``sensaug.rig.virtual_drive_args``: the registered virtual drive of
    each profile gets the configuration's plant, node and torque limit (not
    its own defaults); Coulomb friction converted from model torque (deg
    units) to N m."""
    import importlib

    from sensaug import presets, rig
    from sensaug_bridge.virtual_hi5 import drive_config_fields

    cfg = presets.hi5_rig()
    cfg.rig.drive = drive
    cfg.rig.node_id = 3
    cfg.rig.torque_limit_nm = 2.5
    cfg.plant.mass, cfg.plant.damping, cfg.plant.coulomb, cfg.plant.dt_s = 0.005, 0.01, 0.5, 2e-3
    module = importlib.import_module(rig.virtual_drives()[drive])
    fields = drive_config_fields(module.parse_args(rig.virtual_drive_args(cfg)))
    assert (fields["node"], fields["torque_limit_nm"]) == (3, 2.5)
    assert (fields["mass"], fields["damping"], fields["dt_s"]) == (0.005, 0.01, 2e-3)
    assert fields["coulomb"] == pytest.approx(0.5 * math.pi / 180.0, rel=1e-15)
