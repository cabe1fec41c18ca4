//! The 1 kHz loop: absolute deadlines, one torque command per tick over CAN,
//! the robot controller and the virtual human inside, logging to a ring.
//!
//! Set-up (`Rig::start`) talks to the drive until it is ENABLED and reads the
//! first feedback; `Rig::run` is the real-time part: every buffer it touches
//! exists before it starts, and a tick performs no allocation and no blocking
//! call other than the deadline sleep (proven by `tests/alloc.rs`).

use crate::log::{LogRecord, LogSink};
use crate::os;
use crate::stats::{CanCounters, Histogram, LoopReport};
use sensaug_bridge::protocol::{decode, encode, DriveState, FaultFlags, Message, NodeId};
use sensaug_bridge::{Frame, Transport};
use sensaug_core::agent::{feedback_torque, guard_torque, xi, Guard};
use sensaug_core::scenario::{Protocol, Robot, RobotTick, ScenarioError};
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

/// Set-up failures, before anything moved.
#[derive(Debug)]
pub enum StartError {
    /// The controller's configuration was rejected by the core.
    Scenario(ScenarioError),
    /// The drive did not reach the wanted state in time.
    Drive(String),
}

impl fmt::Display for StartError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            StartError::Scenario(e) => write!(f, "controller configuration: {e:?}"),
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
    /// Set-up: builds the controller, then brings the drive from BOOT or
    /// DISABLED (clearing faults if needed) to ENABLED, and reads the first
    /// feedback with a zero-torque command.
    pub fn start(
        settings: LoopSettings,
        transport: Box<dyn Transport + Send>,
        robot: Robot<'a>,
        timeout: Duration,
    ) -> Result<Self, StartError> {
        let protocol = *robot.protocol();
        let mut rig = Rig {
            settings,
            transport,
            robot,
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
        rig.send(&Message::SetState {
            enable: true,
            watchdog_ms: settings.watchdog_ms,
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
    pub fn run(&mut self, log: &mut LogSink, stop: &AtomicBool) -> StopReason {
        let s = self.settings;
        let period_ns = (s.dt_s * 1e9).round() as u64;
        let total = self.protocol.total_ticks();
        let timeout_ticks = (s.feedback_timeout_ms * 1e-3 / s.dt_s).ceil() as u64;
        let ramp_ticks = (s.ramp_down_s / s.dt_s).round() as u64;
        let unit = s.rad_per_unit;
        let start_ns = os::now_ns() + period_ns;
        let mut last_command = 0.0;
        let mut ramp: Option<(u64, f64)> = None;
        let mut k = 0u64;
        let reason = loop {
            let deadline = start_ns + k * period_ns;
            os::sleep_until(deadline);
            let woke = os::now_ns();
            self.wake.record(woke.saturating_sub(deadline));
            if woke > deadline + period_ns {
                self.deadline_misses += 1;
            }

            self.drain(k);
            let expected = (k.wrapping_sub(1) & 0xff) as u8;
            let fresh = k == 0 || self.drive.last_seq == Some(expected);
            if !fresh {
                self.can.missing_feedback += 1;
            }
            let age = k.saturating_sub(self.drive.last_feedback_tick);
            if k > 0 && age > timeout_ticks {
                self.send(&Message::EmergencyStop);
                break StopReason::FeedbackTimeout;
            }
            if self.drive.state == DriveState::Fault {
                break StopReason::DriveFault(self.drive.faults.bits());
            }
            if ramp.is_none() && stop.load(Ordering::Relaxed) {
                ramp = Some((k, last_command));
            }
            if ramp.is_none() && k >= total {
                break StopReason::Completed;
            }

            // Controller units: positions in `unit`s, torques in model units.
            let x = self.drive.x_rad / unit;
            let v = self.drive.v_rad_s / unit;
            let mut rec = LogRecord {
                tick: k,
                t: k as f64 * s.dt_s,
                x,
                v,
                tau: f64::NAN,
                tau_h: f64::NAN,
                u_h: f64::NAN,
                torque_nm: 0.0,
                robot: RobotTick {
                    u: f64::NAN,
                    ..RobotTick::NONE
                },
                wake_latency_us: woke.saturating_sub(deadline) as f64 / 1e3,
                compute_us: f64::NAN,
                feedback_age_ticks: age,
                drive_state: self.drive.state.raw(),
                guard: f64::NAN,
                ramp: ramp.is_some(),
            };
            let torque_nm = match (ramp, self.protocol.sample(k)) {
                (Some((k0, from)), _) => {
                    let i = k - k0;
                    if i >= ramp_ticks {
                        break StopReason::Signal;
                    }
                    from * (1.0 - (i + 1) as f64 / ramp_ticks.max(1) as f64)
                }
                (None, Some(sample)) => {
                    rec.robot = self.robot.tick_at(&sample, fresh.then_some((x, v)));
                    let (u_h, _) = guard_torque(
                        feedback_torque(&s.partner_gains, &xi(x, v, sample.tau, sample.tau_h)),
                        s.partner_torque_limit,
                    );
                    (rec.tau, rec.tau_h, rec.u_h) = (sample.tau, sample.tau_h, u_h);
                    // Model torque -> N m: the same factor as position.
                    let (t, g) = guard_torque((rec.robot.u + u_h) * unit, s.torque_limit_nm);
                    match g {
                        Guard::Passed => {}
                        Guard::Clamped => self.torque_clamped += 1,
                        Guard::NonFinite => self.non_finite += 1,
                    }
                    rec.guard = g as u8 as f64;
                    t
                }
                // k < total here, so the protocol has a sample.
                (None, None) => break StopReason::Completed,
            };
            last_command = torque_nm;
            self.send(&Message::TorqueCommand {
                torque_nm,
                sequence: (k & 0xff) as u8,
            });
            let done = os::now_ns();
            self.compute.record(done.saturating_sub(woke));
            rec.torque_nm = torque_nm;
            rec.compute_us = done.saturating_sub(woke) as f64 / 1e3;
            log.push(rec);
            k += 1;
        };
        self.ticks_run = k;
        self.shut_down(reason);
        reason
    }

    /// After the loop: zero torque and disable (an emergency stop was
    /// already sent on a feedback timeout).
    fn shut_down(&mut self, reason: StopReason) {
        if reason != StopReason::FeedbackTimeout {
            self.send(&Message::TorqueCommand {
                torque_nm: 0.0,
                sequence: 0,
            });
        }
        self.send(&Message::SetState {
            enable: false,
            watchdog_ms: self.settings.watchdog_ms,
        });
    }

    /// The end-of-run report (without the log and real-time fields).
    pub fn report(&self, reason: StopReason) -> LoopReport {
        let bus = self.transport.stats();
        let mut can = self.can;
        can.bus_sent = bus.sent;
        can.bus_received = bus.received;
        can.bus_malformed_dropped = bus.malformed_dropped;
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
