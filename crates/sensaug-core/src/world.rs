//! The simulated world of a trial: the true handle, the motor and sensor
//! noise, the partner agent (a [`VirtualHuman`], and in the simulation
//! section its mirrored identification of the robot, or with goal
//! integration the robot's own controller on the mirrored protocol) around
//! a [`Robot`], each tick written into one log [`Row`] (caller-provided
//! buffers, or handed to a closure).
//!
//! Everything is built and validated at set-up; a tick allocates nothing.

use crate::agent::{mirrored, Guard, HumanLike, PartnerLaw};
use crate::controller::{Robot, RobotConfig, RobotCounters};
use crate::delay::DelayEvidence;
use crate::identifier::{Identifier, PartnerDelay};
use crate::plant::{Plant, PlantParams, PlantState};
use crate::protocol::{Phase, PhaseKind, Protocol, Sample, MAX_PHASES};
use crate::rng::Noise;
use crate::row::Row;
use crate::ScenarioError;
use nalgebra::Vector3;

/// What the partner's mirrored identifier says about the robot in one tick
/// (gains in the robot's `xi` order).
pub use crate::identifier::PartnerEstimate;

/// The partner agent of a simulated trial (the virtual human).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PartnerConfig {
    /// Its gains over `xi` (e.g. `[0, 0, Lhh]` for the Hi5 virtual human,
    /// `[0, k_vel, k_pos]` for an LQR partner, `docs/model.md`).
    pub gains: [f64; 3],
    /// Torque limit, > 0.
    pub torque_limit: f64,
    /// Whether the partner also identifies the robot (the simulation
    /// section): an [`Identifier`] with the robot's filter settings on the
    /// mirrored `xi`.
    pub estimates_robot: bool,
    /// Which handle state the virtual human's torque law reads.
    pub acts_on: StateSource,
    /// The human-like partner's delays, motor noise and drift
    /// (`partner.human`); `None`: the paper's virtual human, exactly.
    pub human: Option<HumanLike>,
    /// The partner's goal integration (the simulation section's "Goal
    /// integration"); `None`: in integration phases the partner tracks its
    /// own target exactly, as a virtual human does.
    pub integration: Option<PartnerIntegration>,
}

/// The handle state an agent's torque law reads.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum StateSource {
    /// The sensed state: the same noisy `(x, v)` sample the robot receives
    /// (one position-noise draw enters both `x - tau` and `x - tau_h`).
    #[default]
    Measured,
    /// The true state of the handle.
    True,
}

/// Goal integration by the partner: the robot's whole controller
/// ([`Robot`]) run on the mirrored protocol (own target `tau_h`, partner
/// target `tau`), with the partner's gains and the robot's filter settings.
/// Needs `estimates_robot` (its stage 2 is the partner channel).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PartnerIntegration {
    /// Std of the white noise on the partner's view of its own target in
    /// integration phases (position unit), >= 0.
    pub target_noise_std: f64,
    /// Let the integrated estimate drive the partner's command.
    pub integrate: bool,
    /// Seed of the partner's target-view noise.
    pub seed: u64,
}

/// The simulated world around the agents.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WorldConfig {
    /// The true handle.
    pub plant: PlantParams,
    /// Initial handle state.
    pub initial: PlantState,
    /// Std of the motor noise `eps` added to the summed torque (eq.dynamics).
    pub motor_noise_std: f64,
    /// Std of the position sensor noise.
    pub position_noise_std: f64,
    /// Std of the velocity sensor noise.
    pub velocity_noise_std: f64,
    /// Seed of the motor and sensor noise.
    pub seed: u64,
}

/// The partner's identification of the robot (simulation section): the
/// robot's [`Identifier`] on `[x - tau_h, xdot, x - tau]`, driven by the
/// partner's own torque `u_h`; gains reported in the robot's `xi` order. It
/// does not run in integration phases.
fn mirror_tick(
    id: &mut Identifier,
    s: &Sample<'_>,
    (x, v): (f64, f64),
    u_h: f64,
) -> PartnerEstimate {
    if s.phase.kind == PhaseKind::Integration {
        return PartnerEstimate::NONE;
    }
    let est = id.update(s, Some(Vector3::new(x - s.tau_h, v, x - s.tau)), x, None);
    id.predict(s.phase.kind, u_h, s.dtau_h, s.dtau);
    est.mirrored()
}

/// The partner model of the partner's identification of the robot
/// (`docs/model.md`, "The partner in simulation"): the paper's when the
/// robot runs the paper's (`robot.partner_delay` absent: bit-identical);
/// otherwise the delay-aware model with the delay identified online, as the
/// robot's `"auto"`. Not the robot's configured number: that is the
/// partner's delay, and the robot's own is what the search finds (0 here:
/// the robot acts on the sample it measures, the one the mirror sees).
fn mirror_delay(robot: PartnerDelay) -> PartnerDelay {
    match robot {
        PartnerDelay::Paper => PartnerDelay::Paper,
        PartnerDelay::Known { .. } | PartnerDelay::Auto => PartnerDelay::Auto,
    }
}

/// What a finished trial reports besides its records.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RunSummary {
    /// Ticks run.
    pub ticks: usize,
    /// The robot's counters.
    pub robot: RobotCounters,
    /// Partner commands clamped or replaced.
    pub partner_guarded: u64,
    /// Mirrored-estimator errors (each handled by the filter).
    pub mirror_errors: u64,
}

impl RunSummary {
    /// Each count by name, as a simulated trial's summary reports it (the
    /// robot's counters but `missing_measurements`: a simulation measures
    /// every tick).
    pub fn named(&self) -> [(&'static str, u64); 7] {
        let [clamped, non_finite, errors, resymmetrised, _] = self.robot.named();
        [
            ("ticks", self.ticks as u64),
            clamped,
            non_finite,
            errors,
            resymmetrised,
            ("partner_guarded", self.partner_guarded),
            ("mirror_errors", self.mirror_errors),
        ]
    }
}

/// The memory a simulated trial's log may take: half of what is available
/// when it starts. The log is one record per tick, kept whole in memory;
/// writing it to a file takes a second copy (`sensaug run` peaks at about
/// 2.1x the log), and the rest of the process and of the machine need room.
pub fn log_budget(available_bytes: u64) -> u64 {
    available_bytes / 2
}

/// A simulated trial whose log would take more memory than it may
/// ([`check_log_memory`]); names the fields that make it large.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LogTooLarge {
    /// Phases in the protocol.
    pub phases: usize,
    /// The protocol's length (s).
    pub duration_s: f64,
    /// Loop period (s).
    pub dt_s: f64,
    /// Ticks in the trial.
    pub ticks: u64,
    /// Bytes its log needs.
    pub bytes: u64,
    /// Bytes it may take; `None`: the system refused to reserve `bytes`.
    pub budget: Option<u64>,
}

impl LogTooLarge {
    /// The trial of `protocol` at `record_bytes` per tick, over `budget`.
    pub fn new(protocol: &Protocol<'_>, record_bytes: usize, budget: Option<u64>) -> Self {
        LogTooLarge {
            phases: protocol.phases().len(),
            duration_s: protocol.phases().iter().map(|p| p.duration_s).sum(),
            dt_s: protocol.dt_s(),
            ticks: protocol.total_ticks(),
            bytes: log_bytes(protocol, record_bytes),
            budget,
        }
    }

    /// The fields that make a trial's log large: the error's field.
    pub const FIELD: &'static str = "phases[*].duration_s, plant.dt_s";

    /// What is wrong and the fix, without [`Self::FIELD`].
    pub fn message(&self) -> impl core::fmt::Display + '_ {
        LogTooLargeMessage(self)
    }
}

struct LogTooLargeMessage<'a>(&'a LogTooLarge);

impl core::fmt::Display for LogTooLargeMessage<'_> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let e = self.0;
        let gb = |b: u64| b as f64 / 1e9;
        write!(
            f,
            "{} phase(s) of {} s in all at plant.dt_s = {} s are {} ticks, whose log needs \
             {:.2} GB of memory, ",
            e.phases,
            e.duration_s,
            e.dt_s,
            e.ticks,
            gb(e.bytes),
        )?;
        match e.budget {
            Some(b) => write!(f, "more than the {:.2} GB this trial may take", gb(b))?,
            None => f.write_str("which the system refused to reserve")?,
        }
        f.write_str("; shorten the phases, raise plant.dt_s, or split the trial into shorter runs")
    }
}

impl core::fmt::Display for LogTooLarge {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "{}: {}", Self::FIELD, self.message())
    }
}

/// The bytes of `protocol`'s log kept in memory at `record_bytes` per tick
/// (saturating at `u64::MAX`).
pub fn log_bytes(protocol: &Protocol<'_>, record_bytes: usize) -> u64 {
    protocol.total_ticks().saturating_mul(record_bytes as u64)
}

/// The bytes of `protocol`'s log at `record_bytes` per tick, checked before
/// the trial runs: `Err` when more than `budget_bytes`.
pub fn check_log_memory(
    protocol: &Protocol<'_>,
    record_bytes: usize,
    budget_bytes: u64,
) -> Result<u64, LogTooLarge> {
    let e = LogTooLarge::new(protocol, record_bytes, Some(budget_bytes));
    if e.bytes <= budget_bytes {
        Ok(e.bytes)
    } else {
        Err(e)
    }
}

/// The partner agent of a simulated trial.
// One per trial, built at set-up; without `alloc` there is no box to move
// the larger variant into, and the size costs nothing per tick.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug)]
enum Partner<'a> {
    /// A virtual human: its torque law on its true target, reading the
    /// `acts_on` state, and optionally its identifier of the robot (stages
    /// 1 and 2; not run in integration phases).
    Virtual {
        law: PartnerLaw,
        acts_on: StateSource,
        mirror: Option<Identifier>,
    },
    /// The goal-integrating partner: the robot's controller on the mirrored
    /// protocol (see [`PartnerIntegration`]).
    Mirrored(Robot<'a>),
}

/// The phases as the partner sees them: targets swapped, the partner's own
/// target-view noise.
fn mirrored_phases<'a>(phases: &[Phase<'a>], target_noise_std: f64) -> [Phase<'a>; MAX_PHASES] {
    let mut out = [phases[0]; MAX_PHASES];
    for (o, p) in out.iter_mut().zip(phases) {
        *o = Phase {
            robot_target: p.partner_target,
            partner_target: p.robot_target,
            target_noise_std,
            ..*p
        };
    }
    out
}

/// A simulated trial: robot, partner, plant and noise.
#[derive(Clone, Debug)]
pub struct Scenario<'a> {
    robot: Robot<'a>,
    partner: Partner<'a>,
    world: WorldConfig,
    plant: Plant,
    noise: Noise,
}

impl<'a> Scenario<'a> {
    /// Set-up: validates everything and builds every part.
    pub fn new(
        phases: &[Phase<'a>],
        robot: RobotConfig,
        partner: PartnerConfig,
        world: WorldConfig,
    ) -> Result<Self, ScenarioError> {
        let protocol = Protocol::new(phases, world.plant.dt_s)?;
        let mut plant = Plant::new(world.plant).map_err(ScenarioError::Plant)?;
        if !(world.initial.x.is_finite() && world.initial.v.is_finite()) {
            return Err(ScenarioError::InvalidSetting("world.initial"));
        }
        plant.set_state(world.initial);
        for (v, name) in [
            (world.motor_noise_std, "world.motor_noise_std"),
            (world.position_noise_std, "world.position_noise_std"),
            (world.velocity_noise_std, "world.velocity_noise_std"),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(ScenarioError::InvalidSetting(name));
            }
        }
        let virtual_human = PartnerLaw::new(
            partner.gains,
            partner.torque_limit,
            partner.human,
            world.plant.dt_s,
        )?;
        let cfg = robot;
        let robot = Robot::new(cfg, protocol)?;
        let partner = match partner.integration {
            None => Partner::Virtual {
                law: virtual_human,
                acts_on: partner.acts_on,
                // The partner knows no prior robot gains.
                mirror: if partner.estimates_robot {
                    Some(
                        cfg.identifier(protocol.dt_s(), None)?
                            .with_delay(mirror_delay(cfg.partner_delay))?,
                    )
                } else {
                    None
                },
            },
            Some(pi) => {
                if partner.human.is_some() {
                    return Err(ScenarioError::InvalidSetting("partner.human"));
                }
                if !partner.estimates_robot {
                    return Err(ScenarioError::InvalidSetting("partner.integration"));
                }
                if partner.acts_on != StateSource::Measured {
                    return Err(ScenarioError::InvalidSetting("partner.acts_on"));
                }
                if !(pi.target_noise_std.is_finite() && pi.target_noise_std >= 0.0) {
                    return Err(ScenarioError::InvalidSetting(
                        "partner.integration.target_noise_std",
                    ));
                }
                let store = mirrored_phases(phases, pi.target_noise_std);
                let own = Protocol::new(&store[..phases.len()], world.plant.dt_s)?;
                // The robot's controller and filter settings, with the
                // partner's gains in its own (mirrored) xi order.
                let mirrored_cfg = RobotConfig {
                    gains: mirrored(partner.gains),
                    torque_limit: partner.torque_limit,
                    integrate: pi.integrate,
                    seed: pi.seed,
                    prior_partner_gains: None,
                    partner_delay: mirror_delay(cfg.partner_delay),
                    ..cfg
                };
                Partner::Mirrored(Robot::new(mirrored_cfg, own)?)
            }
        };
        Ok(Scenario {
            robot,
            partner,
            world,
            plant,
            noise: Noise::new(world.seed),
        })
    }

    /// Ticks in the trial.
    pub fn ticks(&self) -> usize {
        self.robot.protocol().total_ticks() as usize
    }

    /// The virtual partner's identification of the robot: its delay
    /// search's current choice (the robot's delay as the partner finds it;
    /// not a log column), `None` without a mirror, a search or a choice.
    pub fn mirror_delay_evidence(&self) -> Option<DelayEvidence> {
        match &self.partner {
            Partner::Virtual {
                mirror: Some(m), ..
            } => m.delay_evidence(),
            _ => None,
        }
    }

    /// Runs the whole trial, one row per tick into `out`.
    pub fn run(&mut self, out: &mut [Row]) -> Result<RunSummary, ScenarioError> {
        let n = self.ticks();
        let Some(out) = out.get_mut(..n) else {
            return Err(ScenarioError::OutputTooShort {
                needed: n,
                got: out.len(),
            });
        };
        let mut slots = out.iter_mut();
        Ok(self.run_with(|row| {
            if let Some(slot) = slots.next() {
                *slot = *row;
            }
        }))
    }

    /// Runs the whole trial, handing each tick's log row to `each` in tick
    /// order ([`Scenario::ticks`] calls): a caller that packs rows (the
    /// Python binding) needs no buffer of the whole trial's rows.
    pub fn run_with(&mut self, mut each: impl FnMut(&Row)) -> RunSummary {
        let mut summary = RunSummary {
            ticks: self.ticks(),
            ..RunSummary::default()
        };
        // A copy, so the samples do not borrow the robot the ticks change.
        let protocol = *self.robot.protocol();
        let mut row = Row::UNKNOWN;
        // A simulation measures every tick; the rig's columns stay unknown.
        row.fresh = true;
        row.feedback_age_ticks = 0;
        for sample in protocol.samples() {
            self.tick(&sample, &mut summary, &mut row);
            each(&row);
        }
        summary.robot = self.robot.counters();
        summary.mirror_errors = match &self.partner {
            Partner::Virtual { mirror, .. } => mirror.as_ref().map_or(0, |m| m.tally().errors),
            Partner::Mirrored(p) => p.counters().estimator_errors,
        };
        if let Partner::Mirrored(p) = &self.partner {
            let c = p.counters();
            summary.partner_guarded = c.clamped + c.non_finite;
        }
        summary
    }

    /// One tick of the world: sense, robot, partner, plant; the tick's
    /// time, controller and world columns written into `row`.
    fn tick(&mut self, sample: &Sample<'_>, summary: &mut RunSummary, row: &mut Row) {
        let k = sample.k;
        let s = self.plant.state();
        let x_meas = s.x + self.noise.normal(self.world.position_noise_std);
        let v_meas = s.v + self.noise.normal(self.world.velocity_noise_std);
        self.robot.tick_at(sample, Some((x_meas, v_meas)), row);

        let (u_h, mirror) = match &mut self.partner {
            Partner::Virtual {
                law,
                acts_on,
                mirror,
            } => {
                let (x, v) = match acts_on {
                    StateSource::Measured => (x_meas, v_meas),
                    StateSource::True => (s.x, s.v),
                };
                let (u_h, g) = law.torque(x, v, sample.tau, sample.tau_h);
                if g != Guard::Passed {
                    summary.partner_guarded += 1;
                }
                let est = match mirror.as_mut() {
                    Some(m) => mirror_tick(m, sample, (x_meas, v_meas), u_h),
                    None => PartnerEstimate::NONE,
                };
                (row.e_h_meas, row.e_h_hat_own, row.e_h_hat_fused) = (f64::NAN, f64::NAN, f64::NAN);
                (u_h, est)
            }
            Partner::Mirrored(p) => {
                // The partner's controller fills its own row; the robot's
                // log keeps what it says about the robot and about x - tau_h.
                let mut own = Row::UNKNOWN;
                p.tick_with(k, Some((x_meas, v_meas)), &mut own);
                (row.e_h_meas, row.e_h_hat_own, row.e_h_hat_fused) =
                    (own.e_meas, own.e_hat_own, own.e_hat_fused);
                (own.u, partner_estimate(&own).mirrored())
            }
        };

        let eps = self.noise.normal(self.world.motor_noise_std);
        // Every term is finite (guarded), so the step cannot fail.
        let _ = self.plant.step(row.u + u_h + eps);
        row.tick = k as i64;
        row.t = k as f64 * self.robot.protocol().dt_s();
        (row.x, row.xdot, row.x_meas, row.xdot_meas) = (s.x, s.v, x_meas, v_meas);
        (row.tau, row.tau_h, row.u_h, row.eps) = (sample.tau, sample.tau_h, u_h, eps);
        row.e = s.x - sample.tau;
        [row.Lx_hat, row.Lv_hat, row.Lh_hat] = mirror.gains;
        [row.Lx_var, row.Lv_var, row.Lh_var] = mirror.gains_var;
        (row.tau_hat, row.tau_hat_var) = (mirror.target, mirror.target_var);
    }
}

/// What a mirrored partner's row says about the robot (its own `xi`
/// order; [`PartnerEstimate::mirrored`] turns it into the robot's).
fn partner_estimate(own: &Row) -> PartnerEstimate {
    PartnerEstimate {
        gains: [own.Lhx_hat, own.Lhv_hat, own.Lhh_hat],
        gains_var: [own.Lhx_var, own.Lhv_var, own.Lhh_var],
        target: own.tau_h_hat,
        target_var: own.tau_h_var,
        ..PartnerEstimate::NONE
    }
}
