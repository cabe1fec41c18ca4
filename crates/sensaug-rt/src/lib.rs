//! The real-time binary's pieces: configuration, OS real-time services, the
//! loop, its log and its statistics. `main.rs` wires them together.
#![deny(missing_docs)]
#![allow(non_snake_case)]

pub mod config;
pub mod control;
pub mod feed;
pub mod friction;
pub mod log;
pub mod os;
pub mod range;
pub mod safety;
pub mod stats;
pub mod wake;
