"""Python and the real-time binary read a configuration file the same way.

Both sides have their own schema and defaults (Python dataclasses; Rust
serde structs in crates/sensaug-rt/src/config.rs). `sensaug-rt
--print-resolved` prints what the binary resolved, defaults filled in; it
must equal `sensaug.experiment.resolve` plus the `[rig]` table, exactly
(the gains come from the same core solver on both sides).
"""
import dataclasses
import json
import subprocess

import numpy as np
import pytest

from sensaug import presets, rig
from sensaug.config import ScenarioConfig
from sensaug.experiment import resolve

MINIMAL = """
[[phases]]
kind = "gains"
duration_s = 2.0
robot_target = [{ kind = "rounded_square", amplitude = 8.0, period_s = 4.0 }]
partner_target = [{ kind = "square", amplitude = 1.0, period_s = 2.0 }]

[partner]
gains = [0.0, 0.5, 1.5]
"""


def rust_resolved(path) -> dict:
    out = subprocess.run([str(rig.find_binary()), str(path), "--print-resolved"], capture_output=True, text=True, timeout=30)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


@pytest.mark.parametrize(
    "make",
    [
        lambda: ScenarioConfig.from_toml(MINIMAL),
        presets.hi5_rig,
        presets.simulation_section,
    ],
    ids=["minimal-file-all-defaults", "hi5-rig", "simulation"],
)
def test_both_sides_resolve_the_same_settings(make, tmp_path):
    cfg = make()
    path = tmp_path / "c.toml"
    if make is not presets.hi5_rig and make is not presets.simulation_section:
        path.write_text(MINIMAL)
    else:
        cfg.to_toml(path)
    rs = rust_resolved(path)
    py = resolve(cfg)
    r, pr = rs["robot"], py["robot"]
    assert rs["dt_s"] == cfg.plant.dt_s and rs["mass"] == cfg.plant.mass and rs["damping"] == cfg.plant.damping
    np.testing.assert_array_equal(r["gains"], pr["gains"])
    for key in ("integrate", "gain_window_s", "torque_limit", "seed"):
        assert r[key] == pr[key], key
    assert (r["prior_partner_gains"] is None) == (pr["prior_partner_gains"] is None)
    assert r["sigma"] == pr["sigma"]
    for stage in ("stage1", "stage2"):
        for key in ("x0", "P0", "Q", "R"):
            np.testing.assert_array_equal(np.array(r[stage][key]), pr[stage][key], err_msg=f"{stage}.{key}")
    for key in ("P0", "Q", "R_sensor"):
        np.testing.assert_array_equal(np.array(r["stage3"][key]), pr["stage3"][key], err_msg=f"stage3.{key}")
    assert r["stage3"]["partner_window_s"] == pr["stage3"]["partner_window_s"]
    np.testing.assert_array_equal(rs["partner"]["gains"], py["partner"]["gains"])
    assert rs["partner"]["torque_limit"] == py["partner"]["torque_limit"]
    assert [(p["kind"], p["duration_s"], p["target_noise_std"]) for p in rs["phases"]] == [
        (p["kind"], p["duration_s"], p["target_noise_std"]) for p in py["phases"]
    ]
    assert rs["rig"] == dataclasses.asdict(cfg.rig)
