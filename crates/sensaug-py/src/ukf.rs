//! Binding for the UKF demo model: conversion only. `DemoUkf.run` crosses
//! into Rust once per trial; `predict` / `update` step for replaying data.
#![allow(non_snake_case)]

use crate::convert::{
    mat_from, mat_to, phase_name, recoveries_dict, status_str, to_py, vec_from, vec_to,
    UkfStepError,
};
use nalgebra::SVector;
use numpy::{
    PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods,
};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use sensaug_core::demo_model::{DemoUkf as CoreUkf, Pendulum, M, N};
use sensaug_core::ukf::{MerweParams, UkfError};

/// `(xs, Pdiag)` returned by `DemoUkf.run`.
type Trajectory<'py> = (Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<f64>>);

/// UKF on the built-in pendulum demo model (N = 3, M = 2).
#[pyclass(module = "sensaug._core")]
pub struct DemoUkf {
    ukf: CoreUkf,
    model: Pendulum,
}

#[pymethods]
impl DemoUkf {
    #[new]
    #[pyo3(signature = (*, x0, P0, Q, R, alpha, beta, kappa, dt_s=1e-3, length_m=0.5, mass_kg=1.0, damping_nms=0.1, gravity_mps2=9.81))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        x0: PyReadonlyArray1<'_, f64>,
        P0: PyReadonlyArray2<'_, f64>,
        Q: PyReadonlyArray2<'_, f64>,
        R: PyReadonlyArray2<'_, f64>,
        alpha: f64,
        beta: f64,
        kappa: f64,
        dt_s: f64,
        length_m: f64,
        mass_kg: f64,
        damping_nms: f64,
        gravity_mps2: f64,
    ) -> PyResult<Self> {
        let model = Pendulum {
            dt_s,
            length_m,
            mass_kg,
            damping_nms,
            gravity_mps2,
        };
        let ukf = model
            .ukf(
                vec_from::<N>(&x0, "x0")?,
                mat_from::<N, N>(&P0, "P0")?,
                mat_from::<N, N>(&Q, "Q")?,
                mat_from::<M, M>(&R, "R")?,
                MerweParams { alpha, beta, kappa },
            )
            .map_err(|e| match e {
                // The constructor's P is called P0 here.
                UkfError::NotPositiveDefinite {
                    which: sensaug_core::ukf::Arg::P,
                } => PyValueError::new_err("P0: must be symmetric positive definite"),
                UkfError::NonFiniteArgument {
                    which: sensaug_core::ukf::Arg::P,
                } => PyValueError::new_err("P0: must be finite (no NaN or inf)"),
                UkfError::NonFiniteArgument {
                    which: sensaug_core::ukf::Arg::X,
                } => PyValueError::new_err("x0: must be finite (no NaN or inf)"),
                other => to_py(other),
            })?;
        Ok(Self { ukf, model })
    }

    /// Predict one step with torque `u` (N m); optional per-call `Q`.
    #[pyo3(signature = (u, *, Q=None))]
    fn predict(&mut self, u: f64, Q: Option<PyReadonlyArray2<'_, f64>>) -> PyResult<String> {
        let model = self.model;
        let f = |x: &SVector<f64, N>| model.f(x, u);
        let r = match Q {
            Some(q) => self.ukf.predict_with_q(&mat_from::<N, N>(&q, "Q")?, f),
            None => self.ukf.predict(f),
        };
        r.map(status_str).map_err(to_py)
    }

    /// Update with measurement `z` (shape (2,)); optional per-call `R`.
    #[pyo3(signature = (z, *, R=None))]
    fn update(
        &mut self,
        z: PyReadonlyArray1<'_, f64>,
        R: Option<PyReadonlyArray2<'_, f64>>,
    ) -> PyResult<String> {
        let model = self.model;
        let z = vec_from::<M>(&z, "z")?;
        let h = |x: &SVector<f64, N>| model.h(x);
        let r = match R {
            Some(r) => self.ukf.update_with_r(&z, &mat_from::<M, M>(&r, "R")?, h),
            None => self.ukf.update(&z, h),
        };
        r.map(status_str).map_err(to_py)
    }

    /// Whole trial in Rust: predict(u[k]) then update(z[k]) for every k.
    /// Returns `(xs (T, 3), Pdiag (T, 3))`. With `strict`, any step error
    /// raises `UkfStepError` after the run (the filter has handled it).
    #[pyo3(signature = (u, z, *, strict=true))]
    fn run<'py>(
        &mut self,
        py: Python<'py>,
        u: PyReadonlyArray1<'py, f64>,
        z: PyReadonlyArray2<'py, f64>,
        strict: bool,
    ) -> PyResult<Trajectory<'py>> {
        let T = u.len();
        if z.shape() != [T, M] {
            return Err(PyValueError::new_err(format!(
                "z: expected shape ({T}, {M}) to match u of length {T}, got {:?}",
                z.shape()
            )));
        }
        let u_s = u.as_slice().map_err(|_| {
            PyValueError::new_err("u: must be C-contiguous (use np.ascontiguousarray)")
        })?;
        let z_s = z.as_slice().map_err(|_| {
            PyValueError::new_err("z: must be C-contiguous (use np.ascontiguousarray)")
        })?;
        let xs = PyArray2::<f64>::zeros(py, [T, N], false);
        let pd = PyArray2::<f64>::zeros(py, [T, N], false);
        let report = {
            let mut xs_rw = xs.readwrite();
            let mut pd_rw = pd.readwrite();
            let xs_s = xs_rw
                .as_slice_mut()
                .map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
            let pd_s = pd_rw
                .as_slice_mut()
                .map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
            self.model
                .run(&mut self.ukf, u_s, z_s, xs_s, pd_s)
                .map_err(to_py)?
        };
        if strict {
            if let Some(first) = report.first_error {
                let inner = to_py(first.error);
                return Err(UkfStepError::new_err(format!(
                    "{} step error(s); first at step {} ({}): {}",
                    report.errors,
                    first.step,
                    phase_name(first.phase),
                    inner.value(py)
                )));
            }
        }
        Ok((xs, pd))
    }

    /// Replace x and P (validated).
    #[pyo3(signature = (x, P))]
    fn reset(
        &mut self,
        x: PyReadonlyArray1<'_, f64>,
        P: PyReadonlyArray2<'_, f64>,
    ) -> PyResult<()> {
        self.ukf
            .reset(vec_from::<N>(&x, "x")?, mat_from::<N, N>(&P, "P")?)
            .map_err(to_py)
    }

    #[getter]
    fn x<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec_to(py, self.ukf.x())
    }
    #[getter]
    fn P<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        mat_to(py, self.ukf.P())
    }
    #[getter]
    fn x_prior<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec_to(py, self.ukf.x_prior())
    }
    #[getter]
    fn P_prior<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        mat_to(py, self.ukf.P_prior())
    }
    #[getter]
    fn x_post<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec_to(py, self.ukf.x_post())
    }
    #[getter]
    fn P_post<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        mat_to(py, self.ukf.P_post())
    }
    #[getter]
    fn Q<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        mat_to(py, self.ukf.Q())
    }
    #[setter(Q)]
    fn set_Q(&mut self, Q: PyReadonlyArray2<'_, f64>) -> PyResult<()> {
        self.ukf.set_Q(mat_from::<N, N>(&Q, "Q")?).map_err(to_py)
    }
    #[getter]
    fn R<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        mat_to(py, self.ukf.R())
    }
    #[setter(R)]
    fn set_R(&mut self, R: PyReadonlyArray2<'_, f64>) -> PyResult<()> {
        self.ukf.set_R(mat_from::<M, M>(&R, "R")?).map_err(to_py)
    }
    #[getter]
    fn P_reset<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        mat_to(py, self.ukf.reset_covariance())
    }
    #[setter(P_reset)]
    fn set_P_reset(&mut self, P: PyReadonlyArray2<'_, f64>) -> PyResult<()> {
        self.ukf
            .set_reset_covariance(mat_from::<N, N>(&P, "P_reset")?)
            .map_err(to_py)
    }
    #[getter]
    fn y<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec_to(py, self.ukf.y())
    }
    #[getter]
    fn S<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        mat_to(py, self.ukf.S())
    }
    #[getter]
    fn K<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        mat_to(py, self.ukf.K())
    }
    #[getter]
    fn Wm<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec_to(py, self.ukf.Wm())
    }
    #[getter]
    fn Wc<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec_to(py, self.ukf.Wc())
    }
    /// Counters: resymmetrised, covariance_resets, rejected, predicts, updates.
    fn recoveries<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        recoveries_dict(py, &self.ukf.recoveries())
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<DemoUkf>()?;
    m.add("UkfStepError", m.py().get_type::<UkfStepError>())?;
    Ok(())
}
