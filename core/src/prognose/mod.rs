//! Prognosis: end-of-life and remaining-useful-life prediction.

pub mod eol;

pub use eol::{EndOfLife, PredictionSettings, predict_eol, rul_distribution};
