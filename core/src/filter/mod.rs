//! Recursive Bayesian filters.

pub mod adaptive;
pub mod adaptive_ukf;
pub mod imm;
pub mod particle;
pub mod resample;
pub mod ukf;
