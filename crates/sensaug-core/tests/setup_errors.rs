//! Set-up errors name the parameter and say how to fix it: the plant's
//! extremes, the estimators' covariances, and a trial's log too large for
//! its memory budget. (The Python corpus, `tests/constructor_corpus.py`,
//! checks every constructor through the binding.)
#![allow(non_snake_case)]

mod common;

use nalgebra::SMatrix;
use sensaug_core::estimator::{EstimatorError, GainEstimator, HandleModel, TrajectoryEstimator};
use sensaug_core::goal::{ChannelConfig, GoalIntegrator, GoalIntegratorConfig};
use sensaug_core::plant::{Plant, PlantError, PlantParams, PlantState};
use sensaug_core::protocol::Protocol;
use sensaug_core::ukf::{Arg, UkfError};
use sensaug_core::world::{check_log_memory, log_budget, log_bytes};
use sensaug_core::{CoreError, ErrorKind};

fn plant(mass: f64, damping: f64, coulomb: f64, dt_s: f64) -> Result<Plant, PlantError> {
    Plant::new(PlantParams {
        mass,
        damping,
        coulomb,
        dt_s,
    })
}

#[test]
fn a_plant_whose_step_would_overflow_is_refused_by_the_parameter() {
    for (params, name) in [
        ((1e-320, 0.0, 0.0, 1e-3), "mass"),       // 1 / M overflows
        ((1e-300, 0.0, 0.0, 1e100), "mass"),      // dt^2 / M overflows
        ((1.0, 0.0, 0.0, 1e160), "dt_s"),         // dt^2 overflows
        ((1.0, 0.0, 0.0, 1e-160), "dt_s"),        // dt^2 underflows
        ((1e-300, 1e300, 0.0, 1e-3), "damping"),  // C dt / M overflows
        ((1e-10, 1e300, 0.0, 1e-100), "damping"), // dt phi1 = M / C underflows
        ((1e-6, 0.0, 1.7e308, 1e-3), "coulomb"),  // the friction's response overflows
    ] {
        let (m, c, fc, dt) = params;
        let e = plant(m, c, fc, dt).unwrap_err();
        assert_eq!(e, PlantError::NonFiniteStep(name), "{params:?}");
        let msg = e.to_string();
        assert!(msg.starts_with(&format!("{name}: ")), "{msg}");
        assert!(msg.contains("; "), "says what to do: {msg}");
    }
    for (name, e) in [
        ("mass", plant(0.0, 0.0, 0.0, 1e-3)),
        ("damping", plant(1.0, -1.0, 0.0, 1e-3)),
        ("coulomb", plant(1.0, 0.0, f64::NAN, 1e-3)),
        ("dt_s", plant(1.0, 0.0, 0.0, f64::INFINITY)),
    ] {
        let e = e.unwrap_err();
        assert_eq!(e, PlantError::InvalidParam(name));
        assert!(e
            .to_string()
            .starts_with(&format!("{name}: must be finite and ")));
    }
    // The Hi5 and the paper's simulation are far from any of this.
    assert!(Plant::new(PlantParams::HI5).is_ok());
    assert!(plant(6.0, 0.0, 0.0, 1e-3).is_ok());
}

#[test]
fn a_step_whose_state_would_overflow_is_refused_and_the_state_kept() {
    let mut p = plant(1e-300, 0.0, 0.0, 1.0).unwrap();
    p.set_state(PlantState { x: 1.0, v: 2.0 });
    assert_eq!(p.step(1e10), Err(PlantError::NonFiniteState));
    assert_eq!(p.state(), PlantState { x: 1.0, v: 2.0 });
    assert!(PlantError::NonFiniteState
        .to_string()
        .starts_with("torque: "));
    assert!(p.step(1e-10).unwrap().x.is_finite());
}

#[test]
fn the_damping_ratio_and_phi2_survive_huge_products() {
    // C dt overflows on its own, s = C dt / M = 1e100 does not (it was inf).
    let z = *plant(1e300, 1e300, 0.0, 1e100).unwrap().zoh();
    assert_eq!(z.decay, 0.0);
    assert!((z.dt_phi1 - 1.0).abs() < 1e-15, "{}", z.dt_phi1);
    assert!((z.dt2_phi2 / 1e100 - 1.0).abs() < 1e-15, "{}", z.dt2_phi2);
    // s = 1e200: s^2 overflows, dt^2 phi2 = dt^2 (1 - 1/s) / s = 1 (it was 0).
    let z = *plant(1.0, 1e100, 0.0, 1e100).unwrap().zoh();
    assert!((z.dt_phi1 / 1e-100 - 1.0).abs() < 1e-15, "{}", z.dt_phi1);
    assert!((z.dt2_phi2 - 1.0).abs() < 1e-15, "{}", z.dt2_phi2);
}

#[test]
fn estimator_covariances_must_be_covariances() {
    let model = common::model();
    let mut cfg = common::extended::<3>();
    cfg.Q[(0, 0)] = -1e-2;
    let e = GainEstimator::new(model, &cfg).unwrap_err();
    assert_eq!(e, EstimatorError::NotPositiveSemidefinite(Arg::Q));
    assert!(e
        .to_string()
        .starts_with("Q: must be positive semidefinite"));

    let mut cfg = common::extended::<5>();
    cfg.R[(0, 1)] = 1e-3;
    let e = TrajectoryEstimator::new(model, &cfg).unwrap_err();
    assert_eq!(e, EstimatorError::NotSymmetric(Arg::R));
    assert_eq!(e.to_string(), "R: must be symmetric; pass (R + R.T) / 2");

    let mut cfg = common::extended::<3>();
    cfg.P0[(5, 0)] = 0.5; // the filter reads one triangle only
    let e = GainEstimator::new(model, &cfg).unwrap_err();
    assert_eq!(e, EstimatorError::NotSymmetric(Arg::P));
    assert!(e.to_string().starts_with("P0: "));

    // Zero variances are fine (positive semidefinite).
    let mut cfg = common::extended::<3>();
    cfg.Q = SMatrix::zeros();
    assert!(GainEstimator::new(model, &cfg).is_ok());

    let goal = GoalIntegratorConfig {
        x0: nalgebra::Vector2::zeros(),
        P0: SMatrix::identity(),
        Q: SMatrix::identity(),
        R_own: -SMatrix::<f64, 2, 2>::identity(),
        channel: ChannelConfig::default(),
    };
    let e = GoalIntegrator::new(model, &goal).unwrap_err();
    assert!(
        e.to_string()
            .starts_with("R: must be positive semidefinite"),
        "{e}"
    );
    // Stage 3's own settings: the target's random walk and the channel's.
    let mut zero_q = goal;
    zero_q.R_own = SMatrix::identity();
    zero_q.Q[(0, 0)] = 0.0;
    let e = GoalIntegrator::new(model, &zero_q).unwrap_err();
    assert!(e.to_string().starts_with("Q: its (0, 0) entry"), "{e}");
    for (field, set) in [
        (
            "gate",
            (|c: &mut ChannelConfig| c.gate = 0.0) as fn(&mut ChannelConfig),
        ),
        ("window_n0", |c| c.window_n0 = f64::NAN),
        ("hold_max_s", |c| c.hold_max_s = -1.0),
    ] {
        let mut bad = goal;
        bad.R_own = SMatrix::identity();
        set(&mut bad.channel);
        let e = GoalIntegrator::new(model, &bad).unwrap_err();
        assert_eq!(e, EstimatorError::InvalidModel(field));
        assert!(
            e.to_string()
                .starts_with(&format!("{field}: must be finite and > 0")),
            "{e}"
        );
    }
}

#[test]
fn an_estimator_model_whose_step_would_overflow_is_refused() {
    for (model, name) in [
        ((1e-320, 0.0, 1e-3), "mass"),
        ((1.0, 0.0, 1e200), "dt_s"),
        ((1e-300, 1e300, 1e-3), "damping"),
    ] {
        let (mass, damping, dt_s) = model;
        let m = HandleModel {
            mass,
            damping,
            dt_s,
        };
        assert_eq!(m.validate(), Err(EstimatorError::InvalidModel(name)));
        let msg = EstimatorError::InvalidModel(name).to_string();
        assert!(msg.starts_with(&format!("{name}: must be finite")), "{msg}");
    }
}

#[test]
fn a_log_over_its_budget_names_the_fields_that_make_it_large() {
    // The finding: 3 phases x 3600 s at dt 1e-4, 362-byte records.
    let mut phases = common::phases(3600.0, 0.0);
    for p in &mut phases {
        p.duration_s = 3600.0;
    }
    let protocol = Protocol::new(&phases, 1e-4).unwrap();
    assert_eq!(log_bytes(&protocol, 362), 39_096_000_000);
    let e = check_log_memory(&protocol, 362, 12_000_000_000).unwrap_err();
    assert_eq!(
        (e.ticks, e.bytes, e.budget),
        (108_000_000, 39_096_000_000, Some(12_000_000_000))
    );
    assert_eq!(
        e.to_string(),
        "phases[*].duration_s, plant.dt_s: 3 phase(s) of 10800 s in all at plant.dt_s = 0.0001 s \
         are 108000000 ticks, whose log needs 39.10 GB of memory, more than the 12.00 GB this \
         trial may take; shorten the phases, raise plant.dt_s, or split the trial into shorter runs"
    );
    assert_eq!(
        check_log_memory(&protocol, 362, 39_096_000_000),
        Ok(39_096_000_000)
    );
    assert_eq!(log_budget(24_000_000_000), 12_000_000_000);
}

#[test]
fn a_predict_with_a_non_finite_input_names_the_inputs_and_changes_nothing() {
    let (mut g, mut t, mut gi) = common::estimators();
    let names = "u, dtau, dtau_h";
    for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        for inputs in [[bad, 0.0, 0.0], [0.0, bad, 0.0], [0.0, 0.0, bad]] {
            let [u, dtau, dtau_h] = inputs;
            let before = (*g.filter().x(), *g.filter().P(), g.filter().recoveries());
            let e = g.predict(u, dtau, dtau_h).unwrap_err();
            assert_eq!(e, UkfError::NonFiniteInput { names });
            assert_eq!(
                before,
                (*g.filter().x(), *g.filter().P(), g.filter().recoveries())
            );
            let e = t.predict(u, dtau, dtau_h).unwrap_err();
            assert_eq!(
                e.to_string(),
                "u, dtau, dtau_h: must be finite; predict not run"
            );
        }
        let before = gi.estimate(true);
        let e = gi.predict(bad, 0.0).unwrap_err();
        assert_eq!(e, UkfError::NonFiniteInput { names: "u, dtau" });
        assert_eq!(gi.predict(0.0, bad).unwrap_err(), e);
        assert_eq!(before, gi.estimate(true));
        assert_eq!(e.kind(), ErrorKind::Argument);
    }
}
