"""The issue's table: visual delays {0, 50, 100, 150, 200 ms} x proprioceptive
{0, 40 ms} x Lhh {0.5, 1, 2}, paper's identification vs the delay-aware one,
on the Hi5 settings (presets.hi5_experiment).

    .venv/bin/python benches/partner_delay/table.py --family paper --km 0 --seeds 0 1 2 --out results/x.json

``--family paper``: the paper's virtual human L_h = [0, 0, Lhh];
``--family damped``: L_h = [0, sqrt(2 M Lhh), Lhh] (the velocity gain an LQR
partner with q_vel = 0 has at that stiffness, like the robot's own).
``--km``: the partner's signal-dependent motor-noise gain; ``--drift``: the
gains' relative drift std (time constant 10 s). Each (cell, seed) is one
trial; all cells of one seed share the world's noise draws.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np

from pipeline import run
from settings import hi5
from stability import verdict
from world import HumanSettings

VISUAL = (0, 50, 100, 150, 200)
PROPRIO = (0, 40)
LHH = (0.5, 1.0, 2.0)


def cells(h, family: str):
    """The paper's virtual human has no velocity term, so its proprioceptive
    delay changes nothing (the trials are identical, checked on seed 0): only
    d_p = 0 is run for it."""
    for lhh in LHH:
        lhv = 0.0 if family == "paper" else math.sqrt(2 * h.M * lhh)
        for dp in PROPRIO if family == "damped" else (0,):
            for dv in VISUAL:
                yield lhh, lhv, dv, dp


def jsonable(o):
    if isinstance(o, dict):
        return {k: jsonable(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [jsonable(v) for v in o]
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer, np.bool_)):
        return o.item()
    return o


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--family", choices=("paper", "damped"), default="paper")
    ap.add_argument("--km", type=float, default=0.0)
    ap.add_argument("--drift", type=float, default=0.0)
    ap.add_argument("--seeds", type=int, nargs="+", required=True)
    ap.add_argument("--phase-s", type=float, default=20.0)
    ap.add_argument("--known-delay", action="store_true")
    ap.add_argument("--only", type=str, default=None, help="lhh,dv,dp: one cell")
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args()
    h = hi5(phase_s=a.phase_s)
    todo = list(cells(h, a.family))
    if a.only:
        lhh, dv, dp = (float(x) for x in a.only.split(","))
        todo = [c for c in todo if c[0] == lhh and c[2] == dv and c[3] == dp]
    partners, seeds = [], []
    for s in a.seeds:
        for lhh, lhv, dv, dp in todo:
            partners.append(HumanSettings((0.0, lhv, lhh), dv, dp, motor_noise_gain=a.km, drift_std=a.drift,
                                          drift_time_constant_s=10.0, seed=s))
            seeds.append(s)
    t0 = time.time()
    res = run(h, partners, seeds, known_delay=a.known_delay)
    for r, p in zip(res, partners):
        ok, rho = verdict(h, p.gains, p.visual_delay_ms, p.proprioceptive_delay_ms)
        r["stable"], r["spectral_radius"] = ok, rho
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(dict(args={k: str(v) for k, v in vars(a).items()}, seconds=time.time() - t0,
                                     results=jsonable(res)), indent=1))
    print(f"{len(res)} trials in {time.time() - t0:.0f} s -> {a.out}")


if __name__ == "__main__":
    main()
