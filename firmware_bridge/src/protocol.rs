//! The Hi5 drive protocol: `hi5.dbc` as Rust types, encode and decode.
//!
//! `firmware_bridge/hi5.dbc` is the single source of truth: its ids, DLCs,
//! bit positions, scales, ranges, node addressing, state values and fault
//! bits reach this module only through the tables `build.rs` generates from
//! it ([`crate::dbc`]). This module adds the Rust types and the rules a DBC
//! cannot state (the CRC with its data id; the drive's acceptance rules,
//! [`CommandGate`]). The golden vectors
//! (`golden/frames.json`, made by cantools from the DBC) check the result
//! byte for byte against an independent reader.
//!
//! Ids: the DBC lists node [`dbc::LISTED_NODE`]'s ids. Node `n`
//! (0..[`dbc::NODE_COUNT`]) uses `base + n` with the bases in
//! [`MessageKind::base_id`]. Signals are little-endian (Intel).
//!
//! Physical to raw: `raw = round_ties_even(value / scale)`, exactly what
//! cantools does (Python's `round` is ties-to-even), after a range check
//! against the DBC's `[min|max]` with cantools' tolerance of `1e-6` LSB.
//! Nothing wraps: a value out of range or not finite is an [`EncodeError`]
//! naming the signal. Raw to physical: `raw * scale`.
//!
//! Nothing here allocates.

use core::fmt;

use crate::dbc::{self, MessageDef, SignalDef};
use crate::frame::Frame;

// ---------------------------------------------------------------- node ids

/// A drive's node id, 0..=15 (0..`dbc::NODE_COUNT`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct NodeId(u8);

/// A node id outside 0..=15.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct InvalidNodeId {
    /// The rejected value.
    pub got: u32,
}

impl fmt::Display for InvalidNodeId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "node id must be in 0..={}, got {}",
            NodeId::MAX,
            self.got
        )
    }
}

impl std::error::Error for InvalidNodeId {}

impl NodeId {
    /// Largest node id.
    pub const MAX: u8 = dbc::NODE_COUNT - 1;

    /// Node `n`, if `n <= 15`.
    pub const fn new(n: u32) -> Result<Self, InvalidNodeId> {
        if n <= Self::MAX as u32 {
            Ok(Self(n as u8))
        } else {
            Err(InvalidNodeId { got: n })
        }
    }

    /// The number, 0..=15.
    pub const fn get(self) -> u8 {
        self.0
    }
}

impl fmt::Display for NodeId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)
    }
}

// ----------------------------------------------------------- message kinds

/// The seven frames of `hi5.dbc`, without their contents.
///
/// `ALL` lists them in the DBC's id order; a DBC with another number of
/// messages fails to compile.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum MessageKind {
    /// `EmergencyStop`, host to drive, DLC 0.
    EmergencyStop,
    /// `Fault`, drive to host, DLC 4.
    Fault,
    /// `TorqueCommand`, host to drive, DLC 8.
    TorqueCommand,
    /// `Feedback`, drive to host, DLC 8.
    Feedback,
    /// `SetState`, host to drive, DLC 4.
    SetState,
    /// `ClearFaults`, host to drive, DLC 0.
    ClearFaults,
    /// `Heartbeat`, drive to host, DLC 8.
    Heartbeat,
}

impl MessageKind {
    /// Every kind, in id order (the order of [`dbc::MESSAGES`]).
    pub const ALL: [Self; dbc::MESSAGES.len()] = [
        Self::EmergencyStop,
        Self::Fault,
        Self::TorqueCommand,
        Self::Feedback,
        Self::SetState,
        Self::ClearFaults,
        Self::Heartbeat,
    ];

    /// The DBC's table for this message.
    pub const fn def(self) -> &'static MessageDef {
        match self {
            Self::EmergencyStop => &dbc::emergency_stop::MESSAGE,
            Self::Fault => &dbc::fault::MESSAGE,
            Self::TorqueCommand => &dbc::torque_command::MESSAGE,
            Self::Feedback => &dbc::feedback::MESSAGE,
            Self::SetState => &dbc::set_state::MESSAGE,
            Self::ClearFaults => &dbc::clear_faults::MESSAGE,
            Self::Heartbeat => &dbc::heartbeat::MESSAGE,
        }
    }

    /// The id for node 0; node `n` uses `base_id() + n`.
    pub const fn base_id(self) -> u32 {
        self.def().base_id
    }

    /// The DLC the DBC gives.
    pub const fn dlc(self) -> u8 {
        self.def().dlc
    }

    /// The DBC's message name.
    pub const fn name(self) -> &'static str {
        self.def().name
    }

    /// This kind's id for `node`.
    pub const fn id(self, node: NodeId) -> u32 {
        self.base_id() + node.0 as u32
    }

    /// Which kind and node an id belongs to, if any.
    pub fn from_id(id: u32) -> Option<(Self, NodeId)> {
        Self::ALL.into_iter().find_map(|kind| {
            let n = id.checked_sub(kind.base_id())?;
            NodeId::new(n).ok().map(|node| (kind, node))
        })
    }
}

// ------------------------------------------------------- states and flags

/// The drive's state machine (see `docs/can_protocol.md`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum DriveState {
    /// `BOOT`: powering up.
    Boot = dbc::state_values::BOOT,
    /// `DISABLED`: ready, torque off.
    Disabled = dbc::state_values::DISABLED,
    /// `ENABLED`: following torque commands, watchdog armed.
    Enabled = dbc::state_values::ENABLED,
    /// `FAULT`: torque off, a fault latched until `ClearFaults`.
    Fault = dbc::state_values::FAULT,
}

impl DriveState {
    /// The state with raw value `raw`, if it is one of the DBC's `VAL_`s.
    pub const fn from_raw(raw: u8) -> Option<Self> {
        match raw {
            dbc::state_values::BOOT => Some(Self::Boot),
            dbc::state_values::DISABLED => Some(Self::Disabled),
            dbc::state_values::ENABLED => Some(Self::Enabled),
            dbc::state_values::FAULT => Some(Self::Fault),
            _ => None,
        }
    }

    /// The raw value.
    pub const fn raw(self) -> u8 {
        self as u8
    }
}

/// The drive's latched fault bits (16-bit field; the bits the DBC does not
/// name are reserved and kept as received, not dropped).
#[derive(Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct FaultFlags(u16);

impl FaultFlags {
    /// No `TorqueCommand` within the watchdog period.
    pub const WATCHDOG: Self = Self(dbc::fault_bits::WATCHDOG);
    /// An `EmergencyStop` frame was received.
    pub const EMERGENCY_STOP: Self = Self(dbc::fault_bits::EMERGENCY_STOP);
    /// The motor exceeded its speed limit.
    pub const OVERSPEED: Self = Self(dbc::fault_bits::OVERSPEED);
    /// The drive's own self-check failed.
    pub const INTERNAL: Self = Self(dbc::fault_bits::INTERNAL);
    /// A valid TorqueCommand out of sequence while enabled: a second command
    /// source on the bus, or a lost command.
    pub const SEQUENCE: Self = Self(dbc::fault_bits::SEQUENCE);

    /// No fault.
    pub const fn empty() -> Self {
        Self(0)
    }

    /// Exactly these bits, reserved ones included.
    pub const fn from_bits_retain(bits: u16) -> Self {
        Self(bits)
    }

    /// The raw 16 bits.
    pub const fn bits(self) -> u16 {
        self.0
    }

    /// No bit set.
    pub const fn is_empty(self) -> bool {
        self.0 == 0
    }

    /// Every bit of `other` is set in `self`.
    pub const fn contains(self, other: Self) -> bool {
        self.0 & other.0 == other.0
    }

    /// Set the bits of `other`.
    pub fn insert(&mut self, other: Self) {
        self.0 |= other.0;
    }

    /// Clear the bits of `other`.
    pub fn remove(&mut self, other: Self) {
        self.0 &= !other.0;
    }
}

impl core::ops::BitOr for FaultFlags {
    type Output = Self;
    fn bitor(self, rhs: Self) -> Self {
        Self(self.0 | rhs.0)
    }
}

impl core::ops::BitOrAssign for FaultFlags {
    fn bitor_assign(&mut self, rhs: Self) {
        self.0 |= rhs.0;
    }
}

impl fmt::Debug for FaultFlags {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "FaultFlags(")?;
        let mut rest = self.0;
        let mut first = true;
        for (bit, name) in dbc::fault_bits::ALL {
            if self.0 & bit != 0 {
                write!(f, "{}{name}", if first { "" } else { " | " })?;
                rest &= !bit;
                first = false;
            }
        }
        if rest != 0 || first {
            write!(f, "{}{rest:#06x}", if first { "" } else { " | " })?;
        }
        write!(f, ")")
    }
}

// ---------------------------------------------------------------- messages

/// One decoded frame, in physical units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Message {
    /// Host to drive, every control tick.
    TorqueCommand {
        /// Motor torque, N m (`TorqueCommand.torque`: scale and range in
        /// `hi5.dbc`, `docs/can_protocol.md`).
        torque_nm: f64,
        /// Command counter, echoed in `Feedback`.
        sequence: u8,
    },
    /// Drive to host, one per accepted torque command.
    Feedback {
        /// Motor position, rad (`Feedback.position`: scale and range in
        /// `hi5.dbc`, `docs/can_protocol.md`).
        position_rad: f64,
        /// Motor velocity, rad/s (`Feedback.velocity`, likewise).
        velocity_rad_s: f64,
        /// The accepted command's sequence.
        sequence: u8,
        /// Drive state.
        state: DriveState,
        /// The command was clipped to the drive's torque limit.
        torque_limited: bool,
        /// A fault is latched.
        fault_active: bool,
    },
    /// Drive to host, about 10 Hz.
    Heartbeat {
        /// Drive state.
        state: DriveState,
        /// Latched faults.
        fault_flags: FaultFlags,
        /// Heartbeat counter, wraps.
        counter: u8,
        /// Torque commands dropped for a bad CRC (saturates at 255).
        crc_errors: u8,
        /// Frames dropped for a wrong DLC (saturates at 255).
        length_errors: u8,
        /// Torque commands dropped as stale or repeated (saturates at 255).
        sequence_errors: u8,
        /// Frames for this node with an id it does not know (saturates).
        unknown_ids: u8,
        /// Torque commands beyond the drive's torque limit, rejected
        /// (saturates at 255).
        range_errors: u8,
    },
    /// Host to drive: enable (arms the watchdog) or disable.
    SetState {
        /// `true`: request ENABLED; `false`: request DISABLED.
        enable: bool,
        /// Command watchdog period, ms (`SetState.watchdog_ms`'s range).
        watchdog_ms: u16,
        /// The sequence of the next TorqueCommand the drive accepts (resync).
        sequence: u8,
    },
    /// Host to drive: zero torque now, latch FAULT (EMERGENCY_STOP).
    EmergencyStop,
    /// Host to drive: clear latched faults, go to DISABLED.
    ClearFaults,
    /// Drive to host, on every change of state or fault flags.
    Fault {
        /// Drive state.
        state: DriveState,
        /// Latched faults.
        fault_flags: FaultFlags,
        /// Fault frame counter, wraps.
        counter: u8,
    },
}

impl Message {
    /// Which frame this message travels in.
    pub const fn kind(&self) -> MessageKind {
        match self {
            Self::TorqueCommand { .. } => MessageKind::TorqueCommand,
            Self::Feedback { .. } => MessageKind::Feedback,
            Self::Heartbeat { .. } => MessageKind::Heartbeat,
            Self::SetState { .. } => MessageKind::SetState,
            Self::EmergencyStop => MessageKind::EmergencyStop,
            Self::ClearFaults => MessageKind::ClearFaults,
            Self::Fault { .. } => MessageKind::Fault,
        }
    }
}

// ------------------------------------------------------------------ errors

/// A message that cannot be encoded.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum EncodeError {
    /// NaN or infinite.
    NotFinite {
        /// `Message.signal`, as in the DBC.
        signal: &'static str,
        /// The value given.
        value: f64,
    },
    /// Outside the DBC's `[min|max]`.
    OutOfRange {
        /// `Message.signal`, as in the DBC.
        signal: &'static str,
        /// The value given.
        value: f64,
        /// Smallest allowed.
        min: f64,
        /// Largest allowed.
        max: f64,
    },
}

impl fmt::Display for EncodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Self::NotFinite { signal, value } => {
                write!(f, "{signal}: must be finite, got {value}")
            }
            Self::OutOfRange {
                signal,
                value,
                min,
                max,
            } => write!(f, "{signal}: must be in [{min}, {max}], got {value}"),
        }
    }
}

impl std::error::Error for EncodeError {}

/// A frame that is not a valid message for this node.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DecodeError {
    /// The id is not one of this node's (or any node's) ids, or the frame
    /// is not a standard data frame.
    UnknownId {
        /// The frame's `can_id` (with the kernel's EFF/RTR/ERR flag bits).
        id: u32,
    },
    /// The DLC differs from the DBC's.
    WrongLength {
        /// The DBC message name.
        message: &'static str,
        /// The DBC's DLC.
        expected: u8,
        /// The frame's DLC.
        got: u8,
    },
    /// The TorqueCommand's CRC-16 does not match its bytes 0..=5 and data
    /// id (the frame's id: a command for another node or message fails).
    BadCrc {
        /// [`torque_command_crc`] of the frame.
        expected: u16,
        /// Bytes 6..8.
        got: u16,
    },
    /// A raw value outside its defined set (state > 3, request > 1,
    /// watchdog_ms 0, non-zero reserved bytes of a TorqueCommand).
    InvalidValue {
        /// `Message.signal`, as in the DBC.
        signal: &'static str,
        /// The raw value.
        raw: u32,
    },
}

impl fmt::Display for DecodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Self::UnknownId { id } => write!(
                f,
                "unknown CAN id {id:#05x} for this node (the protocol uses standard data frames)"
            ),
            Self::WrongLength {
                message,
                expected,
                got,
            } => write!(f, "{message}: DLC must be {expected}, got {got}"),
            Self::BadCrc { expected, got } => write!(
                f,
                "TorqueCommand.crc16: bytes 0..=5 and the data id give {expected:#06x}, frame has {got:#06x}"
            ),
            Self::InvalidValue { signal, raw } => write!(f, "{signal}: invalid raw value {raw}"),
        }
    }
}

impl std::error::Error for DecodeError {}

// -------------------------------------------------------------- sequences

/// Whether `next` is newer than `prev` on the wrapping u8 sequence.
///
/// Window: `next` is newer iff `next - prev (mod 256)` is in `1..=127`.
/// `0` is a repeat; `128..=255` is older. For a host telling a late
/// `Feedback` from a new one; the drive is stricter and accepts only the
/// exact next `TorqueCommand` sequence ([`CommandGate`]).
pub const fn seq_is_newer(prev: u8, next: u8) -> bool {
    let d = next.wrapping_sub(prev);
    d >= 1 && d <= 127
}

// ------------------------------------------------------- the drive's gate

/// Why the drive does not apply a TorqueCommand ([`CommandGate::admit`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Rejection {
    /// Not a valid TorqueCommand for this node (id, DLC, CRC with data id,
    /// reserved bits, DBC range); counted as a CRC, length or unknown-id error.
    Decode(DecodeError),
    /// A valid protocol frame, but not a TorqueCommand.
    NotACommand,
    /// The drive is not enabled (no sequence to expect).
    NotEnabled,
    /// Valid, but not the expected sequence: the drive latches
    /// FAULT(SEQUENCE) (a second command source, or a lost command).
    Sequence {
        /// The only sequence the drive accepts now.
        expected: u8,
        /// The frame's.
        got: u8,
    },
    /// Valid and in sequence, but beyond the drive's torque limit: rejected
    /// and counted (`range_errors`), never clamped. The sequence is consumed.
    Range {
        /// The commanded torque.
        torque_nm: f64,
        /// The drive's limit.
        limit_nm: f64,
    },
}

/// The drive's acceptance rules for TorqueCommands, as the Hi5 drive (and
/// `sensaug_bridge.virtual_hi5`) apply them:
///
/// 1. the frame decodes for this node (CRC-16 with the frame id as data
///    id, reserved bits zero, torque within the DBC range);
/// 2. the drive is enabled;
/// 3. `sequence` is exactly the expected one: `SetState.sequence` after an
///    enable (the resync), then one more than the last accepted. Anything
///    else latches FAULT(SEQUENCE) and disables the gate;
/// 4. `|torque| <= limit`, else rejected and counted, never clamped.
///
/// Allocation-free; the drive calls [`CommandGate::resync`] on SetState
/// enable and [`CommandGate::disable`] on disable or any fault.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CommandGate {
    node: NodeId,
    limit_nm: f64,
    expected: Option<u8>,
}

impl CommandGate {
    /// A disabled gate for `node` with the drive's torque limit (N m).
    pub const fn new(node: NodeId, limit_nm: f64) -> Self {
        Self {
            node,
            limit_nm,
            expected: None,
        }
    }

    /// Enable (or resync): the next accepted command must carry `sequence`.
    pub fn resync(&mut self, sequence: u8) {
        self.expected = Some(sequence);
    }

    /// Disable: no command is accepted until the next resync.
    pub fn disable(&mut self) {
        self.expected = None;
    }

    /// The sequence the next command must carry, if enabled.
    pub const fn expected(&self) -> Option<u8> {
        self.expected
    }

    /// The torque to apply, or why not (see the type's rules).
    pub fn admit(&mut self, frame: &Frame) -> Result<f64, Rejection> {
        let (torque_nm, sequence) = match decode(self.node, frame) {
            Ok(Message::TorqueCommand {
                torque_nm,
                sequence,
            }) => (torque_nm, sequence),
            Ok(_) => return Err(Rejection::NotACommand),
            Err(e) => return Err(Rejection::Decode(e)),
        };
        let expected = self.expected.ok_or(Rejection::NotEnabled)?;
        if sequence != expected {
            self.expected = None;
            return Err(Rejection::Sequence {
                expected,
                got: sequence,
            });
        }
        self.expected = Some(sequence.wrapping_add(1));
        if torque_nm.abs() > self.limit_nm {
            return Err(Rejection::Range {
                torque_nm,
                limit_nm: self.limit_nm,
            });
        }
        Ok(torque_nm)
    }
}

// ------------------------------------------------------------------ CRC-16

const CRC16: crc::Crc<u16> = crc::Crc::<u16>::new(&crc::CRC_16_IBM_3740);

/// CRC-16/IBM-3740 (a.k.a. CCITT-FALSE, AUTOSAR E2E's CRC-16): poly 0x1021,
/// init 0xFFFF, no reflection, xorout 0 (check value over `b"123456789"`
/// is 0x29B1).
pub fn crc16_ibm_3740(bytes: &[u8]) -> u16 {
    CRC16.checksum(bytes)
}

/// The TorqueCommand's `crc16`, in the spirit of an AUTOSAR E2E data id:
/// `crc16 = CRC-16/IBM-3740(payload[..6] ++ id_le16)`, with `id` the
/// frame's 11-bit CAN id (not sent). A frame meant for another node, or
/// another message's bytes, fails the check.
pub fn torque_command_crc(id: u32, payload: &[u8]) -> u16 {
    let mut digest = CRC16.digest();
    digest.update(payload);
    // The 11-bit id fits in u16.
    digest.update(&(id as u16).to_le_bytes());
    digest.finalize()
}

// ------------------------------------------------------------ encode/decode

// The Rust field types must hold the DBC's fields; a DBC change that breaks
// this fails to compile here instead of truncating.
const _: () = {
    use dbc::{feedback as fb, heartbeat as hb, set_state as ss, torque_command as tc};
    assert!(tc::SEQUENCE.is_unsigned(8) && fb::SEQUENCE.is_unsigned(8));
    assert!(tc::CRC16.is_unsigned(16) && tc::CRC16.start_bit % 8 == 0);
    assert!(ss::SEQUENCE.is_unsigned(8) && hb::RANGE_ERRORS.is_unsigned(8));
    assert!(hb::COUNTER.is_unsigned(8) && dbc::fault::COUNTER.is_unsigned(8));
    assert!(hb::FAULT_FLAGS.bits <= 16 && dbc::fault::FAULT_FLAGS.bits <= 16);
    assert!(hb::CRC_ERRORS.is_unsigned(8) && hb::LENGTH_ERRORS.is_unsigned(8));
    assert!(hb::SEQUENCE_ERRORS.is_unsigned(8) && hb::UNKNOWN_IDS.is_unsigned(8));
    assert!(hb::STATE.bits <= 8 && dbc::fault::STATE.bits <= 8 && fb::STATE.bits <= 8);
    assert!(fb::TORQUE_LIMITED.is_unsigned(1) && fb::FAULT_ACTIVE.is_unsigned(1));
    assert!(ss::REQUEST.bits <= 8 && ss::WATCHDOG_MS.is_unsigned(16));
    assert!(MessageKind::ALL.len() == dbc::MESSAGES.len());
};

/// Encode `msg` as the frame for `node`.
///
/// Errors name the signal of a value that is not finite or outside the
/// DBC's range; nothing is clamped or wrapped. Bits no signal covers are 0.
pub fn encode(node: NodeId, msg: &Message) -> Result<Frame, EncodeError> {
    let kind = msg.kind();
    let mut d = [0u8; 8];
    match *msg {
        Message::TorqueCommand {
            torque_nm,
            sequence,
        } => encode_torque_command(&mut d, kind.id(node), torque_nm, sequence)?,
        Message::Feedback {
            position_rad,
            velocity_rad_s,
            sequence,
            state,
            torque_limited,
            fault_active,
        } => {
            use dbc::feedback::{
                FAULT_ACTIVE, POSITION, SEQUENCE, STATE, TORQUE_LIMITED, VELOCITY,
            };
            put(&mut d, &POSITION, position_rad)?;
            put(&mut d, &VELOCITY, velocity_rad_s)?;
            put(&mut d, &SEQUENCE, f64::from(sequence))?;
            put(&mut d, &STATE, f64::from(state.raw()))?;
            put(&mut d, &TORQUE_LIMITED, f64::from(u8::from(torque_limited)))?;
            put(&mut d, &FAULT_ACTIVE, f64::from(u8::from(fault_active)))?;
        }
        Message::Heartbeat {
            state,
            fault_flags,
            counter,
            crc_errors,
            length_errors,
            sequence_errors,
            unknown_ids,
            range_errors,
        } => {
            use dbc::heartbeat::{
                COUNTER, CRC_ERRORS, FAULT_FLAGS, LENGTH_ERRORS, RANGE_ERRORS, SEQUENCE_ERRORS,
                STATE, UNKNOWN_IDS,
            };
            put(&mut d, &STATE, f64::from(state.raw()))?;
            put(&mut d, &FAULT_FLAGS, f64::from(fault_flags.bits()))?;
            put(&mut d, &COUNTER, f64::from(counter))?;
            put(&mut d, &CRC_ERRORS, f64::from(crc_errors))?;
            put(&mut d, &LENGTH_ERRORS, f64::from(length_errors))?;
            put(&mut d, &SEQUENCE_ERRORS, f64::from(sequence_errors))?;
            put(&mut d, &UNKNOWN_IDS, f64::from(unknown_ids))?;
            put(&mut d, &RANGE_ERRORS, f64::from(range_errors))?;
        }
        Message::SetState {
            enable,
            watchdog_ms,
            sequence,
        } => {
            use dbc::set_state::{REQUEST, SEQUENCE, WATCHDOG_MS};
            let request = if enable {
                dbc::request_values::ENABLE
            } else {
                dbc::request_values::DISABLE
            };
            put(&mut d, &REQUEST, f64::from(request))?;
            put(&mut d, &WATCHDOG_MS, f64::from(watchdog_ms))?;
            put(&mut d, &SEQUENCE, f64::from(sequence))?;
        }
        Message::EmergencyStop | Message::ClearFaults => {}
        Message::Fault {
            state,
            fault_flags,
            counter,
        } => {
            use dbc::fault::{COUNTER, FAULT_FLAGS, STATE};
            put(&mut d, &STATE, f64::from(state.raw()))?;
            put(&mut d, &FAULT_FLAGS, f64::from(fault_flags.bits()))?;
            put(&mut d, &COUNTER, f64::from(counter))?;
        }
    }
    Ok(Frame {
        id: kind.id(node),
        len: kind.dlc(),
        data: d,
        ..Frame::default()
    })
}

/// Decode `frame` as a message to or from `node`.
///
/// A frame of another node, and any frame but a standard data frame, is
/// [`DecodeError::UnknownId`].
pub fn decode(node: NodeId, frame: &Frame) -> Result<Message, DecodeError> {
    match decode_any(frame)? {
        (n, msg) if n == node => Ok(msg),
        _ => Err(DecodeError::UnknownId { id: frame.id }),
    }
}

/// Decode `frame` for whichever node its id belongs to (bus monitors,
/// simulators of several drives).
///
/// Every signal's raw value must lie in the DBC's `[min|max]`
/// ([`DecodeError::InvalidValue`] otherwise: state > 3, request > 1,
/// watchdog_ms 0); bits no signal covers are ignored (as cantools does),
/// except in a TorqueCommand, where they must be 0.
pub fn decode_any(frame: &Frame) -> Result<(NodeId, Message), DecodeError> {
    // Extended, remote and error frames are not the protocol's, whatever
    // their id: reported with the kernel's flag bits in the id.
    let unknown = DecodeError::UnknownId { id: frame.can_id() };
    if !frame.is_standard_data() {
        return Err(unknown);
    }
    let (kind, node) = MessageKind::from_id(frame.id).ok_or(unknown)?;
    if frame.len != kind.dlc() {
        return Err(DecodeError::WrongLength {
            message: kind.name(),
            expected: kind.dlc(),
            got: frame.len,
        });
    }
    let d = &frame.data;
    let msg = match kind {
        MessageKind::TorqueCommand => decode_torque_command(frame.id, d)?,
        MessageKind::Feedback => {
            use dbc::feedback::{
                FAULT_ACTIVE, POSITION, SEQUENCE, STATE, TORQUE_LIMITED, VELOCITY,
            };
            Message::Feedback {
                position_rad: POSITION.physical(get(d, &POSITION)?),
                velocity_rad_s: VELOCITY.physical(get(d, &VELOCITY)?),
                sequence: get(d, &SEQUENCE)? as u8,
                state: get_state(d, &STATE)?,
                torque_limited: get(d, &TORQUE_LIMITED)? != 0,
                fault_active: get(d, &FAULT_ACTIVE)? != 0,
            }
        }
        MessageKind::Heartbeat => {
            use dbc::heartbeat::{
                COUNTER, CRC_ERRORS, FAULT_FLAGS, LENGTH_ERRORS, RANGE_ERRORS, SEQUENCE_ERRORS,
                STATE, UNKNOWN_IDS,
            };
            Message::Heartbeat {
                state: get_state(d, &STATE)?,
                fault_flags: FaultFlags::from_bits_retain(get(d, &FAULT_FLAGS)? as u16),
                counter: get(d, &COUNTER)? as u8,
                crc_errors: get(d, &CRC_ERRORS)? as u8,
                length_errors: get(d, &LENGTH_ERRORS)? as u8,
                sequence_errors: get(d, &SEQUENCE_ERRORS)? as u8,
                unknown_ids: get(d, &UNKNOWN_IDS)? as u8,
                range_errors: get(d, &RANGE_ERRORS)? as u8,
            }
        }
        MessageKind::SetState => {
            use dbc::set_state::{REQUEST, SEQUENCE, WATCHDOG_MS};
            let request = get(d, &REQUEST)?;
            Message::SetState {
                enable: request == i64::from(dbc::request_values::ENABLE),
                watchdog_ms: get(d, &WATCHDOG_MS)? as u16,
                sequence: get(d, &SEQUENCE)? as u8,
            }
        }
        MessageKind::EmergencyStop => Message::EmergencyStop,
        MessageKind::ClearFaults => Message::ClearFaults,
        MessageKind::Fault => {
            use dbc::fault::{COUNTER, FAULT_FLAGS, STATE};
            Message::Fault {
                state: get_state(d, &STATE)?,
                fault_flags: FaultFlags::from_bits_retain(get(d, &FAULT_FLAGS)? as u16),
                counter: get(d, &COUNTER)? as u8,
            }
        }
    };
    Ok((node, msg))
}

// ------------------------------------------------------- scaling helpers

/// Physical value to raw integer, cantools' way: reject non-finite values
/// and values outside `[min - 1e-6 |scale|, max + 1e-6 |scale|]`, then
/// `raw = round_ties_even((value - offset) / scale)`, then refuse anything
/// the field cannot hold ([`SignalDef::raw_range`]).
fn to_raw(sig: &SignalDef, value: f64) -> Result<i64, EncodeError> {
    let signal = sig.name;
    if !value.is_finite() {
        return Err(EncodeError::NotFinite { signal, value });
    }
    let (min, max) = (sig.min, sig.max);
    let tol = sig.scale.abs() * 1e-6;
    let out_of_range = EncodeError::OutOfRange {
        signal,
        value,
        min,
        max,
    };
    if value < min - tol || value > max + tol {
        return Err(out_of_range);
    }
    let raw = ((value - sig.offset) / sig.scale).round_ties_even();
    let (raw_min, raw_max) = sig.raw_range();
    // Exact: |raw| < 2^53 here, and the bounds (at most 32 bits) are exact in f64.
    if raw < raw_min as f64 || raw > raw_max as f64 {
        return Err(out_of_range);
    }
    Ok(raw as i64)
}

/// Encode `value` (physical) into `sig`'s bits of `d`.
fn put(d: &mut [u8; 8], sig: &SignalDef, value: f64) -> Result<(), EncodeError> {
    sig.put(d, to_raw(sig, value)?);
    Ok(())
}

/// `sig`'s raw value in `d`, if its physical value is in the DBC's
/// `[min|max]`.
fn get(d: &[u8; 8], sig: &SignalDef) -> Result<i64, DecodeError> {
    let raw = sig.get(d);
    let value = sig.physical(raw);
    let tol = sig.scale.abs() * 1e-6;
    if value < sig.min - tol || value > sig.max + tol {
        return Err(DecodeError::InvalidValue {
            signal: sig.name,
            raw: raw as u32,
        });
    }
    Ok(raw)
}

/// A `state` signal as a [`DriveState`].
fn get_state(d: &[u8; 8], sig: &SignalDef) -> Result<DriveState, DecodeError> {
    let raw = get(d, sig)?;
    DriveState::from_raw(raw as u8).ok_or(DecodeError::InvalidValue {
        signal: sig.name,
        raw: raw as u32,
    })
}

/// Scale of `TorqueCommand.torque`, N m per LSB.
pub const TORQUE_SCALE_NM: f64 = dbc::torque_command::TORQUE.scale;
/// Scale of `Feedback.position`, rad per LSB.
pub const POSITION_SCALE_RAD: f64 = dbc::feedback::POSITION.scale;
/// Scale of `Feedback.velocity`, rad/s per LSB.
pub const VELOCITY_SCALE_RAD_S: f64 = dbc::feedback::VELOCITY.scale;

/// TorqueCommand: `torque`, `sequence`, and `crc16` =
/// [`torque_command_crc`] of the bytes before it and the frame's `id`; the
/// bits no signal covers are 0.
fn encode_torque_command(
    d: &mut [u8; 8],
    id: u32,
    torque_nm: f64,
    sequence: u8,
) -> Result<(), EncodeError> {
    use dbc::torque_command::{CRC16, SEQUENCE, TORQUE};
    put(d, &TORQUE, torque_nm)?;
    put(d, &SEQUENCE, f64::from(sequence))?;
    let covered = usize::from(CRC16.start_bit / 8);
    CRC16.put(d, i64::from(torque_command_crc(id, &d[..covered])));
    Ok(())
}

/// Inverse of [`encode_torque_command`]: checks the CRC (with the frame's
/// `id` as data id) first, then that the bits no signal covers
/// (`TorqueCommand.reserved`) are zero, then the torque's DBC range.
fn decode_torque_command(id: u32, d: &[u8; 8]) -> Result<Message, DecodeError> {
    use dbc::torque_command::{CRC16, MESSAGE, SEQUENCE, TORQUE};
    let covered = usize::from(CRC16.start_bit / 8);
    let expected = torque_command_crc(id, &d[..covered]);
    let got = CRC16.get(d) as u16;
    if got != expected {
        return Err(DecodeError::BadCrc { expected, got });
    }
    let unused = MESSAGE.unused_bits();
    let reserved = u64::from_le_bytes(*d) & unused;
    if reserved != 0 {
        return Err(DecodeError::InvalidValue {
            signal: "TorqueCommand.reserved",
            raw: (reserved >> unused.trailing_zeros()) as u32,
        });
    }
    Ok(Message::TorqueCommand {
        torque_nm: TORQUE.physical(get(d, &TORQUE)?),
        sequence: get(d, &SEQUENCE)? as u8,
    })
}
