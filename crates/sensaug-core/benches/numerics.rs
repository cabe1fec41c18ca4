//! Latency of the per-tick numerics: UKF steps of the paper's estimators
//! (6 states; 3 and 5 measurements), CARE/DARE (2 and 3 states) and a whole
//! robot tick. `benches/run.sh` runs this next to the scipy/filterpy timings.
#![allow(non_snake_case)]

#[path = "../tests/common/mod.rs"]
mod common;

use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::{Matrix2, Matrix3, SMatrix, SVector, Vector3};
use sensaug_core::controller::Robot;
use sensaug_core::estimator::{GainEstimator, TrajectoryEstimator};
use sensaug_core::protocol::Protocol;
use sensaug_core::riccati::{care, dare};
use std::hint::black_box;

/// The 3-state system timed here and in `benches/compare_oracles.py`.
pub fn system3() -> (Matrix3<f64>, SMatrix<f64, 3, 1>) {
    (
        Matrix3::new(0.0, 1.0, 0.0, 0.0, -0.1, 1.0, 0.5, 0.0, -1.0),
        SMatrix::<f64, 3, 1>::new(0.0, 0.0, 1.0),
    )
}

fn ukf_steps(c: &mut Criterion) {
    let model = common::model();
    let mut g = GainEstimator::new(model, &common::extended::<3>()).unwrap();
    let mut k = 0u64;
    // Sanity before timing: a step succeeds and stays finite.
    let _ = g.update(&Vector3::new(0.1, 0.0, 0.1)).unwrap();
    assert!(g.filter().x().iter().all(|v| v.is_finite()));
    c.bench_function("ukf_step/6_states_3_measurements", |b| {
        b.iter(|| {
            k += 1;
            let s = (k as f64 * 1e-3).sin();
            let _ = g.update(black_box(&Vector3::new(s, 0.1, s)));
            let _ = g.predict(black_box(0.01 * s), 1e-3, 1e-3);
        })
    });
    let mut t = TrajectoryEstimator::new(model, &common::extended::<5>()).unwrap();
    c.bench_function("ukf_step/6_states_5_measurements", |b| {
        b.iter(|| {
            k += 1;
            let s = (k as f64 * 1e-3).sin();
            let _ = t.update(black_box(&SVector::<f64, 5>::new(s, 0.1, 0.0, 0.0, 2.0)));
            let _ = t.predict(black_box(0.01 * s), 1e-3, 0.0);
        })
    });
}

fn riccati(c: &mut Criterion) {
    let A2 = Matrix2::new(0.0, 1.0, 0.0, -0.5);
    let B2 = SMatrix::<f64, 2, 1>::new(0.0, 1.0 / common::M);
    let R = SMatrix::<f64, 1, 1>::identity();
    let (A3, B3) = system3();
    let Ad2 = Matrix2::new(1.0, 1e-3, 0.0, 1.0);
    let Bd2 = SMatrix::<f64, 2, 1>::new(5e-7, 1e-3);
    let Ad3 = Matrix3::identity() + A3 * 1e-2;
    let Bd3 = B3 * 1e-2;
    assert!(care(&A3, &B3, &Matrix3::identity(), &R).is_ok());
    c.bench_function("care/2_states", |b| {
        b.iter(|| care(black_box(&A2), &B2, &Matrix2::identity(), &R))
    });
    c.bench_function("care/3_states", |b| {
        b.iter(|| care(black_box(&A3), &B3, &Matrix3::identity(), &R))
    });
    c.bench_function("dare/2_states", |b| {
        b.iter(|| dare(black_box(&Ad2), &Bd2, &Matrix2::identity(), &R))
    });
    c.bench_function("dare/3_states", |b| {
        b.iter(|| dare(black_box(&Ad3), &Bd3, &Matrix3::identity(), &R))
    });
}

fn robot_tick(c: &mut Criterion) {
    let phase_s = 1000.0;
    let phases = common::phases(phase_s, 1.0);
    let protocol = Protocol::new(&phases, common::DT).unwrap();
    let phase_ticks = (phase_s / common::DT) as u64;
    for (name, first_tick) in [
        ("robot_tick/gains_phase", 0),
        ("robot_tick/integration_phase", 2 * phase_ticks),
    ] {
        let mut robot = Robot::new(common::robot(), protocol).unwrap();
        let mut k = first_tick;
        c.bench_function(name, |b| {
            b.iter(|| {
                k += 1;
                black_box(robot.tick(k, black_box(0.01), 0.0))
            })
        });
    }
}

criterion_group!(benches, ukf_steps, riccati, robot_tick);
criterion_main!(benches);
