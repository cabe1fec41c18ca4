//! The one log schema (`sensaug-log`) for Python: the column table, the
//! metadata of a simulated trial, rows <-> numpy columns, and the writer of
//! a log file. Conversion only; the format lives in `sensaug-log`.

use numpy::{IntoPyArray, PyReadonlyArray1};
use pyo3::exceptions::{PyOSError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use sensaug_config::outputs::{create_partial, partial_path, replace};
use sensaug_log::{Kind, PackedRow, Row, Value, COLUMNS};
use std::io::Write;
use std::path::{Path, PathBuf};
use zerocopy::IntoBytes;

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(log_schema, m)?)?;
    m.add_function(wrap_pyfunction!(git_commit, m)?)?;
    m.add_function(wrap_pyfunction!(write_log, m)?)?;
    m.add_function(wrap_pyfunction!(config_sha256, m)?)?;
    Ok(())
}

/// The schema: format line and version, `columns` as `(name, unit, kind,
/// description)` tuples, `sources` (who fills each column: time,
/// controller, world, rig), phase names, the unknown-integer sentinel, units.
#[pyfunction]
fn log_schema(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("format_line", sensaug_log::FORMAT_LINE)?;
    d.set_item("format_version", sensaug_log::FORMAT_VERSION)?;
    d.set_item("checksum_field", sensaug_log::CHECKSUM_FIELD)?;
    d.set_item("json_checksum_key", sensaug_log::JSON_CHECKSUM_KEY)?;
    let cols: Vec<(&str, &str, &str, &str)> = COLUMNS
        .iter()
        .map(|c| (c.name, c.unit, c.kind.name(), c.description))
        .collect();
    d.set_item("columns", cols)?;
    let sources = PyDict::new(py);
    for c in COLUMNS {
        sources.set_item(c.name, c.source.name())?;
    }
    d.set_item("sources", sources)?;
    d.set_item("phase_names", sensaug_log::PHASE_NAMES.to_vec())?;
    d.set_item("unknown_int", sensaug_log::UNKNOWN)?;
    d.set_item("units", sensaug_log::UNITS.to_vec())?;
    Ok(d)
}

/// The git commit of the checkout containing `dir` (`-dirty` if modified),
/// or `None`.
#[pyfunction]
fn git_commit(py: Python<'_>, dir: PathBuf) -> Option<String> {
    py.detach(|| sensaug_log::git_commit(&dir))
}

/// The configuration digest a log records (`meta["config_sha256"]`) of the
/// configuration given as JSON text.
#[pyfunction]
fn config_sha256(config_json: &str) -> PyResult<String> {
    let config = serde_json::from_str::<serde_json::Value>(config_json)
        .map_err(|e| PyValueError::new_err(format!("config_json: not valid JSON: {e}")))?;
    Ok(sensaug_log::config_sha256(&config))
}

/// Bytes of one packed record ([`PackedRow`]: the columns in schema order,
/// native-endian int64 / float64, bool as one byte; `sensaug.logs.DTYPE`).
pub const RECORD_BYTES: usize = std::mem::size_of::<PackedRow>();

/// Appends `row` to `out` as one packed record, for `ndarray.view(DTYPE)`:
/// records appended to one buffer are the log, with no per-column arrays to
/// re-interleave in Python.
pub fn pack_record(row: &Row, out: &mut Vec<u8>) {
    out.extend_from_slice(row.packed().as_bytes());
}

/// Rows as the bytes of packed records (every Rust -> numpy path of log
/// rows returns these; `sensaug.logs.from_records` views them).
pub fn packed_records<'py>(py: Python<'py>, rows: &[Row]) -> Bound<'py, numpy::PyArray1<u8>> {
    let mut out = Vec::with_capacity(rows.len() * RECORD_BYTES);
    for r in rows {
        pack_record(r, &mut out);
    }
    out.into_pyarray(py)
}

/// Rows from `data[name]` for every column (a numpy structured array or a
/// dict of 1-D arrays with the schema's dtypes).
fn columns_to_rows(data: &Bound<'_, PyAny>) -> PyResult<Vec<Row>> {
    // A field of a structured array is a strided, possibly unaligned view:
    // numpy copies it into an aligned contiguous array first.
    let contiguous = data.py().import("numpy")?.getattr("ascontiguousarray")?;
    let mut rows: Vec<Row> = Vec::new();
    for (j, c) in COLUMNS.iter().enumerate() {
        let col = data
            .get_item(c.name)
            .map_err(|_| PyValueError::new_err(format!("data.{}: missing column", c.name)))?;
        let col = contiguous.call1((col,))?;
        let wrong = |what: &str| {
            PyValueError::new_err(format!(
                "data.{}: expected a 1-D {what} array (column kind {})",
                c.name,
                c.kind.name()
            ))
        };
        let len = col.len().map_err(|_| wrong("numpy"))?;
        if j == 0 {
            rows = vec![Row::UNKNOWN; len];
        } else if len != rows.len() {
            return Err(PyValueError::new_err(format!(
                "data.{}: {len} values, but {} has {}",
                c.name,
                COLUMNS[0].name,
                rows.len()
            )));
        }
        let set = |rows: &mut [Row], k: usize, v: Value| {
            rows[k]
                .set(j, v)
                .map_err(|e| PyValueError::new_err(format!("data.{e} (row {k})")))
        };
        match c.kind {
            Kind::Int => {
                let a: PyReadonlyArray1<i64> = col.extract().map_err(|_| wrong("int64"))?;
                for (k, v) in a.as_array().iter().enumerate() {
                    set(&mut rows, k, Value::Int(*v))?;
                }
            }
            Kind::Float => {
                let a: PyReadonlyArray1<f64> = col.extract().map_err(|_| wrong("float64"))?;
                for (k, v) in a.as_array().iter().enumerate() {
                    set(&mut rows, k, Value::Float(*v))?;
                }
            }
            Kind::Bool => {
                let a: PyReadonlyArray1<bool> = col.extract().map_err(|_| wrong("bool"))?;
                for (k, v) in a.as_array().iter().enumerate() {
                    set(&mut rows, k, Value::Bool(*v))?;
                }
            }
        }
    }
    Ok(rows)
}

/// Writes the log to `<path>.partial`, then renames it over `path` (an
/// older regular file is replaced only by a complete log; nothing else is
/// ever opened or replaced: `sensaug_config::outputs`).
fn write_file(
    path: &Path,
    meta: &serde_json::Value,
    rows: &[Row],
    end: &serde_json::Value,
) -> std::io::Result<()> {
    let file = create_partial(path)?;
    let written = write_rows(file, meta, rows, end).and_then(|()| replace(path));
    if written.is_err() {
        let _ = std::fs::remove_file(partial_path(path));
    }
    written
}

fn write_rows(
    file: std::fs::File,
    meta: &serde_json::Value,
    rows: &[Row],
    end: &serde_json::Value,
) -> std::io::Result<()> {
    let mut out = std::io::BufWriter::new(file);
    let mut sum = sensaug_log::write_header(&mut out, meta)?;
    let mut line = Vec::with_capacity(1024);
    for r in rows {
        line.clear();
        sensaug_log::format_row(r, &mut sum, &mut line);
        out.write_all(&line)?;
    }
    if !end.is_null() {
        sensaug_log::write_footer(&mut out, end, &mut sum)?;
    }
    out.flush()
}

/// Writes a log file: the metadata line `meta_json`, one line per row of
/// `data` (every column of the schema, with its dtype), then the end-status
/// line `end_json` if given.
#[pyfunction]
#[pyo3(signature = (path, data, /, *, meta_json, end_json=None))]
fn write_log(
    py: Python<'_>,
    path: PathBuf,
    data: &Bound<'_, PyAny>,
    meta_json: &str,
    end_json: Option<&str>,
) -> PyResult<()> {
    let parse = |name: &str, text: &str| {
        serde_json::from_str::<serde_json::Value>(text)
            .map_err(|e| PyValueError::new_err(format!("{name}: not valid JSON: {e}")))
    };
    let meta = parse("meta_json", meta_json)?;
    let end = match end_json {
        Some(t) => parse("end_json", t)?,
        None => serde_json::Value::Null,
    };
    let rows = columns_to_rows(data)?;
    sensaug_config::outputs::check_outputs(&[("path", &path)])
        .map_err(crate::scenario::config_err)?;
    py.detach(|| write_file(&path, &meta, &rows, &end))
        .map_err(|e| PyOSError::new_err(format!("{}: cannot write the log: {e}", path.display())))
}
