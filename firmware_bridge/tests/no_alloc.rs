//! The per-frame paths (encode, decode, wire conversion, UDP send and recv,
//! including dropped own and malformed datagrams and timeouts) allocate
//! nothing: a counting global allocator over warmed-up iterations must read
//! 0 (counted on this test's thread only).

use std::net::{SocketAddrV4, UdpSocket};
use std::time::Duration;

use sensaug_bridge::protocol::{decode, encode, DriveState, Message, NodeId};
use sensaug_bridge::transport::{Transport, UdpBus, UDP_BUS_ADDR};
use sensaug_bridge::Frame;

#[path = "../../crates/sensaug-core/tests/common/alloc_counter.rs"]
mod alloc_counter;

use alloc_counter::allocations;

mod common;

fn tick(host: &mut UdpBus, drive: &mut UdpBus, raw: &UdpSocket, dest: SocketAddrV4, i: u32) {
    let node = NodeId::new(i % 16).unwrap();
    let cmd = Message::TorqueCommand {
        torque_nm: f64::from(i) * 1e-3 - 1.0,
        sequence: i as u8,
    };
    let f = encode(node, &cmd).unwrap();
    host.send(&f).unwrap();
    let got = drive.recv(Duration::from_secs(1)).unwrap().unwrap();
    let Message::TorqueCommand { sequence, .. } = decode(node, &got).unwrap() else {
        panic!("not a torque command");
    };
    let fb = Message::Feedback {
        position_rad: 0.1,
        velocity_rad_s: -0.2,
        sequence,
        state: DriveState::Enabled,
        torque_limited: false,
        fault_active: false,
    };
    drive.send(&encode(node, &fb).unwrap()).unwrap();
    // Garbage the host must skip on its way to the feedback.
    raw.send_to(&[0u8; 5], dest).unwrap();
    let back = host.recv(Duration::from_secs(1)).unwrap().unwrap();
    decode(node, &back).unwrap();
    let _ = Frame::from_wire(&back.to_wire()).unwrap();
    // Nothing left: a short timeout that ends in Ok(None).
    assert!(host.recv(Duration::from_micros(200)).unwrap().is_none());
}

#[test]
fn per_frame_paths_do_not_allocate() {
    let port = common::free_port();
    let mut host = UdpBus::open(port).unwrap();
    let mut drive = UdpBus::open(port).unwrap();
    let raw = UdpSocket::bind("127.0.0.1:0").unwrap();
    raw.set_broadcast(true).unwrap();
    let dest = SocketAddrV4::new(UDP_BUS_ADDR, port);

    for i in 0..100 {
        tick(&mut host, &mut drive, &raw, dest, i);
    }
    let n = allocations(|| {
        for i in 0..1000 {
            tick(&mut host, &mut drive, &raw, dest, i);
        }
    });
    assert_eq!(n, 0, "allocations in 1000 ticks");
    assert_eq!(host.stats().malformed_dropped, 1100);
    assert!(host.stats().own_dropped >= 1100);
}
