//! One agent's identification of its partner (sections "Estimation of
//! human's control gain" and "Estimation of the partner's desired
//! trajectory"): stage 1 estimates the partner's gains, the gain window
//! averages them, and the hand-off starts stage 2 on the partner's target.
//!
//! The robot runs one [`Identifier`] on `[x - tau, xdot, x - tau_h]`; the
//! mirrored partner of the simulation section runs another on
//! `[x - tau_h, xdot, x - tau]` with its own torque. Written from the side of
//! the agent running it: "own" is that agent, "partner" the one identified.
//!
//! Per tick the owner calls [`Identifier::update`] with its measurement,
//! computes its command, then [`Identifier::predict`] with it; the phase
//! picks the stage. Built at set-up; a tick allocates
//! nothing, and filter trouble is counted ([`FilterTally`]), never a panic.

use crate::agent::{delay_ticks, mirrored, History};
use crate::delay::{DelayEvidence, DelaySearch, SearchSchedule};
use crate::estimator::{
    Cov6, ExtendedFilterConfig, GainEstimator, HandleModel, Step, TrajectoryEstimator, E_H, GAINS,
};
use crate::protocol::{PhaseKind, Sample};
use crate::ukf::{Status, UkfError};
use crate::ScenarioError;
use nalgebra::{SMatrix, SVector, Vector3};

/// Counts of what the filters reported in their calls.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FilterTally {
    /// Calls that returned an error (each already handled by the filter:
    /// state restored or covariance reset).
    pub errors: u64,
    /// Calls that needed a re-symmetrised covariance.
    pub resymmetrised: u64,
}

impl FilterTally {
    /// Counts one filter call's outcome.
    pub fn note(&mut self, r: Result<Status, UkfError>) {
        match r {
            Ok(Status::Nominal) => {}
            Ok(Status::Resymmetrised { .. }) => self.resymmetrised += 1,
            Err(_) => self.errors += 1,
        }
    }
}

/// What an identifier says about the partner after a tick's update.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PartnerEstimate {
    /// The partner's gains (the owner's `xi` order, unless [`mirrored`](PartnerEstimate::mirrored)).
    pub gains: [f64; 3],
    /// Their posterior variances.
    pub gains_var: [f64; 3],
    /// The partner's target `x - (x - target)^` (stage 2), NaN in stage 1.
    pub target: f64,
    /// Posterior variance of `(x - target)^`, NaN in stage 1.
    pub target_var: f64,
    /// The partner delays `[visual, proprioceptive]` (ms) the filters assume
    /// this tick: NaN with the paper's model or before the search's first
    /// choice; the proprioceptive one NaN while the search cannot tell it.
    pub delay_ms: [f64; 2],
    /// The search's margin (nats) of the chosen visual delay over the best
    /// other one (NaN without a search choice).
    pub delay_margin_nats: f64,
}

impl PartnerEstimate {
    /// No estimate (NaN).
    pub const NONE: PartnerEstimate = PartnerEstimate {
        gains: [f64::NAN; 3],
        gains_var: [f64::NAN; 3],
        target: f64::NAN,
        target_var: f64::NAN,
        delay_ms: [f64::NAN; 2],
        delay_margin_nats: f64::NAN,
    };

    /// The gains (and their variances) in the other agent's `xi` order
    /// ([`mirrored`]): how the mirrored partner reports the robot's gains.
    pub fn mirrored(self) -> PartnerEstimate {
        PartnerEstimate {
            gains: mirrored(self.gains),
            gains_var: mirrored(self.gains_var),
            ..self
        }
    }
}

/// The stage-1 estimates at the end of a gain phase, summed for their mean
/// (stage 2's gain pseudo-measurement, `docs/model.md`).
#[derive(Clone, Copy, Debug, PartialEq)]
struct GainWindow {
    /// Ticks at the end of a gain phase whose estimates are averaged.
    ticks: u64,
    sum: [f64; 3],
    count: u64,
}

impl GainWindow {
    /// Whether tick `k` of a phase ending before tick `end` is in the window:
    /// `k + ticks >= end`.
    fn contains(&self, k: u64, end: u64) -> bool {
        k + self.ticks >= end
    }

    fn add(&mut self, gains: [f64; 3]) {
        for (s, g) in self.sum.iter_mut().zip(gains) {
            *s += g;
        }
        self.count += 1;
    }

    /// `sum / count`, `None` before the first estimate.
    fn mean(&self) -> Option<[f64; 3]> {
        let n = self.count as f64;
        (self.count > 0).then(|| [self.sum[0] / n, self.sum[1] / n, self.sum[2] / n])
    }
}

/// Which partner model stages 1 and 2 assume (`robot.partner_delay`).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum PartnerDelay {
    /// The paper's: the partner acts on the current state (bit-identical to
    /// the model without delays).
    #[default]
    Paper,
    /// The partner acts on the robot's measured sample of these delays ago
    /// (ms: visual on the target terms, proprioceptive on the velocity).
    Known {
        /// Visual delay (ms).
        visual_ms: f64,
        /// Proprioceptive delay (ms).
        proprioceptive_ms: f64,
    },
    /// As `Known`, with the delays identified online in every gain phase
    /// ([`DelaySearch`]); `(0, 0)` until its first choice.
    Auto,
}

/// The delayed model's state inside the identifier.
// One per identifier, built at set-up; without `alloc` there is no box to
// move the larger variant into, and the size costs nothing per tick.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug)]
enum Delayed {
    /// The paper's model: no history.
    Paper,
    /// Delays in ticks `(visual, proprioceptive)`, the history they read,
    /// and the search (`Auto`) with the phase it runs in.
    On {
        delays: (usize, usize),
        history: History<4>,
        search: Option<(DelaySearch, Option<usize>)>,
        /// Stage-1's predicted partner torque at the last predict.
        last_c: f64,
    },
}

/// The handle as the identifier last saw it: the position `x` it stood on
/// (measured, or carried through a gap), its stage's posterior `e = x - tau`
/// there, and the own target's increment given to the predict since.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct GapView {
    x: f64,
    e: f64,
    dtau: f64,
}

/// Stage 1 and stage 2 of one agent, with the gain window and the hand-off.
#[derive(Clone, Debug)]
pub struct Identifier {
    stage1: GainEstimator,
    stage2: TrajectoryEstimator,
    /// Stage 2's covariance at the hand-off.
    stage2_P0: Cov6,
    window: GainWindow,
    prior_gains: Option<[f64; 3]>,
    /// Stage 2's gain pseudo-measurement, fixed at the hand-off; `None`
    /// until stage 2 starts.
    pseudo_gains: Option<[f64; 3]>,
    /// Stage 1 has predicted without a measurement since its last one
    /// ([`GainEstimator::resync`] before the next).
    stage1_gap: bool,
    /// Where the last tick left the handle, for a gap's prediction.
    view: GapView,
    tally: FilterTally,
    /// The delayed partner model (`robot.partner_delay`).
    delayed: Delayed,
    /// The loop period (s) and the model's step, for the delays' units and
    /// the search's residuals.
    dt_s: f64,
    step: Step,
}

impl Identifier {
    /// Set-up: builds both filters on `model`. The gain window is the last
    /// `gain_window_s` of a gain phase, in whole ticks of the loop period
    /// `dt_s` (both > 0); `prior_gains` (finite) stand in for the window
    /// when no gain phase precedes.
    pub fn new(
        model: HandleModel,
        stage1: &ExtendedFilterConfig<3>,
        stage2: &ExtendedFilterConfig<5>,
        gain_window_s: f64,
        dt_s: f64,
        prior_gains: Option<[f64; 3]>,
    ) -> Result<Self, ScenarioError> {
        let window_ticks = gain_window_s / dt_s;
        if !(gain_window_s > 0.0 && dt_s > 0.0 && window_ticks.is_finite()) {
            return Err(ScenarioError::InvalidSetting("robot.gain_window_s"));
        }
        if prior_gains.is_some_and(|g| g.iter().any(|v| !v.is_finite())) {
            return Err(ScenarioError::InvalidSetting("robot.prior_partner_gains"));
        }
        let est = |stage| move |error| ScenarioError::Estimator { stage, error };
        Ok(Identifier {
            stage1: GainEstimator::new(model, stage1).map_err(est("stage1"))?,
            stage2: TrajectoryEstimator::new(model, stage2).map_err(est("stage2"))?,
            stage2_P0: stage2.P0,
            window: GainWindow {
                ticks: window_ticks as u64,
                sum: [0.0; 3],
                count: 0,
            },
            prior_gains,
            pseudo_gains: None,
            stage1_gap: false,
            view: GapView::default(),
            tally: FilterTally::default(),
            delayed: Delayed::Paper,
            dt_s,
            step: model.step(),
        })
    }

    /// Set-up: the partner model stages 1 and 2 assume; errors name
    /// `robot.partner_delay` (delays 0-300 ms within the history).
    pub fn with_delay(mut self, delay: PartnerDelay) -> Result<Self, ScenarioError> {
        let bad = ScenarioError::InvalidSetting("robot.partner_delay");
        self.delayed = match delay {
            PartnerDelay::Paper => Delayed::Paper,
            PartnerDelay::Known {
                visual_ms,
                proprioceptive_ms,
            } => Delayed::On {
                delays: (
                    delay_ticks(visual_ms, self.dt_s).ok_or(bad)?,
                    delay_ticks(proprioceptive_ms, self.dt_s).ok_or(bad)?,
                ),
                history: History::default(),
                search: None,
                last_c: f64::NAN,
            },
            PartnerDelay::Auto => Delayed::On {
                delays: (0, 0),
                history: History::default(),
                search: Some((
                    DelaySearch::new(SearchSchedule::for_phase(1, self.dt_s)),
                    None,
                )),
                last_c: f64::NAN,
            },
        };
        Ok(self)
    }

    /// The delay search's current evidence (`robot.partner_delay = "auto"`),
    /// `None` otherwise or before its first choice.
    pub fn delay_evidence(&self) -> Option<DelayEvidence> {
        match &self.delayed {
            Delayed::On {
                search: Some((s, _)),
                ..
            } => s.choice().copied(),
            _ => None,
        }
    }

    /// The delays the filters assume (ms) and the search's margin, for the
    /// log line.
    fn delay_report(&self) -> ([f64; 2], f64) {
        let ms = |d: usize| d as f64 * self.dt_s * 1e3;
        match &self.delayed {
            Delayed::Paper => ([f64::NAN; 2], f64::NAN),
            Delayed::On {
                delays,
                search: None,
                ..
            } => ([ms(delays.0), ms(delays.1)], f64::NAN),
            Delayed::On {
                search: Some((s, _)),
                ..
            } => match s.choice() {
                None => ([f64::NAN; 2], f64::NAN),
                Some(c) => (
                    [
                        ms(c.visual),
                        if c.proprioceptive_identified {
                            ms(c.proprioceptive)
                        } else {
                            f64::NAN
                        },
                    ],
                    c.margin_nats,
                ),
            },
        }
    }

    /// Stores this tick's sample `[x - tau, xdot, x - tau_h, x]`: the
    /// measured one (`fresh`), else the active stage's prediction of it
    /// (docs/model.md, "Feedback gaps"), and, in a gain phase with a
    /// search, feeds the search (which uses only fresh residuals) and takes
    /// its choice.
    fn record(&mut self, sample: &Sample<'_>, y: [f64; 4], fresh: bool) {
        let step = (self.step.v_v, self.step.v_f);
        let dt_s = self.dt_s;
        let Delayed::On {
            delays,
            history,
            search,
            ..
        } = &mut self.delayed
        else {
            return;
        };
        history.push(y);
        if sample.phase.kind != PhaseKind::Gains {
            return;
        }
        if let Some((s, phase)) = search.as_mut() {
            if *phase != Some(sample.index) {
                let ticks = libm::round(sample.phase.duration_s / dt_s) as u64;
                *s = DelaySearch::new(SearchSchedule::for_phase(ticks, dt_s));
                *phase = Some(sample.index);
            }
            s.observe(history, fresh, step);
            if let Some(c) = s.choice() {
                *delays = (c.visual, c.proprioceptive);
            }
        }
    }

    /// In a gap (no measurement this tick): the active stage's prior
    /// `[e, v, e_h]` (`e_h` NaN in stage 2, whose entry is another
    /// quantity) and the handle position it implies,
    /// `x = x_prev + (e - e_prev) + dtau_prev` (`e = x - tau`): the sample
    /// the partner acted on, as well as the robot can tell.
    fn predicted_sample(&self, kind: PhaseKind) -> [f64; 4] {
        let z = match kind {
            PhaseKind::Gains => self.stage1.filter().x(),
            PhaseKind::Trajectory | PhaseKind::Integration => self.stage2.filter().x(),
        };
        let e_h = if kind == PhaseKind::Gains {
            z[E_H]
        } else {
            f64::NAN
        };
        let v = &self.view;
        [z[0], z[1], e_h, v.x + (z[0] - v.e) + v.dtau]
    }

    /// Per tick, first: fuse the measurement `y = [x - tau_own, xdot,
    /// x - tau_partner]` when there is one (its third entry is only used in
    /// gain phases) and return the estimate at the handle position `x`, the
    /// measured one; without a measurement `x` is not read: the stage's
    /// predicted position stands in for it ([`Identifier::predicted_sample`]).
    /// Gain phases run stage 1 and its window; later phases run stage 2
    /// (after the hand-off at its first tick), with this tick's measurement
    /// covariance `R` if given, else the configured one.
    pub fn update(
        &mut self,
        sample: &Sample<'_>,
        y: Option<Vector3<f64>>,
        x: f64,
        R: Option<&SMatrix<f64, 5, 5>>,
    ) -> PartnerEstimate {
        let kind = sample.phase.kind;
        if kind != PhaseKind::Gains && self.pseudo_gains.is_none() {
            self.hand_off();
        }
        let (fresh, y4) = match y {
            Some(y) => (true, [y[0], y[1], y[2], x]),
            None => (false, self.predicted_sample(kind)),
        };
        let x = y4[3];
        let y4 = match kind {
            PhaseKind::Gains => y4,
            // Stage 2's third entry is not `x - tau_h` (unknown there).
            PhaseKind::Trajectory | PhaseKind::Integration => [y4[0], y4[1], f64::NAN, y4[3]],
        };
        self.record(sample, y4, fresh);
        let est = match kind {
            PhaseKind::Gains => self.update_gains(sample, y),
            PhaseKind::Trajectory | PhaseKind::Integration => {
                self.update_trajectory(y.map(|y| (y[0], y[1])), x, R)
            }
        };
        // The stage's posterior `e` and the position it stands on, for the
        // next gap's prediction.
        let z = match kind {
            PhaseKind::Gains => self.stage1.filter().x(),
            PhaseKind::Trajectory | PhaseKind::Integration => self.stage2.filter().x(),
        };
        self.view.x = x;
        self.view.e = z[0];
        let (delay_ms, delay_margin_nats) = self.delay_report();
        PartnerEstimate {
            delay_ms,
            delay_margin_nats,
            ..est
        }
    }

    /// Per tick, last: propagate the phase's stage with the own torque `u`
    /// and the targets' increments over the coming step (stage 2 does not
    /// know the partner's: 0).
    pub fn predict(&mut self, kind: PhaseKind, u: f64, dtau_own: f64, dtau_partner: f64) {
        self.view.dtau = dtau_own;
        let r = match (&mut self.delayed, kind) {
            (Delayed::Paper, PhaseKind::Gains) => {
                self.stage1.predict_finite(u, dtau_own, dtau_partner)
            }
            (Delayed::Paper, _) => self.stage2.predict_finite(u, dtau_own, 0.0),
            (
                Delayed::On {
                    delays: (dv, dp),
                    history,
                    search,
                    last_c,
                },
                PhaseKind::Gains,
            ) => {
                let (seen, felt) = (history.ago(*dv), history.ago(*dp));
                let phi = [seen[0], felt[1], seen[2]];
                let g = self.stage1.gains();
                *last_c = -(g[0] * phi[0] + g[1] * phi[1] + g[2] * phi[2]);
                if let Some((s, _)) = search.as_mut() {
                    s.commanded(history, u, *last_c);
                }
                self.stage1.predict_delayed(phi, u, dtau_own, dtau_partner)
            }
            (
                Delayed::On {
                    delays: (dv, dp),
                    history,
                    ..
                },
                _,
            ) => {
                let (now, seen, felt) = (history.ago(0), history.ago(*dv), history.ago(*dp));
                let known = [seen[0], felt[1], now[3] - seen[3]];
                self.stage2.predict_delayed(known, u, dtau_own)
            }
        };
        self.tally.note(r);
    }

    /// Stage 1: fuse `y1 = [x - tau_own, xdot, x - tau_partner]` when there
    /// is one, add the estimate to the gain window when `sample` is in it,
    /// and return it.
    fn update_gains(&mut self, sample: &Sample<'_>, y: Option<Vector3<f64>>) -> PartnerEstimate {
        match y {
            Some(y) => {
                if self.stage1_gap {
                    let r = self.stage1.resync(&y);
                    self.tally.note(r.map(|()| Status::Nominal));
                    self.stage1_gap = false;
                }
                let r = self.stage1.update(&y);
                self.tally.note(r);
            }
            None => self.stage1_gap = true,
        }
        let gains = self.stage1.gains();
        if self.window.contains(sample.k, sample.end) {
            self.window.add(gains);
        }
        PartnerEstimate {
            gains,
            gains_var: diag3(self.stage1.filter().P(), GAINS),
            ..PartnerEstimate::NONE
        }
    }

    /// The gains stage 2 is given as pseudo-measurements: the stage-1 mean
    /// over the gain window, else the prior, else the current stage-1
    /// estimate.
    pub fn pseudo_gains(&self) -> [f64; 3] {
        self.window
            .mean()
            .or(self.prior_gains)
            .unwrap_or_else(|| self.stage1.gains())
    }

    /// The hand-off, at the first stage-2 tick (later calls do nothing):
    /// stage 2 restarts from the stage-1 posterior with its gains replaced
    /// by the [`pseudo_gains`](Identifier::pseudo_gains), which stay fixed.
    fn hand_off(&mut self) -> [f64; 3] {
        if let Some(g) = self.pseudo_gains {
            return g;
        }
        let g = self.pseudo_gains();
        let mut x0 = *self.stage1.filter().x();
        x0.fixed_rows_mut::<3>(GAINS).copy_from_slice(&g);
        // Delayed: stage 2's third entry is the error against the target
        // the partner perceives, `x - tau_h[k - d_v]`: shift it by the
        // target's motion over `d_v`, `tau_h = x - e_h` from the history
        // (its newest sample is the gain phase's last tick).
        if let Delayed::On {
            delays: (dv, _),
            history,
            ..
        } = &self.delayed
        {
            let tau_h = |y: [f64; 4]| y[3] - y[2];
            let shift = tau_h(history.ago(0)) - tau_h(history.ago(*dv));
            if shift.is_finite() {
                x0[E_H] += shift;
            }
        }
        let r = self.stage2.reset(x0, self.stage2_P0);
        self.tally.note(r.map(|()| Status::Nominal));
        self.pseudo_gains = Some(g);
        g
    }

    /// Stage 2: the hand-off if this is its first tick, then fuse
    /// `y2 = [x - tau_own, xdot, pseudo-gains]` from `y = (x - tau_own, xdot)`
    /// when there is one, and return the estimate at the handle position `x`.
    fn update_trajectory(
        &mut self,
        y: Option<(f64, f64)>,
        x: f64,
        R: Option<&SMatrix<f64, 5, 5>>,
    ) -> PartnerEstimate {
        let g = self.hand_off();
        if let Some((e, v)) = y {
            let y = SVector::<f64, 5>::new(e, v, g[0], g[1], g[2]);
            let r = match R {
                Some(R) => self.stage2.update_with_r(&y, R),
                None => self.stage2.update(&y),
            };
            self.tally.note(r);
        }
        let f = self.stage2.filter();
        PartnerEstimate {
            gains: [f.x()[GAINS], f.x()[GAINS + 1], f.x()[GAINS + 2]],
            gains_var: diag3(f.P(), GAINS),
            target: self.stage2.partner_target(x),
            target_var: self.stage2.partner_error_variance(),
            ..PartnerEstimate::NONE
        }
    }

    /// Stage 2 (for the goal integration: its `x - tau_h` channel and the
    /// partner torque it implies).
    pub fn trajectory(&self) -> &TrajectoryEstimator {
        &self.stage2
    }

    /// Filter outcomes so far.
    pub fn tally(&self) -> FilterTally {
        self.tally
    }
}

/// Three consecutive diagonal entries of `P` from index `from`.
fn diag3(P: &Cov6, from: usize) -> [f64; 3] {
    [
        P[(from, from)],
        P[(from + 1, from + 1)],
        P[(from + 2, from + 2)],
    ]
}
