//! The real-time loop's settings, derived once from a configuration when it
//! is resolved ([`crate::Resolved::rig`]): the `[rig]` table in the loop's
//! units (N m, rad, ticks, ns) plus what follows from the controller (its
//! period, unit and virtual human). `sensaug-rt` runs on these and records
//! them, serialised, as its log's `loop` metadata.
//!
//! A new rig setting: its field in `schema.rs` (`RigSpec`: default, bound,
//! description), its line in [`RigSettings::new`] here, and its use in
//! `sensaug-rt` (docs/realtime.md, "Adding a rig setting").

use crate::error::{num, ConfigError};
use crate::schema::{
    Cia402Freshness, DriveProfile, FrictionSpec, RangeSpec, RigSpec, ScenarioSpec,
};
use sensaug_core::agent::HumanLike;
use sensaug_core::plant::PlantParams;
use sensaug_core::world::PartnerConfig;
use serde::Serialize;

/// Drive watchdog periods of listening for another controller before
/// enabling: a running controller sends at least one command per period or
/// its drive trips.
pub const QUIET_WATCHDOG_PERIODS: u64 = 3;

/// The controlled stop's settings (`rig.stop_*`, docs/safety.md).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct StopSettings {
    /// The longest it brakes before disabling (s).
    #[serde(rename = "stop_time_limit_s")]
    pub time_limit_s: f64,
    /// The brake's damping, `plant.mass / rig.stop_time_constant_s`
    /// (N m s/rad).
    #[serde(rename = "stop_damping_nm_s_per_rad")]
    pub damping_nm_s_per_rad: f64,
    /// The brake's largest torque (N m).
    #[serde(rename = "stop_torque_limit_nm")]
    pub torque_limit_nm: f64,
    /// At rest below this speed (rad/s).
    #[serde(rename = "stop_rest_velocity_rad_s")]
    pub rest_velocity_rad_s: f64,
}

/// The handle's range of motion and speed in the loop's units (`rig.range`
/// from degrees: rad, rad/s, N m/rad, N m s/rad; docs/safety.md, "Range of
/// motion"). Serialised flat, `range_*` keys.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct RangeSettings {
    /// Soft end stop, low side (rad): the virtual wall below it.
    #[serde(rename = "range_soft_min_rad")]
    pub soft_min_rad: f64,
    /// Soft end stop, high side (rad).
    #[serde(rename = "range_soft_max_rad")]
    pub soft_max_rad: f64,
    /// Hard limit, low side (rad): the controlled stop below it.
    #[serde(rename = "range_hard_min_rad")]
    pub hard_min_rad: f64,
    /// Hard limit, high side (rad).
    #[serde(rename = "range_hard_max_rad")]
    pub hard_max_rad: f64,
    /// The controller's torque ramps down over this width inside each
    /// soft end stop (rad).
    #[serde(rename = "range_ramp_width_rad")]
    pub ramp_width_rad: f64,
    /// The wall's stiffness (N m/rad).
    #[serde(rename = "range_wall_stiffness_nm_per_rad")]
    pub wall_stiffness_nm_per_rad: f64,
    /// The wall's damping (N m s/rad).
    #[serde(rename = "range_wall_damping_nm_s_per_rad")]
    pub wall_damping_nm_s_per_rad: f64,
    /// Damping above this speed (rad/s).
    #[serde(rename = "range_soft_speed_rad_s")]
    pub soft_speed_rad_s: f64,
    /// The controlled stop above this speed (rad/s).
    #[serde(rename = "range_hard_speed_rad_s")]
    pub hard_speed_rad_s: f64,
    /// Damping on the speed above the soft speed (N m s/rad).
    #[serde(rename = "range_speed_damping_nm_s_per_rad")]
    pub speed_damping_nm_s_per_rad: f64,
}

/// The handle's friction the loop compensates (`rig.friction`, N m, N m
/// s/rad, rad/s). Serialised flat, `friction_*` keys.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct FrictionSettings {
    /// Coulomb friction to compensate (N m).
    #[serde(rename = "friction_coulomb_nm")]
    pub coulomb_nm: f64,
    /// Viscous friction to compensate (N m s/rad).
    #[serde(rename = "friction_viscous_nm_s_per_rad")]
    pub viscous_nm_s_per_rad: f64,
    /// The Coulomb term's velocity band (rad/s).
    #[serde(rename = "friction_coulomb_band_rad_s")]
    pub coulomb_band_rad_s: f64,
    /// The Coulomb term's torque band at rest (N m).
    #[serde(rename = "friction_coulomb_torque_band_nm")]
    pub coulomb_torque_band_nm: f64,
}

impl FrictionSettings {
    /// `rig.friction` (already in the loop's units).
    pub fn new(f: &FrictionSpec) -> Self {
        FrictionSettings {
            coulomb_nm: f.coulomb_nm,
            viscous_nm_s_per_rad: f.viscous_nm_s_per_rad,
            coulomb_band_rad_s: f.coulomb_band_rad_s,
            coulomb_torque_band_nm: f.coulomb_torque_band_nm,
        }
    }
}

/// rad per degree.
const RAD_PER_DEG: f64 = core::f64::consts::PI / 180.0;

impl RangeSettings {
    /// `rig.range` (degrees) in rad; the wall's stiffness and the dampings
    /// the configuration leaves out from the handle (`mass`, kg m^2) and
    /// the period `dt_s` ([`default_wall`]).
    pub fn new(r: &RangeSpec, mass: f64, dt_s: f64) -> Self {
        let (stiffness, damping) = default_wall(mass, dt_s);
        let nm_per_rad =
            |given: Option<f64>, default: f64| given.map_or(default, |v| v / RAD_PER_DEG);
        RangeSettings {
            soft_min_rad: r.soft_min_deg * RAD_PER_DEG,
            soft_max_rad: r.soft_max_deg * RAD_PER_DEG,
            hard_min_rad: r.hard_min_deg * RAD_PER_DEG,
            hard_max_rad: r.hard_max_deg * RAD_PER_DEG,
            ramp_width_rad: r.ramp_width_deg * RAD_PER_DEG,
            wall_stiffness_nm_per_rad: nm_per_rad(r.wall_stiffness_nm_per_deg, stiffness),
            wall_damping_nm_s_per_rad: nm_per_rad(r.wall_damping_nm_s_per_deg, damping),
            soft_speed_rad_s: r.soft_speed_deg_s * RAD_PER_DEG,
            hard_speed_rad_s: r.hard_speed_deg_s * RAD_PER_DEG,
            speed_damping_nm_s_per_rad: nm_per_rad(r.speed_damping_nm_s_per_deg, damping),
        }
    }
}

/// The wall's stiffness (N m/rad) and the wall's and the speed limit's
/// damping (N m s/rad) when `rig.range` leaves them out: `mass / (8 dt)^2`
/// and `mass / (8 dt)`. On the handle with one tick of feedback delay the
/// behaviour depends only on `K dt^2 / M` and `B dt / M`, so these settle
/// alike on every plant: spectral radius 0.941 with the wall's damping
/// alone, 0.912 with the speed damping too ([`wall_spectral_radius`]).
pub fn default_wall(mass: f64, dt_s: f64) -> (f64, f64) {
    let per_tick = mass / (8.0 * dt_s);
    (per_tick / (8.0 * dt_s), per_tick)
}

/// Settings of the loop (from `[rig]` and the controller's configuration).
/// Serialised flat, one key per setting: the rig log's `loop` metadata.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct RigSettings {
    /// Drive profile.
    pub drive: DriveProfile,
    /// Drive node id (bounded by the schema to a CAN node id).
    pub node_id: u8,
    /// Loop period (s).
    pub dt_s: f64,
    /// Loop period in whole ns: the deadlines' step.
    pub period_ns: u64,
    /// rad per controller position unit (torque scales the same way).
    pub rad_per_unit: f64,
    /// Torque limit at the drive (N m).
    pub torque_limit_nm: f64,
    /// Drive watchdog (ms).
    pub watchdog_ms: u16,
    /// CiA 402: the drive's heartbeat is lost after this long (ms).
    pub drive_heartbeat_timeout_ms: u32,
    /// CiA 402: how TPDOs are matched to SYNCs (`rig.cia402.freshness`).
    pub cia402_freshness: Cia402Freshness,
    /// Feedback timeout (ms).
    pub feedback_timeout_ms: f64,
    /// Feedback older than this many ticks trips the timeout.
    pub feedback_timeout_ticks: u64,
    /// The controlled stop.
    #[serde(flatten)]
    pub stop: StopSettings,
    /// The controlled stop's time limit (ticks).
    pub stop_ticks: u64,
    /// The handle's range of motion and speed.
    #[serde(flatten)]
    pub range: RangeSettings,
    /// The friction compensation.
    #[serde(flatten)]
    pub friction: FrictionSettings,
    /// Virtual human gains over `xi` (zeros: no virtual human).
    pub partner_gains: [f64; 3],
    /// Virtual human torque limit (model units).
    pub partner_torque_limit: f64,
    /// The human-like partner's delays, noise and drift (`partner.human`;
    /// `None`: the paper's virtual human). The metadata says only whether
    /// there is one: the configuration has its settings.
    #[serde(serialize_with = "is_some")]
    pub partner_human: Option<HumanLike>,
    /// The handle's model (model units): the virtual human's view of the
    /// handle on ticks without fresh feedback (the configuration has it).
    #[serde(skip)]
    pub plant: PlantParams,
    /// Records the log's ring buffer holds.
    pub ring_capacity: u64,
    /// Feedback plausibility: velocity limit (rad/s).
    pub max_feedback_velocity_rad_s: f64,
    /// Feedback plausibility: position step margin (rad).
    pub feedback_step_margin_rad: f64,
    /// Feedback consistency: the plant's largest acceleration under the
    /// torque limit, `torque_limit_nm / plant.mass` (rad/s^2).
    pub max_acceleration_rad_s2: f64,
    /// Feedback consistency: velocity margin (rad/s).
    pub feedback_velocity_margin_rad_s: f64,
    /// Degraded run: largest fraction of ticks without fresh feedback.
    pub max_missing_feedback_fraction: f64,
    /// Degraded run: longest run of ticks without fresh feedback.
    pub max_stale_feedback_ticks: u64,
    /// Degraded run: most estimator errors plus non-finite outputs.
    pub max_estimator_errors: u64,
    /// Sleep-then-spin: the sleep ends this long before each deadline and
    /// the loop spins on the clock for the rest (us; 0: sleep only).
    pub spin_us: u32,
    /// How long set-up listens for another controller before enabling:
    /// [`QUIET_WATCHDOG_PERIODS`] drive watchdogs (ms).
    pub quiet_period_ms: u64,
}

/// The metadata's `partner_human`: whether the virtual human is human-like.
fn is_some<S: serde::Serializer>(human: &Option<HumanLike>, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_bool(human.is_some())
}

/// The loop period in whole ns, as the loop steps its deadlines.
pub fn period_ns(dt_s: f64) -> u64 {
    (dt_s * 1e9).round() as u64
}

/// The ticks of `dt_s` a feedback timeout of `timeout_ms` spans, rounded
/// up: the timeout never trips before its time.
pub fn feedback_timeout_ticks(timeout_ms: f64, dt_s: f64) -> u64 {
    (timeout_ms * 1e-3 / dt_s).ceil() as u64
}

impl RigSettings {
    /// The settings of a configuration whose fields and cross-field rules
    /// are checked (the schema bounds `node_id` and `watchdog_ms`).
    pub(crate) fn new(
        spec: &ScenarioSpec,
        rad_per_unit: f64,
        partner: &PartnerConfig,
        plant: PlantParams,
    ) -> Self {
        let rig: &RigSpec = &spec.rig;
        let dt_s = plant.dt_s;
        // The handle's inertia (kg m^2): the model's mass is the same number
        // in rad and N m whatever rig.position_unit (torque scales as position).
        let mass = plant.mass;
        RigSettings {
            drive: rig.drive,
            node_id: rig.node_id as u8,
            dt_s,
            period_ns: period_ns(dt_s),
            rad_per_unit,
            torque_limit_nm: rig.torque_limit_nm,
            watchdog_ms: rig.watchdog_ms as u16,
            drive_heartbeat_timeout_ms: rig.cia402.heartbeat_timeout_ms,
            cia402_freshness: rig.cia402.freshness,
            feedback_timeout_ms: rig.feedback_timeout_ms,
            feedback_timeout_ticks: feedback_timeout_ticks(rig.feedback_timeout_ms, dt_s),
            stop: StopSettings {
                time_limit_s: rig.stop_time_limit_s,
                damping_nm_s_per_rad: mass / rig.stop_time_constant_s,
                torque_limit_nm: rig.stop_torque_limit_nm,
                rest_velocity_rad_s: rig.stop_rest_velocity_rad_s,
            },
            stop_ticks: (rig.stop_time_limit_s / dt_s).round() as u64,
            range: RangeSettings::new(&rig.range, mass, dt_s),
            friction: FrictionSettings::new(&rig.friction),
            partner_gains: if rig.virtual_human {
                partner.gains
            } else {
                [0.0; 3]
            },
            partner_torque_limit: partner.torque_limit,
            partner_human: if rig.virtual_human {
                partner.human
            } else {
                None
            },
            plant,
            ring_capacity: rig.ring_capacity,
            max_feedback_velocity_rad_s: rig.max_feedback_velocity_rad_s,
            feedback_step_margin_rad: rig.feedback_step_margin_rad,
            max_acceleration_rad_s2: rig.torque_limit_nm / mass,
            feedback_velocity_margin_rad_s: rig.feedback_velocity_margin_rad_s,
            max_missing_feedback_fraction: rig.max_missing_feedback_fraction,
            max_stale_feedback_ticks: rig.max_stale_feedback_ticks,
            max_estimator_errors: rig.max_estimator_errors,
            spin_us: rig.realtime.spin_us,
            quiet_period_ms: u64::from(rig.watchdog_ms) * QUIET_WATCHDOG_PERIODS,
        }
    }

    /// How long set-up listens for another controller before enabling.
    pub fn quiet_period(&self) -> std::time::Duration {
        std::time::Duration::from_millis(self.quiet_period_ms)
    }
}

/// The largest eigenvalue modulus of the handle (inertia `mass`, kg m^2)
/// under a spring-damper `stiffness` (N m/rad), `damping` (N m s/rad)
/// acting one tick of `dt_s` late (a feedback delay of one period, as on the
/// bus): state `[x_k, v_k, x_(k-1), v_(k-1)]`, exact zero-order hold of
/// `a_k = -(stiffness x_(k-1) + damping v_(k-1)) / mass`. Below 1: the
/// wall settles; the smaller, the faster.
pub fn wall_spectral_radius(mass: f64, stiffness: f64, damping: f64, dt_s: f64) -> f64 {
    let (k, b) = (stiffness / mass, damping / mass);
    let h = 0.5 * dt_s * dt_s;
    let a = nalgebra::Matrix4::new(
        1.0,
        dt_s,
        -h * k,
        -h * b,
        0.0,
        1.0,
        -dt_s * k,
        -dt_s * b,
        1.0,
        0.0,
        0.0,
        0.0,
        0.0,
        1.0,
        0.0,
        0.0,
    );
    // A bounded Schur iteration: a matrix it cannot reduce (non-finite
    // entries) counts as not settling, never as a hang.
    match nalgebra::linalg::Schur::try_new(a, f64::EPSILON, 10_000) {
        Some(schur) => schur
            .complex_eigenvalues()
            .iter()
            .map(|z| z.re.hypot(z.im))
            .map(|r| if r.is_nan() { f64::INFINITY } else { r })
            .fold(0.0, f64::max),
        None => f64::INFINITY,
    }
}

/// The cross-field rules of `rig.range` (the fields' own bounds are the
/// schema's): the soft window inside the hard limits, ramps that do not
/// overlap, the hard speed between the soft one and the feedback's
/// plausibility bound, and a wall and speed damping that settle on the
/// handle (`plant.mass`, kg m^2) with one tick of feedback delay.
pub(crate) fn check_range(rig: &RigSpec, mass: f64, dt_s: f64) -> Result<(), ConfigError> {
    let r = &rig.range;
    let err = |field: &str, msg: String| Err(ConfigError::new(format!("rig.range.{field}"), msg));
    // The optional gains: null in the JSON the bounds are checked on, so a
    // nan or inf reaches here.
    for (field, value) in [
        ("wall_stiffness_nm_per_deg", r.wall_stiffness_nm_per_deg),
        ("wall_damping_nm_s_per_deg", r.wall_damping_nm_s_per_deg),
        ("speed_damping_nm_s_per_deg", r.speed_damping_nm_s_per_deg),
    ] {
        if value.is_some_and(|v| !v.is_finite()) {
            return err(
                field,
                "must be a finite number (nan and inf are not allowed); write a number, or leave \
                 it out for the plant's default"
                    .into(),
            );
        }
    }
    // The window's order, as (violated, field, its value, "above"/"below",
    // the other field, its value, the fix).
    let inside_hard = "the soft window must lie inside the hard limits";
    for (violated, field, value, relation, other, bound, fix) in [
        (
            r.soft_min_deg >= r.soft_max_deg,
            "soft_max_deg",
            r.soft_max_deg,
            "above",
            "soft_min_deg",
            r.soft_min_deg,
            "the soft window needs soft_min_deg < soft_max_deg".to_string(),
        ),
        (
            r.hard_min_deg >= r.soft_min_deg,
            "hard_min_deg",
            r.hard_min_deg,
            "below",
            "soft_min_deg",
            r.soft_min_deg,
            format!("{inside_hard}: lower hard_min_deg or raise soft_min_deg"),
        ),
        (
            r.hard_max_deg <= r.soft_max_deg,
            "hard_max_deg",
            r.hard_max_deg,
            "above",
            "soft_max_deg",
            r.soft_max_deg,
            format!("{inside_hard}: raise hard_max_deg or lower soft_max_deg"),
        ),
    ] {
        if violated {
            return err(
                field,
                format!(
                    "{} deg is not {relation} rig.range.{other} ({} deg); {fix}",
                    num(value),
                    num(bound)
                ),
            );
        }
    }
    let half_window = 0.5 * (r.soft_max_deg - r.soft_min_deg);
    if r.ramp_width_deg > half_window {
        return err(
            "ramp_width_deg",
            format!(
                "{} deg is more than half the soft window ({} deg): the two ramps would \
                 overlap; use at most {} deg",
                num(r.ramp_width_deg),
                num(r.soft_max_deg - r.soft_min_deg),
                num(half_window)
            ),
        );
    }
    if r.hard_speed_deg_s <= r.soft_speed_deg_s {
        return err(
            "hard_speed_deg_s",
            format!(
                "{} deg/s is not above rig.range.soft_speed_deg_s ({} deg/s); raise \
                 hard_speed_deg_s or lower soft_speed_deg_s",
                num(r.hard_speed_deg_s),
                num(r.soft_speed_deg_s)
            ),
        );
    }
    let hard_speed_rad_s = r.hard_speed_deg_s * RAD_PER_DEG;
    if hard_speed_rad_s >= rig.max_feedback_velocity_rad_s {
        return err(
            "hard_speed_deg_s",
            format!(
                "{} deg/s ({} rad/s) is not below rig.max_feedback_velocity_rad_s ({} rad/s): \
                 a faster feedback is refused as implausible (torque off) before the speed \
                 limit's controlled stop; use less than {} deg/s",
                num(r.hard_speed_deg_s),
                num(hard_speed_rad_s),
                num(rig.max_feedback_velocity_rad_s),
                num(rig.max_feedback_velocity_rad_s / RAD_PER_DEG)
            ),
        );
    }
    // Damping gains per tick, b dt / M: each at most 1/2 (the brake's
    // rule, docs/safety.md); both act on a fast handle in the wall, checked
    // with the stiffness below.
    let s = RangeSettings::new(r, mass, dt_s);
    for (field, b) in [
        ("wall_damping_nm_s_per_deg", s.wall_damping_nm_s_per_rad),
        ("speed_damping_nm_s_per_deg", s.speed_damping_nm_s_per_rad),
    ] {
        let gain = b * dt_s / mass;
        if gain > 0.5 {
            return err(
                field,
                format!(
                    "{} N m s/deg takes {} of the speed per tick off the handle (plant.mass = {} \
                     kg m^2, plant.dt_s = {} s), more than 1/2: it would oscillate with one tick \
                     of feedback delay; use at most {} N m s/deg, or leave it out (plant.mass / \
                     (8 plant.dt_s))",
                    num(b * RAD_PER_DEG),
                    num(gain),
                    num(mass),
                    num(dt_s),
                    num(0.5 * mass / dt_s * RAD_PER_DEG)
                ),
            );
        }
    }
    for (what, b) in [
        ("", s.wall_damping_nm_s_per_rad),
        (
            " and rig.range.speed_damping_nm_s_per_deg",
            s.wall_damping_nm_s_per_rad + s.speed_damping_nm_s_per_rad,
        ),
    ] {
        let rho = wall_spectral_radius(mass, s.wall_stiffness_nm_per_rad, b, dt_s);
        if rho >= 1.0 {
            return err(
                "wall_stiffness_nm_per_deg",
                format!(
                    "{} N m/deg with rig.range.wall_damping_nm_s_per_deg{what} does not settle \
                     on the handle (plant.mass = {} kg m^2, plant.dt_s = {} s) with one tick \
                     of feedback delay (spectral radius {:.3} >= 1); lower the stiffness, bring \
                     the damping toward plant.mass / (8 plant.dt_s), or leave both out",
                    num(s.wall_stiffness_nm_per_rad * RAD_PER_DEG),
                    num(mass),
                    num(dt_s),
                    rho
                ),
            );
        }
    }
    Ok(())
}

/// The cross-field rules of `rig.friction` (the fields' own bounds are the
/// schema's): the Coulomb torque within `rig.torque_limit_nm`, and the
/// viscous compensation's gain per tick, `C dt / M` on the handle
/// (`plant.mass`, kg m^2), at most 1/2 like the brake's: over-compensating
/// the damping is negative damping, and one tick of feedback delay makes
/// more than that oscillate.
pub(crate) fn check_friction(rig: &RigSpec, mass: f64, dt_s: f64) -> Result<(), ConfigError> {
    let f = &rig.friction;
    let err =
        |field: &str, msg: String| Err(ConfigError::new(format!("rig.friction.{field}"), msg));
    // Null in the JSON the bounds are checked on, so a nan or inf reaches here.
    for (field, value) in [
        ("coulomb_nm", f.coulomb_nm),
        ("viscous_nm_s_per_rad", f.viscous_nm_s_per_rad),
        ("coulomb_band_rad_s", f.coulomb_band_rad_s),
        ("coulomb_torque_band_nm", f.coulomb_torque_band_nm),
    ] {
        if !value.is_finite() {
            return err(
                field,
                "must be a finite number (nan and inf are not allowed); write a number, or \
                 leave it out (no compensation)"
                    .into(),
            );
        }
    }
    if f.coulomb_nm > rig.torque_limit_nm {
        return err(
            "coulomb_nm",
            format!(
                "{} N m is above rig.torque_limit_nm ({} N m): the compensation alone would \
                 saturate the drive; check the calibration (sensaug calibrate) or its unit",
                num(f.coulomb_nm),
                num(rig.torque_limit_nm)
            ),
        );
    }
    let gain = f.viscous_nm_s_per_rad * dt_s / mass;
    if gain > 0.5 {
        return err(
            "viscous_nm_s_per_rad",
            format!(
                "{} N m s/rad compensates {} of the speed per tick on the handle (plant.mass = \
                 {} kg m^2, plant.dt_s = {} s), more than 1/2: over-compensated it would \
                 oscillate with one tick of feedback delay; use at most {} N m s/rad, or \
                 check plant.mass against the calibration",
                num(f.viscous_nm_s_per_rad),
                num(gain),
                num(mass),
                num(dt_s),
                num(0.5 * mass / dt_s)
            ),
        );
    }
    Ok(())
}
