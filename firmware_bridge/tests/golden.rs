//! The Rust codec against cantools, frame by frame.
//!
//! `golden/frames.json` is cantools' encoding of hi5.dbc for a fixed list
//! of messages (`tools/make_golden.py`; `tests/test_bridge_golden.py` checks
//! the committed file is exactly that script's output). For every entry:
//! `encode` must give the same id and bytes; `decode` of those bytes must
//! give cantools' decoded values bit for bit, and be within half an LSB of
//! the physical input.

use std::collections::HashSet;

use sensaug_bridge::protocol::{
    decode, encode, DriveState, FaultFlags, Message, NodeId, POSITION_SCALE_RAD, TORQUE_SCALE_NM,
    VELOCITY_SCALE_RAD_S,
};
use sensaug_bridge::Frame;
use serde_json::Value;

fn load() -> Vec<Value> {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/golden/frames.json");
    let text = std::fs::read_to_string(path).expect("golden/frames.json");
    let doc: Value = serde_json::from_str(&text).expect("valid JSON");
    doc["frames"].as_array().expect("frames array").clone()
}

fn f(v: &Value, key: &str) -> f64 {
    v[key]
        .as_f64()
        .unwrap_or_else(|| panic!("{key} not a number: {v}"))
}

fn u(v: &Value, key: &str) -> u64 {
    v[key]
        .as_u64()
        .unwrap_or_else(|| panic!("{key} not an unsigned integer: {v}"))
}

fn u8_of(v: &Value, key: &str) -> u8 {
    u8::try_from(u(v, key)).unwrap()
}

fn state_of(v: &Value, key: &str) -> DriveState {
    DriveState::from_raw(u8_of(v, key)).unwrap()
}

/// The Message for one entry's physical signals (DBC names).
fn message(name: &str, s: &Value) -> Message {
    match name {
        "TorqueCommand" => Message::TorqueCommand {
            torque_nm: f(s, "torque"),
            sequence: u8_of(s, "sequence"),
        },
        "Feedback" => Message::Feedback {
            position_rad: f(s, "position"),
            velocity_rad_s: f(s, "velocity"),
            sequence: u8_of(s, "sequence"),
            state: state_of(s, "state"),
            torque_limited: u(s, "torque_limited") == 1,
            fault_active: u(s, "fault_active") == 1,
        },
        "Heartbeat" => Message::Heartbeat {
            state: state_of(s, "state"),
            fault_flags: FaultFlags::from_bits_retain(u16::try_from(u(s, "fault_flags")).unwrap()),
            counter: u8_of(s, "counter"),
            crc_errors: u8_of(s, "crc_errors"),
            length_errors: u8_of(s, "length_errors"),
            sequence_errors: u8_of(s, "sequence_errors"),
            unknown_ids: u8_of(s, "unknown_ids"),
            range_errors: u8_of(s, "range_errors"),
        },
        "Fault" => Message::Fault {
            state: state_of(s, "state"),
            fault_flags: FaultFlags::from_bits_retain(u16::try_from(u(s, "fault_flags")).unwrap()),
            counter: u8_of(s, "counter"),
        },
        "SetState" => Message::SetState {
            enable: u(s, "request") == 1,
            watchdog_ms: u16::try_from(u(s, "watchdog_ms")).unwrap(),
            sequence: u8_of(s, "sequence"),
        },
        "EmergencyStop" => Message::EmergencyStop,
        "ClearFaults" => Message::ClearFaults,
        other => panic!("unknown message {other}"),
    }
}

fn hex_bytes(s: &str) -> Vec<u8> {
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}

/// `got` equals cantools' decode exactly and is within half an LSB of the
/// input (the half LSB widened by 1e-9 relative for the float arithmetic).
fn check_scaled(label: &str, signal: &str, got: f64, cantools: f64, input: f64, scale: f64) {
    assert_eq!(
        got.to_bits(),
        cantools.to_bits(),
        "{label}: {signal} decoded {got:e}, cantools {cantools:e}"
    );
    let err = (got - input).abs();
    assert!(
        err <= 0.5 * scale * (1.0 + 1e-9),
        "{label}: {signal} decoded {got:e}, input {input:e}, |delta| {err:e} > half LSB {:e}",
        0.5 * scale
    );
}

#[test]
fn golden_frames_encode_and_decode_like_cantools() {
    let frames = load();
    assert!(frames.len() >= 200, "only {} golden frames", frames.len());
    let mut kinds = HashSet::new();
    for g in &frames {
        let label = g["label"].as_str().unwrap();
        let name = g["message"].as_str().unwrap();
        kinds.insert(name.to_owned());
        let node = NodeId::new(u(g, "node") as u32).unwrap();
        let id = u32::try_from(u(g, "id")).unwrap();
        let bytes = hex_bytes(g["data"].as_str().unwrap());
        let signals = &g["signals"];
        let cantools = &g["decoded"];

        // Encode.
        let msg = message(name, signals);
        let frame = encode(node, &msg).unwrap_or_else(|e| panic!("{label}: {e}"));
        assert_eq!(frame.id, id, "{label}: id");
        assert_eq!(
            frame.payload(),
            &bytes[..],
            "{label}: encoded {:02x?}, cantools {:02x?}",
            frame.payload(),
            bytes
        );
        if name == "TorqueCommand" {
            let crc = u64::from(u16::from_le_bytes([bytes[6], bytes[7]]));
            assert_eq!(u(signals, "crc16"), crc, "{label}: crc16");
        }

        // Decode cantools' bytes.
        let wire = Frame::new(id, &bytes).unwrap();
        let back = decode(node, &wire).unwrap_or_else(|e| panic!("{label}: {e}"));
        match back {
            Message::TorqueCommand {
                torque_nm,
                sequence,
            } => {
                check_scaled(
                    label,
                    "torque",
                    torque_nm,
                    f(cantools, "torque"),
                    f(signals, "torque"),
                    TORQUE_SCALE_NM,
                );
                assert_eq!(sequence, u8_of(signals, "sequence"), "{label}");
            }
            Message::Feedback {
                position_rad,
                velocity_rad_s,
                ..
            } => {
                check_scaled(
                    label,
                    "position",
                    position_rad,
                    f(cantools, "position"),
                    f(signals, "position"),
                    POSITION_SCALE_RAD,
                );
                check_scaled(
                    label,
                    "velocity",
                    velocity_rad_s,
                    f(cantools, "velocity"),
                    f(signals, "velocity"),
                    VELOCITY_SCALE_RAD_S,
                );
                // The integer fields must round-trip exactly: the decoded
                // message is the input with the decoded position and velocity.
                let mut want = msg;
                if let Message::Feedback {
                    position_rad: p,
                    velocity_rad_s: v,
                    ..
                } = &mut want
                {
                    (*p, *v) = (position_rad, velocity_rad_s);
                }
                assert_eq!(back, want, "{label}");
            }
            // No scaled signals: exact equality.
            other => assert_eq!(other, msg, "{label}"),
        }
    }
    let all = [
        "TorqueCommand",
        "Feedback",
        "Heartbeat",
        "Fault",
        "SetState",
        "EmergencyStop",
        "ClearFaults",
    ];
    for k in all {
        assert!(kinds.contains(k), "no golden {k}");
    }
}
