//! The robot tick's tail: 1e6 individually timed ticks per phase of the Hi5
//! protocol (`workloads::TICK_WORKLOADS`, each in its steady state), as a
//! histogram with p50, p99, p99.9 and max, and the number of allocations made
//! by the timed ticks (a counting global allocator; must be 0).
//!
//! `cargo bench -p sensaug-core --bench tick_tail [-- <ticks>] [--json]`:
//! `--json` prints one JSON object per phase (for `benches/report.py`)
//! instead of the histograms.
#![allow(non_snake_case)]

#[path = "../tests/common/alloc_counter.rs"]
mod alloc_counter;
#[path = "workloads/mod.rs"]
mod workloads;

use std::time::Instant;

const DEFAULT_TICKS: usize = 1_000_000;
const WARM_UP_TICKS: usize = 10_000;
/// Histogram bucket edges (ns): one bucket per edge, the last open-ended.
const EDGES_NS: [u64; 12] = [
    250, 500, 750, 1_000, 1_500, 2_000, 3_000, 5_000, 10_000, 50_000, 100_000, 1_000_000,
];

fn percentile(sorted: &[u64], q: f64) -> u64 {
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let json = args.iter().any(|a| a == "--json");
    let ticks = args
        .iter()
        .find_map(|a| a.parse::<usize>().ok())
        .unwrap_or(DEFAULT_TICKS)
        .max(1);
    for (name, make) in workloads::TICK_WORKLOADS {
        let mut tick = make();
        for _ in 0..WARM_UP_TICKS {
            tick();
        }
        let mut samples = vec![0u64; ticks];
        let allocations = alloc_counter::allocations(|| {
            for s in samples.iter_mut() {
                let t0 = Instant::now();
                tick();
                *s = t0.elapsed().as_nanos() as u64;
            }
        });
        samples.sort_unstable();
        let (p50, p99, p999, max) = (
            percentile(&samples, 0.5),
            percentile(&samples, 0.99),
            percentile(&samples, 0.999),
            samples[ticks - 1],
        );
        if json {
            println!(
                "{{\"name\": \"{name}\", \"ticks\": {ticks}, \"p50_ns\": {p50}, \"p99_ns\": {p99}, \
                 \"p999_ns\": {p999}, \"max_ns\": {max}, \"allocations\": {allocations}}}"
            );
            continue;
        }
        println!("{name}: {ticks} ticks, each timed on its own (Instant around the tick)");
        println!(
            "  p50 {:.2} us, p99 {:.2} us, p99.9 {:.2} us, max {:.2} us; allocations {allocations}",
            p50 as f64 / 1e3,
            p99 as f64 / 1e3,
            p999 as f64 / 1e3,
            max as f64 / 1e3
        );
        let mut lo = 0u64;
        for (i, &hi) in EDGES_NS.iter().chain([u64::MAX].iter()).enumerate() {
            let n = samples.partition_point(|&s| s < hi) - samples.partition_point(|&s| s < lo);
            if n > 0 {
                let label = if i == EDGES_NS.len() {
                    format!(">= {:.2} us", lo as f64 / 1e3)
                } else {
                    format!("[{:.2}, {:.2}) us", lo as f64 / 1e3, hi as f64 / 1e3)
                };
                println!(
                    "  {label:>22} {n:>8} {:>8.4}%",
                    100.0 * n as f64 / ticks as f64
                );
            }
            lo = hi;
        }
    }
}
