//! The live feed: every row of the log, as the log writer thread formats it,
//! sent to local subscribers (the experimenter's live view, the
//! participant's display) as UDP datagrams on loopback.
//!
//! Why this shape (`docs/live.md`): the feed is fed by the writer thread, so
//! the 1 kHz tick does nothing more than push its record into the log ring;
//! UDP on loopback needs no connection, and a subscriber that is slow, stalls
//! or has not started yet costs the sender one non-blocking `sendto(2)` per
//! datagram: the kernel drops what the subscriber's receive buffer cannot
//! hold, nothing is queued on the sender's side. Rows are batched (every row
//! of one writer pass in one datagram, up to [`MAX_ROWS`]) so a subscriber
//! wakes ~100 times a second, not 1000.
//!
//! Wire format, version [`WIRE_VERSION`]: a 32-byte header, little-endian,
//!
//! | offset | type | field |
//! |---|---|---|
//! | 0 | 4 bytes | magic `SAFD` |
//! | 4 | u16 | wire version ([`WIRE_VERSION`]) |
//! | 6 | u16 | the log schema's format version (`sensaug_log::FORMAT_VERSION`) |
//! | 8 | u16 | bytes of one row (`size_of::<PackedRow>()`) |
//! | 10 | u16 | rows in this datagram |
//! | 12 | u16 | flags: bit 0 the run's last datagram |
//! | 14 | u16 | reserved, 0 |
//! | 16 | u64 | sequence number of the datagram in this run, from 0 (a gap: datagrams lost) |
//! | 24 | u64 | the run's start, ns since the Unix epoch (`meta.start_unix_s`): identifies the run |
//!
//! then either `rows` packed rows (`sensaug_log::PackedRow`: the columns in
//! `COLUMNS` order, native-endian, the layout of `sensaug.logs.DTYPE`), or,
//! in the last datagram (flag bit 0, `rows` 0), the run's end status as
//! JSON text (the log's end line: `stop_reason`, `ticks`, ...).

use sensaug_log::{PackedRow, Row};
use std::fmt;
use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4, UdpSocket};
use zerocopy::IntoBytes;

/// The first four bytes of every datagram.
pub const MAGIC: [u8; 4] = *b"SAFD";
/// Version of the wire format (bumped on any change of the header).
pub const WIRE_VERSION: u16 = 1;
/// Bytes of the header.
pub const HEADER_BYTES: usize = 32;
/// Bytes of one row.
pub const ROW_BYTES: usize = std::mem::size_of::<PackedRow>();
/// The most rows in one datagram (~23 kB, well under UDP's 65 507 bytes).
pub const MAX_ROWS: usize = 64;
/// Flag bit: the run's last datagram, carrying its end status.
pub const FLAG_END: u16 = 1;

/// A subscriber address the feed refuses.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum FeedError {
    /// Not an IPv4 loopback address: the feed never leaves the machine.
    NotLoopback(SocketAddr),
    /// Port 0 cannot be sent to.
    PortZero(SocketAddr),
    /// The sending socket could not be opened.
    Socket(String),
}

impl fmt::Display for FeedError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            FeedError::NotLoopback(a) => write!(
                f,
                "--feed {a}: not a loopback address; the feed is sent to 127.0.0.0/8 only (e.g. 127.0.0.1:{})",
                a.port()
            ),
            FeedError::PortZero(a) => {
                write!(f, "--feed {a}: port 0; give the subscriber's port 1..65535")
            }
            FeedError::Socket(e) => write!(f, "--feed: cannot open a UDP socket: {e}"),
        }
    }
}

impl std::error::Error for FeedError {}

/// What the feed did (reported in the log's end line and the statistics).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FeedStats {
    /// Datagrams handed to the kernel (per subscriber).
    pub datagrams_sent: u64,
    /// Datagrams the kernel refused at once (full send buffer, no listener
    /// reported by ICMP): dropped, never retried.
    pub datagrams_dropped: u64,
}

/// The sending side, owned by the log writer thread.
pub struct Feed {
    socket: UdpSocket,
    subscribers: Vec<SocketAddr>,
    start_unix_ns: u64,
    seq: u64,
    rows: usize,
    datagram: Vec<u8>,
    stats: FeedStats,
}

/// Checks one subscriber address: IPv4 loopback, a port.
pub fn check_subscriber(addr: SocketAddr) -> Result<SocketAddr, FeedError> {
    match addr {
        SocketAddr::V4(a) if a.ip().is_loopback() => {
            if a.port() == 0 {
                Err(FeedError::PortZero(addr))
            } else {
                Ok(addr)
            }
        }
        _ => Err(FeedError::NotLoopback(addr)),
    }
}

impl Feed {
    /// A feed to `subscribers` (each checked by [`check_subscriber`]) for the
    /// run that started at `start_unix_s` (s since the epoch); the socket is
    /// bound to an ephemeral loopback port and non-blocking.
    pub fn open(subscribers: &[SocketAddr], start_unix_s: f64) -> Result<Feed, FeedError> {
        let subscribers = subscribers
            .iter()
            .map(|a| check_subscriber(*a))
            .collect::<Result<Vec<_>, _>>()?;
        let socket = UdpSocket::bind(SocketAddrV4::new(Ipv4Addr::LOCALHOST, 0))
            .and_then(|s| s.set_nonblocking(true).map(|()| s))
            .map_err(|e| FeedError::Socket(e.to_string()))?;
        let mut datagram = Vec::with_capacity(HEADER_BYTES + MAX_ROWS * ROW_BYTES);
        datagram.resize(HEADER_BYTES, 0);
        Ok(Feed {
            socket,
            subscribers,
            start_unix_ns: (start_unix_s.max(0.0) * 1e9) as u64,
            seq: 0,
            rows: 0,
            datagram,
            stats: FeedStats::default(),
        })
    }

    /// Appends one row; sends the datagram when it holds [`MAX_ROWS`].
    pub fn push(&mut self, row: &Row) {
        self.datagram.extend_from_slice(row.packed().as_bytes());
        self.rows += 1;
        if self.rows == MAX_ROWS {
            self.flush();
        }
    }

    /// Sends the rows pushed since the last datagram, if any (the writer
    /// calls it after each pass).
    pub fn flush(&mut self) {
        if self.rows > 0 {
            self.send(0);
        }
    }

    /// Sends what is pending, then the run's last datagram with its end
    /// status (JSON text); returns what the feed did.
    pub fn finish(mut self, end: &serde_json::Value) -> FeedStats {
        self.flush();
        self.datagram.extend_from_slice(end.to_string().as_bytes());
        self.send(FLAG_END);
        self.stats
    }

    /// What the feed did so far.
    pub fn stats(&self) -> FeedStats {
        self.stats
    }

    /// Writes the header and sends the datagram to every subscriber.
    fn send(&mut self, flags: u16) {
        let header = header(self.rows as u16, flags, self.seq, self.start_unix_ns);
        self.datagram[..HEADER_BYTES].copy_from_slice(&header);
        for addr in &self.subscribers {
            match self.socket.send_to(&self.datagram, addr) {
                Ok(_) => self.stats.datagrams_sent += 1,
                // Best effort: a full buffer or an ICMP "no listener" drops
                // this datagram; the next one is tried as usual.
                Err(_) => self.stats.datagrams_dropped += 1,
            }
        }
        self.seq += 1;
        self.rows = 0;
        self.datagram.truncate(HEADER_BYTES);
    }
}

/// The 32-byte header of a datagram.
pub fn header(rows: u16, flags: u16, seq: u64, start_unix_ns: u64) -> [u8; HEADER_BYTES] {
    let mut h = [0u8; HEADER_BYTES];
    h[0..4].copy_from_slice(&MAGIC);
    h[4..6].copy_from_slice(&WIRE_VERSION.to_le_bytes());
    h[6..8].copy_from_slice(&(sensaug_log::FORMAT_VERSION as u16).to_le_bytes());
    h[8..10].copy_from_slice(&(ROW_BYTES as u16).to_le_bytes());
    h[10..12].copy_from_slice(&rows.to_le_bytes());
    h[12..14].copy_from_slice(&flags.to_le_bytes());
    h[16..24].copy_from_slice(&seq.to_le_bytes());
    h[24..32].copy_from_slice(&start_unix_ns.to_le_bytes());
    h
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    fn row(tick: i64) -> Row {
        Row {
            tick,
            t: tick as f64 * 1e-3,
            x: 0.25,
            ..Row::UNKNOWN
        }
    }

    #[test]
    fn subscribers_stay_on_loopback() {
        let lan: SocketAddr = "192.168.1.5:9870".parse().unwrap();
        let v6: SocketAddr = "[::1]:9870".parse().unwrap();
        let zero: SocketAddr = "127.0.0.1:0".parse().unwrap();
        assert_eq!(
            Feed::open(&[lan], 0.0).err(),
            Some(FeedError::NotLoopback(lan))
        );
        assert!(Feed::open(&[v6], 0.0).is_err());
        assert_eq!(
            Feed::open(&[zero], 0.0).err(),
            Some(FeedError::PortZero(zero))
        );
        let msg = FeedError::NotLoopback(lan).to_string();
        assert!(
            msg.contains("--feed") && msg.contains("127.0.0.1:9870"),
            "{msg}"
        );
    }

    #[test]
    fn rows_arrive_batched_then_the_end_status() {
        let rx = UdpSocket::bind("127.0.0.1:0").unwrap();
        rx.set_read_timeout(Some(Duration::from_secs(2))).unwrap();
        let mut feed = Feed::open(&[rx.local_addr().unwrap()], 1.5).unwrap();
        for k in 0..(MAX_ROWS as i64 + 3) {
            feed.push(&row(k));
        }
        feed.flush();
        let stats = feed.finish(&serde_json::json!({"stop_reason": "completed"}));
        assert_eq!(stats.datagrams_sent, 3);
        let mut buf = vec![0u8; 65536];
        let mut got = Vec::new();
        for _ in 0..3 {
            let n = rx.recv(&mut buf).unwrap();
            got.push(buf[..n].to_vec());
        }
        let rows = |d: &[u8]| u16::from_le_bytes([d[10], d[11]]);
        let seq = |d: &[u8]| u64::from_le_bytes(d[16..24].try_into().unwrap());
        assert_eq!(&got[0][..4], b"SAFD");
        assert_eq!((rows(&got[0]), rows(&got[1]), rows(&got[2])), (64, 3, 0));
        assert_eq!((seq(&got[0]), seq(&got[1]), seq(&got[2])), (0, 1, 2));
        assert_eq!(got[0].len(), HEADER_BYTES + 64 * ROW_BYTES);
        assert_eq!(
            u64::from_le_bytes(got[0][24..32].try_into().unwrap()),
            1_500_000_000
        );
        // The second datagram's first row is tick 64, packed as the log's row.
        let first = &got[1][HEADER_BYTES..HEADER_BYTES + ROW_BYTES];
        assert_eq!(first, row(64).packed().as_bytes());
        assert_eq!(u16::from_le_bytes([got[2][12], got[2][13]]), FLAG_END);
        let end: serde_json::Value = serde_json::from_slice(&got[2][HEADER_BYTES..]).unwrap();
        assert_eq!(end["stop_reason"], "completed");
    }

    #[test]
    fn no_listener_costs_a_dropped_count_at_most() {
        // A port nobody listens on: sends never block or fail the writer.
        let free = UdpSocket::bind("127.0.0.1:0").unwrap();
        let addr = free.local_addr().unwrap();
        drop(free);
        let mut feed = Feed::open(&[addr], 0.0).unwrap();
        for k in 0..1000 {
            feed.push(&row(k));
            feed.flush();
        }
        let s = feed.stats();
        assert_eq!(s.datagrams_sent + s.datagrams_dropped, 1000);
    }
}
