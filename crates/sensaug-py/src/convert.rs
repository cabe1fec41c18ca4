//! Conversions shared by the bindings: numpy <-> nalgebra, core errors ->
//! Python exceptions whose message names the argument.
use nalgebra::{SMatrix, SVector};
use numpy::ndarray::{Array1, Array2};
use numpy::{
    IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods,
};
use pyo3::create_exception;
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use sensaug_core::ukf::{Phase, Recoveries, Stage, Status, UkfError};

create_exception!(
    _core,
    UkfStepError,
    PyRuntimeError,
    "A UKF predict/update was rejected (state unchanged) or reset P (state valid)."
);

pub(crate) fn stage_name(s: Stage) -> &'static str {
    match s {
        Stage::PredictSigmaPoints => "predict_sigma_points",
        Stage::PredictRedraw => "predict_redraw",
        Stage::UpdateSigmaPoints => "update_sigma_points",
        Stage::InnovationCovariance => "innovation_covariance",
    }
}

pub(crate) fn phase_name(p: Phase) -> &'static str {
    match p {
        Phase::Predict => "predict",
        Phase::Update => "update",
    }
}

/// Core error -> Python exception whose message names the argument.
pub(crate) fn to_py(e: UkfError) -> PyErr {
    match e {
        UkfError::NonFiniteArgument { which } => {
            PyValueError::new_err(format!("{}: must be finite (no NaN or inf)", which.name()))
        }
        UkfError::NotPositiveDefinite { which } => PyValueError::new_err(format!(
            "{}: must be symmetric positive definite (Cholesky of (n + lambda) * {} failed)",
            which.name(),
            which.name()
        )),
        UkfError::InvalidSigmaParams => PyValueError::new_err(
            "alpha/beta/kappa: need finite values with alpha > 0 and n + kappa > 0",
        ),
        UkfError::InvalidModelParameter { name } => PyValueError::new_err(format!(
            "{name}: out of range (dt_s, length_m, mass_kg > 0; damping_nms >= 0; all finite)"
        )),
        UkfError::InputLength { which, needed, got } => PyValueError::new_err(format!(
            "{}: needs {needed} values, got {got}",
            which.name()
        )),
        UkfError::OutputTooShort { which, needed, got } => PyValueError::new_err(format!(
            "{}: needs {needed} values, got {got}",
            which.name()
        )),
        UkfError::NonFiniteMeasurement => {
            UkfStepError::new_err("z: must be finite; update rejected, state unchanged")
        }
        UkfError::NonFiniteProcess => UkfStepError::new_err(
            "process model returned NaN/inf; predict rejected, state unchanged",
        ),
        UkfError::NonFiniteMeasurementModel => UkfStepError::new_err(
            "measurement model returned NaN/inf; update rejected, state unchanged",
        ),
        UkfError::NonFiniteResult { phase } => UkfStepError::new_err(format!(
            "{} overflowed to NaN/inf; rejected, state unchanged",
            phase_name(phase)
        )),
        UkfError::CovarianceReset { stage } => UkfStepError::new_err(format!(
            "covariance not positive definite at {} even after re-symmetrising; P reset to the reset covariance (filter valid)",
            stage_name(stage)
        )),
    }
}

pub(crate) fn status_str(s: Status) -> String {
    match s {
        Status::Nominal => "nominal".to_owned(),
        Status::Resymmetrised { stage } => format!("resymmetrised:{}", stage_name(stage)),
    }
}

pub(crate) fn vec_from<const D: usize>(
    a: &PyReadonlyArray1<'_, f64>,
    name: &str,
) -> PyResult<SVector<f64, D>> {
    if a.shape() != [D] {
        return Err(PyValueError::new_err(format!(
            "{name}: expected shape ({D},), got {:?}",
            a.shape()
        )));
    }
    let v = a.as_array();
    Ok(SVector::<f64, D>::from_fn(|i, _| v[i]))
}

pub(crate) fn mat_from<const R: usize, const C: usize>(
    a: &PyReadonlyArray2<'_, f64>,
    name: &str,
) -> PyResult<SMatrix<f64, R, C>> {
    if a.shape() != [R, C] {
        return Err(PyValueError::new_err(format!(
            "{name}: expected shape ({R}, {C}), got {:?}",
            a.shape()
        )));
    }
    let v = a.as_array();
    Ok(SMatrix::<f64, R, C>::from_fn(|i, j| v[[i, j]]))
}

pub(crate) fn vec_to<'py, const D: usize>(
    py: Python<'py>,
    v: &SVector<f64, D>,
) -> Bound<'py, PyArray1<f64>> {
    Array1::from_shape_fn(D, |i| v[i]).into_pyarray(py)
}

pub(crate) fn mat_to<'py, const R: usize, const C: usize>(
    py: Python<'py>,
    m: &SMatrix<f64, R, C>,
) -> Bound<'py, PyArray2<f64>> {
    Array2::from_shape_fn((R, C), |(i, j)| m[(i, j)]).into_pyarray(py)
}

/// The UKF's counters as a dict.
pub(crate) fn recoveries_dict<'py>(
    py: Python<'py>,
    r: &Recoveries,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("resymmetrised", r.resymmetrised)?;
    d.set_item("covariance_resets", r.covariance_resets)?;
    d.set_item("rejected", r.rejected)?;
    d.set_item("predicts", r.predicts)?;
    d.set_item("updates", r.updates)?;
    Ok(d)
}

/// A constructor's UKF error: its `P` and `x` are the arguments `P0`, `x0`.
pub(crate) fn setup_err(e: UkfError) -> PyErr {
    use sensaug_core::ukf::Arg;
    match e {
        UkfError::NotPositiveDefinite { which: Arg::P } => {
            PyValueError::new_err("P0: must be symmetric positive definite")
        }
        UkfError::NonFiniteArgument { which: Arg::P } => {
            PyValueError::new_err("P0: must be finite (no NaN or inf)")
        }
        UkfError::NonFiniteArgument { which: Arg::X } => {
            PyValueError::new_err("x0: must be finite (no NaN or inf)")
        }
        other => to_py(other),
    }
}

/// An estimator's set-up error.
pub(crate) fn estimator_err(e: sensaug_core::estimator::EstimatorError) -> PyErr {
    use sensaug_core::estimator::EstimatorError;
    match e {
        EstimatorError::InvalidModel(name) => PyValueError::new_err(format!(
            "{name}: out of range (mass, dt and partner_window_s > 0; damping >= 0; all finite)"
        )),
        EstimatorError::Ukf(u) => setup_err(u),
    }
}
