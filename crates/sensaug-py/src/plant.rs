//! `sensaug._core.Plant`: the 1-DoF handle, steppable or run over a whole
//! torque sequence in one core call. Conversion only: every argument
//! required; `sensaug.Plant` adds the schema's defaults and the docs.
use crate::convert::{methods, py_err, slice};
use numpy::{IntoPyArray, PyArray1, PyReadonlyArray1};
use pyo3::prelude::*;
use sensaug_core::plant::{Plant as CorePlant, PlantParams, PlantState};
use sensaug_core::replay::simulate;

type ArrayPair<'py> = (Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<f64>>);

#[pyclass(module = "sensaug._core", subclass)]
pub struct Plant {
    inner: CorePlant,
}

methods!(Plant {
    #[new]
    #[pyo3(signature = (*, mass, damping, coulomb, dt_s, x0, v0))]
    fn new(mass: f64, damping: f64, coulomb: f64, dt_s: f64, x0: f64, v0: f64) -> PyResult<Self> {
        let params = PlantParams {
            mass,
            damping,
            coulomb,
            dt_s,
        };
        let inner = CorePlant::starting_at(params, PlantState { x: x0, v: v0 }).map_err(py_err)?;
        Ok(Plant { inner })
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
        let (mut xs, mut vs) = (vec![0.0; torques.len()], vec![0.0; torques.len()]);
        simulate(&mut self.inner, torques, &mut xs, &mut vs).map_err(py_err)?;
        Ok((xs.into_pyarray(py), vs.into_pyarray(py)))
    }
}
    x = |s, _py| s.state().x;
    v = |s, _py| s.state().v;
);
