//! Complete on-board prognosers, one `step(t, u, y)` call per sample.

pub mod edge;
pub mod reaction_wheel;

pub use reaction_wheel::ReactionWheel;
