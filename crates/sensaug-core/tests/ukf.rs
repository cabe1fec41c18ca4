//! UKF properties: linear-model equivalence with a closed-form Kalman filter,
//! weights, sigma point moments, every error variant, the recovery policy,
//! and "no state change" on rejected calls.
#![allow(non_snake_case)]

use nalgebra::{Matrix2, SMatrix, SVector, Vector1, Vector2};
#[path = "common/pendulum.rs"]
mod pendulum;
use pendulum::{DemoUkf, Pendulum};
use sensaug_core::ukf::{
    merwe_weights, scaled_cholesky, sigma_points, unscented_covariance, unscented_mean, Arg,
    BilinearForm, BilinearProcess, MerweParams, Phase, Selection, Stage, Status, Ukf, UkfError,
};

type Lin = Ukf<2, 1, 5>;

const DT: f64 = 0.01;

fn F() -> Matrix2<f64> {
    Matrix2::new(1.0, DT, -0.2 * DT, 1.0 - 0.05 * DT)
}
fn B() -> Vector2<f64> {
    Vector2::new(0.0, DT)
}
fn H() -> SMatrix<f64, 1, 2> {
    SMatrix::<f64, 1, 2>::new(1.0, 0.5)
}
fn Q() -> Matrix2<f64> {
    Matrix2::new(1e-4, 2e-5, 2e-5, 3e-4)
}
fn R() -> SMatrix<f64, 1, 1> {
    SMatrix::<f64, 1, 1>::new(0.04)
}
fn P0() -> Matrix2<f64> {
    Matrix2::new(0.5, 0.1, 0.1, 0.3)
}
fn x0() -> Vector2<f64> {
    Vector2::new(0.2, -0.1)
}
/// The sigma-point parameters (alpha, beta, kappa) the special predicts are
/// compared with the unscented one at: the paper's, a kappa > 0, a small
/// alpha with beta 0.
const PREDICT_PARAMS: [(f64, f64, f64); 3] = [(1.0, 2.0, 0.0), (0.5, 2.0, 1.0), (0.1, 0.0, 0.0)];

fn params(alpha: f64, beta: f64, kappa: f64) -> MerweParams {
    MerweParams { alpha, beta, kappa }
}
fn lin(p: MerweParams) -> Lin {
    Lin::new(x0(), P0(), Q(), R(), p).expect("valid linear filter")
}

/// Deterministic pseudo-measurements (no RNG dependency).
fn z_at(k: usize) -> f64 {
    let t = k as f64 * DT;
    libm::sin(3.0 * t) + 0.1 * libm::cos(17.0 * t + 0.3)
}
fn u_at(k: usize) -> f64 {
    libm::cos(2.0 * k as f64 * DT)
}

fn max_abs<const R: usize, const C: usize>(A: &SMatrix<f64, R, C>) -> f64 {
    A.iter().fold(0.0, |m, v| m.max(v.abs()))
}

#[test]
fn weights_sum_exactly() {
    for p in [
        params(1.0, 2.0, 0.0),
        params(0.1, 2.0, 1.0),
        params(1e-3, 2.0, 0.0),
        params(0.5, 0.0, -1.0),
    ] {
        let (Wm, Wc) = merwe_weights::<7>(3, &p);
        let sm: f64 = Wm.iter().sum();
        let sc: f64 = Wc.iter().sum();
        // Wm sums to 1; Wc sums to 1 + (1 - alpha^2 + beta). Relative to the
        // largest weight (|Wm_0| ~ 1/alpha^2 for small alpha).
        let scale = Wm.iter().fold(1.0f64, |m, v| m.max(v.abs()));
        assert!(
            (sm - 1.0).abs() <= 4.0 * f64::EPSILON * scale,
            "sum Wm = {sm}, scale {scale}"
        );
        let want = 2.0 - p.alpha * p.alpha + p.beta;
        assert!(
            (sc - want).abs() <= 4.0 * f64::EPSILON * scale.max(want.abs()),
            "sum Wc = {sc}, want {want}"
        );
    }
}

#[test]
fn sigma_points_reconstruct_mean_and_covariance() {
    let x = SVector::<f64, 3>::new(0.3, -1.2, 4.0);
    let P = SMatrix::<f64, 3, 3>::new(2.0, 0.3, -0.1, 0.3, 1.0, 0.2, -0.1, 0.2, 0.5);
    for p in [
        params(1.0, 2.0, 0.0),
        params(0.3, 2.0, 0.0),
        params(0.5, 0.0, 2.0),
    ] {
        let (Wm, Wc) = merwe_weights::<7>(3, &p);
        let c = sensaug_core::ukf::merwe_lambda(3, &p) + 3.0;
        let L = scaled_cholesky(&P, c).expect("P is positive definite");
        let chi = sigma_points::<3, 7>(&x, &L);
        let mean = unscented_mean(&Wm, &chi);
        let zero = SMatrix::<f64, 3, 3>::zeros();
        let cov = unscented_covariance(&Wc, &chi, &x, &zero);
        let dm = max_abs(&(mean - x));
        let dP = max_abs(&(cov - P));
        assert!(dm <= 1e-13 / (p.alpha * p.alpha), "mean off by {dm}");
        assert!(dP <= 1e-14, "covariance off by {dP}");
    }
}

/// Closed-form linear Kalman filter, one predict + update.
fn kf_step(x: &mut Vector2<f64>, P: &mut Matrix2<f64>, u: f64, z: f64) {
    // x- = F x + B u ; P- = F P F' + Q
    *x = F() * *x + B() * u;
    *P = F() * *P * F().transpose() + Q();
    // S = H P- H' + R ; K = P- H' S^-1
    let S = H() * *P * H().transpose() + R();
    let K = *P * H().transpose() / S[(0, 0)];
    // x+ = x- + K (z - H x-) ; P+ = P- - K S K'
    let y = z - (H() * *x)[(0, 0)];
    *x += K * y;
    *P -= K * S * K.transpose();
}

#[test]
fn equals_linear_kalman_filter() {
    for p in [
        params(1.0, 2.0, 0.0),
        params(0.5, 2.0, 1.0),
        params(0.1, 2.0, 0.0),
    ] {
        let mut ukf = lin(p);
        let (mut x, mut P) = (x0(), P0());
        let (mut worst_x, mut worst_P) = (0.0f64, 0.0f64);
        for k in 0..2000 {
            let (u, z) = (u_at(k), z_at(k));
            let st = ukf.predict(|s| F() * s + B() * u).expect("predict");
            assert_eq!(st, Status::Nominal);
            let st = ukf.update(&Vector1::new(z), |s| H() * s).expect("update");
            assert_eq!(st, Status::Nominal);
            kf_step(&mut x, &mut P, u, z);
            worst_x = worst_x.max(max_abs(&(ukf.x() - x)) / max_abs(&x).max(1.0));
            worst_P = worst_P.max(max_abs(&(ukf.P() - P)) / max_abs(&P));
        }
        eprintln!(
            "alpha {}: max rel diff x {worst_x:.2e}, P {worst_P:.2e}",
            p.alpha
        );
        // Cancellation in Wm_0 ~ 1 - n / alpha^2 costs ~1/alpha^2 ulps.
        let tol = 1e-12 / (p.alpha * p.alpha);
        assert!(
            worst_x <= tol && worst_P <= tol,
            "alpha {}: x rel {worst_x:e}, P rel {worst_P:e}, tol {tol:e}",
            p.alpha
        );
        assert_eq!(ukf.recoveries().predicts, 2000);
        assert_eq!(ukf.recoveries().updates, 2000);
    }
}

/// The closed-form update for selections against the sigma-point update on
/// the same filter: a nonlinear 3-state process (so `P` is not that of a
/// linear filter), measurements of entries 2 and 0 (index order and a
/// skipped entry exercised), 2000 steps, and an update before any predict.
#[test]
fn selection_update_equals_sigma_point_update() {
    type F3 = Ukf<3, 2, 7>;
    let sel = Selection::<3, 2>::new([2, 0]).expect("indices < 3");
    assert!(Selection::<3, 2>::new([0, 3]).is_none());
    let f = |s: &SVector<f64, 3>, u: f64| {
        SVector::<f64, 3>::new(
            s[0] + DT * s[1],
            s[1] + DT * (u - libm::sin(s[0]) - 0.1 * s[1] * s[2]),
            s[2],
        )
    };
    let h = |s: &SVector<f64, 3>| Vector2::new(s[2], s[0]);
    for p in [params(1.0, 2.0, 0.0), params(0.5, 2.0, 1.0)] {
        let P0 = SMatrix::<f64, 3, 3>::new(0.3, 0.05, 0.0, 0.05, 0.2, 0.01, 0.0, 0.01, 0.5);
        let x0 = SVector::<f64, 3>::new(0.2, 0.0, 1.0);
        let Q = SMatrix::<f64, 3, 3>::identity() * 1e-5;
        let R = Matrix2::new(1e-3, 0.0, 0.0, 2e-3);
        let mut a = F3::new(x0, P0, Q, R, p).expect("valid");
        let mut b = a.clone();
        let z0 = Vector2::new(0.9, 0.25);
        assert_eq!(a.update(&z0, h), b.update_selected(&z0, &sel));
        let mut worst = 0.0f64;
        for k in 0..2000 {
            let (u, z) = (u_at(k), Vector2::new(1.0 + 0.1 * z_at(k), z_at(k)));
            assert_eq!(a.predict(|s| f(s, u)), b.predict(|s| f(s, u)));
            assert_eq!(a.update(&z, h), Ok(Status::Nominal));
            assert_eq!(b.update_selected(&z, &sel), Ok(Status::Nominal));
            worst = worst
                .max(max_abs(&(a.x() - b.x())) / max_abs(a.x()))
                .max(max_abs(&(a.P() - b.P())) / max_abs(a.P()));
        }
        eprintln!(
            "alpha {}: selection vs sigma points, max rel diff {worst:.2e}",
            p.alpha
        );
        assert!(worst <= 1e-12, "alpha {}: rel diff {worst:e}", p.alpha);
        assert_eq!(a.recoveries(), b.recoveries());
    }
}

/// A 4-state process whose last two states are constant parameters of the
/// first two (as the estimators' gains are), with one bilinear term:
/// `s0' = s0 + DT s1`, `s1' = s1 + DT (u - s2 s0 - s3 s1)`.
type F4 = Ukf<4, 1, 9>;

fn process4(u: f64) -> BilinearProcess<4, 2, 2> {
    BilinearProcess {
        F: SMatrix::<f64, 2, 4>::new(1.0, DT, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0),
        b: Vector2::new(0.0, DT * u),
        g: Vector2::new(0.0, -DT),
        q: BilinearForm::new([(2, 0), (3, 1)]).expect("indices < 4"),
    }
}

/// A second shape of bilinear process: a square term, a pair of two
/// constant states, the term entering both moving rows.
fn process4_square(u: f64) -> BilinearProcess<4, 2, 2> {
    BilinearProcess {
        F: SMatrix::<f64, 2, 4>::new(0.98, DT, 0.01, 0.0, -0.3 * DT, 1.0, 0.0, 0.02),
        b: Vector2::new(0.001 * u, DT * u),
        g: Vector2::new(0.5 * DT, -DT),
        q: BilinearForm::new([(0, 0), (2, 3)]).expect("indices < 4"),
    }
}

fn P0_4() -> SMatrix<f64, 4, 4> {
    SMatrix::<f64, 4, 4>::from_diagonal(&SVector::<f64, 4>::new(0.1, 0.1, 1.0, 0.5))
}

/// The filter of [`process4`], measuring the first state.
fn filter4(p: MerweParams) -> F4 {
    let x0 = SVector::<f64, 4>::new(0.3, 0.0, 2.0, 0.5);
    let mut Q = SMatrix::<f64, 4, 4>::identity() * 1e-4;
    Q[(0, 2)] = 2e-5;
    Q[(2, 0)] = 2e-5;
    F4::new(x0, P0_4(), Q, SMatrix::<f64, 1, 1>::new(1e-3), p).expect("valid")
}

/// `BilinearForm` evaluates `sum_j z[a_j] z[b_j]` and its gradient; a bad
/// index is refused.
#[test]
fn bilinear_form_value_and_gradient() {
    let q = BilinearForm::<4, 3>::new([(2, 0), (3, 1), (1, 1)]).expect("indices < 4");
    let z = SVector::<f64, 4>::new(0.5, -2.0, 3.0, 7.0);
    assert_eq!(q.eval(&z), 3.0 * 0.5 + 7.0 * -2.0 + 4.0);
    assert_eq!(
        q.gradient(&z),
        SVector::<f64, 4>::new(3.0, 7.0 + 2.0 * -2.0, 0.5, -2.0)
    );
    assert_eq!(BilinearForm::<4, 1>::new([(0, 4)]), None);
    assert_eq!(BilinearForm::<4, 1>::new([(4, 0)]), None);
}

/// `predict_bilinear` (the unscented transform of a bilinear process in
/// closed form) against `predict` on its sigma points with the full
/// process, for two shapes of process and three sigma-point settings, over
/// 2000 steps with updates in between: each step from the same filter
/// (the closed form's own rounding), and the two filters run side by side
/// (how that rounding accumulates).
#[test]
fn bilinear_predict_equals_full_predict() {
    let h = |s: &SVector<f64, 4>| Vector1::new(s[0]);
    let rel = |a: &F4, b: &F4| {
        (max_abs(&(a.x() - b.x())) / max_abs(a.x())).max(max_abs(&(a.P() - b.P())) / max_abs(a.P()))
    };
    let shapes: [fn(f64) -> BilinearProcess<4, 2, 2>; 2] = [process4, process4_square];
    for (shape, process) in shapes.into_iter().enumerate() {
        for p in PREDICT_PARAMS.map(|(a, b, k)| params(a, b, k)) {
            let mut a = filter4(p);
            let mut b = a.clone();
            let (mut step_worst, mut run_worst) = (0.0f64, 0.0f64);
            for k in 0..2000 {
                let (u, z) = (u_at(k), Vector1::new(z_at(k)));
                let f = process(u);
                let mut one_step = a.clone();
                assert_eq!(a.predict(|s| f.apply(s)), Ok(Status::Nominal));
                assert_eq!(one_step.predict_bilinear(&f), Ok(Status::Nominal));
                assert_eq!(b.predict_bilinear(&f), Ok(Status::Nominal));
                assert_eq!(b.P(), &b.P().transpose(), "P- exactly symmetric");
                step_worst = step_worst.max(rel(&a, &one_step));
                run_worst = run_worst.max(rel(&a, &b));
                assert_eq!(a.update(&z, h), b.update(&z, h));
            }
            eprintln!(
                "shape {shape}, alpha {}: bilinear vs unscented predict, max rel diff \
                 {step_worst:.2e} per step, {run_worst:.2e} over the run",
                p.alpha
            );
            let scale = 1.0 / (p.alpha * p.alpha);
            assert!(
                step_worst <= 1e-14 * scale,
                "shape {shape}, alpha {}: {step_worst:e}",
                p.alpha
            );
            assert!(
                run_worst <= 1e-10 * scale,
                "shape {shape}, alpha {}: {run_worst:e}",
                p.alpha
            );
            assert_eq!(a.recoveries(), b.recoveries());
        }
    }
}

/// `predict_bilinear` refuses a non-finite process and an overflowing
/// result, leaving the state as it was.
#[test]
fn bilinear_predict_refusals() {
    let mut b = filter4(params(1.0, 2.0, 0.0));
    let (x, P) = (*b.x(), *b.P());
    let mut nan_f = process4(0.1);
    nan_f.F[(0, 1)] = f64::NAN;
    let mut inf_b = process4(0.1);
    inf_b.b[1] = f64::INFINITY;
    let mut inf_g = process4(0.1);
    inf_g.g[0] = f64::NEG_INFINITY;
    for bad in [nan_f, inf_b, inf_g] {
        assert_eq!(b.predict_bilinear(&bad), Err(UkfError::NonFiniteProcess));
    }
    let mut huge = process4(0.1);
    huge.g[1] = 1e308;
    assert_eq!(
        b.predict_bilinear(&huge),
        Err(UkfError::NonFiniteResult {
            phase: Phase::Predict
        })
    );
    assert_eq!((*b.x(), *b.P()), (x, P), "state unchanged");
    assert_eq!(b.recoveries().rejected, 4);
    assert_eq!(b.recoveries().predicts, 0);
}

/// `predict_linear` (the closed form `F x + b`, `F P F' + Q`) against the
/// unscented `predict` of the same affine process, with updates in between
/// (so `P` is not that of the closed form), and its refusals.
#[test]
fn linear_predict_equals_unscented_predict() {
    let b = Vector2::new(0.01, -0.02);
    for p in PREDICT_PARAMS.map(|(a, b, k)| params(a, b, k)) {
        let mut a = lin(p);
        let mut c = a.clone();
        let mut worst = 0.0f64;
        for k in 0..2000 {
            let z = Vector1::new(z_at(k));
            assert_eq!(a.predict(|s| F() * s + b), Ok(Status::Nominal));
            assert_eq!(c.predict_linear(&F(), &b), Ok(Status::Nominal));
            assert_eq!(c.P(), &c.P().transpose(), "P- exactly symmetric");
            worst = worst
                .max(max_abs(&(a.x() - c.x())) / max_abs(a.x()))
                .max(max_abs(&(a.P() - c.P())) / max_abs(a.P()));
            assert_eq!(a.update(&z, |s| H() * s), c.update(&z, |s| H() * s));
        }
        eprintln!(
            "alpha {}: linear vs unscented predict, max rel diff {worst:.2e}",
            p.alpha
        );
        assert!(
            worst <= 1e-12 / (p.alpha * p.alpha),
            "alpha {}: rel diff {worst:e}",
            p.alpha
        );
        assert_eq!(a.recoveries(), c.recoveries());
    }
    let mut c = lin(params(1.0, 2.0, 0.0));
    let before = snapshot(&c);
    assert_eq!(
        c.predict_linear(&(F() * f64::NAN), &b),
        Err(UkfError::NonFiniteProcess)
    );
    assert_eq!(
        c.predict_linear(&F(), &Vector2::new(f64::INFINITY, 0.0)),
        Err(UkfError::NonFiniteProcess)
    );
    assert_eq!(
        c.predict_linear(&(F() * 1e300), &b),
        Err(UkfError::NonFiniteResult {
            phase: Phase::Predict
        })
    );
    assert_eq!(snapshot(&c), before);
    assert_eq!(c.recoveries().rejected, 3);
}

/// `predict_bilinear` defers filterpy's re-draw: the points drawn on demand
/// equal the full predict's up to rounding, and an indefinite `P-` is
/// repaired by the call that factors it (the generic update, as stage
/// `PredictRedraw`) or refused by the factorisation of `S` in the selection
/// update; never a NaN.
#[test]
fn bilinear_predict_defers_the_redraw() {
    let h = |s: &SVector<f64, 4>| Vector1::new(s[0]);
    let sel = Selection::<4, 1>::new([0]).expect("index < 4");
    let mut a = filter4(params(0.5, 2.0, 1.0));
    let mut b = a.clone();
    let f = process4(0.3);
    assert_eq!(a.predict(|s| f.apply(s)), Ok(Status::Nominal));
    assert_eq!(b.predict_bilinear(&f), Ok(Status::Nominal));
    let (pa, pb) = (
        a.sigmas_f().expect("drawn"),
        b.sigmas_f().expect("P- factors"),
    );
    let rel = max_abs(&(pa - pb)) / max_abs(&pa);
    assert!(rel <= 1e-14, "re-drawn points differ by {rel:e}");

    // A strongly negative Q: P- is indefinite, and predict_bilinear does not
    // factor it.
    b.set_Q(SMatrix::<f64, 4, 4>::identity() * -10.0)
        .expect("finite");
    assert_eq!(b.predict_bilinear(&f), Ok(Status::Nominal));
    assert_eq!(b.sigmas_f(), None);
    let mut c = b.clone();
    let z = Vector1::new(0.2);
    assert_eq!(
        b.update(&z, h),
        Err(UkfError::CovarianceReset {
            stage: Stage::PredictRedraw
        })
    );
    assert!(b.x().iter().chain(b.P().iter()).all(|v| v.is_finite()));
    assert_eq!(b.recoveries().covariance_resets, 1);
    assert_eq!(b.recoveries().updates, 1, "updated from the reset P");
    let x_before = *c.x();
    assert_eq!(
        c.update_selected(&z, &sel),
        Err(UkfError::CovarianceReset {
            stage: Stage::InnovationCovariance
        })
    );
    assert_eq!(*c.x(), x_before, "measurement discarded");
    assert_eq!(*c.P(), P0_4());
}

#[test]
fn update_before_predict_draws_from_current_state() {
    // filterpy would use all-zero sigma points here (K ~ 0); we draw from
    // (x, P), which on a linear model is the exact Kalman update.
    let mut ukf = lin(params(1.0, 2.0, 0.0));
    let (mut x, mut P) = (x0(), P0());
    let z = 0.7;
    assert_eq!(
        ukf.update(&Vector1::new(z), |s| H() * s),
        Ok(Status::Nominal)
    );
    let S = H() * P * H().transpose() + R();
    let K = P * H().transpose() / S[(0, 0)];
    x += K * (z - (H() * x)[(0, 0)]);
    P -= K * S * K.transpose();
    assert!(max_abs(&(ukf.x() - x)) < 1e-14);
    assert!(max_abs(&(ukf.P() - P)) < 1e-14);
    assert!(max_abs(&(ukf.K() - K)) < 1e-14);
    assert!((ukf.S()[(0, 0)] - S[(0, 0)]).abs() < 1e-14);
}

#[test]
fn constructor_errors_name_the_argument() {
    let p = params(1.0, 2.0, 0.0);
    let nan = f64::NAN;
    assert_eq!(
        Lin::new(x0(), P0(), Q(), R(), params(0.0, 2.0, 0.0)).unwrap_err(),
        UkfError::InvalidSigmaParams { name: "alpha" }
    );
    assert_eq!(
        Lin::new(x0(), P0(), Q(), R(), params(1.0, 2.0, -2.0)).unwrap_err(),
        UkfError::InvalidSigmaParams { name: "kappa" }
    );
    assert_eq!(
        Lin::new(x0(), P0(), Q(), R(), params(1.0, nan, 0.0)).unwrap_err(),
        UkfError::InvalidSigmaParams { name: "beta" }
    );
    assert_eq!(
        Lin::new(Vector2::new(nan, 0.0), P0(), Q(), R(), p).unwrap_err(),
        UkfError::NonFiniteArgument { which: Arg::X }
    );
    let mut Pbad = P0();
    Pbad[(1, 0)] = f64::INFINITY;
    assert_eq!(
        Lin::new(x0(), Pbad, Q(), R(), p).unwrap_err(),
        UkfError::NonFiniteArgument { which: Arg::P }
    );
    assert_eq!(
        Lin::new(x0(), Matrix2::new(1.0, 2.0, 2.0, 1.0), Q(), R(), p).unwrap_err(),
        UkfError::NotPositiveDefinite { which: Arg::P }
    );
    assert_eq!(
        Lin::new(x0(), P0(), Q() * nan, R(), p).unwrap_err(),
        UkfError::NonFiniteArgument { which: Arg::Q }
    );
    assert_eq!(
        Lin::new(x0(), P0(), Q(), R() * nan, p).unwrap_err(),
        UkfError::NonFiniteArgument { which: Arg::R }
    );
    let mut ukf = lin(p);
    assert_eq!(
        ukf.set_reset_covariance(-P0()).unwrap_err(),
        UkfError::NotPositiveDefinite {
            which: Arg::ResetCovariance
        }
    );
    assert_eq!(
        ukf.reset(x0(), -P0()).unwrap_err(),
        UkfError::NotPositiveDefinite { which: Arg::P }
    );
    assert_eq!(
        ukf.set_Q(Q() * nan).unwrap_err(),
        UkfError::NonFiniteArgument { which: Arg::Q }
    );
    assert_eq!(
        ukf.set_R(R() * nan).unwrap_err(),
        UkfError::NonFiniteArgument { which: Arg::R }
    );
    let bad = Pendulum {
        mass_kg: 0.0,
        ..Pendulum::default()
    };
    assert_eq!(
        bad.validate().unwrap_err(),
        UkfError::InvalidModelParameter { name: "mass_kg" }
    );
}

/// Everything observable about the filter, for "unchanged" checks:
/// x, P, x_prior, P_prior, sigmas_f, K, y, S.
type Snapshot = (
    Vector2<f64>,
    Matrix2<f64>,
    Vector2<f64>,
    Matrix2<f64>,
    Option<SMatrix<f64, 2, 5>>,
    SMatrix<f64, 2, 1>,
    Vector1<f64>,
    SMatrix<f64, 1, 1>,
);

fn snapshot(u: &Lin) -> Snapshot {
    (
        *u.x(),
        *u.P(),
        *u.x_prior(),
        *u.P_prior(),
        u.sigmas_f(),
        *u.K(),
        *u.y(),
        *u.S(),
    )
}

#[test]
fn rejected_calls_leave_state_unchanged_and_are_counted() {
    let mut ukf = lin(params(1.0, 2.0, 0.0));
    assert_eq!(ukf.predict(|s| F() * s), Ok(Status::Nominal));
    assert_eq!(
        ukf.update(&Vector1::new(0.1), |s| H() * s),
        Ok(Status::Nominal)
    );
    assert_eq!(ukf.predict(|s| F() * s), Ok(Status::Nominal));
    let before = snapshot(&ukf);
    let nan = f64::NAN;

    assert_eq!(
        ukf.update(&Vector1::new(nan), |s| H() * s),
        Err(UkfError::NonFiniteMeasurement)
    );
    assert_eq!(
        ukf.update(&Vector1::new(f64::INFINITY), |s| H() * s),
        Err(UkfError::NonFiniteMeasurement)
    );
    assert_eq!(
        ukf.update(&Vector1::new(0.1), |_| Vector1::new(nan)),
        Err(UkfError::NonFiniteMeasurementModel)
    );
    assert_eq!(
        ukf.update_with_r(&Vector1::new(0.1), &(R() * nan), |s| H() * s),
        Err(UkfError::NonFiniteArgument { which: Arg::R })
    );
    // h finite but huge: S overflows.
    assert_eq!(
        ukf.update(&Vector1::new(0.1), |s| Vector1::new(1e300 * s[0])),
        Err(UkfError::NonFiniteResult {
            phase: Phase::Update
        })
    );
    assert_eq!(snapshot(&ukf), before);
    assert_eq!(
        ukf.predict(|_| Vector2::new(nan, 0.0)),
        Err(UkfError::NonFiniteProcess)
    );
    // Only one sigma point goes bad: still rejected.
    assert_eq!(
        ukf.predict(|s| if s[0] > ukf_x0_bound() {
            Vector2::new(f64::INFINITY, 0.0)
        } else {
            *s
        }),
        Err(UkfError::NonFiniteProcess)
    );
    assert_eq!(
        ukf.predict_with_q(&(Q() * nan), |s| F() * s),
        Err(UkfError::NonFiniteArgument { which: Arg::Q })
    );
    assert_eq!(
        ukf.predict(|s| s * 1e300),
        Err(UkfError::NonFiniteResult {
            phase: Phase::Predict
        })
    );
    assert_eq!(snapshot(&ukf), before);

    let r = ukf.recoveries();
    assert_eq!(r.rejected, 9);
    assert_eq!(
        (r.predicts, r.updates, r.resymmetrised, r.covariance_resets),
        (2, 1, 0, 0)
    );
    // And the filter still works.
    assert_eq!(
        ukf.update(&Vector1::new(0.1), |s| H() * s),
        Ok(Status::Nominal)
    );
}

fn ukf_x0_bound() -> f64 {
    0.5
}

#[test]
fn resymmetrisation_is_reported_and_counted() {
    // A skew-symmetric Q makes P_prior asymmetric: its upper triangle alone
    // is indefinite, its symmetric part is P_prior's nominal value.
    let mut ukf = lin(params(1.0, 2.0, 0.0));
    let skew = Matrix2::new(0.0, 5.0, -5.0, 0.0);
    let st = ukf
        .predict_with_q(&(Q() + skew), |s| *s)
        .expect("recovered predict");
    assert_eq!(
        st,
        Status::Resymmetrised {
            stage: Stage::PredictRedraw
        }
    );
    assert_eq!(ukf.recoveries().resymmetrised, 1);
    assert!(
        max_abs(&(ukf.P() - ukf.P().transpose())) == 0.0,
        "P was re-symmetrised in place"
    );
    assert!(max_abs(&(ukf.P() - (P0() + Q()))) < 1e-15);
}

#[test]
fn covariance_reset_in_predict_and_update() {
    let mut ukf = lin(params(1.0, 2.0, 0.0));
    let P_reset = Matrix2::new(2.0, 0.0, 0.0, 2.0);
    ukf.set_reset_covariance(P_reset).expect("PD");

    // Strongly negative Q: P_prior is indefinite, re-draw resets it.
    assert_eq!(
        ukf.predict_with_q(&(Matrix2::identity() * -10.0), |s| F() * s),
        Err(UkfError::CovarianceReset {
            stage: Stage::PredictRedraw
        })
    );
    assert_eq!(*ukf.P(), P_reset);
    assert_eq!(*ukf.P_prior(), P_reset);
    assert!(ukf.x().iter().all(|v| v.is_finite()));
    assert_eq!(ukf.recoveries().covariance_resets, 1);
    assert_eq!(ukf.recoveries().predicts, 1, "the predict itself completed");

    // Negative R: S is not positive definite; measurement dropped, P reset.
    let x_before = *ukf.x();
    ukf.reset(x_before, P0()).expect("reset");
    assert_eq!(ukf.predict(|s| F() * s), Ok(Status::Nominal));
    let x_before = *ukf.x();
    assert_eq!(
        ukf.update_with_r(
            &Vector1::new(3.0),
            &SMatrix::<f64, 1, 1>::new(-100.0),
            |s| H() * s
        ),
        Err(UkfError::CovarianceReset {
            stage: Stage::InnovationCovariance
        })
    );
    assert_eq!(*ukf.x(), x_before, "measurement discarded");
    assert_eq!(*ukf.P(), P_reset);
    let r = ukf.recoveries();
    assert_eq!((r.covariance_resets, r.updates, r.rejected), (2, 0, 0));
    // Next update draws fresh sigma points from (x, P_reset) and works.
    assert_eq!(
        ukf.update(&Vector1::new(0.3), |s| H() * s),
        Ok(Status::Nominal)
    );
}

#[test]
fn run_checks_slices_and_matches_stepping() {
    let model = Pendulum::default();
    let make = || -> DemoUkf {
        model.validate().expect("valid model");
        DemoUkf::new(
            SVector::<f64, 3>::new(0.3, 0.0, 0.0),
            SMatrix::<f64, 3, 3>::from_diagonal(&SVector::<f64, 3>::new(0.1, 0.1, 0.5)),
            SMatrix::<f64, 3, 3>::from_diagonal(&SVector::<f64, 3>::new(1e-8, 1e-6, 1e-6)),
            SMatrix::<f64, 2, 2>::identity() * 1e-4,
            params(0.5, 2.0, 0.0),
        )
        .expect("valid")
    };
    const T: usize = 200;
    let u: [f64; T] = core::array::from_fn(u_at);
    let mut z = [0.0; 2 * T];
    for k in 0..T {
        let th = 0.3 * libm::cos(k as f64 * 1e-2);
        z[2 * k] = 0.5 * libm::sin(th);
        z[2 * k + 1] = -0.5 * libm::cos(th);
    }
    let (mut xs, mut pd) = ([0.0; 3 * T], [0.0; 3 * T]);
    let mut ukf = make();
    assert_eq!(
        model.run(&mut ukf, &u, &z[..2 * T - 1], &mut xs, &mut pd),
        Err(UkfError::InputLength {
            which: Arg::Measurements,
            needed: 2 * T,
            got: 2 * T - 1
        })
    );
    assert_eq!(
        model.run(&mut ukf, &u, &z, &mut xs[..3 * T - 1], &mut pd),
        Err(UkfError::OutputTooShort {
            which: Arg::XsOut,
            needed: 3 * T,
            got: 3 * T - 1
        })
    );
    assert_eq!(
        model.run(&mut ukf, &u, &z, &mut xs, &mut pd[..2]),
        Err(UkfError::OutputTooShort {
            which: Arg::PdiagOut,
            needed: 3 * T,
            got: 2
        })
    );
    assert_eq!(ukf.recoveries().predicts, 0, "nothing ran");
    let report = model.run(&mut ukf, &u, &z, &mut xs, &mut pd).expect("run");
    assert_eq!(
        (report.steps, report.errors, report.first_error),
        (T, 0, None)
    );

    let mut step = make();
    for k in 0..T {
        assert_eq!(step.predict(|x| model.f(x, u[k])), Ok(Status::Nominal));
        assert_eq!(
            step.update(&SVector::<f64, 2>::new(z[2 * k], z[2 * k + 1]), |x| {
                model.h(x)
            }),
            Ok(Status::Nominal)
        );
        for i in 0..3 {
            assert_eq!(xs[3 * k + i], step.x()[i]);
            assert_eq!(pd[3 * k + i], step.P()[(i, i)]);
        }
    }

    // A bad measurement mid-trial is rejected, counted, and the trial goes on.
    z[2 * 50] = f64::NAN;
    let mut ukf = make();
    let report = model.run(&mut ukf, &u, &z, &mut xs, &mut pd).expect("run");
    assert_eq!(report.errors, 1);
    let first = report.first_error.expect("one error");
    assert_eq!(
        (first.step, first.phase, first.error),
        (50, Phase::Update, UkfError::NonFiniteMeasurement)
    );
    assert!(xs.iter().chain(pd.iter()).all(|v| v.is_finite()));
    assert_eq!(ukf.recoveries().rejected, 1);
}

/// The hand-written factor and solve of `S` equal nalgebra's `Cholesky` and
/// `solve_mut` up to rounding (they multiply by `1 / L_jj` where nalgebra
/// divides by `L_jj`: one rounding more per entry, amplified by the
/// conditioning of `S`), and refuse what it refuses.
#[test]
fn innovation_factor_and_gain_equal_nalgebra() {
    use sensaug_core::ukf::{cholesky_lower, kalman_gain};
    let mut seed = 0x2545_f491_4f6c_dd1du64;
    let mut next = || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    let (mut worst_l, mut worst_k) = (0.0f64, 0.0f64);
    for _ in 0..200 {
        let A = SMatrix::<f64, 5, 5>::from_fn(|_, _| next());
        let S = A * A.transpose() + SMatrix::<f64, 5, 5>::identity() * 1e-3;
        let Pxz = SMatrix::<f64, 6, 5>::from_fn(|_, _| next());
        let ch = nalgebra::Cholesky::new(S).expect("positive definite");
        let L = cholesky_lower(&S).expect("positive definite");
        worst_l = worst_l.max(max_abs(&(L - ch.l())) / max_abs(&ch.l()));
        let mut Kt = Pxz.transpose();
        ch.solve_mut(&mut Kt);
        let K = kalman_gain(&Pxz, &L);
        // Relative to the gain's row scale: S is factored with condition
        // numbers up to ~1e5 here, so a row's small entries carry the
        // rounding of its large ones.
        for r in 0..6 {
            let row = Kt.column(r);
            let scale = row.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let diff = (K.row(r).transpose() - row).abs().max();
            worst_k = worst_k.max(diff / scale);
        }
    }
    eprintln!("factor vs nalgebra {worst_l:.2e}, gain vs nalgebra {worst_k:.2e} (relative)");
    // A few ulps per entry, carried through five columns (2.7e-15 seen).
    assert!(worst_l <= 1e-14, "factor differs by {worst_l:e}");
    // Two triangular solves on top of the factor (3.7e-14 seen).
    assert!(worst_k <= 1e-12, "gain differs by {worst_k:e}");
    let indefinite = Matrix2::new(1.0, 2.0, 2.0, 1.0);
    assert!(cholesky_lower(&indefinite).is_none());
    assert!(nalgebra::Cholesky::new(indefinite).is_none());
    assert!(cholesky_lower(&Matrix2::new(f64::NAN, 0.0, 0.0, 1.0)).is_none());
    assert!(cholesky_lower(&Matrix2::new(1.0, 0.0, f64::INFINITY, 1.0)).is_none());
}
