//! Set-up errors of a trial, shared by the protocol, the controller and the
//! simulation world (re-exported as `sensaug_core::ScenarioError`), and the
//! kind of every error of the core ([`CoreError`]).

use crate::estimator::EstimatorError;
use crate::plant::PlantError;
use crate::replay::ReplayError;
use crate::target::TargetError;
use crate::ukf::RunReport;

/// Whose fault an error of the core is: a caller that maps errors to its
/// own classes (the Python binding's exceptions) maps them by kind.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ErrorKind {
    /// An argument or setting breaks a precondition.
    Argument,
    /// A filter step the numbers broke: rejected (state unchanged) or
    /// repaired (`P` reset).
    StepFailure,
    /// The Riccati solver failed its own checks (no convergence, residual,
    /// closed loop).
    SolverFailure,
}

/// An error of the core: its message (field and fix) is its `Display`,
/// [`CoreError::kind`] says whose fault it is.
pub trait CoreError: core::fmt::Display {
    /// Whose fault it is; an argument's unless the numbers failed.
    fn kind(&self) -> ErrorKind {
        ErrorKind::Argument
    }
}

impl CoreError for EstimatorError {}
impl CoreError for ReplayError {}
impl CoreError for PlantError {}

/// A strict run that had step errors.
impl CoreError for RunReport {
    fn kind(&self) -> ErrorKind {
        ErrorKind::StepFailure
    }
}

/// Set-up errors of a trial; each names what to fix.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ScenarioError {
    /// No phase, or more than [`MAX_PHASES`](crate::protocol::MAX_PHASES).
    PhaseCount(usize),
    /// A phase field is out of range.
    InvalidPhase {
        /// Phase index.
        phase: usize,
        /// Field name.
        field: &'static str,
    },
    /// A target of a phase is invalid.
    InvalidTarget {
        /// Phase index.
        phase: usize,
        /// `"robot_target"` or `"partner_target"`.
        which: &'static str,
        /// The target's own error (part and field).
        error: TargetError,
    },
    /// A trajectory or integration phase comes before any gain phase and no
    /// prior partner gains were given.
    NoPartnerGains {
        /// Phase index.
        phase: usize,
    },
    /// A robot or scenario setting is out of range.
    InvalidSetting(&'static str),
    /// The plant parameters are invalid.
    Plant(PlantError),
    /// An estimator's settings are invalid.
    Estimator {
        /// `"stage1"`, `"stage2"`, `"stage3"`.
        stage: &'static str,
        /// The estimator's error.
        error: EstimatorError,
    },
    /// The output buffer is shorter than the trial.
    OutputTooShort {
        /// Ticks in the trial.
        needed: usize,
        /// Records given.
        got: usize,
    },
}

impl core::fmt::Display for ScenarioError {
    /// The field at fault and what to do, for people (no debug output).
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match *self {
            ScenarioError::PhaseCount(n) => write!(f, "phases: has {n} phases; give 1 to 4"),
            ScenarioError::InvalidPhase { phase, field } => write!(
                f,
                "phases[{phase}].{field}: out of range for the loop period"
            ),
            ScenarioError::InvalidTarget {
                phase,
                which,
                error,
            } => write!(
                f,
                "phases[{phase}].{which}[{}].{}: out of range (amplitudes finite, periods and \
                 durations > 0, frequencies >= 0)",
                error.part, error.field
            ),
            ScenarioError::NoPartnerGains { phase } => write!(
                f,
                "phases[{phase}].kind: needs an earlier gains phase or prior partner gains"
            ),
            ScenarioError::InvalidSetting(name) => {
                write!(
                    f,
                    "{name}: out of range; finite, and > 0 where it is a limit"
                )
            }
            ScenarioError::Plant(error) => write!(f, "plant.{error}"),
            ScenarioError::Estimator { stage, error } => write!(
                f,
                "robot.{stage}: rejected by the filter; check its covariances and sigma points \
                 ({error})"
            ),
            ScenarioError::OutputTooShort { needed, got } => {
                write!(f, "output: {got} records for a trial of {needed} ticks")
            }
        }
    }
}
