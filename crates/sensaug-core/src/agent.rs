//! The agents' control laws (eq.LQRrobot, eq.LQRhuman) on the paper's
//! 3-state `xi = [x - tau, xdot, x - tau_h]`.
//!
//! Gains are row vectors over `xi`: an LQR robot is `L = [k_pos, k_vel, 0]`,
//! an LQR partner `L_h = [0, k_vel, k_pos]` (from the reduced 2-state
//! problem, `docs/model.md`), and the Hi5 experiment's virtual human has the
//! imposed `L_h = [0, 0, Lhh]`.
//!
//! [`VirtualHuman`] is the partner's whole torque law, the one the simulated
//! world and the rig loop both run.

use crate::ScenarioError;

/// `xi = [x - tau, xdot, x - tau_h]` (eq.system).
pub fn xi(x: f64, v: f64, tau: f64, tau_h: f64) -> [f64; 3] {
    [x - tau, v, x - tau_h]
}

/// `u = -L xi` (eq.LQRrobot; eq.LQRhuman with `L_h`).
pub fn feedback_torque(gains: &[f64; 3], xi: &[f64; 3]) -> f64 {
    -(gains[0] * xi[0] + gains[1] * xi[1] + gains[2] * xi[2])
}

/// A gain vector seen from the other agent: `xi` with its first and third
/// entries swapped (`[x - tau_h, xdot, x - tau]`), as a human model that
/// estimates the robot uses it.
pub fn mirrored(gains: [f64; 3]) -> [f64; 3] {
    [gains[2], gains[1], gains[0]]
}

/// What a torque guard did to a command, ordered by severity (so the
/// worst of several guards is their `max`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Guard {
    /// The command was finite and within the limit.
    Passed,
    /// The command exceeded the limit and was clamped.
    Clamped,
    /// The command was NaN or infinite and was replaced by 0.
    NonFinite,
}

/// Clamps `u` to `[-limit, limit]`; a non-finite `u` becomes 0. Never lets a
/// NaN reach a motor.
pub fn guard_torque(u: f64, limit: f64) -> (f64, Guard) {
    if !u.is_finite() {
        (0.0, Guard::NonFinite)
    } else if u > limit {
        (limit, Guard::Clamped)
    } else if u < -limit {
        (-limit, Guard::Clamped)
    } else {
        (u, Guard::Passed)
    }
}

/// The virtual human: the partner agent's torque law in a simulated trial and
/// inside the rig loop (eq.LQRhuman, guarded):
/// `u_h = guard(-L_h xi(x, v, tau, tau_h), torque_limit)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VirtualHuman {
    gains: [f64; 3],
    torque_limit: f64,
}

impl VirtualHuman {
    /// Set-up: `gains` (`L_h` over `xi`) must be finite, `torque_limit` > 0
    /// (errors name `partner.gains` / `partner.torque_limit`).
    pub fn new(gains: [f64; 3], torque_limit: f64) -> Result<Self, ScenarioError> {
        if gains.iter().any(|g| !g.is_finite()) {
            return Err(ScenarioError::InvalidSetting("partner.gains"));
        }
        if torque_limit.is_nan() || torque_limit <= 0.0 {
            return Err(ScenarioError::InvalidSetting("partner.torque_limit"));
        }
        Ok(VirtualHuman {
            gains,
            torque_limit,
        })
    }

    /// Its gains `L_h` over `xi`.
    pub fn gains(&self) -> [f64; 3] {
        self.gains
    }

    /// Per tick: the guarded torque at the sensed `(x, v)` with the robot's
    /// target `tau` and its own `tau_h`, and what the guard did.
    pub fn torque(&self, x: f64, v: f64, tau: f64, tau_h: f64) -> (f64, Guard) {
        guard_torque(
            feedback_torque(&self.gains, &xi(x, v, tau, tau_h)),
            self.torque_limit,
        )
    }
}

/// Capacity of the delay histories (ticks): the longest delay a partner may
/// have or the robot may assume is `HISTORY - 1` ticks (300 ms at 1 kHz
/// needs 301). A power of two, so the ring's index is a mask.
pub const HISTORY: usize = 512;

/// The longest sensorimotor delay a setting may name (ms).
pub const MAX_DELAY_MS: f64 = 300.0;

/// A fixed-size ring of the last [`HISTORY`] samples; `ago(d)` is the one
/// pushed `d` pushes ago, clamped at the first one pushed (before the trial
/// the handle rests where it starts).
#[derive(Clone, Debug, PartialEq)]
pub struct History<const W: usize> {
    buf: [[f64; W]; HISTORY],
    head: usize,
    len: usize,
}

impl<const W: usize> Default for History<W> {
    fn default() -> Self {
        History {
            buf: [[0.0; W]; HISTORY],
            head: 0,
            len: 0,
        }
    }
}

impl<const W: usize> History<W> {
    /// Appends the newest sample.
    pub fn push(&mut self, y: [f64; W]) {
        self.head = (self.head + 1) & (HISTORY - 1);
        self.buf[self.head] = y;
        self.len = (self.len + 1).min(HISTORY);
    }

    /// The sample `d` pushes ago (`d = 0`: the newest), clamped at the
    /// oldest one held; zeros before the first push.
    pub fn ago(&self, d: usize) -> [f64; W] {
        let d = d.min(self.len.saturating_sub(1));
        self.buf[(self.head + HISTORY - d) & (HISTORY - 1)]
    }

    /// Samples pushed so far (at most [`HISTORY`]).
    pub fn len(&self) -> usize {
        self.len
    }

    /// Nothing pushed yet.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
}

/// A delay in ms as whole ticks of the loop period `dt_s`:
/// `round(ms / 1000 / dt)`; `None` unless `0 <= ms <= MAX_DELAY_MS` and the
/// ticks fit in [`HISTORY`].
pub fn delay_ticks(ms: f64, dt_s: f64) -> Option<usize> {
    if !(ms.is_finite() && (0.0..=MAX_DELAY_MS).contains(&ms) && dt_s > 0.0) {
        return None;
    }
    let d = libm::round(ms * 1e-3 / dt_s);
    (d < HISTORY as f64).then_some(d as usize)
}

/// The human-like partner's settings (`partner.human`, docs/model.md):
/// delays on what it perceives, signal-dependent motor noise, a bounded
/// drift of its gains, its own seed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HumanLike {
    /// Visual delay (ms) on the target-related terms `x - tau`, `x - tau_h`.
    pub visual_delay_ms: f64,
    /// Proprioceptive delay (ms) on the velocity term.
    pub proprioceptive_delay_ms: f64,
    /// `k_m`: the command gets white noise of std `k_m |c|` (>= 0).
    pub motor_noise_gain: f64,
    /// Relative stationary std `sigma_d` of the gains' drift (0: none).
    pub drift_std: f64,
    /// The drift's time constant `T_d` (s, > 0).
    pub drift_time_constant_s: f64,
    /// Seed of the partner's motor noise and drift (its own stream).
    pub seed: u64,
}

/// `delta' = clip(rho delta + sigma sqrt(1 - rho^2) w, -3 sigma, 3 sigma)`,
/// `rho = exp(-dt / T)`: one step of the bounded Ornstein-Uhlenbeck walk of
/// a gain's relative drift (stationary std `sigma`, correlation time `T`).
pub fn drift_step(delta: f64, w: f64, rho: f64, sigma: f64) -> f64 {
    let next = rho * delta + sigma * libm::sqrt(1.0 - rho * rho) * w;
    next.clamp(-3.0 * sigma, 3.0 * sigma)
}

/// The human-like partner's torque law: eq.LQRhuman on the state it
/// perceived (`e = x - tau` and `e_h = x - tau_h` `d_v` ticks ago, `v` `d_p`
/// ticks ago), gains `L_h (1 + delta_k)`, plus motor noise of std
/// `k_m |c|`, guarded like [`VirtualHuman`]:
/// `u_h = guard(c + k_m |c| n, limit)`,
/// `c = -(Lhx e[k-d_v] + Lhv v[k-d_p] + Lhh e_h[k-d_v]) `.
#[derive(Clone, Debug)]
pub struct HumanPartner {
    law: VirtualHuman,
    visual: usize,
    proprioceptive: usize,
    motor_noise_gain: f64,
    drift_std: f64,
    drift_rho: f64,
    delta: [f64; 3],
    perceived: History<3>,
    noise: crate::rng::Noise,
}

impl HumanPartner {
    /// Set-up at the loop period `dt_s`; errors name the `partner.human`
    /// field to fix.
    pub fn new(law: VirtualHuman, h: HumanLike, dt_s: f64) -> Result<Self, ScenarioError> {
        let bad = |name| Err(ScenarioError::InvalidSetting(name));
        let Some(visual) = delay_ticks(h.visual_delay_ms, dt_s) else {
            return bad("partner.human.visual_delay_ms");
        };
        let Some(proprioceptive) = delay_ticks(h.proprioceptive_delay_ms, dt_s) else {
            return bad("partner.human.proprioceptive_delay_ms");
        };
        if !(h.motor_noise_gain.is_finite() && h.motor_noise_gain >= 0.0) {
            return bad("partner.human.motor_noise_gain");
        }
        if !(h.drift_std.is_finite() && (0.0..1.0 / 3.0).contains(&h.drift_std)) {
            return bad("partner.human.gain_drift.std");
        }
        if !(h.drift_time_constant_s.is_finite() && h.drift_time_constant_s > 0.0) {
            return bad("partner.human.gain_drift.time_constant_s");
        }
        Ok(HumanPartner {
            law,
            visual,
            proprioceptive,
            motor_noise_gain: h.motor_noise_gain,
            drift_std: h.drift_std,
            drift_rho: libm::exp(-dt_s / h.drift_time_constant_s),
            delta: [0.0; 3],
            perceived: History::default(),
            noise: crate::rng::Noise::new(h.seed),
        })
    }

    /// Its delays `(d_v, d_p)` in ticks.
    pub fn delays(&self) -> (usize, usize) {
        (self.visual, self.proprioceptive)
    }

    /// Its gains this tick, `L_h (1 + delta_k)`.
    pub fn gains(&self) -> [f64; 3] {
        let g = self.law.gains();
        [
            g[0] * (1.0 + self.delta[0]),
            g[1] * (1.0 + self.delta[1]),
            g[2] * (1.0 + self.delta[2]),
        ]
    }

    /// Per tick, in order: perceives the sensed `(x, v)` with the targets,
    /// returns the guarded torque on what it perceived the delays ago.
    pub fn torque(&mut self, x: f64, v: f64, tau: f64, tau_h: f64) -> (f64, Guard) {
        self.perceived.push(xi(x, v, tau, tau_h));
        let seen = self.perceived.ago(self.visual);
        let felt = self.perceived.ago(self.proprioceptive);
        let c = feedback_torque(&self.gains(), &[seen[0], felt[1], seen[2]]);
        let noise = if self.motor_noise_gain > 0.0 {
            self.motor_noise_gain * libm::fabs(c) * self.noise.standard()
        } else {
            0.0
        };
        if self.drift_std > 0.0 {
            for d in self.delta.iter_mut() {
                *d = drift_step(*d, self.noise.standard(), self.drift_rho, self.drift_std);
            }
        }
        guard_torque(c + noise, self.law.torque_limit)
    }
}

/// The partner's torque law on the simulation and the rig: the paper's
/// virtual human, or the human-like one.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug)]
pub enum PartnerLaw {
    /// The paper's virtual human (no `partner.human` table).
    Paper(VirtualHuman),
    /// The human-like partner (`partner.human`).
    Human(HumanPartner),
}

impl PartnerLaw {
    /// Set-up: the virtual human of `gains`, `torque_limit`, made human-like
    /// by `human` when given.
    pub fn new(
        gains: [f64; 3],
        torque_limit: f64,
        human: Option<HumanLike>,
        dt_s: f64,
    ) -> Result<Self, ScenarioError> {
        let law = VirtualHuman::new(gains, torque_limit)?;
        Ok(match human {
            None => PartnerLaw::Paper(law),
            Some(h) => PartnerLaw::Human(HumanPartner::new(law, h, dt_s)?),
        })
    }

    /// Per tick: the guarded torque at the sensed `(x, v)`.
    pub fn torque(&mut self, x: f64, v: f64, tau: f64, tau_h: f64) -> (f64, Guard) {
        match self {
            PartnerLaw::Paper(law) => law.torque(x, v, tau, tau_h),
            PartnerLaw::Human(h) => h.torque(x, v, tau, tau_h),
        }
    }

    /// The gains acting this tick.
    pub fn gains(&self) -> [f64; 3] {
        match self {
            PartnerLaw::Paper(law) => law.gains(),
            PartnerLaw::Human(h) => h.gains(),
        }
    }
}
