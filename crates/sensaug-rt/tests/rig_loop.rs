//! The real-time loop against a minimal in-process drive on the loopback
//! bus: it completes, it stops cleanly on the stop flag, a silent drive trips
//! the feedback timeout, its ticks allocate nothing (counting allocator,
//! counted only on the loop's thread), with or without the sleep-then-spin
//! wake-up. No timing is asserted.

use sensaug_bridge::protocol::TORQUE_SCALE_NM;
use sensaug_bridge::transport::UdpBus;
use sensaug_config::rig::feedback_timeout_ticks;
use sensaug_config::{load_str, Format};
use sensaug_core::agent::Guard;
use sensaug_log::Row;
use sensaug_rt::config::drive_link;
use sensaug_rt::control::{LoopSettings, Rig, StopReason};
use sensaug_rt::log;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Duration;

#[path = "../../sensaug-core/tests/common/alloc_counter.rs"]
mod alloc_counter;

use alloc_counter::allocations;

#[path = "common/drive.rs"]
mod drive;

use drive::{drive, drive_stalling, free_port, Stall};

#[path = "common/trial.rs"]
mod trial;

use trial::CONFIG;

struct Outcome {
    reason: StopReason,
    allocations: u64,
    records: u64,
    ticks: u64,
    estimate: [f64; 3],
    /// Samples in the wake-up and sleep latency histograms.
    wake_samples: u64,
    sleep_samples: u64,
    /// The log's rows (parsed back from the file).
    rows: Vec<Row>,
}

/// A drive thread on a loopback port, stopped by the flag.
type StartDrive = fn(u16, Arc<AtomicBool>) -> std::thread::JoinHandle<()>;

/// The drive of most tests: it answers every command.
fn answering(port: u16, stop: Arc<AtomicBool>) -> std::thread::JoinHandle<()> {
    drive(port, stop, u64::MAX)
}

/// The loop's settings for the test, from those of [`drive::loop_settings`].
type Adjust = fn(LoopSettings) -> LoopSettings;

fn run_loop(start_drive: StartDrive, stop_after: Option<Duration>, adjust: Adjust) -> Outcome {
    let resolved = load_str(CONFIG, Format::Toml).unwrap();
    let port = free_port();
    let drive_stop = Arc::new(AtomicBool::new(false));
    let handle = start_drive(port, Arc::clone(&drive_stop));
    let robot = resolved.controller().unwrap();
    let settings = adjust(drive::loop_settings(&resolved));
    let transport = Box::new(UdpBus::open(port).unwrap());
    let mut rig = Rig::start(settings, drive_link(&settings).unwrap(), transport, robot).unwrap();
    let dir = std::env::temp_dir().join(format!("sensaug-rt-test-{port}"));
    let meta = serde_json::json!({"source": "rig"});
    let (mut sink, writer) = log::start(&dir.join("log.csv"), 1 << 14, &meta, None).unwrap();
    let stop = Arc::new(AtomicUsize::new(0));
    if let Some(after) = stop_after {
        let s = Arc::clone(&stop);
        std::thread::spawn(move || {
            std::thread::sleep(after);
            s.store(libc::SIGTERM as usize, Ordering::Relaxed);
        });
    }
    let mut reason = StopReason::Completed;
    let allocations = allocations(|| reason = rig.run(&mut sink, &stop));
    drop(sink);
    let written = writer.finish(serde_json::Map::new());
    assert_eq!(written.error, None);
    let records = written.records_written;
    drive_stop.store(true, Ordering::Relaxed);
    handle.join().unwrap();
    let report = rig.report(reason);
    let text = std::fs::read_to_string(dir.join("log.csv")).unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    // Every line's checksum verified.
    let rows = sensaug_log::read(&text).unwrap().rows;
    Outcome {
        reason,
        allocations,
        records,
        ticks: report.ticks,
        estimate: report.partner_gains_estimate,
        wake_samples: report.wake_latency.count,
        sleep_samples: report.sleep_latency.count,
        rows,
    }
}

/// A whole trial ran: it completed without allocating, logged every tick,
/// and recorded one wake-up and one sleep latency per wake-up (every
/// tick's, and the last one's, which found the protocol done and ran no
/// tick).
fn assert_completed_and_recorded(o: &Outcome) {
    assert_eq!(o.reason, StopReason::Completed);
    assert_eq!(o.allocations, 0, "the loop allocated");
    assert_eq!(o.ticks, 3500);
    assert_eq!(o.records, o.ticks);
    assert_eq!(o.rows.len() as u64, o.ticks);
    assert_eq!(
        (o.wake_samples, o.sleep_samples),
        (o.ticks + 1, o.ticks + 1)
    );
}

#[test]
fn a_whole_trial_completes_without_allocating_and_logs_every_tick() {
    let o = run_loop(answering, None, |s| s);
    assert_completed_and_recorded(&o);
    // Without a spin the sleep's target is the deadline: one latency.
    assert!(o
        .rows
        .iter()
        .all(|r| r.sleep_latency_us == r.wake_latency_us));
    // The same protocol simulated without noise (sensaug.experiment, 3 s gain
    // phase, 0.5 s window) gives Lhh = 1.99929; 0.02 leaves room for the
    // ticks a noisy VM loses feedback (predict-only there).
    assert!((o.estimate[2] - 2.0).abs() < 0.02, "{:?}", o.estimate);
    assert_the_model_sees_the_torque_applied(&o);
}

/// Every controller tick: the torque sent is on the drive's grid, and the
/// robot's `u` (what its estimators predicted with) plus the virtual
/// human's exact `u_h` is that torque (no friction, ramp or clamp here), so
/// the drive's rounding is the robot's and the partner the estimators see
/// is the virtual human itself. Rounding the robot's command alone (the
/// drive then applying `u + round(u_h)`) misses by up to half a step, more
/// than the tolerance's thousand times.
fn assert_the_model_sees_the_torque_applied(o: &Outcome) {
    let unit = load_str(CONFIG, Format::Toml).unwrap().rad_per_unit;
    let mut residuals = 0;
    for r in &o.rows {
        assert_eq!(
            (r.friction_nm, r.guard),
            (0.0, Some(Guard::Passed)),
            "tick {}",
            r.tick
        );
        let steps = r.torque_nm / TORQUE_SCALE_NM;
        assert!((steps - steps.round()).abs() < 1e-6, "tick {}", r.tick);
        let implied_nm = (r.u + r.u_h) * unit;
        assert!(
            (implied_nm - r.torque_nm).abs() < 1e-3 * TORQUE_SCALE_NM,
            "tick {}: (u + u_h) unit = {implied_nm} N m, sent {} N m",
            r.tick,
            r.torque_nm
        );
        // The partner's torque is its own, never on the grid by construction.
        residuals += usize::from((r.u_h * unit / TORQUE_SCALE_NM).fract().abs() > 1e-3);
    }
    assert!(residuals > o.rows.len() / 2, "{residuals}");
}

#[test]
fn the_stop_flag_brakes_without_allocating_and_stops() {
    let o = run_loop(answering, Some(Duration::from_millis(700)), |s| s);
    assert_eq!(o.reason, StopReason::Signal(libc::SIGTERM));
    assert_eq!(o.allocations, 0, "the loop allocated");
    assert!(o.ticks < 3500);
    assert_eq!(o.records, o.ticks);
}

#[test]
fn a_silent_drive_trips_the_feedback_timeout() {
    let o = run_loop(|p, s| drive(p, s, 300), None, |s| s);
    assert_eq!(o.reason, StopReason::FeedbackTimeout);
    // 300 answered commands, then the 50 ms timeout (+ the tick that
    // notices) before stopping.
    assert!(o.ticks >= 300 && o.ticks <= 300 + 52, "{}", o.ticks);
    assert_eq!(o.records, o.ticks);
}

#[test]
fn with_a_spin_every_tick_records_both_latencies_without_allocating() {
    let o = run_loop(answering, None, |s| LoopSettings { spin_us: 100, ..s });
    assert_completed_and_recorded(&o);
    for r in &o.rows {
        assert!(r.wake_latency_us >= 0.0, "tick {}", r.tick);
        assert!(
            r.sleep_latency_us.is_finite() && r.sleep_latency_us >= 0.0,
            "tick {}",
            r.tick
        );
    }
}

#[test]
fn a_late_answer_sent_with_the_next_is_not_taken_for_a_jump() {
    // When the handle moves faster than 1.1 rad/s (at most once per 100
    // commands) the drive stalls 25 ms after stepping its plant, then sends
    // that answer and, about a tick later, the answer to the 25 commands
    // queued meanwhile (a CI run's virtual drive, stopped by the test
    // between the two): two feedbacks received about a tick apart, 25
    // drive steps apart.
    let stalling = |port, stop| {
        let stall = Stall {
            above_rad_s: 1.1,
            every: 100,
            duration: Duration::from_millis(25),
        };
        drive_stalling(port, stop, stall)
    };
    // A 200 ms feedback timeout: the stall's 25 ms on a loaded machine
    // stay far from it (the timeout is not this test's subject).
    let patient = |s: LoopSettings| LoopSettings {
        feedback_timeout_ms: 200.0,
        feedback_timeout_ticks: feedback_timeout_ticks(200.0, s.dt_s),
        ..s
    };
    let o = run_loop(stalling, None, patient);
    assert_eq!(o.reason, StopReason::Completed);
    assert_eq!(o.allocations, 0, "the loop allocated");
    // The case happened: a feedback moved more than one tick allows
    // (8 rad/s x 2 ms + 10 mrad) from the one before it.
    let rad_per_unit = load_str(CONFIG, Format::Toml).unwrap().rad_per_unit;
    let largest_step_rad = o
        .rows
        .windows(2)
        .map(|w| (w[1].x_meas - w[0].x_meas).abs() * rad_per_unit)
        .fold(0.0, f64::max);
    eprintln!("largest step between two ticks' feedback: {largest_step_rad:.4} rad");
    assert!(largest_step_rad > 0.026, "{largest_step_rad}");
}
