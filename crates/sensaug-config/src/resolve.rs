//! From a parsed configuration to the core's structs, checking everything
//! that is not a single field's bound: phase order, covariances, LQR gains,
//! the bus URL, and timing settings against the loop period. The core's own
//! set-up ([`Protocol::new`], [`Robot::new`]) runs last, so a configuration
//! that passes here also builds.

#![allow(non_snake_case)]

use crate::cov::Cov;
use crate::error::{num, ConfigError};
use crate::rig::{period_ns, RigSettings};
use crate::schema::{
    ActsOnSpec, DriveProfile, PartnerDelaySpec, PhaseKindSpec, PositionUnit, RigSpec, RobotSpec,
    ScenarioSpec, ShapeSpec, MAX_PARTS,
};
use nalgebra::{SVector, Vector2};
use sensaug_core::agent::HumanLike;
use sensaug_core::controller::{Robot, RobotConfig};
use sensaug_core::estimator::{ExtendedFilterConfig, HandleModel};
use sensaug_core::goal::{ChannelConfig, GoalIntegratorConfig};
use sensaug_core::identifier::PartnerDelay;
use sensaug_core::plant::{PlantParams, PlantState};
use sensaug_core::protocol::{Phase, PhaseKind, Protocol};
use sensaug_core::riccati::agent_gains;
use sensaug_core::target::{Shape, Target};
use sensaug_core::ukf::MerweParams;
use sensaug_core::world::{PartnerConfig, PartnerIntegration, StateSource, WorldConfig};
use sensaug_core::ScenarioError;
use serde::ser::{Serialize, SerializeMap, Serializer};
use std::cell::Cell;

/// A configuration resolved: the file's values (every default filled in)
/// and everything derived from them, built once ([`Resolved::new`]) and
/// then passed around as one owned value: the simulation, the replay and
/// the real-time loop take their settings from it, and a log's metadata is
/// its serialisation ([`Resolved::derived`]).
#[derive(Clone, Debug)]
pub struct Resolved {
    /// The configuration, every default filled in.
    pub spec: ScenarioSpec,
    /// The robot's controller (its LQR gains solved).
    pub robot: RobotConfig,
    /// The partner (virtual human): gains over xi, torque limit.
    pub partner: PartnerConfig,
    /// The simulated world (the simulation only).
    pub world: WorldConfig,
    /// Loop period (s).
    pub dt_s: f64,
    /// rad per controller position unit on the rig (torque scales alike).
    pub rad_per_unit: f64,
    /// The real-time loop's settings.
    pub rig: RigSettings,
}

std::thread_local! {
    /// Configurations resolved on this thread ([`resolve_count`]).
    static RESOLVES: Cell<u64> = const { Cell::new(0) };
}

/// How many configurations the calling thread has resolved
/// ([`Resolved::new`]): the tests' proof that a trial resolves its
/// configuration once (per thread, so that tests running side by side do
/// not count each other's).
pub fn resolve_count() -> u64 {
    RESOLVES.with(Cell::get)
}

impl Resolved {
    /// Checks every field's bounds and the cross-field rules, solves the
    /// agents' gains and runs the core's own set-up checks: a configuration
    /// that resolves also builds.
    pub fn new(spec: ScenarioSpec) -> Result<Resolved, ConfigError> {
        RESOLVES.with(|n| n.set(n.get() + 1));
        if !spec.include.is_empty() {
            return Err(ConfigError::new(
                "include",
                "names files relative to a configuration file, but this configuration was not \
                 read from a file (text, or Python tables): read the file itself \
                 (ScenarioConfig.from_toml(path), sensaug-rt CONFIG), or give the included \
                 settings here",
            ));
        }
        let value = serde_json::to_value(&spec)
            .map_err(|e| ConfigError::new("(config)", format!("cannot be represented: {e}")))?;
        crate::check::bounds(crate::json_schema(), &value)?;
        resolve(spec)
    }

    /// The core's phases, borrowing the sampled targets of [`Self::spec`].
    pub fn phases(&self) -> Vec<Phase<'_>> {
        self.spec
            .phases
            .iter()
            .map(|ph| Phase {
                kind: kind(ph.kind),
                duration_s: ph.duration_s,
                robot_target: target(&ph.robot_target),
                partner_target: target(&ph.partner_target),
                target_noise_std: ph.target_noise_std,
            })
            .collect()
    }

    /// The values derived from the configuration that a log records
    /// (`meta["resolved"]`): the agents' gains, the period and the unit.
    pub fn derived(&self) -> serde_json::Value {
        serde_json::json!({
            "robot": {"gains": self.robot.gains},
            "partner": {"gains": self.partner.gains},
            "dt_s": self.dt_s,
            "rad_per_unit": self.rad_per_unit,
        })
    }
}

/// A resolved configuration serialises as `{"config": .., "resolved": ..,
/// "loop": ..}`: the file's values, [`Resolved::derived`] and the loop's
/// settings, the keys of a log's metadata.
impl Serialize for Resolved {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut m = s.serialize_map(Some(3))?;
        m.serialize_entry("config", &self.spec)?;
        m.serialize_entry("resolved", &self.derived())?;
        m.serialize_entry("loop", &self.rig)?;
        m.end()
    }
}

fn shape(s: &ShapeSpec) -> Shape<'_> {
    match s {
        ShapeSpec::Constant(c) => Shape::Constant { value: c.value },
        ShapeSpec::Square(q) => Shape::Square {
            amplitude: q.amplitude,
            period_s: q.period_s,
        },
        ShapeSpec::RoundedSquare(q) => Shape::RoundedSquare {
            amplitude: q.amplitude,
            period_s: q.period_s,
        },
        ShapeSpec::Chirp(c) => Shape::Chirp {
            amplitude: c.amplitude,
            f0_hz: c.f0_hz,
            f1_hz: c.f1_hz,
            duration_s: c.duration_s,
        },
        ShapeSpec::Harmonics(h) => Shape::Harmonics {
            amplitude: h.amplitude,
            omega_rad_s: h.omega_rad_s,
            harmonics: h.harmonics,
            cosine: h.cosine,
        },
        ShapeSpec::Sampled(s) => Shape::Sampled {
            samples: &s.samples,
            dt_s: s.dt_s,
        },
    }
}

fn target(specs: &[ShapeSpec]) -> Target<'_> {
    debug_assert!(specs.len() <= MAX_PARTS, "bounded by the schema");
    let mut t = Target::default();
    for (slot, s) in t.parts.iter_mut().zip(specs) {
        *slot = shape(s);
    }
    t
}

fn kind(k: PhaseKindSpec) -> PhaseKind {
    match k {
        PhaseKindSpec::Gains => PhaseKind::Gains,
        PhaseKindSpec::Trajectory => PhaseKind::Trajectory,
        PhaseKindSpec::Integration => PhaseKind::Integration,
    }
}

/// The 6-state filter's initial state: handle errors 0, the gains' guesses.
fn extended_x0(field: &str, gains0: &[f64]) -> Result<SVector<f64, 6>, ConfigError> {
    let mut x0 = SVector::<f64, 6>::zeros();
    x0.fixed_rows_mut::<3>(3)
        .copy_from_slice(&gains3(field, gains0)?);
    Ok(x0)
}

/// Three gains [Lhx, Lhv, Lhh] (the schema bounds the length; checked again
/// here for callers that resolve without validating).
fn gains3(field: &str, v: &[f64]) -> Result<[f64; 3], ConfigError> {
    <[f64; 3]>::try_from(v)
        .map_err(|_| ConfigError::new(field, format!("has {} entries; give exactly 3", v.len())))
}

fn lqr(
    field: &str,
    mass: f64,
    damping: f64,
    q_pos: f64,
    q_vel: f64,
) -> Result<[f64; 2], ConfigError> {
    agent_gains(mass, damping, q_pos, q_vel).map_err(|e| {
        ConfigError::new(
            field,
            format!(
                "no stabilizing LQR gains for these weights ({e}); use q_pos > 0 and q_vel >= 0"
            ),
        )
    })
}

/// A 6-state filter (stage 1: `M = 3`, stage 2: `M = 5`) from its table.
fn extended<const M: usize>(
    path: &str,
    [Q, P0]: [&Cov<6>; 2],
    R: &Cov<M>,
    gains0: &[f64],
    sigma: MerweParams,
) -> Result<ExtendedFilterConfig<M>, ConfigError> {
    Ok(ExtendedFilterConfig {
        x0: extended_x0(&format!("{path}.gains0"), gains0)?,
        P0: P0.matrix(&format!("{path}.P0"))?,
        Q: Q.matrix(&format!("{path}.Q"))?,
        R: R.matrix(&format!("{path}.R"))?,
        sigma,
    })
}

fn robot(r: &RobotSpec, model: HandleModel) -> Result<RobotConfig, ConfigError> {
    let [k_pos, k_vel] = lqr("robot.q_pos", model.mass, model.damping, r.q_pos, r.q_vel)?;
    let sigma = MerweParams {
        alpha: r.sigma.alpha,
        beta: r.sigma.beta,
        kappa: r.sigma.kappa,
    };
    let s1 = &r.stage1;
    let s2 = &r.stage2;
    let s3 = &r.stage3;
    Ok(RobotConfig {
        gains: [k_pos, k_vel, 0.0],
        model,
        stage1: extended("robot.stage1", [&s1.Q, &s1.P0], &s1.R, &s1.gains0, sigma)?,
        stage2: extended("robot.stage2", [&s2.Q, &s2.P0], &s2.R, &s2.gains0, sigma)?,
        stage3: GoalIntegratorConfig {
            x0: Vector2::zeros(),
            P0: s3.P0.matrix("robot.stage3.P0")?,
            Q: s3.Q.matrix("robot.stage3.Q")?,
            R_own: s3.R_sensor.matrix("robot.stage3.R_sensor")?,
            channel: ChannelConfig {
                gate: s3.channel.gate,
                window_n0: s3.channel.window_n0,
                hold_max_s: s3.channel.hold_max_s,
            },
        },
        integrate: r.integrate,
        gain_window_s: r.gain_window_s,
        prior_partner_gains: match &r.prior_partner_gains {
            Some(g) => Some(gains3("robot.prior_partner_gains", g)?),
            None => None,
        },
        torque_limit: r.torque_limit,
        seed: r.seed,
        partner_delay: match r.partner_delay {
            None => PartnerDelay::Paper,
            Some(PartnerDelaySpec::Auto(_)) => PartnerDelay::Auto,
            Some(PartnerDelaySpec::Ms(ms)) => PartnerDelay::Known {
                visual_ms: ms,
                proprioceptive_ms: ms,
            },
        },
    })
}

/// `partner.integration` needs the partner's identification of the robot
/// (`estimates_robot`, stage 2 is its partner channel), a gain phase first
/// (the partner knows no prior robot gains) and the measured state.
fn partner_integration(spec: &ScenarioSpec) -> Result<(), ConfigError> {
    let pa = &spec.partner;
    if pa.integration.is_none() {
        return Ok(());
    }
    if !pa.estimates_robot {
        return Err(ConfigError::new(
            "partner.integration",
            "needs partner.estimates_robot = true (the partner's estimate of the robot's target \
             is its partner channel); set it, or remove [partner.integration]",
        ));
    }
    if pa.acts_on != ActsOnSpec::Measured {
        return Err(ConfigError::new(
            "partner.acts_on",
            "\"true\" is for the virtual human only; a goal-integrating partner acts on its \
             measurement, like the robot: use \"measured\" or remove [partner.integration]",
        ));
    }
    if spec.phases.first().map(|p| p.kind) != Some(PhaseKindSpec::Gains) {
        return Err(ConfigError::new(
            "partner.integration",
            "the goal-integrating partner estimates the robot's gains first: make phases[0] a \
             \"gains\" phase, or remove [partner.integration]",
        ));
    }
    Ok(())
}

/// CiA 402: the master's consumer time for the drive's heartbeat is at most
/// this many drive watchdogs (`rig.cia402.heartbeat_timeout_ms`).
pub const MAX_HEARTBEAT_WATCHDOGS: u32 = 3;

fn rig_timing(rig: &RigSpec, dt_s: f64) -> Result<(), ConfigError> {
    sensaug_bridge::transport::BusUrl::parse(&rig.can)
        .map_err(|e| ConfigError::new("rig.can", e.to_string()))?;
    let dt_ms = dt_s * 1e3;
    if rig.feedback_timeout_ms < dt_ms {
        return Err(ConfigError::new(
            "rig.feedback_timeout_ms",
            format!(
                "{} ms is shorter than one loop period (plant.dt_s = {} s); use at least {} ms",
                num(rig.feedback_timeout_ms),
                num(dt_s),
                num(dt_ms)
            ),
        ));
    }
    if rig.drive == DriveProfile::Cia402 && rig.node_id == 0 {
        return Err(ConfigError::new(
            "rig.node_id",
            "0 is the NMT broadcast address, not a CANopen node (rig.drive = \"cia402\"); \
             use the drive's node-ID, 1..15",
        ));
    }
    let heartbeat = rig.cia402.heartbeat_timeout_ms;
    if rig.drive == DriveProfile::Cia402 && heartbeat > MAX_HEARTBEAT_WATCHDOGS * rig.watchdog_ms {
        return Err(ConfigError::new(
            "rig.cia402.heartbeat_timeout_ms",
            format!(
                "{heartbeat} ms is more than {MAX_HEARTBEAT_WATCHDOGS} x rig.watchdog_ms ({} ms): \
                 a drive that stopped beating would go unnoticed far longer than a master that \
                 stopped; use at most {} ms, or a longer rig.watchdog_ms",
                rig.watchdog_ms,
                MAX_HEARTBEAT_WATCHDOGS * rig.watchdog_ms
            ),
        ));
    }
    let (min, max, bound) = rig.drive.watchdog_ms_range();
    if !(min..=max).contains(&rig.watchdog_ms) {
        return Err(ConfigError::new(
            "rig.watchdog_ms",
            format!(
                "{} ms is outside {min}..={max} ms, the range of {bound} \
                 (rig.drive = \"{}\"); use a value in it",
                rig.watchdog_ms,
                rig.drive.name()
            ),
        ));
    }
    if f64::from(rig.watchdog_ms) < 2.0 * dt_ms {
        return Err(ConfigError::new(
            "rig.watchdog_ms",
            format!(
                "{} ms is shorter than two loop periods (plant.dt_s = {} s); the drive would \
                 trip between commands; use at least {} ms",
                rig.watchdog_ms,
                num(dt_s),
                num((2.0 * dt_ms).ceil())
            ),
        ));
    }
    // The brake's gain per tick is dt / stop_time_constant_s: at most 1/2
    // keeps it stable with one tick of feedback delay (docs/safety.md).
    if rig.stop_time_constant_s < 2.0 * dt_s {
        return Err(ConfigError::new(
            "rig.stop_time_constant_s",
            format!(
                "{} s is shorter than two loop periods (plant.dt_s = {} s); the brake would \
                 oscillate; use at least {} s",
                num(rig.stop_time_constant_s),
                num(dt_s),
                num(2.0 * dt_s)
            ),
        ));
    }
    // The period in whole ns, as the loop derives it. A spin of half the
    // period or more would leave the tick less time to run than it spins.
    let period_ns = period_ns(dt_s);
    let spin_us = u64::from(rig.realtime.spin_us);
    if spin_us > 0 && 2 * spin_us * 1000 >= period_ns {
        return Err(ConfigError::new(
            "rig.realtime.spin_us",
            format!(
                "{spin_us} us is not below half the loop period ({} us, plant.dt_s = {} s); \
                 choose a smaller spin_us",
                num(period_ns as f64 / 2e3),
                num(dt_s)
            ),
        ));
    }
    if rig.log.is_empty() {
        return Err(ConfigError::new(
            "rig.log",
            "empty; give the log file's path",
        ));
    }
    if rig.stats.is_empty() {
        return Err(ConfigError::new(
            "rig.stats",
            "empty; give the statistics file's path",
        ));
    }
    Ok(())
}

/// The core's set-up errors, as field errors (the schema and the checks
/// above catch them first; this maps what remains).
fn core_error(e: ScenarioError) -> ConfigError {
    match e {
        ScenarioError::PhaseCount(n) => {
            ConfigError::new("phases", format!("has {n} phases; give 1 to 4"))
        }
        ScenarioError::InvalidPhase { phase, field } => ConfigError::new(
            format!("phases[{phase}].{field}"),
            "out of range for the loop period; check it against plant.dt_s",
        ),
        ScenarioError::InvalidTarget {
            phase,
            which,
            error,
        } => ConfigError::new(
            format!("phases[{phase}].{which}[{}].{}", error.part, error.field),
            "out of range; amplitudes finite, periods and durations > 0, frequencies >= 0",
        ),
        ScenarioError::NoPartnerGains { phase } => ConfigError::new(
            format!("phases[{phase}].kind"),
            "needs an earlier \"gains\" phase or robot.prior_partner_gains",
        ),
        ScenarioError::InvalidSetting(name) => {
            ConfigError::new(name, "out of range; see `sensaug schema` for its bounds")
        }
        ScenarioError::Plant(_) => ConfigError::new(
            "plant",
            "rejected by the plant model; mass > 0, damping and coulomb >= 0, dt_s > 0",
        ),
        // Stage 3 has no sigma points: its own message names the setting.
        ScenarioError::Estimator {
            stage: "stage3",
            error,
        } => ConfigError::new("robot.stage3", format!("rejected: {error}")),
        ScenarioError::Estimator { stage, .. } => ConfigError::new(
            format!("robot.{stage}"),
            "rejected by the filter; check its covariances and robot.sigma",
        ),
        ScenarioError::OutputTooShort { .. } => {
            ConfigError::new("phases", "trial too long for the output buffer")
        }
    }
}

/// Validates the cross-field rules and builds the core's structs (the
/// fields' bounds are [`Resolved::new`]'s).
fn resolve(spec: ScenarioSpec) -> Result<Resolved, ConfigError> {
    let p = &spec.plant;
    let dt_s = p.dt_s;
    let model = HandleModel {
        mass: p.mass,
        damping: p.damping,
        dt_s,
    };
    let mut gains_known = spec.robot.prior_partner_gains.is_some();
    for (i, ph) in spec.phases.iter().enumerate() {
        if ph.duration_s < dt_s {
            return Err(ConfigError::new(
                format!("phases[{i}].duration_s"),
                format!(
                    "{} s is shorter than one tick (plant.dt_s = {} s); lengthen it",
                    num(ph.duration_s),
                    num(dt_s)
                ),
            ));
        }
        match ph.kind {
            PhaseKindSpec::Gains => gains_known = true,
            _ if !gains_known => {
                return Err(ConfigError::new(
                    format!("phases[{i}].kind"),
                    "a \"trajectory\" or \"integration\" phase needs an earlier \"gains\" phase \
                     or robot.prior_partner_gains; reorder the phases or give the prior gains",
                ))
            }
            _ => {}
        }
    }
    let robot = robot(&spec.robot, model)?;
    let pa = &spec.partner;
    let partner_gains =
        match (pa.gains.as_deref(), pa.q_pos, pa.q_vel) {
            (Some(g), None, None) => gains3("partner.gains", g)?,
            (None, Some(q_pos), q_vel) => {
                let [k_pos, k_vel] = lqr(
                    "partner.q_pos",
                    p.mass,
                    p.damping,
                    q_pos,
                    q_vel.unwrap_or(0.0),
                )?;
                // The partner's own error is x - tau_h: the third entry of xi.
                [0.0, k_vel, k_pos]
            }
            (None, None, Some(_)) => {
                return Err(ConfigError::new(
                    "partner.q_vel",
                    "given without partner.q_pos; add q_pos (LQR partner) or give gains instead",
                ))
            }
            (None, None, None) => {
                return Err(ConfigError::new(
                    "partner",
                    "give either gains = [Lhx, Lhv, Lhh] or the LQR weight q_pos (and q_vel)",
                ))
            }
            (Some(_), _, _) => return Err(ConfigError::new(
                "partner",
                "give either gains = [Lhx, Lhv, Lhh] or the LQR weights q_pos and q_vel, not both",
            )),
        };
    partner_integration(&spec)?;
    rig_timing(&spec.rig, dt_s)?;
    crate::rig::check_range(&spec.rig, p.mass, dt_s)?;
    crate::rig::check_friction(&spec.rig, p.mass, dt_s)?;
    crate::person::check(&spec)?;

    let w = &spec.world;
    let world = WorldConfig {
        plant: PlantParams {
            mass: p.mass,
            damping: p.damping,
            coulomb: p.coulomb,
            dt_s,
        },
        initial: PlantState { x: w.x0, v: w.v0 },
        motor_noise_std: w.motor_noise_std,
        position_noise_std: w.position_noise_std,
        velocity_noise_std: w.velocity_noise_std,
        seed: w.seed,
    };
    let partner = PartnerConfig {
        gains: partner_gains,
        torque_limit: pa.torque_limit,
        estimates_robot: pa.estimates_robot,
        acts_on: match pa.acts_on {
            ActsOnSpec::Measured => StateSource::Measured,
            ActsOnSpec::True => StateSource::True,
        },
        human: pa.human.as_ref().map(|h| HumanLike {
            visual_delay_ms: h.visual_delay_ms,
            proprioceptive_delay_ms: h.proprioceptive_delay_ms,
            motor_noise_gain: h.motor_noise_gain,
            drift_std: h.gain_drift.as_ref().map_or(0.0, |d| d.std),
            drift_time_constant_s: h.gain_drift.as_ref().map_or(1.0, |d| d.time_constant_s),
            seed: h.seed,
        }),
        integration: pa.integration.as_ref().map(|i| PartnerIntegration {
            target_noise_std: i.target_noise_std,
            integrate: i.integrate,
            seed: i.seed,
        }),
    };
    let rad_per_unit = match spec.rig.position_unit {
        PositionUnit::Deg => core::f64::consts::PI / 180.0,
        PositionUnit::Rad => 1.0,
        // A linear handle has no angle: only simulated (the rig refuses
        // "m" before it resolves, `check_rig_unit`); nothing reads it.
        PositionUnit::M => 1.0,
    };
    let rig = RigSettings::new(&spec, rad_per_unit, &partner, world.plant);
    let resolved = Resolved {
        spec,
        robot,
        partner,
        world,
        dt_s,
        rad_per_unit,
        rig,
    };
    // The core's own set-up checks, so that a valid file always builds.
    let phases = resolved.phases();
    let protocol = Protocol::new(&phases, dt_s).map_err(core_error)?;
    Robot::new(resolved.robot, protocol).map_err(core_error)?;
    drop(phases);
    Ok(resolved)
}
