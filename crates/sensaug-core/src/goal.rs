//! Stage 3, goal integration (section "Goal integration"): the agent's
//! estimate of `e = x - tau` from its own noisy view of the target, fused
//! with the partner channel `c = x - tau_h^` (stage 2's posterior), a second
//! view of `e` when both agents track the same target.
//!
//! The channel's error is not white: it spikes at every jump of the target
//! (stage 2 lags) and is small between jumps, so no fixed variance fits it,
//! and judging the channel by its own residuals collapses to whatever the
//! filter already believes. Here the channel's trust adapts online
//! (`docs/model.md`, "Stage 3: the adaptive partner channel"):
//!
//! * a bank of [`MEMBERS`] linear Kalman filters on `s = [e, v]` fed the same
//!   data: member 0 uses the own measurement only, member `i >= 1` also the
//!   channel at a fixed variance `r_i` on a geometric grid ([`channel_grid`]);
//! * each member is scored by its recent one-step predictions of the agent's
//!   **own** position measurement ([`score_step`]), unbiased whatever the
//!   channel's error does; the output is the score-weighted mixture
//!   ([`mixture_weights`]);
//! * a change-point test on the own innovation marks a jump of the target
//!   ([`is_change_point`]): the priors are inflated and the channel is
//!   suspended until it agrees with the own measurement again
//!   ([`channel_agrees`]).
//!
//! `no_std`, allocation-free: one array per field over the members
//! (structure of arrays), so every per-member loop is straight arithmetic.
//! Per tick the caller runs [`GoalIntegrator::update`], reads
//! [`GoalIntegrator::estimate`], computes its command, then
//! [`GoalIntegrator::predict`].

use crate::estimator::{error_transition, EstimatorError, HandleModel, Step};
use crate::linalg::{is_positive_definite, is_positive_semidefinite, is_symmetric};
use crate::ukf::{Arg, Phase, Status, UkfError};
use nalgebra::{SMatrix, Vector2};

/// Members of the bank: own sensing only, and seven channel variances.
pub const MEMBERS: usize = 8;
/// Smallest channel variance as a fraction of `min(q_e, A)`: a member's
/// prior variance is at least `q_e`, so its gain on the channel is
/// `>= 64 / 65`: it follows the channel.
const LOW: f64 = 1.0 / 64.0;
/// Largest channel variance as a multiple of `A`: the channel's gain is
/// about `A / (A + r) <= 1 / 17`: nearly own sensing.
const HIGH: f64 = 16.0;

/// Settings of the adaptive channel (`[robot.stage3.channel]`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ChannelConfig {
    /// Change-point and readmission threshold, in standard deviations of
    /// the own innovation (> 0; 4 by default).
    pub gate: f64,
    /// Score window `n0 (1 + R_e / A)` ticks: `n0` (> 0; 80 by default).
    pub window_n0: f64,
    /// Longest suspension of the channel after a change point (s, > 0;
    /// 0.25 by default).
    pub hold_max_s: f64,
}

impl Default for ChannelConfig {
    fn default() -> Self {
        ChannelConfig {
            gate: 4.0,
            window_n0: 80.0,
            hold_max_s: 0.25,
        }
    }
}

/// Settings of the [`GoalIntegrator`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GoalIntegratorConfig {
    /// Initial `[e, v]` (replaced at each phase start by [`GoalIntegrator::reset`]).
    pub x0: Vector2<f64>,
    /// Initial covariance of every member (also the reset covariance).
    pub P0: SMatrix<f64, 2, 2>,
    /// Per-step process noise; `Q[(0, 0)] = q_e > 0` is the random walk
    /// standing for the unknown target motion.
    pub Q: SMatrix<f64, 2, 2>,
    /// The agent's own sensor noise covariance on `[e, v]`.
    pub R_own: SMatrix<f64, 2, 2>,
    /// The adaptive channel's settings.
    pub channel: ChannelConfig,
}

/// `A` (S1): the steady-state posterior variance of a random walk of
/// per-step variance `q` seen through white noise of variance `r`, i.e. the
/// own-only filter's `P_ee` once settled:
/// `Pm = (q + sqrt(q^2 + 4 q r)) / 2` solves `Pm = Pm r / (Pm + r) + q`, and
/// `A = Pm r / (Pm + r)`.
pub fn steady_state_posterior(q: f64, r: f64) -> f64 {
    let pm = 0.5 * (q + libm::sqrt(q * q + 4.0 * q * r));
    pm * r / (pm + r)
}

/// The channel variances (S2, S3): `r_0 = inf` (own sensing only) and
/// `r_i = r_lo (r_hi / r_lo)^((i - 1) / (K - 1))`, `i = 1..K`, with
/// `r_lo = min(q_e, A) / 64`, `r_hi = 16 A`.
pub fn channel_grid(q_e: f64, A: f64) -> [f64; MEMBERS] {
    let r_lo = LOW * q_e.min(A);
    let r_hi = HIGH * A;
    let step = libm::log(r_hi / r_lo) / (MEMBERS - 2) as f64;
    let mut r = [f64::INFINITY; MEMBERS];
    for (i, ri) in r.iter_mut().enumerate().skip(1) {
        *ri = r_lo * libm::exp(step * (i - 1) as f64);
    }
    r
}

/// The scores' forgetting weight (S4): `alpha = 1 / (n0 (1 + R_e / A))`, one
/// over the window in ticks. Long where the own view is poor relative to
/// what the filter achieves (telling members apart then takes more ticks).
pub fn score_weight(window_n0: f64, R_e: f64, A: f64) -> f64 {
    1.0 / (window_n0 * (1.0 + R_e / A))
}

/// Change point (U2): the own-only member's innovation `nu_0` is beyond
/// `gate` standard deviations, `nu_0^2 > g^2 S0`: the target jumped.
pub fn is_change_point(nu0: f64, S0: f64, gate2: f64) -> bool {
    nu0 * nu0 > gate2 * S0
}

/// Readmission (U4): the channel agrees with the fresh own measurement,
/// `(c - y_e)^2 <= g^2 (R_e + A)`.
pub fn channel_agrees(c: f64, y_e: f64, bound: f64) -> bool {
    (c - y_e) * (c - y_e) <= bound
}

/// One member's score (U6): `J += alpha (nu^2 / S0 - J)`, the exponentially
/// weighted mean of its normalised squared own-position prediction errors.
/// For any member `E[nu^2] = MSE^- + R_e`: the own noise at this tick is
/// independent of a prior built from earlier ticks, whatever the channel's
/// error does.
pub fn score_step(J: f64, nu: f64, inv_S0: f64, alpha: f64) -> f64 {
    J + alpha * (nu * nu * inv_S0 - J)
}

/// The mixture weights (U8): `w_i = exp(-(J_i - min J) / (2 alpha)) / sum`,
/// the Gaussian likelihood of each member's last `1 / alpha` prediction
/// errors at the common variance `S0` (a forgetting-factor multiple-model
/// posterior with a flat prior over the grid).
pub fn mixture_weights(J: &[f64; MEMBERS], alpha: f64) -> [f64; MEMBERS] {
    let j_min = J.iter().fold(f64::INFINITY, |m, &j| m.min(j));
    let scale = 0.5 / alpha;
    let mut w: [f64; MEMBERS] = core::array::from_fn(|i| libm::exp(-(J[i] - j_min) * scale));
    let sum: f64 = w.iter().sum();
    for wi in &mut w {
        *wi /= sum;
    }
    w
}

/// One member's mean `[e, v]` and covariance entries `a = P_ee`, `b = P_ev`,
/// `d = P_vv`, loaded for its update.
#[derive(Clone, Copy, Debug)]
struct Member {
    e: f64,
    v: f64,
    a: f64,
    b: f64,
    d: f64,
}

impl Member {
    /// Kalman update with the own measurement `[y_e, y_v]` of covariance
    /// `R` (any symmetric positive definite 2x2): `S = P + R`,
    /// `K = P S^-1`, `s += K (y - s)`, `P -= K P`.
    #[inline(always)]
    fn own(&mut self, y_e: f64, y_v: f64, R: &[f64; 3]) {
        let (s00, s01, s11) = (self.a + R[0], self.b + R[1], self.d + R[2]);
        let inv_det = 1.0 / (s00 * s11 - s01 * s01);
        let k00 = (self.a * s11 - self.b * s01) * inv_det;
        let k01 = (self.b * s00 - self.a * s01) * inv_det;
        let k10 = (self.b * s11 - self.d * s01) * inv_det;
        let k11 = (self.d * s00 - self.b * s01) * inv_det;
        let (ne, nv) = (y_e - self.e, y_v - self.v);
        self.e += k00 * ne + k01 * nv;
        self.v += k10 * ne + k11 * nv;
        (self.a, self.b, self.d) = (
            self.a - (k00 * self.a + k01 * self.b),
            self.b - (k00 * self.b + k01 * self.d),
            self.d - (k10 * self.b + k11 * self.d),
        );
    }

    /// Scalar Kalman update with the channel `c`, a view of `e` of variance
    /// `r`: `S = a + r`, `K = [a, b] / S`. An infinite `r` is a zero gain.
    #[inline(always)]
    fn channel(&mut self, c: f64, r: f64) {
        let inv = 1.0 / (self.a + r);
        let (k0, k1) = (self.a * inv, self.b * inv);
        let nu = c - self.e;
        self.e += k0 * nu;
        self.v += k1 * nu;
        (self.a, self.b, self.d) = (
            self.a - k0 * self.a,
            self.b - k0 * self.b,
            self.d - k1 * self.b,
        );
    }
}

/// The bank's per-member state (structure of arrays).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Members {
    e: [f64; MEMBERS],
    v: [f64; MEMBERS],
    pee: [f64; MEMBERS],
    pev: [f64; MEMBERS],
    pvv: [f64; MEMBERS],
    score: [f64; MEMBERS],
}

impl Members {
    fn at(x0: Vector2<f64>, P0: &SMatrix<f64, 2, 2>) -> Self {
        Members {
            e: [x0[0]; MEMBERS],
            v: [x0[1]; MEMBERS],
            pee: [P0[(0, 0)]; MEMBERS],
            pev: [P0[(0, 1)]; MEMBERS],
            pvv: [P0[(1, 1)]; MEMBERS],
            score: [0.0; MEMBERS],
        }
    }

    fn is_finite(&self) -> bool {
        [self.e, self.v, self.pee, self.pev, self.pvv, self.score]
            .iter()
            .all(|f| f.iter().all(|x| x.is_finite()))
    }
}

/// What the last update gave (the controller's and the log's view).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Output {
    /// The mixture `[e, v]` (U9).
    estimate: Vector2<f64>,
    /// Its variances `[var e, var v]`: within-member plus between-member spread.
    variance: [f64; 2],
    weights: [f64; MEMBERS],
    change_point: bool,
    admitted: bool,
}

/// Stage 3 with the adaptive partner channel (module docs): member 0 is
/// goal integration without the partner (the "own" estimate, for the
/// comparison), the mixture is goal integration with it.
#[derive(Clone, Debug)]
pub struct GoalIntegrator {
    /// `model`'s step, computed once at set-up.
    step: Step,
    Q: SMatrix<f64, 2, 2>,
    P0: SMatrix<f64, 2, 2>,
    channel: ChannelConfig,
    // Set by `set_own_noise` (S1-S4).
    /// `[R_ee, R_ev, R_vv]` of the own measurement.
    r_own: [f64; 3],
    /// Channel variance per member (`r[0]` infinite).
    r: [f64; MEMBERS],
    /// `A`, the own-only filter's steady-state posterior variance of `e`.
    A: f64,
    alpha: f64,
    gate2: f64,
    /// `g^2 (R_e + A)`: bound on `(c - y_e)^2` to readmit the channel.
    readmit: f64,
    hold_ticks: u32,
    // State.
    m: Members,
    hold: u32,
    out: Output,
}

fn positive(v: f64, name: &'static str) -> Result<(), EstimatorError> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(EstimatorError::InvalidModel(name))
    }
}

/// `R` as `[R_ee, R_ev, R_vv]` after checking it is finite, symmetric and
/// positive semidefinite with `R_ee > 0` (the own view of `e` is noisy; a
/// perfect velocity, `R_vv = 0`, is fine).
fn own_noise(R: &SMatrix<f64, 2, 2>) -> Result<[f64; 3], EstimatorError> {
    if R.iter().any(|x| !x.is_finite()) {
        return Err(EstimatorError::Ukf(UkfError::NonFiniteArgument {
            which: Arg::R,
        }));
    }
    if !is_symmetric(R) {
        return Err(EstimatorError::NotSymmetric(Arg::R));
    }
    if !is_positive_semidefinite(R) {
        return Err(EstimatorError::NotPositiveSemidefinite(Arg::R));
    }
    positive(R[(0, 0)], "stage3.R_e")?;
    Ok([R[(0, 0)], R[(0, 1)], R[(1, 1)]])
}

impl GoalIntegrator {
    /// Set-up: validates the model, the covariances and the channel's
    /// settings, then sets the grid and window for `cfg.R_own`.
    pub fn new(model: HandleModel, cfg: &GoalIntegratorConfig) -> Result<Self, EstimatorError> {
        model.validate()?;
        let finite = |m: &SMatrix<f64, 2, 2>| m.iter().all(|x| x.is_finite());
        let non_finite = |which| EstimatorError::Ukf(UkfError::NonFiniteArgument { which });
        if !cfg.x0.iter().all(|x| x.is_finite()) {
            return Err(non_finite(Arg::X));
        }
        if !finite(&cfg.P0) {
            return Err(non_finite(Arg::P));
        }
        if !finite(&cfg.Q) {
            return Err(non_finite(Arg::Q));
        }
        if !is_symmetric(&cfg.P0) {
            return Err(EstimatorError::NotSymmetric(Arg::P));
        }
        if !is_positive_definite(&cfg.P0) {
            return Err(EstimatorError::Ukf(UkfError::NotPositiveDefinite {
                which: Arg::P,
            }));
        }
        if !is_symmetric(&cfg.Q) {
            return Err(EstimatorError::NotSymmetric(Arg::Q));
        }
        if !is_positive_semidefinite(&cfg.Q) {
            return Err(EstimatorError::NotPositiveSemidefinite(Arg::Q));
        }
        positive(cfg.Q[(0, 0)], "stage3.Q_e")?;
        positive(cfg.channel.gate, "gate")?;
        positive(cfg.channel.window_n0, "window_n0")?;
        positive(cfg.channel.hold_max_s, "hold_max_s")?;
        let mut g = GoalIntegrator {
            step: model.step(),
            Q: cfg.Q,
            P0: cfg.P0,
            channel: cfg.channel,
            r_own: [0.0; 3],
            r: [f64::INFINITY; MEMBERS],
            A: 0.0,
            alpha: 0.0,
            gate2: cfg.channel.gate * cfg.channel.gate,
            readmit: 0.0,
            hold_ticks: libm::round(cfg.channel.hold_max_s / model.dt_s) as u32,
            m: Members::at(cfg.x0, &cfg.P0),
            hold: 0,
            out: Output {
                estimate: cfg.x0,
                variance: [cfg.P0[(0, 0)], cfg.P0[(1, 1)]],
                weights: [1.0 / MEMBERS as f64; MEMBERS],
                change_point: false,
                admitted: false,
            },
        };
        g.set_own_noise(cfg.R_own)?;
        Ok(g)
    }

    /// Set-up or phase start: the own sensor noise covariance on `[e, v]`
    /// (a phase's target-view noise added), and with it `A` (S1), the
    /// channel grid (S2, S3) and the score window (S4). Symmetric positive
    /// semidefinite with `R_ee > 0`; on error nothing changes.
    pub fn set_own_noise(&mut self, R_own: SMatrix<f64, 2, 2>) -> Result<(), EstimatorError> {
        let r_own = own_noise(&R_own)?;
        let q_e = self.Q[(0, 0)];
        let A = steady_state_posterior(q_e, r_own[0]);
        let r = channel_grid(q_e, A);
        let alpha = score_weight(self.channel.window_n0, r_own[0], A);
        if !(A > 0.0 && alpha > 0.0 && r.iter().all(|ri| *ri > 0.0)) {
            // Only a variance ratio beyond f64's range gets here.
            return Err(EstimatorError::InvalidModel("stage3.R_e"));
        }
        self.r_own = r_own;
        self.A = A;
        self.r = r;
        self.alpha = alpha;
        self.readmit = self.gate2 * (r_own[0] + A);
        Ok(())
    }

    /// Phase start: every member at `x0` with `P0`, scores 0, channel
    /// admitted. `x0` must be finite.
    pub fn reset(&mut self, x0: Vector2<f64>) -> Result<(), UkfError> {
        if !x0.iter().all(|x| x.is_finite()) {
            return Err(UkfError::NonFiniteArgument { which: Arg::X });
        }
        self.m = Members::at(x0, &self.P0);
        self.hold = 0;
        Ok(())
    }

    /// Per tick, first (U1-U10): the own measurement `[x - tau, xdot]` and
    /// the partner channel `x - tau_h^` (`None`, or non-finite, when there is
    /// none). A non-finite own measurement, or a step that would overflow, is
    /// an error and changes nothing.
    pub fn update(
        &mut self,
        y_own: &Vector2<f64>,
        channel: Option<f64>,
    ) -> Result<Status, UkfError> {
        if !y_own.iter().all(|x| x.is_finite()) {
            return Err(UkfError::NonFiniteMeasurement);
        }
        let (y_e, y_v) = (y_own[0], y_own[1]);
        let c = channel.filter(|c| c.is_finite());
        let before = (self.m, self.hold);
        // (U1, U2) The own-only member's innovation decides the change point.
        let nu0 = y_e - self.m.e[0];
        let S0 = self.m.pee[0] + self.r_own[0];
        let change_point = is_change_point(nu0, S0, self.gate2);
        // (U3, U4) Inflate every prior by the excess; suspend the channel,
        // or readmit a suspended one that agrees again.
        let inflate = if change_point {
            self.hold = self.hold_ticks;
            nu0 * nu0 - self.gate2 * S0
        } else {
            if self.hold > 0 && c.is_some_and(|c| channel_agrees(c, y_e, self.readmit)) {
                self.hold = 0;
            }
            0.0
        };
        // (U5) A suspended or missing channel is an infinite variance: a zero gain.
        let admitted = c.is_some() && self.hold == 0;
        let (c, r) = match c {
            Some(c) if admitted => (c, self.r),
            _ => (0.0, [f64::INFINITY; MEMBERS]),
        };
        // (U6) Scores skip change points: no member could predict a jump.
        let alpha = if change_point { 0.0 } else { self.alpha };
        let inv_S0 = 1.0 / S0;
        let m = &mut self.m;
        for (i, &r_i) in r.iter().enumerate() {
            m.score[i] = score_step(m.score[i], y_e - m.e[i], inv_S0, alpha);
            // (U7) Own measurement, then the channel at the member's variance.
            let mut k = Member {
                e: m.e[i],
                v: m.v[i],
                a: m.pee[i] + inflate,
                b: m.pev[i],
                d: m.pvv[i],
            };
            k.own(y_e, y_v, &self.r_own);
            k.channel(c, r_i);
            (m.e[i], m.v[i], m.pee[i], m.pev[i], m.pvv[i]) = (k.e, k.v, k.a, k.b, k.d);
        }
        // (U8, U9) The mixture.
        let weights = mixture_weights(&m.score, self.alpha);
        let mean = |x: &[f64; MEMBERS]| weights.iter().zip(x).map(|(w, x)| w * x).sum::<f64>();
        let (e, v) = (mean(&m.e), mean(&m.v));
        let spread = |x: &[f64; MEMBERS], p: &[f64; MEMBERS], at: f64| {
            weights
                .iter()
                .zip(x.iter().zip(p))
                .map(|(w, (x, p))| w * (p + (x - at) * (x - at)))
                .sum::<f64>()
        };
        let variance = [spread(&m.e, &m.pee, e), spread(&m.v, &m.pvv, v)];
        if !(m.is_finite()
            && e.is_finite()
            && v.is_finite()
            && variance.iter().all(|x| x.is_finite()))
        {
            (self.m, self.hold) = before;
            return Err(UkfError::NonFiniteResult {
                phase: Phase::Update,
            });
        }
        // (U10) This tick counts towards the suspension.
        self.hold = self.hold.saturating_sub(1);
        self.out = Output {
            estimate: Vector2::new(e, v),
            variance,
            weights,
            change_point,
            admitted,
        };
        Ok(Status::Nominal)
    }

    /// Per tick, last (P1): every member `s' = F s + b`, `P' = F P F' + Q`,
    /// with the known torque `u` (own plus estimated partner) and the own
    /// target's increment `dtau` (0 when unknown) ([`error_transition`]).
    /// A step that would overflow, or non-finite `u` or `dtau`
    /// ([`UkfError::NonFiniteInput`]), is an error and changes nothing.
    pub fn predict(&mut self, u: f64, dtau: f64) -> Result<Status, UkfError> {
        crate::estimator::finite_inputs(&[u, dtau], "u, dtau")?;
        self.predict_finite(u, dtau)
    }

    /// [`GoalIntegrator::predict`] without the argument check, for the
    /// robot's tick and the replays (see
    /// [`crate::estimator::GainEstimator::predict_finite`]); a non-finite
    /// input still overflows into an error that changes nothing.
    pub(crate) fn predict_finite(&mut self, u: f64, dtau: f64) -> Result<Status, UkfError> {
        let (F, b) = error_transition(&self.step, u, dtau);
        let (f01, f11) = (F[(0, 1)], F[(1, 1)]);
        let (q00, q01, q11) = (self.Q[(0, 0)], self.Q[(0, 1)], self.Q[(1, 1)]);
        let before = self.m;
        let m = &mut self.m;
        for i in 0..MEMBERS {
            let (a, pb, d) = (m.pee[i], m.pev[i], m.pvv[i]);
            m.e[i] += f01 * m.v[i] + b[0];
            m.v[i] = f11 * m.v[i] + b[1];
            m.pee[i] = a + 2.0 * f01 * pb + f01 * f01 * d + q00;
            m.pev[i] = f11 * (pb + f01 * d) + q01;
            m.pvv[i] = f11 * f11 * d + q11;
        }
        if !m.is_finite() {
            self.m = before;
            return Err(UkfError::NonFiniteResult {
                phase: Phase::Predict,
            });
        }
        Ok(Status::Nominal)
    }

    /// `[e, v]` as of the last update: the mixture (`integrated`, goal
    /// integration with the partner) or member 0 (own sensing only, with the
    /// change-point inflation).
    pub fn estimate(&self, integrated: bool) -> Vector2<f64> {
        if integrated {
            self.out.estimate
        } else {
            Vector2::new(self.m.e[0], self.m.v[0])
        }
    }

    /// Variances `[var e, var v]` of [`estimate`](Self::estimate): the
    /// mixture's (within-member plus between-member spread) or member 0's.
    pub fn variance(&self, integrated: bool) -> [f64; 2] {
        if integrated {
            self.out.variance
        } else {
            [self.m.pee[0], self.m.pvv[0]]
        }
    }

    /// The channel's effective variance in the last update,
    /// `1 / sum_i (w_i / r_i)`: infinite when the channel was not fused (none,
    /// suspended, or all weight on member 0).
    pub fn partner_variance(&self) -> f64 {
        if !self.out.admitted {
            return f64::INFINITY;
        }
        let precision: f64 = self
            .out
            .weights
            .iter()
            .zip(&self.r)
            .map(|(w, r)| w / r)
            .sum();
        1.0 / precision
    }

    /// The mixture weights of the last update (member 0 first).
    pub fn weights(&self) -> &[f64; MEMBERS] {
        &self.out.weights
    }

    /// Each member's `e` (posterior after an update, prior after a predict).
    pub fn members(&self) -> &[f64; MEMBERS] {
        &self.m.e
    }

    /// The channel variances of the members (`[0]` infinite).
    pub fn grid(&self) -> &[f64; MEMBERS] {
        &self.r
    }

    /// The last update detected a change point (a jump of the target).
    pub fn change_point(&self) -> bool {
        self.out.change_point
    }

    /// The last update fused the partner channel.
    pub fn channel_admitted(&self) -> bool {
        self.out.admitted
    }
}
