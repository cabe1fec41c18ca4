//! The binding's one set of conversions: numpy <-> nalgebra and slices, and
//! one mapping from every core error to a Python exception naming the argument
//! (the message is the core error's own `Display`).
use nalgebra::{SMatrix, SVector};
use numpy::ndarray::Array2;
use numpy::PyUntypedArrayMethods;
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArrayDyn, PyArrayMethods, PyReadonlyArray};
use numpy::{PyReadonlyArray1, PyReadonlyArray2};
use pyo3::exceptions::{PyRuntimeError, PyTypeError, PyValueError};
use pyo3::types::{IntoPyDict, PyBool, PyDict};
use pyo3::{create_exception, prelude::*};
use sensaug_core::estimator::EstimatorError;
use sensaug_core::plant::PlantError;
use sensaug_core::replay::ReplayError;
use sensaug_core::riccati::RiccatiError;
use sensaug_core::ukf::{Recoveries, RunReport, Status, UkfError};

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

/// `obj` as an array of real numbers: a float64 numpy array as it is, else
/// whatever `numpy.asarray` reads as integers or floats (lists, int or
/// float32 arrays), converted to float64. Anything else (str, None, bool,
/// complex, ragged lists) is refused naming the argument `name`.
pub fn real_array<'py>(
    obj: &Bound<'py, PyAny>,
    name: &str,
) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
    if let Ok(a) = obj.cast::<PyArrayDyn<f64>>() {
        return Ok(a.clone());
    }
    let py = obj.py();
    let np = PyModule::import(py, "numpy")?;
    let got = type_name(obj);
    let arr = np.call_method1("asarray", (obj,)).map_err(|e| {
        PyValueError::new_err(format!(
            "{name}: expected an array of real numbers, cannot read this {got} as one ({})",
            e.value(py)
        ))
    })?;
    let dtype = arr.getattr("dtype")?;
    let kind: String = dtype.getattr("kind")?.extract()?;
    if !matches!(kind.as_str(), "f" | "i" | "u") {
        return Err(PyTypeError::new_err(format!(
            "{name}: expected real numbers (int or float), got {}",
            if kind == "O" {
                got
            } else {
                format!("an array of {}", dtype.str()?)
            }
        )));
    }
    let arr = arr.call_method1("astype", ("float64",))?;
    Ok(arr.cast_into::<PyArrayDyn<f64>>()?)
}

/// The type of `obj` as Python names it.
fn type_name(obj: &Bound<'_, PyAny>) -> String {
    obj.get_type()
        .name()
        .map_or_else(|_| "object".to_owned(), |n| n.to_string())
}

/// `obj` (any array-like, [`real_array`]) as a 2-D float64 array of any
/// shape; `name` is the argument in the error.
pub fn array2<'py>(obj: &Bound<'py, PyAny>, name: &str) -> PyResult<PyReadonlyArray2<'py, f64>> {
    let a = real_array(obj, name)?;
    if a.ndim() != 2 {
        return Err(PyValueError::new_err(format!(
            "{name}: expected a 2-D array, got shape {}",
            shape(a.shape())
        )));
    }
    Ok(a.cast_into::<PyArray2<f64>>()?.readonly())
}

/// `obj` (any array-like, [`real_array`]) as a fixed-size matrix; `name` is
/// the argument in the error.
pub fn matrix<const R: usize, const C: usize>(
    obj: &Bound<'_, PyAny>,
    name: &str,
) -> PyResult<SMatrix<f64, R, C>> {
    let a = real_array(obj, name)?.readonly();
    let v = a.as_array();
    if v.shape() != [R, C] {
        return Err(PyValueError::new_err(format!(
            "{name}: expected shape ({R}, {C}), got {}",
            shape(v.shape())
        )));
    }
    Ok(SMatrix::from_fn(|i, j| v[[i, j]]))
}

/// `obj` (any array-like, [`real_array`]) as a fixed-size vector; `name` is
/// the argument in the error.
pub fn vector<const D: usize>(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<SVector<f64, D>> {
    let a = real_array(obj, name)?.readonly();
    let v = a.as_array();
    if v.shape() != [D] {
        return Err(PyValueError::new_err(format!(
            "{name}: expected shape ({D},), got {}",
            shape(v.shape())
        )));
    }
    Ok(SVector::from_fn(|i, _| v[[i]]))
}

/// `obj` as a real number (int, float or a numpy scalar, not bool, str or
/// complex); `name` is the argument in the error.
pub fn real(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<f64> {
    let refused = || {
        PyTypeError::new_err(format!(
            "{name}: expected a real number, got {}",
            type_name(obj)
        ))
    };
    if obj.is_instance_of::<PyBool>() {
        return Err(refused());
    }
    obj.extract::<f64>().map_err(|_| refused())
}

/// An optional keyword: `None` when not given (its default is the callee's).
pub type Opt<'a, 'py> = Option<&'a Bound<'py, PyAny>>;

/// `obj` as a real number ([`real`]), or `default` when not given.
pub fn real_or(obj: Opt<'_, '_>, name: &str, default: f64) -> PyResult<f64> {
    obj.map_or(Ok(default), |o| real(o, name))
}

/// A shape as Python prints it: `(3,)`, `(2, 3)`, `()`.
pub fn shape(s: &[usize]) -> String {
    match s {
        [n] => format!("({n},)"),
        _ => format!(
            "({})",
            s.iter()
                .map(|n| n.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

/// `a` as a fixed-size matrix; `name` is the argument in the error.
pub fn mat_from<const R: usize, const C: usize>(
    a: &PyReadonlyArray2<'_, f64>,
    name: &str,
) -> PyResult<SMatrix<f64, R, C>> {
    if a.shape() != [R, C] {
        return Err(PyValueError::new_err(format!(
            "{name}: expected shape ({R}, {C}), got {}",
            shape(a.shape())
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
        return Err(PyValueError::new_err(format!(
            "{name}: expected shape ({D},), got {}",
            shape(a.shape())
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

/// How a UKF step went (the core's `ukf::Status`): `Status.Nominal()`, or
/// `Status.Resymmetrised(stage=...)` with the stage that was repaired (a
/// counted repair); `str()` gives `nominal` / `resymmetrised:<stage>`.
#[pyclass(name = "Status", module = "sensaug._core", frozen, eq)]
#[derive(Clone, Debug, PartialEq)]
pub enum PyStatus {
    Nominal(),
    Resymmetrised { stage: String },
}

impl std::fmt::Display for PyStatus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            PyStatus::Nominal() => f.write_str("nominal"),
            PyStatus::Resymmetrised { stage } => write!(f, "resymmetrised:{stage}"),
        }
    }
}

#[pymethods]
impl PyStatus {
    fn __str__(&self) -> String {
        self.to_string()
    }
}

/// The core's status as [`PyStatus`].
pub fn status(s: Status) -> PyStatus {
    match s {
        Status::Nominal => PyStatus::Nominal(),
        Status::Resymmetrised { stage } => PyStatus::Resymmetrised {
            stage: stage.name().to_owned(),
        },
    }
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

/// The exception kind and the core's own message (its `Display`: the
/// argument first, then what is wrong and how to fix it).
fn describe(e: CoreError) -> (Kind, String) {
    use Kind::{Convergence, Step, Value};
    match e {
        // A constructor's UKF arguments are the estimators' `x0` and `P0`.
        CoreError::Setup(u) => (Value, EstimatorError::Ukf(u).to_string()),
        CoreError::Estimator(e) => (Value, e.to_string()),
        CoreError::Ukf(e) => {
            let kind = match e {
                UkfError::NonFiniteMeasurement
                | UkfError::NonFiniteProcess
                | UkfError::NonFiniteMeasurementModel
                | UkfError::NonFiniteResult { .. }
                | UkfError::CovarianceReset { .. } => Step,
                _ => Value,
            };
            (kind, e.to_string())
        }
        CoreError::Replay(e) => (Value, e.to_string()),
        CoreError::Plant(e) => (Value, e.to_string()),
        CoreError::Riccati(
            e @ (RiccatiError::NoConvergence
            | RiccatiError::ResidualTooLarge { .. }
            | RiccatiError::NotStabilizing),
        ) => (Convergence, e.to_string()),
        CoreError::Riccati(e) => (Value, e.to_string()),
        CoreError::Run(r) => (
            Step,
            match r.first_error {
                Some(first) => format!(
                    "{} step error(s); first at step {} ({}): {}",
                    r.errors,
                    first.step,
                    first.phase.name(),
                    first.error
                ),
                None => "no step error".into(),
            },
        ),
    }
}
