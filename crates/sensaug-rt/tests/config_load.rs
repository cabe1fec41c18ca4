//! The binary's configuration: read and resolved once per start, the loop's
//! settings and the log's `loop` metadata taken from that one value.

use sensaug_rt::config::{load, Overrides};
use std::path::Path;

fn hi5_rig() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/hi5_rig.toml")
}

#[test]
fn a_start_resolves_its_configuration_once() {
    let before = sensaug_config::resolve_count();
    let overrides = Overrides {
        can: Some("udp:47999".into()),
        ..Overrides::default()
    };
    let resolved = load(&hi5_rig(), &overrides, false).unwrap();
    assert_eq!(sensaug_config::resolve_count() - before, 1);
    assert_eq!(resolved.spec.rig.can, "udp:47999");
    // The loop's settings are part of the resolved value, derived from it.
    let settings = resolved.rig;
    assert_eq!(settings.dt_s, resolved.dt_s);
    assert_eq!(settings.period_ns, (resolved.dt_s * 1e9).round() as u64);
    assert_eq!(settings.spin_us, resolved.spec.rig.realtime.spin_us);
}

#[test]
fn an_override_is_checked_with_the_file() {
    let overrides = Overrides {
        can: Some("carrier-pigeon:1".into()),
        ..Overrides::default()
    };
    let err = load(&hi5_rig(), &overrides, false).unwrap_err();
    assert_eq!(err.field, "rig.can");
}
