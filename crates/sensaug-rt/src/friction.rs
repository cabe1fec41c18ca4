//! The handle's friction compensation (`rig.friction`, docs/hardware.md,
//! "Calibrating the handle"): the paper models the Hi5 "after Coulomb and
//! viscous friction compensation", so the loop adds the identified friction
//! back to its command before the estimators' frictionless model applies.
//! Torques in N m, velocities in rad/s.

pub use sensaug_config::rig::FrictionSettings;

/// The friction compensation torque (N m) at the measured velocity `v`
/// (rad/s):
///
/// `tau_f = C v + F_c sat(v / v_b)`, `sat(s) = clamp(s, -1, 1)`,
///
/// with `C` = `viscous_nm_s_per_rad`, `F_c` = `coulomb_nm`, `v_b` =
/// `coulomb_band_rad_s`. The saturated ramp is the Coulomb term's smooth
/// sign: continuous (Lipschitz, slope `F_c / v_b`) through zero velocity, so
/// the velocity report's noise near rest moves the torque by at most
/// `F_c noise / v_b` instead of flipping it by `2 F_c` (chatter); and it
/// never exceeds the Coulomb friction it cancels (`|sat| <= 1`, with the
/// sign of `v`), so with `F_c` at most the true friction the compensated
/// handle still loses energy to friction inside the band. A non-finite `v`
/// gives 0 (never a NaN toward the motor); the command's torque guard still
/// clamps the sum at the torque limit.
pub fn compensation_nm(s: &FrictionSettings, v_rad_s: f64) -> f64 {
    if !v_rad_s.is_finite() {
        return 0.0;
    }
    let coulomb_sign = (v_rad_s / s.coulomb_band_rad_s).clamp(-1.0, 1.0);
    s.viscous_nm_s_per_rad * v_rad_s + s.coulomb_nm * coulomb_sign
}

#[cfg(test)]
mod tests {
    use super::*;

    const S: FrictionSettings = FrictionSettings {
        coulomb_nm: 0.02,
        viscous_nm_s_per_rad: 0.01,
        coulomb_band_rad_s: 0.05,
    };

    #[test]
    fn off_by_default_gives_exact_zero() {
        let off = FrictionSettings::new(&sensaug_config::schema::FrictionSpec::default());
        for v in [-3.0, -1e-9, 0.0, 1e-9, 3.0, f64::NAN, f64::INFINITY] {
            assert_eq!(compensation_nm(&off, v), 0.0, "v = {v}");
        }
    }

    #[test]
    fn cancels_coulomb_and_viscous_outside_the_band() {
        for v in [0.05, 0.3, 2.0, -0.05, -0.7] {
            let expected = 0.01 * v + 0.02 * f64::signum(v);
            assert!((compensation_nm(&S, v) - expected).abs() < 1e-15, "v = {v}");
        }
    }

    #[test]
    fn continuous_through_zero_and_never_above_the_friction() {
        // No jump anywhere: neighbouring velocities 1e-6 rad/s apart differ
        // by at most the ramp's slope times the step.
        let slope = S.coulomb_nm / S.coulomb_band_rad_s + S.viscous_nm_s_per_rad;
        let mut prev = compensation_nm(&S, -0.1);
        for i in 1..=200_000 {
            let v = -0.1 + i as f64 * 1e-6;
            let now = compensation_nm(&S, v);
            assert!(
                (now - prev).abs() <= slope * 1e-6 * (1.0 + 1e-9),
                "jump at v = {v}"
            );
            // Never more than the friction it cancels, always with v's sign.
            assert!(now.abs() <= S.coulomb_nm + S.viscous_nm_s_per_rad * v.abs() + 1e-15);
            assert!(now * v >= 0.0);
            prev = now;
        }
        assert_eq!(compensation_nm(&S, 0.0), 0.0);
    }

    #[test]
    fn non_finite_velocity_gives_zero() {
        for v in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            assert_eq!(compensation_nm(&S, v), 0.0);
        }
    }
}
