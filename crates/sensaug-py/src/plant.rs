//! `sensaug._core.Plant`: the 1-DoF handle, steppable or run over a whole
//! torque sequence in one core call. Conversion only.
use crate::convert::{py_err, real, real_or, slice, Opt};
use numpy::{PyArray1, PyArrayMethods, PyReadonlyArray1};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use sensaug_config::{PlantSpec, WorldSpec};
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
    #[pyo3(signature = (*, mass, damping = None, coulomb = None, dt_s = None, x0 = None, v0 = None))]
    #[pyo3(text_signature = "(*, mass, damping=0.0, coulomb=0.0, dt_s=1e-3, x0=0.0, v0=0.0)")]
    fn new(
        mass: &Bound<'_, PyAny>,
        damping: Opt<'_, '_>,
        coulomb: Opt<'_, '_>,
        dt_s: Opt<'_, '_>,
        x0: Opt<'_, '_>,
        v0: Opt<'_, '_>,
    ) -> PyResult<Self> {
        // Defaults: the schema's `[plant]` and `[world]` ones.
        let (d, w) = (PlantSpec::default(), WorldSpec::default());
        let params = PlantParams {
            mass: real(mass, "mass")?,
            damping: real_or(damping, "damping", d.damping)?,
            coulomb: real_or(coulomb, "coulomb", d.coulomb)?,
            dt_s: real_or(dt_s, "dt_s", d.dt_s)?,
        };
        let mut inner = CorePlant::new(params).map_err(py_err)?;
        let state = PlantState {
            x: real_or(x0, "x0", w.x0)?,
            v: real_or(v0, "v0", w.v0)?,
        };
        for (value, name) in [(state.x, "x0"), (state.v, "v0")] {
            if !value.is_finite() {
                return Err(PyValueError::new_err(format!(
                    "{name}: must be finite (the initial state)"
                )));
            }
        }
        inner.set_state(state);
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
