//! Targets against their closed forms, and the protocol's samples of them.
#![allow(non_snake_case)]
mod common;

use sensaug_core::protocol::Protocol;
use sensaug_core::target::{Shape, Target};
use std::f64::consts::PI;

#[test]
fn rounded_square_is_the_papers_cbrt_sine() {
    let s = Shape::RoundedSquare {
        amplitude: 8.0,
        period_s: 4.0,
    };
    for k in 0..4000 {
        let t = k as f64 * 1e-3;
        let want = 8.0 * (0.5 * PI * t).sin().cbrt();
        assert!((s.at(t) - want).abs() <= 1e-12, "t = {t}");
    }
    // real cube root: negative half-wave is negative, not NaN
    assert!(s.at(3.0) < -7.99);
}

#[test]
fn chirp_instantaneous_frequency_sweeps_linearly() {
    let s = Shape::Chirp {
        amplitude: 1.0,
        f0_hz: 0.0,
        f1_hz: 2.0,
        duration_s: 20.0,
    };
    // Two consecutive zero crossings are half a period apart; for a linear
    // chirp that period belongs to the frequency at their midpoint,
    // f(t) = f0 + (f1 - f0) t / T. Crossings are resolved to 1 ms.
    let crossings: Vec<f64> = (1..20_000)
        .map(|k| k as f64 * 1e-3)
        .filter(|&t| s.at(t).signum() != s.at(t + 1e-3).signum())
        .collect();
    for t0 in [5.0, 10.0, 15.0] {
        let i = crossings.iter().position(|&t| t >= t0).unwrap();
        let (a, b) = (crossings[i], crossings[i + 1]);
        let measured = 1.0 / (2.0 * (b - a));
        let want = 2.0 * 0.5 * (a + b) / 20.0;
        assert!(
            (measured - want).abs() < 0.01 * want,
            "t = {t0}: {measured} vs {want}"
        );
    }
}

#[test]
fn square_and_harmonics() {
    let sq = Shape::Square {
        amplitude: 0.1,
        period_s: 2.0,
    };
    assert_eq!(sq.at(0.0), 0.1);
    assert_eq!(sq.at(0.999), 0.1);
    assert_eq!(sq.at(1.0), -0.1);
    assert_eq!(sq.at(2.5), 0.1);
    let h = Shape::Harmonics {
        amplitude: 1e-4,
        omega_rad_s: 1.0,
        harmonics: 3,
        cosine: false,
    };
    let t = 0.7_f64;
    let want = (t.sin() + (2.0 * t).sin() + (3.0 * t).sin()) / 1e4;
    assert!((h.at(t) - want).abs() < 1e-18);
}

#[test]
fn sampled_interpolates_and_holds_ends() {
    let data = [0.0, 1.0, 4.0];
    let s = Shape::Sampled {
        samples: &data,
        dt_s: 0.5,
    };
    assert_eq!(s.at(-1.0), 0.0);
    assert_eq!(s.at(0.25), 0.5);
    assert_eq!(s.at(0.75), 2.5);
    assert_eq!(s.at(10.0), 4.0);
}

#[test]
fn sum_of_parts() {
    let base = Shape::RoundedSquare {
        amplitude: 8.0,
        period_s: 4.0,
    };
    let t = Target::single(base)
        .plus(Shape::Constant { value: 1.0 })
        .unwrap();
    assert!((t.at(1.0) - 9.0).abs() < 1e-12);
    let full = t
        .plus(Shape::Constant { value: 2.0 })
        .unwrap()
        .plus(Shape::Constant { value: 3.0 });
    assert!(full.is_none(), "a fourth part has no slot");
}

#[test]
fn validation_names_part_and_field() {
    let t = Target::single(Shape::Constant { value: 0.0 })
        .plus(Shape::Chirp {
            amplitude: 1.0,
            f0_hz: 0.0,
            f1_hz: 2.0,
            duration_s: 0.0,
        })
        .unwrap();
    let e = t.validate().unwrap_err();
    assert_eq!((e.part, e.field), (1, "duration_s"));
    let empty: [f64; 0] = [];
    let e = Target::single(Shape::Sampled {
        samples: &empty,
        dt_s: 1.0,
    })
    .validate()
    .unwrap_err();
    assert_eq!(e.field, "samples");
}

/// The protocol's samples carry both targets at `t = k dt` and their
/// increments to `(k + 1) dt` exactly as `Target::at` gives them (shared
/// shapes evaluated once, the next tick's values kept), and the in-order
/// samples equal the random-access ones, phase changes included.
#[test]
fn samples_are_the_targets_and_their_increments() {
    let phases = common::phases(0.5, 1.0);
    let dt = common::DT;
    let protocol = Protocol::new(&phases, dt).unwrap();
    let mut ticks = 0;
    for (k, s) in protocol.samples().enumerate() {
        let k = k as u64;
        assert_eq!(Some(s), protocol.sample(k), "tick {k}");
        let p = &phases[s.index];
        let (t, t1) = (k as f64 * dt, (k + 1) as f64 * dt);
        assert_eq!(s.tau, p.robot_target.at(t), "tick {k}");
        assert_eq!(s.tau_h, p.partner_target.at(t), "tick {k}");
        assert_eq!(s.dtau, p.robot_target.at(t1) - s.tau, "tick {k}");
        assert_eq!(s.dtau_h, p.partner_target.at(t1) - s.tau_h, "tick {k}");
        ticks += 1;
    }
    assert_eq!(ticks, protocol.total_ticks());
    assert_eq!(protocol.sample(protocol.total_ticks()), None);
}
