//! Why the loop gives the drive's rounding to the robot (`drive_torque`;
//! docs/cia402.md, "The Lhh difference between the profiles"), in a
//! noise-free simulation of the rig's arithmetic: the handle receives the
//! drive's torque, the robot's estimators predict with the torque each
//! variant gives them. Quantising the virtual human's torque alone moves the
//! estimated Lhh off the exact run's; giving the rounding of the sum to the
//! robot (the loop's `drive_torque`) leaves it where the exact run has it.
//! Deterministic: the thresholds are not timing margins.

use sensaug_config::{load_str, Format};
use sensaug_core::agent::VirtualHuman;
use sensaug_core::controller::applied_torque;
use sensaug_core::plant::Plant;
use sensaug_core::row::Row;
use sensaug_rt::control::drive_torque;

#[path = "common/trial.rs"]
mod trial;

use trial::CONFIG;

/// The CiA 402 drive's default step: one per-mille of 1 N m (N m).
const STEP_NM: f64 = 1e-3;

#[derive(Clone, Copy, Debug)]
enum Rounding {
    /// No drive step.
    Exact,
    /// Only the virtual human's torque rounded (the mechanism, alone).
    PartnerOnly,
    /// The loop before: the robot's command rounded (and predicted with),
    /// the drive rounding the sum, `u + round(u_h)`.
    RobotCommand,
    /// The loop now: the sum rounded, the rounding the robot's.
    Sum,
}

/// The robot's Lhh estimate (its stage-2 pseudo-measurement) after the run.
fn estimated_lhh(rounding: Rounding, lhh: f64) -> f64 {
    let resolved = load_str(CONFIG, Format::Toml).unwrap();
    let protocol = resolved.protocol().unwrap();
    let mut robot = resolved.controller().unwrap();
    let partner = VirtualHuman::new([0.0, 0.0, lhh], 1e3).unwrap();
    let mut plant = Plant::new(resolved.rig.plant).unwrap();
    let unit = resolved.rad_per_unit;
    let limit_nm = 3.0;
    let round = |t: f64| applied_torque(t * unit, STEP_NM, limit_nm) / unit;
    for sample in protocol.samples() {
        let s = plant.state();
        let mut row = Row::UNKNOWN;
        let decision = robot.decide(&sample, Some((s.x, s.v)), &mut row);
        let (u_h, _) = partner.torque(s.x, s.v, sample.tau, sample.tau_h);
        let (predicted, handle) = match rounding {
            Rounding::Exact => (decision.u, decision.u + u_h),
            Rounding::PartnerOnly => (decision.u, decision.u + round(u_h)),
            Rounding::RobotCommand => {
                let u = round(decision.u);
                (u, round(u + u_h))
            }
            Rounding::Sum => {
                let asked_nm = (decision.u + u_h) * unit;
                let (sent_nm, u) = drive_torque(asked_nm, decision.u, STEP_NM, limit_nm, unit);
                (u, sent_nm / unit)
            }
        };
        robot.predict(decision, predicted);
        plant.step(handle).unwrap();
    }
    robot.pseudo_gains()[2]
}

#[test]
fn rounding_the_partners_torque_moves_lhh_and_the_loops_rounding_does_not() {
    for lhh in [2.0, 1.0, 0.5] {
        let exact = estimated_lhh(Rounding::Exact, lhh);
        let shift = |r| estimated_lhh(r, lhh) - exact;
        let (partner, before, now) = (
            shift(Rounding::PartnerOnly),
            shift(Rounding::RobotCommand),
            shift(Rounding::Sum),
        );
        println!(
            "Lhh {lhh}: exact {exact:.4}; minus exact: partner's torque rounded {partner:+.4}, \
             the robot's command rounded {before:+.4}, the sum's rounding the robot's {now:+.4}"
        );
        assert!((exact - lhh).abs() < 0.005, "{exact}");
        assert!(now.abs() < 5e-4, "Lhh {lhh}: {now:+.5}");
        if lhh >= 1.0 {
            // The mechanism: ten times what the loop's rounding leaves.
            assert!(
                partner.abs() > 5e-3 && before.abs() > 5e-3,
                "{partner} {before}"
            );
        }
    }
}
