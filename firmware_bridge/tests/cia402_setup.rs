//! [`Master::boot`]'s checks of the drive before it is started, against a
//! scripted SDO server on the UDP bus (`cia402_common`): a drive without
//! the SYNC counter echo 0x2000 (an off-the-shelf CiA 402 drive) runs in
//! standard mode when the mode is chosen from its dictionary (auto), and is
//! refused with [`Cia402Error::NoSyncCounterEcho`] when the echo is
//! required; a drive whose max torque 0x6072
//! is not the configured limit (another node wrote 32767, 11x the limit;
//! or 50, below it) is refused with [`Cia402Error::MaxTorqueMismatch`]
//! naming both values; neither is NMT-started.

use std::time::Duration;

use sensaug_bridge::cia402::{Cia402Error, Freshness, FreshnessSetting, Master, MasterSettings};

mod cia402_common;
mod common;

use cia402_common::{eds_value, on_a_bus, serve_set_up, spawn_eds_drive, spawn_standard_drive};

#[test]
fn a_drive_without_the_sync_counter_echo_runs_in_standard_mode_when_chosen_automatically() {
    let (mut host, node, drive) = on_a_bus(spawn_standard_drive);
    let mut master = Master::new(MasterSettings::new(node)).unwrap();
    assert_eq!(master.freshness(), None);
    master.boot(&mut host).unwrap();
    assert_eq!(master.freshness(), Some(Freshness::Standard));
    // Its TPDOs already had the standard mapping: nothing rewritten.
    assert_eq!(master.pdos_rewritten(), 0);
    assert!(
        drive.join().unwrap().1,
        "the master did not start the drive"
    );
}

#[test]
fn a_drive_with_the_echo_runs_with_it_unless_standard_is_forced() {
    for (setting, mode) in [
        (FreshnessSetting::Auto, Freshness::SyncCounterEcho),
        (
            FreshnessSetting::SyncCounterEcho,
            Freshness::SyncCounterEcho,
        ),
    ] {
        let (mut host, node, drive) = on_a_bus(|bus, node| spawn_eds_drive(bus, node, 3000));
        let mut s = MasterSettings::new(node);
        s.freshness = setting;
        let mut master = Master::new(s).unwrap();
        master.boot(&mut host).unwrap();
        assert_eq!(master.freshness(), Some(mode), "{setting:?}");
        assert!(drive.join().unwrap().1);
    }
    // Forced standard on the echo drive: its TPDOs must be remapped without
    // 0x2000; the scripted drive does not store writes, so the read-back
    // refuses it, naming the mapping (a real drive takes the writes).
    let (mut host, node, drive) = on_a_bus(|bus, node| spawn_eds_drive(bus, node, 3000));
    let mut s = MasterSettings::new(node);
    s.freshness = FreshnessSetting::Standard;
    let mut master = Master::new(s).unwrap();
    let err = master.boot(&mut host).unwrap_err();
    assert!(
        matches!(err, Cia402Error::Mismatch { index: 0x1A00, .. }),
        "{err:?}"
    );
    assert_eq!(master.freshness(), Some(Freshness::Standard));
    assert!(!drive.join().unwrap().1);
}

#[test]
fn a_drive_without_the_sync_counter_echo_is_refused_when_the_echo_is_required() {
    let (mut host, node, drive) = on_a_bus(|bus, node| {
        std::thread::spawn(move || {
            let value = |i, s| match (i, s) {
                (0x2000, 0) => None,
                _ => eds_value(node, 3000, i, s),
            };
            serve_set_up(bus, node, value, Duration::from_secs(2)).1
        })
    });
    let mut s = MasterSettings::new(node);
    s.freshness = FreshnessSetting::SyncCounterEcho;
    let mut master = Master::new(s).unwrap();
    let err = master.boot(&mut host).unwrap_err();
    assert!(matches!(err, Cia402Error::NoSyncCounterEcho), "{err:?}");
    let msg = err.to_string();
    assert!(
        msg.contains("0x2000")
            && msg.contains("SYNC counter echo")
            && msg.contains("rig.cia402.freshness"),
        "{msg}"
    );
    assert!(
        !drive.join().unwrap(),
        "the master started a drive it refused"
    );
}

/// Boots a master configured for 3 N m against a drive holding
/// `max_torque_per_mille` in 0x6072 (1 N m rated): the result and whether
/// the drive was NMT-started.
fn boot_with_max_torque(max_torque_per_mille: u32) -> (Result<(), Cia402Error>, bool) {
    let (mut host, node, drive) =
        on_a_bus(|bus, node| spawn_eds_drive(bus, node, max_torque_per_mille));
    let mut settings = MasterSettings::new(node);
    settings.max_torque_nm = 3.0;
    let mut master = Master::new(settings).unwrap();
    let result = master.boot(&mut host);
    (result, drive.join().unwrap().1)
}

#[test]
fn a_max_torque_other_than_the_configured_limit_is_refused_and_the_drive_not_started() {
    for (per_mille, nm) in [(32767, "32.767"), (50, "0.05")] {
        let (result, started) = boot_with_max_torque(per_mille);
        let err = result.unwrap_err();
        assert!(
            matches!(err, Cia402Error::MaxTorqueMismatch { drive_per_mille, .. } if u32::from(drive_per_mille) == per_mille),
            "{err:?}"
        );
        let msg = err.to_string();
        for part in [
            "0x6072",
            &format!("{per_mille} per-mille"),
            &format!("{nm} N m"),
            "rig.torque_limit_nm is 3 N m",
            "3000 per-mille",
        ] {
            assert!(msg.contains(part), "{part:?} not in {msg}");
        }
        assert!(
            !started,
            "0x6072 = {per_mille}: the master started the drive"
        );
    }
    let (result, started) = boot_with_max_torque(3000);
    assert!(result.is_ok() && started, "{result:?}");
}
