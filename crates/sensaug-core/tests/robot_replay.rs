//! `replay::replay_robot`: the controller re-run over a recorded trial gives
//! the online per-tick output bit for bit (with and without missing
//! measurements), checks lengths before running, and allocates nothing.

#![allow(non_snake_case)]

#[path = "common/alloc_counter.rs"]
mod alloc_counter;
mod common;

use alloc_counter::allocations;
use sensaug_core::controller::{Robot, RobotTick};
use sensaug_core::protocol::Protocol;
use sensaug_core::replay::{replay_robot, ReplayArg, ReplayError};
use sensaug_core::world::{Scenario, TickRecord};

/// Every field's bit pattern (NaN equals NaN, -0.0 differs from 0.0).
fn bits(t: &RobotTick) -> [u64; 16] {
    let f = [
        t.u,
        t.phase,
        t.e_meas,
        t.gains[0],
        t.gains[1],
        t.gains[2],
        t.gains_var[0],
        t.gains_var[1],
        t.gains_var[2],
        t.tau_h_hat,
        t.tau_h_var,
        t.e_hat_own,
        t.e_hat_fused,
        t.e_hat_own_var,
        t.e_hat_fused_var,
        t.partner_var,
    ];
    f.map(f64::to_bits)
}

fn assert_identical(replayed: &[RobotTick], online: &[RobotTick]) {
    assert_eq!(replayed.len(), online.len());
    for (k, (a, b)) in replayed.iter().zip(online).enumerate() {
        assert_eq!(bits(a), bits(b), "tick {k}: {a:?} vs {b:?}");
    }
}

/// A noisy simulated trial (sensor, motor and target-view noise).
fn simulated(phases: &[sensaug_core::protocol::Phase<'static>]) -> Vec<TickRecord> {
    let mut sc = Scenario::new(
        phases,
        common::robot(),
        common::partner(2.0),
        common::world(5),
    )
    .unwrap();
    let mut out = vec![TickRecord::default(); sc.ticks()];
    sc.run(&mut out).unwrap();
    out
}

#[test]
fn a_simulated_trial_replays_bit_for_bit() {
    let phases = common::phases(1.5, 1.0);
    let recs = simulated(&phases);
    let measurements: Vec<_> = recs.iter().map(|r| Some((r.x_meas, r.v_meas))).collect();
    let protocol = Protocol::new(&phases, common::DT).unwrap();
    let mut robot = Robot::new(common::robot(), protocol).unwrap();
    let mut out = vec![RobotTick::NONE; recs.len()];
    let counters = replay_robot(&mut robot, &measurements, &mut out).unwrap();
    let online: Vec<RobotTick> = recs.iter().map(|r| r.robot).collect();
    assert!(online.iter().any(|t| t.e_hat_fused.is_finite()));
    assert_identical(&out, &online);
    assert_eq!(counters.missing_measurements, 0);
}

#[test]
fn missing_measurements_replay_as_the_online_predict_only_ticks() {
    let phases = common::phases(1.5, 1.0);
    let recs = simulated(&phases);
    // Every 7th tick lost (as a rig's feedback can be), one non-finite.
    let mut measurements: Vec<_> = recs
        .iter()
        .enumerate()
        .map(|(k, r)| (k % 7 != 3).then_some((r.x_meas, r.v_meas)))
        .collect();
    measurements[100] = Some((f64::NAN, 0.0));
    let protocol = Protocol::new(&phases, common::DT).unwrap();
    let mut online_robot = Robot::new(common::robot(), protocol).unwrap();
    let online: Vec<RobotTick> = measurements
        .iter()
        .enumerate()
        .map(|(k, m)| {
            let s = protocol.sample(k as u64).unwrap();
            online_robot.tick_at(&s, *m)
        })
        .collect();
    let mut robot = Robot::new(common::robot(), protocol).unwrap();
    let mut out = vec![RobotTick::NONE; recs.len()];
    let counters = replay_robot(&mut robot, &measurements, &mut out).unwrap();
    assert_identical(&out, &online);
    assert_eq!(counters, online_robot.counters());
    let lost = measurements.iter().filter(|m| m.is_none()).count() as u64 + 1;
    assert_eq!(counters.missing_measurements, lost);
    // ... and differ from a replay that had every measurement.
    let full: Vec<RobotTick> = recs.iter().map(|r| r.robot).collect();
    assert_ne!(bits(&out[4]), bits(&full[4]));
}

#[test]
fn lengths_are_checked_and_ticks_after_the_protocol_are_none() {
    let phases = common::phases(0.01, 0.0);
    let protocol = Protocol::new(&phases, common::DT).unwrap();
    let mut robot = Robot::new(common::robot(), protocol).unwrap();
    let mut out = vec![RobotTick::NONE; 3];
    assert_eq!(
        replay_robot(&mut robot, &[None; 4], &mut out),
        Err(ReplayError::Length {
            which: ReplayArg::RobotTicks,
            needed: 4,
            got: 3
        })
    );
    let n = protocol.total_ticks() as usize;
    let mut out = vec![RobotTick::default(); n + 2];
    replay_robot(&mut robot, &vec![Some((0.0, 0.0)); n + 2], &mut out).unwrap();
    assert!(out[n - 1].phase == 2.0);
    assert_identical(&out[n..], &[RobotTick::NONE; 2]);
}

#[test]
fn a_robot_replay_does_not_allocate() {
    let phases = common::phases(1.0, 1.0);
    let protocol = Protocol::new(&phases, common::DT).unwrap();
    let mut robot = Robot::new(common::robot(), protocol).unwrap();
    let n = protocol.total_ticks() as usize;
    let measurements: Vec<_> = (0..n)
        .map(|k| (k % 5 != 0).then_some((1e-3 * (k as f64 * 1e-2).sin(), 0.0)))
        .collect();
    let mut out = vec![RobotTick::NONE; n];
    let mut result = None;
    let a = allocations(|| result = Some(replay_robot(&mut robot, &measurements, &mut out)));
    assert_eq!(a, 0);
    assert!(result.unwrap().is_ok());
    assert!(out.iter().all(|t| t.u.is_finite()));
}
