//! Algebraic Riccati equations and LQR gains (eq.LQRrobot, eq.LQRhuman).
//!
//! Solves, for `N` states (`1 <= N <= 6`) and `M` inputs (`1 <= M <= N`),
//!
//! * CARE: `A'X + XA - X B R^-1 B' X + Q = 0`
//! * DARE: `X = A'XA - A'XB (R + B'XB)^-1 B'XA + Q`
//!
//! returning the unique stabilising symmetric positive semidefinite `X`.
//! The algorithm is the structure-preserving doubling algorithm (SDA) of
//! Chu, Fan, Lin and Wang (DARE: J. Phys. A 2004 / Int. J. Control 2004;
//! CARE via a Cayley transform: Chu, Fan and Lin, Linear Algebra Appl. 396,
//! 2005). It works on `N x N` matrices only, uses LU/Cholesky solves and no
//! explicit inverse, and never allocates.
//!
//! When it runs: at set-up (gain design), not in the control tick. A solve is
//! a few dozen `N^3` operations plus the input checks, which include a Schur
//! decomposition of `A` and of the closed loop.
//!
//! Every broken precondition has its own [`RiccatiError`] variant; tolerances
//! are the `pub const`s below and are explained in `docs/riccati.md`.

use core::fmt;

use nalgebra::allocator::Allocator;
use nalgebra::{Cholesky, Complex, Const, DefaultAllocator, DimDiff, DimSub, SMatrix, Schur, U1};

use crate::linalg::{all_finite, hermitian_positive_definite, symmetrize, Lu};
use crate::linalg::{is_positive_definite, is_positive_semidefinite, is_symmetric};

/// Largest state dimension the solvers accept (checked at compile time).
///
/// The eigenvalue checks have one concrete Schur instance per size (see
/// [`eigenvalues`]), which is what bounds `N`.
pub const MAX_STATES: usize = 6;

/// Accepted relative residual of a returned solution (see [`care_residual`],
/// [`dare_residual`]).
pub const RESIDUAL_TOL: f64 = 1e-10;

/// `Q` and `R` must be symmetric within [`SYMMETRY_TOL`]; `Q` positive
/// semidefinite and `R` positive definite within [`DEFINITENESS_TOL`]
/// (`linalg`'s tests, shared with the estimators' covariances).
pub use crate::linalg::{DEFINITENESS_TOL, SYMMETRY_TOL};

/// An eigenvalue of `A` is "unstable or marginal" (and gets a PBH test) when
/// `Re(lambda) >= -MARGINAL_TOL ||A||_F` (continuous) or
/// `|lambda| >= 1 - MARGINAL_TOL` (discrete).
pub const MARGINAL_TOL: f64 = 1e-6;

/// PBH rank threshold: a mode counts as uncontrollable (unobservable) when the
/// smallest singular value of `[A - lambda I, B]` (of `[A - lambda I; C]`,
/// `C'C = Q`) is at most `PBH_TOL` times the scale `sqrt(||A||_F^2 + ||B||_F^2)`
/// (`sqrt(||A||_F^2 + ||Q||_F)`).
pub const PBH_TOL: f64 = 1e-7;

/// Default cap on SDA doubling steps. Convergence is quadratic: `k` steps
/// reach `rho^(2^k)` for closed-loop (Cayley) spectral radius `rho`, so 100 is
/// far beyond anything a well-posed problem needs.
pub const MAX_ITERATIONS: usize = 100;

/// The padding eigenvalue used by [`eigenvalues`]; stable in both senses.
const PAD_EIGENVALUE: f64 = -0.5;

/// Which argument of a Riccati solve an error refers to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Argument {
    /// State matrix `A` (`N x N`).
    A,
    /// Input matrix `B` (`N x M`).
    B,
    /// State weight `Q` (`N x N`).
    Q,
    /// Input weight `R` (`M x M`).
    R,
}

/// Which parameter of [`agent_gains`] an error refers to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AgentParameter {
    /// Mass `M` of the manipulandum; must be finite and `> 0`.
    Mass,
    /// Viscous damping `C`; must be finite and `>= 0`.
    Damping,
    /// Position weight `Q_x`; must be finite and `> 0`.
    QPos,
    /// Velocity weight `Q_xdot`; must be finite and `>= 0`.
    QVel,
}

/// Why a Riccati/LQR solve failed. One variant per broken precondition.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RiccatiError {
    /// An entry of the named argument is NaN or infinite.
    NonFinite(Argument),
    /// `Q` or `R` is not symmetric within [`SYMMETRY_TOL`].
    NotSymmetric(Argument),
    /// `Q` has an eigenvalue below `-DEFINITENESS_TOL ||Q||_F`.
    QNotPositiveSemidefinite,
    /// `R` is not positive definite (margin [`DEFINITENESS_TOL`]).
    RNotPositiveDefinite,
    /// `(A, B)` has an uncontrollable unstable or marginal mode (PBH test).
    NotStabilizable,
    /// `(Q, A)` has an unobservable unstable or marginal mode (PBH test).
    NotDetectable,
    /// The doubling iteration did not converge within the iteration cap, or
    /// an iterate became singular or non-finite.
    NoConvergence,
    /// The iteration converged but the relative residual exceeds
    /// [`RESIDUAL_TOL`].
    ResidualTooLarge {
        /// The measured relative residual.
        relative: f64,
    },
    /// The solution does not stabilise the closed loop (`A - BK` has an
    /// eigenvalue with `Re >= 0`, or `|lambda| >= 1` in discrete time).
    NotStabilizing,
    /// An [`agent_gains`] parameter is out of range or non-finite.
    InvalidAgentParameter(AgentParameter),
    /// A [`lqr_dense`] argument's shape `got` does not fit: `A` must be
    /// `n x n` with `1 <= n <= MAX_STATES`, `B` `n x m` with `1 <= m <= n`,
    /// `Q` `n x n`, `R` `m x m`.
    Shape {
        /// The argument at fault.
        argument: Argument,
        /// Its shape `(rows, cols)`.
        got: [usize; 2],
        /// The states `n` (from `A`) and inputs `m` (from `B`) known so far.
        n: usize,
        /// See `n`.
        m: usize,
    },
}

impl crate::CoreError for RiccatiError {
    /// The solver failed its own checks (no convergence, residual, closed
    /// loop), as opposed to inputs that break a precondition.
    fn kind(&self) -> crate::ErrorKind {
        match self {
            RiccatiError::NoConvergence
            | RiccatiError::ResidualTooLarge { .. }
            | RiccatiError::NotStabilizing => crate::ErrorKind::SolverFailure,
            _ => crate::ErrorKind::Argument,
        }
    }
}

impl fmt::Display for Argument {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let s = match self {
            Argument::A => "A",
            Argument::B => "B",
            Argument::Q => "Q",
            Argument::R => "R",
        };
        f.write_str(s)
    }
}

impl fmt::Display for RiccatiError {
    /// The argument at fault first, then what is wrong and how to fix it.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            RiccatiError::NonFinite(a) => {
                write!(
                    f,
                    "{a}: contains NaN or infinite entries; pass finite values"
                )
            }
            RiccatiError::NotSymmetric(a) => write!(
                f,
                "{a}: must be symmetric (||{a} - {a}'||_F <= {SYMMETRY_TOL:e} ||{a}||_F); \
                 pass ({a} + {a}') / 2"
            ),
            RiccatiError::QNotPositiveSemidefinite => write!(
                f,
                "Q: must be positive semidefinite (no eigenvalue below \
                 -{DEFINITENESS_TOL:e} ||Q||_F); raise its diagonal"
            ),
            RiccatiError::RNotPositiveDefinite => write!(
                f,
                "R: must be positive definite (every eigenvalue above \
                 {DEFINITENESS_TOL:e} ||R||_F); raise its diagonal"
            ),
            RiccatiError::NotStabilizable => f.write_str(
                "(A, B): not stabilisable, an unstable or marginal mode of A is uncontrollable \
                 (PBH test); no stabilising solution exists",
            ),
            RiccatiError::NotDetectable => f.write_str(
                "(Q, A): not detectable, an unstable or marginal mode of A is unobservable \
                 through Q (PBH test); no stabilising solution exists",
            ),
            RiccatiError::NoConvergence => {
                f.write_str("doubling iteration did not converge (or an iterate became singular)")
            }
            RiccatiError::ResidualTooLarge { relative } => write!(
                f,
                "solution rejected: relative residual {relative:e} > {RESIDUAL_TOL:e}"
            ),
            RiccatiError::NotStabilizing => {
                f.write_str("solution rejected: closed loop A - BK is not stable")
            }
            RiccatiError::InvalidAgentParameter(p) => f.write_str(match p {
                AgentParameter::Mass => {
                    "mass: must be finite and > 0 (the handle's inertia), with 1 / mass finite"
                }
                AgentParameter::Damping => {
                    "damping: must be finite and >= 0 (viscous damping; 0 after friction \
                     compensation), with damping / mass finite"
                }
                AgentParameter::QPos => {
                    "q_pos: must be finite and > 0 (the position weight makes the problem \
                     detectable)"
                }
                AgentParameter::QVel => "q_vel: must be finite and >= 0 (0 is fine)",
            }),
            RiccatiError::Shape {
                argument,
                got: [r, c],
                n,
                m,
            } => match argument {
                Argument::A => write!(
                    f,
                    "A: expected a square (n, n) array with 1 <= n <= {MAX_STATES}, got ({r}, {c})"
                ),
                Argument::B => write!(
                    f,
                    "(A, B): B must have as many rows as A: expected shape (n, m) = ({n}, m) with \
                     1 <= m <= {n}, got ({r}, {c})"
                ),
                Argument::Q => write!(
                    f,
                    "(A, Q): Q must match A: expected shape (n, n) = ({n}, {n}), got ({r}, {c})"
                ),
                Argument::R => write!(
                    f,
                    "(B, R): R must match B's columns: expected shape (m, m) = ({m}, {m}), \
                     got ({r}, {c})"
                ),
            },
        }
    }
}

/// Knobs for [`care_with`] / [`dare_with`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SolverOptions {
    /// Cap on doubling steps ([`MAX_ITERATIONS`] by default).
    pub max_iterations: usize,
    /// Run the stabilisability / detectability / definiteness checks
    /// (default `true`). Finiteness and the post-solve residual and
    /// closed-loop checks always run.
    pub check_preconditions: bool,
}

impl Default for SolverOptions {
    fn default() -> Self {
        Self {
            max_iterations: MAX_ITERATIONS,
            check_preconditions: true,
        }
    }
}

/// Continuous or discrete time: selects the stability region.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Domain {
    Continuous,
    Discrete,
}

/// Checked and symmetrised inputs plus `G = B R^-1 B'`.
struct Prepared<const N: usize, const M: usize> {
    Q: SMatrix<f64, N, N>,
    R: SMatrix<f64, M, M>,
    G: SMatrix<f64, N, N>,
}

// ---------------------------------------------------------------------------
// Public solvers
// ---------------------------------------------------------------------------

/// CARE `A'X + XA - X B R^-1 B' X + Q = 0`: the stabilising solution `X`.
///
/// Same as [`care_with`] with default [`SolverOptions`].
pub fn care<const N: usize, const M: usize>(
    A: &SMatrix<f64, N, N>,
    B: &SMatrix<f64, N, M>,
    Q: &SMatrix<f64, N, N>,
    R: &SMatrix<f64, M, M>,
) -> Result<SMatrix<f64, N, N>, RiccatiError> {
    care_with(A, B, Q, R, &SolverOptions::default())
}

/// CARE `A'X + XA - X B R^-1 B' X + Q = 0` with explicit options.
///
/// Steps: input checks; `G = B R^-1 B'`; Cayley transform
/// (`care_sda_initial`); doubling (`sda`); acceptance checks
/// (relative residual [`care_residual`] `<= RESIDUAL_TOL`,
/// `A - G X` Hurwitz).
pub fn care_with<const N: usize, const M: usize>(
    A: &SMatrix<f64, N, N>,
    B: &SMatrix<f64, N, M>,
    Q: &SMatrix<f64, N, N>,
    R: &SMatrix<f64, M, M>,
    options: &SolverOptions,
) -> Result<SMatrix<f64, N, N>, RiccatiError> {
    let p = prepare(A, B, Q, R, Domain::Continuous, options.check_preconditions)?;
    let gamma = cayley_shift(A, &p.G, &p.Q);
    let (A0, G0, H0) = care_sda_initial(A, &p.G, &p.Q, gamma).ok_or(RiccatiError::NoConvergence)?;
    let X = sda(&A0, &G0, &H0, options.max_iterations)?;
    // Closed loop A - B K = A - G X with K = R^-1 B' X.
    accepted(
        X,
        care_residual(A, B, &p.Q, &p.R, &X),
        Domain::Continuous,
        |X| Ok(A - p.G * X),
    )
}

/// DARE `X = A'XA - A'XB (R + B'XB)^-1 B'XA + Q`: the stabilising solution.
///
/// Same as [`dare_with`] with default [`SolverOptions`].
pub fn dare<const N: usize, const M: usize>(
    A: &SMatrix<f64, N, N>,
    B: &SMatrix<f64, N, M>,
    Q: &SMatrix<f64, N, N>,
    R: &SMatrix<f64, M, M>,
) -> Result<SMatrix<f64, N, N>, RiccatiError> {
    dare_with(A, B, Q, R, &SolverOptions::default())
}

/// DARE `X = A'XA - A'XB (R + B'XB)^-1 B'XA + Q` with explicit options.
///
/// Uses the equivalent form `X = A' X (I + G X)^-1 A + Q`, `G = B R^-1 B'`,
/// so the SDA starts from `A0 = A`, `G0 = G`, `H0 = Q`. Acceptance:
/// [`dare_residual`] `<= RESIDUAL_TOL` and `A - B K` Schur stable.
pub fn dare_with<const N: usize, const M: usize>(
    A: &SMatrix<f64, N, N>,
    B: &SMatrix<f64, N, M>,
    Q: &SMatrix<f64, N, N>,
    R: &SMatrix<f64, M, M>,
    options: &SolverOptions,
) -> Result<SMatrix<f64, N, N>, RiccatiError> {
    let p = prepare(A, B, Q, R, Domain::Discrete, options.check_preconditions)?;
    let X = sda(A, &p.G, &p.Q, options.max_iterations)?;
    accepted(
        X,
        dare_residual(A, B, &p.Q, &p.R, &X),
        Domain::Discrete,
        |X| {
            let K = dare_gain(A, B, &p.R, X).ok_or(RiccatiError::NoConvergence)?;
            Ok(A - B * K)
        },
    )
}

/// The acceptance of an SDA solution `X`, in this order: its relative
/// residual at most `RESIDUAL_TOL`, then its closed loop (built only for a
/// small residual) stable in `domain`.
fn accepted<const N: usize>(
    X: SMatrix<f64, N, N>,
    relative: f64,
    domain: Domain,
    closed_loop: impl FnOnce(&SMatrix<f64, N, N>) -> Result<SMatrix<f64, N, N>, RiccatiError>,
) -> Result<SMatrix<f64, N, N>, RiccatiError> {
    if relative.is_nan() || relative > RESIDUAL_TOL {
        return Err(RiccatiError::ResidualTooLarge { relative });
    }
    if !is_stable(&closed_loop(&X)?, domain) {
        return Err(RiccatiError::NotStabilizing);
    }
    Ok(X)
}

/// Continuous LQR: `K = R^-1 B' X` with `X` from [`care`]; `u = -K x`.
///
/// Returns `(K, X)`.
pub fn lqr_continuous<const N: usize, const M: usize>(
    A: &SMatrix<f64, N, N>,
    B: &SMatrix<f64, N, M>,
    Q: &SMatrix<f64, N, N>,
    R: &SMatrix<f64, M, M>,
) -> Result<(SMatrix<f64, M, N>, SMatrix<f64, N, N>), RiccatiError> {
    let X = care(A, B, Q, R)?;
    let chol = Cholesky::new(symmetrize(R)).ok_or(RiccatiError::RNotPositiveDefinite)?;
    // K = R^-1 (B' X), by a Cholesky solve.
    let K = chol.solve(&(B.transpose() * X));
    Ok((K, X))
}

/// Discrete LQR: `K = (R + B'XB)^-1 B'XA` with `X` from [`dare`];
/// `u_k = -K x_k`. Returns `(K, X)`.
pub fn lqr_discrete<const N: usize, const M: usize>(
    A: &SMatrix<f64, N, N>,
    B: &SMatrix<f64, N, M>,
    Q: &SMatrix<f64, N, N>,
    R: &SMatrix<f64, M, M>,
) -> Result<(SMatrix<f64, M, N>, SMatrix<f64, N, N>), RiccatiError> {
    let X = dare(A, B, Q, R)?;
    let K = dare_gain(A, B, &symmetrize(R), &X).ok_or(RiccatiError::NoConvergence)?;
    Ok((K, X))
}

// ---------------------------------------------------------------------------
// Residuals
// ---------------------------------------------------------------------------

/// Relative CARE residual of a candidate `X`:
///
/// `||A'X + XA - X G X + Q||_F / (||Q||_F + 2 ||A'X||_F + ||X G X||_F)`,
/// `G = B R^-1 B'`. The denominator is the size of the terms, so the value
/// is scale invariant and near machine precision for a backward-stable
/// solution. Returns `f64::INFINITY` if `R` is not positive definite, and
/// `0` for an all-zero equation.
pub fn care_residual<const N: usize, const M: usize>(
    A: &SMatrix<f64, N, N>,
    B: &SMatrix<f64, N, M>,
    Q: &SMatrix<f64, N, N>,
    R: &SMatrix<f64, M, M>,
    X: &SMatrix<f64, N, N>,
) -> f64 {
    let Some(G) = input_gramian(B, R) else {
        return f64::INFINITY;
    };
    let AtX = A.transpose() * X;
    let XGX = X * G * X;
    // A'X + XA - XGX + Q, with XA = (A'X)' for symmetric X.
    let res = AtX + AtX.transpose() - XGX + Q;
    let scale = Q.norm() + 2.0 * AtX.norm() + XGX.norm();
    relative(res.norm(), scale)
}

/// Relative DARE residual of a candidate `X`:
///
/// `||A'XA - X - A'XB (R + B'XB)^-1 B'XA + Q||_F /
///  (||Q||_F + ||X||_F + ||A'XA||_F + ||A'XB (R + B'XB)^-1 B'XA||_F)`.
/// Returns `f64::INFINITY` if `R + B'XB` is not positive definite.
pub fn dare_residual<const N: usize, const M: usize>(
    A: &SMatrix<f64, N, N>,
    B: &SMatrix<f64, N, M>,
    Q: &SMatrix<f64, N, N>,
    R: &SMatrix<f64, M, M>,
    X: &SMatrix<f64, N, N>,
) -> f64 {
    let AtXA = A.transpose() * X * A;
    let BtXA = B.transpose() * X * A;
    let Some(chol) = Cholesky::new(symmetrize(&(R + B.transpose() * X * B))) else {
        return f64::INFINITY;
    };
    // A'XB (R + B'XB)^-1 B'XA = (B'XA)' S^-1 (B'XA).
    let corr = BtXA.transpose() * chol.solve(&BtXA);
    let res = AtXA - X - corr + Q;
    let scale = Q.norm() + X.norm() + AtXA.norm() + corr.norm();
    relative(res.norm(), scale)
}

/// `num / den`, with `0 / 0 = 0`.
fn relative(num: f64, den: f64) -> f64 {
    if num == 0.0 {
        0.0
    } else {
        num / den
    }
}

// ---------------------------------------------------------------------------
// Equations of the algorithm
// ---------------------------------------------------------------------------

/// `G = B R^-1 B'` (symmetrised), by a Cholesky solve with `R`.
/// `None` if `R` is not positive definite.
fn input_gramian<const N: usize, const M: usize>(
    B: &SMatrix<f64, N, M>,
    R: &SMatrix<f64, M, M>,
) -> Option<SMatrix<f64, N, N>> {
    let chol = Cholesky::new(symmetrize(R))?;
    // R^-1 B'
    let RinvBt = chol.solve(&B.transpose());
    Some(symmetrize(&(B * RinvBt)))
}

/// Discrete gain `K = (R + B'XB)^-1 B'XA` by a Cholesky solve.
fn dare_gain<const N: usize, const M: usize>(
    A: &SMatrix<f64, N, N>,
    B: &SMatrix<f64, N, M>,
    R: &SMatrix<f64, M, M>,
    X: &SMatrix<f64, N, N>,
) -> Option<SMatrix<f64, M, N>> {
    let chol = Cholesky::new(symmetrize(&(R + B.transpose() * X * B)))?;
    Some(chol.solve(&(B.transpose() * X * A)))
}

/// Cayley shift for the CARE:
/// `gamma = max(2 ||A||_F, sqrt(||G||_F ||Q||_F))`.
///
/// Why: every eigenvalue of `A` has `|lambda| <= ||A||_2 <= ||A||_F`, so
/// `gamma >= 2 ||A||_F` gives `sigma_min(A - gamma I) >= gamma - ||A||_2 >=
/// gamma / 2` and `cond_2(A - gamma I) <= 3`: the shifted matrix is always
/// safely invertible. When `A` is small against the coupling
/// (`A = 0` gives closed-loop eigenvalues of size `sqrt(||G|| ||Q||)`),
/// the second term puts `gamma` on the scale of the closed-loop spectrum,
/// which keeps the Cayley spectral radius `max |(lambda + gamma) /
/// (lambda - gamma)|` away from 1. The input checks guarantee `gamma > 0`
/// (`A = 0` with `Q = 0` or `B = 0` is not detectable / stabilisable); a
/// positive floor covers the unchecked path.
fn cayley_shift<const N: usize>(
    A: &SMatrix<f64, N, N>,
    G: &SMatrix<f64, N, N>,
    Q: &SMatrix<f64, N, N>,
) -> f64 {
    let g = (2.0 * A.norm()).max(libm::sqrt(G.norm() * Q.norm()));
    if g > 0.0 {
        g
    } else {
        1.0
    }
}

/// SDA initial values for the CARE `A'X + XA - XGX + H = 0` (Cayley
/// transform with shift `gamma`; Chu, Fan and Lin 2005):
///
/// * `A_g = A - gamma I`
/// * `W = A_g' + H A_g^-1 G`   (note `V = A_g + G A_g^-T H = W'`)
/// * `A0 = I + 2 gamma V^-1 = V^-1 (V + 2 gamma I)`
/// * `G0 = 2 gamma A_g^-1 G W^-1`
/// * `H0 = 2 gamma W^-1 H A_g^-1`
///
/// after which `X` solves the DARE form `X = H0 + A0' X (I + G0 X)^-1 A0`.
/// `None` if `A_g` or `W` is singular.
fn care_sda_initial<const N: usize>(
    A: &SMatrix<f64, N, N>,
    G: &SMatrix<f64, N, N>,
    H: &SMatrix<f64, N, N>,
    gamma: f64,
) -> Option<(SMatrix<f64, N, N>, SMatrix<f64, N, N>, SMatrix<f64, N, N>)> {
    let I = SMatrix::<f64, N, N>::identity();
    // A_g = A - gamma I
    let Ag = A - I * gamma;
    let Ag_lu = Lu::new(&Ag)?;
    let Agt_lu = Lu::new(&Ag.transpose())?;
    // W = A_g' + H (A_g^-1 G)
    let W = Ag.transpose() + H * Ag_lu.solve(G);
    let V = W.transpose();
    let W_lu = Lu::new(&W)?;
    let V_lu = Lu::new(&V)?;
    // A0 = V^-1 (V + 2 gamma I)
    let A0 = V_lu.solve(&(V + I * (2.0 * gamma)));
    // G W^-1 = (W^-T G)' = (V^-1 G)'  (G symmetric); G0 = 2 gamma A_g^-1 (G W^-1)
    let GWinv = V_lu.solve(G).transpose();
    let G0 = symmetrize(&(Ag_lu.solve(&GWinv) * (2.0 * gamma)));
    // H A_g^-1 = (A_g^-T H)'  (H symmetric); H0 = 2 gamma W^-1 (H A_g^-1)
    let HAginv = Agt_lu.solve(H).transpose();
    let H0 = symmetrize(&(W_lu.solve(&HAginv) * (2.0 * gamma)));
    if all_finite(&A0) && all_finite(&G0) && all_finite(&H0) {
        Some((A0, G0, H0))
    } else {
        None
    }
}

/// Structure-preserving doubling for `X = H + A' X (I + G X)^-1 A`:
///
/// * `W_k = I + G_k H_k`
/// * `A_{k+1} = A_k W_k^-1 A_k`
/// * `G_{k+1} = G_k + A_k W_k^-1 G_k A_k'`
/// * `H_{k+1} = H_k + A_k' H_k W_k^-1 A_k`
///
/// `H_k -> X` quadratically. `G_k`, `H_k` are symmetrised every step. Stops
/// when `||H_{k+1} - H_k||_F <= 4 eps ||H_{k+1}||_F`.
fn sda<const N: usize>(
    A0: &SMatrix<f64, N, N>,
    G0: &SMatrix<f64, N, N>,
    H0: &SMatrix<f64, N, N>,
    max_iterations: usize,
) -> Result<SMatrix<f64, N, N>, RiccatiError> {
    let I = SMatrix::<f64, N, N>::identity();
    let (mut A, mut G, mut H) = (*A0, *G0, *H0);
    for _ in 0..max_iterations {
        // W = I + G H, factorised once for both solves.
        let W_lu = Lu::new(&(I + G * H)).ok_or(RiccatiError::NoConvergence)?;
        // W^-1 A_k and W^-1 G_k
        let WinvA = W_lu.solve(&A);
        let WinvG = W_lu.solve(&G);
        let A_next = A * WinvA;
        let G_next = symmetrize(&(G + A * WinvG * A.transpose()));
        let H_next = symmetrize(&(H + A.transpose() * H * WinvA));
        if !(all_finite(&A_next) && all_finite(&G_next) && all_finite(&H_next)) {
            return Err(RiccatiError::NoConvergence);
        }
        let change = (H_next - H).norm();
        A = A_next;
        G = G_next;
        H = H_next;
        if change <= 4.0 * f64::EPSILON * H.norm() {
            return Ok(H);
        }
    }
    Err(RiccatiError::NoConvergence)
}

// ---------------------------------------------------------------------------
// Input checks
// ---------------------------------------------------------------------------

/// Checks the inputs in order (finite, symmetric, definite, stabilisable,
/// detectable) and returns symmetrised `Q`, `R` and `G = B R^-1 B'`.
fn prepare<const N: usize, const M: usize>(
    A: &SMatrix<f64, N, N>,
    B: &SMatrix<f64, N, M>,
    Q: &SMatrix<f64, N, N>,
    R: &SMatrix<f64, M, M>,
    domain: Domain,
    check: bool,
) -> Result<Prepared<N, M>, RiccatiError> {
    const {
        assert!(N >= 1 && N <= MAX_STATES, "N must be in 1..=6");
        assert!(M >= 1 && M <= N, "M must be in 1..=N");
    };
    let finite = [
        (Argument::A, all_finite(A)),
        (Argument::B, all_finite(B)),
        (Argument::Q, all_finite(Q)),
        (Argument::R, all_finite(R)),
    ];
    if let Some(&(argument, _)) = finite.iter().find(|(_, ok)| !ok) {
        return Err(RiccatiError::NonFinite(argument));
    }
    let symmetric = [
        (Argument::Q, is_symmetric(Q)),
        (Argument::R, is_symmetric(R)),
    ];
    if let Some(&(argument, _)) = symmetric.iter().find(|(_, ok)| !ok) {
        return Err(RiccatiError::NotSymmetric(argument));
    }
    let Qs = symmetrize(Q);
    let Rs = symmetrize(R);
    if check {
        if !is_positive_semidefinite(&Qs) {
            return Err(RiccatiError::QNotPositiveSemidefinite);
        }
        if !is_positive_definite(&Rs) {
            return Err(RiccatiError::RNotPositiveDefinite);
        }
    }
    let G = input_gramian(B, &Rs).ok_or(RiccatiError::RNotPositiveDefinite)?;
    if check {
        let eig = eigenvalues(A).ok_or(RiccatiError::NoConvergence)?;
        let a_norm = A.norm();
        for &lambda in eig.iter() {
            if !needs_pbh(lambda, a_norm, domain) {
                continue;
            }
            if !pbh_controllable(A, B, lambda) {
                return Err(RiccatiError::NotStabilizable);
            }
        }
        for &lambda in eig.iter() {
            if !needs_pbh(lambda, a_norm, domain) {
                continue;
            }
            if !pbh_observable(A, &Qs, lambda) {
                return Err(RiccatiError::NotDetectable);
            }
        }
    }
    Ok(Prepared { Q: Qs, R: Rs, G })
}

/// Unstable or marginal: continuous `Re(lambda) >= -MARGINAL_TOL ||A||_F`,
/// discrete `|lambda| >= 1 - MARGINAL_TOL`.
fn needs_pbh(lambda: Complex<f64>, a_norm: f64, domain: Domain) -> bool {
    match domain {
        Domain::Continuous => lambda.re >= -MARGINAL_TOL * a_norm,
        Domain::Discrete => libm::hypot(lambda.re, lambda.im) >= 1.0 - MARGINAL_TOL,
    }
}

/// PBH controllability of mode `lambda`: `sigma_min([A - lambda I, B]) >
/// PBH_TOL s`, `s^2 = ||A||_F^2 + ||B||_F^2`.
///
/// `sigma_min^2` is `lambda_min` of the Hermitian
/// `(A - lambda I)(A - lambda I)^H + B B'`, so the test is whether that
/// matrix minus `(PBH_TOL s)^2 I` is positive definite.
fn pbh_controllable<const N: usize, const M: usize>(
    A: &SMatrix<f64, N, N>,
    B: &SMatrix<f64, N, M>,
    lambda: Complex<f64>,
) -> bool {
    let Al = shifted(A, lambda);
    let Bc = B.map(|v| Complex::new(v, 0.0));
    let s2 = A.norm_squared() + B.norm_squared();
    let delta = PBH_TOL * PBH_TOL * s2;
    let H =
        Al * Al.adjoint() + Bc * Bc.adjoint() - complex_identity::<N>() * Complex::new(delta, 0.0);
    hermitian_positive_definite(&H)
}

/// PBH observability of mode `lambda` through `Q = C'C`:
/// `sigma_min([A - lambda I; C]) > PBH_TOL s`, `s^2 = ||A||_F^2 + ||Q||_F`.
///
/// `sigma_min^2` is `lambda_min` of `(A - lambda I)^H (A - lambda I) + Q`
/// (`C'C = Q`, so no factor of `Q` is needed).
fn pbh_observable<const N: usize>(
    A: &SMatrix<f64, N, N>,
    Q: &SMatrix<f64, N, N>,
    lambda: Complex<f64>,
) -> bool {
    let Al = shifted(A, lambda);
    let Qc = Q.map(|v| Complex::new(v, 0.0));
    let s2 = A.norm_squared() + Q.norm();
    let delta = PBH_TOL * PBH_TOL * s2;
    let H = Al.adjoint() * Al + Qc - complex_identity::<N>() * Complex::new(delta, 0.0);
    hermitian_positive_definite(&H)
}

/// `A - lambda I` as a complex matrix.
fn shifted<const N: usize>(
    A: &SMatrix<f64, N, N>,
    lambda: Complex<f64>,
) -> SMatrix<Complex<f64>, N, N> {
    A.map(|v| Complex::new(v, 0.0)) - complex_identity::<N>() * lambda
}

/// The complex `N x N` identity.
fn complex_identity<const N: usize>() -> SMatrix<Complex<f64>, N, N> {
    SMatrix::<Complex<f64>, N, N>::identity()
}

/// Strictly stable: every eigenvalue has `Re < 0` (continuous) or
/// `|lambda| < 1` (discrete). `false` if the eigenvalues cannot be computed.
fn is_stable<const N: usize>(A: &SMatrix<f64, N, N>, domain: Domain) -> bool {
    let Some(eig) = eigenvalues(A) else {
        return false;
    };
    eig.iter().all(|l| match domain {
        Domain::Continuous => l.re < 0.0,
        Domain::Discrete => libm::hypot(l.re, l.im) < 1.0,
    })
}

/// Eigenvalues of `A` via nalgebra's real Schur decomposition, in the first
/// `N` entries; the other `6 - N` entries are the padding value `-0.5`,
/// strictly stable in both continuous and discrete time, so they never
/// trigger a PBH test nor fail a stability check.
///
/// nalgebra's `Schur` needs `Const<N>: DimSub<U1>`, which generic code
/// cannot state without typenum where-clauses on every caller, so `A` is
/// copied into a matrix of the same, concrete size (one arm per `N`; a
/// `6 x 6` embedding of every `A` used to cost a 2-state solve most of its
/// time). Returns `None` if the QR iteration does not converge.
pub fn eigenvalues<const N: usize>(A: &SMatrix<f64, N, N>) -> Option<[Complex<f64>; MAX_STATES]> {
    const { assert!(N >= 1 && N <= MAX_STATES, "N must be in 1..=6") };
    let mut out = [Complex::new(PAD_EIGENVALUE, 0.0); MAX_STATES];
    let converged = match N {
        1 => {
            out[0] = Complex::new(A[(0, 0)], 0.0);
            true
        }
        2 => schur_eigenvalues::<N, 2>(A, &mut out),
        3 => schur_eigenvalues::<N, 3>(A, &mut out),
        4 => schur_eigenvalues::<N, 4>(A, &mut out),
        5 => schur_eigenvalues::<N, 5>(A, &mut out),
        _ => schur_eigenvalues::<N, 6>(A, &mut out),
    };
    let finite = out.iter().all(|l| l.re.is_finite() && l.im.is_finite());
    (converged && finite).then_some(out)
}

/// The eigenvalues of `A` (`N == K`) from the real Schur form of its
/// `K x K` copy, written to `out[..K]`. `false` if the QR iteration does not
/// converge.
fn schur_eigenvalues<const N: usize, const K: usize>(
    A: &SMatrix<f64, N, N>,
    out: &mut [Complex<f64>; MAX_STATES],
) -> bool
where
    Const<K>: DimSub<U1>,
    DefaultAllocator: Allocator<Const<K>, DimDiff<Const<K>, U1>> + Allocator<DimDiff<Const<K>, U1>>,
{
    let m = SMatrix::<f64, K, K>::from_fn(|i, j| A.get((i, j)).copied().unwrap_or(0.0));
    let Some(schur) = Schur::try_new(m, f64::EPSILON, 10_000) else {
        return false;
    };
    for (o, e) in out.iter_mut().zip(schur.complex_eigenvalues().iter()) {
        *o = *e;
    }
    true
}

// ---------------------------------------------------------------------------
// Agent gains (eq.LQRrobot / eq.LQRhuman, reduced problem)
// ---------------------------------------------------------------------------

/// Each agent's LQR gains `[k_pos, k_vel]` (eq.LQRrobot, eq.LQRhuman).
///
/// The paper states the LQR on the 3-state `[x - tau, xdot, x - tau_h]`,
/// whose `(A, B)` is not stabilisable (mode 0 with left eigenvector
/// `[1, 0, -1]`), so no stabilising CARE solution exists there. Each agent
/// instead solves the reduced 2-state problem on `[x - target, xdot]`:
/// `A = [[0, 1], [0, -C/M]]`, `B = [0, 1/M]'`, `Q = diag(q_pos, q_vel)`,
/// `R = 1`, `K = B'X`. For `C = 0` this has the closed form
/// `k_pos = sqrt(q_pos)`, `k_vel = sqrt(q_vel + 2 M sqrt(q_pos))`.
///
/// `mass > 0`, `damping >= 0`, `q_pos > 0`, `q_vel >= 0`, all finite;
/// `q_vel = 0` is fine (the position weight makes `(Q, A)` detectable).
pub fn agent_gains(
    mass: f64,
    damping: f64,
    q_pos: f64,
    q_vel: f64,
) -> Result<[f64; 2], RiccatiError> {
    if !(mass.is_finite() && mass > 0.0) {
        return Err(RiccatiError::InvalidAgentParameter(AgentParameter::Mass));
    }
    if !(damping.is_finite() && damping >= 0.0) {
        return Err(RiccatiError::InvalidAgentParameter(AgentParameter::Damping));
    }
    if !(q_pos.is_finite() && q_pos > 0.0) {
        return Err(RiccatiError::InvalidAgentParameter(AgentParameter::QPos));
    }
    if !(q_vel.is_finite() && q_vel >= 0.0) {
        return Err(RiccatiError::InvalidAgentParameter(AgentParameter::QVel));
    }
    // B = 1/M and A's C/M must be finite too.
    if !(1.0 / mass).is_finite() {
        return Err(RiccatiError::InvalidAgentParameter(AgentParameter::Mass));
    }
    if !(damping / mass).is_finite() {
        return Err(RiccatiError::InvalidAgentParameter(AgentParameter::Damping));
    }
    let A = SMatrix::<f64, 2, 2>::new(0.0, 1.0, 0.0, -damping / mass);
    let B = SMatrix::<f64, 2, 1>::new(0.0, 1.0 / mass);
    let Q = SMatrix::<f64, 2, 2>::new(q_pos, 0.0, 0.0, q_vel);
    let R = SMatrix::<f64, 1, 1>::new(1.0);
    let (K, _) = lqr_continuous(&A, &B, &Q, &R)?;
    Ok([K[(0, 0)], K[(0, 1)]])
}

/// The robot's gain on the paper's state `[x - tau, xdot, x - tau_h]`
/// (eq.LQRrobot): `L = [k_pos, k_vel, 0]`, from [`agent_gains`]' output.
pub fn robot_gain_vector(gains: [f64; 2]) -> [f64; 3] {
    [gains[0], gains[1], 0.0]
}

/// The partner's gain on `[x - tau, xdot, x - tau_h]` (eq.LQRhuman):
/// `L_h = [0, k_vel, k_pos]`, from [`agent_gains`]' output.
pub fn partner_gain_vector(gains: [f64; 2]) -> [f64; 3] {
    [0.0, gains[1], gains[0]]
}

// ---------------------------------------------------------------------------
// Runtime shapes (for callers without the dimensions in their types: Python)
// ---------------------------------------------------------------------------

/// A matrix whose shape is known only at run time: `rows x cols` entries,
/// row-major, in `data`.
#[derive(Clone, Copy, Debug)]
pub struct DenseMatrix<'a> {
    /// The entries, row-major (`rows * cols` of them).
    pub data: &'a [f64],
    /// `(rows, cols)`.
    pub shape: [usize; 2],
}

impl DenseMatrix<'_> {
    fn fixed<const R: usize, const C: usize>(&self) -> SMatrix<f64, R, C> {
        SMatrix::from_fn(|i, j| self.data[i * self.shape[1] + j])
    }
}

/// [`lqr_dense`]'s solution: `K` (`m x n`) and `X` (`n x n`), row-major.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DenseLqr {
    /// States.
    pub n: usize,
    /// Inputs.
    pub m: usize,
    k: [f64; MAX_STATES * MAX_STATES],
    x: [f64; MAX_STATES * MAX_STATES],
}

impl DenseLqr {
    /// The gain `K`, `m x n`, row-major.
    pub fn k(&self) -> &[f64] {
        &self.k[..self.m * self.n]
    }

    /// The Riccati solution `X`, `n x n`, row-major.
    pub fn x(&self) -> &[f64] {
        &self.x[..self.n * self.n]
    }
}

/// `(n, m)` from the shapes of `A` and `B`, with `Q` and `R` checked
/// against them (and every `data` against its shape).
fn dense_dims(args: [&DenseMatrix<'_>; 4]) -> Result<(usize, usize), RiccatiError> {
    let [a, b, q, r] = args;
    let (n, m) = (a.shape[0], b.shape[1]);
    for (arg, argument, want, ok) in [
        (a, Argument::A, [n, n], (1..=MAX_STATES).contains(&n)),
        (b, Argument::B, [n, m], (1..=n).contains(&m)),
        (q, Argument::Q, [n, n], true),
        (r, Argument::R, [m, m], true),
    ] {
        let whole = arg.data.len() == arg.shape[0] * arg.shape[1];
        if arg.shape != want || !ok || !whole {
            let got = arg.shape;
            return Err(RiccatiError::Shape {
                argument,
                got,
                n,
                m,
            });
        }
    }
    Ok((n, m))
}

/// [`lqr_continuous`] (or with `discrete` [`lqr_discrete`]) on matrices of
/// runtime shape, `1 <= m <= n <= MAX_STATES`: the shapes are checked, then
/// the fixed-size solver for `(n, m)` runs.
pub fn lqr_dense(
    A: DenseMatrix<'_>,
    B: DenseMatrix<'_>,
    Q: DenseMatrix<'_>,
    R: DenseMatrix<'_>,
    discrete: bool,
) -> Result<DenseLqr, RiccatiError> {
    fn solve<const N: usize, const M: usize>(
        [a, b, q, r]: [DenseMatrix<'_>; 4],
        discrete: bool,
    ) -> Result<DenseLqr, RiccatiError> {
        let (A, B) = (a.fixed::<N, N>(), b.fixed::<N, M>());
        let (Q, R) = (q.fixed::<N, N>(), r.fixed::<M, M>());
        let (K, X) = match discrete {
            true => lqr_discrete(&A, &B, &Q, &R)?,
            false => lqr_continuous(&A, &B, &Q, &R)?,
        };
        let mut out = DenseLqr {
            n: N,
            m: M,
            k: [0.0; MAX_STATES * MAX_STATES],
            x: [0.0; MAX_STATES * MAX_STATES],
        };
        for (i, j) in (0..M).flat_map(|i| (0..N).map(move |j| (i, j))) {
            out.k[i * N + j] = K[(i, j)];
        }
        for (i, j) in (0..N).flat_map(|i| (0..N).map(move |j| (i, j))) {
            out.x[i * N + j] = X[(i, j)];
        }
        Ok(out)
    }
    let args = [A, B, Q, R];
    let (n, m) = dense_dims([&A, &B, &Q, &R])?;
    // One match arm per `(n, m)`: `inputs!(n; m...)` dispatches the inputs.
    macro_rules! inputs {
        ($n:literal; $($m:literal)*) => {
            match m {
                $($m => solve::<$n, $m>(args, discrete),)*
                _ => Err(RiccatiError::Shape { argument: Argument::B, got: B.shape, n, m }),
            }
        };
    }
    match n {
        1 => inputs!(1; 1),
        2 => inputs!(2; 1 2),
        3 => inputs!(3; 1 2 3),
        4 => inputs!(4; 1 2 3 4),
        5 => inputs!(5; 1 2 3 4 5),
        6 => inputs!(6; 1 2 3 4 5 6),
        _ => Err(RiccatiError::Shape {
            argument: Argument::A,
            got: A.shape,
            n,
            m,
        }),
    }
}
