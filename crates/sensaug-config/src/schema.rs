//! The configuration's types: one struct per TOML table. They are at once
//! the parser (serde), the defaults (`#[serde(default)]`), the bounds
//! (`#[schemars(range)]`, enforced by [`crate::check`]) and the JSON Schema
//! (schemars). Units are in the field names and doc comments; the doc
//! comments become the schema's descriptions and the comments of written
//! TOML files.
//!
//! Positions are in the controller's unit: degrees for the Hi5 presets
//! (`rig.position_unit`), metres for the simulation section; torques in the
//! matching model unit (docs/model.md, Units).
#![allow(non_snake_case)]

use crate::cov::Cov;
pub use crate::person::{
    BlockOrder, BlockSpec, DisplaySpec, OnFreeze, ScreenDirection, SessionSpec,
};
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

/// Largest magnitude accepted for a gain, a target amplitude, an initial
/// state or a torque limit in model units: far beyond any physical setting,
/// small enough that products stay finite.
pub const MAX_MAGNITUDE: f64 = 1e6;
/// Longest phase, target period or chirp (s): one hour.
pub const MAX_DURATION_S: f64 = 3600.0;
/// Most phases in one trial.
pub const MAX_PHASES: usize = sensaug_core::protocol::MAX_PHASES;
/// Most shapes summed into one target.
pub const MAX_PARTS: usize = sensaug_core::target::MAX_PARTS;
/// The drive watchdog's bounds whatever the profile (ms): at least 2 ms (the
/// CiA 402 master's own least, [`sensaug_bridge::cia402::master::DRIVE_CONSUMER_MS_MIN`]).
/// Each profile narrows the range ([`DriveProfile::watchdog_ms_range`]).
pub const WATCHDOG_MS_MIN: f64 = 2.0;
/// At most 200 ms: the longest a drive may go on applying its last torque
/// after the controller fell silent (a crashed process, docs/safety.md),
/// whatever its protocol allows.
pub const WATCHDOG_MS_MAX: f64 = 200.0;
/// Largest torque the drive protocol carries (N m), from `hi5.dbc`
/// (`TorqueCommand.torque`).
pub const TORQUE_NM_MAX: f64 = sensaug_bridge::dbc::torque_command::TORQUE.max;
/// Largest velocity the drive's feedback carries (rad/s), from `hi5.dbc`
/// (`Feedback.velocity`).
pub const FEEDBACK_VELOCITY_MAX: f64 = sensaug_bridge::dbc::feedback::VELOCITY.max;
/// Largest configuration file read (bytes); larger ones are refused before
/// parsing.
pub const MAX_FILE_BYTES: u64 = 1 << 20;

/// A whole trial: the protocol's phases, the handle, the simulated world, the
/// robot, its partner and the real-time rig. Every table but `phases` may be
/// left out (all defaults).
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize, JsonSchema)]
#[serde(deny_unknown_fields)]
#[schemars(title = "sensaug trial configuration")]
pub struct ScenarioSpec {
    /// The protocol: 1 to 4 phases run in order.
    #[schemars(length(min = 1, max = 4))]
    pub phases: Vec<PhaseSpec>,
    /// The handle as the controller models it.
    #[serde(default)]
    pub plant: PlantSpec,
    /// Simulation only: noise, seed and initial state of the simulated world.
    #[serde(default)]
    pub world: WorldSpec,
    /// The robot's controller and estimators.
    #[serde(default)]
    pub robot: RobotSpec,
    /// The partner: the virtual human (simulation, and inside the rig loop).
    #[serde(default)]
    pub partner: PartnerSpec,
    /// The real-time loop and its CAN link (`sensaug-rt`; the simulation ignores it).
    #[serde(default)]
    pub rig: RigSpec,
    /// The participant's display (Python `sensaug.display`; the loop ignores it).
    #[serde(default)]
    pub display: DisplaySpec,
    /// A session plan: blocks of trials of this base trial (`sensaug
    /// session`; a single trial ignores it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub session: Option<SessionSpec>,
    /// Files whose tables this file takes in, each path relative to this
    /// file (`include = ["calibration.toml"]`), merged when the file is read
    /// (`sensaug-rt CONFIG`, `ScenarioConfig.from_toml(path)`); a setting
    /// may be given in one file only (docs/config.md, "Includes"). Text and
    /// tables read without a file cannot include.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    #[schemars(length(max = MAX_INCLUDES))]
    pub include: Vec<String>,
    /// Written when the file is read, not by hand: each file the
    /// configuration included, its path and SHA-256, so that a trial's log
    /// says which files (which handle calibration) it ran with.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    #[schemars(length(max = MAX_INCLUDES))]
    pub included: Vec<IncludedFile>,
}

/// Most files one configuration may include, nested includes counted.
pub const MAX_INCLUDES: usize = 32;

/// A file a configuration included (`included`).
#[derive(Clone, Debug, PartialEq, Eq, Deserialize, Serialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct IncludedFile {
    /// The file as opened: the `include` entry joined to the including
    /// file's folder, made absolute.
    pub path: String,
    /// SHA-256 of the file's bytes as read (64 lowercase hex digits).
    pub sha256: String,
}

/// What the robot does during a phase.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, Serialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum PhaseKindSpec {
    /// Stage 1: both targets known; estimate the partner's gains.
    Gains,
    /// Stage 2: the partner's target unknown; estimate it.
    Trajectory,
    /// Stage 3: the robot's view of the target noisy; fuse it with the partner's.
    Integration,
}

/// One phase (`[[phases]]`).
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct PhaseSpec {
    /// What the robot estimates: "gains", "trajectory" or "integration".
    pub kind: PhaseKindSpec,
    /// Duration (s), at least one tick.
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = MAX_DURATION_S))]
    pub duration_s: f64,
    /// The robot's target tau: a sum of 1 to 3 shapes (position unit).
    #[schemars(length(min = 1, max = 3))]
    pub robot_target: Vec<ShapeSpec>,
    /// The partner's target tau_h: a sum of 1 to 3 shapes (position unit).
    #[schemars(length(min = 1, max = 3))]
    pub partner_target: Vec<ShapeSpec>,
    /// Std of the white noise on the robot's view of its target (position
    /// unit); used in integration phases.
    #[serde(default)]
    #[schemars(range(min = 0.0, max = MAX_MAGNITUDE))]
    pub target_noise_std: f64,
}

/// A target shape, chosen by `kind` (deserialized in `crate::shape` so that
/// errors name the field inside the shape).
#[derive(Clone, Debug, PartialEq, Serialize, JsonSchema)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum ShapeSpec {
    /// A constant offset.
    Constant(ConstantSpec),
    /// +amplitude for the first half of each period, -amplitude after.
    Square(SquareSpec),
    /// amplitude * cbrt(sin(2 pi t / period)): the Hi5 target (8 deg, 4 s).
    RoundedSquare(SquareSpec),
    /// Linear chirp from f0_hz to f1_hz over duration_s, then at f1_hz.
    Chirp(ChirpSpec),
    /// amplitude * sum over k = 1..harmonics of sin(k omega t) (cos if cosine).
    Harmonics(HarmonicsSpec),
    /// Samples every dt_s from t = 0, linearly interpolated, held at the ends.
    Sampled(SampledSpec),
}

/// `kind = "constant"`.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ConstantSpec {
    /// Offset (position unit).
    #[schemars(range(min = -MAX_MAGNITUDE, max = MAX_MAGNITUDE))]
    pub value: f64,
}

/// `kind = "square"` or `"rounded_square"`.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct SquareSpec {
    /// Amplitude (position unit).
    #[schemars(range(min = -MAX_MAGNITUDE, max = MAX_MAGNITUDE))]
    pub amplitude: f64,
    /// Period (s).
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = MAX_DURATION_S))]
    pub period_s: f64,
}

/// `kind = "chirp"`.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ChirpSpec {
    /// Amplitude (position unit).
    #[schemars(range(min = -MAX_MAGNITUDE, max = MAX_MAGNITUDE))]
    pub amplitude: f64,
    /// Start frequency (Hz).
    #[schemars(range(min = 0.0, max = 500.0))]
    pub f0_hz: f64,
    /// End frequency (Hz).
    #[schemars(range(min = 0.0, max = 500.0))]
    pub f1_hz: f64,
    /// Sweep duration (s).
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = MAX_DURATION_S))]
    pub duration_s: f64,
}

/// `kind = "harmonics"`.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct HarmonicsSpec {
    /// Amplitude of each harmonic (position unit).
    #[schemars(range(min = -MAX_MAGNITUDE, max = MAX_MAGNITUDE))]
    pub amplitude: f64,
    /// Fundamental angular frequency (rad/s).
    #[schemars(range(min = -3200.0, max = 3200.0))]
    pub omega_rad_s: f64,
    /// Number of harmonics.
    #[serde(default = "three")]
    #[schemars(range(min = 1, max = 32))]
    pub harmonics: u32,
    /// Cosines instead of sines.
    #[serde(default)]
    pub cosine: bool,
}

fn three() -> u32 {
    3
}

/// `kind = "sampled"`.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct SampledSpec {
    /// The samples (position unit).
    #[schemars(length(min = 1, max = 100000), inner(range(min = -MAX_MAGNITUDE, max = MAX_MAGNITUDE)))]
    pub samples: Vec<f64>,
    /// Sample spacing (s).
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = MAX_DURATION_S))]
    pub dt_s: f64,
}

/// `[plant]`: the handle, `M xdd + C xd = u + u_h + eps` (eq.dynamics).
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct PlantSpec {
    /// Inertia M (model mass unit: 0.0035 for the Hi5 in degrees, kg in the
    /// simulation section).
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = 1e3))]
    pub mass: f64,
    /// Viscous damping C (model torque unit per position unit per s).
    #[schemars(range(min = 0.0, max = 1e3))]
    pub damping: f64,
    /// Coulomb friction of the simulated handle (model torque unit).
    #[schemars(range(min = 0.0, max = 1e3))]
    pub coulomb: f64,
    /// Control period dt (s): 1e-4 to 0.1.
    #[schemars(range(min = 1e-4, max = 0.1))]
    pub dt_s: f64,
}

impl Default for PlantSpec {
    fn default() -> Self {
        PlantSpec {
            mass: sensaug_core::plant::PlantParams::HI5.mass,
            damping: 0.0,
            coulomb: 0.0,
            dt_s: 1e-3,
        }
    }
}

/// `[world]`: simulation only (the rig is the world and ignores it).
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct WorldSpec {
    /// Std of the motor noise eps added to the summed torque (model torque unit).
    #[schemars(range(min = 0.0, max = MAX_MAGNITUDE))]
    pub motor_noise_std: f64,
    /// Std of the position sensor noise (position unit).
    #[schemars(range(min = 0.0, max = MAX_MAGNITUDE))]
    pub position_noise_std: f64,
    /// Std of the velocity sensor noise (position unit/s).
    #[schemars(range(min = 0.0, max = MAX_MAGNITUDE))]
    pub velocity_noise_std: f64,
    /// Seed of the motor and sensor noise.
    pub seed: u64,
    /// Initial position (position unit).
    #[schemars(range(min = -MAX_MAGNITUDE, max = MAX_MAGNITUDE))]
    pub x0: f64,
    /// Initial velocity (position unit/s).
    #[schemars(range(min = -MAX_MAGNITUDE, max = MAX_MAGNITUDE))]
    pub v0: f64,
}

impl Default for WorldSpec {
    fn default() -> Self {
        // Sensor variance 1e-7 per step: the paper's R.
        let sensor_std = 1e-7f64.sqrt();
        WorldSpec {
            motor_noise_std: 1e-3,
            position_noise_std: sensor_std,
            velocity_noise_std: sensor_std,
            seed: 0,
            x0: 0.0,
            v0: 0.0,
        }
    }
}

/// `[robot.sigma]`: Merwe scaled sigma points of every UKF.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct SigmaSpec {
    /// Spread alpha.
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = 1.0))]
    pub alpha: f64,
    /// Prior-knowledge beta (2 for Gaussians).
    #[schemars(range(min = 0.0, max = 10.0))]
    pub beta: f64,
    /// Secondary scaling kappa; n + kappa must be > 0.
    #[schemars(range(min = -5.0, max = 100.0))]
    pub kappa: f64,
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

/// `[robot.stage1]`: the gain-estimation UKF (eq.system-extended; 6 states,
/// measurements [x - tau, xdot, x - tau_h]). Covariances are per step.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct GainFilterSpec {
    /// Process noise Q (6 diagonal entries or a 6x6 matrix).
    pub Q: Cov<6>,
    /// Measurement noise R (3 diagonal entries or a 3x3 matrix).
    pub R: Cov<3>,
    /// Initial covariance P0 (6 diagonal entries or a 6x6 matrix).
    pub P0: Cov<6>,
    /// Initial guesses of the partner gains [Lhx, Lhv, Lhh].
    #[schemars(length(min = 3, max = 3), inner(range(min = -MAX_MAGNITUDE, max = MAX_MAGNITUDE)))]
    pub gains0: Vec<f64>,
}

impl Default for GainFilterSpec {
    fn default() -> Self {
        GainFilterSpec {
            Q: Cov::diagonal([1e-2; 6]),
            R: Cov::diagonal([1e-7; 3]),
            P0: Cov::diagonal([1e-4, 1e-4, 1e-4, 1.0, 1.0, 1.0]),
            gains0: vec![0.0; 3],
        }
    }
}

/// `[robot.stage2]`: the trajectory-estimation UKF (6 states, measurements
/// [x - tau, xdot] and the three gains as pseudo-measurements).
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct TrajectoryFilterSpec {
    /// Process noise Q (6 diagonal entries or a 6x6 matrix).
    pub Q: Cov<6>,
    /// Measurement noise R (5 diagonal entries or a 5x5 matrix).
    pub R: Cov<5>,
    /// Initial covariance P0 (6 diagonal entries or a 6x6 matrix).
    pub P0: Cov<6>,
    /// Unused (stage 2 starts from the stage-1 posterior); kept so one
    /// filter table fits both stages.
    #[schemars(length(min = 3, max = 3), inner(range(min = -MAX_MAGNITUDE, max = MAX_MAGNITUDE)))]
    pub gains0: Vec<f64>,
}

impl Default for TrajectoryFilterSpec {
    fn default() -> Self {
        TrajectoryFilterSpec {
            Q: Cov::diagonal([1e-2; 6]),
            R: Cov::diagonal([1e-7; 5]),
            P0: Cov::diagonal([1e-4, 1e-4, 1e-4, 1.0, 1.0, 1.0]),
            gains0: vec![0.0; 3],
        }
    }
}

/// `[robot.stage3]`: goal integration on [x - tau, xdot]: a bank of Kalman
/// filters over the partner channel's variance (docs/model.md, stage 3).
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct IntegratorSpec {
    /// Process noise Q per step (2 diagonal entries or a 2x2 matrix): the
    /// first entry is the random walk of x - tau standing for the unknown
    /// target motion (> 0), the second the velocity's (the motor noise,
    /// (dt sigma_motor / M)^2).
    pub Q: Cov<2>,
    /// Own sensor noise on [x - tau, xdot] before the phase's target noise is
    /// added (2 diagonal entries or a 2x2 matrix).
    pub R_sensor: Cov<2>,
    /// Initial covariance P0 of every filter of the bank (2 diagonal entries
    /// or a 2x2 matrix).
    pub P0: Cov<2>,
    /// The adaptive partner channel's settings.
    pub channel: ChannelSpec,
}

impl Default for IntegratorSpec {
    fn default() -> Self {
        IntegratorSpec {
            Q: Cov::diagonal([1e-2; 2]),
            R_sensor: Cov::diagonal([1e-7; 2]),
            P0: Cov::diagonal([1e-2; 2]),
            channel: ChannelSpec::default(),
        }
    }
}

/// `[robot.stage3.channel]`: how the partner channel's trust adapts
/// (docs/model.md, stage 3). The defaults are the design's; the same for
/// every preset.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ChannelSpec {
    /// Change-point and readmission threshold, in standard deviations of the
    /// own position innovation.
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = 100.0))]
    pub gate: f64,
    /// Scale of the score window: n0 (1 + R_e / A) ticks, R_e the own view's
    /// variance, A the own-only filter's.
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = 1e6))]
    pub window_n0: f64,
    /// Longest suspension of the partner channel after a target jump (s).
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = MAX_DURATION_S))]
    pub hold_max_s: f64,
}

impl Default for ChannelSpec {
    fn default() -> Self {
        let d = sensaug_core::goal::ChannelConfig::default();
        ChannelSpec {
            gate: d.gate,
            window_n0: d.window_n0,
            hold_max_s: d.hold_max_s,
        }
    }
}

/// `[robot]`: LQR weights, estimators and the goal-integration switch.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct RobotSpec {
    /// LQR weight on the position error (its gains come from the reduced
    /// 2-state CARE, docs/model.md).
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = MAX_MAGNITUDE))]
    pub q_pos: f64,
    /// LQR weight on the velocity.
    #[schemars(range(min = 0.0, max = MAX_MAGNITUDE))]
    pub q_vel: f64,
    /// Let the integrated estimate drive control in integration phases.
    pub integrate: bool,
    /// Stage 2's gain pseudo-measurement is the mean of the stage-1 estimate
    /// over the last gain_window_s of the gain phase (s).
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = MAX_DURATION_S))]
    pub gain_window_s: f64,
    /// Torque limit of the controller (model torque unit).
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = MAX_MAGNITUDE))]
    pub torque_limit: f64,
    /// Seed of the injected target-view noise.
    pub seed: u64,
    /// Partner gains [Lhx, Lhv, Lhh] to use when no gain phase precedes.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schemars(length(min = 3, max = 3), inner(range(min = -MAX_MAGNITUDE, max = MAX_MAGNITUDE)))]
    pub prior_partner_gains: Option<Vec<f64>>,
    /// The partner model of stages 1 and 2: absent, the paper's (the
    /// partner acts on the current state); a number of ms, the partner acts
    /// on the robot's measured sample that long ago (visual and
    /// proprioceptive delay alike); "auto", both delays identified online in
    /// every gain phase (docs/model.md, "A partner with a delay").
    #[serde(skip_serializing_if = "Option::is_none")]
    pub partner_delay: Option<PartnerDelaySpec>,
    /// Sigma points of every filter.
    pub sigma: SigmaSpec,
    /// Stage 1 (partner gains).
    pub stage1: GainFilterSpec,
    /// Stage 2 (partner trajectory).
    pub stage2: TrajectoryFilterSpec,
    /// Stage 3 (goal integration).
    pub stage3: IntegratorSpec,
}

impl Default for RobotSpec {
    fn default() -> Self {
        RobotSpec {
            q_pos: 1.0,
            q_vel: 0.0,
            integrate: true,
            gain_window_s: 8.0,
            torque_limit: 1e3,
            seed: 1,
            prior_partner_gains: None,
            partner_delay: None,
            sigma: SigmaSpec::default(),
            stage1: GainFilterSpec::default(),
            stage2: TrajectoryFilterSpec::default(),
            stage3: IntegratorSpec::default(),
        }
    }
}

/// `robot.partner_delay`: "auto" or a delay in ms (0-300).
#[derive(Clone, Copy, Debug, PartialEq, Deserialize, Serialize, JsonSchema)]
#[serde(untagged)]
pub enum PartnerDelaySpec {
    /// "auto": identified online.
    Auto(AutoDelay),
    /// A known delay (ms), both visual and proprioceptive.
    Ms(#[schemars(range(min = 0.0, max = 300.0))] f64),
}

/// The word "auto".
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, Serialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum AutoDelay {
    /// Identify the delays online.
    Auto,
}

/// `[partner.human]`: a human-like virtual partner (docs/model.md, "The
/// human-like partner"): it acts on what it perceived a sensorimotor delay
/// ago, with signal-dependent motor noise and optionally drifting gains.
/// Absent: the paper's virtual human, exactly.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct HumanSpec {
    /// Visual delay (ms) on the target terms x - tau and x - tau_h (the
    /// cursor and the target are both seen on the monitor that late).
    #[schemars(range(min = 0.0, max = 300.0))]
    pub visual_delay_ms: f64,
    /// Proprioceptive delay (ms) on the velocity term.
    #[schemars(range(min = 0.0, max = 300.0))]
    pub proprioceptive_delay_ms: f64,
    /// k_m: white noise of std k_m |c| on the partner's command c (the
    /// constant floor is world.motor_noise_std).
    #[schemars(range(min = 0.0, max = MAX_MAGNITUDE))]
    pub motor_noise_gain: f64,
    /// Slow drift of the gains; absent: none.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gain_drift: Option<GainDriftSpec>,
    /// Seed of the partner's motor noise and drift (its own stream).
    pub seed: u64,
}

impl Default for HumanSpec {
    fn default() -> Self {
        HumanSpec {
            visual_delay_ms: 0.0,
            proprioceptive_delay_ms: 0.0,
            motor_noise_gain: 0.0,
            gain_drift: None,
            seed: 24,
        }
    }
}

/// `[partner.human.gain_drift]`: each gain is L (1 + delta), delta a
/// mean-reverting random walk clipped at +-3 std.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct GainDriftSpec {
    /// Stationary relative std of delta (< 1/3, so a gain keeps its sign).
    #[schemars(range(min = 0.0, max = 0.333))]
    pub std: f64,
    /// Its time constant (s).
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = MAX_DURATION_S))]
    pub time_constant_s: f64,
}

impl Default for GainDriftSpec {
    fn default() -> Self {
        GainDriftSpec {
            std: 0.1,
            time_constant_s: 10.0,
        }
    }
}

/// `[partner]`: the virtual human, with imposed gains or LQR weights (give
/// one, not both).
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct PartnerSpec {
    /// Imposed gains [Lhx, Lhv, Lhh] over xi = [x - tau, xdot, x - tau_h]
    /// (the Hi5 virtual human: [0, 0, Lhh]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schemars(length(min = 3, max = 3), inner(range(min = -MAX_MAGNITUDE, max = MAX_MAGNITUDE)))]
    pub gains: Option<Vec<f64>>,
    /// LQR weight on the partner's own position error (instead of gains).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = MAX_MAGNITUDE))]
    pub q_pos: Option<f64>,
    /// LQR weight on the velocity (with q_pos; default 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schemars(range(min = 0.0, max = MAX_MAGNITUDE))]
    pub q_vel: Option<f64>,
    /// Torque limit (model torque unit).
    #[serde(default = "default_torque_limit")]
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = MAX_MAGNITUDE))]
    pub torque_limit: f64,
    /// The partner also identifies the robot (the simulation section).
    #[serde(default)]
    pub estimates_robot: bool,
    /// Which handle state the virtual human's torque law reads (simulation
    /// only): "measured", the robot's noisy sample (one position-noise draw
    /// in both x - tau and x - tau_h, as inside the rig loop), or "true".
    #[serde(default)]
    pub acts_on: ActsOnSpec,
    /// A human-like partner; absent: the paper's virtual human.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub human: Option<HumanSpec>,
    /// The partner's goal integration (the simulation section's "Goal
    /// integration"); absent: off, the partner tracks its own target exactly.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub integration: Option<PartnerIntegrationSpec>,
}

/// The handle state an agent's torque law reads.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum ActsOnSpec {
    /// The noisy measurement the robot receives.
    #[default]
    Measured,
    /// The true handle state.
    True,
}

/// `[partner.integration]`: the partner runs the robot's controller on the
/// mirrored protocol (the robot's filter settings; needs estimates_robot):
/// in integration phases it sees its own target through white noise and
/// fuses the robot's estimated target with it.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct PartnerIntegrationSpec {
    /// Std of the white noise on the partner's view of its own target in
    /// every integration phase (position unit).
    #[schemars(range(min = 0.0, max = MAX_MAGNITUDE))]
    pub target_noise_std: f64,
    /// Let the integrated estimate drive the partner's command.
    pub integrate: bool,
    /// Seed of the partner's target-view noise.
    pub seed: u64,
}

impl Default for PartnerIntegrationSpec {
    fn default() -> Self {
        PartnerIntegrationSpec {
            target_noise_std: 0.0,
            integrate: true,
            seed: 2,
        }
    }
}

fn default_torque_limit() -> f64 {
    1e3
}

impl Default for PartnerSpec {
    /// Without a `[partner]` table: the Hi5 virtual human with Lhh = 2.
    fn default() -> Self {
        PartnerSpec {
            gains: Some(vec![0.0, 0.0, 2.0]),
            q_pos: None,
            q_vel: None,
            torque_limit: default_torque_limit(),
            estimates_robot: false,
            acts_on: ActsOnSpec::Measured,
            human: None,
            integration: None,
        }
    }
}

/// Unit of the controller's positions; the torque, gain and mass units
/// follow from it (docs/model.md, Units).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, Serialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum PositionUnit {
    /// Degrees (the paper's Hi5 numbers): torque in (pi/180) N m.
    Deg,
    /// Radians: torque in N m.
    Rad,
    /// Metres, a linear handle (the paper's simulation section: force in N,
    /// mass in kg). Simulation only: the rig's joint is revolute and
    /// `sensaug-rt` refuses it.
    M,
}

impl PositionUnit {
    /// Whether the unit is an angle (the only kind the rig's revolute joint,
    /// and its drive's rad and N m, can take).
    pub fn is_angle(self) -> bool {
        matches!(self, PositionUnit::Deg | PositionUnit::Rad)
    }
}

/// The drive's protocol on the CAN bus.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, Serialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum DriveProfile {
    /// The Hi5 protocol (`hi5.dbc`, docs/can_protocol.md).
    Hi5,
    /// CiA 402 over CANopen (docs/cia402.md): rated torque, maximum torque,
    /// encoder and gear ratios are read from the drive over SDO at set-up.
    Cia402,
}

impl DriveProfile {
    /// Its name in a configuration file (`rig.drive`).
    pub fn name(self) -> &'static str {
        match self {
            DriveProfile::Hi5 => "hi5",
            DriveProfile::Cia402 => "cia402",
        }
    }

    /// The drive watchdog's range on this profile (ms, both ends included)
    /// within [`WATCHDOG_MS_MIN`]..=[`WATCHDOG_MS_MAX`], and what bounds it.
    pub fn watchdog_ms_range(self) -> (u32, u32, &'static str) {
        let within = |min: f64, max: f64| {
            (
                min.max(WATCHDOG_MS_MIN) as u32,
                max.min(WATCHDOG_MS_MAX) as u32,
            )
        };
        match self {
            DriveProfile::Hi5 => {
                let ms = sensaug_bridge::dbc::set_state::WATCHDOG_MS;
                let (min, max) = within(ms.min, ms.max);
                (
                    min,
                    max,
                    "the Hi5 protocol's SetState.watchdog_ms (hi5.dbc)",
                )
            }
            DriveProfile::Cia402 => {
                use sensaug_bridge::cia402::master::DRIVE_CONSUMER_MS_MIN;
                let (min, max) = within(f64::from(DRIVE_CONSUMER_MS_MIN), f64::from(u16::MAX));
                (
                    min,
                    max,
                    "the drive's heartbeat consumer time (0x1016, 16-bit ms, longer than the \
                     master's 1 ms least heartbeat period)",
                )
            }
        }
    }
}

/// `[rig.realtime]`: thread settings of the loop; each falls back with a
/// warning if the OS refuses it.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct RealtimeSpec {
    /// SCHED_FIFO priority 1..99; absent keeps the default scheduler.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schemars(range(min = 1, max = 99))]
    pub fifo_priority: Option<u32>,
    /// CPU to pin the loop thread to; absent: no pinning.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schemars(range(max = 1023))]
    pub cpu: Option<u32>,
    /// Lock all memory (mlockall) before the loop.
    pub mlockall: bool,
    /// Sleep-then-spin wake-up (us; 0: off, the tick sleeps until its
    /// deadline). With spin_us > 0 each tick sleeps until spin_us before
    /// its deadline, then busy-waits on the clock until the deadline: an OS
    /// timer wake-up later than its target by less than spin_us no longer
    /// delays the tick. The cost: the loop's cpu is busy for spin_us of
    /// every period (100 us at 1 kHz: 10% of a cpu). Best with `cpu` (the
    /// spin stays on the loop's own cpu, which the log writer avoids) and
    /// `fifo_priority` (no ordinary thread preempts the spin); with /dev/cpu_dma_latency held at 0 the
    /// idle cpu polls anyway (no deep idle state), so the spin costs no more
    /// power than idling would, though it gives its cpu to no one. Must be
    /// below half the loop period.
    #[schemars(range(max = 900))]
    pub spin_us: u32,
}

impl Default for RealtimeSpec {
    fn default() -> Self {
        RealtimeSpec {
            fifo_priority: None,
            cpu: None,
            mlockall: true,
            spin_us: 0,
        }
    }
}

/// `[rig.cia402]`: settings of the CiA 402 profile (`rig.drive = "cia402"`;
/// ignored on the Hi5).
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct Cia402Spec {
    /// The master's heartbeat consumer time for the drive (ms): a drive
    /// heartbeat missing this long stops the run with an emergency stop
    /// ("drive fault: the drive's heartbeat lost"). The drive is set to beat
    /// every half of it (0x1017). At most 3 x rig.watchdog_ms (the drive
    /// watches the master within the watchdog; the master watches the drive
    /// within a small multiple of it).
    #[schemars(range(min = 10, max = 600))]
    pub heartbeat_timeout_ms: u32,
    /// How the master tells a TPDO answering this tick's SYNC from a late or
    /// replayed one: "auto" (the SYNC counter echo 0x2000 if the drive's
    /// dictionary has it, else standard), "sync_counter_echo" (a drive
    /// without 0x2000 is refused) or "standard" (judged from the bus: a TPDO
    /// received after SYNC k and before SYNC k+1 answers SYNC k; a replay
    /// inside that window goes unseen, docs/safety.md). The statistics'
    /// drive.freshness says which ran.
    pub freshness: Cia402Freshness,
}

impl Default for Cia402Spec {
    fn default() -> Self {
        Cia402Spec {
            heartbeat_timeout_ms: 100,
            freshness: Cia402Freshness::Auto,
        }
    }
}

/// `rig.cia402.freshness` (docs/cia402.md, "Freshness").
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, Serialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum Cia402Freshness {
    /// The echo if the drive has 0x2000, else standard (set-up reads it).
    Auto,
    /// The SYNC counter echo 0x2000; a drive without it is refused.
    SyncCounterEcho,
    /// Judged from the bus, whether or not the drive has 0x2000.
    Standard,
}

impl From<Cia402Freshness> for sensaug_bridge::cia402::FreshnessSetting {
    fn from(f: Cia402Freshness) -> Self {
        match f {
            Cia402Freshness::Auto => Self::Auto,
            Cia402Freshness::SyncCounterEcho => Self::SyncCounterEcho,
            Cia402Freshness::Standard => Self::Standard,
        }
    }
}

/// `[rig]`: the real-time loop, its CAN link, its safety limits and outputs.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct RigSpec {
    /// CAN link: "udp:<port>" (loopback virtual bus, port 1..65535) or
    /// "socketcan:<ifname>".
    pub can: String,
    /// Drive profile: "hi5" or "cia402" (its units are read from the drive
    /// over SDO; its heartbeat consumer is armed with `watchdog_ms`).
    pub drive: DriveProfile,
    /// Drive node id (CiA 402: 1..15, node 0 is NMT broadcast).
    #[schemars(range(max = 15))]
    pub node_id: u32,
    /// Unit of the controller's positions: "deg" or "rad" on the rig (the
    /// drive speaks rad and N m, and torque is scaled by the same factor),
    /// "m" for a simulated linear handle (force in N; the rig refuses it;
    /// docs/model.md, Units).
    pub position_unit: PositionUnit,
    /// Torque limit at the drive (N m).
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = TORQUE_NM_MAX))]
    pub torque_limit_nm: f64,
    /// Drive command watchdog (ms): the drive disables itself when commands
    /// stop for this long (Hi5: 5..200, hi5.dbc's SetState.watchdog_ms;
    /// CiA 402: 2..200, the drive's heartbeat consumer time 0x1016).
    #[schemars(range(min = WATCHDOG_MS_MIN, max = WATCHDOG_MS_MAX))]
    pub watchdog_ms: u32,
    /// Feedback older than this stops the loop with an emergency stop (ms).
    #[schemars(range(min = 1.0, max = 300.0))]
    pub feedback_timeout_ms: f64,
    /// The controlled stop (every stop but an emergency stop; docs/safety.md,
    /// "The controlled stop"): the longest it brakes before the drive is
    /// disabled (s). 0: torque off at once.
    #[schemars(range(min = 0.0, max = 2.0))]
    pub stop_time_limit_s: f64,
    /// The controlled stop's velocity time constant (s): the brake is a
    /// damping torque `-(plant.mass / stop_time_constant_s) v` on the
    /// measured velocity, so the handle's speed decays by `dt /
    /// stop_time_constant_s` of itself per tick. At least two loop periods
    /// (stable with one period of feedback delay).
    #[schemars(range(min = 0.0001, max = 1.0))]
    pub stop_time_constant_s: f64,
    /// The controlled stop's largest brake torque (N m); every command is
    /// also clamped at `torque_limit_nm`.
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = TORQUE_NM_MAX))]
    pub stop_torque_limit_nm: f64,
    /// The controlled stop ends (the drive is disabled) once the measured
    /// speed is below this (rad/s).
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = 1.0))]
    pub stop_rest_velocity_rad_s: f64,
    /// Run the virtual human inside the loop (false: a person holds the handle).
    pub virtual_human: bool,
    /// Log file (CSV with metadata, docs/logs.md).
    pub log: String,
    /// Loop statistics (JSON).
    pub stats: String,
    /// Log ring capacity (records).
    #[schemars(range(min = 1024, max = 4194304))]
    pub ring_capacity: u64,
    /// Feedback plausibility: a feedback velocity beyond this (rad/s, the
    /// drive's velocity limit; the virtual Hi5 faults OVERSPEED above 8)
    /// stops the loop ("implausible feedback", docs/safety.md).
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = FEEDBACK_VELOCITY_MAX))]
    pub max_feedback_velocity_rad_s: f64,
    /// Feedback plausibility: a position step between two feedbacks larger
    /// than `max_feedback_velocity_rad_s` times their time apart plus this
    /// margin (rad) stops the loop ("implausible feedback").
    #[schemars(range(min = 0.0, max = 1.0))]
    pub feedback_step_margin_rad: f64,
    /// Feedback consistency: a feedback velocity farther from the velocity
    /// the position's change implies than the plant allows (its largest
    /// acceleration, `torque_limit_nm / plant.mass`, over the time between
    /// the two feedbacks) plus this margin (rad/s: encoder quantisation,
    /// a drive's velocity filter) stops the loop ("implausible feedback",
    /// docs/safety.md).
    #[schemars(range(min = 0.0, max = 8.0))]
    pub feedback_velocity_margin_rad_s: f64,
    /// Degraded run: more than this fraction of ticks without fresh
    /// feedback (over the run so far, the first second counted as a whole
    /// second) turns the torque off and stops ("degraded").
    #[schemars(range(min = 0.0, max = 1.0))]
    pub max_missing_feedback_fraction: f64,
    /// Degraded run: more than this many consecutive ticks without fresh
    /// feedback turns the torque off and stops ("degraded").
    #[schemars(range(min = 1, max = 100000))]
    pub max_stale_feedback_ticks: u64,
    /// Degraded run: more than this many estimator errors (filter
    /// recoveries) or non-finite controller outputs stops the run with the
    /// controlled stop ("degraded").
    #[schemars(range(max = 1000000))]
    pub max_estimator_errors: u64,
    /// Thread settings.
    pub realtime: RealtimeSpec,
    /// CiA 402 profile settings.
    pub cia402: Cia402Spec,
    /// The handle's range of motion and speed for the wrist in it (deg):
    /// soft end stops with a virtual wall, hard limits, a speed limit
    /// (docs/safety.md, "Range of motion").
    pub range: RangeSpec,
    /// The handle's friction the loop compensates (`sensaug calibrate`
    /// identifies it; docs/hardware.md, "Calibrating the handle"). Off by
    /// default (both zero).
    pub friction: FrictionSpec,
}

impl Default for RigSpec {
    fn default() -> Self {
        RigSpec {
            can: "udp:47100".into(),
            drive: DriveProfile::Hi5,
            node_id: 1,
            position_unit: PositionUnit::Deg,
            torque_limit_nm: 3.0,
            watchdog_ms: 50,
            feedback_timeout_ms: 20.0,
            stop_time_limit_s: 0.2,
            stop_time_constant_s: 0.004,
            stop_torque_limit_nm: 3.0,
            stop_rest_velocity_rad_s: 0.01,
            virtual_human: true,
            log: "out/rig_log.csv".into(),
            stats: "out/rig_stats.json".into(),
            ring_capacity: 1 << 16,
            max_feedback_velocity_rad_s: 8.0,
            feedback_step_margin_rad: 0.01,
            feedback_velocity_margin_rad_s: 0.05,
            max_missing_feedback_fraction: 0.5,
            max_stale_feedback_ticks: 100,
            max_estimator_errors: 10,
            realtime: RealtimeSpec::default(),
            cia402: Cia402Spec::default(),
            range: RangeSpec::default(),
            friction: FrictionSpec::default(),
        }
    }
}

/// `[rig.range]`: the handle's range of motion and speed, in degrees
/// whatever `rig.position_unit` (like every `[rig]` field, the unit is in
/// the name), enforced by `sensaug-rt` every tick (docs/safety.md, "Range
/// of motion"; the defaults and their sources: docs/person.md). The
/// simulation ignores it.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct RangeSpec {
    /// Soft end stop, low side (deg): below it a virtual wall (a
    /// spring-damper, `wall_stiffness_nm_per_deg`,
    /// `wall_damping_nm_s_per_deg`) pushes the handle back.
    #[schemars(range(min = -180.0, max = 180.0))]
    pub soft_min_deg: f64,
    /// Soft end stop, high side (deg).
    #[schemars(range(min = -180.0, max = 180.0))]
    pub soft_max_deg: f64,
    /// Hard limit, low side (deg): a measured position below it stops the
    /// run with the controlled stop ("range limit"). Below `soft_min_deg`.
    #[schemars(range(min = -180.0, max = 180.0))]
    pub hard_min_deg: f64,
    /// Hard limit, high side (deg). Above `soft_max_deg`.
    #[schemars(range(min = -180.0, max = 180.0))]
    pub hard_max_deg: f64,
    /// Width of the ramp-down inside each soft end stop (deg): the
    /// controller's torque toward a soft end stop is scaled from 1, at
    /// `ramp_width_deg` from it, down to 0 at it (the partner's is not).
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = 180.0))]
    pub ramp_width_deg: f64,
    /// The wall's stiffness beyond a soft end stop (N m/deg). Absent:
    /// `plant.mass / (8 plant.dt_s)^2` (0.955 N m/deg for the Hi5 at 1 kHz;
    /// the wall's natural frequency is 1/8 rad per tick).
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schemars(range(min = 0.0, max = 100.0))]
    pub wall_stiffness_nm_per_deg: Option<f64>,
    /// The wall's damping beyond a soft end stop (N m s/deg); the wall only
    /// ever pushes back into the window. Absent: `plant.mass / (8
    /// plant.dt_s)` (0.00764 N m s/deg for the Hi5 at 1 kHz: 1/8 of the
    /// speed per tick).
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schemars(range(min = 0.0, max = 10.0))]
    pub wall_damping_nm_s_per_deg: Option<f64>,
    /// Soft speed limit (deg/s): above it a damping torque on the excess
    /// speed (`speed_damping_nm_s_per_deg`) slows the handle.
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = 1e5))]
    pub soft_speed_deg_s: f64,
    /// Hard speed limit (deg/s): a measured speed above it stops the run
    /// with the controlled stop ("range limit"). Above `soft_speed_deg_s`,
    /// below `rig.max_feedback_velocity_rad_s`.
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = 1e5))]
    pub hard_speed_deg_s: f64,
    /// Damping on the speed above `soft_speed_deg_s` (N m s/deg). Absent:
    /// `plant.mass / (8 plant.dt_s)`, as the wall's (the two together
    /// critically damped with one tick of feedback delay).
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schemars(range(min = 0.0, max = 10.0))]
    pub speed_damping_nm_s_per_deg: Option<f64>,
}

impl Default for RangeSpec {
    /// The Hi5 wrist (docs/person.md, "Range of motion"): soft end stops at
    /// +-40 deg (the wrist's functional range in flexion and extension),
    /// hard limits at +-50 deg (inside the average maximum extension of
    /// 60 deg), a 5 deg ramp; the wall and the speed damping from the plant
    /// ([`crate::rig::RangeSettings::new`]); speed limits 200 and 400 deg/s.
    fn default() -> Self {
        RangeSpec {
            soft_min_deg: -40.0,
            soft_max_deg: 40.0,
            hard_min_deg: -50.0,
            hard_max_deg: 50.0,
            ramp_width_deg: 5.0,
            wall_stiffness_nm_per_deg: None,
            wall_damping_nm_s_per_deg: None,
            soft_speed_deg_s: 200.0,
            hard_speed_deg_s: 400.0,
            speed_damping_nm_s_per_deg: None,
        }
    }
}

/// `[rig.friction]`: the handle's Coulomb and viscous friction, compensated
/// by the loop before its model applies (the paper's Hi5 is modelled "after
/// Coulomb and viscous friction compensation"): the command gains
/// `viscous_nm_s_per_rad v + coulomb_nm s` on the measured velocity `v`
/// (rad/s), the Coulomb term's sign `s` the velocity's while the handle
/// moves and the asked torque's at rest, ramped over `coulomb_band_rad_s`
/// and `coulomb_torque_band_nm` (docs/hardware.md, "Calibrating the
/// handle"), inside the torque limit. `sensaug calibrate` identifies both
/// and writes this table. The simulation ignores it (its handle is
/// `[plant]`).
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct FrictionSpec {
    /// Coulomb friction to compensate (N m); 0: none. At most
    /// `rig.torque_limit_nm`.
    #[schemars(range(min = 0.0, max = TORQUE_NM_MAX))]
    pub coulomb_nm: f64,
    /// Viscous friction to compensate (N m s/rad); 0: none. Its gain per
    /// tick, `viscous_nm_s_per_rad plant.dt_s / plant.mass`, at most 1/2.
    #[schemars(range(min = 0.0, max = 10.0))]
    pub viscous_nm_s_per_rad: f64,
    /// The Coulomb term's velocity band (rad/s): below this speed its sign
    /// blends linearly from the velocity's to the asked torque's, so the
    /// compensation is continuous through zero velocity and never chatters
    /// on the velocity report's noise; keep it above that noise (the
    /// default is 2000 steps of the Hi5 report's 1e-6 rad/s; a drive that
    /// reports the finite difference of its encoder needs several counts
    /// per period).
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = 10.0))]
    pub coulomb_band_rad_s: f64,
    /// The Coulomb term's torque band at rest (N m): at rest its sign is
    /// `clamp(tau / coulomb_torque_band_nm, -1, 1)` of the torque `tau` the
    /// controller and the partner ask, so a push breaks the handle's
    /// stiction and a torque dithering about zero does not flip it; keep it
    /// at a few of the drive's torque steps or more.
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = TORQUE_NM_MAX))]
    pub coulomb_torque_band_nm: f64,
}

impl Default for FrictionSpec {
    /// Off: no compensation (the presets run bit-identical).
    fn default() -> Self {
        FrictionSpec {
            coulomb_nm: 0.0,
            viscous_nm_s_per_rad: 0.0,
            coulomb_band_rad_s: 0.002,
            coulomb_torque_band_nm: 0.0005,
        }
    }
}
