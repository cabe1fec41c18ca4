//! Riccati / LQR: conversion only (`sensaug_core::riccati::lqr_dense` checks
//! the shapes and dispatches to the fixed-size solvers; `sensaug.lqr` makes
//! each argument a C-contiguous 2-D float64 array).
use crate::convert::{py_err, slice};
use numpy::{PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::prelude::*;
use sensaug_core::riccati::{self, DenseMatrix};

type Matrix<'py> = PyReadonlyArray2<'py, f64>;
type Pair<'py> = (Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<f64>>);

fn dense<'a>(a: &'a Matrix<'_>, name: &str) -> PyResult<DenseMatrix<'a>> {
    let shape = [a.shape()[0], a.shape()[1]];
    Ok(DenseMatrix {
        data: slice(a, name)?,
        shape,
    })
}

#[pyfunction]
#[pyo3(signature = (a, b, q, r, /, *, discrete))]
pub fn lqr<'py>(
    py: Python<'py>,
    a: Matrix<'py>,
    b: Matrix<'py>,
    q: Matrix<'py>,
    r: Matrix<'py>,
    discrete: bool,
) -> PyResult<Pair<'py>> {
    let [a, b, q, r] = [
        dense(&a, "A")?,
        dense(&b, "B")?,
        dense(&q, "Q")?,
        dense(&r, "R")?,
    ];
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
