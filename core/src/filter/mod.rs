//! Recursive Bayesian filters.

pub mod adaptive;
pub mod adaptive_ukf;
pub mod particle;
pub mod resample;
pub mod ukf;
