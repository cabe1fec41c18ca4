"""The participant's display in a real OpenGL window, headless: Xvfb with
Mesa's llvmpipe (scripts/test.sh installs them; no vsync there). Each test
runs its scenario in a subprocess under ``xvfb-run`` and reads back the
frames (PNG of the back buffer) and the display log."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from test_rig import RIG_TEST_FIFO_PRIORITY, stall_tolerant

from sensaug import presets
from sensaug.display import CURSOR_RGB, TARGET_RGB, load_display_log, visual_dots
from sensaug.logs import load_log
from sensaug.session import load_session

ROOT = Path(__file__).resolve().parent.parent


def xvfb(script: str, tmp: Path, timeout: float = 120) -> dict:
    """Runs ``script`` (Python) under xvfb-run; the JSON it printed last."""
    if shutil.which("xvfb-run") is None:
        pytest.fail("xvfb-run is missing: install Debian's xvfb (scripts/test.sh does, as root)")
    path = tmp / "scenario.py"
    path.write_text(textwrap.dedent(script))
    proc = subprocess.Popen(
        ["xvfb-run", "-a", "-s", "-screen 0 1280x720x24", sys.executable, str(path)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp, start_new_session=True,
    )
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)  # xvfb-run, its Xvfb, the scenario and what it started
        proc.communicate()
        raise
    assert proc.returncode == 0, err[-3000:]
    return json.loads(out.strip().splitlines()[-1])


def short_rig(tmp: Path, phase_s: float = 2.0, **display) -> Path:
    cfg = presets.hi5_rig()
    for p in cfg.phases:
        p.duration_s = phase_s
    cfg.phases[0].robot_target[1].duration_s = phase_s
    cfg.robot.gain_window_s = phase_s / 2
    # As the rig tests (tests/test_rig.py): loop and drive under SCHED_FIFO,
    # and stall-tolerant (test_rig.stall_tolerant): the display is under
    # test, not this shared machine's scheduling of the Python virtual drive.
    cfg.rig.realtime.fifo_priority = RIG_TEST_FIFO_PRIORITY
    stall_tolerant(cfg)
    cfg.display.enabled = True
    # A 640 x 360 window: llvmpipe renders on the CPU, which the loop shares here.
    cfg.display.fullscreen, cfg.display.width_px, cfg.display.height_px = False, 640, 360
    for k, v in display.items():
        setattr(cfg.display, k, v)
    path = tmp / "trial.toml"
    cfg.to_toml(path)
    return path


def blobs(img: np.ndarray, rgb: tuple[int, int, int], tol: int = 40) -> np.ndarray:
    """Pixel coordinates (x, y with y up, as OpenGL) of colour ``rgb``."""
    mask = (np.abs(img[:, :, :3].astype(int) - np.array(rgb)).max(axis=2) <= tol)
    ys, xs = np.nonzero(mask)
    return np.column_stack([xs, img.shape[0] - 1 - ys])


def test_a_rig_trial_is_drawn_where_the_display_log_says(tmp_path):
    """A virtual-rig trial with the display: in every saved frame the
    cursor's and the target's centres are where that frame's log row puts
    them (within 1.5 px), the display follows the loop to its last tick, and
    tick-to-swap latency is measured. The frames are under test, not the
    trial's end: a loop that stopped itself (a virtual drive starved on this
    shared machine) is drawn as faithfully, so its stop is only printed."""
    # The frames are under test, not the freeze watch: a display starved
    # for a while on a loaded 2-core machine must not end the trial here.
    cfg = short_rig(tmp_path, on_freeze="continue")
    res = xvfb(f"""
        import json
        from pathlib import Path
        from sensaug.config import ScenarioConfig
        from sensaug.display import DisplayProcess
        from sensaug.rig import run_virtual_rig
        cfg = ScenarioConfig.from_toml({str(cfg)!r})
        out = Path("run")
        screen = DisplayProcess(cfg, workdir=out, env={{"SENSAUG_DISPLAY_SCREENSHOTS": "shots:25"}})
        try:
            run = run_virtual_rig(cfg, out=out, display=screen, capture=None)
        finally:
            screen.close()
        print(json.dumps({{"stop": run.stats["stop_reason"], "display": run.display, "can": run.stats["can"],
                          "last_tick": int(run.log["tick"][-1])}}))
    """, tmp_path)
    print(f"the loop's stop: {res['stop']}")
    run_dir = tmp_path / "run"
    df = load_display_log(run_dir / "display_log.csv")
    shots = sorted((run_dir / "shots").glob("frame_*.png"))
    checked = 0
    for shot in shots:
        frame = int(shot.stem.split("_")[1])
        row = df[df["frame"] == frame].iloc[0]
        if row["tick"] < 0:
            continue
        img = np.asarray(Image.open(shot))
        cursor = blobs(img, CURSOR_RGB, tol=20)
        assert len(cursor), f"{shot.name}: no cursor drawn"
        assert abs(cursor[:, 0].mean() - row["cursor_px"]) < 1.5, (shot.name, cursor[:, 0].mean(), row["cursor_px"])
        if abs(row["cursor_px"] - row["target_px"]) > 30:  # the ring is not under the cursor
            ring = blobs(img, TARGET_RGB)
            assert abs(ring[:, 0].mean() - row["target_px"]) < 1.5, (shot.name, ring[:, 0].mean(), row["target_px"])
        checked += 1
    assert checked >= 4, f"only {checked} frames with a tick were saved"
    # Every row reaches the display (the feed's batches, ~10 ms): its last
    # frames show the loop's last ticks.
    assert df["tick"].max() >= res["last_tick"] - 50, (df["tick"].max(), res)
    if res["stop"] == "completed":
        assert res["last_tick"] > 5000
    assert res["display"]["latency_p50_ms"] > 0
    assert np.isfinite(res["display"]["latency_p99_ms"])


def test_the_noisy_target_is_a_cloud_of_sigma_v(tmp_path):
    """sigma_v = 2 deg at 25 px/deg, 300 dots: every dot is drawn where
    visual_dots(seed, refresh) puts it, and their spread along the axis is
    sigma_v (within the 99.9% chi-square interval of 300 samples)."""
    from scipy import stats

    from sensaug import experiment

    cfg = presets.hi5_rig()
    for p in cfg.phases:
        p.duration_s = 1.0
    cfg.phases[0].robot_target[1].duration_s = 1.0
    cfg.robot.gain_window_s = 0.5
    cfg.display.sigma_v, cfg.display.dots, cfg.display.seed = 2.0, 300, 7
    cfg.to_toml(tmp_path / "cfg.toml")
    experiment.run(cfg).save(tmp_path / "trial.csv")
    xvfb(f"""
        import sys
        from sensaug import display
        display.main([{str(tmp_path / 'cfg.toml')!r}, "--replay", {str(tmp_path / 'trial.csv')!r},
                      "--display-log", "dlog.csv", "--screenshots", "shots", "--screenshot-frames",
                      ",".join(str(i) for i in range(0, 400, 10))])
        print("{{}}")
    """, tmp_path)
    df = load_display_log(tmp_path / "dlog.csv")
    noisy = df[(df["dots_refresh"] >= 0) & df["frame"].isin(range(0, 400, 10))]
    shots = [(r, tmp_path / "shots" / f"frame_{int(r.frame):05d}.png") for r in noisy.itertuples()]
    shots = [(r, p) for r, p in shots if p.exists()]
    assert shots, "no frame of the integration phase was saved"
    row, shot = shots[0]
    img = np.asarray(Image.open(shot))
    dots = visual_dots(7, row.dots_refresh, 300, 2.0)
    cy = img.shape[0] / 2
    px = 25.0
    # Every dot that lies on screen and not under the cursor is drawn where its offset says.
    on = 0
    for along, across in dots:
        x, y = row.target_px + along * px, cy + across * px
        if abs(x - row.cursor_px) < 12 or not (2 <= x < img.shape[1] - 2 and 2 <= y < img.shape[0] - 2):
            continue
        pix = img[img.shape[0] - 1 - int(round(y)), int(round(x)), :3].astype(int)
        assert np.abs(pix - TARGET_RGB).max() <= 60, (x, y, pix)
        on += 1
    assert on > 200, on  # the rest lie off screen or under the cursor
    # The drawn cloud's spread along the axis: the dots' pixels (each dot a
    # disk of radius 2 px adds 1 px^2 of variance).
    lo, hi = stats.chi2.ppf([0.0005, 0.9995], 299)
    sd = dots[:, 0].std(ddof=1)
    assert np.sqrt(lo / 299) * 2.0 < sd < np.sqrt(hi / 299) * 2.0, sd
    cloud = blobs(img, TARGET_RGB)
    drawn_sd = np.sqrt(max(cloud[:, 0].var() - 1.0, 0)) / px
    assert abs(drawn_sd - sd) < 0.1 * sd, (drawn_sd, sd)


def _freeze_scenario(cfg: Path, stop_after_s: float) -> str:
    return f"""
        import json, os, signal, threading, time
        from pathlib import Path
        from sensaug.config import ScenarioConfig
        from sensaug.display import DisplayProcess
        from sensaug.rig import run_virtual_rig
        cfg = ScenarioConfig.from_toml({str(cfg)!r})
        screen = DisplayProcess(cfg, workdir=Path("run"))
        frozen = {{}}
        def freeze():
            while not Path("run/rig_log.csv").exists():
                time.sleep(0.01)
            time.sleep({stop_after_s})
            frozen["ns"] = time.monotonic_ns()
            os.kill(screen.proc.pid, signal.SIGSTOP)
        threading.Thread(target=freeze, daemon=True).start()
        try:
            run = run_virtual_rig(cfg, out=Path("run"), display=screen, capture=None)
        finally:
            os.kill(screen.proc.pid, signal.SIGCONT)
            screen.close()
        s = run.stats
        last_tick = int(run.log["tick"][-1])
        safe_ns = s["start"]["tick0_monotonic_ns"] + last_tick * 1_000_000
        print(json.dumps({{"stop": s["stop_reason"], "ticks": s["ticks"], "display": run.display,
                          "frozen_ns": frozen.get("ns"), "safe_ns": safe_ns, "misses": s["deadline_misses"],
                          "can": s["can"], "feed": s.get("feed")}}))
    """


def test_a_frozen_display_stops_the_trial_under_control(tmp_path):
    """SIGSTOP on the display mid-trial (on_freeze = "stop"): the watch sees
    no frame for freeze_timeout_ms and the loop ends with its controlled
    stop; the time from the freeze to the loop's last tick is measured and
    bounded by the timeout (500 ms here), the watch's 5 ms poll and the
    stop's time limit (0.2 s) with 150 ms of slack for a loaded machine."""
    cfg = short_rig(tmp_path, phase_s=3.0, freeze_timeout_ms=500.0)
    res = xvfb(_freeze_scenario(cfg, 1.0), tmp_path)
    assert res["display"]["event"] == "display frozen", res
    assert res["display"]["stopped_loop"] is True
    assert res["stop"] != "completed" and res["ticks"] < 9000, res
    to_safe_ms = (res["safe_ns"] - res["frozen_ns"]) / 1e6
    detect_ms = (res["display"]["detected_monotonic_ns"] - res["frozen_ns"]) / 1e6
    print(f"frozen display: detected after {detect_ms:.0f} ms, loop stopped (last tick) {to_safe_ms:.0f} ms after the freeze")
    # The last frame was written up to a frame period (here < 100 ms) before the freeze.
    assert 500 - 100 <= detect_ms < 500 + 150, detect_ms
    assert to_safe_ms < 500 + 200 + 150, to_safe_ms


def test_a_frozen_display_costs_the_loop_nothing(tmp_path):
    """With the virtual human and on_freeze = "continue", a display stopped
    (SIGSTOP) mid-trial is recorded and the trial runs to its end, every tick."""
    cfg = short_rig(tmp_path, phase_s=2.0, on_freeze="continue")
    res = xvfb(_freeze_scenario(cfg, 0.5), tmp_path)
    assert res["stop"] == "completed", res
    assert res["ticks"] == 6000
    assert res["display"]["event"] == "display frozen"
    assert res["display"]["stopped_loop"] is False


def test_a_session_with_a_person_waits_for_keys_and_esc_stops_a_trial(tmp_path):
    """The template plan reduced (practice + one block, 2 s phases) with a
    person at the handle (rig.virtual_human = false), keys pressed in the
    Xvfb window with xdotool: SPACE starts, R repeats the practice, Esc mid-
    trial stops it with the loop's controlled stop, SPACE re-runs it, a digit
    answers the questionnaire. The manifest has every attempt and no truth."""
    if shutil.which("xdotool") is None:
        pytest.fail("xdotool is missing: install Debian's xdotool (scripts/test.sh does, as root)")
    text = (ROOT / "configs" / "session_template.toml").read_text()
    for a, b in [("duration_s = 10.0", "duration_s = 2.0"), ("gain_window_s = 4.0", "gain_window_s = 1.0"),
                 ("rest_s = 60.0", "rest_s = 1.0"), ("fullscreen = true", "fullscreen = false"),
                 ("width_px = 1280", "width_px = 640"), ("height_px = 720", "height_px = 360"),
                 ('order = "latin_square"', 'order = "fixed"'), ("freeze_timeout_ms = 250.0", "freeze_timeout_ms = 1000.0"),
                 # As the rig tests: loop and drive under SCHED_FIFO, so this shared machine's
                 # load does not starve the virtual drive (the display runs niced below them).
                 ("[rig.realtime]\n", f"[rig.realtime]\nfifo_priority = {RIG_TEST_FIFO_PRIORITY}\n")]:
        assert a in text, a
        text = text.replace(a, b)
    text = text.replace("trials = 5", "trials = 1").replace("trials = 2\npractice", "trials = 1\npractice")
    text = text[: text.index('[[session.blocks]]\nname = "sv0_5_noise2_0"')]
    text = text[: text.index("questionnaire = [")] + 'questionnaire = ["Help? (1-7)"]\n\n' + text[text.index("[[session.blocks]]"):]
    (tmp_path / "plan.toml").write_text(text)
    res = xvfb(f"""
        import json, subprocess, threading, time
        from pathlib import Path
        from sensaug.session import run_session

        folder = Path("sessions/P01")
        def rows():
            m = folder / "manifest.csv"
            return len(m.read_text().splitlines()) - 1 if m.exists() else 0
        def until(cond, what, timeout=60):
            t0 = time.monotonic()
            while not cond():
                assert time.monotonic() - t0 < timeout, what
                time.sleep(0.05)
            time.sleep(0.5)  # the session shows its next prompt
        def key(name):
            win = subprocess.run(["xdotool", "search", "--name", "sensaug"], capture_output=True, text=True).stdout.split()
            subprocess.run(["xdotool", "mousemove", "--window", win[0], "20", "20"], check=True)
            subprocess.run(["xdotool", "key", name], check=True)
        events = {{}}
        def person():
            # Answers each prompt the session shows (sessions/P01/prompts.csv) as a participant would.
            seen, practice_done, escaped = 0, 0, False
            t0 = time.monotonic()
            while time.monotonic() - t0 < 200:
                path = folder / "prompts.csv"
                lines = path.read_text().splitlines() if path.exists() else []
                for line in lines[seen:]:
                    text = line.split(",", 2)[2].strip('"')
                    time.sleep(0.3)
                    if "Press SPACE to start" in text or text.startswith("Trial stopped"):
                        key("space")
                    elif text.startswith("Practice done"):
                        practice_done += 1
                        key("r" if practice_done == 1 else "space")
                    elif "(press 1-7)" in text:
                        key("5")
                    elif text.startswith("(trial trials/001_") and not escaped:
                        log = folder / text[len("(trial "):-1] / "rig_log.csv"
                        until(log.exists, "the block trial's first tick")  # the loop is past its set-up
                        time.sleep(0.5)
                        events["esc_ns"] = time.monotonic_ns()
                        key("Escape")
                        escaped = True
                    elif text.startswith("Thank you"):
                        return
                seen = len(lines)
                time.sleep(0.05)
        threading.Thread(target=person, daemon=True).start()
        run_session("plan.toml", "P01", out="sessions", progress=lambda _: None)
        print(json.dumps(events))
    """, tmp_path, timeout=240)
    s = load_session(tmp_path / "sessions" / "P01")
    df = s.manifest
    # Every attempt ended as the person made it end: no stop of the loop's own.
    assert sorted(df["stop_reason"]) == ["completed"] * 3 + ["escape"], df[["block", "attempt", "stop_reason"]]
    done = s.finished()
    assert list(done["block"]) == ["practice", "practice", "sv0_5_noise0_5"], df
    assert list(done["round"]) == [0, 1, 0]
    esc = df[df["stop_reason"] == "escape"]
    assert len(esc) == 1 and esc["block"].iloc[0] == "sv0_5_noise0_5" and esc["finished"].iloc[0] == 0, df
    assert df["truth_Lhh"].isna().all(), "no truth with a person at the handle"
    stopped = json.loads((tmp_path / "sessions" / "P01" / esc["folder"].iloc[0] / "rig_stats.json").read_text())
    assert "SIGTERM" in stopped["stop_reason"] and "drive disabled" in stopped["stop_reason"]
    q = (tmp_path / "sessions" / "P01" / "questionnaire.csv").read_text().splitlines()
    assert q[1].split(",")[:3] == ["sv0_5_noise0_5", "Help? (1-7)", "5"]
    log = s.log(int(done["trial"].iloc[-1]))
    last_tick_ns = stopped["start"]["tick0_monotonic_ns"] + int(
        load_log(tmp_path / "sessions" / "P01" / esc["folder"].iloc[0] / "rig_log.csv")["tick"][-1]) * 1_000_000
    esc_to_safe_ms = (last_tick_ns - res["esc_ns"]) / 1e6
    print(f"Esc pressed -> the loop's last tick: {esc_to_safe_ms:.0f} ms")
    assert 0 < esc_to_safe_ms < 500, esc_to_safe_ms
    assert log.complete
