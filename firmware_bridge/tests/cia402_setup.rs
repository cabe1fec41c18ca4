//! [`Master::boot`] refuses a drive without the SYNC counter echo 0x2000 (an
//! off-the-shelf CiA 402 drive): a scripted SDO server on the UDP bus answers
//! every upload with the EDS's values and aborts the read of 0x2000 with
//! "object does not exist"; the master must stop there with
//! [`Cia402Error::NoSyncCounterEcho`], before starting the drive.

use std::thread;
use std::time::{Duration, Instant};

use sensaug_bridge::cia402::frames::{self, NmtState};
use sensaug_bridge::cia402::{od, CanopenNode, Cia402Error, Master, MasterSettings};
use sensaug_bridge::transport::{Transport, UdpBus};
use sensaug_bridge::Frame;

mod common;

/// The value the scripted drive uploads for `index:sub` (the EDS defaults of
/// what the master reads before 0x2000), None for 0x2000, which this drive
/// does not have.
fn value_of(index: u16, sub: u8) -> Option<u32> {
    Some(match (index, sub) {
        (0x1000, 0) => 0x0002_0192,
        (0x6061, 0) => 10,
        (0x6076, 0) => 1000,
        (0x6072, 0) => 3000,
        (0x608F, 1) => 1 << 20,
        (0x608F, 2) | (0x6091, 1) | (0x6091, 2) => 1,
        (0x2000, 0) => return None,
        _ => 0,
    })
}

/// Answers SDO requests for `run_for`: uploads with [`value_of`] (abort
/// 0x06020000 when None), downloads with a confirmation. Returns whether it
/// saw an NMT start.
fn scripted_drive(mut bus: UdpBus, node: CanopenNode, run_for: Duration) -> bool {
    let start = Instant::now();
    let mut started = false;
    bus.send(&frames::heartbeat(node, NmtState::PreOperational))
        .unwrap();
    while start.elapsed() < run_for {
        let Some(f) = bus.recv(Duration::from_millis(10)).unwrap() else {
            continue;
        };
        let p = f.payload();
        if f.id == 0 && p == [0x01, node.get()] {
            started = true;
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
    started
}

#[test]
fn a_drive_without_the_sync_counter_echo_is_refused_before_it_is_started() {
    let port = common::free_port();
    let mut host = UdpBus::open(port).unwrap();
    let drive_bus = UdpBus::open(port).unwrap();
    let node = CanopenNode::new(1).unwrap();
    let drive = thread::spawn(move || scripted_drive(drive_bus, node, Duration::from_secs(2)));
    let mut master = Master::new(MasterSettings::new(node)).unwrap();
    let err = master.boot(&mut host).unwrap_err();
    assert!(matches!(err, Cia402Error::NoSyncCounterEcho), "{err:?}");
    let msg = err.to_string();
    assert!(
        msg.contains("0x2000") && msg.contains("SYNC counter echo"),
        "{msg}"
    );
    assert!(
        !drive.join().unwrap(),
        "the master started a drive it refused"
    );
}
