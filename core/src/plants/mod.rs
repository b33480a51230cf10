//! Estimation models of the plants the papers study.

pub mod reaction_wheel;
pub mod valve;
