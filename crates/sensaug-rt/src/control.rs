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
//! ([`Safety::next`]) that says whether the controller commands, the
//! controlled stop brakes the handle, or the loop stops.

use crate::log::LogSink;
use crate::os;
use crate::stats::{CanCounters, ComputeParts, DriveReport, Histogram, LoopReport, StartGap};
use crate::wake::{wake_up, Wake};
use sensaug_bridge::drive_link::{Absorbed, DriveLink, DriveSample, DriveStatus};
use sensaug_bridge::{Frame, Transport};
/// The loop's settings: derived once, with the rest of the configuration,
/// when it is resolved (`sensaug_config::Resolved::rig`).
pub use sensaug_config::rig::{RigSettings as LoopSettings, StopSettings, QUIET_WATCHDOG_PERIODS};
use sensaug_core::agent::{guard_torque, Guard, PartnerLaw};
use sensaug_core::controller::{applied_torque, Robot};
use sensaug_core::plant::{Plant, PlantParams, PlantState};
use sensaug_core::protocol::{Protocol, Sample};
use sensaug_core::row::Row;
use sensaug_core::ScenarioError;
use std::fmt;
use std::sync::atomic::{AtomicUsize, Ordering};

use crate::safety::{
    brake_torque_nm, degradation, DegradedLimits, FeedbackLimits, Health, Implausible, Previous,
    Reading,
};
pub use crate::safety::{Checks, Safety, StopKind, StopReason};
use crate::stats::StopReport;
use std::time::{Duration, Instant};

/// `t` on the `CLOCK_MONOTONIC` ns scale of [`os::now_ns`].
fn instant_ns(t: Instant) -> u64 {
    let ago = u64::try_from(t.elapsed().as_nanos()).unwrap_or(u64::MAX);
    os::now_ns().saturating_sub(ago)
}

/// Tick timing, derived once from the settings before the first tick.
#[derive(Clone, Copy, Debug)]
struct Timing {
    /// Absolute time of tick 0 (ns, `CLOCK_MONOTONIC`).
    start_ns: u64,
    period_ns: u64,
    /// How long before each deadline the sleep ends and the spin begins.
    spin_ns: u64,
    /// Feedback older than this many ticks trips the timeout.
    timeout_ticks: u64,
    /// The controlled stop's time limit (ticks).
    stop_ticks: u64,
}

impl Timing {
    /// Tick 0 is due one period after the set-up's first command
    /// (`first_command_ns`), or now if that has passed: the drive's watchdog
    /// sees no longer gap at the start than between two ticks.
    fn new(s: &LoopSettings, first_command_ns: u64) -> Self {
        Timing {
            start_ns: (first_command_ns + s.period_ns).max(os::now_ns()),
            period_ns: s.period_ns,
            spin_ns: u64::from(s.spin_us) * 1000,
            timeout_ticks: s.feedback_timeout_ticks,
            stop_ticks: s.stop_ticks,
        }
    }
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

/// What a tick decided: the torque to send and the tick's log row so far
/// (the controller's columns, the targets, the virtual human's torque, the
/// torque sent and its guard; unknown during the controlled stop).
#[derive(Clone, Copy, Debug)]
struct Command {
    torque_nm: f64,
    row: Row,
}

impl Command {
    /// A tick of the controlled stop: `torque_nm` from the brake (zero on
    /// a tick without fresh feedback), no controller.
    fn stopping(torque_nm: f64) -> Command {
        Command {
            torque_nm,
            row: Row {
                torque_nm,
                ..Row::UNKNOWN
            },
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
    /// Command frames for this node that this process did not send were
    /// seen before enabling (their count): another controller is on the bus.
    ForeignController(u64),
}

impl StartError {
    /// The process exit code: 3 for another controller, 2 for the others
    /// (a set-up error).
    pub fn exit_code(&self) -> u8 {
        match self {
            StartError::ForeignController(_) => 3,
            _ => 2,
        }
    }
}

impl fmt::Display for StartError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            StartError::Scenario(e) => write!(f, "virtual human: {e}"),
            StartError::Drive(s) => write!(f, "drive: {s}"),
            StartError::ForeignController(n) => write!(
                f,
                "another controller is on the bus: {n} command frame(s) for this node that \
                 this process did not send, seen before enabling; is another sensaug-rt \
                 running on the same bus and rig.node_id? Refusing to start (drive not enabled)"
            ),
        }
    }
}

impl std::error::Error for StartError {}

/// The feedback checks' limits from the loop's settings.
fn feedback_limits(s: &LoopSettings) -> FeedbackLimits {
    FeedbackLimits {
        max_velocity_rad_s: s.max_feedback_velocity_rad_s,
        step_margin_rad: s.feedback_step_margin_rad,
        dt_s: s.dt_s,
        max_acceleration_rad_s2: s.max_acceleration_rad_s2,
        velocity_margin_rad_s: s.feedback_velocity_margin_rad_s,
    }
}

/// The degraded-run checks' limits from the loop's settings.
fn degraded_limits(s: &LoopSettings) -> DegradedLimits {
    DegradedLimits {
        missing_fraction: s.max_missing_feedback_fraction,
        stale_run_ticks: s.max_stale_feedback_ticks,
        estimator_errors: s.max_estimator_errors,
        ticks_per_s: (1.0 / s.dt_s).round() as u64,
    }
}

/// When set-up talked to the drive (ns, `CLOCK_MONOTONIC`), for the start
/// gap in the statistics.
#[derive(Clone, Copy, Debug, Default)]
struct StartTimes {
    enable_ns: u64,
    first_command_ns: u64,
    first_tick_ns: u64,
}

/// What the drive last told us.
#[derive(Clone, Copy, Debug)]
struct DriveView {
    /// The link's sample as of the last sense: the position, velocity and
    /// status the loop acts on.
    sample: DriveSample,
    /// The last feedback taken and the tick it came in: the plausibility
    /// check's previous feedback (several can arrive between two senses)
    /// and the feedback's age.
    last_feedback: Option<(Reading, u64)>,
}

/// What the virtual human acts on: the handle's state, measured when the
/// tick's feedback is fresh, else predicted by the handle's model from the
/// previous tick's view through the torque sent then.
///
/// The virtual human stands for a person, who sees and feels the handle
/// itself, not through the bus. Acting on the last measurement instead gave
/// it a delay of as many ticks as the feedback was late, which the robot's
/// stage 1 (a partner acting on the current state) read as other gains: on
/// a loaded 2-core CI machine the Hi5 run estimated Lhh 2.11 and 2.19 for 2.
/// The virtual drives step the same model once per command, so the
/// prediction is theirs up to the encoder's resolution.
struct HandleView {
    model: Plant,
    /// The torque sent in the previous tick (model units).
    last_torque: f64,
}

impl HandleView {
    fn new(params: PlantParams) -> Result<Self, sensaug_core::plant::PlantError> {
        Ok(Self {
            model: Plant::new(params)?,
            last_torque: 0.0,
        })
    }

    /// This tick's view: `measured` when fresh, else one model step from
    /// the previous view (the measurement if the step is not finite).
    fn see(&mut self, measured: PlantState, fresh: bool) -> PlantState {
        if fresh {
            self.model.set_state(measured);
            return measured;
        }
        match self.model.step(self.last_torque) {
            Ok(predicted) => predicted,
            Err(_) => {
                self.model.set_state(measured);
                measured
            }
        }
    }
}

/// The torque the drive applies for the sum `asked_nm` (N m, guarded at
/// `limit_nm`): rounded to its step `step_nm` ([`applied_torque`]); and the
/// robot's part of it (model units): its command `u` plus that rounding.
///
/// The drive rounds the sum of the robot's and the virtual human's torques;
/// the rounding is the robot's, so the virtual human's torque reaches the
/// handle exact, as a person's does on a real rig, and the estimators,
/// predicting with the robot's part, identify the virtual human itself, not
/// its torque quantised to the step (`docs/cia402.md`, "The Lhh difference
/// between the profiles").
pub fn drive_torque(
    asked_nm: f64,
    u: f64,
    step_nm: f64,
    limit_nm: f64,
    rad_per_unit: f64,
) -> (f64, f64) {
    let torque_nm = applied_torque(asked_nm, step_nm, limit_nm);
    (torque_nm, u + (torque_nm - asked_nm) / rad_per_unit)
}

/// The loop's state: everything allocated at set-up.
pub struct Rig<'a> {
    settings: LoopSettings,
    /// From `settings`, built once at start (not in every tick).
    degraded_limits: DegradedLimits,
    feedback_limits: FeedbackLimits,
    link: Box<dyn DriveLink + Send>,
    transport: Box<dyn Transport + Send>,
    robot: Robot<'a>,
    partner: PartnerLaw,
    /// The virtual human's view of the handle.
    handle_view: HandleView,
    protocol: Protocol<'a>,
    drive: DriveView,
    wake: Histogram,
    /// The deadline sleep's return after its own target (the OS's part).
    sleep: Histogram,
    compute: Histogram,
    parts: ComputeParts,
    /// Page faults of the loop's thread during [`Rig::run`].
    page_faults: u64,
    can: CanCounters,
    deadline_misses: u64,
    torque_clamped: u64,
    /// The drive's torque resolution (N m; [`DriveLink::torque_step_nm`],
    /// known after the enable): the torque sent is rounded to it
    /// ([`drive_torque`]).
    torque_step_nm: f64,
    non_finite: u64,
    ticks_run: u64,
    /// The first implausible feedback.
    implausible: Option<Implausible>,
    /// Consecutive ticks without fresh feedback, and the longest such run.
    stale_run: u64,
    longest_stale_run: u64,
    times: StartTimes,
    /// How the stop went (filled in by [`Rig::run`]).
    stop: StopReport,
}

impl<'a> Rig<'a> {
    /// Set-up: checks the virtual human, waits for the drive to be on the
    /// bus ([`DriveLink::connect`]), listens for another controller
    /// ([`LoopSettings::quiet_period`]; any command for this drive refuses
    /// the start), then enables it ([`DriveLink::enable`]: faults cleared,
    /// zero torque, the first feedback read). Each step is bounded by the
    /// link's own timeout.
    pub fn start(
        settings: LoopSettings,
        link: Box<dyn DriveLink + Send>,
        transport: Box<dyn Transport + Send>,
        robot: Robot<'a>,
    ) -> Result<Self, StartError> {
        let protocol = *robot.protocol();
        let partner = PartnerLaw::new(
            settings.partner_gains,
            settings.partner_torque_limit,
            settings.partner_human,
            settings.dt_s,
        )
        .map_err(StartError::Scenario)?;
        let handle_view = HandleView::new(settings.plant)
            .map_err(|e| StartError::Scenario(ScenarioError::Plant(e)))?;
        let mut rig = Rig {
            degraded_limits: degraded_limits(&settings),
            feedback_limits: feedback_limits(&settings),
            settings,
            link,
            transport,
            robot,
            partner,
            handle_view,
            protocol,
            drive: DriveView {
                sample: DriveSample::default(),
                last_feedback: None,
            },
            wake: Histogram::new(50_000),
            sleep: Histogram::new(50_000),
            compute: Histogram::new(50_000),
            parts: ComputeParts::new(10_000),
            page_faults: 0,
            can: CanCounters::default(),
            deadline_misses: 0,
            torque_clamped: 0,
            torque_step_nm: f64::NAN,
            non_finite: 0,
            ticks_run: 0,
            implausible: None,
            stale_run: 0,
            longest_stale_run: 0,
            times: StartTimes::default(),
            stop: StopReport {
                kind: StopKind::Completed,
                tick: 0,
                braking_ticks: 0,
                brake_end: None,
                speed_at_stop_rad_s: f64::NAN,
                speed_at_end_rad_s: f64::NAN,
            },
        };
        rig.link
            .connect(rig.transport.as_mut())
            .map_err(|e| StartError::Drive(e.to_string()))?;
        // Commands seen while connecting refuse the start like the listen's.
        let seen_connecting = rig.link.foreign_commands_in_setup();
        rig.can.foreign_commands += seen_connecting;
        // Listen before sending anything that enables: a running controller
        // on this drive sends a command at least every watchdog period.
        rig.listen(settings.quiet_period());
        if rig.can.foreign_commands > 0 {
            return Err(StartError::ForeignController(rig.can.foreign_commands));
        }
        let times = rig
            .link
            .enable(rig.transport.as_mut())
            .map_err(|e| StartError::Drive(e.to_string()))?;
        // Commands seen while the link alone read the bus: tick 0 stops on them.
        rig.can.foreign_commands += rig.link.foreign_commands_in_setup() - seen_connecting;
        // The estimators and the log see the torque as the drive applies it
        // (`Rig::control`).
        rig.torque_step_nm = rig.link.torque_step_nm();
        rig.times.enable_ns = instant_ns(times.enable);
        rig.times.first_command_ns = instant_ns(times.first_command);
        // The enable's feedback: the first one, seen by tick 0 (no steps
        // counted: there is none before it).
        let first = rig.link.sample(0);
        rig.take_feedback(
            Reading {
                x_rad: first.position_rad,
                v_rad_s: first.velocity_rad_s,
            },
            0,
            0,
            0,
        );
        rig.drive.sample = first;
        Ok(rig)
    }

    /// Receives (and absorbs) every frame for `period`.
    fn listen(&mut self, period: Duration) {
        let start = Instant::now();
        while let Some(left) = period.checked_sub(start.elapsed()) {
            if let Ok(Some(f)) = self.transport.recv(left.min(Duration::from_millis(10))) {
                self.absorb(&f, 0);
            }
        }
    }

    /// Takes one received frame through the link (which takes only
    /// feedback newer than the newest: [`DriveLink::absorb`]); counts what
    /// the loop watches (foreign commands, undecodable and discarded
    /// frames) and checks feedback against physics.
    fn absorb(&mut self, frame: &Frame, tick: u64) {
        let received = self.transport.last_rx_time();
        let absorbed = self.link.absorb_received(frame, received);
        self.absorbed(absorbed, tick);
    }

    /// What the link made of a frame (or settled after a drain).
    fn absorbed(&mut self, absorbed: Absorbed, tick: u64) {
        match absorbed {
            Absorbed::Feedback {
                position_rad,
                velocity_rad_s,
                steps,
                most_steps,
            } => {
                let reading = Reading {
                    x_rad: position_rad,
                    v_rad_s: velocity_rad_s,
                };
                self.take_feedback(reading, steps, most_steps, tick);
            }
            Absorbed::StaleFeedback => self.can.feedback_discarded += 1,
            Absorbed::ConflictingFeedback { sequence } => {
                self.implausible_feedback(Implausible::Conflicting { sequence })
            }
            Absorbed::ForeignCommand => self.can.foreign_commands += 1,
            Absorbed::Undecodable => self.can.decode_errors += 1,
            Absorbed::Other => {}
        }
    }

    /// A feedback the link took in tick `tick`: checked against physics
    /// and against the one before it (`steps` drive steps earlier, 0:
    /// unknown, and at most `most_steps`; [`FeedbackLimits::check`]), then
    /// kept as the previous one.
    fn take_feedback(&mut self, reading: Reading, steps: u32, most_steps: u32, tick: u64) {
        let prev = self.drive.last_feedback.map(|(reading, at)| Previous {
            reading,
            ticks_apart: tick.saturating_sub(at),
            steps,
            most_steps,
        });
        if let Err(why) = self.feedback_limits.check(reading, prev) {
            self.implausible_feedback(why);
        }
        self.drive.last_feedback = Some((reading, tick));
    }

    /// Counts an implausible feedback and keeps the first.
    fn implausible_feedback(&mut self, why: Implausible) {
        self.can.implausible_feedback += 1;
        self.implausible.get_or_insert(why);
    }

    /// Drains every frame already received, without waiting
    /// ([`Transport::recv_ready`]: one system call on the UDP bus).
    /// Then the link's settled feedback, if it holds one back until the
    /// drain is over ([`DriveLink::settle`]: CiA 402's standard mode).
    fn drain(&mut self, tick: u64) {
        loop {
            match self.transport.recv_ready() {
                Ok(Some(f)) => self.absorb(&f, tick),
                Ok(None) => break,
                Err(_) => {
                    self.can.recv_errors += 1;
                    break;
                }
            }
        }
        if let Some(settled) = self.link.settle() {
            self.absorbed(settled, tick);
        }
    }

    /// The real-time loop. Runs every tick of the protocol unless `stop` is
    /// raised (a terminating signal's number: the controlled stop),
    /// feedback times out, the drive faults or another safety check fires.
    ///
    /// Each tick: wait for its deadline, **sense** (drain the feedback, its
    /// freshness and age), **decide** (the safety state, then the controller
    /// or the brake), **actuate** (one torque command), **record** (one log
    /// record).
    pub fn run(&mut self, log: &mut LogSink, stop: &AtomicUsize) -> StopReason {
        let timing = Timing::new(&self.settings, self.times.first_command_ns);
        // The protocol's samples in tick order, each tick's next targets kept
        // for the following tick (one evaluation a tick): the loop runs from
        // tick 0 and stays running until it stops or brakes,
        // so the running ticks take the samples one by one, in order.
        let protocol = self.protocol;
        let mut samples = protocol.samples();
        let mut safety = Safety::Running;
        let mut k = 0u64;
        let faults_before = os::thread_page_faults();
        let reason = loop {
            let wake = self.wait_for_tick(&timing, k);
            let sensed = self.sense(k, wake);
            let sensed_ns = os::now_ns();
            let checks = self.checks(&timing, k, &sensed, stop, log.failed());
            let next = safety.next(&checks);
            self.note_stop(safety, next, &checks);
            safety = next;
            let command = match safety {
                Safety::Stopped(reason) => break reason,
                Safety::Running => match samples.next() {
                    Some(sample) => self.control(&sample, &sensed),
                    // k < total while running, so the protocol has a sample.
                    None => break StopReason::Completed,
                },
                Safety::Braking { .. } => self.brake(&sensed),
            };
            let decided_ns = os::now_ns();
            self.actuate(k, command.torque_nm);
            let sent_ns = os::now_ns();
            if k == 0 {
                self.times.first_tick_ns = sent_ns;
            }
            self.parts
                .record_compute(wake.woke_ns, sensed_ns, decided_ns, sent_ns);
            self.record(log, k, &sensed, &command, safety, sent_ns);
            self.parts
                .record
                .record(os::now_ns().saturating_sub(sent_ns));
            k += 1;
        };
        self.page_faults = os::thread_page_faults().saturating_sub(faults_before);
        self.ticks_run = k;
        self.stop.speed_at_end_rad_s = self.drive.sample.velocity_rad_s.abs();
        self.shut_down(reason);
        reason
    }

    /// Keeps how the stop goes for the report ([`StopReport`]): when it was
    /// decided and the speed then, the braking ticks, why braking ended.
    fn note_stop(&mut self, from: Safety, to: Safety, c: &Checks) {
        let speed_rad_s = self.drive.sample.velocity_rad_s.abs();
        match (from, to) {
            (Safety::Running, Safety::Braking { .. } | Safety::Stopped(_)) => {
                self.stop.tick = c.tick;
                self.stop.speed_at_stop_rad_s = speed_rad_s;
            }
            (Safety::Braking { from_tick, .. }, Safety::Stopped(_)) => {
                self.stop.brake_end = c.brake_end(from_tick);
            }
            _ => {}
        }
        match to {
            Safety::Braking { .. } => self.stop.braking_ticks += 1,
            Safety::Stopped(reason) => {
                self.stop.kind = reason.stop_kind();
                if from == Safety::Running && reason.brakes() {
                    // A controlled stop that ended in its first tick.
                    self.stop.brake_end = c.brake_end(c.tick);
                }
            }
            Safety::Running => {}
        }
    }

    /// Decide, during the controlled stop: the brake on the measured
    /// velocity when this tick's feedback is fresh, zero torque when it is
    /// not (never a stale command); no virtual human.
    fn brake(&mut self, sensed: &Sensed) -> Command {
        let stop = &self.settings.stop;
        let torque_nm = if sensed.fresh {
            brake_torque_nm(
                self.drive.sample.velocity_rad_s,
                stop.damping_nm_s_per_rad,
                stop.torque_limit_nm,
            )
        } else {
            0.0
        };
        let (torque_nm, g) = guard_torque(torque_nm, self.settings.torque_limit_nm);
        if g == Guard::NonFinite {
            self.non_finite += 1;
        }
        Command::stopping(torque_nm)
    }

    /// Waits for tick `k`'s absolute deadline (a sleep, then the spin if
    /// one is set: [`wake_up`]); records the wake-up latency and the sleep's
    /// own, and counts a miss when the next deadline has already passed.
    fn wait_for_tick(&mut self, timing: &Timing, k: u64) -> Wake {
        let deadline_ns = timing.start_ns + k * timing.period_ns;
        let wake = wake_up(deadline_ns, timing.spin_ns, os::sleep_until, os::now_ns);
        self.wake.record(wake.wake_latency_ns());
        self.sleep.record(wake.sleep_latency_ns());
        if wake.woke_ns > deadline_ns + timing.period_ns {
            self.deadline_misses += 1;
        }
        wake
    }

    /// Sense: drain the received frames; the feedback is fresh when it
    /// answers command `k - 1` (tick 0 uses the set-up's feedback).
    fn sense(&mut self, k: u64, wake: Wake) -> Sensed {
        self.drain(k);
        self.drive.sample = self.link.sample(k);
        let fresh = self.drive.sample.fresh;
        if fresh {
            self.stale_run = 0;
        } else {
            self.can.missing_feedback += 1;
            self.stale_run += 1;
            self.longest_stale_run = self.longest_stale_run.max(self.stale_run);
        }
        // Controller units: positions in `unit`s, torques in model units.
        let unit = self.settings.rad_per_unit;
        Sensed {
            wake,
            x: self.drive.sample.position_rad / unit,
            v: self.drive.sample.velocity_rad_s / unit,
            fresh,
            age_ticks: k.saturating_sub(self.drive.last_feedback.map_or(0, |(_, at)| at)),
        }
    }

    /// What the safety state machine looks at in tick `k`.
    fn checks(
        &self,
        timing: &Timing,
        k: u64,
        sensed: &Sensed,
        stop: &AtomicUsize,
        log_failed: bool,
    ) -> Checks {
        let robot = self.robot.counters();
        let health = Health {
            ticks: k + 1,
            missing: self.can.missing_feedback,
            stale_run: self.stale_run,
            estimator_errors: robot.estimator_errors + robot.non_finite + self.non_finite,
        };
        Checks {
            tick: k,
            feedback_timed_out: k > 0 && sensed.age_ticks > timing.timeout_ticks,
            drive_fault: self.drive.sample.alarm,
            foreign_command: self.can.foreign_commands > 0,
            implausible: self.implausible,
            log_failed,
            out_of_range: crate::range::out_of_range(
                &self.settings.range,
                self.drive.sample.position_rad,
                self.drive.sample.velocity_rad_s,
                k == 0,
            ),
            degraded: degradation(&health, &self.degraded_limits),
            signal: match stop.load(Ordering::Relaxed) {
                0 => None,
                n => Some(i32::try_from(n).unwrap_or(i32::MAX)),
            },
            protocol_done: k >= self.protocol.total_ticks(),
            at_rest: sensed.fresh
                && self.drive.sample.velocity_rad_s.abs() < self.settings.stop.rest_velocity_rad_s,
            stop_ticks: timing.stop_ticks,
        }
    }

    /// Decide, while running: the robot's command (its estimators updated
    /// when the feedback is fresh), the virtual human's torque, their sum in
    /// N m guarded at the drive's limit and rounded to the drive's torque
    /// step; then the robot's estimators predict with its part of that sum.
    fn control(&mut self, sample: &Sample<'_>, sensed: &Sensed) -> Command {
        let (x, v) = (sensed.x, sensed.v);
        let mut row = Row::UNKNOWN;
        let decision = self
            .robot
            .decide(sample, sensed.fresh.then_some((x, v)), &mut row);
        let seen = self.handle_view.see(PlantState { x, v }, sensed.fresh);
        let (u_h, _) = self
            .partner
            .torque(seen.x, seen.v, sample.tau, sample.tau_h);
        // Model torque -> N m: the same factor as position. The range's
        // ramp, wall and speed damping act on the handle as the virtual
        // human sees it (measured, or predicted on a tick without fresh
        // feedback), before the limit (`crate::range::command_nm`).
        let unit = self.settings.rad_per_unit;
        // The handle's friction, compensated as part of the controller's
        // torque (ramped near the soft end stops, guarded with it).
        let friction_nm = crate::friction::compensation_nm(
            &self.settings.friction,
            seen.v * unit,
            (row.u + u_h) * unit,
        );
        let (torque_nm, g) = crate::range::command_nm(
            &self.settings.range,
            seen.x * unit,
            seen.v * unit,
            row.u * unit + friction_nm,
            u_h * unit,
            self.settings.torque_limit_nm,
        );
        let (torque_nm, u) = drive_torque(
            torque_nm,
            row.u,
            self.torque_step_nm,
            self.settings.torque_limit_nm,
            unit,
        );
        self.robot.predict(decision, u);
        row.u = u;
        match g {
            Guard::Passed => {}
            Guard::Clamped => self.torque_clamped += 1,
            Guard::NonFinite => self.non_finite += 1,
        }
        (row.tau, row.tau_h, row.u_h) = (sample.tau, sample.tau_h, u_h);
        (row.torque_nm, row.friction_nm, row.guard) = (torque_nm, friction_nm, Some(g));
        Command { torque_nm, row }
    }

    /// Actuate: one torque command (the link numbers it for tick `k`).
    fn actuate(&mut self, k: u64, torque_nm: f64) {
        self.handle_view.last_torque = torque_nm / self.settings.rad_per_unit;
        if self
            .link
            .send_torque(self.transport.as_mut(), k, torque_nm)
            .is_err()
        {
            self.can.send_errors += 1;
        }
    }

    /// Record: the tick's compute time (wake-up to `sent_ns`, the command
    /// sent) and its log record.
    fn record(
        &mut self,
        log: &mut LogSink,
        k: u64,
        sensed: &Sensed,
        command: &Command,
        safety: Safety,
        sent_ns: u64,
    ) {
        let wake = sensed.wake;
        let compute_ns = sent_ns.saturating_sub(wake.woke_ns);
        self.compute.record(compute_ns);
        // On the rig the controller's measurement is the drive's feedback.
        let mut row = command.row;
        (row.tick, row.t) = (k as i64, k as f64 * self.settings.dt_s);
        (row.x, row.xdot, row.x_meas, row.xdot_meas) = (sensed.x, sensed.v, sensed.x, sensed.v);
        (row.fresh, row.e) = (sensed.fresh, sensed.x - row.tau);
        row.wake_latency_us = wake.wake_latency_ns() as f64 / 1e3;
        row.sleep_latency_us = wake.sleep_latency_ns() as f64 / 1e3;
        row.compute_us = compute_ns as f64 / 1e3;
        row.feedback_age_ticks = sensed.age_ticks as i64;
        row.drive_state = i64::from(self.drive.sample.status.code());
        row.ramp = matches!(safety, Safety::Braking { .. });
        log.push(row);
    }

    /// After the loop, without waiting: the drive's emergency stop on a
    /// feedback timeout, a lost drive heartbeat, a foreign command or a
    /// drive reset (it leaves the drive unable to move until set up again:
    /// no controller can drive the motor), else zero torque; then disable
    /// ([`DriveLink::stop`]).
    fn shut_down(&mut self, reason: StopReason) {
        let emergency = reason.stop_kind() == StopKind::EmergencyStop;
        // The command after the loop's last one (tick k - 1).
        if self
            .link
            .stop(self.transport.as_mut(), self.ticks_run, emergency)
            .is_err()
        {
            self.can.send_errors += 1;
        }
    }

    /// The step the torque sent was rounded to (model units; the drive's
    /// torque step over rad per unit), None before the enable.
    pub fn robot_torque_step(&self) -> Option<f64> {
        let step = self.torque_step_nm / self.settings.rad_per_unit;
        step.is_finite().then_some(step)
    }

    /// The drive's status as the loop last sensed it (the log's end
    /// status: "fault" after a drive fault stopped the run).
    pub fn drive_status(&self) -> DriveStatus {
        self.drive.sample.status
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
            stop: self.stop,
            wake_latency: self.wake.summary(),
            sleep_latency: self.sleep.summary(),
            compute: self.compute.summary(),
            compute_parts: self.parts.summary(),
            loop_page_faults: self.page_faults,
            deadline_misses: self.deadline_misses,
            can,
            drive: DriveReport::new(&self.link.events(), self.settings.dt_s),
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
            longest_stale_run: self.longest_stale_run,
            exit_code: reason.exit_code(),
            start: StartGap::new(
                self.times.enable_ns,
                self.times.first_command_ns,
                self.times.first_tick_ns,
            ),
            realtime: Vec::new(),
        }
    }
}
