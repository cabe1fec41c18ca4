//! One error type for every configuration problem: the dotted path of the
//! field (`rig.can`, `robot.stage1.R`, `phases[2].kind`) and a message that
//! says what is wrong and how to fix it. Serde's messages are reworded here
//! so that no Rust type name or bare line number reaches the user.

use std::fmt;

/// A configuration error.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ConfigError {
    /// Dotted path of the first bad field; the file itself when the file
    /// cannot be read or parsed.
    pub field: String,
    /// What is wrong and how to fix it.
    pub message: String,
}

impl ConfigError {
    /// An error at `field`.
    pub fn new(field: impl Into<String>, message: impl Into<String>) -> Self {
        ConfigError {
            field: field.into(),
            message: message.into(),
        }
    }
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.field, self.message)
    }
}

impl std::error::Error for ConfigError {}

/// A number as people write it: plain when moderate, exponent otherwise.
pub fn num(v: f64) -> String {
    if v.fract() == 0.0 && v.abs() < 1e7 {
        format!("{v:.0}")
    } else if (1e-3..1e6).contains(&v.abs()) {
        format!("{v}")
    } else if v.is_finite() {
        format!("{v:e}")
    } else {
        format!("{v}").to_lowercase()
    }
}

/// Marks a nested path inside a custom serde message (see
/// [`ShapeSpec`](crate::ShapeSpec)'s deserializer), so it can be joined to the
/// outer path.
pub(crate) const NESTED: char = '\u{1f}';

/// Joins a path and a child segment (`robot` + `q_pos`, `phases` + `[2]`).
pub(crate) fn join(path: &str, child: &str) -> String {
    if child.is_empty() {
        path.to_string()
    } else if path.is_empty() {
        child.trim_start_matches('.').to_string()
    } else if child.starts_with('[') {
        format!("{path}{child}")
    } else {
        format!("{path}.{}", child.trim_start_matches('.'))
    }
}

/// The words for what serde expected, without Rust type names.
fn expected(e: &str) -> String {
    let e = e.trim();
    match e {
        "f64" | "f32" => "a number".into(),
        "u8" | "u16" | "u32" | "u64" | "usize" => "a whole number >= 0".into(),
        "i32" | "i64" => "a whole number".into(),
        "a boolean" => "true or false".into(),
        "a sequence" => "a list".into(),
        "a map" => "a table".into(),
        _ if e.starts_with("struct ") => "a table".into(),
        _ if e.starts_with("an array of length ") => {
            format!("a list of {} numbers", &e["an array of length ".len()..])
        }
        _ => e.replace('`', "\""),
    }
}

/// What serde found, in the file's words.
fn got_words(got: &str) -> String {
    match got {
        "sequence" => "a list".into(),
        "map" => "a table".into(),
        _ => strip_ticks(got).replace("floating point", "the number"),
    }
}

fn strip_ticks(s: &str) -> String {
    s.replace('`', "")
}

/// Rewords a serde message at `path` into a [`ConfigError`].
pub(crate) fn from_serde(path: &str, msg: &str) -> ConfigError {
    let msg = msg.trim();
    // A nested path reported by an inner deserializer.
    if let Some(rest) = msg.strip_prefix(NESTED) {
        if let Some((inner, m)) = rest.split_once(NESTED) {
            return from_serde(&join(path, inner), m);
        }
    }
    if msg == "wanted string or table" {
        return ConfigError::new(
            path,
            "expected one of the allowed names, as a quoted string",
        );
    }
    if let Some(name) = msg
        .strip_prefix("missing field `")
        .and_then(|r| r.strip_suffix('`'))
    {
        return ConfigError::new(
            join(path, name),
            "missing; this field has no default, add it",
        );
    }
    if let Some(rest) = msg.strip_prefix("unknown field `") {
        if let Some((name, allowed)) = rest.split_once('`') {
            let allowed = allowed
                .trim_start_matches(", expected ")
                .trim_start_matches("one of ");
            let allowed = strip_ticks(allowed);
            let hint = if allowed.contains("there are no fields") {
                "remove it".to_string()
            } else {
                format!("remove it or correct its spelling (allowed: {allowed})")
            };
            // The path already ends at the unknown key.
            let at = if path == name || path.ends_with(&format!(".{name}")) {
                path.to_string()
            } else {
                join(path, name)
            };
            return ConfigError::new(at, format!("unknown field; {hint}"));
        }
    }
    if let Some(rest) = msg.strip_prefix("unknown variant `") {
        if let Some((value, allowed)) = rest.split_once('`') {
            let allowed = strip_ticks(
                allowed
                    .trim_start_matches(", expected ")
                    .trim_start_matches("one of "),
            );
            return ConfigError::new(
                path,
                format!("unknown value \"{value}\"; use one of {allowed}"),
            );
        }
    }
    if let Some(rest) = msg.strip_prefix("invalid type: ") {
        if let Some((got, exp)) = rest.split_once(", expected ") {
            return ConfigError::new(
                path,
                format!(
                    "expected {}, got {}; change the value's type",
                    expected(exp),
                    got_words(got)
                ),
            );
        }
    }
    if let Some(rest) = msg.strip_prefix("invalid value: ") {
        if let Some((got, exp)) = rest.split_once(", expected ") {
            return ConfigError::new(
                path,
                format!("expected {}, got {}", expected(exp), strip_ticks(got)),
            );
        }
    }
    if let Some(rest) = msg.strip_prefix("invalid length ") {
        if let Some((got, exp)) = rest.split_once(", expected ") {
            return ConfigError::new(
                path,
                format!("has {got} entries; expected {}", expected(exp)),
            );
        }
    }
    ConfigError::new(path, strip_ticks(msg))
}
