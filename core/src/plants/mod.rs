//! Estimation models of the plants the papers study.

pub mod valve;
