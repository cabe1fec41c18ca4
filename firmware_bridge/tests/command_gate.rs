//! The drive's TorqueCommand acceptance (`CommandGate`): stray frames never
//! become torque.

use sensaug_bridge::protocol::{torque_command_crc, DecodeError};
use sensaug_bridge::{encode, CommandGate, Frame, Message, MessageKind, NodeId, Rejection};

const LIMIT_NM: f64 = 3.0;

fn node(n: u32) -> NodeId {
    NodeId::new(n).unwrap()
}

/// xorshift64*: a fixed, dependency-free stream of test bytes.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
}

fn command(n: u32, torque_nm: f64, sequence: u8) -> Frame {
    encode(
        node(n),
        &Message::TorqueCommand {
            torque_nm,
            sequence,
        },
    )
    .unwrap()
}

#[test]
fn none_of_a_million_random_payloads_is_applied() {
    let id = MessageKind::TorqueCommand.id(node(1));
    let mut gate = CommandGate::new(node(1), LIMIT_NM);
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    let (mut crc_ok, mut applied, mut latched) = (0u32, 0u32, 0u32);
    for _ in 0..1_000_000 {
        // Worst case: the gate always enabled, expecting some sequence.
        if gate.expected().is_none() {
            gate.resync(rng.next() as u8);
        }
        let frame = Frame::new(id, &rng.next().to_le_bytes()).unwrap();
        match gate.admit(&frame) {
            Ok(t) => {
                applied += 1;
                eprintln!("applied {t} N m from {:02x?}", frame.data);
            }
            Err(Rejection::Decode(DecodeError::BadCrc { .. })) => {}
            Err(Rejection::Sequence { .. }) => {
                crc_ok += 1;
                latched += 1;
            }
            Err(other) => {
                crc_ok += 1;
                let _ = other;
            }
        }
    }
    println!(
        "1e6 random payloads: {crc_ok} passed the CRC-16, {latched} of those latched a \
         sequence fault, {applied} applied"
    );
    assert_eq!(applied, 0);
    // CRC-16 lets ~1 in 65536 through; the rest of the gate must stop them.
    assert!(crc_ok < 60, "{crc_ok} random payloads passed the CRC");
}

#[test]
fn valid_frames_with_random_sequences_are_accepted_only_in_order() {
    let mut gate = CommandGate::new(node(1), LIMIT_NM);
    let mut rng = Rng(42);
    let mut accepted = 0;
    for _ in 0..1000 {
        let expected = rng.next() as u8;
        gate.resync(expected);
        let seq = rng.next() as u8;
        match gate.admit(&command(1, 0.5, seq)) {
            Ok(t) => {
                assert_eq!(seq, expected);
                assert_eq!(t, 0.5);
                assert_eq!(gate.expected(), Some(expected.wrapping_add(1)));
                accepted += 1;
            }
            Err(Rejection::Sequence { expected: e, got }) => {
                assert_eq!((e, got), (expected, seq));
                assert_ne!(seq, expected);
                // Latched: nothing more until the next resync.
                assert_eq!(gate.expected(), None);
                assert_eq!(
                    gate.admit(&command(1, 0.5, expected)),
                    Err(Rejection::NotEnabled)
                );
            }
            other => panic!("{other:?}"),
        }
    }
    println!("1000 valid frames, random sequences: {accepted} accepted (each the expected one)");
    assert!(accepted < 20, "{accepted}");
}

#[test]
fn a_stream_wraps_and_a_second_source_is_caught() {
    let mut gate = CommandGate::new(node(3), LIMIT_NM);
    assert_eq!(gate.admit(&command(3, 0.0, 0)), Err(Rejection::NotEnabled));
    gate.resync(250);
    for k in 0..300u32 {
        let seq = (250 + k) as u8;
        assert_eq!(gate.admit(&command(3, 0.125, seq)), Ok(0.125), "{k}");
    }
    // A second host replaying the previous command: caught, and latched.
    let next = gate.expected().unwrap();
    assert_eq!(
        gate.admit(&command(3, 0.1, next.wrapping_sub(1))),
        Err(Rejection::Sequence {
            expected: next,
            got: next.wrapping_sub(1)
        })
    );
    assert_eq!(
        gate.admit(&command(3, 0.1, next)),
        Err(Rejection::NotEnabled)
    );
    // Another node's command is not this drive's.
    gate.resync(0);
    assert!(matches!(
        gate.admit(&command(4, 0.1, 0)),
        Err(Rejection::Decode(DecodeError::UnknownId { .. }))
    ));
}

#[test]
fn out_of_range_torque_is_rejected_not_clamped() {
    let mut gate = CommandGate::new(node(1), LIMIT_NM);
    gate.resync(7);
    assert_eq!(
        gate.admit(&command(1, 3.5, 7)),
        Err(Rejection::Range {
            torque_nm: 3.5,
            limit_nm: LIMIT_NM
        })
    );
    // The sequence was consumed: the stream goes on.
    assert_eq!(gate.admit(&command(1, -3.0, 8)), Ok(-3.0));
    // One LSB (1 uN m) past the limit.
    assert!(matches!(
        gate.admit(&command(1, -3.000001, 9)),
        Err(Rejection::Range { torque_nm, .. }) if (torque_nm + 3.000001).abs() < 1e-9
    ));
    // Beyond the DBC's range it does not even encode; raw bytes for it fail
    // to decode (range checked after the CRC).
    let mut f = command(1, 0.0, 10);
    f.data[0..4].copy_from_slice(&(2_000_000_000i32).to_le_bytes());
    let crc = torque_command_crc(f.id, &f.data[..6]);
    f.data[6..8].copy_from_slice(&crc.to_le_bytes());
    assert_eq!(
        gate.admit(&f),
        Err(Rejection::Decode(DecodeError::InvalidValue {
            signal: "TorqueCommand.torque",
            raw: 2_000_000_000
        }))
    );
}

#[test]
fn the_shutdown_zero_torque_command_is_accepted() {
    // The controller's last loop command has sequence (k - 1) & 0xff; its
    // shutdown command carries k & 0xff.
    let mut gate = CommandGate::new(node(1), LIMIT_NM);
    gate.resync(255);
    let ticks = 1000u32;
    assert_eq!(gate.admit(&command(1, 0.0, 255)), Ok(0.0));
    for k in 0..ticks {
        assert_eq!(gate.admit(&command(1, 0.25, k as u8)), Ok(0.25));
    }
    assert_eq!(gate.admit(&command(1, 0.0, ticks as u8)), Ok(0.0));
}
