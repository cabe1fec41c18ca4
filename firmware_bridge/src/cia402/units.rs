//! Units of the CiA 402 profile, converted in one place.
//!
//! - Torque (0x6071 target, 0x6072 max, 0x6077 actual) is an integer in
//!   per-mille of the motor rated torque 0x6076, which is in mN m. One step
//!   is `rated / 1000`: with the virtual drive's 1000 mN m, **1 mN m**, where
//!   the Hi5 protocol's TorqueCommand has 1 uN m steps (docs/cia402.md
//!   works out what this means for the Hi5 experiment).
//! - Position 0x6064 is in encoder increments, velocity 0x606C in
//!   increments per second. 0x608F gives `increments` per `motor_revs`
//!   motor revolutions, 0x6091 `gear_motor_revs` motor revolutions per
//!   `gear_shaft_revs` shaft (handle) revolutions.

use core::f64::consts::TAU;

use super::Cia402Error;

/// The drive's unit parameters, read from it by SDO at set-up.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Units {
    /// 0x6076, mN m.
    pub rated_torque_mnm: u32,
    /// 0x6072, per-mille of rated torque.
    pub max_torque_per_mille: u16,
    /// 0x608F:01.
    pub encoder_increments: u32,
    /// 0x608F:02.
    pub encoder_motor_revs: u32,
    /// 0x6091:01.
    pub gear_motor_revs: u32,
    /// 0x6091:02.
    pub gear_shaft_revs: u32,
    rad_per_increment: f64,
}

impl Units {
    /// Checks that every parameter is non-zero.
    pub fn new(
        rated_torque_mnm: u32,
        max_torque_per_mille: u16,
        encoder: (u32, u32),
        gear: (u32, u32),
    ) -> Result<Self, Cia402Error> {
        let fields = [
            ("0x6076 rated torque", rated_torque_mnm),
            ("0x6072 max torque", u32::from(max_torque_per_mille)),
            ("0x608F:01 encoder increments", encoder.0),
            ("0x608F:02 motor revolutions", encoder.1),
            ("0x6091:01 motor revolutions", gear.0),
            ("0x6091:02 shaft revolutions", gear.1),
        ];
        for (field, v) in fields {
            if v == 0 {
                return Err(Cia402Error::BadParameter {
                    field,
                    value: 0,
                    why: "must be > 0",
                });
            }
        }
        Ok(Self {
            rated_torque_mnm,
            max_torque_per_mille,
            encoder_increments: encoder.0,
            encoder_motor_revs: encoder.1,
            gear_motor_revs: gear.0,
            gear_shaft_revs: gear.1,
            rad_per_increment: rad_per_increment(encoder, gear),
        })
    }

    /// The virtual drive's EDS defaults: 1000 mN m rated, 3000 per-mille
    /// max (3 N m), 2^20 increments per revolution, gear 1:1.
    pub fn eds_defaults() -> Self {
        Self {
            rated_torque_mnm: 1000,
            max_torque_per_mille: 3000,
            encoder_increments: 1 << 20,
            encoder_motor_revs: 1,
            gear_motor_revs: 1,
            gear_shaft_revs: 1,
            rad_per_increment: rad_per_increment((1 << 20, 1), (1, 1)),
        }
    }

    /// One torque step, N m: `rated_mNm / 1000 / 1000`.
    pub fn torque_step_nm(&self) -> f64 {
        f64::from(self.rated_torque_mnm) * 1e-6
    }

    /// The largest torque the drive accepts, N m.
    pub fn max_torque_nm(&self) -> f64 {
        f64::from(self.max_torque_per_mille) * self.torque_step_nm()
    }

    /// `t_pm = round_ties_even(torque_nm / (rated_mNm 1e-6))`, refused
    /// (never clamped) when not finite or beyond max torque 0x6072.
    pub fn torque_to_per_mille(&self, torque_nm: f64) -> Result<i16, Cia402Error> {
        if !torque_nm.is_finite() {
            return Err(Cia402Error::NotFinite {
                field: "target torque",
            });
        }
        let raw = (torque_nm / self.torque_step_nm()).round_ties_even();
        if raw.abs() > f64::from(self.max_torque_per_mille) {
            return Err(Cia402Error::TorqueBeyondLimit {
                torque_nm,
                max_nm: self.max_torque_nm(),
            });
        }
        // |raw| <= u16 max torque and <= i16::MAX (checked against 0x6072,
        // itself refused above 32767 by `Master` set-up).
        Ok(raw as i16)
    }

    /// 0x6072 with the sign of `torque_nm`: the command a torque beyond
    /// the limit is clamped to.
    pub fn max_torque_per_mille_signed(&self, torque_nm: f64) -> i16 {
        // 0x6072 <= 32767: `Master` set-up refuses larger values.
        let max = self.max_torque_per_mille.min(i16::MAX as u16) as i16;
        if torque_nm < 0.0 {
            -max
        } else {
            max
        }
    }

    /// `tau = t_pm rated_mNm 1e-6`.
    pub fn per_mille_to_torque_nm(&self, per_mille: i16) -> f64 {
        f64::from(per_mille) * self.torque_step_nm()
    }

    /// One increment in shaft radians:
    /// `2 pi encoder_motor_revs / encoder_increments * gear_shaft / gear_motor`.
    pub fn position_step_rad(&self) -> f64 {
        self.rad_per_increment
    }

    /// `x = increments * position_step_rad`.
    pub fn increments_to_rad(&self, increments: i32) -> f64 {
        f64::from(increments) * self.rad_per_increment
    }

    /// `v = increments_per_s * position_step_rad`.
    pub fn increments_per_s_to_rad_s(&self, increments_per_s: i32) -> f64 {
        f64::from(increments_per_s) * self.rad_per_increment
    }
}

/// `2 pi (motor revs per increment) (shaft revs per motor rev)`.
fn rad_per_increment(encoder: (u32, u32), gear: (u32, u32)) -> f64 {
    TAU * f64::from(encoder.1) / f64::from(encoder.0) * f64::from(gear.1) / f64::from(gear.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn torque_round_trip_rounding_and_refusals() {
        let u = Units::eds_defaults();
        assert_eq!(u.torque_step_nm(), 1e-3);
        assert_eq!(u.torque_to_per_mille(0.1234).unwrap(), 123);
        assert_eq!(u.torque_to_per_mille(-0.0025).unwrap(), -2); // ties to even
        assert_eq!(u.torque_to_per_mille(3.0).unwrap(), 3000);
        assert_eq!(u.per_mille_to_torque_nm(-1500), -1.5);
        assert!(matches!(
            u.torque_to_per_mille(3.001),
            Err(Cia402Error::TorqueBeyondLimit { .. })
        ));
        assert!(matches!(
            u.torque_to_per_mille(f64::NAN),
            Err(Cia402Error::NotFinite { .. })
        ));
        assert!(Units::new(0, 3000, (1, 1), (1, 1)).is_err());
    }

    #[test]
    fn increments_to_radians_with_gear() {
        let u = Units::eds_defaults();
        assert!((u.increments_to_rad(1 << 20) - TAU).abs() < 1e-12);
        let g = Units::new(1000, 3000, (4096, 1), (10, 1)).unwrap();
        // 10 motor revolutions per shaft revolution.
        assert!((g.increments_to_rad(40960) - TAU).abs() < 1e-12);
        assert!((g.increments_per_s_to_rad_s(-4096) + TAU / 10.0).abs() < 1e-12);
    }
}
