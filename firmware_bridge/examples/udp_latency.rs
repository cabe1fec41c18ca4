//! Round-trip latency of the loopback UDP virtual CAN bus.
//!
//! Peer A (host) encodes a TorqueCommand and sends it; peer B (a thread
//! playing the drive) decodes it and answers with a Feedback echoing the
//! sequence; A waits for that Feedback and decodes it. One round trip =
//! A's send to A's decoded answer. Loopback only (127.255.255.255).
//!
//! ```text
//! cargo run --release -p sensaug-bridge --example udp_latency -- [N] [PORT]
//! ```
//! N defaults to 10000 (after 1000 warm-up round trips); PORT to a free
//! one.

use std::net::UdpSocket;
use std::thread;
use std::time::{Duration, Instant};

use sensaug_bridge::protocol::{decode, encode, DriveState, Message, NodeId};
use sensaug_bridge::transport::{Transport, UdpBus};

const WARMUP: usize = 1000;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let n: usize = args.next().map_or(Ok(10_000), |s| s.parse())?;
    let port: u16 = match args.next() {
        Some(p) => p.parse()?,
        None => UdpSocket::bind("127.0.0.1:0")?.local_addr()?.port(),
    };
    let node = NodeId::new(1)?;
    let total = WARMUP + n;

    let mut host = UdpBus::open(port)?;
    let mut drive = UdpBus::open(port)?;

    let echo = thread::spawn(move || -> Result<(), String> {
        for _ in 0..total {
            let f = drive
                .recv(Duration::from_secs(5))
                .map_err(|e| e.to_string())?
                .ok_or("drive: no command within 5 s")?;
            let Message::TorqueCommand { sequence, .. } =
                decode(node, &f).map_err(|e| e.to_string())?
            else {
                return Err("drive: expected a TorqueCommand".into());
            };
            let fb = Message::Feedback {
                position_rad: 0.25,
                velocity_rad_s: -1.5,
                sequence,
                state: DriveState::Enabled,
                torque_limited: false,
                fault_active: false,
            };
            drive
                .send(&encode(node, &fb).map_err(|e| e.to_string())?)
                .map_err(|e| e.to_string())?;
        }
        Ok(())
    });

    let mut rtt = Vec::with_capacity(n);
    for i in 0..total {
        let seq = i as u8;
        let cmd = encode(
            node,
            &Message::TorqueCommand {
                torque_nm: 0.001 * (i % 1000) as f64,
                sequence: seq,
            },
        )?;
        let t0 = Instant::now();
        host.send(&cmd)?;
        let f = host
            .recv(Duration::from_secs(5))?
            .ok_or("host: no feedback within 5 s")?;
        let back = decode(node, &f)?;
        let dt = t0.elapsed();
        match back {
            Message::Feedback { sequence, .. } if sequence == seq => {}
            other => return Err(format!("host: unexpected {other:?}").into()),
        }
        if i >= WARMUP {
            rtt.push(dt);
        }
    }
    echo.join().map_err(|_| "echo thread panicked")??;

    rtt.sort_unstable();
    let pct = |p: f64| rtt[((rtt.len() - 1) as f64 * p).round() as usize];
    let us = |d: Duration| d.as_secs_f64() * 1e6;
    let mean = rtt.iter().sum::<Duration>() / u32::try_from(rtt.len())?;
    println!("UDP bus round trip (encode, send, recv, decode, echo), N = {n}, port {port}");
    println!(
        "min {:.1} us  median {:.1} us  mean {:.1} us  p99 {:.1} us  p99.9 {:.1} us  max {:.1} us",
        us(rtt[0]),
        us(pct(0.5)),
        us(mean),
        us(pct(0.99)),
        us(pct(0.999)),
        us(rtt[rtt.len() - 1])
    );
    let s = host.stats();
    println!(
        "host stats: sent {} received {} own dropped {} malformed {} kernel dropped {}",
        s.sent, s.received, s.own_dropped, s.malformed_dropped, s.kernel_dropped
    );
    Ok(())
}
