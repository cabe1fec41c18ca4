//! `_core.replay_robot`: the robot's controller re-run offline over a
//! recorded trial (`sensaug_core::replay::replay_robot`). Conversion only.

use crate::convert::{py_err, slice};
use crate::scenario::{protocol, rejected, Config};
use numpy::PyReadonlyArray1;
use pyo3::prelude::*;
use pyo3::types::{IntoPyDict, PyDict};
use sensaug_core::controller::Robot;
use sensaug_core::replay::replay_recorded;
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
    let phases = resolved.phases();
    let mut robot =
        Robot::new(resolved.robot, protocol(resolved, &phases)?).map_err(|_| rejected())?;
    let mut rows = vec![Row::UNKNOWN; x.len()];
    let counters = py
        .detach(|| replay_recorded(&mut robot, resolved.dt_s, [x, v], fresh, applied, &mut rows))
        .map_err(py_err)?;
    let d = [("ticks", rows.len() as u64)]
        .into_iter()
        .chain(counters.named())
        .into_py_dict(py)?;
    Ok((crate::log::packed_records(py, &rows), d))
}
