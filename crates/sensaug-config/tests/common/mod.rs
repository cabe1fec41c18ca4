//! What the schema crate's test files share.

/// The smallest valid configuration: one gain phase, every table default.
pub const MINIMAL: &str = r#"
[[phases]]
kind = "gains"
duration_s = 1.0
robot_target = [{ kind = "rounded_square", amplitude = 8.0, period_s = 4.0 }]
partner_target = [{ kind = "rounded_square", amplitude = 8.0, period_s = 4.0 }]
"#;
