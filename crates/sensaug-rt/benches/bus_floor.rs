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
//! - `paced drain` / `paced send` / `paced drain + send`: the loop's bus
//!   calls alone, at its pace and in its order: at each 1 ms deadline one
//!   drain (the peer's answer to the last frame and the own frame's echo,
//!   one `recvmmsg`) then one send, while a peer on the other CPU polls the
//!   bus as the bench's polling drive does and answers every frame with
//!   one: what a tick's `sense` and `actuate` cost with no controller
//!   between them (the floor of `rig_tick -- polling`'s compute).
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

/// A peer on `cpu` that polls the bus like the polling drive of the rig
/// bench ([`drive::wait_poll_gap`] after an empty look) and
/// answers every frame with one frame, until `stop`.
fn polling_echo(port: u16, cpu: usize, stop: Arc<AtomicBool>) -> std::thread::JoinHandle<()> {
    let mut peer = UdpBus::open(port).expect("loopback bus");
    std::thread::spawn(move || {
        let _ = os::pin_to_cpu(cpu);
        let answer = Frame::new(0x181, &[0; 8]).expect("frame");
        while !stop.load(Ordering::Relaxed) {
            match peer.recv_ready() {
                Ok(Some(_)) => peer.send(&answer).expect("send"),
                _ => drive::wait_poll_gap(),
            }
        }
    })
}

/// `calls` ticks at 1 kHz of the loop's bus calls alone: drain, then send,
/// each timed, with [`polling_echo`] on `peer_cpu` answering every send.
/// Returns (drain, send, drain + send) in ns.
fn paced_exchange(
    calls: usize,
    peer_cpu: usize,
    port: u16,
    tx: &mut UdpBus,
) -> (Vec<u64>, Vec<u64>, Vec<u64>) {
    let stop = Arc::new(AtomicBool::new(false));
    let peer = polling_echo(port, peer_cpu, Arc::clone(&stop));
    std::thread::sleep(Duration::from_millis(50));
    drain(tx);
    let frame = Frame::new(0x201, &[1, 2, 3, 4, 5, 6, 7, 8]).expect("frame");
    let (mut drains, mut sends, mut both) = (
        Vec::with_capacity(calls),
        Vec::with_capacity(calls),
        Vec::with_capacity(calls),
    );
    let mut deadline = os::now_ns();
    for _ in 0..calls {
        deadline += 1_000_000;
        os::sleep_until(deadline);
        let t0 = os::now_ns();
        drain(tx);
        let t1 = os::now_ns();
        tx.send(&frame).expect("send");
        let t2 = os::now_ns();
        drains.push(t1 - t0);
        sends.push(t2 - t1);
        both.push(t2 - t0);
    }
    stop.store(true, Ordering::Relaxed);
    peer.join().expect("peer thread");
    (drains, sends, both)
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

    if loop_cpu > 0 {
        let (drains, sends, both) = paced_exchange(calls, 0, port, &mut tx);
        cases.push(summary(
            "paced drain (1 kHz, polling peer answering)",
            drains,
        ));
        cases.push(summary("paced send (1 kHz, polling peer answering)", sends));
        cases.push(summary(
            "paced drain + send (1 kHz, polling peer answering)",
            both,
        ));
    }

    let out = serde_json::json!({
        "caller_cpu": pinned.then_some(loop_cpu),
        "cases": cases,
    });
    println!("{out}");
}
