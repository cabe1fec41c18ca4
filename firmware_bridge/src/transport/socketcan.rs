//! Linux SocketCAN (`AF_CAN`, `CAN_RAW`): real adapters and `vcan`.
//!
//! The kernel's `struct can_frame` is exactly [`Frame::to_wire`]'s 16
//! bytes, so frames are read and written as they are. What only a kernel
//! bus gives, and how this transport uses it:
//!
//! - **Receive filters** (`CAN_RAW_FILTER`, [`Transport::accept_only`]): the
//!   kernel drops every data frame whose id is not on the list before it
//!   reaches the socket, so a controller is not woken by other nodes'
//!   traffic.
//! - **Error frames** (`CAN_RAW_ERR_FILTER`, all classes): received and
//!   counted in [`BusStats::error_frames`], never returned as data.
//! - **Kernel receive timestamps** (`SO_TIMESTAMPNS`): every `recv` reads
//!   the frame and its arrival time in one `recvmsg(2)`;
//!   [`SocketCan::last_rx_time`] is when the kernel queued the last
//!   returned frame, not when the caller got to it.
//! - **A full transmit queue** (`ENOBUFS` from the qdisc, `EAGAIN` from a
//!   full socket send buffer): the socket is non-blocking, so `send` returns
//!   at once with [`TransportError::Io`] and counts it in
//!   [`BusStats::tx_queue_full`]; the control loop never stalls on the bus.
//!
//! By default the kernel does not hand a socket its own frames
//! (`CAN_RAW_RECV_OWN_MSGS` off), matching the UDP bus.
//!
//! Why `libc` and not the `socketcan` crate: the receive path has to be
//! allocation-free and read frame and timestamp in one call into stack
//! buffers; that is one `recvmsg` here, while the crate's timestamp API is
//! recent (3.6) and brings `nix` and several more dependencies for the four
//! socket options this file sets. Every `unsafe` block states its contract.

use std::ffi::CString;
use std::io;
use std::os::fd::AsRawFd;
use std::time::{Duration, SystemTime};

use socket2::{Domain, Protocol, Socket, Type};

use super::{deadline_after, wait_readable, BusStats, Transport, TransportError};
use crate::frame::{Frame, MAX_STANDARD_ID, WIRE_SIZE};

/// `CAN_RAW_FILTER_MAX`: the kernel refuses longer filter lists.
pub const MAX_FILTERS: usize = 512;

/// Room for one `SCM_TIMESTAMPNS` control message (a `cmsghdr` and a
/// `timespec`: 16 + 16 bytes on 64-bit Linux) with margin; `u64` elements
/// give the alignment `cmsghdr` needs.
const CMSG_WORDS: usize = 8;

/// A raw CAN socket bound to one interface (`socketcan:<ifname>`).
#[derive(Debug)]
pub struct SocketCan {
    sock: Socket,
    ifname: String,
    stats: BusStats,
    last_rx: Option<SystemTime>,
}

impl SocketCan {
    /// Bind a non-blocking `CAN_RAW` socket to interface `ifname` (e.g.
    /// `can0`, `vcan0`), with error frames and kernel receive timestamps on
    /// and no receive filter (every data frame). Set-up only.
    pub fn open(ifname: &str) -> Result<Self, TransportError> {
        let url = || format!("socketcan:{ifname}");
        let open_err = |step: &'static str| {
            move |source: io::Error| TransportError::Open {
                url: url(),
                step,
                source,
            }
        };
        let c_name = CString::new(ifname).map_err(|_| TransportError::BadUrl {
            url: url(),
            reason: "interface name has a NUL byte".into(),
        })?;
        // SAFETY: `c_name` is a valid NUL-terminated string that outlives
        // the call; if_nametoindex only reads it.
        let ifindex = unsafe { libc::if_nametoindex(c_name.as_ptr()) };
        if ifindex == 0 {
            return Err(TransportError::NoSuchInterface {
                url: url(),
                ifname: ifname.to_owned(),
            });
        }
        let ifindex = libc::c_int::try_from(ifindex)
            .map_err(|_| open_err("if_nametoindex")(io::Error::from(io::ErrorKind::InvalidData)))?;

        let sock = Socket::new(
            Domain::from(libc::AF_CAN),
            Type::RAW,
            Some(Protocol::from(libc::CAN_RAW)),
        )
        .map_err(open_err("socket(AF_CAN, SOCK_RAW, CAN_RAW)"))?;

        // Error frames of every class (bus-off, controller, protocol, ...).
        let err_mask: libc::can_err_mask_t = libc::CAN_ERR_MASK;
        set_option(
            &sock,
            libc::SOL_CAN_RAW,
            libc::CAN_RAW_ERR_FILTER,
            &err_mask,
        )
        .map_err(open_err("setsockopt(CAN_RAW_ERR_FILTER)"))?;
        let on: libc::c_int = 1;
        set_option(&sock, libc::SOL_SOCKET, libc::SO_TIMESTAMPNS, &on)
            .map_err(open_err("setsockopt(SO_TIMESTAMPNS)"))?;

        // SAFETY: sockaddr_can is plain old data; all-zero is a valid value.
        let mut addr: libc::sockaddr_can = unsafe { std::mem::zeroed() };
        addr.can_family = libc::AF_CAN as libc::sa_family_t;
        addr.can_ifindex = ifindex;
        // SAFETY: the fd is an open socket owned by `sock`; `addr` is a
        // valid sockaddr_can and the length passed is its size.
        let rc = unsafe {
            libc::bind(
                sock.as_raw_fd(),
                (&raw const addr).cast::<libc::sockaddr>(),
                std::mem::size_of::<libc::sockaddr_can>() as libc::socklen_t,
            )
        };
        if rc != 0 {
            return Err(open_err("bind")(io::Error::last_os_error()));
        }
        sock.set_nonblocking(true).map_err(open_err("O_NONBLOCK"))?;
        Ok(Self {
            sock,
            ifname: ifname.to_owned(),
            stats: BusStats::default(),
            last_rx: None,
        })
    }

    /// The interface name.
    pub fn ifname(&self) -> &str {
        &self.ifname
    }

    /// When the kernel received the frame the last successful `recv`
    /// returned (`SO_TIMESTAMPNS`, `CLOCK_REALTIME`); `None` before the
    /// first frame or if the kernel sent no timestamp.
    pub fn last_rx_time(&self) -> Option<SystemTime> {
        self.last_rx
    }

    /// Set the kernel receive filter to exactly these 11-bit ids
    /// (`CAN_RAW_FILTER`, each matched on id, EFF and RTR bits). An empty
    /// list lets no data frame through (error frames still come). Set-up
    /// only: allocates the filter array.
    pub fn set_filter(&mut self, ids: &[u32]) -> Result<(), TransportError> {
        let url = || format!("socketcan:{}", self.ifname);
        if ids.len() > MAX_FILTERS {
            return Err(TransportError::BadFilter {
                url: url(),
                reason: format!("{} ids, the kernel takes at most {MAX_FILTERS}", ids.len()),
            });
        }
        if let Some(bad) = ids.iter().find(|&&id| id > MAX_STANDARD_ID) {
            return Err(TransportError::BadFilter {
                url: url(),
                reason: format!("id {bad:#x} is not an 11-bit id (0..=0x7FF)"),
            });
        }
        let filters: Vec<libc::can_filter> = ids
            .iter()
            .map(|&id| libc::can_filter {
                can_id: id,
                can_mask: libc::CAN_SFF_MASK | libc::CAN_EFF_FLAG | libc::CAN_RTR_FLAG,
            })
            .collect();
        let len = std::mem::size_of_val(filters.as_slice()) as libc::socklen_t;
        // SAFETY: the fd is an open CAN_RAW socket; `filters` is a live
        // array of `len` bytes of can_filter, which the kernel copies.
        // A null pointer with length 0 (an empty list) is accepted.
        let rc = unsafe {
            libc::setsockopt(
                self.sock.as_raw_fd(),
                libc::SOL_CAN_RAW,
                libc::CAN_RAW_FILTER,
                filters.as_ptr().cast::<libc::c_void>(),
                len,
            )
        };
        if rc != 0 {
            return Err(TransportError::Open {
                url: url(),
                step: "setsockopt(CAN_RAW_FILTER)",
                source: io::Error::last_os_error(),
            });
        }
        Ok(())
    }

    /// One `recvmsg(2)`: the frame's bytes into `buf`, its kernel arrival
    /// time from the `SCM_TIMESTAMPNS` control message. Never blocks (the
    /// socket is non-blocking); no allocation.
    fn recv_one(&self, buf: &mut [u8]) -> io::Result<(usize, Option<SystemTime>)> {
        let mut control = [0u64; CMSG_WORDS];
        let mut iov = libc::iovec {
            iov_base: buf.as_mut_ptr().cast::<libc::c_void>(),
            iov_len: buf.len(),
        };
        // SAFETY: msghdr is plain old data; all-zero is a valid value (no
        // name, no iovecs, no control buffer) before the fields are set.
        let mut msg: libc::msghdr = unsafe { std::mem::zeroed() };
        msg.msg_iov = &raw mut iov;
        msg.msg_iovlen = 1;
        msg.msg_control = control.as_mut_ptr().cast::<libc::c_void>();
        msg.msg_controllen = std::mem::size_of_val(&control) as _;
        // SAFETY: the fd is open; `msg` points to one iovec over `buf` and
        // a control buffer of `msg_controllen` bytes, all live and writable
        // for the duration of the call.
        let n = unsafe { libc::recvmsg(self.sock.as_raw_fd(), &raw mut msg, 0) };
        if n < 0 {
            return Err(io::Error::last_os_error());
        }
        let mut when = None;
        // SAFETY: `msg` was filled by a successful recvmsg; CMSG_FIRSTHDR and
        // CMSG_NXTHDR walk its control buffer within `msg_controllen` and
        // return null at its end.
        let mut cmsg = unsafe { libc::CMSG_FIRSTHDR(&raw const msg) };
        while !cmsg.is_null() {
            // SAFETY: `cmsg` is non-null and points inside `control`.
            let hdr = unsafe { &*cmsg };
            if hdr.cmsg_level == libc::SOL_SOCKET && hdr.cmsg_type == libc::SCM_TIMESTAMPNS {
                // SAFETY: an SCM_TIMESTAMPNS message carries one timespec;
                // CMSG_DATA points at it, possibly unaligned for timespec.
                let ts = unsafe {
                    std::ptr::read_unaligned(libc::CMSG_DATA(cmsg).cast::<libc::timespec>())
                };
                when = timespec_to_system_time(&ts);
            }
            // SAFETY: as for CMSG_FIRSTHDR; `cmsg` is a header of `msg`.
            cmsg = unsafe { libc::CMSG_NXTHDR(&raw const msg, cmsg) };
        }
        Ok((n as usize, when))
    }
}

/// `setsockopt(2)` with a plain value.
fn set_option<T: Copy>(
    sock: &Socket,
    level: libc::c_int,
    name: libc::c_int,
    value: &T,
) -> io::Result<()> {
    // SAFETY: the fd is open; `value` points to a live `T` of the size
    // passed, which the kernel only reads. Callers pass the C type the
    // option expects (c_int or can_err_mask_t).
    let rc = unsafe {
        libc::setsockopt(
            sock.as_raw_fd(),
            level,
            name,
            (value as *const T).cast::<libc::c_void>(),
            std::mem::size_of::<T>() as libc::socklen_t,
        )
    };
    if rc == 0 {
        Ok(())
    } else {
        Err(io::Error::last_os_error())
    }
}

/// A `CLOCK_REALTIME` timespec as a `SystemTime` (`None` if out of range).
fn timespec_to_system_time(ts: &libc::timespec) -> Option<SystemTime> {
    let secs = u64::try_from(ts.tv_sec).ok()?;
    let nanos = u32::try_from(ts.tv_nsec)
        .ok()
        .filter(|&n| n < 1_000_000_000)?;
    SystemTime::UNIX_EPOCH.checked_add(Duration::new(secs, nanos))
}

/// `ENOBUFS` (the interface queue is full) or `EAGAIN` (the socket's send
/// buffer is full): the bus cannot take the frame now.
fn is_tx_queue_full(e: &io::Error) -> bool {
    e.raw_os_error() == Some(libc::ENOBUFS) || e.kind() == io::ErrorKind::WouldBlock
}

impl Transport for SocketCan {
    fn last_rx_time(&self) -> Option<SystemTime> {
        self.last_rx
    }

    /// One non-blocking `send` of the 16-byte `can_frame`. A full transmit
    /// queue (`ENOBUFS`/`EAGAIN`) is counted in `tx_queue_full` and returned
    /// as [`TransportError::Io`] at once: the frame is dropped, the caller
    /// is not held up.
    fn send(&mut self, frame: &Frame) -> Result<(), TransportError> {
        frame.validate().map_err(TransportError::InvalidFrame)?;
        let wire = frame.to_wire();
        let n = match self.sock.send(&wire) {
            Ok(n) => n,
            Err(source) => {
                if is_tx_queue_full(&source) {
                    self.stats.tx_queue_full += 1;
                }
                return Err(TransportError::Io { op: "send", source });
            }
        };
        self.stats.count_sent(n, "short CAN frame write")
    }

    /// Read frames until a valid classic data frame turns up, sleeping in
    /// `ppoll` while the socket is empty, at most `timeout`. Error frames
    /// are counted in `error_frames`; RTR, extended and CAN FD frames in
    /// `malformed_dropped`; both skipped.
    fn recv(&mut self, timeout: Duration) -> Result<Option<Frame>, TransportError> {
        let deadline = deadline_after(timeout);
        // A CAN FD frame (72 bytes) would show up as the wrong size.
        let mut buf = [0u8; 72];
        loop {
            match self.recv_one(&mut buf) {
                Ok((n, when)) => {
                    let bytes = &buf[..n];
                    if is_error_frame(bytes) {
                        self.stats.error_frames += 1;
                        continue;
                    }
                    match Frame::from_wire(bytes) {
                        Ok(frame) => {
                            self.stats.received += 1;
                            self.last_rx = when;
                            return Ok(Some(frame));
                        }
                        Err(_) => self.stats.malformed_dropped += 1,
                    }
                }
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => {
                    if !wait_readable(self.sock.as_raw_fd(), deadline)? {
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

    /// `CAN_RAW_FILTER` with these ids: see [`SocketCan::set_filter`].
    fn accept_only(&mut self, ids: &[u32]) -> Result<(), TransportError> {
        self.set_filter(ids)
    }
}

/// A classic `can_frame` whose id carries `CAN_ERR_FLAG`.
fn is_error_frame(bytes: &[u8]) -> bool {
    match bytes.first_chunk::<4>() {
        Some(id) if bytes.len() == WIRE_SIZE => u32::from_le_bytes(*id) & libc::CAN_ERR_FLAG != 0,
        _ => false,
    }
}

#[cfg(test)]
mod tests {
    //! Host tests need no CAN interface; the tests that do are `#[ignore]`d
    //! here and run inside a VM with `vcan0` up (`scripts/test-socketcan.sh`):
    //! `cargo test -p sensaug-bridge --release -- --ignored vcan`.
    use super::*;

    #[test]
    fn error_flag_is_recognised_only_on_a_whole_frame() {
        let mut wire = [0u8; WIRE_SIZE];
        wire[..4].copy_from_slice(&(libc::CAN_ERR_FLAG | 0x4).to_le_bytes());
        assert!(is_error_frame(&wire));
        assert!(!is_error_frame(&wire[..8]));
        wire[..4].copy_from_slice(&0x281u32.to_le_bytes());
        assert!(!is_error_frame(&wire));
    }

    #[test]
    fn timespec_conversion() {
        let ts = libc::timespec {
            tv_sec: 1,
            tv_nsec: 5,
        };
        assert_eq!(
            timespec_to_system_time(&ts),
            Some(SystemTime::UNIX_EPOCH + Duration::new(1, 5))
        );
        let bad = libc::timespec {
            tv_sec: -1,
            tv_nsec: 0,
        };
        assert_eq!(timespec_to_system_time(&bad), None);
        let bad = libc::timespec {
            tv_sec: 0,
            tv_nsec: 1_000_000_000,
        };
        assert_eq!(timespec_to_system_time(&bad), None);
    }

    #[test]
    fn queue_full_errors() {
        assert!(is_tx_queue_full(&io::Error::from_raw_os_error(
            libc::ENOBUFS
        )));
        assert!(is_tx_queue_full(&io::Error::from_raw_os_error(
            libc::EAGAIN
        )));
        assert!(!is_tx_queue_full(&io::Error::from_raw_os_error(
            libc::ENETDOWN
        )));
    }

    // ---- on a real kernel CAN bus (ignored on the host; run in the VM) ----

    use std::time::Instant;

    /// The vcan interface the VM brings up (`SENSAUG_VCAN`, default vcan0).
    fn vcan() -> String {
        std::env::var("SENSAUG_VCAN").unwrap_or_else(|_| "vcan0".into())
    }

    fn frame(id: u32, byte: u8) -> Frame {
        Frame::new(id, &[byte; 8]).unwrap()
    }

    const WAIT: Duration = Duration::from_secs(2);
    const SHORT: Duration = Duration::from_millis(50);

    #[test]
    #[ignore = "needs a vcan interface (scripts/test-socketcan.sh)"]
    fn vcan_carries_frames_with_kernel_timestamps() {
        let mut a = SocketCan::open(&vcan()).unwrap();
        let mut b = SocketCan::open(&vcan()).unwrap();
        let before = SystemTime::now();
        a.send(&frame(0x281, 7)).unwrap();
        let after = SystemTime::now();
        // Let the frame sit in b's socket: the kernel time must be the
        // arrival, not the moment b reads it.
        std::thread::sleep(Duration::from_millis(200));
        let got = b.recv(WAIT).unwrap();
        assert_eq!(got, Some(frame(0x281, 7)));
        let t = b.last_rx_time().expect("SO_TIMESTAMPNS gave no timestamp");
        assert!(
            t >= before && t <= after,
            "{t:?} not in [{before:?}, {after:?}]"
        );
        // A node does not hear its own frames.
        assert_eq!(a.recv(SHORT).unwrap(), None);
        assert_eq!(a.stats().sent, 1);
        assert_eq!(b.stats().received, 1);
    }

    #[test]
    #[ignore = "needs a vcan interface (scripts/test-socketcan.sh)"]
    fn vcan_kernel_filter_passes_only_listed_ids() {
        let mut a = SocketCan::open(&vcan()).unwrap();
        let mut b = SocketCan::open(&vcan()).unwrap();
        b.accept_only(&[0x281, 0x701]).unwrap();
        for (id, byte) in [(0x123, 1), (0x281, 2), (0x282, 3), (0x701, 4), (0x7ff, 5)] {
            a.send(&frame(id, byte)).unwrap();
        }
        assert_eq!(b.recv(WAIT).unwrap(), Some(frame(0x281, 2)));
        assert_eq!(b.recv(WAIT).unwrap(), Some(frame(0x701, 4)));
        assert_eq!(b.recv(SHORT).unwrap(), None);
        // Filtered in the kernel: never seen, so nothing counted as dropped.
        assert_eq!(b.stats().received, 2);
        assert_eq!(b.stats().malformed_dropped, 0);

        let e = b.set_filter(&[0x800]).unwrap_err();
        assert!(matches!(e, TransportError::BadFilter { .. }), "{e:?}");
        assert!(e.to_string().contains("0x800"), "{e}");
        let many = vec![0x100; MAX_FILTERS + 1];
        assert!(matches!(
            b.set_filter(&many),
            Err(TransportError::BadFilter { .. })
        ));
    }

    #[test]
    #[ignore = "needs a vcan interface (scripts/test-socketcan.sh)"]
    fn vcan_error_frames_are_counted_not_returned() {
        let mut b = SocketCan::open(&vcan()).unwrap();
        b.accept_only(&[0x281]).unwrap();
        let raw = SocketCan::open(&vcan()).unwrap();
        // An error frame (CAN_ERR_FLAG | CAN_ERR_CRTL), written raw: `send`
        // refuses it. The kernel delivers it by the error mask, whatever the
        // data filter.
        let mut wire = frame(0x281, 9).to_wire();
        wire[..4].copy_from_slice(&(libc::CAN_ERR_FLAG | 0x4).to_le_bytes());
        assert_eq!(raw.sock.send(&wire).unwrap(), WIRE_SIZE);
        let mut a = raw;
        a.send(&frame(0x281, 1)).unwrap();
        assert_eq!(b.recv(WAIT).unwrap(), Some(frame(0x281, 1)));
        assert_eq!(b.stats().error_frames, 1);
        assert_eq!(b.stats().received, 1);
        assert!(matches!(
            a.send(&Frame {
                id: libc::CAN_ERR_FLAG | 4,
                ..frame(0, 0)
            }),
            Err(TransportError::InvalidFrame(_))
        ));
    }

    /// `SENSAUG_VCAN_SLOW` names a vcan whose root qdisc holds frames (the
    /// script gives it `tbf` at a few kbit/s), so its queue fills.
    #[test]
    #[ignore = "needs a vcan interface with a slow qdisc (scripts/test-socketcan.sh)"]
    fn vcan_full_transmit_queue_is_counted_and_never_blocks() {
        let ifname = std::env::var("SENSAUG_VCAN_SLOW").unwrap_or_else(|_| "vcan1".into());
        let mut a = SocketCan::open(&ifname).unwrap();
        let n = 5000u64;
        let mut slowest = Duration::ZERO;
        let mut refused = 0u64;
        let t0 = Instant::now();
        for i in 0..n {
            let t = Instant::now();
            match a.send(&frame(0x281, i as u8)) {
                Ok(()) => {}
                Err(TransportError::Io { op: "send", source }) if is_tx_queue_full(&source) => {
                    refused += 1
                }
                Err(e) => panic!("send {i}: {e}"),
            }
            slowest = slowest.max(t.elapsed());
        }
        let s = a.stats();
        println!(
            "{n} sends on {ifname} in {:?}: {} sent, {} refused (queue full), slowest send {slowest:?}",
            t0.elapsed(),
            s.sent,
            s.tx_queue_full
        );
        assert!(
            refused > 0,
            "the queue never filled: is the slow qdisc set?"
        );
        assert_eq!(s.tx_queue_full, refused);
        assert_eq!(s.sent + s.tx_queue_full, n);
    }
}
