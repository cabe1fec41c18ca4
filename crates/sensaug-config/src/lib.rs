//! The one configuration schema of sensaug, read by the Python API (through
//! the binding), the simulation and the real-time binary `sensaug-rt`.
//!
//! * [`schema`]: the types. They parse TOML and JSON (serde), carry every
//!   default and every bound, and generate the JSON Schema ([`json_schema`]).
//! * [`load_file`] / [`load_str`]: read, parse and resolve ([`Resolved`]: the
//!   one owned value every consumer takes); the error names the first bad
//!   field by its dotted path and says how to fix it. [`parse_file`] /
//!   [`parse_str`] only parse, for a caller that edits before resolving.
//!   A file may include others (`include.rs`; expanded by [`parse_file`]).
//! * [`Resolved::new`]: every field's bound, the cross-field rules, then the
//!   core's structs and the loop's settings ([`rig::RigSettings`]).
//! * [`run`]: what runs from a [`Resolved`]: the core's protocol and
//!   controller, a simulated trial ([`Resolved::simulate`]) and a log's
//!   metadata ([`Resolved::log_metadata`]).
//! * [`to_toml`]: a configuration as TOML with each field's description and
//!   unit as a comment.
//! * [`outputs`]: the rig's output paths, checked against the file system
//!   ([`check_file`] = [`load_file`] + [`outputs::check_outputs`]).
//!
//! Set-up only: everything here allocates; the loop gets the core's structs.

pub mod check;
pub mod cov;
pub mod error;
mod include;
pub mod outputs;
pub mod person;
pub mod resolve;
pub mod rig;
pub mod run;
pub mod schema;
mod shape;
mod write;

pub use cov::Cov;
pub use error::ConfigError;
pub use resolve::{resolve_count, Resolved};
pub use run::{trial_memory_budget, Rejected, SimulatedTrial, TrialError};
pub use schema::*;
pub use write::to_toml;

use std::io::Read;
use std::path::Path;
use std::sync::OnceLock;

/// The text formats a configuration may be written in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// TOML (the usual form).
    Toml,
    /// JSON (what editors and scripts often produce).
    Json,
}

impl std::str::FromStr for Format {
    type Err = ConfigError;

    /// `"toml"` or `"json"`; anything else is refused naming `format`.
    fn from_str(name: &str) -> Result<Format, ConfigError> {
        match name {
            "toml" => Ok(Format::Toml),
            "json" => Ok(Format::Json),
            other => Err(ConfigError::new(
                "format",
                format!("{other:?} is not a configuration format; use \"toml\" or \"json\""),
            )),
        }
    }
}

impl Format {
    /// By the file's extension: `.json` is JSON, anything else TOML.
    pub fn of_path(path: &Path) -> Format {
        match path.extension().and_then(|e| e.to_str()) {
            Some(e) if e.eq_ignore_ascii_case("json") => Format::Json,
            _ => Format::Toml,
        }
    }
}

/// The JSON Schema of a configuration file (draft 2020-12), generated from
/// the types in [`schema`] once per process.
pub fn json_schema() -> &'static serde_json::Value {
    static SCHEMA: OnceLock<serde_json::Value> = OnceLock::new();
    SCHEMA.get_or_init(|| {
        serde_json::to_value(schemars::schema_for!(ScenarioSpec)).expect("a schema is JSON")
    })
}

/// Reads, parses and resolves a configuration file ([`parse_file`], then
/// [`Resolved::new`]). An error at a setting an included file gave names
/// that file.
pub fn load_file(path: &Path) -> Result<Resolved, ConfigError> {
    load_file_with(path, |_| Ok(()))
}

/// [`load_file`] with `edit` applied to the file's values before they are
/// resolved (`sensaug-rt`'s command-line overrides), so that its errors
/// are worded as [`load_file`]'s.
pub fn load_file_with(
    path: &Path,
    edit: impl FnOnce(&mut ScenarioSpec) -> Result<(), ConfigError>,
) -> Result<Resolved, ConfigError> {
    let (mut spec, origins) = read_file(path)?;
    let top = path.display().to_string();
    edit(&mut spec)
        .and_then(|()| Resolved::new(spec))
        .map_err(|e| origins.annotate(&top, e))
}

/// Reads and parses a configuration file, not yet checked against the
/// bounds or resolved, its `include`s merged in and recorded in
/// `included` (`include.rs`). Files over [`MAX_FILE_BYTES`] are refused
/// before parsing. Errors about the file itself or its syntax name it as
/// given.
pub fn parse_file(path: &Path) -> Result<ScenarioSpec, ConfigError> {
    read_file(path).map(|(spec, _)| spec)
}

/// [`parse_file`], and the file each setting came from.
fn read_file(path: &Path) -> Result<(ScenarioSpec, include::Origins), ConfigError> {
    let name = path.display().to_string();
    let text = read_text(path)?;
    let format = Format::of_path(path);
    if include::names_includes(&text, format) {
        return include::expand(path, &text);
    }
    // An error about the whole text (its syntax, its size) names the file,
    // not "(config)": the person reading it has a file open.
    let spec = parse_str(&text, format).map_err(|e| match e.field.as_str() {
        "(config)" => ConfigError::new(&name, e.message),
        _ => e,
    })?;
    Ok((spec, include::Origins::default()))
}

/// A configuration file's text; the error names the file as given.
pub(crate) fn read_text(path: &Path) -> Result<String, ConfigError> {
    let name = path.display().to_string();
    let file = std::fs::File::open(path).map_err(|e| {
        ConfigError::new(
            &name,
            format!("cannot open: {}; check the path", io_reason(&e)),
        )
    })?;
    let mut text = String::new();
    // Read one byte past the limit to tell "at the limit" from "over it".
    let read = file
        .take(MAX_FILE_BYTES + 1)
        .read_to_string(&mut text)
        .map_err(|e| {
            ConfigError::new(
                &name,
                format!("cannot read as UTF-8 text: {}", io_reason(&e)),
            )
        })?;
    if read as u64 > MAX_FILE_BYTES {
        return Err(ConfigError::new(
            &name,
            format!(
                "larger than {} bytes (1 MiB); a configuration is a few kB: give long sampled \
                 targets a coarser dt_s",
                MAX_FILE_BYTES
            ),
        ));
    }
    Ok(text)
}

/// What both checkers (`sensaug check`, `sensaug-rt --check`) run: the file
/// loaded and validated ([`load_file`]), a session plan's every block
/// expanded and validated ([`person::check_conditions`]), then the rig's
/// output paths ([`outputs::check_outputs`]; relative paths from the
/// current folder).
pub fn check_file(path: &Path) -> Result<Resolved, ConfigError> {
    let resolved = load_file(path)?;
    person::check_conditions(&resolved.spec)?;
    check_rig_outputs(&resolved.spec)?;
    Ok(resolved)
}

/// What the rig needs of the position unit: an angle (its joint is
/// revolute, its drive speaks rad and N m). "m" is for simulations.
pub fn check_rig_unit(spec: &ScenarioSpec) -> Result<(), ConfigError> {
    if spec.rig.position_unit.is_angle() {
        return Ok(());
    }
    Err(ConfigError::new(
        "rig.position_unit",
        "\"m\" is a simulated linear handle; the rig's joint is revolute: use \"deg\" or \"rad\" \
         (and the gains, noises and targets in that unit)",
    ))
}

/// The rig's output paths (`rig.log`, `rig.stats`) checked against the file
/// system ([`outputs::check_outputs`]).
pub fn check_rig_outputs(spec: &ScenarioSpec) -> Result<(), ConfigError> {
    outputs::check_outputs(&outputs::rig_outputs(spec))
}

pub(crate) fn io_reason(e: &std::io::Error) -> String {
    // The OS message without Rust's "(os error N)" suffix.
    let s = e.to_string();
    match s.find(" (os error") {
        Some(i) => s[..i].to_string(),
        None => s,
    }
}

/// Parses and resolves configuration text ([`parse_str`], then
/// [`Resolved::new`]).
pub fn load_str(text: &str, format: Format) -> Result<Resolved, ConfigError> {
    Resolved::new(parse_str(text, format)?)
}

/// Parses configuration text, not yet checked against the bounds or resolved.
pub fn parse_str(text: &str, format: Format) -> Result<ScenarioSpec, ConfigError> {
    if text.len() as u64 > MAX_FILE_BYTES {
        return Err(ConfigError::new(
            "(config)",
            "larger than 1 MiB; a configuration is a few kB",
        ));
    }
    match format {
        Format::Toml => parse_toml(text),
        Format::Json => parse_json(text),
    }
}

/// The configuration, every default filled in, as compact JSON.
pub fn to_json(spec: &ScenarioSpec) -> String {
    serde_json::to_string(spec).expect("a validated configuration is JSON")
}

/// The configuration, every default filled in, as text in `format`
/// ([`to_toml`] or [`to_json`]).
pub fn to_text(spec: &ScenarioSpec, format: Format) -> String {
    match format {
        Format::Toml => to_toml(spec),
        Format::Json => to_json(spec),
    }
}

fn path_string(p: &serde_path_to_error::Path) -> String {
    let s = p.to_string();
    // "." is the root; "?" a position serde could not name.
    if s == "." || s == "?" {
        String::new()
    } else {
        s
    }
}

fn parse_toml(text: &str) -> Result<ScenarioSpec, ConfigError> {
    let de = toml::Deserializer::parse(text).map_err(|e| syntax_error(text, &e))?;
    serde_path_to_error::deserialize(de).map_err(|e| {
        let path = path_string(e.path());
        error::from_serde(&path, e.inner().message())
    })
}

/// Parses a configuration from any serde data format's deserializer (the
/// binding reads Python's dicts and lists with one). The values are read
/// into TOML's data model first, so that they are checked, and their errors
/// worded, exactly as a file's; the error names the field by its dotted path.
pub fn parse_from<'de, D: serde::Deserializer<'de>>(de: D) -> Result<ScenarioSpec, ConfigError>
where
    D::Error: std::fmt::Display,
{
    let value = <toml::Value as serde::Deserialize>::deserialize(de).map_err(|e| {
        ConfigError::new(
            "(config)",
            format!("cannot be read as tables of numbers, strings, true/false and lists ({e})"),
        )
    })?;
    spec_of_value(value)
}

/// A configuration from TOML's data model, errors worded as a file's.
pub(crate) fn spec_of_value(value: toml::Value) -> Result<ScenarioSpec, ConfigError> {
    serde_path_to_error::deserialize(value).map_err(|e| {
        let path = path_string(e.path());
        // A TOML value's error ends with the key it was at ("\nin ..."):
        // the path says that already.
        let msg = e.into_inner().to_string();
        error::from_serde(&path, msg.split("\nin ").next().unwrap_or(&msg))
    })
}

fn parse_json(text: &str) -> Result<ScenarioSpec, ConfigError> {
    // serde would also read a struct from a JSON list, by position.
    if !text.trim_start().starts_with('{') {
        return Err(ConfigError::new(
            "(config)",
            "a JSON configuration is one object ({ \"phases\": [...], ... }); wrap the tables in braces",
        ));
    }
    let mut de = serde_json::Deserializer::from_str(text);
    let spec: ScenarioSpec = serde_path_to_error::deserialize(&mut de).map_err(|e| {
        let path = path_string(e.path());
        let inner = e.into_inner();
        if inner.is_syntax() || inner.is_eof() {
            return ConfigError::new(
                if path.is_empty() {
                    "(config)".into()
                } else {
                    path
                },
                format!(
                    "not valid JSON at line {}, column {}; fix the syntax",
                    inner.line(),
                    inner.column()
                ),
            );
        }
        // serde_json appends " at line L column C" to data errors.
        let msg = inner.to_string();
        let msg = msg.split(" at line ").next().unwrap_or(&msg).to_string();
        error::from_serde(&path, &msg)
    })?;
    de.end().map_err(|e| {
        ConfigError::new(
            "(config)",
            format!(
                "trailing text after the JSON object at line {}; remove it",
                e.line()
            ),
        )
    })?;
    Ok(spec)
}

/// A TOML syntax error, at the dotted path of the key on the offending line
/// when one can be read off the text (the tables opened before it, the key
/// at the start of the line), else at the table.
fn syntax_error(text: &str, e: &toml::de::Error) -> ConfigError {
    let offset = e.span().map_or(0, |s| s.start).min(text.len());
    let before = &text[..offset];
    let line_no = before.matches('\n').count() + 1;
    let col = offset - before.rfind('\n').map_or(0, |i| i + 1) + 1;
    let mut table = String::new();
    let mut counts: std::collections::HashMap<String, usize> = Default::default();
    for line in text.lines().take(line_no - 1) {
        let l = line.trim();
        if let Some(name) = l.strip_prefix("[[").and_then(|r| r.split("]]").next()) {
            let name = name.trim().to_string();
            let n = counts.entry(name.clone()).or_insert(0);
            table = format!("{name}[{n}]");
            *n += 1;
        } else if let Some(name) = l.strip_prefix('[').and_then(|r| r.split(']').next()) {
            table = name.trim().to_string();
        }
    }
    let line = text.lines().nth(line_no - 1).unwrap_or("");
    let key = line.split_once('=').map(|(k, _)| k.trim()).filter(|k| {
        !k.is_empty()
            && k.chars()
                .all(|c| c.is_ascii_alphanumeric() || "_-.".contains(c))
    });
    let on_header = line.trim_start().starts_with('[');
    let field = match (table.is_empty() || on_header, key) {
        (true, _) if on_header => "(config)".into(),
        (_, Some(k)) => error::join(&table, k),
        (false, None) => table,
        (true, None) => "(config)".into(),
    };
    ConfigError::new(
        field,
        format!(
            "not valid TOML at line {line_no}, column {col}: {}; fix the syntax",
            e.message().trim_end_matches('\n').replace('\n', "; ")
        ),
    )
}
