//! Test support, not product: a small nonlinear model for cross-checking the
//! generic UKF against filterpy (`tests/ukf_oracle`, `tests/test_ukf.py`) and
//! for the UKF's own Rust tests: a damped pendulum driven by a known torque plus an
//! unknown constant torque bias (a stand-in for a partner's torque), observed
//! by a marker at the pendulum tip.
//!
//! State `x = [theta_rad, omega_radps, bias_nm]` (`N = 3`), control
//! `u = torque_nm`, measurement `z = [l sin(theta), -l cos(theta)]` in metres
//! (`M = 2`, tip position with the pivot at the origin, `y` up).
//! `docs/ukf.md` states the same equations.
#![allow(dead_code)]

use nalgebra::SVector;
use sensaug_core::replay::{row, write_posterior, Input, Replay};
use sensaug_core::ukf::{RunReport, Status, Ukf, UkfError};

/// State size of the demo model.
pub const N: usize = 3;
/// Measurement size of the demo model.
pub const M: usize = 2;
/// Sigma point count `2N + 1`.
pub const S: usize = 2 * N + 1;

/// The UKF type for the demo model.
pub type DemoUkf = Ukf<N, M, S>;

/// Damped point-mass pendulum, discretised with semi-implicit Euler at a
/// fixed step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pendulum {
    /// Time step, s (> 0).
    pub dt_s: f64,
    /// Rod length, m (> 0).
    pub length_m: f64,
    /// Point mass at the tip, kg (> 0).
    pub mass_kg: f64,
    /// Viscous damping at the pivot, N m s / rad (>= 0).
    pub damping_nms: f64,
    /// Gravitational acceleration, m / s^2 (finite).
    pub gravity_mps2: f64,
}

impl Default for Pendulum {
    /// 1 kHz, 0.5 m, 1 kg, 0.1 N m s / rad, 9.81 m / s^2.
    fn default() -> Self {
        Self {
            dt_s: 1e-3,
            length_m: 0.5,
            mass_kg: 1.0,
            damping_nms: 0.1,
            gravity_mps2: 9.81,
        }
    }
}

impl Pendulum {
    /// Set-up: validate the parameters; the error names the field.
    pub fn validate(&self) -> Result<(), UkfError> {
        let bad = |name| Err(UkfError::InvalidModelParameter { name });
        if !(self.dt_s.is_finite() && self.dt_s > 0.0) {
            return bad("dt_s");
        }
        if !(self.length_m.is_finite() && self.length_m > 0.0) {
            return bad("length_m");
        }
        if !(self.mass_kg.is_finite() && self.mass_kg > 0.0) {
            return bad("mass_kg");
        }
        if !(self.damping_nms.is_finite() && self.damping_nms >= 0.0) {
            return bad("damping_nms");
        }
        if !self.gravity_mps2.is_finite() {
            return bad("gravity_mps2");
        }
        Ok(())
    }

    /// Angular acceleration:
    /// `alpha = (u + b - c omega - m g l sin(theta)) / (m l^2)`.
    pub fn angular_acceleration(&self, x: &SVector<f64, N>, torque_nm: f64) -> f64 {
        let (theta, omega, bias) = (x[0], x[1], x[2]);
        let inertia = self.mass_kg * self.length_m * self.length_m;
        let gravity_torque = self.mass_kg * self.gravity_mps2 * self.length_m * libm::sin(theta);
        (torque_nm + bias - self.damping_nms * omega - gravity_torque) / inertia
    }

    /// Process model (semi-implicit Euler):
    /// `omega+ = omega + dt alpha`, `theta+ = theta + dt omega+`, `b+ = b`.
    pub fn f(&self, x: &SVector<f64, N>, torque_nm: f64) -> SVector<f64, N> {
        let omega_next = x[1] + self.dt_s * self.angular_acceleration(x, torque_nm);
        let theta_next = x[0] + self.dt_s * omega_next;
        SVector::<f64, N>::new(theta_next, omega_next, x[2])
    }

    /// Measurement model (tip marker): `z = [l sin(theta), -l cos(theta)]`.
    pub fn h(&self, x: &SVector<f64, N>) -> SVector<f64, M> {
        SVector::<f64, M>::new(
            self.length_m * libm::sin(x[0]),
            -self.length_m * libm::cos(x[0]),
        )
    }

    /// Replay a trial through [`Ukf::run`] with this model: predict with
    /// `u[k]`, then update with row `k` of `z` (row-major `T x 2`).
    pub fn run(
        &self,
        ukf: &mut DemoUkf,
        u: &[f64],
        z: &[f64],
        xs_out: &mut [f64],
        pdiag_out: &mut [f64],
    ) -> Result<RunReport, UkfError> {
        ukf.run(
            u,
            z,
            xs_out,
            pdiag_out,
            |x, uk| self.f(x, uk),
            |x| self.h(x),
        )
    }
}

/// The demo UKF with its model, replayable by `sensaug_core::replay` in the
/// estimators' order: update with `z[k]`, then predict with `u[k]`.
#[derive(Clone, Debug)]
pub struct PendulumFilter {
    /// The filter.
    pub ukf: DemoUkf,
    /// Its model.
    pub model: Pendulum,
}

impl Replay for PendulumFilter {
    fn measurement_len(&self) -> usize {
        M
    }
    fn state_len(&self) -> usize {
        N
    }
    fn target_increments(&self) -> usize {
        0
    }
    fn update_row(&mut self, z: &[f64]) -> Result<Status, UkfError> {
        let model = self.model;
        self.ukf.update(&row::<M>(z), |x| model.h(x))
    }
    fn predict_input(&mut self, input: Input) -> Result<Status, UkfError> {
        let model = self.model;
        self.ukf.predict(|x| model.f(x, input.u))
    }
    fn posterior(&self, x: &mut [f64], var: &mut [f64]) {
        write_posterior(self.ukf.x(), self.ukf.P(), x, var)
    }
}
