//! Latency of the per-tick numerics: UKF steps of the paper's estimators
//! (6 states; 3 and 5 measurements), CARE/DARE (2 and 3 states) and a whole
//! robot tick. `benches/run.sh` runs this next to the scipy/filterpy timings.
#![allow(non_snake_case)]

#[path = "../tests/common/mod.rs"]
mod common;

use criterion::{criterion_group, criterion_main, Criterion};
use sensaug_core::controller::Robot;
use sensaug_core::protocol::Protocol;
use std::hint::black_box;

#[path = "workloads/mod.rs"]
mod workloads;

/// The UKF steps and Riccati solves of `workloads.rs`, one bench each.
fn numerics(c: &mut Criterion) {
    for (name, make) in workloads::all() {
        let mut call = make();
        c.bench_function(name, |b| b.iter(&mut call));
    }
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

criterion_group!(benches, numerics, robot_tick);
criterion_main!(benches);
