//! Every protocol error variant, round trips, ids, sequence window.

use sensaug_bridge::protocol::torque_command_crc;
use sensaug_bridge::protocol::{
    crc16_ibm_3740, decode, decode_any, encode, seq_is_newer, DecodeError, DriveState, EncodeError,
    FaultFlags, Message, MessageKind, NodeId,
};
use sensaug_bridge::Frame;

fn node(n: u32) -> NodeId {
    NodeId::new(n).unwrap()
}

/// A disabled drive's Feedback at this position (rad) and velocity (rad/s).
fn fb(position_rad: f64, velocity_rad_s: f64) -> Message {
    Message::Feedback {
        position_rad,
        velocity_rad_s,
        sequence: 0,
        state: DriveState::Disabled,
        torque_limited: false,
        fault_active: false,
    }
}

fn samples() -> [Message; 7] {
    [
        Message::TorqueCommand {
            torque_nm: -1.25,
            sequence: 7,
        },
        Message::Feedback {
            position_rad: 0.5,
            velocity_rad_s: -3.0,
            sequence: 7,
            state: DriveState::Enabled,
            torque_limited: true,
            fault_active: false,
        },
        Message::Heartbeat {
            state: DriveState::Fault,
            fault_flags: FaultFlags::WATCHDOG | FaultFlags::OVERSPEED,
            counter: 200,
            crc_errors: 1,
            length_errors: 2,
            sequence_errors: 3,
            unknown_ids: 4,
            range_errors: 5,
        },
        Message::SetState {
            enable: true,
            watchdog_ms: 20,
            sequence: 9,
        },
        Message::EmergencyStop,
        Message::ClearFaults,
        Message::Fault {
            state: DriveState::Fault,
            fault_flags: FaultFlags::EMERGENCY_STOP,
            counter: 9,
        },
    ]
}

#[test]
fn node_ids() {
    assert_eq!(node(0).get(), 0);
    assert_eq!(node(15).get(), 15);
    let e = NodeId::new(16).unwrap_err();
    assert_eq!(e.got, 16);
    assert!(e.to_string().contains("0..=15"));
}

#[test]
fn ids_are_base_plus_node_and_unique() {
    let mut seen = std::collections::HashSet::new();
    for kind in MessageKind::ALL {
        for n in 0..=15 {
            let id = kind.id(node(n));
            assert_eq!(id, kind.base_id() + n);
            assert!(id <= 0x7FF);
            assert!(seen.insert(id), "id {id:#x} used twice");
            assert_eq!(MessageKind::from_id(id), Some((kind, node(n))));
        }
    }
    // The DBC's node-1 ids.
    assert_eq!(MessageKind::EmergencyStop.id(node(1)), 17);
    assert_eq!(MessageKind::Fault.id(node(1)), 129);
    assert_eq!(MessageKind::TorqueCommand.id(node(1)), 513);
    assert_eq!(MessageKind::Feedback.id(node(1)), 641);
    assert_eq!(MessageKind::SetState.id(node(1)), 769);
    assert_eq!(MessageKind::ClearFaults.id(node(1)), 801);
    assert_eq!(MessageKind::Heartbeat.id(node(1)), 1793);
    assert_eq!(MessageKind::from_id(0x7FF), None);
    assert_eq!(MessageKind::from_id(0x00F), None);
}

#[test]
fn every_message_round_trips_on_every_node() {
    for n in 0..=15 {
        for msg in samples() {
            let frame = encode(node(n), &msg).unwrap();
            assert_eq!(frame.len, msg.kind().dlc());
            assert_eq!(frame.id, msg.kind().id(node(n)));
            assert_eq!(decode(node(n), &frame).unwrap(), msg);
            assert_eq!(decode_any(&frame).unwrap(), (node(n), msg));
            let wire = Frame::from_wire(&frame.to_wire()).unwrap();
            assert_eq!(wire, frame);
        }
    }
}

#[test]
fn encode_rejects_non_finite_naming_the_signal() {
    for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        let e = encode(
            node(1),
            &Message::TorqueCommand {
                torque_nm: bad,
                sequence: 0,
            },
        )
        .unwrap_err();
        assert!(
            matches!(
                e,
                EncodeError::NotFinite {
                    signal: "TorqueCommand.torque",
                    ..
                }
            ),
            "{e:?}"
        );
        assert!(e
            .to_string()
            .starts_with("TorqueCommand.torque: must be finite"));
        assert!(matches!(
            encode(node(1), &fb(bad, 0.0)),
            Err(EncodeError::NotFinite {
                signal: "Feedback.position",
                ..
            })
        ));
        assert!(matches!(
            encode(node(1), &fb(0.0, bad)),
            Err(EncodeError::NotFinite {
                signal: "Feedback.velocity",
                ..
            })
        ));
    }
}

#[test]
fn encode_rejects_out_of_range_never_wraps() {
    let torque = |t| Message::TorqueCommand {
        torque_nm: t,
        sequence: 0,
    };
    // The extremes themselves are fine ...
    assert!(encode(node(1), &torque(10.0)).is_ok());
    assert!(encode(node(1), &torque(-10.0)).is_ok());
    // ... one LSB past them is not.
    for t in [10.000001, -10.000001, 2147.483647, 1e12, -1e12] {
        let e = encode(node(1), &torque(t)).unwrap_err();
        match e {
            EncodeError::OutOfRange {
                signal,
                value,
                min,
                max,
            } => {
                assert_eq!(signal, "TorqueCommand.torque");
                assert_eq!(value, t);
                assert_eq!((min, max), (-10.0, 10.0));
            }
            other => panic!("{other:?}"),
        }
        assert!(e.to_string().contains("TorqueCommand.torque"), "{e}");
    }
    assert!(encode(node(1), &fb(8.388607, 8.388607)).is_ok());
    assert!(encode(node(1), &fb(-8.388608, -8.388608)).is_ok());
    assert!(matches!(
        encode(node(1), &fb(8.388608, 0.0)),
        Err(EncodeError::OutOfRange {
            signal: "Feedback.position",
            ..
        })
    ));
    assert!(matches!(
        encode(node(1), &fb(0.0, 8.388608)),
        Err(EncodeError::OutOfRange {
            signal: "Feedback.velocity",
            ..
        })
    ));
    assert!(matches!(
        encode(node(1), &fb(0.0, -65.538)),
        Err(EncodeError::OutOfRange {
            signal: "Feedback.velocity",
            ..
        })
    ));
    let e = encode(
        node(1),
        &Message::SetState {
            enable: true,
            watchdog_ms: 0,
            sequence: 0,
        },
    )
    .unwrap_err();
    assert!(
        matches!(e, EncodeError::OutOfRange { signal: "SetState.watchdog_ms", value, .. } if value == 0.0),
        "{e:?}"
    );
}

#[test]
fn encode_rounds_to_nearest_ties_to_even() {
    let raw = |t: f64| {
        let f = encode(
            node(1),
            &Message::TorqueCommand {
                torque_nm: t,
                sequence: 0,
            },
        )
        .unwrap();
        i32::from_le_bytes([f.data[0], f.data[1], f.data[2], f.data[3]])
    };
    assert_eq!(raw(0.4e-6), 0);
    assert_eq!(raw(0.6e-6), 1);
    assert_eq!(raw(-0.6e-6), -1);
    assert_eq!(raw(0.5e-6), 0); // tie -> even
    assert_eq!(raw(1.5e-6), 2); // tie -> even
    assert_eq!(raw(1.0), 1_000_000);
}

fn torque_frame(n: u32) -> Frame {
    encode(
        node(n),
        &Message::TorqueCommand {
            torque_nm: 0.125,
            sequence: 42,
        },
    )
    .unwrap()
}

#[test]
fn decode_unknown_id() {
    let f = Frame::new(0x123, &[]).unwrap();
    assert_eq!(
        decode(node(1), &f),
        Err(DecodeError::UnknownId { id: 0x123 })
    );
    assert_eq!(decode_any(&f), Err(DecodeError::UnknownId { id: 0x123 }));
    // Another node's frame is not this node's.
    let other = torque_frame(2);
    assert_eq!(
        decode(node(1), &other),
        Err(DecodeError::UnknownId { id: 0x202 })
    );
    assert!(decode(node(1), &other)
        .unwrap_err()
        .to_string()
        .contains("0x202"));
}

#[test]
fn decode_wrong_length_for_every_kind() {
    for kind in MessageKind::ALL {
        let wrong = if kind.dlc() == 0 { 1 } else { kind.dlc() - 1 };
        let f = Frame {
            id: kind.id(node(3)),
            len: wrong,
            data: [0; 8],
            ..Frame::default()
        };
        assert_eq!(
            decode(node(3), &f),
            Err(DecodeError::WrongLength {
                message: kind.name(),
                expected: kind.dlc(),
                got: wrong
            }),
            "{kind:?}"
        );
    }
}

#[test]
fn decode_bad_crc_any_flipped_bit() {
    let good = torque_frame(1);
    for byte in 0..8 {
        for bit in 0..8 {
            let mut f = good;
            f.data[byte] ^= 1 << bit;
            match decode(node(1), &f) {
                Err(DecodeError::BadCrc { expected, got }) => assert_ne!(expected, got),
                other => panic!("byte {byte} bit {bit}: {other:?}"),
            }
        }
    }
    let mut f = good;
    f.data[7] ^= 0xFF;
    assert!(decode(node(1), &f)
        .unwrap_err()
        .to_string()
        .contains("TorqueCommand.crc16"));
}

#[test]
fn the_crc_covers_the_frame_id_as_data_id() {
    // Node 1's command, byte for byte, sent under node 2's id: bad CRC.
    let mut f = torque_frame(1);
    f.id = MessageKind::TorqueCommand.id(node(2));
    assert!(matches!(
        decode(node(2), &f),
        Err(DecodeError::BadCrc { .. })
    ));
    let c = torque_command_crc(0x201, &torque_frame(1).data[..6]);
    assert_eq!(torque_frame(1).data[6..8], c.to_le_bytes());
}

#[test]
fn decode_invalid_values() {
    // TorqueCommand with non-zero reserved bytes but a valid CRC.
    let mut f = torque_frame(1);
    f.data[5] = 1;
    let crc = torque_command_crc(f.id, &f.data[..6]);
    f.data[6..8].copy_from_slice(&crc.to_le_bytes());
    assert_eq!(
        decode(node(1), &f),
        Err(DecodeError::InvalidValue {
            signal: "TorqueCommand.reserved",
            raw: 1
        })
    );

    let status = |kind: MessageKind, d0: u8| Frame {
        id: kind.id(node(1)),
        len: kind.dlc(),
        data: [d0, 0, 0, 0, 0, 0, 0, 0],
        ..Frame::default()
    };
    assert_eq!(
        decode(node(1), &status(MessageKind::Heartbeat, 4)),
        Err(DecodeError::InvalidValue {
            signal: "Heartbeat.state",
            raw: 4
        })
    );
    assert_eq!(
        decode(node(1), &status(MessageKind::Fault, 255)),
        Err(DecodeError::InvalidValue {
            signal: "Fault.state",
            raw: 255
        })
    );

    let set_state = |req: u8, wd: u16| {
        let [w0, w1] = wd.to_le_bytes();
        Frame::new(MessageKind::SetState.id(node(1)), &[req, w0, w1, 0]).unwrap()
    };
    assert_eq!(
        decode(node(1), &set_state(2, 10)),
        Err(DecodeError::InvalidValue {
            signal: "SetState.request",
            raw: 2
        })
    );
    for wd in [0, 4, 201, 65535] {
        let e = decode(node(1), &set_state(1, wd)).unwrap_err();
        assert_eq!(
            e,
            DecodeError::InvalidValue {
                signal: "SetState.watchdog_ms",
                raw: u32::from(wd)
            }
        );
        assert!(e.to_string().contains("SetState.watchdog_ms"));
    }
    assert_eq!(
        decode(node(1), &set_state(0, 200)).unwrap(),
        Message::SetState {
            enable: false,
            watchdog_ms: 200,
            sequence: 0,
        }
    );
}

#[test]
fn feedback_reserved_bits_are_ignored_like_cantools() {
    let mut f = encode(node(1), &samples()[1]).unwrap();
    f.data[7] |= 0xF0;
    assert_eq!(decode(node(1), &f).unwrap(), samples()[1]);
}

#[test]
fn crc16_catalogue_check_value() {
    assert_eq!(crc16_ibm_3740(b"123456789"), 0x29B1);
}

#[test]
fn sequence_window() {
    assert!(seq_is_newer(0, 1));
    assert!(seq_is_newer(255, 0));
    assert!(seq_is_newer(250, 3));
    assert!(seq_is_newer(0, 127));
    assert!(!seq_is_newer(0, 128));
    assert!(!seq_is_newer(5, 5));
    assert!(!seq_is_newer(1, 0));
    assert!(!seq_is_newer(0, 255));
    // Exactly one of a, b is newer than the other unless equal or 128 apart.
    for a in 0..=255u8 {
        for b in 0..=255u8 {
            let d = b.wrapping_sub(a);
            let expected = (1..=127).contains(&d);
            assert_eq!(seq_is_newer(a, b), expected, "{a} -> {b}");
            if d != 0 && d != 128 {
                assert_ne!(seq_is_newer(a, b), seq_is_newer(b, a), "{a} {b}");
            }
        }
    }
}

#[test]
fn fault_flags_ops() {
    let mut f = FaultFlags::empty();
    assert!(f.is_empty());
    f.insert(FaultFlags::WATCHDOG);
    f |= FaultFlags::INTERNAL;
    assert!(f.contains(FaultFlags::WATCHDOG | FaultFlags::INTERNAL));
    assert!(!f.contains(FaultFlags::OVERSPEED));
    assert_eq!(f.bits(), 0b1001);
    f.remove(FaultFlags::WATCHDOG);
    assert_eq!(f, FaultFlags::INTERNAL);
    assert_eq!(
        format!("{:?}", FaultFlags::from_bits_retain(0x8003)),
        "FaultFlags(WATCHDOG | EMERGENCY_STOP | 0x8000)"
    );
    assert_eq!(format!("{:?}", FaultFlags::empty()), "FaultFlags(0x0000)");
}

#[test]
fn extended_remote_and_error_frames_are_not_protocol_frames() {
    let good = torque_frame(1);
    let ext = Frame {
        extended: true,
        ..good
    };
    let rtr = Frame::remote(good.id, false, 8).unwrap();
    let err = Frame {
        kind: sensaug_bridge::FrameKind::Error,
        ..good
    };
    for f in [ext, rtr, err] {
        let e = decode_any(&f).unwrap_err();
        assert_eq!(e, DecodeError::UnknownId { id: f.can_id() }, "{f:?}");
        assert!(e.to_string().contains("standard data frames"), "{e}");
    }
    assert!(decode_any(&good).is_ok());
}
