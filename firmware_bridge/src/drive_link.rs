//! One interface to a torque drive, whatever its profile: the Hi5 protocol
//! (`hi5.dbc`) or CiA 402 over CANopen ([`crate::cia402`]).
//!
//! A control loop holds a `Box<dyn DriveLink + Send>` (chosen by
//! `[rig] drive = "hi5" | "cia402"`). Set-up: [`DriveLink::connect`] (the
//! drive is on the bus; nothing that moves it is sent), then
//! [`DriveLink::enable`]. Per tick `k`: sense ([`DriveLink::absorb`] each
//! received frame, then [`DriveLink::sample`]; or both in
//! [`DriveLink::drain`]), then actuate ([`DriveLink::send_torque`]). After
//! the last tick: [`DriveLink::stop`] (no wait, but for CiA 402's normal
//! stop: [`Cia402Link`]) or [`DriveLink::shut_down`] (waits until
//! disabled). Set-up and `shut_down` may wait on the bus (bounded); the
//! per-tick calls never wait and never allocate.

use core::fmt;
use std::time::{Duration, Instant, SystemTime};

use serde::Serialize;

use crate::cia402::{
    Cia402Error, DriveState as Cia402State, Emcy, Freshness, Heard, Master, MasterSettings,
    NmtState,
};
use crate::frame::Frame;
use crate::protocol::{decode, encode, DriveState, FaultFlags, Message, MessageKind, NodeId};
use crate::transport::{Transport, TransportError};

/// What the loop senses from the drive in one tick.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DriveSample {
    /// Position, rad (the drive's last report).
    pub position_rad: f64,
    /// Velocity, rad/s.
    pub velocity_rad_s: f64,
    /// The report answers the previous tick's command.
    pub fresh: bool,
    /// The drive's state, whatever its profile (the log's `drive_state`).
    pub status: DriveStatus,
    /// Why the drive cannot be driven on, if it cannot: its fault, its
    /// heartbeat lost, or a reset.
    pub alarm: Option<DriveAlarm>,
}

/// The drive's state in the loop's terms, whatever its profile: the log's
/// `drive_state` column holds [`DriveStatus::code`] (`sensaug-log`). Each
/// profile maps its own states onto these four (`From` below).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[repr(u8)]
pub enum DriveStatus {
    /// Powering up, or no state report yet (Hi5 BOOT; CiA 402
    /// NotReadyToSwitchOn, or no statusword yet).
    #[default]
    Booting = 0,
    /// On the bus, torque off (Hi5 DISABLED; CiA 402 SwitchOnDisabled,
    /// ReadyToSwitchOn, SwitchedOn, QuickStopActive).
    Disabled = 1,
    /// Applies torque commands (Hi5 ENABLED; CiA 402 OperationEnabled).
    Enabled = 2,
    /// Torque off, a fault latched (Hi5 FAULT; CiA 402 FaultReactionActive,
    /// Fault).
    Fault = 3,
}

impl DriveStatus {
    /// The log's `drive_state` code: 0 booting, 1 disabled, 2 enabled, 3 fault.
    pub const fn code(self) -> u8 {
        self as u8
    }

    /// Its name, lower case (the log's end status, messages).
    pub const fn name(self) -> &'static str {
        match self {
            Self::Booting => "booting",
            Self::Disabled => "disabled",
            Self::Enabled => "enabled",
            Self::Fault => "fault",
        }
    }
}

impl From<DriveState> for DriveStatus {
    fn from(s: DriveState) -> Self {
        match s {
            DriveState::Boot => Self::Booting,
            DriveState::Disabled => Self::Disabled,
            DriveState::Enabled => Self::Enabled,
            DriveState::Fault => Self::Fault,
        }
    }
}

impl From<Option<Cia402State>> for DriveStatus {
    /// `None`: no statusword received yet.
    fn from(s: Option<Cia402State>) -> Self {
        match s {
            None | Some(Cia402State::NotReadyToSwitchOn) => Self::Booting,
            Some(
                Cia402State::SwitchOnDisabled
                | Cia402State::ReadyToSwitchOn
                | Cia402State::SwitchedOn
                | Cia402State::QuickStopActive,
            ) => Self::Disabled,
            Some(Cia402State::OperationEnabled) => Self::Enabled,
            Some(Cia402State::FaultReactionActive | Cia402State::Fault) => Self::Fault,
        }
    }
}

/// Why the loop must stop driving the drive at once, as the profile says it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DriveAlarm {
    /// Hi5: FAULT, with its latched fault flags (`hi5.dbc`).
    Hi5Fault {
        /// The Fault/Heartbeat frame's `fault_flags`.
        flags: u16,
    },
    /// CiA 402: the statusword reports Fault; the last EMCY's error code and
    /// error register (0x1001) say why (both 0 when no EMCY came).
    Cia402Fault {
        /// Emergency error code (CiA 301 table 21, CiA 402).
        emcy_code: u16,
        /// Error register 0x1001 as the EMCY carried it.
        error_register: u8,
    },
    /// CiA 402: no heartbeat from the drive for longer than the master's
    /// consumer time.
    HeartbeatLost {
        /// The consumer time (`rig.cia402.heartbeat_timeout_ms`), ms.
        timeout_ms: u64,
    },
    /// The drive restarted, or left its enabled state by itself: what said
    /// so.
    Reset(ResetReport),
}

/// What told the loop that the drive reset or left its enabled state by
/// itself while the loop ran.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ResetReport {
    /// CiA 402: the drive's boot-up message (its NMT state 0x00).
    BootUp,
    /// CiA 402: the drive's heartbeat reports this NMT state after it had
    /// reported OPERATIONAL.
    NmtState(NmtState),
    /// Hi5: a state report (Fault, Heartbeat or Feedback frame) of BOOT or
    /// DISABLED after the enable.
    Hi5State(DriveState),
    /// CiA 402: the statusword reports this state (neither
    /// OperationEnabled nor a fault) after the enable.
    Cia402State(Cia402State),
}

impl fmt::Display for DriveAlarm {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Hi5Fault { flags } => {
                write!(f, "Hi5 FAULT {:?}", FaultFlags::from_bits_retain(*flags))
            }
            Self::Cia402Fault {
                emcy_code: 0,
                error_register: 0,
            } => write!(f, "CiA 402 Fault (no EMCY received)"),
            Self::Cia402Fault {
                emcy_code,
                error_register,
            } => {
                let emcy = Emcy {
                    code: *emcy_code,
                    register: *error_register,
                    manufacturer: [0; 5],
                };
                write!(
                    f,
                    "CiA 402 Fault, EMCY {emcy_code:#06x} ({}), error register {error_register:#04x}",
                    emcy.name()
                )
            }
            Self::HeartbeatLost { timeout_ms } => write!(
                f,
                "the drive's heartbeat lost: none for more than {timeout_ms} ms \
                 (rig.cia402.heartbeat_timeout_ms)"
            ),
            Self::Reset(r) => write!(f, "{r}"),
        }
    }
}

impl fmt::Display for ResetReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::BootUp => write!(f, "the drive sent a boot-up message (CiA 301 NMT 0x00)"),
            Self::NmtState(s) => write!(
                f,
                "the drive's heartbeat reports NMT {s:?} ({:#04x}) after OPERATIONAL",
                *s as u8
            ),
            Self::Hi5State(s) => write!(f, "the Hi5 drive reports {s:?} while enabled"),
            Self::Cia402State(s) => write!(
                f,
                "the drive's statusword reports {s:?} while enabled (it left OperationEnabled \
                 by itself: a reset, or its own stop input)"
            ),
        }
    }
}

/// What a drive link saw over a run beyond each tick's sample, for the
/// statistics (CiA 402; the Hi5 link reports none).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DriveEvents {
    /// EMCYs received (all of them).
    pub emcy_received: u64,
    /// The first EMCYs (up to the master's [`crate::cia402::master::EMCY_RECORDS`]),
    /// each with its time in seconds after tick 0's command (negative:
    /// during set-up).
    pub emcy: Vec<(Emcy, f64)>,
    /// CiA 402: how TPDOs were matched to SYNCs (None: the Hi5, or set-up
    /// did not get that far).
    pub freshness: Option<Freshness>,
    /// What was discarded, not fresh or clamped, counted.
    pub counts: LinkCounts,
}

/// A drive link's counts of feedback it did not take as fresh and of
/// commands it changed: one set for the link and for `sensaug-rt`'s
/// statistics (`stats.json` `drive`, serialised flat there). Zeros on the
/// Hi5 profile but for `feedback_discarded`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct LinkCounts {
    /// Feedback frames discarded as older than, or a repeat of, the
    /// feedback already taken (CiA 402: the newest SYNC counter wins).
    pub feedback_discarded: u64,
    /// CiA 402 standard mode: TPDOs received before the last SYNC, read
    /// after it (late; kernel receive time: SocketCAN and the UDP bus), not
    /// taken.
    pub feedback_late: u64,
    /// CiA 402 standard mode: answers (TPDO1 + TPDO2) taken as the newest
    /// feedback but not fresh, because they may answer an earlier SYNC:
    /// the first answer after a SYNC without one in its window, or one
    /// received more than half a period after its SYNC ([`Cia402Link`]).
    pub feedback_out_of_step: u64,
    /// CiA 402 standard mode: second TPDOs of one kind after one SYNC
    /// (duplicated; that tick's feedback is not fresh).
    pub feedback_duplicated: u64,
    /// CiA 402: SYNCs the next SYNC followed without a TPDO1 and TPDO2
    /// taken for them (missing; set-up's and the stop's included).
    pub syncs_unanswered: u64,
    /// Commands beyond the drive's own limit (0x6072) sent clamped to it.
    pub commands_clamped_at_drive_limit: u64,
    /// Non-finite commands the link sent as zero torque.
    pub commands_non_finite: u64,
}

/// What one received frame was, for the loop's counters and checks.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Absorbed {
    /// One tick's feedback (Hi5 Feedback; CiA 402 TPDO1 + TPDO2 with one
    /// SYNC counter), newer than every one before it ([`FeedbackOrder`]).
    Feedback {
        /// Position, rad.
        position_rad: f64,
        /// Velocity, rad/s.
        velocity_rad_s: f64,
        /// Drive steps (commands answered) since the previous feedback
        /// taken, from the two sequence numbers (Hi5) or SYNC counters
        /// (CiA 402); 0 for the first after the enable.
        steps: u32,
        /// The most drive steps there can be between the two: `steps`
        /// where the feedback says which command it answers (sequence
        /// numbers, the SYNC counter echo); more in CiA 402's standard
        /// mode, where an answer is placed on a SYNC by its arrival time
        /// and a late answer looks like a later SYNC's: any count from 1 to
        /// this one is then possible ([`StepWatch::answer_taken`]).
        most_steps: u32,
    },
    /// A feedback not taken: a copy of the newest, an older one arriving
    /// after it (a replay, a late frame), or one answering no command sent.
    StaleFeedback,
    /// A feedback answering the same command as the newest one with other
    /// values: two nodes send feedback for this drive (the newest is kept).
    ConflictingFeedback {
        /// The command's sequence number (CiA 402: its SYNC counter).
        sequence: u8,
    },
    /// A command to this drive that this process did not send (transports
    /// never hand a socket its own frames): another controller is on the
    /// bus.
    ForeignCommand,
    /// A frame for or from this drive that did not decode.
    Undecodable,
    /// Anything else (state reports, other nodes' traffic).
    Other,
}

/// When [`DriveLink::enable`] sent its enabling command and the first
/// command the drive's watchdog counts (the start gap in the statistics).
#[derive(Clone, Copy, Debug)]
pub struct EnableTimes {
    /// The enabling command (Hi5 SetState; CiA 402 the first controlword
    /// step).
    pub enable: Instant,
    /// The first zero-torque command.
    pub first_command: Instant,
}

/// Why a drive link failed.
#[derive(Debug)]
pub enum LinkError {
    /// The bus failed.
    Transport(TransportError),
    /// A Hi5 message could not be encoded (a torque outside the DBC range).
    Hi5Encode(crate::protocol::EncodeError),
    /// The CiA 402 master failed.
    Cia402(Cia402Error),
    /// The drive did not reach a state in time.
    Timeout {
        /// What was awaited.
        what: &'static str,
        /// How long.
        waited: Duration,
    },
    /// The drive faulted, lost its heartbeat or reset while being enabled.
    Faulted(DriveAlarm),
}

impl fmt::Display for LinkError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Transport(e) => write!(f, "CAN bus: {e}"),
            Self::Hi5Encode(e) => write!(f, "Hi5 protocol: {e}"),
            Self::Cia402(e) => write!(f, "CiA 402: {e}"),
            Self::Timeout { what, waited } => {
                write!(f, "waited {waited:?} for {what}; is the drive on the bus?")
            }
            Self::Faulted(alarm) => write!(f, "right after the enable: {alarm}"),
        }
    }
}

impl std::error::Error for LinkError {}

impl From<TransportError> for LinkError {
    fn from(e: TransportError) -> Self {
        Self::Transport(e)
    }
}

impl From<Cia402Error> for LinkError {
    fn from(e: Cia402Error) -> Self {
        Self::Cia402(e)
    }
}

/// A drive the control loop can run, whatever its protocol.
pub trait DriveLink {
    /// Set-up, first step: wait (bounded) until the drive is on the bus and
    /// configured; sends nothing that enables it.
    fn connect(&mut self, bus: &mut dyn Transport) -> Result<(), LinkError>;

    /// Set-up, last step (after [`DriveLink::connect`]): clear a latched
    /// fault, bring the drive to the state where it applies torque, at zero
    /// torque, and read its answer, ready for tick 0. May wait (bounded).
    fn enable(&mut self, bus: &mut dyn Transport) -> Result<EnableTimes, LinkError>;

    /// Sense: take one received frame. No wait, no allocation.
    fn absorb(&mut self, frame: &Frame) -> Absorbed;

    /// [`DriveLink::absorb`] with the frame's kernel receive time
    /// ([`Transport::last_rx_time`]; CiA 402's standard mode uses it).
    fn absorb_received(&mut self, frame: &Frame, received: Option<SystemTime>) -> Absorbed {
        let _ = received;
        self.absorb(frame)
    }

    /// After the frames of a drain: a feedback the link held back until
    /// no more frames were waiting (CiA 402's standard mode takes a SYNC's
    /// answer only once no second answer came with it). Default: none.
    fn settle(&mut self) -> Option<Absorbed> {
        None
    }

    /// Sense tick `k`, after absorbing every frame received so far: `fresh`
    /// when the feedback answers tick `k - 1` (tick 0: the set-up's). No
    /// allocation.
    fn sample(&mut self, k: u64) -> DriveSample;

    /// Actuate tick `k`: send `torque_nm`. No wait, no allocation.
    fn send_torque(
        &mut self,
        bus: &mut dyn Transport,
        k: u64,
        torque_nm: f64,
    ) -> Result<(), LinkError>;

    /// After the last tick `k - 1`, without waiting (but CiA 402's normal
    /// stop waits, bounded: [`Cia402Link`]'s `stop`): zero torque and
    /// disable; with `emergency`, the profile's emergency stop instead,
    /// which leaves the drive unable to move until set up again (Hi5:
    /// EmergencyStop latches FAULT until ClearFaults; CiA 402: quick stop,
    /// the drive holds QuickStopActive at zero torque until a master's
    /// controlword moves it on).
    fn stop(&mut self, bus: &mut dyn Transport, k: u64, emergency: bool) -> Result<(), LinkError>;

    /// After the last tick `k - 1`: zero torque, then leave the drive
    /// disabled. May wait (bounded).
    fn shut_down(&mut self, bus: &mut dyn Transport, k: u64) -> Result<(), LinkError>;

    /// The drive's torque resolution (N m): it applies a command as
    /// `round_ties_even(torque / step) * step`. CiA 402: one per-mille of
    /// its rated torque 0x6076, read by [`DriveLink::enable`]; Hi5: the
    /// DBC's TorqueCommand scale.
    fn torque_step_nm(&self) -> f64;

    /// Commands to this drive from another sender seen while
    /// [`DriveLink::connect`] and [`DriveLink::enable`] read the bus
    /// (the loop counts the rest through [`DriveLink::absorb`]).
    fn foreign_commands_in_setup(&self) -> u64;

    /// The CAN ids the loop must receive (a kernel filter may drop the
    /// rest): the drive's frames and commands to it (which only another
    /// sender can have put on the bus).
    fn receive_ids(&self) -> Vec<u32>;

    /// What the link saw over the run beyond the samples (EMCYs, discarded
    /// feedback, commands clamped at the drive's limit).
    fn events(&self) -> DriveEvents {
        DriveEvents::default()
    }

    /// [`DriveLink::connect`] then [`DriveLink::enable`].
    fn bring_up(&mut self, bus: &mut dyn Transport) -> Result<EnableTimes, LinkError> {
        self.connect(bus)?;
        self.enable(bus)
    }

    /// Sense tick `k`: [`DriveLink::absorb`] every frame received so far,
    /// then [`DriveLink::sample`]. No wait, no allocation.
    fn drain(&mut self, bus: &mut dyn Transport, k: u64) -> Result<DriveSample, LinkError> {
        while let Some(f) = bus.recv_ready()? {
            self.absorb_received(&f, bus.last_rx_time());
        }
        self.settle();
        Ok(self.sample(k))
    }
}

// -- feedback order ------------------------------------------------------------------

/// The feedbacks a drive link takes: answers to commands sent, newest
/// first, whatever order they arrive in. A feedback's sequence number
/// (Hi5: the command's, modulo 256; CiA 402: the SYNC counter, 1..=240)
/// names the most recent command sent with that number; it is taken only if
/// that command is later than the newest one answered. Commands are counted
/// here, so the order holds across the numbers' wrap (a stall of more than
/// 256 commands included). The last [`FEEDBACK_HISTORY`] feedbacks taken
/// are kept: an answer to one of their commands with other values is a
/// second source (a node that answered first, then the drive). Allocation-free.
#[derive(Clone, Copy, Debug)]
pub struct FeedbackOrder {
    modulus: u16,
    /// Commands sent so far.
    sent: u64,
    /// The last command sent: its index (0-based) and sequence number.
    last_sent: Option<(u64, u8)>,
    /// The newest feedback taken: its command's index and its values.
    newest: Option<(u64, f64, f64)>,
    /// The feedbacks taken, by command index (a ring; `taken` of them so far).
    history: [(u64, f64, f64); FEEDBACK_HISTORY],
    taken: usize,
}

/// Feedbacks [`FeedbackOrder`] remembers to tell a copy from a second
/// answer: 128 commands (128 ms at 1 kHz; below both profiles' wrap).
pub const FEEDBACK_HISTORY: usize = 128;

/// Where a feedback stands against the newest one taken
/// ([`FeedbackOrder::classify`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Order {
    /// It answers a command sent after the newest one's: take it. The
    /// drive steps between the two (0: no feedback taken yet).
    Newer(u32),
    /// The newest one again, same values: a copy.
    Copy,
    /// The newest one's command, or a remembered older one's, with other
    /// values.
    Conflicting,
    /// Older than the newest (and not remembered, or not taken), or no
    /// command sent yet.
    Stale,
}

impl FeedbackOrder {
    /// Sequence numbers modulo `modulus` (only their differences count:
    /// CiA 402's counters 1..=240 are taken as they are).
    pub fn new(modulus: u16) -> Self {
        Self {
            modulus,
            sent: 0,
            last_sent: None,
            newest: None,
            history: [(u64::MAX, 0.0, 0.0); FEEDBACK_HISTORY],
            taken: 0,
        }
    }

    /// Forget every feedback (a resync: the enable).
    pub fn reset(&mut self) {
        self.newest = None;
        self.history = [(u64::MAX, 0.0, 0.0); FEEDBACK_HISTORY];
    }

    /// A command with sequence number `seq` was sent.
    pub fn sent(&mut self, seq: u8) {
        self.last_sent = Some((self.sent, seq));
        self.sent += 1;
    }

    /// `(to - from) mod modulus`.
    fn ahead(&self, from: u8, to: u8) -> u16 {
        (u16::from(to) + self.modulus - u16::from(from) % self.modulus) % self.modulus
    }

    /// The index of the most recent command sent with sequence `seq`.
    fn index_of(&self, seq: u8) -> Option<u64> {
        let (index, last) = self.last_sent?;
        index.checked_sub(u64::from(self.ahead(seq, last)))
    }

    /// Where feedback `(seq, position, velocity)` stands.
    pub fn classify(&self, seq: u8, position_rad: f64, velocity_rad_s: f64) -> Order {
        self.classify_part(seq, Some(position_rad), Some(velocity_rad_s))
    }

    /// [`Self::classify`] for part of a feedback (CiA 402: TPDO1 has the
    /// position, TPDO2 the velocity): a copy or a conflict is judged on the
    /// values given.
    pub fn classify_part(
        &self,
        seq: u8,
        position_rad: Option<f64>,
        velocity_rad_s: Option<f64>,
    ) -> Order {
        let Some(index) = self.index_of(seq) else {
            return Order::Stale;
        };
        let same = |taken: f64, got: Option<f64>| got.is_none_or(|g| g == taken);
        match self.newest {
            None => Order::Newer(0),
            Some((newest, ..)) if index > newest => {
                Order::Newer(u32::try_from(index - newest).unwrap_or(u32::MAX))
            }
            // The newest, or an older one remembered: a copy or a second answer.
            Some(_) => match self.history.iter().find(|(i, ..)| *i == index) {
                Some((_, x, v)) if same(*x, position_rad) && same(*v, velocity_rad_s) => {
                    Order::Copy
                }
                Some(_) => Order::Conflicting,
                None => Order::Stale,
            },
        }
    }

    /// Takes the feedback if it is [`Order::Newer`]; says what it was.
    pub fn absorb(&mut self, seq: u8, position_rad: f64, velocity_rad_s: f64) -> Absorbed {
        match self.classify(seq, position_rad, velocity_rad_s) {
            Order::Newer(steps) => {
                if let Some(index) = self.index_of(seq) {
                    let taken = (index, position_rad, velocity_rad_s);
                    self.newest = Some(taken);
                    self.history[self.taken % FEEDBACK_HISTORY] = taken;
                    self.taken += 1;
                }
                Absorbed::Feedback {
                    position_rad,
                    velocity_rad_s,
                    steps,
                    most_steps: steps,
                }
            }
            Order::Copy | Order::Stale => Absorbed::StaleFeedback,
            Order::Conflicting => Absorbed::ConflictingFeedback { sequence: seq },
        }
    }

    /// The newest feedback taken: `(position, velocity)`.
    pub fn newest(&self) -> Option<(f64, f64)> {
        self.newest.map(|(_, x, v)| (x, v))
    }

    /// The newest feedback answers the last command sent.
    pub fn up_to_date(&self) -> bool {
        matches!((self.newest, self.last_sent), (Some((n, ..)), Some((s, _))) if n == s)
    }
}

// -- Hi5 ------------------------------------------------------------------------------

/// The Hi5 protocol: SetState/TorqueCommand with sequence numbers, Feedback
/// echoing them (`docs/can_protocol.md`).
pub struct Hi5Link {
    node: NodeId,
    watchdog_ms: u16,
    timeout: Duration,
    state: DriveState,
    faults: FaultFlags,
    sample: DriveSample,
    /// The feedbacks taken: newest sequence number first.
    order: FeedbackOrder,
    /// Foreign commands seen by set-up's waits.
    foreign_in_setup: u64,
    /// The enable succeeded: a BOOT or DISABLED report from now on is a reset.
    enabled_once: bool,
    /// The first BOOT or DISABLED report after the enable.
    reset: Option<DriveState>,
}

impl Hi5Link {
    /// The drive at `node`, its command watchdog `watchdog_ms` (5..=200), set-up
    /// steps bounded by `timeout`.
    pub fn new(node: NodeId, watchdog_ms: u16, timeout: Duration) -> Self {
        Self {
            node,
            watchdog_ms,
            timeout,
            state: DriveState::Boot,
            faults: FaultFlags::empty(),
            sample: DriveSample::default(),
            order: FeedbackOrder::new(256),
            foreign_in_setup: 0,
            enabled_once: false,
            reset: None,
        }
    }

    /// Takes a state report: after the enable, the first BOOT or DISABLED
    /// is kept as a reset (the drive never disables itself otherwise; a
    /// SetState(disable) from another node is a foreign command).
    fn note_state(&mut self, state: DriveState) {
        self.state = state;
        if self.enabled_once
            && self.reset.is_none()
            && matches!(state, DriveState::Boot | DriveState::Disabled)
        {
            self.reset = Some(state);
        }
    }

    fn send(&self, bus: &mut dyn Transport, msg: &Message) -> Result<(), LinkError> {
        let frame = encode(self.node, msg).map_err(LinkError::Hi5Encode)?;
        bus.send(&frame)?;
        Ok(())
    }

    fn wait_for(
        &mut self,
        bus: &mut dyn Transport,
        what: &'static str,
        done: impl Fn(&Self) -> bool,
    ) -> Result<(), LinkError> {
        let start = Instant::now();
        while !done(self) {
            if start.elapsed() > self.timeout {
                return Err(LinkError::Timeout {
                    what,
                    waited: self.timeout,
                });
            }
            if let Some(f) = bus.recv(Duration::from_millis(10))? {
                if self.absorb(&f) == Absorbed::ForeignCommand {
                    self.foreign_in_setup += 1;
                }
            }
        }
        Ok(())
    }

    /// Disable; the next TorqueCommand after it would carry sequence 0.
    fn disable(&self, bus: &mut dyn Transport) -> Result<(), LinkError> {
        self.send(
            bus,
            &Message::SetState {
                enable: false,
                watchdog_ms: self.watchdog_ms,
                sequence: 0,
            },
        )
    }
}

/// The sequence number of tick `k`'s command (`k mod 256`).
fn hi5_sequence(k: u64) -> u8 {
    (k & 0xff) as u8
}

impl DriveLink for Hi5Link {
    /// Waits for a heartbeat (any state but BOOT).
    fn connect(&mut self, bus: &mut dyn Transport) -> Result<(), LinkError> {
        self.wait_for(bus, "a heartbeat from the drive", |s| {
            s.state != DriveState::Boot
        })
    }

    /// ClearFaults if in FAULT (and wait for DISABLED); SetState(enable,
    /// resync to sequence 255) followed at once by a zero-torque command
    /// 255 (the drive handles frames in order and enables on SetState: its
    /// watchdog, armed by the enable, never waits for our round trip); wait
    /// for its Feedback, or a fault.
    fn enable(&mut self, bus: &mut dyn Transport) -> Result<EnableTimes, LinkError> {
        if self.state == DriveState::Fault {
            self.send(bus, &Message::ClearFaults)?;
            self.wait_for(bus, "DISABLED after clearing faults", |s| {
                s.state == DriveState::Disabled
            })?;
        }
        self.order.reset();
        let enable = Instant::now();
        self.send(
            bus,
            &Message::SetState {
                enable: true,
                watchdog_ms: self.watchdog_ms,
                sequence: 255,
            },
        )?;
        let first_command = Instant::now();
        self.send_torque(bus, u64::from(u8::MAX), 0.0)?;
        self.wait_for(bus, "ENABLED and the first feedback", |s| {
            s.order.up_to_date() || s.state == DriveState::Fault
        })?;
        if self.state == DriveState::Fault {
            return Err(LinkError::Faulted(DriveAlarm::Hi5Fault {
                flags: self.faults.bits(),
            }));
        }
        self.enabled_once = true;
        self.reset = None;
        Ok(EnableTimes {
            enable,
            first_command,
        })
    }

    /// A Feedback is taken only if it answers a command sent after the
    /// newest one taken ([`FeedbackOrder`]); its state with it.
    fn absorb(&mut self, f: &Frame) -> Absorbed {
        match decode(self.node, f) {
            Ok(Message::Feedback {
                position_rad,
                velocity_rad_s,
                sequence,
                state,
                ..
            }) => {
                let absorbed = self.order.absorb(sequence, position_rad, velocity_rad_s);
                if let Absorbed::Feedback { .. } = absorbed {
                    self.sample.position_rad = position_rad;
                    self.sample.velocity_rad_s = velocity_rad_s;
                    self.note_state(state);
                }
                absorbed
            }
            Ok(Message::Heartbeat {
                state, fault_flags, ..
            })
            | Ok(Message::Fault {
                state, fault_flags, ..
            }) => {
                self.note_state(state);
                self.faults = fault_flags;
                Absorbed::Other
            }
            Ok(Message::TorqueCommand { .. })
            | Ok(Message::SetState { .. })
            | Ok(Message::EmergencyStop)
            | Ok(Message::ClearFaults) => Absorbed::ForeignCommand,
            Err(_) => Absorbed::Undecodable,
        }
    }

    fn sample(&mut self, k: u64) -> DriveSample {
        self.sample.fresh = k == 0 || self.order.up_to_date();
        self.sample.status = self.state.into();
        self.sample.alarm = match self.reset {
            Some(s) => Some(DriveAlarm::Reset(ResetReport::Hi5State(s))),
            None => (self.state == DriveState::Fault).then_some(DriveAlarm::Hi5Fault {
                flags: self.faults.bits(),
            }),
        };
        self.sample
    }

    fn send_torque(
        &mut self,
        bus: &mut dyn Transport,
        k: u64,
        torque_nm: f64,
    ) -> Result<(), LinkError> {
        let sequence = hi5_sequence(k);
        self.order.sent(sequence);
        self.send(
            bus,
            &Message::TorqueCommand {
                torque_nm,
                sequence,
            },
        )
    }

    /// Emergency: EmergencyStop (latches FAULT: no controller can drive the
    /// motor until faults are cleared); else a zero-torque command with the
    /// next sequence. Then SetState(disable). Both are sent even if the
    /// first fails; the first error is returned.
    fn stop(&mut self, bus: &mut dyn Transport, k: u64, emergency: bool) -> Result<(), LinkError> {
        let first = if emergency {
            self.send(bus, &Message::EmergencyStop)
        } else {
            self.send_torque(bus, k, 0.0)
        };
        let second = self.disable(bus);
        first.and(second)
    }

    fn torque_step_nm(&self) -> f64 {
        crate::protocol::TORQUE_SCALE_NM
    }

    fn foreign_commands_in_setup(&self) -> u64 {
        self.foreign_in_setup
    }

    fn receive_ids(&self) -> Vec<u32> {
        [
            MessageKind::Feedback,
            MessageKind::Fault,
            MessageKind::Heartbeat,
            MessageKind::TorqueCommand,
            MessageKind::SetState,
            MessageKind::EmergencyStop,
            MessageKind::ClearFaults,
        ]
        .map(|kind| kind.id(self.node))
        .to_vec()
    }

    fn shut_down(&mut self, bus: &mut dyn Transport, k: u64) -> Result<(), LinkError> {
        self.stop(bus, k, false)?;
        self.wait_for(bus, "Hi5 DISABLED", |s| s.state != DriveState::Enabled)
    }
}

// -- CiA 402 ----------------------------------------------------------------------------

/// CiA 402 standard mode: whether the answer taken for the last SYNC
/// surely answers it, judged from the bus alone (no SYNC counter echo).
///
/// A drive answers SYNCs in order, each at most once, and never before the
/// SYNC; so once an answer landed in its SYNC's window, an answer in the
/// next window answers the next SYNC, unless it came late. An answer can
/// only be late (answer an earlier SYNC than the one it is placed on) if a
/// SYNC since the last in-step answer went without one in its own window
/// (docs/safety.md, "Standard CiA 402 drives"). So an answer is fresh only
/// when the SYNC before it got exactly one answer, taken, and both came
/// within `answer_window` of their SYNC (kernel receive time against the
/// SYNC's send time; a drive answering more than one period late lands in
/// a later window, and is told from a prompt answer only by its time or by
/// the unanswered SYNC before it). An answer that fails this is still the
/// newest feedback (the safety checks read it) but is not fresh: the
/// estimators predict over that tick. Allocation-free.
#[derive(Clone, Copy, Debug)]
pub struct StepWatch {
    answer_window: Duration,
    /// The kernel receive time of the last TPDO since the last SYNC.
    window_received: Option<SystemTime>,
    /// The SYNC before the last one got one answer, taken, on time.
    previous_in_step: bool,
    /// The last SYNC's answer was taken, on time.
    answered_on_time: bool,
    /// The answer taken for the last SYNC is fresh.
    in_step: bool,
    /// Answers taken but not fresh.
    out_of_step: u64,
    /// The most SYNCs the last answer taken may be late by.
    late_at_most: u32,
}

impl StepWatch {
    /// Answers later than `answer_window` after their SYNC are not fresh.
    pub fn new(answer_window: Duration) -> Self {
        Self {
            answer_window,
            window_received: None,
            previous_in_step: false,
            answered_on_time: false,
            in_step: false,
            out_of_step: 0,
            late_at_most: 0,
        }
    }

    /// The enable's last SYNC was answered (set-up waits for it): in step.
    pub fn enabled(&mut self) {
        *self = Self {
            answered_on_time: true,
            in_step: true,
            ..Self::new(self.answer_window)
        };
    }

    /// A TPDO was received (kernel time, if the bus gives one).
    pub fn tpdo_received(&mut self, received: Option<SystemTime>) {
        self.window_received = self.window_received.max(received);
    }

    /// The answer to the last SYNC (sent at `sync_at`) was taken, placed
    /// `steps` SYNCs after the answer taken before it. Returns the most
    /// drive steps between the two answers' samples: `steps` plus the most
    /// SYNCs the earlier answer may have been late by, at least one (an
    /// answer one SYNC behind can look in step: docs/safety.md). An answer
    /// in step is not late; one out of step answers a later SYNC than the
    /// answer before it did (a drive answers in order, each SYNC once), so
    /// it may be late by at most the returned count less one.
    pub fn answer_taken(&mut self, sync_at: Option<SystemTime>, steps: u32) -> u32 {
        self.answered_on_time = match (self.window_received, sync_at) {
            (Some(r), Some(s)) => r.duration_since(s).is_ok_and(|d| d <= self.answer_window),
            _ => true,
        };
        self.in_step = self.previous_in_step && self.answered_on_time;
        self.out_of_step += u64::from(!self.in_step);
        // 0 steps: the first answer after the enable (unknown, as `steps`).
        let most_steps = match steps {
            0 => 0,
            _ => steps.saturating_add(self.late_at_most.max(1)),
        };
        self.late_at_most = if self.in_step {
            0
        } else {
            most_steps.saturating_sub(1)
        };
        most_steps
    }

    /// A TPDO received before the last SYNC went out was read after it:
    /// the SYNC before got two answers, one of them late.
    pub fn late_tpdo(&mut self) {
        self.previous_in_step = false;
    }

    /// A SYNC goes out; `duplicated`: the last one got a second answer.
    pub fn sync_sent(&mut self, duplicated: bool) {
        self.previous_in_step = std::mem::take(&mut self.answered_on_time) && !duplicated;
        self.in_step = false;
        self.window_received = None;
    }

    /// The answer taken for the last SYNC is fresh.
    pub fn in_step(&self) -> bool {
        self.in_step
    }

    /// Answers taken but not fresh so far.
    pub fn out_of_step(&self) -> u64 {
        self.out_of_step
    }
}

/// CiA 402 over CANopen: [`Master`], one RPDO + SYNC per tick. A tick's
/// feedback is a TPDO1 (position) and a TPDO2 (velocity) echoing one SYNC
/// counter; pairs are taken newest counter first ([`FeedbackOrder`]).
pub struct Cia402Link {
    master: Master,
    step: Duration,
    /// The feedbacks taken, by SYNC counter.
    order: FeedbackOrder,
    /// A TPDO1 newer than the newest feedback, waiting for its TPDO2:
    /// (SYNC counter, position rad).
    pending_tpdo1: Option<(u8, f64)>,
    /// The enable succeeded: a statusword other than OperationEnabled or a
    /// fault from now on is the drive leaving it by itself.
    enabled_once: bool,
    /// When tick 0's command went out (the EMCYs' time origin).
    tick0: Option<Instant>,
    /// Standard mode: a second TPDO of one kind arrived after the last
    /// SYNC, so its answer is ambiguous: not fresh.
    window_duplicated: bool,
    /// Standard mode: the TPDO1 + TPDO2 answering the last SYNC, held back
    /// until the drain is over ([`DriveLink::settle`]): (counter, position,
    /// velocity).
    candidate: Option<(u8, f64, f64)>,
    /// Standard mode: whether the drive answers in step.
    step_watch: StepWatch,
}

impl Cia402Link {
    /// A master with these settings; set-up steps one SYNC per `step`.
    pub fn new(settings: MasterSettings, step: Duration) -> Result<Self, LinkError> {
        Ok(Self {
            master: Master::new(settings)?,
            step,
            order: FeedbackOrder::new(u16::from(crate::cia402::od::SYNC_COUNTER_OVERFLOW)),
            pending_tpdo1: None,
            enabled_once: false,
            tick0: None,
            window_duplicated: false,
            candidate: None,
            step_watch: StepWatch::new(step / 2),
        })
    }

    /// A TPDO1 the master decoded: kept if newer than the newest feedback
    /// (until its TPDO2); a copy of the newest's is discarded, another
    /// position for the newest's counter conflicts.
    fn tpdo1(&mut self) -> Absorbed {
        let fb = self.master.feedback();
        let (counter, x) = (fb.tpdo1_sync_counter, fb.position_rad);
        match self.order.classify_part(counter, Some(x), None) {
            Order::Newer(_) => {
                self.pending_tpdo1 = Some((counter, x));
                Absorbed::Other
            }
            Order::Copy | Order::Stale => Absorbed::StaleFeedback,
            Order::Conflicting => Absorbed::ConflictingFeedback { sequence: counter },
        }
    }

    /// A TPDO2 the master decoded: with the pending TPDO1 of its counter,
    /// one tick's feedback; without one (the TPDO1 lost), nothing; a copy
    /// of the newest's is discarded, another velocity for the newest's
    /// counter conflicts.
    fn tpdo2(&mut self) -> Absorbed {
        let fb = self.master.feedback();
        let (counter, v) = (fb.tpdo2_sync_counter, fb.velocity_rad_s);
        match self.pending_tpdo1 {
            Some((c, x)) if c == counter && self.standard() => {
                self.pending_tpdo1 = None;
                self.candidate = Some((counter, x, v));
                Absorbed::Other
            }
            Some((c, x)) if c == counter => {
                self.pending_tpdo1 = None;
                self.order.absorb(counter, x, v)
            }
            _ => match self.order.classify_part(counter, None, Some(v)) {
                Order::Newer(_) => Absorbed::Other,
                Order::Copy | Order::Stale => Absorbed::StaleFeedback,
                Order::Conflicting => Absorbed::ConflictingFeedback { sequence: counter },
            },
        }
    }

    fn standard(&self) -> bool {
        self.master.freshness() == Some(Freshness::Standard)
    }

    /// Why the drive cannot be driven on, if it cannot: a reset (boot-up or
    /// NMT state), its Fault (with the last EMCY), its heartbeat lost, or,
    /// after the enable, a statusword that left OperationEnabled.
    fn alarm(&self) -> Option<DriveAlarm> {
        let fb = self.master.feedback();
        let reset = |r| Some(DriveAlarm::Reset(r));
        match (fb.reset, fb.state) {
            (Some(NmtState::BootUp), _) => reset(ResetReport::BootUp),
            (Some(s), _) => reset(ResetReport::NmtState(s)),
            (None, Some(Cia402State::Fault | Cia402State::FaultReactionActive)) => {
                Some(DriveAlarm::Cia402Fault {
                    emcy_code: fb.last_emcy.map_or(0, |e| e.code),
                    error_register: fb.last_emcy.map_or(0, |e| e.register),
                })
            }
            _ if fb.drive_heartbeat_lost => Some(DriveAlarm::HeartbeatLost {
                timeout_ms: self.master.settings().drive_heartbeat_timeout.as_millis() as u64,
            }),
            (None, Some(s)) if self.enabled_once && s != Cia402State::OperationEnabled => {
                reset(ResetReport::Cia402State(s))
            }
            _ => None,
        }
    }

    /// The master (units, feedback counters), for tests: the loop reads
    /// the link only through [`DriveLink`].
    #[cfg(feature = "test-support")]
    pub fn master(&self) -> &Master {
        &self.master
    }
}

impl DriveLink for Cia402Link {
    /// [`Master::wait_for_drive`]: its boot-up or heartbeat; sends nothing
    /// (the loop listens for another master before anything is sent).
    fn connect(&mut self, bus: &mut dyn Transport) -> Result<(), LinkError> {
        self.master.wait_for_drive(bus)?;
        Ok(())
    }

    /// [`Master::configure`] (SDO set-up, heartbeats, NMT start), then
    /// [`Master::enable`]: controlword steps (one RPDO + SYNC each, a fault
    /// reset first if needed) until OperationEnabled at zero torque, and
    /// the last SYNC answered. Every step is a zero-torque command the drive's
    /// heartbeat consumer is fed by.
    fn enable(&mut self, bus: &mut dyn Transport) -> Result<EnableTimes, LinkError> {
        self.master.configure(bus)?;
        let enable = Instant::now();
        self.master.enable(bus, self.step)?;
        // The enable's last SYNC is answered: its feedback is the newest.
        let counter = self.master.sync_counter();
        let fb = self.master.feedback();
        self.order.reset();
        self.pending_tpdo1 = None;
        self.window_duplicated = false;
        self.step_watch.enabled();
        self.order.sent(counter);
        self.order
            .absorb(counter, fb.position_rad, fb.velocity_rad_s);
        self.master.check_drive_heartbeat(Instant::now());
        if let Some(alarm) = self.alarm() {
            return Err(LinkError::Faulted(alarm));
        }
        self.enabled_once = true;
        Ok(EnableTimes {
            enable,
            first_command: enable,
        })
    }

    fn absorb(&mut self, f: &Frame) -> Absorbed {
        self.absorb_received(f, None)
    }

    /// Standard mode: a TPDO received before the last SYNC is late
    /// (discarded), a second one after it duplicated (discarded, and the
    /// SYNC's answer not fresh: [`DriveLink::sample`]).
    fn absorb_received(&mut self, f: &Frame, received: Option<SystemTime>) -> Absorbed {
        let node = self.master.settings().node;
        if self.standard() && f.is_standard_data() && (f.id == node.tpdo1() || f.id == node.tpdo2())
        {
            self.step_watch.tpdo_received(received);
        }
        let late_before = self.master.feedback().tpdos_late;
        let heard = self.master.absorb_received(f, received);
        if self.master.feedback().tpdos_late > late_before {
            self.step_watch.late_tpdo();
        }
        match heard {
            Heard::Tpdo2 => self.tpdo2(),
            Heard::Other if f.is_standard_data() && f.id == self.master.settings().node.tpdo1() => {
                self.tpdo1()
            }
            Heard::ForeignCommand => Absorbed::ForeignCommand,
            Heard::Undecodable => Absorbed::Undecodable,
            Heard::Conflicting { sync_counter } => Absorbed::ConflictingFeedback {
                sequence: sync_counter,
            },
            Heard::Discarded => Absorbed::StaleFeedback,
            Heard::Duplicated => {
                self.window_duplicated = true;
                Absorbed::StaleFeedback
            }
            Heard::Other => Absorbed::Other,
        }
    }

    /// Standard mode: the last SYNC's answer, taken now unless a second
    /// TPDO of a kind came after that SYNC (then neither is: the answer is
    /// ambiguous, maybe a late answer to the SYNC before). Taken but not
    /// fresh (it may answer an earlier SYNC: counted in
    /// [`LinkCounts::feedback_out_of_step`]) when it may be late
    /// ([`StepWatch`]).
    fn settle(&mut self) -> Option<Absorbed> {
        let (counter, x, v) = self.candidate.take()?;
        if self.window_duplicated || counter != self.master.sync_counter() {
            return None;
        }
        let mut absorbed = self.order.absorb(counter, x, v);
        if let Absorbed::Feedback {
            steps,
            ref mut most_steps,
            ..
        } = absorbed
        {
            *most_steps = self
                .step_watch
                .answer_taken(self.master.last_sync_at(), steps);
        }
        Some(absorbed)
    }

    /// Fresh: the newest feedback taken echoes the counter of tick `k -
    /// 1`'s SYNC (a replayed or late TPDO arriving after it is not taken);
    /// standard mode: it arrived after that SYNC, no second TPDO of a kind
    /// did, and the drive answered in step ([`StepWatch`]).
    fn sample(&mut self, k: u64) -> DriveSample {
        self.master.check_drive_heartbeat(Instant::now());
        let fb = self.master.feedback();
        let (position_rad, velocity_rad_s) = self
            .order
            .newest()
            .unwrap_or((fb.position_rad, fb.velocity_rad_s));
        DriveSample {
            position_rad,
            velocity_rad_s,
            fresh: k == 0
                || (self.order.up_to_date()
                    && !self.window_duplicated
                    && (!self.standard() || self.step_watch.in_step())),
            status: fb.state.into(),
            alarm: self.alarm(),
        }
    }

    fn send_torque(
        &mut self,
        bus: &mut dyn Transport,
        k: u64,
        torque_nm: f64,
    ) -> Result<(), LinkError> {
        if k == 0 {
            self.tick0 = Some(Instant::now());
        }
        let sent = self.master.tick(bus, torque_nm);
        self.order.sent(self.master.sync_counter());
        self.step_watch.sync_sent(self.window_duplicated);
        self.window_duplicated = false;
        self.candidate = None;
        sent?;
        Ok(())
    }

    /// The EMCYs (time after tick 0's command), the TPDOs discarded by the
    /// newest-SYNC-counter rule, the commands clamped at 0x6072.
    fn events(&self) -> DriveEvents {
        let fb = self.master.feedback();
        let origin = self.tick0;
        let seconds = |at: Instant| match origin {
            Some(t0) if at >= t0 => at.duration_since(t0).as_secs_f64(),
            Some(t0) => -t0.duration_since(at).as_secs_f64(),
            None => f64::NAN,
        };
        DriveEvents {
            emcy_received: fb.emcy_received,
            emcy: self
                .master
                .emcy_records()
                .iter()
                .map(|r| (r.emcy, seconds(r.at)))
                .collect(),
            freshness: self.master.freshness(),
            counts: LinkCounts {
                feedback_discarded: fb.tpdos_discarded,
                feedback_late: fb.tpdos_late,
                feedback_out_of_step: self.step_watch.out_of_step(),
                feedback_duplicated: fb.tpdos_duplicated,
                syncs_unanswered: fb.syncs_unanswered,
                commands_clamped_at_drive_limit: self.master.commands_clamped(),
                commands_non_finite: self.master.commands_non_finite(),
            },
        }
    }

    /// Emergency: [`Master::quick_stop`] (torque 0 at once; the drive
    /// holds QuickStopActive until a master's controlword). Else
    /// [`Master::shut_down`], which, unlike the Hi5's stop, waits (bounded
    /// by the response timeout) for the drive to leave OperationEnabled and
    /// for its heartbeat consumer to be switched off: without that, the
    /// drive would fault when this master falls silent.
    fn stop(&mut self, bus: &mut dyn Transport, _k: u64, emergency: bool) -> Result<(), LinkError> {
        if emergency {
            self.master.quick_stop(bus)?;
        } else {
            self.master.shut_down(bus, self.step)?;
        }
        Ok(())
    }

    fn torque_step_nm(&self) -> f64 {
        self.master.units().torque_step_nm()
    }

    /// Every foreign command the master counted (set-up reads the bus
    /// through the master alone).
    fn foreign_commands_in_setup(&self) -> u64 {
        self.master.feedback().foreign_commands
    }

    /// The drive's TPDOs, EMCY, heartbeat and SDO responses; its RPDO1 and
    /// SDO requests, SYNC and NMT (another master's).
    fn receive_ids(&self) -> Vec<u32> {
        use crate::cia402::od::{NMT_COB_ID, SYNC_COB_ID};
        let n = self.master.settings().node;
        vec![
            n.tpdo1(),
            n.tpdo2(),
            n.emcy(),
            n.heartbeat(),
            n.sdo_tx(),
            n.rpdo1(),
            n.sdo_rx(),
            SYNC_COB_ID,
            NMT_COB_ID,
        ]
    }

    /// [`Master::shut_down`].
    fn shut_down(&mut self, bus: &mut dyn Transport, _k: u64) -> Result<(), LinkError> {
        self.master.shut_down(bus, self.step)?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Commands 0..=4 sent, feedback for 0 taken.
    fn hi5_order() -> FeedbackOrder {
        let mut o = FeedbackOrder::new(256);
        o.sent(0);
        assert_eq!(o.absorb(0, 0.1, 1.0), fb(0.1, 1.0, 0));
        for s in 1..=4 {
            o.sent(s);
        }
        o
    }

    fn fb(position_rad: f64, velocity_rad_s: f64, steps: u32) -> Absorbed {
        Absorbed::Feedback {
            position_rad,
            velocity_rad_s,
            steps,
            most_steps: steps,
        }
    }

    /// Both profiles' states on the four neutral ones, with the log's codes
    /// (the Hi5's are its DBC's values, so Hi5 logs read as before).
    #[test]
    fn each_profiles_states_map_onto_the_neutral_status() {
        use DriveStatus::*;
        for (hi5, status) in [
            (DriveState::Boot, Booting),
            (DriveState::Disabled, Disabled),
            (DriveState::Enabled, Enabled),
            (DriveState::Fault, Fault),
        ] {
            assert_eq!(DriveStatus::from(hi5), status);
            assert_eq!(status.code(), hi5.raw(), "{hi5:?}");
        }
        for (cia402, status) in [
            (None, Booting),
            (Some(Cia402State::NotReadyToSwitchOn), Booting),
            (Some(Cia402State::SwitchOnDisabled), Disabled),
            (Some(Cia402State::ReadyToSwitchOn), Disabled),
            (Some(Cia402State::SwitchedOn), Disabled),
            (Some(Cia402State::QuickStopActive), Disabled),
            (Some(Cia402State::OperationEnabled), Enabled),
            (Some(Cia402State::FaultReactionActive), Fault),
            (Some(Cia402State::Fault), Fault),
        ] {
            assert_eq!(DriveStatus::from(cia402), status, "{cia402:?}");
        }
        let codes = [Booting, Disabled, Enabled, Fault].map(|s| (s.code(), s.name()));
        assert_eq!(
            codes,
            [
                (0, "booting"),
                (1, "disabled"),
                (2, "enabled"),
                (3, "fault")
            ]
        );
    }

    #[test]
    fn the_newest_sequence_wins_whatever_the_order_of_arrival() {
        let mut o = hi5_order();
        // 2 arrives before 1 (1 late): 2 is taken, two steps after 0; 1 then is older.
        assert_eq!(o.absorb(2, 0.3, 1.2), fb(0.3, 1.2, 2));
        assert_eq!(o.absorb(1, 0.2, 1.1), Absorbed::StaleFeedback);
        assert_eq!(o.newest(), Some((0.3, 1.2)));
        assert!(!o.up_to_date(), "4 is the last sent");
        assert_eq!(o.absorb(4, 0.5, 1.4), fb(0.5, 1.4, 2));
        assert!(o.up_to_date());
    }

    #[test]
    fn a_copy_is_discarded_and_another_answer_to_the_same_command_conflicts() {
        let mut o = hi5_order();
        assert_eq!(o.absorb(1, 0.2, 1.1), fb(0.2, 1.1, 1));
        assert_eq!(o.absorb(1, 0.2, 1.1), Absorbed::StaleFeedback);
        assert_eq!(
            o.absorb(1, 0.2, 2.2),
            Absorbed::ConflictingFeedback { sequence: 1 }
        );
        // The newest is kept.
        assert_eq!(o.newest(), Some((0.2, 1.1)));
        // A node answered 2 first, then the drive, late, after 3 was taken.
        assert_eq!(o.absorb(2, 0.9, 0.9), fb(0.9, 0.9, 1));
        assert_eq!(o.absorb(3, 0.4, 1.3), fb(0.4, 1.3, 1));
        assert_eq!(
            o.absorb(2, 0.3, 1.2),
            Absorbed::ConflictingFeedback { sequence: 2 }
        );
        assert_eq!(o.absorb(2, 0.9, 0.9), Absorbed::StaleFeedback, "a replay");
        // Parts (CiA 402's TPDOs) are judged on what they carry.
        assert_eq!(o.classify_part(2, Some(0.9), None), Order::Copy);
        assert_eq!(o.classify_part(2, None, Some(0.9)), Order::Copy);
        assert_eq!(o.classify_part(2, None, Some(1.0)), Order::Conflicting);
    }

    #[test]
    fn a_feedback_for_a_command_not_sent_or_far_behind_is_discarded() {
        let o = hi5_order();
        // 5 is not sent yet: it would answer the command 251 before 4.
        assert_eq!(o.classify(5, 0.6, 1.5), Order::Stale);
        assert_eq!(o.classify(156, 0.6, 1.5), Order::Stale, "100 behind");
        assert_eq!(o.classify(4, 0.0, 0.0), Order::Newer(4));
        // Nothing sent: nothing answered.
        assert_eq!(FeedbackOrder::new(256).classify(0, 0.0, 0.0), Order::Stale);
        // After a reset (the enable), the first answer to a command sent is taken.
        let mut r = hi5_order();
        r.reset();
        assert_eq!(r.classify(3, 0.0, 0.0), Order::Newer(0));
    }

    #[test]
    fn the_order_holds_across_the_wrap_and_a_long_stall() {
        let mut o = FeedbackOrder::new(256);
        for s in 250..=255 {
            o.sent(s);
        }
        o.absorb(253, 0.0, 0.0);
        for s in 0..=1 {
            o.sent(s);
        }
        assert_eq!(o.classify(0, 0.0, 0.0), Order::Newer(3));
        assert_eq!(o.classify(252, 0.0, 0.0), Order::Stale);
        // 300 more commands without a feedback taken (a stalled drive,
        // within a 300 ms feedback timeout): the answer to the last one
        // (number 45) is the newest, 304 commands after 253's; one with
        // 253's number answers the command 256 before the last, not 253.
        for k in 0..300u64 {
            o.sent(((2 + k) % 256) as u8);
        }
        assert_eq!(o.classify(253, 9.0, 9.0), Order::Newer(256));
        assert_eq!(o.classify(45, 1.0, 1.0), Order::Newer(304));
        assert_eq!(o.absorb(45, 1.0, 1.0), fb(1.0, 1.0, 304));
        assert!(o.up_to_date());
    }

    /// Standard CiA 402: an answer is fresh only in step: on time, and the
    /// SYNC before answered once, on time.
    #[test]
    fn a_standard_answer_is_fresh_only_when_the_sync_before_was_answered_in_step() {
        let t0 = SystemTime::UNIX_EPOCH + Duration::from_secs(1_000_000);
        let sync = |k: u64| t0 + Duration::from_millis(k);
        // SYNC `k` sent (the one before duplicated or not), answered `us`
        // after it (None: no receive time): fresh?
        let answer = |w: &mut StepWatch, k: u64, duplicated: bool, us: Option<u64>| {
            w.sync_sent(duplicated);
            w.tpdo_received(us.map(|us| sync(k) + Duration::from_micros(us)));
            w.answer_taken(us.map(|_| sync(k)), 1);
            w.in_step()
        };
        let mut w = StepWatch::new(Duration::from_micros(500));
        w.enabled();
        assert!(w.in_step(), "the enable's answer");
        assert!(answer(&mut w, 1, false, Some(200)));
        // SYNC 2 without answer: SYNC 3's prompt answer may be SYNC 2's,
        // late: not fresh. SYNC 4's is fresh again.
        w.sync_sent(false);
        assert!(!w.in_step(), "no answer yet");
        assert!(
            !answer(&mut w, 3, false, Some(100)),
            "after an unanswered SYNC"
        );
        assert!(answer(&mut w, 4, false, Some(100)));
        // 600 us after its SYNC (window 500 us): not fresh, nor the next one.
        assert!(!answer(&mut w, 5, false, Some(600)), "late in its window");
        assert!(!answer(&mut w, 6, false, Some(50)), "after a late one");
        // After a duplicated window: not fresh.
        assert!(
            !answer(&mut w, 7, true, Some(50)),
            "after a duplicated window"
        );
        assert!(answer(&mut w, 8, false, Some(50)));
        // A TPDO received before SYNC 9 and read after it (two answers in
        // SYNC 8's window): SYNC 9's answer is not fresh.
        w.sync_sent(false);
        w.late_tpdo();
        w.tpdo_received(Some(sync(9) + Duration::from_micros(50)));
        w.answer_taken(Some(sync(9)), 1);
        assert!(!w.in_step(), "after a late TPDO");
        // Without receive times only the unanswered SYNCs count.
        assert!(answer(&mut w, 10, false, None));
        assert_eq!(w.out_of_step(), 5);
    }

    #[test]
    fn a_standard_answer_out_of_step_widens_the_steps_after_it_until_one_is_in_step() {
        // SYNC `k` sent, answered (on time), placed `steps` SYNCs after the
        // answer taken before: the most drive steps between the two.
        let answer = |w: &mut StepWatch, steps: u64| {
            for _ in 1..steps {
                w.sync_sent(false); // unanswered
            }
            w.sync_sent(false);
            w.answer_taken(None, steps as u32)
        };
        let mut w = StepWatch::new(Duration::from_micros(500));
        w.enabled();
        // In step: the previous answer may still be one SYNC behind.
        assert_eq!(answer(&mut w, 1), 2);
        // A drive that stalled after sampling SYNC 2 sends that answer
        // after SYNC 4: placed on 4, 3 SYNCs after the last, out of step
        // (SYNCs 2 and 3 went unanswered): 4 steps at most (the one before
        // may have been 1 behind), so it may be 3 late (it is 2).
        assert_eq!(answer(&mut w, 3), 4);
        assert!(!w.in_step());
        // Then SYNC 4's answer, placed on 5, 2 steps after SYNC 2's: 1
        // counted, 4 at most. Two on-time answers: in step (it is one
        // behind: what the floor of one is for), the widening ends.
        assert_eq!(answer(&mut w, 1), 4);
        assert!(w.in_step());
        assert_eq!(answer(&mut w, 1), 2);
        // The first answer after the enable: unknown, as its steps.
        assert_eq!(answer(&mut w, 0), 0);
    }

    #[test]
    fn cia402_counters_run_1_to_240() {
        let mut o = FeedbackOrder::new(240);
        o.sent(239);
        o.absorb(239, 0.0, 0.0);
        o.sent(240);
        o.sent(1);
        assert_eq!(o.classify(240, 0.0, 0.0), Order::Newer(1));
        assert_eq!(o.classify(1, 0.0, 0.0), Order::Newer(2));
        assert_eq!(o.classify(139, 0.0, 0.0), Order::Stale, "100 behind");
        assert_eq!(o.classify(2, 0.0, 0.0), Order::Stale, "not sent");
    }
}
