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
//!
//! Bursts: the receive buffer asks for [`RECV_BUFFER_BYTES`] (the kernel
//! grants up to `net.core.rmem_max`, or more with `CAP_NET_ADMIN`; see
//! [`UdpBus::recv_buffer_bytes`]). A datagram that arrives while it is full
//! is dropped by the kernel; `SO_RXQ_OVFL` reports the socket's drop count
//! with every datagram received, and [`BusStats::kernel_dropped`] sums it.

use std::io;
use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4, UdpSocket};
use std::os::fd::{AsRawFd, RawFd};
use std::time::Duration;

use socket2::{Domain, Protocol, Socket, Type};

use super::{deadline_after, wait_readable, BusStats, Transport, TransportError};
use crate::frame::{Frame, WIRE_SIZE};

/// The loopback broadcast address the UDP bus uses.
pub const UDP_BUS_ADDR: Ipv4Addr = Ipv4Addr::new(127, 255, 255, 255);

/// The receive buffer each peer asks for: 4 MiB, about 5000 queued frames
/// (a 16-byte datagram costs ~800 bytes of buffer on loopback).
pub const RECV_BUFFER_BYTES: usize = 4 << 20;

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
    /// The last `SO_RXQ_OVFL` value (the kernel's wrapping u32 count).
    kernel_drops_seen: u32,
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
        set_recv_buffer(&rx, RECV_BUFFER_BYTES).map_err(open_err("SO_RCVBUF"))?;
        set_int_option(rx.as_raw_fd(), libc::SO_RXQ_OVFL, 1).map_err(open_err("SO_RXQ_OVFL"))?;
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
            kernel_drops_seen: 0,
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

    /// The receive buffer the kernel granted, bytes (`SO_RCVBUF`).
    pub fn recv_buffer_bytes(&self) -> io::Result<usize> {
        socket2::SockRef::from(&self.rx).recv_buffer_size()
    }

    /// One datagram from the receive socket without blocking: its length
    /// and source; folds the `SO_RXQ_OVFL` count into the statistics.
    fn recv_datagram(&mut self, buf: &mut [u8]) -> io::Result<(usize, SocketAddr)> {
        let (n, src, drops) = recvmsg_with_drops(self.rx.as_raw_fd(), buf)?;
        if let Some(drops) = drops {
            let new = drops.wrapping_sub(self.kernel_drops_seen);
            self.stats.kernel_dropped += u64::from(new);
            self.kernel_drops_seen = drops;
        }
        Ok((n, src))
    }
}

/// Ask for `bytes` of receive buffer: `SO_RCVBUFFORCE` (allowed with
/// `CAP_NET_ADMIN`), else `SO_RCVBUF` (capped by `net.core.rmem_max`).
fn set_recv_buffer(sock: &Socket, bytes: usize) -> io::Result<()> {
    let n = libc::c_int::try_from(bytes).unwrap_or(libc::c_int::MAX);
    if set_int_option(sock.as_raw_fd(), libc::SO_RCVBUFFORCE, n).is_ok() {
        return Ok(());
    }
    sock.set_recv_buffer_size(bytes)
}

/// `setsockopt(fd, SOL_SOCKET, name, value)` for an int option.
fn set_int_option(fd: RawFd, name: libc::c_int, value: libc::c_int) -> io::Result<()> {
    // SAFETY: `value` is a live c_int and the length passed is its size;
    // the kernel only reads it.
    let rc = unsafe {
        libc::setsockopt(
            fd,
            libc::SOL_SOCKET,
            name,
            (&value as *const libc::c_int).cast(),
            core::mem::size_of::<libc::c_int>() as libc::socklen_t,
        )
    };
    if rc == 0 {
        Ok(())
    } else {
        Err(io::Error::last_os_error())
    }
}

/// Control-message buffer for one `SO_RXQ_OVFL` (a u32), aligned for
/// `cmsghdr`.
#[repr(C, align(8))]
struct CmsgBuf([u8; 64]);

/// `recvmsg(2)` of one IPv4 datagram without blocking: length, source, and
/// the socket's `SO_RXQ_OVFL` drop count if the kernel attached it.
/// Allocation-free.
fn recvmsg_with_drops(fd: RawFd, buf: &mut [u8]) -> io::Result<(usize, SocketAddr, Option<u32>)> {
    // SAFETY: sockaddr_in and msghdr are plain C structs for which all-zero
    // bytes are a valid value.
    let mut addr: libc::sockaddr_in = unsafe { core::mem::zeroed() };
    let mut iov = libc::iovec {
        iov_base: buf.as_mut_ptr().cast(),
        iov_len: buf.len(),
    };
    let mut control = CmsgBuf([0; 64]);
    // SAFETY: as above.
    let mut msg: libc::msghdr = unsafe { core::mem::zeroed() };
    msg.msg_name = (&mut addr as *mut libc::sockaddr_in).cast();
    msg.msg_namelen = core::mem::size_of::<libc::sockaddr_in>() as libc::socklen_t;
    msg.msg_iov = &mut iov;
    msg.msg_iovlen = 1;
    msg.msg_control = control.0.as_mut_ptr().cast();
    msg.msg_controllen = control.0.len() as _;
    // SAFETY: every pointer in `msg` (name, one iovec over `buf`, control)
    // points to live, writable memory of the stated length for the call.
    let n = unsafe { libc::recvmsg(fd, &mut msg, libc::MSG_DONTWAIT) };
    if n < 0 {
        return Err(io::Error::last_os_error());
    }
    let mut drops = None;
    // SAFETY: `msg` was filled by recvmsg; CMSG_FIRSTHDR/CMSG_NXTHDR stay
    // within `msg_control[..msg_controllen]` and return null at its end.
    let mut cmsg = unsafe { libc::CMSG_FIRSTHDR(&msg) };
    while !cmsg.is_null() {
        // SAFETY: `cmsg` is non-null and points into `control` (above).
        let hdr = unsafe { &*cmsg };
        if hdr.cmsg_level == libc::SOL_SOCKET && hdr.cmsg_type == libc::SO_RXQ_OVFL {
            // SAFETY: an SO_RXQ_OVFL message carries one u32 (possibly
            // unaligned) right after its header, inside `control`.
            drops = Some(unsafe { core::ptr::read_unaligned(libc::CMSG_DATA(cmsg).cast::<u32>()) });
        }
        // SAFETY: as for CMSG_FIRSTHDR.
        cmsg = unsafe { libc::CMSG_NXTHDR(&msg, cmsg) };
    }
    let ip = Ipv4Addr::from(u32::from_be(addr.sin_addr.s_addr));
    let src = SocketAddr::V4(SocketAddrV4::new(ip, u16::from_be(addr.sin_port)));
    // Fits: n >= 0 checked above.
    Ok((n as usize, src, drops))
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
    /// frames and malformed datagrams are counted and skipped; so are the
    /// kernel's drops (`SO_RXQ_OVFL`). Every classic frame is returned:
    /// standard or extended, data, remote or error.
    fn recv(&mut self, timeout: Duration) -> Result<Option<Frame>, TransportError> {
        let deadline = deadline_after(timeout);
        // One byte more than a frame, so oversized datagrams show as such.
        let mut buf = [0u8; WIRE_SIZE + 1];
        loop {
            match self.recv_datagram(&mut buf) {
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
