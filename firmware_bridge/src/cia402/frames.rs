//! CANopen frames: NMT, SYNC, heartbeat, SDO expedited transfers, the PDOs
//! and EMCY. Encode into and decode from [`Frame`]; nothing allocates.
//!
//! Byte layouts follow CiA 301 (all little-endian); `golden/cia402_frames.json`
//! holds python-canopen's bytes for each, checked by `tests/cia402_golden.rs`.

use super::od::{CanopenNode, Object, NMT_COB_ID, SYNC_COB_ID};
use super::Cia402Error;
use crate::frame::Frame;

/// An NMT command specifier (CiA 301 7.2.8.3.1.1).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum NmtCommand {
    /// 0x01: to OPERATIONAL (PDOs run).
    Start = 0x01,
    /// 0x02: to STOPPED.
    Stop = 0x02,
    /// 0x80: to PRE-OPERATIONAL (SDO only).
    EnterPreOperational = 0x80,
    /// 0x81: reset the application.
    ResetNode = 0x81,
    /// 0x82: reset communication.
    ResetCommunication = 0x82,
}

/// `[command, node]` on COB-ID 0; `node` 0 addresses every node.
pub fn nmt(command: NmtCommand, node: u8) -> Frame {
    frame(NMT_COB_ID, &[command as u8, node])
}

/// SYNC with its counter (CiA 301 SYNC object): COB-ID 0x80, one byte,
/// 1..=0x1019 ([`super::od::SYNC_COUNTER_OVERFLOW`]).
pub fn sync(counter: u8) -> Frame {
    frame(SYNC_COB_ID, &[counter])
}

/// The NMT state a heartbeat reports (CiA 301 7.2.8.3.2.2).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum NmtState {
    /// 0x00: the boot-up message.
    BootUp = 0x00,
    /// 0x04.
    Stopped = 0x04,
    /// 0x05.
    Operational = 0x05,
    /// 0x7F.
    PreOperational = 0x7F,
}

impl NmtState {
    fn from_byte(b: u8) -> Option<Self> {
        match b & 0x7F {
            0x00 => Some(Self::BootUp),
            0x04 => Some(Self::Stopped),
            0x05 => Some(Self::Operational),
            0x7F => Some(Self::PreOperational),
            _ => None,
        }
    }
}

/// A heartbeat from `node`: one byte, its NMT state.
pub fn heartbeat(node: CanopenNode, state: NmtState) -> Frame {
    frame(node.heartbeat(), &[state as u8])
}

/// Decodes a heartbeat payload (the toggle bit 7, used only by node
/// guarding, is ignored).
pub fn decode_heartbeat(payload: &[u8]) -> Result<NmtState, Cia402Error> {
    let [b] = payload else {
        return Err(wrong_length("heartbeat", 1, payload));
    };
    NmtState::from_byte(*b).ok_or(Cia402Error::InvalidValue {
        field: "heartbeat.state",
        raw: u32::from(*b),
    })
}

// -- SDO -------------------------------------------------------------------------

/// Client command specifier 1 (initiate download), expedited, size indicated.
const SDO_DOWNLOAD_EXPEDITED: u8 = 0x23;
/// Client command specifier 2 (initiate upload).
const SDO_UPLOAD_REQUEST: u8 = 0x40;
/// Server command specifier 3 (initiate download response).
const SDO_DOWNLOAD_RESPONSE: u8 = 0x60;
/// Server command specifier 2 (initiate upload response); bits below say
/// expedited (1) and size indicated (0) and n (2-3).
const SDO_UPLOAD_RESPONSE: u8 = 0x40;
/// Abort transfer (either direction).
const SDO_ABORT: u8 = 0x80;

/// An expedited SDO download (write) of 1 to 4 bytes `value` to `o`:
/// `0x23 | (4 - n) << 2`, index LE, sub-index, data padded to 4 bytes.
pub fn sdo_download(node: CanopenNode, o: Object, value: &[u8]) -> Result<Frame, Cia402Error> {
    let n = value.len();
    if !(1..=4).contains(&n) {
        return Err(Cia402Error::WrongLength {
            what: "SDO expedited data",
            expected: 4,
            got: n,
        });
    }
    let mut data = sdo_header(SDO_DOWNLOAD_EXPEDITED | (((4 - n) as u8) << 2), o);
    data[4..4 + n].copy_from_slice(value);
    Ok(frame(node.sdo_rx(), &data))
}

/// An SDO upload (read) request for `o`.
pub fn sdo_upload(node: CanopenNode, o: Object) -> Frame {
    frame(node.sdo_rx(), &sdo_header(SDO_UPLOAD_REQUEST, o))
}

/// What an SDO server answered.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SdoResponse {
    /// The download (write) to `index:subindex` succeeded.
    Downloaded {
        /// Index.
        index: u16,
        /// Sub-index.
        subindex: u8,
    },
    /// Expedited upload (read): `data[..len]` is the value (len 4 when
    /// the server did not indicate a size).
    Uploaded {
        /// Index.
        index: u16,
        /// Sub-index.
        subindex: u8,
        /// The value, little-endian, zero-padded.
        data: [u8; 4],
        /// Its size in bytes.
        len: u8,
    },
    /// The server aborted the transfer with a CiA 301 abort code.
    Aborted {
        /// Index.
        index: u16,
        /// Sub-index.
        subindex: u8,
        /// Abort code, e.g. 0x06010002 "attempt to write a read only object".
        code: u32,
    },
}

/// Decodes an SDO server response (COB-ID 0x580 + node).
pub fn decode_sdo_response(payload: &[u8]) -> Result<SdoResponse, Cia402Error> {
    let Ok(b) = <&[u8; 8]>::try_from(payload) else {
        return Err(wrong_length("SDO response", 8, payload));
    };
    let index = u16::from_le_bytes([b[1], b[2]]);
    let subindex = b[3];
    let cmd = b[0];
    match cmd & 0xE0 {
        SDO_DOWNLOAD_RESPONSE => Ok(SdoResponse::Downloaded { index, subindex }),
        SDO_UPLOAD_RESPONSE => {
            let expedited = cmd & 0x02 != 0;
            let size_indicated = cmd & 0x01 != 0;
            if !expedited {
                // A segmented upload: not needed by this master (every
                // object it reads is at most 4 bytes).
                return Err(Cia402Error::SdoSegmented { index, subindex });
            }
            let len = if size_indicated {
                4 - ((cmd >> 2) & 0x03)
            } else {
                4
            };
            Ok(SdoResponse::Uploaded {
                index,
                subindex,
                data: [b[4], b[5], b[6], b[7]],
                len,
            })
        }
        SDO_ABORT => Ok(SdoResponse::Aborted {
            index,
            subindex,
            code: u32::from_le_bytes([b[4], b[5], b[6], b[7]]),
        }),
        _ => Err(Cia402Error::InvalidValue {
            field: "SDO response command specifier",
            raw: u32::from(cmd),
        }),
    }
}

fn sdo_header(cmd: u8, o: Object) -> [u8; 8] {
    let [lo, hi] = o.index.to_le_bytes();
    [cmd, lo, hi, o.subindex, 0, 0, 0, 0]
}

// -- PDOs --------------------------------------------------------------------------

/// RPDO1 (mapping 0x1600): controlword (u16), target torque (i16 per-mille).
pub fn rpdo1(node: CanopenNode, controlword: u16, target_torque_per_mille: i16) -> Frame {
    let [c0, c1] = controlword.to_le_bytes();
    let [t0, t1] = target_torque_per_mille.to_le_bytes();
    frame(node.rpdo1(), &[c0, c1, t0, t1])
}

/// TPDO1 (mapping 0x1A00): statusword, position actual (increments), SYNC
/// counter echo.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Tpdo1 {
    /// 0x6041.
    pub statusword: u16,
    /// 0x6064, encoder increments.
    pub position_increments: i32,
    /// 0x2000, the counter of the SYNC this TPDO answers.
    pub sync_counter: u8,
}

/// TPDO2 (mapping 0x1A01): velocity actual, torque actual, SYNC counter echo.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Tpdo2 {
    /// 0x606C, increments per second.
    pub velocity_increments_s: i32,
    /// 0x6077, per-mille of rated torque.
    pub torque_per_mille: i16,
    /// 0x2000, the counter of the SYNC this TPDO answers.
    pub sync_counter: u8,
}

/// Decodes TPDO1's 7 bytes.
pub fn decode_tpdo1(payload: &[u8]) -> Result<Tpdo1, Cia402Error> {
    let Ok(b) = <&[u8; 7]>::try_from(payload) else {
        return Err(wrong_length("TPDO1", 7, payload));
    };
    Ok(Tpdo1 {
        statusword: u16::from_le_bytes([b[0], b[1]]),
        position_increments: i32::from_le_bytes([b[2], b[3], b[4], b[5]]),
        sync_counter: b[6],
    })
}

/// Decodes TPDO2's 7 bytes.
pub fn decode_tpdo2(payload: &[u8]) -> Result<Tpdo2, Cia402Error> {
    let Ok(b) = <&[u8; 7]>::try_from(payload) else {
        return Err(wrong_length("TPDO2", 7, payload));
    };
    Ok(Tpdo2 {
        velocity_increments_s: i32::from_le_bytes([b[0], b[1], b[2], b[3]]),
        torque_per_mille: i16::from_le_bytes([b[4], b[5]]),
        sync_counter: b[6],
    })
}

/// Decodes a standard drive's TPDO1 (6 bytes: no SYNC counter echo); the
/// counter is the one of the SYNC window it arrived in (`sync_counter`,
/// the master's judgement, docs/cia402.md "Freshness without 0x2000").
pub fn decode_tpdo1_standard(payload: &[u8], sync_counter: u8) -> Result<Tpdo1, Cia402Error> {
    let Ok(b) = <&[u8; 6]>::try_from(payload) else {
        return Err(wrong_length("TPDO1", 6, payload));
    };
    Ok(Tpdo1 {
        statusword: u16::from_le_bytes([b[0], b[1]]),
        position_increments: i32::from_le_bytes([b[2], b[3], b[4], b[5]]),
        sync_counter,
    })
}

/// Decodes a standard drive's TPDO2 (6 bytes), as [`decode_tpdo1_standard`].
pub fn decode_tpdo2_standard(payload: &[u8], sync_counter: u8) -> Result<Tpdo2, Cia402Error> {
    let Ok(b) = <&[u8; 6]>::try_from(payload) else {
        return Err(wrong_length("TPDO2", 6, payload));
    };
    Ok(Tpdo2 {
        velocity_increments_s: i32::from_le_bytes([b[0], b[1], b[2], b[3]]),
        torque_per_mille: i16::from_le_bytes([b[4], b[5]]),
        sync_counter,
    })
}

// -- EMCY ----------------------------------------------------------------------------

/// An emergency message (CiA 301 7.2.7.3.1): error code, error register
/// (0x1001), 5 manufacturer-specific bytes. Code 0 is "error reset / no
/// error".
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Emcy {
    /// Emergency error code (CiA 301 table 21, CiA 402 section 9).
    pub code: u16,
    /// 0x1001 error register at the time.
    pub register: u8,
    /// Manufacturer-specific error field.
    pub manufacturer: [u8; 5],
}

impl Emcy {
    /// A short name: the codes the virtual drive sends, else the code's
    /// class (CiA 301 table 21 by its high byte or nibble).
    pub fn name(&self) -> &'static str {
        match self.code {
            0x0000 => "error reset or no error",
            0x8130 => "heartbeat error (the drive lost the master's heartbeat)",
            0x8400 => "velocity speed controller (overspeed)",
            0x8611 => "target torque beyond max torque 0x6072",
            0x6100 => "internal software",
            c => match c >> 8 {
                0x10 => "generic error",
                0x81 => "communication",
                0x82 => "protocol error",
                0x90 => "external error",
                0xF0 => "additional functions",
                0xFF => "device specific",
                _ => match c >> 12 {
                    0x2 => "current",
                    0x3 => "voltage",
                    0x4 => "temperature",
                    0x5 => "device hardware",
                    0x6 => "device software",
                    0x7 => "additional modules",
                    0x8 => "monitoring",
                    _ => "unknown class",
                },
            },
        }
    }
}

/// Decodes an EMCY payload (exactly 8 bytes).
pub fn decode_emcy(payload: &[u8]) -> Result<Emcy, Cia402Error> {
    let Ok(b) = <&[u8; 8]>::try_from(payload) else {
        return Err(wrong_length("EMCY", 8, payload));
    };
    Ok(Emcy {
        code: u16::from_le_bytes([b[0], b[1]]),
        register: b[2],
        manufacturer: [b[3], b[4], b[5], b[6], b[7]],
    })
}

fn frame(id: u32, payload: &[u8]) -> Frame {
    let mut data = [0u8; 8];
    data[..payload.len()].copy_from_slice(payload);
    Frame {
        id,
        // Every caller passes at most 8 bytes.
        len: payload.len() as u8,
        data,
        extended: false,
        kind: crate::frame::FrameKind::Data,
    }
}

fn wrong_length(what: &'static str, expected: usize, payload: &[u8]) -> Cia402Error {
    Cia402Error::WrongLength {
        what,
        expected,
        got: payload.len(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cia402::od;

    #[test]
    fn sdo_download_sizes_and_abort_decode() {
        let n = CanopenNode::new(1).unwrap();
        let f = sdo_download(n, od::MODES_OF_OPERATION, &[10]).unwrap();
        assert_eq!(
            (f.id, f.payload()),
            (0x601, &[0x2F, 0x60, 0x60, 0, 10, 0, 0, 0][..])
        );
        let f = sdo_download(n, od::CONSUMER_HEARTBEAT, &[1, 2, 3, 4]).unwrap();
        assert_eq!(f.data[0], 0x23);
        assert!(sdo_download(n, od::CONTROLWORD, &[]).is_err());
        assert!(sdo_download(n, od::CONTROLWORD, &[0; 5]).is_err());
        let abort = [0x80, 0x41, 0x60, 0, 0x02, 0x00, 0x01, 0x06];
        assert_eq!(
            decode_sdo_response(&abort).unwrap(),
            SdoResponse::Aborted {
                index: 0x6041,
                subindex: 0,
                code: 0x0601_0002
            }
        );
        assert!(matches!(
            decode_sdo_response(&[0x41, 0, 0, 0, 0, 0, 0, 0]),
            Err(Cia402Error::SdoSegmented { .. })
        ));
        assert!(decode_sdo_response(&[0x60; 7]).is_err());
    }

    #[test]
    fn short_payloads_are_errors_not_panics() {
        for len in 0..8 {
            let p = [0u8; 8];
            assert!(decode_emcy(&p[..len]).is_err());
            if len != 7 {
                assert!(decode_tpdo1(&p[..len]).is_err());
                assert!(decode_tpdo2(&p[..len]).is_err());
            }
        }
        assert!(decode_heartbeat(&[]).is_err());
        assert!(decode_heartbeat(&[0x33]).is_err());
        assert_eq!(decode_heartbeat(&[0x85]).unwrap(), NmtState::Operational);
    }
}
