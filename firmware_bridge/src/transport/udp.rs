//! A virtual CAN bus in user space, on loopback only.
//!
//! Every peer on bus `<port>` has two sockets:
//!
//! - a receive socket bound to `127.255.255.255:<port>` with `SO_REUSEADDR`
//!   and `SO_REUSEPORT`, so every peer on the port gets every broadcast;
//! - a send socket bound to `127.0.0.1:0` with `SO_BROADCAST`, which sends
//!   each frame as one 16-byte `struct can_frame` datagram to
//!   `127.255.255.255:<port>`.
//!
//! A peer's own frames come back to its receive socket; it drops those
//! whose source is its send socket's address. Nothing leaves 127.0.0.0/8:
//! the broadcast address of the loopback network is only delivered on `lo`.

use std::io;
use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4, UdpSocket};
use std::os::fd::AsRawFd;
use std::time::Duration;

use socket2::{Domain, Protocol, Socket, Type};

use super::{deadline_after, wait_readable, BusStats, Transport, TransportError};
use crate::frame::{Frame, WIRE_SIZE};

/// The loopback broadcast address the UDP bus uses.
pub const UDP_BUS_ADDR: Ipv4Addr = Ipv4Addr::new(127, 255, 255, 255);

/// One peer on the loopback UDP virtual CAN bus `udp:<port>`.
#[derive(Debug)]
pub struct UdpBus {
    rx: UdpSocket,
    tx: UdpSocket,
    /// `tx`'s local address: the source of this peer's own frames.
    own: SocketAddr,
    /// `127.255.255.255:<port>`.
    dest: SocketAddr,
    stats: BusStats,
}

impl UdpBus {
    /// Join bus `port` (1..=65535). Set-up only: opens and binds two
    /// sockets.
    pub fn open(port: u16) -> Result<Self, TransportError> {
        let url = || format!("udp:{port}");
        if port == 0 {
            return Err(TransportError::BadUrl {
                url: url(),
                reason: "port 0 is not a bus (pick 1-65535)".into(),
            });
        }
        let open_err = |step: &'static str| {
            move |source: io::Error| TransportError::Open {
                url: url(),
                step,
                source,
            }
        };
        let dest = SocketAddr::V4(SocketAddrV4::new(UDP_BUS_ADDR, port));

        let rx = Socket::new(Domain::IPV4, Type::DGRAM, Some(Protocol::UDP))
            .map_err(open_err("socket (receive)"))?;
        rx.set_reuse_address(true)
            .map_err(open_err("SO_REUSEADDR"))?;
        rx.set_reuse_port(true).map_err(open_err("SO_REUSEPORT"))?;
        rx.bind(&dest.into())
            .map_err(open_err("bind 127.255.255.255"))?;
        rx.set_nonblocking(true)
            .map_err(open_err("O_NONBLOCK (receive)"))?;

        let tx = Socket::new(Domain::IPV4, Type::DGRAM, Some(Protocol::UDP))
            .map_err(open_err("socket (send)"))?;
        tx.set_broadcast(true).map_err(open_err("SO_BROADCAST"))?;
        let any_local = SocketAddr::V4(SocketAddrV4::new(Ipv4Addr::LOCALHOST, 0));
        tx.bind(&any_local.into())
            .map_err(open_err("bind 127.0.0.1:0"))?;
        let tx: UdpSocket = tx.into();
        let own = tx.local_addr().map_err(open_err("getsockname (send)"))?;

        Ok(Self {
            rx: rx.into(),
            tx,
            own,
            dest,
            stats: BusStats::default(),
        })
    }

    /// The bus port.
    pub fn port(&self) -> u16 {
        self.dest.port()
    }

    /// This peer's identity on the bus: its send socket's address, the
    /// source address of every frame it sends.
    pub fn local_addr(&self) -> SocketAddr {
        self.own
    }
}

impl Transport for UdpBus {
    /// One `send_to` of the 16-byte wire frame; no allocation.
    fn send(&mut self, frame: &Frame) -> Result<(), TransportError> {
        frame.validate().map_err(TransportError::InvalidFrame)?;
        let wire = frame.to_wire();
        let n = self
            .tx
            .send_to(&wire, self.dest)
            .map_err(|source| TransportError::Io { op: "send", source })?;
        if n != WIRE_SIZE {
            return Err(TransportError::Io {
                op: "send",
                source: io::Error::new(io::ErrorKind::WriteZero, "short datagram"),
            });
        }
        self.stats.sent += 1;
        Ok(())
    }

    /// Drain the receive socket until another peer's valid frame turns up;
    /// sleep in `ppoll` while it is empty, until `timeout` has passed. Own
    /// frames and malformed datagrams are counted and skipped.
    fn recv(&mut self, timeout: Duration) -> Result<Option<Frame>, TransportError> {
        let deadline = deadline_after(timeout);
        // One byte more than a frame, so oversized datagrams show as such.
        let mut buf = [0u8; WIRE_SIZE + 1];
        loop {
            match self.rx.recv_from(&mut buf) {
                Ok((n, src)) => {
                    if src == self.own {
                        self.stats.own_dropped += 1;
                        continue;
                    }
                    match Frame::from_wire(&buf[..n]) {
                        Ok(frame) => {
                            self.stats.received += 1;
                            return Ok(Some(frame));
                        }
                        Err(_) => self.stats.malformed_dropped += 1,
                    }
                }
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => {
                    if !wait_readable(self.rx.as_raw_fd(), deadline)? {
                        return Ok(None);
                    }
                }
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(source) => return Err(TransportError::Io { op: "recv", source }),
            }
        }
    }

    fn stats(&self) -> BusStats {
        self.stats
    }
}
