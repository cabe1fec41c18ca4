//! `_core.replay_robot`: the robot's controller re-run offline over a
//! recorded trial (`sensaug_core::replay::replay_robot`). Conversion only:
//! the resolved configuration (`_core.Config`) and the recorded measurement columns in, the
//! controller's columns of the log schema out.

use crate::convert::slice;
use crate::scenario::{protocol, rejected, Config};
use numpy::PyReadonlyArray1;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use sensaug_core::controller::Robot;
use sensaug_log::Row;

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(replay_robot, m)?)
}

/// Re-runs the robot's controller over recorded measurements: tick `k`
/// fuses `(x_meas[k], xdot_meas[k])` when `fresh[k]`, else only predicts.
/// Returns `(records, counters)`: the rows as packed records
/// (`sensaug.logs.from_records`; the controller's columns, `tick`, `t`,
/// `x_meas`, `xdot_meas`, `fresh` filled, the rest unknown) and the robot's
/// counters.
#[pyfunction]
#[pyo3(signature = (config, x_meas, xdot_meas, fresh, /, torque_step=None))]
fn replay_robot<'py>(
    py: Python<'py>,
    config: &Config,
    x_meas: PyReadonlyArray1<'py, f64>,
    xdot_meas: PyReadonlyArray1<'py, f64>,
    fresh: PyReadonlyArray1<'py, bool>,
    torque_step: Option<f64>,
) -> PyResult<(Bound<'py, numpy::PyArray1<u8>>, Bound<'py, PyDict>)> {
    let resolved = &config.resolved;
    let (x, v) = (slice(&x_meas, "x_meas")?, slice(&xdot_meas, "xdot_meas")?);
    let fresh = fresh.as_slice().map_err(|_| {
        PyValueError::new_err("fresh: must be C-contiguous (use np.ascontiguousarray)")
    })?;
    for (name, len) in [("xdot_meas", v.len()), ("fresh", fresh.len())] {
        if len != x.len() {
            return Err(PyValueError::new_err(format!(
                "{name}: {len} values, but x_meas has {}; pass one value per tick",
                x.len()
            )));
        }
    }
    let phases = resolved.phases();
    let mut robot =
        Robot::new(resolved.robot, protocol(resolved, &phases)?).map_err(|_| rejected())?;
    robot.set_torque_step(torque_step);
    let measurements: Vec<Option<(f64, f64)>> = (0..x.len())
        .map(|k| fresh[k].then_some((x[k], v[k])))
        .collect();
    let dt = resolved.dt_s;
    let mut rows: Vec<Row> = (0..x.len())
        .map(|k| Row {
            tick: k as i64,
            t: k as f64 * dt,
            x_meas: x[k],
            xdot_meas: v[k],
            fresh: fresh[k],
            ..Row::UNKNOWN
        })
        .collect();
    let counters = py
        .detach(|| sensaug_core::replay::replay_robot(&mut robot, &measurements, &mut rows))
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
    let d = PyDict::new(py);
    d.set_item("ticks", rows.len())?;
    d.set_item("robot_clamped", counters.clamped)?;
    d.set_item("robot_non_finite", counters.non_finite)?;
    d.set_item("estimator_errors", counters.estimator_errors)?;
    d.set_item("resymmetrised", counters.resymmetrised)?;
    d.set_item("missing_measurements", counters.missing_measurements)?;
    Ok((crate::log::packed_records(py, &rows), d))
}
