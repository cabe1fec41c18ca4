//! The binding's one set of conversions: numpy <-> nalgebra and slices, and
//! one mapping from every core error to a Python exception naming the argument.
use nalgebra::{SMatrix, SVector};
use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray, PyUntypedArrayMethods};
use numpy::{PyReadonlyArray1, PyReadonlyArray2};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::types::{IntoPyDict, PyDict};
use pyo3::{create_exception, prelude::*};
use sensaug_core::estimator::EstimatorError;
use sensaug_core::plant::PlantError;
use sensaug_core::replay::ReplayError;
use sensaug_core::riccati::RiccatiError;
use sensaug_core::ukf::{Arg, Recoveries, RunReport, Status, UkfError};

create_exception!(
    _core,
    UkfStepError,
    PyRuntimeError,
    "A UKF predict/update was rejected (state unchanged) or reset P (state valid)."
);
create_exception!(
    _core,
    RiccatiConvergenceError,
    PyRuntimeError,
    "A Riccati solve did not converge or its solution failed the residual or closed-loop check."
);

/// `a` as a fixed-size matrix; `name` is the argument in the error.
pub fn mat_from<const R: usize, const C: usize>(
    a: &PyReadonlyArray2<'_, f64>,
    name: &str,
) -> PyResult<SMatrix<f64, R, C>> {
    if a.shape() != [R, C] {
        let got = a.shape();
        return Err(PyValueError::new_err(format!(
            "{name}: expected shape ({R}, {C}), got {got:?}"
        )));
    }
    let v = a.as_array();
    Ok(SMatrix::from_fn(|i, j| v[[i, j]]))
}

/// `a` as a fixed-size vector; `name` is the argument in the error.
pub fn vec_from<const D: usize>(
    a: &PyReadonlyArray1<'_, f64>,
    name: &str,
) -> PyResult<SVector<f64, D>> {
    if a.shape() != [D] {
        let got = a.shape();
        return Err(PyValueError::new_err(format!(
            "{name}: expected shape ({D},), got {got:?}"
        )));
    }
    let v = a.as_array();
    Ok(SVector::from_fn(|i, _| v[i]))
}

/// A C-contiguous array's data, row-major.
pub fn slice<'a, D: numpy::ndarray::Dimension>(
    a: &'a PyReadonlyArray<'_, f64, D>,
    name: &str,
) -> PyResult<&'a [f64]> {
    a.as_slice().map_err(|_| {
        PyValueError::new_err(format!(
            "{name}: must be C-contiguous (use np.ascontiguousarray)"
        ))
    })
}

pub fn mat_to<'py, const R: usize, const C: usize>(
    py: Python<'py>,
    m: &SMatrix<f64, R, C>,
) -> Bound<'py, PyArray2<f64>> {
    Array2::from_shape_fn((R, C), |(i, j)| m[(i, j)]).into_pyarray(py)
}

pub fn vec_to<'py, const D: usize>(
    py: Python<'py>,
    v: &SVector<f64, D>,
) -> Bound<'py, PyArray1<f64>> {
    v.as_slice().to_vec().into_pyarray(py)
}

/// "nominal" or "resymmetrised:<stage>".
pub fn status_str(s: Status) -> String {
    match s {
        Status::Nominal => "nominal".to_owned(),
        Status::Resymmetrised { stage } => format!("resymmetrised:{}", snake(stage)),
    }
}

/// A core enum variant's name in snake case (`PredictRedraw` -> `predict_redraw`).
fn snake(variant: impl core::fmt::Debug) -> String {
    let mut out = String::new();
    for (i, c) in format!("{variant:?}").chars().enumerate() {
        if c.is_uppercase() && i > 0 {
            out.push('_');
        }
        out.push(c.to_ascii_lowercase());
    }
    out
}

/// A UKF's counters as a dict.
pub fn recoveries_dict<'py>(py: Python<'py>, r: &Recoveries) -> PyResult<Bound<'py, PyDict>> {
    let (rs, cr, rj) = (r.resymmetrised, r.covariance_resets, r.rejected);
    [
        ("resymmetrised", rs),
        ("covariance_resets", cr),
        ("rejected", rj),
    ]
    .into_iter()
    .chain([("predicts", r.predicts), ("updates", r.updates)])
    .into_py_dict(py)
}

/// Every core error the binding can meet.
pub enum CoreError {
    /// A step's or setter's error.
    Ukf(UkfError),
    /// A constructor's: its `x` and `P` are the arguments `x0`, `P0`.
    Setup(UkfError),
    Estimator(EstimatorError),
    Replay(ReplayError),
    Plant(PlantError),
    Riccati(RiccatiError),
    /// A strict run that had step errors.
    Run(RunReport),
}

macro_rules! from_core {
    ($($t:ty => $v:ident),*) => {$(
        impl From<$t> for CoreError {
            fn from(e: $t) -> Self {
                CoreError::$v(e)
            }
        }
    )*};
}
from_core!(UkfError => Ukf, EstimatorError => Estimator, ReplayError => Replay,
    PlantError => Plant, RiccatiError => Riccati, RunReport => Run);

/// Which Python exception an error becomes.
enum Kind {
    Value,
    Step,
    Convergence,
}

/// The one error mapping: a core error as a Python exception whose message
/// starts with the argument's name.
pub fn py_err(e: impl Into<CoreError>) -> PyErr {
    let (kind, msg) = describe(e.into());
    match kind {
        Kind::Value => PyValueError::new_err(msg),
        Kind::Step => UkfStepError::new_err(msg),
        Kind::Convergence => RiccatiConvergenceError::new_err(msg),
    }
}

fn describe(e: CoreError) -> (Kind, String) {
    use Kind::{Convergence, Step, Value};
    match e {
        CoreError::Estimator(EstimatorError::Ukf(u)) | CoreError::Setup(u) => match u {
            UkfError::NotPositiveDefinite { which: Arg::P } => {
                (Value, "P0: must be symmetric positive definite".into())
            }
            UkfError::NonFiniteArgument {
                which: w @ (Arg::P | Arg::X),
            } => (Value, format!("{}0: must be finite (no NaN or inf)", w.name())),
            other => describe(CoreError::Ukf(other)),
        },
        CoreError::Estimator(EstimatorError::InvalidModel(name)) => (Value, format!(
            "{name}: out of range (mass, dt and partner_window_s > 0; damping >= 0; all finite)"
        )),
        CoreError::Ukf(e) => match e {
            UkfError::NonFiniteArgument { which } => {
                (Value, format!("{}: must be finite (no NaN or inf)", which.name()))
            }
            UkfError::NotPositiveDefinite { which } => (Value, format!(
                "{0}: must be symmetric positive definite (Cholesky of (n + lambda) * {0} failed)",
                which.name()
            )),
            UkfError::InvalidSigmaParams => (Value,
                "alpha/beta/kappa: need finite values with alpha > 0 and n + kappa > 0".into(),
            ),
            UkfError::InvalidModelParameter { name } => (Value, format!(
                "{name}: out of range (dt_s, length_m, mass_kg > 0; damping_nms >= 0; all finite)"
            )),
            // Ukf::run's slice errors: the binding replays through sensaug_core::replay.
            other @ (UkfError::InputLength { .. } | UkfError::OutputTooShort { .. }) => {
                (Value, format!("{other:?}"))
            }
            UkfError::NonFiniteMeasurement => {
                (Step, "z: must be finite; update rejected, state unchanged".into())
            }
            UkfError::NonFiniteProcess => (Step,
                "process model returned NaN/inf; predict rejected, state unchanged".into(),
            ),
            UkfError::NonFiniteMeasurementModel => (Step,
                "measurement model returned NaN/inf; update rejected, state unchanged".into(),
            ),
            UkfError::NonFiniteResult { phase } => (Step, format!(
                "{} overflowed to NaN/inf; rejected, state unchanged",
                snake(phase)
            )),
            UkfError::CovarianceReset { stage } => (Step, format!(
                "covariance not positive definite at {} even after re-symmetrising; P reset to the reset covariance (filter valid)",
                snake(stage)
            )),
        },
        CoreError::Replay(e) => (Value, e.to_string()),
        CoreError::Plant(PlantError::InvalidParam(field)) => (Value, format!(
            "{field}: must be finite and {}",
            if matches!(field, "mass" | "dt_s") { "> 0" } else { ">= 0" }
        )),
        CoreError::Plant(PlantError::NonFiniteTorque) => {
            (Value, "torque: must be finite (NaN/inf rejected, state unchanged)".into())
        }
        CoreError::Riccati(
            e @ (RiccatiError::NoConvergence
            | RiccatiError::ResidualTooLarge { .. }
            | RiccatiError::NotStabilizing),
        ) => (Convergence, e.to_string()),
        CoreError::Riccati(e) => (Value, e.to_string()),
        CoreError::Run(r) => (Step, match r.first_error {
            Some(first) => format!(
                "{} step error(s); first at step {} ({}): {}",
                r.errors,
                first.step,
                snake(first.phase),
                describe(CoreError::Ukf(first.error)).1
            ),
            None => "no step error".into(),
        }),
    }
}
