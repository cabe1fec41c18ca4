//! CAN link to the Hi5 wrist robot's DC-motor driver.
//!
//! - [`frame`]: one classic CAN frame (standard or extended id; data,
//!   remote or error) and the SocketCAN `can_frame` wire layout.
//! - [`protocol`]: the messages of `hi5.dbc`, encode and decode.
//! - [`cia402`]: a CANopen master for a CiA 402 drive (the second drive
//!   profile, `docs/cia402.md`).
//! - [`drive_link`]: one interface to a drive of either profile.
//! - [`transport`]: sending and receiving frames over SocketCAN or over a
//!   loopback-only UDP "virtual CAN bus" (those two: the default feature
//!   `transports`; without it the crate is the protocols, the DBC's ranges
//!   and bus URL parsing, with no socket code).
//!
//! The per-frame paths (encode, decode, send, receive) do not allocate.
//! The protocol and the state machine the drive implements are described in
//! `docs/can_protocol.md`.
#![deny(missing_docs)]
#![deny(clippy::undocumented_unsafe_blocks)]

pub mod cia402;
pub mod dbc;
pub mod drive_link;
pub mod frame;
pub mod protocol;
pub mod transport;

pub use frame::{Frame, FrameKind, WireError};
pub use protocol::{
    decode, decode_any, encode, seq_is_newer, CommandGate, DecodeError, DriveState, EncodeError,
    FaultFlags, Message, MessageKind, NodeId, Rejection,
};
#[cfg(feature = "transports")]
pub use transport::open;
pub use transport::{Transport, TransportError};
