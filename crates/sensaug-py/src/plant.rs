//! `sensaug._core.Plant`: the 1-DoF handle, steppable or run over a whole
//! torque sequence in one call.
use numpy::{IntoPyArray, PyArray1, PyReadonlyArray1};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use sensaug_core::plant::{Plant as CorePlant, PlantError, PlantParams, PlantState};

/// Two 1-D arrays returned together (positions, velocities).
type ArrayPair<'py> = (Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<f64>>);

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Plant>()
}

fn to_py_err(err: PlantError) -> PyErr {
    match err {
        PlantError::InvalidParam(field) => PyValueError::new_err(format!(
            "{field}: {}",
            match field {
                "mass" => "must be finite and > 0",
                "dt_s" => "must be finite and > 0",
                _ => "must be finite and >= 0",
            }
        )),
        PlantError::NonFiniteTorque => {
            PyValueError::new_err("torque: must be finite (NaN/inf rejected, state unchanged)")
        }
    }
}

/// The handle `M xdd + C xd = torque`, exact zero-order hold over `dt_s`.
#[pyclass(module = "sensaug._core")]
pub struct Plant {
    inner: CorePlant,
}

#[pymethods]
impl Plant {
    #[new]
    #[pyo3(signature = (*, mass, damping = 0.0, coulomb = 0.0, dt_s = 1e-3, x0 = 0.0, v0 = 0.0))]
    fn new(mass: f64, damping: f64, coulomb: f64, dt_s: f64, x0: f64, v0: f64) -> PyResult<Self> {
        let mut inner = CorePlant::new(PlantParams {
            mass,
            damping,
            coulomb,
            dt_s,
        })
        .map_err(to_py_err)?;
        if !(x0.is_finite() && v0.is_finite()) {
            return Err(PyValueError::new_err("x0, v0: must be finite"));
        }
        inner.set_state(PlantState { x: x0, v: v0 });
        Ok(Plant { inner })
    }

    /// Position.
    #[getter]
    fn x(&self) -> f64 {
        self.inner.state().x
    }

    /// Velocity.
    #[getter]
    fn v(&self) -> f64 {
        self.inner.state().v
    }

    /// One period with `torque` held; returns the new `(x, v)`.
    fn step(&mut self, torque: f64) -> PyResult<(f64, f64)> {
        let s = self.inner.step(torque).map_err(to_py_err)?;
        Ok((s.x, s.v))
    }

    /// Runs every torque in `torques`; returns the positions and velocities
    /// after each step.
    fn run<'py>(
        &mut self,
        py: Python<'py>,
        torques: PyReadonlyArray1<'py, f64>,
    ) -> PyResult<ArrayPair<'py>> {
        let torques = torques.as_slice()?;
        if let Some(k) = torques.iter().position(|t| !t.is_finite()) {
            return Err(PyValueError::new_err(format!(
                "torques[{k}]: must be finite; nothing was stepped"
            )));
        }
        let mut xs = Vec::with_capacity(torques.len());
        let mut vs = Vec::with_capacity(torques.len());
        for &t in torques {
            let s = self.inner.step(t).map_err(to_py_err)?;
            xs.push(s.x);
            vs.push(s.v);
        }
        Ok((xs.into_pyarray(py), vs.into_pyarray(py)))
    }
}
