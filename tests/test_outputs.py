"""Outputs that never destroy anything (docs/safety.md, "Output paths"):
sensaug-rt's log and statistics and the Python launcher's files are refused,
by name and before anything is opened or the drive enabled, when they are a
device, a FIFO, a folder or a link, or the same file twice; set-up never
blocks on a FIFO; a statistics file that cannot be written at the end of a
run loses only that file (the run keeps its stop reason and exit code, and
the statistics still reach stdout).

The configuration checkers' verdicts on the same paths (`sensaug check` and
`sensaug-rt --check`, identical) are in tests/test_config_corpus.py.
"""
from __future__ import annotations

import json
import os
import re
import shutil
import stat
import subprocess
import threading
import time
from pathlib import Path

import pytest
from sensaug_bridge.udp_bus import free_port
from test_rig import short_config, stall_tolerant

from sensaug import cli, rig
from sensaug.logs import load_log

EXIT_SETUP = 2


def config(tmp_path: Path) -> Path:
    toml = tmp_path / "trial.toml"
    stall_tolerant(short_config(gain_s=1.0, other_s=0.5)).to_toml(toml)
    return toml


def rt(toml: Path, log: Path | str, stats: Path | str, port: int | None = None, **kw) -> subprocess.CompletedProcess:
    """sensaug-rt on a loopback port (nothing listens unless a drive was started)."""
    return subprocess.run(
        [str(rig.find_binary()), str(toml), "--can", f"udp:{port or free_port()}", "--log", str(log), "--stats", str(stats)],
        capture_output=True, text=True, timeout=kw.pop("timeout", 30), **kw,
    )


def identity(path: str | Path) -> tuple[int, int, int]:
    """What is at ``path`` (not following a link): type, inode, device number."""
    st = os.lstat(path)
    return stat.S_IFMT(st.st_mode), st.st_ino, st.st_rdev


@pytest.mark.parametrize("device", ["/dev/full", "/dev/null"])
@pytest.mark.parametrize("which", ["log", "stats"])
def test_a_device_is_refused_and_left_as_it_is(tmp_path, device, which):
    """As root, `--log /dev/full` used to run to "completed" and replace the
    device node with a CSV."""
    before = identity(device)
    log, stats = (device, tmp_path / "stats.json") if which == "log" else (tmp_path / "log.csv", device)
    r = rt(config(tmp_path), log, stats)
    assert r.returncode == EXIT_SETUP, r.stderr
    first = r.stderr.splitlines()[0]
    assert first == (f"rig.{which}: cannot write {device}: it is a character device, not a regular file; "
                     f"give the path of a regular file or a new one (--{which})"), first
    assert identity(device) == before and stat.S_ISCHR(before[0])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["trial.toml"]


@pytest.mark.parametrize("where", ["log", "log.partial", "stats", "stats.partial"])
def test_a_fifo_never_blocks_the_set_up(tmp_path, where):
    """A FIFO at `<log>.partial` used to hang the set-up (an open for writing
    waits for a reader) and ignore SIGTERM. Now it is refused within the
    check, never opened; the FIFO stays."""
    log, stats = tmp_path / "log.csv", tmp_path / "stats.json"
    fifo = {"log": log, "log.partial": tmp_path / "log.csv.partial",
            "stats": stats, "stats.partial": tmp_path / "stats.json.partial"}[where]
    os.mkfifo(fifo)
    t0 = time.monotonic()
    r = rt(config(tmp_path), log, stats, timeout=20)
    elapsed = time.monotonic() - t0
    assert r.returncode == EXIT_SETUP, r.stderr
    field = "rig.log" if where.startswith("log") else "rig.stats"
    assert r.stderr.startswith(f"{field}: cannot write ") and "a FIFO (named pipe)" in r.stderr, r.stderr
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    print(f"\nFIFO at {where}: refused in {elapsed * 1e3:.0f} ms")


def test_a_link_to_a_device_is_refused_and_kept(tmp_path):
    link = tmp_path / "log.csv"
    link.symlink_to("/dev/full")
    r = rt(config(tmp_path), link, tmp_path / "stats.json")
    assert r.returncode == EXIT_SETUP
    assert r.stderr.startswith(f"rig.log: cannot write {link}: it is a symbolic link to /dev/full (a character device)")
    assert os.readlink(link) == "/dev/full"


@pytest.mark.parametrize("stats_name", ["run.csv", "./run.csv", "run.csv.partial"])
def test_the_same_file_twice_is_refused(tmp_path, stats_name):
    """`--log X --stats X` used to pass both checkers; the statistics then
    replaced the 30,000-record log."""
    log = tmp_path / "run.csv"
    log.write_text("the previous run's log\n")
    r = subprocess.run(
        [str(rig.find_binary()), str(config(tmp_path)), "--can", f"udp:{free_port()}",
         "--log", str(log), "--stats", str(tmp_path / stats_name)],
        capture_output=True, text=True, timeout=30,
    )
    assert r.returncode == EXIT_SETUP
    assert r.stderr.startswith(f"rig.stats: {tmp_path / stats_name} is the same file as rig.log"), r.stderr
    assert log.read_text() == "the previous run's log\n"


# --- a statistics file that cannot be written at the end ---------------------------------


def _run_with_drive(tmp_path: Path, command: list[str], port: int, during=None) -> subprocess.CompletedProcess:
    drive = rig.start_drive(port, duration_s=60)
    try:
        time.sleep(0.5)
        proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        if during is not None:
            during()
        out, err = proc.communicate(timeout=60)
        return subprocess.CompletedProcess(command, proc.returncode, out, err)
    finally:
        rig.stop_process(drive)


def _assert_run_kept(r: subprocess.CompletedProcess, log: Path, stats: Path, why: str) -> dict:
    assert r.returncode == 0, r.stderr
    warning = [ln for ln in r.stderr.splitlines() if ln.startswith("warning: rig.stats:")]
    assert len(warning) == 1, r.stderr
    assert f"cannot write {stats}: " in warning[0] and why in warning[0], warning
    assert "printed on stdout only" in warning[0] and "the run itself: completed, exit 0" in warning[0]
    printed = json.loads(r.stdout)
    assert printed["stop_reason"] == "completed"
    run_log = load_log(log)
    assert run_log.complete and run_log.verified and len(run_log) == printed["records_written"] == printed["ticks"]
    assert not Path(f"{stats}.partial").exists()
    return printed


def test_a_full_disk_for_the_statistics_keeps_the_stop_reason_and_exit_code(tmp_path):
    """The statistics on a 64 KiB tmpfs filled before the run (a mount
    namespace of its own, so nothing outside sees it): creating the empty
    `.partial` at set-up succeeds, writing it at the end fails with ENOSPC.
    Before, this turned "completed" into exit 2 and lost the statistics."""
    if os.geteuid() != 0 or shutil.which("unshare") is None:
        pytest.skip("needs root and unshare(1) to mount a private tmpfs (CI runs as root)")
    full = tmp_path / "full"
    full.mkdir()
    log, stats, port = tmp_path / "log.csv", full / "stats.json", free_port()
    rt_cmd = (f"'{rig.find_binary()}' '{config(tmp_path)}' --can udp:{port} --log '{log}' --stats '{stats}'")
    script = (f"mount -t tmpfs -o size=64k tmpfs '{full}' && "
              f"(dd if=/dev/zero of='{full}/filler' bs=4k 2>/dev/null; true) && exec {rt_cmd}")
    r = _run_with_drive(tmp_path, ["unshare", "--mount", "--propagation", "private", "sh", "-c", script], port)
    if "mount:" in r.stderr and r.returncode != 0:
        pytest.skip(f"tmpfs cannot be mounted here: {r.stderr.strip()}")
    printed = _assert_run_kept(r, log, stats, "No space left on device")
    print(f"\nstatistics on a full disk: run completed (exit 0), {printed['ticks']} ticks; "
          "statistics printed, file not written")


def test_a_statistics_path_taken_mid_run_keeps_the_stop_reason_and_the_folder(tmp_path):
    """Something puts a folder at the statistics path while the run goes on:
    at the end the statistics are not renamed over it (it is not a regular
    file), the run keeps "completed" and exit 0, and the folder stays."""
    log, stats, port = tmp_path / "log.csv", tmp_path / "stats.json", free_port()
    command = [str(rig.find_binary()), str(config(tmp_path)), "--can", f"udp:{port}",
               "--log", str(log), "--stats", str(stats)]

    def take_the_path() -> None:
        t0 = time.monotonic()
        while not log.exists():  # published at tick 0: the run is going
            assert time.monotonic() - t0 < 30
            time.sleep(0.01)
        (stats / "inside").mkdir(parents=True)

    _assert_run_kept(_run_with_drive(tmp_path, command, port, take_the_path), log, stats, "is a directory, not replaced")
    assert (stats / "inside").is_dir()


# --- the Python launcher's own files ------------------------------------------------------


def test_the_launcher_checks_every_output_before_starting(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    cfg = short_config(gain_s=0.5, other_s=0.2)
    with pytest.raises(ValueError, match=r"^capture: .*rig_log\.csv is the same file as rig\.log"):
        rig.run_virtual_rig(cfg, out=out, capture="rig_log.csv")
    os.mkfifo(out / "bus.log")
    t0 = time.monotonic()
    with pytest.raises(ValueError, match=r"^capture: cannot write .*bus\.log: it is a FIFO"):
        rig.run_virtual_rig(cfg, out=out)
    assert time.monotonic() - t0 < 5
    os.unlink(out / "bus.log")
    (out / "README.txt").symlink_to("/dev/null")
    with pytest.raises(ValueError, match=r"^README: cannot write .*symbolic link to /dev/null"):
        rig.run_virtual_rig(cfg, out=out)
    os.unlink(out / "README.txt")
    (out / "rig_gains.png").mkdir()
    with pytest.raises(ValueError, match=r"^plot rig_gains\.png: cannot write .*it is a directory"):
        rig.run_virtual_rig(cfg, out=out, also_written={"plot rig_gains.png": out / "rig_gains.png"})
    # Nothing was written, nothing started.
    assert sorted(p.name for p in out.iterdir()) == ["rig_gains.png"]
    # The capture itself refuses too, before opening the bus or the file.
    os.mkfifo(out / "cap.log")
    with pytest.raises(ValueError, match="capture: cannot write"):
        rig.BusCapture(free_port(), out / "cap.log")
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    with pytest.raises(ValueError, match="out: .* is not a directory"):
        rig.run_virtual_rig(cfg, out=a_file)


def test_the_demo_refuses_a_fifo_capture_at_once(tmp_path, capsys):
    out = tmp_path / "demo"
    out.mkdir()
    os.mkfifo(out / "bus.log")
    assert cli.main(["demo", "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: capture: cannot write {out / 'bus.log'}: it is a FIFO"), err


def test_the_launcher_reports_statistics_it_could_not_save(tmp_path):
    """The launcher reads the statistics from sensaug-rt's stdout, so a lost
    file loses nothing of the run, and its README says the file is missing."""
    out = tmp_path / "out"
    cfg = stall_tolerant(short_config(gain_s=1.0, other_s=0.5))

    def take_the_path() -> None:
        t0 = time.monotonic()
        while not (out / "rig_log.csv").exists():
            if time.monotonic() - t0 > 60:
                return
            time.sleep(0.01)
        (out / "rig_stats.json").mkdir()

    taker = threading.Thread(target=take_the_path)
    taker.start()
    run = rig.run_virtual_rig(cfg, out=out, timeout_s=60)
    taker.join()
    assert run.returncode == 0 and run.stats["stop_reason"] == "completed"
    readme = (out / "README.txt").read_text()
    assert re.search(r"^rig_stats\.json +NOT WRITTEN by this run \(rig\.stats: cannot write", readme, re.M), readme
    assert (out / "rig_stats.json").is_dir()
