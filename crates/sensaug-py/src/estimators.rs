//! The paper's three estimators with filterpy's conventions: step-wise
//! `update` / `predict`, and `run` over a whole recording in one core call
//! (`sensaug_core::replay`). Conversion only; the docs are in `_core.pyi`.
#![allow(non_snake_case)]

use crate::convert::{mat_to, matrix, py_err, real, recoveries_dict, settings, slice, status};
use crate::convert::{vec_to, vector, PyStatus};
use numpy::{PyArray2, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2};
use numpy::{PyUntypedArrayMethods, ToPyArray};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use pyo3::IntoPyObjectExt;
use sensaug_config::{PlantSpec, SigmaSpec};
use sensaug_core::estimator::{EstimatorError, ExtendedFilterConfig, HandleModel};
use sensaug_core::estimator::{GainEstimator as CoreGain, TrajectoryEstimator as CoreTrajectory};
use sensaug_core::goal::{ChannelConfig, GoalIntegrator as CoreGoal, GoalIntegratorConfig};
use sensaug_core::replay::{replay, GoalReplay, Posteriors, Recording, Replay};
use sensaug_core::ukf::MerweParams;

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<GainEstimator>()?;
    m.add_class::<TrajectoryEstimator>()?;
    m.add_class::<GoalIntegrator>()
}

/// `(xs (T, n), Pdiag (T, n))` of a run.
pub type Batch<'py> = (Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<f64>>);

fn finite(values: &[f64], names: &str) -> PyResult<()> {
    match values.iter().all(|v| v.is_finite()) {
        true => Ok(()),
        false => Err(PyValueError::new_err(format!(
            "{names}: must be finite; predict not run"
        ))),
    }
}

/// A whole recording through [`replay`]; with `strict`, the first step
/// error raised after the run.
pub fn run_batch<'py>(
    py: Python<'py>,
    filter: &mut impl Replay,
    y: &PyReadonlyArray2<'py, f64>,
    u: &PyReadonlyArray1<'py, f64>,
    [dtau, dtau_h]: [Option<&PyReadonlyArray1<'py, f64>>; 2],
    strict: bool,
) -> PyResult<Batch<'py>> {
    let (m, n) = (filter.measurement_len(), filter.state_len());
    if y.shape()[1] != m {
        let got = y.shape();
        return Err(PyValueError::new_err(format!(
            "y: expected shape (T, {m}), got {got:?}"
        )));
    }
    let dtau = dtau.map(|d| slice(d, "dtau")).transpose()?;
    let dtau_h = dtau_h.map(|d| slice(d, "dtau_h")).transpose()?;
    let rec = Recording {
        y: slice(y, "y")?,
        u: slice(u, "u")?,
        dtau,
        dtau_h,
    };
    let zeros = || PyArray2::zeros(py, [rec.u.len(), n], false);
    let (xs, pd) = (zeros(), zeros());
    let report = {
        let (mut x, mut var) = (xs.readwrite(), pd.readwrite());
        let mut out = Posteriors {
            x: x.as_slice_mut()?,
            var: var.as_slice_mut()?,
        };
        replay(filter, &rec, &mut out).map_err(py_err)?
    };
    match strict && report.errors > 0 {
        true => Err(py_err(report)),
        false => Ok((xs, pd)),
    }
}

/// A constructor's core error: the core calls the model's step `dt_s`,
/// these classes' keyword is `dt`.
fn setup_error(e: EstimatorError) -> PyErr {
    match e.to_string().strip_prefix("dt_s:") {
        Some(rest) => PyValueError::new_err(format!("dt:{rest}")),
        None => py_err(e),
    }
}

/// `#[pymethods]` of `$name`: `$methods`, then one-line getters, each
/// `name = |inner, py| value` over the class's core value `inner`.
macro_rules! methods {
    ($name:ident { $($methods:tt)* } $($get:ident = |$s:ident, $py:ident| $e:expr;)*) => {
        #[pymethods]
        impl $name {
            $($methods)*
            $(#[getter] fn $get(&self, $py: Python<'_>) -> PyResult<Py<PyAny>> {
                let $s = &self.inner;
                ($e).into_py_any($py)
            })*
        }
    };
}

/// One class over a core estimator of the 6-state extended model with `$m`
/// measurements.
macro_rules! extended_estimator {
    ($name:ident, $core:ty, $m:literal, { $($extra:tt)* }) => {
        #[pyclass(module = "sensaug._core")]
        pub struct $name {
            inner: $core,
        }

        methods!($name {
            #[new]
            #[pyo3(signature = (*, mass, Q, R, x0, P0, **kw))]
            #[pyo3(text_signature = "(*, mass, Q, R, x0, P0, damping=0.0, dt=1e-3, alpha=1.0, beta=2.0, kappa=0.0)")]
            fn new(mass: &Bound<'_, PyAny>, Q: &Bound<'_, PyAny>, R: &Bound<'_, PyAny>,
                   x0: &Bound<'_, PyAny>, P0: &Bound<'_, PyAny>, kw: Option<&Bound<'_, PyDict>>) -> PyResult<Self> {
                let (p, s) = (PlantSpec::default(), SigmaSpec::default());
                let names = ["damping", "dt", "alpha", "beta", "kappa"];
                let [damping, dt_s, alpha, beta, kappa] =
                    settings(kw, names, [p.damping, p.dt_s, s.alpha, s.beta, s.kappa])?;
                let model = HandleModel { mass: real(mass, "mass")?, damping, dt_s };
                let sigma = MerweParams { alpha, beta, kappa };
                let (x0, P0) = (vector(x0, "x0")?, matrix(P0, "P0")?);
                let cfg = ExtendedFilterConfig::<$m> { x0, P0, Q: matrix(Q, "Q")?, R: matrix(R, "R")?, sigma };
                Ok(Self { inner: <$core>::new(model, &cfg).map_err(setup_error)? })
            }

            fn update(&mut self, y: &Bound<'_, PyAny>) -> PyResult<PyStatus> {
                self.inner.update(&vector::<$m>(y, "y")?).map(status).map_err(py_err)
            }

            #[pyo3(signature = (u, dtau = 0.0, dtau_h = 0.0))]
            fn predict(&mut self, u: f64, dtau: f64, dtau_h: f64) -> PyResult<PyStatus> {
                finite(&[u, dtau, dtau_h], "u, dtau, dtau_h")?;
                self.inner.predict(u, dtau, dtau_h).map(status).map_err(py_err)
            }

            #[pyo3(signature = (y, u, dtau, dtau_h, *, strict = true))]
            fn run<'py>(&mut self, py: Python<'py>, y: PyReadonlyArray2<'py, f64>, u: PyReadonlyArray1<'py, f64>,
                        dtau: PyReadonlyArray1<'py, f64>, dtau_h: PyReadonlyArray1<'py, f64>, strict: bool,
            ) -> PyResult<Batch<'py>> {
                run_batch(py, &mut self.inner, &y, &u, [Some(&dtau), Some(&dtau_h)], strict)
            }

            fn recoveries<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
                recoveries_dict(py, &self.inner.filter().recoveries())
            }

            $($extra)*
        }
            gains = |s, py| s.filter().x().as_slice()[3..].to_pyarray(py);
            x = |s, py| vec_to(py, s.filter().x());
            P = |s, py| mat_to(py, s.filter().P());
            x_prior = |s, py| vec_to(py, s.filter().x_prior());
            P_prior = |s, py| mat_to(py, s.filter().P_prior());
        );
    };
}

extended_estimator!(GainEstimator, CoreGain, 3, {});
extended_estimator!(TrajectoryEstimator, CoreTrajectory, 5, {
    fn partner_target(&self, x: f64) -> f64 {
        self.inner.partner_target(x)
    }
});

/// Whether a measurement of `len` entries carries the partner channel.
fn with_channel(len: usize) -> PyResult<bool> {
    match len {
        2 | 3 => Ok(len == 3),
        n => Err(PyValueError::new_err(format!(
            "y: expected 2 entries [x - tau, xdot] or 3 [x - tau, xdot, x - tau_h^], got {n}"
        ))),
    }
}

#[pyclass(module = "sensaug._core")]
pub struct GoalIntegrator {
    inner: CoreGoal,
}

methods!(GoalIntegrator {
    #[new]
    #[pyo3(signature = (*, mass, Q, R, x0, P0, **kw))]
    #[pyo3(
        text_signature = "(*, mass, Q, R, x0, P0, damping=0.0, dt=1e-3, gate=4.0, window_n0=80.0, hold_max_s=0.25)"
    )]
    fn new(
        mass: &Bound<'_, PyAny>,
        Q: &Bound<'_, PyAny>,
        R: &Bound<'_, PyAny>,
        x0: &Bound<'_, PyAny>,
        P0: &Bound<'_, PyAny>,
        kw: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Self> {
        let (p, c) = (PlantSpec::default(), ChannelConfig::default());
        let names = ["damping", "dt", "gate", "window_n0", "hold_max_s"];
        let defaults = [p.damping, p.dt_s, c.gate, c.window_n0, c.hold_max_s];
        let [damping, dt_s, gate, window_n0, hold_max_s] = settings(kw, names, defaults)?;
        let mass = real(mass, "mass")?;
        let model = HandleModel { mass, damping, dt_s };
        let (x0, P0) = (vector(x0, "x0")?, matrix(P0, "P0")?);
        let (Q, R_own) = (matrix(Q, "Q")?, matrix(R, "R")?);
        let channel = ChannelConfig { gate, window_n0, hold_max_s };
        let cfg = GoalIntegratorConfig { x0, P0, Q, R_own, channel };
        Ok(Self {
            inner: CoreGoal::new(model, &cfg).map_err(setup_error)?,
        })
    }

    fn update(&mut self, y: PyReadonlyArray1<'_, f64>) -> PyResult<PyStatus> {
        let y = slice(&y, "y")?;
        let mut one_tick = GoalReplay::new(&mut self.inner, with_channel(y.len())?);
        one_tick.update_row(y).map(status).map_err(py_err)
    }

    #[pyo3(signature = (u, dtau = 0.0, dtau_h = 0.0))]
    fn predict(&mut self, u: f64, dtau: f64, dtau_h: f64) -> PyResult<PyStatus> {
        if dtau_h != 0.0 {
            let msg = "dtau_h: must be 0 for GoalIntegrator (its state is [x - tau, xdot])";
            return Err(PyValueError::new_err(msg));
        }
        finite(&[u, dtau], "u, dtau")?;
        self.inner.predict(u, dtau).map(status).map_err(py_err)
    }

    fn set_own_noise(&mut self, R: &Bound<'_, PyAny>) -> PyResult<()> {
        self.inner
            .set_own_noise(matrix(R, "R")?)
            .map_err(setup_error)
    }

    fn reset(&mut self, x0: &Bound<'_, PyAny>) -> PyResult<()> {
        self.inner.reset(vector(x0, "x0")?).map_err(py_err)
    }

    #[pyo3(signature = (y, u, dtau, *, strict = true))]
    fn run<'py>(
        &mut self,
        py: Python<'py>,
        y: PyReadonlyArray2<'py, f64>,
        u: PyReadonlyArray1<'py, f64>,
        dtau: PyReadonlyArray1<'py, f64>,
        strict: bool,
    ) -> PyResult<Batch<'py>> {
        let mut r = GoalReplay::new(&mut self.inner, with_channel(y.shape()[1])?);
        run_batch(py, &mut r, &y, &u, [Some(&dtau), None], strict)
    }

}
    x = |s, py| vec_to(py, &s.estimate(true));
    var = |s, py| s.variance(true).to_pyarray(py);
    x_own = |s, py| vec_to(py, &s.estimate(false));
    var_own = |s, py| s.variance(false).to_pyarray(py);
    weights = |s, py| s.weights().to_pyarray(py);
    members = |s, py| s.members().to_pyarray(py);
    grid = |s, py| s.grid().to_pyarray(py);
    change_point = |s, _py| s.change_point();
    channel_admitted = |s, _py| s.channel_admitted();
    partner_variance = |s, _py| s.partner_variance();
);
