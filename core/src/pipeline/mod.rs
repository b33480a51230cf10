//! Complete on-board prognosers, one `step(t, u, y)` call per sample.

pub mod scooter;

pub use scooter::Scooter;
