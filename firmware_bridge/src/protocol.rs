//! The Hi5 drive protocol: `hi5.dbc` as Rust types, encode and decode.
//!
//! `firmware_bridge/hi5.dbc` is the single source of truth; this module
//! mirrors it by hand and the golden vectors (`golden/frames.json`, made by
//! cantools from the DBC) check that it does, byte for byte.
//!
//! Ids: the DBC lists node 1's ids. Node `n` (0..=15) uses `base + n` with the
//! bases in [`MessageKind::base_id`]. Signals are little-endian (Intel).
//!
//! Physical to raw: `raw = round_ties_even(value / scale)`, exactly what
//! cantools does (Python's `round` is ties-to-even), after a range check
//! against the DBC's `[min|max]` with cantools' tolerance of `1e-6` LSB.
//! Nothing wraps: a value out of range or not finite is an [`EncodeError`]
//! naming the signal. Raw to physical: `raw * scale`.
//!
//! Nothing here allocates.

use core::fmt;

use crate::frame::Frame;

// ---------------------------------------------------------------- node ids

/// A drive's node id, 0..=15.
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
        write!(f, "node id must be in 0..=15, got {}", self.got)
    }
}

impl std::error::Error for InvalidNodeId {}

impl NodeId {
    /// Largest node id.
    pub const MAX: u8 = 15;

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
    /// Every kind, in id order.
    pub const ALL: [Self; 7] = [
        Self::EmergencyStop,
        Self::Fault,
        Self::TorqueCommand,
        Self::Feedback,
        Self::SetState,
        Self::ClearFaults,
        Self::Heartbeat,
    ];

    /// The id for node 0; node `n` uses `base_id() + n`.
    pub const fn base_id(self) -> u32 {
        match self {
            Self::EmergencyStop => 0x010,
            Self::Fault => 0x080,
            Self::TorqueCommand => 0x200,
            Self::Feedback => 0x280,
            Self::SetState => 0x300,
            Self::ClearFaults => 0x320,
            Self::Heartbeat => 0x700,
        }
    }

    /// The DLC the DBC gives.
    pub const fn dlc(self) -> u8 {
        match self {
            Self::EmergencyStop | Self::ClearFaults => 0,
            Self::Fault | Self::SetState => 4,
            Self::TorqueCommand | Self::Feedback | Self::Heartbeat => 8,
        }
    }

    /// The DBC's message name.
    pub const fn name(self) -> &'static str {
        match self {
            Self::EmergencyStop => "EmergencyStop",
            Self::Fault => "Fault",
            Self::TorqueCommand => "TorqueCommand",
            Self::Feedback => "Feedback",
            Self::SetState => "SetState",
            Self::ClearFaults => "ClearFaults",
            Self::Heartbeat => "Heartbeat",
        }
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
    /// 0: powering up.
    Boot = 0,
    /// 1: ready, torque off.
    Disabled = 1,
    /// 2: following torque commands, watchdog armed.
    Enabled = 2,
    /// 3: torque off, a fault latched until `ClearFaults`.
    Fault = 3,
}

impl DriveState {
    /// The state with raw value `raw`, if 0..=3.
    pub const fn from_raw(raw: u8) -> Option<Self> {
        match raw {
            0 => Some(Self::Boot),
            1 => Some(Self::Disabled),
            2 => Some(Self::Enabled),
            3 => Some(Self::Fault),
            _ => None,
        }
    }

    /// The raw value, 0..=3.
    pub const fn raw(self) -> u8 {
        self as u8
    }
}

/// The drive's latched fault bits (16-bit field; bits 4..=15 are reserved
/// and kept as received, not dropped).
#[derive(Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct FaultFlags(u16);

impl FaultFlags {
    /// Bit 0: no `TorqueCommand` within the watchdog period.
    pub const WATCHDOG: Self = Self(1 << 0);
    /// Bit 1: an `EmergencyStop` frame was received.
    pub const EMERGENCY_STOP: Self = Self(1 << 1);
    /// Bit 2: the motor exceeded its speed limit.
    pub const OVERSPEED: Self = Self(1 << 2);
    /// Bit 3: the drive's own self-check failed.
    pub const INTERNAL: Self = Self(1 << 3);

    const NAMED: [(Self, &'static str); 4] = [
        (Self::WATCHDOG, "WATCHDOG"),
        (Self::EMERGENCY_STOP, "EMERGENCY_STOP"),
        (Self::OVERSPEED, "OVERSPEED"),
        (Self::INTERNAL, "INTERNAL"),
    ];

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
        for (flag, name) in Self::NAMED {
            if self.contains(flag) {
                write!(f, "{}{name}", if first { "" } else { " | " })?;
                rest &= !flag.0;
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
        /// Motor torque; int32 x 1e-6 N m, range +-2147.48 N m.
        torque_nm: f64,
        /// Command counter, echoed in `Feedback`.
        sequence: u8,
    },
    /// Drive to host, one per accepted torque command.
    Feedback {
        /// Motor position; int32 x 1e-7 rad, range +-214.748 rad.
        position_rad: f64,
        /// Motor velocity; int16 x 0.002 rad/s, range -65.536..=65.534 rad/s.
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
    },
    /// Host to drive: enable (arms the watchdog) or disable.
    SetState {
        /// `true`: request ENABLED; `false`: request DISABLED.
        enable: bool,
        /// Command watchdog period, 1..=65535 ms.
        watchdog_ms: u16,
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
    /// The id is not one of this node's (or any node's) ids.
    UnknownId {
        /// The frame's id.
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
    /// The TorqueCommand's CRC-8 does not match bytes 0..=6.
    BadCrc {
        /// CRC-8/SAE-J1850 of bytes 0..=6.
        expected: u8,
        /// Byte 7.
        got: u8,
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
            Self::UnknownId { id } => write!(f, "unknown CAN id {id:#05x} for this node"),
            Self::WrongLength {
                message,
                expected,
                got,
            } => write!(f, "{message}: DLC must be {expected}, got {got}"),
            Self::BadCrc { expected, got } => write!(
                f,
                "TorqueCommand.crc8: bytes 0..=6 give {expected:#04x}, frame has {got:#04x}"
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
/// `0` is a repeat; `128..=255` is older (or more than 127 frames were
/// lost, which at 1 kHz is 128 ms: longer than any sane watchdog, so the
/// drive has faulted anyway). The drive accepts a `TorqueCommand` only if
/// its sequence is newer than the last accepted one; the host accepts a
/// `Feedback` only if newer than the last one it saw.
pub const fn seq_is_newer(prev: u8, next: u8) -> bool {
    let d = next.wrapping_sub(prev);
    d >= 1 && d <= 127
}

// ------------------------------------------------------------------- CRC-8

const CRC8: crc::Crc<u8> = crc::Crc::<u8>::new(&crc::CRC_8_SAE_J1850);

/// CRC-8/SAE-J1850: poly 0x1D, init 0xFF, xorout 0xFF, no reflection
/// (check value over `b"123456789"` is 0x4B).
pub fn crc8_sae_j1850(bytes: &[u8]) -> u8 {
    CRC8.checksum(bytes)
}

// ------------------------------------------------------------ encode/decode

/// Encode `msg` as the frame for `node`.
///
/// Errors name the signal of a value that is not finite or outside the
/// DBC's range; nothing is clamped or wrapped.
pub fn encode(node: NodeId, msg: &Message) -> Result<Frame, EncodeError> {
    let id = msg.kind().id(node);
    let (len, data) = match *msg {
        Message::TorqueCommand {
            torque_nm,
            sequence,
        } => (8, encode_torque_command(torque_nm, sequence)?),
        Message::Feedback {
            position_rad,
            velocity_rad_s,
            sequence,
            state,
            torque_limited,
            fault_active,
        } => (
            8,
            encode_feedback(
                position_rad,
                velocity_rad_s,
                sequence,
                state,
                torque_limited,
                fault_active,
            )?,
        ),
        Message::Heartbeat {
            state,
            fault_flags,
            counter,
            crc_errors,
            length_errors,
            sequence_errors,
            unknown_ids,
        } => (
            8,
            encode_heartbeat(
                state,
                fault_flags,
                counter,
                [crc_errors, length_errors, sequence_errors, unknown_ids],
            ),
        ),
        Message::SetState {
            enable,
            watchdog_ms,
        } => (4, encode_set_state(enable, watchdog_ms)?),
        Message::EmergencyStop | Message::ClearFaults => (0, [0; 8]),
        Message::Fault {
            state,
            fault_flags,
            counter,
        } => (4, encode_fault(state, fault_flags, counter)),
    };
    Ok(Frame { id, len, data })
}

/// Decode `frame` as a message to or from `node`.
///
/// A frame of another node is [`DecodeError::UnknownId`].
pub fn decode(node: NodeId, frame: &Frame) -> Result<Message, DecodeError> {
    match decode_any(frame)? {
        (n, msg) if n == node => Ok(msg),
        _ => Err(DecodeError::UnknownId { id: frame.id }),
    }
}

/// Decode `frame` for whichever node its id belongs to (bus monitors,
/// simulators of several drives).
pub fn decode_any(frame: &Frame) -> Result<(NodeId, Message), DecodeError> {
    let (kind, node) =
        MessageKind::from_id(frame.id).ok_or(DecodeError::UnknownId { id: frame.id })?;
    if frame.len != kind.dlc() {
        return Err(DecodeError::WrongLength {
            message: kind.name(),
            expected: kind.dlc(),
            got: frame.len,
        });
    }
    let d = &frame.data;
    let msg = match kind {
        MessageKind::TorqueCommand => decode_torque_command(d)?,
        MessageKind::Feedback => decode_feedback(d),
        MessageKind::Heartbeat => decode_heartbeat(d)?,
        MessageKind::SetState => decode_set_state(d)?,
        MessageKind::EmergencyStop => Message::EmergencyStop,
        MessageKind::ClearFaults => Message::ClearFaults,
        MessageKind::Fault => decode_fault(d)?,
    };
    Ok((node, msg))
}

// ------------------------------------------------------- scaling helpers

/// Scaled value to raw integer, cantools' way: reject non-finite values and
/// values outside `[min - 1e-6 |scale|, max + 1e-6 |scale|]`, then
/// `round_ties_even(value / scale)`, then refuse anything the raw type
/// cannot hold (`raw_min..=raw_max`).
fn to_raw(
    signal: &'static str,
    value: f64,
    scale: f64,
    (min, max): (f64, f64),
    (raw_min, raw_max): (i64, i64),
) -> Result<i64, EncodeError> {
    if !value.is_finite() {
        return Err(EncodeError::NotFinite { signal, value });
    }
    let tol = scale.abs() * 1e-6;
    let out_of_range = EncodeError::OutOfRange {
        signal,
        value,
        min,
        max,
    };
    if value < min - tol || value > max + tol {
        return Err(out_of_range);
    }
    let raw = (value / scale).round_ties_even();
    // Exact: |raw| < 2^53 here, and the bounds are exact in f64.
    if raw < raw_min as f64 || raw > raw_max as f64 {
        return Err(out_of_range);
    }
    Ok(raw as i64)
}

/// Integer signal (scale 1) with a range narrower than its type.
fn check_int(signal: &'static str, value: u32, min: u32, max: u32) -> Result<(), EncodeError> {
    if value < min || value > max {
        return Err(EncodeError::OutOfRange {
            signal,
            value: f64::from(value),
            min: f64::from(min),
            max: f64::from(max),
        });
    }
    Ok(())
}

/// Scale of `TorqueCommand.torque`, N m per LSB.
pub const TORQUE_SCALE_NM: f64 = 1e-6;
/// Scale of `Feedback.position`, rad per LSB.
pub const POSITION_SCALE_RAD: f64 = 1e-6;
/// Scale of `Feedback.velocity`, rad/s per LSB.
pub const VELOCITY_SCALE_RAD_S: f64 = 1e-6;

const TORQUE_RANGE: (f64, f64) = (-2147.483648, 2147.483647);
const POSITION_RANGE: (f64, f64) = (-8.388608, 8.388607);
const VELOCITY_RANGE: (f64, f64) = (-8.388608, 8.388607);
const I32_RANGE: (i64, i64) = (i32::MIN as i64, i32::MAX as i64);
const I24_RANGE: (i64, i64) = (-(1 << 23), (1 << 23) - 1);

/// The low three bytes of `raw` (in `I24_RANGE`), little-endian.
fn i24_to_le(raw: i32) -> [u8; 3] {
    let b = raw.to_le_bytes();
    [b[0], b[1], b[2]]
}

/// A little-endian two's-complement 24-bit integer, sign-extended.
fn i24_from_le(b: [u8; 3]) -> i32 {
    i32::from_le_bytes([b[0], b[1], b[2], 0]) << 8 >> 8
}

/// TorqueCommand (DLC 8):
/// bytes 0..4 `torque` int32 LE, raw = torque_nm / 1e-6 (1 uN m per LSB,
/// -2147.483648..=2147.483647 N m); byte 4 `sequence`; bytes 5, 6 zero;
/// byte 7 `crc8` = CRC-8/SAE-J1850 of bytes 0..=6.
fn encode_torque_command(torque_nm: f64, sequence: u8) -> Result<[u8; 8], EncodeError> {
    let raw = to_raw(
        "TorqueCommand.torque",
        torque_nm,
        TORQUE_SCALE_NM,
        TORQUE_RANGE,
        I32_RANGE,
    )? as i32;
    let mut d = [0u8; 8];
    d[0..4].copy_from_slice(&raw.to_le_bytes());
    d[4] = sequence;
    d[7] = crc8_sae_j1850(&d[0..7]);
    Ok(d)
}

/// Inverse of [`encode_torque_command`]: torque_nm = raw x 1e-6; checks
/// the CRC first, then that bytes 5, 6 are zero.
fn decode_torque_command(d: &[u8; 8]) -> Result<Message, DecodeError> {
    let expected = crc8_sae_j1850(&d[0..7]);
    if d[7] != expected {
        return Err(DecodeError::BadCrc {
            expected,
            got: d[7],
        });
    }
    if d[5] != 0 || d[6] != 0 {
        return Err(DecodeError::InvalidValue {
            signal: "TorqueCommand.reserved",
            raw: u32::from(u16::from_le_bytes([d[5], d[6]])),
        });
    }
    let raw = i32::from_le_bytes([d[0], d[1], d[2], d[3]]);
    Ok(Message::TorqueCommand {
        torque_nm: f64::from(raw) * TORQUE_SCALE_NM,
        sequence: d[4],
    })
}

/// Feedback (DLC 8):
/// bytes 0..3 `position` int24 LE, raw = position_rad / 1e-6 (1 urad per
/// LSB, -8.388608..=8.388607 rad); bytes 3..6 `velocity` int24 LE,
/// raw = velocity_rad_s / 1e-6 (1 urad/s per LSB, -8.388608..=8.388607 rad/s);
/// byte 6 `sequence`; byte 7 bits 0..2 `state`, bit 2 `torque_limited`,
/// bit 3 `fault_active`, bits 4..8 zero.
fn encode_feedback(
    position_rad: f64,
    velocity_rad_s: f64,
    sequence: u8,
    state: DriveState,
    torque_limited: bool,
    fault_active: bool,
) -> Result<[u8; 8], EncodeError> {
    let pos = to_raw(
        "Feedback.position",
        position_rad,
        POSITION_SCALE_RAD,
        POSITION_RANGE,
        I24_RANGE,
    )? as i32;
    let vel = to_raw(
        "Feedback.velocity",
        velocity_rad_s,
        VELOCITY_SCALE_RAD_S,
        VELOCITY_RANGE,
        I24_RANGE,
    )? as i32;
    let mut d = [0u8; 8];
    d[0..3].copy_from_slice(&i24_to_le(pos));
    d[3..6].copy_from_slice(&i24_to_le(vel));
    d[6] = sequence;
    d[7] = state.raw() | u8::from(torque_limited) << 2 | u8::from(fault_active) << 3;
    Ok(d)
}

/// Inverse of [`encode_feedback`]: position_rad = raw x 1e-6,
/// velocity_rad_s = raw x 1e-6. Bits 4..8 of byte 7 are not defined by
/// the DBC and are ignored (as cantools does).
fn decode_feedback(d: &[u8; 8]) -> Message {
    let pos = i24_from_le([d[0], d[1], d[2]]);
    let vel = i24_from_le([d[3], d[4], d[5]]);
    // Two bits hold exactly the four states.
    const STATES: [DriveState; 4] = [
        DriveState::Boot,
        DriveState::Disabled,
        DriveState::Enabled,
        DriveState::Fault,
    ];
    let state = STATES[usize::from(d[7] & 0b11)];
    Message::Feedback {
        position_rad: f64::from(pos) * POSITION_SCALE_RAD,
        velocity_rad_s: f64::from(vel) * VELOCITY_SCALE_RAD_S,
        sequence: d[6],
        state,
        torque_limited: d[7] & (1 << 2) != 0,
        fault_active: d[7] & (1 << 3) != 0,
    }
}

/// Heartbeat (DLC 8): byte 0 `state`; bytes 1..3 `fault_flags` u16 LE;
/// byte 3 `counter`; bytes 4..8 `crc_errors`, `length_errors`,
/// `sequence_errors`, `unknown_ids` (scale 1, saturating counters).
fn encode_heartbeat(
    state: DriveState,
    fault_flags: FaultFlags,
    counter: u8,
    errors: [u8; 4],
) -> [u8; 8] {
    let mut d = [0u8; 8];
    d[0..4].copy_from_slice(&encode_status(state, fault_flags, counter));
    d[4..8].copy_from_slice(&errors);
    d
}

/// Inverse of [`encode_heartbeat`]; `state` > 3 is invalid.
fn decode_heartbeat(d: &[u8; 8]) -> Result<Message, DecodeError> {
    let (state, fault_flags, counter) = decode_status("Heartbeat.state", d)?;
    Ok(Message::Heartbeat {
        state,
        fault_flags,
        counter,
        crc_errors: d[4],
        length_errors: d[5],
        sequence_errors: d[6],
        unknown_ids: d[7],
    })
}

/// Fault (DLC 4): byte 0 `state`; bytes 1..3 `fault_flags` u16 LE; byte 3
/// `counter`.
fn encode_fault(state: DriveState, fault_flags: FaultFlags, counter: u8) -> [u8; 8] {
    let mut d = [0u8; 8];
    d[0..4].copy_from_slice(&encode_status(state, fault_flags, counter));
    d
}

/// Inverse of [`encode_fault`]; `state` > 3 is invalid.
fn decode_fault(d: &[u8; 8]) -> Result<Message, DecodeError> {
    let (state, fault_flags, counter) = decode_status("Fault.state", d)?;
    Ok(Message::Fault {
        state,
        fault_flags,
        counter,
    })
}

/// The first four bytes Heartbeat and Fault share.
fn encode_status(state: DriveState, fault_flags: FaultFlags, counter: u8) -> [u8; 4] {
    let [f0, f1] = fault_flags.bits().to_le_bytes();
    [state.raw(), f0, f1, counter]
}

fn decode_status(
    state_signal: &'static str,
    d: &[u8; 8],
) -> Result<(DriveState, FaultFlags, u8), DecodeError> {
    let state = DriveState::from_raw(d[0]).ok_or(DecodeError::InvalidValue {
        signal: state_signal,
        raw: u32::from(d[0]),
    })?;
    let flags = FaultFlags::from_bits_retain(u16::from_le_bytes([d[1], d[2]]));
    Ok((state, flags, d[3]))
}

/// SetState (DLC 4): byte 0 `request` (0 DISABLE, 1 ENABLE); bytes 1..3
/// `watchdog_ms` u16 LE, 1..=65535 ms (0 would disarm the watchdog, so the
/// DBC forbids it).
fn encode_set_state(enable: bool, watchdog_ms: u16) -> Result<[u8; 8], EncodeError> {
    check_int("SetState.watchdog_ms", u32::from(watchdog_ms), 1, 65535)?;
    let mut d = [0u8; 8];
    d[0] = u8::from(enable);
    d[1..3].copy_from_slice(&watchdog_ms.to_le_bytes());
    Ok(d)
}

/// Inverse of [`encode_set_state`]; `request` > 1 and `watchdog_ms` 0 are
/// invalid.
fn decode_set_state(d: &[u8; 8]) -> Result<Message, DecodeError> {
    let enable = match d[0] {
        0 => false,
        1 => true,
        raw => {
            return Err(DecodeError::InvalidValue {
                signal: "SetState.request",
                raw: u32::from(raw),
            })
        }
    };
    let watchdog_ms = u16::from_le_bytes([d[1], d[2]]);
    if watchdog_ms == 0 {
        return Err(DecodeError::InvalidValue {
            signal: "SetState.watchdog_ms",
            raw: 0,
        });
    }
    Ok(Message::SetState {
        enable,
        watchdog_ms,
    })
}
