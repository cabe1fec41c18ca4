//! A minimal in-process Hi5 drive on the loopback bus, for the loop's tests
//! (`tests/rig_loop.rs`) and its bench (`benches/rig_tick.rs`).
#![allow(dead_code)]

use sensaug_bridge::protocol::{decode, encode, DriveState, FaultFlags, Message, NodeId};
use sensaug_bridge::transport::UdpBus;
use sensaug_bridge::Transport;
use sensaug_config::rig::feedback_timeout_ticks;
use sensaug_config::Resolved;
use sensaug_core::plant::{Plant, PlantParams};
use sensaug_rt::control::{LoopSettings, StopSettings};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// How the drive thread waits for the next frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DriveWait {
    /// Asleep in a blocking `recv` (5 ms timeout): every command wakes it,
    /// an inter-processor interrupt when it sleeps on another CPU. The
    /// virtual rig of the tests and the demo.
    Sleeping,
    /// Spinning, never asleep: a non-blocking `recv_ready`, then
    /// [`POLL_GAP`] of busy-waiting before the next look when it found
    /// nothing. A command wakes no one, as on a CAN adapter (hardware
    /// always listening).
    Polling,
}

/// The polling drive's busy-wait between two looks at an empty bus: the
/// feedback is at most this late, and the loop's sends do not meet a
/// receive system call on the drive's socket every few hundred ns (an
/// adapter's hardware listens without the host's socket locks).
pub const POLL_GAP: Duration = Duration::from_micros(20);

/// The polling drive's wait after an empty look: [`POLL_GAP`] of
/// busy-waiting, never asleep.
pub fn wait_poll_gap() {
    let looked = Instant::now();
    while looked.elapsed() < POLL_GAP {
        std::hint::spin_loop();
    }
}

/// A drive that does just what the loop needs: heartbeats, enable, one
/// feedback per torque command from the exact plant. It stops answering
/// commands after `answer_for` of them (a dead drive).
pub fn drive(port: u16, stop: Arc<AtomicBool>, answer_for: u64) -> JoinHandle<()> {
    drive_waiting(port, stop, answer_for, DriveWait::Sleeping)
}

/// [`drive`], waiting for frames as `wait` says.
pub fn drive_waiting(
    port: u16,
    stop: Arc<AtomicBool>,
    answer_for: u64,
    wait: DriveWait,
) -> JoinHandle<()> {
    serve(port, stop, answer_for, wait, None)
}

/// A drive that stalls after stepping its plant for a command, when the
/// handle moves fast.
#[derive(Clone, Copy, Debug)]
pub struct Stall {
    /// At a speed above this (rad/s).
    pub above_rad_s: f64,
    /// At most once per this many commands answered.
    pub every: u64,
    /// For this long, before sending that command's answer.
    pub duration: Duration,
}

/// [`drive`] stalling as `stall` says: after the stall it sends the held
/// answer, then steps its plant for each command queued meanwhile and
/// answers only the last (as the virtual Hi5 drive does after a stall).
pub fn drive_stalling(port: u16, stop: Arc<AtomicBool>, stall: Stall) -> JoinHandle<()> {
    serve(port, stop, u64::MAX, DriveWait::Sleeping, Some(stall))
}

/// The drive's thread: [`drive_waiting`], stalling as `stall` says.
fn serve(
    port: u16,
    stop: Arc<AtomicBool>,
    answer_for: u64,
    wait: DriveWait,
    stall: Option<Stall>,
) -> JoinHandle<()> {
    std::thread::spawn(move || {
        let node = NodeId::new(1).unwrap();
        let mut bus = UdpBus::open(port).unwrap();
        let mut plant = Plant::new(PlantParams::HI5).unwrap();
        let mut state = DriveState::Disabled;
        let mut answered = 0u64;
        let mut stalled_at = 0u64;
        let mut last_beat = Instant::now() - Duration::from_secs(1);
        while !stop.load(Ordering::Relaxed) {
            if last_beat.elapsed() > Duration::from_millis(20) {
                let hb = Message::Heartbeat {
                    state,
                    fault_flags: FaultFlags::empty(),
                    counter: 0,
                    crc_errors: 0,
                    length_errors: 0,
                    sequence_errors: 0,
                    unknown_ids: 0,
                    range_errors: 0,
                };
                bus.send(&encode(node, &hb).unwrap()).unwrap();
                last_beat = Instant::now();
            }
            let received = match wait {
                DriveWait::Sleeping => bus.recv(Duration::from_millis(5)),
                DriveWait::Polling => bus.recv_ready(),
            };
            let Ok(Some(f)) = received else {
                if wait == DriveWait::Polling {
                    wait_poll_gap();
                }
                continue;
            };
            match decode(node, &f) {
                Ok(Message::SetState { enable, .. }) => {
                    state = if enable {
                        DriveState::Enabled
                    } else {
                        DriveState::Disabled
                    };
                }
                Ok(Message::TorqueCommand {
                    torque_nm,
                    sequence,
                }) if state == DriveState::Enabled && answered < answer_for => {
                    let feedback =
                        |s: sensaug_core::plant::PlantState, sequence| Message::Feedback {
                            position_rad: s.x,
                            velocity_rad_s: s.v,
                            sequence,
                            state,
                            torque_limited: false,
                            fault_active: false,
                        };
                    let now = plant.step(torque_nm).unwrap();
                    answered += 1;
                    let stalls =
                        |s: &Stall| now.v.abs() > s.above_rad_s && answered >= stalled_at + s.every;
                    let stalled = stall.filter(stalls);
                    if let Some(stall) = stalled {
                        stalled_at = answered;
                        std::thread::sleep(stall.duration);
                    }
                    bus.send(&encode(node, &feedback(now, sequence)).unwrap())
                        .unwrap();
                    if stalled.is_some() {
                        // The commands queued meanwhile: each steps the
                        // plant, the last one is answered.
                        let mut last = None;
                        while let Ok(Some(f)) = bus.recv_ready() {
                            if let Ok(Message::TorqueCommand {
                                torque_nm,
                                sequence,
                            }) = decode(node, &f)
                            {
                                last = Some(feedback(plant.step(torque_nm).unwrap(), sequence));
                                answered += 1;
                            }
                        }
                        if let Some(fb) = last {
                            bus.send(&encode(node, &fb).unwrap()).unwrap();
                        }
                    }
                }
                _ => {}
            }
        }
    })
}

/// The bridge tests' helper: a loopback port no one is bound to right now.
#[path = "../../../../firmware_bridge/tests/common/mod.rs"]
mod bridge_common;
pub use bridge_common::free_port;

/// The loop's settings against this drive (node 1, 3 N m, 50 ms watchdog
/// and feedback timeout, a controlled stop of at most 50 ms) for a
/// resolved configuration: its period, unit, plant and virtual human.
pub fn loop_settings(resolved: &Resolved) -> LoopSettings {
    let r = &resolved.rig;
    let dt_s = r.dt_s;
    LoopSettings {
        drive: sensaug_config::DriveProfile::Hi5,
        node_id: 1,
        torque_limit_nm: 3.0,
        watchdog_ms: 50,
        quiet_period_ms: 50 * sensaug_rt::control::QUIET_WATCHDOG_PERIODS,
        drive_heartbeat_timeout_ms: 100,
        feedback_timeout_ms: 50.0,
        feedback_timeout_ticks: feedback_timeout_ticks(50.0, dt_s),
        stop: StopSettings {
            time_limit_s: 0.05,
            damping_nm_s_per_rad: PlantParams::HI5.mass / 0.004,
            torque_limit_nm: 3.0,
            rest_velocity_rad_s: 0.01,
        },
        stop_ticks: (0.05 / dt_s).round() as u64,
        partner_gains: resolved.partner.gains,
        partner_torque_limit: 1e3,
        partner_human: resolved.partner.human,
        max_feedback_velocity_rad_s: 8.0,
        feedback_step_margin_rad: 0.01,
        max_acceleration_rad_s2: 3.0 / PlantParams::HI5.mass,
        feedback_velocity_margin_rad_s: 0.05,
        max_missing_feedback_fraction: 0.5,
        max_stale_feedback_ticks: 100,
        max_estimator_errors: 10,
        spin_us: 0,
        ..*r
    }
}
