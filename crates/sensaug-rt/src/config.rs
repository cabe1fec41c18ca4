//! The configuration as the binary loads it (resolved once, with the
//! command line's overrides) and the drive link its settings name (the
//! loop's settings are derived when it is resolved: `sensaug_config::rig`).

use crate::control::LoopSettings;
use sensaug_bridge::cia402::{CanopenNode, MasterSettings};
use sensaug_bridge::drive_link::{Cia402Link, DriveLink, Hi5Link};
use sensaug_bridge::protocol::NodeId;
use sensaug_config::{load_file_with, ConfigError, DriveProfile, Resolved};
use std::path::Path;
use std::time::Duration;

/// The command line's overrides of the file's `[rig]` table.
#[derive(Clone, Debug, Default)]
pub struct Overrides {
    /// `rig.can` (`--can`).
    pub can: Option<String>,
    /// `rig.log` (`--log`).
    pub log: Option<String>,
    /// `rig.stats` (`--stats`).
    pub stats: Option<String>,
}

/// The configuration file with the overrides applied, resolved once as a
/// whole (the loop's settings are its [`Resolved::rig`]); with
/// `check_outputs` its output paths checked too.
pub fn load(
    path: &Path,
    overrides: &Overrides,
    check_outputs: bool,
) -> Result<Resolved, ConfigError> {
    let resolved = load_file_with(path, |spec| {
        let rig = &mut spec.rig;
        for (field, value) in [
            (&mut rig.can, &overrides.can),
            (&mut rig.log, &overrides.log),
            (&mut rig.stats, &overrides.stats),
        ] {
            if let Some(v) = value {
                field.clone_from(v);
            }
        }
        // A revolute joint: the rig refuses a linear position unit before
        // resolving (the simulation accepts it).
        sensaug_config::check_rig_unit(spec)
    })?;
    if check_outputs {
        sensaug_config::check_rig_outputs(&resolved.spec)?;
    }
    Ok(resolved)
}

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
        DriveProfile::Hi5 => {
            let node = NodeId::new(u32::from(s.node_id))
                .map_err(|e| ConfigError::new("rig.node_id", e.to_string()))?;
            Box::new(Hi5Link::new(node, s.watchdog_ms, SETUP_TIMEOUT))
        }
        DriveProfile::Cia402 => {
            let node = CanopenNode::new(s.node_id)
                .map_err(|e| ConfigError::new("rig.node_id", e.to_string()))?;
            let mut m = MasterSettings::new(node).with_drive_heartbeat_timeout(
                Duration::from_millis(u64::from(s.drive_heartbeat_timeout_ms)),
            );
            m.max_torque_nm = s.torque_limit_nm;
            m.freshness = s.cia402_freshness.into();
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
