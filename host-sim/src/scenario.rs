//! Scenario files: TOML under `host-sim/scenarios/` naming the system, the sample time, the
//! run length, seeds and run count (typed here), plus system-specific sections (`plant`,
//! `effects`, `faults`, `noise`, `sensors`, `filter`) that each system parses with
//! [`Scenario::section`] into its own `#[serde(deny_unknown_fields)]` structs.
//!
//! ```toml
//! name = "linear_degradation"
//! system = "linear_degradation"
//! dt = 1.0
//! duration = 600.0        # seconds; or `cycles = 600` (number of samples after t = 0)
//! seed = 42
//! runs = 20
//! [inputs]
//! load = { kind = "constant", value = 1.0 }
//! [plant]
//! rate = 0.002
//! ```
//!
//! Every error names the file, line and column ([`SimError::BadInput`]); unknown keys are
//! rejected at the top level and, when the system's structs deny them, in every section.

use crate::error::{SimError, read_input};
use serde::Deserialize;
use serde::de::{DeserializeOwned, IntoDeserializer};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use toml::Spanned;

/// The system-specific sections a scenario may contain.
pub const SECTIONS: [&str; 7] = [
    "plant",
    "effects",
    "faults",
    "noise",
    "sensors",
    "sensor_faults",
    "filter",
];

/// How long one run lasts.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RunLength {
    /// Simulated seconds.
    Duration(f64),
    /// Number of samples after the one at t = 0.
    Cycles(u64),
}

/// A parsed, validated scenario.
#[derive(Clone, Debug)]
pub struct Scenario {
    /// Where it came from (for error messages).
    pub path: PathBuf,
    /// The source text, kept so sections can be parsed with exact error positions.
    pub text: String,
    /// Scenario name: letters, digits, `_` and `-` (used for output folder names).
    pub name: String,
    /// The system (registry name) this scenario drives.
    pub system: String,
    /// Free text.
    pub description: Option<String>,
    /// Sample time in seconds.
    pub dt: f64,
    /// Length of one run.
    pub length: RunLength,
    /// Base seed; run `i` uses [`Scenario::run_seed`]`(i)`.
    pub seed: u64,
    /// Default number of Monte-Carlo runs for `prognos campaign`.
    pub runs: usize,
    /// Stop a run at the sample where the truth reaches end of life.
    pub stop_at_eol: bool,
    /// Accuracy band of the alpha-lambda metric and the prognostic horizon (default 0.2).
    pub alpha: f64,
    /// Input profiles by input channel name.
    pub inputs: BTreeMap<String, InputProfile>,
    /// Faults the host injects between the sensor and the estimator (`[sensor_faults]`).
    pub sensor_faults: SensorFaults,
}

/// `[sensor_faults]`: faults injected into every measurement channel after the sensor
/// model, on their own seeded random stream (so a faulty run sees the same sensor noise as
/// the clean run of the same seed). All default to off.
///
/// ```toml
/// [sensor_faults]
/// dropout_probability = 0.05    # a sample is missing (NaN)
/// outlier_probability = 0.01    # a spike: y + outlier_std * N(0, 1)
/// outlier_std = 1.0
/// stuck_probability = 0.002     # the channel freezes at its last value ...
/// stuck_samples = 20            # ... for this many samples
/// nan_burst_probability = 0.001 # a run of NaN samples ...
/// nan_burst_samples = 10        # ... this long
/// bias_jump_time = 300.0        # from this time on (s) ...
/// bias_jump = 0.05              # ... every channel reads this much high
/// jitter_std = 0.1              # the sample time the estimator sees is t + N(0, jitter_std^2)
///                               # (clamped to +-0.4 dt so time still increases)
/// ```
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct SensorFaults {
    pub dropout_probability: f64,
    pub outlier_probability: f64,
    pub outlier_std: f64,
    pub stuck_probability: f64,
    pub stuck_samples: usize,
    pub nan_burst_probability: f64,
    pub nan_burst_samples: usize,
    pub bias_jump_time: Option<f64>,
    pub bias_jump: f64,
    pub jitter_std: f64,
}

impl SensorFaults {
    /// True when no fault is configured.
    pub fn is_off(&self) -> bool {
        *self == SensorFaults::default()
    }

    fn check(&self, scenario: &Scenario) -> Result<(), SimError> {
        let at = |key: &str, message: String| scenario.error_at(&["sensor_faults", key], message);
        for (key, p) in [
            ("dropout_probability", self.dropout_probability),
            ("outlier_probability", self.outlier_probability),
            ("stuck_probability", self.stuck_probability),
            ("nan_burst_probability", self.nan_burst_probability),
        ] {
            if !(0.0..=1.0).contains(&p) {
                return Err(at(key, format!("`{key}` must be in [0, 1], found {p}")));
            }
        }
        for (key, v) in [
            ("outlier_std", self.outlier_std),
            ("jitter_std", self.jitter_std),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(at(
                    key,
                    format!("`{key}` must be a non-negative number, found {v}"),
                ));
            }
        }
        if !self.bias_jump.is_finite() {
            return Err(at("bias_jump", "`bias_jump` must be finite".into()));
        }
        if let Some(t) = self.bias_jump_time
            && !t.is_finite()
        {
            return Err(at(
                "bias_jump_time",
                "`bias_jump_time` must be finite".into(),
            ));
        }
        Ok(())
    }
}

/// A deterministic input profile `u(t)`, written as an inline table with a `kind`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum InputProfile {
    /// `u = value`.
    Constant { value: f64 },
    /// `u = before` until `at`, then `after`.
    Step { before: f64, after: f64, at: f64 },
    /// `u = start + slope * t`.
    Ramp { start: f64, slope: f64 },
    /// `u = offset + amplitude * sin(2 pi t / period)`.
    Sine {
        offset: f64,
        amplitude: f64,
        period: f64,
    },
    /// `u = high` for the first `duty` fraction of each period, else `low`.
    Square {
        low: f64,
        high: f64,
        period: f64,
        #[serde(default = "half")]
        duty: f64,
    },
}

fn half() -> f64 {
    0.5
}

impl InputProfile {
    /// The input at time `t`.
    pub fn value(&self, t: f64) -> f64 {
        match *self {
            InputProfile::Constant { value } => value,
            InputProfile::Step { before, after, at } => {
                if t < at {
                    before
                } else {
                    after
                }
            }
            InputProfile::Ramp { start, slope } => start + slope * t,
            InputProfile::Sine {
                offset,
                amplitude,
                period,
            } => offset + amplitude * (std::f64::consts::TAU * t / period).sin(),
            InputProfile::Square {
                low,
                high,
                period,
                duty,
            } => {
                let phase = (t / period).rem_euclid(1.0);
                if phase < duty { high } else { low }
            }
        }
    }

    fn check(&self) -> Result<(), String> {
        match *self {
            InputProfile::Sine { period, .. } | InputProfile::Square { period, .. }
                if !(period.is_finite() && period > 0.0) =>
            {
                Err(format!("`period` must be positive, found {period}"))
            }
            InputProfile::Square { duty, .. } if !(0.0..=1.0).contains(&duty) => {
                Err(format!("`duty` must be in [0, 1], found {duty}"))
            }
            _ => Ok(()),
        }
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawScenario {
    name: Spanned<String>,
    system: String,
    #[serde(default)]
    description: Option<String>,
    dt: Spanned<f64>,
    #[serde(default)]
    duration: Option<Spanned<f64>>,
    #[serde(default)]
    cycles: Option<Spanned<u64>>,
    #[serde(default)]
    seed: u64,
    #[serde(default)]
    runs: Option<Spanned<usize>>,
    #[serde(default = "yes")]
    stop_at_eol: bool,
    #[serde(default)]
    alpha: Option<Spanned<f64>>,
    #[serde(default)]
    inputs: BTreeMap<String, Spanned<InputProfile>>,
    // System-specific sections, parsed later by the system with `Scenario::section`.
    #[serde(default)]
    plant: Option<toml::Value>,
    #[serde(default)]
    effects: Option<toml::Value>,
    #[serde(default)]
    faults: Option<toml::Value>,
    #[serde(default)]
    noise: Option<toml::Value>,
    #[serde(default)]
    sensors: Option<toml::Value>,
    #[serde(default)]
    sensor_faults: Option<toml::Value>,
    #[serde(default)]
    filter: Option<toml::Value>,
}

fn yes() -> bool {
    true
}

impl Scenario {
    /// Reads and validates a scenario file.
    pub fn load(path: &Path) -> Result<Self, SimError> {
        let text = read_input(path)?;
        Self::parse(path, &text)
    }

    /// Parses and validates scenario text; `path` names it in error messages.
    pub fn parse(path: &Path, text: &str) -> Result<Self, SimError> {
        let bad = |offset: usize, message: String| SimError::at_offset(path, text, offset, message);
        let raw: RawScenario =
            toml::from_str(text).map_err(|e| crate::dataio::toml_error(path, text, &e))?;
        let _ = (
            &raw.plant,
            &raw.effects,
            &raw.faults,
            &raw.noise,
            &raw.sensors,
            &raw.sensor_faults,
            &raw.filter,
        );
        let name = raw.name.get_ref();
        let name_ok = !name.is_empty()
            && name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-');
        if !name_ok {
            return Err(bad(
                raw.name.span().start,
                format!("`name` must be non-empty letters, digits, `_` or `-`, found {name:?}"),
            ));
        }
        let dt = *raw.dt.get_ref();
        if !(dt.is_finite() && dt > 0.0) {
            return Err(bad(
                raw.dt.span().start,
                format!("`dt` must be a positive number, found {dt}"),
            ));
        }
        let length = match (raw.duration, raw.cycles) {
            (Some(d), None) => {
                let v = *d.get_ref();
                if !(v.is_finite() && v > 0.0) {
                    return Err(bad(
                        d.span().start,
                        format!("`duration` must be a positive number, found {v}"),
                    ));
                }
                RunLength::Duration(v)
            }
            (None, Some(c)) => {
                if *c.get_ref() == 0 {
                    return Err(bad(c.span().start, "`cycles` must be at least 1".into()));
                }
                RunLength::Cycles(*c.get_ref())
            }
            (Some(_), Some(c)) => {
                return Err(bad(
                    c.span().start,
                    "give either `duration` or `cycles`, not both".into(),
                ));
            }
            (None, None) => {
                return Err(bad(0, "missing `duration` (seconds) or `cycles`".into()));
            }
        };
        let runs = match raw.runs {
            Some(r) if *r.get_ref() == 0 => {
                return Err(bad(r.span().start, "`runs` must be at least 1".into()));
            }
            Some(r) => *r.get_ref(),
            None => 1,
        };
        let alpha = match raw.alpha {
            Some(a) if !(*a.get_ref() > 0.0 && *a.get_ref() < 1.0) => {
                return Err(bad(a.span().start, "`alpha` must be in (0, 1)".into()));
            }
            Some(a) => *a.get_ref(),
            None => 0.2,
        };
        let mut inputs = BTreeMap::new();
        for (channel, profile) in raw.inputs {
            profile
                .get_ref()
                .check()
                .map_err(|m| bad(profile.span().start, format!("input `{channel}`: {m}")))?;
            inputs.insert(channel, profile.into_inner());
        }
        let mut scenario = Scenario {
            path: path.to_path_buf(),
            text: text.to_string(),
            name: raw.name.into_inner(),
            system: raw.system,
            description: raw.description,
            dt,
            length,
            seed: raw.seed,
            runs,
            stop_at_eol: raw.stop_at_eol,
            alpha,
            inputs,
            sensor_faults: SensorFaults::default(),
        };
        scenario.sensor_faults = scenario.section("sensor_faults")?;
        scenario.sensor_faults.check(&scenario)?;
        Ok(scenario)
    }

    /// Number of samples after t = 0 (the run logs `samples + 1` rows unless it stops at EOL).
    pub fn samples(&self) -> usize {
        match self.length {
            RunLength::Duration(d) => (d / self.dt - 1e-9).ceil().max(1.0) as usize,
            RunLength::Cycles(c) => usize::try_from(c).unwrap_or(usize::MAX),
        }
    }

    /// Seed of Monte-Carlo run `run`: a SplitMix64 mix of the base seed and the run index,
    /// so neighbouring runs get unrelated streams and run `i` is the same in every campaign.
    pub fn run_seed(&self, run: usize) -> u64 {
        crate::lockstep::mix_seed(self.seed, run as u64)
    }

    /// Parses the system-specific section `key` (one of [`SECTIONS`]) into `T`; a missing
    /// section gives `T::default()`. Errors carry the exact line and column in this file.
    pub fn section<T: DeserializeOwned + Default>(&self, key: &str) -> Result<T, SimError> {
        let root = toml::de::DeTable::parse(&self.text)
            .map_err(|e| crate::dataio::toml_error(&self.path, &self.text, &e))?;
        let value = root
            .into_inner()
            .into_iter()
            .find(|(k, _)| k.get_ref() == key)
            .map(|(_, v)| v);
        match value {
            None => Ok(T::default()),
            Some(v) => T::deserialize(v.into_deserializer())
                .map_err(|e| crate::dataio::toml_error(&self.path, &self.text, &e)),
        }
    }

    /// A [`SimError::BadInput`] pointing at the value of the key path `keys` (e.g.
    /// `["plant", "rate"]`), or at the start of the file when the key is absent.
    pub fn error_at(&self, keys: &[&str], message: impl Into<String>) -> SimError {
        SimError::at_offset(
            &self.path,
            &self.text,
            self.offset_of(keys).unwrap_or(0),
            message,
        )
    }

    fn offset_of(&self, keys: &[&str]) -> Option<usize> {
        let root = toml::de::DeTable::parse(&self.text).ok()?;
        let (first, rest) = keys.split_first()?;
        let mut current = root
            .get_ref()
            .iter()
            .find(|(k, _)| k.get_ref() == first)
            .map(|(k, v)| (k.span(), v))?;
        for key in rest {
            let table = current.1.get_ref().as_table()?;
            current = table
                .iter()
                .find(|(k, _)| k.get_ref() == key)
                .map(|(k, v)| (k.span(), v))?;
        }
        // Point at the value; a table defined by a `[header]` has no useful value span, so
        // point at its key instead.
        let (key_span, value) = current;
        Some(if value.get_ref().is_table() {
            key_span.start
        } else {
            value.span().start
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = r#"
name = "demo-1"
system = "linear_degradation"
dt = 0.5
duration = 10.0
seed = 3
runs = 4
[inputs]
load = { kind = "square", low = 0.0, high = 2.0, period = 4.0 }
[plant]
rate = 0.25
threshold = 1.0
"#;

    fn location(e: SimError) -> (usize, usize, String) {
        match e {
            SimError::BadInput {
                line,
                column,
                message,
                ..
            } => (line, column, message),
            other => panic!("expected BadInput, got {other}"),
        }
    }

    #[derive(Debug, Default, Deserialize, PartialEq)]
    #[serde(deny_unknown_fields)]
    struct Plant {
        rate: f64,
        threshold: f64,
    }

    #[test]
    fn parses_common_fields_and_sections() {
        let s = Scenario::parse(Path::new("s.toml"), GOOD).unwrap();
        assert_eq!(s.name, "demo-1");
        assert_eq!(s.samples(), 20);
        assert_eq!(s.runs, 4);
        assert!(s.stop_at_eol);
        let load = &s.inputs["load"];
        assert_eq!(load.value(0.5), 2.0);
        assert_eq!(load.value(2.5), 0.0);
        assert_eq!(load.value(4.1), 2.0);
        let plant: Plant = s.section("plant").unwrap();
        assert_eq!(
            plant,
            Plant {
                rate: 0.25,
                threshold: 1.0
            }
        );
        let filter: Option<Plant> = s.section("filter").unwrap();
        assert_eq!(filter, None);
        assert_ne!(s.run_seed(0), s.run_seed(1));
        let (l, c, _) = location(s.error_at(&["plant", "threshold"], "too big"));
        assert_eq!((l, c), (12, 13));
        let (l, c, _) = location(s.error_at(&["plant"], "x"));
        assert_eq!((l, c), (10, 2));
    }

    #[test]
    fn section_errors_are_located() {
        let text = GOOD.replace("threshold = 1.0", "threshold = 1.0\nthreshhold = 2.0");
        let s = Scenario::parse(Path::new("s.toml"), &text).unwrap();
        let (l, c, m) = location(s.section::<Plant>("plant").unwrap_err());
        assert_eq!((l, c), (13, 1));
        assert!(m.contains("threshhold"), "{m}");
        let text = GOOD.replace("rate = 0.25", "rate = \"fast\"");
        let s = Scenario::parse(Path::new("s.toml"), &text).unwrap();
        let (l, c, _) = location(s.section::<Plant>("plant").unwrap_err());
        assert_eq!((l, c), (11, 8));
    }

    #[test]
    fn top_level_errors_are_located() {
        let cases: [(&str, &str, (usize, usize)); 7] = [
            ("seed = 3", "seed = 3\ncolour = 1", (7, 1)),
            ("dt = 0.5", "dt = -0.5", (4, 6)),
            ("dt = 0.5", "dt = 0.5 0.6", (4, 6)),
            ("duration = 10.0", "duration = 10.0\ncycles = 5", (6, 10)),
            ("runs = 4", "runs = 0", (7, 8)),
            ("name = \"demo-1\"", "name = \"a b\"", (2, 8)),
            ("period = 4.0", "period = 0.0", (9, 8)),
        ];
        for (from, to, expected) in cases {
            let text = GOOD.replace(from, to);
            let (l, c, m) = location(Scenario::parse(Path::new("s.toml"), &text).unwrap_err());
            assert_eq!((l, c), expected, "{to}: {m}");
        }
        let text = GOOD.replace("duration = 10.0", "");
        let (l, c, m) = location(Scenario::parse(Path::new("s.toml"), &text).unwrap_err());
        assert_eq!((l, c), (1, 1));
        assert!(m.contains("duration"));
    }

    proptest::proptest! {
        #[test]
        fn arbitrary_text_never_panics(text in "\\PC{0,300}") {
            if let Err(SimError::BadInput { line, column, .. }) =
                Scenario::parse(Path::new("s.toml"), &text)
            {
                proptest::prop_assert!(line >= 1 && column >= 1);
            }
        }

        #[test]
        fn mutated_scenario_never_panics(position in 0usize..300, byte in proptest::prelude::any::<u8>()) {
            let mut bytes = GOOD.as_bytes().to_vec();
            let position = position % bytes.len();
            bytes[position] = byte;
            let text = String::from_utf8_lossy(&bytes);
            if let Ok(s) = Scenario::parse(Path::new("s.toml"), &text) {
                let _ = s.section::<Plant>("plant");
            }
        }
    }
}
