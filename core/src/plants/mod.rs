//! Estimation models of the plants the papers study.

pub mod lubricant_kalman;
pub mod lubricant_two_step;
pub mod reaction_wheel;
pub mod scooter;
pub mod valve;
