//! `_core.Config`, the resolved configuration as one Python object, and the
//! entry points that take it: a simulated trial and the memory it needs.
//! The one schema (`sensaug-config`) reads, checks and resolves; the core
//! runs the whole trial in one call. Conversion only.

use crate::log::{pack_record, RECORD_BYTES};
use numpy::IntoPyArray;
use pyo3::create_exception;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyTuple};
use pythonize::{pythonize, Depythonizer};
use sensaug_config::{Format, Resolved};
use sensaug_core::protocol::Protocol;
use sensaug_core::world::{check_log_memory, log_budget, LogTooLarge, Scenario};
use std::path::{Path, PathBuf};

create_exception!(
    _core,
    ConfigError,
    PyValueError,
    "A configuration error: `.field` is the dotted field path, `.message` what is wrong and how to fix it; `str(e)` is `<field>: <message>`."
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
    m.add_class::<Config>()?;
    m.add_function(wrap_pyfunction!(available_memory, m)?)?;
    m.add_function(wrap_pyfunction!(check_output_paths, m)?)?;
    m.add_function(wrap_pyfunction!(config_schema, m)?)?;
    m.add_function(wrap_pyfunction!(resolve_count, m)?)?;
    m.add_function(wrap_pyfunction!(run_scenario, m)?)?;
    Ok(())
}

/// A configuration error as `ConfigError` (or `kind`) with `.field` and
/// `.message` set.
fn field_error<E: pyo3::PyTypeInfo>(field: &str, message: &str) -> PyErr {
    Python::attach(|py| {
        let err = PyErr::new::<E, _>(format!("{field}: {message}"));
        let value = err.value(py);
        for (name, v) in [("field", field), ("message", message)] {
            if let Err(e) = value.setattr(name, v) {
                return e;
            }
        }
        err
    })
}

pub(crate) fn config_err(e: sensaug_config::ConfigError) -> PyErr {
    field_error::<ConfigError>(&e.field, &e.message)
}

fn too_large(e: LogTooLarge) -> PyErr {
    let text = e.to_string();
    let (field, message) = text.split_once(": ").unwrap_or(("phases", &text));
    field_error::<TrialTooLargeError>(field, message)
}

/// A configuration resolved once (`sensaug_config::Resolved`): the file's
/// values with every default filled in and everything derived from them
/// (gains, period, unit, the rig loop's settings). Immutable; what runs,
/// replays and launches the rig takes it.
#[pyclass(module = "sensaug._core", frozen)]
pub struct Config {
    pub resolved: Resolved,
}

#[pymethods]
impl Config {
    /// Resolves a configuration given as plain dicts and lists (the tables
    /// of a file); raises `ConfigError` naming the first bad field.
    #[new]
    fn new(tables: &Bound<'_, PyAny>) -> PyResult<Self> {
        let spec = sensaug_config::parse_from(&mut Depythonizer::from_object(tables))
            .map_err(config_err)?;
        let resolved = Resolved::new(spec).map_err(config_err)?;
        Ok(Config { resolved })
    }

    /// Reads and resolves a file (TOML, or JSON by extension); with
    /// `check_outputs` also a session plan's conditions and its rig output
    /// paths, as `sensaug-rt --check` (`sensaug_config::check_file`).
    #[staticmethod]
    #[pyo3(signature = (path, /, *, check_outputs))]
    fn from_file(path: PathBuf, check_outputs: bool) -> PyResult<Self> {
        let resolved = match check_outputs {
            true => sensaug_config::check_file(&path),
            false => sensaug_config::load_file(&path),
        };
        Ok(Config {
            resolved: resolved.map_err(config_err)?,
        })
    }

    /// Parses and resolves configuration text in `format` ("toml" or "json").
    #[staticmethod]
    #[pyo3(signature = (text, /, *, format))]
    fn from_text(text: &str, format: &str) -> PyResult<Self> {
        let format = match format {
            "toml" => Format::Toml,
            "json" => Format::Json,
            other => {
                let msg =
                    format!("{other:?} is not a configuration format; use \"toml\" or \"json\"");
                return Err(field_error::<ConfigError>("format", &msg));
            }
        };
        let resolved = sensaug_config::load_str(text, format).map_err(config_err)?;
        Ok(Config { resolved })
    }

    /// The file's values, every default filled in, as plain dicts and lists.
    fn to_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        pythonize(py, &self.resolved.spec).map_err(|e| PyValueError::new_err(e.to_string()))
    }

    /// The file's values as compact JSON.
    fn to_json(&self) -> String {
        sensaug_config::to_json(&self.resolved.spec)
    }

    /// The file's values as TOML with each field's description and unit.
    fn to_toml(&self) -> String {
        sensaug_config::to_toml(&self.resolved.spec)
    }

    /// What a log's metadata records of it: `{"config", "resolved", "loop"}`
    /// (the file's values, the derived values, the rig loop's settings).
    fn metadata<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        pythonize(py, &self.resolved).map_err(|e| PyValueError::new_err(e.to_string()))
    }

    /// `(ticks, log_bytes)` of its trial: the protocol's ticks and the bytes
    /// of its log kept in memory. With `memory_budget` (bytes), raises
    /// `TrialTooLargeError` when the log needs more, as `run_scenario` does.
    #[pyo3(signature = (*, memory_budget))]
    fn trial_memory(&self, memory_budget: Option<u64>) -> PyResult<(u64, u64)> {
        let phases = self.resolved.phases();
        let protocol = protocol(&self.resolved, &phases)?;
        let bytes = check_log_memory(&protocol, RECORD_BYTES, memory_budget.unwrap_or(u64::MAX))
            .map_err(too_large)?;
        Ok((protocol.total_ticks(), bytes))
    }

    /// Immutable: a copy is the same object.
    fn __copy__(slf: Py<Self>) -> Py<Self> {
        slf
    }

    fn __deepcopy__(slf: Py<Self>, _memo: &Bound<'_, PyAny>) -> Py<Self> {
        slf
    }

    /// Pickled as its tables (a process pool resolves it again).
    fn __reduce__<'py>(slf: &Bound<'py, Self>) -> PyResult<Bound<'py, PyTuple>> {
        let py = slf.py();
        let tables = slf.get().to_dict(py)?;
        PyTuple::new(
            py,
            [
                slf.get_type().into_any(),
                PyTuple::new(py, [tables])?.into_any(),
            ],
        )
    }
}

/// The core's protocol of a resolved configuration.
pub(crate) fn protocol<'a>(
    r: &Resolved,
    phases: &'a [sensaug_core::protocol::Phase<'a>],
) -> PyResult<Protocol<'a>> {
    Protocol::new(phases, r.dt_s).map_err(|_| rejected())
}

/// The core refused what the schema resolved: a bug, not the user's.
pub(crate) fn rejected() -> PyErr {
    field_error::<ConfigError>(
        "(config)",
        "the core rejected a resolved configuration; please report this",
    )
}

/// Configurations resolved on the calling thread (`sensaug_config::resolve_count`):
/// the tests' check that a trial resolves its configuration once.
#[pyfunction]
fn resolve_count() -> u64 {
    sensaug_config::resolve_count()
}

/// Checks output paths, `(field, path)` each, as the rig's own are checked
/// (`sensaug_config::outputs::check_outputs`): regular files or absent,
/// distinct. Raises `ConfigError` naming the field.
#[pyfunction]
fn check_output_paths(outputs: Vec<(String, PathBuf)>) -> PyResult<()> {
    let refs: Vec<(&str, &Path)> = outputs
        .iter()
        .map(|(f, p)| (f.as_str(), p.as_path()))
        .collect();
    sensaug_config::outputs::check_outputs(&refs).map_err(config_err)
}

/// The JSON Schema of a configuration file.
#[pyfunction]
fn config_schema() -> String {
    serde_json::to_string_pretty(sensaug_config::json_schema()).expect("a schema is JSON")
}

/// The memory (bytes) a simulated trial's log may take here: half of what
/// is available (`sensaug_core::world::log_budget`), or `None` (no check)
/// where that cannot be read.
#[pyfunction]
fn available_memory() -> Option<u64> {
    sensaug_log::available_bytes().map(log_budget)
}

/// Runs one trial of a resolved configuration. Returns `(records, summary,
/// meta)`: the log's rows as the bytes of packed records in the log
/// schema's column order (`records.view(sensaug.logs.DTYPE)` is the log),
/// the run's counters, and the log's metadata line as JSON text (built
/// here, from the configuration: `sensaug_log::metadata`).
///
/// Before it runs, the log's size is checked against `memory_budget` bytes
/// (`None`: [`available_memory`]); a trial that would not fit raises
/// `TrialTooLargeError` naming the fields that make it large.
#[pyfunction]
#[pyo3(signature = (config, /, *, memory_budget, git_commit))]
fn run_scenario<'py>(
    py: Python<'py>,
    config: &Config,
    memory_budget: Option<u64>,
    git_commit: Option<String>,
) -> PyResult<(Bound<'py, numpy::PyArray1<u8>>, Bound<'py, PyDict>, String)> {
    let resolved = &config.resolved;
    let phases = resolved.phases();
    let protocol = protocol(resolved, &phases)?;
    let budget = memory_budget.or_else(available_memory).unwrap_or(u64::MAX);
    let bytes = check_log_memory(&protocol, RECORD_BYTES, budget).map_err(too_large)?;
    let mut scenario = Scenario::new(&phases, resolved.robot, resolved.partner, resolved.world)
        .map_err(|_| rejected())?;
    // Each tick's log row is packed as the tick ends, straight into the
    // buffer numpy takes over without a copy: no buffer of the whole
    // trial's records in between. Reserved fallibly: where the budget is
    // unknown, or the system refuses, the trial still fails with a message.
    let mut records = Vec::new();
    usize::try_from(bytes)
        .ok()
        .and_then(|n| records.try_reserve_exact(n).ok())
        .ok_or_else(|| too_large(LogTooLarge::new(&protocol, RECORD_BYTES, None)))?;
    let meta = sensaug_log::metadata(&sensaug_log::RunInfo {
        source: sensaug_log::Source::Simulation,
        config: serde_json::to_value(&resolved.spec).unwrap_or_default(),
        resolved: resolved.derived(),
        git_commit,
        start_unix_s: sensaug_log::now_unix_s(),
        loop_settings: serde_json::Value::Null,
    });
    let summary = py.detach(|| scenario.run_with(|row| pack_record(row, &mut records)));
    let d = PyDict::new(py);
    d.set_item("ticks", summary.ticks)?;
    d.set_item("robot_clamped", summary.robot.clamped)?;
    d.set_item("robot_non_finite", summary.robot.non_finite)?;
    d.set_item("estimator_errors", summary.robot.estimator_errors)?;
    d.set_item("resymmetrised", summary.robot.resymmetrised)?;
    d.set_item("partner_guarded", summary.partner_guarded)?;
    d.set_item("mirror_errors", summary.mirror_errors)?;
    Ok((records.into_pyarray(py), d, meta.to_string()))
}
