//! Bearing prognosis (Anger et al. 2012): stochastic pitting degradation, vibration model and
//! envelope feature, GP training, GP-UKF / IMM prognosis and the paper's tables.

pub mod degradation;
pub mod feature;
pub mod trial;
pub mod vibration;
