//! Complete on-board prognosers that compose the core pieces for one system.

pub mod edge;
