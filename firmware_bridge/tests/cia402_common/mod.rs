//! A scripted CiA 402 drive for the master's tests: an SDO server on the UDP
//! bus answering from a value table (by default the EDS's values, with a
//! max torque 0x6072 of choice), run in a thread until the master's NMT
//! start; the test then plays the drive's cyclic part itself on the socket
//! it gets back.

#![allow(dead_code)] // each test crate uses part of it

use std::thread::{self, JoinHandle};
use std::time::{Duration, Instant};

use sensaug_bridge::cia402::frames::{self, NmtState};
use sensaug_bridge::cia402::{od, CanopenNode};
use sensaug_bridge::transport::{Transport, UdpBus};
use sensaug_bridge::Frame;

/// The value the drive uploads for `index:sub`: the EDS's (device type,
/// mode display 10 once written, units, the SYNC counter echo, the
/// predefined PDO set) with 0x6072 = `max_torque_per_mille`; 0 for the rest.
pub fn eds_value(node: CanopenNode, max_torque_per_mille: u32, index: u16, sub: u8) -> Option<u32> {
    pdo_set_value(&od::PDOS, node, max_torque_per_mille, index, sub)
}

/// [`eds_value`] for a standard drive: no 0x2000 (its upload aborts
/// "object does not exist"), the TPDOs mapped without it
/// ([`od::STANDARD_PDOS`]).
pub fn standard_value(
    node: CanopenNode,
    max_torque_per_mille: u32,
    index: u16,
    sub: u8,
) -> Option<u32> {
    if index == od::SYNC_COUNTER_ECHO.index {
        return None;
    }
    pdo_set_value(&od::STANDARD_PDOS, node, max_torque_per_mille, index, sub)
}

fn pdo_set_value(
    pdos: &[od::Pdo],
    node: CanopenNode,
    max_torque_per_mille: u32,
    index: u16,
    sub: u8,
) -> Option<u32> {
    for &pdo in pdos {
        let at = |o: od::Object| (o.index, o.subindex) == (index, sub);
        if at(pdo.cob_id) {
            return Some((pdo.predefined_cob_id)(node));
        }
        if at(pdo.transmission) {
            return Some(u32::from(od::TRANSMISSION_EVERY_SYNC));
        }
        let m = pdo.mapping;
        if index == m.index {
            return Some(match sub {
                0 => m.entries.len() as u32,
                i => m.entries.get(usize::from(i) - 1).copied().unwrap_or(0),
            });
        }
    }
    Some(match (index, sub) {
        (0x1000, 0) => 0x0002_0192,
        (0x6061, 0) => 10,
        (0x6076, 0) => 1000,
        (0x6072, 0) => max_torque_per_mille,
        (0x608F, 1) => 1 << 20,
        (0x608F, 2) | (0x6091, 1) | (0x6091, 2) => 1,
        _ => 0,
    })
}

/// Answers SDO requests to `node` with `value_of` (an upload of None: abort
/// "object does not exist") until the master's NMT start or `run_for`;
/// first sends a heartbeat PRE-OPERATIONAL. Returns the socket and whether
/// the master started the drive.
pub fn serve_set_up(
    mut bus: UdpBus,
    node: CanopenNode,
    value_of: impl Fn(u16, u8) -> Option<u32>,
    run_for: Duration,
) -> (UdpBus, bool) {
    let start = Instant::now();
    bus.send(&frames::heartbeat(node, NmtState::PreOperational))
        .unwrap();
    while start.elapsed() < run_for {
        let Some(f) = bus.recv(Duration::from_millis(10)).unwrap() else {
            continue;
        };
        let p = f.payload();
        if f.id == 0 && p == [0x01, node.get()] {
            return (bus, true);
        }
        if f.id != node.sdo_rx() {
            continue;
        }
        let (index, sub) = (u16::from_le_bytes([p[1], p[2]]), p[3]);
        let mut reply = [0u8; 8];
        reply[1..4].copy_from_slice(&p[1..4]);
        match (p[0] & 0xE0, value_of(index, sub)) {
            (0x40, Some(v)) => {
                reply[0] = 0x43;
                reply[4..].copy_from_slice(&v.to_le_bytes());
            }
            (0x40, None) => {
                reply[0] = 0x80;
                reply[4..].copy_from_slice(&od::SDO_ABORT_NO_OBJECT.to_le_bytes());
            }
            _ => reply[0] = 0x60,
        }
        bus.send(&Frame::new(node.sdo_tx(), &reply).unwrap())
            .unwrap();
    }
    (bus, false)
}

/// A fresh UDP bus with the master's socket on it and a scripted drive,
/// node 1, on its own socket: `spawn` starts the drive's thread (e.g.
/// [`spawn_standard_drive`]). Returns the master's socket, the node and the
/// drive's thread.
pub fn on_a_bus<T>(
    spawn: impl FnOnce(UdpBus, CanopenNode) -> JoinHandle<T>,
) -> (UdpBus, CanopenNode, JoinHandle<T>) {
    let port = crate::common::free_port();
    let host = UdpBus::open(port).unwrap();
    let node = CanopenNode::new(1).unwrap();
    let drive = spawn(UdpBus::open(port).unwrap(), node);
    (host, node, drive)
}

/// [`serve_set_up`] with [`eds_value`] in a thread.
pub fn spawn_eds_drive(
    bus: UdpBus,
    node: CanopenNode,
    max_torque_per_mille: u32,
) -> JoinHandle<(UdpBus, bool)> {
    thread::spawn(move || {
        serve_set_up(
            bus,
            node,
            |i, s| eds_value(node, max_torque_per_mille, i, s),
            Duration::from_secs(3),
        )
    })
}

/// [`serve_set_up`] with [`standard_value`] in a thread: a standard drive.
pub fn spawn_standard_drive(bus: UdpBus, node: CanopenNode) -> JoinHandle<(UdpBus, bool)> {
    thread::spawn(move || {
        serve_set_up(
            bus,
            node,
            |i, s| standard_value(node, 3000, i, s),
            Duration::from_secs(3),
        )
    })
}

/// A standard drive's TPDO1 (statusword, position: 6 bytes) from `node`.
pub fn standard_tpdo1(node: CanopenNode, statusword: u16, position: i32) -> Frame {
    let (s, p) = (statusword.to_le_bytes(), position.to_le_bytes());
    Frame::new(node.tpdo1(), &[s[0], s[1], p[0], p[1], p[2], p[3]]).unwrap()
}

/// A standard drive's TPDO2 (velocity, torque: 6 bytes) from `node`.
pub fn standard_tpdo2(node: CanopenNode, velocity: i32, torque: i16) -> Frame {
    let (v, t) = (velocity.to_le_bytes(), torque.to_le_bytes());
    Frame::new(node.tpdo2(), &[v[0], v[1], v[2], v[3], t[0], t[1]]).unwrap()
}

/// A TPDO1 (statusword, position, SYNC counter echo) from `node`.
pub fn tpdo1(node: CanopenNode, statusword: u16, position: i32, echo: u8) -> Frame {
    let (s, p) = (statusword.to_le_bytes(), position.to_le_bytes());
    Frame::new(node.tpdo1(), &[s[0], s[1], p[0], p[1], p[2], p[3], echo]).unwrap()
}

/// A TPDO2 (velocity, torque, SYNC counter echo) from `node`.
pub fn tpdo2(node: CanopenNode, velocity: i32, torque: i16, echo: u8) -> Frame {
    let (v, t) = (velocity.to_le_bytes(), torque.to_le_bytes());
    Frame::new(node.tpdo2(), &[v[0], v[1], v[2], v[3], t[0], t[1], echo]).unwrap()
}

/// Reads frames on `bus` until a SYNC; returns the RPDO1 payload before it
/// (if any) and the SYNC's counter.
pub fn next_cycle(bus: &mut UdpBus, node: CanopenNode) -> (Option<[u8; 4]>, u8) {
    let mut rpdo = None;
    loop {
        let f = bus
            .recv(Duration::from_secs(1))
            .unwrap()
            .expect("no SYNC within 1 s");
        if f.id == node.rpdo1() {
            rpdo = Some(<[u8; 4]>::try_from(f.payload()).unwrap());
        }
        if f.id == od::SYNC_COB_ID {
            return (rpdo, f.payload()[0]);
        }
    }
}
