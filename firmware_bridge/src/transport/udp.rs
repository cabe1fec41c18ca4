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
//!
//! Receive times: `SO_TIMESTAMPNS` gives each datagram the kernel's arrival
//! time ([`Transport::last_rx_time`], as on SocketCAN), which the CiA 402
//! master's standard mode uses to tell a TPDO that arrived before a SYNC
//! from one after it.

use std::io;
use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4, UdpSocket};
use std::os::fd::{AsRawFd, RawFd};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

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
    /// Datagrams received by the last `recvmmsg` and not yet looked at.
    batch: Batch,
    /// When the kernel received the datagram of the last frame returned
    /// (`SO_TIMESTAMPNS`), as on SocketCAN.
    last_rx: Option<SystemTime>,
}

/// Datagrams taken from the receive socket per `recvmmsg(2)`: a tick's
/// drain (the drive's feedback, this peer's own command coming back, the
/// odd heartbeat) fits in one call.
pub const RECV_BATCH: usize = 16;

/// One datagram's slot: one byte more than a frame, so oversized datagrams
/// show as such.
type Slot = [u8; WIRE_SIZE + 1];

/// The datagrams of one `recvmmsg`, consumed in order by `recv`. Fixed-size,
/// filled in place: receiving allocates nothing.
#[derive(Debug)]
struct Batch {
    data: [Slot; RECV_BATCH],
    len: [usize; RECV_BATCH],
    src: [SocketAddr; RECV_BATCH],
    /// Kernel receive times (`SO_TIMESTAMPNS`, `CLOCK_REALTIME`).
    rx_time: [Option<SystemTime>; RECV_BATCH],
    /// Datagrams in the batch.
    filled: usize,
    /// The next one to look at.
    next: usize,
    /// The `recvmmsg` of a [`Transport::recv_ready`] drain that filled the
    /// batch returned fewer than [`RECV_BATCH`]: the socket was empty then,
    /// so that drain ends when the batch is used up, without another call.
    emptied_socket: bool,
}

impl Batch {
    fn new() -> Self {
        let nowhere = SocketAddr::V4(SocketAddrV4::new(Ipv4Addr::UNSPECIFIED, 0));
        Batch {
            data: [[0; WIRE_SIZE + 1]; RECV_BATCH],
            len: [0; RECV_BATCH],
            src: [nowhere; RECV_BATCH],
            rx_time: [None; RECV_BATCH],
            filled: 0,
            next: 0,
            emptied_socket: false,
        }
    }
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
        set_int_option(rx.as_raw_fd(), libc::SO_TIMESTAMPNS, 1)
            .map_err(open_err("SO_TIMESTAMPNS"))?;
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
        // Connected once here, so a send does no per-call address or route
        // look-up.
        tx.connect(&dest.into())
            .map_err(open_err("connect 127.255.255.255"))?;
        let tx: UdpSocket = tx.into();
        let own = tx.local_addr().map_err(open_err("getsockname (send)"))?;

        Ok(Self {
            rx: rx.into(),
            tx,
            own,
            dest,
            stats: BusStats::default(),
            kernel_drops_seen: 0,
            batch: Batch::new(),
            last_rx: None,
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

    /// Refill the batch with the datagrams waiting on the receive socket
    /// (up to [`RECV_BATCH`], one `recvmmsg` without blocking); folds the
    /// `SO_RXQ_OVFL` counts into the statistics. `Ok(0)`: nothing waiting.
    fn refill(&mut self) -> io::Result<usize> {
        let mut drops = [None; RECV_BATCH];
        let n = recvmmsg_with_drops(self.rx.as_raw_fd(), &mut self.batch, &mut drops)?;
        for d in drops[..n].iter().flatten() {
            let new = d.wrapping_sub(self.kernel_drops_seen);
            self.stats.kernel_dropped += u64::from(new);
            self.kernel_drops_seen = *d;
        }
        Ok(n)
    }

    /// The next valid frame from another peer among the batched datagrams;
    /// own frames and malformed datagrams on the way are counted and
    /// skipped. `None` once the batch is used up.
    fn next_batched(&mut self) -> Option<Frame> {
        let b = &mut self.batch;
        while b.next < b.filled {
            let i = b.next;
            b.next += 1;
            if b.src[i] == self.own {
                self.stats.own_dropped += 1;
                continue;
            }
            match Frame::from_wire(&b.data[i][..b.len[i]]) {
                Ok(frame) => {
                    self.stats.received += 1;
                    self.last_rx = b.rx_time[i];
                    return Some(frame);
                }
                Err(_) => self.stats.malformed_dropped += 1,
            }
        }
        None
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

/// Control-message buffer for one `SO_RXQ_OVFL` (a u32) and one
/// `SCM_TIMESTAMPNS` (a timespec): 24 + 32 bytes, aligned for `cmsghdr`.
#[repr(C, align(8))]
#[derive(Clone, Copy)]
struct CmsgBuf([u8; 64]);

/// `recvmmsg(2)` of up to [`RECV_BATCH`] IPv4 datagrams without blocking,
/// into `batch` (from its start; `filled` set, `next` reset): the count, and
/// each datagram's `SO_RXQ_OVFL` drop count if the kernel attached one.
/// Allocation-free: every buffer is on the stack or in `batch`.
fn recvmmsg_with_drops(
    fd: RawFd,
    batch: &mut Batch,
    drops: &mut [Option<u32>; RECV_BATCH],
) -> io::Result<usize> {
    // SAFETY: sockaddr_in, iovec and mmsghdr are plain C structs for which
    // all-zero bytes are a valid value.
    let mut addr: [libc::sockaddr_in; RECV_BATCH] = unsafe { core::mem::zeroed() };
    // SAFETY: as above.
    let mut iov: [libc::iovec; RECV_BATCH] = unsafe { core::mem::zeroed() };
    let mut control = [CmsgBuf([0; 64]); RECV_BATCH];
    // SAFETY: as above.
    let mut msgs: [libc::mmsghdr; RECV_BATCH] = unsafe { core::mem::zeroed() };
    for i in 0..RECV_BATCH {
        iov[i] = libc::iovec {
            iov_base: batch.data[i].as_mut_ptr().cast(),
            iov_len: batch.data[i].len(),
        };
        let h = &mut msgs[i].msg_hdr;
        h.msg_name = (&mut addr[i] as *mut libc::sockaddr_in).cast();
        h.msg_namelen = core::mem::size_of::<libc::sockaddr_in>() as libc::socklen_t;
        h.msg_iov = &mut iov[i];
        h.msg_iovlen = 1;
        h.msg_control = control[i].0.as_mut_ptr().cast();
        h.msg_controllen = control[i].0.len() as _;
    }
    batch.filled = 0;
    batch.next = 0;
    // SAFETY: every pointer in `msgs` (name, one iovec over a slot of
    // `batch.data`, control) points to live, writable memory of the stated
    // length for the call; `vlen` is the array's length; no timeout.
    let n = unsafe {
        libc::recvmmsg(
            fd,
            msgs.as_mut_ptr(),
            RECV_BATCH as libc::c_uint,
            libc::MSG_DONTWAIT,
            core::ptr::null_mut(),
        )
    };
    if n < 0 {
        return Err(io::Error::last_os_error());
    }
    // Fits: 0 <= n <= RECV_BATCH.
    let n = n as usize;
    for i in 0..n {
        let msg = &msgs[i].msg_hdr;
        drops[i] = None;
        // SAFETY: `msg` was filled by recvmmsg; CMSG_FIRSTHDR/CMSG_NXTHDR
        // stay within `msg_control[..msg_controllen]` and return null at
        // its end.
        let mut cmsg = unsafe { libc::CMSG_FIRSTHDR(msg) };
        batch.rx_time[i] = None;
        while !cmsg.is_null() {
            // SAFETY: `cmsg` is non-null and points into `control[i]`.
            let hdr = unsafe { &*cmsg };
            if hdr.cmsg_level == libc::SOL_SOCKET && hdr.cmsg_type == libc::SO_RXQ_OVFL {
                // SAFETY: an SO_RXQ_OVFL message carries one u32 (possibly
                // unaligned) right after its header, inside `control[i]`.
                drops[i] =
                    Some(unsafe { core::ptr::read_unaligned(libc::CMSG_DATA(cmsg).cast::<u32>()) });
            }
            if hdr.cmsg_level == libc::SOL_SOCKET && hdr.cmsg_type == libc::SCM_TIMESTAMPNS {
                // SAFETY: an SCM_TIMESTAMPNS message carries one timespec
                // right after its header, inside `control[i]`.
                let ts = unsafe {
                    core::ptr::read_unaligned(libc::CMSG_DATA(cmsg).cast::<libc::timespec>())
                };
                batch.rx_time[i] = u64::try_from(ts.tv_sec).ok().map(|secs| {
                    UNIX_EPOCH + Duration::new(secs, u32::try_from(ts.tv_nsec).unwrap_or(0))
                });
            }
            // SAFETY: as for CMSG_FIRSTHDR.
            cmsg = unsafe { libc::CMSG_NXTHDR(msg, cmsg) };
        }
        let ip = Ipv4Addr::from(u32::from_be(addr[i].sin_addr.s_addr));
        batch.src[i] = SocketAddr::V4(SocketAddrV4::new(ip, u16::from_be(addr[i].sin_port)));
        // At most the slot's length: the kernel truncates longer datagrams.
        batch.len[i] = (msgs[i].msg_len as usize).min(batch.data[i].len());
    }
    batch.filled = n;
    Ok(n)
}

impl Transport for UdpBus {
    /// One `send` of the 16-byte wire frame on the connected send socket;
    /// no allocation.
    fn send(&mut self, frame: &Frame) -> Result<(), TransportError> {
        frame.validate().map_err(TransportError::InvalidFrame)?;
        let wire = frame.to_wire();
        let n = self
            .tx
            .send(&wire)
            .map_err(|source| TransportError::Io { op: "send", source })?;
        self.stats.count_sent(n, "short datagram")
    }

    /// Drain the receive socket until another peer's valid frame turns up,
    /// [`RECV_BATCH`] datagrams per system call (`recvmmsg`; the rest wait in
    /// the batch for the next call); sleep in `ppoll` while it is empty,
    /// until `timeout` has passed. Own
    /// frames and malformed datagrams are counted and skipped; so are the
    /// kernel's drops (`SO_RXQ_OVFL`). Every classic frame is returned:
    /// standard or extended, data, remote or error.
    fn recv(&mut self, timeout: Duration) -> Result<Option<Frame>, TransportError> {
        let deadline = deadline_after(timeout);
        // Frames may have arrived since a drain's short batch.
        self.batch.emptied_socket = false;
        loop {
            if let Some(frame) = self.next_batched() {
                return Ok(Some(frame));
            }
            match self.refill() {
                Ok(0) => {}
                Ok(_) => continue,
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => {
                    // A zero timeout only looks: no poll after the look.
                    if timeout.is_zero() || !wait_readable(self.rx.as_raw_fd(), deadline)? {
                        return Ok(None);
                    }
                }
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(source) => return Err(TransportError::Io { op: "recv", source }),
            }
        }
    }

    /// The batched datagrams first; when they are used up, one `recvmmsg`
    /// unless the one that filled them came back short (it emptied the
    /// socket: this drain is over, and the next drain's first call reads
    /// the socket again). A tick's drain is one system call.
    fn recv_ready(&mut self) -> Result<Option<Frame>, TransportError> {
        loop {
            if let Some(frame) = self.next_batched() {
                return Ok(Some(frame));
            }
            if std::mem::take(&mut self.batch.emptied_socket) {
                return Ok(None);
            }
            match self.refill() {
                Ok(n) => self.batch.emptied_socket = n < RECV_BATCH,
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => return Ok(None),
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(source) => return Err(TransportError::Io { op: "recv", source }),
            }
        }
    }

    fn stats(&self) -> BusStats {
        self.stats
    }

    fn last_rx_time(&self) -> Option<SystemTime> {
        self.last_rx
    }
}
