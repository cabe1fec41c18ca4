//! The handle's friction compensation (`rig.friction`, docs/hardware.md,
//! "Calibrating the handle"): the paper models the Hi5 "after Coulomb and
//! viscous friction compensation", so the loop adds the identified friction
//! back to its command before the estimators' frictionless model applies.
//! Torques in N m, velocities in rad/s.

pub use sensaug_config::rig::FrictionSettings;

/// The friction compensation torque (N m) at the measured velocity `v`
/// (rad/s), the controller and the partner asking `tau` (N m):
///
/// `tau_f = C v + F_c s`, `s = sat(v / v_b) + (1 - |sat(v / v_b)|) sat(tau / tau_b)`,
/// `sat(z) = clamp(z, -1, 1)`,
///
/// with `C` = `viscous_nm_s_per_rad`, `F_c` = `coulomb_nm`, `v_b` =
/// `coulomb_band_rad_s`, `tau_b` = `coulomb_torque_band_nm`. The Coulomb
/// term's sign `s` is the velocity's while the handle moves (beyond `v_b`)
/// and the torque asked for at rest, blended linearly in between: at rest a
/// handle is held by stiction up to `F_c`, which a velocity-only sign never
/// compensates (the handle sticks wherever the asked torque is small);
/// moving, friction opposes the velocity. Both ramps make `s` continuous
/// (Lipschitz) in `v` and `tau`, so the velocity report's noise near rest
/// moves the torque by at most `F_c noise / v_b` instead of flipping it by
/// `2 F_c` (chatter); `|s| <= 1`, so it never exceeds the Coulomb friction
/// it cancels. A non-finite `v` or `tau` gives 0 (never a NaN toward the
/// motor); the command's torque guard still clamps the sum at the torque
/// limit.
pub fn compensation_nm(s: &FrictionSettings, v_rad_s: f64, asked_nm: f64) -> f64 {
    if !(v_rad_s.is_finite() && asked_nm.is_finite()) {
        return 0.0;
    }
    let moving = (v_rad_s / s.coulomb_band_rad_s).clamp(-1.0, 1.0);
    let pushed = (asked_nm / s.coulomb_torque_band_nm).clamp(-1.0, 1.0);
    let sign = moving + (1.0 - moving.abs()) * pushed;
    s.viscous_nm_s_per_rad * v_rad_s + s.coulomb_nm * sign
}

#[cfg(test)]
mod tests {
    use super::*;

    const S: FrictionSettings = FrictionSettings {
        coulomb_nm: 0.02,
        viscous_nm_s_per_rad: 0.01,
        coulomb_band_rad_s: 0.05,
        coulomb_torque_band_nm: 0.005,
    };

    #[test]
    fn off_by_default_gives_exact_zero() {
        let off = FrictionSettings::new(&sensaug_config::schema::FrictionSpec::default());
        for v in [-3.0, -1e-9, 0.0, 1e-9, 3.0, f64::NAN, f64::INFINITY] {
            for asked in [-1.0, 0.0, 1e-9, 0.5] {
                assert_eq!(compensation_nm(&off, v, asked), 0.0, "v = {v}");
            }
        }
    }

    #[test]
    fn cancels_coulomb_and_viscous_outside_the_band() {
        for v in [0.05, 0.3, 2.0, -0.05, -0.7] {
            let expected = 0.01 * v + 0.02 * f64::signum(v);
            // Moving: the velocity's sign whatever the torque asked.
            for asked in [-1.0, 0.0, 1.0] {
                let got = compensation_nm(&S, v, asked);
                assert!((got - expected).abs() < 1e-15, "v = {v}");
            }
        }
    }

    #[test]
    fn continuous_through_zero_and_never_above_the_friction() {
        // No jump anywhere: neighbouring velocities 1e-6 rad/s apart differ
        // by at most the ramps' slope times the step (the asked torque's
        // ramp adds as much again: `1 - |sat|` changes at the same rate).
        let slope = 2.0 * S.coulomb_nm / S.coulomb_band_rad_s + S.viscous_nm_s_per_rad;
        for asked in [-0.01, -0.001, 0.0, 0.002, 0.01] {
            let mut prev = compensation_nm(&S, -0.1, asked);
            for i in 1..=200_000 {
                let v = -0.1 + i as f64 * 1e-6;
                let now = compensation_nm(&S, v, asked);
                assert!(
                    (now - prev).abs() <= slope * 1e-6 * (1.0 + 1e-9),
                    "jump at v = {v}"
                );
                // Never more than the friction it cancels.
                assert!(now.abs() <= S.coulomb_nm + S.viscous_nm_s_per_rad * v.abs() + 1e-15);
                prev = now;
            }
        }
        // At rest: the asked torque's direction, ramped over its band.
        assert_eq!(compensation_nm(&S, 0.0, 0.0), 0.0);
        assert_eq!(compensation_nm(&S, 0.0, 0.01), 0.02);
        assert_eq!(compensation_nm(&S, 0.0, -0.01), -0.02);
        assert!((compensation_nm(&S, 0.0, 0.0025) - 0.01).abs() < 1e-15);
        // Moving beyond the band: the velocity's direction, not the torque's.
        assert!(compensation_nm(&S, 0.06, -0.5) > 0.0);
    }

    #[test]
    fn non_finite_velocity_or_torque_gives_zero() {
        for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            assert_eq!(compensation_nm(&S, bad, 0.01), 0.0);
            assert_eq!(compensation_nm(&S, 0.3, bad), 0.0);
        }
    }
}
