//! `_core.run_scenario` and the configuration entry points: the one schema
//! (`sensaug-config`) reads, checks and resolves the text; the core runs the
//! whole trial in one call. Conversion only.

use crate::log::{pack_record, RECORD_BYTES};
use numpy::IntoPyArray;
use pyo3::create_exception;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use sensaug_config::{Format, ScenarioSpec};
use sensaug_core::world::{check_log_memory, log_budget, LogTooLarge, Scenario};
use sensaug_log::Row;
use std::path::Path;

create_exception!(
    _core,
    ConfigError,
    PyValueError,
    "A configuration error: `str(e)` is `<dotted field path>: <what is wrong and how to fix it>`."
);
create_exception!(
    _core,
    TrialTooLargeError,
    ConfigError,
    "A simulated trial whose log would not fit the memory it may take; raised before it runs, naming the fields that make it large."
);

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("ConfigError", m.py().get_type::<ConfigError>())?;
    m.add(
        "TrialTooLargeError",
        m.py().get_type::<TrialTooLargeError>(),
    )?;
    m.add_function(wrap_pyfunction!(trial_memory, m)?)?;
    m.add_function(wrap_pyfunction!(available_memory, m)?)?;
    m.add_function(wrap_pyfunction!(config_check_file, m)?)?;
    m.add_function(wrap_pyfunction!(config_load_file, m)?)?;
    m.add_function(wrap_pyfunction!(check_output_paths, m)?)?;
    m.add_function(wrap_pyfunction!(config_load, m)?)?;
    m.add_function(wrap_pyfunction!(config_to_toml, m)?)?;
    m.add_function(wrap_pyfunction!(config_schema, m)?)?;
    m.add_function(wrap_pyfunction!(run_scenario, m)?)?;
    Ok(())
}

pub(crate) fn config_err(e: sensaug_config::ConfigError) -> PyErr {
    ConfigError::new_err(e.to_string())
}

fn format(name: &str) -> PyResult<Format> {
    match name {
        "toml" => Ok(Format::Toml),
        "json" => Ok(Format::Json),
        other => Err(PyValueError::new_err(format!(
            "format: {other:?} is not a configuration format; use \"toml\" or \"json\""
        ))),
    }
}

pub(crate) fn load(text: &str, fmt: &str) -> PyResult<ScenarioSpec> {
    sensaug_config::load_str(text, format(fmt)?).map_err(config_err)
}

/// Reads and validates a configuration file and checks its rig output paths
/// against the file system, as `sensaug-rt --check` does; returns it as JSON
/// with every default filled in.
#[pyfunction]
fn config_check_file(path: &str) -> PyResult<String> {
    let spec = sensaug_config::check_file(Path::new(path)).map_err(config_err)?;
    Ok(sensaug_config::to_json(&spec))
}

/// Reads and validates a configuration file (its output paths unchecked);
/// returns it as JSON with every default filled in.
#[pyfunction]
fn config_load_file(path: &str) -> PyResult<String> {
    let spec = sensaug_config::load_file(Path::new(path)).map_err(config_err)?;
    Ok(sensaug_config::to_json(&spec))
}

/// Checks output paths, `(field, path)` each, as the rig's own are checked
/// (`sensaug_config::outputs::check_outputs`): regular files or absent,
/// distinct. Raises `ConfigError` naming the field.
#[pyfunction]
fn check_output_paths(outputs: Vec<(String, std::path::PathBuf)>) -> PyResult<()> {
    let refs: Vec<(&str, &Path)> = outputs
        .iter()
        .map(|(f, p)| (f.as_str(), p.as_path()))
        .collect();
    sensaug_config::outputs::check_outputs(&refs).map_err(config_err)
}

/// Validates configuration text; returns it as JSON with every default filled in.
#[pyfunction]
#[pyo3(signature = (text, /, *, format = "toml"))]
fn config_load(text: &str, format: &str) -> PyResult<String> {
    Ok(sensaug_config::to_json(&load(text, format)?))
}

/// Validates configuration text; returns it as TOML with each field's
/// description and unit as a comment.
#[pyfunction]
#[pyo3(signature = (text, /, *, format = "toml"))]
fn config_to_toml(text: &str, format: &str) -> PyResult<String> {
    Ok(sensaug_config::to_toml(&load(text, format)?))
}

/// The JSON Schema of a configuration file.
#[pyfunction]
fn config_schema() -> String {
    serde_json::to_string_pretty(sensaug_config::json_schema()).expect("a schema is JSON")
}

/// Bytes this process can still take: `MemAvailable` of `/proc/meminfo`,
/// and under a cgroup (v2) memory limit what is left of it; `None` where
/// neither can be read (not Linux).
fn available_bytes() -> Option<u64> {
    let meminfo = std::fs::read_to_string("/proc/meminfo").ok();
    let available = meminfo.as_deref().and_then(|text| {
        let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
        let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
        Some(kib.saturating_mul(1024))
    });
    let cgroup = std::fs::read_to_string("/proc/self/cgroup")
        .ok()
        .and_then(|text| {
            let path = text.lines().find_map(|l| l.strip_prefix("0::"))?.to_owned();
            let dir = Path::new("/sys/fs/cgroup").join(path.trim_start_matches('/'));
            let read = |f: &str| std::fs::read_to_string(dir.join(f)).ok();
            let max: u64 = read("memory.max")?.trim().parse().ok()?; // "max": no limit
            let current: u64 = read("memory.current")?.trim().parse().ok()?;
            Some(max.saturating_sub(current))
        });
    match (available, cgroup) {
        (Some(a), Some(c)) => Some(a.min(c)),
        (a, c) => a.or(c),
    }
}

/// The memory (bytes) a simulated trial's log may take here: half of what
/// is available (`sensaug_core::world::log_budget`), or `None` (no check)
/// where that cannot be read.
#[pyfunction]
fn available_memory() -> Option<u64> {
    available_bytes().map(log_budget)
}

/// `(ticks, log_bytes)` of the trial a configuration describes: the ticks
/// of its protocol and the bytes of its log kept in memory. With
/// `memory_budget` (bytes), raises `TrialTooLargeError` when the log needs
/// more, as `run_scenario` does before it runs.
#[pyfunction]
#[pyo3(signature = (text, /, *, format = "toml", memory_budget = None))]
fn trial_memory(text: &str, format: &str, memory_budget: Option<u64>) -> PyResult<(u64, u64)> {
    let spec = load(text, format)?;
    let resolved = sensaug_config::resolve(&spec).map_err(config_err)?;
    let protocol = resolved.protocol();
    let bytes = check_log_memory(&protocol, RECORD_BYTES, memory_budget.unwrap_or(u64::MAX))
        .map_err(too_large)?;
    Ok((protocol.total_ticks(), bytes))
}

fn too_large(e: LogTooLarge) -> PyErr {
    TrialTooLargeError::new_err(e.to_string())
}

/// Runs one trial from configuration text. Returns `(records, summary)`:
/// the log's rows as the bytes of packed records in the log schema's column
/// order (`log_schema()`; `records.view(sensaug.logs.DTYPE)` is the log).
///
/// Before it runs, the log's size is checked against `memory_budget` bytes
/// (default: [`available_memory`]); a trial that would not fit raises
/// `TrialTooLargeError` naming the fields that make it large.
#[pyfunction]
#[pyo3(signature = (text, /, *, format = "toml", memory_budget = None))]
fn run_scenario<'py>(
    py: Python<'py>,
    text: &str,
    format: &str,
    memory_budget: Option<u64>,
) -> PyResult<(Bound<'py, numpy::PyArray1<u8>>, Bound<'py, PyDict>)> {
    let spec = load(text, format)?;
    let resolved = sensaug_config::resolve(&spec).map_err(config_err)?;
    let protocol = resolved.protocol();
    let budget = memory_budget.or_else(available_memory).unwrap_or(u64::MAX);
    let bytes = check_log_memory(&protocol, RECORD_BYTES, budget).map_err(too_large)?;
    let mut scenario = Scenario::new(
        &resolved.phases,
        resolved.robot,
        resolved.partner,
        resolved.world,
    )
    .map_err(|_| {
        ConfigError::new_err(
            "(config): the core rejected a validated configuration; please report this",
        )
    })?;
    // Each tick's log row is packed as the tick ends, straight into the
    // buffer numpy takes over without a copy: no buffer of the whole
    // trial's records in between. Reserved fallibly: where the budget is
    // unknown, or the system refuses, the trial still fails with a message.
    let mut records = Vec::new();
    usize::try_from(bytes)
        .ok()
        .and_then(|n| records.try_reserve_exact(n).ok())
        .ok_or_else(|| too_large(LogTooLarge::new(&protocol, RECORD_BYTES, None)))?;
    let summary = py.detach(|| {
        scenario.run_with(|k, rec| pack_record(&Row::from_tick_record(k, rec), &mut records))
    });
    let out = records.into_pyarray(py);
    let d = PyDict::new(py);
    d.set_item("ticks", summary.ticks)?;
    d.set_item("robot_clamped", summary.robot.clamped)?;
    d.set_item("robot_non_finite", summary.robot.non_finite)?;
    d.set_item("estimator_errors", summary.robot.estimator_errors)?;
    d.set_item("resymmetrised", summary.robot.resymmetrised)?;
    d.set_item("partner_guarded", summary.partner_guarded)?;
    d.set_item("mirror_errors", summary.mirror_errors)?;
    d.set_item("robot_gains", resolved.robot.gains.to_vec())?;
    d.set_item("partner_gains", resolved.partner.gains.to_vec())?;
    Ok((out, d))
}
