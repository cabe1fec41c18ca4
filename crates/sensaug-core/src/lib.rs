//! Allocation-free numerics for human-robot sensory augmentation.
//!
//! The method is Li, Eden, Carboni and Burdet, "Improving Tracking through
//! Human-Robot Sensory Augmentation" (IEEE RA-L). Equation labels in the doc
//! comments (`eq.dynamics`, `eq.system-extended`, ...) are the paper's LaTeX
//! labels. `docs/model.md` states every equation implemented here and every
//! choice made where the paper is silent.
//!
//! Everything is `no_std` with no `alloc`: dimensions are const generics and
//! every buffer lives in the caller's structs, so nothing in a control tick can
//! allocate. Bad numbers are reported as typed errors, never panics.
#![no_std]
#![deny(missing_docs)]
#![allow(non_snake_case)]

pub mod agent;
pub mod estimator;
pub mod linalg;
pub mod plant;
pub mod replay;
pub mod riccati;
pub mod rng;
pub mod scenario;
pub mod target;
pub mod ukf;
