//! The master under the drive-side faults of issue 17, against a scripted
//! drive on the UDP bus (`cia402_common`: the SDO set-up in a thread, then
//! the test plays the drive's TPDOs, heartbeats and EMCYs itself):
//!
//! - an older TPDO arriving after a newer one, or a repeat, is discarded
//!   and counted: the newest SYNC counter wins;
//! - standard mode (no 0x2000): a TPDO answers the SYNC before it; a second
//!   one in that window is duplicated, one received before the last SYNC
//!   (kernel time) late, a SYNC without answers unanswered: each counted;
//! - a torque beyond 0x6072 is sent clamped to it and counted, a
//!   non-finite one as 0: RPDO1, SYNC and heartbeat go out every tick;
//! - a boot-up after NMT start, or a heartbeat leaving OPERATIONAL, is a
//!   reset (and a PRE-OPERATIONAL beat before the first OPERATIONAL is not);
//! - EMCY frames as python-canopen encodes them (`golden/cia402_frames.json`)
//!   are kept with their code, register and time;
//! - the drive's heartbeat is declared lost after the consumer time
//!   (measured; bounded by a generous margin on this loaded VM).

use std::time::{Duration, Instant, SystemTime};

use sensaug_bridge::cia402::frames::{self, NmtState};
use sensaug_bridge::cia402::{od, CanopenNode, Freshness, Heard, Master, MasterSettings};
use sensaug_bridge::transport::{Transport, UdpBus};
use sensaug_bridge::Frame;

mod cia402_common;
mod common;

use cia402_common::{
    next_cycle, on_a_bus, spawn_eds_drive, spawn_standard_drive, standard_tpdo1, standard_tpdo2,
    tpdo1, tpdo2,
};

const OPERATION_ENABLED: u16 = 0x0237;

/// A master booted against the scripted drive (3 N m, 0x6072 = 3000 of
/// 1 N m rated), and the drive's socket.
fn booted(settings: impl FnOnce(&mut MasterSettings)) -> (Master, UdpBus, UdpBus, CanopenNode) {
    let (mut host, node, drive) = on_a_bus(|bus, node| spawn_eds_drive(bus, node, 3000));
    let mut s = MasterSettings::new(node);
    settings(&mut s);
    let mut master = Master::new(s).unwrap();
    master.boot(&mut host).unwrap();
    let (drive, started) = drive.join().unwrap();
    assert!(started);
    (master, host, drive, node)
}

/// The drive sends a heartbeat in each of `states`; drains until the
/// master has taken them all in.
fn heartbeats(
    master: &mut Master,
    host: &mut UdpBus,
    drive: &mut UdpBus,
    node: CanopenNode,
    states: &[NmtState],
) {
    let heard = master.feedback().heartbeats_received + states.len() as u64;
    for &state in states {
        drive.send(&frames::heartbeat(node, state)).unwrap();
    }
    drain_until(master, host, |m| m.feedback().heartbeats_received == heard);
}

/// Drains until `pred` holds for the master (bounded).
fn drain_until(master: &mut Master, host: &mut UdpBus, pred: impl Fn(&Master) -> bool) {
    let start = Instant::now();
    while !pred(master) {
        assert!(
            start.elapsed() < Duration::from_secs(2),
            "the frames did not arrive"
        );
        master.drain(host).unwrap();
    }
}

#[test]
fn an_older_tpdo_after_a_newer_one_is_discarded_and_counted() {
    let (mut master, mut host, mut drive, node) = booted(|_| {});
    let mut counters = Vec::new();
    for k in 0..3 {
        master.tick(&mut host, 0.0).unwrap();
        let (_, c) = next_cycle(&mut drive, node);
        counters.push(c);
        drive
            .send(&tpdo1(node, OPERATION_ENABLED, 100 * k, c))
            .unwrap();
        drive.send(&tpdo2(node, 10 * k, 0, c)).unwrap();
    }
    // A copy of the first cycle's TPDOs, then of the last one's, after the last.
    let (first, last) = (counters[0], counters[2]);
    for f in [
        tpdo1(node, OPERATION_ENABLED, 0, first),
        tpdo2(node, 0, 0, first),
        tpdo1(node, OPERATION_ENABLED, 200, last),
        tpdo2(node, 20, 0, last),
    ] {
        drive.send(&f).unwrap();
    }
    drain_until(&mut master, &mut host, |m| m.feedback().tpdo2_received == 5);
    let fb = master.feedback();
    assert_eq!(fb.tpdos_discarded, 4, "{fb:?}");
    assert_eq!((fb.tpdo1_sync_counter, fb.tpdo2_sync_counter), (last, last));
    assert_eq!(fb.position_rad, master.units().increments_to_rad(200));
    assert!(master.last_sync_answered());
    // A TPDO echoing a SYNC this master has not sent yet is no newer either.
    drive
        .send(&tpdo1(
            node,
            OPERATION_ENABLED,
            999,
            last % od::SYNC_COUNTER_OVERFLOW + 1,
        ))
        .unwrap();
    drain_until(&mut master, &mut host, |m| m.feedback().tpdo1_received == 6);
    assert_eq!(master.feedback().tpdos_discarded, 5);
    assert!(master.last_sync_answered());
}

#[test]
fn a_command_beyond_max_torque_is_sent_clamped_and_counted_never_dropped() {
    let (mut master, mut host, mut drive, node) = booted(|s| {
        s.heartbeat_period = Duration::from_millis(1);
    });
    let per_mille = |rpdo: Option<[u8; 4]>| {
        let r = rpdo.expect("an RPDO1 before the SYNC");
        (
            u16::from_le_bytes([r[0], r[1]]),
            i16::from_le_bytes([r[2], r[3]]),
        )
    };
    let mut heartbeats = 0;
    for (torque_nm, sent) in [(10.0, 3000), (-32.0, -3000), (f64::NAN, 0), (2.5, 2500)] {
        std::thread::sleep(Duration::from_millis(2)); // the heartbeat is due
        master.tick(&mut host, torque_nm).unwrap();
        let (rpdo, _) = next_cycle(&mut drive, node);
        assert_eq!(per_mille(rpdo), (0x000F, sent), "{torque_nm} N m");
        let beat = drive.recv(Duration::from_secs(1)).unwrap().unwrap();
        assert_eq!(beat.id, 0x700 + 127, "{beat:?}");
        heartbeats += 1;
    }
    assert_eq!(heartbeats, 4);
    assert_eq!(
        (master.commands_clamped(), master.commands_non_finite()),
        (2, 1)
    );
}

#[test]
fn a_boot_up_after_nmt_start_is_a_reset_and_so_is_a_heartbeat_leaving_operational() {
    // A PRE-OPERATIONAL beat sent before the drive took the start is not.
    let (mut master, mut host, mut drive, node) = booted(|_| {});
    let mut beat = |states: &[NmtState]| {
        heartbeats(&mut master, &mut host, &mut drive, node, states);
        master.feedback().reset
    };
    assert_eq!(
        beat(&[NmtState::PreOperational, NmtState::Operational]),
        None
    );
    assert_eq!(
        beat(&[NmtState::PreOperational]),
        Some(NmtState::PreOperational)
    );

    let (mut master, mut host, mut drive, node) = booted(|_| {});
    heartbeats(
        &mut master,
        &mut host,
        &mut drive,
        node,
        &[NmtState::BootUp, NmtState::PreOperational],
    );
    assert_eq!(
        master.feedback().reset,
        Some(NmtState::BootUp),
        "the first report is kept"
    );
}

#[test]
fn emcy_frames_as_python_canopen_encodes_them_are_kept_with_code_register_and_time() {
    let doc: serde_json::Value =
        serde_json::from_str(include_str!("../golden/cia402_frames.json")).unwrap();
    let emcys: Vec<(u16, u8, Vec<u8>)> = doc["frames"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|f| f["kind"] == "emcy" && f["node"] == 1)
        .map(|f| {
            let hex = f["frame"]["data"].as_str().unwrap();
            let bytes = (0..hex.len())
                .step_by(2)
                .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).unwrap())
                .collect();
            (
                f["code"].as_u64().unwrap() as u16,
                f["register"].as_u64().unwrap() as u8,
                bytes,
            )
        })
        .collect();
    assert_eq!(emcys.len(), 5);
    let (mut master, mut host, mut drive, node) = booted(|_| {});
    let before = Instant::now();
    for (_, _, data) in &emcys {
        drive.send(&Frame::new(node.emcy(), data).unwrap()).unwrap();
    }
    drain_until(&mut master, &mut host, |m| m.feedback().emcy_received == 5);
    let kept: Vec<(u16, u8)> = master
        .emcy_records()
        .iter()
        .map(|r| (r.emcy.code, r.emcy.register))
        .collect();
    let sent: Vec<(u16, u8)> = emcys.iter().map(|(c, r, _)| (*c, *r)).collect();
    assert_eq!(kept, sent);
    assert!(master
        .emcy_records()
        .iter()
        .all(|r| r.at >= before && r.at <= Instant::now()));
    assert_eq!(master.emcy_records()[1].emcy.manufacturer, [1, 2, 3, 4, 5]);
}

#[test]
fn the_drives_heartbeat_is_lost_after_the_consumer_time() {
    let timeout = Duration::from_millis(100);
    let (mut master, mut host, mut drive, node) =
        booted(|s| *s = s.with_drive_heartbeat_timeout(timeout));
    assert_eq!(master.settings().drive_producer_ms, 50);
    heartbeats(
        &mut master,
        &mut host,
        &mut drive,
        node,
        &[NmtState::Operational],
    );
    let last_beat = Instant::now(); // received at or before this
    while !master.feedback().drive_heartbeat_lost {
        assert!(
            last_beat.elapsed() < timeout + Duration::from_secs(1),
            "not declared lost"
        );
        master.drain(&mut host).unwrap();
        std::thread::sleep(Duration::from_micros(200));
    }
    let lost_after = last_beat.elapsed();
    println!("drive heartbeat declared lost {:.1} ms after the last beat was taken in (consumer time 100 ms)", lost_after.as_secs_f64() * 1e3);
    assert!(lost_after >= timeout, "{lost_after:?}");
    // A beat brings it back.
    drive
        .send(&frames::heartbeat(node, NmtState::Operational))
        .unwrap();
    drain_until(&mut master, &mut host, |m| {
        !m.feedback().drive_heartbeat_lost
    });
}

#[test]
fn standard_mode_counts_duplicated_late_and_unanswered_tpdos() {
    let (mut host, node, drive) = on_a_bus(spawn_standard_drive);
    let mut master = Master::new(MasterSettings::new(node)).unwrap();
    master.boot(&mut host).unwrap();
    let (mut drive, started) = drive.join().unwrap();
    assert!(started);
    assert_eq!(master.freshness(), Some(Freshness::Standard));

    // SYNC 1 answered once: taken as its answer.
    master.tick(&mut host, 0.0).unwrap();
    let (_, c) = next_cycle(&mut drive, node);
    drive
        .send(&standard_tpdo1(node, OPERATION_ENABLED, 100))
        .unwrap();
    drive.send(&standard_tpdo2(node, 10, 0)).unwrap();
    drain_until(&mut master, &mut host, |m| m.feedback().tpdo2_received == 1);
    assert!(master.last_sync_answered());
    assert_eq!(master.feedback().tpdo1_sync_counter, c);
    assert_eq!(
        master.feedback().position_rad,
        master.units().increments_to_rad(100)
    );

    // A second TPDO1 and TPDO2 after the same SYNC: duplicated, not taken.
    drive
        .send(&standard_tpdo1(node, OPERATION_ENABLED, 555))
        .unwrap();
    drive.send(&standard_tpdo2(node, 55, 0)).unwrap();
    drain_until(&mut master, &mut host, |m| m.feedback().tpdo2_received == 2);
    let fb = *master.feedback();
    assert_eq!(fb.tpdos_duplicated, 2, "{fb:?}");
    assert_eq!(fb.tpdos_discarded, 0);
    assert_eq!(fb.position_rad, master.units().increments_to_rad(100));

    // SYNC 2 not answered, then SYNC 3: SYNC 2 counted unanswered.
    master.tick(&mut host, 0.0).unwrap();
    master.tick(&mut host, 0.0).unwrap();
    assert_eq!(master.feedback().syncs_unanswered, 1);

    // A TPDO the kernel received before SYNC 3 went out (read after it):
    // late, not taken; the same frame received now answers SYNC 3.
    let before = SystemTime::now() - Duration::from_millis(5);
    let late = standard_tpdo1(node, OPERATION_ENABLED, 777);
    assert_eq!(
        master.absorb_received(&late, Some(before)),
        Heard::Discarded
    );
    assert_eq!(master.feedback().tpdos_late, 1);
    assert_eq!(
        master.feedback().position_rad,
        master.units().increments_to_rad(100)
    );
    let now = SystemTime::now();
    assert_eq!(master.absorb_received(&late, Some(now)), Heard::Other);
    assert_eq!(
        master.feedback().position_rad,
        master.units().increments_to_rad(777)
    );
    assert_eq!(master.feedback().tpdo1_sync_counter, master.sync_counter());
    // An echo-mode (7-byte) TPDO does not decode in standard mode.
    assert_eq!(
        master.absorb(&tpdo1(node, OPERATION_ENABLED, 1, master.sync_counter())),
        Heard::Undecodable
    );
}
