//! Prognos host simulator: truth plants, lockstep runs and Monte-Carlo campaigns.

pub mod plants;
pub mod reaction_wheel;
