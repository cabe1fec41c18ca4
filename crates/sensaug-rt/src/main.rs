//! `sensaug-rt CONFIG`: runs the paper's Hi5 experiment at 1 kHz over CAN.
//! Validates the whole configuration (the one schema, `sensaug-config`)
//! before anything moves; prints and saves the loop statistics at the end.
//! Exit code 0 only when the protocol completed; 2 for a configuration or
//! set-up error (the output paths are checked, and the outputs created,
//! before the drive is enabled: `docs/safety.md`, "Output paths"); 3
//! when another controller was seen on the bus before enabling; the other
//! stop reasons have their own codes (`StopReason::exit_code`,
//! docs/realtime.md).

use clap::Parser;
use sensaug_bridge::TransportError;
use sensaug_config::outputs::{create_partial, finish_partial, partial_path};
use sensaug_config::{ConfigError, Resolved};
use sensaug_rt::config::{drive_link, load, Overrides};
use sensaug_rt::control::{Rig, StartError, StopReason};
use sensaug_rt::{feed, log, os};
use std::io::Write;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::AtomicUsize;
use std::sync::Arc;

/// The 1 kHz real-time loop of sensaug: the paper's three-phase experiment
/// over CAN, with the robot controller (and optionally a virtual human)
/// inside the loop.
#[derive(Parser, Debug)]
#[command(version, about)]
struct Args {
    /// The trial configuration (TOML, or JSON by extension): the Python API's
    /// file plus an optional [rig] table. `sensaug schema` prints
    /// every field.
    config: PathBuf,
    /// Validate the configuration (a session plan's every block expanded, as
    /// `sensaug check` does) and its output paths, print "valid" and exit
    /// (exit 2 and the first bad field on stderr when it is not).
    #[arg(long)]
    check: bool,
    /// Print the configuration with every default filled in, as JSON, and exit.
    #[arg(long)]
    print_resolved: bool,
    /// Override rig.can: udp:<port> (loopback virtual bus) or socketcan:<ifname>.
    #[arg(long, value_name = "URL")]
    can: Option<String>,
    /// Override rig.log (the CSV log).
    #[arg(long, value_name = "PATH")]
    log: Option<String>,
    /// Override rig.stats (the JSON loop statistics).
    #[arg(long, value_name = "PATH")]
    stats: Option<String>,
    /// Send every row of the log, live, to this loopback UDP address
    /// (repeatable: one per subscriber, e.g. the live view and the
    /// participant's display). Wire format: docs/live.md.
    #[arg(long, value_name = "127.0.0.1:PORT")]
    feed: Vec<SocketAddr>,
}

fn main() -> ExitCode {
    let args = Args::parse();
    let resolved = match load_args(&args) {
        Ok(resolved) => resolved,
        Err(e) => {
            eprintln!("{e}");
            return ExitCode::from(2);
        }
    };
    if let Some(e) = args
        .feed
        .iter()
        .find_map(|a| feed::check_subscriber(*a).err())
    {
        eprintln!("{e}");
        return ExitCode::from(2);
    }
    if args.check {
        println!("valid");
        return ExitCode::SUCCESS;
    }
    if args.print_resolved {
        println!("{}", sensaug_config::to_json(&resolved.spec));
        return ExitCode::SUCCESS;
    }
    match run(&resolved, &args.feed) {
        Ok(StopReason::Completed) => ExitCode::SUCCESS,
        Ok(reason) => {
            say(&mut std::io::stderr(), &format!("stopped: {reason}"));
            ExitCode::from(reason.exit_code())
        }
        Err(e) => {
            say(&mut std::io::stderr(), &format!("error: {e}"));
            ExitCode::from(e.exit_code())
        }
    }
}

/// Writes one line to an end-of-run stream, ignoring a failure: with the
/// terminal or SSH session gone (SIGHUP, then EPIPE or EIO) the run's
/// outcome is in the statistics, the log's end line and the exit code,
/// which a failed print must not change (`println!` would panic).
fn say(stream: &mut dyn std::io::Write, line: &str) {
    let _ = writeln!(stream, "{line}");
}

/// Why a run did not reach its loop, or failed to report it.
#[derive(Debug)]
enum RunError {
    /// A setting the drive link refused, or one the core refused after it
    /// resolved (a bug: `sensaug_config::Rejected`) (exit 2).
    Config(ConfigError),
    /// The bus `rig.can` names could not be opened or filtered (exit 2).
    Bus(TransportError),
    /// The stop signals' handlers could not be installed (exit 2).
    Signals(std::io::Error),
    /// The live feed's socket (exit 2).
    Feed(feed::FeedError),
    /// An output could not be created (exit 2): its field, path and flag.
    Output {
        field: &'static str,
        path: PathBuf,
        flag: &'static str,
        error: std::io::Error,
    },
    /// The statistics could not be serialised (exit 2).
    Report(serde_json::Error),
    /// The drive set-up failed (exit by [`StartError::exit_code`]).
    Start(StartError),
}

impl RunError {
    fn exit_code(&self) -> u8 {
        match self {
            RunError::Start(e) => e.exit_code(),
            _ => 2,
        }
    }
}

impl std::fmt::Display for RunError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            RunError::Config(e) => write!(f, "{e}"),
            RunError::Bus(e) => write!(f, "rig.can: {e}"),
            RunError::Signals(e) => write!(f, "signal handler: {e}"),
            RunError::Feed(e) => write!(f, "{e}"),
            RunError::Output {
                field,
                path,
                flag,
                error,
            } => write!(
                f,
                "{field}: cannot write {}: {error}; choose a writable path ({flag})",
                partial_path(path).display()
            ),
            RunError::Report(e) => write!(f, "statistics: cannot be written as JSON: {e}"),
            RunError::Start(e) => write!(f, "{e}"),
        }
    }
}

/// Writes the statistics to `<stats>.partial` (made at set-up by
/// [`create_partial`], so a path that cannot be written stops the run before
/// it starts), syncs it, then renames it to `path` ([`finish_partial`]: an
/// older regular file is replaced only by a complete one; on failure the
/// `.partial` is removed).
fn write_stats(mut file: std::fs::File, path: &Path, json: &str) -> std::io::Result<()> {
    let written = file
        .write_all(json.as_bytes())
        .and_then(|()| file.sync_all());
    finish_partial(path, written)
}

/// The file, with the command line's overrides applied, resolved once
/// ([`load`]); its output paths checked too unless only printing it, and
/// with `--check` a session plan's every condition expanded and checked.
fn load_args(args: &Args) -> Result<Resolved, ConfigError> {
    let overrides = Overrides {
        can: args.can.clone(),
        log: args.log.clone(),
        stats: args.stats.clone(),
    };
    let resolved = load(&args.config, &overrides, !args.print_resolved)?;
    if args.check {
        sensaug_config::person::check_conditions(&resolved.spec)?;
    }
    Ok(resolved)
}

fn run(resolved: &Resolved, feed_to: &[SocketAddr]) -> Result<StopReason, RunError> {
    let settings = resolved.rig;
    let robot = resolved
        .controller()
        .map_err(|e| RunError::Config(e.into()))?;
    let rig = &resolved.spec.rig;
    let mut transport = sensaug_bridge::open(&rig.can).map_err(RunError::Bus)?;
    let link = drive_link(&settings).map_err(RunError::Config)?;
    // Only this node's frames wake the loop (a kernel filter on SocketCAN):
    // the drive's, and commands to it, which only another sender can have
    // put on the bus (a socket does not receive its own frames).
    transport
        .accept_only(&link.receive_ids())
        .map_err(RunError::Bus)?;

    // A file-size limit (RLIMIT_FSIZE) makes a write fail (EFBIG) instead of
    // killing the process, so the loop can stop under control.
    if let Err(e) = os::ignore_file_size_signal() {
        eprintln!("warning: SIGXFSZ not ignored ({e})");
    }
    let stop = Arc::new(AtomicUsize::new(0));
    os::register_stop_signals(&stop).map_err(RunError::Signals)?;
    let log_path = PathBuf::from(&rig.log);
    let stats_path = PathBuf::from(&rig.stats);
    let meta = log_metadata(resolved);
    // The log writer thread inherits this thread's affinity: keep it off
    // the loop's CPU (the loop pins itself to it below).
    let writer_off_cpu = rig.realtime.cpu.map(|cpu| os::avoid_cpu(cpu as usize));
    let feed = match feed_to {
        [] => None,
        to => {
            let start = meta["start_unix_s"].as_f64().unwrap_or(0.0);
            Some(feed::Feed::open(to, start).map_err(RunError::Feed)?)
        }
    };
    // Both outputs exist (as `.partial`) before the drive is enabled.
    let (mut sink, writer) = log::start(&log_path, rig.ring_capacity as usize, &meta, feed)
        .map_err(|error| RunError::Output {
            field: "rig.log",
            path: log_path.clone(),
            flag: "--log",
            error,
        })?;
    let stats_file = match create_partial(&stats_path) {
        Ok(f) => f,
        Err(e) => {
            writer.abandon();
            return Err(RunError::Output {
                field: "rig.stats",
                path: stats_path,
                flag: "--stats",
                error: e,
            });
        }
    };

    // Real-time settings before the drive is enabled: from the enable on,
    // nothing slow may stand between the drive and the first tick (mlockall
    // can take long enough to trip the drive's watchdog).
    let mut realtime = Vec::new();
    let note = |what: &str, r: std::io::Result<()>, out: &mut Vec<String>| match r {
        Ok(()) => out.push(format!("{what}: ok")),
        Err(e) => {
            eprintln!("warning: {what} not applied ({e}); continuing without it");
            out.push(format!("{what}: not applied ({e})"));
        }
    };
    note("timer slack 1 ns", os::minimal_timer_slack(), &mut realtime);
    if let Some(r) = writer_off_cpu {
        note("log writer off the loop's cpu", r, &mut realtime);
    }
    if rig.realtime.mlockall {
        note("mlockall", os::lock_memory(), &mut realtime);
        os::prefault_stack();
        realtime.push(format!(
            "stack pre-touched: {} KiB",
            os::PREFAULT_STACK_BYTES / 1024
        ));
    }
    if let Some(cpu) = rig.realtime.cpu {
        note(
            &format!("pin to cpu {cpu}"),
            os::pin_to_cpu(cpu as usize),
            &mut realtime,
        );
    }
    match rig.realtime.fifo_priority {
        Some(p) => note(
            &format!("SCHED_FIFO {p}"),
            os::set_fifo(p as i32),
            &mut realtime,
        ),
        None => note(
            &format!("SCHED_OTHER slice {} us", os::FAIR_SLICE_NS / 1000),
            os::short_fair_slice(),
            &mut realtime,
        ),
    }
    if rig.realtime.spin_us > 0 {
        // Nothing to refuse: the spin is the loop's own busy-wait.
        realtime.push(format!(
            "spin {} us before each deadline",
            rig.realtime.spin_us
        ));
    }

    let mut rig_loop = match Rig::start(settings, link, transport, robot) {
        Ok(r) => r,
        Err(e) => {
            // The run never started: any older log and statistics stay.
            writer.abandon();
            drop(stats_file);
            let _ = std::fs::remove_file(partial_path(&stats_path));
            return Err(RunError::Start(e));
        }
    };

    let reason = rig_loop.run(&mut sink, &stop);

    let overflows = sink.overflows();
    drop(sink);
    let mut report = rig_loop.report(reason);
    for emcy in &report.drive.emcy {
        eprintln!("{}", emcy.line());
    }
    let unlisted = report.drive.emcy_received - report.drive.emcy.len() as u64;
    if unlisted > 0 {
        eprintln!("drive EMCY: {unlisted} more not listed (counted in stats drive.emcy_received)");
    }
    report.ring_overflows = overflows;
    report.realtime = realtime;
    let mut end = serde_json::Map::new();
    end.insert("stop_reason".into(), report.stop_reason.clone().into());
    end.insert("ticks".into(), report.ticks.into());
    end.insert("ring_overflows".into(), overflows.into());
    end.insert("realtime".into(), report.realtime.clone().into());
    end.insert("exit_code".into(), reason.exit_code().into());
    end.insert("drive_status".into(), rig_loop.drive_status().name().into());
    // The drive's torque step (model units; null: not set up): the torque
    // sent was rounded to it, the rounding carried by the robot's `u`.
    end.insert(
        "robot_torque_step".into(),
        rig_loop.robot_torque_step().into(),
    );
    let written = writer.finish(end);
    if let Some(e) = &written.error {
        say(
            &mut std::io::stderr(),
            &format!(
                "warning: rig.log: {e}; {} records lost after the failure",
                written.records_lost
            ),
        );
    }
    report.records_written = written.records_written;
    report.log_write_errors = written.write_errors;
    report.log_records_lost = written.records_lost;
    report.log_error = written.error;
    let json = serde_json::to_string_pretty(&report).map_err(RunError::Report)?;
    // A failure to save the statistics loses only that file: the run's stop
    // reason and exit code stand, and the statistics still reach stdout.
    if let Err(e) = write_stats(stats_file, &stats_path, &json) {
        eprintln!(
            "warning: rig.stats: cannot write {}: {e}; the statistics are printed on stdout \
             only, not saved ({} keeps what it held before); the run itself: {}, exit {}",
            stats_path.display(),
            stats_path.display(),
            report.stop_reason,
            reason.exit_code()
        );
    }
    say(&mut std::io::stdout(), &json);
    Ok(reason)
}

/// The log's metadata line: the resolved configuration's serialisation
/// (the file's values, the values derived from them and the loop's
/// settings), the bus, the log writer's period and the git commit.
fn log_metadata(resolved: &Resolved) -> serde_json::Value {
    let exe_dir = std::env::current_exe()
        .ok()
        .and_then(|p| p.parent().map(Path::to_path_buf));
    let mut loop_settings = serde_json::to_value(resolved.rig).unwrap_or_default();
    if let Some(m) = loop_settings.as_object_mut() {
        m.insert("can".into(), resolved.spec.rig.can.clone().into());
        m.insert(
            "log_write_period_ms".into(),
            (log::WRITE_PERIOD.as_secs_f64() * 1e3).into(),
        );
    }
    let git_commit = exe_dir.as_deref().and_then(sensaug_log::git_commit);
    resolved.log_metadata(sensaug_log::Source::Rig, git_commit, loop_settings)
}
