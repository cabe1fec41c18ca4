//! Python bindings for `sensaug-core`. Type conversion only: every function
//! here fills core structs from Python values, calls the core once, and
//! converts the result back.
use pyo3::prelude::*;

mod convert;
mod estimators;
mod log;
mod plant;
mod riccati;
mod scenario;
mod ukf;

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    estimators::register(m)?;
    log::register(m)?;
    plant::register(m)?;
    riccati::register(m)?;
    scenario::register(m)?;
    ukf::register(m)?;
    Ok(())
}
