"""The loop with and without the participant's display, side by side in one
run: virtual-rig trials alternated (without, with, with, without, ...), each
the hi5-rig preset shortened to ``--phase-s`` per phase. Prints the loop's
tick compute and wake-up latency (p50 / p99 / p99.9 / max, us, from the
per-tick log columns pooled over the rounds), its deadline misses, and the
display's frames, dropped frames and tick-to-swap latency (ms).

    python benches/display_overhead.py [--rounds 2] [--phase-s 5]

Without a ``$DISPLAY`` it runs itself under ``xvfb-run`` (Mesa's llvmpipe:
software OpenGL on the same CPUs as the loop, and no vsync; a rig's GPU and
monitor differ, docs/person.md).
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--rounds", type=int, default=2, help="trials of each kind (default 2)")
    p.add_argument("--phase-s", type=float, default=5.0, help="seconds per phase (default 5)")
    args = p.parse_args()
    if not os.environ.get("DISPLAY"):
        if shutil.which("xvfb-run") is None:
            sys.exit("display_overhead: no $DISPLAY and no xvfb-run (apt-get install xvfb)")
        return subprocess.call(["xvfb-run", "-a", "-s", "-screen 0 1280x720x24", sys.executable, *sys.argv])

    from sensaug import presets
    from sensaug.display import DisplayProcess
    from sensaug.rig import run_virtual_rig

    cfg = presets.hi5_rig()
    for ph in cfg.phases:
        ph.duration_s = args.phase_s
    cfg.phases[0].robot_target[1].duration_s = args.phase_s
    cfg.robot.gain_window_s = args.phase_s / 2
    cfg.display.enabled = True
    pooled: dict[str, dict[str, list]] = {k: {"compute": [], "wake": [], "misses": [], "stops": [], "display": []}
                                          for k in ("without display", "with display")}
    order = ["without display", "with display", "with display", "without display"] * ((args.rounds + 1) // 2)
    order = order[: 2 * args.rounds]
    with tempfile.TemporaryDirectory() as tmp:
        for i, kind in enumerate(order):
            out = Path(tmp) / f"round{i}"
            screen = DisplayProcess(cfg, workdir=out) if kind == "with display" else None
            try:
                run = run_virtual_rig(cfg, out=out, display=screen, capture=None)
            finally:
                if screen is not None:
                    screen.close()
            log = run.log
            on = log["tick"] >= 0
            d = pooled[kind]
            d["compute"].append(log["compute_us"][on])
            d["wake"].append(log["wake_latency_us"][on])
            d["misses"].append(run.stats["deadline_misses"])
            d["stops"].append(run.stats["stop_reason"])
            if run.display:
                d["display"].append(run.display)
    print(f"{args.rounds} trials each, {3 * args.phase_s:g} s each, alternated; us unless said\n")
    print("| run | tick compute p50 / p99 / p99.9 / max | wake-up p50 / p99 / p99.9 / max | deadline misses | stops |")
    print("|---|---:|---:|---:|---|")
    for kind, d in pooled.items():
        c, w = np.concatenate(d["compute"]), np.concatenate(d["wake"])
        q = lambda a: " / ".join(f"{v:.0f}" for v in (*np.percentile(a, [50, 99, 99.9]), a.max()))  # noqa: E731
        print(f"| {kind} | {q(c)} | {q(w)} | {sum(d['misses'])} | {', '.join(sorted(set(d['stops'])))} |")
    disp = pooled["with display"]["display"]
    if disp:
        print("\n| display round | frames | dropped | tick-to-swap p50 (ms) | p99 (ms) | max (ms) | event |")
        print("|---|---:|---:|---:|---:|---:|---|")
        for i, r in enumerate(disp):
            print(f"| {i} | {r['frames']} | {r['dropped']} | {r.get('latency_p50_ms', float('nan')):.1f} | "
                  f"{r.get('latency_p99_ms', float('nan')):.1f} | {r.get('latency_max_ms', float('nan')):.1f} | {r['event']} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
