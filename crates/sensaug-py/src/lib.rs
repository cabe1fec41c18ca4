//! Python bindings for `sensaug-core`. Type conversion only: every function
//! here fills core structs from Python values, calls the core once, and
//! converts the result back.
use pyo3::prelude::*;

mod plant;
mod riccati;
mod ukf;

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    plant::register(m)?;
    riccati::register(m)?;
    ukf::register(m)?;
    Ok(())
}
