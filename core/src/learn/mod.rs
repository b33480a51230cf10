//! Learned models on board: autoregressive identification and Gaussian processes.

pub mod ar;
pub mod gp;
pub mod gp_rate;
