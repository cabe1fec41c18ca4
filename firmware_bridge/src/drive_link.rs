//! One interface to a torque drive, whatever its profile: the Hi5 protocol
//! (`hi5.dbc`) or CiA 402 over CANopen ([`crate::cia402`]).
//!
//! A control loop holds a `Box<dyn DriveLink + Send>` (chosen by
//! `[rig] drive = "hi5" | "cia402"`) and calls, per tick `k`:
//! [`DriveLink::drain`] (sense: the feedback and whether it answers tick
//! `k - 1`), then [`DriveLink::send_torque`] (actuate). Set-up
//! ([`DriveLink::enable`]) and [`DriveLink::shut_down`] may wait on the bus;
//! `drain` and `send_torque` never wait and never allocate.

use core::fmt;
use std::time::{Duration, Instant};

use crate::cia402::{Cia402Error, DriveState as Cia402State, Master, MasterSettings};
use crate::frame::Frame;
use crate::protocol::{decode, encode, DriveState, FaultFlags, Message, NodeId};
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
    /// The drive applies torque commands (Hi5 ENABLED, CiA 402
    /// OperationEnabled).
    pub enabled: bool,
    /// The drive is in its fault state, or (CiA 402) its heartbeat is lost.
    pub fault: bool,
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
    },
}

impl fmt::Display for LinkError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Transport(e) => write!(f, "CAN bus: {e}"),
            Self::Hi5Encode(e) => write!(f, "Hi5 protocol: {e}"),
            Self::Cia402(e) => write!(f, "CiA 402: {e}"),
            Self::Timeout { what } => {
                write!(f, "timed out waiting for {what}; is the drive on the bus?")
            }
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
    /// Set-up: bring the drive to the state where it applies torque, at zero
    /// torque, ready for tick 0. May wait (bounded).
    fn enable(&mut self, bus: &mut dyn Transport) -> Result<(), LinkError>;

    /// Actuate tick `k`: send `torque_nm`. No wait, no allocation.
    fn send_torque(
        &mut self,
        bus: &mut dyn Transport,
        k: u64,
        torque_nm: f64,
    ) -> Result<(), LinkError>;

    /// Sense tick `k`: take every frame received so far; `fresh` when the
    /// feedback answers tick `k - 1` (tick 0: the set-up's). No wait, no
    /// allocation.
    fn drain(&mut self, bus: &mut dyn Transport, k: u64) -> Result<DriveSample, LinkError>;

    /// After the last tick `k - 1`: zero torque, then leave the drive
    /// disabled. May wait (bounded).
    fn shut_down(&mut self, bus: &mut dyn Transport, k: u64) -> Result<(), LinkError>;
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
    last_seq: Option<u8>,
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
            last_seq: None,
        }
    }

    fn send(&self, bus: &mut dyn Transport, msg: &Message) -> Result<(), LinkError> {
        let frame = encode(self.node, msg).map_err(LinkError::Hi5Encode)?;
        bus.send(&frame)?;
        Ok(())
    }

    fn absorb(&mut self, f: &Frame) {
        match decode(self.node, f) {
            Ok(Message::Feedback {
                position_rad,
                velocity_rad_s,
                sequence,
                state,
                ..
            }) => {
                self.sample.position_rad = position_rad;
                self.sample.velocity_rad_s = velocity_rad_s;
                self.state = state;
                self.last_seq = Some(sequence);
            }
            Ok(Message::Heartbeat {
                state, fault_flags, ..
            })
            | Ok(Message::Fault {
                state, fault_flags, ..
            }) => {
                self.state = state;
                self.faults = fault_flags;
            }
            _ => {}
        }
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
                return Err(LinkError::Timeout { what });
            }
            if let Some(f) = bus.recv(Duration::from_millis(10))? {
                self.absorb(&f);
            }
        }
        Ok(())
    }
}

impl DriveLink for Hi5Link {
    /// Heartbeat, ClearFaults if in FAULT, SetState(enable, sequence 255),
    /// a zero-torque command 255 and its Feedback.
    fn enable(&mut self, bus: &mut dyn Transport) -> Result<(), LinkError> {
        self.wait_for(bus, "a Hi5 heartbeat", |s| s.state != DriveState::Boot)?;
        if self.state == DriveState::Fault {
            self.send(bus, &Message::ClearFaults)?;
            self.wait_for(bus, "Hi5 DISABLED", |s| s.state == DriveState::Disabled)?;
        }
        self.send(
            bus,
            &Message::SetState {
                enable: true,
                watchdog_ms: self.watchdog_ms,
                sequence: 255,
            },
        )?;
        self.wait_for(bus, "Hi5 ENABLED", |s| s.state == DriveState::Enabled)?;
        self.send(
            bus,
            &Message::TorqueCommand {
                torque_nm: 0.0,
                sequence: 255,
            },
        )?;
        self.wait_for(bus, "the first Hi5 Feedback", |s| s.last_seq == Some(255))
    }

    fn send_torque(
        &mut self,
        bus: &mut dyn Transport,
        k: u64,
        torque_nm: f64,
    ) -> Result<(), LinkError> {
        self.send(
            bus,
            &Message::TorqueCommand {
                torque_nm,
                sequence: (k & 0xff) as u8,
            },
        )
    }

    fn drain(&mut self, bus: &mut dyn Transport, k: u64) -> Result<DriveSample, LinkError> {
        while let Some(f) = bus.recv(Duration::ZERO)? {
            self.absorb(&f);
        }
        let expected = (k.wrapping_sub(1) & 0xff) as u8;
        self.sample.fresh = self.last_seq == Some(expected);
        self.sample.enabled = self.state == DriveState::Enabled;
        self.sample.fault = self.state == DriveState::Fault;
        Ok(self.sample)
    }

    fn shut_down(&mut self, bus: &mut dyn Transport, k: u64) -> Result<(), LinkError> {
        self.send(
            bus,
            &Message::TorqueCommand {
                torque_nm: 0.0,
                sequence: (k & 0xff) as u8,
            },
        )?;
        self.send(
            bus,
            &Message::SetState {
                enable: false,
                watchdog_ms: self.watchdog_ms,
                sequence: 0,
            },
        )?;
        self.wait_for(bus, "Hi5 DISABLED", |s| s.state != DriveState::Enabled)
    }
}

// -- CiA 402 ----------------------------------------------------------------------------

/// CiA 402 over CANopen: [`Master`], one RPDO + SYNC per tick.
pub struct Cia402Link {
    master: Master,
    step: Duration,
}

impl Cia402Link {
    /// A master with these settings; set-up steps one SYNC per `step`.
    pub fn new(settings: MasterSettings, step: Duration) -> Result<Self, LinkError> {
        Ok(Self {
            master: Master::new(settings)?,
            step,
        })
    }

    /// The master (units, feedback counters).
    pub fn master(&self) -> &Master {
        &self.master
    }
}

impl DriveLink for Cia402Link {
    /// [`Master::boot`] then [`Master::enable`].
    fn enable(&mut self, bus: &mut dyn Transport) -> Result<(), LinkError> {
        self.master.boot(bus)?;
        self.master.enable(bus, self.step)?;
        Ok(())
    }

    fn send_torque(
        &mut self,
        bus: &mut dyn Transport,
        _k: u64,
        torque_nm: f64,
    ) -> Result<(), LinkError> {
        self.master.tick(bus, torque_nm)?;
        Ok(())
    }

    /// Fresh: every SYNC sent so far has been answered
    /// ([`Master::all_answered`]), so the TPDOs are the last tick's.
    fn drain(&mut self, bus: &mut dyn Transport, k: u64) -> Result<DriveSample, LinkError> {
        self.master.drain(bus)?;
        let fb = self.master.feedback();
        Ok(DriveSample {
            position_rad: fb.position_rad,
            velocity_rad_s: fb.velocity_rad_s,
            fresh: k == 0 || self.master.all_answered(),
            enabled: fb.state == Some(Cia402State::OperationEnabled),
            fault: fb.state == Some(Cia402State::Fault) || fb.drive_heartbeat_lost,
        })
    }

    /// [`Master::shut_down`].
    fn shut_down(&mut self, bus: &mut dyn Transport, _k: u64) -> Result<(), LinkError> {
        self.master.shut_down(bus, self.step)?;
        Ok(())
    }
}
