//! The schema crate on its own: the committed files load, written TOML reads
//! back to the same configuration, TOML and JSON agree, and the bounds the
//! schema publishes are the ones enforced.

use sensaug_config::{json_schema, to_json, to_toml, ConfigError, Format, ScenarioSpec};

/// The file's values of a configuration that resolves.
fn load_file(path: &Path) -> Result<ScenarioSpec, ConfigError> {
    sensaug_config::load_file(path).map(|r| r.spec)
}

/// The values of configuration text that resolves.
fn load_str(text: &str, format: Format) -> Result<ScenarioSpec, ConfigError> {
    sensaug_config::load_str(text, format).map(|r| r.spec)
}
use std::path::Path;

mod common;
use common::MINIMAL;

fn repo() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .unwrap()
        .parent()
        .unwrap()
}

#[test]
fn committed_configs_load() {
    for entry in std::fs::read_dir(repo().join("configs")).unwrap() {
        let path = entry.unwrap().path();
        let spec = load_file(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        assert!(!spec.phases.is_empty());
    }
}

#[test]
fn defaults_fill_every_table() {
    let spec = load_str(MINIMAL, Format::Toml).unwrap();
    assert_eq!(spec.plant.dt_s, 1e-3);
    assert_eq!(spec.rig.watchdog_ms, 50);
    assert_eq!(spec.partner.gains, Some(vec![0.0, 0.0, 2.0]));
    assert_eq!(
        spec.robot.stage2.R,
        sensaug_config::Cov::diagonal([1e-7; 5])
    );
}

#[test]
fn written_toml_reads_back_the_same() {
    let spec = load_file(&repo().join("configs/hi5_rig.toml")).unwrap();
    let text = to_toml(&spec);
    assert!(text.contains("# Torque limit at the drive (N m)."));
    let back: ScenarioSpec = load_str(&text, Format::Toml).unwrap();
    assert_eq!(back, spec);
}

#[test]
fn json_and_toml_are_one_schema() {
    let spec = load_str(MINIMAL, Format::Toml).unwrap();
    let from_json = load_str(&to_json(&spec), Format::Json).unwrap();
    assert_eq!(from_json, spec);
}

#[test]
fn full_covariances_are_kept_as_written() {
    let text = format!("{MINIMAL}\n[robot.stage3]\nQ = [[0.01, 0.001], [0.001, 0.01]]\n");
    let spec = load_str(&text, Format::Toml).unwrap();
    let back = load_str(&to_toml(&spec), Format::Toml).unwrap();
    assert_eq!(back.robot.stage3.Q, spec.robot.stage3.Q);
    assert!(to_toml(&spec).contains("[0.01, 0.001]"));
}

/// Every numeric bound in the schema rejects a value just past it and
/// accepts the bound itself (checked on the rig's safety settings).
#[test]
fn published_bounds_are_enforced() {
    let rig = &json_schema()["$defs"]["RigSpec"]["properties"];
    for key in [
        "watchdog_ms",
        "stop_time_limit_s",
        "stop_time_constant_s",
        "stop_torque_limit_nm",
        "stop_rest_velocity_rad_s",
        "feedback_timeout_ms",
        "ring_capacity",
        "torque_limit_nm",
        "max_feedback_velocity_rad_s",
        "feedback_step_margin_rad",
        "feedback_velocity_margin_rad_s",
        "max_missing_feedback_fraction",
        "max_stale_feedback_ticks",
        "max_estimator_errors",
    ] {
        let max = rig[key]["maximum"].as_f64().unwrap();
        let int = rig[key]["type"] == "integer";
        let fmt = |v: f64| {
            if int {
                format!("{}", v as u64)
            } else {
                format!("{v:?}")
            }
        };
        let at = format!("{MINIMAL}\n[rig]\n{key} = {}\n", fmt(max));
        assert!(
            load_str(&at, Format::Toml).is_ok(),
            "{key} = {max} must be valid"
        );
        let past = if int { max + 1.0 } else { max * 1.0001 };
        let over = format!("{MINIMAL}\n[rig]\n{key} = {}\n", fmt(past));
        let err = load_str(&over, Format::Toml).unwrap_err();
        assert_eq!(err.field, format!("rig.{key}"), "{key}");
        assert!(err.message.contains("out of range"), "{}", err.message);
    }
}

#[test]
fn oversized_text_is_refused_before_parsing() {
    let text = "#".repeat((1 << 20) + 1);
    let err = load_str(&text, Format::Toml).unwrap_err();
    assert!(err.message.contains("1 MiB"), "{err}");
}

/// `rig.stop_time_constant_s`: at least two loop periods (the brake's
/// gain per tick at most 1/2), named with the fix.
#[test]
fn the_brakes_time_constant_is_at_least_two_periods() {
    let with = |dt_s: &str, tc: &str| {
        load_str(
            &format!("{MINIMAL}\n[plant]\ndt_s = {dt_s}\n[rig]\nstop_time_constant_s = {tc}\n"),
            Format::Toml,
        )
    };
    assert_eq!(
        with("0.001", "0.002").unwrap().rig.stop_time_constant_s,
        0.002
    );
    let short = with("0.002", "0.003").unwrap_err();
    assert_eq!(short.field, "rig.stop_time_constant_s");
    assert_eq!(
        short.message,
        "0.003 s is shorter than two loop periods (plant.dt_s = 0.002 s); the brake would \
         oscillate; use at least 0.004 s"
    );
    let default = load_str(MINIMAL, Format::Toml).unwrap().rig;
    assert_eq!(
        (default.stop_time_constant_s, default.stop_time_limit_s),
        (0.004, 0.2)
    );
}

/// `rig.realtime.spin_us`: the schema's 0..=900, and below half the loop
/// period (a cross-field rule), named with the fix.
#[test]
fn spin_is_bounded_by_the_schema_and_by_half_the_period() {
    let with = |dt_s: &str, spin: &str| {
        load_str(
            &format!("{MINIMAL}\n[plant]\ndt_s = {dt_s}\n[rig.realtime]\nspin_us = {spin}\n"),
            Format::Toml,
        )
    };
    assert_eq!(with("0.001", "0").unwrap().rig.realtime.spin_us, 0);
    assert_eq!(with("0.001", "499").unwrap().rig.realtime.spin_us, 499);
    let half = with("0.001", "500").unwrap_err();
    assert_eq!(half.field, "rig.realtime.spin_us");
    assert_eq!(
        half.message,
        "500 us is not below half the loop period (500 us, plant.dt_s = 0.001 s); \
         choose a smaller spin_us"
    );
    // At 500 Hz the schema's bound is the one that binds.
    assert_eq!(with("0.002", "900").unwrap().rig.realtime.spin_us, 900);
    let over = with("0.002", "901").unwrap_err();
    assert_eq!(over.field, "rig.realtime.spin_us");
    assert!(over.message.contains("out of range"), "{}", over.message);
    assert_eq!(
        load_str(MINIMAL, Format::Toml)
            .unwrap()
            .rig
            .realtime
            .spin_us,
        0
    );
}

/// `rig.cia402.heartbeat_timeout_ms`: the schema's 10..=600 ms, and on the
/// CiA 402 profile at most 3 x `rig.watchdog_ms` (a cross-field rule), named
/// with the fix; the Hi5 profile does not use it.
#[test]
fn the_drive_heartbeat_timeout_is_bounded_by_the_watchdog_on_cia402() {
    let with = |drive: &str, watchdog: u32, timeout: u32| {
        load_str(
            &format!(
                "{MINIMAL}\n[rig]\ndrive = \"{drive}\"\nwatchdog_ms = {watchdog}\n\
                 [rig.cia402]\nheartbeat_timeout_ms = {timeout}\n"
            ),
            Format::Toml,
        )
    };
    let default = load_str(MINIMAL, Format::Toml).unwrap().rig.cia402;
    assert_eq!(default.heartbeat_timeout_ms, 100);
    assert_eq!(
        with("cia402", 50, 150)
            .unwrap()
            .rig
            .cia402
            .heartbeat_timeout_ms,
        150
    );
    let long = with("cia402", 50, 151).unwrap_err();
    assert_eq!(long.field, "rig.cia402.heartbeat_timeout_ms");
    assert_eq!(
        long.message,
        "151 ms is more than 3 x rig.watchdog_ms (50 ms): a drive that stopped beating would go \
         unnoticed far longer than a master that stopped; use at most 150 ms, or a longer \
         rig.watchdog_ms"
    );
    assert!(with("hi5", 50, 151).is_ok());
    for (timeout, field_ok) in [(9, false), (10, true), (600, true), (601, false)] {
        let r = with("cia402", 200, timeout);
        assert_eq!(r.is_ok(), field_ok, "{timeout}: {r:?}");
        if let Err(e) = r {
            assert!(e.message.contains("out of range"), "{e}");
        }
    }
}

/// Loading resolves once; the resolved value is owned, carries the loop's
/// settings and serialises to the metadata's keys.
#[test]
fn a_load_resolves_once_into_one_owned_value() {
    let before = sensaug_config::resolve_count();
    let resolved = sensaug_config::load_file(&repo().join("configs/hi5_rig.toml")).unwrap();
    assert_eq!(sensaug_config::resolve_count() - before, 1);
    let rig = &resolved.rig;
    assert_eq!(rig.period_ns, 1_000_000);
    assert_eq!(rig.dt_s, resolved.dt_s);
    assert_eq!(
        rig.feedback_timeout_ticks,
        (resolved.spec.rig.feedback_timeout_ms * 1e-3 / resolved.dt_s).ceil() as u64
    );
    assert_eq!(
        rig.quiet_period_ms,
        u64::from(resolved.spec.rig.watchdog_ms) * sensaug_config::rig::QUIET_WATCHDOG_PERIODS
    );
    let value = serde_json::to_value(&resolved).unwrap();
    assert_eq!(
        value["config"],
        serde_json::to_value(&resolved.spec).unwrap()
    );
    assert_eq!(
        value["resolved"]["robot"]["gains"],
        serde_json::json!(resolved.robot.gains)
    );
    let settings = value["loop"].as_object().unwrap();
    for key in [
        "stop_time_limit_s",
        "spin_us",
        "quiet_period_ms",
        "node_id",
        "drive",
    ] {
        assert!(settings.contains_key(key), "loop settings lack {key}");
    }
    assert!(!settings.contains_key("plant"));
}

/// MINIMAL with a two-phase base trial and a session of the given blocks.
fn plan(blocks: &str) -> ScenarioSpec {
    let text = format!(
        "{MINIMAL}\n[[phases]]\nkind = \"trajectory\"\nduration_s = 1.0\n\
         robot_target = [{{ kind = \"constant\", value = 0.0 }}]\n\
         partner_target = [{{ kind = \"constant\", value = 0.0 }}]\n\n[session]\n{blocks}"
    );
    load_str(&text, Format::Toml).unwrap()
}

#[test]
fn a_plans_conditions_are_expanded_and_checked() {
    use sensaug_config::person::check_conditions;
    let ok = plan(
        "[[session.blocks]]\nname = \"a\"\ntrials = 3\nphases = [0, 1]\n\
         set = { \"partner.gains.lhh\" = 1.5, \"phases[*].duration_s\" = 2.0 }\n",
    );
    check_conditions(&ok).unwrap();
    let cases = [
        // A path the configuration does not have, named with the block.
        (
            "set = { \"partner.gainz.lhh\" = 1.0 }",
            "session.blocks[0].set: partner.gainz.lhh: partner.gainz is not a field",
        ),
        // Gains by name map to their index; the value is out of bounds.
        (
            "set = { \"partner.gains.lhh\" = 1e9 }",
            "session.blocks[0].set: partner.gains[2]:",
        ),
        // The block keeps phase 0 only: the expanded trial has one phase.
        (
            "phases = [0]\nset = { \"phases[1].duration_s\" = 2.0 }",
            "session.blocks[0].set: phases[1].duration_s: phases[1] does not exist",
        ),
        (
            "set = { \"robot.stage1\" = 3.0 }",
            "session.blocks[0].set: robot.stage1:",
        ),
        (
            "set = { \"phases[x]\" = 3.0 }",
            "session.blocks[0].set: phases[x]: not a dotted path",
        ),
    ];
    for (set, expected) in cases {
        let spec = plan(&format!(
            "[[session.blocks]]\nname = \"a\"\ntrials = 2\n{set}\n"
        ));
        let err = check_conditions(&spec).unwrap_err().to_string();
        assert!(err.starts_with(expected), "{set}: {err}");
    }
}

#[test]
fn the_rig_refuses_a_linear_position_unit() {
    let mut spec = load_str(MINIMAL, Format::Toml).unwrap();
    sensaug_config::check_rig_unit(&spec).unwrap();
    spec.rig.position_unit = sensaug_config::PositionUnit::M;
    sensaug_config::Resolved::new(spec.clone()).unwrap(); // a valid simulation
    let err = sensaug_config::check_rig_unit(&spec).unwrap_err();
    assert_eq!(err.field, "rig.position_unit");
}

/// `rig.watchdog_ms` is bounded per drive profile inside the schema's
/// 2..=200 ms: Hi5 by its protocol (hi5.dbc's SetState.watchdog_ms, 5..=200),
/// CiA 402 by its consumer time (2..=200), not by the Hi5's range.
#[test]
fn the_watchdog_is_bounded_per_drive_profile() {
    let with = |drive: &str, watchdog: u32| {
        load_str(
            &format!(
                "{MINIMAL}\n[rig]\ndrive = \"{drive}\"\nwatchdog_ms = {watchdog}\n\
                 [rig.cia402]\nheartbeat_timeout_ms = 10\n"
            ),
            Format::Toml,
        )
    };
    assert_eq!(
        sensaug_config::DriveProfile::Hi5.watchdog_ms_range().0,
        5,
        "the DBC's minimum"
    );
    // CiA 402's least in practice is 4 ms: its heartbeat consumer time
    // (at least 10 ms) is at most 3 watchdogs.
    for (watchdog, hi5_ok, cia402_ok) in [(1, false, false), (4, false, true)].into_iter().chain([
        (5, true, true),
        (200, true, true),
        (201, false, false),
    ]) {
        let (hi5, cia402) = (with("hi5", watchdog), with("cia402", watchdog));
        assert_eq!(hi5.is_ok(), hi5_ok, "hi5 {watchdog}: {hi5:?}");
        assert_eq!(cia402.is_ok(), cia402_ok, "cia402 {watchdog}: {cia402:?}");
        for e in [hi5.err(), cia402.err()].into_iter().flatten() {
            assert_eq!(e.field, "rig.watchdog_ms");
        }
    }
    let e = with("hi5", 4).unwrap_err();
    assert_eq!(
        e.message,
        "4 ms is outside 5..=200 ms, the range of the Hi5 protocol's SetState.watchdog_ms \
         (hi5.dbc) (rig.drive = \"hi5\"); use a value in it"
    );
}
