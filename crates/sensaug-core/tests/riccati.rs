//! Riccati / LQR solver tests: the solution is put back into its equation
//! (relative residual <= 1e-10), checked for symmetry, PSD and closed-loop
//! stability, compared with closed forms, and every error variant is
//! triggered once. The independent scipy oracle lives in
//! `tests/test_riccati.py`.
#![allow(non_snake_case)]

use nalgebra::{Matrix1, Matrix2, Matrix3, SMatrix, Vector2, Vector3};
use sensaug_core::riccati::{
    agent_gains, care, care_residual, care_with, dare, dare_residual, dare_with, eigenvalues,
    lqr_continuous, lqr_discrete, partner_gain_vector, robot_gain_vector, AgentParameter, Argument,
    RiccatiError, SolverOptions, RESIDUAL_TOL,
};

/// Symmetric and PSD (smallest eigenvalue >= -1e-12 ||X||).
fn assert_sym_psd<const N: usize>(X: &SMatrix<f64, N, N>) {
    let asym = (X - X.transpose()).norm();
    assert!(asym <= 1e-14 * X.norm(), "asymmetry {asym:e}\nX = {X}");
    let eig = eigenvalues(X).expect("eigenvalues");
    for l in eig.iter() {
        // X is symmetric, so the spectrum is real; skip the -0.5 padding.
        if (l.re + 0.5).abs() > 1e-12 {
            assert!(l.re >= -1e-12 * X.norm(), "eigenvalue {l} < 0\nX = {X}");
        }
    }
}

/// `X` solves its equation (relative residual `<= RESIDUAL_TOL`) and is
/// symmetric PSD.
fn assert_solution<const N: usize>(X: &SMatrix<f64, N, N>, residual: f64) {
    assert!(residual <= RESIDUAL_TOL, "residual {residual:e}");
    assert_sym_psd(X);
}

/// The scalar problem `(a, b, q, r)` as 1 x 1 matrices `(A, B, Q, R)`.
fn scalar(
    a: f64,
    b: f64,
    q: f64,
    r: f64,
) -> (Matrix1<f64>, Matrix1<f64>, Matrix1<f64>, Matrix1<f64>) {
    (
        Matrix1::new(a),
        Matrix1::new(b),
        Matrix1::new(q),
        Matrix1::new(r),
    )
}

fn max_re<const N: usize>(A: &SMatrix<f64, N, N>) -> f64 {
    eigenvalues(A)
        .expect("eigenvalues")
        .iter()
        .map(|l| l.re)
        .fold(f64::NEG_INFINITY, f64::max)
}

fn max_abs<const N: usize>(A: &SMatrix<f64, N, N>) -> f64 {
    eigenvalues(A)
        .expect("eigenvalues")
        .iter()
        .map(|l| l.re.hypot(l.im))
        .fold(f64::NEG_INFINITY, f64::max)
}

/// The paper's 3-state pair on [x - tau, xdot, x - tau_h] (eq.system).
fn paper_pair(mass: f64, damping: f64) -> (Matrix3<f64>, Vector3<f64>) {
    let A = Matrix3::new(0.0, 1.0, 0.0, 0.0, -damping / mass, 0.0, 0.0, 1.0, 0.0);
    let B = Vector3::new(0.0, 1.0 / mass, 0.0);
    (A, B)
}

/// A 3-state, 2-input test system: unstable A, controllable, Q PSD singular.
fn system3() -> (Matrix3<f64>, SMatrix<f64, 3, 2>, Matrix3<f64>, Matrix2<f64>) {
    let A = Matrix3::new(0.2, 1.0, -0.3, 0.5, -1.0, 0.7, -0.4, 0.3, 0.9);
    let B = SMatrix::<f64, 3, 2>::new(1.0, 0.0, 0.3, 1.0, -0.5, 0.8);
    let C = SMatrix::<f64, 2, 3>::new(1.0, 0.5, 0.0, 0.0, 1.0, 1.0);
    let Q = C.transpose() * C;
    let R = Matrix2::new(2.0, 0.5, 0.5, 1.0);
    (A, B, Q, R)
}

/// The 3-state, 2-input system through CARE and DARE: residual, symmetry,
/// PSD and a stable closed loop for both.
#[test]
fn system3_residual_symmetry_psd_stability() {
    let (A, B, Q, R) = system3();
    let X = care(&A, &B, &Q, &R).unwrap();
    assert_solution(&X, care_residual(&A, &B, &Q, &R, &X));
    let (K, X2) = lqr_continuous(&A, &B, &Q, &R).unwrap();
    assert_eq!(X, X2);
    let m = max_re(&(A - B * K));
    assert!(m < 0.0, "closed loop max Re {m}");
    let Xd = dare(&A, &B, &Q, &R).unwrap();
    assert_solution(&Xd, dare_residual(&A, &B, &Q, &R, &Xd));
    let (Kd, _) = lqr_discrete(&A, &B, &Q, &R).unwrap();
    let rho = max_abs(&(A - B * Kd));
    assert!(rho < 1.0, "closed loop spectral radius {rho}");
}

#[test]
fn six_states_three_inputs() {
    let A = SMatrix::<f64, 6, 6>::from_fn(|i, j| {
        if j == i + 1 {
            1.0
        } else if i == j {
            0.1 * (i as f64) - 0.2
        } else {
            0.05 * ((i * 7 + j * 3) % 5) as f64 - 0.1
        }
    });
    let B = SMatrix::<f64, 6, 3>::from_fn(|i, j| if i == 2 * j + 1 { 1.0 } else { 0.1 });
    let Q = SMatrix::<f64, 6, 6>::identity();
    let R = Matrix3::identity() * 0.5;
    let X = care(&A, &B, &Q, &R).unwrap();
    assert_solution(&X, care_residual(&A, &B, &Q, &R, &X));
    let Xd = dare(&A, &B, &Q, &R).unwrap();
    assert_solution(&Xd, dare_residual(&A, &B, &Q, &R, &Xd));
}

/// Scalar CARE `2 a x - (b^2 / r) x^2 + q = 0`: the positive root
/// `x = r (a + sqrt(a^2 + b^2 q / r)) / b^2` (closed loop
/// `a - b^2 x / r = -sqrt(a^2 + b^2 q / r) < 0`).
#[test]
fn scalar_care_closed_form() {
    for &(a, b, q, r) in &[
        (1.0_f64, 1.0_f64, 1.0_f64, 1.0_f64),
        (-2.0, 0.5, 3.0, 0.1),
        (0.0, 2.0, 4.0, 1.0),
        (5.0, 1e-2, 1e-3, 10.0),
        (-1.0, 1.0, 0.0, 1.0), // stable a, q = 0: x = 0
    ] {
        let x = r * (a + (a * a + b * b * q / r).sqrt()) / (b * b);
        let (A, B, Q, R) = scalar(a, b, q, r);
        let X = care(&A, &B, &Q, &R).unwrap()[(0, 0)];
        let err = (X - x).abs();
        assert!(
            err <= 1e-12 * x.abs().max(1e-300),
            "a={a} b={b} q={q} r={r}: {X} vs {x}"
        );
    }
}

/// Scalar DARE `x = a^2 x - a^2 b^2 x^2 / (r + b^2 x) + q`; multiplying by
/// `r + b^2 x` gives `b^2 x^2 + (r - a^2 r - q b^2) x - q r = 0`, whose
/// non-negative root is `x = (-p + sqrt(p^2 + 4 b^2 q r)) / (2 b^2)`,
/// `p = r - a^2 r - q b^2`.
#[test]
fn scalar_dare_closed_form() {
    for &(a, b, q, r) in &[
        (1.0_f64, 1.0_f64, 1.0_f64, 1.0_f64),
        (2.0, 0.5, 3.0, 0.1),
        (0.5, 2.0, 4.0, 1.0),
        (-1.5, 1.0, 0.2, 3.0),
    ] {
        let p = r - a * a * r - q * b * b;
        let x = (-p + (p * p + 4.0 * b * b * q * r).sqrt()) / (2.0 * b * b);
        let (A, B, Q, R) = scalar(a, b, q, r);
        let X = dare(&A, &B, &Q, &R).unwrap()[(0, 0)];
        assert!(
            (X - x).abs() <= 1e-12 * x,
            "a={a} b={b} q={q} r={r}: {X} vs {x}"
        );
    }
}

/// C = 0: k_pos = sqrt(q_pos), k_vel = sqrt(q_vel + 2 M sqrt(q_pos)).
#[test]
fn agent_gains_closed_form() {
    // (M, Qx, Qv): the paper's simulation, and the Hi5 experiment (q_vel = 0).
    for &(m, qx, qv) in &[(6.0, 20000.0, 2.0), (0.0035, 1.0, 0.0), (1.0, 3.0, 0.5)] {
        let [kp, kv] = agent_gains(m, 0.0, qx, qv).unwrap();
        let kp_ref: f64 = qx.sqrt();
        let kv_ref: f64 = (qv + 2.0 * m * qx.sqrt()).sqrt();
        assert!(
            (kp - kp_ref).abs() <= 1e-10 * kp_ref,
            "k_pos {kp} vs {kp_ref}"
        );
        assert!(
            (kv - kv_ref).abs() <= 1e-10 * kv_ref,
            "k_vel {kv} vs {kv_ref}"
        );
    }
}

#[test]
fn agent_gains_with_damping_solve_reduced_care() {
    let (m, c, qx, qv) = (2.0, 3.0, 50.0, 1.0);
    let [kp, kv] = agent_gains(m, c, qx, qv).unwrap();
    let A = Matrix2::new(0.0, 1.0, 0.0, -c / m);
    let B = Vector2::new(0.0, 1.0 / m);
    let Q = Matrix2::new(qx, 0.0, 0.0, qv);
    let R = Matrix1::new(1.0);
    let X = care(&A, &B, &Q, &R).unwrap();
    let K = B.transpose() * X;
    assert!((K[0] - kp).abs() <= 1e-14 * kp && (K[1] - kv).abs() <= 1e-14 * kv);
    // Damping lowers the velocity gain needed; the position gain is still sqrt(q_pos).
    assert!((kp - qx.sqrt()).abs() <= 1e-10 * kp);
    assert_eq!(robot_gain_vector([kp, kv]), [kp, kv, 0.0]);
    assert_eq!(partner_gain_vector([kp, kv]), [0.0, kv, kp]);
}

#[test]
fn agent_gains_reject_bad_parameters() {
    use AgentParameter::*;
    let bad = |p| Err(RiccatiError::InvalidAgentParameter(p));
    assert_eq!(agent_gains(0.0, 0.0, 1.0, 0.0), bad(Mass));
    assert_eq!(agent_gains(f64::NAN, 0.0, 1.0, 0.0), bad(Mass));
    assert_eq!(agent_gains(1.0, -1.0, 1.0, 0.0), bad(Damping));
    assert_eq!(agent_gains(1.0, f64::INFINITY, 1.0, 0.0), bad(Damping));
    assert_eq!(agent_gains(1.0, 0.0, 0.0, 0.0), bad(QPos));
    assert_eq!(agent_gains(1.0, 0.0, 1.0, -1e-9), bad(QVel));
    assert_eq!(agent_gains(1.0, 0.0, 1.0, f64::NAN), bad(QVel));
}

// --------------------------------------------------------------------------
// One test per error variant
// --------------------------------------------------------------------------

/// `m` with its entry `at` set to `value`.
fn with<const R: usize, const C: usize>(
    mut m: SMatrix<f64, R, C>,
    at: (usize, usize),
    value: f64,
) -> SMatrix<f64, R, C> {
    m[at] = value;
    m
}

#[test]
fn err_non_finite_names_argument() {
    let (A, B, Q, R) = system3();
    let solves = [
        (care(&with(A, (1, 2), f64::NAN), &B, &Q, &R), Argument::A),
        (
            dare(&A, &with(B, (0, 1), f64::INFINITY), &Q, &R),
            Argument::B,
        ),
        (
            care(&A, &B, &with(Q, (0, 0), f64::NEG_INFINITY), &R),
            Argument::Q,
        ),
        (care(&A, &B, &Q, &with(R, (1, 1), f64::NAN)), Argument::R),
    ];
    for (solved, argument) in solves {
        assert_eq!(solved, Err(RiccatiError::NonFinite(argument)));
    }
}

#[test]
fn err_not_symmetric() {
    let (A, B, Q, R) = system3();
    let Qa = with(Q, (0, 1), Q[(0, 1)] + 1e-3);
    let Ra = with(R, (1, 0), R[(1, 0)] + 1e-3);
    let solves = [
        (care(&A, &B, &Qa, &R), Argument::Q),
        (dare(&A, &B, &Q, &Ra), Argument::R),
    ];
    for (solved, argument) in solves {
        assert_eq!(solved, Err(RiccatiError::NotSymmetric(argument)));
    }
}

#[test]
fn err_q_not_psd() {
    let (A, B, _, R) = system3();
    let Q = Matrix3::from_diagonal(&Vector3::new(1.0, -1e-3, 1.0));
    assert_eq!(
        care(&A, &B, &Q, &R),
        Err(RiccatiError::QNotPositiveSemidefinite)
    );
}

#[test]
fn err_r_not_pd() {
    let (A, B, Q, _) = system3();
    let R = Matrix2::new(1.0, 2.0, 2.0, 1.0); // eigenvalues 3, -1
    assert_eq!(
        care(&A, &B, &Q, &R),
        Err(RiccatiError::RNotPositiveDefinite)
    );
    let R0 = Matrix2::new(1.0, 0.0, 0.0, 0.0); // singular
    assert_eq!(
        dare(&A, &B, &Q, &R0),
        Err(RiccatiError::RNotPositiveDefinite)
    );
}

/// The paper's 3-state pair: mode 0 with left eigenvector [1, 0, -1] is
/// uncontrollable, so there is no stabilising solution (scipy returns one
/// anyway). Both with and without damping.
#[test]
fn err_paper_three_state_pair_not_stabilizable() {
    for &(m, c) in &[(6.0, 0.0), (6.0, 2.0), (0.0035, 0.0)] {
        let (A, B) = paper_pair(m, c);
        let Q = Matrix3::from_diagonal(&Vector3::new(20000.0, 2.0, 0.0));
        let R = Matrix1::new(1.0);
        assert_eq!(care(&A, &B, &Q, &R), Err(RiccatiError::NotStabilizable));
        assert_eq!(
            lqr_continuous(&A, &B, &Q, &R).map(|_| ()),
            Err(RiccatiError::NotStabilizable)
        );
    }
}

#[test]
fn err_not_stabilizable_discrete() {
    // Mode 1.5 is untouched by B.
    let A = Matrix2::new(1.5, 0.0, 0.0, 0.5);
    let B = Vector2::new(0.0, 1.0);
    assert_eq!(
        dare(&A, &B, &Matrix2::identity(), &Matrix1::new(1.0)),
        Err(RiccatiError::NotStabilizable)
    );
}

#[test]
fn err_not_detectable() {
    // Double integrator weighted only on velocity: the position mode at 0 is
    // unobservable through Q.
    let A = Matrix2::new(0.0, 1.0, 0.0, 0.0);
    let B = Vector2::new(0.0, 1.0);
    let Q = Matrix2::new(0.0, 0.0, 0.0, 1.0);
    let R = Matrix1::new(1.0);
    assert_eq!(care(&A, &B, &Q, &R), Err(RiccatiError::NotDetectable));
    // Discrete: unstable mode 2 not weighted.
    let Ad = Matrix2::new(2.0, 0.0, 0.0, 0.5);
    let Bd = Matrix2::identity();
    let Qd = Matrix2::new(0.0, 0.0, 0.0, 1.0);
    assert_eq!(
        dare(&Ad, &Bd, &Qd, &Matrix2::identity()),
        Err(RiccatiError::NotDetectable)
    );
}

#[test]
fn err_no_convergence_when_iterations_capped() {
    let (A, B, Q, R) = system3();
    let opts = SolverOptions {
        max_iterations: 1,
        ..SolverOptions::default()
    };
    assert_eq!(
        care_with(&A, &B, &Q, &R, &opts),
        Err(RiccatiError::NoConvergence)
    );
    assert_eq!(
        dare_with(&A, &B, &Q, &R, &opts),
        Err(RiccatiError::NoConvergence)
    );
}

/// With the precondition checks skipped, the not-stabilisable paper pair
/// reaches the post-solve checks, which must still refuse it.
#[test]
fn err_unchecked_paper_pair_is_still_refused() {
    let (A, B) = paper_pair(6.0, 0.0);
    let Q = Matrix3::from_diagonal(&Vector3::new(20000.0, 2.0, 0.0));
    let R = Matrix1::new(1.0);
    let opts = SolverOptions {
        check_preconditions: false,
        ..SolverOptions::default()
    };
    let r = care_with(&A, &B, &Q, &R, &opts);
    assert_eq!(r, Err(RiccatiError::NotStabilizing));
}

/// `A = 0, B = 1, Q = 0` with the checks skipped (it is not detectable):
/// `X = 0` solves `-X^2 = 0` exactly (residual 0), but the closed loop
/// `A - B K = 0` is only marginally stable, so the solution is refused.
#[test]
fn err_not_stabilizing() {
    let opts = SolverOptions {
        check_preconditions: false,
        ..SolverOptions::default()
    };
    let (A, B, Q, R) = (
        Matrix1::new(0.0),
        Matrix1::new(1.0),
        Matrix1::new(0.0),
        Matrix1::new(1.0),
    );
    assert_eq!(
        care_with(&A, &B, &Q, &R, &opts),
        Err(RiccatiError::NotStabilizing)
    );
    // Discrete: A = 1 (marginal), Q = 0: X = 0, closed loop 1.
    let A1 = Matrix1::new(1.0);
    assert_eq!(
        dare_with(&A1, &B, &Q, &R, &opts),
        Err(RiccatiError::NotStabilizing)
    );
    // With the checks on, the same problems are refused up front.
    assert_eq!(care(&A, &B, &Q, &R), Err(RiccatiError::NotDetectable));
}

#[test]
fn residual_function_detects_wrong_solution() {
    let (A, B, Q, R) = system3();
    let X = care(&A, &B, &Q, &R).unwrap();
    let wrong = X * (1.0 + 1e-6);
    let res = care_residual(&A, &B, &Q, &R, &wrong);
    assert!(res > RESIDUAL_TOL, "{res:e}");
    let Xd = dare(&A, &B, &Q, &R).unwrap();
    assert!(dare_residual(&A, &B, &Q, &R, &(Xd * (1.0 + 1e-6))) > RESIDUAL_TOL);
}

/// Runtime shapes (`lqr_dense`, the Python binding's entry): the same `K`
/// and `X` as the fixed-size solver, row-major, and each wrong shape named.
#[test]
fn lqr_dense_matches_the_fixed_size_solver_and_names_a_wrong_shape() {
    use sensaug_core::riccati::{lqr_dense, DenseMatrix};
    let (A, B, Q, R) = system3();
    let row_major = |m: &[f64], r: usize, c: usize| -> Vec<f64> {
        (0..r * c).map(|i| m[(i % c) * r + i / c]).collect()
    };
    let (a, b) = (row_major(A.as_slice(), 3, 3), row_major(B.as_slice(), 3, 2));
    let (q, r) = (row_major(Q.as_slice(), 3, 3), row_major(R.as_slice(), 2, 2));
    let dense = |data, shape| DenseMatrix { data, shape };
    for discrete in [false, true] {
        let (K, X) = match discrete {
            true => lqr_discrete(&A, &B, &Q, &R).unwrap(),
            false => lqr_continuous(&A, &B, &Q, &R).unwrap(),
        };
        let s = lqr_dense(
            dense(&a, [3, 3]),
            dense(&b, [3, 2]),
            dense(&q, [3, 3]),
            dense(&r, [2, 2]),
            discrete,
        )
        .unwrap();
        assert_eq!((s.n, s.m), (3, 2));
        assert_eq!(s.k(), row_major(K.as_slice(), 2, 3));
        assert_eq!(s.x(), row_major(X.as_slice(), 3, 3));
    }
    let err = lqr_dense(
        dense(&a, [3, 3]),
        dense(&b[..4], [2, 2]),
        dense(&q, [3, 3]),
        dense(&r, [2, 2]),
        false,
    )
    .unwrap_err();
    assert_eq!(
        err,
        RiccatiError::Shape {
            argument: Argument::B,
            got: [2, 2],
            n: 3,
            m: 2
        }
    );
    assert!(
        err.to_string()
            .starts_with("(A, B): B must have as many rows as A"),
        "{err}"
    );
    let err = lqr_dense(
        dense(&a, [3, 3]),
        dense(&b, [3, 2]),
        dense(&q, [3, 3]),
        dense(&r[..1], [1, 1]),
        false,
    )
    .unwrap_err();
    assert!(
        err.to_string()
            .starts_with("(B, R): R must match B's columns"),
        "{err}"
    );
}
