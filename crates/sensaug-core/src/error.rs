//! Set-up errors of a trial, shared by the protocol, the controller and the
//! simulation world (re-exported as `sensaug_core::ScenarioError`).

use crate::estimator::EstimatorError;
use crate::plant::PlantError;
use crate::target::TargetError;

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
