//! Batch replay (`sensaug_core::replay`): the same numbers as stepping by
//! hand in the estimators' order, every shape error before anything runs,
//! step errors counted without stopping.
#![allow(non_snake_case)]

mod common;

use nalgebra::{Vector2, Vector3};
use sensaug_core::estimator::GainEstimator;
use sensaug_core::goal::GoalIntegrator;
use sensaug_core::plant::{Plant, PlantParams};
use sensaug_core::replay::{
    replay, simulate, GoalReplay, Posteriors, Recording, Replay, ReplayArg, ReplayError,
};
use sensaug_core::ukf::{Phase, RunReport, StepError, UkfError};

const T: usize = 300;

/// A deterministic recording: `y` rows of 3, torques, both increments.
fn recording() -> (Vec<f64>, Vec<f64>, Vec<f64>, Vec<f64>) {
    let s = |k: usize| (k as f64 * 7e-3).sin();
    let y = (0..T)
        .flat_map(|k| [0.01 * s(k), 0.1 * s(k + 50), 0.012 * s(k + 3)])
        .collect();
    let u = (0..T).map(|k| 0.02 * s(2 * k)).collect();
    let dtau = (0..T).map(|k| 1e-4 * s(k + 9)).collect();
    let dtau_h = (0..T).map(|k| 1e-4 * s(k + 20)).collect();
    (y, u, dtau, dtau_h)
}

/// Replays a whole recording through `g`; returns the report and the outputs.
fn replay_gain(
    g: &mut GainEstimator,
    y: &[f64],
    u: &[f64],
    dtau: &[f64],
    dtau_h: &[f64],
) -> (RunReport, Vec<f64>, Vec<f64>) {
    let (mut xs, mut var) = (vec![0.0; 6 * T], vec![0.0; 6 * T]);
    let rec = Recording {
        y,
        u,
        dtau: Some(dtau),
        dtau_h: Some(dtau_h),
    };
    let mut out = Posteriors {
        x: &mut xs,
        var: &mut var,
    };
    let report = replay(g, &rec, &mut out).unwrap();
    (report, xs, var)
}

#[test]
fn gain_replay_equals_stepping_update_then_predict() {
    let (y, u, dtau, dtau_h) = recording();
    let model = common::model();
    let mut batch = GainEstimator::new(model, &common::extended::<3>()).unwrap();
    let mut step = batch.clone();
    let (report, xs, var) = replay_gain(&mut batch, &y, &u, &dtau, &dtau_h);
    assert_eq!(
        (report.steps, report.errors, report.first_error),
        (T, 0, None)
    );
    for k in 0..T {
        let _ = step.update(&Vector3::from_column_slice(&y[3 * k..3 * k + 3]));
        for i in 0..6 {
            assert_eq!(xs[6 * k + i], step.filter().x()[i], "x[{k}][{i}]");
            assert_eq!(var[6 * k + i], step.filter().P()[(i, i)], "var[{k}][{i}]");
        }
        let _ = step.predict(u[k], dtau[k], dtau_h[k]);
    }
    assert_eq!(
        batch.filter().x(),
        step.filter().x(),
        "the last predict ran too"
    );
}

#[test]
fn goal_replay_equals_stepping_with_and_without_the_partner_channel() {
    let (y, u, dtau, _) = recording();
    let model = common::model();
    for with_channel in [false, true] {
        let mut gi = GoalIntegrator::new(model, &common::robot().stage3).unwrap();
        let mut step = gi.clone();
        let m = if with_channel { 3 } else { 2 };
        let y: Vec<f64> = y.chunks(3).flat_map(|r| r[..m].to_vec()).collect();
        let (mut xs, mut var) = (vec![0.0; 2 * T], vec![0.0; 2 * T]);
        let rec = Recording {
            y: &y,
            u: &u,
            dtau: Some(&dtau),
            dtau_h: None,
        };
        let mut out = Posteriors {
            x: &mut xs,
            var: &mut var,
        };
        let mut r = GoalReplay::new(&mut gi, with_channel);
        assert_eq!(replay(&mut r, &rec, &mut out).unwrap().errors, 0);
        for k in 0..T {
            let row = &y[m * k..m * (k + 1)];
            let _ = step.update(&Vector2::new(row[0], row[1]), with_channel.then(|| row[2]));
            assert_eq!(&xs[2 * k..2 * k + 2], step.estimate(true).as_slice());
            assert_eq!(&var[2 * k..2 * k + 2], step.variance(true).as_slice());
            let _ = step.predict(u[k], dtau[k]);
        }
    }
}

#[test]
fn shape_errors_name_the_slice_and_nothing_runs() {
    let (y, u, dtau, dtau_h) = recording();
    let model = common::model();
    let mut g = GainEstimator::new(model, &common::extended::<3>()).unwrap();
    let (mut xs, mut var) = (vec![0.0; 6 * T], vec![0.0; 6 * T]);
    let len = |which, needed, got| Err(ReplayError::Length { which, needed, got });
    let full = Recording {
        y: &y,
        u: &u,
        dtau: Some(&dtau),
        dtau_h: Some(&dtau_h),
    };
    let cases = [
        (
            Recording { y: &y[1..], ..full },
            len(ReplayArg::Y, 3 * T, 3 * T - 1),
        ),
        (
            Recording {
                dtau: Some(&dtau[1..]),
                ..full
            },
            len(ReplayArg::Dtau, T, T - 1),
        ),
        (
            Recording {
                dtau_h: Some(&dtau_h[2..]),
                ..full
            },
            len(ReplayArg::DtauH, T, T - 2),
        ),
    ];
    for (rec, expected) in cases {
        let mut out = Posteriors {
            x: &mut xs,
            var: &mut var,
        };
        assert_eq!(replay(&mut g, &rec, &mut out), expected);
    }
    let mut out = Posteriors {
        x: &mut xs[1..],
        var: &mut var,
    };
    assert_eq!(
        replay(&mut g, &full, &mut out),
        len(ReplayArg::Xs, 6 * T, 6 * T - 1)
    );
    let mut out = Posteriors {
        x: &mut xs,
        var: &mut var[..6],
    };
    assert_eq!(
        replay(&mut g, &full, &mut out),
        len(ReplayArg::Pdiag, 6 * T, 6)
    );
    assert_eq!(g.filter().recoveries().updates, 0, "nothing ran");

    let mut gi = GoalIntegrator::new(model, &common::robot().stage3).unwrap();
    let mut r = GoalReplay::new(&mut gi, true);
    let mut out = Posteriors {
        x: &mut xs[..2 * T],
        var: &mut var[..2 * T],
    };
    assert_eq!(
        replay(&mut r, &full, &mut out),
        Err(ReplayError::NotRead {
            which: ReplayArg::DtauH
        })
    );
    assert_eq!(ReplayArg::DtauH.name(), "dtau_h");
    for (columns, with_channel) in [(2, false), (3, true)] {
        let r = GoalReplay::for_columns(&mut gi, columns).unwrap();
        assert_eq!(r.measurement_len(), 2 + usize::from(with_channel));
    }
    let four = GoalReplay::for_columns(&mut gi, 4).map(|_| ()).unwrap_err();
    assert_eq!(four, ReplayError::GoalColumns { got: 4 });
    assert!(
        four.to_string().starts_with("y: expected 2 entries"),
        "{four}"
    );
}

#[test]
fn step_errors_are_counted_and_the_replay_goes_on() {
    let (mut y, u, dtau, dtau_h) = recording();
    y[3 * 100 + 1] = f64::NAN;
    y[3 * 200] = f64::INFINITY;
    let mut g = GainEstimator::new(common::model(), &common::extended::<3>()).unwrap();
    let (report, xs, var) = replay_gain(&mut g, &y, &u, &dtau, &dtau_h);
    assert_eq!(report.errors, 2);
    let first = StepError {
        step: 100,
        phase: Phase::Update,
        error: UkfError::NonFiniteMeasurement,
    };
    assert_eq!(report.first_error, Some(first));
    assert_eq!(g.filter().recoveries().updates, T as u64 - 2);
    assert!(xs.iter().chain(&var).all(|v| v.is_finite()));
}

#[test]
fn simulate_equals_stepping_and_rejects_a_bad_torque_up_front() {
    let params = PlantParams {
        mass: 0.0035,
        damping: 0.01,
        coulomb: 0.002,
        dt_s: 1e-3,
    };
    let mut batch = Plant::new(params).unwrap();
    let mut step = batch;
    let torques: Vec<f64> = (0..T).map(|k| 0.01 * (k as f64 * 1e-2).sin()).collect();
    let (mut xs, mut vs) = (vec![0.0; T], vec![0.0; T]);
    simulate(&mut batch, &torques, &mut xs, &mut vs).unwrap();
    for k in 0..T {
        let s = step.step(torques[k]).unwrap();
        assert_eq!((xs[k], vs[k]), (s.x, s.v));
    }
    let before = batch.state();
    let mut bad = torques.clone();
    bad[7] = f64::NAN;
    assert_eq!(
        simulate(&mut batch, &bad, &mut xs, &mut vs),
        Err(ReplayError::NonFinite {
            which: ReplayArg::Torques,
            step: 7
        })
    );
    assert_eq!(batch.state(), before, "nothing was stepped");
}
