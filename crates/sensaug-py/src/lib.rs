//! Python bindings for `sensaug-core`. Type conversion only: every function
//! here fills core structs from Python values, calls the core once, and
//! converts the result back (`convert` holds the one set of conversions).
use pyo3::prelude::*;

pub mod convert;
pub mod estimators;
mod log;
mod plant;
mod replay;
mod riccati;
mod scenario;

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    estimators::register(m)?;
    log::register(m)?;
    plant::register(m)?;
    replay::register(m)?;
    riccati::register(m)?;
    scenario::register(m)?;
    let py = m.py();
    m.add("UkfStepError", py.get_type::<convert::UkfStepError>())?;
    m.add_class::<convert::PyStatus>()?;
    m.add(
        "RiccatiConvergenceError",
        py.get_type::<convert::RiccatiConvergenceError>(),
    )
}
