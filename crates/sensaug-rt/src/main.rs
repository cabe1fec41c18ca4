//! `sensaug-rt CONFIG.toml`: runs the paper's Hi5 experiment at 1 kHz over
//! CAN. Validates the whole configuration before anything moves; prints and
//! saves the loop statistics at the end. Exit code 0 only when the protocol
//! completed.

use sensaug_bridge::protocol::{MessageKind, NodeId};
use sensaug_core::scenario::{Protocol, Robot};
use sensaug_rt::config::{parse, ConfigError};
use sensaug_rt::control::{LoopSettings, Rig, StopReason};
use sensaug_rt::{log, os};
use std::path::PathBuf;
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
  --log PATH    override rig.log (.npy)
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
    let mut transport = sensaug_bridge::open(&rig.can).map_err(|e| format!("rig.can: {e}"))?;
    // Only this drive's frames wake the loop (a kernel filter on SocketCAN).
    let drive_ids = [
        MessageKind::Feedback,
        MessageKind::Fault,
        MessageKind::Heartbeat,
    ];
    transport
        .accept_only(&drive_ids.map(|k| k.id(node)))
        .map_err(|e| format!("rig.can: {e}"))?;

    let stop = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(sig, Arc::clone(&stop))
            .map_err(|e| format!("signal handler: {e}"))?;
    }
    let (mut sink, writer) = log::start(&rig.log, rig.ring_capacity)
        .map_err(|e| format!("rig.log: {}: {e}", rig.log.display()))?;

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
    let written = writer.finish().map_err(|e| format!("rig.log: {e}"))?;
    let mut report = rig_loop.report(reason);
    report.ring_overflows = overflows;
    report.records_written = written;
    report.realtime = realtime;
    let json = serde_json::to_string_pretty(&report).map_err(|e| e.to_string())?;
    if let Some(dir) = rig.stats.parent() {
        let _ = std::fs::create_dir_all(dir);
    }
    std::fs::write(&rig.stats, &json).map_err(|e| format!("rig.stats: {e}"))?;
    println!("{json}");
    Ok(reason)
}
