"""Reference implementation of the delay identification (issue 24), written
from docs/design/partner_delay.md, section "Identifying the delays": the
profile log-likelihood of the least-squares fit of the measured partner
torque on the delayed measured state, for given delay pairs. Direct
``numpy.linalg.lstsq`` on the stacked regressors (no running sums), so it is
independent of the accumulator form the filter uses.

    r[k]   = M (v_m[k+1] - v_m[k]) / dt - u[k]                 (C = 0)
    phi[k] = [y_e[k - dv], y_v[k - dp], y_eh[k - dv]]          (index clamped at 0)
    -r[k]  = phi[k]' L + w[k]
    RSS(dv, dp) = min_L sum_k q_k (r[k] + phi[k]' L)^2,   l = -N/2 ln(RSS / N)

with weights ``q_k`` (1 for ordinary least squares; the fine stage uses
``q_k = 1 / (s0 + kappa^2 c_k^2)``, the signal-dependent noise model, see the
design note).
"""

from __future__ import annotations

import numpy as np


def residual_torque(vm: np.ndarray, u: np.ndarray, M: float, dt: float) -> np.ndarray:
    """``r[k]`` for ``k = 0 .. len(vm) - 2``: the torque not commanded by the
    robot over tick ``k`` (the partner's, plus motor and sensor noise)."""
    return M * (vm[1:] - vm[:-1]) / dt - u[:-1]


def regressors(Y: np.ndarray, ks: np.ndarray, dv: int, dp: int) -> np.ndarray:
    """Rows ``phi[k]`` for ``k`` in ``ks``; ``Y[j] = [y_e, y_v, y_eh]`` at tick j."""
    iv, ip = np.maximum(ks - dv, 0), np.maximum(ks - dp, 0)
    return np.column_stack([Y[iv, 0], Y[ip, 1], Y[iv, 2]])


def profile(Y: np.ndarray, r: np.ndarray, ks: np.ndarray, dv: int, dp: int, q=None) -> tuple[float, np.ndarray]:
    """``(l, L)`` of the pair ``(dv, dp)`` over the ticks ``ks`` (weights
    ``q``, one per tick of ``ks``, or none)."""
    Phi = regressors(Y, ks, dv, dp)
    sq = np.ones(len(ks)) if q is None else np.sqrt(np.asarray(q, float))
    L, *_ = np.linalg.lstsq(Phi * sq[:, None], -r[ks] * sq, rcond=None)
    rss = float((sq * sq * (r[ks] + Phi @ L) ** 2).sum())
    n = len(ks)
    return -0.5 * n * np.log(rss / n), L


def search(Y, r, ks, pairs) -> tuple[tuple[int, int], float, np.ndarray]:
    """The pair of ``pairs`` with the largest profile log-likelihood."""
    best = max(pairs, key=lambda p: profile(Y, r, ks, *p)[0])
    l, L = profile(Y, r, ks, *best)
    return best, l, L
