//! Prognos host simulator: truth plants, lockstep campaigns and paper reproductions.

pub mod plants;
pub mod scooter;
