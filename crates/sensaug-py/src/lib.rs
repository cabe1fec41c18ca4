//! Python bindings for `sensaug-core`. Type conversion only: every function
//! here fills core structs from Python values, calls the core once, and
//! converts the result back (`convert` holds the one set of conversions).
use pyo3::pymodule;

pub mod convert;
pub mod estimators;
mod log;
mod plant;
mod riccati;
mod scenario;

#[pymodule]
mod _core {
    #[pymodule_export]
    use crate::{
        convert::{PyStatus, RiccatiConvergenceError, UkfStepError},
        estimators::{GainEstimator, GoalIntegrator, TrajectoryEstimator},
        log::{config_sha256, git_commit, log_schema, write_log},
        plant::Plant,
        riccati::{agent_gains, lqr},
        scenario::{available_memory, check_output_paths, config_schema, Config},
        scenario::{replay_robot, resolve_count, run_scenario},
    };
}
