//! Allocation-free numerics for human-robot sensory augmentation.
//!
//! The method is Li, Eden, Carboni and Burdet, "Improving Tracking through
//! Human-Robot Sensory Augmentation" (IEEE RA-L). Equation labels in the doc
//! comments (`eq.dynamics`, `eq.system-extended`, ...) are the paper's LaTeX
//! labels. `docs/model.md` states every equation implemented here and every
//! choice made where the paper is silent.
//!
//! A trial is laid out the way the loop runs it: the [`protocol`] says what
//! each tick is, the [`controller`] is what the real-time loop runs (its
//! partner [`identifier`] is shared with the simulated partner), and the
//! [`world`] simulates the handle, the noise and the partner
//! ([`agent::VirtualHuman`]) around it.
//!
//! Everything is `no_std` with no `alloc`: dimensions are const generics and
//! every buffer lives in the caller's structs, so nothing in a control tick can
//! allocate. Bad numbers are reported as typed errors, never panics.
#![no_std]
#![deny(missing_docs)]
#![allow(non_snake_case)]

pub mod agent;
pub mod controller;
pub mod delay;
mod error;
pub mod estimator;
pub mod goal;
pub mod identifier;
pub mod linalg;
pub mod plant;
pub mod protocol;
pub mod replay;
pub mod riccati;
pub mod rng;
pub mod row;
pub mod target;
pub mod ukf;
pub mod world;

pub use error::{CoreError, ErrorKind, ScenarioError};
