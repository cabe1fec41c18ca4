//! The paper's three estimators with filterpy's conventions: step-wise
//! `update` / `predict`, and `run` over a whole recording in one core call
//! (`sensaug_core::replay`). Conversion only: every constructor argument is
//! required and typed; `sensaug.estimators` subclasses these with the
//! schema's defaults, the conversion of array-likes and the docs.
#![allow(non_snake_case)]

use crate::convert::{array, methods, py_err, read, slice, status};
use crate::convert::{Array, PyStatus};
use numpy::{PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2};
use numpy::{PyUntypedArrayMethods, ToPyArray};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::{IntoPyDict, PyDict};
use sensaug_core::estimator::{ExtendedFilterConfig, HandleModel};
use sensaug_core::estimator::{GainEstimator as CoreGain, TrajectoryEstimator as CoreTrajectory};
use sensaug_core::goal::{ChannelConfig, GoalIntegrator as CoreGoal, GoalIntegratorConfig};
use sensaug_core::replay::{replay, GoalReplay, Posteriors, Recording, Replay};
use sensaug_core::ukf::MerweParams;

/// A recording's per-tick values: `(T,)`; measurements: `(T, m)`.
type Column<'py> = PyReadonlyArray1<'py, f64>;
type Rows<'py> = PyReadonlyArray2<'py, f64>;

/// `(xs (T, n), Pdiag (T, n))` of a run.
pub type Batch<'py> = (Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<f64>>);

/// A whole recording through [`replay`]; with `strict`, the first step
/// error raised after the run.
pub fn run_batch<'py>(
    py: Python<'py>,
    filter: &mut impl Replay,
    y: &Rows<'py>,
    u: &Column<'py>,
    [dtau, dtau_h]: [Option<&Column<'py>>; 2],
    strict: bool,
) -> PyResult<Batch<'py>> {
    let m = filter.measurement_len();
    // The core checks `y`'s length; its rows' length only the array knows.
    if y.shape()[1] != m {
        let msg = format!("y: expected shape (T, {m}), got {:?}", y.shape());
        return Err(PyValueError::new_err(msg));
    }
    let rec = Recording {
        y: slice(y, "y")?,
        u: slice(u, "u")?,
        dtau: dtau.map(|d| slice(d, "dtau")).transpose()?,
        dtau_h: dtau_h.map(|d| slice(d, "dtau_h")).transpose()?,
    };
    let (T, n) = (rec.u.len(), filter.state_len());
    let (mut x, mut var) = (vec![0.0; T * n], vec![0.0; T * n]);
    let out = &mut Posteriors {
        x: &mut x,
        var: &mut var,
    };
    let report = replay(filter, &rec, out).map_err(py_err)?;
    if strict && report.errors > 0 {
        return Err(py_err(report));
    }
    let array = |v: Vec<f64>| PyArray1::from_vec(py, v).reshape([T, n]);
    Ok((array(x)?, array(var)?))
}

/// One class over a core estimator of the 6-state extended model with `$m`
/// measurements.
macro_rules! extended_estimator {
    ($name:ident, $core:ty, $m:literal, { $($extra:tt)* }) => {
        #[pyclass(module = "sensaug._core", subclass)]
        pub struct $name {
            inner: $core,
        }

        methods!($name {
            #[new]
            #[pyo3(signature = (*, mass, Q, R, x0, P0, damping, dt_s, alpha, beta, kappa))]
            #[allow(clippy::too_many_arguments)]
            fn new(mass: f64, Q: Array<'_>, R: Array<'_>, x0: Array<'_>, P0: Array<'_>,
                   damping: f64, dt_s: f64, alpha: f64, beta: f64, kappa: f64) -> PyResult<Self> {
                let model = HandleModel { mass, damping, dt_s };
                let sigma = MerweParams { alpha, beta, kappa };
                let (x0, P0) = (read(&x0, "x0")?, read(&P0, "P0")?);
                let (Q, R) = (read(&Q, "Q")?, read(&R, "R")?);
                let cfg = ExtendedFilterConfig::<$m> { x0, P0, Q, R, sigma };
                Ok(Self { inner: <$core>::new(model, &cfg).map_err(py_err)? })
            }

            fn update(&mut self, y: Array<'_>) -> PyResult<PyStatus> {
                self.inner.update(&read::<$m, 1>(&y, "y")?).map(status).map_err(py_err)
            }

            #[pyo3(signature = (u, dtau = 0.0, dtau_h = 0.0))]
            fn predict(&mut self, u: f64, dtau: f64, dtau_h: f64) -> PyResult<PyStatus> {
                self.inner.predict(u, dtau, dtau_h).map(status).map_err(py_err)
            }

            #[pyo3(signature = (y, u, dtau, dtau_h, *, strict = true))]
            fn run<'py>(&mut self, py: Python<'py>, y: Rows<'py>, u: Column<'py>, dtau: Column<'py>,
                        dtau_h: Column<'py>, strict: bool) -> PyResult<Batch<'py>> {
                run_batch(py, &mut self.inner, &y, &u, [Some(&dtau), Some(&dtau_h)], strict)
            }

            fn recoveries<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
                self.inner.filter().recoveries().named().into_py_dict(py)
            }

            $($extra)*
        }
            gains = |s, py| s.filter().x().as_slice()[3..].to_pyarray(py);
            x = |s, py| array(py, s.filter().x())?;
            P = |s, py| array(py, s.filter().P())?;
            x_prior = |s, py| array(py, s.filter().x_prior())?;
            P_prior = |s, py| array(py, s.filter().P_prior())?;
        );
    };
}

extended_estimator!(GainEstimator, CoreGain, 3, {});
extended_estimator!(TrajectoryEstimator, CoreTrajectory, 5, {
    fn partner_target(&self, x: f64) -> f64 {
        self.inner.partner_target(x)
    }
});

#[pyclass(module = "sensaug._core", subclass)]
pub struct GoalIntegrator {
    inner: CoreGoal,
}

methods!(GoalIntegrator {
    #[new]
    #[pyo3(signature = (*, mass, Q, R, x0, P0, damping, dt_s, gate, window_n0, hold_max_s))]
    #[allow(clippy::too_many_arguments)]
    fn new(mass: f64, Q: Array<'_>, R: Array<'_>, x0: Array<'_>, P0: Array<'_>,
           damping: f64, dt_s: f64, gate: f64, window_n0: f64, hold_max_s: f64) -> PyResult<Self> {
        let model = HandleModel { mass, damping, dt_s };
        let (x0, P0) = (read(&x0, "x0")?, read(&P0, "P0")?);
        let (Q, R_own) = (read(&Q, "Q")?, read(&R, "R")?);
        let channel = ChannelConfig { gate, window_n0, hold_max_s };
        let cfg = GoalIntegratorConfig { x0, P0, Q, R_own, channel };
        let inner = CoreGoal::new(model, &cfg).map_err(py_err)?;
        Ok(Self { inner })
    }

    fn update(&mut self, y: PyReadonlyArray1<'_, f64>) -> PyResult<PyStatus> {
        let y = slice(&y, "y")?;
        let mut one_tick = GoalReplay::for_columns(&mut self.inner, y.len()).map_err(py_err)?;
        one_tick.update_row(y).map(status).map_err(py_err)
    }

    fn predict(&mut self, u: f64, dtau: f64) -> PyResult<PyStatus> {
        self.inner.predict(u, dtau).map(status).map_err(py_err)
    }

    fn set_own_noise(&mut self, R: Array<'_>) -> PyResult<()> {
        self.inner.set_own_noise(read(&R, "R")?).map_err(py_err)
    }

    fn reset(&mut self, x0: Array<'_>) -> PyResult<()> {
        self.inner.reset(read(&x0, "x0")?).map_err(py_err)
    }

    #[pyo3(signature = (y, u, dtau, *, strict = true))]
    fn run<'py>(&mut self, py: Python<'py>, y: Rows<'py>, u: Column<'py>, dtau: Column<'py>,
                strict: bool) -> PyResult<Batch<'py>> {
        let mut r = GoalReplay::for_columns(&mut self.inner, y.shape()[1]).map_err(py_err)?;
        run_batch(py, &mut r, &y, &u, [Some(&dtau), None], strict)
    }
}
    x = |s, py| array(py, &s.estimate(true))?;
    var = |s, py| s.variance(true).to_pyarray(py);
    x_own = |s, py| array(py, &s.estimate(false))?;
    var_own = |s, py| s.variance(false).to_pyarray(py);
    weights = |s, py| s.weights().to_pyarray(py);
    members = |s, py| s.members().to_pyarray(py);
    grid = |s, py| s.grid().to_pyarray(py);
    change_point = |s, _py| s.change_point();
    channel_admitted = |s, _py| s.channel_admitted();
    partner_variance = |s, _py| s.partner_variance();
);
