//! `_core.Config`, the resolved configuration as one Python object, and the
//! entry points that take it: a simulated trial and the memory it needs.
//! The schema (`sensaug-config`) reads, checks and resolves; the core runs
//! the whole trial in one call. Conversion only; the docs are in `_core.pyi`.

use crate::log::{pack_record, RECORD_BYTES};
use numpy::IntoPyArray;
use pyo3::create_exception;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::{IntoPyDict, PyDict, PyTuple};
use pythonize::{pythonize, Depythonizer};
use sensaug_config::Resolved;
use sensaug_core::protocol::Protocol;
use sensaug_core::world::{check_log_memory, log_budget, LogTooLarge, Scenario};
use std::path::{Path, PathBuf};

create_exception!(_core, ConfigError, PyValueError);
create_exception!(_core, TrialTooLargeError, ConfigError);

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
    m.add_function(wrap_pyfunction!(run_scenario, m)?)
}

/// `E` (`ConfigError` or a subclass) with `.field` and `.message` set.
fn field_error<E: pyo3::PyTypeInfo>(field: &str, message: &str) -> PyErr {
    Python::attach(|py| {
        let err = PyErr::new::<E, _>(format!("{field}: {message}"));
        let set = |(name, v)| err.value(py).setattr(name, v);
        match [("field", field), ("message", message)]
            .into_iter()
            .try_for_each(set)
        {
            Ok(()) => err,
            Err(e) => e,
        }
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

/// A configuration resolved once (`sensaug_config::Resolved`). Immutable.
#[pyclass(module = "sensaug._core", frozen)]
pub struct Config {
    pub resolved: Resolved,
}

#[pymethods]
impl Config {
    #[new]
    fn new(tables: &Bound<'_, PyAny>) -> PyResult<Self> {
        let spec = sensaug_config::parse_from(&mut Depythonizer::from_object(tables));
        let resolved = Resolved::new(spec.map_err(config_err)?).map_err(config_err)?;
        Ok(Config { resolved })
    }

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

    #[staticmethod]
    #[pyo3(signature = (text, /, *, format))]
    fn from_text(text: &str, format: &str) -> PyResult<Self> {
        let format = format.parse().map_err(config_err)?;
        let resolved = sensaug_config::load_str(text, format).map_err(config_err)?;
        Ok(Config { resolved })
    }

    fn to_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        Ok(pythonize(py, &self.resolved.spec)?)
    }

    fn to_json(&self) -> String {
        sensaug_config::to_json(&self.resolved.spec)
    }

    fn to_toml(&self) -> String {
        sensaug_config::to_toml(&self.resolved.spec)
    }

    fn metadata<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        Ok(pythonize(py, &self.resolved)?)
    }

    #[pyo3(signature = (*, memory_budget))]
    fn trial_memory(&self, memory_budget: Option<u64>) -> PyResult<(u64, u64)> {
        let phases = self.resolved.phases();
        let protocol = protocol(&self.resolved, &phases)?;
        let bytes = check_log_memory(&protocol, RECORD_BYTES, memory_budget.unwrap_or(u64::MAX));
        Ok((protocol.total_ticks(), bytes.map_err(too_large)?))
    }

    fn __copy__(slf: Py<Self>) -> Py<Self> {
        slf
    }

    fn __deepcopy__(slf: Py<Self>, _memo: &Bound<'_, PyAny>) -> Py<Self> {
        slf
    }

    /// Pickled as its tables (a process pool resolves it again).
    fn __reduce__<'py>(slf: &Bound<'py, Self>) -> PyResult<Bound<'py, PyTuple>> {
        let tables = slf.get().to_dict(slf.py())?;
        (slf.get_type(), (tables,)).into_pyobject(slf.py())
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
    let msg = "the core rejected a resolved configuration; please report this";
    field_error::<ConfigError>("(config)", msg)
}

#[pyfunction]
fn resolve_count() -> u64 {
    sensaug_config::resolve_count()
}

#[pyfunction]
fn check_output_paths(outputs: Vec<(String, PathBuf)>) -> PyResult<()> {
    let refs: Vec<(&str, &Path)> = outputs
        .iter()
        .map(|(f, p)| (f.as_str(), p.as_path()))
        .collect();
    sensaug_config::outputs::check_outputs(&refs).map_err(config_err)
}

#[pyfunction]
fn config_schema() -> String {
    serde_json::to_string_pretty(sensaug_config::json_schema()).expect("a schema is JSON")
}

#[pyfunction]
fn available_memory() -> Option<u64> {
    sensaug_log::available_bytes().map(log_budget)
}

/// One trial: `(records, summary, meta)`; each tick's row is packed as the
/// tick ends into the buffer numpy takes over (no buffer of rows between).
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
    // Reserved fallibly: where the budget is unknown, or the system
    // refuses, the trial still fails with a message.
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
    let summary = summary.named().into_py_dict(py)?;
    Ok((records.into_pyarray(py), summary, meta.to_string()))
}
