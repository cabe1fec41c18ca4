//! One classic CAN frame and its SocketCAN `struct can_frame` wire layout.
//!
//! The wire layout is the kernel's (`linux/can.h`), 16 bytes:
//!
//! | bytes  | field                                   |
//! |--------|-----------------------------------------|
//! | 0..4   | `can_id`, u32 little-endian (host order on x86/ARM): the 11- or 29-bit id, plus flag bits 31 `CAN_EFF_FLAG` (29-bit id), 30 `CAN_RTR_FLAG` (remote frame), 29 `CAN_ERR_FLAG` (error frame) |
//! | 4      | `len` (DLC), 0..=8                      |
//! | 5..8   | pad / reserved, written as 0            |
//! | 8..16  | `data[8]`, bytes past `len` written as 0 (all 0 in a remote frame) |
//!
//! Every classic CAN frame fits: standard and extended data frames, remote
//! frames, and the error frames a SocketCAN controller reports. The same 16
//! bytes travel as one datagram on the loopback UDP bus, so a capture from
//! either transport reads the same. (The Hi5 protocol uses only standard
//! data frames; [`crate::protocol::decode`] rejects the others.)

use core::fmt;

/// Size of a `struct can_frame` on the wire (SocketCAN and the UDP bus).
pub const WIRE_SIZE: usize = 16;

/// Largest 11-bit (standard) identifier.
pub const MAX_STANDARD_ID: u32 = 0x7FF;
/// Largest 29-bit (extended) identifier; also `CAN_ERR_MASK`, the bits an
/// error frame's class may use.
pub const MAX_EXTENDED_ID: u32 = 0x1FFF_FFFF;

/// `CAN_EFF_FLAG`: 29-bit extended frame.
const EFF_FLAG: u32 = 0x8000_0000;
/// `CAN_RTR_FLAG`: remote transmission request.
const RTR_FLAG: u32 = 0x4000_0000;
/// `CAN_ERR_FLAG`: error frame from the controller.
const ERR_FLAG: u32 = 0x2000_0000;

/// What a frame carries.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum FrameKind {
    /// A data frame: `data[..len]` is the payload.
    #[default]
    Data,
    /// A remote transmission request: `len` is the requested DLC, no data.
    Remote,
    /// An error frame (`CAN_ERR_FLAG`): `id` is the error class
    /// (`linux/can/error.h`), `data` its details.
    Error,
}

/// One classic CAN frame.
///
/// Invariants (checked by [`Frame::new`], [`Frame::from_wire`] and
/// [`Frame::validate`]): `id <= 0x7FF` unless `extended` (then
/// `id <= 0x1FFF_FFFF`; error frames likewise), `len <= 8`, `data[len..]`
/// is zero (all of `data` in a remote frame). The fields are public so a
/// caller can fill a frame in place; transports call [`Frame::validate`]
/// before sending. `Frame::default()` is an empty standard data frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub struct Frame {
    /// Identifier without flag bits: 11 bits, or 29 if `extended`.
    pub id: u32,
    /// Data length code, 0..=8.
    pub len: u8,
    /// Payload; only `data[..len]` of a data frame is meaningful, the rest
    /// is zero.
    pub data: [u8; 8],
    /// 29-bit identifier (`CAN_EFF_FLAG`).
    pub extended: bool,
    /// Data, remote or error frame.
    pub kind: FrameKind,
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
    /// The id does not fit in 11 bits (standard) or 29 bits (extended,
    /// error).
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
            Self::IdTooLarge { id } => write!(
                f,
                "CAN id must be <= 0x7FF (standard) or <= 0x1FFFFFFF (extended), got {id:#x}"
            ),
        }
    }
}

impl std::error::Error for WireError {}

impl Frame {
    /// A standard (11-bit) data frame with `id` and a copy of `payload` (at
    /// most 8 bytes).
    pub fn new(id: u32, payload: &[u8]) -> Result<Self, WireError> {
        Self::data(id, false, payload)
    }

    /// A data frame with an 11-bit (`extended` false) or 29-bit id.
    pub fn data(id: u32, extended: bool, payload: &[u8]) -> Result<Self, WireError> {
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
            extended,
            kind: FrameKind::Data,
        };
        frame.validate()?;
        Ok(frame)
    }

    /// A remote frame requesting `len` bytes.
    pub fn remote(id: u32, extended: bool, len: u8) -> Result<Self, WireError> {
        let frame = Self {
            id,
            len,
            data: [0; 8],
            extended,
            kind: FrameKind::Remote,
        };
        frame.validate()?;
        Ok(frame)
    }

    /// `data[..len]` of a data frame (all of `data` if `len` is out of
    /// range); empty for a remote frame.
    pub fn payload(&self) -> &[u8] {
        match self.kind {
            FrameKind::Remote => &[],
            _ => &self.data[..usize::from(self.len).min(8)],
        }
    }

    /// True for a standard (11-bit) data frame, the only kind the Hi5
    /// protocol uses.
    pub fn is_standard_data(&self) -> bool {
        !self.extended && self.kind == FrameKind::Data
    }

    /// The kernel's `can_id` word: the id with its flag bits.
    pub fn can_id(&self) -> u32 {
        let mut can_id = self.id;
        if self.extended {
            can_id |= EFF_FLAG;
        }
        match self.kind {
            FrameKind::Data => {}
            FrameKind::Remote => can_id |= RTR_FLAG,
            FrameKind::Error => can_id |= ERR_FLAG,
        }
        can_id
    }

    /// Check the invariants: the id fits its width, `len <= 8`.
    ///
    /// Bytes past `len` are not checked here; [`Frame::to_wire`] writes them
    /// as zero.
    pub fn validate(&self) -> Result<(), WireError> {
        if self.len > 8 {
            return Err(WireError::LengthTooLarge { len: self.len });
        }
        let max = if self.extended || self.kind == FrameKind::Error {
            MAX_EXTENDED_ID
        } else {
            MAX_STANDARD_ID
        };
        if self.id > max {
            return Err(WireError::IdTooLarge { id: self.id });
        }
        Ok(())
    }

    /// The 16-byte `struct can_frame` for this frame; bytes past `len` (all
    /// data bytes of a remote frame) are 0.
    ///
    /// Does not validate: call [`Frame::validate`] first if the frame was
    /// filled by hand (the transports do).
    pub fn to_wire(&self) -> [u8; WIRE_SIZE] {
        let mut wire = [0u8; WIRE_SIZE];
        wire[0..4].copy_from_slice(&self.can_id().to_le_bytes());
        wire[4] = self.len;
        let n = self.payload().len();
        wire[8..8 + n].copy_from_slice(&self.data[..n]);
        wire
    }

    /// Parse a 16-byte `struct can_frame`.
    ///
    /// The three pad/reserved bytes are ignored (Linux may use the last one
    /// as `len8_dlc`); bytes past `len` (all data of a remote frame) are
    /// zeroed in the result so equal frames compare equal. The id is the
    /// low 29 bits of `can_id` (python-can's SocketCAN reading); a standard
    /// frame's id above 0x7FF is refused.
    pub fn from_wire(bytes: &[u8]) -> Result<Self, WireError> {
        let wire: &[u8; WIRE_SIZE] = bytes
            .try_into()
            .map_err(|_| WireError::WrongSize { got: bytes.len() })?;
        let can_id = u32::from_le_bytes([wire[0], wire[1], wire[2], wire[3]]);
        let len = wire[4];
        let kind = if can_id & ERR_FLAG != 0 {
            FrameKind::Error
        } else if can_id & RTR_FLAG != 0 {
            FrameKind::Remote
        } else {
            FrameKind::Data
        };
        let mut frame = Self {
            id: can_id & MAX_EXTENDED_ID,
            len,
            data: [0u8; 8],
            extended: can_id & EFF_FLAG != 0,
            kind,
        };
        frame.validate()?;
        let n = frame.payload().len();
        frame.data[..n].copy_from_slice(&wire[8..8 + n]);
        Ok(frame)
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
        assert_eq!(with_id(0x800), Err(WireError::IdTooLarge { id: 0x800 }));
    }

    #[test]
    fn every_classic_frame_kind_round_trips_with_the_kernels_flags() {
        let ext = Frame::data(0x1234_5678 & MAX_EXTENDED_ID, true, &[1, 2, 3]).unwrap();
        let w = ext.to_wire();
        assert_eq!(
            u32::from_le_bytes([w[0], w[1], w[2], w[3]]),
            0x8000_0000 | 0x1234_5678
        );
        assert_eq!(Frame::from_wire(&w).unwrap(), ext);
        assert!(!ext.is_standard_data());

        let rtr = Frame::remote(0x200, false, 4).unwrap();
        let w = rtr.to_wire();
        assert_eq!(&w[0..5], &[0x00, 0x02, 0, 0x40, 4]);
        assert_eq!(&w[8..], &[0; 8]);
        assert_eq!(Frame::from_wire(&w).unwrap(), rtr);
        assert_eq!(rtr.payload(), &[] as &[u8]);

        let rtr_ext = Frame::remote(0x1FFF_FFFF, true, 8).unwrap();
        assert_eq!(rtr_ext.can_id(), 0xDFFF_FFFF);
        assert_eq!(Frame::from_wire(&rtr_ext.to_wire()).unwrap(), rtr_ext);

        // An error frame as the kernel reports it: CAN_ERR_FLAG | class, DLC 8.
        let mut w = [0u8; WIRE_SIZE];
        w[0..4].copy_from_slice(&(0x2000_0004u32).to_le_bytes());
        w[4] = 8;
        w[9] = 0x10;
        let err = Frame::from_wire(&w).unwrap();
        assert_eq!(err.kind, FrameKind::Error);
        assert_eq!((err.id, err.len, err.data[1]), (4, 8, 0x10));
        assert_eq!(err.to_wire(), w);

        // Remote frames carry no data, whatever the bytes say.
        let mut w = rtr.to_wire();
        w[8] = 0xEE;
        assert_eq!(Frame::from_wire(&w).unwrap(), rtr);
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
        assert_eq!(
            Frame::data(0x2000_0000, true, &[]),
            Err(WireError::IdTooLarge { id: 0x2000_0000 })
        );
        assert_eq!(
            Frame::remote(0x10, false, 9),
            Err(WireError::LengthTooLarge { len: 9 })
        );
        let f = Frame {
            id: 1,
            len: 12,
            ..Frame::default()
        };
        assert_eq!(f.validate(), Err(WireError::LengthTooLarge { len: 12 }));
        assert_eq!(f.payload().len(), 8);
    }
}
