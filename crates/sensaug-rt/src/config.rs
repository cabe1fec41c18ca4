//! The loop's settings from a resolved configuration (`sensaug-config`, the
//! one schema the Python API and this binary share).

use crate::control::{LoopSettings, StopSettings};
use sensaug_bridge::cia402::{CanopenNode, MasterSettings};
use sensaug_bridge::drive_link::{Cia402Link, DriveLink, Hi5Link};
use sensaug_bridge::protocol::NodeId;
use sensaug_config::{ConfigError, DriveProfile, Resolved};
use std::time::Duration;

/// How long each set-up step may wait for the drive.
pub const SETUP_TIMEOUT: Duration = Duration::from_secs(5);

/// CiA 402: the master's heartbeat period is this fraction of the drive's
/// heartbeat consumer time (`rig.watchdog_ms`): five beats per watchdog.
const HEARTBEATS_PER_WATCHDOG: u64 = 5;

/// The link to the drive `[rig] drive` names. CiA 402: the drive's
/// heartbeat consumer (its command watchdog) is `rig.watchdog_ms`, the
/// master beats [`HEARTBEATS_PER_WATCHDOG`] times per watchdog; the master's
/// consumer of the drive's heartbeat is `rig.cia402.heartbeat_timeout_ms`
/// (the drive beats twice per timeout); the drive's max torque 0x6072 must
/// be `rig.torque_limit_nm`; the set-up's response timeout is
/// [`MasterSettings::new`]'s.
pub fn drive_link(s: &LoopSettings) -> Result<Box<dyn DriveLink + Send>, ConfigError> {
    Ok(match s.drive {
        DriveProfile::Hi5 => Box::new(Hi5Link::new(s.node, s.watchdog_ms, SETUP_TIMEOUT)),
        DriveProfile::Cia402 => {
            let node = CanopenNode::new(s.node.get())
                .map_err(|e| ConfigError::new("rig.node_id", e.to_string()))?;
            let mut m = MasterSettings::new(node).with_drive_heartbeat_timeout(
                Duration::from_millis(u64::from(s.drive_heartbeat_timeout_ms)),
            );
            m.max_torque_nm = s.torque_limit_nm;
            m.drive_consumer_ms = s.watchdog_ms;
            m.heartbeat_period =
                Duration::from_millis((u64::from(s.watchdog_ms) / HEARTBEATS_PER_WATCHDOG).max(1));
            let step = Duration::from_secs_f64(s.dt_s);
            Box::new(
                Cia402Link::new(m, step)
                    .map_err(|e| ConfigError::new("rig.watchdog_ms", e.to_string()))?,
            )
        }
    })
}

/// The loop's settings: the `[rig]` table, the controller's period, unit
/// and virtual human (zero gains when a person holds the handle), and the
/// plant's inertia (the brake's damping, the feedback's largest
/// acceleration).
pub fn loop_settings(resolved: &Resolved<'_>) -> Result<LoopSettings, ConfigError> {
    let rig = &resolved.spec.rig;
    // The handle's inertia (kg m^2): the model's mass is the same number in
    // rad and N m whatever rig.position_unit (torque scales as position).
    let mass = resolved.spec.plant.mass;
    let node =
        NodeId::new(rig.node_id).map_err(|e| ConfigError::new("rig.node_id", e.to_string()))?;
    Ok(LoopSettings {
        drive: rig.drive,
        node,
        dt_s: resolved.dt_s,
        rad_per_unit: resolved.rad_per_unit,
        torque_limit_nm: rig.torque_limit_nm,
        watchdog_ms: rig.watchdog_ms as u16,
        drive_heartbeat_timeout_ms: rig.cia402.heartbeat_timeout_ms,
        feedback_timeout_ms: rig.feedback_timeout_ms,
        stop: StopSettings {
            time_limit_s: rig.stop_time_limit_s,
            damping_nm_s_per_rad: mass / rig.stop_time_constant_s,
            torque_limit_nm: rig.stop_torque_limit_nm,
            rest_velocity_rad_s: rig.stop_rest_velocity_rad_s,
        },
        partner_gains: if rig.virtual_human {
            resolved.partner.gains
        } else {
            [0.0; 3]
        },
        partner_torque_limit: resolved.partner.torque_limit,
        partner_human: if rig.virtual_human {
            resolved.partner.human
        } else {
            None
        },
        plant: resolved.world.plant,
        max_feedback_velocity_rad_s: rig.max_feedback_velocity_rad_s,
        feedback_step_margin_rad: rig.feedback_step_margin_rad,
        max_acceleration_rad_s2: rig.torque_limit_nm / mass,
        feedback_velocity_margin_rad_s: rig.feedback_velocity_margin_rad_s,
        max_missing_feedback_fraction: rig.max_missing_feedback_fraction,
        max_stale_feedback_ticks: rig.max_stale_feedback_ticks,
        max_estimator_errors: rig.max_estimator_errors,
        spin_us: rig.realtime.spin_us,
    })
}
