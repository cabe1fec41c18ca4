//! The one log schema (`sensaug-log`) for Python: the schema, rows <->
//! numpy, and the writer of a log file. Conversion only.

use crate::scenario::config_err;
use numpy::{IntoPyArray, PyReadonlyArray1};
use pyo3::exceptions::{PyOSError, PyValueError};
use pyo3::prelude::*;
use pythonize::pythonize;
use sensaug_config::outputs::{check_outputs, write_replacing};
use sensaug_log::{PackedRow, Row};
use std::path::PathBuf;
use zerocopy::IntoBytes;

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(log_schema, m)?)?;
    m.add_function(wrap_pyfunction!(git_commit, m)?)?;
    m.add_function(wrap_pyfunction!(write_log, m)?)?;
    m.add_function(wrap_pyfunction!(config_sha256, m)?)
}

#[pyfunction]
fn log_schema(py: Python<'_>) -> PyResult<Bound<'_, PyAny>> {
    Ok(pythonize(py, &sensaug_log::schema())?)
}

#[pyfunction]
fn git_commit(py: Python<'_>, dir: PathBuf) -> Option<String> {
    py.detach(|| sensaug_log::git_commit(&dir))
}

fn json(name: &str, text: &str) -> PyResult<serde_json::Value> {
    serde_json::from_str(text)
        .map_err(|e| PyValueError::new_err(format!("{name}: not valid JSON: {e}")))
}

#[pyfunction]
fn config_sha256(config_json: &str) -> PyResult<String> {
    Ok(sensaug_log::config_sha256(&json(
        "config_json",
        config_json,
    )?))
}

/// Bytes of one packed record ([`PackedRow`]: the columns in schema order,
/// native-endian int64 / float64, bool as one byte; `sensaug.logs.DTYPE`).
pub const RECORD_BYTES: usize = std::mem::size_of::<PackedRow>();

/// Appends `row` to `out` as one packed record (`ndarray.view(DTYPE)`).
pub fn pack_record(row: &Row, out: &mut Vec<u8>) {
    out.extend_from_slice(row.packed().as_bytes());
}

/// Rows as the bytes of packed records (every Rust -> numpy path of log
/// rows returns these; `sensaug.logs.from_records` views them).
pub fn packed_records<'py>(py: Python<'py>, rows: &[Row]) -> Bound<'py, numpy::PyArray1<u8>> {
    let mut out = Vec::with_capacity(rows.len() * RECORD_BYTES);
    rows.iter().for_each(|r| pack_record(r, &mut out));
    out.into_pyarray(py)
}

#[pyfunction]
#[pyo3(signature = (path, records, /, *, meta_json, end_json))]
fn write_log(
    py: Python<'_>,
    path: PathBuf,
    records: PyReadonlyArray1<'_, u8>,
    meta_json: &str,
    end_json: Option<&str>,
) -> PyResult<()> {
    let meta = json("meta_json", meta_json)?;
    let end = end_json.map_or(Ok(serde_json::Value::Null), |t| json("end_json", t))?;
    let rows = sensaug_log::rows_from_records(crate::convert::slice(&records, "records")?)
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
    check_outputs(&[("path", &path)]).map_err(config_err)?;
    let write = |out: &mut _| sensaug_log::write_log(out, &meta, &rows, &end);
    py.detach(|| write_replacing(&path, write))
        .map_err(|e| PyOSError::new_err(format!("{}: cannot write the log: {e}", path.display())))
}
