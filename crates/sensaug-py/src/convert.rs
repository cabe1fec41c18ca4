//! The binding's one set of conversions: float64 arrays -> core matrices
//! (a wrong shape names the argument; `sensaug/_args.py` turns a user's
//! array-likes and numbers into these typed arguments), core values and
//! errors -> Python (an error's message is the core's own `Display`).
use nalgebra::SMatrix;
use numpy::PyReadonlyArrayDyn;
use numpy::PyUntypedArrayMethods;
use numpy::{PyArray1, PyArrayDyn, PyArrayMethods, PyReadonlyArray, PyReadonlyArray1};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::types::PyTuple;
use pyo3::{create_exception, prelude::*};
use sensaug_core::ukf::Status;

create_exception!(_core, UkfStepError, PyRuntimeError);
create_exception!(_core, RiccatiConvergenceError, PyRuntimeError);

/// A float64 array argument; its shape is checked where it is read.
pub type Array<'py> = PyReadonlyArrayDyn<'py, f64>;

/// The numpy shape of an `R x C` core matrix: `(R,)` for a vector (`C = 1`).
fn dims<const R: usize, const C: usize>() -> Vec<usize> {
    if C == 1 {
        vec![R]
    } else {
        vec![R, C]
    }
}

/// `a` as an `R x C` core matrix, of shape [`dims`]; `name` is the argument.
pub fn read<const R: usize, const C: usize>(
    a: &Array<'_>,
    name: &str,
) -> PyResult<SMatrix<f64, R, C>> {
    let (v, want) = (a.as_array(), dims::<R, C>());
    if v.shape() != want {
        let shape = |s: &[usize]| PyTuple::new(a.py(), s).and_then(|t| t.repr());
        let msg = format!(
            "{name}: expected shape {}, got {}",
            shape(&want)?,
            shape(v.shape())?
        );
        return Err(PyValueError::new_err(msg));
    }
    Ok(SMatrix::from_row_iterator(v.iter().copied()))
}

/// A C-contiguous array's data, row-major. Any other layout is an error:
/// numpy's `as_slice` also takes a Fortran-ordered array (as pandas'
/// `to_numpy()` often returns), whose data read row-major would be its
/// transpose's.
pub fn slice<'a, T: numpy::Element, D: numpy::ndarray::Dimension>(
    a: &'a PyReadonlyArray<'_, T, D>,
    name: &str,
) -> PyResult<&'a [T]> {
    let msg = || format!("{name}: must be C-contiguous (use np.ascontiguousarray)");
    let data = a.as_slice().ok().filter(|_| a.is_c_contiguous());
    data.ok_or_else(|| PyValueError::new_err(msg()))
}

/// A core matrix as a numpy array of shape [`dims`].
pub fn array<'py, const R: usize, const C: usize>(
    py: Python<'py>,
    m: &SMatrix<f64, R, C>,
) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
    // nalgebra stores column-major: the transpose's storage is `m` row-major.
    PyArray1::from_slice(py, m.transpose().as_slice()).reshape(dims::<R, C>())
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
                pyo3::IntoPyObjectExt::into_py_any($e, $py)
            })*
        }
    };
}
pub(crate) use methods;

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

/// Log rows from the bytes of packed records (`sensaug_log::PackedRow`).
pub fn rows(records: &PyReadonlyArray1<'_, u8>) -> PyResult<Vec<sensaug_log::Row>> {
    sensaug_log::rows_from_records(slice(records, "records")?)
        .map_err(|e| PyValueError::new_err(e.to_string()))
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
