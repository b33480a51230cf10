//! Fault detection and isolation: analytical redundancy relations with adaptive thresholds,
//! coherence vectors and fault-signature-matrix isolation.

pub mod scooter;
