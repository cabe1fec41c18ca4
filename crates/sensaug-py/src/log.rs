//! The one log schema (`sensaug-log`) for Python: the schema, and the
//! writer of a log file from packed records. Conversion only.

use crate::convert::config_err;
use numpy::PyReadonlyArray1;
use pyo3::exceptions::{PyOSError, PyValueError};
use pyo3::prelude::*;
use pythonize::pythonize;
use sensaug_config::outputs::{check_outputs, write_replacing};
use std::path::PathBuf;

#[pyfunction]
pub fn log_schema(py: Python<'_>) -> PyResult<Bound<'_, PyAny>> {
    Ok(pythonize(py, &sensaug_log::schema())?)
}

#[pyfunction]
pub fn git_commit(py: Python<'_>, dir: PathBuf) -> Option<String> {
    py.detach(|| sensaug_log::git_commit(&dir))
}

/// The metadata comes as JSON text, not dicts: `sensaug.logs.to_json`
/// writes numpy values as numbers and refuses NaN, in one place (a dict
/// taken as it is would turn NaN into null and refuse numpy integers).
fn json(name: &str, text: &str) -> PyResult<serde_json::Value> {
    serde_json::from_str(text)
        .map_err(|e| PyValueError::new_err(format!("{name}: not valid JSON: {e}")))
}

#[pyfunction]
pub fn config_sha256(config_json: &str) -> PyResult<String> {
    let config = json("config_json", config_json)?;
    Ok(sensaug_log::config_sha256(&config))
}

#[pyfunction]
#[pyo3(signature = (path, records, /, *, meta_json, end_json))]
pub fn write_log(
    py: Python<'_>,
    path: PathBuf,
    records: PyReadonlyArray1<'_, u8>,
    meta_json: &str,
    end_json: Option<&str>,
) -> PyResult<()> {
    let meta = json("meta_json", meta_json)?;
    let end = end_json.map_or(Ok(serde_json::Value::Null), |t| json("end_json", t))?;
    let rows = crate::convert::rows(&records)?;
    check_outputs(&[("path", &path)]).map_err(config_err)?;
    let write = |out: &mut _| sensaug_log::write_log(out, &meta, &rows, &end);
    py.detach(|| write_replacing(&path, write))
        .map_err(|e| PyOSError::new_err(format!("{}: cannot write the log: {e}", path.display())))
}
