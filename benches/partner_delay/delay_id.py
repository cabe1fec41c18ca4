"""Online identification of the partner's delays by least squares on the
measured partner torque (a prediction-error / profile-likelihood search over
a grid of delay pairs), batched over seeds. Written as the Rust version would
run it: fixed-size accumulators updated once per tick, a coarse grid first,
then a fine grid around the coarse optimum; see docs/design/partner_delay.md,
section "Identifying the delays".

Per tick ``k >= 1`` the robot knows the torque the partner (and the motor
noise) applied over tick ``k - 1`` from its own velocity measurements
(C = 0; exact ZOH):

    r[k-1] = M (v_m[k] - v_m[k-1]) / dt - u[k-1]  (= u_h[k-1] + eps + sensor noise)

and the delayed regressor of the pair (dv, dp),
``phi[k-1] = [y_e[k-1-dv], y_v[k-1-dp], y_eh[k-1-dv]]``. For every pair it
accumulates ``A = sum phi phi'`` and ``b = sum phi (-r)`` and ``rr = sum r^2``;
the residual sum of squares of the least-squares fit is
``RSS = rr - b' A^-1 b`` and the concentrated (profile) log-likelihood
``l = -N/2 ln(RSS / N)``. The chosen pair maximises ``l``.

Which sums depend on which delay: ``A11, A13, A33, b1, b3`` on dv only,
``A22, b2`` on dp only, ``A12, A23`` on the pair; so a grid of Kv x Kp pairs
costs ``5 Kv + 2 Kp + 2 Kv Kp + 1`` multiply-adds per tick.
"""

from __future__ import annotations

import numpy as np

from settings import Hi5


class Grid:
    """Accumulators over the pairs ``dv_b[i] x dp_b[j]`` (per seed b)."""

    def __init__(self, dv: np.ndarray, dp: np.ndarray, start: int):
        self.dv, self.dp = dv, dp  # (B, Kv), (B, Kp) ticks
        B, Kv, Kp = dv.shape[0], dv.shape[1], dp.shape[1]
        self.s_v = np.zeros((B, 5, Kv))  # A11 A13 A33 b1 b3
        self.s_p = np.zeros((B, 2, Kp))  # A22 b2
        self.s_vp = np.zeros((B, 2, Kv, Kp))  # A12 A23
        self.rr = np.zeros(B)
        self.n = 0
        self.start = start

    def add(self, Y: np.ndarray, j: int, r: np.ndarray, w: np.ndarray | None = None) -> None:
        """One residual ``r`` (B,) at tick ``j`` with the history ``Y`` (B, ticks, 3),
        with weight ``w`` (B,) (1 if None)."""
        rows = np.arange(Y.shape[0])[:, None]
        yv = Y[rows, np.maximum(j - self.dv, 0)]  # (B, Kv, 3)
        yp = Y[rows, np.maximum(j - self.dp, 0)]  # (B, Kp, 3)
        e, eh, v = yv[..., 0], yv[..., 2], yp[..., 1]
        if w is not None:  # weighted sums: scale one factor of every product by w
            r = r * np.sqrt(w)
            sw = np.sqrt(w)[:, None]
            e, eh, v = e * sw, eh * sw, v * sw
        m = -r[:, None]
        self.s_v += np.stack([e * e, e * eh, eh * eh, e * m, eh * m], 1)
        self.s_p += np.stack([v * v, v * m], 1)
        self.s_vp[:, 0] += e[:, :, None] * v[:, None, :]
        self.s_vp[:, 1] += v[:, None, :] * eh[:, :, None]
        self.rr += r * r
        self.n += 1

    def profile(self) -> tuple[np.ndarray, np.ndarray]:
        """``(l, gains)``: the profile log-likelihood (B, Kv, Kp) and the
        least-squares gains (B, Kv, Kp, 3)."""
        B, Kv, Kp = self.s_vp.shape[0], self.s_vp.shape[2], self.s_vp.shape[3]
        A = np.empty((B, Kv, Kp, 3, 3))
        a11, a13, a33, b1, b3 = (self.s_v[:, i, :, None] for i in range(5))
        a22, b2 = (self.s_p[:, i, None, :] for i in range(2))
        a12, a23 = self.s_vp[:, 0], self.s_vp[:, 1]
        A[..., 0, 0], A[..., 1, 1], A[..., 2, 2] = a11, a22, a33
        A[..., 0, 1] = A[..., 1, 0] = a12
        A[..., 0, 2] = A[..., 2, 0] = np.broadcast_to(a13, (B, Kv, Kp))
        A[..., 1, 2] = A[..., 2, 1] = a23
        b = np.stack(np.broadcast_arrays(b1, b2, b3), -1)
        # A tiny ridge keeps a regressor that never moved solvable.
        ridge = 1e-12 * np.trace(A, axis1=-2, axis2=-1)[..., None, None] * np.eye(3) + 1e-300 * np.eye(3)
        L = np.linalg.solve(A + ridge, b[..., None])[..., 0]
        rss = np.maximum(self.rr[:, None, None] - (b * L).sum(-1), 1e-300)
        n = max(self.n, 1)
        return -0.5 * n * np.log(rss / n), L


class DelayIdentifier:
    """Coarse grid (``coarse_ms`` steps over ``[0, max_ms]``, both delays)
    from ``start`` to ``fine_tick``; then a fine grid (1 tick steps,
    ``+-fine_half`` around the coarse optimum) from ``fine_tick`` on. The
    choice is refreshed every ``every`` ticks: the fine optimum once the fine
    grid holds ``min_fine`` residuals, else the coarse one once it holds
    ``min_coarse``, else ``None``.

    The proprioceptive delay is *identified* only if the coarse profile
    along dp (at the best dv) spans more than ``dp_threshold`` nats: a partner
    without a velocity term (the paper's virtual human) leaves it flat. When
    it is not identified, dp is tied to dv (the 1-D model) and the fine grid
    is 1-D."""

    def __init__(self, h: Hi5, B: int, max_ms=300, coarse_ms=10, fine_half_ms=10, start_ms=300,
                 fine_ms=6000, min_coarse_ms=1000, min_fine_ms=2000, every=100, dp_threshold=100.0):
        tick = lambda ms: int(round(ms * 1e-3 / h.dt))
        self.h, self.B = h, B
        self.maxd = tick(max_ms)
        c = np.arange(0, self.maxd + 1, tick(coarse_ms))
        self.coarse = Grid(np.tile(c, (B, 1)), np.tile(c, (B, 1)), tick(start_ms))
        self.fine: Grid | None = None
        self.fine_half = tick(fine_half_ms)
        self.fine_tick = tick(fine_ms)
        self.min_coarse, self.min_fine, self.every = tick(min_coarse_ms), tick(min_fine_ms), every
        self.dp_threshold = dp_threshold
        self.choice: np.ndarray | None = None  # (B, 2) ticks
        self.dp_identified = np.zeros(B, bool)
        self.k = -1
        # The partner's torque noise model var(r) = s0 + kappa2 c^2, fitted
        # to the residuals of the stage-1 filter's prediction c (fine stage).
        self.noise_sums = np.zeros((B, 5))  # sum 1, c^2, c^4, res^2, res^2 c^2
        self.min_noise_fit = 500
        self.noise = (np.full(B, np.nan), np.full(B, np.nan))

    def noise_model(self):
        """``(s0, kappa2)`` by least squares of res^2 on [1, c^2]; s0 floored
        at 1e-3 of the mean squared residual, kappa2 at 0."""
        n, c2, c4, r2, r2c2 = (self.noise_sums[:, i] for i in range(5))
        det = n * c4 - c2 * c2
        det = np.where(det > 0, det, np.inf)
        s0 = (c4 * r2 - c2 * r2c2) / det
        k2 = (n * r2c2 - c2 * r2) / det
        floor = 1e-3 * r2 / np.maximum(n, 1)
        return np.maximum(s0, floor), np.maximum(k2, 0.0)

    def _best(self, g: Grid, tie_dp: np.ndarray | None):
        """Argmax of the profile; where ``tie_dp``, dp := dv."""
        l, L = g.profile()
        flat = l.reshape(self.B, -1).argmax(1)
        i, j = np.unravel_index(flat, l.shape[1:])
        rows = np.arange(self.B)
        choice = np.column_stack([g.dv[rows, i], g.dp[rows, j]])
        if tie_dp is not None:
            choice[:, 1] = np.where(tie_dp, choice[:, 0], choice[:, 1])
        return choice, l, L, (i, j)

    def _coarse_choice(self):
        choice, l, _, (i, _) = self._best(self.coarse, None)
        rows = np.arange(self.B)
        span = l[rows, i, :].max(1) - l[rows, i, :].min(1)
        self.dp_span = span
        self.dp_identified = span > self.dp_threshold
        choice[:, 1] = np.where(self.dp_identified, choice[:, 1], choice[:, 0])
        return choice

    def tick(self, Y: np.ndarray, k: int, r_prev: np.ndarray | None, c_prev: np.ndarray | None = None) -> None:
        """Tick ``k``: ``Y[:, :k+1]`` is the history, ``r_prev = r[k-1]``,
        ``c_prev`` the stage-1 filter's predicted partner torque for tick
        ``k - 1`` (the fine stage's weights: feasible weighted least squares
        under the signal-dependent noise model)."""
        self.k = k
        if r_prev is not None and k - 1 >= self.coarse.start:
            if self.fine is None and k - 1 >= self.fine_tick and self.choice is not None:
                cv, cp = self.choice[:, 0], self.choice[:, 1]
                off = np.arange(-self.fine_half, self.fine_half + 1)
                dvf = np.clip(cv[:, None] + off, 0, self.maxd)
                # Not identified: a 1-D fine grid at dp = the coarse dv.
                dpf = np.where(self.dp_identified[:, None], np.clip(cp[:, None] + off, 0, self.maxd), cv[:, None])
                self.fine = Grid(dvf, dpf, k - 1)
            if self.fine is None:
                self.coarse.add(Y, k - 1, r_prev)
            else:
                w = None
                if c_prev is not None:
                    if self.noise_sums[0, 0] >= self.min_noise_fit:
                        s0, k2 = self.noise_model()
                        self.noise = (s0, k2)
                        w = 1.0 / (s0 + k2 * c_prev * c_prev)
                    res2, c2 = (r_prev - c_prev) ** 2, c_prev * c_prev
                    self.noise_sums += np.column_stack([np.ones_like(c2), c2, c2 * c2, res2, res2 * c2])
                self.fine.add(Y, k - 1, r_prev, w)
        if k % self.every == 0:
            if self.fine is not None and self.fine.n >= self.min_fine:
                self.choice = self._best(self.fine, ~self.dp_identified)[0]
            elif self.fine is None and self.coarse.n >= self.min_coarse:
                self.choice = self._coarse_choice()

    def evidence(self) -> dict:
        """What the log would hold at the end: the chosen pair, whether dp is
        identified (and the coarse profile's span along dp that decided it),
        the 95% profile-likelihood interval of each delay on the fine grid
        (``l >= l* - 1.92``), the least-squares gains at the chosen pair."""
        g = self.fine if self.fine is not None else self.coarse
        choice, l, L, (i, j) = self._best(g, ~self.dp_identified)
        rows = np.arange(self.B)
        lstar = l[rows, i, j]
        prof_v, prof_p = l[rows, :, j], l[rows, i, :]
        inside_v = prof_v >= (lstar - 1.92)[:, None]
        inside_p = prof_p >= (lstar - 1.92)[:, None]
        ci = lambda inside, d: (np.where(inside, d, np.inf).min(1), np.where(inside, d, -np.inf).max(1))
        return dict(choice=choice, gains_ls=L[rows, i, j], loglik=lstar, noise_s0=self.noise[0], noise_kappa2=self.noise[1],
                    dv_ci=ci(inside_v, g.dv),
                    dp_ci=ci(inside_p, g.dp), dp_identified=self.dp_identified.copy(), dp_span=self.dp_span.copy(),
                    n=g.n)
