//! The real-time loop's settings, derived once from a configuration when it
//! is resolved ([`crate::Resolved::rig`]): the `[rig]` table in the loop's
//! units (N m, rad, ticks, ns) plus what follows from the controller (its
//! period, unit and virtual human). `sensaug-rt` runs on these and records
//! them, serialised, as its log's `loop` metadata.
//!
//! A new rig setting: its field in `schema.rs` (`RigSpec`: default, bound,
//! description), its line in [`RigSettings::new`] here, and its use in
//! `sensaug-rt` (docs/realtime.md, "Adding a rig setting").

use crate::schema::{Cia402Freshness, DriveProfile, RigSpec, ScenarioSpec};
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
            feedback_timeout_ticks: (rig.feedback_timeout_ms * 1e-3 / dt_s).ceil() as u64,
            stop: StopSettings {
                time_limit_s: rig.stop_time_limit_s,
                damping_nm_s_per_rad: mass / rig.stop_time_constant_s,
                torque_limit_nm: rig.stop_torque_limit_nm,
                rest_velocity_rad_s: rig.stop_rest_velocity_rad_s,
            },
            stop_ticks: (rig.stop_time_limit_s / dt_s).round() as u64,
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
