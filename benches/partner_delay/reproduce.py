"""Reproduces the issue's check: the paper's stage 1 at Hi5 settings with the
virtual human L_h = [0, 0, 2] acting on the measured state d ms ago.
Also checks this numpy stage 1 against the project's own (sensaug.GainEstimator,
the Rust core) step by step on one recording.

    .venv/bin/python benches/partner_delay/reproduce.py [seeds...]
"""
import sys

import numpy as np

import sensaug
from filters import PaperStage1
from settings import hi5
from world import World, HumanSettings


def gain_phase(h, partners, seeds):
    w = World(h, partners, seeds)
    w.run_open(h.ticks)
    return w


def run_paper_stage1(h, w):
    T, B = h.ticks, w.B
    f = PaperStage1(h, B)
    out = np.zeros((B, T, 3))
    for k in range(T):
        y = np.column_stack([w.rec["xm"][:, k] - w.tau[k], w.rec["vm"][:, k], w.rec["xm"][:, k] - w.tau_h[k]])
        f.update(y)
        out[:, k] = f.gains
        f.predict(w.rec["u"][:, k], np.full(B, w.dtau[k]), np.full(B, w.dtau_h[k]))
    return out, f


def check_against_core(h, w, b=0, steps=5000):
    g = sensaug.GainEstimator(mass=h.M, dt=h.dt, Q=h.Q1, R=h.R1, x0=np.zeros(6), P0=h.P01)
    f = PaperStage1(h, 1)
    worst = 0.0
    for k in range(steps):
        y = np.array([w.rec["xm"][b, k] - w.tau[k], w.rec["vm"][b, k], w.rec["xm"][b, k] - w.tau_h[k]])
        g.update(y)
        f.update(y[None])
        worst = max(worst, np.abs(g.x - f.x[0]).max() / np.abs(g.x).max(), np.abs(g.P - f.P[0]).max() / np.abs(g.P).max())
        u = w.rec["u"][b, k]
        g.predict(u, w.dtau[k], w.dtau_h[k])
        f.predict(np.array([u]), np.array([w.dtau[k]]), np.array([w.dtau_h[k]]))
    return worst


def main():
    seeds = [int(s) for s in sys.argv[1:]] or [0, 1, 2, 3]
    h = hi5()
    last = int(round(h.gain_window_s / h.dt))
    for d in (0, 20, 50, 100):
        partners = [HumanSettings((0.0, 0.0, 2.0), visual_delay_ms=d, seed=s) for s in seeds]
        w = gain_phase(h, partners, seeds)
        if d == 0:
            print(f"numpy stage 1 vs the project's GainEstimator, 5000 steps: worst relative difference {check_against_core(h, w):.1e}")
        est, f = run_paper_stage1(h, w)
        tail = est[:, -last:, 2]
        xmax = np.abs(w.rec["x"][:, : h.ticks]).max(axis=1)
        print(f"d = {d:3d} ms: Lhh^ mean of last 8 s per seed {np.round(tail.mean(1), 3)}, "
              f"std within {np.round(tail.std(1), 3)}, covariance resets {f.resets}, max |x| {np.round(xmax, 1)} deg")


if __name__ == "__main__":
    main()
