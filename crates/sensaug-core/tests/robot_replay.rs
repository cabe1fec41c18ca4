//! `replay::replay_robot`: the controller re-run over a recorded trial gives
//! the online per-tick output bit for bit (with and without missing
//! measurements), checks lengths before running, and allocates nothing.

#![allow(non_snake_case)]

#[path = "common/alloc_counter.rs"]
mod alloc_counter;
mod common;

use alloc_counter::allocations;
use sensaug_core::controller::Robot;
use sensaug_core::protocol::Protocol;
use sensaug_core::replay::{replay_robot, ReplayArg, ReplayError};
use sensaug_core::row::{ColumnSource, Row, Value, COLUMNS};
use sensaug_core::world::Scenario;

/// A new robot of the tests' configuration following `protocol`: what a
/// replay must start from to repeat a trial bit for bit.
fn fresh_robot(protocol: Protocol<'_>) -> Robot<'_> {
    Robot::new(common::robot(), protocol).unwrap()
}

/// The controller's columns of a row (only those a replay writes), each
/// value's bit pattern (NaN equals NaN, -0.0 differs from 0.0).
fn bits(t: &Row) -> Vec<u64> {
    COLUMNS
        .iter()
        .zip(t.values())
        .filter(|(c, _)| c.source == ColumnSource::Controller)
        .map(|(_, v)| match v {
            Value::Float(f) => f.to_bits(),
            Value::Int(i) => i as u64,
            Value::Bool(b) => u64::from(b),
        })
        .collect()
}

fn assert_identical(replayed: &[Row], online: &[Row]) {
    assert_eq!(replayed.len(), online.len());
    for (k, (a, b)) in replayed.iter().zip(online).enumerate() {
        assert_eq!(bits(a), bits(b), "tick {k}: {a:?} vs {b:?}");
    }
}

/// The row after the protocol's end: every controller column unknown, the
/// command 0.
const AFTER_THE_PROTOCOL: Row = Row {
    u: 0.0,
    ..Row::UNKNOWN
};

/// A noisy simulated trial (sensor, motor and target-view noise).
fn simulated(phases: &[sensaug_core::protocol::Phase<'static>]) -> Vec<Row> {
    let mut sc = Scenario::new(
        phases,
        common::robot(),
        common::partner(2.0),
        common::world(5),
    )
    .unwrap();
    let mut out = vec![Row::UNKNOWN; sc.ticks()];
    sc.run(&mut out).unwrap();
    out
}

/// A noisy simulated trial and every tick's measurement of it.
fn measured(
    phases: &[sensaug_core::protocol::Phase<'static>],
) -> (Vec<Row>, Vec<Option<(f64, f64)>>) {
    let recs = simulated(phases);
    let measurements = recs.iter().map(|r| Some((r.x_meas, r.xdot_meas))).collect();
    (recs, measurements)
}

#[test]
fn a_simulated_trial_replays_bit_for_bit() {
    let phases = common::phases(1.5, 1.0);
    let (recs, measurements) = measured(&phases);
    let protocol = Protocol::new(&phases, common::DT).unwrap();
    let mut robot = fresh_robot(protocol);
    let mut out = vec![Row::UNKNOWN; recs.len()];
    let counters = replay_robot(&mut robot, &measurements, None, &mut out).unwrap();
    let online = recs;
    assert!(online.iter().any(|t| t.e_hat_fused.is_finite()));
    assert_identical(&out, &online);
    assert_eq!(counters.missing_measurements, 0);
}

/// A rig's robot predicts with its command plus the drive's rounding (the
/// log's `u`, `Robot::decide` then `Robot::predict`): a replay given that
/// torque repeats it bit for bit; without it, the replay predicts with its
/// own command and differs.
#[test]
fn a_rig_trial_replays_with_the_torque_the_drive_applied() {
    let phases = common::phases(1.5, 1.0);
    let (recs, measurements) = measured(&phases);
    let protocol = Protocol::new(&phases, common::DT).unwrap();
    let mut online_robot = fresh_robot(protocol);
    let step = 0.05;
    let online: Vec<Row> = measurements
        .iter()
        .enumerate()
        .map(|(k, m)| {
            let s = protocol.sample(k as u64).unwrap();
            let mut row = Row::UNKNOWN;
            let decision = online_robot.decide(&s, *m, &mut row);
            // The sum with a partner's torque, rounded, the rounding the robot's.
            let u_h = recs[k].u_h;
            row.u = ((decision.u + u_h) / step).round_ties_even() * step - u_h;
            online_robot.predict(decision, row.u);
            row
        })
        .collect();
    let applied: Vec<f64> = online.iter().map(|r| r.u).collect();
    let mut robot = fresh_robot(protocol);
    let mut out = vec![Row::UNKNOWN; recs.len()];
    replay_robot(&mut robot, &measurements, Some(&applied), &mut out).unwrap();
    assert_identical(&out, &online);
    let mut robot = fresh_robot(protocol);
    replay_robot(&mut robot, &measurements, None, &mut out).unwrap();
    assert!(out.iter().zip(&online).any(|(a, b)| a.Lhh_hat != b.Lhh_hat));
    assert_eq!(
        replay_robot(&mut robot, &measurements, Some(&applied[1..]), &mut out),
        Err(ReplayError::Length {
            which: ReplayArg::U,
            needed: applied.len(),
            got: applied.len() - 1
        })
    );
}

#[test]
fn missing_measurements_replay_as_the_online_predict_only_ticks() {
    let phases = common::phases(1.5, 1.0);
    let recs = simulated(&phases);
    // Every 7th tick lost (as a rig's feedback can be), one non-finite.
    let mut measurements: Vec<_> = recs
        .iter()
        .enumerate()
        .map(|(k, r)| (k % 7 != 3).then_some((r.x_meas, r.xdot_meas)))
        .collect();
    measurements[100] = Some((f64::NAN, 0.0));
    let protocol = Protocol::new(&phases, common::DT).unwrap();
    let mut online_robot = fresh_robot(protocol);
    let online: Vec<Row> = measurements
        .iter()
        .enumerate()
        .map(|(k, m)| {
            let s = protocol.sample(k as u64).unwrap();
            let mut row = Row::UNKNOWN;
            online_robot.tick_at(&s, *m, &mut row);
            row
        })
        .collect();
    let mut robot = fresh_robot(protocol);
    let mut out = vec![Row::UNKNOWN; recs.len()];
    let counters = replay_robot(&mut robot, &measurements, None, &mut out).unwrap();
    assert_identical(&out, &online);
    assert_eq!(counters, online_robot.counters());
    let lost = measurements.iter().filter(|m| m.is_none()).count() as u64 + 1;
    assert_eq!(counters.missing_measurements, lost);
    // ... and differ from a replay that had every measurement.
    let full = recs;
    assert_ne!(bits(&out[4]), bits(&full[4]));
}

#[test]
fn lengths_are_checked_and_ticks_after_the_protocol_are_none() {
    let phases = common::phases(0.01, 0.0);
    let protocol = Protocol::new(&phases, common::DT).unwrap();
    let mut robot = fresh_robot(protocol);
    let mut out = vec![Row::UNKNOWN; 3];
    assert_eq!(
        replay_robot(&mut robot, &[None; 4], None, &mut out),
        Err(ReplayError::Length {
            which: ReplayArg::Rows,
            needed: 4,
            got: 3
        })
    );
    let n = protocol.total_ticks() as usize;
    let mut out = vec![Row::UNKNOWN; n + 2];
    replay_robot(&mut robot, &vec![Some((0.0, 0.0)); n + 2], None, &mut out).unwrap();
    assert_eq!(
        out[n - 1].phase,
        Some(sensaug_core::protocol::PhaseKind::Integration)
    );
    assert_identical(&out[n..], &[AFTER_THE_PROTOCOL; 2]);
}

#[test]
fn a_robot_replay_does_not_allocate() {
    let phases = common::phases(1.0, 1.0);
    let protocol = Protocol::new(&phases, common::DT).unwrap();
    let mut robot = fresh_robot(protocol);
    let n = protocol.total_ticks() as usize;
    let measurements: Vec<_> = (0..n)
        .map(|k| (k % 5 != 0).then_some((1e-3 * (k as f64 * 1e-2).sin(), 0.0)))
        .collect();
    let mut out = vec![Row::UNKNOWN; n];
    let mut result = None;
    let a = allocations(|| result = Some(replay_robot(&mut robot, &measurements, None, &mut out)));
    assert_eq!(a, 0);
    assert!(result.unwrap().is_ok());
    assert!(out.iter().all(|t| t.u.is_finite()));
}

/// Every column not tagged `source`, each set to a value that is not its
/// unknown one.
fn all_but(source: ColumnSource) -> Row {
    let mut row = Row::UNKNOWN;
    for (i, c) in COLUMNS.iter().enumerate() {
        if c.source != source {
            let v = match row.values()[i] {
                Value::Int(_) => Value::Int(1),
                Value::Float(_) => Value::Float(1.5),
                Value::Bool(_) => Value::Bool(true),
            };
            row.set(i, v).unwrap();
        }
    }
    row
}

/// The source tags are the truth replay relies on: the controller writes
/// its columns and no other, and a simulated trial leaves the rig's
/// columns unknown.
#[test]
fn the_controller_and_the_world_fill_the_columns_their_tags_name() {
    let phases = common::phases(0.5, 1.0);
    let protocol = Protocol::new(&phases, common::DT).unwrap();
    let mut robot = fresh_robot(protocol);
    let before = all_but(ColumnSource::Controller);
    for k in 0..protocol.total_ticks() + 2 {
        let mut row = before;
        robot.tick_with(k, Some((1e-3 * k as f64, 0.0)), &mut row);
        let mut others = row;
        others.copy_columns(&before, ColumnSource::Controller);
        assert_eq!(format!("{others:?}"), format!("{before:?}"), "tick {k}");
    }
    for row in simulated(&phases) {
        let mut rig = Row::UNKNOWN;
        rig.copy_columns(&row, ColumnSource::Rig);
        assert_eq!(format!("{rig:?}"), format!("{:?}", Row::UNKNOWN));
        assert!(row.u.is_finite() && row.phase.is_some() && row.x.is_finite());
    }
}
