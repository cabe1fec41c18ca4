//! Riccati / LQR: conversion only (`sensaug_core::riccati::lqr_dense` checks
//! the shapes and dispatches to the fixed-size solvers).
use crate::convert::{py_err, shape, Array};
use numpy::{PyArray1, PyArray2, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use sensaug_core::riccati::{self, DenseMatrix};

type Pair<'py> = (Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<f64>>);

/// `a`'s entries row-major and its shape, if it is 2-D; `name` is the argument.
fn dense(a: &Array<'_>, name: &str) -> PyResult<(Vec<f64>, [usize; 2])> {
    match *a.shape() {
        [r, c] => Ok((a.as_array().iter().copied().collect(), [r, c])),
        ref s => Err(PyValueError::new_err(format!(
            "{name}: expected a 2-D array, got shape {}",
            shape(a.py(), s)?
        ))),
    }
}

#[pyfunction]
#[pyo3(signature = (a, b, q, r, /, *, discrete))]
pub fn lqr<'py>(
    py: Python<'py>,
    a: Array<'py>,
    b: Array<'py>,
    q: Array<'py>,
    r: Array<'py>,
    discrete: bool,
) -> PyResult<Pair<'py>> {
    let [a, b, q, r] = [
        dense(&a, "A")?,
        dense(&b, "B")?,
        dense(&q, "Q")?,
        dense(&r, "R")?,
    ];
    let [a, b, q, r] = [&a, &b, &q, &r].map(|(data, shape)| DenseMatrix {
        data,
        shape: *shape,
    });
    let s = riccati::lqr_dense(a, b, q, r, discrete).map_err(py_err)?;
    let array = |data: &[f64], shape: [usize; 2]| PyArray1::from_slice(py, data).reshape(shape);
    Ok((array(s.k(), [s.m, s.n])?, array(s.x(), [s.n, s.n])?))
}

#[pyfunction]
#[pyo3(signature = (*, mass, damping, q_pos, q_vel))]
pub fn agent_gains(mass: f64, damping: f64, q_pos: f64, q_vel: f64) -> PyResult<(f64, f64)> {
    let gains = riccati::agent_gains(mass, damping, q_pos, q_vel).map_err(py_err)?;
    Ok(gains.into())
}
