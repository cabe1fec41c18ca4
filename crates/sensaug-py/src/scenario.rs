//! `_core.Config`, the resolved configuration as one Python object, and the
//! entry points that take it: a simulated trial and the memory it needs,
//! and the robot's controller re-run offline over a recorded trial. The
//! schema (`sensaug-config`) reads, checks, resolves and runs the whole
//! trial in one call. Conversion only; the docs are in `_core.pyi`.

use crate::convert::{config_err, rows, trial_err};
use numpy::{IntoPyArray, PyArray1, PyReadonlyArray1};
use pyo3::prelude::*;
use pyo3::types::{IntoPyDict, PyDict, PyTuple};
use pythonize::{pythonize, Depythonizer};
use sensaug_config::Resolved;
use std::path::PathBuf;

/// Log rows as the bytes of packed records (`sensaug_log::push_record`).
type Records<'py> = Bound<'py, PyArray1<u8>>;

/// A configuration resolved once (`sensaug_config::Resolved`). Immutable.
#[pyclass(module = "sensaug._core", frozen)]
pub struct Config {
    pub resolved: Resolved,
}

/// A configuration that resolved, or its `ConfigError`.
fn config(resolved: Result<Resolved, sensaug_config::ConfigError>) -> PyResult<Config> {
    resolved
        .map(|resolved| Config { resolved })
        .map_err(config_err)
}

#[pymethods]
impl Config {
    #[new]
    fn new(tables: &Bound<'_, PyAny>) -> PyResult<Self> {
        let spec = sensaug_config::parse_from(&mut Depythonizer::from_object(tables));
        config(spec.and_then(Resolved::new))
    }

    #[staticmethod]
    #[pyo3(signature = (path, /, *, check_outputs))]
    fn from_file(path: PathBuf, check_outputs: bool) -> PyResult<Self> {
        match check_outputs {
            true => config(sensaug_config::check_file(&path)),
            false => config(sensaug_config::load_file(&path)),
        }
    }

    #[staticmethod]
    #[pyo3(signature = (text, /, *, format))]
    fn from_text(text: &str, format: &str) -> PyResult<Self> {
        let resolved = format
            .parse()
            .and_then(|f| sensaug_config::load_str(text, f));
        config(resolved)
    }

    fn to_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        Ok(pythonize(py, &self.resolved.spec)?)
    }

    #[pyo3(signature = (*, format))]
    fn to_text(&self, format: &str) -> PyResult<String> {
        let format = format.parse().map_err(config_err)?;
        Ok(sensaug_config::to_text(&self.resolved.spec, format))
    }

    fn metadata<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        Ok(pythonize(py, &self.resolved)?)
    }

    #[pyo3(signature = (*, memory_budget))]
    fn trial_memory(&self, memory_budget: Option<u64>) -> PyResult<(u64, u64)> {
        self.resolved.trial_memory(memory_budget).map_err(trial_err)
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

#[pyfunction]
pub fn resolve_count() -> u64 {
    sensaug_config::resolve_count()
}

#[pyfunction]
pub fn check_output_paths(outputs: Vec<(String, PathBuf)>) -> PyResult<()> {
    sensaug_config::outputs::check_outputs(&outputs).map_err(config_err)
}

#[pyfunction]
pub fn config_schema() -> String {
    serde_json::to_string_pretty(sensaug_config::json_schema()).expect("a schema is JSON")
}

#[pyfunction]
pub fn available_memory() -> Option<u64> {
    sensaug_config::trial_memory_budget()
}

/// One trial (`Resolved::simulate`): `(records, summary, meta)`.
#[pyfunction]
#[pyo3(signature = (config, /, *, memory_budget, git_commit))]
pub fn run_scenario<'py>(
    py: Python<'py>,
    config: &Config,
    memory_budget: Option<u64>,
    git_commit: Option<String>,
) -> PyResult<(Records<'py>, Bound<'py, PyDict>, Bound<'py, PyAny>)> {
    let trial = py.detach(|| config.resolved.simulate(memory_budget, git_commit));
    let trial = trial.map_err(trial_err)?;
    let summary = trial.summary.named().into_py_dict(py)?;
    Ok((
        trial.records.into_pyarray(py),
        summary,
        pythonize(py, &trial.meta)?,
    ))
}

/// The robot's controller re-run over a recorded trial's rows
/// (`Resolved::replay`): `(records, counters)`.
#[pyfunction]
#[pyo3(signature = (config, records, /, *, applied_u))]
pub fn replay_robot<'py>(
    py: Python<'py>,
    config: &Config,
    records: PyReadonlyArray1<'py, u8>,
    applied_u: bool,
) -> PyResult<(Records<'py>, Bound<'py, PyDict>)> {
    let recorded = rows(&records)?;
    let replayed = py.detach(|| config.resolved.replay(&recorded, applied_u));
    let (out, counters) = replayed.map_err(|e| config_err(e.into()))?;
    let ticks = [("ticks", out.len() as u64)].into_iter();
    let counters = ticks.chain(counters.named()).into_py_dict(py)?;
    Ok((
        sensaug_log::records_from_rows(&out).into_pyarray(py),
        counters,
    ))
}
