//! The paper's protocol: phases (partner-gain estimation, partner-trajectory
//! estimation, goal integration), each with its duration and both targets,
//! and the [`Sample`] of it that every tick reads once.
//!
//! Built and validated at set-up; [`Protocol::sample`] allocates nothing.

use crate::target::Target;
use crate::ScenarioError;

/// Most phases one protocol holds.
pub const MAX_PHASES: usize = 4;

/// What the robot does during a phase.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PhaseKind {
    /// Stage 1: both targets known; estimate the partner's gains.
    Gains,
    /// Stage 2: the partner's target unknown; estimate it.
    Trajectory,
    /// Stage 3: same target for both, the robot's view of it noisy; fuse the
    /// estimated partner target with the own view.
    Integration,
}

impl PhaseKind {
    /// A number for logs: 0, 1, 2.
    pub fn code(self) -> f64 {
        match self {
            PhaseKind::Gains => 0.0,
            PhaseKind::Trajectory => 1.0,
            PhaseKind::Integration => 2.0,
        }
    }
}

/// One phase of a trial.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Phase<'a> {
    /// What the robot estimates.
    pub kind: PhaseKind,
    /// Duration (s), > 0.
    pub duration_s: f64,
    /// The robot's target `tau`.
    pub robot_target: Target<'a>,
    /// The partner's target `tau_h`.
    pub partner_target: Target<'a>,
    /// Std of the white noise on the robot's view of its own target
    /// (the "injected robot measurement noise" of the Hi5 goal integration);
    /// only used in [`PhaseKind::Integration`].
    pub target_noise_std: f64,
}

/// One tick of the protocol (see [`Protocol::sample`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample<'a> {
    /// The tick.
    pub k: u64,
    /// Index of its phase.
    pub index: usize,
    /// Its phase.
    pub phase: Phase<'a>,
    /// First tick after its phase.
    pub end: u64,
    /// Robot target `tau` at `k`.
    pub tau: f64,
    /// Partner target `tau_h` at `k`.
    pub tau_h: f64,
    /// `tau[k+1] - tau[k]`.
    pub dtau: f64,
    /// `tau_h[k+1] - tau_h[k]`.
    pub dtau_h: f64,
}

/// The phases, and their boundaries in ticks.
#[derive(Clone, Copy, Debug)]
pub struct Protocol<'a> {
    phases: [Phase<'a>; MAX_PHASES],
    ends: [u64; MAX_PHASES],
    len: usize,
    dt_s: f64,
}

impl<'a> Protocol<'a> {
    /// Set-up: validates every phase; durations are rounded to whole ticks.
    pub fn new(phases: &[Phase<'a>], dt_s: f64) -> Result<Self, ScenarioError> {
        if phases.is_empty() || phases.len() > MAX_PHASES {
            return Err(ScenarioError::PhaseCount(phases.len()));
        }
        if !(dt_s.is_finite() && dt_s > 0.0) {
            return Err(ScenarioError::InvalidSetting("dt_s"));
        }
        let mut store = [phases[0]; MAX_PHASES];
        let mut ends = [0u64; MAX_PHASES];
        let mut end = 0u64;
        for (i, p) in phases.iter().enumerate() {
            let ticks = p.duration_s / dt_s;
            if !(1.0..1e12).contains(&ticks) {
                return Err(ScenarioError::InvalidPhase {
                    phase: i,
                    field: "duration_s",
                });
            }
            if !(p.target_noise_std.is_finite() && p.target_noise_std >= 0.0) {
                return Err(ScenarioError::InvalidPhase {
                    phase: i,
                    field: "target_noise_std",
                });
            }
            for (which, target) in [
                ("robot_target", &p.robot_target),
                ("partner_target", &p.partner_target),
            ] {
                target
                    .validate()
                    .map_err(|error| ScenarioError::InvalidTarget {
                        phase: i,
                        which,
                        error,
                    })?;
            }
            end += libm::round(ticks) as u64;
            store[i] = *p;
            ends[i] = end;
        }
        Ok(Protocol {
            phases: store,
            ends,
            len: phases.len(),
            dt_s,
        })
    }

    /// Ticks in the whole trial.
    pub fn total_ticks(&self) -> u64 {
        self.ends[self.len - 1]
    }

    /// The phases.
    pub fn phases(&self) -> &[Phase<'a>] {
        &self.phases[..self.len]
    }

    /// Everything a tick needs from the protocol, computed once per tick:
    /// the phase of tick `k`, both targets at `k` and their increments to
    /// `k + 1` (from the phase of `k`). `None` after the last tick.
    pub fn sample(&self, k: u64) -> Option<Sample<'a>> {
        let index = self.ends[..self.len].iter().position(|&end| k < end)?;
        let phase = self.phases[index];
        let t = k as f64 * self.dt_s;
        let dt = self.dt_s;
        Some(Sample {
            k,
            index,
            phase,
            end: self.ends[index],
            tau: phase.robot_target.at(t),
            tau_h: phase.partner_target.at(t),
            dtau: phase.robot_target.increment(t, dt),
            dtau_h: phase.partner_target.increment(t, dt),
        })
    }

    /// The loop period.
    pub fn dt_s(&self) -> f64 {
        self.dt_s
    }
}
