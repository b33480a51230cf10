//! Recursive Bayesian filters.

pub mod particle;
pub mod resample;
pub mod ukf;
