"""A configuration file including others (docs/config.md, "Includes"):
Python, both checkers, ``sensaug doctor``, a simulated trial's and a rig
run's log all see the merged configuration and the files it included."""

from __future__ import annotations

import dataclasses
import hashlib
import pickle
import subprocess
import sys
from pathlib import Path

import pytest
import tomli_w

import sensaug
from sensaug import cli, experiment, presets, rig
from sensaug.config import check_file
from test_config_corpus import RT, rt_check
from test_rig import RIG_TEST_FIFO_PRIORITY, stall_tolerant

CALIBRATION = {"plant": {"mass": 0.0041, "damping": 0.0},
               "rig": {"friction": {"coulomb_nm": 0.004, "viscous_nm_s_per_rad": 0.002}}}  # fmt: skip


def lab(tmp_path: Path, base: sensaug.ScenarioConfig) -> tuple[Path, Path, sensaug.ScenarioConfig]:
    """``lab/rig.toml`` including ``lab/handles/a.toml`` (the calibration),
    the rest ``base``'s settings; and ``base`` with the calibration in
    place (what the merge must give)."""
    (tmp_path / "lab" / "handles").mkdir(parents=True)
    fragment = tmp_path / "lab" / "handles" / "a.toml"
    fragment.write_text(tomli_w.dumps(CALIBRATION))
    tables = base.to_dict()
    for table, keys in (("plant", ("mass", "damping")),):
        for k in keys:
            tables[table].pop(k)
    tables["rig"].pop("friction")
    top = tmp_path / "lab" / "rig.toml"
    top.write_text(tomli_w.dumps({"include": ["handles/a.toml"], **tables}))
    merged = sensaug.ScenarioConfig.from_dict(base.to_dict())
    merged.plant.mass, merged.plant.damping = 0.0041, 0.0
    merged.rig.friction.coulomb_nm, merged.rig.friction.viscous_nm_s_per_rad = 0.004, 0.002
    merged.validate()
    return top, fragment, merged


def test_from_toml_of_an_including_file_is_the_merged_configuration(tmp_path):
    top, fragment, merged = lab(tmp_path, presets.hi5_rig())
    cfg = sensaug.ScenarioConfig.from_toml(top)
    assert [(Path(i.path), i.sha256) for i in cfg.included] == [
        (fragment.resolve(), hashlib.sha256(fragment.read_bytes()).hexdigest())]
    assert dataclasses.replace(cfg, included=None) == merged
    assert cfg.include is None
    # The record travels with the configuration: written, read, pickled.
    again = sensaug.ScenarioConfig.from_toml(cfg.to_toml())
    assert again == cfg
    assert pickle.loads(pickle.dumps(cfg)) == cfg
    assert check_file(top) == cfg


def test_text_and_tables_refuse_include(tmp_path):
    text = presets.hi5_rig().to_toml()
    with pytest.raises(sensaug.ConfigError) as e:
        sensaug.ScenarioConfig.from_toml('include = ["a.toml"]\n' + text)
    assert e.value.field == "include" and "from_toml(path)" in e.value.message
    with pytest.raises(sensaug.ConfigError) as e:
        sensaug.ScenarioConfig.from_dict({**presets.hi5_rig().to_dict(), "include": ["a.toml"]})
    assert e.value.field == "include"


def test_both_checkers_and_doctor_read_an_including_file(tmp_path, capsys):
    top, fragment, _ = lab(tmp_path, presets.hi5_rig())
    assert cli.main(["check", str(top)]) == 0
    assert capsys.readouterr().out.strip() == "valid"
    assert rt_check(top) == (0, "valid\n", "")
    doctor = subprocess.run([sys.executable, "-m", "sensaug", "doctor", str(top)], capture_output=True, text=True,
                            timeout=60)  # fmt: skip
    assert doctor.returncode == 0, doctor.stdout + doctor.stderr
    assert str(top) in doctor.stdout
    # The handle's mass given in both files: the same refusal from each,
    # naming the key and both files; doctor says the configuration is bad.
    text = top.read_text()
    top.write_text(text.replace("[plant]\n", "[plant]\nmass = 0.0035\n", 1))
    assert cli.main(["check", str(top)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("plant.mass: set in both ") and str(fragment) in err and str(top) in err
    assert rt_check(top) == (2, "", err)
    doctor = subprocess.run([sys.executable, "-m", "sensaug", "doctor", str(top)], capture_output=True, text=True,
                            timeout=60)  # fmt: skip
    assert doctor.returncode == 2 and "plant.mass: set in both" in doctor.stdout + doctor.stderr
    # A bad value in the fragment: the same message from both, naming it.
    top.write_text(text)
    fragment.write_text(fragment.read_text().replace("mass = 0.0041", "mass = -1.0"))
    assert cli.main(["check", str(top)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("plant.mass: ") and err.rstrip().endswith(f"(set in {fragment})"), err
    assert rt_check(top) == (2, "", err)


def test_a_simulated_trial_records_the_files_included(tmp_path):
    base = presets.simulation_section()
    top, fragment, merged = lab(tmp_path, base)
    trial = experiment.run(sensaug.ScenarioConfig.from_toml(top))
    recorded = trial.meta["config"]["included"]
    assert recorded == [{"path": str(fragment.resolve()), "sha256": hashlib.sha256(fragment.read_bytes()).hexdigest()}]
    # The merged values ran: the same rows as the configuration written out.
    plain = experiment.run(merged)
    assert trial.data.tobytes() == plain.data.tobytes()  # NaN columns: compared as bytes
    assert trial.meta["config"]["plant"] == plain.meta["config"]["plant"]
    # Saved and loaded, the record is still there, and the replay takes the
    # recorded configuration (its config_sha256 covers the record).
    path = trial.save(tmp_path / "trial.csv")
    loaded = experiment.Trial.load(path)
    assert loaded.config.included == sensaug.ScenarioConfig.from_toml(top).included
    replayed = sensaug.replay(path)
    assert len(replayed) == len(trial)


def test_a_rig_run_records_the_files_included(tmp_path):
    """The Python launcher hands ``sensaug-rt`` the resolved configuration
    (``rig_config.toml``): the record goes with it into the rig's log."""
    base = stall_tolerant(presets.hi5_rig(phase_s=1.0))
    base.rig.realtime.fifo_priority = RIG_TEST_FIFO_PRIORITY
    top, fragment, _ = lab(tmp_path, base)
    run = rig.run_virtual_rig(top, out=tmp_path / "out", capture=None, stop_key=False)
    assert run.returncode == 0, run.stats.get("stop_reason")
    assert run.log.meta["source"] == "rig"
    assert run.log.meta["config"]["included"] == [
        {"path": str(fragment.resolve()), "sha256": hashlib.sha256(fragment.read_bytes()).hexdigest()}]
    assert run.log.meta["config"]["plant"]["mass"] == 0.0041
    assert run.log.meta["loop"]["friction_coulomb_nm"] == 0.004
    assert RT.is_file()
