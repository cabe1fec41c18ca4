"""The 1 kHz loop with and without the participant's display, side by side in
one run.

    python benches/display_overhead.py [--rounds 3] [--phase-s 4]

Three kinds of round, each a virtual-rig run of the Hi5 protocol
(``presets.hi5_rig`` with ``--phase-s`` s phases: sensaug-rt at 1 kHz, the
virtual drive on the loopback bus; loop and drive under SCHED_FIFO 20 and
the widest feedback limits, as the rig tests, so the shared machine's load
ends fewer rounds early), interleaved A B C C B A ... so a drift in the
machine's load hits all alike:

- *no display*: no ``--feed``, no display process;
- *display*: the display (its own process, niced 10, pyglet under Xvfb with
  llvmpipe: software OpenGL on the same 2 CPUs) fed by the loop's live feed
  (``sensaug-rt --feed``: the log writer thread's datagrams, never the tick);
- *frozen display*: the same, the display stopped (SIGSTOP) 0.5 s into the
  trial and left stopped (``on_freeze = "continue"``): its socket fills and
  the kernel drops what it cannot hold.

Per kind, pooled over its rounds: the loop's compute per tick (``compute_us``:
wake-up to command sent) and wake-up latency, p50 / p99 / p99.9 / max (us),
each with its ratio to *no display*; deadline misses; the feed's datagrams
sent / dropped by the sender (the log's end line); the rounds' stop reasons.
Then per display round its frames, dropped frames and tick-to-swap latency.
Without a ``$DISPLAY`` it runs itself under ``xvfb-run`` (no vsync there).
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

KINDS = ("no display", "display", "frozen display")
#: As tests/test_rig.py: loop and virtual drive under SCHED_FIFO.
FIFO_PRIORITY = 20


def one_round(kind: str, phase_s: float, out: Path) -> dict:
    from sensaug import presets
    from sensaug.display import DisplayProcess
    from sensaug.rig import run_virtual_rig

    cfg = presets.hi5_rig(phase_s=phase_s)
    cfg.phases[0].robot_target[1].duration_s = phase_s
    cfg.rig.realtime.fifo_priority = FIFO_PRIORITY
    cfg.rig.feedback_timeout_ms, cfg.rig.watchdog_ms, cfg.rig.max_stale_feedback_ticks = 300.0, 200, 1000
    cfg.display.enabled = kind != "no display"
    cfg.display.fullscreen, cfg.display.width_px, cfg.display.height_px = False, 1280, 720
    cfg.display.on_freeze = "continue"
    screen = DisplayProcess(cfg, workdir=out) if cfg.display.enabled else None
    if kind == "frozen display":
        def freeze() -> None:
            while not (out / "rig_log.csv").exists():
                time.sleep(0.01)
            time.sleep(0.5)
            os.kill(screen.proc.pid, signal.SIGSTOP)
        threading.Thread(target=freeze, daemon=True).start()
    try:
        run = run_virtual_rig(cfg, out=out, display=screen, capture=None)
    finally:
        if screen is not None:
            os.kill(screen.proc.pid, signal.SIGCONT)
            screen.close()
    log = run.log
    on = log["tick"] >= 0
    end = log.meta.get("end", {})
    return {
        "compute": log["compute_us"][on], "wake": log["wake_latency_us"][on],
        "misses": run.stats["deadline_misses"], "stop": run.stats["stop_reason"],
        "feed_sent": end.get("feed_datagrams_sent", 0), "feed_dropped": end.get("feed_datagrams_dropped", 0),
        "display": run.display,
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--rounds", type=int, default=3, help="rounds of each kind (default 3)")
    p.add_argument("--phase-s", type=float, default=4.0, help="seconds per phase, three phases (default 4)")
    args = p.parse_args()
    if not os.environ.get("DISPLAY"):
        if shutil.which("xvfb-run") is None:
            sys.exit("display_overhead: no $DISPLAY and no xvfb-run (apt-get install xvfb)")
        return subprocess.call(["xvfb-run", "-a", "-s", "-screen 0 1280x720x24", sys.executable, *sys.argv])

    order: list[str] = []
    for r in range(args.rounds):
        order += list(KINDS) if r % 2 == 0 else list(reversed(KINDS))
    results: dict[str, list[dict]] = {k: [] for k in KINDS}
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="sensaug-display-bench-") as tmp:
        for i, kind in enumerate(order):
            results[kind].append(one_round(kind, args.phase_s, Path(tmp) / f"r{i}"))

    def pct(a: np.ndarray) -> np.ndarray:
        a = a[np.isfinite(a)]
        return np.array([*np.percentile(a, [50, 99, 99.9]), a.max()])

    pooled = {k: {"compute": pct(np.concatenate([r["compute"] for r in rs])),
                  "wake": pct(np.concatenate([r["wake"] for r in rs])),
                  "ticks": sum(len(r["compute"]) for r in rs)} for k, rs in results.items()}
    base = pooled["no display"]
    print(f"{args.rounds} rounds of {3 * args.phase_s:g} s per kind, interleaved; us; "
          f"(x r): the ratio to 'no display'; {time.perf_counter() - t0:.0f} s\n")
    print("| run | ticks | tick compute p50 / p99 / p99.9 / max | wake-up p50 / p99 / p99.9 / max | "
          "deadline misses | feed datagrams sent / dropped | stops |")
    print("|---|---:|---:|---:|---:|---:|---|")
    for kind, rs in results.items():
        d = pooled[kind]

        def cell(name: str) -> str:
            return " / ".join(f"{v:.0f}" + ("" if kind == "no display" else f" (x{v / b:.2f})")
                              for v, b in zip(d[name], base[name]))

        feed = "-" if kind == "no display" else f"{sum(r['feed_sent'] for r in rs)} / {sum(r['feed_dropped'] for r in rs)}"
        print(f"| {kind} | {d['ticks']} | {cell('compute')} | {cell('wake')} | {sum(r['misses'] for r in rs)} | "
              f"{feed} | {', '.join(sorted({r['stop'] for r in rs}))} |")
    print("\n| round | kind | wake-up p99 / p99.9 / max (us) | deadline misses |")
    print("|---:|---|---:|---:|")
    seen = {k: 0 for k in KINDS}
    for i, kind in enumerate(order):
        r = results[kind][seen[kind]]
        seen[kind] += 1
        w = pct(r["wake"])
        print(f"| {i} | {kind} | {w[1]:.0f} / {w[2]:.0f} / {w[3]:.0f} | {r['misses']} |")
    print("\n| display round | frames | dropped | tick-to-swap p50 (ms) | p99 (ms) | max (ms) | event |")
    print("|---|---:|---:|---:|---:|---:|---|")
    for kind in KINDS[1:]:
        for i, r in enumerate(results[kind]):
            dsp = r["display"] or {}
            print(f"| {kind} {i} | {dsp.get('frames', 0)} | {dsp.get('dropped', 0)} | "
                  f"{dsp.get('latency_p50_ms', float('nan')):.1f} | {dsp.get('latency_p99_ms', float('nan')):.1f} | "
                  f"{dsp.get('latency_max_ms', float('nan')):.1f} | {dsp.get('event')} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
