//! Riccati / LQR bindings: numpy <-> `SMatrix` conversion and error mapping
//! only. Runtime shapes `n in 1..=6`, `m in 1..=n` are dispatched to the
//! const-generic core by [`dispatch!`].
//!
//! Errors: bad inputs (non-finite, asymmetric, indefinite weights, not
//! stabilisable / detectable, bad agent parameters, bad shapes) raise
//! `ValueError`; a solve that fails its own checks (no convergence, residual
//! too large, not stabilising) raises `RiccatiConvergenceError`, a subclass
//! of `RuntimeError`.
#![allow(non_snake_case)] // paper symbols A, B, Q, R, K, X (STYLE.md (f))

use nalgebra::SMatrix;
use numpy::ndarray::{Array2, ArrayView2};
use numpy::{IntoPyArray, PyArray2, PyReadonlyArray2};
use pyo3::create_exception;
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use sensaug_core::riccati::{self, RiccatiError};

create_exception!(
    _core,
    RiccatiConvergenceError,
    PyRuntimeError,
    "A Riccati solve did not converge or its solution failed the residual or closed-loop check."
);

fn to_py_err(e: RiccatiError) -> PyErr {
    match e {
        RiccatiError::NoConvergence
        | RiccatiError::ResidualTooLarge { .. }
        | RiccatiError::NotStabilizing => RiccatiConvergenceError::new_err(e.to_string()),
        _ => PyValueError::new_err(e.to_string()),
    }
}

/// Copies a view whose shape the caller has checked into an `SMatrix`.
fn to_smatrix<const R: usize, const C: usize>(a: &ArrayView2<'_, f64>) -> SMatrix<f64, R, C> {
    SMatrix::<f64, R, C>::from_fn(|i, j| a[(i, j)])
}

fn to_numpy<'py, const R: usize, const C: usize>(
    py: Python<'py>,
    m: &SMatrix<f64, R, C>,
) -> Bound<'py, PyArray2<f64>> {
    Array2::from_shape_fn((R, C), |(i, j)| m[(i, j)]).into_pyarray(py)
}

/// Checks the four shapes and returns `(n, m)`.
fn shapes(
    a: &ArrayView2<'_, f64>,
    b: &ArrayView2<'_, f64>,
    q: &ArrayView2<'_, f64>,
    r: &ArrayView2<'_, f64>,
) -> PyResult<(usize, usize)> {
    let (n, n2) = a.dim();
    if n != n2 || n == 0 || n > riccati::MAX_STATES {
        return Err(PyValueError::new_err(format!(
            "A: expected a square (n, n) array with 1 <= n <= {}, got {:?}",
            riccati::MAX_STATES,
            a.dim()
        )));
    }
    let (bn, m) = b.dim();
    if bn != n || m == 0 || m > n {
        return Err(PyValueError::new_err(format!(
            "B: expected shape (n, m) = ({n}, m) with 1 <= m <= {n}, got {:?}",
            b.dim()
        )));
    }
    if q.dim() != (n, n) {
        return Err(PyValueError::new_err(format!(
            "Q: expected shape ({n}, {n}), got {:?}",
            q.dim()
        )));
    }
    if r.dim() != (m, m) {
        return Err(PyValueError::new_err(format!(
            "R: expected shape ({m}, {m}), got {:?}",
            r.dim()
        )));
    }
    Ok((n, m))
}

/// Calls `$f::<N, M>(args..)` for the runtime `(n, m)`.
macro_rules! dispatch {
    ($n:expr, $m:expr, $f:ident ( $($arg:expr),* )) => {
        match ($n, $m) {
            (1, 1) => $f::<1, 1>($($arg),*),
            (2, 1) => $f::<2, 1>($($arg),*),
            (2, 2) => $f::<2, 2>($($arg),*),
            (3, 1) => $f::<3, 1>($($arg),*),
            (3, 2) => $f::<3, 2>($($arg),*),
            (3, 3) => $f::<3, 3>($($arg),*),
            (4, 1) => $f::<4, 1>($($arg),*),
            (4, 2) => $f::<4, 2>($($arg),*),
            (4, 3) => $f::<4, 3>($($arg),*),
            (4, 4) => $f::<4, 4>($($arg),*),
            (5, 1) => $f::<5, 1>($($arg),*),
            (5, 2) => $f::<5, 2>($($arg),*),
            (5, 3) => $f::<5, 3>($($arg),*),
            (5, 4) => $f::<5, 4>($($arg),*),
            (5, 5) => $f::<5, 5>($($arg),*),
            (6, 1) => $f::<6, 1>($($arg),*),
            (6, 2) => $f::<6, 2>($($arg),*),
            (6, 3) => $f::<6, 3>($($arg),*),
            (6, 4) => $f::<6, 4>($($arg),*),
            (6, 5) => $f::<6, 5>($($arg),*),
            (6, 6) => $f::<6, 6>($($arg),*),
            (n, m) => Err(PyValueError::new_err(format!(
                "unsupported dimensions n = {n}, m = {m}"
            ))),
        }
    };
}

/// Which equation a call solves.
#[derive(Clone, Copy)]
enum Equation {
    Continuous,
    Discrete,
}

type Views<'a, 'b> = (
    &'b ArrayView2<'a, f64>,
    &'b ArrayView2<'a, f64>,
    &'b ArrayView2<'a, f64>,
    &'b ArrayView2<'a, f64>,
);

fn solve_nm<'py, const N: usize, const M: usize>(
    py: Python<'py>,
    v: Views<'_, '_>,
    eq: Equation,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let (A, B, Q, R) = (
        to_smatrix::<N, N>(v.0),
        to_smatrix::<N, M>(v.1),
        to_smatrix::<N, N>(v.2),
        to_smatrix::<M, M>(v.3),
    );
    let X = match eq {
        Equation::Continuous => riccati::care(&A, &B, &Q, &R),
        Equation::Discrete => riccati::dare(&A, &B, &Q, &R),
    }
    .map_err(to_py_err)?;
    Ok(to_numpy(py, &X))
}

type Pair<'py> = (Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<f64>>);

fn lqr_nm<'py, const N: usize, const M: usize>(
    py: Python<'py>,
    v: Views<'_, '_>,
    eq: Equation,
) -> PyResult<Pair<'py>> {
    let (A, B, Q, R) = (
        to_smatrix::<N, N>(v.0),
        to_smatrix::<N, M>(v.1),
        to_smatrix::<N, N>(v.2),
        to_smatrix::<M, M>(v.3),
    );
    let (K, X) = match eq {
        Equation::Continuous => riccati::lqr_continuous(&A, &B, &Q, &R),
        Equation::Discrete => riccati::lqr_discrete(&A, &B, &Q, &R),
    }
    .map_err(to_py_err)?;
    Ok((to_numpy(py, &K), to_numpy(py, &X)))
}

/// CARE `A'X + XA - X B R^-1 B' X + Q = 0`: the stabilising solution.
#[pyfunction]
#[pyo3(signature = (a, b, q, r, /))]
fn care<'py>(
    py: Python<'py>,
    a: PyReadonlyArray2<'py, f64>,
    b: PyReadonlyArray2<'py, f64>,
    q: PyReadonlyArray2<'py, f64>,
    r: PyReadonlyArray2<'py, f64>,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let (a, b, q, r) = (a.as_array(), b.as_array(), q.as_array(), r.as_array());
    let (n, m) = shapes(&a, &b, &q, &r)?;
    dispatch!(n, m, solve_nm(py, (&a, &b, &q, &r), Equation::Continuous))
}

/// DARE `X = A'XA - A'XB (R + B'XB)^-1 B'XA + Q`: the stabilising solution.
#[pyfunction]
#[pyo3(signature = (a, b, q, r, /))]
fn dare<'py>(
    py: Python<'py>,
    a: PyReadonlyArray2<'py, f64>,
    b: PyReadonlyArray2<'py, f64>,
    q: PyReadonlyArray2<'py, f64>,
    r: PyReadonlyArray2<'py, f64>,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let (a, b, q, r) = (a.as_array(), b.as_array(), q.as_array(), r.as_array());
    let (n, m) = shapes(&a, &b, &q, &r)?;
    dispatch!(n, m, solve_nm(py, (&a, &b, &q, &r), Equation::Discrete))
}

/// LQR gain and Riccati solution `(K, X)`; `discrete` selects the DARE.
#[pyfunction]
#[pyo3(signature = (a, b, q, r, /, *, discrete = false))]
fn lqr<'py>(
    py: Python<'py>,
    a: PyReadonlyArray2<'py, f64>,
    b: PyReadonlyArray2<'py, f64>,
    q: PyReadonlyArray2<'py, f64>,
    r: PyReadonlyArray2<'py, f64>,
    discrete: bool,
) -> PyResult<Pair<'py>> {
    let (a, b, q, r) = (a.as_array(), b.as_array(), q.as_array(), r.as_array());
    let (n, m) = shapes(&a, &b, &q, &r)?;
    let eq = if discrete {
        Equation::Discrete
    } else {
        Equation::Continuous
    };
    dispatch!(n, m, lqr_nm(py, (&a, &b, &q, &r), eq))
}

/// Reduced 2-state agent gains `(k_pos, k_vel)` (eq.LQRrobot / eq.LQRhuman).
#[pyfunction]
#[pyo3(signature = (*, mass, damping, q_pos, q_vel))]
fn agent_gains(mass: f64, damping: f64, q_pos: f64, q_vel: f64) -> PyResult<(f64, f64)> {
    let [kp, kv] = riccati::agent_gains(mass, damping, q_pos, q_vel).map_err(to_py_err)?;
    Ok((kp, kv))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(care, m)?)?;
    m.add_function(wrap_pyfunction!(dare, m)?)?;
    m.add_function(wrap_pyfunction!(lqr, m)?)?;
    m.add_function(wrap_pyfunction!(agent_gains, m)?)?;
    m.add(
        "RiccatiConvergenceError",
        m.py().get_type::<RiccatiConvergenceError>(),
    )?;
    Ok(())
}
