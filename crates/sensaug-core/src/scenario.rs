//! Whole trials of the paper's protocol, stepped in Rust.
//!
//! * [`Protocol`]: the phases (partner-gain estimation, partner-trajectory
//!   estimation, goal integration), each with its duration and both targets.
//! * [`Robot`]: the robot's controller, the piece the real-time loop runs:
//!   one [`Robot::tick`] per sample does update, control and predict.
//! * [`Scenario`]: a robot, a partner agent (a virtual human), the plant and
//!   the noise, run over caller-provided [`TickRecord`] buffers.
//!
//! Everything is built at set-up and validated there; a tick allocates
//! nothing, and estimator trouble is counted, never a panic.

use crate::agent::{feedback_torque, guard_torque, mirrored, xi, Guard};
use crate::estimator::{
    EstimatorError, ExtendedFilterConfig, GainEstimator, GoalIntegrator, GoalIntegratorConfig,
    HandleModel, TrajectoryEstimator, E_H, GAINS,
};
use crate::plant::{Plant, PlantError, PlantParams, PlantState};
use crate::rng::Noise;
use crate::target::{Target, TargetError};
use crate::ukf::{Status, UkfError};
use nalgebra::{SVector, Vector2, Vector3};

/// Most phases one protocol holds.
pub const MAX_PHASES: usize = 4;

/// What the robot does during a phase.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PhaseKind {
    /// Stage 1: both targets known; estimate the partner's gains.
    Gains,
    /// Stage 2: the partner's target unknown; estimate it.
    Trajectory,
    /// Stage 3: same target for both, the robot's view of it noisy; fuse the
    /// estimated partner target with the own view.
    Integration,
}

impl PhaseKind {
    /// A number for logs: 0, 1, 2.
    pub fn code(self) -> f64 {
        match self {
            PhaseKind::Gains => 0.0,
            PhaseKind::Trajectory => 1.0,
            PhaseKind::Integration => 2.0,
        }
    }
}

/// One phase of a trial.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Phase<'a> {
    /// What the robot estimates.
    pub kind: PhaseKind,
    /// Duration (s), > 0.
    pub duration_s: f64,
    /// The robot's target `tau`.
    pub robot_target: Target<'a>,
    /// The partner's target `tau_h`.
    pub partner_target: Target<'a>,
    /// Std of the white noise on the robot's view of its own target
    /// (the "injected robot measurement noise" of the Hi5 goal integration);
    /// only used in [`PhaseKind::Integration`].
    pub target_noise_std: f64,
}

/// Set-up errors of a trial; each names what to fix.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ScenarioError {
    /// No phase, or more than [`MAX_PHASES`].
    PhaseCount(usize),
    /// A phase field is out of range.
    InvalidPhase {
        /// Phase index.
        phase: usize,
        /// Field name.
        field: &'static str,
    },
    /// A target of a phase is invalid.
    InvalidTarget {
        /// Phase index.
        phase: usize,
        /// `"robot_target"` or `"partner_target"`.
        which: &'static str,
        /// The target's own error (part and field).
        error: TargetError,
    },
    /// A trajectory or integration phase comes before any gain phase and no
    /// prior partner gains were given.
    NoPartnerGains {
        /// Phase index.
        phase: usize,
    },
    /// A robot or scenario setting is out of range.
    InvalidSetting(&'static str),
    /// The plant parameters are invalid.
    Plant(PlantError),
    /// An estimator's settings are invalid.
    Estimator {
        /// `"stage1"`, `"stage2"`, `"stage3"`.
        stage: &'static str,
        /// The estimator's error.
        error: EstimatorError,
    },
    /// The output buffer is shorter than the trial.
    OutputTooShort {
        /// Ticks in the trial.
        needed: usize,
        /// Records given.
        got: usize,
    },
}

/// One tick of the protocol (see [`Protocol::sample`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample<'a> {
    /// The tick.
    pub k: u64,
    /// Index of its phase.
    pub index: usize,
    /// Its phase.
    pub phase: Phase<'a>,
    /// First tick after its phase.
    pub end: u64,
    /// Robot target `tau` at `k`.
    pub tau: f64,
    /// Partner target `tau_h` at `k`.
    pub tau_h: f64,
    /// `tau[k+1] - tau[k]`.
    pub dtau: f64,
    /// `tau_h[k+1] - tau_h[k]`.
    pub dtau_h: f64,
}

/// The phases, and their boundaries in ticks.
#[derive(Clone, Copy, Debug)]
pub struct Protocol<'a> {
    phases: [Phase<'a>; MAX_PHASES],
    ends: [u64; MAX_PHASES],
    len: usize,
    dt_s: f64,
}

impl<'a> Protocol<'a> {
    /// Set-up: validates every phase; durations are rounded to whole ticks.
    pub fn new(phases: &[Phase<'a>], dt_s: f64) -> Result<Self, ScenarioError> {
        if phases.is_empty() || phases.len() > MAX_PHASES {
            return Err(ScenarioError::PhaseCount(phases.len()));
        }
        if !(dt_s.is_finite() && dt_s > 0.0) {
            return Err(ScenarioError::InvalidSetting("dt_s"));
        }
        let mut store = [phases[0]; MAX_PHASES];
        let mut ends = [0u64; MAX_PHASES];
        let mut end = 0u64;
        for (i, p) in phases.iter().enumerate() {
            let ticks = p.duration_s / dt_s;
            if !(1.0..1e12).contains(&ticks) {
                return Err(ScenarioError::InvalidPhase {
                    phase: i,
                    field: "duration_s",
                });
            }
            if !(p.target_noise_std.is_finite() && p.target_noise_std >= 0.0) {
                return Err(ScenarioError::InvalidPhase {
                    phase: i,
                    field: "target_noise_std",
                });
            }
            for (which, target) in [
                ("robot_target", &p.robot_target),
                ("partner_target", &p.partner_target),
            ] {
                target
                    .validate()
                    .map_err(|error| ScenarioError::InvalidTarget {
                        phase: i,
                        which,
                        error,
                    })?;
            }
            end += libm::round(ticks) as u64;
            store[i] = *p;
            ends[i] = end;
        }
        Ok(Protocol {
            phases: store,
            ends,
            len: phases.len(),
            dt_s,
        })
    }

    /// Ticks in the whole trial.
    pub fn total_ticks(&self) -> u64 {
        self.ends[self.len - 1]
    }

    /// The phases.
    pub fn phases(&self) -> &[Phase<'a>] {
        &self.phases[..self.len]
    }

    /// Everything a tick needs from the protocol, computed once per tick:
    /// the phase of tick `k`, both targets at `k` and their increments to
    /// `k + 1` (from the phase of `k`). `None` after the last tick.
    pub fn sample(&self, k: u64) -> Option<Sample<'a>> {
        let index = self.ends[..self.len].iter().position(|&end| k < end)?;
        let phase = self.phases[index];
        let t = k as f64 * self.dt_s;
        let dt = self.dt_s;
        Some(Sample {
            k,
            index,
            phase,
            end: self.ends[index],
            tau: phase.robot_target.at(t),
            tau_h: phase.partner_target.at(t),
            dtau: phase.robot_target.increment(t, dt),
            dtau_h: phase.partner_target.increment(t, dt),
        })
    }

    /// The loop period.
    pub fn dt_s(&self) -> f64 {
        self.dt_s
    }
}

/// Settings of the robot's controller.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RobotConfig {
    /// Feedback gains over `xi = [x - tau, xdot, x - tau_h]` (third entry 0
    /// for an LQR robot: `agent::robot_gains`).
    pub gains: [f64; 3],
    /// The estimators' model of the handle.
    pub model: HandleModel,
    /// Stage-1 filter (gains). `x0` holds the initial guesses.
    pub stage1: ExtendedFilterConfig<3>,
    /// Stage-2 filter (trajectory). Its `x0` is replaced at start by the
    /// stage-1 posterior, gains by their pseudo-measurement; `P0` is used.
    pub stage2: ExtendedFilterConfig<5>,
    /// Stage-3 filters (goal integration). `x0` is replaced at start by the
    /// current own measurement; `P0` is used. `R_own` is the sensor noise on
    /// `[x - tau, xdot]`; the phase's `target_noise_std^2` is added to its
    /// first entry at the phase start.
    pub stage3: GoalIntegratorConfig,
    /// Let the integrated estimate drive control in integration phases
    /// (both filters always run, for the comparison).
    pub integrate: bool,
    /// Stage-2's gain pseudo-measurement is the mean of the stage-1
    /// estimate over the last `gain_window_s` of the gain phase (8 s in the
    /// paper).
    pub gain_window_s: f64,
    /// Partner gains to use when no gain phase precedes (skips stage 1).
    pub prior_partner_gains: Option<[f64; 3]>,
    /// Torque limit (model units), > 0.
    pub torque_limit: f64,
    /// Seed of the injected target-view noise.
    pub seed: u64,
}

/// Counters of everything unusual in the robot's loop.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RobotCounters {
    /// Commands clamped to the torque limit.
    pub clamped: u64,
    /// Non-finite commands replaced by 0.
    pub non_finite: u64,
    /// Estimator calls that returned an error (each already handled by the
    /// filter: state restored or covariance reset).
    pub estimator_errors: u64,
    /// Estimator calls that needed a re-symmetrised covariance.
    pub resymmetrised: u64,
    /// Ticks without a fresh measurement (predict only).
    pub missing_measurements: u64,
}

/// What the robot did in one tick (its log line).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RobotTick {
    /// Guarded torque command.
    pub u: f64,
    /// Phase code (`PhaseKind::code`); NaN after the protocol ended.
    pub phase: f64,
    /// The robot's (possibly noisy) view of `x - tau`.
    pub e_meas: f64,
    /// Estimated partner gains (stage 1 or 2, whichever runs).
    pub gains: [f64; 3],
    /// Their posterior variances.
    pub gains_var: [f64; 3],
    /// Estimated partner target `tau_h^` (stages 2-3), NaN otherwise.
    pub tau_h_hat: f64,
    /// Posterior variance of `x - tau_h^`.
    pub tau_h_var: f64,
    /// Stage 3: `(x - tau)^` from own sensing only.
    pub e_hat_own: f64,
    /// Stage 3: `(x - tau)^` with the partner channel.
    pub e_hat_fused: f64,
    /// Posterior variance of `e_hat_own`.
    pub e_hat_own_var: f64,
    /// Posterior variance of `e_hat_fused`.
    pub e_hat_fused_var: f64,
    /// Stage 3: the partner-channel variance used.
    pub partner_var: f64,
}

impl RobotTick {
    /// No estimate anywhere (NaN), zero command: the start of every tick's
    /// log line, and the whole of it after the protocol's end.
    pub const NONE: RobotTick = RobotTick {
        u: 0.0,
        phase: f64::NAN,
        e_meas: f64::NAN,
        gains: [f64::NAN; 3],
        gains_var: [f64::NAN; 3],
        tau_h_hat: f64::NAN,
        tau_h_var: f64::NAN,
        e_hat_own: f64::NAN,
        e_hat_fused: f64::NAN,
        e_hat_own_var: f64::NAN,
        e_hat_fused_var: f64::NAN,
        partner_var: f64::NAN,
    };
}

/// The robot's controller: estimators and control law.
#[derive(Clone, Debug)]
pub struct Robot<'a> {
    cfg: RobotConfig,
    protocol: Protocol<'a>,
    stage1: GainEstimator,
    stage2: TrajectoryEstimator,
    stage3: GoalIntegrator,
    gain_sum: [f64; 3],
    gain_count: u64,
    stage2_live: bool,
    /// The integration phase stage 3 was last started for.
    integration_phase: Option<usize>,
    noise: Noise,
    counters: RobotCounters,
    last_measurement: (f64, f64),
    /// Ticks at the end of a gain phase whose estimates are averaged.
    gain_window_ticks: u64,
    /// Stage 2's gain pseudo-measurement, fixed when stage 2 starts.
    stage2_gains: [f64; 3],
    /// Stage 2's measurement covariance with the integration phase's
    /// target-view noise added, set when that phase starts.
    stage2_R_noisy: nalgebra::SMatrix<f64, 5, 5>,
}

fn check_finite_positive(v: f64, name: &'static str) -> Result<(), ScenarioError> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(ScenarioError::InvalidSetting(name))
    }
}

impl<'a> Robot<'a> {
    /// Set-up: validates the settings against the protocol and builds all
    /// estimators.
    pub fn new(cfg: RobotConfig, protocol: Protocol<'a>) -> Result<Self, ScenarioError> {
        if cfg.gains.iter().any(|g| !g.is_finite()) {
            return Err(ScenarioError::InvalidSetting("robot.gains"));
        }
        check_finite_positive(cfg.gain_window_s, "robot.gain_window_s")?;
        if cfg.torque_limit.is_nan() || cfg.torque_limit <= 0.0 {
            return Err(ScenarioError::InvalidSetting("robot.torque_limit"));
        }
        if let Some(g) = cfg.prior_partner_gains {
            if g.iter().any(|v| !v.is_finite()) {
                return Err(ScenarioError::InvalidSetting("robot.prior_partner_gains"));
            }
        }
        if (cfg.model.dt_s - protocol.dt_s()).abs() > 1e-12 * protocol.dt_s() {
            return Err(ScenarioError::InvalidSetting("robot.model.dt_s"));
        }
        let mut gains_known = cfg.prior_partner_gains.is_some();
        for (i, p) in protocol.phases().iter().enumerate() {
            match p.kind {
                PhaseKind::Gains => gains_known = true,
                _ if !gains_known => return Err(ScenarioError::NoPartnerGains { phase: i }),
                _ => {}
            }
        }
        let est = |stage| move |error| ScenarioError::Estimator { stage, error };
        Ok(Robot {
            stage1: GainEstimator::new(cfg.model, &cfg.stage1).map_err(est("stage1"))?,
            stage2: TrajectoryEstimator::new(cfg.model, &cfg.stage2).map_err(est("stage2"))?,
            stage3: GoalIntegrator::new(cfg.model, &cfg.stage3).map_err(est("stage3"))?,
            cfg,
            protocol,
            gain_sum: [0.0; 3],
            gain_count: 0,
            stage2_live: false,
            integration_phase: None,
            noise: Noise::new(cfg.seed),
            counters: RobotCounters::default(),
            last_measurement: (0.0, 0.0),
            gain_window_ticks: (cfg.gain_window_s / protocol.dt_s()) as u64,
            stage2_gains: [0.0; 3],
            stage2_R_noisy: cfg.stage2.R,
        })
    }

    /// The protocol this robot follows.
    pub fn protocol(&self) -> &Protocol<'a> {
        &self.protocol
    }

    /// Counters so far.
    pub fn counters(&self) -> RobotCounters {
        self.counters
    }

    /// The gains stage 2 is given as pseudo-measurements: the stage-1 mean
    /// over the gain window, else the current stage-1 estimate, else the prior.
    pub fn pseudo_gains(&self) -> [f64; 3] {
        if self.gain_count > 0 {
            let n = self.gain_count as f64;
            [
                self.gain_sum[0] / n,
                self.gain_sum[1] / n,
                self.gain_sum[2] / n,
            ]
        } else if let Some(g) = self.cfg.prior_partner_gains {
            g
        } else {
            self.stage1.gains()
        }
    }

    fn note(&mut self, r: Result<Status, UkfError>) {
        match r {
            Ok(Status::Nominal) => {}
            Ok(Status::Resymmetrised { .. }) => self.counters.resymmetrised += 1,
            Err(_) => self.counters.estimator_errors += 1,
        }
    }

    /// Starts stage 2 from the stage-1 posterior with the pseudo-gains.
    fn start_stage2(&mut self) {
        let mut x0 = *self.stage1.filter().x();
        let g = self.pseudo_gains();
        self.stage2_gains = g;
        x0.fixed_rows_mut::<3>(GAINS).copy_from_slice(&g);
        if self.stage2.reset(x0, self.cfg.stage2.P0).is_err() {
            self.counters.estimator_errors += 1;
        }
        self.stage2_live = true;
    }

    /// One control period: fuse the measurement `(x, v)` of tick `k`,
    /// compute the command, then propagate the estimators with it. After
    /// the protocol's end the command is 0.
    pub fn tick(&mut self, k: u64, x: f64, v: f64) -> RobotTick {
        self.tick_with(k, Some((x, v)))
    }

    /// [`Robot::tick_at`] for tick `k` (samples the protocol itself).
    pub fn tick_with(&mut self, k: u64, measurement: Option<(f64, f64)>) -> RobotTick {
        match self.protocol.sample(k) {
            Some(sample) => self.tick_at(&sample, measurement),
            None => RobotTick::NONE,
        }
    }

    /// One control period with a possibly missing measurement (a feedback
    /// frame that did not arrive in time, or a non-finite one). Without a
    /// fresh measurement the estimators skip their update and only predict,
    /// and the command uses the last measurement received: a stale sample
    /// fed to the filters as if new would corrupt them.
    pub fn tick_at(&mut self, sample: &Sample<'_>, measurement: Option<(f64, f64)>) -> RobotTick {
        let fresh = measurement.filter(|(x, v)| x.is_finite() && v.is_finite());
        if let Some(m) = fresh {
            self.last_measurement = m;
        } else {
            self.counters.missing_measurements += 1;
        }
        let (x, v) = self.last_measurement;
        let fresh = fresh.is_some();
        let &Sample {
            k,
            index: phase_index,
            phase,
            end,
            tau,
            tau_h,
            dtau,
            dtau_h,
        } = sample;
        let L = self.cfg.gains;
        let mut out = RobotTick {
            phase: phase.kind.code(),
            e_meas: x - tau,
            ..RobotTick::NONE
        };
        let u_raw = match phase.kind {
            PhaseKind::Gains => {
                if fresh {
                    let r = self.stage1.update(&Vector3::new(x - tau, v, x - tau_h));
                    self.note(r);
                }
                let g = self.stage1.gains();
                if k + self.gain_window_ticks >= end {
                    for (s, gi) in self.gain_sum.iter_mut().zip(g) {
                        *s += gi;
                    }
                    self.gain_count += 1;
                }
                out.gains = g;
                out.gains_var = diag3(self.stage1.filter().P(), GAINS);
                let u = feedback_torque(&L, &xi(x, v, tau, tau_h));
                let u = self.guard(u);
                let r = self.stage1.predict(u, dtau, dtau_h);
                self.note(r);
                u
            }
            PhaseKind::Trajectory => {
                if !self.stage2_live {
                    self.start_stage2();
                }
                let g = self.stage2_gains;
                let y = SVector::<f64, 5>::new(x - tau, v, g[0], g[1], g[2]);
                if fresh {
                    let r = self.stage2.update(&y);
                    self.note(r);
                }
                self.record_stage2(&mut out, x);
                let u = feedback_torque(&L, &xi(x, v, tau, tau_h));
                let u = self.guard(u);
                let r = self.stage2.predict(u, dtau, 0.0);
                self.note(r);
                u
            }
            PhaseKind::Integration => {
                if !self.stage2_live {
                    self.start_stage2();
                }
                let std = phase.target_noise_std;
                let e_meas = x - (tau + self.noise.normal(std));
                out.e_meas = e_meas;
                if self.integration_phase != Some(phase_index) {
                    self.start_integration(phase_index, std, Vector2::new(e_meas, v));
                }
                let g = self.stage2_gains;
                let y = SVector::<f64, 5>::new(e_meas, v, g[0], g[1], g[2]);
                if fresh {
                    let r = self.stage2.update_with_r(&y, &self.stage2_R_noisy);
                    self.note(r);
                }
                self.record_stage2(&mut out, x);
                let channel = self.stage2.filter().x()[E_H];
                let floor = self.stage2.partner_error_variance();
                if fresh {
                    let r = self
                        .stage3
                        .update(&Vector2::new(e_meas, v), Some((channel, floor)));
                    self.note(r);
                }
                out.e_hat_own = self.stage3.estimate(false)[0];
                out.e_hat_fused = self.stage3.estimate(true)[0];
                out.e_hat_own_var = self.stage3.own_filter().P()[(0, 0)];
                out.e_hat_fused_var = self.stage3.fused_filter().P()[(0, 0)];
                out.partner_var = self.stage3.partner_variance();
                let e_hat = self.stage3.estimate(self.cfg.integrate)[0];
                let u = feedback_torque(&L, &[e_hat, v, 0.0]);
                let u = self.guard(u);
                let u_h_hat = self.stage2.partner_torque();
                // The target is unknown to the robot here: its increments are 0.
                let r = self.stage2.predict(u, 0.0, 0.0);
                self.note(r);
                let r = self.stage3.predict(u + u_h_hat, 0.0);
                self.note(r);
                u
            }
        };
        out.u = u_raw;
        out
    }

    /// Start of an integration phase: the phase's target-view noise enters
    /// stage 2's and stage 3's measurement covariances (computed here, once),
    /// and stage 3 restarts from the current measurement.
    fn start_integration(&mut self, phase_index: usize, std: f64, y: Vector2<f64>) {
        self.stage2_R_noisy = self.cfg.stage2.R;
        self.stage2_R_noisy[(0, 0)] += std * std;
        let mut R_own = self.cfg.stage3.R_own;
        R_own[(0, 0)] += std * std;
        let r = self
            .stage3
            .set_own_noise(R_own)
            .and_then(|()| self.stage3.reset(y));
        self.note(r.map(|()| Status::Nominal));
        self.integration_phase = Some(phase_index);
    }

    fn record_stage2(&self, out: &mut RobotTick, x: f64) {
        let f = self.stage2.filter();
        out.gains = [f.x()[GAINS], f.x()[GAINS + 1], f.x()[GAINS + 2]];
        out.gains_var = diag3(f.P(), GAINS);
        out.tau_h_hat = self.stage2.partner_target(x);
        out.tau_h_var = self.stage2.partner_error_variance();
    }

    fn guard(&mut self, u: f64) -> f64 {
        let (u, g) = guard_torque(u, self.cfg.torque_limit);
        match g {
            Guard::Passed => {}
            Guard::Clamped => self.counters.clamped += 1,
            Guard::NonFinite => self.counters.non_finite += 1,
        }
        u
    }
}

fn diag3(P: &nalgebra::SMatrix<f64, 6, 6>, from: usize) -> [f64; 3] {
    [
        P[(from, from)],
        P[(from + 1, from + 1)],
        P[(from + 2, from + 2)],
    ]
}

/// The partner agent of a simulated trial (the virtual human).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PartnerConfig {
    /// Its gains over `xi` (e.g. `[0, 0, Lhh]` for the Hi5 virtual human,
    /// `agent::partner_gains` for an LQR partner).
    pub gains: [f64; 3],
    /// Torque limit, > 0.
    pub torque_limit: f64,
    /// Whether the partner also identifies the robot (the simulation
    /// section): a mirrored stage-1 and stage-2 estimator with the robot's
    /// filter settings.
    pub estimates_robot: bool,
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

/// One tick of a simulated trial: the world's side, the robot's log line
/// and the partner's estimates of the robot. [`TickRecord::to_row`] flattens
/// it into `f64` columns named by [`FIELDS`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TickRecord {
    /// Time (s).
    pub t: f64,
    /// True position.
    pub x: f64,
    /// True velocity.
    pub v: f64,
    /// Robot target.
    pub tau: f64,
    /// Partner target.
    pub tau_h: f64,
    /// Partner torque.
    pub u_h: f64,
    /// Motor noise.
    pub eps: f64,
    /// True `x - tau`.
    pub e: f64,
    /// What the robot did (command, estimates, variances).
    pub robot: RobotTick,
    /// The partner's mirrored estimates of the robot.
    pub mirror: PartnerEstimate,
}

impl Default for TickRecord {
    fn default() -> Self {
        TickRecord {
            t: 0.0,
            x: 0.0,
            v: 0.0,
            tau: 0.0,
            tau_h: 0.0,
            u_h: 0.0,
            eps: 0.0,
            e: 0.0,
            robot: RobotTick::NONE,
            mirror: PartnerEstimate::NONE,
        }
    }
}

/// Column names of a [`TickRecord`] seen as a row of `f64`.
pub const FIELDS: [&str; 32] = [
    "t",
    "phase",
    "x",
    "xdot",
    "tau",
    "tau_h",
    "u",
    "u_h",
    "eps",
    "e",
    "e_meas",
    "Lhx_hat",
    "Lhv_hat",
    "Lhh_hat",
    "Lhx_var",
    "Lhv_var",
    "Lhh_var",
    "tau_h_hat",
    "tau_h_var",
    "e_hat_own",
    "e_hat_fused",
    "e_hat_own_var",
    "e_hat_fused_var",
    "partner_var",
    "Lx_hat",
    "Lv_hat",
    "Lh_hat",
    "Lx_var",
    "Lv_var",
    "Lh_var",
    "tau_hat",
    "tau_hat_var",
];

impl TickRecord {
    /// The record as a row in [`FIELDS`] order.
    pub fn to_row(&self) -> [f64; FIELDS.len()] {
        let (r, m) = (&self.robot, &self.mirror);
        [
            self.t,
            r.phase,
            self.x,
            self.v,
            self.tau,
            self.tau_h,
            r.u,
            self.u_h,
            self.eps,
            self.e,
            r.e_meas,
            r.gains[0],
            r.gains[1],
            r.gains[2],
            r.gains_var[0],
            r.gains_var[1],
            r.gains_var[2],
            r.tau_h_hat,
            r.tau_h_var,
            r.e_hat_own,
            r.e_hat_fused,
            r.e_hat_own_var,
            r.e_hat_fused_var,
            r.partner_var,
            m.gains[0],
            m.gains[1],
            m.gains[2],
            m.gains_var[0],
            m.gains_var[1],
            m.gains_var[2],
            m.target,
            m.target_var,
        ]
    }
}

/// The partner's mirrored estimators (simulation section): the same code as
/// the robot's, on `[x - tau_h, xdot, x - tau]` with the partner's own torque.
#[derive(Clone, Debug)]
struct Mirror {
    stage1: GainEstimator,
    stage2: TrajectoryEstimator,
    stage2_live: bool,
    P0: nalgebra::SMatrix<f64, 6, 6>,
    gain_sum: [f64; 3],
    gain_count: u64,
    errors: u64,
}

impl Mirror {
    fn note(&mut self, r: Result<Status, UkfError>) {
        if r.is_err() {
            self.errors += 1;
        }
    }

    /// One tick; returns the robot gains (robot's `xi` order) and target as
    /// the partner estimates them, with variances (NaN where the phase has
    /// no estimate).
    fn tick(
        &mut self,
        sample: &Sample<'_>,
        in_window: bool,
        (x, v): (f64, f64),
        u_h: f64,
    ) -> PartnerEstimate {
        let &Sample {
            tau,
            tau_h,
            dtau,
            dtau_h,
            ..
        } = sample;
        match sample.phase.kind {
            PhaseKind::Gains => {
                let r = self.stage1.update(&Vector3::new(x - tau_h, v, x - tau));
                self.note(r);
                let g = self.stage1.gains();
                if in_window {
                    for (s, gi) in self.gain_sum.iter_mut().zip(g) {
                        *s += gi;
                    }
                    self.gain_count += 1;
                }
                let out = PartnerEstimate {
                    gains: mirrored(g),
                    gains_var: mirrored(diag3(self.stage1.filter().P(), GAINS)),
                    ..PartnerEstimate::NONE
                };
                let r = self.stage1.predict(u_h, dtau_h, dtau);
                self.note(r);
                out
            }
            PhaseKind::Trajectory => {
                let n = self.gain_count.max(1) as f64;
                let g = if self.gain_count > 0 {
                    [
                        self.gain_sum[0] / n,
                        self.gain_sum[1] / n,
                        self.gain_sum[2] / n,
                    ]
                } else {
                    self.stage1.gains()
                };
                if !self.stage2_live {
                    let mut x0 = *self.stage1.filter().x();
                    x0.fixed_rows_mut::<3>(GAINS).copy_from_slice(&g);
                    let r = self.stage2.reset(x0, self.P0);
                    self.note(r.map(|()| Status::Nominal));
                    self.stage2_live = true;
                }
                let r = self
                    .stage2
                    .update(&SVector::<f64, 5>::new(x - tau_h, v, g[0], g[1], g[2]));
                self.note(r);
                let (z, P) = (self.stage2.filter().x(), self.stage2.filter().P());
                let out = PartnerEstimate {
                    gains: mirrored([z[GAINS], z[GAINS + 1], z[GAINS + 2]]),
                    gains_var: mirrored(diag3(P, GAINS)),
                    target: x - z[E_H],
                    target_var: P[(E_H, E_H)],
                };
                let r = self.stage2.predict(u_h, dtau_h, 0.0);
                self.note(r);
                out
            }
            PhaseKind::Integration => PartnerEstimate::NONE,
        }
    }
}

/// What the partner's mirrored estimators say about the robot in one tick.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PartnerEstimate {
    /// The robot's gains, in the robot's `xi` order.
    pub gains: [f64; 3],
    /// Their posterior variances.
    pub gains_var: [f64; 3],
    /// The robot's target.
    pub target: f64,
    /// Posterior variance of the partner's `(x - tau)^`.
    pub target_var: f64,
}

impl PartnerEstimate {
    /// No estimate (NaN).
    pub const NONE: PartnerEstimate = PartnerEstimate {
        gains: [f64::NAN; 3],
        gains_var: [f64::NAN; 3],
        target: f64::NAN,
        target_var: f64::NAN,
    };
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

/// A simulated trial: robot, partner, plant and noise.
#[derive(Clone, Debug)]
pub struct Scenario<'a> {
    robot: Robot<'a>,
    partner: PartnerConfig,
    mirror: Option<Mirror>,
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
        if partner.gains.iter().any(|g| !g.is_finite()) {
            return Err(ScenarioError::InvalidSetting("partner.gains"));
        }
        if partner.torque_limit.is_nan() || partner.torque_limit <= 0.0 {
            return Err(ScenarioError::InvalidSetting("partner.torque_limit"));
        }
        let robot = Robot::new(robot, protocol)?;
        let mirror = if partner.estimates_robot {
            let est = |stage| move |error| ScenarioError::Estimator { stage, error };
            Some(Mirror {
                stage1: GainEstimator::new(robot.cfg.model, &robot.cfg.stage1)
                    .map_err(est("stage1"))?,
                stage2: TrajectoryEstimator::new(robot.cfg.model, &robot.cfg.stage2)
                    .map_err(est("stage2"))?,
                stage2_live: false,
                P0: robot.cfg.stage2.P0,
                gain_sum: [0.0; 3],
                gain_count: 0,
                errors: 0,
            })
        } else {
            None
        };
        Ok(Scenario {
            robot,
            partner,
            mirror,
            world,
            plant,
            noise: Noise::new(world.seed),
        })
    }

    /// Ticks in the trial.
    pub fn ticks(&self) -> usize {
        self.robot.protocol.total_ticks() as usize
    }

    /// Runs the whole trial, one record per tick into `out`.
    pub fn run(&mut self, out: &mut [TickRecord]) -> Result<RunSummary, ScenarioError> {
        let n = self.ticks();
        let Some(out) = out.get_mut(..n) else {
            return Err(ScenarioError::OutputTooShort {
                needed: n,
                got: out.len(),
            });
        };
        let mut summary = RunSummary {
            ticks: n,
            ..RunSummary::default()
        };
        for (k, rec) in out.iter_mut().enumerate() {
            *rec = self.tick(k as u64, &mut summary);
        }
        summary.robot = self.robot.counters();
        summary.mirror_errors = self.mirror.as_ref().map_or(0, |m| m.errors);
        Ok(summary)
    }

    /// One tick of the world: sense, robot, partner, plant.
    fn tick(&mut self, k: u64, summary: &mut RunSummary) -> TickRecord {
        let s = self.plant.state();
        let x_meas = s.x + self.noise.normal(self.world.position_noise_std);
        let v_meas = s.v + self.noise.normal(self.world.velocity_noise_std);
        let Some(sample) = self.robot.protocol.sample(k) else {
            return TickRecord::default();
        };
        let robot = self.robot.tick_at(&sample, Some((x_meas, v_meas)));

        let (u_h, g) = guard_torque(
            feedback_torque(
                &self.partner.gains,
                &xi(x_meas, v_meas, sample.tau, sample.tau_h),
            ),
            self.partner.torque_limit,
        );
        if g != Guard::Passed {
            summary.partner_guarded += 1;
        }
        let in_window = k + self.robot.gain_window_ticks >= sample.end;
        let mirror = match self.mirror.as_mut() {
            Some(m) => m.tick(&sample, in_window, (x_meas, v_meas), u_h),
            None => PartnerEstimate::NONE,
        };

        let eps = self.noise.normal(self.world.motor_noise_std);
        // Every term is finite (guarded), so the step cannot fail.
        let _ = self.plant.step(robot.u + u_h + eps);
        TickRecord {
            t: k as f64 * self.robot.protocol.dt_s(),
            x: s.x,
            v: s.v,
            tau: sample.tau,
            tau_h: sample.tau_h,
            u_h,
            eps,
            e: s.x - sample.tau,
            robot,
            mirror,
        }
    }
}
