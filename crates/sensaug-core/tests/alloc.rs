//! Proves at run time that nothing in a control tick allocates: a counting
//! global allocator records every allocation made by the measuring thread
//! while a flag is set (thread-local, so parallel tests do not interfere).
#![allow(non_snake_case)]

#[path = "common/alloc_counter.rs"]
mod alloc_counter;
mod common;

use alloc_counter::allocations;

use nalgebra::{Matrix2, Matrix3, SMatrix, SVector, Vector2, Vector3};
use sensaug_core::estimator::GainEstimator;
use sensaug_core::goal::GoalIntegrator;
use sensaug_core::plant::{Plant, PlantParams};
use sensaug_core::riccati::{care, dare};
use sensaug_core::row::Row;
use sensaug_core::world::Scenario;

#[test]
fn the_counter_sees_an_allocation() {
    let n = allocations(|| {
        let v: Vec<u8> = Vec::with_capacity(16);
        std::hint::black_box(v);
    });
    assert_eq!(n, 1);
}

#[test]
fn plant_steps_do_not_allocate() {
    let mut p = Plant::new(PlantParams {
        damping: 0.01,
        coulomb: 0.002,
        ..PlantParams::HI5
    })
    .unwrap();
    let n = allocations(|| {
        for k in 0..100_000 {
            let _ = p.step((k as f64 * 1e-3).sin() * 0.01);
        }
    });
    assert_eq!(n, 0);
}

#[test]
fn riccati_solves_do_not_allocate() {
    let A = Matrix3::new(0.0, 1.0, 0.0, 0.0, -0.1, 1.0, 0.5, 0.0, -1.0);
    let B = SMatrix::<f64, 3, 1>::new(0.0, 0.0, 1.0);
    let Q = Matrix3::identity();
    let R = SMatrix::<f64, 1, 1>::identity();
    let Ad = Matrix2::new(1.0, 1e-3, 0.0, 1.0);
    let Bd = SMatrix::<f64, 2, 1>::new(0.0, 1e-3);
    let n = allocations(|| {
        for _ in 0..100 {
            std::hint::black_box(care(&A, &B, &Q, &R).unwrap());
            std::hint::black_box(dare(&Ad, &Bd, &Matrix2::identity(), &R).unwrap());
        }
    });
    assert_eq!(n, 0);
}

#[test]
fn estimator_steps_do_not_allocate() {
    let (mut g, mut t, mut gi) = common::estimators();
    let n = allocations(|| {
        for k in 0..10_000 {
            let s = (k as f64 * 1e-3).sin();
            let _ = g.update(&Vector3::new(s, 0.1, s));
            let _ = g.predict(0.1 * s, 1e-3, 1e-3);
            let _ = t.update(&SVector::<f64, 5>::new(s, 0.1, 0.0, 0.0, 2.0));
            let _ = t.predict(0.1 * s, 1e-3, 0.0);
            let _ = gi.update(&Vector2::new(s, 0.1), Some(s));
            let _ = gi.predict(0.1, 0.0);
        }
    });
    assert_eq!(n, 0);
}

#[test]
fn a_full_trial_of_ticks_does_not_allocate() {
    // Set-up (may allocate): the scenario and its output buffer.
    let phases = common::phases(2.0, 1.0);
    let mut sc = Scenario::new(
        &phases,
        common::robot(),
        common::partner(2.0),
        common::world(3),
    )
    .unwrap();
    let mut out = vec![Row::UNKNOWN; sc.ticks()];
    // Every tick: sense, robot (3 estimators + control), partner, plant.
    let mut summary = None;
    let n = allocations(|| summary = Some(sc.run(&mut out)));
    assert_eq!(n, 0);
    let summary = summary.unwrap().unwrap();
    assert_eq!(summary.ticks, 6000);
    assert!(out.iter().all(|r| r.x.is_finite() && r.u.is_finite()));
}

#[test]
fn batch_replays_do_not_allocate() {
    use sensaug_core::replay::{replay, simulate, GoalReplay, Posteriors, Recording};
    const T: usize = 2_000;
    let model = common::model();
    let mut g = GainEstimator::new(model, &common::extended::<3>()).unwrap();
    let mut gi = GoalIntegrator::new(model, &common::robot().stage3).unwrap();
    let mut plant = Plant::new(PlantParams {
        mass: 0.0035,
        damping: 0.01,
        coulomb: 0.002,
        dt_s: 1e-3,
    })
    .unwrap();
    let y: Vec<f64> = (0..3 * T).map(|i| 1e-3 * (i as f64 * 1e-2).sin()).collect();
    let u: Vec<f64> = (0..T).map(|k| 0.01 * (k as f64 * 1e-3).sin()).collect();
    let dtau = vec![1e-4; T];
    let (mut xs, mut var) = (vec![0.0; 6 * T], vec![0.0; 6 * T]);
    let n = allocations(|| {
        let rec = Recording {
            y: &y,
            u: &u,
            dtau: Some(&dtau),
            dtau_h: Some(&dtau),
        };
        let mut out = Posteriors {
            x: &mut xs,
            var: &mut var,
        };
        let report = replay(&mut g, &rec, &mut out).unwrap();
        std::hint::black_box(report);
        let mut r = GoalReplay::new(&mut gi, true);
        let rec = Recording {
            dtau_h: None,
            ..rec
        };
        let mut out = Posteriors {
            x: &mut xs[..2 * T],
            var: &mut var[..2 * T],
        };
        std::hint::black_box(replay(&mut r, &rec, &mut out).unwrap());
        let (x, v) = xs.split_at_mut(T);
        simulate(&mut plant, &u, x, &mut v[..T]).unwrap();
    });
    assert_eq!(n, 0);
}
