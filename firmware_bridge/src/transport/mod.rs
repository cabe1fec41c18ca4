//! Moving [`Frame`]s: over SocketCAN (real adapters) or over a loopback-only
//! UDP "virtual CAN bus" (simulation and tests).
//!
//! Pick one with a URL: [`open`]`("udp:47000")` or
//! [`open`]`("socketcan:can0")`. Opening allocates; `send` and `recv` do
//! not, and never busy-spin: `recv` sleeps in `ppoll(2)` until a frame
//! arrives or the timeout ends.
//!
//! The transports themselves (and [`open`]) are the crate's default feature
//! `transports`; without it this module is the [`Transport`] trait, its
//! errors and [`BusUrl`] parsing only (what `sensaug-config` needs, so the
//! Python extension links no socket code).

use std::fmt;
use std::io;
#[cfg(feature = "transports")]
use std::os::fd::RawFd;
use std::time::Duration;
#[cfg(feature = "transports")]
use std::time::Instant;

#[cfg(feature = "transports")]
use crate::frame::WIRE_SIZE;
use crate::frame::{Frame, WireError};

#[cfg(all(feature = "transports", target_os = "linux"))]
mod socketcan;
#[cfg(feature = "transports")]
mod udp;

#[cfg(all(feature = "transports", target_os = "linux"))]
pub use socketcan::SocketCan;
#[cfg(feature = "transports")]
pub use udp::{UdpBus, UDP_BUS_ADDR};

/// A CAN bus seen from one node: send frames, receive the other nodes'.
///
/// A node never receives its own frames (SocketCAN's default, and the UDP
/// bus filters them). Neither method allocates.
pub trait Transport {
    /// Put one frame on the bus. Invalid frames (see [`Frame::validate`])
    /// are refused with [`TransportError::InvalidFrame`]; the call does not
    /// wait for a receiver.
    fn send(&mut self, frame: &Frame) -> Result<(), TransportError>;

    /// The next frame from another node, waiting at most `timeout`
    /// (`Duration::ZERO` only looks). `Ok(None)`: nothing arrived in time.
    /// Malformed input is dropped and counted in [`Transport::stats`], not
    /// returned as an error.
    fn recv(&mut self, timeout: Duration) -> Result<Option<Frame>, TransportError>;

    /// The next frame from another node that has already arrived, without
    /// waiting; `Ok(None)` once none is left. Calling it until `None` drains
    /// the bus (the control loop's sense step). The default is
    /// `recv(Duration::ZERO)`, whose last call finds the queue empty; the
    /// UDP bus spares that call: a `recvmmsg` that returns fewer datagrams
    /// than asked for has emptied the socket, so the drain ends there (one
    /// system call per tick).
    fn recv_ready(&mut self) -> Result<Option<Frame>, TransportError> {
        self.recv(Duration::ZERO)
    }

    /// Counters since opening.
    fn stats(&self) -> BusStats;

    /// Ask the transport to deliver only data frames with these ids. Set-up
    /// only. SocketCAN installs them as the kernel filter (`CAN_RAW_FILTER`),
    /// so other ids never wake the receiver; the UDP bus has no kernel
    /// filter and keeps delivering every frame (the default: `Ok(())`).
    fn accept_only(&mut self, ids: &[u32]) -> Result<(), TransportError> {
        let _ = ids;
        Ok(())
    }

    /// When the kernel received the frame the last `recv`/`recv_ready`
    /// returned (`CLOCK_REALTIME`), where the transport knows it
    /// (SocketCAN's `SO_TIMESTAMPNS`); `None` otherwise (the default, the
    /// UDP bus).
    fn last_rx_time(&self) -> Option<std::time::SystemTime> {
        None
    }
}

/// What a transport has seen since it was opened.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BusStats {
    /// Frames sent.
    pub sent: u64,
    /// Frames received and returned by `recv`.
    pub received: u64,
    /// Own frames received back and dropped (UDP bus only).
    pub own_dropped: u64,
    /// Datagrams or frames that were not a valid classic CAN frame (wrong
    /// size, len > 8, an id too wide for its format), dropped.
    pub malformed_dropped: u64,
    /// Frames the kernel dropped because this node's receive buffer was
    /// full (`SO_RXQ_OVFL`; learnt with the next frame received). Any
    /// non-zero value means frames were lost before `recv` saw them.
    pub kernel_dropped: u64,
    /// Error frames the kernel reported (SocketCAN only), counted and
    /// dropped.
    pub error_frames: u64,
    /// Sends refused because the transmit queue was full (SocketCAN
    /// `ENOBUFS`/`EAGAIN`); the frame was dropped without waiting.
    pub tx_queue_full: u64,
}

/// Why a transport could not be opened, or could not send or receive.
#[derive(Debug)]
pub enum TransportError {
    /// The URL is not `udp:<port>` or `socketcan:<ifname>`.
    BadUrl {
        /// The URL given.
        url: String,
        /// What is wrong with it.
        reason: String,
    },
    /// `socketcan:<ifname>` names no network interface.
    NoSuchInterface {
        /// The URL given.
        url: String,
        /// The interface name.
        ifname: String,
    },
    /// The transport does not exist on this platform.
    Unsupported {
        /// The URL given.
        url: String,
    },
    /// A system call failed while opening.
    Open {
        /// The URL given.
        url: String,
        /// What was being done.
        step: &'static str,
        /// The OS error.
        source: io::Error,
    },
    /// A system call failed while sending or receiving.
    Io {
        /// `"send"`, `"recv"` or `"poll"`.
        op: &'static str,
        /// The OS error.
        source: io::Error,
    },
    /// The frame given to `send` breaks the frame invariants.
    InvalidFrame(WireError),
    /// A receive filter the kernel cannot take (too many ids, an id over
    /// 11 bits).
    BadFilter {
        /// The bus URL.
        url: String,
        /// What is wrong with it.
        reason: String,
    },
}

const URL_HELP: &str = "expected 'udp:<port>' (loopback virtual CAN bus on 127.255.255.255, \
                        port 1-65535, e.g. udp:47000) or 'socketcan:<ifname>' (e.g. socketcan:can0)";

impl fmt::Display for TransportError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::BadUrl { url, reason } => write!(f, "bus URL '{url}': {reason}; {URL_HELP}"),
            Self::NoSuchInterface { url, ifname } => write!(
                f,
                "bus URL '{url}': no network interface '{ifname}'; bring the adapter up with \
                 `ip link set {ifname} up type can bitrate 1000000` (a virtual one: \
                 `ip link add dev {ifname} type vcan && ip link set {ifname} up`), \
                 or use 'udp:<port>' for the loopback bus"
            ),
            Self::Unsupported { url } => write!(
                f,
                "bus URL '{url}': SocketCAN exists only on Linux; use 'udp:<port>' instead"
            ),
            Self::Open { url, step, source } => {
                write!(f, "bus URL '{url}': {step} failed: {source}")?;
                if source.raw_os_error() == Some(libc::EAFNOSUPPORT) {
                    write!(f, " (the kernel has no CAN support: `modprobe can_raw`)")?;
                }
                if source.kind() == io::ErrorKind::AddrInUse {
                    write!(f, " (another program holds the port without SO_REUSEPORT)")?;
                }
                Ok(())
            }
            Self::Io { op, source } => write!(f, "CAN {op} failed: {source}"),
            Self::InvalidFrame(e) => write!(f, "refusing to send an invalid frame: {e}"),
            Self::BadFilter { url, reason } => {
                write!(f, "bus URL '{url}': receive filter refused: {reason}")
            }
        }
    }
}

impl std::error::Error for TransportError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Self::Open { source, .. } | Self::Io { source, .. } => Some(source),
            Self::InvalidFrame(e) => Some(e),
            _ => None,
        }
    }
}

/// A parsed bus URL.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum BusUrl {
    /// `udp:<port>`: the loopback virtual bus on `127.255.255.255:<port>`.
    Udp {
        /// UDP port, 1..=65535.
        port: u16,
    },
    /// `socketcan:<ifname>`: a Linux CAN interface.
    SocketCan {
        /// Interface name, 1..=15 bytes, no `/`, whitespace or NUL.
        ifname: String,
    },
}

impl BusUrl {
    /// Parse `udp:<port>` or `socketcan:<ifname>`.
    pub fn parse(url: &str) -> Result<Self, TransportError> {
        let bad = |reason: String| TransportError::BadUrl {
            url: url.to_owned(),
            reason,
        };
        if let Some(port) = url.strip_prefix("udp:") {
            match port.parse::<u16>() {
                Ok(0) => Err(bad("port 0 is not a bus (pick 1-65535)".into())),
                Ok(port) => Ok(Self::Udp { port }),
                Err(_) => Err(bad(format!("'{port}' is not a port number"))),
            }
        } else if let Some(ifname) = url.strip_prefix("socketcan:") {
            if ifname.is_empty() {
                Err(bad("missing interface name".into()))
            } else if ifname.len() >= 16 {
                Err(bad(format!(
                    "interface name '{ifname}' is longer than 15 bytes"
                )))
            } else if ifname
                .bytes()
                .any(|b| b == b'/' || b == 0 || b.is_ascii_whitespace() || b == b':')
            {
                Err(bad(format!(
                    "interface name '{ifname}' has a '/', ':', space or NUL"
                )))
            } else {
                Ok(Self::SocketCan {
                    ifname: ifname.to_owned(),
                })
            }
        } else {
            Err(bad("unknown scheme".into()))
        }
    }
}

#[cfg(feature = "transports")]
/// Open the bus a URL names: `udp:<port>` or `socketcan:<ifname>`.
///
/// Runs at set-up; allocates. Errors name the URL and the fix.
pub fn open(url: &str) -> Result<Box<dyn Transport + Send>, TransportError> {
    match BusUrl::parse(url)? {
        BusUrl::Udp { port } => Ok(Box::new(UdpBus::open(port)?)),
        #[cfg(target_os = "linux")]
        BusUrl::SocketCan { ifname } => Ok(Box::new(SocketCan::open(&ifname)?)),
        #[cfg(not(target_os = "linux"))]
        BusUrl::SocketCan { .. } => Err(TransportError::Unsupported {
            url: url.to_owned(),
        }),
    }
}

impl BusStats {
    /// A send that wrote `written` bytes of a frame's wire form: counted as
    /// sent when that is the whole frame ([`WIRE_SIZE`]), else the short
    /// write is an error (`what`: what came out short, e.g. "short datagram").
    #[cfg(feature = "transports")]
    fn count_sent(&mut self, written: usize, what: &'static str) -> Result<(), TransportError> {
        if written != WIRE_SIZE {
            return Err(TransportError::Io {
                op: "send",
                source: io::Error::new(io::ErrorKind::WriteZero, what),
            });
        }
        self.sent += 1;
        Ok(())
    }
}

/// `Instant::now() + timeout`, or `None` for "forever" if that overflows.
#[cfg(feature = "transports")]
fn deadline_after(timeout: Duration) -> Option<Instant> {
    Instant::now().checked_add(timeout)
}

/// Sleep until `fd` is readable or `deadline` passes; `Ok(false)` on
/// timeout. `None` waits forever. Interrupted waits are resumed.
#[cfg(feature = "transports")]
fn wait_readable(fd: RawFd, deadline: Option<Instant>) -> Result<bool, TransportError> {
    loop {
        let remaining = match deadline {
            Some(d) => {
                let r = d.saturating_duration_since(Instant::now());
                if r.is_zero() {
                    return Ok(false);
                }
                Some(r)
            }
            None => None,
        };
        let mut pfd = libc::pollfd {
            fd,
            events: libc::POLLIN,
            revents: 0,
        };
        let n = poll_one(&mut pfd, remaining);
        if n < 0 {
            let e = io::Error::last_os_error();
            if e.kind() == io::ErrorKind::Interrupted {
                continue;
            }
            return Err(TransportError::Io {
                op: "poll",
                source: e,
            });
        }
        if n > 0 {
            return Ok(true);
        }
        // n == 0: timed out; the loop re-checks the deadline.
    }
}

/// `ppoll(2)` on one fd with a nanosecond timeout (`None`: forever).
#[cfg(all(feature = "transports", target_os = "linux"))]
fn poll_one(pfd: &mut libc::pollfd, timeout: Option<Duration>) -> libc::c_int {
    let ts = timeout.map(|t| libc::timespec {
        tv_sec: libc::time_t::try_from(t.as_secs()).unwrap_or(libc::time_t::MAX),
        tv_nsec: libc::c_long::from(t.subsec_nanos() as i32),
    });
    let ts_ptr = ts
        .as_ref()
        .map_or(core::ptr::null(), |t| t as *const libc::timespec);
    // SAFETY: `pfd` points to one valid pollfd for the duration of the call,
    // `ts_ptr` is null or points to a live timespec, and a null sigmask
    // leaves the signal mask unchanged.
    unsafe { libc::ppoll(pfd, 1, ts_ptr, core::ptr::null()) }
}

/// `poll(2)` on one fd, the timeout rounded up to whole milliseconds.
#[cfg(all(feature = "transports", not(target_os = "linux")))]
fn poll_one(pfd: &mut libc::pollfd, timeout: Option<Duration>) -> libc::c_int {
    let ms = timeout.map_or(-1, |t| {
        libc::c_int::try_from(t.as_nanos().div_ceil(1_000_000)).unwrap_or(libc::c_int::MAX)
    });
    // SAFETY: `pfd` points to one valid pollfd for the duration of the call.
    unsafe { libc::poll(pfd, 1, ms) }
}

#[cfg(all(test, feature = "transports"))]
mod tests {
    use super::*;

    #[test]
    fn parse_urls() {
        assert_eq!(
            BusUrl::parse("udp:47000").unwrap(),
            BusUrl::Udp { port: 47000 }
        );
        assert_eq!(
            BusUrl::parse("socketcan:can0").unwrap(),
            BusUrl::SocketCan {
                ifname: "can0".into()
            }
        );
        for bad in [
            "udp:",
            "udp:0",
            "udp:65536",
            "udp:-1",
            "udp:12x",
            "socketcan:",
            "socketcan:abcdefghijklmnop",
            "socketcan:a/b",
            "socketcan:a b",
            "can0",
            "tcp:1234",
            "",
        ] {
            let e = BusUrl::parse(bad).unwrap_err();
            assert!(
                matches!(e, TransportError::BadUrl { ref url, .. } if url == bad),
                "{bad}: {e:?}"
            );
            let msg = e.to_string();
            assert!(msg.contains(&format!("'{bad}'")), "{msg}");
            assert!(msg.contains("udp:<port>"), "{msg}");
        }
    }

    #[test]
    fn open_rejects_bad_url() {
        let e = open("serial:/dev/ttyUSB0").err().unwrap();
        assert!(matches!(e, TransportError::BadUrl { .. }), "{e:?}");
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn socketcan_missing_interface_names_url_and_fix() {
        let e = open("socketcan:nosuchcan7").err().unwrap();
        match &e {
            TransportError::NoSuchInterface { url, ifname } => {
                assert_eq!(url, "socketcan:nosuchcan7");
                assert_eq!(ifname, "nosuchcan7");
            }
            other => panic!("expected NoSuchInterface, got {other:?}"),
        }
        let msg = e.to_string();
        assert!(msg.contains("socketcan:nosuchcan7"), "{msg}");
        assert!(msg.contains("ip link"), "{msg}");
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn socketcan_on_a_non_can_interface_fails_with_the_url() {
        // `lo` exists everywhere; it is not a CAN interface, and this
        // machine's kernel may lack AF_CAN altogether. Either way: an error
        // that names the URL, not a panic.
        let e = open("socketcan:lo").err().unwrap();
        assert!(matches!(e, TransportError::Open { .. }), "{e:?}");
        assert!(e.to_string().contains("socketcan:lo"), "{e}");
    }

    #[test]
    fn wait_readable_times_out_without_spinning() {
        let sock = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
        use std::os::fd::AsRawFd;
        let t0 = Instant::now();
        let ready = wait_readable(sock.as_raw_fd(), deadline_after(Duration::from_millis(20)));
        assert!(!ready.unwrap());
        let dt = t0.elapsed();
        assert!(dt >= Duration::from_millis(20), "{dt:?}");
        assert!(dt < Duration::from_millis(500), "{dt:?}");
    }
}
