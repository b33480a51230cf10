//! Prognos host simulator.

pub mod bearing;
