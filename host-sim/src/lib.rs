//! Prognos host simulator: truth plants, sensor models and the lockstep runner that drives
//! the estimator core against them; scenario files, recorded-data CSV, Monte-Carlo
//! campaigns, plots, and the `prognos` command line.
//!
//! To plug in a system: implement [`lockstep::TruthPlant`], [`lockstep::Estimator`]
//! (wrapping the core pipeline), usually [`lockstep::ChannelSensor`] and
//! [`lockstep::ProfileInputs`] from the scenario, and a [`registry::System`] that builds
//! them; then add it to [`registry::Registry::builtin`].
#![forbid(unsafe_code)]

pub mod bearing;
pub mod bench_report;
pub mod campaign;
pub mod cli;
pub mod dataio;
pub mod edge_cloud;
pub mod error;
pub mod faults;
pub mod gap;
pub mod linear_degradation;
pub mod lockstep;
pub mod output;
pub mod plants;
pub mod plot;
pub mod reaction_wheel;
pub mod registry;
pub mod reproduce;
pub mod scenario;
pub mod scooter;
pub mod soak;
pub mod valve;

pub use error::SimError;
