//! Online identification of the partner's sensorimotor delays (docs/model.md,
//! "Identifying the delay"; the design and its measurements:
//! docs/design/partner_delay.md, section 7).
//!
//! The robot measures what the partner did: with the model's step
//! (`v' = v_v v + v_f f`), the torque applied over tick `k - 1` besides the
//! robot's own is `r[k-1] = (v_m[k] - v_v v_m[k-1]) / v_f - u[k-1]`
//! (the partner's torque plus the motor and sensor noise). For every
//! candidate pair of delays `(d_v, d_p)` the partner's law is the linear
//! regression `-r = phi(d_v, d_p)' L + w` with
//! `phi = [y_e[k-1-d_v], y_v[k-1-d_p], y_eh[k-1-d_v]]`; least squares gives
//! its residual sum of squares `RSS = rr - b' A^-1 b` (`A = sum phi phi'`,
//! `b = sum phi (-r)`, `rr = sum r^2`) and the profile log-likelihood
//! `l = -N/2 ln(RSS / N)`: the prediction-error (maximum-likelihood) delay
//! is the pair maximising `l`. No filter per candidate, 1 ms resolution.
//!
//! Fixed-size running sums: `A11, A13, A33, b1, b3` depend on `d_v` only,
//! `A22, b2` on `d_p` only, `A12, A23` on the pair. A coarse grid (10 ms
//! steps over 0-300 ms, both delays; every second residual) accumulates first; then a fine grid
//! (1 ms steps, +-10 ms around the coarse choice) accumulates, its residuals
//! weighted by a fitted signal-dependent noise model. A few pairs are
//! evaluated per tick (round robin); the choice is the best of the last
//! complete sweep. A pair whose normal equations are not positive definite
//! is skipped and counted, never chosen.

use crate::agent::History;

/// Pairs evaluated per tick (round robin over the active grid): a coarse
/// sweep takes 241 ticks, a fine one 111, far below the 5% and 10% of the
/// phase before the choices count.
const PAIRS_PER_TICK: usize = 4;
/// The coarse grid accumulates every `COARSE_EVERY`-th residual: it only
/// picks the fine grid's neighbourhood, where neighbouring 10 ms delays
/// differ by hundreds of nats (docs/design/partner_delay.md, section 10),
/// and its 31 x 31 cross sums are most of the search's cost.
const COARSE_EVERY: u64 = 2;
/// Coarse grid points per delay (0, 10, ..., 300 ms).
const COARSE: usize = 31;
/// Fine grid points per delay (+-10 ticks).
const FINE: usize = 21;
/// Residuals of the stage-1 prediction before the noise model weights.
const MIN_NOISE_FIT: f64 = 500.0;
/// The proprioceptive delay is identified only when the coarse profile
/// along it spans more than this (nats): a partner without a velocity term
/// leaves it flat (docs/design/partner_delay.md: 10 nats let the
/// signal-dependent noise flag a flat axis).
pub const DP_THRESHOLD_NATS: f64 = 100.0;
/// Half-width of the 95% profile-likelihood interval (chi^2_1 / 2).
const CI_NATS: f64 = 1.92;

/// Lower Cholesky factor of a symmetric 3x3 matrix; `None` unless positive
/// definite.
// Indexed as the textbook writes it: rows and columns of two matrices.
#[allow(clippy::needless_range_loop)]
fn chol3(a: &[[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
    let mut l = [[0.0f64; 3]; 3];
    for c in 0..3 {
        let mut d = a[c][c];
        for k in 0..c {
            d -= l[c][k] * l[c][k];
        }
        if !(d > 0.0 && d.is_finite()) {
            return None;
        }
        l[c][c] = libm::sqrt(d);
        for r in c + 1..3 {
            let mut t = a[r][c];
            for k in 0..c {
                t -= l[r][k] * l[c][k];
            }
            l[r][c] = t / l[c][c];
        }
    }
    Some(l)
}

/// Running least-squares sums of every pair `dv[i] x dp[j]` (ticks), and the
/// profile log-likelihood of each pair as last evaluated.
#[derive(Clone, Debug, PartialEq)]
struct PairGrid<const KV: usize, const KP: usize> {
    dv: [usize; KV],
    dp: [usize; KP],
    /// A11, A13, A33, b1, b3 per `dv`.
    s_v: [[f64; KV]; 5],
    /// A22, b2 per `dp`.
    s_p: [[f64; KP]; 2],
    a12: [[f64; KP]; KV],
    a23: [[f64; KP]; KV],
    rr: f64,
    n: u64,
    /// `l` of each pair at its last evaluation (NaN: refused or not yet).
    loglik: [[f64; KP]; KV],
    cursor: usize,
    refused: u64,
}

impl<const KV: usize, const KP: usize> PairGrid<KV, KP> {
    fn new(dv: [usize; KV], dp: [usize; KP]) -> Self {
        PairGrid {
            dv,
            dp,
            s_v: [[0.0; KV]; 5],
            s_p: [[0.0; KP]; 2],
            a12: [[0.0; KP]; KV],
            a23: [[0.0; KP]; KV],
            rr: 0.0,
            n: 0,
            loglik: [[f64::NAN; KP]; KV],
            cursor: 0,
            refused: 0,
        }
    }

    /// One residual `r` of tick `k - 1` (weight `w`), the history's newest
    /// sample being tick `k`.
    fn add(&mut self, ring: &History<4>, r: f64, w: f64) {
        let sw = libm::sqrt(w);
        let m = -r * sw;
        let mut e = [0.0; KV];
        let mut eh = [0.0; KV];
        let mut v = [0.0; KP];
        for i in 0..KV {
            let y = ring.ago(1 + self.dv[i]);
            e[i] = y[0] * sw;
            eh[i] = y[2] * sw;
        }
        for (j, vj) in v.iter_mut().enumerate() {
            *vj = ring.ago(1 + self.dp[j])[1] * sw;
        }
        for i in 0..KV {
            self.s_v[0][i] += e[i] * e[i];
            self.s_v[1][i] += e[i] * eh[i];
            self.s_v[2][i] += eh[i] * eh[i];
            self.s_v[3][i] += e[i] * m;
            self.s_v[4][i] += eh[i] * m;
        }
        for (j, vj) in v.iter().enumerate() {
            self.s_p[0][j] += vj * vj;
            self.s_p[1][j] += vj * m;
        }
        for i in 0..KV {
            let (ei, ehi) = (e[i], eh[i]);
            for (j, vj) in v.iter().enumerate() {
                self.a12[i][j] += ei * vj;
                self.a23[i][j] += vj * ehi;
            }
        }
        self.rr += m * m;
        self.n += 1;
    }

    /// `(l, L)` of pair `(i, j)`: the profile log-likelihood and the
    /// least-squares gains, by a Cholesky solve of the 3x3 normal
    /// equations; `None` when they are not positive definite.
    fn eval(&self, i: usize, j: usize) -> Option<(f64, [f64; 3])> {
        let a = [
            [self.s_v[0][i], self.a12[i][j], self.s_v[1][i]],
            [self.a12[i][j], self.s_p[0][j], self.a23[i][j]],
            [self.s_v[1][i], self.a23[i][j], self.s_v[2][i]],
        ];
        let b = [self.s_v[3][i], self.s_p[1][j], self.s_v[4][i]];
        let l = chol3(&a)?;
        let mut z = [0.0; 3];
        for r in 0..3 {
            let mut s = b[r];
            for k in 0..r {
                s -= l[r][k] * z[k];
            }
            z[r] = s / l[r][r];
        }
        let explained = z[0] * z[0] + z[1] * z[1] + z[2] * z[2];
        let mut g = [0.0; 3];
        for r in (0..3).rev() {
            let mut s = z[r];
            for k in r + 1..3 {
                s -= l[k][r] * g[k];
            }
            g[r] = s / l[r][r];
        }
        let n = self.n.max(1) as f64;
        let rss = (self.rr - explained).max(1e-300);
        let ll = -0.5 * n * libm::log(rss / n);
        ll.is_finite().then_some((ll, g))
    }

    /// Evaluates the next `PAIRS_PER_TICK` pairs; `true` when a sweep of
    /// the whole grid just completed.
    fn sweep_step(&mut self) -> bool {
        let total = KV * KP;
        let mut done = false;
        for _ in 0..PAIRS_PER_TICK {
            let (i, j) = (self.cursor / KP, self.cursor % KP);
            self.loglik[i][j] = match self.eval(i, j) {
                Some((l, _)) => l,
                None => {
                    self.refused += 1;
                    f64::NAN
                }
            };
            self.cursor += 1;
            if self.cursor == total {
                self.cursor = 0;
                done = true;
            }
        }
        done
    }

    /// The best evaluated pair `(i, j, l)`; with `tied`, only pairs whose
    /// `dp` equals their `dv` (the 1-D model).
    fn best(&self, tied: bool) -> Option<(usize, usize, f64)> {
        let mut best: Option<(usize, usize, f64)> = None;
        for i in 0..KV {
            for j in 0..KP {
                if tied && self.dp[j] != self.dv[i] {
                    continue;
                }
                let l = self.loglik[i][j];
                if l.is_finite() && best.is_none_or(|b| l > b.2) {
                    best = Some((i, j, l));
                }
            }
        }
        best
    }

    /// Span (max - min, nats) of the profile along `dp` at row `i`.
    fn dp_span(&self, i: usize) -> f64 {
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for l in self.loglik[i].iter().filter(|l| l.is_finite()) {
            lo = lo.min(*l);
            hi = hi.max(*l);
        }
        if hi >= lo {
            hi - lo
        } else {
            0.0
        }
    }

    /// The 95% profile-likelihood intervals `([dv lo, hi], [dp lo, hi])` in
    /// ticks around pair `(i, j)` with `l*`.
    fn intervals(&self, i: usize, j: usize, lstar: f64) -> ([usize; 2], [usize; 2]) {
        let inside = |l: f64| l.is_finite() && l >= lstar - CI_NATS;
        let mut v = [self.dv[i]; 2];
        for (a, row) in self.loglik.iter().enumerate() {
            if inside(row[j]) {
                v = [v[0].min(self.dv[a]), v[1].max(self.dv[a])];
            }
        }
        let mut p = [self.dp[j]; 2];
        for (b, l) in self.loglik[i].iter().enumerate() {
            if inside(*l) {
                p = [p[0].min(self.dp[b]), p[1].max(self.dp[b])];
            }
        }
        (v, p)
    }
}

/// The search's schedule and limits, in ticks (docs/model.md).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SearchSchedule {
    /// The longest delay searched (ticks); residuals start once the history
    /// holds it.
    pub max_delay: usize,
    /// Coarse grid step (ticks).
    pub coarse_step: usize,
    /// Residuals on the coarse grid before its first choice (it takes
    /// every `COARSE_EVERY`-th).
    pub min_coarse: u64,
    /// Gain-phase tick at which the fine grid starts.
    pub fine_start: u64,
    /// Residuals on the fine grid before its choice replaces the coarse one.
    pub min_fine: u64,
}

impl SearchSchedule {
    /// The schedule for a gain phase of `ticks` ticks at `dt_s`: coarse
    /// 10 ms over 0-300 ms; first choice after 5% of the phase; fine grid
    /// from 30% of the phase; its choice after 10% more.
    pub fn for_phase(ticks: u64, dt_s: f64) -> Self {
        let ms = |ms: f64| libm::round(ms * 1e-3 / dt_s).max(1.0) as usize;
        let max_delay = ms(crate::agent::MAX_DELAY_MS).min(crate::agent::HISTORY - 2);
        SearchSchedule {
            max_delay,
            coarse_step: (max_delay / (COARSE - 1)).max(1),
            min_coarse: ticks / 20 / COARSE_EVERY,
            fine_start: (max_delay as u64 + 1).max(ticks * 3 / 10),
            min_fine: ticks / 10,
        }
    }
}

/// What the search found, for the log and the trial's summary.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DelayEvidence {
    /// The chosen visual delay (ticks).
    pub visual: usize,
    /// The chosen proprioceptive delay (ticks; equal to `visual` when not
    /// identified).
    pub proprioceptive: usize,
    /// Whether the data could tell the proprioceptive delay (its coarse
    /// profile spanned more than [`DP_THRESHOLD_NATS`]).
    pub proprioceptive_identified: bool,
    /// That span (nats).
    pub dp_span_nats: f64,
    /// The chosen pair's profile log-likelihood (nats).
    pub loglik: f64,
    /// How much better the choice is than the best pair at another visual
    /// delay (nats): its margin.
    pub margin_nats: f64,
    /// 95% profile-likelihood interval of the visual delay (ticks).
    pub visual_interval: [usize; 2],
    /// Same, proprioceptive.
    pub proprioceptive_interval: [usize; 2],
    /// Residuals in the grid that decided.
    pub residuals: u64,
    /// The least-squares gains at the chosen pair (a cross-check of stage 1).
    pub gains_ls: [f64; 3],
    /// The fitted noise model `var(r) = s0 + kappa2 c^2` (NaN before the fit).
    pub noise_s0: f64,
    /// Its signal-dependent part (the partner's motor-noise gain squared).
    pub noise_kappa2: f64,
    /// Pair evaluations refused (normal equations not positive definite).
    pub pairs_refused: u64,
    /// Whether it came from the fine grid.
    pub fine: bool,
}

/// Running fit of the squared prediction residuals on `[1, c^2]`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct NoiseFit {
    n: f64,
    c2: f64,
    c4: f64,
    r2: f64,
    r2c2: f64,
}

impl NoiseFit {
    fn add(&mut self, residual: f64, c: f64) {
        let (c2, r2) = (c * c, residual * residual);
        self.n += 1.0;
        self.c2 += c2;
        self.c4 += c2 * c2;
        self.r2 += r2;
        self.r2c2 += r2 * c2;
    }

    /// `(s0, kappa2)` by least squares, `s0` floored at 1e-3 of the mean
    /// squared residual, `kappa2` at 0; `None` before `MIN_NOISE_FIT`.
    fn model(&self) -> Option<(f64, f64)> {
        let det = self.n * self.c4 - self.c2 * self.c2;
        if self.n < MIN_NOISE_FIT || det.is_nan() || det <= 0.0 {
            return None;
        }
        let s0 = (self.c4 * self.r2 - self.c2 * self.r2c2) / det;
        let k2 = (self.n * self.r2c2 - self.c2 * self.r2) / det;
        Some((s0.max(1e-3 * self.r2 / self.n), k2.max(0.0)))
    }
}

/// The online delay search of one gain phase (see the module's doc).
#[derive(Clone, Debug, PartialEq)]
pub struct DelaySearch {
    schedule: SearchSchedule,
    coarse: PairGrid<COARSE, COARSE>,
    fine: Option<PairGrid<FINE, FINE>>,
    noise: NoiseFit,
    /// `(v_m, u, c^)` of the previous tick, for its residual.
    prev: Option<(f64, f64, f64)>,
    choice: Option<DelayEvidence>,
    /// Ticks of the gain phase seen.
    k: u64,
    /// Ticks since a missing measurement.
    fresh_run: usize,
    /// Residuals offered to the coarse grid.
    coarse_offered: u64,
}

impl DelaySearch {
    /// A search on `schedule` ([`SearchSchedule::for_phase`]).
    pub fn new(schedule: SearchSchedule) -> Self {
        let step = schedule.coarse_step;
        let grid: [usize; COARSE] = core::array::from_fn(|i| (i * step).min(schedule.max_delay));
        DelaySearch {
            schedule,
            coarse: PairGrid::new(grid, grid),
            fine: None,
            noise: NoiseFit::default(),
            prev: None,
            choice: None,
            k: 0,
            fresh_run: 0,
            coarse_offered: 0,
        }
    }

    /// The current choice, `None` before the first.
    pub fn choice(&self) -> Option<&DelayEvidence> {
        self.choice.as_ref()
    }

    /// Per gain-phase tick, after the measurement is in `ring` (newest =
    /// this tick; `fresh` whether it is new): forms the residual of the
    /// previous tick from `v_m` and the model step `(v_v, v_f)`, adds it to
    /// the active grid, evaluates a few pairs. Then the caller computes the
    /// command and calls [`DelaySearch::commanded`].
    pub fn observe(&mut self, ring: &History<4>, fresh: bool, step: (f64, f64)) {
        self.k += 1;
        if !fresh {
            self.fresh_run = 0;
            self.prev = None;
            return;
        }
        self.fresh_run += 1;
        let v_m = ring.ago(0)[1];
        // The residual needs two fresh velocities in a row (`prev` is reset
        // by a missing one); a regressor may be a gap's predicted sample
        // (the identifier's, docs/model.md "Feedback gaps"), a small error
        // next to dropping every residual for 300 ms after each gap on a
        // loaded rig. No residual before the history
        // holds the longest delay.
        let started = ring.len() > self.schedule.max_delay + 1;
        if let (Some((v_prev, u_prev, c_prev)), true) = (self.prev, started) {
            let (v_v, v_f) = step;
            let r = (v_m - v_v * v_prev) / v_f - u_prev;
            self.add(ring, r, c_prev);
        }
        self.choose();
    }

    /// Per gain-phase tick, last: the robot's command `u` and the stage-1
    /// filter's predicted partner torque `c` for this tick.
    pub fn commanded(&mut self, ring: &History<4>, u: f64, c: f64) {
        self.prev = (self.fresh_run > 0).then(|| (ring.ago(0)[1], u, c));
    }

    fn add(&mut self, ring: &History<4>, r: f64, c_prev: f64) {
        if self.fine.is_none() && self.k >= self.schedule.fine_start {
            if let Some(c) = self.choice {
                self.fine = Some(self.fine_grid(&c));
            }
        }
        match self.fine.as_mut() {
            None => {
                self.coarse_offered += 1;
                if self.coarse_offered % COARSE_EVERY == 0 {
                    self.coarse.add(ring, r, 1.0);
                }
            }
            Some(fine) => {
                // Feasible weighted least squares under var = s0 + k2 c^2.
                let w = match self.noise.model() {
                    Some((s0, k2)) => 1.0 / (s0 + k2 * c_prev * c_prev),
                    None => 1.0,
                };
                if c_prev.is_finite() {
                    self.noise.add(r - c_prev, c_prev);
                }
                if w.is_finite() && w > 0.0 {
                    fine.add(ring, r, w);
                }
            }
        }
    }

    /// The fine grid around the coarse choice: 1-tick steps, +-10; 1-D at
    /// `dp = dv` when the proprioceptive delay is not identified.
    fn fine_grid(&self, c: &DelayEvidence) -> PairGrid<FINE, FINE> {
        let max = self.schedule.max_delay;
        let half = FINE / 2;
        let around = |d: usize| -> [usize; FINE] {
            core::array::from_fn(|i| (d + i).saturating_sub(half).min(max))
        };
        let dv = around(c.visual);
        let dp = if c.proprioceptive_identified {
            around(c.proprioceptive)
        } else {
            dv
        };
        PairGrid::new(dv, dp)
    }

    /// A sweep step on the active grid; at a sweep's end, the new choice.
    fn choose(&mut self) {
        let noise = self.noise.model();
        let refused = self.coarse.refused + self.fine.as_ref().map_or(0, |f| f.refused);
        match self.fine.as_mut() {
            Some(fine) => {
                if fine.sweep_step() && fine.n >= self.schedule.min_fine {
                    let Some(prev) = self.choice else { return };
                    let tied = !prev.proprioceptive_identified;
                    if let Some(c) = evidence(fine, tied, prev, noise, refused, true) {
                        self.choice = Some(c);
                    }
                }
            }
            None => {
                let g = &mut self.coarse;
                if g.sweep_step() && g.n >= self.schedule.min_coarse {
                    let Some((i, _, _)) = g.best(false) else {
                        return;
                    };
                    let span = g.dp_span(i);
                    let base = DelayEvidence {
                        visual: 0,
                        proprioceptive: 0,
                        proprioceptive_identified: span > DP_THRESHOLD_NATS,
                        dp_span_nats: span,
                        loglik: f64::NAN,
                        margin_nats: f64::NAN,
                        visual_interval: [0; 2],
                        proprioceptive_interval: [0; 2],
                        residuals: 0,
                        gains_ls: [f64::NAN; 3],
                        noise_s0: f64::NAN,
                        noise_kappa2: f64::NAN,
                        pairs_refused: 0,
                        fine: false,
                    };
                    let tied = !base.proprioceptive_identified;
                    if let Some(c) = evidence(g, tied, base, None, refused, false) {
                        self.choice = Some(c);
                    }
                }
            }
        }
    }
}

/// The evidence of grid `g`'s best pair (tied to `dp = dv` when `tied`),
/// keeping `base`'s identification of the proprioceptive delay.
fn evidence<const KV: usize, const KP: usize>(
    g: &PairGrid<KV, KP>,
    tied: bool,
    base: DelayEvidence,
    noise: Option<(f64, f64)>,
    refused: u64,
    fine: bool,
) -> Option<DelayEvidence> {
    let (i, j, l) = g.best(tied)?;
    let (_, gains) = g.eval(i, j)?;
    let (vi, pi) = g.intervals(i, j, l);
    // The runner-up at another visual delay.
    let mut other = f64::NEG_INFINITY;
    for (a, row) in g.loglik.iter().enumerate() {
        if g.dv[a] == g.dv[i] {
            continue;
        }
        for (b, x) in row.iter().enumerate() {
            if (!tied || g.dp[b] == g.dv[a]) && x.is_finite() {
                other = other.max(*x);
            }
        }
    }
    let (s0, k2) = noise.unwrap_or((f64::NAN, f64::NAN));
    Some(DelayEvidence {
        visual: g.dv[i],
        proprioceptive: g.dp[j],
        loglik: l,
        margin_nats: l - other,
        visual_interval: vi,
        proprioceptive_interval: if tied { vi } else { pi },
        residuals: g.n,
        gains_ls: gains,
        noise_s0: s0,
        noise_kappa2: k2,
        pairs_refused: refused,
        fine,
        ..base
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_regressor_that_never_moved_is_refused_not_chosen() {
        let mut g = PairGrid::<2, 2>::new([0, 1], [0, 1]);
        let ring = History::<4>::default();
        for _ in 0..10 {
            g.add(&ring, 1.0, 1.0);
        }
        assert_eq!(g.eval(0, 0), None);
        g.sweep_step();
        assert_eq!(g.best(false), None);
        assert!(g.refused >= 4);
    }

    #[test]
    fn the_search_finds_a_known_delay_in_noise_free_data() {
        // -r = 2 * y_eh[k-1-37]: a pure Lhh = 2 partner with d_v = 37 ticks.
        let mut ring = History::<4>::default();
        let s = SearchSchedule::for_phase(20_000, 1e-3);
        let mut search = DelaySearch::new(s);
        let mut eh = [0.0f64; 20_000];
        for (k, e) in eh.iter_mut().enumerate() {
            let t = k as f64 * 1e-3;
            *e = libm::sin(3.0 * t) + 0.5 * libm::sin(7.3 * t);
        }
        // Handle with unit model step: v' = v + f, so r = v' - v - u, u = 0.
        let mut v = 0.0;
        for k in 0..20_000usize {
            let e = libm::sin(1.3 * k as f64 * 1e-3);
            ring.push([e, v, eh[k], 0.0]);
            search.observe(&ring, true, (1.0, 1.0));
            search.commanded(&ring, 0.0, 0.0);
            let f = -2.0 * eh[k.saturating_sub(37)];
            v += f;
        }
        let c = search.choice().expect("a choice");
        assert_eq!(c.visual, 37);
        assert!(c.fine);
        assert!((c.gains_ls[2] - 2.0).abs() < 1e-6, "{:?}", c.gains_ls);
    }
}
