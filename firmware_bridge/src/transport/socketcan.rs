//! Linux SocketCAN (`AF_CAN`, `CAN_RAW`) for real adapters: thin.
//!
//! The kernel's `struct can_frame` is exactly [`Frame::to_wire`]'s 16
//! bytes, so frames are read and written as they are. The socket is
//! non-blocking: a full transmit queue is an error (`ENOBUFS`), never a
//! stall of the control loop. By default the kernel does not hand a socket
//! its own frames (`CAN_RAW_RECV_OWN_MSGS` off), matching the UDP bus.

use std::ffi::CString;
use std::io::{self, Read};
use std::os::fd::AsRawFd;
use std::time::Duration;

use socket2::{Domain, Protocol, Socket, Type};

use super::{deadline_after, wait_readable, BusStats, Transport, TransportError};
use crate::frame::{Frame, WIRE_SIZE};

/// A raw CAN socket bound to one interface (`socketcan:<ifname>`).
#[derive(Debug)]
pub struct SocketCan {
    sock: Socket,
    ifname: String,
    stats: BusStats,
}

impl SocketCan {
    /// Bind a `CAN_RAW` socket to interface `ifname` (e.g. `can0`). Set-up
    /// only.
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
        })
    }

    /// The interface name.
    pub fn ifname(&self) -> &str {
        &self.ifname
    }
}

impl Transport for SocketCan {
    /// One `write` of the 16-byte `can_frame`; `ENOBUFS`/`EAGAIN` (transmit
    /// queue full) is returned as [`TransportError::Io`].
    fn send(&mut self, frame: &Frame) -> Result<(), TransportError> {
        frame.validate().map_err(TransportError::InvalidFrame)?;
        let wire = frame.to_wire();
        let n = self
            .sock
            .send(&wire)
            .map_err(|source| TransportError::Io { op: "send", source })?;
        if n != WIRE_SIZE {
            return Err(TransportError::Io {
                op: "send",
                source: io::Error::new(io::ErrorKind::WriteZero, "short CAN frame write"),
            });
        }
        self.stats.sent += 1;
        Ok(())
    }

    /// Read frames until a valid classic data frame turns up (RTR, error
    /// and extended frames are counted as malformed and skipped), sleeping
    /// in `ppoll` while the socket is empty, at most `timeout`.
    fn recv(&mut self, timeout: Duration) -> Result<Option<Frame>, TransportError> {
        let deadline = deadline_after(timeout);
        // A CAN FD frame (72 bytes) would show up as the wrong size.
        let mut buf = [0u8; 72];
        loop {
            match (&self.sock).read(&mut buf) {
                Ok(n) => match Frame::from_wire(&buf[..n]) {
                    Ok(frame) => {
                        self.stats.received += 1;
                        return Ok(Some(frame));
                    }
                    Err(_) => self.stats.malformed_dropped += 1,
                },
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
}
