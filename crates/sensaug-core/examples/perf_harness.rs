//! Runs one workload of `benches/workloads/mod.rs` for `benches/report.py`:
//!
//! * `perf_harness time <name> <calls>`: times every call on its own
//!   (`Instant` around each call, after a warm-up) and prints one JSON line
//!   with the median, p99, p99.9 and maximum in nanoseconds, and the cost of
//!   an empty timed call (the timer overhead included in every sample).
//! * `perf_harness count <name> <calls>`: warms up, then runs `calls` calls
//!   untimed; run under `valgrind --tool=callgrind` with two call counts, the
//!   difference of the totals over the difference of the counts is the
//!   instruction count of one call (set-up and warm-up cancel).
//! * `perf_harness trial (time|count) <trials>`: the whole simulated Hi5
//!   trial (`workloads::trial`), one trial per call after one warm-up trial;
//!   `time` prints the median and maximum wall time per tick over the
//!   trials, `count` runs them untimed (under callgrind with two trial
//!   counts, the difference over the difference of ticks is the
//!   instruction count of one trial tick).
//! * `perf_harness list`: the workload names.
#![allow(non_snake_case)]

#[path = "../benches/workloads/mod.rs"]
mod workloads;

use std::process::ExitCode;
use std::time::Instant;

const WARM_UP_CALLS: usize = 1000;

fn percentile(sorted: &[u64], q: f64) -> u64 {
    let i = ((sorted.len() - 1) as f64 * q).round() as usize;
    sorted[i]
}

/// Per-call durations (ns) of `calls` calls of `f`, sorted.
fn timed(f: &mut dyn FnMut(), calls: usize) -> Vec<u64> {
    let mut samples = Vec::with_capacity(calls);
    for _ in 0..calls {
        let t0 = Instant::now();
        f();
        samples.push(t0.elapsed().as_nanos() as u64);
    }
    samples.sort_unstable();
    samples
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().collect();
    let usage =
        "usage: perf_harness (time|count) <workload> <calls> | trial (time|count) <trials> | list";
    if args.get(1).map(String::as_str) == Some("list") {
        for (name, _) in workloads::all() {
            println!("{name}");
        }
        return ExitCode::SUCCESS;
    }
    if args.get(1).map(String::as_str) == Some("trial") {
        return trial(
            args.get(2).map(String::as_str),
            args.get(3).map(String::as_str),
        );
    }
    let (Some(mode), Some(name), Some(calls)) = (args.get(1), args.get(2), args.get(3)) else {
        eprintln!("{usage}");
        return ExitCode::FAILURE;
    };
    let Ok(calls) = calls.parse::<usize>() else {
        eprintln!("calls: expected a positive integer, got {calls:?}");
        return ExitCode::FAILURE;
    };
    let Some((_, make)) = workloads::all().into_iter().find(|(n, _)| n == name) else {
        eprintln!("workload: unknown {name:?}; `perf_harness list` prints the names");
        return ExitCode::FAILURE;
    };
    let mut call = make();
    for _ in 0..WARM_UP_CALLS {
        call();
    }
    match mode.as_str() {
        "count" => {
            for _ in 0..calls {
                call();
            }
        }
        "time" if calls > 0 => {
            let samples = timed(&mut *call, calls);
            let empty = timed(&mut || {}, calls);
            println!(
                "{{\"name\": \"{name}\", \"calls\": {calls}, \"median_ns\": {}, \"p99_ns\": {}, \
                 \"p999_ns\": {}, \"max_ns\": {}, \"timer_overhead_median_ns\": {}}}",
                percentile(&samples, 0.5),
                percentile(&samples, 0.99),
                percentile(&samples, 0.999),
                samples[samples.len() - 1],
                percentile(&empty, 0.5),
            );
        }
        _ => {
            eprintln!("{usage}");
            return ExitCode::FAILURE;
        }
    }
    ExitCode::SUCCESS
}

/// `perf_harness trial (time|count) <trials>`.
fn trial(mode: Option<&str>, trials: Option<&str>) -> ExitCode {
    let Some(Ok(trials)) = trials.map(str::parse::<usize>) else {
        eprintln!("trials: expected a positive integer after `trial (time|count)`");
        return ExitCode::FAILURE;
    };
    let (mut call, ticks) = workloads::trial();
    call();
    match mode {
        Some("count") => {
            for _ in 0..trials {
                call();
            }
        }
        Some("time") if trials > 0 => {
            let samples = timed(&mut *call, trials);
            let per_tick = |ns: u64| ns as f64 / ticks as f64;
            println!(
                "{{\"name\": \"trial/hi5\", \"trials\": {trials}, \"ticks\": {ticks}, \
                 \"median_ns_per_tick\": {:.1}, \"max_ns_per_tick\": {:.1}}}",
                per_tick(percentile(&samples, 0.5)),
                per_tick(samples[samples.len() - 1]),
            );
        }
        _ => {
            eprintln!("usage: perf_harness trial (time|count) <trials>");
            return ExitCode::FAILURE;
        }
    }
    ExitCode::SUCCESS
}
