//! Recursive Bayesian filters.

pub mod imm;
pub mod particle;
pub mod resample;
pub mod ukf;
