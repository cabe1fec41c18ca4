//! `sensaug._core.Plant`: the 1-DoF handle, steppable or run over a whole
//! torque sequence in one core call. Conversion only.
use crate::convert::{py_err, slice};
use numpy::{PyArray1, PyArrayMethods, PyReadonlyArray1};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use sensaug_core::plant::{Plant as CorePlant, PlantParams, PlantState};
use sensaug_core::replay::simulate;

/// Positions and velocities after each step.
type ArrayPair<'py> = (Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<f64>>);

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Plant>()
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
        let params = PlantParams {
            mass,
            damping,
            coulomb,
            dt_s,
        };
        let mut inner = CorePlant::new(params).map_err(py_err)?;
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
        let s = self.inner.step(torque).map_err(py_err)?;
        Ok((s.x, s.v))
    }

    /// Every torque in `torques` in turn; the positions and velocities after each step.
    fn run<'py>(
        &mut self,
        py: Python<'py>,
        torques: PyReadonlyArray1<'py, f64>,
    ) -> PyResult<ArrayPair<'py>> {
        let torques = slice(&torques, "torques")?;
        let xs = PyArray1::zeros(py, torques.len(), false);
        let vs = PyArray1::zeros(py, torques.len(), false);
        {
            let (mut x, mut v) = (xs.readwrite(), vs.readwrite());
            simulate(
                &mut self.inner,
                torques,
                x.as_slice_mut()?,
                v.as_slice_mut()?,
            )
            .map_err(py_err)?;
        }
        Ok((xs, vs))
    }
}
