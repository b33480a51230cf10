//! Estimation models of the monitored systems.

pub mod scooter;
