//! Test only: the generic UKF on the pendulum model of
//! `crates/sensaug-core/tests/common/pendulum.rs`, as the Python module
//! `_ukf_oracle` that `tests/test_ukf.py` builds and checks against filterpy.
//! Not part of the shipped binding; it reuses the binding's conversions.
#![allow(non_snake_case)]

#[path = "../../crates/sensaug-core/tests/common/pendulum.rs"]
mod pendulum;

use _core::convert::UkfStepError;
use _core::convert::{array, py_err, read, Array};
use _core::estimators::{run_batch, Batch};
use numpy::{PyArrayDyn, PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods};
use pendulum::{Pendulum, PendulumFilter, M, N};
use pyo3::prelude::*;
use pyo3::types::{IntoPyDict, PyDict};
use sensaug_core::estimator::EstimatorError;
use sensaug_core::ukf::MerweParams;

/// Merwe-scaled UKF on the pendulum model (N = 3, M = 2).
#[pyclass]
struct DemoUkf {
    inner: PendulumFilter,
}

#[pymethods]
impl DemoUkf {
    #[new]
    #[pyo3(signature = (*, x0, P0, Q, R, alpha, beta, kappa, dt_s=1e-3, length_m=0.5, mass_kg=1.0, damping_nms=0.1, gravity_mps2=9.81))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        x0: Array<'_>,
        P0: Array<'_>,
        Q: Array<'_>,
        R: Array<'_>,
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
        let (x0, P0) = (read::<N, 1>(&x0, "x0")?, read::<N, N>(&P0, "P0")?);
        let (Q, R) = (read::<N, N>(&Q, "Q")?, read::<M, M>(&R, "R")?);
        // The model is validated first, then the filter.
        let ukf = model
            .validate()
            .and_then(|()| pendulum::DemoUkf::new(x0, P0, Q, R, MerweParams { alpha, beta, kappa }))
            .map_err(|e| py_err(EstimatorError::Ukf(e)))?;
        Ok(Self {
            inner: PendulumFilter { ukf, model },
        })
    }

    /// Predict one step with torque `u` (N m); optional per-call `Q`.
    #[pyo3(signature = (u, *, Q=None))]
    fn predict(&mut self, u: f64, Q: Option<Array<'_>>) -> PyResult<String> {
        let (model, ukf) = (self.inner.model, &mut self.inner.ukf);
        let f = |x: &nalgebra::SVector<f64, N>| model.f(x, u);
        match Q {
            Some(q) => ukf.predict_with_q(&read::<N, N>(&q, "Q")?, f),
            None => ukf.predict(f),
        }
        .map(|s| s.to_string())
        .map_err(py_err)
    }

    /// Update with measurement `z` (shape (2,)); optional per-call `R`.
    #[pyo3(signature = (z, *, R=None))]
    fn update(&mut self, z: Array<'_>, R: Option<Array<'_>>) -> PyResult<String> {
        let (model, ukf) = (self.inner.model, &mut self.inner.ukf);
        let z = read::<M, 1>(&z, "z")?;
        let h = |x: &nalgebra::SVector<f64, N>| model.h(x);
        match R {
            Some(r) => ukf.update_with_r(&z, &read::<M, M>(&r, "R")?, h),
            None => ukf.update(&z, h),
        }
        .map(|s| s.to_string())
        .map_err(py_err)
    }

    /// The estimators' replay: for each k, `update(z[k])` then `predict(u[k])`.
    #[pyo3(signature = (z, u, *, strict=true))]
    fn run<'py>(
        &mut self,
        py: Python<'py>,
        z: PyReadonlyArray2<'py, f64>,
        u: PyReadonlyArray1<'py, f64>,
        strict: bool,
    ) -> PyResult<Batch<'py>> {
        let T = u.shape()[0];
        if z.shape() != [T, M] {
            let got = z.shape();
            let msg = format!("z: expected shape ({T}, {M}) to match u of length {T}, got {got:?}");
            return Err(pyo3::exceptions::PyValueError::new_err(msg));
        }
        run_batch(py, &mut self.inner, &z, &u, [None, None], strict)
    }

    /// Replace x and P (validated).
    fn reset(&mut self, x: Array<'_>, P: Array<'_>) -> PyResult<()> {
        let (x, P) = (read::<N, 1>(&x, "x")?, read::<N, N>(&P, "P")?);
        self.inner.ukf.reset(x, P).map_err(py_err)
    }

    fn recoveries<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        self.inner.ukf.recoveries().named().into_py_dict(py)
    }
    #[getter]
    fn x<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        array(py, self.inner.ukf.x())
    }
    #[getter]
    fn P<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        array(py, self.inner.ukf.P())
    }
    #[getter]
    fn x_prior<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        array(py, self.inner.ukf.x_prior())
    }
    #[getter]
    fn P_prior<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        array(py, self.inner.ukf.P_prior())
    }
    #[getter]
    fn Q<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        array(py, self.inner.ukf.Q())
    }
    #[setter(Q)]
    fn set_Q(&mut self, Q: Array<'_>) -> PyResult<()> {
        self.inner.ukf.set_Q(read::<N, N>(&Q, "Q")?).map_err(py_err)
    }
    #[getter]
    fn R<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        array(py, self.inner.ukf.R())
    }
    #[setter(R)]
    fn set_R(&mut self, R: Array<'_>) -> PyResult<()> {
        self.inner.ukf.set_R(read::<M, M>(&R, "R")?).map_err(py_err)
    }
    #[getter]
    fn y<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        array(py, self.inner.ukf.y())
    }
    #[getter]
    fn S<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        array(py, self.inner.ukf.S())
    }
    #[getter]
    fn K<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        array(py, self.inner.ukf.K())
    }
    #[getter]
    fn Wm<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        array(py, self.inner.ukf.Wm())
    }
    #[getter]
    fn Wc<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        array(py, self.inner.ukf.Wc())
    }
}

#[pymodule]
fn _ukf_oracle(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<DemoUkf>()?;
    m.add("UkfStepError", m.py().get_type::<UkfStepError>())
}
