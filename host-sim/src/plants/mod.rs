//! Simulated truth plants.

pub mod reaction_wheel;
pub mod scooter;
