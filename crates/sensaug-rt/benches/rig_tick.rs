//! The rig's tick compute on the loopback UDP bus: the real loop
//! (`Rig::run`: drain the feedback, decide, send the command, log) against
//! the minimal in-process drive of the tests, through the Hi5 rig protocol
//! (`configs/hi5_rig.toml`, each phase shortened to `<phase_s>`). Prints
//! the loop's own histograms, as JSON: `compute` (wake-up to the command
//! sent) and its parts `compute_parts` (sense: drain the bus; decide: the
//! safety checks, the robot's tick and the virtual human; actuate: the
//! send; record: the log push after it), `wake_latency`, 1 us bins (bin
//! upper edges), the loop thread's page faults, the bus counters and the
//! drive model (`drive_wait`). Nothing is asserted (a bench, not a test).
//!
//! `cargo bench -p sensaug-rt --bench rig_tick [-- <phase_s> [pinned] [polling]]`
//! (default 3 s per phase: 9000 ticks). The loop runs as an ordinary thread
//! (SCHED_OTHER, timer slack 1 ns, no mlockall), anywhere the scheduler
//! puts it; with `pinned`, on the last CPU with the drive and log writer
//! threads kept off it (as `sensaug-rt` with `rig.realtime.cpu` set).
//!
//! The drive model: by default the drive thread sleeps in a blocking
//! `recv`, as the virtual rig of the demo does, so the loop's send wakes it:
//! on the loop's CPU the drive may run before the send returns; on another
//! CPU the wake is an inter-processor interrupt (`benches/bus_floor.rs`
//! times both). With `polling` (implies `pinned`) the drive thread spins on
//! another CPU, never asleep (the non-blocking `recv_ready`, then 20 us of
//! busy-waiting when the bus was empty): the send wakes no one, the closer
//! model of a CAN adapter, whose hardware is always listening. The polling
//! drive keeps that CPU busy for the run.

#[path = "../tests/common/drive.rs"]
mod drive;

use sensaug_bridge::transport::UdpBus;
use sensaug_config::load_file;
use sensaug_core::controller::Robot;
use sensaug_core::protocol::Protocol;
use sensaug_rt::config::drive_link;
use sensaug_rt::control::Rig;
use sensaug_rt::log;
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let phase_s = args
        .iter()
        .find_map(|a| a.parse::<f64>().ok())
        .unwrap_or(3.0);
    let polling = args.iter().any(|a| a == "polling");
    let pin = polling || args.iter().any(|a| a == "pinned");
    let wait = if polling {
        drive::DriveWait::Polling
    } else {
        drive::DriveWait::Sleeping
    };
    let config = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/hi5_rig.toml");
    let resolved = load_file(&config).expect("configs/hi5_rig.toml resolves");
    let mut phases = resolved.phases();
    for p in &mut phases {
        p.duration_s = phase_s;
    }
    let protocol = Protocol::new(&phases, resolved.dt_s).expect("valid protocol");
    let robot = Robot::new(resolved.robot, protocol).expect("valid robot");
    let settings = drive::loop_settings(&resolved);
    if let Err(e) = sensaug_rt::os::minimal_timer_slack() {
        eprintln!("timer slack 1 ns not applied: {e}");
    }
    // The drive and log writer threads spawned below inherit this affinity
    // (every CPU but the loop's); the loop pins itself after them.
    let loop_cpu = std::thread::available_parallelism().map_or(1, |n| n.get()) - 1;
    let others_free = pin && loop_cpu > 0 && sensaug_rt::os::avoid_cpu(loop_cpu).is_ok();
    let port = drive::free_port();
    let drive_stop = Arc::new(AtomicBool::new(false));
    let handle = drive::drive_waiting(port, Arc::clone(&drive_stop), u64::MAX, wait);
    let transport = Box::new(UdpBus::open(port).expect("loopback bus"));
    let mut rig =
        Rig::start(settings, drive_link(&settings).unwrap(), transport, robot).expect("drive");
    let dir = std::env::temp_dir().join(format!("sensaug-rig-tick-{port}"));
    let meta = serde_json::json!({"source": "rig"});
    let (mut sink, writer) = log::start(&dir.join("log.csv"), 1 << 14, &meta, None).expect("log");
    let pinned = others_free && sensaug_rt::os::pin_to_cpu(loop_cpu).is_ok();
    let reason = rig.run(&mut sink, &AtomicUsize::new(0));
    drop(sink);
    let written = writer.finish(serde_json::Map::new());
    drive_stop.store(true, Ordering::Relaxed);
    handle.join().expect("drive thread");
    let _ = std::fs::remove_dir_all(&dir);
    let report = rig.report(reason);
    let out = serde_json::json!({
        "stop_reason": report.stop_reason,
        "ticks": report.ticks,
        "records_written": written.records_written,
        "loop_cpu": pinned.then_some(loop_cpu),
        "drive_wait": if polling { "polling" } else { "sleeping" },
        "compute": report.compute,
        "compute_parts": report.compute_parts,
        "loop_page_faults": report.loop_page_faults,
        "wake_latency": report.wake_latency,
        "deadline_misses": report.deadline_misses,
        "can": report.can,
    });
    println!("{out}");
}
