//! The 1 kHz loop: absolute deadlines, one torque command per tick over CAN,
//! the robot controller and the virtual human inside, logging to a ring.
//!
//! Set-up (`Rig::start`) talks to the drive until it is ENABLED and reads the
//! first feedback; `Rig::run` is the real-time part: every buffer it touches
//! exists before it starts, and a tick performs no allocation and no blocking
//! call other than the deadline sleep (proven by `tests/rig_loop.rs`).
//!
//! A tick reads sense -> decide -> actuate -> record; the decision starts
//! with the loop's [`Safety`] state, a small state machine
//! ([`Safety::next`]) that says whether the controller commands, the torque
//! ramps down, or the loop stops.

use crate::log::{LogRecord, LogSink};
use crate::os;
use crate::stats::{CanCounters, Histogram, LoopReport};
use sensaug_bridge::protocol::{decode, encode, DriveState, FaultFlags, Message, NodeId};
use sensaug_bridge::{Frame, Transport};
use sensaug_core::agent::{guard_torque, Guard, VirtualHuman};
use sensaug_core::controller::{Robot, RobotTick};
use sensaug_core::protocol::{Protocol, Sample};
use sensaug_core::ScenarioError;
use std::fmt;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// Why the loop stopped.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum StopReason {
    /// Every tick of the protocol ran.
    Completed,
    /// SIGINT or SIGTERM: torque ramped to zero, drive disabled.
    Signal,
    /// No feedback for longer than `rig.feedback_timeout_ms`: emergency stop sent.
    FeedbackTimeout,
    /// The drive reported FAULT (flags).
    DriveFault(u16),
}

impl fmt::Display for StopReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            StopReason::Completed => write!(f, "completed"),
            StopReason::Signal => write!(f, "signal (ramped down, drive disabled)"),
            StopReason::FeedbackTimeout => write!(f, "feedback timeout (emergency stop sent)"),
            StopReason::DriveFault(flags) => {
                write!(f, "drive fault {:?}", FaultFlags::from_bits_retain(*flags))
            }
        }
    }
}

/// The loop's safety state: who sets the next torque command.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Safety {
    /// The protocol runs: the controller commands.
    Running,
    /// A stop was requested at `from_tick`: the command ramps linearly from
    /// `from_torque_nm` (the last command sent) to 0.
    RampingDown {
        /// First tick of the ramp.
        from_tick: u64,
        /// The last command before the ramp (N m).
        from_torque_nm: f64,
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
    /// The drive reported FAULT (its flags).
    pub drive_fault: Option<u16>,
    /// SIGINT/SIGTERM (the stop flag).
    pub stop_requested: bool,
    /// Every tick of the protocol ran.
    pub protocol_done: bool,
    /// The last command sent (N m).
    pub last_torque_nm: f64,
    /// Length of the ramp-down (ticks).
    pub ramp_ticks: u64,
}

impl Safety {
    /// The state for this tick. A feedback timeout, then a drive fault, stop
    /// at once; a stop request starts the ramp (it wins over completion);
    /// the ramp stops after `ramp_ticks`; the protocol's end completes.
    pub fn next(self, c: &Checks) -> Safety {
        if let Safety::Stopped(_) = self {
            return self;
        }
        if c.feedback_timed_out {
            return Safety::Stopped(StopReason::FeedbackTimeout);
        }
        if let Some(flags) = c.drive_fault {
            return Safety::Stopped(StopReason::DriveFault(flags));
        }
        let state = match self {
            Safety::Running if c.stop_requested => Safety::RampingDown {
                from_tick: c.tick,
                from_torque_nm: c.last_torque_nm,
            },
            Safety::Running if c.protocol_done => Safety::Stopped(StopReason::Completed),
            other => other,
        };
        match state {
            Safety::RampingDown { from_tick, .. } if c.tick - from_tick >= c.ramp_ticks => {
                Safety::Stopped(StopReason::Signal)
            }
            other => other,
        }
    }
}

/// Tick timing, derived once from the settings before the first tick.
#[derive(Clone, Copy, Debug)]
struct Timing {
    /// Absolute time of tick 0 (ns, `CLOCK_MONOTONIC`).
    start_ns: u64,
    period_ns: u64,
    /// Feedback older than this many ticks trips the timeout.
    timeout_ticks: u64,
    ramp_ticks: u64,
}

impl Timing {
    fn new(s: &LoopSettings) -> Self {
        let period_ns = (s.dt_s * 1e9).round() as u64;
        Timing {
            start_ns: os::now_ns() + period_ns,
            period_ns,
            timeout_ticks: (s.feedback_timeout_ms * 1e-3 / s.dt_s).ceil() as u64,
            ramp_ticks: (s.ramp_down_s / s.dt_s).round() as u64,
        }
    }
}

/// When a tick was due and when it woke (ns).
#[derive(Clone, Copy, Debug)]
struct Wake {
    deadline_ns: u64,
    woke_ns: u64,
}

/// What a tick sensed.
#[derive(Clone, Copy, Debug)]
struct Sensed {
    wake: Wake,
    /// Last position received (controller units).
    x: f64,
    /// Last velocity received (controller units).
    v: f64,
    /// The feedback answers the previous command.
    fresh: bool,
    /// Ticks since the last feedback.
    age_ticks: u64,
}

/// What a tick decided: the torque to send and the controller's part of the
/// log record (NaN while ramping down).
#[derive(Clone, Copy, Debug)]
struct Command {
    torque_nm: f64,
    robot: RobotTick,
    tau: f64,
    tau_h: f64,
    u_h: f64,
    guard: Option<Guard>,
}

impl Command {
    /// Tick `i` of a ramp of `ramp_ticks` from `from_torque_nm`:
    /// `from (1 - (i + 1) / ramp_ticks)`.
    fn ramp(from_torque_nm: f64, i: u64, ramp_ticks: u64) -> Command {
        Command {
            torque_nm: from_torque_nm * (1.0 - (i + 1) as f64 / ramp_ticks.max(1) as f64),
            robot: RobotTick {
                u: f64::NAN,
                ..RobotTick::NONE
            },
            tau: f64::NAN,
            tau_h: f64::NAN,
            u_h: f64::NAN,
            guard: None,
        }
    }
}

/// Set-up failures, before anything moved.
#[derive(Debug)]
pub enum StartError {
    /// The virtual human's settings were rejected by the core (names the
    /// field).
    Scenario(ScenarioError),
    /// The drive did not reach the wanted state in time.
    Drive(String),
}

impl fmt::Display for StartError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            StartError::Scenario(e) => write!(f, "virtual human: {e}"),
            StartError::Drive(s) => write!(f, "drive: {s}"),
        }
    }
}

impl std::error::Error for StartError {}

/// Settings of the loop (from `[rig]` and the controller's configuration).
#[derive(Clone, Copy, Debug)]
pub struct LoopSettings {
    /// Drive node id.
    pub node: NodeId,
    /// Loop period (s).
    pub dt_s: f64,
    /// rad per controller position unit (torque scales the same way).
    pub rad_per_unit: f64,
    /// Torque limit at the drive (N m).
    pub torque_limit_nm: f64,
    /// Drive watchdog (ms).
    pub watchdog_ms: u16,
    /// Feedback timeout (ms).
    pub feedback_timeout_ms: f64,
    /// Ramp-down on a signal (s).
    pub ramp_down_s: f64,
    /// Virtual human gains over `xi` (zeros: no virtual human).
    pub partner_gains: [f64; 3],
    /// Virtual human torque limit (model units).
    pub partner_torque_limit: f64,
}

/// What the drive last told us.
#[derive(Clone, Copy, Debug)]
struct DriveView {
    state: DriveState,
    faults: FaultFlags,
    x_rad: f64,
    v_rad_s: f64,
    last_seq: Option<u8>,
    last_feedback_tick: u64,
}

/// The loop's state: everything allocated at set-up.
pub struct Rig<'a> {
    settings: LoopSettings,
    transport: Box<dyn Transport + Send>,
    robot: Robot<'a>,
    partner: VirtualHuman,
    protocol: Protocol<'a>,
    drive: DriveView,
    wake: Histogram,
    compute: Histogram,
    can: CanCounters,
    deadline_misses: u64,
    torque_clamped: u64,
    non_finite: u64,
    ticks_run: u64,
}

impl<'a> Rig<'a> {
    /// Set-up: checks the virtual human, then brings the drive from BOOT or
    /// DISABLED (clearing faults if needed) to ENABLED, and reads the first
    /// feedback with a zero-torque command.
    pub fn start(
        settings: LoopSettings,
        transport: Box<dyn Transport + Send>,
        robot: Robot<'a>,
        timeout: Duration,
    ) -> Result<Self, StartError> {
        let protocol = *robot.protocol();
        let partner = VirtualHuman::new(settings.partner_gains, settings.partner_torque_limit)
            .map_err(StartError::Scenario)?;
        let mut rig = Rig {
            settings,
            transport,
            robot,
            partner,
            protocol,
            drive: DriveView {
                state: DriveState::Boot,
                faults: FaultFlags::empty(),
                x_rad: 0.0,
                v_rad_s: 0.0,
                last_seq: None,
                last_feedback_tick: 0,
            },
            wake: Histogram::new(50_000),
            compute: Histogram::new(50_000),
            can: CanCounters::default(),
            deadline_misses: 0,
            torque_clamped: 0,
            non_finite: 0,
            ticks_run: 0,
        };
        rig.wait_for(timeout, "a heartbeat from the drive", |d| {
            d.state != DriveState::Boot
        })?;
        if rig.drive.state == DriveState::Fault {
            rig.send(&Message::ClearFaults);
            rig.wait_for(timeout, "DISABLED after clearing faults", |d| {
                d.state == DriveState::Disabled
            })?;
        }
        // Resync: the drive accepts exactly this sequence next, then +1 each.
        rig.send(&Message::SetState {
            enable: true,
            watchdog_ms: settings.watchdog_ms,
            sequence: 255,
        });
        rig.wait_for(timeout, "ENABLED", |d| d.state == DriveState::Enabled)?;
        rig.send(&Message::TorqueCommand {
            torque_nm: 0.0,
            sequence: 255,
        });
        rig.wait_for(timeout, "the first feedback", |d| d.last_seq == Some(255))?;
        Ok(rig)
    }

    fn wait_for(
        &mut self,
        timeout: Duration,
        what: &str,
        done: impl Fn(&DriveView) -> bool,
    ) -> Result<(), StartError> {
        let start = Instant::now();
        while !done(&self.drive) {
            if start.elapsed() > timeout {
                return Err(StartError::Drive(format!(
                    "waited {timeout:?} for {what} (state {:?}, faults {:?}); is the drive on the bus?",
                    self.drive.state, self.drive.faults
                )));
            }
            if let Ok(Some(f)) = self.transport.recv(Duration::from_millis(10)) {
                self.absorb(&f, 0);
            }
        }
        Ok(())
    }

    fn send(&mut self, msg: &Message) {
        match encode(self.settings.node, msg) {
            Ok(frame) => {
                if self.transport.send(&frame).is_err() {
                    self.can.send_errors += 1;
                }
            }
            Err(_) => self.can.send_errors += 1,
        }
    }

    /// Updates the drive view from one received frame.
    fn absorb(&mut self, frame: &Frame, tick: u64) {
        match decode(self.settings.node, frame) {
            Ok(Message::Feedback {
                position_rad,
                velocity_rad_s,
                sequence,
                state,
                ..
            }) => {
                self.drive.x_rad = position_rad;
                self.drive.v_rad_s = velocity_rad_s;
                self.drive.state = state;
                self.drive.last_seq = Some(sequence);
                self.drive.last_feedback_tick = tick;
            }
            Ok(Message::Heartbeat {
                state, fault_flags, ..
            })
            | Ok(Message::Fault {
                state, fault_flags, ..
            }) => {
                self.drive.state = state;
                self.drive.faults = fault_flags;
            }
            // Our own commands on a shared bus are not for us.
            Ok(_) => {}
            Err(_) => self.can.decode_errors += 1,
        }
    }

    /// Drains every frame already received, without waiting.
    fn drain(&mut self, tick: u64) {
        loop {
            match self.transport.recv(Duration::ZERO) {
                Ok(Some(f)) => self.absorb(&f, tick),
                Ok(None) => return,
                Err(_) => {
                    self.can.recv_errors += 1;
                    return;
                }
            }
        }
    }

    /// The real-time loop. Runs every tick of the protocol unless `stop` is
    /// raised (ramp down), feedback times out or the drive faults.
    ///
    /// Each tick: wait for its deadline, **sense** (drain the feedback, its
    /// freshness and age), **decide** (the safety state, then the controller
    /// or the ramp), **actuate** (one torque command), **record** (one log
    /// record).
    pub fn run(&mut self, log: &mut LogSink, stop: &AtomicBool) -> StopReason {
        let timing = Timing::new(&self.settings);
        let mut safety = Safety::Running;
        let mut last_torque_nm = 0.0;
        let mut k = 0u64;
        let reason = loop {
            let wake = self.wait_for_tick(&timing, k);
            let sensed = self.sense(k, wake);
            safety = safety.next(&self.checks(&timing, k, &sensed, stop, last_torque_nm));
            let command = match safety {
                Safety::Stopped(reason) => break reason,
                Safety::Running => match self.protocol.sample(k) {
                    Some(sample) => self.control(&sample, &sensed),
                    // k < total while running, so the protocol has a sample.
                    None => break StopReason::Completed,
                },
                Safety::RampingDown {
                    from_tick,
                    from_torque_nm,
                } => Command::ramp(from_torque_nm, k - from_tick, timing.ramp_ticks),
            };
            self.actuate(k, command.torque_nm);
            last_torque_nm = command.torque_nm;
            self.record(log, k, &sensed, &command, safety);
            k += 1;
        };
        self.ticks_run = k;
        self.shut_down(reason);
        reason
    }

    /// Sleeps until tick `k`'s absolute deadline; records the wake-up
    /// latency and counts a miss when the next deadline has already passed.
    fn wait_for_tick(&mut self, timing: &Timing, k: u64) -> Wake {
        let deadline_ns = timing.start_ns + k * timing.period_ns;
        os::sleep_until(deadline_ns);
        let woke_ns = os::now_ns();
        self.wake.record(woke_ns.saturating_sub(deadline_ns));
        if woke_ns > deadline_ns + timing.period_ns {
            self.deadline_misses += 1;
        }
        Wake {
            deadline_ns,
            woke_ns,
        }
    }

    /// Sense: drain the received frames; the feedback is fresh when it
    /// answers command `k - 1` (tick 0 uses the set-up's feedback).
    fn sense(&mut self, k: u64, wake: Wake) -> Sensed {
        self.drain(k);
        let expected = (k.wrapping_sub(1) & 0xff) as u8;
        let fresh = k == 0 || self.drive.last_seq == Some(expected);
        if !fresh {
            self.can.missing_feedback += 1;
        }
        // Controller units: positions in `unit`s, torques in model units.
        let unit = self.settings.rad_per_unit;
        Sensed {
            wake,
            x: self.drive.x_rad / unit,
            v: self.drive.v_rad_s / unit,
            fresh,
            age_ticks: k.saturating_sub(self.drive.last_feedback_tick),
        }
    }

    /// What the safety state machine looks at in tick `k`.
    fn checks(
        &self,
        timing: &Timing,
        k: u64,
        sensed: &Sensed,
        stop: &AtomicBool,
        last_torque_nm: f64,
    ) -> Checks {
        Checks {
            tick: k,
            feedback_timed_out: k > 0 && sensed.age_ticks > timing.timeout_ticks,
            drive_fault: (self.drive.state == DriveState::Fault).then(|| self.drive.faults.bits()),
            stop_requested: stop.load(Ordering::Relaxed),
            protocol_done: k >= self.protocol.total_ticks(),
            last_torque_nm,
            ramp_ticks: timing.ramp_ticks,
        }
    }

    /// Decide, while running: the robot's tick (predict-only without fresh
    /// feedback), the virtual human's torque, their sum in N m guarded at the
    /// drive's limit.
    fn control(&mut self, sample: &Sample<'_>, sensed: &Sensed) -> Command {
        let (x, v) = (sensed.x, sensed.v);
        let robot = self.robot.tick_at(sample, sensed.fresh.then_some((x, v)));
        let (u_h, _) = self.partner.torque(x, v, sample.tau, sample.tau_h);
        // Model torque -> N m: the same factor as position.
        let unit = self.settings.rad_per_unit;
        let (torque_nm, g) = guard_torque((robot.u + u_h) * unit, self.settings.torque_limit_nm);
        match g {
            Guard::Passed => {}
            Guard::Clamped => self.torque_clamped += 1,
            Guard::NonFinite => self.non_finite += 1,
        }
        Command {
            torque_nm,
            robot,
            tau: sample.tau,
            tau_h: sample.tau_h,
            u_h,
            guard: Some(g),
        }
    }

    /// Actuate: one torque command, sequence `k mod 256`.
    fn actuate(&mut self, k: u64, torque_nm: f64) {
        self.send(&Message::TorqueCommand {
            torque_nm,
            sequence: (k & 0xff) as u8,
        });
    }

    /// Record: the tick's compute time and its log record.
    fn record(
        &mut self,
        log: &mut LogSink,
        k: u64,
        sensed: &Sensed,
        command: &Command,
        safety: Safety,
    ) {
        let Wake {
            deadline_ns,
            woke_ns,
        } = sensed.wake;
        let compute_ns = os::now_ns().saturating_sub(woke_ns);
        self.compute.record(compute_ns);
        log.push(LogRecord {
            tick: k,
            t: k as f64 * self.settings.dt_s,
            x: sensed.x,
            v: sensed.v,
            fresh: sensed.fresh,
            tau: command.tau,
            tau_h: command.tau_h,
            u_h: command.u_h,
            torque_nm: command.torque_nm,
            robot: command.robot,
            wake_latency_us: woke_ns.saturating_sub(deadline_ns) as f64 / 1e3,
            compute_us: compute_ns as f64 / 1e3,
            feedback_age_ticks: sensed.age_ticks,
            drive_state: self.drive.state.raw(),
            guard: command.guard,
            ramp: matches!(safety, Safety::RampingDown { .. }),
        });
    }

    /// After the loop: an emergency stop on a feedback timeout, else zero
    /// torque; then disable.
    fn shut_down(&mut self, reason: StopReason) {
        if reason == StopReason::FeedbackTimeout {
            self.send(&Message::EmergencyStop);
        } else {
            // The sequence after the loop's last command (tick k sent k & 0xff).
            self.send(&Message::TorqueCommand {
                torque_nm: 0.0,
                sequence: (self.ticks_run & 0xff) as u8,
            });
        }
        self.send(&Message::SetState {
            enable: false,
            watchdog_ms: self.settings.watchdog_ms,
            sequence: 0,
        });
    }

    /// The end-of-run report (without the log and real-time fields).
    pub fn report(&self, reason: StopReason) -> LoopReport {
        let bus = self.transport.stats();
        let mut can = self.can;
        can.bus_sent = bus.sent;
        can.bus_received = bus.received;
        can.bus_malformed_dropped = bus.malformed_dropped;
        can.bus_kernel_dropped = bus.kernel_dropped;
        can.bus_error_frames = bus.error_frames;
        can.bus_tx_queue_full = bus.tx_queue_full;
        LoopReport {
            ticks: self.ticks_run,
            stop_reason: reason.to_string(),
            wake_latency: self.wake.summary(),
            compute: self.compute.summary(),
            deadline_misses: self.deadline_misses,
            can,
            ring_overflows: 0,
            records_written: 0,
            log_write_errors: 0,
            log_records_lost: 0,
            log_error: None,
            torque_clamped: self.torque_clamped,
            non_finite_commands: self.non_finite,
            estimator_errors: self.robot.counters().estimator_errors,
            missing_measurements: self.robot.counters().missing_measurements,
            partner_gains_estimate: self.robot.pseudo_gains(),
            partner_gains_true: self.settings.partner_gains,
            realtime: Vec::new(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{Checks, Safety, StopReason};

    /// Tick 10 of a running protocol, nothing wrong, a 5-tick ramp.
    fn calm() -> Checks {
        Checks {
            tick: 10,
            feedback_timed_out: false,
            drive_fault: None,
            stop_requested: false,
            protocol_done: false,
            last_torque_nm: 0.7,
            ramp_ticks: 5,
        }
    }

    const RAMP: Safety = Safety::RampingDown {
        from_tick: 8,
        from_torque_nm: 0.5,
    };

    #[test]
    fn running_stays_running_when_nothing_happens() {
        assert_eq!(Safety::Running.next(&calm()), Safety::Running);
        assert_eq!(RAMP.next(&calm()), RAMP);
    }

    #[test]
    fn a_timeout_then_a_fault_stop_at_once_even_while_ramping() {
        let both = Checks {
            feedback_timed_out: true,
            drive_fault: Some(3),
            stop_requested: true,
            ..calm()
        };
        for s in [Safety::Running, RAMP] {
            let timeout = Safety::Stopped(StopReason::FeedbackTimeout);
            assert_eq!(s.next(&both), timeout);
            let fault = Checks {
                feedback_timed_out: false,
                ..both
            };
            assert_eq!(s.next(&fault), Safety::Stopped(StopReason::DriveFault(3)));
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
                from_torque_nm: 0.7
            }
        );
        // A second request does not restart the ramp.
        let later = Checks { tick: 12, ..stop };
        assert_eq!(ramp.next(&later), ramp);
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
}
