//! Logging off the real-time thread: the loop pushes fixed-size records into
//! a lock-free single-producer/single-consumer ring (`rtrb`); a writer thread
//! drains it, turns each record into a row of the one log schema
//! (`sensaug_log`) and appends it as a CSV line (`docs/logs.md`).
//!
//! A full ring is a value (`push` returns the record back): the loop counts
//! it and goes on; it never blocks or grows. The ring is sized for many
//! seconds of records, so a healthy writer never lets it fill.
//!
//! Crash safety: the writer hands complete lines to the kernel (`write(2)`,
//! no user-space buffer kept across passes) every [`WRITE_PERIOD`], so a
//! SIGKILL loses at most the records of the last pass; the loader ignores a
//! partial last line. A failed write is counted and its message kept; from
//! then on the file stays a valid prefix and later records are counted lost,
//! and the loop sees the failure ([`LogSink::failed`]) and stops under control.
//!
//! Every line carries the log's chained CRC-32 (`sensaug_log::Checksum`): the
//! writer keeps the running value across passes, so the file is verifiable
//! up to any point a crash cuts it.
//!
//! An old log is not replaced by a run that never starts: set-up writes
//! `<log>.partial` (which also proves the path writable before the drive is
//! enabled); the writer renames it to `<log>` when the first record arrives
//! (the loop's tick 0), or at the end of a run without records. A run that
//! never starts removes `<log>.partial` ([`LogWriter::abandon`]). Nothing
//! but a regular file is ever opened or replaced ([`create_partial`],
//! [`replace`]; `docs/safety.md`, "Output paths").

use crate::feed::Feed;
use rtrb::{Consumer, Producer, RingBuffer};
use sensaug_bridge::drive_link::DriveStatus;
use sensaug_config::outputs::{create_partial, partial_path, replace};
use sensaug_core::agent::Guard;
use sensaug_core::controller::RobotTick;
use sensaug_log::{format_row, write_footer, write_header, Checksum, Row, UNKNOWN};
use std::fs::File;
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

/// How often the writer drains the ring and writes what it found.
pub const WRITE_PERIOD: Duration = Duration::from_millis(10);

/// One tick of the real-time loop, as the loop knows it; the writer thread
/// turns it into a [`Row`] ([`LogRecord::to_row`]), off the loop.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LogRecord {
    /// Tick number.
    pub tick: u64,
    /// Time of the tick (s).
    pub t: f64,
    /// Measured position (controller units): the drive's last feedback.
    pub x: f64,
    /// Measured velocity (controller units).
    pub v: f64,
    /// The feedback was new this tick (the controller updated with it).
    pub fresh: bool,
    /// Robot target (NaN during the controlled stop).
    pub tau: f64,
    /// Partner target (NaN during the controlled stop).
    pub tau_h: f64,
    /// Virtual human torque (model units; NaN during the controlled stop).
    pub u_h: f64,
    /// Torque sent to the drive (N m).
    pub torque_nm: f64,
    /// The friction compensation in it (N m; NaN during the controlled stop).
    pub friction_nm: f64,
    /// The controller's log line (its `u` is NaN during the controlled stop).
    pub robot: RobotTick,
    /// Wake-up latency: the tick's start after its deadline (us).
    pub wake_latency_us: f64,
    /// Sleep latency: the deadline sleep's return after its own target,
    /// the deadline less the spin (us).
    pub sleep_latency_us: f64,
    /// Wake-up to command sent (us).
    pub compute_us: f64,
    /// Ticks since the last feedback.
    pub feedback_age_ticks: u64,
    /// The drive's status, whatever its profile.
    pub drive_state: DriveStatus,
    /// What the drive-torque guard did (`None` during the controlled stop).
    pub guard: Option<Guard>,
    /// The controlled stop's ticks (braking after a stop request).
    pub ramp: bool,
}

/// The `guard` column's code of a guard outcome.
fn guard_code(g: Option<Guard>) -> i64 {
    match g {
        Some(Guard::Passed) => 0,
        Some(Guard::Clamped) => 1,
        Some(Guard::NonFinite) => 2,
        None => UNKNOWN,
    }
}

impl LogRecord {
    /// The record as a row of the log schema. On the rig the controller's
    /// measurement is the drive's feedback, so `x_meas = x`.
    pub fn to_row(&self) -> Row {
        Row {
            x: self.x,
            xdot: self.v,
            x_meas: self.x,
            xdot_meas: self.v,
            fresh: self.fresh,
            tau: self.tau,
            tau_h: self.tau_h,
            u_h: self.u_h,
            torque_nm: self.torque_nm,
            friction_nm: self.friction_nm,
            e: self.x - self.tau,
            wake_latency_us: self.wake_latency_us,
            sleep_latency_us: self.sleep_latency_us,
            compute_us: self.compute_us,
            feedback_age_ticks: self.feedback_age_ticks as i64,
            drive_state: i64::from(self.drive_state.code()),
            guard: guard_code(self.guard),
            ramp: self.ramp,
            ..Row::from_robot(self.tick, self.t, &self.robot)
        }
    }
}

/// The real-time side of the log: a ring producer plus an overflow counter.
pub struct LogSink {
    producer: Producer<LogRecord>,
    overflows: u64,
    failed: Arc<AtomicBool>,
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

    /// Per tick: the writer failed (records are being lost).
    pub fn failed(&self) -> bool {
        self.failed.load(Ordering::Relaxed)
    }
}

/// The log's place: `<path>.partial` until [`Place::publish`] renames it.
#[derive(Debug)]
struct Place {
    path: PathBuf,
    published: bool,
}

impl Place {
    /// Renames `<path>.partial` to `path` (once).
    fn publish(&mut self) -> io::Result<()> {
        if !self.published {
            replace(&self.path)?;
            self.published = true;
        }
        Ok(())
    }
}

/// What the writer did.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct WriterStats {
    /// Records whose line reached the file.
    pub records_written: u64,
    /// Failed writes (the first one stops writing).
    pub write_errors: u64,
    /// Records drained from the ring but not written (after a failed write).
    pub records_lost: u64,
    /// The first write error, if any.
    pub error: Option<String>,
}

/// The writer thread and its stop flag.
pub struct LogWriter {
    done: Arc<AtomicBool>,
    handle: JoinHandle<Written>,
}

/// What the writer thread hands back: the file, its counts, its place and
/// the running checksum after the last line written.
struct Written {
    file: File,
    stats: WriterStats,
    place: Place,
    sum: Checksum,
    feed: Option<Feed>,
}

impl LogWriter {
    /// Signals the end of the run, waits for every queued record to be
    /// written, then appends the end-status line (`end` plus the writer's
    /// counts; skipped after a failed write, which may have left a partial
    /// line) and syncs the file; the file is renamed to its path if no
    /// record did it. A live feed gets the end status last (its counts are
    /// in the end line: `feed_datagrams_sent`, `feed_datagrams_dropped`).
    pub fn finish(self, mut end: serde_json::Map<String, serde_json::Value>) -> WriterStats {
        self.done.store(true, Ordering::Release);
        let Written {
            mut file,
            mut stats,
            mut place,
            mut sum,
            feed,
        } = match self.handle.join() {
            Ok(r) => r,
            Err(_) => {
                return WriterStats {
                    write_errors: 1,
                    error: Some("log writer thread panicked".into()),
                    ..WriterStats::default()
                }
            }
        };
        if let Err(e) = place.publish() {
            stats.write_errors += 1;
            stats
                .error
                .get_or_insert(format!("rename to {}: {e}", place.path.display()));
        }
        if let Some(f) = &feed {
            let s = f.stats();
            end.insert("feed_datagrams_sent".into(), s.datagrams_sent.into());
            end.insert("feed_datagrams_dropped".into(), s.datagrams_dropped.into());
        }
        if stats.error.is_none() {
            end.insert("records_written".into(), stats.records_written.into());
            end.insert(
                "end_time_utc".into(),
                sensaug_log::iso8601_utc(sensaug_log::now_unix_s()).into(),
            );
            let mut line = Vec::new();
            // Writing to a Vec cannot fail.
            let _ = write_footer(&mut line, &serde_json::Value::Object(end.clone()), &mut sum);
            if let Err(e) = file.write_all(&line).and_then(|()| file.sync_all()) {
                stats.write_errors += 1;
                stats.error = Some(format!("end-status line: {e}"));
            }
        }
        if let Some(f) = feed {
            f.finish(&serde_json::Value::Object(end));
        }
        stats
    }

    /// The run never started: stops the writer and removes
    /// `<path>.partial`, leaving any older log at the path untouched.
    pub fn abandon(self) {
        self.done.store(true, Ordering::Release);
        if let Ok(Written { place, .. }) = self.handle.join() {
            if !place.published {
                let _ = std::fs::remove_file(partial_path(&place.path));
            }
        }
    }
}

/// Set-up: creates `<path>.partial` with the metadata and header lines
/// (`sensaug_log::metadata`), the ring of `capacity` records and the writer
/// thread, which also sends every row to `feed` if given (`feed.rs`).
pub fn start(
    path: &Path,
    capacity: usize,
    meta: &serde_json::Value,
    feed: Option<Feed>,
) -> io::Result<(LogSink, LogWriter)> {
    let mut file = create_partial(path)?;
    let mut head = Vec::new();
    let sum = write_header(&mut head, meta)?;
    if let Err(e) = file.write_all(&head) {
        let _ = std::fs::remove_file(partial_path(path));
        return Err(e);
    }
    let (mut producer, mut consumer) = RingBuffer::new(capacity);
    touch_every_slot(&mut producer, &mut consumer);
    let done = Arc::new(AtomicBool::new(false));
    let failed = Arc::new(AtomicBool::new(false));
    let (flag, failed_flag) = (Arc::clone(&done), Arc::clone(&failed));
    let place = Place {
        path: path.to_path_buf(),
        published: false,
    };
    let handle = std::thread::Builder::new()
        .name("sensaug-log".into())
        .spawn(move || write_loop(file, consumer, &flag, &failed_flag, place, sum, feed))?;
    Ok((
        LogSink {
            producer,
            overflows: 0,
            failed,
        },
        LogWriter { done, handle },
    ))
}

/// Writes and takes back one record in every slot of the (empty) ring, so
/// its pages are resident before the loop's first pushes: without
/// `mlockall`, or before it, the loop would take a page fault every few
/// dozen ticks until the ring had wrapped once.
fn touch_every_slot(producer: &mut Producer<LogRecord>, consumer: &mut Consumer<LogRecord>) {
    let blank = LogRecord {
        tick: 0,
        t: 0.0,
        x: 0.0,
        v: 0.0,
        fresh: false,
        tau: 0.0,
        tau_h: 0.0,
        u_h: 0.0,
        torque_nm: 0.0,
        friction_nm: 0.0,
        robot: RobotTick::NONE,
        wake_latency_us: 0.0,
        sleep_latency_us: 0.0,
        compute_us: 0.0,
        feedback_age_ticks: 0,
        drive_state: DriveStatus::Booting,
        guard: None,
        ramp: false,
    };
    while producer.push(blank).is_ok() {}
    while consumer.pop().is_ok() {}
}

/// The writer thread: every [`WRITE_PERIOD`], drain the ring into complete
/// lines (each with its running checksum, `sum`) and write them to the file
/// in one call (publishing the file at its path before the first); the
/// first failure raises `failed`. The same rows go to the live feed, one
/// datagram per pass.
fn write_loop(
    mut file: File,
    mut consumer: Consumer<LogRecord>,
    done: &AtomicBool,
    failed: &AtomicBool,
    mut place: Place,
    mut sum: Checksum,
    mut feed: Option<Feed>,
) -> Written {
    let mut stats = WriterStats::default();
    let mut lines = Vec::with_capacity(1 << 20);
    loop {
        // Read the flag before draining: whatever was pushed before it was
        // set is in the ring now and gets written by this pass.
        let finished = done.load(Ordering::Acquire);
        let mut n = 0u64;
        while let Ok(r) = consumer.pop() {
            let row = r.to_row();
            format_row(&row, &mut sum, &mut lines);
            if let Some(f) = feed.as_mut() {
                f.push(&row);
            }
            n += 1;
        }
        // The feed first: a display waits for it, the file does not.
        if let Some(f) = feed.as_mut() {
            f.flush();
        }
        if n > 0 {
            if stats.error.is_some() {
                stats.records_lost += n;
            } else if let Err(e) = place.publish().and_then(|()| file.write_all(&lines)) {
                stats.write_errors += 1;
                stats.records_lost += n;
                stats.error = Some(e.to_string());
                failed.store(true, Ordering::Relaxed);
            } else {
                stats.records_written += n;
            }
            lines.clear();
        }
        if finished {
            break;
        }
        std::thread::sleep(WRITE_PERIOD);
    }
    Written {
        file,
        stats,
        place,
        sum,
        feed,
    }
}

#[cfg(test)]
mod tests {
    use super::{partial_path, replace, start, write_loop, DriveStatus, LogRecord};
    use sensaug_core::agent::Guard;
    use sensaug_core::controller::RobotTick;
    use sensaug_log::Checksum;

    fn record(tick: u64) -> LogRecord {
        LogRecord {
            tick,
            t: tick as f64 * 1e-3,
            x: 0.5,
            v: -0.25,
            fresh: tick % 2 == 0,
            tau: 0.125,
            tau_h: 0.0,
            u_h: 0.1,
            torque_nm: 0.01,
            friction_nm: 0.002,
            robot: RobotTick {
                u: 0.2,
                phase: 1.0,
                ..RobotTick::NONE
            },
            wake_latency_us: 12.5,
            sleep_latency_us: 112.5,
            compute_us: 30.0,
            feedback_age_ticks: 1,
            drive_state: DriveStatus::Enabled,
            guard: Some(Guard::Clamped),
            ramp: false,
        }
    }

    #[test]
    fn a_record_becomes_a_schema_row() {
        let row = record(4).to_row();
        assert_eq!(
            (row.tick, row.phase, row.guard, row.drive_state),
            (4, 1, 1, 2)
        );
        assert!(row.fresh && !row.ramp);
        assert_eq!((row.x_meas, row.xdot_meas), (0.5, -0.25));
        assert_eq!(row.e, 0.5 - 0.125);
        assert_eq!((row.wake_latency_us, row.sleep_latency_us), (12.5, 112.5));
        assert!(row.eps.is_nan() && row.Lx_hat.is_nan());
        let ramp = LogRecord {
            guard: None,
            robot: RobotTick::NONE,
            ..record(5)
        };
        assert_eq!((ramp.to_row().guard, ramp.to_row().phase), (-1, -1));
    }

    #[test]
    fn the_file_has_header_rows_and_end_line() {
        let dir = std::env::temp_dir().join(format!("sensaug-log-unit-{}", std::process::id()));
        let path = dir.join("log.csv");
        let meta = serde_json::json!({"source": "rig"});
        let (mut sink, writer) = start(&path, 16, &meta, None).unwrap();
        for k in 0..40 {
            sink.push(record(k)); // the ring holds 16: some may overflow
        }
        let overflows = sink.overflows();
        let mut end = serde_json::Map::new();
        end.insert("stop_reason".into(), "completed".into());
        let stats = writer.finish(end);
        let text = std::fs::read_to_string(&path).unwrap();
        let _ = std::fs::remove_dir_all(&dir);
        assert_eq!(stats.records_written + overflows, 40);
        // Every checksum verifies, across the writer's passes.
        let log = sensaug_log::read(&text).unwrap();
        assert_eq!(log.rows.len() as u64, stats.records_written);
        // Debug text: NaN fields compare equal.
        let first = format!("{:?}", record(0).to_row());
        assert_eq!(format!("{:?}", log.rows[0]), first);
        let end = log.end.unwrap();
        assert_eq!(end["stop_reason"], "completed");
        assert_eq!(end["records_written"], stats.records_written);
        assert_eq!(log.meta["source"], "rig");
    }

    #[test]
    fn nothing_but_a_regular_file_is_opened_or_replaced() {
        let dir = std::env::temp_dir().join(format!("sensaug-log-kinds-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let meta = serde_json::json!({"source": "rig"});
        // A stale regular `.partial` (a run killed before its rename) is
        // replaced; a FIFO there is refused at once (not opened: no block).
        let stale = dir.join("stale.csv");
        std::fs::write(partial_path(&stale), b"stale").unwrap();
        let (_sink, writer) = start(&stale, 16, &meta, None).unwrap();
        writer.abandon();
        assert!(!partial_path(&stale).exists());
        let fifo = dir.join("fifo.csv");
        let made = std::process::Command::new("mkfifo")
            .arg(partial_path(&fifo))
            .status()
            .unwrap();
        assert!(made.success());
        let e = start(&fifo, 16, &meta, None).err().unwrap().to_string();
        assert!(e.contains("is a FIFO"), "{e}");
        // A link at `.partial` is not followed.
        let target = dir.join("target");
        std::fs::write(&target, b"keep").unwrap();
        let linked = dir.join("linked.csv");
        std::os::unix::fs::symlink(&target, partial_path(&linked)).unwrap();
        assert!(start(&linked, 16, &meta, None).is_err());
        assert_eq!(std::fs::read(&target).unwrap(), b"keep");
        // Something not a regular file at the path itself is not replaced.
        let dev = dir.join("dev.csv");
        std::os::unix::fs::symlink("/dev/null", &dev).unwrap();
        std::fs::write(partial_path(&dev), b"out").unwrap();
        let e = replace(&dev).unwrap_err().to_string();
        assert!(
            e.contains("symbolic link to /dev/null") && e.contains("stays at"),
            "{e}"
        );
        assert!(std::fs::symlink_metadata(&dev)
            .unwrap()
            .file_type()
            .is_symlink());
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn an_old_log_is_kept_until_the_first_record_and_by_a_run_that_never_starts() {
        let dir = std::env::temp_dir().join(format!("sensaug-log-keep-{}", std::process::id()));
        let path = dir.join("log.csv");
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(&path, b"old log\n").unwrap();
        let meta = serde_json::json!({"source": "rig"});
        let (_sink, writer) = start(&path, 16, &meta, None).unwrap();
        assert!(partial_path(&path).exists());
        writer.abandon();
        assert_eq!(std::fs::read(&path).unwrap(), b"old log\n");
        assert!(!partial_path(&path).exists());
        let (mut sink, writer) = start(&path, 16, &meta, None).unwrap();
        sink.push(record(0));
        // The writer publishes the file with the first record.
        let t0 = std::time::Instant::now();
        while std::fs::read(&path).unwrap() == b"old log\n" {
            assert!(t0.elapsed() < std::time::Duration::from_secs(10));
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
        assert!(!partial_path(&path).exists());
        let stats = writer.finish(serde_json::Map::new());
        let text = std::fs::read_to_string(&path).unwrap();
        let _ = std::fs::remove_dir_all(&dir);
        assert_eq!((stats.records_written, stats.error), (1, None));
        assert!(text.starts_with(sensaug_log::FORMAT_LINE));
    }

    #[test]
    fn a_failed_write_is_counted_and_later_records_are_lost_not_hidden() {
        let dir = std::env::temp_dir().join(format!("sensaug-log-fail-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("ro.csv");
        std::fs::write(&path, b"").unwrap();
        // Opened read-only: every write fails (EBADF).
        let file = std::fs::File::open(&path).unwrap();
        let (mut producer, consumer) = rtrb::RingBuffer::new(8);
        for k in 0..5 {
            producer.push(record(k)).unwrap();
        }
        std::fs::write(partial_path(&path), b"").unwrap();
        let done = std::sync::atomic::AtomicBool::new(true);
        let failed = std::sync::atomic::AtomicBool::new(false);
        let place = super::Place {
            path: path.clone(),
            published: false,
        };
        let written = write_loop(file, consumer, &done, &failed, place, Checksum::new(), None);
        let stats = written.stats;
        let _ = std::fs::remove_dir_all(&dir);
        assert!(failed.load(std::sync::atomic::Ordering::Relaxed));
        assert_eq!(stats.write_errors, 1);
        assert_eq!((stats.records_written, stats.records_lost), (0, 5));
        assert!(stats.error.is_some());
    }
}
