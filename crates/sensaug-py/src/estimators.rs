//! The paper's three estimators with filterpy's conventions: step-wise
//! `update` / `predict`, and `run` over a whole recording in one core call
//! (`sensaug_core::replay`). Conversion only.
#![allow(non_snake_case)]

use crate::convert::Opt;
use crate::convert::PyStatus;
use crate::convert::{mat_to, matrix, py_err, real, real_or, recoveries_dict, slice, status};
use crate::convert::{vec_from, vec_to, vector};
use numpy::{PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2};
use numpy::{PyUntypedArrayMethods, ToPyArray};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use sensaug_config::{PlantSpec, SigmaSpec};
use sensaug_core::estimator::GainEstimator as CoreGain;
use sensaug_core::estimator::TrajectoryEstimator as CoreTrajectory;
use sensaug_core::estimator::{EstimatorError, ExtendedFilterConfig, HandleModel};
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

/// `names: must be finite` unless every value is.
fn finite(values: &[f64], names: &str) -> PyResult<()> {
    if values.iter().all(|v| v.is_finite()) {
        return Ok(());
    }
    Err(PyValueError::new_err(format!(
        "{names}: must be finite; predict not run"
    )))
}

/// A whole recording through [`replay`]: converts the arrays, runs, and
/// raises the first step error after the run when `strict`.
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
    let rec = Recording {
        y: slice(y, "y")?,
        u: slice(u, "u")?,
        dtau: dtau.map(|d| slice(d, "dtau")).transpose()?,
        dtau_h: dtau_h.map(|d| slice(d, "dtau_h")).transpose()?,
    };
    let T = rec.u.len();
    let (xs, pd) = (
        PyArray2::zeros(py, [T, n], false),
        PyArray2::zeros(py, [T, n], false),
    );
    let report = {
        let (mut x, mut var) = (xs.readwrite(), pd.readwrite());
        let mut out = Posteriors {
            x: x.as_slice_mut()?,
            var: var.as_slice_mut()?,
        };
        replay(filter, &rec, &mut out).map_err(py_err)?
    };
    if strict && report.errors > 0 {
        return Err(py_err(report));
    }
    Ok((xs, pd))
}

/// The handle model from the constructors' keywords `mass`, `damping`,
/// `dt`: the schema's `[plant]` defaults (`sensaug_config::PlantSpec`)
/// where one is not given, so the binding keeps no defaults of its own.
fn handle_model(
    mass: &Bound<'_, PyAny>,
    damping: Opt<'_, '_>,
    dt: Opt<'_, '_>,
) -> PyResult<HandleModel> {
    let d = PlantSpec::default();
    Ok(HandleModel {
        mass: real(mass, "mass")?,
        damping: real_or(damping, "damping", d.damping)?,
        dt_s: real_or(dt, "dt", d.dt_s)?,
    })
}

/// The keywords every estimator constructor shares, converted with their
/// names: the handle model (`mass`, `damping`, `dt`) and the sigma points
/// (`alpha`, `beta`, `kappa`; the schema's `[robot.sigma]` defaults).
struct Common {
    model: HandleModel,
    sigma: MerweParams,
}

impl Common {
    fn new(mass: &Bound<'_, PyAny>, optional: [Opt<'_, '_>; 5]) -> PyResult<Self> {
        let [damping, dt, alpha, beta, kappa] = optional;
        let d = SigmaSpec::default();
        Ok(Common {
            model: handle_model(mass, damping, dt)?,
            sigma: MerweParams {
                alpha: real_or(alpha, "alpha", d.alpha)?,
                beta: real_or(beta, "beta", d.beta)?,
                kappa: real_or(kappa, "kappa", d.kappa)?,
            },
        })
    }
}

/// A constructor's core error: the core calls the model's step `dt_s`,
/// these classes' keyword is `dt`.
fn setup_error(e: EstimatorError) -> PyErr {
    let msg = e.to_string();
    match msg.strip_prefix("dt_s:") {
        Some(rest) => PyValueError::new_err(format!("dt:{rest}")),
        None => py_err(e),
    }
}

/// A class over the core estimator `$core` whose UKF `self.inner.$f()` gives
/// the shared getters `x`, `P`, `x_prior`, `P_prior` and `recoveries()`.
macro_rules! estimator_class {
    ($name:ident, $core:ty, $f:ident, $doc:literal, { $($methods:tt)* }) => {
        #[doc = $doc]
        #[pyclass(module = "sensaug._core")]
        pub struct $name {
            inner: $core,
        }

        #[pymethods]
        impl $name {
            $($methods)*

            /// Posterior state.
            #[getter]
            fn x<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
                vec_to(py, self.inner.$f().x())
            }
            /// Posterior covariance.
            #[getter]
            fn P<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
                mat_to(py, self.inner.$f().P())
            }
            /// Prior state (after the last predict).
            #[getter]
            fn x_prior<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
                vec_to(py, self.inner.$f().x_prior())
            }
            /// Prior covariance.
            #[getter]
            fn P_prior<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
                mat_to(py, self.inner.$f().P_prior())
            }
            /// Counters of the filter's recoveries.
            fn recoveries<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
                recoveries_dict(py, &self.inner.$f().recoveries())
            }
        }
    };
}

/// One estimator class over the 6-state extended model with `$m` measurements.
macro_rules! extended_estimator {
    ($name:ident, $core:ty, $m:literal, $doc:literal, { $($extra:tt)* }) => {
        estimator_class!($name, $core, filter, $doc, {
            #[new]
            #[pyo3(signature = (*, mass, Q, R, x0, P0, damping = None, dt = None, alpha = None, beta = None, kappa = None))]
            #[pyo3(text_signature = "(*, mass, Q, R, x0, P0, damping=0.0, dt=1e-3, alpha=1.0, beta=2.0, kappa=0.0)")]
            #[allow(clippy::too_many_arguments)]
            fn new(
                mass: &Bound<'_, PyAny>,
                Q: &Bound<'_, PyAny>,
                R: &Bound<'_, PyAny>,
                x0: &Bound<'_, PyAny>,
                P0: &Bound<'_, PyAny>,
                damping: Opt<'_, '_>,
                dt: Opt<'_, '_>,
                alpha: Opt<'_, '_>,
                beta: Opt<'_, '_>,
                kappa: Opt<'_, '_>,
            ) -> PyResult<Self> {
                let Common { model, sigma } = Common::new(mass, [damping, dt, alpha, beta, kappa])?;
                let cfg = ExtendedFilterConfig::<$m> {
                    x0: vector(x0, "x0")?,
                    P0: matrix(P0, "P0")?,
                    Q: matrix(Q, "Q")?,
                    R: matrix(R, "R")?,
                    sigma,
                };
                let inner = <$core>::new(model, &cfg).map_err(setup_error)?;
                Ok(Self { inner })
            }

            /// Fuse one measurement; returns the step's `Status`.
            fn update(&mut self, y: PyReadonlyArray1<'_, f64>) -> PyResult<PyStatus> {
                let y = vec_from::<$m>(&y, "y")?;
                self.inner.update(&y).map(status).map_err(py_err)
            }

            /// Propagate with the own torque and the targets' increments.
            #[pyo3(signature = (u, dtau = 0.0, dtau_h = 0.0))]
            fn predict(&mut self, u: f64, dtau: f64, dtau_h: f64) -> PyResult<PyStatus> {
                finite(&[u, dtau, dtau_h], "u, dtau, dtau_h")?;
                self.inner.predict(u, dtau, dtau_h).map(status).map_err(py_err)
            }

            /// For each k: `update(y[k])`, then `predict(u[k], dtau[k], dtau_h[k])`.
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
                run_batch(py, &mut self.inner, &y, &u, [Some(&dtau), Some(&dtau_h)], strict)
            }

            /// Estimated partner gains `[Lhx, Lhv, Lhh]`.
            #[getter]
            fn gains<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
                self.inner.filter().x().as_slice()[3..].to_pyarray(py)
            }

            $($extra)*
        });
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

/// Whether a measurement of `len` entries carries the partner channel.
fn with_channel(len: usize) -> PyResult<bool> {
    match len {
        2 => Ok(false),
        3 => Ok(true),
        n => Err(PyValueError::new_err(format!(
            "y: expected 2 entries [x - tau, xdot] or 3 [x - tau, xdot, x - tau_h^], got {n}"
        ))),
    }
}

/// Stage 3: goal integration on `[x - tau, xdot]` with the adaptive partner
/// channel (a bank of Kalman filters over the channel's variance, weighted by
/// their predictions of the own measurement; docs/model.md). `x`, `var` are
/// the mixture's (with the partner), `x_own`, `var_own` member 0's (own
/// sensing only), as of the last update.
#[pyclass(module = "sensaug._core")]
pub struct GoalIntegrator {
    inner: CoreGoal,
}

#[pymethods]
impl GoalIntegrator {
    #[new]
    #[pyo3(signature = (*, mass, Q, R, x0, P0, damping = None, dt = None, gate = None, window_n0 = None, hold_max_s = None))]
    #[pyo3(
        text_signature = "(*, mass, Q, R, x0, P0, damping=0.0, dt=1e-3, gate=4.0, window_n0=80.0, hold_max_s=0.25)"
    )]
    #[allow(clippy::too_many_arguments)]
    fn new(
        mass: &Bound<'_, PyAny>,
        Q: &Bound<'_, PyAny>,
        R: &Bound<'_, PyAny>,
        x0: &Bound<'_, PyAny>,
        P0: &Bound<'_, PyAny>,
        damping: Opt<'_, '_>,
        dt: Opt<'_, '_>,
        gate: Opt<'_, '_>,
        window_n0: Opt<'_, '_>,
        hold_max_s: Opt<'_, '_>,
    ) -> PyResult<Self> {
        let model = handle_model(mass, damping, dt)?;
        let d = ChannelConfig::default();
        let cfg = GoalIntegratorConfig {
            x0: vector(x0, "x0")?,
            P0: matrix(P0, "P0")?,
            Q: matrix(Q, "Q")?,
            R_own: matrix(R, "R")?,
            channel: ChannelConfig {
                gate: real_or(gate, "gate", d.gate)?,
                window_n0: real_or(window_n0, "window_n0", d.window_n0)?,
                hold_max_s: real_or(hold_max_s, "hold_max_s", d.hold_max_s)?,
            },
        };
        let inner = CoreGoal::new(model, &cfg).map_err(setup_error)?;
        Ok(Self { inner })
    }

    /// Fuse `y = [x - tau, xdot]` (own sensing only) or
    /// `y = [x - tau, xdot, x - tau_h^]` (with the partner channel; NaN: none).
    fn update(&mut self, y: PyReadonlyArray1<'_, f64>) -> PyResult<PyStatus> {
        let y = slice(&y, "y")?;
        let mut one_tick = GoalReplay::new(&mut self.inner, with_channel(y.len())?);
        one_tick.update_row(y).map(status).map_err(py_err)
    }

    /// Propagate with the known torque `u` (own plus estimated partner) and
    /// the own target's increment. `dtau_h` must be 0: this state has no `x - tau_h`.
    #[pyo3(signature = (u, dtau = 0.0, dtau_h = 0.0))]
    fn predict(&mut self, u: f64, dtau: f64, dtau_h: f64) -> PyResult<PyStatus> {
        if dtau_h != 0.0 {
            return Err(PyValueError::new_err(
                "dtau_h: must be 0 for GoalIntegrator (its state is [x - tau, xdot])",
            ));
        }
        finite(&[u, dtau], "u, dtau")?;
        self.inner.predict(u, dtau).map(status).map_err(py_err)
    }

    /// Phase start: the own measurement's covariance (target-view noise
    /// included), which sets the channel grid and the score window.
    fn set_own_noise(&mut self, R: &Bound<'_, PyAny>) -> PyResult<()> {
        let R = matrix(R, "R")?;
        self.inner.set_own_noise(R).map_err(setup_error)
    }

    /// Phase start: every member at `x0` with `P0`, scores 0.
    fn reset(&mut self, x0: &Bound<'_, PyAny>) -> PyResult<()> {
        let x0 = vector(x0, "x0")?;
        self.inner.reset(x0).map_err(py_err)
    }

    /// For each k: `update(y[k])`, then `predict(u[k], dtau[k])`.
    /// The posteriors are the mixture's.
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

    /// The mixture's `[x - tau, xdot]` (goal integration with the partner).
    #[getter]
    fn x<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec_to(py, &self.inner.estimate(true))
    }

    /// The mixture's variances `[var(x - tau), var(xdot)]`.
    #[getter]
    fn var<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.inner.variance(true).to_pyarray(py)
    }

    /// Member 0's `[x - tau, xdot]` (own sensing only).
    #[getter]
    fn x_own<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec_to(py, &self.inner.estimate(false))
    }

    /// Member 0's variances.
    #[getter]
    fn var_own<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.inner.variance(false).to_pyarray(py)
    }

    /// The mixture weights of the last update (member 0 first).
    #[getter]
    fn weights<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.inner.weights().to_pyarray(py)
    }

    /// Each member's `x - tau` (posterior after update, prior after predict).
    #[getter]
    fn members<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.inner.members().to_pyarray(py)
    }

    /// The members' channel variances (member 0: inf).
    #[getter]
    fn grid<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.inner.grid().to_pyarray(py)
    }

    /// The last update detected a change point (a target jump).
    #[getter]
    fn change_point(&self) -> bool {
        self.inner.change_point()
    }

    /// The last update fused the partner channel.
    #[getter]
    fn channel_admitted(&self) -> bool {
        self.inner.channel_admitted()
    }

    /// The channel's effective variance in the last update (inf: not fused).
    #[getter]
    fn partner_variance(&self) -> f64 {
        self.inner.partner_variance()
    }
}
