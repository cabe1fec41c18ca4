//! `sensaug-rt CONFIG.toml`: runs the paper's Hi5 experiment at 1 kHz over
//! CAN. Validates the whole configuration before anything moves; prints and
//! saves the loop statistics at the end. Exit code 0 only when the protocol
//! completed.

use sensaug_bridge::protocol::NodeId;
use sensaug_core::scenario::{Protocol, Robot};
use sensaug_rt::config::{parse, ConfigError, RigSpec};
use sensaug_rt::control::{LoopSettings, Rig, StopReason};
use sensaug_rt::{log, os};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Duration;

const USAGE: &str =
    "usage: sensaug-rt CONFIG.toml [--check] [--can URL] [--log PATH] [--stats PATH]

  CONFIG.toml   the trial: the Python API's TOML plus an optional [rig] table
  --check       validate the configuration and exit
  --print-resolved  print every resolved setting (defaults filled in) as JSON and exit
  --can URL     override rig.can (udp:<port> or socketcan:<ifname>)
  --log PATH    override rig.log (.csv, docs/logs.md)
  --stats PATH  override rig.stats (.json)";

struct Args {
    config: PathBuf,
    check: bool,
    print_resolved: bool,
    can: Option<String>,
    log: Option<PathBuf>,
    stats: Option<PathBuf>,
}

fn parse_args() -> Result<Args, String> {
    let mut it = std::env::args().skip(1);
    let mut args = Args {
        config: PathBuf::new(),
        check: false,
        print_resolved: false,
        can: None,
        log: None,
        stats: None,
    };
    let mut config = None;
    while let Some(a) = it.next() {
        match a.as_str() {
            "--check" => args.check = true,
            "--print-resolved" => args.print_resolved = true,
            "--can" => args.can = Some(it.next().ok_or("--can needs a URL")?),
            "--log" => args.log = Some(it.next().ok_or("--log needs a path")?.into()),
            "--stats" => args.stats = Some(it.next().ok_or("--stats needs a path")?.into()),
            "-h" | "--help" => return Err(USAGE.into()),
            other if other.starts_with('-') => {
                return Err(format!("unknown option {other}\n{USAGE}"))
            }
            other => config = Some(PathBuf::from(other)),
        }
    }
    args.config = config.ok_or_else(|| USAGE.to_string())?;
    Ok(args)
}

fn main() -> ExitCode {
    let args = match parse_args() {
        Ok(a) => a,
        Err(msg) => {
            eprintln!("{msg}");
            return ExitCode::from(2);
        }
    };
    match run(args) {
        Ok(StopReason::Completed) => ExitCode::SUCCESS,
        Ok(_) => ExitCode::from(1),
        Err(msg) => {
            eprintln!("error: {msg}");
            ExitCode::from(2)
        }
    }
}

fn run(args: Args) -> Result<StopReason, String> {
    let text = std::fs::read_to_string(&args.config)
        .map_err(|e| format!("{}: cannot read: {e}", args.config.display()))?;
    let spec = parse(&text).map_err(|e: ConfigError| format!("{}: {e}", args.config.display()))?;
    let mut resolved = spec
        .resolve()
        .map_err(|e| format!("{}: {e}", args.config.display()))?;
    if let Some(url) = args.can {
        resolved.rig.can = url;
    }
    if let Some(p) = args.log {
        resolved.rig.log = p;
    }
    if let Some(p) = args.stats {
        resolved.rig.stats = p;
    }
    if args.print_resolved {
        println!("{}", resolved.to_json());
        return Ok(StopReason::Completed);
    }
    let protocol =
        Protocol::new(&resolved.phases, resolved.dt_s).map_err(|e| format!("phases: {e:?}"))?;
    let robot = Robot::new(resolved.robot, protocol).map_err(|e| format!("robot: {e:?}"))?;
    let node = NodeId::new(resolved.rig.node_id.into()).map_err(|e| format!("rig.node_id: {e}"))?;
    if args.check {
        println!(
            "{}: valid ({} ticks, robot gains {:?}, partner gains {:?})",
            args.config.display(),
            protocol.total_ticks(),
            resolved.robot.gains,
            resolved.partner_gains
        );
        return Ok(StopReason::Completed);
    }
    let rig = resolved.rig.clone();
    let transport = sensaug_bridge::open(&rig.can).map_err(|e| format!("rig.can: {e}"))?;

    let stop = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(sig, Arc::clone(&stop))
            .map_err(|e| format!("signal handler: {e}"))?;
    }
    let settings = LoopSettings {
        node,
        dt_s: resolved.dt_s,
        rad_per_unit: resolved.rad_per_unit,
        torque_limit_nm: rig.torque_limit_nm,
        watchdog_ms: rig.watchdog_ms,
        feedback_timeout_ms: rig.feedback_timeout_ms,
        ramp_down_s: rig.ramp_down_s,
        partner_gains: resolved.partner_gains,
        partner_torque_limit: resolved.partner_torque_limit,
    };
    let meta = log_metadata(&text, &resolved.to_json(), &settings, &rig);
    let (mut sink, writer) = log::start(&rig.log, rig.ring_capacity, &meta)
        .map_err(|e| format!("rig.log: {}: {e}", rig.log.display()))?;

    let mut rig_loop = Rig::start(settings, transport, robot, Duration::from_secs(5))
        .map_err(|e| e.to_string())?;

    let mut realtime = Vec::new();
    let note = |what: &str, r: std::io::Result<()>, out: &mut Vec<String>| match r {
        Ok(()) => out.push(format!("{what}: ok")),
        Err(e) => {
            eprintln!("warning: {what} not applied ({e}); continuing without it");
            out.push(format!("{what}: not applied ({e})"));
        }
    };
    note("timer slack 1 ns", os::minimal_timer_slack(), &mut realtime);
    if rig.realtime.mlockall {
        note("mlockall", os::lock_memory(), &mut realtime);
    }
    if let Some(cpu) = rig.realtime.cpu {
        note(
            &format!("pin to cpu {cpu}"),
            os::pin_to_cpu(cpu),
            &mut realtime,
        );
    }
    if let Some(p) = rig.realtime.fifo_priority {
        note(&format!("SCHED_FIFO {p}"), os::set_fifo(p), &mut realtime);
    }

    let reason = rig_loop.run(&mut sink, &stop);

    let overflows = sink.overflows();
    drop(sink);
    let mut report = rig_loop.report(reason);
    report.ring_overflows = overflows;
    report.realtime = realtime;
    let mut end = serde_json::Map::new();
    end.insert("stop_reason".into(), report.stop_reason.clone().into());
    end.insert("ticks".into(), report.ticks.into());
    end.insert("ring_overflows".into(), overflows.into());
    end.insert("realtime".into(), report.realtime.clone().into());
    let written = writer.finish(end);
    if let Some(e) = &written.error {
        eprintln!(
            "warning: rig.log: {e}; {} records lost after the failure",
            written.records_lost
        );
    }
    report.records_written = written.records_written;
    report.log_write_errors = written.write_errors;
    report.log_records_lost = written.records_lost;
    report.log_error = written.error;
    let json = serde_json::to_string_pretty(&report).map_err(|e| e.to_string())?;
    if let Some(dir) = rig.stats.parent() {
        let _ = std::fs::create_dir_all(dir);
    }
    std::fs::write(&rig.stats, &json).map_err(|e| format!("rig.stats: {e}"))?;
    println!("{json}");
    Ok(reason)
}

/// The log's metadata line: the configuration file as given (TOML as JSON),
/// every resolved setting, the loop's settings, the start time and the git
/// commit of the checkout the binary was built in (when it is one).
fn log_metadata(
    text: &str,
    resolved: &serde_json::Value,
    s: &LoopSettings,
    rig: &RigSpec,
) -> serde_json::Value {
    let config = toml::from_str::<toml::Value>(text)
        .ok()
        .and_then(|v| serde_json::to_value(v).ok())
        .unwrap_or(serde_json::Value::Null);
    let exe_dir = std::env::current_exe()
        .ok()
        .and_then(|p| p.parent().map(Path::to_path_buf));
    sensaug_log::metadata(&sensaug_log::RunInfo {
        source: sensaug_log::Source::Rig,
        config,
        resolved: resolved.clone(),
        git_commit: exe_dir.as_deref().and_then(sensaug_log::git_commit),
        start_unix_s: sensaug_log::now_unix_s(),
        loop_settings: serde_json::json!({
            "can": rig.can,
            "node_id": s.node.get(),
            "dt_s": s.dt_s,
            "rad_per_unit": s.rad_per_unit,
            "torque_limit_nm": s.torque_limit_nm,
            "watchdog_ms": s.watchdog_ms,
            "feedback_timeout_ms": s.feedback_timeout_ms,
            "ramp_down_s": s.ramp_down_s,
            "partner_gains": s.partner_gains,
            "partner_torque_limit": s.partner_torque_limit,
            "ring_capacity": rig.ring_capacity,
            "log_write_period_ms": log::WRITE_PERIOD.as_secs_f64() * 1e3,
        }),
    })
}
