//! The shared 1-DoF handle (eq.dynamics): `M xdd + C xd = u + u_h + eps`.
//!
//! One joint, stepped by the exact zero-order-hold (ZOH) solution over the
//! loop period: the summed torque is held constant for `dt`, and the linear
//! part is integrated in closed form, so the discrete plant is exact for the
//! linear model at any `dt`, not a first-order approximation.
//!
//! Units are the caller's, consistently: rad, rad/s, N m and kg m^2 for the
//! Hi5 wrist; m, m/s, N and kg for the paper's simulation.
//!
//! Optional Coulomb friction is a torque of magnitude `coulomb` opposing the
//! motion (or, at rest, opposing the applied torque up to `coulomb`: stiction),
//! held constant over a step like the input. Viscous friction is the paper's
//! `C` (`damping`). The paper models the Hi5 *after* friction compensation
//! (`C = 0`, no Coulomb term: [`PlantParams::HI5`]); compensating a real
//! handle's friction is the drive's job, not the controller's.

use libm::{exp, expm1, fabs};

/// Physical parameters of the handle and the loop period.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlantParams {
    /// Inertia `M` (kg m^2 for a revolute joint, kg for a linear one). Must be > 0.
    pub mass: f64,
    /// Viscous damping `C` (N m s/rad). Must be >= 0.
    pub damping: f64,
    /// Coulomb friction torque magnitude (N m). Must be >= 0; 0 disables it.
    pub coulomb: f64,
    /// Loop period `dt` (s). Must be > 0.
    pub dt_s: f64,
}

impl PlantParams {
    /// The Hi5 wrist interface of the paper's experiment: `M = 0.0035 kg m^2`,
    /// `C = 0` (after friction compensation), 1 kHz. The one place the Hi5
    /// numbers live in Rust.
    pub const HI5: PlantParams = PlantParams {
        mass: 0.0035,
        damping: 0.0,
        coulomb: 0.0,
        dt_s: 1e-3,
    };

    /// Checks every field, then that one step stays finite: its
    /// coefficients ([`Zoh`]) and its response to the friction and to a
    /// unit torque. The error names the first parameter that is wrong.
    pub fn validate(&self) -> Result<(), PlantError> {
        if !(self.mass.is_finite() && self.mass > 0.0) {
            return Err(PlantError::InvalidParam("mass"));
        }
        if !(self.damping.is_finite() && self.damping >= 0.0) {
            return Err(PlantError::InvalidParam("damping"));
        }
        if !(self.coulomb.is_finite() && self.coulomb >= 0.0) {
            return Err(PlantError::InvalidParam("coulomb"));
        }
        if !(self.dt_s.is_finite() && self.dt_s > 0.0) {
            return Err(PlantError::InvalidParam("dt_s"));
        }
        self.check_step()
    }

    /// Each parameter in range can still make [`Plant::step`] overflow or
    /// lose itself to underflow: a period whose square overflows or is no
    /// longer a normal number, an inertia so small that `f / M` or the
    /// response to a unit torque (`dt phi1 / M`, `dt^2 phi2 / M`) overflows, a
    /// damping for which `s = C dt / M` overflows or the coefficients
    /// `dt phi1`, `dt^2 phi2` underflow, or a friction torque whose response
    /// overflows.
    fn check_step(&self) -> Result<(), PlantError> {
        let PlantParams {
            mass,
            damping,
            coulomb,
            dt_s,
        } = *self;
        let refuse = |name| Err(PlantError::NonFiniteStep(name));
        let normal = |c: f64| c.is_finite() && c >= f64::MIN_POSITIVE;
        if !normal(dt_s * dt_s) {
            return refuse("dt_s");
        }
        if !(1.0 / mass).is_finite() {
            return refuse("mass");
        }
        if !damping_ratio(mass, damping, dt_s).is_finite() {
            return refuse("damping");
        }
        let zoh = Zoh::new(mass, damping, dt_s);
        if !(zoh.decay.is_finite() && normal(zoh.dt_phi1) && normal(zoh.dt2_phi2)) {
            return refuse("damping");
        }
        let unit = [zoh.dt_phi1 / mass, zoh.dt2_phi2 / mass];
        if !unit.iter().all(|g| g.is_finite()) {
            return refuse("mass");
        }
        let friction = [coulomb / mass, coulomb * unit[0], coulomb * unit[1]];
        if !friction.iter().all(|g| g.is_finite()) {
            return refuse("coulomb");
        }
        Ok(())
    }
}

/// Why a plant could not be built or stepped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PlantError {
    /// The named parameter is non-finite or out of range (see [`PlantParams`]).
    InvalidParam(&'static str),
    /// The parameters are each in range, but with them one step overflows
    /// (or its coefficients underflow); names the parameter to change
    /// ([`PlantParams::validate`]).
    NonFiniteStep(&'static str),
    /// The torque given to [`Plant::step`] is NaN or infinite; the state is unchanged.
    NonFiniteTorque,
    /// The torque is finite, but the step's new state is not (the torque or
    /// the state is too large for this plant); the state is unchanged.
    NonFiniteState,
}

impl core::fmt::Display for PlantError {
    /// The parameter first, then what is wrong and how to fix it.
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match *self {
            PlantError::InvalidParam("mass") => {
                "mass: must be finite and > 0 (the inertia M: kg m^2, or kg for a linear handle)"
            }
            PlantError::InvalidParam("damping") => {
                "damping: must be finite and >= 0 (the viscous damping C, N m s/rad; 0 after \
                 friction compensation)"
            }
            PlantError::InvalidParam("coulomb") => {
                "coulomb: must be finite and >= 0 (the Coulomb friction torque, N m; 0 disables it)"
            }
            PlantError::InvalidParam("dt_s") => {
                "dt_s: must be finite and > 0 (the loop period, s; 1e-3 at 1 kHz)"
            }
            PlantError::InvalidParam("x0") => "x0: must be finite (the initial position)",
            PlantError::InvalidParam("v0") => "v0: must be finite (the initial velocity)",
            PlantError::InvalidParam(other) => other,
            PlantError::NonFiniteStep("dt_s") => {
                "dt_s: so large that dt_s^2 overflows (or so small that it underflows) and one \
                 step is not finite; give the loop period in seconds (1e-3 at 1 kHz)"
            }
            PlantError::NonFiniteStep("mass") => {
                "mass: so small for dt_s that one step's response to a torque (1 / mass, \
                 dt_s / mass, dt_s^2 / mass) overflows; raise mass (check its unit) or shorten dt_s"
            }
            PlantError::NonFiniteStep("damping") => {
                "damping: so large for mass that damping * dt_s / mass overflows, or the step's \
                 coefficients underflow; lower damping (check its unit) or raise mass"
            }
            PlantError::NonFiniteStep("coulomb") => {
                "coulomb: so large for mass that one step's response to the friction \
                 (coulomb * dt_s^2 / mass) overflows; lower coulomb (check its unit)"
            }
            PlantError::NonFiniteStep(other) => other,
            PlantError::NonFiniteTorque => {
                "torque: must be finite (NaN/inf rejected, state unchanged)"
            }
            PlantError::NonFiniteState => {
                "torque: this step's new state would overflow (the torque or the state is too \
                 large for this plant); rejected, state unchanged"
            }
        })
    }
}

/// Position and velocity of the handle.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PlantState {
    /// Position `x` (rad or m).
    pub x: f64,
    /// Velocity `xd` (rad/s or m/s).
    pub v: f64,
}

/// Exact ZOH coefficients of `M xdd + C xd = f`, precomputed once.
///
/// With `s = C dt / M`:
/// `v' = e^{-s} v + dt phi1(s) f/M` and
/// `x' = x + dt phi1(s) v + dt^2 phi2(s) f/M`, where
/// `phi1(s) = (1 - e^{-s})/s` and `phi2(s) = (s - 1 + e^{-s})/s^2`
/// (`phi1(0) = 1`, `phi2(0) = 1/2`: the double integrator).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Zoh {
    /// `e^{-s}`: velocity decay over one step.
    pub decay: f64,
    /// `dt phi1(s)`: position gain of the velocity, and velocity gain of `f/M`.
    pub dt_phi1: f64,
    /// `dt^2 phi2(s)`: position gain of `f/M`.
    pub dt2_phi2: f64,
}

impl Zoh {
    /// Coefficients for inertia `mass`, damping `damping` and period `dt_s`.
    pub fn new(mass: f64, damping: f64, dt_s: f64) -> Self {
        let s = damping_ratio(mass, damping, dt_s);
        Zoh {
            decay: exp(-s),
            dt_phi1: dt_s * phi1(s),
            dt2_phi2: dt_s * dt_s * phi2(s),
        }
    }
}

/// `s = C dt / M`, in the other orders only where the usual one overflows
/// in between (huge damping and period), so it is the same number wherever
/// that is finite.
fn damping_ratio(mass: f64, damping: f64, dt_s: f64) -> f64 {
    let s = damping * dt_s / mass;
    if s.is_finite() {
        s
    } else if (damping * (dt_s / mass)).is_finite() {
        damping * (dt_s / mass)
    } else {
        damping / mass * dt_s
    }
}

/// `phi1(s) = (1 - e^{-s})/s`, via `expm1` to keep precision for small `s`.
fn phi1(s: f64) -> f64 {
    if s == 0.0 {
        1.0
    } else {
        -expm1(-s) / s
    }
}

/// `phi2(s) = (s - 1 + e^{-s})/s^2`; a Taylor series below `s = 1e-3`, where
/// the direct form cancels catastrophically (series error < s^4/720 < 1e-15),
/// and `(1 + (e^{-s} - 1)/s)/s` above `1e150`, where `s^2` overflows.
fn phi2(s: f64) -> f64 {
    if fabs(s) < 1e-3 {
        0.5 - s / 6.0 + s * s / 24.0 - s * s * s / 120.0
    } else if s > 1e150 {
        (1.0 + expm1(-s) / s) / s
    } else {
        (s + expm1(-s)) / (s * s)
    }
}

/// The handle, stepped at a fixed period.
#[derive(Clone, Copy, Debug)]
pub struct Plant {
    params: PlantParams,
    zoh: Zoh,
    state: PlantState,
}

impl Plant {
    /// A plant at rest at `x = 0`. Validates `params` (set-up time, not in the tick).
    pub fn new(params: PlantParams) -> Result<Self, PlantError> {
        params.validate()?;
        Ok(Plant {
            params,
            zoh: Zoh::new(params.mass, params.damping, params.dt_s),
            state: PlantState::default(),
        })
    }

    /// The parameters this plant was built with.
    pub fn params(&self) -> &PlantParams {
        &self.params
    }

    /// The precomputed ZOH coefficients.
    pub fn zoh(&self) -> &Zoh {
        &self.zoh
    }

    /// Current position and velocity.
    pub fn state(&self) -> PlantState {
        self.state
    }

    /// Places the handle at `state` (e.g. the measured start of a trial).
    pub fn set_state(&mut self, state: PlantState) {
        self.state = state;
    }

    /// A plant ([`Plant::new`]) starting at `state`, which must be finite
    /// (`Err` names `x0` or `v0`).
    pub fn starting_at(params: PlantParams, state: PlantState) -> Result<Self, PlantError> {
        let mut plant = Plant::new(params)?;
        for (value, name) in [(state.x, "x0"), (state.v, "v0")] {
            if !value.is_finite() {
                return Err(PlantError::InvalidParam(name));
            }
        }
        plant.state = state;
        Ok(plant)
    }

    /// The friction torque held over the next step, given the applied torque.
    ///
    /// Moving: `-coulomb sign(v)`. At rest: stiction cancels the applied
    /// torque up to `coulomb`, beyond that it opposes it with `coulomb`.
    pub fn coulomb_torque(&self, v: f64, applied: f64) -> f64 {
        let fc = self.params.coulomb;
        if fc == 0.0 {
            0.0
        } else if v != 0.0 {
            -fc * v.signum()
        } else if fabs(applied) <= fc {
            -applied
        } else {
            -fc * applied.signum()
        }
    }

    /// Advances one period with the summed torque `torque = u + u_h + eps`
    /// held constant (ZOH). A non-finite torque, or a step whose new state
    /// would overflow, is rejected and the state is left unchanged.
    ///
    /// With Coulomb friction, a step in which friction alone would reverse the
    /// velocity ends at rest instead (friction cannot drive motion).
    pub fn step(&mut self, torque: f64) -> Result<PlantState, PlantError> {
        if !torque.is_finite() {
            return Err(PlantError::NonFiniteTorque);
        }
        let PlantState { x, v } = self.state;
        let friction = self.coulomb_torque(v, torque);
        let acc = (torque + friction) / self.params.mass;
        let mut v_next = self.zoh.decay * v + self.zoh.dt_phi1 * acc;
        let x_next = x + self.zoh.dt_phi1 * v + self.zoh.dt2_phi2 * acc;
        if friction != 0.0 && v != 0.0 && v_next * v < 0.0 && fabs(torque) <= self.params.coulomb {
            v_next = 0.0;
        }
        if !(x_next.is_finite() && v_next.is_finite()) {
            return Err(PlantError::NonFiniteState);
        }
        self.state = PlantState {
            x: x_next,
            v: v_next,
        };
        Ok(self.state)
    }
}
