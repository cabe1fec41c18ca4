//! The robot's controller, the piece the real-time loop runs: one
//! [`Robot::tick_at`] per sample updates the estimators with the
//! measurement, computes the guarded command, then predicts with it. A
//! caller whose actuator changes the command (a drive's torque step) splits
//! the tick: [`Robot::decide`], then [`Robot::predict`] with the torque the
//! actuator applies for the robot.
//!
//! The partner identification (stages 1 and 2) is an [`Identifier`]; the
//! goal integration (stage 3) and the control law are here. Everything is
//! built and validated at set-up; a tick allocates nothing, and estimator
//! trouble is counted, never a panic.

use crate::agent::{feedback_torque, guard_torque, xi, Guard};
use crate::delay::DelayEvidence;
use crate::estimator::{ExtendedFilterConfig, HandleModel, E_H};
use crate::goal::{GoalIntegrator, GoalIntegratorConfig};
use crate::identifier::{FilterTally, Identifier, PartnerDelay};
use crate::protocol::{PhaseKind, Protocol, Sample};
use crate::rng::Noise;
use crate::row::{ColumnSource, Row};
use crate::ukf::Status;
use crate::ScenarioError;
use nalgebra::{SMatrix, Vector2, Vector3};

/// Settings of the robot's controller.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RobotConfig {
    /// Feedback gains over `xi = [x - tau, xdot, x - tau_h]` (an LQR robot's
    /// are `[k_pos, k_vel, 0]`, `docs/model.md`).
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
    /// (the own-only member always runs beside it, for the comparison).
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
    /// The partner model of stages 1 and 2 (`robot.partner_delay`): the
    /// paper's, known delays, or delays identified online.
    pub partner_delay: PartnerDelay,
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

impl RobotCounters {
    /// Each counter by the name a run's summary gives it.
    pub fn named(&self) -> [(&'static str, u64); 5] {
        [
            ("robot_clamped", self.clamped),
            ("robot_non_finite", self.non_finite),
            ("estimator_errors", self.estimator_errors),
            ("resymmetrised", self.resymmetrised),
            ("missing_measurements", self.missing_measurements),
        ]
    }
}

/// The robot's controller: estimators and control law.
#[derive(Clone, Debug)]
pub struct Robot<'a> {
    cfg: RobotConfig,
    protocol: Protocol<'a>,
    /// Stages 1 and 2.
    identifier: Identifier,
    /// Stage 3.
    stage3: GoalIntegrator,
    /// The integration phase stage 3 was last started for.
    integration_phase: Option<usize>,
    noise: Noise,
    /// Guard and measurement counters (the estimator counts are the
    /// identifier's tally plus `stage3_tally`).
    counters: RobotCounters,
    stage3_tally: FilterTally,
    last_measurement: (f64, f64),
    /// Stage 2's measurement covariance with the integration phase's
    /// target-view noise added, set when that phase starts.
    stage2_R_noisy: SMatrix<f64, 5, 5>,
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
        let identifier = cfg.identifier(protocol.dt_s(), cfg.prior_partner_gains)?;
        Ok(Robot {
            identifier,
            stage3: GoalIntegrator::new(cfg.model, &cfg.stage3).map_err(|error| {
                ScenarioError::Estimator {
                    stage: "stage3",
                    error,
                }
            })?,
            cfg,
            protocol,
            integration_phase: None,
            noise: Noise::new(cfg.seed),
            counters: RobotCounters::default(),
            stage3_tally: FilterTally::default(),
            last_measurement: (0.0, 0.0),
            stage2_R_noisy: cfg.stage2.R,
        })
    }

    /// The protocol this robot follows.
    pub fn protocol(&self) -> &Protocol<'a> {
        &self.protocol
    }

    /// Counters so far.
    pub fn counters(&self) -> RobotCounters {
        let (a, b) = (self.identifier.tally(), self.stage3_tally);
        RobotCounters {
            estimator_errors: a.errors + b.errors,
            resymmetrised: a.resymmetrised + b.resymmetrised,
            ..self.counters
        }
    }

    /// The gains stage 2 is given as pseudo-measurements
    /// ([`Identifier::pseudo_gains`]).
    pub fn pseudo_gains(&self) -> [f64; 3] {
        self.identifier.pseudo_gains()
    }

    /// The partner-delay search's evidence (`robot.partner_delay = "auto"`;
    /// `None` otherwise or before its first choice).
    pub fn delay_evidence(&self) -> Option<DelayEvidence> {
        self.identifier.delay_evidence()
    }

    /// One control period: fuse the measurement `(x, v)` of tick `k`,
    /// compute the command, then propagate the estimators with it; the
    /// controller's columns of `row` written. After the protocol's end the
    /// command is 0.
    pub fn tick(&mut self, k: u64, x: f64, v: f64, row: &mut Row) {
        self.tick_with(k, Some((x, v)), row)
    }

    /// [`Robot::tick_at`] for tick `k` (samples the protocol itself); after
    /// the protocol's end every controller column is unknown but `u`, 0.
    pub fn tick_with(&mut self, k: u64, measurement: Option<(f64, f64)>, row: &mut Row) {
        self.tick_applied(k, measurement, None, row)
    }

    /// [`Robot::tick_with`], the estimators predicting with `applied` (the
    /// torque a recorded run applied for the robot, the log's `u`) instead
    /// of the command when given and finite; `row.u` is the torque
    /// predicted with.
    pub fn tick_applied(
        &mut self,
        k: u64,
        measurement: Option<(f64, f64)>,
        applied: Option<f64>,
        row: &mut Row,
    ) {
        match self.protocol.sample(k) {
            Some(sample) => {
                let decision = self.decide(&sample, measurement, row);
                let u = applied.filter(|a| a.is_finite()).unwrap_or(decision.u);
                self.predict(decision, u);
                row.u = u;
            }
            None => {
                row.clear(ColumnSource::Controller);
                row.u = 0.0;
            }
        }
    }

    /// One control period with a possibly missing measurement (a feedback
    /// frame that did not arrive in time, or a non-finite one). Without a
    /// fresh measurement the estimators skip their update and only predict,
    /// and the command uses the last measurement received: a stale sample
    /// fed to the filters as if new would corrupt them. Writes every
    /// controller column of `row` (the guarded command in `row.u`, the
    /// estimates, unknown where the phase has none) and nothing else.
    pub fn tick_at(&mut self, sample: &Sample<'_>, measurement: Option<(f64, f64)>, row: &mut Row) {
        let decision = self.decide(sample, measurement, row);
        self.predict(decision, decision.u);
    }

    /// The first half of [`Robot::tick_at`]: the estimators' update with the
    /// measurement and the guarded command (in `row.u` and the returned
    /// [`Decision`]), every controller column of `row` written. The tick is
    /// complete after [`Robot::predict`].
    pub fn decide(
        &mut self,
        sample: &Sample<'_>,
        measurement: Option<(f64, f64)>,
        row: &mut Row,
    ) -> Decision {
        let fresh = measurement.filter(|(x, v)| x.is_finite() && v.is_finite());
        if let Some(m) = fresh {
            self.last_measurement = m;
        } else {
            self.counters.missing_measurements += 1;
        }
        let (x, v) = self.last_measurement;
        let fresh = fresh.is_some();
        row.clear(ColumnSource::Controller);
        row.phase = Some(sample.phase.kind);
        row.e_meas = x - sample.tau;
        let decision = match sample.phase.kind {
            PhaseKind::Gains | PhaseKind::Trajectory => {
                self.identification_tick(sample, fresh, (x, v), row)
            }
            PhaseKind::Integration => self.integration_tick(sample, fresh, (x, v), row),
        };
        row.u = decision.u;
        decision
    }

    /// The second half of [`Robot::tick_at`]: every estimator propagates
    /// with `applied`, the robot's torque as the handle receives it (model
    /// units): `decision.u` in simulation; on a rig, the command plus the
    /// drive's rounding of the torque sent (`docs/cia402.md`, "The Lhh
    /// difference between the profiles").
    pub fn predict(&mut self, decision: Decision, applied: f64) {
        let Decision {
            kind, dtau, dtau_h, ..
        } = decision;
        // Stage 3's partner torque is stage 2's estimate before it predicts.
        let u_h_hat =
            (kind == PhaseKind::Integration).then(|| self.identifier.trajectory().partner_torque());
        self.identifier.predict(kind, applied, dtau, dtau_h);
        if let Some(u_h_hat) = u_h_hat {
            let r = self.stage3.predict_finite(applied + u_h_hat, 0.0);
            self.stage3_tally.note(r);
        }
    }

    /// Stages 1 and 2: update the identifier, the command on the true
    /// targets; the prediction reads the targets' increments.
    fn identification_tick(
        &mut self,
        s: &Sample<'_>,
        fresh: bool,
        (x, v): (f64, f64),
        out: &mut Row,
    ) -> Decision {
        let y = fresh.then(|| Vector3::new(x - s.tau, v, x - s.tau_h));
        out.set_partner_estimate(&self.identifier.update(s, y, x, None));
        Decision {
            u: self.guard(feedback_torque(&self.cfg.gains, &xi(x, v, s.tau, s.tau_h))),
            kind: s.phase.kind,
            dtau: s.dtau,
            dtau_h: s.dtau_h,
        }
    }

    /// Stage 3: the robot sees its target through noise; stage 2 keeps
    /// running (its `x - tau_h^` is the partner channel), both stage-3
    /// filters update, the command uses the own or the integrated estimate;
    /// everything predicts with the target motion unknown (0).
    fn integration_tick(
        &mut self,
        s: &Sample<'_>,
        fresh: bool,
        (x, v): (f64, f64),
        out: &mut Row,
    ) -> Decision {
        let std = s.phase.target_noise_std;
        let e_meas = x - (s.tau + self.noise.normal(std));
        out.e_meas = e_meas;
        if self.integration_phase != Some(s.index) {
            self.start_integration(s.index, std, Vector2::new(e_meas, v));
        }
        // The partner's target is unknown here (stage 2 does not read it).
        let y = fresh.then(|| Vector3::new(e_meas, v, f64::NAN));
        let R = self.stage2_R_noisy;
        out.set_partner_estimate(&self.identifier.update(s, y, x, Some(&R)));
        let stage2 = self.identifier.trajectory();
        let channel = stage2.filter().x()[E_H];
        if fresh {
            let r = self.stage3.update(&Vector2::new(e_meas, v), Some(channel));
            self.stage3_tally.note(r);
        }
        out.e_hat_own = self.stage3.estimate(false)[0];
        out.e_hat_fused = self.stage3.estimate(true)[0];
        out.e_hat_own_var = self.stage3.variance(false)[0];
        out.e_hat_fused_var = self.stage3.variance(true)[0];
        out.partner_var = self.stage3.partner_variance();
        let e_hat = self.stage3.estimate(self.cfg.integrate)[0];
        // The target is unknown to the robot here: its increments are 0.
        Decision {
            u: self.guard(feedback_torque(&self.cfg.gains, &[e_hat, v, 0.0])),
            kind: s.phase.kind,
            dtau: 0.0,
            dtau_h: 0.0,
        }
    }

    /// Start of an integration phase: the phase's target-view noise enters
    /// stage 2's and stage 3's measurement covariances (computed here, once),
    /// and stage 3 restarts from the current measurement.
    fn start_integration(&mut self, phase_index: usize, std: f64, y: Vector2<f64>) {
        self.stage2_R_noisy = self.cfg.stage2.R;
        self.stage2_R_noisy[(0, 0)] += std * std;
        let mut R_own = self.cfg.stage3.R_own;
        R_own[(0, 0)] += std * std;
        // R_own was checked at set-up and the phase only adds a finite
        // variance, so neither call fails in practice; a failure is counted.
        let noise = self.stage3.set_own_noise(R_own);
        let reset = self.stage3.reset(y);
        if noise.is_err() {
            self.stage3_tally.errors += 1;
        }
        self.stage3_tally.note(reset.map(|()| Status::Nominal));
        self.integration_phase = Some(phase_index);
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

/// What [`Robot::decide`] leaves for [`Robot::predict`]: the tick's guarded
/// command and the inputs the estimators' prediction reads besides the
/// torque.
#[must_use = "the tick is complete after Robot::predict"]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Decision {
    /// The robot's command after its torque guard (model units).
    pub u: f64,
    kind: PhaseKind,
    /// The targets' increments the prediction takes (0 where the robot
    /// does not know its target: integration phases).
    dtau: f64,
    dtau_h: f64,
}

/// The torque a drive applies for command `u` (already within `limit`):
/// `round_ties_even(u / step) * step` (CiA 402's per-mille and the Hi5 DBC's
/// raw value both round so), one step towards zero if that passes `limit`.
/// A step that is not finite and positive leaves `u` as it is.
pub fn applied_torque(u: f64, step: f64, limit: f64) -> f64 {
    if !(step.is_finite() && step > 0.0) {
        return u;
    }
    // rint: round half to even (the default rounding mode), no_std.
    let steps = libm::rint(u / step);
    let applied = steps * step;
    if applied.abs() > limit {
        (steps - steps.signum()) * step
    } else {
        applied
    }
}

impl RobotConfig {
    /// Set-up: an [`Identifier`] with these filter settings, model and gain
    /// window at loop period `dt_s` (the robot's own, and the mirrored
    /// partner's of the simulation section).
    pub fn identifier(
        &self,
        dt_s: f64,
        prior_gains: Option<[f64; 3]>,
    ) -> Result<Identifier, ScenarioError> {
        Identifier::new(
            self.model,
            &self.stage1,
            &self.stage2,
            self.gain_window_s,
            dt_s,
            prior_gains,
        )?
        .with_delay(self.partner_delay)
    }
}
