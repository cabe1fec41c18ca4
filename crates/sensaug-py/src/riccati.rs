//! Riccati / LQR bindings: conversion only. Runtime shapes `n in 1..=6`,
//! `m in 1..=n` are dispatched to the const-generic core.
//!
//! Bad inputs (non-finite, asymmetric, indefinite weights, not stabilisable /
//! detectable, bad shapes) raise `ValueError`; a solve that fails its own
//! checks raises `RiccatiConvergenceError` (`crate::convert::py_err`).
#![allow(non_snake_case)] // paper symbols A, B, Q, R, K, X (STYLE.md (f))

use crate::convert::{mat_from, mat_to, py_err};
use numpy::{PyArray2, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use sensaug_core::riccati;

type Arrays<'a, 'py> = [&'a PyReadonlyArray2<'py, f64>; 4];
type Pair<'py> = (Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<f64>>);

/// `(n, m)` from the shapes of `A` and `B`; `Q` and `R` are checked on conversion.
fn dims([a, b, ..]: Arrays<'_, '_>) -> PyResult<(usize, usize)> {
    let (n, max) = (a.shape()[0], riccati::MAX_STATES);
    if a.shape() != [n, n] || !(1..=max).contains(&n) {
        let got = a.shape();
        let msg = format!("A: expected a square (n, n) array with 1 <= n <= {max}, got {got:?}");
        return Err(PyValueError::new_err(msg));
    }
    let (m, max) = (b.shape()[1], n);
    if b.shape() != [n, m] || !(1..=max).contains(&m) {
        let got = b.shape();
        let msg = format!("B: expected shape (n, m) = ({n}, m) with 1 <= m <= {max}, got {got:?}");
        return Err(PyValueError::new_err(msg));
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
    a: PyReadonlyArray2<'py, f64>,
    b: PyReadonlyArray2<'py, f64>,
    q: PyReadonlyArray2<'py, f64>,
    r: PyReadonlyArray2<'py, f64>,
    discrete: bool,
) -> PyResult<Pair<'py>> {
    solve(py, [&a, &b, &q, &r], discrete)
}

/// Reduced 2-state agent gains `(k_pos, k_vel)` (eq.LQRrobot / eq.LQRhuman).
#[pyfunction]
#[pyo3(signature = (*, mass, damping, q_pos, q_vel))]
fn agent_gains(mass: f64, damping: f64, q_pos: f64, q_vel: f64) -> PyResult<(f64, f64)> {
    let [kp, kv] = riccati::agent_gains(mass, damping, q_pos, q_vel).map_err(py_err)?;
    Ok((kp, kv))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(lqr, m)?)?;
    m.add_function(wrap_pyfunction!(agent_gains, m)?)
}
