//! One classic CAN frame and its SocketCAN `struct can_frame` wire layout.
//!
//! The wire layout is the kernel's (`linux/can.h`), 16 bytes:
//!
//! | bytes  | field                                   |
//! |--------|-----------------------------------------|
//! | 0..4   | `can_id`, u32 little-endian (host order on x86/ARM) |
//! | 4      | `len` (DLC), 0..=8                      |
//! | 5..8   | pad / reserved, written as 0            |
//! | 8..16  | `data[8]`, bytes past `len` written as 0 |
//!
//! The same 16 bytes travel as one datagram on the loopback UDP bus, so a
//! capture from either transport reads the same.

use core::fmt;

/// Size of a `struct can_frame` on the wire (SocketCAN and the UDP bus).
pub const WIRE_SIZE: usize = 16;

/// Largest 11-bit (standard) identifier.
pub const MAX_STANDARD_ID: u32 = 0x7FF;

/// `CAN_EFF_FLAG`: 29-bit extended frame.
const EFF_FLAG: u32 = 0x8000_0000;
/// `CAN_RTR_FLAG`: remote transmission request.
const RTR_FLAG: u32 = 0x4000_0000;
/// `CAN_ERR_FLAG`: error frame from the controller.
const ERR_FLAG: u32 = 0x2000_0000;

/// One classic CAN frame with an 11-bit identifier.
///
/// Invariants (checked by [`Frame::new`], [`Frame::from_wire`] and
/// [`Frame::validate`]): `id <= 0x7FF`, `len <= 8`, `data[len..]` is zero.
/// The fields are public so a caller can fill a frame in place; transports
/// call [`Frame::validate`] before sending.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub struct Frame {
    /// 11-bit standard identifier (no flag bits).
    pub id: u32,
    /// Data length code, 0..=8.
    pub len: u8,
    /// Payload; only `data[..len]` is meaningful, the rest is zero.
    pub data: [u8; 8],
}

/// Why bytes are not a valid frame, or a frame is not valid to send.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WireError {
    /// The datagram is not exactly [`WIRE_SIZE`] bytes.
    WrongSize {
        /// Bytes received.
        got: usize,
    },
    /// `len` is above 8 (CAN FD or garbage).
    LengthTooLarge {
        /// The length field.
        len: u8,
    },
    /// `CAN_EFF_FLAG` set: 29-bit ids are not used by this protocol.
    Extended {
        /// The raw `can_id` word.
        can_id: u32,
    },
    /// `CAN_RTR_FLAG` set: remote frames are not used by this protocol.
    Remote {
        /// The raw `can_id` word.
        can_id: u32,
    },
    /// `CAN_ERR_FLAG` set: an error frame, not data.
    ErrorFrame {
        /// The raw `can_id` word.
        can_id: u32,
    },
    /// No flag set but the id does not fit in 11 bits.
    IdTooLarge {
        /// The id.
        id: u32,
    },
}

impl fmt::Display for WireError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Self::WrongSize { got } => {
                write!(f, "CAN frame must be {WIRE_SIZE} bytes, got {got}")
            }
            Self::LengthTooLarge { len } => write!(f, "CAN frame len must be <= 8, got {len}"),
            Self::Extended { can_id } => {
                write!(f, "extended (29-bit) frame {can_id:#010x} not supported")
            }
            Self::Remote { can_id } => write!(f, "remote (RTR) frame {can_id:#010x} not supported"),
            Self::ErrorFrame { can_id } => write!(f, "CAN error frame {can_id:#010x}"),
            Self::IdTooLarge { id } => write!(f, "standard CAN id must be <= 0x7FF, got {id:#x}"),
        }
    }
}

impl std::error::Error for WireError {}

impl Frame {
    /// A frame with `id` and a copy of `payload` (at most 8 bytes).
    pub fn new(id: u32, payload: &[u8]) -> Result<Self, WireError> {
        if payload.len() > 8 {
            return Err(WireError::LengthTooLarge {
                len: u8::try_from(payload.len()).unwrap_or(u8::MAX),
            });
        }
        let mut data = [0u8; 8];
        data[..payload.len()].copy_from_slice(payload);
        let frame = Self {
            id,
            // Fits: checked above.
            len: payload.len() as u8,
            data,
        };
        frame.validate()?;
        Ok(frame)
    }

    /// `data[..len]` (all of `data` if `len` is out of range).
    pub fn payload(&self) -> &[u8] {
        &self.data[..usize::from(self.len).min(8)]
    }

    /// Check the invariants: `id <= 0x7FF`, `len <= 8`.
    ///
    /// Bytes past `len` are not checked here; [`Frame::to_wire`] writes them
    /// as zero.
    pub fn validate(&self) -> Result<(), WireError> {
        if self.len > 8 {
            return Err(WireError::LengthTooLarge { len: self.len });
        }
        check_can_id(self.id)
    }

    /// The 16-byte `struct can_frame` for this frame; bytes past `len` are 0.
    ///
    /// Does not validate: call [`Frame::validate`] first if the frame was
    /// filled by hand (the transports do).
    pub fn to_wire(&self) -> [u8; WIRE_SIZE] {
        let mut wire = [0u8; WIRE_SIZE];
        wire[0..4].copy_from_slice(&self.id.to_le_bytes());
        wire[4] = self.len;
        let n = usize::from(self.len).min(8);
        wire[8..8 + n].copy_from_slice(&self.data[..n]);
        wire
    }

    /// Parse a 16-byte `struct can_frame`.
    ///
    /// The three pad/reserved bytes are ignored (Linux may use the last one
    /// as `len8_dlc`); bytes past `len` are zeroed in the result so equal
    /// frames compare equal.
    pub fn from_wire(bytes: &[u8]) -> Result<Self, WireError> {
        let wire: &[u8; WIRE_SIZE] = bytes
            .try_into()
            .map_err(|_| WireError::WrongSize { got: bytes.len() })?;
        let can_id = u32::from_le_bytes([wire[0], wire[1], wire[2], wire[3]]);
        check_can_id(can_id)?;
        let len = wire[4];
        if len > 8 {
            return Err(WireError::LengthTooLarge { len });
        }
        let mut data = [0u8; 8];
        let n = usize::from(len);
        data[..n].copy_from_slice(&wire[8..8 + n]);
        Ok(Self {
            id: can_id,
            len,
            data,
        })
    }
}

/// Reject flag bits and ids wider than 11 bits, flags first (they say why).
fn check_can_id(can_id: u32) -> Result<(), WireError> {
    if can_id & ERR_FLAG != 0 {
        Err(WireError::ErrorFrame { can_id })
    } else if can_id & EFF_FLAG != 0 {
        Err(WireError::Extended { can_id })
    } else if can_id & RTR_FLAG != 0 {
        Err(WireError::Remote { can_id })
    } else if can_id > MAX_STANDARD_ID {
        Err(WireError::IdTooLarge { id: can_id })
    } else {
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wire_round_trip_every_length() {
        for len in 0..=8u8 {
            let payload: Vec<u8> = (0..len).map(|i| 0xA0 + i).collect();
            let f = Frame::new(0x7FF - u32::from(len), &payload).unwrap();
            let wire = f.to_wire();
            assert_eq!(wire.len(), WIRE_SIZE);
            assert_eq!(wire[4], len);
            assert_eq!(&wire[5..8], &[0, 0, 0]);
            assert_eq!(Frame::from_wire(&wire).unwrap(), f);
            assert_eq!(f.payload(), &payload[..]);
        }
    }

    #[test]
    fn wire_layout_is_can_frame() {
        let f = Frame::new(0x201, &[1, 2, 3]).unwrap();
        assert_eq!(
            f.to_wire(),
            [0x01, 0x02, 0, 0, 3, 0, 0, 0, 1, 2, 3, 0, 0, 0, 0, 0]
        );
    }

    #[test]
    fn from_wire_ignores_pad_and_zeroes_tail() {
        let mut wire = Frame::new(0x10, &[9]).unwrap().to_wire();
        wire[5] = 0xEE;
        wire[7] = 0xEE;
        wire[12] = 0xEE; // past len
        let f = Frame::from_wire(&wire).unwrap();
        assert_eq!(f, Frame::new(0x10, &[9]).unwrap());
    }

    #[test]
    fn from_wire_errors() {
        assert_eq!(
            Frame::from_wire(&[0u8; 15]),
            Err(WireError::WrongSize { got: 15 })
        );
        assert_eq!(
            Frame::from_wire(&[0u8; 17]),
            Err(WireError::WrongSize { got: 17 })
        );
        let good = Frame::new(0x123, &[]).unwrap().to_wire();

        let mut w = good;
        w[4] = 9;
        assert_eq!(
            Frame::from_wire(&w),
            Err(WireError::LengthTooLarge { len: 9 })
        );

        let with_id = |can_id: u32| {
            let mut w = good;
            w[0..4].copy_from_slice(&can_id.to_le_bytes());
            Frame::from_wire(&w)
        };
        assert_eq!(
            with_id(0x8000_0123),
            Err(WireError::Extended {
                can_id: 0x8000_0123
            })
        );
        assert_eq!(
            with_id(0x4000_0123),
            Err(WireError::Remote {
                can_id: 0x4000_0123
            })
        );
        assert_eq!(
            with_id(0x2000_0004),
            Err(WireError::ErrorFrame {
                can_id: 0x2000_0004
            })
        );
        assert_eq!(with_id(0x800), Err(WireError::IdTooLarge { id: 0x800 }));
    }

    #[test]
    fn new_and_validate_errors() {
        assert_eq!(
            Frame::new(1, &[0; 9]),
            Err(WireError::LengthTooLarge { len: 9 })
        );
        assert_eq!(
            Frame::new(0x800, &[]),
            Err(WireError::IdTooLarge { id: 0x800 })
        );
        let f = Frame {
            id: 1,
            len: 12,
            data: [0; 8],
        };
        assert_eq!(f.validate(), Err(WireError::LengthTooLarge { len: 12 }));
        assert_eq!(f.payload().len(), 8);
    }
}
