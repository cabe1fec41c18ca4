//! The objects and COB-IDs the master uses, named once.
//!
//! The object dictionary itself is `firmware_bridge/cia402_drive.eds`; the
//! golden file `golden/cia402_frames.json` carries python-canopen's reading
//! of it (index, sub-index, data type, default), and
//! `tests/cia402_golden.rs` checks every constant here against it.

use super::Cia402Error;

/// One object dictionary entry: index and sub-index.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Object {
    /// 16-bit index.
    pub index: u16,
    /// 8-bit sub-index (0 for a plain variable).
    pub subindex: u8,
    /// The EDS `ParameterName`, for error messages.
    pub name: &'static str,
}

const fn obj(index: u16, subindex: u8, name: &'static str) -> Object {
    Object {
        index,
        subindex,
        name,
    }
}

/// 0x1000 Device type (UNSIGNED32): low 16 bits are the profile, 402.
pub const DEVICE_TYPE: Object = obj(0x1000, 0, "Device type");
/// 0x1016:01 Consumer heartbeat time (UNSIGNED32): producer node << 16 | ms.
pub const CONSUMER_HEARTBEAT: Object = obj(0x1016, 1, "Consumer heartbeat time 1");
/// 0x1017 Producer heartbeat time (UNSIGNED16, ms).
pub const PRODUCER_HEARTBEAT: Object = obj(0x1017, 0, "Producer heartbeat time");
/// 0x1400:01 RPDO1 COB-ID (UNSIGNED32).
pub const RPDO1_COB_ID: Object = obj(0x1400, 1, "COB-ID used by RPDO");
/// 0x1400:02 RPDO1 transmission type (UNSIGNED8).
pub const RPDO1_TRANSMISSION: Object = obj(0x1400, 2, "Transmission type");
/// 0x1800:01 TPDO1 COB-ID (UNSIGNED32).
pub const TPDO1_COB_ID: Object = obj(0x1800, 1, "COB-ID used by TPDO");
/// 0x1800:02 TPDO1 transmission type (UNSIGNED8).
pub const TPDO1_TRANSMISSION: Object = obj(0x1800, 2, "Transmission type");
/// 0x1801:01 TPDO2 COB-ID (UNSIGNED32).
pub const TPDO2_COB_ID: Object = obj(0x1801, 1, "COB-ID used by TPDO");
/// 0x1801:02 TPDO2 transmission type (UNSIGNED8).
pub const TPDO2_TRANSMISSION: Object = obj(0x1801, 2, "Transmission type");
/// 0x2000 SYNC counter echo (UNSIGNED8, manufacturer-specific, read-only),
/// TPDO1 and TPDO2: the counter of the SYNC the drive is answering (0 for a
/// SYNC without one). This is what tells a fresh TPDO from a late or
/// replayed one; the object is this project's (docs/cia402.md, "Freshness").
pub const SYNC_COUNTER_ECHO: Object = obj(0x2000, 0, "SYNC counter echo");
/// 0x6040 Controlword (UNSIGNED16), RPDO1.
pub const CONTROLWORD: Object = obj(0x6040, 0, "Controlword");
/// 0x6041 Statusword (UNSIGNED16), TPDO1.
pub const STATUSWORD: Object = obj(0x6041, 0, "Statusword");
/// 0x6060 Modes of operation (INTEGER8).
pub const MODES_OF_OPERATION: Object = obj(0x6060, 0, "Modes of operation");
/// 0x6061 Modes of operation display (INTEGER8).
pub const MODES_OF_OPERATION_DISPLAY: Object = obj(0x6061, 0, "Modes of operation display");
/// 0x6064 Position actual value (INTEGER32, increments), TPDO1.
pub const POSITION_ACTUAL: Object = obj(0x6064, 0, "Position actual value");
/// 0x606C Velocity actual value (INTEGER32, increments/s), TPDO2.
pub const VELOCITY_ACTUAL: Object = obj(0x606C, 0, "Velocity actual value");
/// 0x6071 Target torque (INTEGER16, per-mille of rated torque), RPDO1.
pub const TARGET_TORQUE: Object = obj(0x6071, 0, "Target torque");
/// 0x6072 Max torque (UNSIGNED16, per-mille of rated torque).
pub const MAX_TORQUE: Object = obj(0x6072, 0, "Max torque");
/// 0x6076 Motor rated torque (UNSIGNED32, mN m).
pub const RATED_TORQUE: Object = obj(0x6076, 0, "Motor rated torque");
/// 0x6077 Torque actual value (INTEGER16, per-mille), TPDO2.
pub const TORQUE_ACTUAL: Object = obj(0x6077, 0, "Torque actual value");
/// 0x608F:01 Position encoder resolution: encoder increments (UNSIGNED32).
pub const ENCODER_INCREMENTS: Object = obj(0x608F, 1, "Encoder increments");
/// 0x608F:02 Position encoder resolution: motor revolutions (UNSIGNED32).
pub const ENCODER_MOTOR_REVOLUTIONS: Object = obj(0x608F, 2, "Motor revolutions");
/// 0x6091:01 Gear ratio: motor revolutions (UNSIGNED32).
pub const GEAR_MOTOR_REVOLUTIONS: Object = obj(0x6091, 1, "Motor revolutions");
/// 0x6091:02 Gear ratio: shaft revolutions (UNSIGNED32).
pub const GEAR_SHAFT_REVOLUTIONS: Object = obj(0x6091, 2, "Shaft revolutions");

/// 0x6060 value for cyclic synchronous torque mode.
pub const MODE_CYCLIC_SYNCHRONOUS_TORQUE: i8 = 10;
/// CiA 402's device profile number in the low 16 bits of 0x1000.
pub const PROFILE_402: u32 = 402;
/// Transmission type 1: synchronous, every SYNC.
pub const TRANSMISSION_EVERY_SYNC: u8 = 1;
/// The master's 0x1019 synchronous counter overflow value (CiA 301): every
/// SYNC carries a counter byte, 1 to this value, then 1 again. 240 is the
/// largest value CiA 301 allows, the longest run before a counter repeats.
pub const SYNC_COUNTER_OVERFLOW: u8 = 240;

/// SDO abort code "object does not exist in the object dictionary" (CiA 301
/// table 22).
pub const SDO_ABORT_NO_OBJECT: u32 = 0x0602_0000;

/// A PDO mapping entry: `index << 16 | subindex << 8 | bit length`.
pub const fn mapping_entry(o: Object, bits: u8) -> u32 {
    ((o.index as u32) << 16) | ((o.subindex as u32) << 8) | bits as u32
}

/// One PDO's mapping (0x16xx / 0x1Axx) as the master encodes it.
#[derive(Clone, Copy, Debug)]
pub struct PdoMapping {
    /// The mapping parameter's index (0x1600, 0x1A00, 0x1A01).
    pub index: u16,
    /// The entries in order (sub-index 1, 2, ...).
    pub entries: &'static [u32],
}

/// RPDO1: controlword, target torque (4 bytes).
pub const RPDO1_MAPPING: PdoMapping = PdoMapping {
    index: 0x1600,
    entries: &[
        mapping_entry(CONTROLWORD, 16),
        mapping_entry(TARGET_TORQUE, 16),
    ],
};
/// TPDO1: statusword, position actual, SYNC counter echo (7 bytes).
pub const TPDO1_MAPPING: PdoMapping = PdoMapping {
    index: 0x1A00,
    entries: &[
        mapping_entry(STATUSWORD, 16),
        mapping_entry(POSITION_ACTUAL, 32),
        mapping_entry(SYNC_COUNTER_ECHO, 8),
    ],
};
/// TPDO2: velocity actual, torque actual, SYNC counter echo (7 bytes).
pub const TPDO2_MAPPING: PdoMapping = PdoMapping {
    index: 0x1A01,
    entries: &[
        mapping_entry(VELOCITY_ACTUAL, 32),
        mapping_entry(TORQUE_ACTUAL, 16),
        mapping_entry(SYNC_COUNTER_ECHO, 8),
    ],
};

/// TPDO1 of a standard drive (no 0x2000): statusword, position actual (6 bytes).
pub const TPDO1_STANDARD_MAPPING: PdoMapping = PdoMapping {
    index: 0x1A00,
    entries: &[
        mapping_entry(STATUSWORD, 16),
        mapping_entry(POSITION_ACTUAL, 32),
    ],
};
/// TPDO2 of a standard drive (no 0x2000): velocity actual, torque actual (6 bytes).
pub const TPDO2_STANDARD_MAPPING: PdoMapping = PdoMapping {
    index: 0x1A01,
    entries: &[
        mapping_entry(VELOCITY_ACTUAL, 32),
        mapping_entry(TORQUE_ACTUAL, 16),
    ],
};

/// One PDO as the master configures it: its communication parameter's COB-ID
/// and transmission type, and its mapping.
#[derive(Clone, Copy, Debug)]
pub struct Pdo {
    /// 0x14xx:01 / 0x18xx:01.
    pub cob_id: Object,
    /// 0x14xx:02 / 0x18xx:02.
    pub transmission: Object,
    /// The mapping the master needs (the EDS default).
    pub mapping: PdoMapping,
    /// The COB-ID of CiA 301's predefined connection set for a node.
    pub predefined_cob_id: fn(CanopenNode) -> u32,
}

/// RPDO1, TPDO1, TPDO2: the PDO set the master needs.
pub const PDOS: [Pdo; 3] = [
    Pdo {
        cob_id: RPDO1_COB_ID,
        transmission: RPDO1_TRANSMISSION,
        mapping: RPDO1_MAPPING,
        predefined_cob_id: CanopenNode::rpdo1,
    },
    Pdo {
        cob_id: TPDO1_COB_ID,
        transmission: TPDO1_TRANSMISSION,
        mapping: TPDO1_MAPPING,
        predefined_cob_id: CanopenNode::tpdo1,
    },
    Pdo {
        cob_id: TPDO2_COB_ID,
        transmission: TPDO2_TRANSMISSION,
        mapping: TPDO2_MAPPING,
        predefined_cob_id: CanopenNode::tpdo2,
    },
];

/// The PDO set of a standard drive (no SYNC counter echo 0x2000): [`PDOS`]
/// with the TPDOs' last entry dropped.
pub const STANDARD_PDOS: [Pdo; 3] = [
    PDOS[0],
    Pdo {
        mapping: TPDO1_STANDARD_MAPPING,
        ..PDOS[1]
    },
    Pdo {
        mapping: TPDO2_STANDARD_MAPPING,
        ..PDOS[2]
    },
];

/// COB-ID bit 31: the PDO is not valid (disabled).
pub const PDO_NOT_VALID: u32 = 1 << 31;
/// COB-ID bit 30: no RTR allowed on this PDO (not used by this master).
pub const PDO_NO_RTR: u32 = 1 << 30;

/// One expedited SDO write of the set-up: `size` bytes of `value`, little-endian.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SdoWrite {
    /// The object written.
    pub object: Object,
    /// The value (its low `size` bytes are sent).
    pub value: u32,
    /// 1 to 4 bytes.
    pub size: usize,
}

impl SdoWrite {
    /// The value's bytes as sent.
    pub fn bytes(&self) -> Vec<u8> {
        self.value.to_le_bytes()[..self.size].to_vec()
    }
}

/// CiA 301's procedure to write `pdo`'s transmission type and mapping into
/// a drive, in the order python-canopen's `PdoMap.save` uses:
/// COB-ID with [`PDO_NOT_VALID`] set (`cob_id` is the drive's COB-ID as
/// read, so bit 30 is kept), transmission type, number of entries 0, each
/// entry, number of entries n, the COB-ID valid again.
pub fn remap_writes(pdo: &Pdo, cob_id: u32) -> Vec<SdoWrite> {
    let m = pdo.mapping;
    let count = mapping_count_object(m.index);
    let mut out = vec![
        SdoWrite {
            object: pdo.cob_id,
            value: cob_id | PDO_NOT_VALID,
            size: 4,
        },
        SdoWrite {
            object: pdo.transmission,
            value: u32::from(TRANSMISSION_EVERY_SYNC),
            size: 1,
        },
        SdoWrite {
            object: count,
            value: 0,
            size: 1,
        },
    ];
    out.extend(m.entries.iter().enumerate().map(|(i, &entry)| SdoWrite {
        object: mapping_entry_object(m.index, i),
        value: entry,
        size: 4,
    }));
    out.push(SdoWrite {
        object: count,
        value: m.entries.len() as u32,
        size: 1,
    });
    out.push(SdoWrite {
        object: pdo.cob_id,
        value: cob_id & !PDO_NOT_VALID,
        size: 4,
    });
    out
}

/// The mapping parameter's sub-index 0: the number of mapped objects.
pub fn mapping_count_object(index: u16) -> Object {
    Object {
        index,
        subindex: 0,
        name: "Number of mapped objects",
    }
}

/// The mapping parameter's sub-index `i + 1` (entry `i`).
pub fn mapping_entry_object(index: u16, i: usize) -> Object {
    Object {
        index,
        subindex: i as u8 + 1,
        name: "Mapped object",
    }
}

/// COB-ID of the NMT command (from the master to all nodes).
pub const NMT_COB_ID: u32 = 0x000;
/// COB-ID of the SYNC object (0x1005's default).
pub const SYNC_COB_ID: u32 = 0x080;

/// A CANopen node-ID, 1..=127.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct CanopenNode(u8);

impl CanopenNode {
    /// Checks the range.
    pub fn new(id: u8) -> Result<Self, Cia402Error> {
        if (1..=127).contains(&id) {
            Ok(Self(id))
        } else {
            Err(Cia402Error::InvalidNode { node: id })
        }
    }

    /// The node-ID.
    pub fn get(self) -> u8 {
        self.0
    }

    /// EMCY: 0x080 + node.
    pub fn emcy(self) -> u32 {
        0x080 + u32::from(self.0)
    }
    /// TPDO1: 0x180 + node.
    pub fn tpdo1(self) -> u32 {
        0x180 + u32::from(self.0)
    }
    /// RPDO1: 0x200 + node.
    pub fn rpdo1(self) -> u32 {
        0x200 + u32::from(self.0)
    }
    /// TPDO2: 0x280 + node.
    pub fn tpdo2(self) -> u32 {
        0x280 + u32::from(self.0)
    }
    /// SDO server to client (responses): 0x580 + node.
    pub fn sdo_tx(self) -> u32 {
        0x580 + u32::from(self.0)
    }
    /// SDO client to server (requests): 0x600 + node.
    pub fn sdo_rx(self) -> u32 {
        0x600 + u32::from(self.0)
    }
    /// Heartbeat / boot-up: 0x700 + node.
    pub fn heartbeat(self) -> u32 {
        0x700 + u32::from(self.0)
    }
}
