//! Learned models: Gaussian processes (and autoregressive models).

pub mod gp;
