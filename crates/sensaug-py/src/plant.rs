//! `sensaug._core.Plant`: the 1-DoF handle, steppable or run over a whole
//! torque sequence in one core call. Conversion only.
use crate::convert::{py_err, real, settings, slice};
use numpy::{PyArray1, PyArrayMethods, PyReadonlyArray1};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use sensaug_config::{PlantSpec, WorldSpec};
use sensaug_core::plant::{Plant as CorePlant, PlantParams, PlantState};
use sensaug_core::replay::simulate;

type ArrayPair<'py> = (Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<f64>>);

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Plant>()
}

#[pyclass(module = "sensaug._core")]
pub struct Plant {
    inner: CorePlant,
}

#[pymethods]
impl Plant {
    #[new]
    #[pyo3(signature = (*, mass, **kw))]
    #[pyo3(text_signature = "(*, mass, damping=0.0, coulomb=0.0, dt_s=1e-3, x0=0.0, v0=0.0)")]
    fn new(mass: &Bound<'_, PyAny>, kw: Option<&Bound<'_, PyDict>>) -> PyResult<Self> {
        // Defaults: the schema's `[plant]` and `[world]` ones.
        let (d, w) = (PlantSpec::default(), WorldSpec::default());
        let mass = real(mass, "mass")?;
        let names = ["damping", "coulomb", "dt_s", "x0", "v0"];
        let defaults = [d.damping, d.coulomb, d.dt_s, w.x0, w.v0];
        let [damping, coulomb, dt_s, x, v] = settings(kw, names, defaults)?;
        let params = PlantParams {
            mass,
            damping,
            coulomb,
            dt_s,
        };
        let inner = CorePlant::starting_at(params, PlantState { x, v }).map_err(py_err)?;
        Ok(Plant { inner })
    }

    #[getter]
    fn x(&self) -> f64 {
        self.inner.state().x
    }

    #[getter]
    fn v(&self) -> f64 {
        self.inner.state().v
    }

    fn step(&mut self, torque: f64) -> PyResult<(f64, f64)> {
        let s = self.inner.step(torque).map_err(py_err)?;
        Ok((s.x, s.v))
    }

    fn run<'py>(
        &mut self,
        py: Python<'py>,
        torques: PyReadonlyArray1<'py, f64>,
    ) -> PyResult<ArrayPair<'py>> {
        let torques = slice(&torques, "torques")?;
        let (xs, vs) = (
            PyArray1::zeros(py, torques.len(), false),
            PyArray1::zeros(py, torques.len(), false),
        );
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
