//! Loop statistics: fixed-bin histograms (allocated before the loop; a
//! sample is one counter increment) of wake-up latency, sleep latency and
//! tick compute time, and the loop's error counters.

use crate::safety::{BrakeEnd, StopKind};
use sensaug_bridge::drive_link::{DriveEvents, LinkCounts};
use serde::Serialize;

/// A histogram of durations with 1 us bins up to `max_us`, plus an overflow
/// bin and the exact maximum.
#[derive(Clone, Debug)]
pub struct Histogram {
    bins: Vec<u64>,
    overflow: u64,
    count: u64,
    max_ns: u64,
}

/// Percentiles of a histogram, in microseconds (bin upper edges: resolution 1 us).
#[derive(Clone, Copy, Debug, Default, Serialize, PartialEq)]
pub struct Summary {
    /// Samples.
    pub count: u64,
    /// Median.
    pub p50_us: f64,
    /// 99th percentile.
    pub p99_us: f64,
    /// 99.9th percentile.
    pub p999_us: f64,
    /// Exact maximum.
    pub max_us: f64,
}

impl Histogram {
    /// Set-up: all bins allocated here, and written once so that their
    /// pages are resident before the loop's first samples (zeroed memory
    /// is mapped lazily; `black_box` keeps the writes of zeros).
    pub fn new(max_us: usize) -> Self {
        let mut bins = vec![0; max_us];
        for b in bins.iter_mut().step_by(4096 / std::mem::size_of::<u64>()) {
            *std::hint::black_box(b) = 0;
        }
        Histogram {
            bins,
            overflow: 0,
            count: 0,
            max_ns: 0,
        }
    }

    /// Per tick: one sample.
    pub fn record(&mut self, ns: u64) {
        let us = (ns / 1000) as usize;
        match self.bins.get_mut(us) {
            Some(b) => *b += 1,
            None => self.overflow += 1,
        }
        self.count += 1;
        self.max_ns = self.max_ns.max(ns);
    }

    /// The value below which a fraction `q` of the samples lie (bin upper edge).
    pub fn quantile_us(&self, q: f64) -> f64 {
        if self.count == 0 {
            return f64::NAN;
        }
        let rank = (q * self.count as f64).ceil().max(1.0) as u64;
        let mut seen = 0;
        for (i, b) in self.bins.iter().enumerate() {
            seen += b;
            if seen >= rank {
                return (i + 1) as f64;
            }
        }
        self.max_ns as f64 / 1000.0
    }

    /// p50, p99, p99.9 and the maximum.
    pub fn summary(&self) -> Summary {
        Summary {
            count: self.count,
            p50_us: self.quantile_us(0.5),
            p99_us: self.quantile_us(0.99),
            p999_us: self.quantile_us(0.999),
            max_us: self.max_ns as f64 / 1000.0,
        }
    }
}

/// Where a tick's time goes, one histogram per part (1 us bins): `sense`
/// (drain the bus, the drive's sample), `decide` (the safety checks, the
/// robot's tick and the virtual human), `actuate` (the command's send);
/// together the tick's `compute`. `record` (the log push) follows it.
#[derive(Clone, Debug)]
pub struct ComputeParts {
    /// Wake-up to the bus drained.
    pub sense: Histogram,
    /// Drained to the command decided.
    pub decide: Histogram,
    /// Decided to the command sent.
    pub actuate: Histogram,
    /// The log record's push into the ring.
    pub record: Histogram,
}

/// [`ComputeParts`] as percentiles.
#[derive(Clone, Copy, Debug, Default, Serialize, PartialEq)]
pub struct PartsSummary {
    /// Wake-up to the bus drained.
    pub sense: Summary,
    /// Drained to the command decided.
    pub decide: Summary,
    /// Decided to the command sent.
    pub actuate: Summary,
    /// The log record's push into the ring.
    pub record: Summary,
}

impl ComputeParts {
    /// Set-up: four histograms of `max_us` bins each.
    pub fn new(max_us: usize) -> Self {
        ComputeParts {
            sense: Histogram::new(max_us),
            decide: Histogram::new(max_us),
            actuate: Histogram::new(max_us),
            record: Histogram::new(max_us),
        }
    }

    /// One tick's `sense`, `decide` and `actuate` from its clock readings
    /// (ns, in this order: woke, drained, decided, sent).
    pub fn record_compute(&mut self, woke_ns: u64, sensed_ns: u64, decided_ns: u64, sent_ns: u64) {
        self.sense.record(sensed_ns.saturating_sub(woke_ns));
        self.decide.record(decided_ns.saturating_sub(sensed_ns));
        self.actuate.record(sent_ns.saturating_sub(decided_ns));
    }

    /// Each part's percentiles.
    pub fn summary(&self) -> PartsSummary {
        PartsSummary {
            sense: self.sense.summary(),
            decide: self.decide.summary(),
            actuate: self.actuate.summary(),
            record: self.record.summary(),
        }
    }
}

/// Counters of the CAN link.
#[derive(Clone, Copy, Debug, Default, Serialize, PartialEq, Eq)]
pub struct CanCounters {
    /// Frames the transport failed to send.
    pub send_errors: u64,
    /// Receive errors of the transport.
    pub recv_errors: u64,
    /// Frames that did not decode (unknown id, bad length, bad CRC).
    pub decode_errors: u64,
    /// Ticks whose previous command had no feedback yet.
    pub missing_feedback: u64,
    /// Frames the transport sent.
    pub bus_sent: u64,
    /// Frames the transport received.
    pub bus_received: u64,
    /// Malformed datagrams/frames the transport dropped.
    pub bus_malformed_dropped: u64,
    /// Frames the kernel dropped from the full receive buffer
    /// (`SO_RXQ_OVFL`, UDP bus).
    pub bus_kernel_dropped: u64,
    /// Error frames the transport received (SocketCAN), counted and dropped.
    pub bus_error_frames: u64,
    /// Sends refused at once because the transmit queue was full (SocketCAN).
    pub bus_tx_queue_full: u64,
    /// Command frames for this node that this process did not send (another
    /// controller on the bus).
    pub foreign_commands: u64,
    /// Feedbacks that failed the plausibility or consistency check, or
    /// conflicted with another for the same command.
    pub implausible_feedback: u64,
    /// Feedbacks discarded unused: a copy of the newest, an older one
    /// arriving after it (a replay, a late frame), or one answering no
    /// command sent (docs/safety.md, "Feedback order").
    pub feedback_discarded: u64,
}

/// How the run's stop went (`stats.json` `stop`; docs/safety.md).
#[derive(Clone, Copy, Debug, Serialize, PartialEq)]
pub struct StopReport {
    /// How the drive was brought to its safe state.
    pub kind: StopKind,
    /// The tick the stop was decided in (the last tick run for an
    /// immediate stop; the first braking tick for the controlled stop).
    pub tick: u64,
    /// Ticks the controlled stop braked (commands sent by the brake).
    pub braking_ticks: u64,
    /// Why the controlled stop ended (none for other stops).
    pub brake_end: Option<BrakeEnd>,
    /// The measured speed when the stop was decided (rad/s).
    pub speed_at_stop_rad_s: f64,
    /// The measured speed of the last feedback before the drive was
    /// disabled (rad/s).
    pub speed_at_end_rad_s: f64,
}

/// One emergency message from the drive (CiA 402 EMCY), as the statistics
/// list it: hex codes as a lab reads them in the drive's manual.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct EmcyEntry {
    /// Seconds after tick 0's command (the log's `t`); negative: during
    /// set-up.
    pub t_s: f64,
    /// The tick being sensed when it was taken in (`t_s / dt`, rounded up;
    /// None during set-up).
    pub tick: Option<u64>,
    /// Emergency error code, e.g. "0x8611".
    pub code: String,
    /// Error register 0x1001, e.g. "0x01".
    pub error_register: String,
    /// The 5 manufacturer-specific bytes, hex.
    pub manufacturer: String,
    /// What the code means (its class when not one the master knows).
    pub meaning: &'static str,
}

impl EmcyEntry {
    /// One line for stderr.
    pub fn line(&self) -> String {
        let when = match self.tick {
            Some(k) => format!("t = {:.3} s (tick {k})", self.t_s),
            None => format!("during set-up ({:.3} s before tick 0)", -self.t_s),
        };
        format!(
            "drive EMCY {} ({}), error register {}, manufacturer bytes {}, {when}",
            self.code, self.meaning, self.error_register, self.manufacturer
        )
    }
}

/// What the drive link saw beyond each tick's sample (CiA 402; zeros and an
/// empty list on the Hi5 profile).
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct DriveReport {
    /// EMCY frames received (the first 64 are listed in `emcy`).
    pub emcy_received: u64,
    /// The EMCYs, in the order received.
    pub emcy: Vec<EmcyEntry>,
    /// CiA 402: how TPDOs were matched to SYNCs, "sync_counter_echo" or
    /// "standard" (`rig.cia402.freshness`; none on the Hi5 or before set-up
    /// chose).
    pub freshness: Option<&'static str>,
    /// The link's counts (feedback discarded, late, out of step,
    /// duplicated; SYNCs unanswered; commands clamped or non-finite), as
    /// keys of this table.
    #[serde(flatten)]
    pub counts: LinkCounts,
}

impl DriveReport {
    /// From the link's events, the EMCY times placed on the loop's ticks of
    /// `dt_s`.
    pub fn new(events: &DriveEvents, dt_s: f64) -> Self {
        let emcy = events
            .emcy
            .iter()
            .map(|(e, t_s)| EmcyEntry {
                t_s: *t_s,
                tick: (*t_s >= 0.0).then(|| (t_s / dt_s).ceil() as u64),
                code: format!("{:#06x}", e.code),
                error_register: format!("{:#04x}", e.register),
                manufacturer: e.manufacturer.iter().map(|b| format!("{b:02x}")).collect(),
                meaning: e.name(),
            })
            .collect();
        DriveReport {
            emcy_received: events.emcy_received,
            emcy,
            freshness: events.freshness.map(|f| f.name()),
            counts: events.counts,
        }
    }
}

/// The gaps the drive's watchdog sees at the start (us): from the enable
/// request to the set-up's zero-torque command, and from that command to
/// tick 0's command. NaN when the loop never sent tick 0.
#[derive(Clone, Copy, Debug, Serialize, PartialEq)]
pub struct StartGap {
    /// Enable request to the first (set-up) command.
    pub enable_to_first_command_us: f64,
    /// First command to tick 0's command.
    pub first_command_to_tick0_us: f64,
    /// When tick 0's command was sent (ns, `CLOCK_MONOTONIC`; 0: never):
    /// tick k's time on that clock is about this + k * dt, so a display's
    /// swap times (docs/person.md) can be set against the ticks they show.
    pub tick0_monotonic_ns: u64,
}

impl StartGap {
    /// From the three instants (ns, one clock; 0: did not happen).
    pub fn new(enable_ns: u64, first_command_ns: u64, tick0_ns: u64) -> Self {
        let gap = |a: u64, b: u64| {
            if a == 0 || b == 0 {
                f64::NAN
            } else {
                b.saturating_sub(a) as f64 / 1e3
            }
        };
        StartGap {
            enable_to_first_command_us: gap(enable_ns, first_command_ns),
            first_command_to_tick0_us: gap(first_command_ns, tick0_ns),
            tick0_monotonic_ns: tick0_ns,
        }
    }
}

/// Everything the loop reports at the end.
#[derive(Clone, Debug, Serialize)]
pub struct LoopReport {
    /// Ticks run.
    pub ticks: u64,
    /// Why the loop stopped.
    pub stop_reason: String,
    /// How the stop went.
    pub stop: StopReport,
    /// Wake-up latency: each tick's start after its absolute deadline
    /// (after the spin, with `rig.realtime.spin_us`): what the controller
    /// sees.
    pub wake_latency: Summary,
    /// Sleep latency: the deadline sleep's return after its own target
    /// (the deadline less `rig.realtime.spin_us`): the OS timer's latency,
    /// the quantity cyclictest measures. Equal to `wake_latency` without a
    /// spin.
    pub sleep_latency: Summary,
    /// Compute time of a tick (wake-up to command sent).
    pub compute: Summary,
    /// `compute` by part, and the log push after it.
    pub compute_parts: PartsSummary,
    /// Page faults (minor and major) of the loop's thread while it ran:
    /// memory it touched for the first time; 0 when everything was
    /// pre-touched and locked.
    pub loop_page_faults: u64,
    /// Ticks that woke up after the next deadline had already passed.
    pub deadline_misses: u64,
    /// CAN counters.
    pub can: CanCounters,
    /// The drive's emergency messages and what its link discarded or
    /// clamped.
    pub drive: DriveReport,
    /// Records dropped because the log ring was full.
    pub ring_overflows: u64,
    /// Records written to the log file.
    pub records_written: u64,
    /// Failed writes to the log file (the first one stops the log).
    pub log_write_errors: u64,
    /// Records taken from the ring but not written (after a failed write).
    pub log_records_lost: u64,
    /// The first log write error, if any.
    pub log_error: Option<String>,
    /// Commands clamped to the torque limit.
    pub torque_clamped: u64,
    /// Non-finite commands replaced by zero.
    pub non_finite_commands: u64,
    /// Estimator calls that failed (handled by the filters).
    pub estimator_errors: u64,
    /// Ticks the estimators ran predict-only (no fresh feedback).
    pub missing_measurements: u64,
    /// The robot's estimate of the partner gains (stage 1, final window mean).
    pub partner_gains_estimate: [f64; 3],
    /// The virtual human's true gains.
    pub partner_gains_true: [f64; 3],
    /// The longest run of consecutive ticks without fresh feedback.
    pub longest_stale_run: u64,
    /// The gaps between commands from the enable to tick 0.
    pub start: StartGap,
    /// The exit code (docs/realtime.md).
    pub exit_code: u8,
    /// Which real-time settings took effect, and warnings for those that did not.
    pub realtime: Vec<String>,
}

#[cfg(test)]
mod tests {
    use super::{ComputeParts, Histogram};

    #[test]
    fn compute_parts_are_the_gaps_between_the_clock_readings() {
        let mut parts = ComputeParts::new(100);
        // Woke at 1 us, drained at 3.5, decided at 6, sent at 20.
        parts.record_compute(1_000, 3_500, 6_000, 20_000);
        let s = parts.summary();
        assert_eq!((s.sense.count, s.sense.max_us), (1, 2.5));
        assert_eq!(s.decide.max_us, 2.5);
        assert_eq!(s.actuate.max_us, 14.0);
        assert_eq!(s.record.count, 0, "the log push is recorded on its own");
        // A clock reading earlier than the one before it (it cannot happen
        // on CLOCK_MONOTONIC) is a zero part, not an overflow.
        parts.record_compute(5_000, 4_000, 4_000, 4_000);
        assert_eq!(parts.sense.summary().count, 2);
        assert_eq!(
            parts.sense.quantile_us(0.5),
            1.0,
            "the 0 us bin (upper edge 1 us)"
        );
    }

    #[test]
    fn quantiles_are_bin_upper_edges() {
        let mut h = Histogram::new(100);
        for us in 0..100u64 {
            h.record(us * 1000 + 500);
        }
        let s = h.summary();
        assert_eq!(s.count, 100);
        assert_eq!(s.p50_us, 50.0);
        assert_eq!(s.p99_us, 99.0);
        assert_eq!(s.max_us, 99.5);
        h.record(1_000_000);
        assert_eq!(h.summary().max_us, 1000.0);
        assert_eq!(h.quantile_us(1.0), 1000.0);
    }
}
