//! The binding's one set of conversions: Python values -> core arguments
//! (each refusal names the argument), core values and errors -> Python (an
//! error's message is the core's own `Display`).
use nalgebra::SMatrix;
use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArrayDyn, PyArrayMethods, PyReadonlyArray};
use numpy::{PyUntypedArrayMethods, ToPyArray};
use pyo3::exceptions::{PyRuntimeError, PyTypeError, PyValueError};
use pyo3::types::{IntoPyDict, PyBool, PyDict, PyTuple};
use pyo3::{create_exception, prelude::*};
use sensaug_core::ukf::{Recoveries, Status};

create_exception!(_core, UkfStepError, PyRuntimeError);
create_exception!(_core, RiccatiConvergenceError, PyRuntimeError);

/// `obj` as a float64 array: as it is, or what `numpy.asarray` reads as
/// integers or floats; anything else is refused naming the argument `name`.
pub fn real_array<'py>(
    obj: &Bound<'py, PyAny>,
    name: &str,
) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
    if let Ok(a) = obj.cast::<PyArrayDyn<f64>>() {
        return Ok(a.clone());
    }
    let (py, got) = (obj.py(), type_name(obj));
    let arr = PyModule::import(py, "numpy")?
        .call_method1("asarray", (obj,))
        .map_err(|e| {
            let why = e.value(py);
            PyValueError::new_err(format!(
                "{name}: expected an array of real numbers, cannot read this {got} as one ({why})"
            ))
        })?;
    let dtype = arr.getattr("dtype")?;
    let kind: String = dtype.getattr("kind")?.extract()?;
    if !matches!(kind.as_str(), "f" | "i" | "u") {
        let what = if kind == "O" {
            got
        } else {
            format!("an array of {}", dtype.str()?)
        };
        let msg = format!("{name}: expected real numbers (int or float), got {what}");
        return Err(PyTypeError::new_err(msg));
    }
    Ok(arr
        .call_method1("astype", ("float64",))?
        .cast_into::<PyArrayDyn<f64>>()?)
}

fn type_name(obj: &Bound<'_, PyAny>) -> String {
    obj.get_type()
        .name()
        .map_or_else(|_| "object".to_owned(), |n| n.to_string())
}

/// A shape as Python prints it: `(3,)`, `(2, 3)`.
fn shape(py: Python<'_>, s: &[usize]) -> PyResult<String> {
    Ok(PyTuple::new(py, s)?.repr()?.to_string())
}

/// `obj` ([`real_array`]) of shape `want` (its `R x C` entries row-major).
fn read<const R: usize, const C: usize>(
    obj: &Bound<'_, PyAny>,
    name: &str,
    want: &[usize],
) -> PyResult<SMatrix<f64, R, C>> {
    let a = real_array(obj, name)?.readonly();
    let v = a.as_array();
    if v.shape() != want {
        let (want, got) = (shape(obj.py(), want)?, shape(obj.py(), v.shape())?);
        return Err(PyValueError::new_err(format!(
            "{name}: expected shape {want}, got {got}"
        )));
    }
    let mut it = v.iter();
    Ok(SMatrix::from_row_iterator(std::iter::from_fn(|| {
        it.next().copied()
    })))
}

/// `obj` ([`real_array`]) as an `R x C` matrix; `name` is the argument.
pub fn matrix<const R: usize, const C: usize>(
    obj: &Bound<'_, PyAny>,
    name: &str,
) -> PyResult<SMatrix<f64, R, C>> {
    read(obj, name, &[R, C])
}

/// `obj` ([`real_array`]) as a vector of `D` entries; `name` is the argument.
pub fn vector<const D: usize>(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<SMatrix<f64, D, 1>> {
    read(obj, name, &[D])
}

/// `obj` ([`real_array`]) as a 2-D array: its entries row-major and its shape.
pub fn array2(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<(Vec<f64>, [usize; 2])> {
    let a = real_array(obj, name)?.readonly();
    match *a.shape() {
        [r, c] => Ok((a.as_array().iter().copied().collect(), [r, c])),
        ref s => Err(PyValueError::new_err(format!(
            "{name}: expected a 2-D array, got shape {}",
            shape(obj.py(), s)?
        ))),
    }
}

/// `obj` as a real number (int, float or a numpy scalar, not bool, str or
/// complex); `name` is the argument.
pub fn real(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<f64> {
    let got = || format!("{name}: expected a real number, got {}", type_name(obj));
    if obj.is_instance_of::<PyBool>() {
        return Err(PyTypeError::new_err(got()));
    }
    obj.extract::<f64>()
        .map_err(|_| PyTypeError::new_err(got()))
}

/// A constructor's optional keywords (its `**kw`) as real numbers
/// ([`real`]): `names`' values, each its entry of `defaults` (the schema's)
/// where not given; a keyword not among `names` is a `TypeError` naming it.
pub fn settings<const K: usize>(
    given: Option<&Bound<'_, PyDict>>,
    names: [&str; K],
    defaults: [f64; K],
) -> PyResult<[f64; K]> {
    let mut out = defaults;
    for (key, value) in given.into_iter().flatten() {
        let key = key.str()?.to_string();
        let Some(i) = names.iter().position(|name| *name == key) else {
            let msg = format!("{key}: not a keyword here; the optional ones are {names:?}");
            return Err(PyTypeError::new_err(msg));
        };
        out[i] = real(&value, &key)?;
    }
    Ok(out)
}

/// A C-contiguous array's data, row-major.
pub fn slice<'a, T: numpy::Element, D: numpy::ndarray::Dimension>(
    a: &'a PyReadonlyArray<'_, T, D>,
    name: &str,
) -> PyResult<&'a [T]> {
    let msg = || format!("{name}: must be C-contiguous (use np.ascontiguousarray)");
    a.as_slice().map_err(|_| PyValueError::new_err(msg()))
}

pub fn mat_to<'py, const R: usize, const C: usize>(
    py: Python<'py>,
    m: &SMatrix<f64, R, C>,
) -> Bound<'py, PyArray2<f64>> {
    Array2::from_shape_fn((R, C), |(i, j)| m[(i, j)]).into_pyarray(py)
}

pub fn vec_to<'py, const D: usize>(
    py: Python<'py>,
    v: &SMatrix<f64, D, 1>,
) -> Bound<'py, PyArray1<f64>> {
    v.as_slice().to_pyarray(py)
}

/// How a UKF step went (the core's `ukf::Status`).
#[pyclass(name = "Status", module = "sensaug._core", frozen, eq)]
#[derive(Clone, Debug, PartialEq)]
pub enum PyStatus {
    Nominal(),
    Resymmetrised { stage: String },
}

#[pymethods]
impl PyStatus {
    fn __str__(&self) -> String {
        match self {
            PyStatus::Nominal() => "nominal".into(),
            PyStatus::Resymmetrised { stage } => format!("resymmetrised:{stage}"),
        }
    }
}

pub fn status(s: Status) -> PyStatus {
    match s {
        Status::Nominal => PyStatus::Nominal(),
        Status::Resymmetrised { stage } => PyStatus::Resymmetrised {
            stage: stage.name().to_owned(),
        },
    }
}

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

/// The one error mapping: a core error as the Python exception of its kind
/// (`sensaug_core::ErrorKind`), its message the core's own `Display`.
pub fn py_err(e: impl sensaug_core::CoreError) -> PyErr {
    use sensaug_core::ErrorKind;
    let text = e.to_string();
    match e.kind() {
        ErrorKind::Argument => PyValueError::new_err(text),
        ErrorKind::StepFailure => UkfStepError::new_err(text),
        ErrorKind::SolverFailure => RiccatiConvergenceError::new_err(text),
    }
}

// The configuration's exceptions are Python classes, raised with
// `(field, message)`, which they keep as `.field` and `.message`.
pyo3::import_exception!(sensaug.config, ConfigError);
pyo3::import_exception!(sensaug.experiment, TrialTooLargeError);

pub fn config_err(e: sensaug_config::ConfigError) -> PyErr {
    ConfigError::new_err((e.field, e.message))
}

/// A simulated trial that did not run: too large, or (a bug) rejected.
pub fn trial_err(e: sensaug_config::TrialError) -> PyErr {
    match e {
        sensaug_config::TrialError::TooLarge(e) => {
            let field = sensaug_core::world::LogTooLarge::FIELD;
            TrialTooLargeError::new_err((field, e.message().to_string()))
        }
        sensaug_config::TrialError::Rejected(e) => config_err(e.into()),
    }
}
