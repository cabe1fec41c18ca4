//! The three partner estimators of the paper (section "Estimation of human's
//! control" and "Goal integration"), each a UKF on the reference discrete
//! model of `docs/model.md`.
//!
//! Written from the robot's side: "own" is the agent running the estimator,
//! "partner" the agent being identified. The same code serves a human model
//! that estimates the robot: give it the mirrored state order
//! (`[x - tau_h, xdot, x - tau]`), its own torque and the targets swapped
//! (`identifier::Identifier` runs stages 1 and 2 this way for either agent).
//!
//! Per tick the caller runs: `update` with `y_k`, reads the posterior,
//! computes its command `u_k`, then `predict` with `u_k` and the targets'
//! increments `tau[k+1] - tau[k]` (0 for a target the agent does not know).

use crate::linalg::{is_positive_semidefinite, is_symmetric};
use crate::ukf::{
    Arg, BilinearForm, BilinearProcess, MerweParams, Selection, Status, Ukf, UkfError,
};
use nalgebra::{SMatrix, SVector, Vector2, Vector3};

/// Extended state (eq.state-extended): `[e, v, e_h, Lhx, Lhv, Lhh]` with
/// `e = x - tau`, `v = xdot`, `e_h = x - tau_h`.
pub type Extended = SVector<f64, 6>;
/// 6x6 covariance of the extended state.
pub type Cov6 = SMatrix<f64, 6, 6>;

/// Index of `x - tau_h` in [`Extended`].
pub const E_H: usize = 2;
/// Index of the first partner gain in [`Extended`].
pub const GAINS: usize = 3;

/// The estimator's model of the handle; may differ from the true plant.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HandleModel {
    /// Inertia `M`, > 0.
    pub mass: f64,
    /// Viscous damping `C`, >= 0.
    pub damping: f64,
    /// Step `dt` (s), > 0.
    pub dt_s: f64,
}

impl HandleModel {
    /// Checks every field; `Err` names the first bad one.
    pub fn validate(&self) -> Result<(), EstimatorError> {
        let bad = |name| Err(EstimatorError::InvalidModel(name));
        if !(self.mass.is_finite() && self.mass > 0.0) {
            return bad("mass");
        }
        if !(self.damping.is_finite() && self.damping >= 0.0) {
            return bad("damping");
        }
        if !(self.dt_s.is_finite() && self.dt_s > 0.0) {
            return bad("dt_s");
        }
        // A step whose coefficients overflow would turn every state into
        // inf or NaN: dt^2 is dt's fault, dt / M and dt^2 / M the mass's,
        // the rest (dt^2 C / M, dt C / M) the damping's.
        let dt = self.dt_s;
        let s = self.step();
        if !(dt * dt).is_finite() {
            return bad("dt_s");
        }
        if !(s.dx_f.is_finite() && s.v_f.is_finite()) {
            return bad("mass");
        }
        if !(s.dx_v.is_finite() && s.v_v.is_finite()) {
            return bad("damping");
        }
        Ok(())
    }

    /// One step of `M a = f - C v` with the acceleration held,
    /// `dx = dt v + dt^2 a / 2`, `v' = v + dt a` (exact for `C = 0`: the
    /// zero-order hold of the double integrator), as a linear map of `v`
    /// and `f` ([`Step`]).
    pub fn step(&self) -> Step {
        let (dt, m, c) = (self.dt_s, self.mass, self.damping);
        let (dx_f, v_f) = (0.5 * dt * dt / m, dt / m);
        Step {
            dx_v: dt - dx_f * c,
            dx_f,
            v_v: 1.0 - v_f * c,
            v_f,
        }
    }
}

/// [`HandleModel::step`] written out: with `a = (f - C v) / M`,
/// `dx = dx_v v + dx_f f` and `v' = v_v v + v_f f`, where
/// `dx_f = dt^2 / (2 M)`, `dx_v = dt - dx_f C`, `v_f = dt / M`,
/// `v_v = 1 - v_f C`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Step {
    /// `d dx / d v`.
    pub dx_v: f64,
    /// `d dx / d f`.
    pub dx_f: f64,
    /// `d v' / d v`.
    pub v_v: f64,
    /// `d v' / d f`.
    pub v_f: f64,
}

/// Set-up errors of an estimator; each names the argument as the
/// estimator's configuration spells it (`x0`, `P0`, `Q`, `R`, the model's
/// fields, `alpha`, `beta`, `kappa`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EstimatorError {
    /// A field of [`HandleModel`] (or a stage-3 setting,
    /// [`GoalIntegratorConfig`](crate::goal::GoalIntegratorConfig)) is out
    /// of range, or makes the model's step overflow.
    InvalidModel(&'static str),
    /// The underlying UKF rejected its set-up (names the argument).
    Ukf(UkfError),
    /// A covariance (`P0`, `Q` or `R`) is not symmetric within
    /// [`SYMMETRY_TOL`](crate::linalg::SYMMETRY_TOL).
    NotSymmetric(Arg),
    /// A noise covariance (`Q` or `R`) has a negative eigenvalue (beyond
    /// [`DEFINITENESS_TOL`](crate::linalg::DEFINITENESS_TOL)): a negative
    /// variance.
    NotPositiveSemidefinite(Arg),
}

impl EstimatorError {
    /// The estimator's name for a UKF argument: the initial state and
    /// covariance are `x0` and `P0`.
    fn arg(which: Arg) -> &'static str {
        match which {
            Arg::X => "x0",
            Arg::P => "P0",
            other => other.name(),
        }
    }
}

impl core::fmt::Display for EstimatorError {
    /// The argument first, then what is wrong and how to fix it.
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match *self {
            EstimatorError::InvalidModel(field) => f.write_str(match field {
                "mass" => {
                    "mass: must be finite and > 0 (the handle's inertia), and large enough \
                     that dt / mass and dt^2 / mass are finite"
                }
                "damping" => {
                    "damping: must be finite and >= 0 (viscous damping), and small enough \
                     that damping * dt / mass is finite"
                }
                "dt_s" => "dt_s: must be finite and > 0 (the step, s), with dt^2 finite",
                "stage3.Q_e" => {
                    "Q: its (0, 0) entry must be finite and > 0 (stage 3's random walk of \
                     x - tau per step, standing for the unknown target motion)"
                }
                "stage3.R_e" => {
                    "R: its (0, 0) entry must be finite and > 0 (the own view's variance of \
                     x - tau), and within a factor 1e300 of Q's"
                }
                "gate" => {
                    "gate: must be finite and > 0 (the change-point test's threshold, \
                     standard deviations; 4 is the default)"
                }
                "window_n0" => {
                    "window_n0: must be finite and > 0 (the score window's scale, \
                     ticks; 80 is the default)"
                }
                "hold_max_s" => {
                    "hold_max_s: must be finite and > 0 (the longest suspension of \
                     the partner channel after a target jump, s; 0.25 is the default)"
                }
                other => other,
            }),
            EstimatorError::Ukf(UkfError::NonFiniteArgument { which }) => {
                write!(f, "{}: must be finite (no NaN or inf)", Self::arg(which))
            }
            EstimatorError::Ukf(UkfError::NotPositiveDefinite { which }) => write!(
                f,
                "{}: must be symmetric positive definite; raise its diagonal",
                Self::arg(which)
            ),
            EstimatorError::Ukf(other) => other.fmt(f),
            EstimatorError::NotSymmetric(which) => write!(
                f,
                "{0}: must be symmetric; pass ({0} + {0}.T) / 2",
                Self::arg(which)
            ),
            EstimatorError::NotPositiveSemidefinite(which) => write!(
                f,
                "{}: must be positive semidefinite (a covariance: no negative variance, no \
                 negative eigenvalue); raise its diagonal",
                Self::arg(which)
            ),
        }
    }
}

/// The covariances' shape of a UKF set-up the filter itself does not check:
/// `P0` symmetric (the filter reads one triangle), `Q` and `R` symmetric
/// and positive semidefinite (the filter accepts any finite `Q`, `R`).
/// Run after [`Ukf::new`], which checks that all are finite.
fn check_covariances<const N: usize, const M: usize>(
    P0: &SMatrix<f64, N, N>,
    Q: &SMatrix<f64, N, N>,
    R: &SMatrix<f64, M, M>,
) -> Result<(), EstimatorError> {
    if !is_symmetric(P0) {
        return Err(EstimatorError::NotSymmetric(Arg::P));
    }
    if !is_symmetric(Q) {
        return Err(EstimatorError::NotSymmetric(Arg::Q));
    }
    if !is_positive_semidefinite(Q) {
        return Err(EstimatorError::NotPositiveSemidefinite(Arg::Q));
    }
    if !is_symmetric(R) {
        return Err(EstimatorError::NotSymmetric(Arg::R));
    }
    if !is_positive_semidefinite(R) {
        return Err(EstimatorError::NotPositiveSemidefinite(Arg::R));
    }
    Ok(())
}

/// A predict's inputs `inputs` (named `names`) all finite, or
/// [`UkfError::NonFiniteInput`]: the filter would reject them as a
/// non-finite process, a step failure, where this is the caller's mistake.
pub(crate) fn finite_inputs(inputs: &[f64], names: &'static str) -> Result<(), UkfError> {
    match inputs.iter().all(|v| v.is_finite()) {
        true => Ok(()),
        false => Err(UkfError::NonFiniteInput { names }),
    }
}

impl From<UkfError> for EstimatorError {
    fn from(e: UkfError) -> Self {
        EstimatorError::Ukf(e)
    }
}

/// The partner's control (eq.LQRhuman) without its sign, a bilinear form of
/// the extended state: `Lhx e + Lhv v + Lhh e_h`.
pub const PARTNER_CONTROL: BilinearForm<6, 3> =
    match BilinearForm::new([(GAINS, 0), (GAINS + 1, 1), (GAINS + 2, E_H)]) {
        Some(q) => q,
        None => panic!("partner control index out of range"),
    };

/// Partner torque (eq.LQRhuman) from the extended state:
/// `u_h = -(Lhx e + Lhv v + Lhh e_h)`.
pub fn partner_torque(z: &Extended) -> f64 {
    -PARTNER_CONTROL.eval(z)
}

/// Discrete process model of the extended state (eq.system-extended,
/// discretised as in docs/model.md) as a [`BilinearProcess`]:
/// `a = (u + u_h - C v)/M`, `dx = dt v + dt^2 a/2`,
/// `e' = e + dx - dtau`, `v' = v + dt a`, `e_h' = e_h + dx - dtau_h`, `L' = L`.
///
/// With the step written out ([`HandleModel::step`]) and `u_h = -q`
/// (`q` = [`PARTNER_CONTROL`]), `dx = dx_v v + dx_f (u - q)` and
/// `v' = v_v v + v_f (u - q)`, so the moving rows are
/// `[e', v', e_h'] = F z + b + g q(z)` with
/// `F = [[1, dx_v, 0, 0, 0, 0], [0, v_v, 0, 0, 0, 0], [0, dx_v, 1, 0, 0, 0]]`,
/// `b = [dx_f u - dtau, v_f u, dx_f u - dtau_h]`, `g = [-dx_f, -v_f, -dx_f]`;
/// the gains are constant (`Ukf::predict_bilinear` exploits both).
pub fn extended_transition(
    step: &Step,
    u: f64,
    dtau: f64,
    dtau_h: f64,
) -> BilinearProcess<6, 3, 3> {
    let (F, b, g) = motion_rows(step, u, dtau, dtau_h);
    BilinearProcess {
        F,
        b,
        g,
        q: PARTNER_CONTROL,
    }
}

/// The moving rows `[e', v', e_h'] = F z + b + g q` shared by the extended
/// processes ([`extended_transition`], [`delayed_trajectory_transition`]):
/// `F = [[1, dx_v, 0, 0, 0, 0], [0, v_v, 0, 0, 0, 0], [0, dx_v, 1, 0, 0, 0]]`,
/// `b = [dx_f u - dtau, v_f u, dx_f u - dtau_h]`, `g = [-dx_f, -v_f, -dx_f]`
/// (the partner's torque is `-q`). Inlined, so a constant step still folds
/// into the predict's arithmetic ([`GainEstimator::predict`]).
#[inline(always)]
fn motion_rows(
    step: &Step,
    u: f64,
    dtau: f64,
    dtau_h: f64,
) -> (SMatrix<f64, 3, 6>, Vector3<f64>, Vector3<f64>) {
    let Step {
        dx_v,
        dx_f,
        v_v,
        v_f,
    } = *step;
    let mut F = SMatrix::<f64, 3, 6>::zeros();
    F[(0, 0)] = 1.0;
    F[(0, 1)] = dx_v;
    F[(1, 1)] = v_v;
    F[(2, 1)] = dx_v;
    F[(2, E_H)] = 1.0;
    (
        F,
        Vector3::new(dx_f * u - dtau, v_f * u, dx_f * u - dtau_h),
        Vector3::new(-dx_f, -v_f, -dx_f),
    )
}

/// [`extended_transition`] applied to `z`: the next extended state.
pub fn extended_process(
    model: &HandleModel,
    z: &Extended,
    u: f64,
    dtau: f64,
    dtau_h: f64,
) -> Extended {
    extended_transition(&model.step(), u, dtau, dtau_h).apply(z)
}

/// The delay-aware stage-1 process (docs/model.md, "A partner with a
/// delay"): the partner's torque acts on the robot's *measured* sample of
/// `d` ticks ago, `u_h = -(Lhx phi_1 + Lhv phi_2 + Lhh phi_3)` with the
/// regressor `phi = [y_e[k - d_v], y_v[k - d_p], y_eh[k - d_v]]` (data, not
/// state), so the process is affine, `z' = F z + b`: `F = I6` but for rows
/// `e' = [1, dx_v, 0, -dx_f phi]`, `v' = [0, v_v, 0, -v_f phi]`,
/// `e_h' = [0, dx_v, 1, -dx_f phi]`, and
/// `b = [dx_f u - dtau, v_f u, dx_f u - dtau_h, 0, 0, 0]`.
pub fn delayed_transition(
    step: &Step,
    phi: [f64; 3],
    u: f64,
    dtau: f64,
    dtau_h: f64,
) -> (Cov6, Extended) {
    let (rows, b3, g) = motion_rows(step, u, dtau, dtau_h);
    let mut F = Cov6::identity();
    F.fixed_rows_mut::<3>(0).copy_from(&rows);
    for (r, gr) in g.iter().enumerate() {
        for (c, p) in phi.iter().enumerate() {
            F[(r, GAINS + c)] = gr * p;
        }
    }
    let b = Extended::new(b3[0], b3[1], b3[2], 0.0, 0.0, 0.0);
    (F, b)
}

/// The partner's control in the delay-aware stage 2, as a bilinear form:
/// only `Lhh eta` is bilinear (`eta = x - tau_h[k - d_v]`, state entry 2);
/// the other terms multiply known data and enter the transition's gain
/// columns ([`delayed_trajectory_transition`]).
pub const DELAYED_PARTNER_CONTROL: BilinearForm<6, 1> = match BilinearForm::new([(GAINS + 2, E_H)])
{
    Some(q) => q,
    None => panic!("partner control index out of range"),
};

/// The delay-aware stage-2 process (docs/model.md): the partner acts on
/// `phi = [y_e[k - d_v], y_v[k - d_p], eta - s]` with
/// `s = x_m[k] - x_m[k - d_v]`, so
/// `q = Lhh eta + Lhx phi_1 + Lhv phi_2 - Lhh s`: the bilinear part is
/// [`DELAYED_PARTNER_CONTROL`], the rest is linear in the gains and sits in
/// `F`'s gain columns. `dtau_h` is unknown (0). At `d_v = d_p = 0` with
/// `phi_1 = e`, `phi_2 = v` it is [`extended_transition`] up to the data
/// standing for the state.
pub fn delayed_trajectory_transition(
    step: &Step,
    known: [f64; 3],
    u: f64,
    dtau: f64,
) -> BilinearProcess<6, 3, 1> {
    let [phi1, phi2, s] = known;
    let (mut F, b, g) = motion_rows(step, u, dtau, 0.0);
    for (r, gr) in g.iter().enumerate() {
        F[(r, GAINS)] = gr * phi1;
        F[(r, GAINS + 1)] = gr * phi2;
        F[(r, GAINS + 2)] = -gr * s;
    }
    BilinearProcess {
        F,
        b,
        g,
        q: DELAYED_PARTNER_CONTROL,
    }
}

/// `Some(sel)` at compile time, or a compile error naming a bad selection.
const fn checked<const N: usize, const M: usize>(sel: Option<Selection<N, M>>) -> Selection<N, M> {
    match sel {
        Some(s) => s,
        None => panic!("measurement selection index out of range"),
    }
}

/// Stage-1 measurement (eq.measurement-extended_control) as a selection:
/// `y1 = [e, v, e_h]`.
pub const GAIN_MEASUREMENT: Selection<6, 3> = checked(Selection::new([0, 1, E_H]));

/// Stage-2 measurement (eq.measurement-extended) as a selection:
/// `y2 = [e, v, Lhx, Lhv, Lhh]`.
pub const TRAJECTORY_MEASUREMENT: Selection<6, 5> =
    checked(Selection::new([0, 1, GAINS, GAINS + 1, GAINS + 2]));

/// Stage-1 measurement function [`GAIN_MEASUREMENT`]: `y1 = [e, v, e_h]`.
pub fn gain_measurement(z: &Extended) -> Vector3<f64> {
    GAIN_MEASUREMENT.apply(z)
}

/// Stage-2 measurement function [`TRAJECTORY_MEASUREMENT`]:
/// `y2 = [e, v, Lhx, Lhv, Lhh]`.
pub fn trajectory_measurement(z: &Extended) -> SVector<f64, 5> {
    TRAJECTORY_MEASUREMENT.apply(z)
}

/// UKF settings shared by the extended-state estimators.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ExtendedFilterConfig<const M: usize> {
    /// Initial state.
    pub x0: Extended,
    /// Initial covariance (also the reset covariance).
    pub P0: Cov6,
    /// Per-step process noise covariance.
    pub Q: Cov6,
    /// Per-step measurement noise covariance.
    pub R: SMatrix<f64, M, M>,
    /// Sigma-point parameters.
    pub sigma: MerweParams,
}

/// Stage 1 (section "Estimation of human's control gain"): the partner's
/// gains, with both targets known.
#[derive(Clone, Debug)]
pub struct GainEstimator {
    /// The handle model's step, computed once at set-up.
    step: Step,
    ukf: Ukf<6, 3, 13>,
}

impl GainEstimator {
    /// Set-up: validates the model and the filter settings.
    pub fn new(model: HandleModel, cfg: &ExtendedFilterConfig<3>) -> Result<Self, EstimatorError> {
        model.validate()?;
        let ukf = Ukf::new(cfg.x0, cfg.P0, cfg.Q, cfg.R, cfg.sigma)?;
        check_covariances(&cfg.P0, &cfg.Q, &cfg.R)?;
        Ok(GainEstimator {
            step: model.step(),
            ukf,
        })
    }

    /// Per tick: fuse `y1 = [x - tau, xdot, x - tau_h]`.
    pub fn update(&mut self, y: &Vector3<f64>) -> Result<Status, UkfError> {
        self.ukf.update_selected(y, &GAIN_MEASUREMENT)
    }

    /// Per tick: propagate with the own torque `u` and both targets'
    /// increments over the coming step (all finite, else
    /// [`UkfError::NonFiniteInput`]).
    pub fn predict(&mut self, u: f64, dtau: f64, dtau_h: f64) -> Result<Status, UkfError> {
        finite_inputs(&[u, dtau, dtau_h], "u, dtau, dtau_h")?;
        self.predict_finite(u, dtau, dtau_h)
    }

    /// [`GainEstimator::predict`] without the argument check, for the
    /// robot's tick (its inputs are finite by construction: a guarded
    /// command, the protocol's increments) and the batch replays (which
    /// report a bad input as that step's error): the filter still refuses a
    /// non-finite input ([`UkfError::NonFiniteProcess`]), after the same
    /// finiteness test the check would repeat.
    pub(crate) fn predict_finite(
        &mut self,
        u: f64,
        dtau: f64,
        dtau_h: f64,
    ) -> Result<Status, UkfError> {
        // The process is built per call on purpose: inlined into the
        // predict (the extension's one codegen unit), its constant F, g and
        // q fold into the arithmetic; one kept in the struct and read from
        // memory cost ~240 instructions more per trial tick (callgrind).
        self.ukf
            .predict_bilinear(&extended_transition(&self.step, u, dtau, dtau_h))
    }

    /// Per tick, instead of [`GainEstimator::predict`]: the delay-aware
    /// process ([`delayed_transition`]) with the delayed regressor `phi`;
    /// affine, so the unscented predict is the Kalman one
    /// ([`Ukf::predict_linear`]).
    pub fn predict_delayed(
        &mut self,
        phi: [f64; 3],
        u: f64,
        dtau: f64,
        dtau_h: f64,
    ) -> Result<Status, UkfError> {
        let (F, b) = delayed_transition(&self.step, phi, u, dtau, dtau_h);
        self.ukf.predict_linear(&F, &b)
    }

    /// The estimated partner gains `[Lhx, Lhv, Lhh]`.
    pub fn gains(&self) -> [f64; 3] {
        let x = self.ukf.x();
        [x[GAINS], x[GAINS + 1], x[GAINS + 2]]
    }

    /// After ticks without a measurement, before fusing `y1`: the measured
    /// rows `[e, v, e_h]` restart from `y1` with their initial covariance
    /// (`P0`'s block) and no correlation with the gains; the gains keep
    /// their mean and covariance (docs/model.md, "Feedback gaps").
    ///
    /// Why: predicted without measurements, the bilinear partner term
    /// (`Lh . z`) couples the gains' uncertainty into the motion's mean
    /// and covariance, so the first measurement after the gap moves the
    /// gains by its whole accumulated innovation; one 20-tick gap in the
    /// last second of a 3 s gain phase moved the window's Lhh by up to 0.2
    /// (of 2). The gap's motion carries no information this filter can use
    /// reliably; the gains learn again from the next tick on.
    pub fn resync(&mut self, y: &Vector3<f64>) -> Result<(), UkfError> {
        let mut x = *self.ukf.x();
        let mut P = *self.ukf.P();
        let P0 = *self.ukf.reset_covariance();
        for (row, &i) in [0, 1, E_H].iter().enumerate() {
            x[i] = y[row];
            for j in 0..6 {
                P[(i, j)] = 0.0;
                P[(j, i)] = 0.0;
            }
        }
        for &i in &[0, 1, E_H] {
            for &j in &[0, 1, E_H] {
                P[(i, j)] = P0[(i, j)];
            }
        }
        self.ukf.reset(x, P)
    }

    /// The filter (posterior `x`, `P`, counters).
    pub fn filter(&self) -> &Ukf<6, 3, 13> {
        &self.ukf
    }
}

/// Stage 2 (section "Estimation of the partner's desired trajectory"): the
/// partner's target, with the stage-1 gains as pseudo-measurements.
#[derive(Clone, Debug)]
pub struct TrajectoryEstimator {
    /// The handle model's step, computed once at set-up.
    step: Step,
    ukf: Ukf<6, 5, 13>,
}

impl TrajectoryEstimator {
    /// Set-up: validates the model and the filter settings.
    pub fn new(model: HandleModel, cfg: &ExtendedFilterConfig<5>) -> Result<Self, EstimatorError> {
        model.validate()?;
        let ukf = Ukf::new(cfg.x0, cfg.P0, cfg.Q, cfg.R, cfg.sigma)?;
        check_covariances(&cfg.P0, &cfg.Q, &cfg.R)?;
        Ok(TrajectoryEstimator {
            step: model.step(),
            ukf,
        })
    }

    /// Per tick: fuse `y2 = [x - tau, xdot, Lhx^, Lhv^, Lhh^]`.
    pub fn update(&mut self, y: &SVector<f64, 5>) -> Result<Status, UkfError> {
        self.ukf.update_selected(y, &TRAJECTORY_MEASUREMENT)
    }

    /// Per tick: as [`TrajectoryEstimator::update`] with this tick's
    /// measurement covariance (e.g. a noisier view of the own target).
    pub fn update_with_r(
        &mut self,
        y: &SVector<f64, 5>,
        R: &SMatrix<f64, 5, 5>,
    ) -> Result<Status, UkfError> {
        self.ukf
            .update_selected_with_r(y, R, &TRAJECTORY_MEASUREMENT)
    }

    /// Phase start: restart from `x0` with covariance `P0`.
    pub fn reset(&mut self, x0: Extended, P0: Cov6) -> Result<(), UkfError> {
        self.ukf.reset(x0, P0)
    }

    /// Per tick: as [`GainEstimator::predict`]; the partner's target is
    /// unknown, so pass `dtau_h = 0` (its motion is left to the process noise).
    pub fn predict(&mut self, u: f64, dtau: f64, dtau_h: f64) -> Result<Status, UkfError> {
        finite_inputs(&[u, dtau, dtau_h], "u, dtau, dtau_h")?;
        self.predict_finite(u, dtau, dtau_h)
    }

    /// [`TrajectoryEstimator::predict`] without the argument check (see
    /// [`GainEstimator::predict_finite`]).
    pub(crate) fn predict_finite(
        &mut self,
        u: f64,
        dtau: f64,
        dtau_h: f64,
    ) -> Result<Status, UkfError> {
        self.ukf
            .predict_bilinear(&extended_transition(&self.step, u, dtau, dtau_h))
    }

    /// Per tick, instead of [`TrajectoryEstimator::predict`]: the
    /// delay-aware process ([`delayed_trajectory_transition`]) with the
    /// known `[y_e[k - d_v], y_v[k - d_p], x_m[k] - x_m[k - d_v]]`.
    pub fn predict_delayed(
        &mut self,
        known: [f64; 3],
        u: f64,
        dtau: f64,
    ) -> Result<Status, UkfError> {
        self.ukf
            .predict_bilinear(&delayed_trajectory_transition(&self.step, known, u, dtau))
    }

    /// `tau_h^ = x - (x - tau_h)^`, given the handle position `x`.
    pub fn partner_target(&self, x: f64) -> f64 {
        x - self.ukf.x()[E_H]
    }

    /// Posterior variance of `(x - tau_h)^`: the variance of `tau_h^` for a
    /// known `x`.
    pub fn partner_error_variance(&self) -> f64 {
        self.ukf.P()[(E_H, E_H)]
    }

    /// The partner torque implied by the posterior (eq.LQRhuman).
    pub fn partner_torque(&self) -> f64 {
        partner_torque(self.ukf.x())
    }

    /// The filter (posterior `x`, `P`, counters).
    pub fn filter(&self) -> &Ukf<6, 5, 13> {
        &self.ukf
    }
}

/// Discrete process model of the goal-integration state `[e, v]`:
/// `e' = e + dx - dtau`, `v' = v + dt a` with `a = (u - C v)/M`, where `u`
/// is all the torque the agent knows of (its own plus the estimated
/// partner torque). It is affine, `s' = F s + b` ([`error_transition`]).
pub fn error_process(model: &HandleModel, s: &Vector2<f64>, u: f64, dtau: f64) -> Vector2<f64> {
    let (F, b) = error_transition(&model.step(), u, dtau);
    F * s + b
}

/// [`error_process`] as `s' = F s + b`: with the step written out
/// ([`HandleModel::step`]), `dx = dx_v v + dx_f u` and `v' = v_v v + v_f u`, so
/// `F = [[1, dx_v], [0, v_v]]`, `b = [dx_f u - dtau, v_f u]`.
pub fn error_transition(step: &Step, u: f64, dtau: f64) -> (SMatrix<f64, 2, 2>, Vector2<f64>) {
    let F = SMatrix::<f64, 2, 2>::new(1.0, step.dx_v, 0.0, step.v_v);
    let b = Vector2::new(step.dx_f * u - dtau, step.v_f * u);
    (F, b)
}
