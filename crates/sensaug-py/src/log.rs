//! The one log schema (`sensaug-log`) for Python: the schema, rows <->
//! numpy, and the writer of a log file. Conversion only.

use crate::scenario::config_err;
use numpy::{Element, IntoPyArray, PyReadonlyArray1};
use pyo3::exceptions::{PyOSError, PyValueError};
use pyo3::prelude::*;
use pythonize::pythonize;
use sensaug_config::outputs::{check_outputs, create_partial, partial_path, replace};
use sensaug_log::{Kind, PackedRow, Row, Value, COLUMNS};
use std::path::{Path, PathBuf};
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

/// A 1-D array of `T` as values, or `None` if `col` is not one.
fn values<T: Element + Copy>(col: &Bound<'_, PyAny>, value: fn(T) -> Value) -> Option<Vec<Value>> {
    let a: PyReadonlyArray1<T> = col.extract().ok()?;
    Some(a.as_array().iter().map(|v| value(*v)).collect())
}

/// Rows from `data[name]` for every column (a numpy structured array or a
/// dict of 1-D arrays with the schema's dtypes).
fn columns_to_rows(data: &Bound<'_, PyAny>) -> PyResult<Vec<Row>> {
    // A field of a structured array is a strided, possibly unaligned view:
    // numpy copies it into an aligned contiguous array first.
    let contiguous = data.py().import("numpy")?.getattr("ascontiguousarray")?;
    let mut rows: Vec<Row> = Vec::new();
    for (j, c) in COLUMNS.iter().enumerate() {
        let err = |msg: String| PyValueError::new_err(format!("data.{}: {msg}", c.name));
        let col = data
            .get_item(c.name)
            .map_err(|_| err("missing column".into()))?;
        let col = contiguous.call1((col,))?;
        let (values, dtype) = match c.kind {
            Kind::Int => (values(&col, Value::Int), "int64"),
            Kind::Float => (values(&col, Value::Float), "float64"),
            Kind::Bool => (values(&col, Value::Bool), "bool"),
        };
        let kind = c.kind.name();
        let values = values
            .ok_or_else(|| err(format!("expected a 1-D {dtype} array (column kind {kind})")))?;
        if j == 0 {
            rows = vec![Row::UNKNOWN; values.len()];
        } else if values.len() != rows.len() {
            let (n, first) = (rows.len(), COLUMNS[0].name);
            return Err(err(format!("{} values, but {first} has {n}", values.len())));
        }
        for (k, (row, v)) in rows.iter_mut().zip(values).enumerate() {
            row.set(j, v)
                .map_err(|e| PyValueError::new_err(format!("data.{e} (row {k})")))?;
        }
    }
    Ok(rows)
}

/// Writes to `<path>.partial`, then renames it over `path` (an older
/// regular file is replaced only by a complete log: `sensaug_config::outputs`).
fn write_file(
    path: &Path,
    meta: &serde_json::Value,
    rows: &[Row],
    end: &serde_json::Value,
) -> std::io::Result<()> {
    let mut out = std::io::BufWriter::new(create_partial(path)?);
    let written = sensaug_log::write_log(&mut out, meta, rows, end);
    drop(out);
    let written = written.and_then(|()| replace(path));
    if written.is_err() {
        let _ = std::fs::remove_file(partial_path(path));
    }
    written
}

#[pyfunction]
#[pyo3(signature = (path, data, /, *, meta_json, end_json=None))]
fn write_log(
    py: Python<'_>,
    path: PathBuf,
    data: &Bound<'_, PyAny>,
    meta_json: &str,
    end_json: Option<&str>,
) -> PyResult<()> {
    let meta = json("meta_json", meta_json)?;
    let end = end_json.map_or(Ok(serde_json::Value::Null), |t| json("end_json", t))?;
    let rows = columns_to_rows(data)?;
    check_outputs(&[("path", &path)]).map_err(config_err)?;
    py.detach(|| write_file(&path, &meta, &rows, &end))
        .map_err(|e| PyOSError::new_err(format!("{}: cannot write the log: {e}", path.display())))
}
