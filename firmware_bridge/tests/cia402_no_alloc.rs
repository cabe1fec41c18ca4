//! The CiA 402 master's per-tick calls ([`Master::tick`]: RPDO1 + SYNC and
//! the heartbeat when due; [`Master::drain`]: TPDO1, TPDO2, EMCY and
//! heartbeat decoding, the drive-heartbeat check) allocate nothing: a
//! counting global allocator over 1000 warmed-up ticks against a scripted
//! drive on the UDP bus must read 0 (counted on this test's thread only).

use std::time::Duration;

use sensaug_bridge::cia402::frames::{self, NmtState};
use sensaug_bridge::cia402::{CanopenNode, Master, MasterSettings};
use sensaug_bridge::transport::{Transport, UdpBus};
use sensaug_bridge::Frame;

#[path = "../../crates/sensaug-core/tests/common/alloc_counter.rs"]
mod alloc_counter;

use alloc_counter::allocations;

mod common;

fn frame(id: u32, payload: &[u8]) -> Frame {
    Frame::new(id, payload).unwrap()
}

/// One tick: the master sends, the scripted drive answers every SYNC with
/// TPDO1 + TPDO2 echoing its counter (and a heartbeat and an EMCY now and
/// then), the master drains.
fn tick(master: &mut Master, host: &mut UdpBus, drive: &mut UdpBus, node: CanopenNode, i: i32) {
    master.tick(host, f64::from(i % 100) * 1e-3).unwrap();
    let counter = loop {
        let f = drive.recv(Duration::from_secs(1)).unwrap().unwrap();
        if f.id == 0x080 {
            break f.payload()[0];
        }
    };
    let sw = 0x0237u16.to_le_bytes();
    let pos = (i * 1000).to_le_bytes();
    drive
        .send(&frame(
            node.tpdo1(),
            &[sw[0], sw[1], pos[0], pos[1], pos[2], pos[3], counter],
        ))
        .unwrap();
    let vel = (-i).to_le_bytes();
    drive
        .send(&frame(
            node.tpdo2(),
            &[vel[0], vel[1], vel[2], vel[3], 7, 0, counter],
        ))
        .unwrap();
    if i % 10 == 0 {
        drive
            .send(&frames::heartbeat(node, NmtState::Operational))
            .unwrap();
        drive
            .send(&frame(node.emcy(), &[0x11, 0x86, 1, 0, 0, 0, 0, 0]))
            .unwrap();
    }
    // Wait until both TPDOs are in, then drain without waiting.
    let before = master.feedback().tpdo2_received;
    while master.feedback().tpdo2_received == before {
        master.drain(host).unwrap();
    }
    assert!(master.last_sync_answered());
}

#[test]
fn tick_and_drain_do_not_allocate() {
    let port = common::free_port();
    let mut host = UdpBus::open(port).unwrap();
    let mut drive = UdpBus::open(port).unwrap();
    let node = CanopenNode::new(1).unwrap();
    let mut settings = MasterSettings::new(node);
    settings.heartbeat_period = Duration::from_millis(1);
    let mut master = Master::new(settings).unwrap();
    for i in 0..100 {
        tick(&mut master, &mut host, &mut drive, node, i);
    }
    let n = allocations(|| {
        for i in 0..1000 {
            tick(&mut master, &mut host, &mut drive, node, i);
        }
    });
    assert_eq!(n, 0, "allocations in 1000 ticks");
    let fb = master.feedback();
    assert_eq!(fb.tpdo1_received, 1100);
    assert_eq!(fb.emcy_received, 110);
    assert_eq!(fb.last_emcy.unwrap().code, 0x8611);
    assert_eq!(fb.decode_errors, 0);
    assert_eq!(fb.torque_nm, 7e-3);
    assert_eq!(master.syncs_sent(), 1100);
}
