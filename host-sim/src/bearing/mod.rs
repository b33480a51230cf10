//! Bearing prognosis (Anger et al. 2012): stochastic pitting degradation, vibration model and
//! envelope feature, GP training, GP-UKF / IMM prognosis and the paper's tables.

pub mod degradation;
pub mod feature;
pub mod prognosis;
pub mod tables;
pub mod train;
pub mod trial;
pub mod vibration;

pub use tables::{CampaignConfig, Tables, tables};

#[cfg(test)]
mod tests;
