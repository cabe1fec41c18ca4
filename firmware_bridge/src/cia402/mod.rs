//! A CANopen master for one CiA 402 drive in cyclic synchronous torque mode.
//!
//! - [`od`]: the objects and COB-IDs used (the dictionary is
//!   `firmware_bridge/cia402_drive.eds`).
//! - [`frames`]: NMT, SYNC, heartbeat, expedited SDO, PDO and EMCY frames.
//! - [`state`]: statusword decoding and the controlword state machine.
//! - [`units`]: N m <-> per-mille of rated torque, increments <-> rad.
//! - [`master`]: set-up over SDO, enable, one RPDO + SYNC per tick, feedback
//!   from the TPDOs, EMCY and heartbeats, shut-down.
//!
//! Set-up ([`Master::boot`], [`Master::enable`]) may wait and uses the
//! transport's blocking receive; the per-tick calls ([`Master::tick`],
//! [`Master::drain`]) neither wait nor allocate (`tests/cia402_no_alloc.rs`).
//! The profile, its units and the measured numbers: `docs/cia402.md`.

use core::fmt;

use crate::transport::TransportError;

pub mod frames;
pub mod master;
pub mod od;
pub mod state;
pub mod units;

pub use frames::{Emcy, NmtCommand, NmtState, SdoResponse, Tpdo1, Tpdo2};
pub use master::{
    EmcyRecord, Feedback, Freshness, FreshnessSetting, Heard, Master, MasterSettings,
};
pub use od::{CanopenNode, Object};
pub use state::{DriveState, Goal};
pub use units::Units;

/// Everything that can go wrong talking CiA 402; one variant per cause.
#[derive(Debug)]
pub enum Cia402Error {
    /// A CANopen node-ID outside 1..=127.
    InvalidNode {
        /// The id given.
        node: u8,
    },
    /// A frame or value of the wrong size.
    WrongLength {
        /// What was decoded or encoded.
        what: &'static str,
        /// Bytes expected (at most, for SDO data).
        expected: usize,
        /// Bytes got.
        got: usize,
    },
    /// A field holds a value its definition does not allow.
    InvalidValue {
        /// The field.
        field: &'static str,
        /// The raw value.
        raw: u32,
    },
    /// The drive answered an upload with a segmented transfer.
    SdoSegmented {
        /// Index.
        index: u16,
        /// Sub-index.
        subindex: u8,
    },
    /// The drive aborted an SDO transfer.
    SdoAbort {
        /// The object's name.
        object: &'static str,
        /// Index.
        index: u16,
        /// Sub-index.
        subindex: u8,
        /// CiA 301 abort code.
        code: u32,
    },
    /// The drive holds another value than this master needs (device type,
    /// mode display, a PDO's COB-ID, or a PDO's transmission type or
    /// mapping that the master's write did not change).
    Mismatch {
        /// The object's name.
        object: &'static str,
        /// Index.
        index: u16,
        /// Sub-index.
        subindex: u8,
        /// What the master needs.
        expected: u32,
        /// What the drive holds.
        got: u32,
    },
    /// The drive has no SYNC counter echo 0x2000 (an off-the-shelf drive)
    /// and the settings require it ([`FreshnessSetting::SyncCounterEcho`]).
    NoSyncCounterEcho,
    /// A parameter outside its valid range.
    BadParameter {
        /// The parameter.
        field: &'static str,
        /// Its value.
        value: u64,
        /// The rule it breaks.
        why: &'static str,
    },
    /// NaN or infinity where a number is needed.
    NotFinite {
        /// The field.
        field: &'static str,
    },
    /// The drive's max torque 0x6072 is not the configured torque limit
    /// (`rig.torque_limit_nm`) in its torque steps: set-up refuses it.
    MaxTorqueMismatch {
        /// 0x6072 as read, per-mille of rated torque.
        drive_per_mille: u16,
        /// The same in N m.
        drive_nm: f64,
        /// The configured limit, N m.
        configured_nm: f64,
        /// The configured limit in per-mille of the drive's rated torque.
        configured_per_mille: f64,
        /// 0x6076 motor rated torque, mN m.
        rated_mnm: u32,
    },
    /// A torque beyond the drive's max torque 0x6072 (the master sends it
    /// clamped and counts it: [`Master::commands_clamped`]).
    TorqueBeyondLimit {
        /// The torque asked for, N m.
        torque_nm: f64,
        /// 0x6072 in N m.
        max_nm: f64,
    },
    /// The drive did not answer in time.
    Timeout {
        /// What the master waited for.
        what: &'static str,
        /// The drive's last known state.
        state: Option<DriveState>,
    },
    /// The bus failed.
    Transport(TransportError),
}

impl fmt::Display for Cia402Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::InvalidNode { node } => {
                write!(f, "CANopen node id must be in 1..=127, got {node}")
            }
            Self::WrongLength {
                what,
                expected,
                got,
            } => write!(f, "{what}: expected {expected} bytes, got {got}"),
            Self::InvalidValue { field, raw } => write!(f, "{field}: invalid value {raw:#x}"),
            Self::SdoSegmented { index, subindex } => write!(
                f,
                "SDO upload of {index:#06x}:{subindex} is segmented; this master reads only \
                 objects of up to 4 bytes (expedited)"
            ),
            Self::SdoAbort {
                object,
                index,
                subindex,
                code,
            } => write!(
                f,
                "the drive aborted the SDO transfer of {object} ({index:#06x}:{subindex}) with \
                 code {code:#010x}; check the drive's object dictionary against cia402_drive.eds"
            ),
            Self::Mismatch {
                object,
                index,
                subindex,
                expected,
                got,
            } => write!(
                f,
                "{object} ({index:#06x}:{subindex}) is {got:#x}, this master needs {expected:#x}; \
                 configure the drive as cia402_drive.eds"
            ),
            Self::NoSyncCounterEcho => write!(
                f,
                "the drive has no object 0x2000 (SYNC counter echo, UNSIGNED8, mapped last in \
                 TPDO1 and TPDO2) but rig.cia402.freshness = \"sync_counter_echo\" requires it; \
                 set rig.cia402.freshness = \"auto\" or \"standard\" to run it with freshness \
                 judged from the bus (weaker: docs/safety.md), or give the drive that object \
                 and mapping (cia402_drive.eds; docs/cia402.md, \"Freshness\")"
            ),
            Self::BadParameter { field, value, why } => {
                write!(f, "{field}: {why}, got {value}")
            }
            Self::NotFinite { field } => write!(f, "{field}: must be finite"),
            Self::MaxTorqueMismatch {
                drive_per_mille,
                drive_nm,
                configured_nm,
                configured_per_mille,
                rated_mnm,
            } => write!(
                f,
                "the drive's max torque 0x6072 is {drive_per_mille} per-mille of its rated \
                 torque 0x6076 ({rated_mnm} mN m), {drive_nm} N m, but rig.torque_limit_nm is \
                 {configured_nm} N m ({configured_per_mille} per-mille); they must agree \
                 (another node may have changed 0x6072): set rig.torque_limit_nm = {drive_nm}, \
                 or the drive's 0x6072 = {configured_per_mille} with the drive's own tool; \
                 not starting"
            ),
            Self::TorqueBeyondLimit { torque_nm, max_nm } => write!(
                f,
                "target torque: must be within +-{max_nm} N m (0x6072 max torque), got {torque_nm}"
            ),
            Self::Timeout { what, state } => write!(
                f,
                "timed out waiting for {what} (drive state {state:?}); is the drive on the bus?"
            ),
            Self::Transport(e) => write!(f, "CAN bus: {e}"),
        }
    }
}

impl std::error::Error for Cia402Error {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Self::Transport(e) => Some(e),
            _ => None,
        }
    }
}

impl From<TransportError> for Cia402Error {
    fn from(e: TransportError) -> Self {
        Self::Transport(e)
    }
}
