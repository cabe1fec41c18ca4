//! The kernel's share of a rig tick on the loopback UDP bus: what the bus
//! calls the loop makes cost with nothing of the loop around them, each
//! call timed on its own (`CLOCK_MONOTONIC`), the caller pinned to the last
//! CPU as the loop is. Prints JSON: per case the calls timed and p50, p99,
//! p99.9 and max in us. Nothing is asserted (a bench, not a test).
//!
//! - `empty drain`: `recv_ready` on an empty bus, one `recvmmsg` that finds
//!   nothing (the floor of the loop's sense step);
//! - `send, nobody waiting`: `send` of one frame while no thread sleeps on
//!   the bus (a real CAN adapter's case: no process to wake);
//! - `send waking a receiver on the other CPU` / `... on the same CPU`:
//!   `send` while a thread sleeps in `recv` on the bus, as the virtual
//!   drive does: the send wakes it (on another CPU: an inter-processor
//!   interrupt), at 1 kHz like the loop.
//!
//! `cargo bench -p sensaug-rt --bench bus_floor [-- <calls>]` (default
//! 5000 per case).

#[path = "../tests/common/drive.rs"]
mod drive;

use sensaug_bridge::transport::{Transport, UdpBus};
use sensaug_bridge::Frame;
use sensaug_rt::os;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// `p` quantile (nearest rank) of sorted `ns`, in us.
fn quantile_us(sorted_ns: &[u64], p: f64) -> f64 {
    let rank = ((p * sorted_ns.len() as f64).ceil() as usize).clamp(1, sorted_ns.len());
    sorted_ns[rank - 1] as f64 / 1e3
}

/// One case's percentiles as JSON.
fn summary(what: &str, mut ns: Vec<u64>) -> serde_json::Value {
    ns.sort_unstable();
    serde_json::json!({
        "what": what,
        "calls": ns.len(),
        "p50_us": quantile_us(&ns, 0.5),
        "p99_us": quantile_us(&ns, 0.99),
        "p999_us": quantile_us(&ns, 0.999),
        "max_us": quantile_us(&ns, 1.0),
    })
}

/// The duration of `f` (ns).
fn timed(f: impl FnOnce()) -> u64 {
    let t0 = os::now_ns();
    f();
    os::now_ns().saturating_sub(t0)
}

/// Empties `bus` (untimed).
fn drain(bus: &mut UdpBus) {
    while bus.recv_ready().expect("drain").is_some() {}
}

/// `calls` sends at 1 kHz while a thread on `receiver_cpu` sleeps in
/// `recv` on the bus and takes each frame.
fn send_waking(calls: usize, receiver_cpu: usize, port: u16, tx: &mut UdpBus) -> Vec<u64> {
    let stop = Arc::new(AtomicBool::new(false));
    let mut rx = UdpBus::open(port).expect("loopback bus");
    let receiver = {
        let stop = Arc::clone(&stop);
        std::thread::spawn(move || {
            let _ = os::pin_to_cpu(receiver_cpu);
            while !stop.load(Ordering::Relaxed) {
                let _ = rx.recv(Duration::from_millis(20));
            }
        })
    };
    std::thread::sleep(Duration::from_millis(50));
    let frame = Frame::new(0x123, &[1, 2, 3]).expect("frame");
    let mut ns = Vec::with_capacity(calls);
    let mut deadline = os::now_ns();
    for _ in 0..calls {
        deadline += 1_000_000;
        os::sleep_until(deadline);
        ns.push(timed(|| tx.send(&frame).expect("send")));
        drain(tx);
    }
    stop.store(true, Ordering::Relaxed);
    receiver.join().expect("receiver thread");
    ns
}

fn main() {
    let calls = std::env::args()
        .skip(1)
        .find_map(|a| a.parse::<usize>().ok())
        .unwrap_or(5000);
    let loop_cpu = std::thread::available_parallelism().map_or(1, |n| n.get()) - 1;
    let pinned = os::pin_to_cpu(loop_cpu).is_ok();
    let _ = os::minimal_timer_slack();
    let port = drive::free_port();
    let mut tx = UdpBus::open(port).expect("loopback bus");
    let mut cases = Vec::new();

    let empty: Vec<u64> = (0..calls)
        .map(|_| timed(|| assert!(tx.recv_ready().expect("recv").is_none())))
        .collect();
    cases.push(summary("empty drain (one recvmmsg)", empty));

    // A second peer whose socket takes every frame but nobody waits on.
    let mut idle = UdpBus::open(port).expect("loopback bus");
    let frame = Frame::new(0x123, &[1, 2, 3]).expect("frame");
    let mut quiet = Vec::with_capacity(calls);
    for _ in 0..calls {
        quiet.push(timed(|| tx.send(&frame).expect("send")));
        drain(&mut tx);
        drain(&mut idle);
    }
    drop(idle);
    cases.push(summary("send, nobody waiting", quiet));

    if loop_cpu > 0 {
        let other = send_waking(calls, 0, port, &mut tx);
        cases.push(summary("send waking a receiver on the other CPU", other));
    }
    let same = send_waking(calls, loop_cpu, port, &mut tx);
    cases.push(summary("send waking a receiver on the same CPU", same));

    let out = serde_json::json!({
        "caller_cpu": pinned.then_some(loop_cpu),
        "cases": cases,
    });
    println!("{out}");
}
