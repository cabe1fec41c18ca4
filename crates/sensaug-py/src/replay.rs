//! `_core.replay_robot`: the robot's controller re-run offline over a
//! recorded trial (`sensaug_core::replay::replay_robot`). Conversion only.

use crate::convert::slice;
use crate::scenario::{protocol, rejected, Config};
use numpy::PyReadonlyArray1;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::{IntoPyDict, PyDict};
use sensaug_core::controller::Robot;
use sensaug_log::Row;

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(replay_robot, m)?)
}

#[pyfunction]
#[pyo3(signature = (config, x_meas, xdot_meas, fresh, /, applied_u=None))]
fn replay_robot<'py>(
    py: Python<'py>,
    config: &Config,
    x_meas: PyReadonlyArray1<'py, f64>,
    xdot_meas: PyReadonlyArray1<'py, f64>,
    fresh: PyReadonlyArray1<'py, bool>,
    applied_u: Option<PyReadonlyArray1<'py, f64>>,
) -> PyResult<(Bound<'py, numpy::PyArray1<u8>>, Bound<'py, PyDict>)> {
    let resolved = &config.resolved;
    let (x, v) = (slice(&x_meas, "x_meas")?, slice(&xdot_meas, "xdot_meas")?);
    let fresh = slice(&fresh, "fresh")?;
    let applied = applied_u
        .as_ref()
        .map(|a| slice(a, "applied_u"))
        .transpose()?;
    let lengths = [("xdot_meas", v.len()), ("fresh", fresh.len())];
    for (name, len) in lengths
        .into_iter()
        .chain(applied.map(|a| ("applied_u", a.len())))
    {
        if len != x.len() {
            let msg = format!(
                "{name}: {len} values, but x_meas has {}; pass one value per tick",
                x.len()
            );
            return Err(PyValueError::new_err(msg));
        }
    }
    let phases = resolved.phases();
    let mut robot =
        Robot::new(resolved.robot, protocol(resolved, &phases)?).map_err(|_| rejected())?;
    let measurements: Vec<_> = (0..x.len())
        .map(|k| fresh[k].then_some((x[k], v[k])))
        .collect();
    let mut rows: Vec<Row> = (0..x.len())
        .map(|k| Row {
            tick: k as i64,
            t: k as f64 * resolved.dt_s,
            x_meas: x[k],
            xdot_meas: v[k],
            fresh: fresh[k],
            ..Row::UNKNOWN
        })
        .collect();
    let counters = py
        .detach(|| {
            sensaug_core::replay::replay_robot(&mut robot, &measurements, applied, &mut rows)
        })
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
    let d = [("ticks", rows.len() as u64)]
        .into_iter()
        .chain(counters.named())
        .into_py_dict(py)?;
    Ok((crate::log::packed_records(py, &rows), d))
}
