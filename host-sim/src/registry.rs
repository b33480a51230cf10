//! The registry of simulated systems. A system turns a scenario and a run seed into a
//! [`Simulation`]; the commands (`demo`, `run`, `campaign`, `replay`) work for every
//! registered system. To add one: implement [`System`] and add it in [`Registry::builtin`].

use crate::error::SimError;
use crate::lockstep::Simulation;
use crate::scenario::Scenario;
use std::path::Path;

/// A scenario compiled into the binary, so `prognos demo` works from any folder.
#[derive(Clone, Copy, Debug)]
pub struct EmbeddedScenario {
    /// Path shown in messages, e.g. `host-sim/scenarios/valve_demo.toml`.
    pub path: &'static str,
    /// The TOML text (`include_str!`).
    pub text: &'static str,
}

impl EmbeddedScenario {
    /// Parses the embedded text.
    pub fn load(&self) -> Result<Scenario, SimError> {
        Scenario::parse(Path::new(self.path), self.text)
    }
}

/// A simulated system: truth plant, sensors, inputs and estimator, built from a scenario.
pub trait System: Send + Sync {
    /// The name scenarios use in `system = "..."`.
    fn name(&self) -> &'static str;
    /// One line for `prognos systems` and the demo table.
    fn description(&self) -> &'static str;
    /// The scenario `prognos demo` runs for this system, if any.
    fn demo_scenario(&self) -> Option<EmbeddedScenario>;
    /// Builds everything one run needs. `seed` is the run seed (see
    /// [`crate::lockstep::stream_rng`] for the estimator's stream). Bad scenario content is
    /// reported with [`Scenario::error_at`] / [`Scenario::section`] so it carries a location.
    fn build(&self, scenario: &Scenario, seed: u64) -> Result<Simulation, SimError>;
}

/// The systems the commands know.
pub struct Registry {
    systems: Vec<Box<dyn System>>,
}

impl Registry {
    /// Every built-in system. Add new systems here.
    pub fn builtin() -> Self {
        Registry::empty().with(Box::new(crate::linear_degradation::LinearDegradation))
    }

    /// A registry without systems.
    pub fn empty() -> Self {
        Registry {
            systems: Vec::new(),
        }
    }

    /// Adds a system (a later one with the same name replaces the earlier).
    pub fn with(mut self, system: Box<dyn System>) -> Self {
        self.systems.retain(|s| s.name() != system.name());
        self.systems.push(system);
        self
    }

    /// The system called `name`.
    pub fn get(&self, name: &str) -> Option<&dyn System> {
        self.systems
            .iter()
            .find(|s| s.name() == name)
            .map(|s| s.as_ref())
    }

    /// All systems, in registration order.
    pub fn systems(&self) -> impl Iterator<Item = &dyn System> {
        self.systems.iter().map(|s| s.as_ref())
    }

    /// The system a scenario names; an unknown name is a bad-input error at `system`.
    pub fn resolve(&self, scenario: &Scenario) -> Result<&dyn System, SimError> {
        self.get(&scenario.system).ok_or_else(|| {
            let known: Vec<&str> = self.systems().map(|s| s.name()).collect();
            scenario.error_at(
                &["system"],
                format!(
                    "unknown system `{}` (known: {})",
                    scenario.system,
                    known.join(", ")
                ),
            )
        })
    }
}
