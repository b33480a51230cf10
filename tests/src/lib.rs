//! Shared fixtures for the end-to-end and verification tests: test models with known exact
//! answers and readers for reference data produced by independent implementations.
#![forbid(unsafe_code)]

pub mod drag_radar;
pub mod fuzz;
pub mod linear_gaussian;
pub mod reference;
pub mod workloads;
