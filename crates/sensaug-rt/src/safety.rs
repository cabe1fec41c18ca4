//! The loop's safety decisions: why it stops ([`StopReason`], each with its
//! own exit code), the state machine that decides who sets the next torque
//! command ([`Safety::next`]), and the per-tick checks it looks at: feedback
//! plausibility ([`plausible_feedback`]) and run health ([`degradation`]).
//! `docs/safety.md` lists every fault, its safe state and the measured time
//! to reach it.

use sensaug_bridge::drive_link::{DriveAlarm, ResetReport};
use std::fmt;

/// A feedback that physics rules out (`rig.max_feedback_velocity_rad_s`,
/// `rig.feedback_step_margin_rad`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Implausible {
    /// `|v| > limit` (rad/s).
    Velocity {
        /// The feedback's velocity.
        v_rad_s: f64,
        /// `rig.max_feedback_velocity_rad_s`.
        limit_rad_s: f64,
    },
    /// `|x - x_prev| > allowed` (rad).
    Step {
        /// The position step from the previous feedback.
        step_rad: f64,
        /// The largest step the velocity limit allows ([`max_step_rad`]).
        allowed_rad: f64,
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
                 (rig.max_feedback_velocity_rad_s x time since the last feedback \
                 + rig.feedback_step_margin_rad)"
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
    /// SIGINT or SIGTERM: torque ramped to zero, drive disabled.
    Signal,
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
    /// A feedback physics rules out: ramped down, drive disabled.
    ImplausibleFeedback(Implausible),
    /// Missing feedback or estimator health past its threshold: ramped
    /// down, drive disabled.
    Degraded(Degradation),
    /// The log writer failed (e.g. a full disk): ramped down, drive
    /// disabled; the log keeps what was written.
    LogWriteFailed,
}

impl StopReason {
    /// The process exit code (docs/realtime.md): 0 completed; 1 signal,
    /// feedback timeout or drive fault; 4 foreign command; 5 implausible
    /// feedback; 6 degraded; 7 log write failure; 8 drive reset. (2 is a
    /// configuration or set-up error, 3 another controller seen before
    /// enabling.)
    pub fn exit_code(&self) -> u8 {
        match self {
            StopReason::Completed => 0,
            StopReason::Signal | StopReason::FeedbackTimeout | StopReason::DriveFault(_) => 1,
            StopReason::ForeignCommand => 4,
            StopReason::ImplausibleFeedback(_) => 5,
            StopReason::Degraded(_) => 6,
            StopReason::LogWriteFailed => 7,
            StopReason::DriveReset(_) => 8,
        }
    }
}

impl fmt::Display for StopReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            StopReason::Completed => write!(f, "completed"),
            StopReason::Signal => write!(f, "signal (ramped down, drive disabled)"),
            StopReason::FeedbackTimeout => write!(f, "feedback timeout (emergency stop sent)"),
            StopReason::DriveFault(alarm) => write!(f, "drive fault: {alarm}"),
            StopReason::DriveReset(why) => write!(
                f,
                "drive reset: {why} (emergency stop sent; the drive must be set up again)"
            ),
            StopReason::ForeignCommand => write!(
                f,
                "foreign command: a command frame for this node that this process did not \
                 send; another controller (a second sensaug-rt?) is on the same bus and node \
                 (emergency stop sent)"
            ),
            StopReason::ImplausibleFeedback(why) => write!(
                f,
                "implausible feedback: {why} (ramped down, drive disabled)"
            ),
            StopReason::Degraded(why) => {
                write!(f, "degraded: {why} (ramped down, drive disabled)")
            }
            StopReason::LogWriteFailed => write!(
                f,
                "log write failed (ramped down, drive disabled; the log keeps what was written)"
            ),
        }
    }
}

/// The largest position step between two feedbacks `ticks_apart` ticks of
/// `dt_s` apart: `v_max * (max(ticks_apart, 1) + 1) * dt + margin` (one
/// tick added for the receive jitter of either feedback).
pub fn max_step_rad(v_max_rad_s: f64, ticks_apart: u64, dt_s: f64, margin_rad: f64) -> f64 {
    v_max_rad_s * (ticks_apart.max(1) + 1) as f64 * dt_s + margin_rad
}

/// A feedback `(x, v)` against physics: `|v| <= v_max` and, after a previous
/// feedback `x_prev` received `ticks_apart` ticks earlier,
/// `|x - x_prev| <= max_step_rad(..)`. Non-finite values are implausible.
pub fn plausible_feedback(
    x_rad: f64,
    v_rad_s: f64,
    prev: Option<(f64, u64)>,
    v_max_rad_s: f64,
    dt_s: f64,
    margin_rad: f64,
) -> Result<(), Implausible> {
    // A NaN compares as neither: implausible.
    let within = |a: f64, limit: f64| a.abs() <= limit;
    if !within(v_rad_s, v_max_rad_s) {
        return Err(Implausible::Velocity {
            v_rad_s,
            limit_rad_s: v_max_rad_s,
        });
    }
    if let Some((x_prev, ticks_apart)) = prev {
        let step_rad = (x_rad - x_prev).abs();
        let allowed_rad = max_step_rad(v_max_rad_s, ticks_apart, dt_s, margin_rad);
        if !within(step_rad, allowed_rad) {
            return Err(Implausible::Step {
                step_rad,
                allowed_rad,
            });
        }
    }
    Ok(())
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
    /// A stop was requested at `from_tick`: the command ramps linearly from
    /// `from_torque_nm` (the last command sent) to 0, then the loop stops
    /// for `reason`.
    RampingDown {
        /// First tick of the ramp.
        from_tick: u64,
        /// The last command before the ramp (N m).
        from_torque_nm: f64,
        /// Why the loop stops at the ramp's end.
        reason: StopReason,
    },
    /// The loop ends for this reason.
    Stopped(StopReason),
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
    /// The run crossed a degraded-run threshold.
    pub degraded: Option<Degradation>,
    /// SIGINT/SIGTERM (the stop flag).
    pub stop_requested: bool,
    /// Every tick of the protocol ran.
    pub protocol_done: bool,
    /// The last command sent (N m).
    pub last_torque_nm: f64,
    /// Length of the ramp-down (ticks).
    pub ramp_ticks: u64,
}

impl Checks {
    /// Why the loop must ramp down, if it must: implausible feedback, then a
    /// log failure, then a degraded run, then a stop request.
    fn ramp_reason(&self) -> Option<StopReason> {
        self.implausible
            .map(StopReason::ImplausibleFeedback)
            .or(self.log_failed.then_some(StopReason::LogWriteFailed))
            .or(self.degraded.map(StopReason::Degraded))
            .or(self.stop_requested.then_some(StopReason::Signal))
    }
}

impl Safety {
    /// The state for this tick. A feedback timeout, then a drive fault, then
    /// a foreign command stop at once; implausible feedback, a log failure,
    /// a degraded run or a stop request start the ramp (they win over
    /// completion); the ramp stops after `ramp_ticks`; the protocol's end
    /// completes.
    pub fn next(self, c: &Checks) -> Safety {
        if let Safety::Stopped(_) = self {
            return self;
        }
        if c.feedback_timed_out {
            return Safety::Stopped(StopReason::FeedbackTimeout);
        }
        match c.drive_fault {
            Some(DriveAlarm::Reset(why)) => return Safety::Stopped(StopReason::DriveReset(why)),
            Some(alarm) => return Safety::Stopped(StopReason::DriveFault(alarm)),
            None => {}
        }
        if c.foreign_command {
            return Safety::Stopped(StopReason::ForeignCommand);
        }
        let state = match self {
            Safety::Running => match c.ramp_reason() {
                Some(reason) => Safety::RampingDown {
                    from_tick: c.tick,
                    from_torque_nm: c.last_torque_nm,
                    reason,
                },
                None if c.protocol_done => Safety::Stopped(StopReason::Completed),
                None => Safety::Running,
            },
            other => other,
        };
        match state {
            Safety::RampingDown {
                from_tick, reason, ..
            } if c.tick - from_tick >= c.ramp_ticks => Safety::Stopped(reason),
            other => other,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Tick 10 of a running protocol, nothing wrong, a 5-tick ramp.
    fn calm() -> Checks {
        Checks {
            tick: 10,
            feedback_timed_out: false,
            drive_fault: None,
            foreign_command: false,
            implausible: None,
            log_failed: false,
            degraded: None,
            stop_requested: false,
            protocol_done: false,
            last_torque_nm: 0.7,
            ramp_ticks: 5,
        }
    }

    const RAMP: Safety = Safety::RampingDown {
        from_tick: 8,
        from_torque_nm: 0.5,
        reason: StopReason::Signal,
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
        assert_eq!(RAMP.next(&calm()), RAMP);
    }

    #[test]
    fn a_timeout_then_a_fault_then_a_foreign_command_stop_at_once_even_while_ramping() {
        let all = Checks {
            feedback_timed_out: true,
            drive_fault: Some(HI5_FAULT),
            foreign_command: true,
            implausible: Some(JUMP),
            stop_requested: true,
            ..calm()
        };
        for s in [Safety::Running, RAMP] {
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
        }
    }

    #[test]
    fn a_stop_request_ramps_from_the_last_command_and_wins_over_completion() {
        let stop = Checks {
            stop_requested: true,
            protocol_done: true,
            ..calm()
        };
        let ramp = Safety::Running.next(&stop);
        assert_eq!(
            ramp,
            Safety::RampingDown {
                from_tick: 10,
                from_torque_nm: 0.7,
                reason: StopReason::Signal,
            }
        );
        // A second request does not restart the ramp.
        let later = Checks { tick: 12, ..stop };
        assert_eq!(ramp.next(&later), ramp);
    }

    #[test]
    fn implausible_feedback_then_log_failure_then_degradation_ramp_with_their_reason() {
        let degraded = Degradation::StaleRun {
            ticks: 101,
            limit: 100,
        };
        let all = Checks {
            implausible: Some(JUMP),
            log_failed: true,
            degraded: Some(degraded),
            stop_requested: true,
            protocol_done: true,
            ..calm()
        };
        let reason = |c: &Checks| match Safety::Running.next(c) {
            Safety::RampingDown { reason, .. } => reason,
            other => panic!("{other:?}"),
        };
        assert_eq!(reason(&all), StopReason::ImplausibleFeedback(JUMP));
        let no_jump = Checks {
            implausible: None,
            ..all
        };
        assert_eq!(reason(&no_jump), StopReason::LogWriteFailed);
        let only_degraded = Checks {
            log_failed: false,
            ..no_jump
        };
        assert_eq!(reason(&only_degraded), StopReason::Degraded(degraded));
        // The ramp ends with the reason that started it, not a later one.
        let ramp = Safety::Running.next(&Checks {
            stop_requested: false,
            ..only_degraded
        });
        assert_eq!(
            ramp.next(&Checks { tick: 15, ..all }),
            Safety::Stopped(StopReason::Degraded(degraded))
        );
    }

    #[test]
    fn the_ramp_ends_after_ramp_ticks_and_a_zero_ramp_at_once() {
        let at = |tick| Checks { tick, ..calm() };
        assert_eq!(RAMP.next(&at(12)), RAMP);
        assert_eq!(RAMP.next(&at(13)), Safety::Stopped(StopReason::Signal));
        let zero = Checks {
            stop_requested: true,
            ramp_ticks: 0,
            ..calm()
        };
        assert_eq!(
            Safety::Running.next(&zero),
            Safety::Stopped(StopReason::Signal)
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
        // While ramping, the protocol's end does not cut the ramp short.
        assert_eq!(RAMP.next(&done), RAMP);
        // A stopped loop stays stopped.
        let stopped = Safety::Stopped(StopReason::Completed);
        assert_eq!(stopped.next(&calm()), stopped);
    }

    #[test]
    fn feedback_plausibility() {
        let check = |x, v, prev| plausible_feedback(x, v, prev, 8.0, 1e-3, 0.01);
        // 8 rad/s for 2 ms + 10 mrad = 26 mrad per tick apart.
        assert_eq!(check(0.02, 7.9, Some((0.0, 1))), Ok(()));
        assert_eq!(check(-0.02, -8.0, None), Ok(()));
        assert!(matches!(
            check(0.0, 8.01, None),
            Err(Implausible::Velocity { .. })
        ));
        assert!(check(0.0, f64::NAN, None).is_err());
        assert!(check(f64::NAN, 0.0, Some((0.0, 1))).is_err());
        let jump = check(0.5, 0.0, Some((0.0, 1))).unwrap_err();
        assert!(
            matches!(jump, Implausible::Step { step_rad, allowed_rad }
                if step_rad == 0.5 && (allowed_rad - 0.026).abs() < 1e-12),
            "{jump:?}"
        );
        // Two feedbacks in one tick count as one tick apart; 40 ticks allow 0.338 rad.
        assert_eq!(check(0.03, 0.0, Some((0.005, 0))), Ok(()));
        assert_eq!(check(0.3, 0.0, Some((0.0, 40))), Ok(()));
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
