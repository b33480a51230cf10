//! Sim-to-real gap diagnosis (`prognos gap`, DESIGN.md section 4, issue 8).
//!
//! Given measured data (CSV with `t`, `u:*`, `y:*`, optional `x:*`) and its sidecar
//! `<data>.meta.toml` naming the plant and the user's model, answer:
//! 1. *where* the model disagrees with the data ([`analysis`]: residuals per channel,
//!    regime, time window and frequency band, tested against the noise, with Holm's
//!    correction over all tests);
//! 2. *which* unmodelled effect causes it ([`effects`]: every candidate of the plant's
//!    catalogue and of the generic sensor catalogue is fitted on the training blocks and
//!    scored on the held-out blocks with a BIC-like penalty; pairs when no single one
//!    explains);
//! 3. *how far* the gap shrinks on the held-out blocks once the effect is added.
//!
//! A plant is anything that implements [`plant::GapPlant`]; the built-in ones are the
//! reaction wheel ([`wheel`]), the valve ([`valve`]), the scooter ([`scooter`]) and the
//! worked user example, a DC motor with load ([`dc_motor`]). `gap-bench` ([`bench`]) proves the diagnoser on generated data whose
//! effect it is not told about.

pub mod analysis;
pub mod bench;
pub mod dc_motor;
pub mod diagnose;
pub mod effects;
pub mod estimate;
pub mod meta;
pub mod plant;
pub mod report;
pub mod scooter;
pub mod start;
pub mod stats;
pub mod units;
pub mod valve;
pub mod wheel;

pub use diagnose::{Diagnosis, diagnose_files, diagnose_recording};

/// The reference of every built-in plant and of the generic catalogue (Markdown; printed
/// by `prognos gap-plants` and kept in `docs/gap.md`).
pub fn plant_reference() -> String {
    let mut s = String::from("## Built-in plants\n\n");
    for name in plant::BUILTIN_PLANTS {
        if let Some(p) = builtin_plant(name) {
            s.push_str(&plant::describe(p.as_ref()));
            s.push('\n');
        }
    }
    s.push_str("## Generic sensor effects\n\n");
    s.push_str(&effects::GenericKind::describe_all());
    s
}
pub use plant::{GapPlant, builtin_plant};
