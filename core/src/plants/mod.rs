//! Estimation models of the plants the papers study.

pub mod valve;
pub mod reaction_wheel;
