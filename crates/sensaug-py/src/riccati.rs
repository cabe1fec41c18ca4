//! Riccati / LQR: conversion only (`sensaug_core::riccati::lqr_dense` checks
//! the shapes and dispatches to the fixed-size solvers).
use crate::convert::{array2, py_err, real};
use numpy::{PyArray1, PyArray2, PyArrayMethods};
use pyo3::prelude::*;
use sensaug_core::riccati::{self, DenseMatrix};

type Pair<'py> = (Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<f64>>);

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
    let [a, b, q, r] = [
        array2(a, "A")?,
        array2(b, "B")?,
        array2(q, "Q")?,
        array2(r, "R")?,
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
