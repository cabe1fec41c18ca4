//! The paper's three estimators, steppable from Python (to replay recorded
//! rig data or compare with oracles) and runnable over a whole trial in one
//! call. Conversion only; the logic is in `sensaug_core::estimator`.
#![allow(non_snake_case)]

use crate::convert::{estimator_err, mat_from, mat_to, status_str, to_py, vec_from, vec_to};
use nalgebra::{SVector, Vector2, Vector3};
use numpy::{
    PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods,
};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use sensaug_core::estimator::{
    ExtendedFilterConfig, GainEstimator as CoreGain, GoalIntegrator as CoreGoal,
    GoalIntegratorConfig, HandleModel, TrajectoryEstimator as CoreTrajectory,
};
use sensaug_core::ukf::MerweParams;

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<GainEstimator>()?;
    m.add_class::<TrajectoryEstimator>()?;
    m.add_class::<GoalIntegrator>()?;
    Ok(())
}

/// `(xs (T, 6), Pdiag (T, 6))` of a batch run.
type Batch<'py> = (Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<f64>>);

fn column<'a>(a: &'a PyReadonlyArray1<'_, f64>, name: &str, len: usize) -> PyResult<&'a [f64]> {
    let s = a
        .as_slice()
        .map_err(|_| PyValueError::new_err(format!("{name}: must be C-contiguous")))?;
    if s.len() != len {
        return Err(PyValueError::new_err(format!(
            "{name}: expected length {len} (one per step), got {}",
            s.len()
        )));
    }
    Ok(s)
}

/// One estimator class over the 6-state extended model with `$m` measurements.
macro_rules! extended_estimator {
    ($name:ident, $core:ty, $m:literal, $doc:literal, { $($extra:tt)* }) => {
        #[doc = $doc]
        #[pyclass(module = "sensaug._core")]
        pub struct $name {
            inner: $core,
        }

        #[pymethods]
        impl $name {
            #[new]
            #[pyo3(signature = (*, mass, Q, R, x0, P0, damping = 0.0, dt = 1e-3, alpha = 1.0, beta = 2.0, kappa = 0.0))]
            #[allow(clippy::too_many_arguments)]
            fn new(
                mass: f64,
                Q: PyReadonlyArray2<'_, f64>,
                R: PyReadonlyArray2<'_, f64>,
                x0: PyReadonlyArray1<'_, f64>,
                P0: PyReadonlyArray2<'_, f64>,
                damping: f64,
                dt: f64,
                alpha: f64,
                beta: f64,
                kappa: f64,
            ) -> PyResult<Self> {
                let model = HandleModel { mass, damping, dt_s: dt };
                let cfg = ExtendedFilterConfig::<$m> {
                    x0: vec_from::<6>(&x0, "x0")?,
                    P0: mat_from::<6, 6>(&P0, "P0")?,
                    Q: mat_from::<6, 6>(&Q, "Q")?,
                    R: mat_from::<$m, $m>(&R, "R")?,
                    sigma: MerweParams { alpha, beta, kappa },
                };
                let inner = <$core>::new(model, &cfg).map_err(estimator_err)?;
                Ok(Self { inner })
            }

            /// Fuse one measurement; returns "nominal" or "resymmetrised:<stage>".
            fn update(&mut self, y: PyReadonlyArray1<'_, f64>) -> PyResult<String> {
                let y = vec_from::<$m>(&y, "y")?;
                self.inner.update(&y).map(status_str).map_err(to_py)
            }

            /// Propagate with the own torque and the targets' increments.
            #[pyo3(signature = (u, dtau = 0.0, dtau_h = 0.0))]
            fn predict(&mut self, u: f64, dtau: f64, dtau_h: f64) -> PyResult<String> {
                if !(u.is_finite() && dtau.is_finite() && dtau_h.is_finite()) {
                    return Err(PyValueError::new_err(
                        "u, dtau, dtau_h: must be finite; predict not run",
                    ));
                }
                self.inner.predict(u, dtau, dtau_h).map(status_str).map_err(to_py)
            }

            /// A whole recorded trial: for each k, `update(y[k])` then
            /// `predict(u[k], dtau[k], dtau_h[k])`. Returns the posteriors
            /// after each update: `(xs (T, 6), Pdiag (T, 6))`. The first
            /// step error (already handled by the filter) is raised after
            /// the run when `strict`.
            #[pyo3(signature = (y, u, dtau, dtau_h, *, strict = true))]
            fn run<'py>(
                &mut self,
                py: Python<'py>,
                y: PyReadonlyArray2<'py, f64>,
                u: PyReadonlyArray1<'py, f64>,
                dtau: PyReadonlyArray1<'py, f64>,
                dtau_h: PyReadonlyArray1<'py, f64>,
                strict: bool,
            ) -> PyResult<Batch<'py>> {
                let T = y.shape()[0];
                if y.shape() != [T, $m] {
                    return Err(PyValueError::new_err(format!(
                        "y: expected shape (T, {}), got {:?}",
                        $m,
                        y.shape()
                    )));
                }
                let (u, dtau, dtau_h) = (
                    column(&u, "u", T)?,
                    column(&dtau, "dtau", T)?,
                    column(&dtau_h, "dtau_h", T)?,
                );
                let yv = y.as_array();
                let xs = PyArray2::<f64>::zeros(py, [T, 6], false);
                let pd = PyArray2::<f64>::zeros(py, [T, 6], false);
                let mut first_error = None;
                {
                    let mut xs_rw = xs.readwrite();
                    let mut pd_rw = pd.readwrite();
                    let mut xs_a = xs_rw.as_array_mut();
                    let mut pd_a = pd_rw.as_array_mut();
                    for k in 0..T {
                        let yk = SVector::<f64, $m>::from_fn(|i, _| yv[[k, i]]);
                        if let Err(e) = self.inner.update(&yk) {
                            first_error.get_or_insert((k, e));
                        }
                        let f = self.inner.filter();
                        for i in 0..6 {
                            xs_a[[k, i]] = f.x()[i];
                            pd_a[[k, i]] = f.P()[(i, i)];
                        }
                        if let Err(e) = self.inner.predict(u[k], dtau[k], dtau_h[k]) {
                            first_error.get_or_insert((k, e));
                        }
                    }
                }
                if let (true, Some((k, e))) = (strict, first_error) {
                    let inner = to_py(e);
                    return Err(PyValueError::new_err(format!(
                        "step {k}: {}",
                        inner.value(py)
                    )));
                }
                Ok((xs, pd))
            }

            /// Posterior state `[x - tau, xdot, x - tau_h, Lhx, Lhv, Lhh]`.
            #[getter]
            fn x<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
                vec_to(py, self.inner.filter().x())
            }

            /// Posterior covariance.
            #[getter]
            fn P<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
                mat_to(py, self.inner.filter().P())
            }

            /// Prior state (after the last predict).
            #[getter]
            fn x_prior<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
                vec_to(py, self.inner.filter().x_prior())
            }

            /// Prior covariance.
            #[getter]
            fn P_prior<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
                mat_to(py, self.inner.filter().P_prior())
            }

            /// Estimated partner gains `[Lhx, Lhv, Lhh]`.
            #[getter]
            fn gains<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
                let x = self.inner.filter().x();
                vec_to(py, &Vector3::new(x[3], x[4], x[5]))
            }

            $($extra)*

            /// Counters of the filter's recoveries.
            fn recoveries<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
                crate::convert::recoveries_dict(py, &self.inner.filter().recoveries())
            }
        }
    };
}

extended_estimator!(
    GainEstimator,
    CoreGain,
    3,
    "Stage 1: the partner's gains from y1 = [x - tau, xdot, x - tau_h].",
    {}
);
extended_estimator!(
    TrajectoryEstimator,
    CoreTrajectory,
    5,
    "Stage 2: the partner's target from y2 = [x - tau, xdot, Lhx^, Lhv^, Lhh^].",
    {
        /// `tau_h^ = x - (x - tau_h)^` for the handle position `x`.
        fn partner_target(&self, x: f64) -> f64 {
            self.inner.partner_target(x)
        }
    }
);

/// Stage 3: goal integration on `[x - tau, xdot]`, with and without the
/// partner channel `x - tau_h^`, side by side.
#[pyclass(module = "sensaug._core")]
pub struct GoalIntegrator {
    inner: CoreGoal,
}

#[pymethods]
impl GoalIntegrator {
    #[new]
    #[pyo3(signature = (*, mass, Q, R, x0, P0, damping = 0.0, dt = 1e-3, partner_window_s = 0.2, alpha = 1.0, beta = 2.0, kappa = 0.0))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        mass: f64,
        Q: PyReadonlyArray2<'_, f64>,
        R: PyReadonlyArray2<'_, f64>,
        x0: PyReadonlyArray1<'_, f64>,
        P0: PyReadonlyArray2<'_, f64>,
        damping: f64,
        dt: f64,
        partner_window_s: f64,
        alpha: f64,
        beta: f64,
        kappa: f64,
    ) -> PyResult<Self> {
        let model = HandleModel {
            mass,
            damping,
            dt_s: dt,
        };
        let cfg = GoalIntegratorConfig {
            x0: vec_from::<2>(&x0, "x0")?,
            P0: mat_from::<2, 2>(&P0, "P0")?,
            Q: mat_from::<2, 2>(&Q, "Q")?,
            R_own: mat_from::<2, 2>(&R, "R")?,
            partner_window_s,
            sigma: MerweParams { alpha, beta, kappa },
        };
        let inner = CoreGoal::new(model, &cfg).map_err(estimator_err)?;
        Ok(Self { inner })
    }

    /// Fuse `y = [x - tau, xdot]` (own sensing only) or
    /// `y = [x - tau, xdot, x - tau_h^]` (with the partner channel, whose
    /// variance is estimated online and floored at `partner_floor`).
    #[pyo3(signature = (y, partner_floor = 0.0))]
    fn update(&mut self, y: PyReadonlyArray1<'_, f64>, partner_floor: f64) -> PyResult<String> {
        let n = y.len();
        let (own, partner) = match n {
            2 => (vec_from::<2>(&y, "y")?, None),
            3 => {
                let v = vec_from::<3>(&y, "y")?;
                (Vector2::new(v[0], v[1]), Some((v[2], partner_floor)))
            }
            _ => {
                return Err(PyValueError::new_err(format!(
                "y: expected 2 entries [x - tau, xdot] or 3 [x - tau, xdot, x - tau_h^], got {n}"
            )))
            }
        };
        if !(partner_floor.is_finite() && partner_floor >= 0.0) {
            return Err(PyValueError::new_err(
                "partner_floor: must be finite and >= 0",
            ));
        }
        self.inner
            .update(&own, partner)
            .map(status_str)
            .map_err(to_py)
    }

    /// Propagate with the known torque `u` (own plus estimated partner) and
    /// the own target's increment. `dtau_h` is accepted for the common
    /// estimator signature but must be 0: this state has no `x - tau_h`.
    #[pyo3(signature = (u, dtau = 0.0, dtau_h = 0.0))]
    fn predict(&mut self, u: f64, dtau: f64, dtau_h: f64) -> PyResult<String> {
        if dtau_h != 0.0 {
            return Err(PyValueError::new_err(
                "dtau_h: must be 0 for GoalIntegrator (its state is [x - tau, xdot])",
            ));
        }
        if !(u.is_finite() && dtau.is_finite()) {
            return Err(PyValueError::new_err(
                "u, dtau: must be finite; predict not run",
            ));
        }
        self.inner.predict(u, dtau).map(status_str).map_err(to_py)
    }

    /// Integrated posterior `[x - tau, xdot]`.
    #[getter]
    fn x<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec_to(py, self.inner.fused_filter().x())
    }

    /// Integrated posterior covariance.
    #[getter]
    fn P<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        mat_to(py, self.inner.fused_filter().P())
    }

    /// Own-sensing posterior `[x - tau, xdot]`.
    #[getter]
    fn x_own<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec_to(py, self.inner.own_filter().x())
    }

    /// Own-sensing posterior covariance.
    #[getter]
    fn P_own<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        mat_to(py, self.inner.own_filter().P())
    }

    /// The partner-channel variance used in the last update (NaN before).
    #[getter]
    fn partner_variance(&self) -> f64 {
        self.inner.partner_variance()
    }
}
