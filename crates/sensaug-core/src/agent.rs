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

/// What a torque guard did to a command.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
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
