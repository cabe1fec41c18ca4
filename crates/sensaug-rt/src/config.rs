//! The trial configuration, read from the same TOML files as the Python API
//! (`python/sensaug/config.py`), plus the `[rig]` table of the real-time loop.
//!
//! Set-up only: parsing and validation allocate freely; the loop receives
//! the finished core structs. Every error names the field by its dotted
//! path, as the Python side does.

use core::f64::consts::PI;
use nalgebra::{SMatrix, SVector, Vector2};
use sensaug_core::estimator::{ExtendedFilterConfig, GoalIntegratorConfig, HandleModel};
use sensaug_core::riccati::agent_gains;
use sensaug_core::scenario::{PhaseKind, RobotConfig};
use sensaug_core::target::{Shape, Target, MAX_PARTS};
use sensaug_core::ukf::MerweParams;
use serde::{Deserialize, Serialize};
use std::fmt;
use std::path::PathBuf;

/// A configuration error: the dotted path of the field and what to do.
#[derive(Debug, Clone, PartialEq)]
pub struct ConfigError {
    /// e.g. `robot.stage1.Q`.
    pub field: String,
    /// What is wrong and how to fix it.
    pub message: String,
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.field, self.message)
    }
}

impl std::error::Error for ConfigError {}

fn err(field: impl Into<String>, message: impl Into<String>) -> ConfigError {
    ConfigError {
        field: field.into(),
        message: message.into(),
    }
}

/// A covariance: diagonal entries or a full nested list.
#[derive(Debug, Clone, Deserialize)]
#[serde(untagged)]
pub enum Cov {
    /// Diagonal entries.
    Diag(Vec<f64>),
    /// Full matrix, row by row.
    Full(Vec<Vec<f64>>),
}

impl Cov {
    fn matrix<const N: usize>(&self, field: &str) -> Result<SMatrix<f64, N, N>, ConfigError> {
        let m: SMatrix<f64, N, N> = match self {
            Cov::Diag(d) if d.len() == N => SMatrix::from_diagonal(&SVector::from_column_slice(d)),
            Cov::Full(rows) if rows.len() == N && rows.iter().all(|r| r.len() == N) => {
                SMatrix::from_fn(|i, j| rows[i][j])
            }
            _ => {
                return Err(err(
                    field,
                    format!("expected {N} diagonal entries or a {N}x{N} nested list"),
                ))
            }
        };
        if m.iter().any(|v| !v.is_finite()) {
            return Err(err(field, "must be finite (no NaN or inf)"));
        }
        if (m - m.transpose()).abs().max() > 1e-12 * m.abs().max() {
            return Err(err(field, "must be symmetric"));
        }
        if m.cholesky().is_none() {
            return Err(err(field, "must be positive definite; raise the diagonal"));
        }
        Ok(m)
    }
}

/// A target shape (`kind = "..."`).
#[derive(Debug, Clone, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
#[allow(missing_docs)]
pub enum ShapeSpec {
    Constant {
        value: f64,
    },
    Square {
        amplitude: f64,
        period_s: f64,
    },
    RoundedSquare {
        amplitude: f64,
        period_s: f64,
    },
    Chirp {
        amplitude: f64,
        f0_hz: f64,
        f1_hz: f64,
        duration_s: f64,
    },
    Harmonics {
        amplitude: f64,
        omega_rad_s: f64,
        #[serde(default = "three")]
        harmonics: u32,
        #[serde(default)]
        cosine: bool,
    },
    Sampled {
        samples: Vec<f64>,
        dt_s: f64,
    },
}

fn three() -> u32 {
    3
}

impl ShapeSpec {
    fn shape(&self) -> Shape<'_> {
        match *self {
            ShapeSpec::Constant { value } => Shape::Constant { value },
            ShapeSpec::Square {
                amplitude,
                period_s,
            } => Shape::Square {
                amplitude,
                period_s,
            },
            ShapeSpec::RoundedSquare {
                amplitude,
                period_s,
            } => Shape::RoundedSquare {
                amplitude,
                period_s,
            },
            ShapeSpec::Chirp {
                amplitude,
                f0_hz,
                f1_hz,
                duration_s,
            } => Shape::Chirp {
                amplitude,
                f0_hz,
                f1_hz,
                duration_s,
            },
            ShapeSpec::Harmonics {
                amplitude,
                omega_rad_s,
                harmonics,
                cosine,
            } => Shape::Harmonics {
                amplitude,
                omega_rad_s,
                harmonics,
                cosine,
            },
            ShapeSpec::Sampled { ref samples, dt_s } => Shape::Sampled { samples, dt_s },
        }
    }
}

/// `[[phases]]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
#[allow(missing_docs)]
pub struct PhaseSpec {
    pub kind: String,
    pub duration_s: f64,
    pub robot_target: Vec<ShapeSpec>,
    pub partner_target: Vec<ShapeSpec>,
    #[serde(default)]
    pub target_noise_std: f64,
}

/// `[plant]`: the handle as the controller's model sees it.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
#[allow(missing_docs)]
pub struct PlantSpec {
    #[serde(default = "hi5_mass")]
    pub mass: f64,
    #[serde(default)]
    pub damping: f64,
    #[serde(default)]
    pub coulomb: f64,
    #[serde(default = "one_ms")]
    pub dt_s: f64,
}

fn hi5_mass() -> f64 {
    0.0035
}
fn one_ms() -> f64 {
    1e-3
}

impl Default for PlantSpec {
    fn default() -> Self {
        PlantSpec {
            mass: hi5_mass(),
            damping: 0.0,
            coulomb: 0.0,
            dt_s: one_ms(),
        }
    }
}

/// `[world]`: simulation-only settings; the loop ignores them (the rig is
/// the world) but accepts them so one file serves both.
#[derive(Debug, Clone, Default, Deserialize)]
#[allow(missing_docs)]
pub struct WorldSpec {
    #[serde(flatten)]
    pub ignored: toml::Table,
}

/// `[robot.sigma]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
#[allow(missing_docs)]
pub struct SigmaSpec {
    #[serde(default = "one")]
    pub alpha: f64,
    #[serde(default = "two")]
    pub beta: f64,
    #[serde(default)]
    pub kappa: f64,
}

fn one() -> f64 {
    1.0
}
fn two() -> f64 {
    2.0
}

impl Default for SigmaSpec {
    fn default() -> Self {
        SigmaSpec {
            alpha: 1.0,
            beta: 2.0,
            kappa: 0.0,
        }
    }
}

/// `[robot.stage1]` / `[robot.stage2]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
#[allow(missing_docs, non_snake_case)]
pub struct FilterSpec {
    pub Q: Option<Cov>,
    pub R: Option<Cov>,
    pub P0: Option<Cov>,
    pub gains0: Option<Vec<f64>>,
}

/// `[robot.stage3]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
#[allow(missing_docs, non_snake_case)]
pub struct IntegratorSpec {
    pub Q: Option<Cov>,
    pub R_sensor: Option<Cov>,
    pub P0: Option<Cov>,
    #[serde(default = "window")]
    pub partner_window_s: f64,
}

fn window() -> f64 {
    0.2
}

/// `[robot]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
#[allow(missing_docs)]
pub struct RobotSpec {
    #[serde(default = "one")]
    pub q_pos: f64,
    #[serde(default)]
    pub q_vel: f64,
    #[serde(default = "yes")]
    pub integrate: bool,
    #[serde(default = "eight")]
    pub gain_window_s: f64,
    #[serde(default = "big_limit")]
    pub torque_limit: f64,
    #[serde(default = "one_u64")]
    pub seed: u64,
    pub prior_partner_gains: Option<Vec<f64>>,
    #[serde(default)]
    pub sigma: SigmaSpec,
    pub stage1: Option<FilterSpec>,
    pub stage2: Option<FilterSpec>,
    pub stage3: Option<IntegratorSpec>,
}

fn yes() -> bool {
    true
}
fn eight() -> f64 {
    8.0
}
fn big_limit() -> f64 {
    1e3
}
fn one_u64() -> u64 {
    1
}

/// `[partner]`: the virtual human inside the loop.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
#[allow(missing_docs)]
pub struct PartnerSpec {
    pub gains: Option<Vec<f64>>,
    pub q_pos: Option<f64>,
    pub q_vel: Option<f64>,
    #[serde(default = "big_limit")]
    pub torque_limit: f64,
    #[serde(default)]
    pub estimates_robot: bool,
}

/// Real-time settings of the loop thread.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct RealtimeSpec {
    /// SCHED_FIFO priority (1..=99); none keeps the default scheduler.
    pub fifo_priority: Option<i32>,
    /// CPU to pin the loop thread to.
    pub cpu: Option<usize>,
    /// Lock all memory (mlockall) before the loop.
    #[serde(default = "yes")]
    pub mlockall: bool,
}

impl Default for RealtimeSpec {
    fn default() -> Self {
        toml::from_str("").expect("every realtime field has a default")
    }
}

/// `[rig]`: the real-time loop and the CAN link.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct RigSpec {
    /// Transport URL: `udp:<port>` (virtual bus) or `socketcan:<ifname>`.
    #[serde(default = "default_can")]
    pub can: String,
    /// Drive node id, 0..=15.
    #[serde(default = "one_u8")]
    pub node_id: u8,
    /// Unit of the controller's positions: `"deg"` (the paper's Hi5 numbers)
    /// or `"rad"`. The drive speaks rad and N m; torque is scaled by the same
    /// factor (docs/model.md, Units).
    #[serde(default = "deg")]
    pub position_unit: String,
    /// Torque limit at the drive boundary (N m), > 0.
    #[serde(default = "three_nm")]
    pub torque_limit_nm: f64,
    /// Drive command watchdog (ms), 1..=65535.
    #[serde(default = "fifty")]
    pub watchdog_ms: u16,
    /// Feedback older than this stops the loop with an emergency stop (ms).
    #[serde(default = "twenty")]
    pub feedback_timeout_ms: f64,
    /// Ramp from the last command to zero on SIGINT/SIGTERM (s).
    #[serde(default = "ramp")]
    pub ramp_down_s: f64,
    /// Run the virtual human inside the loop (`false`: a real human holds the handle).
    #[serde(default = "yes")]
    pub virtual_human: bool,
    /// Log file (CSV with metadata, docs/logs.md).
    #[serde(default = "log_path")]
    pub log: PathBuf,
    /// Loop statistics (JSON).
    #[serde(default = "stats_path")]
    pub stats: PathBuf,
    /// Log ring capacity in records.
    #[serde(default = "ring")]
    pub ring_capacity: usize,
    /// Thread settings.
    #[serde(default)]
    pub realtime: RealtimeSpec,
}

fn default_can() -> String {
    "udp:47100".into()
}
fn one_u8() -> u8 {
    1
}
fn deg() -> String {
    "deg".into()
}
fn three_nm() -> f64 {
    3.0
}
fn fifty() -> u16 {
    50
}
fn twenty() -> f64 {
    20.0
}
fn ramp() -> f64 {
    0.2
}
fn log_path() -> PathBuf {
    "out/rig_log.csv".into()
}
fn stats_path() -> PathBuf {
    "out/rig_stats.json".into()
}
fn ring() -> usize {
    1 << 16
}

impl Default for RigSpec {
    fn default() -> Self {
        toml::from_str("").expect("every rig field has a default")
    }
}

/// The whole file.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
#[allow(missing_docs)]
pub struct FileSpec {
    pub phases: Vec<PhaseSpec>,
    #[serde(default)]
    pub plant: PlantSpec,
    #[serde(default)]
    pub world: WorldSpec,
    pub robot: Option<RobotSpec>,
    pub partner: Option<PartnerSpec>,
    #[serde(default)]
    pub rig: RigSpec,
}

/// Parses TOML text; syntax and type errors name the location.
pub fn parse(text: &str) -> Result<FileSpec, ConfigError> {
    toml::from_str(text).map_err(|e| {
        let span = e
            .span()
            .map(|s| {
                let line = text[..s.start].lines().count().max(1);
                format!("line {line}")
            })
            .unwrap_or_default();
        err(
            format!("<toml> {span}").trim().to_string(),
            e.message().to_string(),
        )
    })
}

fn positive(field: &str, v: f64) -> Result<f64, ConfigError> {
    if v.is_finite() && v > 0.0 {
        Ok(v)
    } else {
        Err(err(field, format!("must be finite and > 0, got {v}")))
    }
}

fn non_negative(field: &str, v: f64) -> Result<f64, ConfigError> {
    if v.is_finite() && v >= 0.0 {
        Ok(v)
    } else {
        Err(err(field, format!("must be finite and >= 0, got {v}")))
    }
}

/// A stage-1 (`M = 3`) or stage-2 (`M = 5`) filter from its table, with
/// the Python side's defaults: `Q = 1e-2 I6`, `R = 1e-7 I_M`,
/// `P0 = diag(1e-4 x3, 1 x3)`, initial gains 0.
fn extended_filter<const M: usize>(
    path: &str,
    spec: Option<&FilterSpec>,
    sigma: MerweParams,
) -> Result<ExtendedFilterConfig<M>, ConfigError> {
    let cov = |c: Option<&Cov>, default: Vec<f64>| c.cloned().unwrap_or(Cov::Diag(default));
    let mut x0 = SVector::<f64, 6>::zeros();
    if let Some(g) = spec.and_then(|s| s.gains0.as_ref()) {
        let g = gains3(&format!("{path}.gains0"), g)?;
        x0.fixed_rows_mut::<3>(3).copy_from_slice(&g);
    }
    Ok(ExtendedFilterConfig {
        x0,
        P0: cov(
            spec.and_then(|s| s.P0.as_ref()),
            vec![1e-4, 1e-4, 1e-4, 1.0, 1.0, 1.0],
        )
        .matrix::<6>(&format!("{path}.P0"))?,
        Q: cov(spec.and_then(|s| s.Q.as_ref()), vec![1e-2; 6]).matrix::<6>(&format!("{path}.Q"))?,
        R: cov(spec.and_then(|s| s.R.as_ref()), vec![1e-7; M]).matrix::<M>(&format!("{path}.R"))?,
        sigma,
    })
}

/// A phase's target from its shapes (validated).
fn target<'a>(path: &str, name: &str, specs: &'a [ShapeSpec]) -> Result<Target<'a>, ConfigError> {
    if specs.is_empty() || specs.len() > MAX_PARTS {
        return Err(err(
            format!("{path}.{name}"),
            format!("needs 1 to {MAX_PARTS} shapes"),
        ));
    }
    let mut t = Target::default();
    for (slot, s) in t.parts.iter_mut().zip(specs) {
        *slot = s.shape();
    }
    t.validate().map_err(|e| {
        err(
            format!("{path}.{name}[{}].{}", e.part, e.field),
            "out of range (amplitudes finite, periods/durations > 0, frequencies >= 0)",
        )
    })?;
    Ok(t)
}

fn gains3(field: &str, v: &[f64]) -> Result<[f64; 3], ConfigError> {
    match v {
        [a, b, c] if v.iter().all(|g| g.is_finite()) => Ok([*a, *b, *c]),
        _ => Err(err(field, "needs 3 finite entries [Lhx, Lhv, Lhh]")),
    }
}

/// Everything the loop needs, validated.
#[derive(Debug, Clone)]
pub struct Resolved<'a> {
    /// Phases for the core protocol.
    pub phases: Vec<sensaug_core::scenario::Phase<'a>>,
    /// The robot's controller settings.
    pub robot: RobotConfig,
    /// The virtual human's gains over `xi` (zeros without a virtual human).
    pub partner_gains: [f64; 3],
    /// The virtual human's torque limit (model units).
    pub partner_torque_limit: f64,
    /// Loop period (s).
    pub dt_s: f64,
    /// Drive units per controller unit of position (`pi/180` for degrees).
    pub rad_per_unit: f64,
    /// The rig settings.
    pub rig: RigSpec,
}

impl FileSpec {
    /// Validates every field and builds the core structs.
    pub fn resolve(&self) -> Result<Resolved<'_>, ConfigError> {
        let p = &self.plant;
        let mass = positive("plant.mass", p.mass)?;
        let damping = non_negative("plant.damping", p.damping)?;
        non_negative("plant.coulomb", p.coulomb)?;
        let dt_s = positive("plant.dt_s", p.dt_s)?;
        if self.phases.is_empty() || self.phases.len() > sensaug_core::scenario::MAX_PHASES {
            return Err(err("phases", "needs 1 to 4 [[phases]] tables"));
        }
        let mut phases = Vec::with_capacity(self.phases.len());
        for (i, ph) in self.phases.iter().enumerate() {
            let path = format!("phases[{i}]");
            let kind = match ph.kind.as_str() {
                "gains" => PhaseKind::Gains,
                "trajectory" => PhaseKind::Trajectory,
                "integration" => PhaseKind::Integration,
                other => {
                    return Err(err(
                        format!("{path}.kind"),
                        format!("must be one of gains, trajectory, integration; got {other:?}"),
                    ))
                }
            };
            positive(&format!("{path}.duration_s"), ph.duration_s)?;
            non_negative(&format!("{path}.target_noise_std"), ph.target_noise_std)?;
            phases.push(sensaug_core::scenario::Phase {
                kind,
                duration_s: ph.duration_s,
                robot_target: target(&path, "robot_target", &ph.robot_target)?,
                partner_target: target(&path, "partner_target", &ph.partner_target)?,
                target_noise_std: ph.target_noise_std,
            });
        }

        // An absent [robot] table means every default, as on the Python side.
        let default_robot;
        let robot_spec = match &self.robot {
            Some(r) => r,
            None => {
                default_robot = toml::from_str::<RobotSpec>("")
                    .map_err(|e| err("robot", e.message().to_string()))?;
                &default_robot
            }
        };
        let robot = self.robot_config(robot_spec, mass, damping, dt_s)?;
        let mut gains_known = robot.prior_partner_gains.is_some();
        for (i, ph) in phases.iter().enumerate() {
            match ph.kind {
                PhaseKind::Gains => gains_known = true,
                _ if !gains_known => {
                    return Err(err(
                        format!("phases[{i}].kind"),
                        "needs an earlier 'gains' phase or robot.prior_partner_gains",
                    ))
                }
                _ => {}
            }
        }

        let partner = self
            .partner
            .as_ref()
            .ok_or_else(|| err("partner", "missing [partner] table"))?;
        let partner_gains = match (&partner.gains, partner.q_pos, partner.q_vel) {
            (Some(g), None, None) => gains3("partner.gains", g)?,
            (None, Some(qp), qv) => {
                let k = agent_gains(mass, damping, qp, qv.unwrap_or(0.0))
                    .map_err(|e| err("partner.q_pos", format!("no LQR gains: {e:?}")))?;
                [0.0, k[1], k[0]]
            }
            _ => {
                return Err(err(
                    "partner",
                    "give either gains = [Lhx, Lhv, Lhh] or q_pos (and q_vel), not both",
                ))
            }
        };
        positive("partner.torque_limit", partner.torque_limit)?;

        let rig = self.rig.clone();
        let rad_per_unit = match rig.position_unit.as_str() {
            "deg" => PI / 180.0,
            "rad" => 1.0,
            other => {
                return Err(err(
                    "rig.position_unit",
                    format!("must be \"deg\" or \"rad\", got {other:?}"),
                ))
            }
        };
        if rig.node_id > 15 {
            return Err(err("rig.node_id", "must be 0..=15"));
        }
        positive("rig.torque_limit_nm", rig.torque_limit_nm)?;
        if rig.watchdog_ms == 0 {
            return Err(err("rig.watchdog_ms", "must be >= 1"));
        }
        positive("rig.feedback_timeout_ms", rig.feedback_timeout_ms)?;
        non_negative("rig.ramp_down_s", rig.ramp_down_s)?;
        if rig.ring_capacity < 1024 {
            return Err(err("rig.ring_capacity", "must be >= 1024 records"));
        }
        if let Some(p) = rig.realtime.fifo_priority {
            if !(1..=99).contains(&p) {
                return Err(err("rig.realtime.fifo_priority", "must be 1..=99"));
            }
        }
        Ok(Resolved {
            phases,
            robot,
            partner_gains: if rig.virtual_human {
                partner_gains
            } else {
                [0.0; 3]
            },
            partner_torque_limit: partner.torque_limit,
            dt_s,
            rad_per_unit,
            rig,
        })
    }

    fn robot_config(
        &self,
        r: &RobotSpec,
        mass: f64,
        damping: f64,
        dt_s: f64,
    ) -> Result<RobotConfig, ConfigError> {
        positive("robot.q_pos", r.q_pos)?;
        non_negative("robot.q_vel", r.q_vel)?;
        positive("robot.gain_window_s", r.gain_window_s)?;
        positive("robot.torque_limit", r.torque_limit)?;
        let k = agent_gains(mass, damping, r.q_pos, r.q_vel)
            .map_err(|e| err("robot.q_pos", format!("no LQR gains: {e:?}")))?;
        let sigma = MerweParams {
            alpha: positive("robot.sigma.alpha", r.sigma.alpha)?,
            beta: r.sigma.beta,
            kappa: r.sigma.kappa,
        };
        if !(r.sigma.beta.is_finite() && r.sigma.kappa.is_finite() && 6.0 + r.sigma.kappa > 0.0) {
            return Err(err("robot.sigma", "beta, kappa finite with 6 + kappa > 0"));
        }
        let stage1 = extended_filter::<3>("robot.stage1", r.stage1.as_ref(), sigma)?;
        let stage2 = extended_filter::<5>("robot.stage2", r.stage2.as_ref(), sigma)?;
        let s3 = r.stage3.clone().unwrap_or(IntegratorSpec {
            Q: None,
            R_sensor: None,
            P0: None,
            partner_window_s: 0.2,
        });
        let prior = match &r.prior_partner_gains {
            Some(g) => Some(gains3("robot.prior_partner_gains", g)?),
            None => None,
        };
        Ok(RobotConfig {
            gains: [k[0], k[1], 0.0],
            model: HandleModel {
                mass,
                damping,
                dt_s,
            },
            stage1,
            stage2,
            stage3: GoalIntegratorConfig {
                x0: Vector2::zeros(),
                P0: s3
                    .P0
                    .unwrap_or(Cov::Diag(vec![1e-2; 2]))
                    .matrix::<2>("robot.stage3.P0")?,
                Q: s3
                    .Q
                    .unwrap_or(Cov::Diag(vec![1e-2; 2]))
                    .matrix::<2>("robot.stage3.Q")?,
                R_own: s3
                    .R_sensor
                    .unwrap_or(Cov::Diag(vec![1e-7; 2]))
                    .matrix::<2>("robot.stage3.R_sensor")?,
                partner_window_s: positive("robot.stage3.partner_window_s", s3.partner_window_s)?,
                sigma,
            },
            integrate: r.integrate,
            gain_window_s: r.gain_window_s,
            prior_partner_gains: prior,
            torque_limit: r.torque_limit,
            seed: r.seed,
        })
    }
}

fn rows<const R: usize, const C: usize>(m: &SMatrix<f64, R, C>) -> Vec<Vec<f64>> {
    (0..R)
        .map(|i| (0..C).map(|j| m[(i, j)]).collect())
        .collect()
}

impl Resolved<'_> {
    /// Every resolved setting as JSON (`sensaug-rt --print-resolved`), so the
    /// Python side can check that both read a file the same way, defaults
    /// included.
    pub fn to_json(&self) -> serde_json::Value {
        let r = &self.robot;
        let ext = |c: &ExtendedFilterConfig<3>| serde_json::json!({"x0": c.x0.as_slice(), "P0": rows(&c.P0), "Q": rows(&c.Q), "R": rows(&c.R)});
        let ext5 = |c: &ExtendedFilterConfig<5>| serde_json::json!({"x0": c.x0.as_slice(), "P0": rows(&c.P0), "Q": rows(&c.Q), "R": rows(&c.R)});
        let kind = |k: PhaseKind| match k {
            PhaseKind::Gains => "gains",
            PhaseKind::Trajectory => "trajectory",
            PhaseKind::Integration => "integration",
        };
        serde_json::json!({
            "dt_s": self.dt_s,
            "mass": r.model.mass,
            "damping": r.model.damping,
            "phases": self.phases.iter().map(|p| serde_json::json!({
                "kind": kind(p.kind), "duration_s": p.duration_s, "target_noise_std": p.target_noise_std,
            })).collect::<Vec<_>>(),
            "robot": {
                "gains": r.gains,
                "integrate": r.integrate,
                "gain_window_s": r.gain_window_s,
                "torque_limit": r.torque_limit,
                "seed": r.seed,
                "prior_partner_gains": r.prior_partner_gains,
                "sigma": {"alpha": r.stage1.sigma.alpha, "beta": r.stage1.sigma.beta, "kappa": r.stage1.sigma.kappa},
                "stage1": ext(&r.stage1),
                "stage2": ext5(&r.stage2),
                "stage3": {
                    "P0": rows(&r.stage3.P0), "Q": rows(&r.stage3.Q),
                    "R_sensor": rows(&r.stage3.R_own), "partner_window_s": r.stage3.partner_window_s,
                },
            },
            "partner": {"gains": self.partner_gains, "torque_limit": self.partner_torque_limit},
            "rig": self.rig,
        })
    }
}
