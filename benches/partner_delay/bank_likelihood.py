"""Why the issue's "bank of stage-1 filters ranked by innovation likelihood"
does not find the delay with the paper's noise model (Q_k = 1e-2 I6 per step,
R = 1e-7 I3): the summed log-likelihood of each member, split into its fit
term (nu' S^-1 nu) and its log det S term, over the gain phase after 2 s.

    .venv/bin/python benches/partner_delay/bank_likelihood.py [seed]
"""
import math
import sys

import numpy as np

from filters import DelayBank
from settings import hi5
from world import HumanSettings, World

seed = int(sys.argv[1]) if len(sys.argv) > 1 else 0
h = hi5()
T = h.ticks
grid = [0, 20, 40, 50, 60, 80, 100, 150, 200, 300]
cases = [(2.0, 50), (1.0, 150)]
w = World(h, [HumanSettings((0.0, 0.0, lhh), d, d, seed=seed) for lhh, d in cases], [seed] * len(cases))
w.run_open(T)
bank = DelayBank(h, w.B, [(d, d) for d in grid], from_tick=2000)
fit = np.zeros((w.B, len(grid)))
logdet = np.zeros((w.B, len(grid)))
for k in range(T):
    y = np.column_stack([w.rec["xm"][:, k] - w.tau[k], w.rec["vm"][:, k], w.rec["xm"][:, k] - w.tau_h[k]])
    S = bank.P[..., :3, :3] + h.R1
    nu = y[:, None, :] - bank.x[..., :3]
    if k >= 2000:
        fit += np.einsum("bki,bki->bk", nu, np.linalg.solve(S, nu[..., None])[..., 0])
        logdet += np.linalg.slogdet(S)[1]
    bank.update(y)
    bank.predict(w.rec["u"][:, k], np.full(w.B, w.dtau[k]), np.full(w.B, w.dtau_h[k]))
n = T - 2000
print(f"seed {seed}; per member over {n} steps: mean nu'S^-1 nu (3 if the noise model fitted), mean ln det S, summed log-likelihood")
for b, (lhh, d) in enumerate(cases):
    print(f"Lhh = {lhh}, true delay {d} ms")
    for j, g in enumerate(grid):
        print(f"  member {g:3d} ms: fit {fit[b, j] / n:.2e}  ln det S {logdet[b, j] / n:+.4f}  log-lik {bank.loglik[b, j]:+.1f}"
              f"  gains {np.round(bank.gains[b, j], 3)}")
