//! Unscented Kalman filter with Van der Merwe scaled sigma points.
//!
//! This reproduces filterpy 2.0.0's `UnscentedKalmanFilter` with
//! `MerweScaledSigmaPoints` (rlabbe/filterpy, `filterpy/kalman/UKF.py`,
//! `sigma_points.py`, `unscented_transform.py`), with additive noise, without
//! heap allocation and without panics. `docs/ukf.md` lists the equations, the
//! filterpy behaviours mirrored on purpose, the places where this filter
//! deliberately differs, and the recovery policy.
//!
//! Dimensions: `N` state size, `M` measurement size, `S = 2N + 1` sigma points
//! (stable Rust cannot write `2 * N + 1` in a type, so `S` is carried and
//! checked at compile time in [`Ukf::new`]). Sigma points are stored as the
//! columns of an `N x S` matrix.
//!
//! When methods run: [`Ukf::new`] and the setters validate everything once at
//! set-up; [`Ukf::predict`] / [`Ukf::update`] are the per-tick calls (no
//! allocation, `O(S N^2)` work, no panics). A per-tick call either commits a
//! complete, finite new state or returns an error; see [`UkfError`] for what
//! each error leaves behind.

use nalgebra::{SMatrix, SVector};

pub use crate::linalg::all_finite;

/// Van der Merwe's scaled sigma point parameters (filterpy
/// `MerweScaledSigmaPoints(n, alpha, beta, kappa)`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MerweParams {
    /// Spread of the sigma points around the mean, `0 < alpha`, typically `1e-3..=1`.
    pub alpha: f64,
    /// Prior knowledge of the distribution; 2 is optimal for a Gaussian.
    pub beta: f64,
    /// Secondary scaling, often `0` or `3 - N`; `N + kappa` must be positive.
    pub kappa: f64,
}

/// Which argument or field a validation error refers to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Arg {
    /// The initial / reset state `x`.
    X,
    /// The initial / reset covariance `P`.
    P,
    /// The process noise covariance `Q`.
    Q,
    /// The measurement noise covariance `R`.
    R,
    /// The covariance that `P` is reset to when it cannot be factored.
    ResetCovariance,
    /// The sigma point parameters `alpha`, `beta`, `kappa`.
    SigmaParams,
    /// The control sequence given to [`Ukf::run`].
    Controls,
    /// The measurement sequence given to [`Ukf::run`].
    Measurements,
    /// The state output slice of [`Ukf::run`].
    XsOut,
    /// The covariance-diagonal output slice of [`Ukf::run`].
    PdiagOut,
}

impl Arg {
    /// The argument's name as the Python API spells it.
    pub fn name(self) -> &'static str {
        match self {
            Arg::X => "x",
            Arg::P => "P",
            Arg::Q => "Q",
            Arg::R => "R",
            Arg::ResetCovariance => "P_reset",
            Arg::SigmaParams => "alpha/beta/kappa",
            Arg::Controls => "u",
            Arg::Measurements => "z",
            Arg::XsOut => "xs_out",
            Arg::PdiagOut => "pdiag_out",
        }
    }
}

/// Where in a step a Cholesky factorisation was needed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    /// Sigma points of the posterior `(x, P)` at the start of `predict`.
    PredictSigmaPoints,
    /// Sigma points re-drawn from the prior `(x_prior, P_prior)` at the end of
    /// `predict` (filterpy's re-draw, used by the following `update`).
    PredictRedraw,
    /// Sigma points drawn in `update` when no `predict` preceded it.
    UpdateSigmaPoints,
    /// The innovation covariance `S` in `update`.
    InnovationCovariance,
}

/// Which half of a step a [`StepError`] came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phase {
    /// [`Ukf::predict`].
    Predict,
    /// [`Ukf::update`].
    Update,
}

/// Errors of the UKF. Set-up errors name the argument; per-step errors say
/// what the filter state is afterwards.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum UkfError {
    /// Set-up: an argument contains NaN or +-inf.
    NonFiniteArgument {
        /// The offending argument.
        which: Arg,
    },
    /// Set-up: a covariance is not positive definite (its Cholesky factor,
    /// scaled by `N + lambda`, does not exist).
    NotPositiveDefinite {
        /// The offending argument.
        which: Arg,
    },
    /// Set-up: the named sigma-point parameter is not finite, `alpha <= 0`,
    /// `N + kappa <= 0`, or `alpha^2 (N + kappa)` (so `N + lambda`) or the
    /// weights under- or overflow (named `alpha`).
    InvalidSigmaParams {
        /// `"alpha"`, `"beta"` or `"kappa"`.
        name: &'static str,
    },
    /// Set-up of a model: a model parameter is out of range.
    InvalidModelParameter {
        /// The parameter's name.
        name: &'static str,
    },
    /// Step: the measurement `z` contains NaN or +-inf. State unchanged.
    NonFiniteMeasurement,
    /// Step: an input of an estimator's predict (the torque, a target's
    /// increment) is NaN or +-inf: a caller's mistake, so nothing ran and
    /// nothing is counted. State unchanged.
    NonFiniteInput {
        /// The predict's inputs, as the Python API names them.
        names: &'static str,
    },
    /// Step: the process function returned NaN or +-inf. State unchanged.
    NonFiniteProcess,
    /// Step: the measurement function returned NaN or +-inf. State unchanged.
    NonFiniteMeasurementModel,
    /// Step: all inputs were finite but the new `x` or `P` (or `S`)
    /// overflowed. State unchanged.
    NonFiniteResult {
        /// The half of the step that overflowed.
        phase: Phase,
    },
    /// Step: a Cholesky factorisation failed even after re-symmetrising, so
    /// `P` was reset to the reset covariance (default: the initial `P0`) and
    /// [`Recoveries::covariance_resets`] was incremented. The filter is valid.
    /// In `predict` the step was completed with the reset covariance; after a
    /// failure of `S` in `update` the measurement was discarded (`x` kept).
    CovarianceReset {
        /// Which factorisation failed.
        stage: Stage,
    },
    /// [`Ukf::run`]: an input slice has the wrong length.
    InputLength {
        /// The offending input.
        which: Arg,
        /// Required length.
        needed: usize,
        /// Given length.
        got: usize,
    },
    /// [`Ukf::run`]: an output slice is too short.
    OutputTooShort {
        /// The offending output.
        which: Arg,
        /// Required length.
        needed: usize,
        /// Given length.
        got: usize,
    },
}

impl Stage {
    /// The stage's name in snake case, as status strings and messages spell it.
    pub fn name(self) -> &'static str {
        match self {
            Stage::PredictSigmaPoints => "predict_sigma_points",
            Stage::PredictRedraw => "predict_redraw",
            Stage::UpdateSigmaPoints => "update_sigma_points",
            Stage::InnovationCovariance => "innovation_covariance",
        }
    }
}

impl Phase {
    /// `"predict"` or `"update"`.
    pub fn name(self) -> &'static str {
        match self {
            Phase::Predict => "predict",
            Phase::Update => "update",
        }
    }
}

impl crate::CoreError for UkfError {
    /// A step the filter rejected (state unchanged) or repaired (`P`
    /// reset) is a step failure: the numbers went wrong, not an argument.
    fn kind(&self) -> crate::ErrorKind {
        match self {
            UkfError::NonFiniteMeasurement
            | UkfError::NonFiniteProcess
            | UkfError::NonFiniteMeasurementModel
            | UkfError::NonFiniteResult { .. }
            | UkfError::CovarianceReset { .. } => crate::ErrorKind::StepFailure,
            _ => crate::ErrorKind::Argument,
        }
    }
}

impl core::fmt::Display for UkfError {
    /// Set-up errors: the argument first (as [`Arg::name`] spells it), then
    /// what is wrong and how to fix it. Step errors: what was rejected and
    /// the filter's state afterwards.
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match *self {
            UkfError::NonFiniteArgument { which } => {
                write!(f, "{}: must be finite (no NaN or inf)", which.name())
            }
            UkfError::NotPositiveDefinite { which } => write!(
                f,
                "{0}: must be symmetric positive definite (the Cholesky factor of \
                 (n + lambda) * {0} does not exist); raise its diagonal",
                which.name()
            ),
            UkfError::InvalidSigmaParams { name } => f.write_str(match name {
                "beta" => "beta: must be finite (2 is optimal for a Gaussian prior)",
                "kappa" => "kappa: must be finite with n + kappa > 0 (0 or 3 - n is usual)",
                _ => {
                    "alpha: must be finite and > 0, with alpha^2 (n + kappa) and the sigma-point \
                     weights finite and > 0 (1e-3 to 1 is usual)"
                }
            }),
            UkfError::InvalidModelParameter { name } => write!(
                f,
                "{name}: out of range (dt_s, length_m, mass_kg > 0; damping_nms >= 0; all finite)"
            ),
            UkfError::NonFiniteMeasurement => {
                f.write_str("z: must be finite; update rejected, state unchanged")
            }
            UkfError::NonFiniteInput { names } => {
                write!(f, "{names}: must be finite; predict not run")
            }
            UkfError::NonFiniteProcess => {
                f.write_str("process model returned NaN/inf; predict rejected, state unchanged")
            }
            UkfError::NonFiniteMeasurementModel => {
                f.write_str("measurement model returned NaN/inf; update rejected, state unchanged")
            }
            UkfError::NonFiniteResult { phase } => write!(
                f,
                "{} overflowed to NaN/inf; rejected, state unchanged",
                phase.name()
            ),
            UkfError::CovarianceReset { stage } => write!(
                f,
                "covariance not positive definite at {} even after re-symmetrising; P reset to \
                 the reset covariance (filter valid)",
                stage.name()
            ),
            UkfError::InputLength { which, needed, got } => {
                write!(f, "{}: expected {needed} values, got {got}", which.name())
            }
            UkfError::OutputTooShort { which, needed, got } => write!(
                f,
                "{}: needs room for {needed} values, has {got}",
                which.name()
            ),
        }
    }
}

/// Outcome of a successful step: never silent about repairs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[must_use]
pub enum Status {
    /// Every factorisation succeeded first time.
    Nominal,
    /// A factorisation failed, the matrix was re-symmetrised as
    /// `(A + A') / 2`, and the retry succeeded. Counted in
    /// [`Recoveries::resymmetrised`].
    Resymmetrised {
        /// Which factorisation needed it (the last one if several did).
        stage: Stage,
    },
}

impl core::fmt::Display for Status {
    /// `nominal`, or `resymmetrised:<stage>`.
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Status::Nominal => f.write_str("nominal"),
            Status::Resymmetrised { stage } => write!(f, "resymmetrised:{}", stage.name()),
        }
    }
}

/// Counters of everything unusual, readable with [`Ukf::recoveries`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Recoveries {
    /// Factorisations that succeeded only after re-symmetrising.
    pub resymmetrised: u64,
    /// Times `P` was reset to the reset covariance.
    pub covariance_resets: u64,
    /// Calls rejected with the state unchanged (non-finite input or result).
    pub rejected: u64,
    /// Completed `predict` calls (including those that reset `P`).
    pub predicts: u64,
    /// Completed `update` calls (measurement applied).
    pub updates: u64,
}

impl Recoveries {
    /// The counters' names: their fields', in declaration order.
    pub const NAMES: [&'static str; 5] = [
        "resymmetrised",
        "covariance_resets",
        "rejected",
        "predicts",
        "updates",
    ];

    /// Each counter by name ([`Recoveries::NAMES`]).
    pub fn named(&self) -> impl Iterator<Item = (&'static str, u64)> {
        let r = self;
        let values = [
            r.resymmetrised,
            r.covariance_resets,
            r.rejected,
            r.predicts,
            r.updates,
        ];
        Self::NAMES.into_iter().zip(values)
    }
}

/// The first failing step of a [`Ukf::run`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StepError {
    /// Step index `k`.
    pub step: usize,
    /// Predict or update.
    pub phase: Phase,
    /// The error that call returned.
    pub error: UkfError,
}

/// Summary of a [`Ukf::run`]: the trial never stops early; each step error has
/// already been handled by the filter (state restored or `P` reset).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RunReport {
    /// Steps run (= number of controls).
    pub steps: usize,
    /// Calls that returned `Err` (rejections and covariance resets).
    pub errors: usize,
    /// The first of them, if any.
    pub first_error: Option<StepError>,
}

impl core::fmt::Display for RunReport {
    /// How many steps failed and the first failure.
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self.first_error {
            Some(first) => write!(
                f,
                "{} step error(s); first at step {} ({}): {}",
                self.errors,
                first.step,
                first.phase.name(),
                first.error
            ),
            None => f.write_str("no step error"),
        }
    }
}

/// `lambda = alpha^2 (n + kappa) - n` (Van der Merwe 2004, scaled unscented
/// transform), computed in filterpy's order.
pub fn merwe_lambda(n: usize, p: &MerweParams) -> f64 {
    let n = n as f64;
    p.alpha * p.alpha * (n + p.kappa) - n
}

/// Merwe weights: `Wm_0 = lambda / (n + lambda)`,
/// `Wc_0 = Wm_0 + (1 - alpha^2 + beta)`, `Wm_i = Wc_i = 1 / (2 (n + lambda))`
/// for `i = 1..2n`. Returns `(Wm, Wc)`.
pub fn merwe_weights<const S: usize>(
    n: usize,
    p: &MerweParams,
) -> (SVector<f64, S>, SVector<f64, S>) {
    let lambda = merwe_lambda(n, p);
    let c = 0.5 / (n as f64 + lambda);
    let mut Wm = SVector::<f64, S>::repeat(c);
    let mut Wc = SVector::<f64, S>::repeat(c);
    if S > 0 {
        Wm[0] = lambda / (n as f64 + lambda);
        Wc[0] = lambda / (n as f64 + lambda) + (1.0 - p.alpha * p.alpha + p.beta);
    }
    (Wm, Wc)
}

/// Scaled Cholesky factor: lower `L` with `L L' = c P`, reading only the
/// upper triangle of `P` (as scipy's `cholesky(c P)` does, whose upper factor
/// is `U = L'`). `None` if `c P` is not positive definite or anything is not
/// finite.
///
/// `a_ij = c P_ji` for `i >= j` (upper triangle of `P`, as LAPACK
/// `potrf(uplo='U')` reads it; column-major, so `P_ji` is `p[i N + j]`),
/// then [`cholesky_in_place`]. Written out so the tick needs no transpose and
/// no copy of `c P`.
#[inline(always)]
pub fn scaled_cholesky<const N: usize>(
    P: &SMatrix<f64, N, N>,
    c: f64,
) -> Option<SMatrix<f64, N, N>> {
    let p = P.as_slice();
    let mut l = [[0.0f64; N]; N];
    for (j, col) in l.iter_mut().enumerate() {
        for i in j..N {
            col[i] = p[i * N + j] * c;
        }
    }
    cholesky_in_place(l)
}

/// Cholesky factor `L` with `L L' = A` of a symmetric `A`, reading only its
/// lower triangle (as nalgebra's `Cholesky::new` does), used for the
/// innovation covariance `S`. `None` if `A` is not positive definite or
/// anything is not finite.
#[inline(always)]
pub fn cholesky_lower<const M: usize>(A: &SMatrix<f64, M, M>) -> Option<SMatrix<f64, M, M>> {
    let a = A.as_slice();
    let mut l = [[0.0f64; M]; M];
    for (j, col) in l.iter_mut().enumerate() {
        col[j..].copy_from_slice(&a[j * M + j..(j + 1) * M]);
    }
    cholesky_in_place(l)
}

/// The factorisation itself, on the lower triangle `a_ij` (`i >= j`) of
/// `A` given as columns `l[j][i]`; entries above the diagonal are ignored
/// and returned as 0.
///
/// Column by column (left-looking, the operation order of nalgebra's
/// `Cholesky`), for `i >= j`: `a_ij <- a_ij - sum_{k<j} L_jk L_ik`,
/// `L_jj = sqrt(a_jj)`, `L_ij = a_ij (1 / L_jj)`: one division per column,
/// not per entry (the divider's throughput, not the arithmetic, bounded the
/// tick; the factor differs from nalgebra's by rounding only, Rust test
/// `innovation_factor_and_gain_equal_nalgebra`). Non-finite input needs no
/// separate pass: a pivot that is NaN, zero, negative or infinite is
/// refused, and every `L_ij` below the diagonal enters pivot `i` as
/// `-L_ij^2`, so a NaN or infinite entry makes that pivot NaN or `-inf`.
#[inline(always)]
fn cholesky_in_place<const N: usize>(mut l: [[f64; N]; N]) -> Option<SMatrix<f64, N, N>> {
    for j in 0..N {
        let (done, rest) = l.split_at_mut(j);
        let col = &mut rest[0];
        for lk in done.iter() {
            // a_ij += (-L_jk) L_ik for i >= j, in nalgebra's order (axpy)
            let f = -lk[j];
            for i in j..N {
                col[i] += f * lk[i];
            }
        }
        let d = col[j];
        if !d.is_finite() || d <= 0.0 {
            return None;
        }
        let d = libm::sqrt(d);
        col[j] = d;
        let inv = 1.0 / d;
        for v in col[j + 1..].iter_mut() {
            *v *= inv;
        }
    }
    Some(SMatrix::<f64, N, N>::from_data(nalgebra::ArrayStorage(l)))
}

/// Merwe sigma points from the factor `L` of `(n + lambda) P`:
/// `chi_0 = x`, `chi_{1+k} = x + L e_k`, `chi_{1+n+k} = x - L e_k`
/// (columns of `L` = rows of scipy's upper factor, filterpy's `U[k]`).
pub fn sigma_points<const N: usize, const S: usize>(
    x: &SVector<f64, N>,
    L: &SMatrix<f64, N, N>,
) -> SMatrix<f64, N, S> {
    let mut chi = SMatrix::<f64, N, S>::zeros();
    for i in 0..S {
        let col = if i == 0 {
            *x
        } else if i <= N {
            x + L.column(i - 1)
        } else if i <= 2 * N {
            x - L.column(i - 1 - N)
        } else {
            *x
        };
        chi.set_column(i, &col);
    }
    chi
}

/// Unscented mean: `x_bar = sum_i Wm_i chi_i`.
pub fn unscented_mean<const D: usize, const S: usize>(
    Wm: &SVector<f64, S>,
    chi: &SMatrix<f64, D, S>,
) -> SVector<f64, D> {
    chi * Wm
}

/// Unscented covariance with additive noise:
/// `P = sum_i Wc_i (chi_i - x_bar)(chi_i - x_bar)' + Q`.
pub fn unscented_covariance<const D: usize, const S: usize>(
    Wc: &SVector<f64, S>,
    chi: &SMatrix<f64, D, S>,
    mean: &SVector<f64, D>,
    noise: &SMatrix<f64, D, D>,
) -> SMatrix<f64, D, D> {
    // Rank-1 updates P += (Wc_i d) d', column by column on plain arrays (so
    // the compiler unrolls and vectorises them), then the upper triangle is
    // mirrored: (Wc_i d_j) d_k and (Wc_i d_k) d_j differ in the last bit, and
    // the factorisation that follows reads the upper triangle.
    let mut cols = [[0.0f64; D]; D];
    let m = mean.as_slice();
    for (c, w) in chi.as_slice().chunks_exact(D).zip(Wc.as_slice()) {
        let mut d = [0.0f64; D];
        let mut wd = [0.0f64; D];
        for j in 0..D {
            d[j] = c[j] - m[j];
            wd[j] = w * d[j];
        }
        for (col, dk) in cols.iter_mut().zip(d) {
            for (p, wdj) in col.iter_mut().zip(wd) {
                *p += wdj * dk;
            }
        }
    }
    let mut P = SMatrix::<f64, D, D>::zeros();
    for k in 0..D {
        for j in 0..=k {
            P[(j, k)] = cols[k][j];
            P[(k, j)] = cols[k][j];
        }
    }
    P + noise
}

/// Cross covariance: `Pxz = sum_i Wc_i (chi_i - x)(Z_i - z_bar)'`, with `x`
/// the filter's prior mean (filterpy's `cross_variance(self.x, zp, ...)`).
pub fn cross_covariance<const N: usize, const M: usize, const S: usize>(
    Wc: &SVector<f64, S>,
    chi: &SMatrix<f64, N, S>,
    x: &SVector<f64, N>,
    Z: &SMatrix<f64, M, S>,
    z_bar: &SVector<f64, M>,
) -> SMatrix<f64, N, M> {
    let mut Pxz = SMatrix::<f64, N, M>::zeros();
    for i in 0..S {
        let dx = chi.column(i) - x;
        let dz = Z.column(i) - z_bar;
        Pxz += (dx * dz.transpose()) * Wc[i];
    }
    Pxz
}

/// Kalman gain `K = Pxz S^-1`, solved, not inverted: `S K' = Pxz'` with
/// the lower Cholesky factor `L` of the symmetric `S` ([`cholesky_lower`]),
/// row `r` of `K` by forward substitution `L w = Pxz_r'` then back
/// substitution `L' k = w`, in the operation order of nalgebra's
/// `Cholesky::solve_mut` (column-wise `axpy` forward, ascending dot
/// products backward), dividing by `L_ii` as a multiplication by `1 / L_ii`
/// computed once for all rows (`M` divisions instead of `2 N M`; equal to
/// nalgebra's up to rounding).
#[inline(always)]
pub fn kalman_gain<const N: usize, const M: usize>(
    Pxz: &SMatrix<f64, N, M>,
    L: &SMatrix<f64, M, M>,
) -> SMatrix<f64, N, M> {
    let mut K = SMatrix::<f64, N, M>::zeros();
    let inv: [f64; M] = core::array::from_fn(|i| 1.0 / L[(i, i)]);
    for r in 0..N {
        let mut b = [0.0f64; M];
        for (m, bm) in b.iter_mut().enumerate() {
            *bm = Pxz[(r, m)];
        }
        // L w = b: w_i = b_i / L_ii, b_k += (-w_i) L_ki for k > i
        for i in 0..M {
            let w = b[i] * inv[i];
            b[i] = w;
            for k in i + 1..M {
                b[k] += -w * L[(k, i)];
            }
        }
        // L' k = w: k_i = (w_i - sum_{j>i} L_ji k_j) / L_ii
        for i in (0..M).rev() {
            let mut dot = 0.0;
            for j in i + 1..M {
                dot += L[(j, i)] * b[j];
            }
            b[i] = (b[i] - dot) * inv[i];
        }
        for (m, bm) in b.iter().enumerate() {
            K[(r, m)] = *bm;
        }
    }
    K
}

/// Posterior mean: `x+ = x- + K y` with innovation `y = z - z_bar`.
pub fn posterior_mean<const N: usize, const M: usize>(
    x: &SVector<f64, N>,
    K: &SMatrix<f64, N, M>,
    y: &SVector<f64, M>,
) -> SVector<f64, N> {
    x + K * y
}

/// Posterior covariance as filterpy computes it: `P+ = P- - K S K'` (not
/// symmetrised, not Joseph form).
pub fn posterior_covariance<const N: usize, const M: usize>(
    P: &SMatrix<f64, N, N>,
    K: &SMatrix<f64, N, M>,
    S: &SMatrix<f64, M, M>,
) -> SMatrix<f64, N, N> {
    P - K * (S * K.transpose())
}

/// Posterior covariance of a linear (selection) update, `P+ = P- - K Pxz'`
/// (equal to `P- - K S K'` since `K S = Pxz`): the symmetric correction
/// `K Pxz'` is computed on one triangle (`i <= j`) and mirrored.
pub fn posterior_covariance_symmetric<const N: usize, const M: usize>(
    P: &SMatrix<f64, N, N>,
    K: &SMatrix<f64, N, M>,
    Pxz: &SMatrix<f64, N, M>,
) -> SMatrix<f64, N, N> {
    let mut out = *P;
    for j in 0..N {
        for i in 0..=j {
            let mut c = 0.0;
            for m in 0..M {
                c += K[(i, m)] * Pxz[(j, m)];
            }
            out[(i, j)] -= c;
            if i != j {
                out[(j, i)] -= c;
            }
        }
    }
    out
}

/// A measurement that reads state entries: `h(x) = [x[i_0], ..., x[i_{M-1}]]`,
/// i.e. `H x` with `H` the rows `i_0..i_{M-1}` of the `N x N` identity
/// (an index may repeat). [`Ukf::update_selected`] exploits it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Selection<const N: usize, const M: usize> {
    indices: [usize; M],
}

impl<const N: usize, const M: usize> Selection<N, M> {
    /// `None` if an index is `>= N`. In a `const` item, a bad index is a
    /// compile error (see the estimators' measurement selections).
    pub const fn new(indices: [usize; M]) -> Option<Self> {
        let mut k = 0;
        while k < M {
            if indices[k] >= N {
                return None;
            }
            k += 1;
        }
        Some(Self { indices })
    }

    /// The state indices read, in measurement order.
    pub fn indices(&self) -> &[usize; M] {
        &self.indices
    }

    /// `h(x) = H x`.
    pub fn apply(&self, x: &SVector<f64, N>) -> SVector<f64, M> {
        SVector::<f64, M>::from_fn(|k, _| x[self.indices[k]])
    }
}

/// A bilinear form of the state, `q(z) = sum_j z[a_j] z[b_j]` (a pair may
/// repeat an index: `z[a]^2`). The estimators' nonlinearity is one:
/// the partner's torque `Lhx e + Lhv v + Lhh e_h`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BilinearForm<const N: usize, const K: usize> {
    pairs: [(usize, usize); K],
}

impl<const N: usize, const K: usize> BilinearForm<N, K> {
    /// `None` if an index is `>= N`. In a `const` item, a bad index is a
    /// compile error (see the estimators' process).
    pub const fn new(pairs: [(usize, usize); K]) -> Option<Self> {
        let mut j = 0;
        while j < K {
            if pairs[j].0 >= N || pairs[j].1 >= N {
                return None;
            }
            j += 1;
        }
        Some(Self { pairs })
    }

    /// The index pairs `(a_j, b_j)`.
    pub fn pairs(&self) -> &[(usize, usize); K] {
        &self.pairs
    }

    /// `q(z) = sum_j z[a_j] z[b_j]`.
    pub fn eval(&self, z: &SVector<f64, N>) -> f64 {
        self.pairs.iter().map(|&(a, b)| z[a] * z[b]).sum()
    }

    /// The gradient `dq/dz`: `z[b_j]` added at `a_j`, `z[a_j]` at `b_j`.
    pub fn gradient(&self, z: &SVector<f64, N>) -> SVector<f64, N> {
        let mut g = SVector::<f64, N>::zeros();
        for &(a, b) in &self.pairs {
            g[a] += z[b];
            g[b] += z[a];
        }
        g
    }
}

/// A process that moves the first `R` of `N` states by an affine map plus
/// one bilinear term and keeps states `R..N` constant:
/// `f_t(z) = F z + b + g q(z)` for the moving rows `t < R`, `f_c(z) = z_c`
/// for the rest. [`Ukf::predict_bilinear`] propagates it in closed form.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BilinearProcess<const N: usize, const R: usize, const K: usize> {
    /// Linear part of the moving rows (`R x N`).
    pub F: SMatrix<f64, R, N>,
    /// Constant part of the moving rows.
    pub b: SVector<f64, R>,
    /// How the bilinear term enters each moving row.
    pub g: SVector<f64, R>,
    /// The bilinear term `q`.
    pub q: BilinearForm<N, K>,
}

impl<const N: usize, const R: usize, const K: usize> BilinearProcess<N, R, K> {
    /// The moving rows `f_t(z) = F z + b + g q(z)`.
    pub fn moving(&self, z: &SVector<f64, N>) -> SVector<f64, R> {
        self.F * z + self.b + self.g * self.q.eval(z)
    }

    /// The whole next state: the moving rows, then `z_c` for `c >= R`.
    pub fn apply(&self, z: &SVector<f64, N>) -> SVector<f64, N> {
        let mut next = *z;
        next.fixed_rows_mut::<R>(0).copy_from(&self.moving(z));
        next
    }
}

/// Which posterior covariance formula an update uses.
#[derive(Clone, Copy)]
enum Posterior {
    /// `P - K S K'`, filterpy's (generic `h`).
    Filterpy,
    /// `P - K Pxz'` on one triangle (selection `h`).
    Symmetric,
}

/// `chi_f,i = f(chi_i)` for the sigma points of `(x, L)` (`sigma_points`),
/// formed one at a time: `chi_0 = x`, `chi_{1+k} = x + L e_k`,
/// `chi_{1+N+k} = x - L e_k`. `None` if any output is not finite.
#[inline(always)]
fn propagate<const N: usize, const R: usize, const S: usize>(
    x: &SVector<f64, N>,
    L: &SMatrix<f64, N, N>,
    f: &mut impl FnMut(&SVector<f64, N>) -> SVector<f64, R>,
) -> Option<SMatrix<f64, R, S>> {
    let mut chi_f = SMatrix::<f64, R, S>::zeros();
    chi_f.set_column(0, &f(x));
    for k in 0..N {
        chi_f.set_column(1 + k, &f(&(x + L.column(k))));
        chi_f.set_column(1 + N + k, &f(&(x - L.column(k))));
    }
    all_finite(&chi_f).then_some(chi_f)
}

/// `A` as the factorisation reads it: its upper triangle, mirrored into the
/// lower (`a_ij <- a_ji` for `i > j`).
#[inline(always)]
fn mirror_upper<const D: usize>(A: &mut SMatrix<f64, D, D>) {
    for j in 0..D {
        for i in j + 1..D {
            A[(i, j)] = A[(j, i)];
        }
    }
}

/// Re-symmetrisation used by the recovery policy: `A <- (A + A') / 2`.
pub fn symmetrise<const D: usize>(A: &SMatrix<f64, D, D>) -> SMatrix<f64, D, D> {
    (A + A.transpose()) * 0.5
}

/// Where the sigma points of the next `update` come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum UpdatePoints {
    /// None belong to the current `(x, P)` (first call, after an update or a
    /// reset): the update draws them (stage `UpdateSigmaPoints`).
    Stale,
    /// Re-drawn at the end of `predict` (filterpy's re-draw): the stored
    /// centre and factor.
    Drawn,
    /// `predict_bilinear` or `predict_linear` left filterpy's re-draw to the
    /// update that needs it: the generic update draws from `(x-, P-)`
    /// (stage `PredictRedraw`), the selection update needs no points and no
    /// factor.
    Deferred,
}

/// Recovery bookkeeping of one call, committed only with the new state.
#[derive(Default)]
struct Pending {
    resymmetrised: u64,
    resets: u64,
    last_resym: Option<Stage>,
    last_reset: Option<Stage>,
}

/// Unscented Kalman filter: `N` states, `M` measurements, `S = 2N + 1` sigma
/// points. Process and measurement functions are passed per call, so a known
/// control input is simply captured by the closure.
#[derive(Clone, Debug)]
pub struct Ukf<const N: usize, const M: usize, const S: usize> {
    x: SVector<f64, N>,
    P: SMatrix<f64, N, N>,
    Q: SMatrix<f64, N, N>,
    R: SMatrix<f64, M, M>,
    P_reset: SMatrix<f64, N, N>,
    L_reset: SMatrix<f64, N, N>,
    c: f64,
    Wm: SVector<f64, S>,
    Wc: SVector<f64, S>,
    // The sigma points re-drawn at the end of `predict`, kept as their
    // centre and scaled factor (`sigmas_f()` forms them): the selection
    // update never needs the points themselves.
    sigma_center: SVector<f64, N>,
    sigma_factor: SMatrix<f64, N, N>,
    update_points: UpdatePoints,
    x_prior: SVector<f64, N>,
    P_prior: SMatrix<f64, N, N>,
    x_post: SVector<f64, N>,
    P_post: SMatrix<f64, N, N>,
    y: SVector<f64, M>,
    S_innov: SMatrix<f64, M, M>,
    K: SMatrix<f64, N, M>,
    recoveries: Recoveries,
}

impl<const N: usize, const M: usize, const S: usize> Ukf<N, M, S> {
    /// Set-up: validates everything once. `P0` must be positive definite
    /// (after scaling by `N + lambda`) and is also the reset covariance.
    /// `Q` and `R` must be finite (their definiteness is not required, as in
    /// filterpy; an indefinite sum shows up as a recovery later).
    pub fn new(
        x0: SVector<f64, N>,
        P0: SMatrix<f64, N, N>,
        Q: SMatrix<f64, N, N>,
        R: SMatrix<f64, M, M>,
        params: MerweParams,
    ) -> Result<Self, UkfError> {
        const { assert!(S == 2 * N + 1, "S must equal 2 * N + 1") };
        const { assert!(N >= 1 && M >= 1, "N and M must be at least 1") };
        let sigma = |name| Err(UkfError::InvalidSigmaParams { name });
        if !(params.alpha.is_finite() && params.alpha > 0.0) {
            return sigma("alpha");
        }
        if !params.beta.is_finite() {
            return sigma("beta");
        }
        if !(params.kappa.is_finite() && N as f64 + params.kappa > 0.0) {
            return sigma("kappa");
        }
        let c = merwe_lambda(N, &params) + N as f64;
        let (Wm, Wc) = merwe_weights::<S>(N, &params);
        if !(c > 0.0 && c.is_finite() && all_finite(&Wm) && all_finite(&Wc)) {
            return sigma("alpha");
        }
        if !all_finite(&x0) {
            return Err(UkfError::NonFiniteArgument { which: Arg::X });
        }
        if !all_finite(&Q) {
            return Err(UkfError::NonFiniteArgument { which: Arg::Q });
        }
        if !all_finite(&R) {
            return Err(UkfError::NonFiniteArgument { which: Arg::R });
        }
        let L0 = Self::check_covariance(&P0, c, Arg::P)?;
        Ok(Self {
            x: x0,
            P: P0,
            Q,
            R,
            P_reset: P0,
            L_reset: L0,
            c,
            Wm,
            Wc,
            // filterpy starts sigmas_f as zeros; we mark them stale instead
            // (see `update`).
            sigma_center: SVector::zeros(),
            sigma_factor: SMatrix::zeros(),
            update_points: UpdatePoints::Stale,
            x_prior: x0,
            P_prior: P0,
            x_post: x0,
            P_post: P0,
            y: SVector::zeros(),
            S_innov: SMatrix::zeros(),
            K: SMatrix::zeros(),
            recoveries: Recoveries::default(),
        })
    }

    fn check_covariance(
        P: &SMatrix<f64, N, N>,
        c: f64,
        which: Arg,
    ) -> Result<SMatrix<f64, N, N>, UkfError> {
        if !all_finite(P) {
            return Err(UkfError::NonFiniteArgument { which });
        }
        scaled_cholesky(P, c).ok_or(UkfError::NotPositiveDefinite { which })
    }

    /// Set-up: replace `x` and `P` (posterior, prior and post copies too) and
    /// mark the sigma points stale. Counters are kept. Validated like `new`.
    pub fn reset(&mut self, x: SVector<f64, N>, P: SMatrix<f64, N, N>) -> Result<(), UkfError> {
        if !all_finite(&x) {
            return Err(UkfError::NonFiniteArgument { which: Arg::X });
        }
        Self::check_covariance(&P, self.c, Arg::P)?;
        self.x = x;
        self.P = P;
        self.x_prior = x;
        self.P_prior = P;
        self.x_post = x;
        self.P_post = P;
        self.update_points = UpdatePoints::Stale;
        Ok(())
    }

    /// Set-up: the covariance `P` is reset to when it cannot be factored
    /// (default: the initial `P0`). Must be positive definite.
    pub fn set_reset_covariance(&mut self, P: SMatrix<f64, N, N>) -> Result<(), UkfError> {
        self.L_reset = Self::check_covariance(&P, self.c, Arg::ResetCovariance)?;
        self.P_reset = P;
        Ok(())
    }

    /// Set-up: replace the default process noise `Q` (must be finite).
    pub fn set_Q(&mut self, Q: SMatrix<f64, N, N>) -> Result<(), UkfError> {
        if !all_finite(&Q) {
            return Err(UkfError::NonFiniteArgument { which: Arg::Q });
        }
        self.Q = Q;
        Ok(())
    }

    /// Set-up: replace the default measurement noise `R` (must be finite).
    pub fn set_R(&mut self, R: SMatrix<f64, M, M>) -> Result<(), UkfError> {
        if !all_finite(&R) {
            return Err(UkfError::NonFiniteArgument { which: Arg::R });
        }
        self.R = R;
        Ok(())
    }

    /// The scaled factor `L` of `P` that sigma points are drawn with,
    /// repairing `P` in place if needed: plain factorisation; else
    /// re-symmetrise `P` and retry; else `P <- P_reset` (whose factor was
    /// computed at set-up, so this cannot fail).
    #[inline(always)]
    fn factor(
        &self,
        P: &mut SMatrix<f64, N, N>,
        stage: Stage,
        pending: &mut Pending,
    ) -> SMatrix<f64, N, N> {
        if let Some(L) = scaled_cholesky(P, self.c) {
            return L;
        }
        *P = symmetrise(P);
        if let Some(L) = scaled_cholesky(P, self.c) {
            pending.resymmetrised += 1;
            pending.last_resym = Some(stage);
            return L;
        }
        *P = self.P_reset;
        pending.resets += 1;
        pending.last_reset = Some(stage);
        self.L_reset
    }

    /// Sigma points of `(x, P)`, repairing `P` as [`Ukf::factor`] does.
    fn draw(
        &self,
        x: &SVector<f64, N>,
        P: &mut SMatrix<f64, N, N>,
        stage: Stage,
        pending: &mut Pending,
    ) -> SMatrix<f64, N, S> {
        sigma_points(x, &self.factor(P, stage, pending))
    }

    /// Count a rejected call; the state is untouched.
    fn reject(&mut self, e: UkfError) -> Result<Status, UkfError> {
        self.recoveries.rejected = self.recoveries.rejected.saturating_add(1);
        Err(e)
    }

    /// Commit the call's recovery counters and turn them into the result.
    fn finish(&mut self, pending: Pending) -> Result<Status, UkfError> {
        let r = &mut self.recoveries;
        r.resymmetrised = r.resymmetrised.saturating_add(pending.resymmetrised);
        r.covariance_resets = r.covariance_resets.saturating_add(pending.resets);
        if let Some(stage) = pending.last_reset {
            Err(UkfError::CovarianceReset { stage })
        } else if let Some(stage) = pending.last_resym {
            Ok(Status::Resymmetrised { stage })
        } else {
            Ok(Status::Nominal)
        }
    }

    /// Per tick: predict with the default `Q`. See [`Ukf::predict_with_q`].
    pub fn predict(
        &mut self,
        f: impl FnMut(&SVector<f64, N>) -> SVector<f64, N>,
    ) -> Result<Status, UkfError> {
        // The default Q was validated at set-up: no copy, no re-check.
        self.predict_impl(None, f)
    }

    /// Per tick: unscented predict with a per-call process noise `Q`.
    ///
    /// `chi = sigma(x, P)`, `chi_f,i = f(chi_i)`, `x- = sum Wm chi_f`,
    /// `P- = sum Wc (chi_f - x-)(chi_f - x-)' + Q`; then, as filterpy does,
    /// the sigma points used by the next `update` are re-drawn from
    /// `(x-, P-)`. Non-finite `Q`, `f` output or result: `Err`, state
    /// unchanged. Factorisation trouble: see [`UkfError::CovarianceReset`].
    pub fn predict_with_q(
        &mut self,
        Q: &SMatrix<f64, N, N>,
        f: impl FnMut(&SVector<f64, N>) -> SVector<f64, N>,
    ) -> Result<Status, UkfError> {
        if !all_finite(Q) {
            return self.reject(UkfError::NonFiniteArgument { which: Arg::Q });
        }
        self.predict_impl(Some(Q), f)
    }

    /// Per tick: [`Ukf::predict`] for a [`BilinearProcess`], in closed form.
    ///
    /// The sigma points are `x` and `x +- s_k`, `s_k = L e_k` with
    /// `L L' = (N + lambda) P`, weights `w = Wm_k = Wc_k = 1 / (2 (N + lambda))`
    /// for `k >= 1` (so `2 w sum_k s_k s_k' = P` and `Wm_0 + 2 N w = 1`).
    /// With `q(x +- s) = q(x) +- grad q(x)' s + q(s)`, the Jacobian
    /// `J = F + g grad q(x)'` and `p_k = q(s_k)`, the moving rows are
    /// `f_t(x +- s_k) = f_t(x) +- J s_k + g p_k`, so:
    /// `x-_t = Wm_0 f_t(x) + w sum_k 2 (f_t(x) + g p_k) = f_t(x) + g mu`,
    /// `mu = 2 w sum_k p_k` (`= sum_j P_{a_j b_j}`, the exact mean of `q`);
    /// the deviations `d_0 = -g mu`, `d_{+-k} = +-J s_k + g (p_k - mu)`,
    /// whose cross terms cancel in each `+-` pair, give
    /// `P-_tt = sum_i Wc_i d_i d_i' + Q_tt = J P J' + kappa g g' + Q_tt`,
    /// `kappa = Wc_0 mu^2 + 2 w sum_k (p_k - mu)^2`;
    /// a constant row `c` moves by `+-s_k,c`, so
    /// `P-_tc = w sum_k 2 (J s_k) s_k,c + Q_tc = (J P)_tc + Q_tc`,
    /// `x-_c = x_c` and `P-_cc = P_cc + Q_cc`. Only `kappa` (the unscented
    /// transform's fourth-moment term of `q`) needs the factor `L`; no
    /// sigma point is formed and `f` is not evaluated 2N + 1 times. Equal to
    /// [`Ukf::predict`] with `f = process.apply` up to rounding, with the
    /// same repairs of the factorisation (stage `PredictSigmaPoints`). `P`
    /// is read from its upper triangle (as the factorisation reads it) and
    /// one triangle of `P-` is computed, mirrored.
    ///
    /// filterpy's re-draw from `(x-, P-)` is deferred (its factorisation
    /// would be half of this call's cost): [`Ukf::update_selected`] needs no
    /// sigma points and skips it; the generic [`Ukf::update`] draws them
    /// itself from `(x-, P-)`, with the repairs reported by that call as
    /// stage `PredictRedraw`. An indefinite `P-` is then caught by the
    /// factorisation of `S` or of the next predict instead of this call.
    /// Non-finite `F`, `b` or `g`: `Err(NonFiniteProcess)`; overflow:
    /// `Err(NonFiniteResult)`; the state is unchanged.
    pub fn predict_bilinear<const R: usize, const K: usize>(
        &mut self,
        process: &BilinearProcess<N, R, K>,
    ) -> Result<Status, UkfError> {
        const { assert!(R >= 1 && R <= N, "R must be in 1..=N") };
        let BilinearProcess { F, b, g, q } = process;
        if !all_finite(F) || !all_finite(b) || !all_finite(g) {
            return self.reject(UkfError::NonFiniteProcess);
        }
        let mut pending = Pending::default();
        let mut P = self.P;
        let L = self.factor(&mut P, Stage::PredictSigmaPoints, &mut pending);
        // P as the factor read it.
        mirror_upper(&mut P);
        let w = self.Wm[1];
        // p_k = q(L e_k) = sum_j L_{a_j k} L_{b_j k} ; mu = 2 w sum_k p_k
        let l = &L.data.0;
        let mut p = [0.0f64; N];
        for &(a, c) in q.pairs() {
            for (pk, lk) in p.iter_mut().zip(l) {
                *pk += lk[a] * lk[c];
            }
        }
        let mu = 2.0 * w * p.iter().sum::<f64>();
        // kappa = Wc_0 mu^2 + 2 w sum_k (p_k - mu)^2
        let spread: f64 = p.iter().map(|pk| (pk - mu) * (pk - mu)).sum();
        let kappa = self.Wc[0] * mu * mu + 2.0 * w * spread;
        let x = &self.x;
        // x-_t = F x + b + g (q(x) + mu)
        let x_t = F * x + b + g * (q.eval(x) + mu);
        // J = F + g grad q(x)' (rows) ; PJ = P J' (columns: PJ[r] = sum_k P e_k J_rk)
        let grad = q.gradient(x);
        let mut J = [[0.0f64; N]; R];
        let mut PJ = [[0.0f64; N]; R];
        let pc = &P.data.0;
        for r in 0..R {
            for k in 0..N {
                let jrk = F[(r, k)] + g[r] * grad[k];
                J[r][k] = jrk;
                for (v, pik) in PJ[r].iter_mut().zip(pc[k]) {
                    *v += pik * jrk;
                }
            }
        }
        // P- = P + Q, then the moving rows on the upper triangle:
        // P-_tt = J P J' + kappa g g' + Q_tt, P-_tc = (J P)_tc + Q_tc; then
        // mirrored (Q need not be symmetric).
        let mut P_prior = P + self.Q;
        for t in 0..R {
            for r in 0..=t {
                let mut jpj = 0.0;
                for k in 0..N {
                    jpj += J[r][k] * PJ[t][k];
                }
                P_prior[(r, t)] = jpj + kappa * g[r] * g[t] + self.Q[(r, t)];
            }
            for c in R..N {
                P_prior[(t, c)] = PJ[t][c] + self.Q[(t, c)];
            }
        }
        mirror_upper(&mut P_prior);
        // x-_c is the finite state's x_c: only the moving rows can overflow.
        if !all_finite(&x_t) || !all_finite(&P_prior) {
            return self.reject(UkfError::NonFiniteResult {
                phase: Phase::Predict,
            });
        }
        let mut x_prior = self.x;
        x_prior.fixed_rows_mut::<R>(0).copy_from(&x_t);
        self.store_prior(x_prior, P_prior, UpdatePoints::Deferred, pending)
    }

    /// Per tick: [`Ukf::predict`] for an affine process `f(x) = F x + b`,
    /// in closed form: `x- = F x + b`, `P- = F P F' + Q`.
    ///
    /// The unscented transform of an affine map is exact: on the sigma
    /// points `chi_0 = x`, `x +- L e_k` (`L L' = (N + lambda) P`, weights
    /// `w = Wm_k = Wc_k = 1 / (2 (N + lambda))` for `k >= 1`),
    /// `x- = Wm_0 (F x + b) + w sum_k ((F x + F L e_k + b) + (F x - F L e_k + b)) = F x + b`
    /// (the `+-` cancel, the weights sum to 1), and with
    /// `chi_f,i - x- = F (chi_i - x)`:
    /// `P- = Wc_0 0 0' + w sum_k 2 (F L e_k)(F L e_k)' + Q = 2 w F L L' F' + Q = F P F' + Q`.
    /// So no factorisation and no sigma point is needed; equal to
    /// [`Ukf::predict`] with `f` up to rounding. `P` is read from its upper
    /// triangle (as the factorisation reads it) and one triangle of `P-` is
    /// computed, mirrored. filterpy's re-draw is deferred as in
    /// [`Ukf::predict_bilinear`]; an indefinite `P` is caught by the next
    /// factorisation (of `S` or of the generic update's points).
    /// Non-finite `F` or `b`: `Err(NonFiniteProcess)`, overflow:
    /// `Err(NonFiniteResult)`; the state is unchanged.
    pub fn predict_linear(
        &mut self,
        F: &SMatrix<f64, N, N>,
        b: &SVector<f64, N>,
    ) -> Result<Status, UkfError> {
        if !all_finite(F) || !all_finite(b) {
            return self.reject(UkfError::NonFiniteProcess);
        }
        // x- = F x + b
        let x_prior = F * self.x + b;
        // G = F P (P from its upper triangle), then P- = G F' + Q on i <= j.
        let mut G = SMatrix::<f64, N, N>::zeros();
        for c in 0..N {
            for r in 0..N {
                let mut g = 0.0;
                for k in 0..N {
                    let p = if k <= c {
                        self.P[(k, c)]
                    } else {
                        self.P[(c, k)]
                    };
                    g += F[(r, k)] * p;
                }
                G[(r, c)] = g;
            }
        }
        let mut P_prior = SMatrix::<f64, N, N>::zeros();
        for j in 0..N {
            for i in 0..=j {
                let mut v = 0.0;
                for k in 0..N {
                    v += G[(i, k)] * F[(j, k)];
                }
                v += self.Q[(i, j)];
                P_prior[(i, j)] = v;
                P_prior[(j, i)] = v;
            }
        }
        if !all_finite(&x_prior) || !all_finite(&P_prior) {
            return self.reject(UkfError::NonFiniteResult {
                phase: Phase::Predict,
            });
        }
        self.store_prior(x_prior, P_prior, UpdatePoints::Deferred, Pending::default())
    }

    /// The end of a predict: filterpy's re-draw of the sigma points from
    /// `(x-, P-)` (repairing `P-` if needed), then commit.
    #[inline(always)]
    fn commit_prior(
        &mut self,
        x_prior: SVector<f64, N>,
        mut P_prior: SMatrix<f64, N, N>,
        mut pending: Pending,
    ) -> Result<Status, UkfError> {
        let L = self.factor(&mut P_prior, Stage::PredictRedraw, &mut pending);
        self.sigma_center = x_prior;
        self.sigma_factor = L;
        self.store_prior(x_prior, P_prior, UpdatePoints::Drawn, pending)
    }

    /// Commit a predict's `(x-, P-)` and where the next update's sigma
    /// points come from.
    #[inline(always)]
    fn store_prior(
        &mut self,
        x_prior: SVector<f64, N>,
        P_prior: SMatrix<f64, N, N>,
        points: UpdatePoints,
        pending: Pending,
    ) -> Result<Status, UkfError> {
        self.x = x_prior;
        self.P = P_prior;
        self.x_prior = x_prior;
        self.P_prior = P_prior;
        self.update_points = points;
        self.recoveries.predicts = self.recoveries.predicts.saturating_add(1);
        self.finish(pending)
    }

    /// [`Ukf::predict_with_q`] with a checked per-call `Q`, or the default.
    fn predict_impl(
        &mut self,
        Q: Option<&SMatrix<f64, N, N>>,
        mut f: impl FnMut(&SVector<f64, N>) -> SVector<f64, N>,
    ) -> Result<Status, UkfError> {
        let mut pending = Pending::default();
        let mut P = self.P;
        let L = self.factor(&mut P, Stage::PredictSigmaPoints, &mut pending);
        // chi_f,i = f(chi_i)
        let Some(chi_f) = propagate(&self.x, &L, &mut f) else {
            return self.reject(UkfError::NonFiniteProcess);
        };
        // x- = sum_i Wm_i chi_f,i
        let x_prior = unscented_mean(&self.Wm, &chi_f);
        // P- = sum_i Wc_i (chi_f,i - x-)(chi_f,i - x-)' + Q
        let P_prior = unscented_covariance(&self.Wc, &chi_f, &x_prior, Q.unwrap_or(&self.Q));
        if !all_finite(&x_prior) || !all_finite(&P_prior) {
            return self.reject(UkfError::NonFiniteResult {
                phase: Phase::Predict,
            });
        }
        // filterpy quirk mirrored: re-draw sigma points from (x-, P-) now.
        self.commit_prior(x_prior, P_prior, pending)
    }

    /// Per tick: update with the default `R`. See [`Ukf::update_with_r`].
    pub fn update(
        &mut self,
        z: &SVector<f64, M>,
        h: impl FnMut(&SVector<f64, N>) -> SVector<f64, M>,
    ) -> Result<Status, UkfError> {
        let R = self.R;
        self.update_with_r(z, &R, h)
    }

    /// Per tick: unscented update with a per-call measurement noise `R`
    /// (e.g. time-varying).
    ///
    /// Uses the sigma points re-drawn at the end of the last `predict`; if no
    /// `predict` preceded this call (first call, a second update in a row, or
    /// after `reset`), draws them from the current `(x, P)` (filterpy would
    /// use zeros or stale points; `docs/ukf.md`).
    /// `Z_i = h(chi_i)`, `z_bar = sum Wm Z`, `S = sum Wc (Z - z_bar)(Z - z_bar)' + R`,
    /// `Pxz = sum Wc (chi - x)(Z - z_bar)'`, `K = Pxz S^-1` (Cholesky solve),
    /// `y = z - z_bar`, `x+ = x + K y`, `P+ = P - K S K'`.
    /// Non-finite `z`, `R`, `h` output or result: `Err`, state unchanged. If
    /// `S` cannot be factored even after re-symmetrising, the measurement is
    /// discarded, `P` is reset and `Err(CovarianceReset)` is returned.
    pub fn update_with_r(
        &mut self,
        z: &SVector<f64, M>,
        R: &SMatrix<f64, M, M>,
        mut h: impl FnMut(&SVector<f64, N>) -> SVector<f64, M>,
    ) -> Result<Status, UkfError> {
        if !all_finite(z) {
            return self.reject(UkfError::NonFiniteMeasurement);
        }
        if !all_finite(R) {
            return self.reject(UkfError::NonFiniteArgument { which: Arg::R });
        }
        let mut pending = Pending::default();
        let mut P = self.P;
        let chi = match self.update_points {
            UpdatePoints::Drawn => sigma_points(&self.sigma_center, &self.sigma_factor),
            // The deferred re-draw, from (x-, P-) as filterpy's.
            UpdatePoints::Deferred => {
                self.draw(&self.x, &mut P, Stage::PredictRedraw, &mut pending)
            }
            UpdatePoints::Stale => {
                self.draw(&self.x, &mut P, Stage::UpdateSigmaPoints, &mut pending)
            }
        };
        let chi = &chi;
        // Z_i = h(chi_i)
        let mut Z = SMatrix::<f64, M, S>::zeros();
        for i in 0..S {
            let xi: SVector<f64, N> = chi.column(i).into_owned();
            let zi = h(&xi);
            if !all_finite(&zi) {
                return self.reject(UkfError::NonFiniteMeasurementModel);
            }
            Z.set_column(i, &zi);
        }
        // z_bar = sum_i Wm_i Z_i
        let z_bar = unscented_mean(&self.Wm, &Z);
        // S = sum_i Wc_i (Z_i - z_bar)(Z_i - z_bar)' + R
        let S_innov = unscented_covariance(&self.Wc, &Z, &z_bar, R);
        // Pxz = sum_i Wc_i (chi_i - x)(Z_i - z_bar)'
        let Pxz = cross_covariance(&self.Wc, chi, &self.x, &Z, &z_bar);
        if !all_finite(&z_bar) || !all_finite(&S_innov) || !all_finite(&Pxz) {
            return self.reject(UkfError::NonFiniteResult {
                phase: Phase::Update,
            });
        }
        self.correct(z, &z_bar, S_innov, &Pxz, &P, pending, Posterior::Filterpy)
    }

    /// Per tick: update with the default `R` for a measurement that selects
    /// state entries, `h(x) = H x` with `H` the rows of `I` named by `sel`.
    /// See [`Ukf::update_selected_with_r`].
    pub fn update_selected(
        &mut self,
        z: &SVector<f64, M>,
        sel: &Selection<N, M>,
    ) -> Result<Status, UkfError> {
        if !all_finite(z) {
            return self.reject(UkfError::NonFiniteMeasurement);
        }
        // The default R was validated at set-up: no copy, no re-check.
        self.update_selected_impl(z, None, sel)
    }

    /// Per tick: [`Ukf::update_with_r`] for `h = sel`, in closed form.
    ///
    /// The sigma points of the update are `x +- L e_k` with
    /// `L L' = (N + lambda) P` (filterpy's re-draw at the end of `predict`),
    /// and a selection is linear, so the unscented sums are exact:
    /// `z_bar = H x`, `S = H P H' + R`, `Pxz = P H'` (`P` read from its upper
    /// triangle, as the factorisation reads it). The update is then the
    /// linear Kalman update on sub-blocks of `P`: `K = Pxz S^-1` (Cholesky
    /// solve), `x+ = x + K (z - H x)`, `P+ = P - K Pxz'` (`= P - K S K'`,
    /// one triangle computed, mirrored). Equal to the sigma-point update up
    /// to rounding; errors and repairs are the same as [`Ukf::update_with_r`]
    /// (a selection cannot return NaN, so `NonFiniteMeasurementModel` does
    /// not occur).
    pub fn update_selected_with_r(
        &mut self,
        z: &SVector<f64, M>,
        R: &SMatrix<f64, M, M>,
        sel: &Selection<N, M>,
    ) -> Result<Status, UkfError> {
        if !all_finite(z) {
            return self.reject(UkfError::NonFiniteMeasurement);
        }
        if !all_finite(R) {
            return self.reject(UkfError::NonFiniteArgument { which: Arg::R });
        }
        self.update_selected_impl(z, Some(R), sel)
    }

    /// [`Ukf::update_selected_with_r`] with a checked `z` and a checked
    /// per-call `R`, or the default.
    fn update_selected_impl(
        &mut self,
        z: &SVector<f64, M>,
        R: Option<&SMatrix<f64, M, M>>,
        sel: &Selection<N, M>,
    ) -> Result<Status, UkfError> {
        let R = R.unwrap_or(&self.R);
        let mut pending = Pending::default();
        let mut P = self.P;
        if self.update_points == UpdatePoints::Stale {
            // The generic path draws sigma points here: the same
            // factorisation, with the same repairs of P. (A deferred
            // re-draw is skipped: nothing here uses its factor.)
            let _ = self.factor(&mut P, Stage::UpdateSigmaPoints, &mut pending);
        }
        let idx = sel.indices();
        // P as the sigma points see it: its upper triangle, mirrored.
        let mut Pu = P;
        mirror_upper(&mut Pu);
        // z_bar = H x
        let z_bar = sel.apply(&self.x);
        // Pxz = P H' (the selected columns) ; S = H P H' + R
        let mut Pxz = SMatrix::<f64, N, M>::zeros();
        for (b, &c) in idx.iter().enumerate() {
            Pxz.set_column(b, &Pu.column(c));
        }
        let S_innov = SMatrix::<f64, M, M>::from_fn(|a, b| Pxz[(idx[a], b)] + R[(a, b)]);
        // z_bar and Pxz are entries of the finite x and P; S can overflow.
        if !all_finite(&S_innov) {
            return self.reject(UkfError::NonFiniteResult {
                phase: Phase::Update,
            });
        }
        self.correct(z, &z_bar, S_innov, &Pxz, &P, pending, Posterior::Symmetric)
    }

    /// The correction shared by both update paths, from the finite (checked
    /// by the caller) `z_bar`, `S`, `Pxz` and the prior `P`: factor `S`
    /// (with the recovery policy), then
    /// `K = Pxz S^-1`, `y = z - z_bar`, `x+ = x + K y`, and `P+` as chosen.
    #[allow(clippy::too_many_arguments)]
    fn correct(
        &mut self,
        z: &SVector<f64, M>,
        z_bar: &SVector<f64, M>,
        mut S_innov: SMatrix<f64, M, M>,
        Pxz: &SMatrix<f64, N, M>,
        P: &SMatrix<f64, N, N>,
        mut pending: Pending,
        posterior: Posterior,
    ) -> Result<Status, UkfError> {
        let L_S = match cholesky_lower(&S_innov) {
            Some(ch) => ch,
            None => {
                S_innov = symmetrise(&S_innov);
                match cholesky_lower(&S_innov) {
                    Some(ch) => {
                        pending.resymmetrised += 1;
                        pending.last_resym = Some(Stage::InnovationCovariance);
                        ch
                    }
                    None => {
                        // S = H P H' + R is not positive definite: P (or R)
                        // is broken. Drop the measurement, reset P.
                        pending.resets += 1;
                        pending.last_reset = Some(Stage::InnovationCovariance);
                        self.P = self.P_reset;
                        self.x_post = self.x;
                        self.P_post = self.P;
                        self.update_points = UpdatePoints::Stale;
                        return self.finish(pending);
                    }
                }
            }
        };
        // K = Pxz S^-1
        let K = kalman_gain(Pxz, &L_S);
        // y = z - z_bar
        let y = z - z_bar;
        // x+ = x- + K y
        let x_new = posterior_mean(&self.x, &K, &y);
        let P_new = match posterior {
            // P+ = P- - K S K'
            Posterior::Filterpy => posterior_covariance(P, &K, &S_innov),
            // P+ = P- - K Pxz'
            Posterior::Symmetric => posterior_covariance_symmetric(P, &K, Pxz),
        };
        // A non-finite K needs no check of its own: y is finite, so a NaN
        // or infinite K_rm makes x+_r non-finite (inf y_m, or inf 0 = NaN).
        if !all_finite(&x_new) || !all_finite(&P_new) {
            return self.reject(UkfError::NonFiniteResult {
                phase: Phase::Update,
            });
        }
        self.x = x_new;
        self.P = P_new;
        self.x_post = x_new;
        self.P_post = P_new;
        self.y = y;
        self.S_innov = S_innov;
        self.K = K;
        self.update_points = UpdatePoints::Stale;
        self.recoveries.updates = self.recoveries.updates.saturating_add(1);
        self.finish(pending)
    }

    /// Replay a whole trial, allocation-free: for each step `k`,
    /// `predict(|x| f(x, u[k]))` then `update(z[k], h)` (filterpy's
    /// `batch_filter` order), then writes the posterior `x` into
    /// `xs_out[k N..(k+1) N]` and `diag(P)` into `pdiag_out[k N..]`.
    ///
    /// `z` is row-major `T x M` (`T = u.len()`). Step errors do not stop the
    /// trial (each was already handled by the filter); they are counted in
    /// the report and in [`Ukf::recoveries`]. Slice length errors are
    /// reported before anything runs.
    pub fn run(
        &mut self,
        u: &[f64],
        z: &[f64],
        xs_out: &mut [f64],
        pdiag_out: &mut [f64],
        mut f: impl FnMut(&SVector<f64, N>, f64) -> SVector<f64, N>,
        mut h: impl FnMut(&SVector<f64, N>) -> SVector<f64, M>,
    ) -> Result<RunReport, UkfError> {
        let T = u.len();
        let needed_z = T.saturating_mul(M);
        if z.len() != needed_z {
            return Err(UkfError::InputLength {
                which: Arg::Measurements,
                needed: needed_z,
                got: z.len(),
            });
        }
        let needed_x = T.saturating_mul(N);
        if xs_out.len() < needed_x {
            return Err(UkfError::OutputTooShort {
                which: Arg::XsOut,
                needed: needed_x,
                got: xs_out.len(),
            });
        }
        if pdiag_out.len() < needed_x {
            return Err(UkfError::OutputTooShort {
                which: Arg::PdiagOut,
                needed: needed_x,
                got: pdiag_out.len(),
            });
        }
        let mut report = RunReport {
            steps: T,
            errors: 0,
            first_error: None,
        };
        let note = |report: &mut RunReport, step: usize, phase: Phase, error: UkfError| {
            report.errors += 1;
            if report.first_error.is_none() {
                report.first_error = Some(StepError { step, phase, error });
            }
        };
        for (k, (&uk, zk)) in u.iter().zip(z.chunks_exact(M)).enumerate() {
            if let Err(e) = self.predict(|x| f(x, uk)) {
                note(&mut report, k, Phase::Predict, e);
            }
            let zk = SVector::<f64, M>::from_iterator(zk.iter().copied());
            if let Err(e) = self.update(&zk, &mut h) {
                note(&mut report, k, Phase::Update, e);
            }
            for i in 0..N {
                xs_out[k * N + i] = self.x[i];
                pdiag_out[k * N + i] = self.P[(i, i)];
            }
        }
        Ok(report)
    }

    /// State estimate `x` (posterior after `update`, prior after `predict`).
    pub fn x(&self) -> &SVector<f64, N> {
        &self.x
    }
    /// State covariance `P`.
    pub fn P(&self) -> &SMatrix<f64, N, N> {
        &self.P
    }
    /// Prior mean of the last `predict`.
    pub fn x_prior(&self) -> &SVector<f64, N> {
        &self.x_prior
    }
    /// Prior covariance of the last `predict`.
    pub fn P_prior(&self) -> &SMatrix<f64, N, N> {
        &self.P_prior
    }
    /// Posterior mean of the last `update`.
    pub fn x_post(&self) -> &SVector<f64, N> {
        &self.x_post
    }
    /// Posterior covariance of the last `update`.
    pub fn P_post(&self) -> &SMatrix<f64, N, N> {
        &self.P_post
    }
    /// Default process noise `Q`.
    pub fn Q(&self) -> &SMatrix<f64, N, N> {
        &self.Q
    }
    /// Default measurement noise `R`.
    pub fn R(&self) -> &SMatrix<f64, M, M> {
        &self.R
    }
    /// Last innovation `y = z - z_bar` (zeros before the first update).
    pub fn y(&self) -> &SVector<f64, M> {
        &self.y
    }
    /// Last innovation covariance `S` (zeros before the first update).
    pub fn S(&self) -> &SMatrix<f64, M, M> {
        &self.S_innov
    }
    /// Last Kalman gain `K` (zeros before the first update).
    pub fn K(&self) -> &SMatrix<f64, N, M> {
        &self.K
    }
    /// Mean weights `Wm`.
    pub fn Wm(&self) -> &SVector<f64, S> {
        &self.Wm
    }
    /// Covariance weights `Wc`.
    pub fn Wc(&self) -> &SVector<f64, S> {
        &self.Wc
    }
    /// Sigma points (columns) re-drawn at the end of the last `predict`
    /// (formed on demand from the stored centre and factor; zeros before the
    /// first `predict`, as filterpy's). After [`Ukf::predict_bilinear`],
    /// which defers the re-draw, they are drawn now from `(x-, P-)`; `None`
    /// if `P-` does not factor (the next update repairs it first).
    pub fn sigmas_f(&self) -> Option<SMatrix<f64, N, S>> {
        match self.update_points {
            UpdatePoints::Deferred => {
                scaled_cholesky(&self.P, self.c).map(|L| sigma_points(&self.x, &L))
            }
            UpdatePoints::Drawn | UpdatePoints::Stale => {
                Some(sigma_points(&self.sigma_center, &self.sigma_factor))
            }
        }
    }
    /// The covariance `P` is reset to on an unrecoverable factorisation.
    pub fn reset_covariance(&self) -> &SMatrix<f64, N, N> {
        &self.P_reset
    }
    /// Recovery and step counters.
    pub fn recoveries(&self) -> Recoveries {
        self.recoveries
    }
}
