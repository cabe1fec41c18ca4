"""The gains' process noise of stage 1 against a partner with signal-dependent
motor noise: the delay-aware stage-1 filter at the TRUE delays, with the
preset's 1e-2 per step on the gains and with smaller values (the states' Q
unchanged). Mean and std of the estimate over the last 8 s of the gain phase.
Seed 1.

    .venv/bin/python benches/partner_delay/gain_noise.py
"""
import dataclasses

import numpy as np

from pipeline import SwitchingDelayedStage1
from settings import hi5
from world import HumanSettings, World

h0 = hi5()
T = h0.ticks; last = 8000
cases = [(1.0, 0.0837, 0, 0, 0.1), (1.0, 0.0837, 0, 0, 0.0), (1.0, 0.0837, 100, 0, 0.1), (1.0, 0.0837, 100, 40, 0.1), (1.0, 0.0, 100, 0, 0.1)]
ps = [HumanSettings((0.0, lhv, lhh), dv, dp, motor_noise_gain=km, seed=1) for (lhh, lhv, dv, dp, km) in cases]
w = World(h0, ps, [1]*len(ps)); w.run_open(T)
rows = np.arange(w.B); d = np.column_stack([w.dv, w.dp])
for qg in (1e-2, 1e-4, 1e-6):
    h = dataclasses.replace(h0, Q1=np.diag([1e-2]*3 + [qg]*3))
    f = SwitchingDelayedStage1(h, w.B); g = np.zeros((w.B, last, 3))
    for k in range(T):
        Y = np.column_stack([w.rec["xm"][:, k] - w.tau[k], w.rec["vm"][:, k], w.rec["xm"][:, k] - w.tau_h[k]])
        f.update(Y)
        if k >= T-last: g[:, k-(T-last)] = f.x[:, 3:]
        iv, ip = np.maximum(k-d[:,0],0), np.maximum(k-d[:,1],0)
        phi = np.column_stack([w.rec["xm"][rows, iv]-w.tau[iv], w.rec["vm"][rows, ip], w.rec["xm"][rows, iv]-w.tau_h[iv]])
        f.predict(w.rec["u"][:, k], np.full(w.B, w.dtau[k]), np.full(w.B, w.dtau_h[k]), phi)
    for b, c in enumerate(cases):
        print(f"Q gains {qg:.0e}  (Lhh, Lhv, d_v, d_p, k_m) = {c}: mean {np.round(g[b].mean(0), 4)}  std {np.round(g[b].std(0), 4)}")
