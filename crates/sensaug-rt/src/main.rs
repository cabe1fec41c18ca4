//! `sensaug-rt CONFIG`: runs the paper's Hi5 experiment at 1 kHz over CAN.
//! Validates the whole configuration (the one schema, `sensaug-config`)
//! before anything moves; prints and saves the loop statistics at the end.
//! Exit code 0 only when the protocol completed; 2 for a configuration or
//! set-up error.

use clap::Parser;
use sensaug_config::{load_file, validate, ConfigError, ScenarioSpec};
use sensaug_core::controller::Robot;
use sensaug_rt::config::loop_settings;
use sensaug_rt::control::{Rig, StopReason};
use sensaug_rt::{log, os};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Duration;

/// The 1 kHz real-time loop of sensaug: the paper's three-phase experiment
/// over CAN, with the robot controller (and optionally a virtual human)
/// inside the loop.
#[derive(Parser, Debug)]
#[command(version, about)]
struct Args {
    /// The trial configuration (TOML, or JSON by extension): the Python API's
    /// file plus an optional [rig] table. `python -m sensaug schema` prints
    /// every field.
    config: PathBuf,
    /// Validate the configuration, print "valid" and exit (exit 2 and the
    /// first bad field on stderr when it is not).
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
}

fn main() -> ExitCode {
    let args = Args::parse();
    let spec = match load(&args) {
        Ok(spec) => spec,
        Err(e) => {
            eprintln!("{e}");
            return ExitCode::from(2);
        }
    };
    if args.check {
        println!("valid");
        return ExitCode::SUCCESS;
    }
    if args.print_resolved {
        println!("{}", sensaug_config::to_json(&spec));
        return ExitCode::SUCCESS;
    }
    match run(&spec) {
        Ok(StopReason::Completed) => ExitCode::SUCCESS,
        Ok(_) => ExitCode::from(1),
        Err(msg) => {
            eprintln!("error: {msg}");
            ExitCode::from(2)
        }
    }
}

/// The file, with the command line's overrides applied, validated as a whole.
fn load(args: &Args) -> Result<ScenarioSpec, ConfigError> {
    let mut spec = load_file(&args.config)?;
    if let Some(url) = &args.can {
        spec.rig.can = url.clone();
    }
    if let Some(p) = &args.log {
        spec.rig.log = p.clone();
    }
    if let Some(p) = &args.stats {
        spec.rig.stats = p.clone();
    }
    validate(&spec)?;
    Ok(spec)
}

fn run(spec: &ScenarioSpec) -> Result<StopReason, String> {
    let resolved = sensaug_config::resolve(spec).map_err(|e| e.to_string())?;
    let settings = loop_settings(&resolved).map_err(|e| e.to_string())?;
    let robot = Robot::new(resolved.robot, resolved.protocol()).map_err(|_| {
        "robot: the controller rejected a configuration that validated; please report this"
            .to_string()
    })?;
    let rig = &spec.rig;
    let transport = sensaug_bridge::open(&rig.can).map_err(|e| format!("rig.can: {e}"))?;

    let stop = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(sig, Arc::clone(&stop))
            .map_err(|e| format!("signal handler: {e}"))?;
    }
    let log_path = PathBuf::from(&rig.log);
    let stats_path = PathBuf::from(&rig.stats);
    let (mut sink, writer) = log::start(&log_path, rig.ring_capacity as usize)
        .map_err(|e| format!("rig.log: {}: {e}", log_path.display()))?;

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
            os::pin_to_cpu(cpu as usize),
            &mut realtime,
        );
    }
    if let Some(p) = rig.realtime.fifo_priority {
        note(
            &format!("SCHED_FIFO {p}"),
            os::set_fifo(p as i32),
            &mut realtime,
        );
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
    if let Some(dir) = stats_path.parent() {
        let _ = std::fs::create_dir_all(dir);
    }
    std::fs::write(&stats_path, &json).map_err(|e| format!("rig.stats: {e}"))?;
    println!("{json}");
    Ok(reason)
}
