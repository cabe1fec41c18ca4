//! The handle's range of motion and speed (`rig.range`, docs/safety.md,
//! "Range of motion"): what keeps a person's wrist inside a window while
//! the loop runs. Every tick, on the handle's state:
//!
//! * near a soft end stop the controller's torque toward it is ramped down
//!   ([`ramp_factor`]);
//! * beyond a soft end stop a stiff virtual wall pushes back
//!   ([`wall_torque_nm`]);
//! * above the soft speed a damping torque slows the handle
//!   ([`speed_torque_nm`]);
//! * the command is clamped with the wall and the damping given priority
//!   ([`command_nm`]);
//! * beyond a hard limit or the hard speed the run ends with the controlled
//!   stop ([`out_of_range`], [`crate::safety::StopReason::OutOfRange`]).
//!
//! Positions in rad, speeds in rad/s, torques in N m; the settings are
//! converted once from the configuration's degrees.

pub use sensaug_config::rig::RangeSettings;
use sensaug_core::agent::{guard_torque, Guard};
use std::fmt;

/// rad per degree: the stop reasons speak the configuration's degrees.
const RAD_PER_DEG: f64 = std::f64::consts::PI / 180.0;

/// Why the handle is out of its range (a hard limit, the hard speed, or
/// outside the soft window when the run starts).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum OutOfRange {
    /// The measured position beyond a hard limit.
    Position {
        /// The position (rad).
        x_rad: f64,
        /// The limit crossed (rad).
        limit_rad: f64,
        /// Its field (`rig.range.hard_min_deg` or `hard_max_deg`).
        field: &'static str,
    },
    /// At the first tick, the handle outside the soft window: the wall
    /// would start by pushing the wrist with up to the torque limit.
    Start {
        /// The position (rad).
        x_rad: f64,
        /// The soft end stop it is beyond (rad).
        limit_rad: f64,
        /// Its field (`rig.range.soft_min_deg` or `soft_max_deg`).
        field: &'static str,
    },
    /// The measured speed above the hard speed.
    Speed {
        /// The velocity (rad/s).
        v_rad_s: f64,
        /// `rig.range.hard_speed_deg_s` (rad/s).
        limit_rad_s: f64,
    },
}

impl fmt::Display for OutOfRange {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let deg = |rad: f64| rad / RAD_PER_DEG;
        match *self {
            OutOfRange::Position {
                x_rad,
                limit_rad,
                field,
            } => write!(
                f,
                "the handle at {:.2} deg, beyond {field} = {} deg",
                deg(x_rad),
                deg(limit_rad)
            ),
            OutOfRange::Start {
                x_rad,
                limit_rad,
                field,
            } => write!(
                f,
                "the handle starts at {:.2} deg, outside the soft window ({field} = {} deg); \
                 bring it into the window before the trial",
                deg(x_rad),
                deg(limit_rad)
            ),
            OutOfRange::Speed {
                v_rad_s,
                limit_rad_s,
            } => write!(
                f,
                "the handle at {:.1} deg/s, faster than rig.range.hard_speed_deg_s = {} deg/s",
                deg(v_rad_s),
                deg(limit_rad_s)
            ),
        }
    }
}

/// The factor (0 to 1) on a controller torque `torque_nm` at `x_rad`: 1
/// away from the soft end stops and for a torque away from the near one;
/// toward a soft end stop, the distance to it over `ramp_width_rad`,
/// clamped to [0, 1] (0 at and beyond it).
pub fn ramp_factor(s: &RangeSettings, x_rad: f64, torque_nm: f64) -> f64 {
    let room_rad = if torque_nm > 0.0 {
        s.soft_max_rad - x_rad
    } else if torque_nm < 0.0 {
        x_rad - s.soft_min_rad
    } else {
        return 1.0;
    };
    (room_rad / s.ramp_width_rad).clamp(0.0, 1.0)
}

/// The virtual wall beyond a soft end stop (N m): a spring-damper on the
/// penetration `p` and the velocity, `-(K p + B v)` beyond the high stop
/// (`K p - B v` beyond the low one), never pulling the handle outward (a
/// wall only pushes: a handle leaving it fast is not pulled back in). Zero
/// inside the window.
pub fn wall_torque_nm(s: &RangeSettings, x_rad: f64, v_rad_s: f64) -> f64 {
    let (k, b) = (s.wall_stiffness_nm_per_rad, s.wall_damping_nm_s_per_rad);
    if x_rad > s.soft_max_rad {
        (-k * (x_rad - s.soft_max_rad) - b * v_rad_s).min(0.0)
    } else if x_rad < s.soft_min_rad {
        (k * (s.soft_min_rad - x_rad) - b * v_rad_s).max(0.0)
    } else {
        0.0
    }
}

/// The speed limit's damping (N m): `-B (|v| - v_soft) sign(v)` above the
/// soft speed, zero below it.
pub fn speed_torque_nm(s: &RangeSettings, v_rad_s: f64) -> f64 {
    let excess = v_rad_s.abs() - s.soft_speed_rad_s;
    if excess > 0.0 {
        -s.speed_damping_nm_s_per_rad * excess * v_rad_s.signum()
    } else {
        0.0
    }
}

/// The torque command (N m) and its guard, with the range's torques first:
/// the controller's `robot_nm` ramped near the soft end stops plus the
/// partner's `partner_nm` (not scaled: a person's own torque is not ours to
/// scale) are clamped at `limit_nm`; then the wall and the speed damping
/// are added and the sum clamped again. So the wall and the damping keep
/// their full effect however hard the controller and the partner push (a
/// single clamp of the sum would swallow them), and the command never
/// exceeds the limit. A non-finite part becomes 0 ([`guard_torque`]): never
/// a NaN to the motor.
pub fn command_nm(
    s: &RangeSettings,
    x_rad: f64,
    v_rad_s: f64,
    robot_nm: f64,
    partner_nm: f64,
    limit_nm: f64,
) -> (f64, Guard) {
    let ramped_nm = robot_nm * ramp_factor(s, x_rad, robot_nm);
    let (driven_nm, first) = guard_torque(ramped_nm + partner_nm, limit_nm);
    let range_nm = wall_torque_nm(s, x_rad, v_rad_s) + speed_torque_nm(s, v_rad_s);
    let (range_nm, range_guard) = guard_torque(range_nm, limit_nm);
    let (torque_nm, last) = guard_torque(driven_nm + range_nm, limit_nm);
    (torque_nm, first.max(range_guard).max(last))
}

/// Whether the measured handle is out of its range: beyond a hard limit,
/// faster than the hard speed, or (`first_tick`) outside the soft window.
/// Non-finite values are the feedback checks' (implausible), not this.
pub fn out_of_range(
    s: &RangeSettings,
    x_rad: f64,
    v_rad_s: f64,
    first_tick: bool,
) -> Option<OutOfRange> {
    if first_tick && x_rad > s.soft_max_rad {
        return Some(OutOfRange::Start {
            x_rad,
            limit_rad: s.soft_max_rad,
            field: "rig.range.soft_max_deg",
        });
    }
    if first_tick && x_rad < s.soft_min_rad {
        return Some(OutOfRange::Start {
            x_rad,
            limit_rad: s.soft_min_rad,
            field: "rig.range.soft_min_deg",
        });
    }
    if x_rad > s.hard_max_rad {
        return Some(OutOfRange::Position {
            x_rad,
            limit_rad: s.hard_max_rad,
            field: "rig.range.hard_max_deg",
        });
    }
    if x_rad < s.hard_min_rad {
        return Some(OutOfRange::Position {
            x_rad,
            limit_rad: s.hard_min_rad,
            field: "rig.range.hard_min_deg",
        });
    }
    (v_rad_s.abs() > s.hard_speed_rad_s).then_some(OutOfRange::Speed {
        v_rad_s,
        limit_rad_s: s.hard_speed_rad_s,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use sensaug_config::rig::{default_wall, wall_spectral_radius};
    use sensaug_config::schema::RangeSpec;

    const MASS: f64 = 0.0035;
    const DT: f64 = 1e-3;

    fn hi5() -> RangeSettings {
        RangeSettings::new(&RangeSpec::default(), MASS, DT)
    }

    fn deg(d: f64) -> f64 {
        d * RAD_PER_DEG
    }

    #[test]
    fn the_ramp_scales_only_the_torque_toward_the_near_end_stop() {
        let s = hi5();
        // 40 deg soft stop, 5 deg ramp.
        assert_eq!(ramp_factor(&s, deg(0.0), 1.0), 1.0);
        assert_eq!(ramp_factor(&s, deg(35.0), 1.0), 1.0);
        assert!((ramp_factor(&s, deg(37.5), 1.0) - 0.5).abs() < 1e-12);
        assert_eq!(ramp_factor(&s, deg(40.0), 1.0), 0.0);
        assert_eq!(ramp_factor(&s, deg(45.0), 1.0), 0.0);
        // Away from the stop: untouched, in the wall too.
        assert_eq!(ramp_factor(&s, deg(39.0), -1.0), 1.0);
        assert_eq!(ramp_factor(&s, deg(45.0), -1.0), 1.0);
        assert!((ramp_factor(&s, deg(-38.75), -1.0) - 0.25).abs() < 1e-12);
        assert_eq!(ramp_factor(&s, deg(-38.75), 1.0), 1.0);
    }

    #[test]
    fn the_wall_pushes_back_and_never_pulls_outward() {
        let s = hi5();
        assert_eq!(wall_torque_nm(&s, deg(39.9), 5.0), 0.0);
        // 1 deg in, at rest: K x 1 deg (0.955 N m/deg).
        let k_nm_per_deg = s.wall_stiffness_nm_per_rad * RAD_PER_DEG;
        assert!((wall_torque_nm(&s, deg(41.0), 0.0) + k_nm_per_deg).abs() < 1e-9);
        assert!((k_nm_per_deg - 0.955).abs() < 1e-3, "{k_nm_per_deg}");
        // Moving in: more; leaving fast: never outward.
        assert!(wall_torque_nm(&s, deg(41.0), 1.0) < wall_torque_nm(&s, deg(41.0), 0.0));
        assert_eq!(wall_torque_nm(&s, deg(40.1), -10.0), 0.0);
        assert!((wall_torque_nm(&s, deg(-42.0), 0.0) - 2.0 * k_nm_per_deg).abs() < 1e-9);
        assert_eq!(wall_torque_nm(&s, deg(-40.1), 10.0), 0.0);
    }

    #[test]
    fn the_speed_damping_acts_on_the_excess_only() {
        let s = hi5();
        assert_eq!(speed_torque_nm(&s, deg(199.0)), 0.0);
        let b = s.speed_damping_nm_s_per_rad;
        assert!((speed_torque_nm(&s, deg(250.0)) + b * deg(50.0)).abs() < 1e-12);
        assert!((speed_torque_nm(&s, deg(-250.0)) - b * deg(50.0)).abs() < 1e-12);
    }

    #[test]
    fn the_wall_and_the_damping_keep_their_effect_under_a_saturated_push() {
        let s = hi5();
        // 2 deg into the wall at rest, the partner pushing 10 N m outward:
        // the push is clamped at 3 N m, the wall's -1.91 N m still acts.
        let (t, g) = command_nm(&s, deg(42.0), 0.0, 0.0, 10.0, 3.0);
        let k = s.wall_stiffness_nm_per_rad;
        assert!((t - (3.0 - k * deg(2.0))).abs() < 1e-9, "{t}");
        assert_eq!(g, Guard::Clamped);
        // The worst guard of the three is reported.
        let (_, g) = command_nm(&s, deg(42.0), 0.0, f64::NAN, 10.0, 3.0);
        assert_eq!(g, Guard::NonFinite);
        // Never beyond the limit, never NaN.
        for (x, v, r, p) in [
            (deg(80.0), -20.0, 5.0, -5.0),
            (deg(-80.0), 20.0, f64::NAN, 1.0),
            (f64::NAN, 0.0, 1.0, 1.0),
            (0.0, f64::INFINITY, 1.0, 1.0),
        ] {
            let (t, _) = command_nm(&s, x, v, r, p, 3.0);
            assert!(t.is_finite() && t.abs() <= 3.0, "{t}");
        }
        // The robot's push toward the stop is ramped, the partner's not.
        let (t, _) = command_nm(&s, deg(37.5), 0.0, 1.0, 0.5, 3.0);
        assert!((t - 1.0).abs() < 1e-12, "{t}");
    }

    #[test]
    fn out_of_range_names_the_limit_and_the_position() {
        let s = hi5();
        assert_eq!(out_of_range(&s, deg(45.0), 0.0, false), None);
        let high = out_of_range(&s, deg(50.5), 0.0, false).unwrap();
        assert_eq!(
            high.to_string(),
            "the handle at 50.50 deg, beyond rig.range.hard_max_deg = 50 deg"
        );
        let low = out_of_range(&s, deg(-51.0), 0.0, false).unwrap();
        assert!(
            low.to_string().contains("rig.range.hard_min_deg = -50 deg"),
            "{low}"
        );
        let start = out_of_range(&s, deg(41.0), 0.0, true).unwrap();
        assert!(
            start.to_string().contains("starts at 41.00 deg")
                && start.to_string().contains("soft_max_deg"),
            "{start}"
        );
        let fast = out_of_range(&s, deg(10.0), deg(-401.0), false).unwrap();
        assert!(fast.to_string().contains("-401.0 deg/s"), "{fast}");
        assert_eq!(out_of_range(&s, deg(10.0), deg(399.0), false), None);
    }

    /// The handle model (exact zero-order hold, one tick of feedback delay,
    /// as the virtual drive and a bus): a constant push `push_nm` into the
    /// high wall from rest at 35 deg; the largest position reached and the
    /// position after `ticks`.
    fn push_into_wall(s: &RangeSettings, push_nm: f64, limit_nm: f64, ticks: usize) -> (f64, f64) {
        let (mut x, mut v) = (deg(35.0), 0.0);
        let (mut seen_x, mut seen_v) = (x, v);
        let mut peak = x;
        for _ in 0..ticks {
            let wall = wall_torque_nm(s, seen_x, seen_v) + speed_torque_nm(s, seen_v);
            let torque = (push_nm + wall).clamp(-limit_nm, limit_nm);
            (seen_x, seen_v) = (x, v);
            let a = torque / MASS;
            x += v * DT + 0.5 * a * DT * DT;
            v += a * DT;
            peak = peak.max(x);
        }
        (peak, x)
    }

    #[test]
    fn the_wall_holds_a_steady_push_at_its_spring_deflection_and_settles() {
        let s = hi5();
        let k = s.wall_stiffness_nm_per_rad;
        // 1 N m (a person's limit) pushing: rests at 1/K beyond the stop.
        let (peak, end) = push_into_wall(&s, 1.0, 3.0, 3000);
        let rest = s.soft_max_rad + 1.0 / k;
        assert!((end - rest).abs() < 1e-6, "end {end}, rest {rest}");
        // Pushed from rest 5 deg inside the window, the bare handle
        // (no hand on it) reaches the wall at about 7 rad/s; the wall's
        // damping keeps the overshoot past the rest point within 1 deg
        // (0.83 deg on this model).
        assert!(peak - rest < deg(1.0), "peak {peak}, rest {rest}");
        assert!(peak < s.hard_max_rad, "peak {} deg", peak / RAD_PER_DEG);
    }

    #[test]
    fn the_defaults_settle_alike_on_every_plant() {
        for (mass, dt) in [(0.0035, 1e-3), (0.0035, 2e-3), (0.105, 0.1), (6.0, 1e-3)] {
            let (k, b) = default_wall(mass, dt);
            let alone = wall_spectral_radius(mass, k, b, dt);
            let both = wall_spectral_radius(mass, k, 2.0 * b, dt);
            assert!((alone - 0.941).abs() < 1e-3, "{mass} {dt}: {alone}");
            assert!((both - 0.912).abs() < 1e-3, "{mass} {dt}: {both}");
        }
        // Non-finite gains never settle, and never hang the check.
        for bad in [f64::NAN, f64::INFINITY] {
            assert!(wall_spectral_radius(MASS, bad, 0.4, DT) >= 1.0);
            assert!(wall_spectral_radius(MASS, 50.0, bad, DT) >= 1.0);
        }
        // A wall ten times stiffer than the default does not settle.
        let (k, b) = default_wall(MASS, DT);
        assert!(wall_spectral_radius(MASS, 10.0 * k, b, DT) > 1.0);
    }
}
