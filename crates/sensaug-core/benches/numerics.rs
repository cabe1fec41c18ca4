//! Latency of the per-tick numerics (criterion): UKF steps of the paper's
//! estimators (6 states; 3 and 5 measurements), CARE/DARE (2 and 3 states)
//! and the robot's whole tick in each phase of the protocol, each in one
//! steady state (`workloads/mod.rs`). `benches/run.sh` writes the per-call
//! medians and tails next to the scipy/filterpy timings; `--bench tick_tail`
//! prints the tick's tail over 1e6 individually timed ticks.
#![allow(non_snake_case)]

use criterion::{criterion_group, criterion_main, Criterion};

#[path = "workloads/mod.rs"]
mod workloads;

/// Every workload of `workloads/mod.rs`, one bench each: one call per
/// criterion iteration, every call in the workload's steady state.
fn numerics(c: &mut Criterion) {
    for (name, make) in workloads::all() {
        let mut call = make();
        c.bench_function(name, |b| b.iter(&mut call));
    }
}

criterion_group!(benches, numerics);
criterion_main!(benches);
