//! The loopback UDP virtual CAN bus. All traffic stays on 127.0.0.0/8.
//!
//! Each test asks the OS for a free port (bind 127.0.0.1:0, read it, close)
//! so tests running in parallel use different buses.

use std::net::{Ipv4Addr, SocketAddrV4, UdpSocket};
use std::thread;
use std::time::{Duration, Instant};

use sensaug_bridge::transport::{open, BusStats, Transport, TransportError, UdpBus, UDP_BUS_ADDR};
use sensaug_bridge::{Frame, FrameKind, WireError};

mod common;

fn frame(id: u32, byte: u8) -> Frame {
    Frame::new(id, &[byte, byte ^ 0xFF, 3]).unwrap()
}

const SHORT: Duration = Duration::from_millis(30);
const LONG: Duration = Duration::from_secs(2);

/// Two buses on one fresh loopback port.
fn two_buses() -> (UdpBus, UdpBus) {
    let port = common::free_port();
    (UdpBus::open(port).unwrap(), UdpBus::open(port).unwrap())
}

#[test]
fn three_peers_exchange_frames_and_never_see_their_own() {
    let port = common::free_port();
    let mut a = UdpBus::open(port).unwrap();
    let mut b = UdpBus::open(port).unwrap();
    let mut c = UdpBus::open(port).unwrap();
    assert_eq!(a.port(), port);
    assert_ne!(a.local_addr(), b.local_addr());
    assert!(a.local_addr().ip().is_loopback());

    a.send(&frame(0x201, 1)).unwrap();
    assert_eq!(b.recv(LONG).unwrap(), Some(frame(0x201, 1)));
    assert_eq!(c.recv(LONG).unwrap(), Some(frame(0x201, 1)));
    assert_eq!(a.recv(SHORT).unwrap(), None, "a saw its own frame");

    b.send(&frame(0x281, 2)).unwrap();
    c.send(&frame(0x701, 3)).unwrap();
    assert_eq!(a.recv(LONG).unwrap(), Some(frame(0x281, 2)));
    assert_eq!(a.recv(LONG).unwrap(), Some(frame(0x701, 3)));
    assert_eq!(b.recv(LONG).unwrap(), Some(frame(0x701, 3)));
    assert_eq!(b.recv(SHORT).unwrap(), None);
    assert_eq!(c.recv(LONG).unwrap(), Some(frame(0x281, 2)));
    assert_eq!(c.recv(SHORT).unwrap(), None);

    assert_eq!(
        a.stats(),
        BusStats {
            sent: 1,
            received: 2,
            own_dropped: 1,
            malformed_dropped: 0,
            kernel_dropped: 0,
            error_frames: 0,
            tx_queue_full: 0,
        }
    );
    assert_eq!(b.stats().own_dropped, 1);
    assert_eq!(c.stats().received, 2);
}

#[test]
fn frames_arrive_in_order() {
    let (mut a, mut b) = two_buses();
    for i in 0..200u32 {
        a.send(&Frame::new(0x200 + (i % 16), &i.to_le_bytes()).unwrap())
            .unwrap();
    }
    for i in 0..200u32 {
        let f = b.recv(LONG).unwrap().expect("frame");
        assert_eq!(f.payload(), &i.to_le_bytes());
    }
    assert_eq!(b.recv(SHORT).unwrap(), None);
}

#[test]
fn buses_on_different_ports_are_separate() {
    let (p1, p2) = (common::free_port(), common::free_port());
    if p1 == p2 {
        return;
    }
    let mut a = UdpBus::open(p1).unwrap();
    let mut b = UdpBus::open(p2).unwrap();
    a.send(&frame(0x10, 0)).unwrap();
    assert_eq!(b.recv(SHORT).unwrap(), None);
}

#[test]
fn garbage_datagrams_are_dropped_and_counted() {
    let port = common::free_port();
    let mut peer = UdpBus::open(port).unwrap();
    let raw = UdpSocket::bind("127.0.0.1:0").unwrap();
    raw.set_broadcast(true).unwrap();
    let dest = SocketAddrV4::new(UDP_BUS_ADDR, port);

    let good = frame(0x281, 9).to_wire();
    let mut too_long_len = good;
    too_long_len[4] = 9;
    // 0x800 needs 29 bits but the EFF flag is clear.
    let mut wide_standard_id = good;
    wide_standard_id[0..4].copy_from_slice(&0x800u32.to_le_bytes());
    let garbage: [&[u8]; 5] = [
        &[],
        &good[..15],
        &[0u8; 17],
        &too_long_len,
        &wide_standard_id,
    ];
    for g in garbage {
        raw.send_to(g, dest).unwrap();
    }
    raw.send_to(&good, dest).unwrap();

    assert_eq!(peer.recv(LONG).unwrap(), Some(frame(0x281, 9)));
    assert_eq!(peer.stats().malformed_dropped, 5);
    assert_eq!(peer.stats().received, 1);
    // Garbage alone: no frame, no error.
    raw.send_to(&[1, 2, 3], dest).unwrap();
    assert_eq!(peer.recv(SHORT).unwrap(), None);
    assert_eq!(peer.stats().malformed_dropped, 6);
}

#[test]
fn extended_remote_and_error_frames_are_carried() {
    let (mut a, mut b) = two_buses();
    let ext = Frame::data(0x1ABC_DEF0, true, &[1, 2, 3, 4, 5, 6, 7, 8]).unwrap();
    let ext_small = Frame::data(0x5, true, &[]).unwrap();
    let rtr = Frame::remote(0x123, false, 4).unwrap();
    let rtr_ext = Frame::remote(0x1234_5678, true, 8).unwrap();
    let err = Frame {
        id: 0x4, // CAN_ERR_CRTL
        len: 8,
        data: [0, 0x10, 0, 0, 0, 0, 0, 0],
        kind: FrameKind::Error,
        ..Frame::default()
    };
    for f in [ext, ext_small, rtr, rtr_ext, err] {
        a.send(&f).unwrap();
        assert_eq!(b.recv(LONG).unwrap(), Some(f));
    }
    assert_eq!(b.stats().malformed_dropped, 0);
    assert_eq!(b.stats().received, 5);
    // A 29-bit id in a standard frame is refused before sending.
    let wide = Frame {
        id: 0x800,
        ..Frame::default()
    };
    assert!(matches!(
        a.send(&wide),
        Err(TransportError::InvalidFrame(WireError::IdTooLarge {
            id: 0x800
        }))
    ));
}

#[test]
fn kernel_drops_of_a_full_receive_buffer_are_counted() {
    let port = common::free_port();
    let mut peer = UdpBus::open(port).unwrap();
    let granted = peer.recv_buffer_bytes().unwrap();
    assert!(granted >= 200_000, "receive buffer {granted} B");
    let raw = UdpSocket::bind("127.0.0.1:0").unwrap();
    raw.set_broadcast(true).unwrap();
    let dest = SocketAddrV4::new(UDP_BUS_ADDR, port);
    // Far more than the buffer holds (a queued 16-byte datagram costs
    // ~800 bytes of it on loopback), with nobody reading: the kernel drops
    // the rest. One more frame after draining carries the final count.
    let sent: u64 = (granted / 128 + 1000) as u64;
    let wire = frame(0x123, 1).to_wire();
    for _ in 0..sent {
        raw.send_to(&wire, dest).unwrap();
    }
    let mut received = 0u64;
    while peer.recv(Duration::ZERO).unwrap().is_some() {
        received += 1;
    }
    raw.send_to(&wire, dest).unwrap();
    assert!(peer.recv(LONG).unwrap().is_some());
    received += 1;
    let stats = peer.stats();
    assert_eq!(stats.received, received);
    assert!(stats.kernel_dropped > 0, "{stats:?}");
    assert_eq!(stats.kernel_dropped + received, sent + 1, "{stats:?}");
    println!(
        "buffer {granted} B: {received} frames queued, {} dropped",
        stats.kernel_dropped
    );
}

#[test]
fn recv_timeout_returns_none_in_time() {
    let mut peer = UdpBus::open(common::free_port()).unwrap();
    let t0 = Instant::now();
    assert_eq!(peer.recv(Duration::from_millis(50)).unwrap(), None);
    let dt = t0.elapsed();
    assert!(dt >= Duration::from_millis(50), "returned early: {dt:?}");
    assert!(dt < Duration::from_millis(500), "returned late: {dt:?}");

    let t0 = Instant::now();
    assert_eq!(peer.recv(Duration::ZERO).unwrap(), None);
    assert!(t0.elapsed() < Duration::from_millis(50));
}

#[test]
fn recv_wakes_up_when_a_frame_arrives() {
    let (mut a, mut b) = two_buses();
    let sender = thread::spawn(move || {
        thread::sleep(Duration::from_millis(30));
        a.send(&frame(0x300, 5)).unwrap();
    });
    let t0 = Instant::now();
    assert_eq!(
        b.recv(Duration::from_secs(5)).unwrap(),
        Some(frame(0x300, 5))
    );
    assert!(t0.elapsed() < Duration::from_secs(2));
    sender.join().unwrap();
}

#[test]
fn send_refuses_invalid_frames() {
    let mut peer = UdpBus::open(common::free_port()).unwrap();
    for (id, len, refused) in [
        (0x10, 9, WireError::LengthTooLarge { len: 9 }),
        (0x800, 0, WireError::IdTooLarge { id: 0x800 }),
    ] {
        let bad = Frame {
            id,
            len,
            data: [0; 8],
            ..Frame::default()
        };
        assert!(
            matches!(peer.send(&bad), Err(TransportError::InvalidFrame(e)) if e == refused),
            "{bad:?}"
        );
    }
    assert_eq!(peer.stats().sent, 0);
}

#[test]
fn open_by_url_gives_a_working_boxed_transport() {
    let port = common::free_port();
    let url = format!("udp:{port}");
    let mut a = open(&url).unwrap();
    let mut b = open(&url).unwrap();
    a.send(&frame(0x11, 0)).unwrap();
    assert_eq!(b.recv(LONG).unwrap(), Some(frame(0x11, 0)));
    // Send + 'static: usable from another thread.
    let handle = thread::spawn(move || b.recv(SHORT).unwrap());
    assert_eq!(handle.join().unwrap(), None);
}

#[test]
fn udp_bus_port_zero_is_refused() {
    let e = UdpBus::open(0).unwrap_err();
    assert!(matches!(e, TransportError::BadUrl { .. }), "{e:?}");
    assert!(e.to_string().contains("udp:0"));
}

#[test]
fn bus_address_is_loopback() {
    assert_eq!(UDP_BUS_ADDR, Ipv4Addr::new(127, 255, 255, 255));
    assert!(UDP_BUS_ADDR.is_loopback());
}

/// Everything `b` can drain now with `recv_ready` (until `None`).
fn drain_ready(b: &mut UdpBus) -> Vec<Frame> {
    std::iter::from_fn(|| b.recv_ready().unwrap()).collect()
}

#[test]
fn recv_ready_drains_every_waiting_frame_and_sees_later_ones() {
    let (mut a, mut b) = two_buses();
    assert!(
        drain_ready(&mut b).is_empty(),
        "an empty bus drains to nothing"
    );

    // Two full batches and a short one, and b's own frame among them.
    let sent: Vec<Frame> = (0..40u8).map(|i| frame(0x200 + u32::from(i), i)).collect();
    for (i, f) in sent.iter().enumerate() {
        a.send(f).unwrap();
        if i == 20 {
            b.send(&frame(0x7FF, 0xAA)).unwrap();
        }
    }
    // Loopback delivery ends within the send calls; the pause only makes
    // the test independent of the scheduler.
    thread::sleep(SHORT);
    assert_eq!(drain_ready(&mut b), sent);
    assert_eq!(b.stats().own_dropped, 1);

    // The short batch that ended the last drain does not end the next one
    // before it has read the socket again.
    a.send(&frame(0x301, 1)).unwrap();
    a.send(&frame(0x302, 2)).unwrap();
    thread::sleep(SHORT);
    assert_eq!(drain_ready(&mut b), [frame(0x301, 1), frame(0x302, 2)]);
    assert!(drain_ready(&mut b).is_empty());
    assert_eq!(b.stats().received, 42);
}

#[test]
fn every_received_frame_carries_the_kernels_receive_time() {
    let (mut a, mut b) = two_buses();
    assert_eq!(b.last_rx_time(), None);
    let before = std::time::SystemTime::now();
    a.send(&Frame::new(0x123, &[1, 2]).unwrap()).unwrap();
    let got = b.recv(Duration::from_secs(1)).unwrap().expect("no frame");
    let after = std::time::SystemTime::now();
    assert_eq!(got.id, 0x123);
    let t = b.last_rx_time().expect("no SO_TIMESTAMPNS time");
    assert!(
        before <= t && t <= after,
        "{before:?} <= {t:?} <= {after:?}"
    );
}
