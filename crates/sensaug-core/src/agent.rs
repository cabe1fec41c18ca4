//! The agents' control laws (eq.LQRrobot, eq.LQRhuman) on the paper's
//! 3-state `xi = [x - tau, xdot, x - tau_h]`.
//!
//! Gains are row vectors over `xi`: an LQR robot is `L = [k_pos, k_vel, 0]`,
//! an LQR partner `L_h = [0, k_vel, k_pos]` (from the reduced 2-state
//! problem, `docs/model.md`), and the Hi5 experiment's virtual human has the
//! imposed `L_h = [0, 0, Lhh]`.

/// `xi = [x - tau, xdot, x - tau_h]` (eq.system).
pub fn xi(x: f64, v: f64, tau: f64, tau_h: f64) -> [f64; 3] {
    [x - tau, v, x - tau_h]
}

/// `u = -L xi` (eq.LQRrobot; eq.LQRhuman with `L_h`).
pub fn feedback_torque(gains: &[f64; 3], xi: &[f64; 3]) -> f64 {
    -(gains[0] * xi[0] + gains[1] * xi[1] + gains[2] * xi[2])
}

/// Robot gains over `xi` from the reduced LQR gains `[k_pos, k_vel]`.
pub fn robot_gains(k: [f64; 2]) -> [f64; 3] {
    [k[0], k[1], 0.0]
}

/// Partner gains over `xi` from its reduced LQR gains `[k_pos, k_vel]`.
pub fn partner_gains(k: [f64; 2]) -> [f64; 3] {
    [0.0, k[1], k[0]]
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
