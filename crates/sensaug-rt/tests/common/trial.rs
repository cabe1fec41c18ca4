//! The short trial the loop's tests run: `tests/test_rig_cia402.py`'s gain
//! phase (3 s, a 0.5 s gain window) and half a second of goal integration,
//! the paper's virtual human `L_h = [0, 0, 2]`.

pub const CONFIG: &str = r#"
[[phases]]
kind = "gains"
duration_s = 3.0
robot_target = [{ kind = "rounded_square", amplitude = 8.0, period_s = 4.0 },
                { kind = "chirp", amplitude = 2.0, f0_hz = 0.0, f1_hz = 2.0, duration_s = 3.0 }]
partner_target = [{ kind = "rounded_square", amplitude = 8.0, period_s = 4.0 }]

[[phases]]
kind = "integration"
duration_s = 0.5
robot_target = [{ kind = "rounded_square", amplitude = 8.0, period_s = 4.0 }]
partner_target = [{ kind = "rounded_square", amplitude = 8.0, period_s = 4.0 }]
target_noise_std = 1.0

[robot]
gain_window_s = 0.5

[partner]
gains = [0.0, 0.0, 2.0]
"#;
