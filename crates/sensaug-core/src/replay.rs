//! Batch replay of a recorded trial, allocation-free: the caller owns every
//! input and output slice, and nothing stops early.
//!
//! Every filter runner uses the estimators' per-tick order
//! ([`crate::estimator`]): for each tick `k`, update with measurement row
//! `y[k]`, record the posterior, then predict with the inputs `u[k]`,
//! `dtau[k]`, `dtau_h[k]`. A recording made in filterpy's `batch_filter`
//! order (predict `u[k]`, then update `z[k]`) replays here after one
//! step-wise predict with `u[0]` and the inputs shifted by one.
//!
//! Step errors do not stop a replay: each was already handled by the filter
//! (state unchanged or `P` reset) and is counted in the [`RunReport`]. Slice
//! length errors are reported before anything runs.

use crate::controller::{Robot, RobotCounters};
use crate::estimator::{GainEstimator, TrajectoryEstimator};
use crate::goal::GoalIntegrator;
use crate::plant::Plant;
use crate::row::Row;
use crate::ukf::{Phase, RunReport, Status, StepError, UkfError};
use nalgebra::{SMatrix, SVector, Vector2};

/// One tick's known inputs to `predict`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Input {
    /// The own torque (N m); for goal integration all the known torque.
    pub u: f64,
    /// The own target's increment `tau[k+1] - tau[k]`.
    pub dtau: f64,
    /// The partner target's increment `tau_h[k+1] - tau_h[k]`.
    pub dtau_h: f64,
}

/// A filter that a recording can be replayed through, one tick at a time.
pub trait Replay {
    /// Entries of one measurement row.
    fn measurement_len(&self) -> usize;
    /// Entries of one posterior row (the state size).
    fn state_len(&self) -> usize;
    /// How many target increments `predict` reads: 0 (none), 1 (`dtau`) or
    /// 2 (`dtau` and `dtau_h`).
    fn target_increments(&self) -> usize;
    /// Per tick: fuse one measurement row. Missing entries read as NaN (the
    /// update is then rejected, state unchanged).
    fn update_row(&mut self, y: &[f64]) -> Result<Status, UkfError>;
    /// Per tick: propagate with this tick's inputs.
    fn predict_input(&mut self, input: Input) -> Result<Status, UkfError>;
    /// Writes the posterior mean into `x` and `diag(P)` into `var`.
    fn posterior(&self, x: &mut [f64], var: &mut [f64]);
}

/// A recorded trial of `T = u.len()` ticks.
#[derive(Clone, Copy, Debug)]
pub struct Recording<'a> {
    /// Measurements, row-major `T x measurement_len`.
    pub y: &'a [f64],
    /// Torque per tick (N m), length `T`.
    pub u: &'a [f64],
    /// Own target increments, length `T`; `None` reads as zeros.
    pub dtau: Option<&'a [f64]>,
    /// Partner target increments, length `T`; `None` reads as zeros.
    pub dtau_h: Option<&'a [f64]>,
}

/// Caller-owned outputs, each row-major `T x state_len`.
#[derive(Debug)]
pub struct Posteriors<'a> {
    /// Posterior mean after each update.
    pub x: &'a mut [f64],
    /// Diagonal of the posterior covariance after each update.
    pub var: &'a mut [f64],
}

/// Which slice a [`ReplayError`] refers to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ReplayArg {
    /// Measurements.
    Y,
    /// Torques.
    U,
    /// Own target increments.
    Dtau,
    /// Partner target increments.
    DtauH,
    /// Posterior means out.
    Xs,
    /// Posterior variances out.
    Pdiag,
    /// Plant torques.
    Torques,
    /// Plant velocities out.
    Vs,
    /// The robot's per-tick rows ([`replay_robot`]).
    Rows,
}

impl ReplayArg {
    /// The argument's name as the Python API spells it.
    pub fn name(self) -> &'static str {
        match self {
            ReplayArg::Y => "y",
            ReplayArg::U => "u",
            ReplayArg::Dtau => "dtau",
            ReplayArg::DtauH => "dtau_h",
            ReplayArg::Xs => "xs",
            ReplayArg::Pdiag => "Pdiag",
            ReplayArg::Torques => "torques",
            ReplayArg::Vs => "vs",
            ReplayArg::Rows => "out",
        }
    }
}

/// Set-up errors of a replay; nothing has run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ReplayError {
    /// A slice's length does not fit `T = u.len()` ticks.
    Length {
        /// The offending slice.
        which: ReplayArg,
        /// Required length.
        needed: usize,
        /// Given length.
        got: usize,
    },
    /// A slice was given to a filter that does not read it.
    NotRead {
        /// The offending slice.
        which: ReplayArg,
    },
    /// A value is out of range.
    OutOfRange {
        /// The offending value.
        which: ReplayArg,
    },
    /// Entry `step` of the slice is NaN or infinite.
    NonFinite {
        /// The offending slice.
        which: ReplayArg,
        /// Its first bad index.
        step: usize,
    },
    /// Entry `step` of the slice is finite but the state it leads to is not
    /// (too large for the model); the steps before it have run.
    Overflow {
        /// The offending slice.
        which: ReplayArg,
        /// The step that would overflow.
        step: usize,
    },
    /// Goal-integration rows ([`GoalReplay::for_columns`]) of neither 2
    /// entries (own view) nor 3 (and the partner channel).
    GoalColumns {
        /// The rows' length.
        got: usize,
    },
}

impl core::fmt::Display for ReplayError {
    /// The message starts with the argument's name, as the Python API spells it.
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match *self {
            ReplayError::Length { which, needed, got } => write!(
                f,
                "{}: expected {needed} values (one row per tick of u), got {got}",
                which.name()
            ),
            ReplayError::NotRead { which } => {
                write!(f, "{}: not read by this filter; leave it out", which.name())
            }
            ReplayError::OutOfRange { which } => {
                write!(f, "{}: must be finite and >= 0", which.name())
            }
            ReplayError::NonFinite { which, step } => write!(
                f,
                "{}[{step}]: must be finite; nothing was stepped",
                which.name()
            ),
            ReplayError::Overflow { which, step } => write!(
                f,
                "{}[{step}]: the state would overflow at this step (too large for this model); \
                 steps 0..{step} were run, this one was not",
                which.name()
            ),
            ReplayError::GoalColumns { got } => write!(
                f,
                "y: expected 2 entries [x - tau, xdot] or 3 [x - tau, xdot, x - tau_h^], got {got}"
            ),
        }
    }
}

fn check_len(which: ReplayArg, needed: usize, got: usize) -> Result<(), ReplayError> {
    if needed == got {
        Ok(())
    } else {
        Err(ReplayError::Length { which, needed, got })
    }
}

/// Checks an optional per-tick input: its length, and that the filter reads it.
fn check_input(
    which: ReplayArg,
    slice: Option<&[f64]>,
    read: bool,
    T: usize,
) -> Result<(), ReplayError> {
    match slice {
        Some(_) if !read => Err(ReplayError::NotRead { which }),
        Some(s) => check_len(which, T, s.len()),
        None => Ok(()),
    }
}

/// Counts a step's error in the report, keeping the first.
fn note(report: &mut RunReport, step: usize, phase: Phase, result: Result<Status, UkfError>) {
    if let Err(error) = result {
        report.errors += 1;
        report
            .first_error
            .get_or_insert(StepError { step, phase, error });
    }
}

/// Replays `rec` through `filter`: for each tick `k`, `update_row(y[k])`,
/// the posterior into row `k` of `out`, then `predict_input(u[k], dtau[k],
/// dtau_h[k])`. Allocation-free.
pub fn replay<F: Replay + ?Sized>(
    filter: &mut F,
    rec: &Recording<'_>,
    out: &mut Posteriors<'_>,
) -> Result<RunReport, ReplayError> {
    let T = rec.u.len();
    let (m, n) = (filter.measurement_len(), filter.state_len());
    check_len(ReplayArg::Y, T.saturating_mul(m), rec.y.len())?;
    let increments = filter.target_increments();
    check_input(ReplayArg::Dtau, rec.dtau, increments >= 1, T)?;
    check_input(ReplayArg::DtauH, rec.dtau_h, increments >= 2, T)?;
    check_len(ReplayArg::Xs, T.saturating_mul(n), out.x.len())?;
    check_len(ReplayArg::Pdiag, T.saturating_mul(n), out.var.len())?;
    let at = |s: Option<&[f64]>, k: usize| s.map_or(0.0, |s| s[k]);
    let mut report = RunReport {
        steps: T,
        ..RunReport::default()
    };
    let rows = rec.y.chunks_exact(m.max(1));
    let outs = out.x.chunks_exact_mut(n.max(1));
    let vars = out.var.chunks_exact_mut(n.max(1));
    for (k, ((y, x), var)) in rows.zip(outs).zip(vars).enumerate().take(T) {
        note(&mut report, k, Phase::Update, filter.update_row(y));
        filter.posterior(x, var);
        let input = Input {
            u: rec.u[k],
            dtau: at(rec.dtau, k),
            dtau_h: at(rec.dtau_h, k),
        };
        note(&mut report, k, Phase::Predict, filter.predict_input(input));
    }
    Ok(report)
}

/// A measurement row as a vector; entries beyond `y` read as NaN.
pub fn row<const M: usize>(y: &[f64]) -> SVector<f64, M> {
    SVector::from_fn(|i, _| y.get(i).copied().unwrap_or(f64::NAN))
}

/// Writes `x` and `diag(P)` into the first `N` entries of the outputs.
pub fn write_posterior<const N: usize>(
    x: &SVector<f64, N>,
    P: &SMatrix<f64, N, N>,
    x_out: &mut [f64],
    var_out: &mut [f64],
) {
    for (i, (xo, vo)) in x_out.iter_mut().zip(var_out.iter_mut()).take(N).enumerate() {
        *xo = x[i];
        *vo = P[(i, i)];
    }
}

/// The stage-1 and stage-2 estimators share one replay: extended state
/// `[x - tau, xdot, x - tau_h, Lhx, Lhv, Lhh]`, both target increments.
macro_rules! replay_extended {
    ($t:ty, $m:literal) => {
        impl Replay for $t {
            fn measurement_len(&self) -> usize {
                $m
            }
            fn state_len(&self) -> usize {
                6
            }
            fn target_increments(&self) -> usize {
                2
            }
            fn update_row(&mut self, y: &[f64]) -> Result<Status, UkfError> {
                self.update(&row::<$m>(y))
            }
            fn predict_input(&mut self, i: Input) -> Result<Status, UkfError> {
                self.predict_finite(i.u, i.dtau, i.dtau_h)
            }
            fn posterior(&self, x: &mut [f64], var: &mut [f64]) {
                write_posterior(self.filter().x(), self.filter().P(), x, var)
            }
        }
    };
}

replay_extended!(GainEstimator, 3);
replay_extended!(TrajectoryEstimator, 5);

/// Stage-3 replay: rows `[x - tau, xdot]`, or `[x - tau, xdot, x - tau_h^]`
/// with the partner channel (a NaN channel entry: no channel that tick); the
/// posterior is the integrated estimate (the bank's mixture).
#[derive(Debug)]
pub struct GoalReplay<'a> {
    integrator: &'a mut GoalIntegrator,
    with_channel: bool,
}

impl<'a> GoalReplay<'a> {
    /// `with_channel`: the rows carry the partner channel as a third entry.
    pub fn new(integrator: &'a mut GoalIntegrator, with_channel: bool) -> Self {
        GoalReplay {
            integrator,
            with_channel,
        }
    }

    /// For rows of `columns` entries: 2 (`[x - tau, xdot]`) or 3 (and the
    /// partner channel `x - tau_h^`).
    pub fn for_columns(
        integrator: &'a mut GoalIntegrator,
        columns: usize,
    ) -> Result<Self, ReplayError> {
        match columns {
            2 | 3 => Ok(Self::new(integrator, columns == 3)),
            got => Err(ReplayError::GoalColumns { got }),
        }
    }
}

impl Replay for GoalReplay<'_> {
    fn measurement_len(&self) -> usize {
        2 + usize::from(self.with_channel)
    }
    fn state_len(&self) -> usize {
        2
    }
    fn target_increments(&self) -> usize {
        1
    }
    fn update_row(&mut self, y: &[f64]) -> Result<Status, UkfError> {
        let own = row::<2>(y);
        let channel = self.with_channel.then(|| row::<3>(y)[2]);
        self.integrator
            .update(&Vector2::new(own[0], own[1]), channel)
    }
    fn predict_input(&mut self, i: Input) -> Result<Status, UkfError> {
        self.integrator.predict_finite(i.u, i.dtau)
    }
    fn posterior(&self, x: &mut [f64], var: &mut [f64]) {
        let e = self.integrator.estimate(true);
        x[..2].copy_from_slice(e.as_slice());
        var[..2].copy_from_slice(&self.integrator.variance(true));
    }
}

/// Steps `plant` through every torque, writing the position and velocity
/// after each step into `xs` and `vs`. Every torque is checked first: a
/// non-finite one is an error naming its index and nothing is stepped; a
/// step whose state would overflow is an error naming its index, after the
/// steps before it.
pub fn simulate(
    plant: &mut Plant,
    torques: &[f64],
    xs: &mut [f64],
    vs: &mut [f64],
) -> Result<(), ReplayError> {
    let T = torques.len();
    check_len(ReplayArg::Xs, T, xs.len())?;
    check_len(ReplayArg::Vs, T, vs.len())?;
    let bad = |step| ReplayError::NonFinite {
        which: ReplayArg::Torques,
        step,
    };
    if let Some(step) = torques.iter().position(|t| !t.is_finite()) {
        return Err(bad(step));
    }
    for (k, ((&t, x), v)) in torques.iter().zip(xs).zip(vs).enumerate() {
        let s = plant.step(t).map_err(|_| ReplayError::Overflow {
            which: ReplayArg::Torques,
            step: k,
        })?;
        (*x, *v) = (s.x, s.v);
    }
    Ok(())
}

/// Re-runs the robot's controller offline over a recorded trial: for each
/// tick `k`, `robot.tick_applied(k, measurements[k], applied[k], &mut out[k])`,
/// the very calls (and so the same step order: update with the measurement,
/// command, predict) that the rig loop and the simulation make online. `None`
/// is a tick without a fresh measurement (predict only, the command on the
/// last one), as online. `applied` (a rig's log: its `u`, the robot's part of
/// the torque the drive applied) is what the estimators predict with, as
/// they did online; without it, the replayed command (a simulation's log).
/// `robot` must be new (built from the recording's configuration, its
/// protocol and seed) for the numbers to repeat bit for bit. Only the
/// controller's columns of `out` are written (the caller's other columns
/// are kept); after the protocol's end they are unknown and `u` is 0.
///
/// Returns the robot's counters after the last tick; a length mismatch is
/// reported before anything runs. Allocation-free.
pub fn replay_robot(
    robot: &mut Robot<'_>,
    measurements: &[Option<(f64, f64)>],
    applied: Option<&[f64]>,
    out: &mut [Row],
) -> Result<RobotCounters, ReplayError> {
    check_len(ReplayArg::Rows, measurements.len(), out.len())?;
    if let Some(a) = applied {
        check_len(ReplayArg::U, measurements.len(), a.len())?;
    }
    for (k, (m, o)) in measurements.iter().zip(out.iter_mut()).enumerate() {
        let u = applied.map(|a| a[k]);
        robot.tick_applied(k as u64, *m, u, o);
    }
    Ok(robot.counters())
}

/// [`replay_robot`] over a recorded trial's rows: row `k` of `out` gets
/// `tick = k`, `t = k dt_s` and the recorded `x_meas`, `xdot_meas` and
/// `fresh` (the rest unknown), and the robot fuses the measurement when it
/// was fresh, else only predicts, as online; with `applied` (a rig log,
/// whose `u` is the robot's torque as the drive applied it) the estimators
/// predict with the recorded `u`, as [`Robot::tick_applied`]. Lengths are
/// checked before anything runs. Allocation-free.
pub fn replay_recorded(
    robot: &mut Robot<'_>,
    dt_s: f64,
    recorded: &[Row],
    applied: bool,
    out: &mut [Row],
) -> Result<RobotCounters, ReplayError> {
    check_len(ReplayArg::Rows, recorded.len(), out.len())?;
    for (k, (r, o)) in recorded.iter().zip(out.iter_mut()).enumerate() {
        *o = Row {
            tick: k as i64,
            t: k as f64 * dt_s,
            x_meas: r.x_meas,
            xdot_meas: r.xdot_meas,
            fresh: r.fresh,
            ..Row::UNKNOWN
        };
        let measured = r.fresh.then_some((r.x_meas, r.xdot_meas));
        robot.tick_applied(k as u64, measured, applied.then_some(r.u), o);
    }
    Ok(robot.counters())
}
