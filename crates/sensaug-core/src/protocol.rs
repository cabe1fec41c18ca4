//! The paper's protocol: phases (partner-gain estimation, partner-trajectory
//! estimation, goal integration), each with its duration and both targets,
//! and the [`Sample`] of it that every tick reads once.
//!
//! Built and validated at set-up; [`Protocol::sample`] allocates nothing.

use crate::target::{Shape, Target, MAX_PARTS};
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
    /// The names of the kinds, indexed by [`PhaseKind::code`] (the log's
    /// `phase_names`).
    pub const NAMES: [&'static str; 3] = ["gains", "trajectory", "integration"];

    /// The log's code: 0, 1, 2 (an index of [`PhaseKind::NAMES`]).
    pub fn code(self) -> i64 {
        match self {
            PhaseKind::Gains => 0,
            PhaseKind::Trajectory => 1,
            PhaseKind::Integration => 2,
        }
    }

    /// The kind of a log code (`None`: not a phase code).
    pub fn from_code(code: i64) -> Option<PhaseKind> {
        match code {
            0 => Some(PhaseKind::Gains),
            1 => Some(PhaseKind::Trajectory),
            2 => Some(PhaseKind::Integration),
            _ => None,
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
    /// `tau[k+1] - tau[k]`, both from the phase of `k`.
    pub dtau: f64,
    /// `tau_h[k+1] - tau_h[k]`, both from the phase of `k`.
    pub dtau_h: f64,
}

/// Both targets of one phase with the shapes they share evaluated once: in
/// the Hi5 protocol the robot's target is the partner's rounded square (plus
/// a chirp in the gain phase), so one cube root and one sine serve both.
#[derive(Clone, Copy, Debug)]
struct PhaseTargets<'a> {
    /// The distinct shapes of both targets (`Zero` included, so every part
    /// has an entry).
    shapes: [Shape<'a>; 2 * MAX_PARTS],
    len: usize,
    /// Where each part of the robot's target is in `shapes`.
    robot: [usize; MAX_PARTS],
    /// Where each part of the partner's target is in `shapes`.
    partner: [usize; MAX_PARTS],
}

impl<'a> PhaseTargets<'a> {
    /// Set-up: the distinct shapes of `phase`'s two targets.
    fn new(phase: &Phase<'a>) -> Self {
        let mut out = PhaseTargets {
            shapes: [Shape::Zero; 2 * MAX_PARTS],
            len: 0,
            robot: [0; MAX_PARTS],
            partner: [0; MAX_PARTS],
        };
        for (target, slots) in [
            (&phase.robot_target, &mut out.robot),
            (&phase.partner_target, &mut out.partner),
        ] {
            for (part, slot) in target.parts.iter().zip(slots.iter_mut()) {
                *slot = match out.shapes[..out.len].iter().position(|s| s == part) {
                    Some(i) => i,
                    None => {
                        out.shapes[out.len] = *part;
                        out.len += 1;
                        out.len - 1
                    }
                };
            }
        }
        out
    }

    /// `(tau(t), tau_h(t))`, each equal to [`Target::at`]: the same parts
    /// summed in the same order.
    fn at(&self, t: f64) -> (f64, f64) {
        let mut values = [0.0; 2 * MAX_PARTS];
        for (v, s) in values.iter_mut().zip(&self.shapes[..self.len]) {
            *v = s.at(t);
        }
        let sum = |parts: &[usize; MAX_PARTS]| parts.iter().map(|&i| values[i]).sum();
        (sum(&self.robot), sum(&self.partner))
    }
}

/// The phases, and their boundaries in ticks.
#[derive(Clone, Copy, Debug)]
pub struct Protocol<'a> {
    phases: [Phase<'a>; MAX_PHASES],
    targets: [PhaseTargets<'a>; MAX_PHASES],
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
        let mut targets = [PhaseTargets::new(&phases[0]); MAX_PHASES];
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
            targets[i] = PhaseTargets::new(p);
            ends[i] = end;
        }
        Ok(Protocol {
            phases: store,
            targets,
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
    /// the phase of tick `k`, both targets at `t = k dt` and their
    /// increments to `t = (k + 1) dt` (from the phase of `k`). `None` after
    /// the last tick.
    pub fn sample(&self, k: u64) -> Option<Sample<'a>> {
        let index = self.ends[..self.len].iter().position(|&end| k < end)?;
        let now = self.targets[index].at(k as f64 * self.dt_s);
        Some(self.sample_from(k, index, now).0)
    }

    /// The samples of every tick in order, equal to [`Protocol::sample`]
    /// of each: the targets at `k + 1`, evaluated for tick `k`'s increments,
    /// are kept as tick `k + 1`'s values (one evaluation per tick instead
    /// of two) unless the phase changes between them.
    pub fn samples(&self) -> Samples<'_, 'a> {
        Samples {
            protocol: self,
            k: 0,
            index: 0,
            next: None,
        }
    }

    /// The sample of tick `k` in phase `index` from its targets' values
    /// `now` at `t = k dt`; also the values at `t = (k + 1) dt`.
    fn sample_from(&self, k: u64, index: usize, now: (f64, f64)) -> (Sample<'a>, (f64, f64)) {
        let next = self.targets[index].at((k + 1) as f64 * self.dt_s);
        let sample = Sample {
            k,
            index,
            phase: self.phases[index],
            end: self.ends[index],
            tau: now.0,
            tau_h: now.1,
            dtau: next.0 - now.0,
            dtau_h: next.1 - now.1,
        };
        (sample, next)
    }

    /// The loop period.
    pub fn dt_s(&self) -> f64 {
        self.dt_s
    }
}

/// The iterator of [`Protocol::samples`].
#[derive(Clone, Debug)]
pub struct Samples<'p, 'a> {
    protocol: &'p Protocol<'a>,
    /// The next tick.
    k: u64,
    /// Its phase (the phases are visited in order).
    index: usize,
    /// The targets at `k` of phase `index`'s shapes, if already evaluated.
    next: Option<(f64, f64)>,
}

impl<'a> Iterator for Samples<'_, 'a> {
    type Item = Sample<'a>;

    fn next(&mut self) -> Option<Sample<'a>> {
        let p = self.protocol;
        while self.k >= *p.ends[..p.len].get(self.index)? {
            self.index += 1;
            // The values kept are the previous phase's targets.
            self.next = None;
        }
        let now = match self.next {
            Some(v) => v,
            None => p.targets[self.index].at(self.k as f64 * p.dt_s),
        };
        let (sample, next) = p.sample_from(self.k, self.index, now);
        self.k += 1;
        self.next = Some(next);
        Some(sample)
    }
}
