//! Configuration errors name the field; the committed rig file parses.
use sensaug_rt::config::parse;

const BASE: &str = r#"
[[phases]]
kind = "gains"
duration_s = 1.0
robot_target = [{ kind = "rounded_square", amplitude = 8.0, period_s = 4.0 }]
partner_target = [{ kind = "rounded_square", amplitude = 8.0, period_s = 4.0 }]

[robot]
[partner]
gains = [0.0, 0.0, 2.0]
"#;

fn error_of(extra: &str, replace: Option<(&str, &str)>) -> String {
    let mut text = format!("{BASE}\n{extra}");
    if let Some((a, b)) = replace {
        assert!(text.contains(a), "{a}");
        text = text.replace(a, b);
    }
    match parse(&text) {
        Err(e) => e.to_string(),
        Ok(spec) => match spec.resolve() {
            Err(e) => e.to_string(),
            Ok(_) => String::from("ok"),
        },
    }
}

#[test]
fn the_base_config_is_valid() {
    assert_eq!(error_of("", None), "ok");
}

/// Extra TOML to append, a replacement in the base, and the expected message.
type Case = (
    &'static str,
    Option<(&'static str, &'static str)>,
    &'static str,
);

#[test]
fn errors_name_the_field() {
    let cases: &[Case] = &[
        (
            "[plant]\nmass = -1.0",
            None,
            "plant.mass: must be finite and > 0",
        ),
        (
            "",
            Some(("duration_s = 1.0", "duration_s = 0.0")),
            "phases[0].duration_s",
        ),
        (
            "",
            Some(("kind = \"gains\"", "kind = \"wobble\"")),
            "phases[0].kind",
        ),
        (
            "",
            Some(("period_s = 4.0 }]\npartner", "period_s = -4.0 }]\npartner")),
            "phases[0].robot_target[0].period_s",
        ),
        ("", Some(("[robot]", "[robot]\nq_pos = 0.0")), "robot.q_pos"),
        (
            "",
            Some(("[robot]", "[robot]\nstage1 = { Q = [1.0, 1.0] }")),
            "robot.stage1.Q: expected 6 diagonal entries",
        ),
        (
            "",
            Some((
                "[robot]",
                "[robot]\nstage2 = { R = [1.0, 1.0, -1.0, 1.0, 1.0] }",
            )),
            "robot.stage2.R: must be positive definite",
        ),
        (
            "",
            Some(("gains = [0.0, 0.0, 2.0]", "gains = [0.0, 2.0]")),
            "partner.gains",
        ),
        ("[rig]\nnode_id = 20", None, "rig.node_id"),
        (
            "[rig]\nposition_unit = \"furlong\"",
            None,
            "rig.position_unit",
        ),
        ("[rig]\ntorque_limit_nm = 0.0", None, "rig.torque_limit_nm"),
        (
            "[rig]\nrealtime = { fifo_priority = 120 }",
            None,
            "rig.realtime.fifo_priority",
        ),
        ("[rig]\nbogus = 1", None, "unknown field `bogus`"),
    ];
    for (extra, replace, want) in cases {
        let got = error_of(extra, *replace);
        assert!(got.contains(want), "wanted {want:?}, got {got:?}");
    }
}

#[test]
fn trajectory_before_gains_is_refused() {
    let got = error_of("", Some(("kind = \"gains\"", "kind = \"trajectory\"")));
    assert!(
        got.contains("phases[0].kind: needs an earlier 'gains' phase"),
        "{got}"
    );
}

#[test]
fn the_committed_rig_config_is_valid() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../configs/hi5_rig.toml");
    let text = std::fs::read_to_string(path).unwrap();
    let spec = parse(&text).unwrap();
    let r = spec.resolve().unwrap();
    assert_eq!(r.partner_gains, [0.0, 0.0, 2.0]);
    assert!((r.robot.gains[0] - 1.0).abs() < 1e-12);
    assert!((r.rad_per_unit - std::f64::consts::PI / 180.0).abs() < 1e-15);
}
