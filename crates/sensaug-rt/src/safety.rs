//! The loop's safety decisions: why it stops ([`StopReason`], each with its
//! own exit code), the state machine that decides who sets the next torque
//! command ([`Safety::next`]: the controller, the controlled stop's brake,
//! or no one), the brake itself ([`brake_torque_nm`]), and the per-tick
//! checks it looks at: feedback plausibility and consistency
//! ([`FeedbackLimits::check`]) and run health ([`degradation`]).
//! `docs/safety.md` lists every fault, its safe state and the measured time
//! to reach it.

use crate::range::OutOfRange;
use sensaug_bridge::drive_link::{DriveAlarm, ResetReport};
use std::fmt;

/// A feedback that physics rules out (`rig.max_feedback_velocity_rad_s`,
/// `rig.feedback_step_margin_rad`, `rig.feedback_velocity_margin_rad_s`),
/// or that two sources sent.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Implausible {
    /// `|v| > limit` (rad/s).
    Velocity {
        /// The feedback's velocity.
        v_rad_s: f64,
        /// `rig.max_feedback_velocity_rad_s`.
        limit_rad_s: f64,
    },
    /// `|x - x_prev| > allowed` (rad) ([`max_step_rad`] over
    /// [`Previous::ticks_sampled_apart`]).
    Step {
        /// The position step from the previous feedback.
        step_rad: f64,
        /// The largest step the velocity limit allows ([`max_step_rad`]).
        allowed_rad: f64,
    },
    /// The velocities disagree with the position's change:
    /// `|(v_prev + v) / 2 - (x - x_prev) / T| > allowed`
    /// ([`FeedbackLimits::max_velocity_mismatch_rad_s`]).
    Inconsistent {
        /// The mean of the two feedbacks' velocities (rad/s).
        reported_rad_s: f64,
        /// The mean velocity the position's change implies (rad/s).
        implied_rad_s: f64,
        /// The largest difference physics allows (rad/s).
        allowed_rad_s: f64,
    },
    /// Two different feedbacks answer the same command (its sequence
    /// number; CiA 402: its SYNC counter): a second node sends feedback.
    Conflicting {
        /// The command's sequence number.
        sequence: u8,
    },
}

impl fmt::Display for Implausible {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Implausible::Velocity {
                v_rad_s,
                limit_rad_s,
            } => write!(
                f,
                "velocity {v_rad_s:.4} rad/s beyond rig.max_feedback_velocity_rad_s = {limit_rad_s}"
            ),
            Implausible::Step {
                step_rad,
                allowed_rad,
            } => write!(
                f,
                "position step {step_rad:.4} rad > {allowed_rad:.4} rad allowed \
                 (rig.max_feedback_velocity_rad_s x time between the two feedbacks \
                 + rig.feedback_step_margin_rad)"
            ),
            Implausible::Inconsistent {
                reported_rad_s,
                implied_rad_s,
                allowed_rad_s,
            } => write!(
                f,
                "velocity inconsistent with the position: {reported_rad_s:.4} rad/s reported, \
                 {implied_rad_s:.4} rad/s from the position's change, more than \
                 {allowed_rad_s:.4} rad/s apart (the plant's largest acceleration, \
                 rig.torque_limit_nm / plant.mass, over the time between the feedbacks \
                 + rig.feedback_velocity_margin_rad_s)"
            ),
            Implausible::Conflicting { sequence } => write!(
                f,
                "two different feedbacks answer command {sequence}: another node sends \
                 feedback for this drive"
            ),
        }
    }
}

/// The thresholds of a degraded run (`rig.max_*`, docs/safety.md).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DegradedLimits {
    /// Largest fraction of ticks without fresh feedback.
    pub missing_fraction: f64,
    /// Longest run of consecutive ticks without fresh feedback.
    pub stale_run_ticks: u64,
    /// Most estimator errors plus non-finite controller outputs.
    pub estimator_errors: u64,
    /// Ticks in one second: the fraction's smallest denominator.
    pub ticks_per_s: u64,
}

/// The run's health so far, as [`degradation`] reads it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Health {
    /// Ticks run so far (this one included).
    pub ticks: u64,
    /// Ticks without fresh feedback so far.
    pub missing: u64,
    /// Consecutive ticks without fresh feedback up to this one.
    pub stale_run: u64,
    /// Estimator errors plus non-finite controller outputs so far.
    pub estimator_errors: u64,
}

/// Why a run was judged degraded (the first threshold crossed).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Degradation {
    /// `missing > fraction * max(ticks, ticks_per_s)`.
    MissingFeedback {
        /// Ticks without fresh feedback.
        missing: u64,
        /// Ticks run.
        ticks: u64,
        /// `rig.max_missing_feedback_fraction`.
        limit: f64,
    },
    /// `stale_run > rig.max_stale_feedback_ticks`.
    StaleRun {
        /// Consecutive ticks without fresh feedback.
        ticks: u64,
        /// `rig.max_stale_feedback_ticks`.
        limit: u64,
    },
    /// `estimator_errors > rig.max_estimator_errors`.
    Estimator {
        /// Estimator errors plus non-finite outputs.
        errors: u64,
        /// `rig.max_estimator_errors`.
        limit: u64,
    },
}

impl fmt::Display for Degradation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Degradation::MissingFeedback {
                missing,
                ticks,
                limit,
            } => write!(
                f,
                "{missing} of {ticks} ticks without fresh feedback, more than \
                 rig.max_missing_feedback_fraction = {limit}"
            ),
            Degradation::StaleRun { ticks, limit } => write!(
                f,
                "{ticks} consecutive ticks without fresh feedback, more than \
                 rig.max_stale_feedback_ticks = {limit}"
            ),
            Degradation::Estimator { errors, limit } => write!(
                f,
                "{errors} estimator errors or non-finite outputs, more than \
                 rig.max_estimator_errors = {limit}"
            ),
        }
    }
}

/// Why the loop stopped.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum StopReason {
    /// Every tick of the protocol ran.
    Completed,
    /// A terminating signal (its number: SIGINT, SIGTERM, SIGHUP, SIGQUIT,
    /// SIGUSR1, SIGUSR2, SIGPIPE): the controlled stop, drive disabled.
    Signal(i32),
    /// No feedback for longer than `rig.feedback_timeout_ms`: emergency stop sent.
    FeedbackTimeout,
    /// The drive reported its fault (Hi5 FAULT flags; CiA 402 Fault with
    /// the EMCY code and error register) or, CiA 402, its heartbeat was
    /// lost: emergency stop on a lost heartbeat, else stop and disable.
    DriveFault(DriveAlarm),
    /// The drive reset (CiA 402 boot-up, or a heartbeat leaving
    /// OPERATIONAL; Hi5 BOOT or DISABLED reported) or left its enabled
    /// state by itself: emergency stop at once.
    DriveReset(ResetReport),
    /// A command frame for this node that this process did not send (a
    /// second controller on the bus): emergency stop sent.
    ForeignCommand,
    /// A feedback physics rules out, or two feedbacks for one command:
    /// torque off at once, drive disabled.
    ImplausibleFeedback(Implausible),
    /// Missing feedback (torque off at once) or estimator health (the
    /// controlled stop) past its threshold; drive disabled.
    Degraded(Degradation),
    /// The log writer failed (e.g. a full disk): the controlled stop, drive
    /// disabled; the log keeps what was written.
    LogWriteFailed,
    /// The handle beyond a hard limit or the hard speed, or outside the
    /// soft window at the start (`rig.range`): the controlled stop.
    OutOfRange(OutOfRange),
}

impl StopReason {
    /// The process exit code (docs/realtime.md): 0 completed; 1 signal,
    /// feedback timeout or drive fault; 4 foreign command; 5 implausible
    /// feedback; 6 degraded; 7 log write failure; 8 drive reset; 9 out of
    /// range (a hard limit or the hard speed). (2 is a
    /// configuration or set-up error, 3 another controller seen before
    /// enabling.)
    pub fn exit_code(&self) -> u8 {
        match self {
            StopReason::Completed => 0,
            StopReason::Signal(_) | StopReason::FeedbackTimeout | StopReason::DriveFault(_) => 1,
            StopReason::ForeignCommand => 4,
            StopReason::ImplausibleFeedback(_) => 5,
            StopReason::Degraded(_) => 6,
            StopReason::LogWriteFailed => 7,
            StopReason::DriveReset(_) => 8,
            StopReason::OutOfRange(_) => 9,
        }
    }

    /// The stop brakes the handle on its feedback (the controlled stop): a
    /// signal, a log failure, estimator trouble. Not when feedback cannot be
    /// trusted (implausible, or missing past a threshold): then torque off
    /// at once; nor for the immediate stops and completion.
    pub fn brakes(&self) -> bool {
        self.stop_kind() == StopKind::Controlled
    }

    /// How the drive is brought to its safe state for this reason
    /// (`stats.json` `stop.kind`).
    pub fn stop_kind(&self) -> StopKind {
        match self {
            StopReason::Completed => StopKind::Completed,
            StopReason::FeedbackTimeout
            | StopReason::ForeignCommand
            | StopReason::DriveReset(_)
            | StopReason::DriveFault(DriveAlarm::HeartbeatLost { .. }) => StopKind::EmergencyStop,
            StopReason::Signal(_)
            | StopReason::LogWriteFailed
            | StopReason::OutOfRange(_)
            | StopReason::Degraded(Degradation::Estimator { .. }) => StopKind::Controlled,
            StopReason::DriveFault(_)
            | StopReason::ImplausibleFeedback(_)
            | StopReason::Degraded(_) => StopKind::TorqueOff,
        }
    }

    /// What the Display text says about the safe state.
    fn safe_state(&self) -> &'static str {
        match self.stop_kind() {
            StopKind::Controlled => "controlled stop, drive disabled",
            StopKind::TorqueOff => "torque off at once, drive disabled",
            StopKind::EmergencyStop => "emergency stop sent",
            StopKind::Completed => "",
        }
    }
}

/// How a stop brings the drive to its safe state (docs/safety.md).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum StopKind {
    /// The protocol's end: zero torque, disable.
    Completed,
    /// Safe stop 1: brake on fresh feedback until at rest or the time
    /// limit, then zero torque and disable.
    Controlled,
    /// Zero torque and disable at once (feedback not trusted, or the drive
    /// already faulted).
    TorqueOff,
    /// The profile's emergency stop (Hi5 EmergencyStop, CiA 402 quick stop).
    EmergencyStop,
}

impl fmt::Display for StopReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let safe = self.safe_state();
        match self {
            StopReason::Completed => write!(f, "completed"),
            StopReason::Signal(n) => {
                write!(f, "signal {} ({safe})", crate::os::signal_name(*n))
            }
            StopReason::FeedbackTimeout => write!(f, "feedback timeout ({safe})"),
            StopReason::DriveFault(alarm) => write!(f, "drive fault: {alarm} ({safe})"),
            StopReason::DriveReset(why) => write!(
                f,
                "drive reset: {why} ({safe}; the drive must be set up again)"
            ),
            StopReason::ForeignCommand => write!(
                f,
                "foreign command: a command frame for this node that this process did not \
                 send; another controller (a second sensaug-rt?) is on the same bus and node \
                 ({safe})"
            ),
            StopReason::ImplausibleFeedback(why) => {
                write!(f, "implausible feedback: {why} ({safe})")
            }
            StopReason::Degraded(why) => write!(f, "degraded: {why} ({safe})"),
            StopReason::LogWriteFailed => write!(
                f,
                "log write failed ({safe}; the log keeps what was written)"
            ),
            StopReason::OutOfRange(why) => write!(f, "range limit: {why} ({safe})"),
        }
    }
}

/// The largest position step between two feedbacks sampled `ticks` ticks
/// of `dt_s` apart: `v_max * (max(ticks, 1) + 1) * dt + margin` (one tick
/// added for the receive jitter of either feedback).
pub fn max_step_rad(v_max_rad_s: f64, ticks: u64, dt_s: f64, margin_rad: f64) -> f64 {
    v_max_rad_s * (ticks.max(1) + 1) as f64 * dt_s + margin_rad
}

/// One feedback: position (rad) and velocity (rad/s).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reading {
    /// Position (rad).
    pub x_rad: f64,
    /// Velocity (rad/s).
    pub v_rad_s: f64,
}

/// The feedback before this one, as [`FeedbackLimits::check`] compares.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Previous {
    /// Its reading.
    pub reading: Reading,
    /// Loop ticks between the two receptions.
    pub ticks_apart: u64,
    /// Drive steps (commands answered) between the two, from their
    /// sequence numbers; 0 when unknown (then `ticks_apart`, at least 1).
    pub steps: u32,
    /// The most drive steps there can be between the two: `steps` when
    /// the feedbacks say which command they answer; more for CiA 402's
    /// standard mode, where a TPDO is placed on a SYNC by its arrival time
    /// and a late answer looks like a later SYNC's: any count from 1 to
    /// this one is then possible
    /// ([`Absorbed::Feedback`](sensaug_bridge::drive_link::Absorbed::Feedback)).
    pub most_steps: u32,
}

impl Previous {
    /// The ticks between the two feedbacks' samples, at most: the ticks
    /// between their receptions, or the most drive steps between their
    /// commands when more. The steps are more when the previous feedback
    /// itself came late: a drive that stalled after answering one command
    /// sends that answer with the next answer, one tick apart, though the
    /// two answers are many commands apart.
    pub fn ticks_sampled_apart(&self) -> u64 {
        self.ticks_apart.max(u64::from(self.most_steps))
    }
}

/// What physics allows a feedback (`[rig]` and `[plant]`, docs/safety.md).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FeedbackLimits {
    /// `rig.max_feedback_velocity_rad_s`.
    pub max_velocity_rad_s: f64,
    /// `rig.feedback_step_margin_rad`.
    pub step_margin_rad: f64,
    /// The loop period (s): one drive step.
    pub dt_s: f64,
    /// The plant's largest acceleration under the torque limit,
    /// `rig.torque_limit_nm / plant.mass` (rad/s^2).
    pub max_acceleration_rad_s2: f64,
    /// `rig.feedback_velocity_margin_rad_s`.
    pub velocity_margin_rad_s: f64,
}

impl FeedbackLimits {
    /// The largest `|(v0 + v1) / 2 - (x1 - x0) / T|` physics allows over an
    /// interval `T` (s): `a_max T / 4 + margin`. For any motion with
    /// `|a| <= a_max`, `(v0 + v1) / 2 - (x1 - x0) / T = (1/T) int_0^T a(s)
    /// (s - T/2) ds`, at most `a_max T / 4` in size (0 under a constant
    /// torque, as in one exact zero-order-hold step); the margin covers the
    /// encoder's quantisation of both positions and a drive's velocity
    /// filter.
    pub fn max_velocity_mismatch_rad_s(&self, interval_s: f64) -> f64 {
        self.max_acceleration_rad_s2 * interval_s / 4.0 + self.velocity_margin_rad_s
    }

    /// A feedback against physics: `|v| <= v_max`; after a previous one,
    /// `|x - x_prev| <= max_step_rad(..)` and the two velocities agree with
    /// the position's change over the drive steps between them
    /// ([`Self::max_velocity_mismatch_rad_s`]). Non-finite values are
    /// implausible.
    pub fn check(&self, now: Reading, prev: Option<Previous>) -> Result<(), Implausible> {
        // A NaN compares as neither: implausible.
        let within = |a: f64, limit: f64| a.abs() <= limit;
        if !within(now.v_rad_s, self.max_velocity_rad_s) {
            return Err(Implausible::Velocity {
                v_rad_s: now.v_rad_s,
                limit_rad_s: self.max_velocity_rad_s,
            });
        }
        let Some(p) = prev else { return Ok(()) };
        let step_rad = (now.x_rad - p.reading.x_rad).abs();
        let allowed_rad = max_step_rad(
            self.max_velocity_rad_s,
            p.ticks_sampled_apart(),
            self.dt_s,
            self.step_margin_rad,
        );
        if !within(step_rad, allowed_rad) {
            return Err(Implausible::Step {
                step_rad,
                allowed_rad,
            });
        }
        let steps = if p.steps > 0 {
            u64::from(p.steps)
        } else {
            p.ticks_apart.max(1)
        };
        let reported_rad_s = 0.5 * (p.reading.v_rad_s + now.v_rad_s);
        let consistent_over = |steps: u64| {
            let interval_s = steps as f64 * self.dt_s;
            let implied_rad_s = (now.x_rad - p.reading.x_rad) / interval_s;
            let allowed_rad_s = self.max_velocity_mismatch_rad_s(interval_s);
            within(reported_rad_s - implied_rad_s, allowed_rad_s)
                .then_some(())
                .ok_or(Implausible::Inconsistent {
                    reported_rad_s,
                    implied_rad_s,
                    allowed_rad_s,
                })
        };
        let exact = consistent_over(steps);
        if exact.is_ok() || p.most_steps <= p.steps {
            return exact;
        }
        // Standard CiA 402: the new feedback answers some SYNC after the
        // previous one's (a late answer is placed on a later SYNC), and the
        // previous one may itself have been late: 1 to most_steps drive
        // steps. An answer out of step is no fresh feedback, so the count
        // is bounded by the feedback timeout's ticks plus
        // rig.max_stale_feedback_ticks.
        if (1..=u64::from(p.most_steps)).any(|s| consistent_over(s).is_ok()) {
            return Ok(());
        }
        exact
    }
}

/// The controlled stop's brake (N m): a damping torque on the measured
/// velocity, bounded, `clamp(-damping v, -limit, limit)`; opposes the
/// motion, so it only takes energy out of the handle.
pub fn brake_torque_nm(v_rad_s: f64, damping_nm_s_per_rad: f64, limit_nm: f64) -> f64 {
    (-damping_nm_s_per_rad * v_rad_s).clamp(-limit_nm, limit_nm)
}

/// The first degraded-run threshold `h` crosses, if any:
/// `missing > fraction * max(ticks, ticks_per_s)`, `stale_run > stale_run_ticks`,
/// `estimator_errors > estimator_errors limit`.
pub fn degradation(h: &Health, l: &DegradedLimits) -> Option<Degradation> {
    let judged = h.ticks.max(l.ticks_per_s) as f64;
    if h.missing as f64 > l.missing_fraction * judged {
        return Some(Degradation::MissingFeedback {
            missing: h.missing,
            ticks: h.ticks,
            limit: l.missing_fraction,
        });
    }
    if h.stale_run > l.stale_run_ticks {
        return Some(Degradation::StaleRun {
            ticks: h.stale_run,
            limit: l.stale_run_ticks,
        });
    }
    if h.estimator_errors > l.estimator_errors {
        return Some(Degradation::Estimator {
            errors: h.estimator_errors,
            limit: l.estimator_errors,
        });
    }
    None
}

/// The loop's safety state: who sets the next torque command.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Safety {
    /// The protocol runs: the controller commands.
    Running,
    /// The controlled stop, requested at `from_tick`: the brake commands
    /// ([`brake_torque_nm`] on fresh feedback, zero torque on a tick
    /// without), until the handle is at rest, the time limit passes or a
    /// feedback is implausible; then the loop stops for `reason`.
    Braking {
        /// First tick of the stop.
        from_tick: u64,
        /// Why the loop stops.
        reason: StopReason,
    },
    /// The loop ends for this reason (zero torque and disable, or the
    /// emergency stop).
    Stopped(StopReason),
}

/// Why the controlled stop ended (`stats.json` `stop.brake_end`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum BrakeEnd {
    /// The measured speed fell below `rig.stop_rest_velocity_rad_s`.
    AtRest,
    /// `rig.stop_time_limit_s` passed.
    TimeLimit,
    /// A feedback was implausible: torque off at once.
    ImplausibleFeedback,
    /// An immediate stop (feedback timeout, drive fault, foreign command).
    Interrupted,
}

/// What the safety state machine looks at in one tick.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Checks {
    /// The tick.
    pub tick: u64,
    /// No feedback for longer than the timeout.
    pub feedback_timed_out: bool,
    /// The drive's alarm: its fault, its heartbeat lost, or a reset.
    pub drive_fault: Option<DriveAlarm>,
    /// A command frame for this node that this process did not send.
    pub foreign_command: bool,
    /// The first implausible feedback, if any.
    pub implausible: Option<Implausible>,
    /// The log writer failed.
    pub log_failed: bool,
    /// The handle out of its range (`rig.range`), if it is.
    pub out_of_range: Option<OutOfRange>,
    /// The run crossed a degraded-run threshold.
    pub degraded: Option<Degradation>,
    /// The terminating signal received, if any (the stop flag).
    pub signal: Option<i32>,
    /// Every tick of the protocol ran.
    pub protocol_done: bool,
    /// This tick's feedback is fresh and its speed below
    /// `rig.stop_rest_velocity_rad_s`.
    pub at_rest: bool,
    /// The controlled stop's time limit (ticks).
    pub stop_ticks: u64,
}

impl Checks {
    /// Why the loop must stop after running, if it must: implausible
    /// feedback, then the handle out of range, then a log failure, then a
    /// degraded run, then a signal.
    fn stop_reason(&self) -> Option<StopReason> {
        self.implausible
            .map(StopReason::ImplausibleFeedback)
            .or(self.out_of_range.map(StopReason::OutOfRange))
            .or(self.log_failed.then_some(StopReason::LogWriteFailed))
            .or(self.degraded.map(StopReason::Degraded))
            .or(self.signal.map(StopReason::Signal))
    }

    /// An immediate stop, whatever the state: a feedback timeout, then a
    /// drive fault, then a foreign command.
    fn immediate(&self) -> Option<StopReason> {
        if self.feedback_timed_out {
            return Some(StopReason::FeedbackTimeout);
        }
        match self.drive_fault {
            Some(DriveAlarm::Reset(why)) => return Some(StopReason::DriveReset(why)),
            Some(alarm) => return Some(StopReason::DriveFault(alarm)),
            None => {}
        }
        self.foreign_command.then_some(StopReason::ForeignCommand)
    }

    /// Whether the controlled stop begun at `from_tick` ends this tick, and
    /// why: an implausible feedback, then at rest, then the time limit.
    pub fn brake_end(&self, from_tick: u64) -> Option<BrakeEnd> {
        if self.immediate().is_some() {
            Some(BrakeEnd::Interrupted)
        } else if self.implausible.is_some() {
            Some(BrakeEnd::ImplausibleFeedback)
        } else if self.at_rest {
            Some(BrakeEnd::AtRest)
        } else if self.tick - from_tick >= self.stop_ticks {
            Some(BrakeEnd::TimeLimit)
        } else {
            None
        }
    }
}

impl Safety {
    /// The state for this tick. A feedback timeout, then a drive fault, then
    /// a foreign command stop at once, even while braking; implausible
    /// feedback, a log failure, a degraded run or a signal end the run (they
    /// win over completion): with torque off at once when the feedback is
    /// not trusted ([`StopReason::brakes`]), else with the controlled stop,
    /// which ends ([`Checks::brake_end`]) with the reason that began it;
    /// the protocol's end completes.
    pub fn next(self, c: &Checks) -> Safety {
        if let Safety::Stopped(_) = self {
            return self;
        }
        if let Some(reason) = c.immediate() {
            return Safety::Stopped(reason);
        }
        let state = match self {
            Safety::Running => match c.stop_reason() {
                Some(reason) if reason.brakes() => Safety::Braking {
                    from_tick: c.tick,
                    reason,
                },
                Some(reason) => return Safety::Stopped(reason),
                None if c.protocol_done => return Safety::Stopped(StopReason::Completed),
                None => return Safety::Running,
            },
            other => other,
        };
        match state {
            Safety::Braking { from_tick, reason } if c.brake_end(from_tick).is_some() => {
                Safety::Stopped(reason)
            }
            other => other,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SIGTERM: i32 = 15;

    /// Tick 10 of a running protocol, nothing wrong, a 5-tick stop limit.
    fn calm() -> Checks {
        Checks {
            tick: 10,
            feedback_timed_out: false,
            drive_fault: None,
            foreign_command: false,
            implausible: None,
            log_failed: false,
            out_of_range: None,
            degraded: None,
            signal: None,
            protocol_done: false,
            at_rest: false,
            stop_ticks: 5,
        }
    }

    const BRAKING: Safety = Safety::Braking {
        from_tick: 8,
        reason: StopReason::Signal(SIGTERM),
    };

    const HI5_FAULT: DriveAlarm = DriveAlarm::Hi5Fault { flags: 3 };

    #[test]
    fn a_drive_fault_prints_its_profiles_code_and_a_reset_has_its_own_exit_code() {
        let hi5 = StopReason::DriveFault(HI5_FAULT).to_string();
        assert!(
            hi5.contains("Hi5 FAULT") && hi5.contains("WATCHDOG"),
            "{hi5}"
        );
        let cia = StopReason::DriveFault(DriveAlarm::Cia402Fault {
            emcy_code: 0x8400,
            error_register: 0x01,
        });
        let text = cia.to_string();
        assert!(
            text.contains("EMCY 0x8400") && text.contains("overspeed") && text.contains("0x01"),
            "{text}"
        );
        assert!(!text.contains("FaultFlags"), "{text}");
        let lost = StopReason::DriveFault(DriveAlarm::HeartbeatLost { timeout_ms: 100 });
        assert!(lost.to_string().contains("heartbeat lost"), "{lost}");
        assert_eq!((cia.exit_code(), lost.exit_code()), (1, 1));
        let reset = StopReason::DriveReset(ResetReport::BootUp);
        assert_eq!(reset.exit_code(), 8);
        assert!(reset.to_string().starts_with("drive reset: "), "{reset}");
    }

    const JUMP: Implausible = Implausible::Step {
        step_rad: 0.5,
        allowed_rad: 0.026,
    };

    #[test]
    fn running_stays_running_when_nothing_happens() {
        assert_eq!(Safety::Running.next(&calm()), Safety::Running);
        assert_eq!(BRAKING.next(&calm()), BRAKING);
    }

    #[test]
    fn a_timeout_then_a_fault_then_a_foreign_command_stop_at_once_even_while_braking() {
        let all = Checks {
            feedback_timed_out: true,
            drive_fault: Some(HI5_FAULT),
            foreign_command: true,
            implausible: Some(JUMP),
            signal: Some(SIGTERM),
            ..calm()
        };
        for s in [Safety::Running, BRAKING] {
            let timeout = Safety::Stopped(StopReason::FeedbackTimeout);
            assert_eq!(s.next(&all), timeout);
            let fault = Checks {
                feedback_timed_out: false,
                ..all
            };
            assert_eq!(
                s.next(&fault),
                Safety::Stopped(StopReason::DriveFault(HI5_FAULT))
            );
            let reset = Checks {
                drive_fault: Some(DriveAlarm::Reset(ResetReport::BootUp)),
                ..fault
            };
            assert_eq!(
                s.next(&reset),
                Safety::Stopped(StopReason::DriveReset(ResetReport::BootUp))
            );
            let foreign = Checks {
                drive_fault: None,
                ..fault
            };
            assert_eq!(
                s.next(&foreign),
                Safety::Stopped(StopReason::ForeignCommand)
            );
            assert_eq!(foreign.brake_end(8), Some(BrakeEnd::Interrupted));
        }
    }

    #[test]
    fn a_signal_brakes_and_wins_over_completion() {
        let stop = Checks {
            signal: Some(SIGTERM),
            protocol_done: true,
            ..calm()
        };
        let braking = Safety::Running.next(&stop);
        assert_eq!(
            braking,
            Safety::Braking {
                from_tick: 10,
                reason: StopReason::Signal(SIGTERM),
            }
        );
        // A second signal does not restart the stop, nor change its reason.
        let later = Checks {
            tick: 12,
            signal: Some(1),
            ..stop
        };
        assert_eq!(braking.next(&later), braking);
    }

    #[test]
    fn untrusted_feedback_turns_the_torque_off_at_once_the_rest_brake() {
        let stale = Degradation::StaleRun {
            ticks: 101,
            limit: 100,
        };
        let estimator = Degradation::Estimator {
            errors: 11,
            limit: 10,
        };
        let all = Checks {
            implausible: Some(JUMP),
            log_failed: true,
            degraded: Some(estimator),
            signal: Some(SIGTERM),
            protocol_done: true,
            ..calm()
        };
        assert_eq!(
            Safety::Running.next(&all),
            Safety::Stopped(StopReason::ImplausibleFeedback(JUMP))
        );
        let no_jump = Checks {
            implausible: None,
            ..all
        };
        let braking = |reason| Safety::Braking {
            from_tick: 10,
            reason,
        };
        assert_eq!(
            Safety::Running.next(&no_jump),
            braking(StopReason::LogWriteFailed)
        );
        let only_degraded = Checks {
            log_failed: false,
            ..no_jump
        };
        assert_eq!(
            Safety::Running.next(&only_degraded),
            braking(StopReason::Degraded(estimator))
        );
        let missing = Checks {
            degraded: Some(stale),
            ..only_degraded
        };
        assert_eq!(
            Safety::Running.next(&missing),
            Safety::Stopped(StopReason::Degraded(stale))
        );
        let fraction = Degradation::MissingFeedback {
            missing: 600,
            ticks: 1000,
            limit: 0.5,
        };
        assert!(!StopReason::Degraded(fraction).brakes());
        assert_eq!(StopReason::Degraded(stale).stop_kind(), StopKind::TorqueOff);
        assert_eq!(
            StopReason::Signal(SIGTERM).stop_kind(),
            StopKind::Controlled
        );
        // The stop ends with the reason that began it, not a later one.
        let b = braking(StopReason::Degraded(estimator));
        assert_eq!(
            b.next(&Checks { tick: 15, ..all }),
            Safety::Stopped(StopReason::Degraded(estimator))
        );
    }

    #[test]
    fn the_brake_ends_at_rest_at_the_time_limit_or_on_an_implausible_feedback() {
        let at = |tick| Checks { tick, ..calm() };
        assert_eq!(BRAKING.next(&at(12)), BRAKING);
        assert_eq!(at(12).brake_end(8), None);
        assert_eq!(
            BRAKING.next(&at(13)),
            Safety::Stopped(StopReason::Signal(SIGTERM))
        );
        assert_eq!(at(13).brake_end(8), Some(BrakeEnd::TimeLimit));
        let rest = Checks {
            at_rest: true,
            ..at(9)
        };
        assert_eq!(rest.brake_end(8), Some(BrakeEnd::AtRest));
        assert_eq!(
            BRAKING.next(&rest),
            Safety::Stopped(StopReason::Signal(SIGTERM))
        );
        let implausible = Checks {
            implausible: Some(JUMP),
            at_rest: true,
            ..at(9)
        };
        assert_eq!(
            implausible.brake_end(8),
            Some(BrakeEnd::ImplausibleFeedback)
        );
        assert_eq!(
            BRAKING.next(&implausible),
            Safety::Stopped(StopReason::Signal(SIGTERM))
        );
        // A zero time limit, or a handle already at rest: stopped at once.
        let zero = Checks {
            signal: Some(SIGTERM),
            stop_ticks: 0,
            ..calm()
        };
        assert_eq!(
            Safety::Running.next(&zero),
            Safety::Stopped(StopReason::Signal(SIGTERM))
        );
        let resting = Checks {
            signal: Some(SIGTERM),
            at_rest: true,
            ..calm()
        };
        assert_eq!(
            Safety::Running.next(&resting),
            Safety::Stopped(StopReason::Signal(SIGTERM))
        );
    }

    #[test]
    fn the_protocols_end_completes() {
        let done = Checks {
            protocol_done: true,
            ..calm()
        };
        assert_eq!(
            Safety::Running.next(&done),
            Safety::Stopped(StopReason::Completed)
        );
        // While braking, the protocol's end does not cut the stop short.
        assert_eq!(BRAKING.next(&done), BRAKING);
        // A stopped loop stays stopped.
        let stopped = Safety::Stopped(StopReason::Completed);
        assert_eq!(stopped.next(&calm()), stopped);
    }

    #[test]
    fn the_brake_opposes_the_motion_within_its_bound() {
        assert_eq!(brake_torque_nm(1.0, 0.875, 3.0), -0.875);
        assert_eq!(brake_torque_nm(-2.0, 0.875, 3.0), 1.75);
        assert_eq!(brake_torque_nm(8.0, 0.875, 3.0), -3.0);
        assert_eq!(brake_torque_nm(-8.0, 0.875, 3.0), 3.0);
        assert_eq!(brake_torque_nm(0.0, 0.875, 3.0), 0.0);
    }

    /// The brake with the defaults (time constant 4 ms, bound 3 N m) on the
    /// exact zero-order-hold plant (0.0035 kg m^2, 1 ms), acting on the
    /// velocity `delay` ticks old: (travel rad, ticks to 0.01 rad/s, the
    /// largest speed after the first brake command).
    fn brake_from(v0: f64, delay: usize) -> (f64, u64, f64) {
        let (m, dt) = (0.0035, 1e-3);
        let (mut x, mut v, mut n) = (0.0, v0, 0u64);
        let mut seen = vec![v0; delay + 1];
        let mut peak: f64 = 0.0;
        while v.abs() >= 0.01 || seen.iter().any(|s| s.abs() >= 0.01) {
            let a = brake_torque_nm(seen[0], m / 0.004, 3.0) / m;
            (x, v) = (x + v * dt + 0.5 * a * dt * dt, v + a * dt);
            seen.remove(0);
            seen.push(v);
            peak = peak.max(v.abs());
            n += 1;
            assert!(n < 1000, "the brake does not settle");
        }
        (x, n, peak)
    }

    #[test]
    fn the_default_brake_stops_the_fastest_plausible_handle_within_0_05_rad() {
        // From the feedback's velocity limit (8 rad/s): 42.5 mrad, 26 ticks
        // (docs/safety.md; scripts/measure_safety.py --brake-model).
        let (travel, ticks, peak) = brake_from(8.0, 0);
        assert!(travel <= 0.05 && ticks == 26, "{travel} rad, {ticks} ticks");
        assert!(peak < 8.0);
        // With one tick of feedback delay it still settles without a speed
        // increase nor reversal beyond the rest speed.
        let (travel, ticks, peak) = brake_from(2.0, 1);
        assert!(
            travel <= 0.05 && ticks < 60 && peak <= 2.0,
            "{travel} {ticks} {peak}"
        );
    }

    /// The virtual Hi5's plant: 3 N m over 0.0035 kg m^2, 1 ms ticks.
    const LIMITS: FeedbackLimits = FeedbackLimits {
        max_velocity_rad_s: 8.0,
        step_margin_rad: 0.01,
        dt_s: 1e-3,
        max_acceleration_rad_s2: 3.0 / 0.0035,
        velocity_margin_rad_s: 0.05,
    };

    fn prev(x_rad: f64, v_rad_s: f64, ticks_apart: u64, steps: u32) -> Option<Previous> {
        Some(Previous {
            reading: Reading { x_rad, v_rad_s },
            ticks_apart,
            steps,
            most_steps: steps,
        })
    }

    fn at(x_rad: f64, v_rad_s: f64) -> Reading {
        Reading { x_rad, v_rad_s }
    }

    #[test]
    fn standard_cia402_steps_may_be_off_but_a_misreported_velocity_is_still_refused() {
        // After an answer in step: one step more than counted at most.
        let inexact = |p: Option<Previous>| {
            p.map(|p| Previous {
                most_steps: p.steps + 1,
                ..p
            })
        };
        // (feedback, the previous one, taken with exact steps (None: not
        // asserted), taken with inexact steps)
        let cases = [
            // 1 rad/s, 2 ms of motion between two feedbacks placed 1 SYNC
            // apart (a late answer): refused with exact steps, taken when
            // inexact.
            (at(0.002, 1.0), prev(0.0, 1.0, 1, 1), Some(false), true),
            // One step fewer (the previous one was the late one).
            (at(0.002, 1.0), prev(0.0, 1.0, 3, 3), None, true),
            // A velocity reported twice over, 1 step apart: neither 1 nor 2
            // steps explain it (0 is not a step).
            (at(0.001, 2.0), prev(0.0, 2.0, 1, 1), None, false),
            // The price (docs/safety.md): 2 steps apart, a doubled velocity
            // looks like 1 step; the echo mode refuses it.
            (at(0.004, 4.0), prev(0.0, 4.0, 2, 2), Some(false), true),
            // A stalled drive's late answer after a gap (a CI run: 1.44
            // rad/s reported, 0.48 rad/s implied over 3 ticks): one step of
            // motion placed 3 SYNCs after the previous feedback.
            (at(0.00144, 1.44), prev(0.0, 1.44, 3, 3), Some(false), true),
            // Running on, one SYNC apart, a velocity reported 1.5 times over
            // is explained by neither 1 nor 2 steps: refused.
            (at(0.001, 1.5), prev(0.0, 1.5, 1, 1), None, false),
            // Nor does any step count explain a velocity of the wrong sign.
            (at(0.002, -1.0), prev(0.0, -1.0, 3, 3), None, false),
        ];
        for (i, (now, before, exact, inexact_taken)) in cases.into_iter().enumerate() {
            if let Some(taken) = exact {
                assert_eq!(LIMITS.check(now, before).is_ok(), taken, "case {i}");
            }
            let taken = LIMITS.check(now, inexact(before)).is_ok();
            assert_eq!(taken, inexact_taken, "case {i}, inexact steps");
        }
    }

    #[test]
    fn feedback_plausibility() {
        let check = |x, v, p| LIMITS.check(at(x, v), p);
        // 8 rad/s for 2 ms + 10 mrad = 26 mrad per tick apart (the step
        // check); velocities consistent with the position's change.
        assert_eq!(check(0.0079, 7.9, prev(0.0, 7.9, 1, 0)), Ok(()));
        assert_eq!(check(-0.02, -8.0, None), Ok(()));
        assert!(matches!(
            check(0.0, 8.01, None),
            Err(Implausible::Velocity { .. })
        ));
        assert!(check(0.0, f64::NAN, None).is_err());
        assert!(check(f64::NAN, 0.0, prev(0.0, 0.0, 1, 1)).is_err());
        let jump = check(0.5, 0.0, prev(0.0, 0.0, 1, 1)).unwrap_err();
        assert!(
            matches!(jump, Implausible::Step { step_rad, allowed_rad }
                if step_rad == 0.5 && (allowed_rad - 0.026).abs() < 1e-12),
            "{jump:?}"
        );
        // 40 ticks apart allow 0.338 rad (at 7.5 rad/s over 40 steps: consistent).
        assert_eq!(check(0.3, 7.5, prev(0.0, 7.5, 40, 40)), Ok(()));
    }

    #[test]
    fn a_late_answer_then_the_next_one_tick_later_are_bounded_by_their_steps() {
        let check = |x, v, p| LIMITS.check(at(x, v), p);
        // A CI run: the drive stopped after answering one command and sent
        // that answer on resuming, then the answer to the 25 commands queued
        // meanwhile one tick later; 1.06 rad/s over those 25 steps moved
        // 26.5 mrad, more than one tick allows (26 mrad).
        let moved = 1.06 * 0.025;
        assert_eq!(check(moved, 1.06, prev(0.0, 1.06, 1, 25)), Ok(()));
        // The same step one drive step apart is the jump the check is for.
        assert!(matches!(
            check(moved, 1.06, prev(0.0, 1.06, 1, 1)),
            Err(Implausible::Step { .. })
        ));
        // 25 steps bound the step as 25 ticks do: 8 rad/s x 26 ms + 10 mrad.
        let limit = 8.0 * 0.026 + 0.01;
        let beyond = |p: Option<Previous>| match check(limit + 1e-4, 0.0, p) {
            Err(Implausible::Step { allowed_rad, .. }) => (allowed_rad - limit).abs() < 1e-12,
            _ => false,
        };
        assert!(beyond(prev(0.0, 0.0, 1, 25)) && beyond(prev(0.0, 0.0, 25, 1)));
        // Standard CiA 402: as many as the most steps.
        let inexact = Previous {
            most_steps: 25,
            ..prev(0.0, 0.0, 1, 24).unwrap()
        };
        assert_eq!(inexact.ticks_sampled_apart(), 25);
    }

    #[test]
    fn after_a_late_standard_answer_the_steps_it_may_be_late_by_are_allowed() {
        // A full run's numbers (standard CiA 402, a fault-free drive under
        // load): 1.0359 rad/s reported, 3.6282 rad/s from the position's
        // change, as over 1 SYNC counted here: about 3.5 drive steps of
        // motion, the previous answer having come late. One step more (the
        // rule before) refuses it; the most steps after an answer out of
        // step allow it.
        let (now, v) = (at(3.6282e-3, 1.0359), 1.0359);
        let with_most = |most_steps| {
            LIMITS.check(
                now,
                Some(Previous {
                    most_steps,
                    ..prev(0.0, v, 1, 1).unwrap()
                }),
            )
        };
        assert!(matches!(
            with_most(2),
            Err(Implausible::Inconsistent { .. })
        ));
        assert_eq!(with_most(4), Ok(()));
        // The same 4 steps still refuse a velocity of the wrong sign (over
        // 10 the plant's acceleration bound, 857 rad/s^2, would allow it).
        let backwards = Previous {
            most_steps: 4,
            ..prev(0.0, -v, 1, 1).unwrap()
        };
        assert!(LIMITS
            .check(at(3.6282e-3, -1.0359), Some(backwards))
            .is_err());
    }

    /// One exact zero-order-hold step of the plant under a constant torque.
    fn zoh_step(x: f64, v: f64, torque_nm: f64) -> (f64, f64) {
        let a = torque_nm / 0.0035;
        let dt = 1e-3;
        (x + v * dt + 0.5 * a * dt * dt, v + a * dt)
    }

    #[test]
    fn true_motion_at_the_torque_limit_is_consistent_and_forged_velocities_are_not() {
        // The plant's own steps, at the torque limit, pass with no margin at
        // all (the mean of the two velocities is the step's mean velocity).
        let exact = FeedbackLimits {
            velocity_margin_rad_s: 0.0,
            ..LIMITS
        };
        let (mut x, mut v) = (0.1, -2.0);
        for k in 0..200 {
            let torque = if (k / 7) % 2 == 0 { 3.0 } else { -3.0 };
            let (x1, v1) = zoh_step(x, v, torque);
            assert_eq!(
                exact.check(at(x1, v1), prev(x, v, 1, 1)),
                Ok(()),
                "step {k}"
            );
            (x, v) = (x1, v1);
        }
        // A torque changing within the interval (two steps seen as one):
        // within a_max T / 4.
        let (x1, v1) = zoh_step(0.0, 1.0, 3.0);
        let (x2, v2) = zoh_step(x1, v1, -3.0);
        assert_eq!(LIMITS.check(at(x2, v2), prev(0.0, 1.0, 2, 2)), Ok(()));
        // A velocity doubled (x copied, v forged) at 1 rad/s: 1 rad/s off,
        // allowed 0.264 rad/s (857 x 1 ms / 4 + 0.05).
        let (x1, v1) = zoh_step(0.0, 1.0, 0.0);
        let doubled = LIMITS.check(at(x1, 2.0 * v1), prev(0.0, 2.0, 1, 1));
        assert!(
            matches!(doubled, Err(Implausible::Inconsistent { allowed_rad_s, .. })
                if (allowed_rad_s - (3.0 / 0.0035 * 1e-3 / 4.0 + 0.05)).abs() < 1e-12),
            "{doubled:?}"
        );
        // Scaled by 1.5 at 1 rad/s: 0.5 rad/s off.
        assert!(LIMITS.check(at(x1, 1.5), prev(0.0, 1.5, 1, 1)).is_err());
        // A velocity that oscillates while the handle rests.
        assert!(LIMITS.check(at(0.0, 0.4), prev(0.0, 0.3, 1, 1)).is_err());
        // Steps unknown: the ticks apart stand in.
        assert!(LIMITS.check(at(x1, 2.0), prev(0.0, 2.0, 1, 0)).is_err());
    }

    #[test]
    fn degradation_thresholds() {
        let l = DegradedLimits {
            missing_fraction: 0.1,
            stale_run_ticks: 100,
            estimator_errors: 10,
            ticks_per_s: 1000,
        };
        let ok = Health {
            ticks: 500,
            missing: 100,
            stale_run: 100,
            estimator_errors: 10,
        };
        // 100 missing in the first half second: judged over a whole second.
        assert_eq!(degradation(&ok, &l), None);
        let missing = Health { missing: 101, ..ok };
        assert!(matches!(
            degradation(&missing, &l),
            Some(Degradation::MissingFeedback { missing: 101, .. })
        ));
        let later = Health {
            ticks: 5000,
            missing: 501,
            stale_run: 0,
            estimator_errors: 0,
        };
        assert!(degradation(&later, &l).is_some());
        let stale = Health {
            stale_run: 101,
            ..ok
        };
        assert!(matches!(
            degradation(&stale, &l),
            Some(Degradation::StaleRun { ticks: 101, .. })
        ));
        let est = Health {
            estimator_errors: 11,
            ..ok
        };
        assert!(matches!(
            degradation(&est, &l),
            Some(Degradation::Estimator { errors: 11, .. })
        ));
    }
}
