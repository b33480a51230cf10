//! Simulated truth plants.

pub mod scooter;
