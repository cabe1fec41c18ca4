//! Riccati / LQR bindings: conversion only. Runtime shapes `n in 1..=6`,
//! `m in 1..=n` are dispatched to the const-generic core.
//!
//! Bad inputs (non-finite, asymmetric, indefinite weights, not stabilisable /
//! detectable, bad shapes) raise `ValueError`; a solve that fails its own
//! checks raises `RiccatiConvergenceError` (`crate::convert::py_err`).
#![allow(non_snake_case)] // paper symbols A, B, Q, R, K, X (STYLE.md (f))

use crate::convert::{array2, mat_from, mat_to, py_err, real, shape};
use numpy::{PyArray2, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use sensaug_core::riccati;

type Arrays<'a, 'py> = [&'a PyReadonlyArray2<'py, f64>; 4];
type Pair<'py> = (Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<f64>>);

/// `(n, m)` from the shapes of `A` and `B`, and `Q`, `R` checked against
/// them. A mismatch names both arrays: either may be the wrong one.
fn dims([a, b, q, r]: Arrays<'_, '_>) -> PyResult<(usize, usize)> {
    let bad = |msg: String| Err(PyValueError::new_err(msg));
    let (n, max) = (a.shape()[0], riccati::MAX_STATES);
    if a.shape() != [n, n] || !(1..=max).contains(&n) {
        let got = shape(a.shape());
        return bad(format!(
            "A: expected a square (n, n) array with 1 <= n <= {max}, got {got}"
        ));
    }
    let m = b.shape()[1];
    if b.shape() != [n, m] || !(1..=n).contains(&m) {
        let got = shape(b.shape());
        return bad(format!(
            "(A, B): B must have as many rows as A: expected shape (n, m) = ({n}, m) with \
             1 <= m <= {n}, got {got}"
        ));
    }
    if q.shape() != [n, n] {
        let got = shape(q.shape());
        return bad(format!(
            "(A, Q): Q must match A: expected shape (n, n) = ({n}, {n}), got {got}"
        ));
    }
    if r.shape() != [m, m] {
        let got = shape(r.shape());
        return bad(format!(
            "(B, R): R must match B's columns: expected shape (m, m) = ({m}, {m}), got {got}"
        ));
    }
    Ok((n, m))
}

/// `(K, X)` of the continuous or discrete LQR for fixed `N`, `M`.
fn lqr_nm<'py, const N: usize, const M: usize>(
    py: Python<'py>,
    [a, b, q, r]: Arrays<'_, 'py>,
    discrete: bool,
) -> PyResult<Pair<'py>> {
    let (A, B) = (mat_from::<N, N>(a, "A")?, mat_from::<N, M>(b, "B")?);
    let (Q, R) = (mat_from::<N, N>(q, "Q")?, mat_from::<M, M>(r, "R")?);
    let (K, X) = if discrete {
        riccati::lqr_discrete(&A, &B, &Q, &R)
    } else {
        riccati::lqr_continuous(&A, &B, &Q, &R)
    }
    .map_err(py_err)?;
    Ok((mat_to(py, &K), mat_to(py, &X)))
}

/// Runs [`lqr_nm`] for the runtime `(n, m)`.
fn solve<'py>(py: Python<'py>, arrays: Arrays<'_, 'py>, discrete: bool) -> PyResult<Pair<'py>> {
    macro_rules! dispatch {
        ($(($n:literal, $m:literal)),*) => {
            match dims(arrays)? {
                $(($n, $m) => lqr_nm::<$n, $m>(py, arrays, discrete),)*
                (n, m) => Err(PyValueError::new_err(format!("unsupported dimensions n = {n}, m = {m}"))),
            }
        };
    }
    dispatch!(
        (1, 1),
        (2, 1),
        (2, 2),
        (3, 1),
        (3, 2),
        (3, 3),
        (4, 1),
        (4, 2),
        (4, 3),
        (4, 4),
        (5, 1),
        (5, 2),
        (5, 3),
        (5, 4),
        (5, 5),
        (6, 1),
        (6, 2),
        (6, 3),
        (6, 4),
        (6, 5),
        (6, 6)
    )
}

/// LQR gain and stabilising Riccati solution `(K, X)`: CARE
/// `A'X + XA - X B R^-1 B' X + Q = 0`, or with `discrete` the DARE
/// `X = A'XA - A'XB (R + B'XB)^-1 B'XA + Q` (`sensaug.care` / `dare` keep `X`).
#[pyfunction]
#[pyo3(signature = (a, b, q, r, /, *, discrete = false))]
fn lqr<'py>(
    py: Python<'py>,
    a: &Bound<'py, PyAny>,
    b: &Bound<'py, PyAny>,
    q: &Bound<'py, PyAny>,
    r: &Bound<'py, PyAny>,
    discrete: bool,
) -> PyResult<Pair<'py>> {
    let (a, b) = (array2(a, "A")?, array2(b, "B")?);
    let (q, r) = (array2(q, "Q")?, array2(r, "R")?);
    solve(py, [&a, &b, &q, &r], discrete)
}

/// Reduced 2-state agent gains `(k_pos, k_vel)` (eq.LQRrobot / eq.LQRhuman).
#[pyfunction]
#[pyo3(signature = (*, mass, damping, q_pos, q_vel))]
fn agent_gains(
    mass: &Bound<'_, PyAny>,
    damping: &Bound<'_, PyAny>,
    q_pos: &Bound<'_, PyAny>,
    q_vel: &Bound<'_, PyAny>,
) -> PyResult<(f64, f64)> {
    let (mass, damping) = (real(mass, "mass")?, real(damping, "damping")?);
    let (q_pos, q_vel) = (real(q_pos, "q_pos")?, real(q_vel, "q_vel")?);
    let [kp, kv] = riccati::agent_gains(mass, damping, q_pos, q_vel).map_err(py_err)?;
    Ok((kp, kv))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(lqr, m)?)?;
    m.add_function(wrap_pyfunction!(agent_gains, m)?)
}
