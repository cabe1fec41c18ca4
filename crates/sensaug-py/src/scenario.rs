//! `_core.run_scenario`: one whole trial in Rust from a resolved
//! configuration dict (built by `sensaug.experiment`), returning the tick
//! records as the log schema's columns (`sensaug-log`). Conversion only.
#![allow(non_snake_case)]

use crate::convert::{estimator_err, mat_from, vec_from};
use numpy::{PyReadonlyArray1, PyReadonlyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use sensaug_core::estimator::{ExtendedFilterConfig, GoalIntegratorConfig, HandleModel};
use sensaug_core::plant::{PlantParams, PlantState};
use sensaug_core::scenario::{
    PartnerConfig, Phase, PhaseKind, RobotConfig, Scenario, ScenarioError, TickRecord, WorldConfig,
};
use sensaug_core::target::{Shape, Target, MAX_PARTS};
use sensaug_core::ukf::MerweParams;
use sensaug_log::Row;

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(run_scenario, m)?)?;
    Ok(())
}

/// A dict entry, or a `ValueError` naming its dotted path.
fn item<'py>(d: &Bound<'py, PyDict>, key: &str, path: &str) -> PyResult<Bound<'py, PyAny>> {
    d.get_item(key)?
        .ok_or_else(|| PyValueError::new_err(format!("{path}.{key}: missing")))
}

fn num(d: &Bound<'_, PyDict>, key: &str, path: &str) -> PyResult<f64> {
    item(d, key, path)?
        .extract::<f64>()
        .map_err(|_| PyValueError::new_err(format!("{path}.{key}: expected a number")))
}

fn sub<'py>(d: &Bound<'py, PyDict>, key: &str, path: &str) -> PyResult<Bound<'py, PyDict>> {
    item(d, key, path)?
        .cast_into::<PyDict>()
        .map_err(|_| PyValueError::new_err(format!("{path}.{key}: expected a table")))
}

fn arr1<const D: usize>(d: &Bound<'_, PyDict>, key: &str, path: &str) -> PyResult<[f64; D]> {
    let name = format!("{path}.{key}");
    let a: PyReadonlyArray1<f64> = item(d, key, path)?
        .extract()
        .map_err(|_| PyValueError::new_err(format!("{name}: expected a float64 array")))?;
    let v = vec_from::<D>(&a, &name)?;
    Ok(core::array::from_fn(|i| v[i]))
}

fn mat<const R: usize, const C: usize>(
    d: &Bound<'_, PyDict>,
    key: &str,
    path: &str,
) -> PyResult<nalgebra::SMatrix<f64, R, C>> {
    let name = format!("{path}.{key}");
    let a: PyReadonlyArray2<f64> = item(d, key, path)?
        .extract()
        .map_err(|_| PyValueError::new_err(format!("{name}: expected a 2-D float64 array")))?;
    mat_from::<R, C>(&a, &name)
}

/// A target shape with owned data (samples), borrowed into a core `Shape`.
enum ShapeSpec {
    Plain(Shape<'static>),
    Sampled(Vec<f64>, f64),
}

impl ShapeSpec {
    fn shape(&self) -> Shape<'_> {
        match self {
            ShapeSpec::Plain(s) => *s,
            ShapeSpec::Sampled(samples, dt_s) => Shape::Sampled {
                samples,
                dt_s: *dt_s,
            },
        }
    }
}

fn shape(d: &Bound<'_, PyDict>, path: &str) -> PyResult<ShapeSpec> {
    let kind: String = item(d, "kind", path)?.extract()?;
    let n = |k: &str| num(d, k, path);
    Ok(ShapeSpec::Plain(match kind.as_str() {
        "constant" => Shape::Constant { value: n("value")? },
        "square" => Shape::Square {
            amplitude: n("amplitude")?,
            period_s: n("period_s")?,
        },
        "rounded_square" => Shape::RoundedSquare {
            amplitude: n("amplitude")?,
            period_s: n("period_s")?,
        },
        "chirp" => Shape::Chirp {
            amplitude: n("amplitude")?,
            f0_hz: n("f0_hz")?,
            f1_hz: n("f1_hz")?,
            duration_s: n("duration_s")?,
        },
        "harmonics" => Shape::Harmonics {
            amplitude: n("amplitude")?,
            omega_rad_s: n("omega_rad_s")?,
            harmonics: item(d, "harmonics", path)?.extract()?,
            cosine: item(d, "cosine", path)?.extract()?,
        },
        "sampled" => {
            let samples: Vec<f64> = item(d, "samples", path)?.extract()?;
            return Ok(ShapeSpec::Sampled(samples, n("dt_s")?));
        }
        other => {
            return Err(PyValueError::new_err(format!(
                "{path}.kind: unknown shape {other:?}"
            )))
        }
    }))
}

struct PhaseSpec {
    kind: PhaseKind,
    duration_s: f64,
    target_noise_std: f64,
    robot: Vec<ShapeSpec>,
    partner: Vec<ShapeSpec>,
}

fn target_specs(d: &Bound<'_, PyDict>, key: &str, path: &str) -> PyResult<Vec<ShapeSpec>> {
    let list = item(d, key, path)?
        .cast_into::<PyList>()
        .map_err(|_| PyValueError::new_err(format!("{path}.{key}: expected a list of shapes")))?;
    if list.is_empty() || list.len() > MAX_PARTS {
        return Err(PyValueError::new_err(format!(
            "{path}.{key}: needs 1 to {MAX_PARTS} shapes, got {}",
            list.len()
        )));
    }
    list.iter()
        .enumerate()
        .map(|(i, s)| {
            let p = format!("{path}.{key}[{i}]");
            let s = s
                .cast_into::<PyDict>()
                .map_err(|_| PyValueError::new_err(format!("{p}: expected a table")))?;
            shape(&s, &p)
        })
        .collect()
}

fn target(specs: &[ShapeSpec]) -> Target<'_> {
    let mut t = Target::default();
    for (slot, s) in t.parts.iter_mut().zip(specs) {
        *slot = s.shape();
    }
    t
}

fn phase_specs(cfg: &Bound<'_, PyDict>) -> PyResult<Vec<PhaseSpec>> {
    let list = item(cfg, "phases", "config")?
        .cast_into::<PyList>()
        .map_err(|_| PyValueError::new_err("phases: expected a list"))?;
    list.iter()
        .enumerate()
        .map(|(i, p)| {
            let path = format!("phases[{i}]");
            let p = p
                .cast_into::<PyDict>()
                .map_err(|_| PyValueError::new_err(format!("{path}: expected a table")))?;
            let kind: String = item(&p, "kind", &path)?.extract()?;
            let kind = match kind.as_str() {
                "gains" => PhaseKind::Gains,
                "trajectory" => PhaseKind::Trajectory,
                "integration" => PhaseKind::Integration,
                other => {
                    return Err(PyValueError::new_err(format!(
                        "{path}.kind: unknown phase {other:?}"
                    )))
                }
            };
            Ok(PhaseSpec {
                kind,
                duration_s: num(&p, "duration_s", &path)?,
                target_noise_std: num(&p, "target_noise_std", &path)?,
                robot: target_specs(&p, "robot_target", &path)?,
                partner: target_specs(&p, "partner_target", &path)?,
            })
        })
        .collect()
}

fn extended<const M: usize>(
    d: &Bound<'_, PyDict>,
    path: &str,
    sigma: MerweParams,
) -> PyResult<ExtendedFilterConfig<M>> {
    Ok(ExtendedFilterConfig {
        x0: nalgebra::SVector::<f64, 6>::from(arr1::<6>(d, "x0", path)?),
        P0: mat(d, "P0", path)?,
        Q: mat(d, "Q", path)?,
        R: mat(d, "R", path)?,
        sigma,
    })
}

fn robot_config(d: &Bound<'_, PyDict>, dt_s: f64) -> PyResult<RobotConfig> {
    let p = "robot";
    let sigma_d = sub(d, "sigma", p)?;
    let sigma = MerweParams {
        alpha: num(&sigma_d, "alpha", "robot.sigma")?,
        beta: num(&sigma_d, "beta", "robot.sigma")?,
        kappa: num(&sigma_d, "kappa", "robot.sigma")?,
    };
    let model_d = sub(d, "model", p)?;
    let s3 = sub(d, "stage3", p)?;
    let prior = item(d, "prior_partner_gains", p)?;
    Ok(RobotConfig {
        gains: arr1::<3>(d, "gains", p)?,
        model: HandleModel {
            mass: num(&model_d, "mass", "robot.model")?,
            damping: num(&model_d, "damping", "robot.model")?,
            dt_s,
        },
        stage1: extended(&sub(d, "stage1", p)?, "robot.stage1", sigma)?,
        stage2: extended(&sub(d, "stage2", p)?, "robot.stage2", sigma)?,
        stage3: GoalIntegratorConfig {
            x0: nalgebra::Vector2::zeros(),
            P0: mat(&s3, "P0", "robot.stage3")?,
            Q: mat(&s3, "Q", "robot.stage3")?,
            R_own: mat(&s3, "R_sensor", "robot.stage3")?,
            partner_window_s: num(&s3, "partner_window_s", "robot.stage3")?,
            sigma,
        },
        integrate: item(d, "integrate", p)?.extract()?,
        gain_window_s: num(d, "gain_window_s", p)?,
        prior_partner_gains: if prior.is_none() {
            None
        } else {
            Some(arr1::<3>(d, "prior_partner_gains", p)?)
        },
        torque_limit: num(d, "torque_limit", p)?,
        seed: item(d, "seed", p)?.extract()?,
    })
}

fn scenario_err(e: ScenarioError) -> PyErr {
    let msg = match e {
        ScenarioError::PhaseCount(n) => format!("phases: need 1 to 4 phases, got {n}"),
        ScenarioError::InvalidPhase { phase, field } => {
            format!("phases[{phase}].{field}: out of range")
        }
        ScenarioError::InvalidTarget {
            phase,
            which,
            error,
        } => format!(
            "phases[{phase}].{which}[{}].{}: out of range",
            error.part, error.field
        ),
        ScenarioError::NoPartnerGains { phase } => format!(
            "phases[{phase}].kind: needs an earlier 'gains' phase or robot.prior_partner_gains"
        ),
        ScenarioError::InvalidSetting(name) => format!("{name}: out of range"),
        ScenarioError::Plant(p) => format!("plant: {p:?}"),
        ScenarioError::Estimator { stage, error } => {
            let inner = estimator_err(error);
            return PyValueError::new_err(format!(
                "robot.{stage}: {}",
                Python::attach(|py| inner.value(py).to_string())
            ));
        }
        ScenarioError::OutputTooShort { needed, got } => {
            format!("internal: output buffer {got} < {needed}")
        }
    };
    PyValueError::new_err(msg)
}

/// Runs one trial. Returns `(columns, summary)`: one array per column of the
/// log schema (`log_schema()`), by name.
#[pyfunction]
fn run_scenario<'py>(
    py: Python<'py>,
    config: &Bound<'py, PyDict>,
) -> PyResult<(Bound<'py, PyDict>, Bound<'py, PyDict>)> {
    let plant_d = sub(config, "plant", "config")?;
    let plant = PlantParams {
        mass: num(&plant_d, "mass", "plant")?,
        damping: num(&plant_d, "damping", "plant")?,
        coulomb: num(&plant_d, "coulomb", "plant")?,
        dt_s: num(&plant_d, "dt_s", "plant")?,
    };
    let world_d = sub(config, "world", "config")?;
    let world = WorldConfig {
        plant,
        initial: PlantState {
            x: num(&world_d, "x0", "world")?,
            v: num(&world_d, "v0", "world")?,
        },
        motor_noise_std: num(&world_d, "motor_noise_std", "world")?,
        position_noise_std: num(&world_d, "position_noise_std", "world")?,
        velocity_noise_std: num(&world_d, "velocity_noise_std", "world")?,
        seed: item(&world_d, "seed", "world")?.extract()?,
    };
    let partner_d = sub(config, "partner", "config")?;
    let partner = PartnerConfig {
        gains: arr1::<3>(&partner_d, "gains", "partner")?,
        torque_limit: num(&partner_d, "torque_limit", "partner")?,
        estimates_robot: item(&partner_d, "estimates_robot", "partner")?.extract()?,
    };
    let robot = robot_config(&sub(config, "robot", "config")?, plant.dt_s)?;
    let specs = phase_specs(config)?;
    let phases: Vec<Phase<'_>> = specs
        .iter()
        .map(|s| Phase {
            kind: s.kind,
            duration_s: s.duration_s,
            target_noise_std: s.target_noise_std,
            robot_target: target(&s.robot),
            partner_target: target(&s.partner),
        })
        .collect();
    let mut scenario = Scenario::new(&phases, robot, partner, world).map_err(scenario_err)?;
    let mut records = vec![TickRecord::default(); scenario.ticks()];
    let summary = py
        .detach(|| scenario.run(&mut records))
        .map_err(scenario_err)?;
    let rows: Vec<Row> = records
        .iter()
        .enumerate()
        .map(|(k, r)| Row::from_tick_record(k as u64, r))
        .collect();
    let out = crate::log::rows_to_columns(py, &rows)?;
    let d = PyDict::new(py);
    d.set_item("ticks", summary.ticks)?;
    d.set_item("robot_clamped", summary.robot.clamped)?;
    d.set_item("robot_non_finite", summary.robot.non_finite)?;
    d.set_item("estimator_errors", summary.robot.estimator_errors)?;
    d.set_item("resymmetrised", summary.robot.resymmetrised)?;
    d.set_item("partner_guarded", summary.partner_guarded)?;
    d.set_item("mirror_errors", summary.mirror_errors)?;
    Ok((out, d))
}
