"""One delay or two? The least-squares delay search (profile likelihood of
the partner-torque regression, ordinary least squares over the gain phase
after 2 s) with the proprioceptive delay tied to the visual one, fixed at
40 ms, or searched (2-D: a 10 ms grid, then 1 ms +-10 ms around its best).
Human-like partner with motor-noise gain 0.1, Hi5 settings, seed 7.

    .venv/bin/python benches/partner_delay/explore_pem.py
"""
import sys
from pathlib import Path

import numpy as np

from settings import hi5
from world import HumanSettings, World

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests" / "oracles"))
from delay_search import residual_torque  # noqa: E402

h = hi5()
T = h.ticks
CASES = [(2.0, 0.0, 50, 0), (1.0, 0.0, 150, 0), (1.0, 0.0837, 100, 40), (2.0, 0.118, 150, 40), (1.0, 0.0837, 73, 31)]
w = World(h, [HumanSettings((0.0, lhv, lhh), dv, dp, motor_noise_gain=0.1, seed=7) for lhh, lhv, dv, dp in CASES],
          [7] * len(CASES))
w.run_open(T)
B = w.B
Y = np.stack([w.rec["xm"][:, :T] - w.tau[:T], w.rec["vm"][:, :T], w.rec["xm"][:, :T] - w.tau_h[:T]], -1)
r = np.stack([residual_torque(w.rec["vm"][b, :T], w.rec["u"][b, :T], h.M, h.dt) for b in range(B)])
ks = np.arange(2000, T - 1)
N = len(ks)


def fit(dv, dp):
    """Profile log-likelihood and gains of every seed at the pair (dv, dp) (arrays of B)."""
    dv, dp = np.broadcast_to(dv, (B,)), np.broadcast_to(dp, (B,))
    rows = np.arange(B)[:, None]
    Phi = np.stack([Y[rows, np.maximum(ks - dv[:, None], 0), 0], Y[rows, np.maximum(ks - dp[:, None], 0), 1],
                    Y[rows, np.maximum(ks - dv[:, None], 0), 2]], -1)
    A = np.einsum("bni,bnj->bij", Phi, Phi)
    bb = np.einsum("bni,bn->bi", Phi, -r[:, ks])
    L = np.linalg.solve(A, bb[..., None])[..., 0]
    rss = ((-r[:, ks] - np.einsum("bni,bi->bn", Phi, L)) ** 2).sum(1)
    return -0.5 * N * np.log(rss / N), L


def best_over(pairs):
    ls = np.array([fit(a, b)[0] for a, b in pairs])  # (P, B)
    return [pairs[i] for i in ls.argmax(0)]


grid1 = list(range(0, 301))
tied = best_over([(d, d) for d in grid1])
dp40 = best_over([(d, 40) for d in grid1])
coarse = best_over([(a, b) for a in range(0, 301, 10) for b in range(0, 301, 10)])
fine = []
for b in range(B):
    cv, cp = coarse[b]
    pairs = [(a, c) for a in range(max(cv - 10, 0), cv + 11) for c in range(max(cp - 10, 0), cp + 11)]
    ls = np.array([fit(a, c)[0][b] for a, c in pairs])
    fine.append(pairs[int(ls.argmax())])
print("| truth (d_v, d_p), Lhv | 1-D, d_p = d_v | 1-D, d_p = 40 | 2-D coarse | 2-D fine | gains at the 2-D fine pair |")
print("|---|---|---|---|---|---|")
for b, (lhh, lhv, dv, dp) in enumerate(CASES):
    g = fit(np.array([fine[i][0] for i in range(B)]), np.array([fine[i][1] for i in range(B)]))[1][b]
    gt = fit(np.array([tied[i][0] for i in range(B)]), np.array([tied[i][1] for i in range(B)]))[1][b]
    print(f"| ({dv}, {dp}), {lhv} (Lhh {lhh}) | {tied[b][0]} (gains {np.round(gt, 3)}) | {dp40[b][0]} | {coarse[b]} | {fine[b]} | {np.round(g, 4)} |")
