//! Recursive Bayesian filters.

pub mod adaptive;
pub mod particle;
pub mod resample;
pub mod ukf;
