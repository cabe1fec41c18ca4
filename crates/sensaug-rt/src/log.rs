//! Logging off the real-time thread: the loop pushes fixed-size records into
//! a lock-free single-producer/single-consumer ring (`rtrb`); a writer thread
//! drains it into a `.npy` structured array that numpy and pandas read
//! without custom code (`np.load(path)`).
//!
//! A full ring is a value (`push` returns the record back): the loop counts
//! it and goes on; it never blocks or grows. The ring is sized for many
//! seconds of records, so a healthy writer never lets it fill.

use rtrb::{Consumer, Producer, RingBuffer};
use sensaug_core::controller::RobotTick;
use std::fs::File;
use std::io::{self, BufWriter, Seek, SeekFrom, Write};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

/// Column names of a [`LogRecord`], in order; every column is `<f8`.
pub const COLUMNS: [&str; 24] = [
    "tick",
    "t",
    "phase",
    "x",
    "xdot",
    "tau",
    "tau_h",
    "u",
    "u_h",
    "torque_nm",
    "e_meas",
    "Lhx_hat",
    "Lhv_hat",
    "Lhh_hat",
    "tau_h_hat",
    "e_hat_own",
    "e_hat_fused",
    "partner_var",
    "wake_latency_us",
    "compute_us",
    "feedback_age_ticks",
    "drive_state",
    "guard",
    "ramp",
];

/// One tick of the real-time loop; written as the `f64` row
/// [`LogRecord::to_row`] (the tick counter is exact up to 2^53).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LogRecord {
    /// Tick number.
    pub tick: u64,
    /// Time of the tick (s).
    pub t: f64,
    /// Measured position (controller units).
    pub x: f64,
    /// Measured velocity (controller units).
    pub v: f64,
    /// Robot target (NaN while ramping down).
    pub tau: f64,
    /// Partner target (NaN while ramping down).
    pub tau_h: f64,
    /// Virtual human torque (model units; NaN while ramping down).
    pub u_h: f64,
    /// Torque sent to the drive (N m).
    pub torque_nm: f64,
    /// The controller's log line (its `u` is NaN while ramping down).
    pub robot: RobotTick,
    /// Wake-up latency after the deadline (us).
    pub wake_latency_us: f64,
    /// Wake-up to command sent (us).
    pub compute_us: f64,
    /// Ticks since the last feedback.
    pub feedback_age_ticks: u64,
    /// Drive state (raw).
    pub drive_state: u8,
    /// What the torque guard did (`agent::Guard` as a number).
    pub guard: f64,
    /// Ramping down after a stop request.
    pub ramp: bool,
}

impl LogRecord {
    /// The record as a row in [`COLUMNS`] order.
    pub fn to_row(&self) -> [f64; COLUMNS.len()] {
        let r = &self.robot;
        [
            self.tick as f64,
            self.t,
            r.phase,
            self.x,
            self.v,
            self.tau,
            self.tau_h,
            r.u,
            self.u_h,
            self.torque_nm,
            r.e_meas,
            r.gains[0],
            r.gains[1],
            r.gains[2],
            r.tau_h_hat,
            r.e_hat_own,
            r.e_hat_fused,
            r.partner_var,
            self.wake_latency_us,
            self.compute_us,
            self.feedback_age_ticks as f64,
            f64::from(self.drive_state),
            self.guard,
            if self.ramp { 1.0 } else { 0.0 },
        ]
    }
}

/// The real-time side of the log: a ring producer plus an overflow counter.
pub struct LogSink {
    producer: Producer<LogRecord>,
    overflows: u64,
}

impl LogSink {
    /// Per tick: queue a record; a full ring counts an overflow and drops it.
    pub fn push(&mut self, r: LogRecord) {
        if self.producer.push(r).is_err() {
            self.overflows += 1;
        }
    }

    /// Records dropped because the ring was full.
    pub fn overflows(&self) -> u64 {
        self.overflows
    }
}

/// The writer thread and its stop flag.
pub struct LogWriter {
    done: Arc<AtomicBool>,
    handle: JoinHandle<io::Result<u64>>,
}

impl LogWriter {
    /// Signals the end of the trial and waits for every queued record to be
    /// written; returns the number of records in the file.
    pub fn finish(self) -> io::Result<u64> {
        self.done.store(true, Ordering::Release);
        self.handle
            .join()
            .map_err(|_| io::Error::other("log writer thread panicked"))?
    }
}

/// Set-up: creates the file, the ring of `capacity` records and the writer
/// thread.
pub fn start(path: &Path, capacity: usize) -> io::Result<(LogSink, LogWriter)> {
    if let Some(dir) = path.parent() {
        if !dir.as_os_str().is_empty() {
            std::fs::create_dir_all(dir)?;
        }
    }
    let file = File::create(path)?;
    let (producer, consumer) = RingBuffer::new(capacity);
    let done = Arc::new(AtomicBool::new(false));
    let flag = Arc::clone(&done);
    let handle = std::thread::Builder::new()
        .name("sensaug-log".into())
        .spawn(move || write_all(file, consumer, &flag))?;
    Ok((
        LogSink {
            producer,
            overflows: 0,
        },
        LogWriter { done, handle },
    ))
}

/// Digits reserved for the row count in the header, so the real count can be
/// written in place at the end without moving the data.
const COUNT_WIDTH: usize = 20;

/// The `.npy` v1.0 header for `rows` records, padded to a multiple of 64.
pub fn npy_header(rows: u64) -> Vec<u8> {
    let descr: Vec<String> = COLUMNS.iter().map(|c| format!("('{c}', '<f8')")).collect();
    let dict = format!(
        "{{'descr': [{}], 'fortran_order': False, 'shape': ({:>width$},), }}",
        descr.join(", "),
        rows,
        width = COUNT_WIDTH
    );
    let unpadded = 10 + dict.len() + 1;
    let total = unpadded.div_ceil(64) * 64;
    let mut h = Vec::with_capacity(total);
    h.extend_from_slice(b"\x93NUMPY\x01\x00");
    h.extend_from_slice(&((total - 10) as u16).to_le_bytes());
    h.extend_from_slice(dict.as_bytes());
    h.resize(total - 1, b' ');
    h.push(b'\n');
    h
}

fn write_all(file: File, mut consumer: Consumer<LogRecord>, done: &AtomicBool) -> io::Result<u64> {
    let mut out = BufWriter::with_capacity(1 << 20, file);
    out.write_all(&npy_header(0))?;
    let mut rows = 0u64;
    loop {
        // Read the flag before draining: whatever was pushed before it was
        // set is in the ring now and gets written by this pass.
        let finished = done.load(Ordering::Acquire);
        while let Ok(r) = consumer.pop() {
            for v in r.to_row() {
                out.write_all(&v.to_le_bytes())?;
            }
            rows += 1;
        }
        if finished {
            break;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    out.flush()?;
    let mut file = out.into_inner().map_err(|e| e.into_error())?;
    file.seek(SeekFrom::Start(0))?;
    file.write_all(&npy_header(rows))?;
    file.sync_all()?;
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::{npy_header, COLUMNS};

    #[test]
    fn header_is_padded_and_keeps_its_length() {
        let a = npy_header(0);
        let b = npy_header(123_456_789);
        assert_eq!(a.len() % 64, 0);
        assert_eq!(a.len(), b.len(), "the count is rewritten in place");
        assert_eq!(&a[..6], b"\x93NUMPY");
        assert_eq!(*a.last().unwrap(), b'\n');
        let text = String::from_utf8_lossy(&b[10..]);
        assert!(text.contains("123456789,)"));
        assert_eq!(text.matches("'<f8'").count(), COLUMNS.len());
    }
}
