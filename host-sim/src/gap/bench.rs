//! `prognos gap-bench`: the diagnoser on data whose effect it is not told about.
//!
//! For each plant, datasets are generated from the *truth* plant (the reaction wheel's
//! `plants::reaction_wheel::TruthWheel` with every term switchable; the DC motor's equations
//! integrated with 4x finer steps and the extra torques) with: one catalogue effect at each
//! effect-to-noise ratio (ENR) and seed; no effect; two effects; an effect outside the
//! catalogue. The ENR of an effect is the RMS over the record of what it changes in the
//! noise-free measurement divided by the sensor noise std, on the channel it changes most
//! (that channel is the localisation target); the magnitude that gives each ENR is found by
//! bisection. The diagnoser sees only the CSV and a meta file with `plant` and `dt` (noise
//! is estimated from the data). Datasets can also be read from a folder and its subfolders
//! (`--datasets`): each `NAME.csv` with its meta file (`NAME.csv.meta.toml` or
//! `NAME.meta.toml`) and a label (`NAME.csv.label.toml` or `NAME.label.toml`: `kind` =
//! single | none | pair | unknown, `effects` = [...], `channel`, `ratio`) that only the bench
//! reads. A dataset without a label is diagnosed and listed, not scored; one that cannot be
//! read or diagnosed is listed with its error and counts as a miss of its kind.

use crate::dataio::{Recording, TimeSeries, parse_recording};
use crate::error::SimError;
use crate::gap::dc_motor::{DcMotorPlant, simulate_motor};
use crate::gap::diagnose::diagnose_recording;
use crate::gap::effects::GenericKind;
use crate::gap::meta::parse_gap_meta;
use crate::gap::plant::{GapPlant, InputTiming, PlantData};
use crate::gap::scooter::{ScooterGapPlant, simulate_scooter};
use crate::gap::start::{refit_start, start_sensitivities};
use crate::gap::valve::{TruthExtras as ValveTruthExtras, ValveGapPlant, simulate_valve};
use crate::lockstep::{SimRng, standard_normal, stream_rng, uniform};
use crate::output::{format_table, write_json, write_text};
use crate::plants::reaction_wheel::{TruthWheel, WheelEffects, WheelSensors};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// What a dataset contains.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CaseKind {
    /// One catalogue effect.
    Single,
    /// No effect.
    None,
    /// Two catalogue effects.
    Pair,
    /// An effect outside the catalogue.
    Unknown,
    /// No label file: diagnosed and listed, not scored.
    Unlabelled,
}

/// The label of one dataset (what the bench knows and the diagnoser does not).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Label {
    /// Kind.
    pub kind: CaseKind,
    /// Effect names as the diagnoser names them (`kind:channel` for generic ones); the
    /// out-of-catalogue effect's own name for `unknown`.
    #[serde(default)]
    pub effects: Vec<String>,
    /// The channel the effect changes most (`y:<name>`).
    #[serde(default)]
    pub channel: Option<String>,
    /// Effect-to-noise ratio (per effect for pairs); NaN when the label gives none.
    #[serde(default = "unrated")]
    pub ratio: f64,
    /// The truth's magnitude of each effect, in the unit the diagnoser fits it (written
    /// for the reader comparing fitted values; the bench does not read it).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub truth: BTreeMap<String, f64>,
}

fn unrated() -> f64 {
    f64::NAN
}

impl Label {
    /// The label of a dataset that has none.
    pub fn unlabelled() -> Self {
        Label {
            kind: CaseKind::Unlabelled,
            effects: Vec::new(),
            channel: None,
            ratio: f64::NAN,
            truth: BTreeMap::new(),
        }
    }

    /// Checks the label and writes its effects as the diagnoser names them: a sensor
    /// effect given without its channel (`sensor_bias` with `channel = "y:speed"`) or with
    /// the column's prefix (`sensor_bias:y:speed`) becomes `sensor_bias:speed`, and the
    /// spelling is folded (`Quantization`, `dead-zone`).
    fn normalised(mut self) -> Result<Self, String> {
        let needed = match self.kind {
            CaseKind::Single => Some(1),
            CaseKind::Pair => Some(2),
            _ => None,
        };
        if let Some(k) = needed
            && self.effects.len() != k
        {
            return Err(format!(
                "a `{}` label needs {k} effect name(s) in `effects`, found {}",
                serde_json::to_string(&self.kind)
                    .unwrap_or_default()
                    .trim_matches('"'),
                self.effects.len()
            ));
        }
        let channel = self
            .channel
            .as_deref()
            .map(|c| c.strip_prefix("y:").unwrap_or(c).to_string());
        if let Some(c) = &channel {
            self.channel = Some(format!("y:{c}"));
        }
        if matches!(self.kind, CaseKind::Single | CaseKind::Pair) {
            for e in &mut self.effects {
                let folded = e.trim().to_lowercase().replace(['-', ' '], "_");
                let (kind, on) = match folded.split_once(':') {
                    Some((k, c)) => (
                        k.to_string(),
                        Some(c.strip_prefix("y:").unwrap_or(c).to_string()),
                    ),
                    None => (folded.clone(), None),
                };
                let kind = match kind.as_str() {
                    "quantization" => "quantisation".to_string(),
                    _ => kind,
                };
                let generic = GenericKind::from_name(&kind).is_some();
                *e = match on.or_else(|| channel.clone().filter(|_| generic)) {
                    Some(c) => format!("{kind}:{c}"),
                    None => kind,
                };
            }
        }
        Ok(self)
    }
}

/// One dataset to diagnose.
#[derive(Clone, Debug)]
pub struct Dataset {
    /// Name (file stem).
    pub name: String,
    /// CSV text.
    pub csv: String,
    /// Meta text.
    pub meta: String,
    /// Label.
    pub label: Label,
    /// Folder the files were read from (`None`: generated).
    pub folder: Option<PathBuf>,
    /// Why the dataset's files could not be read (then it is not diagnosed).
    pub error: Option<String>,
}

/// One diagnosis of a dataset.
#[derive(Clone, Debug, Serialize)]
pub struct Outcome {
    /// Dataset name.
    pub name: String,
    /// Label.
    pub label: Label,
    /// Verdict.
    pub verdict: String,
    /// The first three ranking entries.
    pub top3: Vec<String>,
    /// Located channel.
    pub channel: String,
    /// The input timing the diagnosis read the record with (empty when it failed).
    pub input_timing: String,
    /// Held-out shrink of the verdict's effect (0 for none / unknown).
    pub shrink: f64,
    /// The plant's estimator's error against the truth columns with the user's model and
    /// with the verdict's effect added (when the record has truth columns and the plant an
    /// estimator).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub estimation_error: Option<[f64; 2]>,
    /// Candidates the held-out data do not separate from the verdict.
    pub confusable: Vec<String>,
    /// Every single and pair candidate, for offline study of the ranking (`bench.json`).
    pub candidates: Vec<CandidateRecord>,
    /// Noise std per channel used by the diagnosis.
    pub sigma: Vec<f64>,
    /// Per channel: training RSS, count, held-out RSS, count of the user's model.
    pub nominal_rss: Vec<[f64; 4]>,
    /// Why the dataset could not be read or diagnosed (its verdict is then `error`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

/// One fitted candidate as `bench.json` records it.
#[derive(Clone, Debug, Serialize)]
pub struct CandidateRecord {
    /// Effect name.
    pub effect: String,
    /// Score (nats over the user's model).
    pub score: f64,
    /// Held-out gap before and after, shrink.
    pub gap: [f64; 3],
    /// p-value of the worst held-out block (see `Evaluation::worst_block_p`).
    pub worst_block_p: f64,
    /// Per channel: training RSS, count, held-out RSS, count.
    pub rss: Vec<[f64; 4]>,
}

impl Outcome {
    fn top1(&self) -> bool {
        match self.label.kind {
            CaseKind::Single => self.verdict == self.label.effects[0],
            CaseKind::Pair => same_set(&self.verdict, &self.label.effects),
            CaseKind::None => self.verdict == "none",
            CaseKind::Unknown => self.verdict == "unknown",
            CaseKind::Unlabelled => false,
        }
    }
    fn top3_hit(&self) -> bool {
        match self.label.kind {
            CaseKind::Single => self.top3.iter().any(|e| *e == self.label.effects[0]),
            _ => self.top1(),
        }
    }
    /// Both effects among the three best single effects, or the verdict is the pair.
    fn pair_in_top3(&self) -> bool {
        same_set(&self.verdict, &self.label.effects)
            || self.label.effects.iter().all(|e| self.top3.contains(e))
    }
    /// The verdict or one of the candidates the data cannot tell from it is the effect.
    fn top1_up_to_confusable(&self) -> bool {
        self.top1()
            || (self.label.kind == CaseKind::Single
                && self.confusable.iter().any(|e| *e == self.label.effects[0]))
            || (self.label.kind == CaseKind::Pair
                && self
                    .confusable
                    .iter()
                    .any(|e| same_set(e, &self.label.effects)))
    }
    fn localised(&self) -> bool {
        self.label.channel.as_deref() == Some(self.channel.as_str())
    }
}

fn same_set(verdict: &str, effects: &[String]) -> bool {
    let mut a: Vec<&str> = verdict.split('+').collect();
    let mut b: Vec<&str> = effects.iter().map(String::as_str).collect();
    a.sort_unstable();
    b.sort_unstable();
    a == b
}

/// Bench settings.
#[derive(Clone, Debug)]
pub struct BenchOptions {
    /// Plants to generate for (`reaction_wheel`, `valve`, `scooter`, `dc_motor`).
    pub plants: Vec<String>,
    /// Seeds per (effect, ratio).
    pub seeds: usize,
    /// Effect-to-noise ratios.
    pub ratios: Vec<f64>,
    /// Base seed.
    pub seed: u64,
    /// Only these effects (all when empty).
    pub only: Vec<String>,
    /// Datasets of each extra kind per plant: this many with no effect, this many pairs,
    /// and this many per out-of-catalogue effect (ratios cycling 2, 4, 8).
    pub extra_sets: usize,
    /// Input profile of the generated records.
    pub excitation: Excitation,
    /// Per dataset, the plant's physical parameters (`BenchPlant::spread_params`) are
    /// drawn log-uniformly within a factor `exp(+-model_spread)` of the defaults, for the
    /// truth and the meta file's `[model]` alike (0: every dataset uses the defaults).
    pub model_spread: f64,
    /// Every sensor's noise std is the bench's default times this (effects are placed at
    /// their ratio to the scaled noise, so they scale with it).
    pub noise_scale: f64,
    /// The sample time is the bench's default times this, the record as long as by
    /// default (more or fewer samples).
    pub sample_time_scale: f64,
    /// How the written rows relate inputs and samples (the diagnoser is not told); `None`:
    /// each plant's own ([`GapPlant::native_timing`]).
    pub input_timing: Option<InputTiming>,
    /// Write the truth plant's states as `x:<name>` columns (the diagnosis then reports the
    /// estimator's error before and after, and the bench its median ratio).
    pub truth_columns: bool,
    /// The distribution of every sensor's noise (its std as without).
    pub noise_shape: NoiseShape,
}

/// What a bench plant varies from the bench's defaults.
#[derive(Clone, Copy, Debug)]
struct Variation {
    excitation: Excitation,
    model_spread: f64,
    noise_scale: f64,
    sample_time_scale: f64,
    input_timing: Option<InputTiming>,
    truth_columns: bool,
    noise_shape: NoiseShape,
}

impl Default for Variation {
    fn default() -> Self {
        Self {
            excitation: Excitation::Steps,
            model_spread: 0.0,
            noise_scale: 1.0,
            sample_time_scale: 1.0,
            input_timing: None,
            truth_columns: false,
            noise_shape: NoiseShape::Gaussian,
        }
    }
}

/// How the bench excites its truth plants. The diagnoser was developed on `Steps`; `Smooth`
/// (sums of slow sinusoids, other valve timings and supply pressures) and `Ramps`
/// (continuous commands with kinks, no jumps) check that nothing was tuned to the
/// staircases.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum Excitation {
    /// Piecewise-constant commands held for a random time (the bench's default).
    #[default]
    Steps,
    /// Sums of sinusoids with random periods and phases (valve: shorter and longer holds,
    /// drifting supply pressure).
    Smooth,
    /// Piecewise-linear commands between random levels over random durations (valve: holds
    /// of 2-10 s and a supply pressure ramping between levels).
    Ramps,
}

/// The distribution of the bench's sensor noise, each of unit variance before it is
/// scaled to the channel's std. The diagnoser's tests assume white Gaussian noise; the
/// others check how far that assumption carries.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum NoiseShape {
    /// White Gaussian (the bench's default).
    #[default]
    Gaussian,
    /// White, uniform on `+-sqrt(3)` (light tails, as a converter's dither).
    Uniform,
    /// White Laplace (excess kurtosis 3).
    Laplace,
    /// White Student-t with 5 degrees of freedom (excess kurtosis 6: occasional large
    /// readings).
    StudentT5,
    /// Gaussian, correlated from sample to sample: AR(1) with coefficient 0.5.
    Ar1,
}

impl NoiseShape {
    /// The next noise sample; `previous` is the channel's last one (AR(1) only).
    pub(crate) fn sample(self, rng: &mut SimRng, previous: f64) -> f64 {
        match self {
            Self::Gaussian => standard_normal(rng),
            Self::Uniform => 12f64.sqrt() * (uniform(rng) - 0.5),
            Self::Laplace => {
                // Inverse CDF of scale 1/sqrt(2); `ln` of (0, 1] stays finite.
                let u = uniform(rng) - 0.5;
                -(0.5f64).sqrt() * u.signum() * (1.0 - 2.0 * u.abs()).max(f64::MIN_POSITIVE).ln()
            }
            Self::StudentT5 => {
                let z = standard_normal(rng);
                let chi2: f64 = (0..5).map(|_| standard_normal(rng).powi(2)).sum();
                z / (chi2 / 5.0).sqrt() * (3.0f64 / 5.0).sqrt()
            }
            Self::Ar1 => 0.5 * previous + 0.75f64.sqrt() * standard_normal(rng),
        }
    }
}

/// Piecewise-linear through random levels in `mean +- amplitude`, one knot every
/// `durations` (uniform), starting at a random level.
fn ramp_signal(
    rng: &mut SimRng,
    t: &[f64],
    mean: f64,
    amplitude: f64,
    durations: (f64, f64),
) -> Vec<f64> {
    let t0 = t.first().copied().unwrap_or(0.0);
    let end = t.last().copied().unwrap_or(0.0);
    let mut knots = vec![(t0, mean + amplitude * (2.0 * uniform(rng) - 1.0))];
    while knots.last().is_some_and(|k| k.0 <= end) {
        let next =
            knots[knots.len() - 1].0 + durations.0 + (durations.1 - durations.0) * uniform(rng);
        knots.push((next, mean + amplitude * (2.0 * uniform(rng) - 1.0)));
    }
    let mut segment = 0;
    t.iter()
        .map(|&t| {
            while segment + 2 < knots.len() && knots[segment + 1].0 < t {
                segment += 1;
            }
            let ((ta, a), (tb, b)) = (knots[segment], knots[segment + 1]);
            a + (b - a) * ((t - ta) / (tb - ta)).clamp(0.0, 1.0)
        })
        .collect()
}

/// `mean + amplitude * s(t)` where `s` is a sum of `count` sinusoids with log-uniform
/// periods in `periods` and random phases, normalised to a peak of 1 over the record.
fn smooth_signal(
    rng: &mut SimRng,
    t: &[f64],
    mean: f64,
    amplitude: f64,
    periods: (f64, f64),
    count: usize,
) -> Vec<f64> {
    let tones: Vec<(f64, f64, f64)> = (0..count)
        .map(|_| {
            let period = (periods.0.ln() + uniform(rng) * (periods.1.ln() - periods.0.ln())).exp();
            let weight = 0.5 + uniform(rng);
            let phase = std::f64::consts::TAU * uniform(rng);
            (std::f64::consts::TAU / period, weight, phase)
        })
        .collect();
    let raw: Vec<f64> = t
        .iter()
        .map(|&t| tones.iter().map(|(w, a, p)| a * (w * t + p).sin()).sum())
        .collect();
    let peak = raw.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-12);
    raw.iter().map(|v| mean + amplitude * v / peak).collect()
}

impl Default for BenchOptions {
    fn default() -> Self {
        Self {
            plants: vec![
                "reaction_wheel".into(),
                "valve".into(),
                "scooter".into(),
                "dc_motor".into(),
            ],
            seeds: 3,
            ratios: vec![0.5, 1.0, 2.0, 4.0, 8.0],
            seed: 2026,
            only: Vec::new(),
            extra_sets: 12,
            excitation: Excitation::Steps,
            model_spread: 0.0,
            noise_scale: 1.0,
            sample_time_scale: 1.0,
            input_timing: None,
            truth_columns: false,
            noise_shape: NoiseShape::Gaussian,
        }
    }
}

/// Noise-free run of a truth plant: time, inputs, the measured channels and the states a
/// record's truth columns `x:<name>` hold.
#[derive(Clone, Debug)]
struct Clean {
    t: Vec<f64>,
    inputs: Vec<(String, Vec<f64>)>,
    outputs: Vec<Vec<f64>>,
    states: Vec<(String, Vec<f64>)>,
}

/// A truth plant the bench can generate from.
trait BenchPlant: Sync {
    fn plant(&self) -> &'static str;
    /// The bench's default sample time (s).
    fn default_dt(&self) -> f64;
    /// The sample time of the generated records.
    fn dt(&self) -> f64 {
        self.default_dt() * self.variation().sample_time_scale
    }
    /// Samples of a record that has `default` samples at the default sample time.
    fn samples(&self, default: usize) -> usize {
        (default as f64 / self.variation().sample_time_scale).round() as usize
    }
    fn outputs(&self) -> Vec<&'static str>;
    /// The bench's default sensor noise std per output.
    fn default_sigma(&self) -> Vec<f64>;
    /// The truth's sensor noise std per output.
    fn sigma(&self) -> Vec<f64> {
        let scale = self.variation().noise_scale;
        self.default_sigma()
            .into_iter()
            .map(|s| s * scale)
            .collect()
    }
    /// Catalogue effects the truth can switch on, with the range searched for a magnitude.
    fn plant_effects(&self) -> Vec<(&'static str, f64, f64, bool)>;
    /// Out-of-catalogue effects, with magnitude ranges.
    fn unknown_effects(&self) -> Vec<(&'static str, f64, f64, bool)>;
    /// The noise-free run for `seed` with effects `(name, magnitude)` on.
    fn clean(&self, seed: u64, effects: &[(&str, f64)]) -> Clean;
    /// The user's model where it departs from the plant's defaults: written to every
    /// dataset's `[model]` (all of a plant's datasets alike, so it says nothing about the
    /// effect) and the truth's starting point.
    fn model_params(&self) -> Vec<(&'static str, f64)> {
        Vec::new()
    }
    /// Physical parameters `--model-spread` draws per dataset (none that an effect sets).
    fn spread_params(&self) -> Vec<&'static str> {
        Vec::new()
    }
    fn variation(&self) -> Variation;
    /// The user's model of the dataset drawn with `seed`: [`BenchPlant::model_params`],
    /// then the spread parameters drawn around the plant's defaults.
    fn model(&self, seed: u64) -> Vec<(&'static str, f64)> {
        let mut model = self.model_params();
        let spread = self.variation().model_spread;
        if spread > 0.0 {
            let defaults = crate::gap::plant::builtin_plant(self.plant())
                .map(|p| p.default_params())
                .unwrap_or_default();
            let mut rng = stream_rng(seed, 31);
            for name in self.spread_params() {
                let factor = (spread * (2.0 * uniform(&mut rng) - 1.0)).exp();
                if let Some(v) = defaults.get(name) {
                    model.push((name, v * factor));
                }
            }
        }
        model
    }
}

struct WheelBench {
    vary: Variation,
}

/// Truth sub-steps per 20 Hz sample.
const WHEEL_SUBSTEPS: usize = 20;

impl BenchPlant for WheelBench {
    fn variation(&self) -> Variation {
        self.vary
    }
    fn spread_params(&self) -> Vec<&'static str> {
        vec![
            "inertia",
            "viscous_coefficient",
            "torque_constant",
            "drive_gain",
        ]
    }
    fn plant(&self) -> &'static str {
        "reaction_wheel"
    }
    fn default_dt(&self) -> f64 {
        0.05
    }
    fn outputs(&self) -> Vec<&'static str> {
        vec!["current", "speed"]
    }
    fn default_sigma(&self) -> Vec<f64> {
        vec![
            WheelSensors::LOW_NOISE.current_std,
            WheelSensors::LOW_NOISE.speed_std,
        ]
    }
    fn plant_effects(&self) -> Vec<(&'static str, f64, f64, bool)> {
        vec![
            ("coulomb_friction", 1e-9, 1e-1, true),
            ("torque_ripple", 1e-3, 1e4, true),
            ("cogging", 1e-9, 1e-1, true),
            ("driver_lowpass", 0.05, 1000.0, true),
            ("backemf_limit", 8.0, 40.0, false),
            ("speed_limiter", 50.0, 1200.0, false),
            ("lubricant_torque_noise", 1e-7, 10.0, true),
            ("viscous_temperature", 1e-12, 1e-5, true),
        ]
    }
    fn unknown_effects(&self) -> Vec<(&'static str, f64, f64, bool)> {
        vec![
            ("bearing_defect_torque_0.7hz", 1e-9, 1e-1, true),
            ("load_torque_step_midway", 1e-9, 1e-1, true),
        ]
    }
    fn clean(&self, seed: u64, effects: &[(&str, f64)]) -> Clean {
        let dt = self.dt();
        let n = self.samples(6000);
        let mut rng = stream_rng(seed, 11);
        let t: Vec<f64> = (0..n).map(|k| k as f64 * dt).collect();
        let command: Vec<f64> = match self.vary.excitation {
            Excitation::Steps => {
                let hold = (25.0 / dt) as usize;
                let levels: Vec<f64> = (0..n.div_ceil(hold))
                    .map(|i| {
                        if i == 0 {
                            2.0 + 2.5 * uniform(&mut rng)
                        } else {
                            -4.5 + 9.0 * uniform(&mut rng)
                        }
                    })
                    .collect();
                (0..n).map(|k| levels[k / hold]).collect()
            }
            // Slow sweeps through zero speed and back (the staircase rarely crosses zero).
            Excitation::Smooth => {
                let mean = -1.5 + 3.0 * uniform(&mut rng);
                smooth_signal(&mut rng, &t, mean, 4.0, (40.0, 400.0), 4)
            }
            Excitation::Ramps => ramp_signal(&mut rng, &t, 0.0, 4.5, (20.0, 120.0)),
        };
        let temp_phase = std::f64::consts::TAU * uniform(&mut rng);
        let noise_phase = std::f64::consts::TAU * uniform(&mut rng);
        let temperature: Vec<f64> = t
            .iter()
            .map(|t| 23.0 + 5.0 * (std::f64::consts::TAU * t / 300.0 + temp_phase).sin())
            .collect();
        let mut wheel = TruthWheel::new();
        wheel.effects = WheelEffects::none();
        wheel.noise_phase = noise_phase;
        for (name, v) in self.model(seed) {
            let p = &mut wheel.params;
            match name {
                "inertia" => p.inertia = v,
                "torque_constant" => p.torque_constant = v,
                "drive_gain" => p.drive_gain = v,
                // c_v at the model's reference temperature, the slope kept.
                "viscous_coefficient" => {
                    p.viscous_base = v + p.viscous_slope * (23.0 + 30.0);
                }
                _ => {}
            }
        }
        let frozen_viscous = wheel.params.viscous_coefficient(23.0);
        let (mut defect, mut load_step) = (0.0, 0.0);
        for &(name, m) in effects {
            let (e, p) = (&mut wheel.effects, &mut wheel.params);
            match name {
                "coulomb_friction" => (e.coulomb_friction, p.coulomb_friction) = (true, m),
                "torque_ripple" => (e.torque_ripple, p.torque_ripple) = (true, m),
                "cogging" => (e.cogging, p.cogging) = (true, m),
                "driver_lowpass" => (e.driver_lowpass, p.driver_bandwidth) = (true, m),
                "backemf_limit" => (e.emf_limiting, p.bus_voltage) = (true, m),
                "speed_limiter" => (e.speed_limiter, p.overspeed) = (true, m),
                "lubricant_torque_noise" => (e.torque_noise, p.noise_angle) = (true, m),
                "viscous_temperature" => {
                    // Keep c_v(23 degC) at the model's value: only the dependence is new.
                    e.viscous_temperature = true;
                    p.viscous_slope = m;
                    p.viscous_base = frozen_viscous + m * 53.0;
                }
                "bearing_defect_torque_0.7hz" => defect = m,
                "load_torque_step_midway" => load_step = m,
                _ => {}
            }
        }
        // Sub-steps: stable RK4 for driver bandwidths up to 1000 rad/s; the limiters'
        // algebraic loop follows the speed within a sample.
        let per_default_sample = if wheel.effects.driver_lowpass {
            WHEEL_SUBSTEPS
        } else if wheel.effects.emf_limiting || wheel.effects.speed_limiter {
            4
        } else {
            1
        };
        let substeps = (per_default_sample as f64 * self.vary.sample_time_scale)
            .ceil()
            .max(1.0) as usize;
        wheel.settle(command[0], temperature[0]);
        if wheel.effects.emf_limiting || wheel.effects.speed_limiter {
            // `settle` ignores the limiters: let them pull the wheel to its limited state
            // first, or the record opens with a snap from a state the wheel never reaches.
            for _ in 0..(20.0 / dt) as usize * substeps {
                wheel.step(command[0], temperature[0], dt / substeps as f64);
            }
            wheel.time = 0.0;
        }
        let (mut current, mut speed, mut angle) = (Vec::new(), Vec::new(), Vec::new());
        // The viscous coefficient acting at each sample: what the wheel's estimator tracks.
        let mut viscous = Vec::with_capacity(n);
        let inertia = wheel.params.inertia;
        let omega_d = std::f64::consts::TAU * 0.7;
        let current_at_row =
            self.vary.input_timing == Some(InputTiming::At) && !wheel.effects.driver_lowpass;
        for k in 0..n {
            viscous.push(wheel.viscous(temperature[k]));
            current.push(if current_at_row {
                wheel.current_following(command[k])
            } else {
                wheel.current
            });
            speed.push(wheel.speed);
            angle.push(wheel.angle);
            let t0 = wheel.time;
            for _ in 0..substeps {
                wheel.step(command[k], temperature[k], dt / substeps as f64);
            }
            // Extra torques outside the truth plant's equations, integrated exactly over
            // the step and added to the speed (operator splitting).
            if defect != 0.0 {
                wheel.speed += defect * ((omega_d * t0).cos() - (omega_d * (t0 + dt)).cos())
                    / omega_d
                    / inertia;
            }
            if load_step != 0.0 && t0 >= 150.0 {
                wheel.speed -= load_step * dt / inertia;
            }
        }
        Clean {
            t,
            inputs: vec![
                ("command".into(), command),
                ("temperature".into(), temperature),
                ("angle".into(), angle),
            ],
            states: vec![
                ("current".into(), current.clone()),
                ("speed".into(), speed.clone()),
                ("viscous_coefficient".into(), viscous),
            ],
            outputs: vec![current, speed],
        }
    }
}

struct MotorBench {
    vary: Variation,
}

impl BenchPlant for MotorBench {
    fn variation(&self) -> Variation {
        self.vary
    }
    fn spread_params(&self) -> Vec<&'static str> {
        vec![
            "resistance",
            "inductance",
            "motor_constant",
            "inertia",
            "viscous_friction",
        ]
    }
    fn plant(&self) -> &'static str {
        "dc_motor"
    }
    fn default_dt(&self) -> f64 {
        0.01
    }
    fn outputs(&self) -> Vec<&'static str> {
        vec!["current", "speed"]
    }
    fn default_sigma(&self) -> Vec<f64> {
        vec![0.02, 0.5]
    }
    fn plant_effects(&self) -> Vec<(&'static str, f64, f64, bool)> {
        vec![
            ("coulomb_friction", 1e-7, 1.0, true),
            ("brush_drop", 1e-4, 5.0, true),
        ]
    }
    fn unknown_effects(&self) -> Vec<(&'static str, f64, f64, bool)> {
        vec![
            ("load_ripple_7hz", 1e-7, 1.0, true),
            ("load_torque_step_midway", 1e-7, 1.0, true),
        ]
    }
    fn clean(&self, seed: u64, effects: &[(&str, f64)]) -> Clean {
        let dt = self.dt();
        let n = self.samples(2000);
        let mut rng = stream_rng(seed, 12);
        let mut data = PlantData {
            dt,
            ..Default::default()
        };
        data.t = (0..n).map(|k| k as f64 * dt).collect();
        let (voltage, load): (Vec<f64>, Vec<f64>) = match self.vary.excitation {
            Excitation::Steps => {
                let hold = (1.0 / dt) as usize;
                let levels: Vec<f64> = (0..n.div_ceil(hold))
                    .map(|_| -12.0 + 24.0 * uniform(&mut rng))
                    .collect();
                let load_levels: Vec<f64> = (0..n.div_ceil(2 * hold))
                    .map(|_| 0.02 * uniform(&mut rng))
                    .collect();
                (
                    (0..n).map(|k| levels[k / hold]).collect(),
                    (0..n).map(|k| load_levels[k / (2 * hold)]).collect(),
                )
            }
            Excitation::Smooth => (
                smooth_signal(&mut rng, &data.t, 0.0, 12.0, (0.4, 6.0), 5),
                smooth_signal(&mut rng, &data.t, 0.01, 0.01, (2.0, 15.0), 2),
            ),
            Excitation::Ramps => (
                ramp_signal(&mut rng, &data.t, 0.0, 12.0, (0.3, 3.0)),
                ramp_signal(&mut rng, &data.t, 0.01, 0.01, (1.0, 6.0)),
            ),
        };
        data.inputs.insert("voltage".into(), voltage);
        data.inputs.insert("load_torque".into(), load);
        let mut params = DcMotorPlant.default_params();
        for (name, v) in self.model(seed) {
            params.insert(name.to_string(), v);
        }
        let mut active = Vec::new();
        let (mut ripple, mut step) = (0.0, 0.0);
        for &(name, m) in effects {
            match name {
                "coulomb_friction" | "brush_drop" => {
                    params.insert(name.to_string(), m);
                    active.push(name);
                }
                "load_ripple_7hz" => ripple = m,
                "load_torque_step_midway" => step = m,
                _ => {}
            }
        }
        let omega = std::f64::consts::TAU * 7.0;
        let extra = move |t: f64| ripple * (omega * t).sin() + if t >= 10.0 { step } else { 0.0 };
        // Start at rest: the diagnoser sees the first measurement, the truth starts at 0.
        let sim = simulate_motor(&params, &active, &data, 4, &extra).unwrap_or_default();
        Clean {
            t: data.t.clone(),
            inputs: data.inputs.into_iter().collect(),
            outputs: sim.outputs,
            states: sim.states.into_iter().collect(),
        }
    }
}

struct ValveBench {
    vary: Variation,
}

impl BenchPlant for ValveBench {
    fn variation(&self) -> Variation {
        self.vary
    }
    fn plant(&self) -> &'static str {
        "valve"
    }
    fn default_dt(&self) -> f64 {
        0.05
    }
    fn outputs(&self) -> Vec<&'static str> {
        vec!["x", "pt", "pb", "q"]
    }
    fn default_sigma(&self) -> Vec<f64> {
        // The project's valve filter noise (data/progpy-valve/gap meta files).
        vec![1e-4, 5e3, 5e3, 5e-3]
    }
    fn plant_effects(&self) -> Vec<(&'static str, f64, f64, bool)> {
        vec![
            ("friction_increase", 6000.0, 1.0e5, true),
            ("spring_weakening", 2.0e3, 48000.0, true),
            ("internal_leak", 1e-12, 1e-4, true),
            ("top_external_leak", 1e-12, 1e-4, true),
            ("bottom_external_leak", 1e-12, 1e-4, true),
            ("seal_contact", 1e5, 1e11, true),
            // The critical pressure ratio: no change below the lowest ratio the orifices
            // see (a vented chamber compressed above supply falls below p_atm / p_s =
            // 0.019), the ideal nozzle at the top.
            (
                "choked_flow",
                1e-3,
                crate::gap::valve::ISENTROPIC_CRITICAL_RATIO,
                true,
            ),
        ]
    }
    fn model_params(&self) -> Vec<(&'static str, f64)> {
        // The user's valve model lacks choking: its orifices follow the non-choked law at
        // every pressure ratio (the truth adds choking with `choked_flow`).
        vec![("critical_pressure_ratio", 0.0)]
    }
    fn unknown_effects(&self) -> Vec<(&'static str, f64, f64, bool)> {
        vec![
            ("supply_pressure_drop_midway", 1e-6, 0.9, true),
            ("inlet_pressure_sensor_offset", 1.0, 3.0e5, true),
        ]
    }
    fn clean(&self, seed: u64, effects: &[(&str, f64)]) -> Clean {
        let dt = self.dt();
        let mut rng = stream_rng(seed, 14);
        // Closed for 2 s, then cycles: open for 3-6 s, closed for 3-6 s, 90 s in all.
        let n = (90.0 / dt) as usize;
        let mut open = vec![false; n];
        let mut k = (2.0 / dt) as usize;
        let mut state = true;
        let (hold_min, hold_span) = match self.vary.excitation {
            Excitation::Steps => (3.0, 3.0),
            Excitation::Smooth => (1.5, 7.5),
            Excitation::Ramps => (2.0, 8.0),
        };
        while k < n {
            let hold = ((hold_min + hold_span * uniform(&mut rng)) / dt) as usize;
            for o in open.iter_mut().skip(k).take(hold) {
                *o = state;
            }
            k += hold;
            state = !state;
        }
        let pl = 3.0e5 + 1.0e5 * uniform(&mut rng);
        let pr = 1.5e5 + 0.5e5 * uniform(&mut rng);
        let mut data = PlantData {
            dt,
            ..Default::default()
        };
        data.t = (0..n).map(|k| k as f64 * dt).collect();
        let supply = match self.vary.excitation {
            Excitation::Steps => vec![pl; n],
            // The supply sags and recovers by up to 15 % over the record.
            Excitation::Smooth => {
                smooth_signal(&mut rng, &data.t, pl, 0.15 * (pl - pr), (30.0, 120.0), 2)
            }
            Excitation::Ramps => ramp_signal(&mut rng, &data.t, pl, 0.15 * (pl - pr), (10.0, 40.0)),
        };
        data.inputs.insert("pl".into(), supply);
        data.inputs.insert("pr".into(), vec![pr; n]);
        data.inputs.insert(
            "top_port_supply".into(),
            open.iter().map(|o| if *o { 0.0 } else { 1.0 }).collect(),
        );
        data.inputs.insert(
            "bottom_port_supply".into(),
            open.iter().map(|o| if *o { 1.0 } else { 0.0 }).collect(),
        );
        let mut params = ValveGapPlant.default_params();
        for (name, v) in self.model(seed) {
            params.insert(name.to_string(), v);
        }
        let mut active = Vec::new();
        // The model's own step: a finer truth shows the semi-implicit scheme's own error
        // at 0.01 s as a significant gap in the no-effect sets (a real model deficiency,
        // but none the catalogue names).
        let mut extras = ValveTruthExtras::default();
        for &(name, m) in effects {
            let param = match name {
                "friction_increase" => "friction",
                "spring_weakening" => "spring",
                "internal_leak" => "internal_leak_area",
                "top_external_leak" => "top_leak_area",
                "bottom_external_leak" => "bottom_leak_area",
                "seal_contact" => "seal_stiffness",
                "choked_flow" => "critical_pressure_ratio",
                "supply_pressure_drop_midway" => {
                    (extras.supply_drop_from, extras.supply_drop) = (45.0, m);
                    continue;
                }
                "inlet_pressure_sensor_offset" => {
                    extras.inlet_offset = m;
                    continue;
                }
                _ => continue,
            };
            params.insert(param.to_string(), m);
            active.push(name);
        }
        let sim = simulate_valve(&params, &active, &data, &extras).unwrap_or_default();
        let mut states: Vec<(String, Vec<f64>)> = sim.states.into_iter().collect();
        // The damage the valve's estimator tracks, constant in the truth.
        for (state, param) in crate::gap::valve::ESTIMATED_DAMAGE {
            states.push((state.to_string(), vec![params[param]; data.len()]));
        }
        Clean {
            t: data.t.clone(),
            inputs: data.inputs.into_iter().collect(),
            outputs: sim.outputs,
            states,
        }
    }
}

struct ScooterBench {
    vary: Variation,
}

impl BenchPlant for ScooterBench {
    fn variation(&self) -> Variation {
        self.vary
    }
    fn spread_params(&self) -> Vec<&'static str> {
        vec![
            "drive_gain",
            "mass",
            "motor_inertia",
            "rear_viscous",
            "front_viscous",
        ]
    }
    fn plant(&self) -> &'static str {
        "scooter"
    }
    fn default_dt(&self) -> f64 {
        0.02
    }
    fn outputs(&self) -> Vec<&'static str> {
        vec!["rear_speed", "body_speed", "front_speed"]
    }
    fn default_sigma(&self) -> Vec<f64> {
        let s = crate::plants::scooter::SensorNoise::default();
        vec![s.rear, s.body, s.front]
    }
    fn plant_effects(&self) -> Vec<(&'static str, f64, f64, bool)> {
        vec![
            ("rear_coulomb_friction", 5.955e-2, 5.0, true),
            ("front_coulomb_friction", 1.857e-3, 1.0, true),
            ("shaft_compliance", 0.1, 10.02, true),
            ("encoder_efficiency", 0.3, 1.0, false),
            ("speed_sensor_efficiency", 0.3, 1.0, false),
            ("motor_resistance_drift", 0.0, 2.0, false),
        ]
    }
    fn unknown_effects(&self) -> Vec<(&'static str, f64, f64, bool)> {
        vec![
            ("road_grade_force_step_midway", 1e-6, 50.0, true),
            ("body_force_ripple_1.5hz", 1e-6, 50.0, true),
        ]
    }
    fn clean(&self, seed: u64, effects: &[(&str, f64)]) -> Clean {
        let dt = self.dt();
        let n = self.samples(3000);
        let mut rng = stream_rng(seed, 15);
        // Driver input held 2-4 s at levels in [-1, 3] V (reversals exercise the dry
        // friction's sign), starting from rest.
        let mut data = PlantData {
            dt,
            ..Default::default()
        };
        data.t = (0..n).map(|k| k as f64 * dt).collect();
        let voltage = match self.vary.excitation {
            Excitation::Steps => {
                let mut voltage = Vec::with_capacity(n);
                while voltage.len() < n {
                    let hold = ((2.0 + 2.0 * uniform(&mut rng)) / dt) as usize;
                    let level = -1.0 + 4.0 * uniform(&mut rng);
                    voltage.extend(std::iter::repeat_n(level, hold));
                }
                voltage.truncate(n);
                voltage
            }
            Excitation::Smooth => smooth_signal(&mut rng, &data.t, 1.0, 2.0, (2.0, 20.0), 4),
            Excitation::Ramps => ramp_signal(&mut rng, &data.t, 1.0, 2.0, (1.0, 8.0)),
        };
        data.inputs.insert("voltage".into(), voltage);
        let mut params = ScooterGapPlant.default_params();
        for (name, v) in self.model(seed) {
            params.insert(name.to_string(), v);
        }
        let (mut grade, mut ripple) = (0.0, 0.0);
        for &(name, m) in effects {
            let param = match name {
                "rear_coulomb_friction" => "rear_coulomb",
                "front_coulomb_friction" => "front_coulomb",
                "shaft_compliance" => "rear_shaft_stiffness",
                "encoder_efficiency" => "beta_theta_r",
                "speed_sensor_efficiency" => "beta_v",
                "motor_resistance_drift" => "resistance_drift",
                "road_grade_force_step_midway" => {
                    grade = m;
                    continue;
                }
                "body_force_ripple_1.5hz" => {
                    ripple = m;
                    continue;
                }
                _ => continue,
            };
            params.insert(param.to_string(), m);
        }
        let omega = std::f64::consts::TAU * 1.5;
        let half = 0.5 * n as f64 * dt;
        let force = move |t: f64| ripple * (omega * t).sin() - if t >= half { grade } else { 0.0 };
        let sim = simulate_scooter(&params, &data, 4, &force).unwrap_or_default();
        let mut states: Vec<(String, Vec<f64>)> = sim.states.into_iter().collect();
        // The fault parameters the scooter's estimator tracks, constant in the truth.
        for (name, _) in crate::gap::scooter::ESTIMATED_PARAMETERS {
            states.push((name.to_string(), vec![params[name]; n]));
        }
        Clean {
            t: data.t.clone(),
            inputs: data.inputs.into_iter().collect(),
            outputs: sim.outputs,
            states,
        }
    }
}

fn rms_ratio(a: &[Vec<f64>], b: &[Vec<f64>], sigma: &[f64]) -> (f64, usize) {
    let mut best = (0.0, 0usize);
    for c in 0..a.len().min(b.len()) {
        let n = a[c].len().max(1) as f64;
        let r = (a[c]
            .iter()
            .zip(&b[c])
            .map(|(x, y)| (x - y).powi(2))
            .sum::<f64>()
            / n)
            .sqrt()
            / sigma[c];
        let r = if r.is_finite() { r } else { f64::INFINITY };
        if r > best.0 {
            best = (r, c);
        }
    }
    best
}

/// Finds the magnitude in `[lo, hi]` whose ENR is `target` (bisection on the search scale;
/// the ENR is monotone in the magnitude). `None` when the range cannot reach it.
fn solve_magnitude(
    enr: &dyn Fn(f64) -> f64,
    lo: f64,
    hi: f64,
    log: bool,
    target: f64,
) -> Option<f64> {
    let at = |u: f64| {
        if log {
            (lo.ln() + u * (hi.ln() - lo.ln())).exp()
        } else {
            lo + u * (hi - lo)
        }
    };
    let (e0, e1) = (enr(at(0.0)), enr(at(1.0)));
    if std::env::var_os("GAP_BENCH_DEBUG").is_some() {
        eprintln!("enr range [{lo}, {hi}]: {e0} .. {e1}, target {target}");
    }
    let increasing = e1 > e0;
    let (min, max) = if increasing { (e0, e1) } else { (e1, e0) };
    if !(target > min && target < max) {
        return None;
    }
    let (mut a, mut b) = (0.0, 1.0);
    for _ in 0..24 {
        let m = 0.5 * (a + b);
        let e = enr(at(m));
        if (e < target) == increasing {
            a = m;
        } else {
            b = m;
        }
    }
    Some(at(0.5 * (a + b)))
}

/// Applies a generic effect to a clean channel (quantisation is applied after the noise).
fn apply_generic(kind: GenericKind, p: f64, y: &[f64], dt: f64) -> Vec<f64> {
    if kind == GenericKind::Quantisation {
        y.to_vec()
    } else {
        kind.apply(&[p], y, dt)
    }
}

fn generic_range(kind: GenericKind, sigma: f64, amplitude: f64, dt: f64) -> (f64, f64, bool) {
    match kind {
        GenericKind::SensorBias => (1e-3 * sigma, 100.0 * sigma, true),
        GenericKind::SensorScale => (1e-8, 0.5, true),
        GenericKind::Quantisation => (0.01 * sigma, 100.0 * sigma, true),
        GenericKind::MeasurementDelay => (0.01 * dt, 25.0 * dt, true),
        GenericKind::OutputSaturation => (0.05 * amplitude, amplitude, false),
        GenericKind::DeadZone => (1e-6 * amplitude, 0.5 * amplitude, true),
        GenericKind::FirstOrderLag => (0.01 * dt, 200.0 * dt, true),
    }
}

struct Spec {
    plant_effects: Vec<(String, f64)>,
    generic: Vec<(GenericKind, usize, f64)>,
}

fn noisy(bp: &dyn BenchPlant, clean: &Clean, spec: &Spec, seed: u64) -> Vec<Vec<f64>> {
    let sigma = bp.sigma();
    let mut rng: SimRng = stream_rng(seed, 13);
    let mut out: Vec<Vec<f64>> = clean.outputs.clone();
    for &(kind, ch, p) in &spec.generic {
        out[ch] = apply_generic(kind, p, &out[ch], bp.dt());
    }
    let shape = bp.variation().noise_shape;
    for (c, y) in out.iter_mut().enumerate() {
        let mut previous = 0.0;
        for v in y.iter_mut() {
            previous = shape.sample(&mut rng, previous);
            *v += sigma[c] * previous;
        }
    }
    for &(kind, ch, p) in &spec.generic {
        if kind == GenericKind::Quantisation {
            out[ch] = kind.apply(&[p], &out[ch], bp.dt());
        }
    }
    out
}

fn to_csv(bp: &dyn BenchPlant, clean: &Clean, measured: &[Vec<f64>]) -> String {
    let truth: &[(String, Vec<f64>)] = if bp.variation().truth_columns {
        &clean.states
    } else {
        &[]
    };
    let mut header = vec!["t".to_string()];
    header.extend(clean.inputs.iter().map(|(n, _)| format!("u:{n}")));
    header.extend(bp.outputs().iter().map(|n| format!("y:{n}")));
    header.extend(truth.iter().map(|(n, _)| format!("x:{n}")));
    let mut ts = TimeSeries::new(header);
    for k in 0..clean.t.len() {
        let mut row = vec![clean.t[k]];
        row.extend(clean.inputs.iter().map(|(_, v)| v[k]));
        row.extend(measured.iter().map(|v| v[k]));
        row.extend(
            truth
                .iter()
                .map(|(_, v)| v.get(k).copied().unwrap_or(f64::NAN)),
        );
        ts.rows.push(row);
    }
    let mut buf = Vec::new();
    let _ = ts.write_csv(&mut buf);
    String::from_utf8(buf).unwrap_or_default()
}

fn meta_text(bp: &dyn BenchPlant, seed: u64) -> String {
    let mut text = format!(
        "plant = \"{}\"\ndt = {}\ndescription = \"gap-bench dataset\"\n",
        bp.plant(),
        bp.dt()
    );
    let model = bp.model(seed);
    if !model.is_empty() {
        text.push_str("[model]\n");
        for (name, v) in model {
            text.push_str(&format!("{name} = {v:?}\n"));
        }
    }
    text
}

/// ENR of a spec (relative to the clean run without effects) and the channel it changes most.
fn spec_enr(bp: &dyn BenchPlant, seed: u64, base: &Clean, spec: &Spec) -> (f64, usize) {
    let effects: Vec<(&str, f64)> = spec
        .plant_effects
        .iter()
        .map(|(n, m)| (n.as_str(), *m))
        .collect();
    let (clean, reference) = if effects.is_empty() {
        (base.clone(), base.outputs.clone())
    } else {
        let clean = bp.clean(seed, &effects);
        let reference = visible_reference(bp, seed, &clean).unwrap_or_else(|| base.outputs.clone());
        (clean, reference)
    };
    let mut out = clean.outputs.clone();
    for &(kind, ch, p) in &spec.generic {
        out[ch] = if kind == GenericKind::Quantisation {
            // Quantisation error of the noisy signal is what the sensor adds.
            let noise = noisy(
                bp,
                &clean,
                &Spec {
                    plant_effects: vec![],
                    generic: vec![],
                },
                seed,
            );
            let q = kind.apply(&[p], &noise[ch], bp.dt());
            out[ch]
                .iter()
                .zip(noise[ch].iter().zip(&q))
                .map(|(c, (n, qv))| c + qv - n)
                .collect()
        } else {
            apply_generic(kind, p, &out[ch], bp.dt())
        };
    }
    rms_ratio(&out, &reference, &bp.sigma())
}

/// What the user's model predicts for a noise-free run with plant effects: the nominal gap
/// plant replayed over the run's inputs from its first sample, with the initial state then
/// refitted by least squares as the diagnoser does. A plant effect's ratio is measured
/// against it rather than against the truth's own run without the effect, which may start
/// from another state (a truth that settles under a speed limiter starts slower), and
/// whatever a free initial state absorbs (an effect that acts only in the first seconds of
/// a slow wheel) is no gap the diagnoser can see either.
fn visible_reference(bp: &dyn BenchPlant, seed: u64, clean: &Clean) -> Option<Vec<Vec<f64>>> {
    let plant = crate::gap::plant::builtin_plant(bp.plant())?;
    let mut data = PlantData {
        t: clean.t.clone(),
        dt: bp.dt(),
        // The clean run's own first sample: a window fit would be off by the curvature of
        // a record that starts in a transient.
        initial_window: 0.0,
        // Other timings are written from a run in the plant's own (see `dataset`).
        input_timing: match bp.variation().input_timing {
            Some(InputTiming::At) => InputTiming::At,
            _ => plant.native_timing(),
        },
        ..Default::default()
    };
    data.inputs = clean.inputs.iter().cloned().collect();
    data.outputs = bp
        .outputs()
        .iter()
        .zip(&clean.outputs)
        .map(|(n, y)| (n.to_string(), y.clone()))
        .collect();
    let mut params = plant.default_params();
    for (name, v) in bp.model(seed) {
        params.insert(name.to_string(), v);
    }
    let active = plant.model_effects(&params);
    let all = plant.outputs();
    let replay = |data: &PlantData| -> Option<Vec<Vec<f64>>> {
        let sim = plant.simulate(&params, &active, data).ok()?;
        bp.outputs()
            .iter()
            .map(|o| {
                let i = all.iter().position(|a| a == o)?;
                sim.outputs.get(i).cloned()
            })
            .collect()
    };
    let raw = replay(&data)?;
    let sigma = bp.sigma();
    let starts: Vec<(String, f64)> = bp
        .outputs()
        .iter()
        .zip(&sigma)
        .map(|(n, s)| (n.to_string(), *s))
        .collect();
    let sens = start_sensitivities(&data, &starts, &raw, replay);
    let reference = refit_start(&raw, &sens, &clean.outputs, &sigma, |_| true, |s| s);
    Some(reference)
}

/// One component to place at a target ENR.
#[derive(Clone, Debug)]
enum Part {
    Plant(&'static str, f64, f64, bool),
    Generic(GenericKind, usize),
}

fn part_name(bp: &dyn BenchPlant, p: &Part) -> String {
    match p {
        Part::Plant(n, ..) => n.to_string(),
        Part::Generic(k, ch) => match bp.outputs().get(*ch) {
            // A generic effect the plant names itself (the scooter's encoder efficiency
            // is the rear encoder's sensor scale) is labelled with the plant's name.
            Some(c) => crate::gap::plant::builtin_plant(bp.plant())
                .and_then(|plant| {
                    plant.effects().into_iter().find(|e| {
                        e.replaces_generic
                            .iter()
                            .any(|(kind, channel)| *kind == k.name() && channel == c)
                    })
                })
                .map_or_else(|| format!("{}:{c}", k.name()), |e| e.name.to_string()),
            None => k.name().to_string(),
        },
    }
}

/// The spec of `part` at `target` ENR, or `None` when its range cannot reach it.
fn place(bp: &dyn BenchPlant, seed: u64, base: &Clean, part: &Part, target: f64) -> Option<Spec> {
    match part {
        Part::Plant(name, lo, hi, log) => {
            let enr = |m: f64| {
                spec_enr(
                    bp,
                    seed,
                    base,
                    &Spec {
                        plant_effects: vec![(name.to_string(), m)],
                        generic: vec![],
                    },
                )
                .0
            };
            let m = solve_magnitude(&enr, *lo, *hi, *log, target)?;
            Some(Spec {
                plant_effects: vec![(name.to_string(), m)],
                generic: vec![],
            })
        }
        Part::Generic(kind, ch) => {
            let amplitude = base.outputs[*ch].iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let (lo, hi, log) = generic_range(*kind, bp.sigma()[*ch], amplitude, bp.dt());
            let enr = |m: f64| {
                spec_enr(
                    bp,
                    seed,
                    base,
                    &Spec {
                        plant_effects: vec![],
                        generic: vec![(*kind, *ch, m)],
                    },
                )
                .0
            };
            let m = solve_magnitude(&enr, lo, hi, log, target)?;
            Some(Spec {
                plant_effects: vec![],
                generic: vec![(*kind, *ch, m)],
            })
        }
    }
}

fn dataset(bp: &dyn BenchPlant, name: String, seed: u64, spec: &Spec, mut label: Label) -> Dataset {
    label.truth = spec
        .plant_effects
        .iter()
        .map(|(n, m)| (n.clone(), *m))
        .chain(
            spec.generic
                .iter()
                .map(|(k, ch, m)| (part_name(bp, &Part::Generic(*k, *ch)), *m)),
        )
        .collect();
    let effects: Vec<(&str, f64)> = spec
        .plant_effects
        .iter()
        .map(|(n, m)| (n.as_str(), *m))
        .collect();
    let mut clean = bp.clean(seed, &effects);
    let measured = noisy(bp, &clean, spec, seed);
    if let (Some(timing), Some(plant)) = (
        bp.variation().input_timing,
        crate::gap::plant::builtin_plant(bp.plant()),
    ) {
        // The run is in the plant's own timing; `after` rows show the input that acted over
        // the step ending at them, `before` rows the one acting from them on.
        let sampled = plant.sampled_inputs();
        let rows = timing.rows_late() - plant.native_timing().rows_late();
        for (name, u) in clean.inputs.iter_mut() {
            if !sampled.contains(&name.as_str()) {
                crate::gap::plant::shift_rows(u, rows);
            }
        }
    }
    Dataset {
        name,
        csv: to_csv(bp, &clean, &measured),
        meta: meta_text(bp, seed),
        label,
        folder: None,
        error: None,
    }
}

fn bench_plant(name: &str, vary: Variation) -> Option<Box<dyn BenchPlant>> {
    match name {
        "reaction_wheel" => Some(Box::new(WheelBench { vary })),
        "dc_motor" => Some(Box::new(MotorBench { vary })),
        "valve" => Some(Box::new(ValveBench { vary })),
        "scooter" => Some(Box::new(ScooterBench { vary })),
        _ => None,
    }
}

/// Generates the datasets of one plant.
pub fn generate(plant: &str, opts: &BenchOptions) -> Result<Vec<Dataset>, SimError> {
    let vary = Variation {
        excitation: opts.excitation,
        model_spread: opts.model_spread,
        noise_scale: opts.noise_scale,
        sample_time_scale: opts.sample_time_scale,
        input_timing: opts.input_timing,
        truth_columns: opts.truth_columns,
        noise_shape: opts.noise_shape,
    };
    let bp = bench_plant(plant, vary)
        .ok_or_else(|| SimError::Run(format!("gap-bench has no generator for plant `{plant}`")))?;
    let bp = bp.as_ref();
    let n_out = bp.outputs().len();
    let mut parts: Vec<Part> = bp
        .plant_effects()
        .into_iter()
        .map(|(n, lo, hi, log)| Part::Plant(n, lo, hi, log))
        .collect();
    for kind in GenericKind::ALL {
        parts.push(Part::Generic(kind, usize::MAX));
    }
    let wanted = |p: &Part| {
        opts.only.is_empty()
            || opts.only.iter().any(|o| match p {
                Part::Plant(n, ..) => o == n,
                Part::Generic(k, _) => o == k.name(),
            })
    };
    let mut jobs: Vec<(String, u64, Part, f64, CaseKind)> = Vec::new();
    for part in parts.iter().filter(|p| wanted(p)) {
        for &ratio in &opts.ratios {
            for s in 0..opts.seeds {
                let seed = crate::lockstep::mix_seed(opts.seed, jobs.len() as u64);
                jobs.push((
                    format!(
                        "{plant}-{}-r{ratio}-s{s}",
                        part_name(bp, part).replace(':', "_")
                    ),
                    seed,
                    part.clone(),
                    ratio,
                    CaseKind::Single,
                ));
            }
        }
    }
    let mut out: Vec<Dataset> = jobs
        .par_iter()
        .filter_map(|(name, seed, part, ratio, _)| {
            let base = bp.clean(*seed, &[]);
            // Generic effects go on the seed's preferred channel, else the other one.
            let candidates: Vec<Part> = match part {
                Part::Generic(k, _) => {
                    let first = (*seed as usize) % n_out;
                    (0..n_out)
                        .map(|i| Part::Generic(*k, (first + i) % n_out))
                        .collect()
                }
                p => vec![p.clone()],
            };
            candidates.iter().find_map(|p| {
                let spec = place(bp, *seed, &base, p, *ratio)?;
                let (_, ch) = spec_enr(bp, *seed, &base, &spec);
                let label = Label {
                    kind: CaseKind::Single,
                    effects: vec![part_name(bp, p)],
                    channel: Some(format!("y:{}", bp.outputs()[ch])),
                    ratio: *ratio,
                    truth: BTreeMap::new(),
                };
                Some(dataset(bp, name.clone(), *seed, &spec, label))
            })
        })
        .collect();
    let extra_seeds = opts.extra_sets;
    for s in 0..extra_seeds {
        let seed = crate::lockstep::mix_seed(opts.seed ^ 0xA5A5, s as u64);
        let label = Label {
            kind: CaseKind::None,
            effects: vec![],
            channel: None,
            ratio: 0.0,
            truth: BTreeMap::new(),
        };
        out.push(dataset(
            bp,
            format!("{plant}-none-s{s}"),
            seed,
            &Spec {
                plant_effects: vec![],
                generic: vec![],
            },
            label,
        ));
    }
    // Pairs: two distinct plant effects (or a plant effect and a sensor effect when the
    // plant has fewer than two), each at ratio 2, 4 or 8.
    let plant_parts: Vec<Part> = parts
        .iter()
        .filter(|p| matches!(p, Part::Plant(..)))
        .cloned()
        .collect();
    let pair_jobs: Vec<(u64, usize)> = (0..extra_seeds)
        .map(|s| (crate::lockstep::mix_seed(opts.seed ^ 0x5A5A, s as u64), s))
        .collect();
    let pairs: Vec<Dataset> = pair_jobs
        .par_iter()
        .filter_map(|&(seed, s)| {
            let mut rng = stream_rng(seed, 21);
            let i = (uniform(&mut rng) * plant_parts.len() as f64) as usize % plant_parts.len();
            let second = if plant_parts.len() >= 2 {
                let mut j = (uniform(&mut rng) * (plant_parts.len() - 1) as f64) as usize
                    % (plant_parts.len() - 1);
                if j >= i {
                    j += 1;
                }
                plant_parts[j].clone()
            } else {
                let k = GenericKind::ALL[(uniform(&mut rng) * 7.0) as usize % 7];
                Part::Generic(k, 1 % n_out)
            };
            let ratio = [2.0, 4.0, 8.0][s % 3];
            let base = bp.clean(seed, &[]);
            let a = place(bp, seed, &base, &plant_parts[i], ratio)?;
            let b = place(bp, seed, &base, &second, ratio)?;
            let spec = Spec {
                plant_effects: a.plant_effects.into_iter().chain(b.plant_effects).collect(),
                generic: a.generic.into_iter().chain(b.generic).collect(),
            };
            let (_, ch) = spec_enr(bp, seed, &base, &spec);
            let names = vec![part_name(bp, &plant_parts[i]), part_name(bp, &second)];
            let label = Label {
                kind: CaseKind::Pair,
                channel: Some(format!("y:{}", bp.outputs()[ch])),
                effects: names.clone(),
                ratio,
                truth: BTreeMap::new(),
            };
            Some(dataset(
                bp,
                format!(
                    "{plant}-pair-{}-r{ratio}-s{s}",
                    names.join("+").replace(':', "_")
                ),
                seed,
                &spec,
                label,
            ))
        })
        .collect();
    out.extend(pairs);
    let unknown_jobs: Vec<(usize, f64, usize)> = (0..bp.unknown_effects().len())
        .flat_map(|u| (0..extra_seeds).map(move |s| (u, [2.0, 4.0, 8.0][s % 3], s)))
        .collect();
    let unknowns: Vec<Dataset> = unknown_jobs
        .par_iter()
        .filter_map(|&(u, ratio, s)| {
            let (name, lo, hi, log) = bp.unknown_effects()[u];
            let seed = crate::lockstep::mix_seed(
                opts.seed ^ 0x3C3C,
                (u * 100 + s) as u64 + (ratio as u64) * 10_000,
            );
            let base = bp.clean(seed, &[]);
            let spec = place(bp, seed, &base, &Part::Plant(name, lo, hi, log), ratio)?;
            let (_, ch) = spec_enr(bp, seed, &base, &spec);
            let label = Label {
                kind: CaseKind::Unknown,
                effects: vec![name.to_string()],
                channel: Some(format!("y:{}", bp.outputs()[ch])),
                ratio,
                truth: BTreeMap::new(),
            };
            Some(dataset(
                bp,
                format!("{plant}-unknown-{name}-r{ratio}-s{s}"),
                seed,
                &spec,
                label,
            ))
        })
        .collect();
    out.extend(unknowns);
    Ok(out)
}

/// Diagnoses one dataset from its texts alone.
pub fn run_one(d: &Dataset) -> Result<Outcome, SimError> {
    if let Some(e) = &d.error {
        return Err(SimError::Run(e.clone()));
    }
    let folder = d.folder.clone().unwrap_or_default();
    let csv_path = folder.join(format!("{}.csv", d.name));
    let meta_path = match &d.folder {
        Some(_) => crate::gap::meta::find_gap_meta(&csv_path),
        None => folder.join(format!("{}.csv.meta.toml", d.name)),
    };
    let recording: Recording = parse_recording(&csv_path, &d.csv)?;
    let meta = parse_gap_meta(&meta_path, &d.meta)?;
    let diag = diagnose_recording(&csv_path, &recording, &meta)?;
    let chosen = diag
        .ranking
        .iter()
        .chain(&diag.pairs)
        .find(|e| e.effect == diag.verdict);
    let shrink = chosen.map_or(0.0, |e| e.shrink);
    let estimation_error =
        chosen.and_then(|e| Some([e.estimation_error_before?, e.estimation_error_after?]));
    Ok(Outcome {
        name: d.name.clone(),
        label: d.label.clone(),
        verdict: diag.verdict.clone(),
        top3: diag
            .ranking
            .iter()
            .take(3)
            .map(|e| e.effect.clone())
            .collect(),
        channel: diag.location.channel.clone(),
        input_timing: diag.input_timing.timing.name().to_string(),
        shrink,
        estimation_error,
        confusable: diag.confusable.iter().map(|c| c.effect.clone()).collect(),
        candidates: diag
            .ranking
            .iter()
            .chain(&diag.pairs)
            .map(|e| CandidateRecord {
                effect: e.effect.clone(),
                score: e.score,
                gap: [e.gap_before, e.gap_after, e.shrink],
                worst_block_p: e.worst_block_p,
                rss: e.channel_rss.clone(),
            })
            .collect(),
        sigma: diag.noise.iter().map(|n| n.std).collect(),
        nominal_rss: diag.nominal_rss.clone(),
        error: None,
    })
}

/// [`run_one`], with an error recorded as the outcome (verdict `error`) instead of returned.
pub fn outcome(d: &Dataset) -> Outcome {
    run_one(d).unwrap_or_else(|e| Outcome {
        name: d.name.clone(),
        label: d.label.clone(),
        verdict: "error".into(),
        top3: Vec::new(),
        channel: String::new(),
        input_timing: String::new(),
        shrink: 0.0,
        estimation_error: None,
        confusable: Vec::new(),
        candidates: Vec::new(),
        sigma: Vec::new(),
        nominal_rss: Vec::new(),
        error: Some(e.to_string()),
    })
}

/// Every `*.csv` under `dir`, subfolders included, sorted.
fn csv_files(dir: &Path, out: &mut Vec<PathBuf>) -> Result<(), SimError> {
    let entries = std::fs::read_dir(dir).map_err(|e| SimError::Unreadable {
        path: dir.to_path_buf(),
        message: e.to_string(),
    })?;
    let mut paths: Vec<PathBuf> = entries.filter_map(|e| e.ok().map(|e| e.path())).collect();
    paths.sort();
    for p in paths {
        if p.is_dir() {
            csv_files(&p, out)?;
        } else if p.extension().is_some_and(|x| x == "csv") {
            out.push(p);
        }
    }
    Ok(())
}

/// The first of `NAME.csv<suffix>` and `NAME<suffix>` that exists.
fn sidecar(csv: &Path, suffix: &str) -> Option<PathBuf> {
    let mut beside = csv.as_os_str().to_owned();
    beside.push(suffix);
    let stem = csv.with_extension(suffix.trim_start_matches('.'));
    [PathBuf::from(beside), stem]
        .into_iter()
        .find(|p| p.exists())
}

/// Reads one dataset; a file that cannot be read becomes the dataset's `error`.
fn read_dataset(root: &Path, csv: &Path) -> Dataset {
    // The path below the folder names the dataset, so that subfolders stay apart.
    let (folder, name) = match csv.strip_prefix(root) {
        Ok(relative) => (
            root.to_path_buf(),
            relative.with_extension("").to_string_lossy().into_owned(),
        ),
        Err(_) => (
            csv.parent().map(Path::to_path_buf).unwrap_or_default(),
            csv.file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default(),
        ),
    };
    let mut d = Dataset {
        name,
        csv: String::new(),
        meta: String::new(),
        label: Label::unlabelled(),
        folder: Some(folder),
        error: None,
    };
    let read = || -> Result<(String, String, Label), SimError> {
        let label = match sidecar(csv, ".label.toml") {
            Some(path) => {
                let text = crate::error::read_input(&path)?;
                let label: Label = toml::from_str(&text)
                    .map_err(|e| crate::dataio::toml_error(&path, &text, &e))?;
                label
                    .normalised()
                    .map_err(|m| SimError::at_offset(&path, &text, 0, m))?
            }
            None => Label::unlabelled(),
        };
        let csv_text = crate::error::read_input(csv)?;
        let meta = crate::gap::meta::read_gap_meta(csv, None)?;
        Ok((csv_text, meta.text, label))
    };
    match read() {
        Ok((csv_text, meta, label)) => {
            d.csv = csv_text;
            d.meta = meta;
            d.label = label;
        }
        Err(e) => {
            // The label, when it reads, still says what kind of miss this is.
            if let Some(path) = sidecar(csv, ".label.toml")
                && let Ok(text) = std::fs::read_to_string(&path)
                && let Ok(label) = toml::from_str::<Label>(&text)
                && let Ok(label) = label.normalised()
            {
                d.label = label;
            }
            d.error = Some(e.to_string());
        }
    }
    d
}

/// Reads the datasets under a folder (see the module docs). Fails only when the folder
/// cannot be listed or holds no CSV file; a bad dataset is kept with its error.
pub fn read_datasets(dir: &Path) -> Result<Vec<Dataset>, SimError> {
    let mut paths = Vec::new();
    csv_files(dir, &mut paths)?;
    if paths.is_empty() {
        return Err(SimError::Unreadable {
            path: dir.to_path_buf(),
            message: "no `*.csv` dataset in this folder or its subfolders".into(),
        });
    }
    Ok(paths.iter().map(|p| read_dataset(dir, p)).collect())
}

/// Writes datasets to a folder in the format [`read_datasets`] reads.
pub fn write_datasets(dir: &Path, datasets: &[Dataset]) -> Result<(), SimError> {
    for d in datasets {
        write_text(&dir.join(format!("{}.csv", d.name)), &d.csv)?;
        write_text(&dir.join(format!("{}.csv.meta.toml", d.name)), &d.meta)?;
        let label = toml::to_string(&d.label).map_err(|e| SimError::Run(e.to_string()))?;
        write_text(&dir.join(format!("{}.csv.label.toml", d.name)), &label)?;
    }
    Ok(())
}

/// Accuracy figures of a set of outcomes.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Scores {
    /// Single-effect datasets.
    pub singles: usize,
    /// Verdict = the effect.
    pub top1: f64,
    /// Effect among the first three.
    pub top3: f64,
    /// Verdict, or a candidate the data do not separate from it, = the effect.
    pub top1_up_to_confusable: f64,
    /// Mean number of candidates reported confusable with the verdict.
    pub mean_confusable: f64,
    /// Located channel = the channel the effect changes most.
    pub localisation: f64,
    /// Median held-out shrink of the verdict's effect.
    pub median_shrink: f64,
    /// Single-effect datasets correctly attributed whose records have truth columns and
    /// whose plant has an estimator.
    pub estimated: usize,
    /// Median over them of the estimator's error with the fitted effect over its error
    /// with the user's model (below 1: the diagnosis improves the estimates).
    pub median_estimation_ratio: f64,
    /// No-effect datasets.
    pub nones: usize,
    /// Fraction of no-effect datasets with a verdict other than `none`.
    pub false_attribution: f64,
    /// Out-of-catalogue datasets.
    pub unknowns: usize,
    /// Fraction of them with verdict `unknown`.
    pub unknown_recall: f64,
    /// Pair datasets.
    pub pairs: usize,
    /// Fraction with both effects among the first three entries.
    pub pair_in_top3: f64,
}

fn frac(v: &[&Outcome], f: impl Fn(&Outcome) -> bool) -> f64 {
    if v.is_empty() {
        f64::NAN
    } else {
        v.iter().filter(|o| f(o)).count() as f64 / v.len() as f64
    }
}

/// Scores of the outcomes whose ratio passes `keep` (none-sets always count).
pub fn score(outcomes: &[Outcome], keep: impl Fn(f64) -> bool) -> Scores {
    let singles: Vec<&Outcome> = outcomes
        .iter()
        .filter(|o| o.label.kind == CaseKind::Single && keep(o.label.ratio))
        .collect();
    let nones: Vec<&Outcome> = outcomes
        .iter()
        .filter(|o| o.label.kind == CaseKind::None)
        .collect();
    let unknowns: Vec<&Outcome> = outcomes
        .iter()
        .filter(|o| o.label.kind == CaseKind::Unknown && keep(o.label.ratio))
        .collect();
    let pairs: Vec<&Outcome> = outcomes
        .iter()
        .filter(|o| o.label.kind == CaseKind::Pair && keep(o.label.ratio))
        .collect();
    let shrinks: Vec<f64> = singles.iter().map(|o| o.shrink).collect();
    let estimation_ratios: Vec<f64> = singles
        .iter()
        .filter(|o| o.top1())
        .filter_map(|o| o.estimation_error)
        .filter(|[before, _]| *before > 0.0)
        .map(|[before, after]| after / before)
        .collect();
    Scores {
        singles: singles.len(),
        top1: frac(&singles, Outcome::top1),
        top3: frac(&singles, Outcome::top3_hit),
        top1_up_to_confusable: frac(&singles, Outcome::top1_up_to_confusable),
        mean_confusable: if singles.is_empty() {
            f64::NAN
        } else {
            singles
                .iter()
                .map(|o| o.confusable.len() as f64)
                .sum::<f64>()
                / singles.len() as f64
        },
        // A label without a channel does not score localisation.
        localisation: frac(
            &singles
                .iter()
                .copied()
                .filter(|o| o.label.channel.is_some())
                .collect::<Vec<_>>(),
            Outcome::localised,
        ),
        median_shrink: crate::gap::stats::median(&shrinks).unwrap_or(f64::NAN),
        estimated: estimation_ratios.len(),
        median_estimation_ratio: crate::gap::stats::median(&estimation_ratios).unwrap_or(f64::NAN),
        nones: nones.len(),
        false_attribution: frac(&nones, |o| o.verdict != "none"),
        unknowns: unknowns.len(),
        unknown_recall: frac(&unknowns, |o| o.verdict == "unknown"),
        pairs: pairs.len(),
        pair_in_top3: frac(&pairs, Outcome::pair_in_top3),
    }
}

fn fixed3(v: f64) -> String {
    if v.is_nan() {
        "-".into()
    } else {
        format!("{v:.3}")
    }
}

fn pct(v: f64) -> String {
    if v.is_nan() {
        "-".into()
    } else {
        format!("{:.1} %", 100.0 * v)
    }
}

/// The printed summary: overall at ratio >= 2 against the targets, per ratio, per effect.
pub fn summary(outcomes: &[Outcome]) -> String {
    let mut s = String::new();
    // Labels written without a ratio cannot be split by it: then every set counts.
    let rated = outcomes
        .iter()
        .any(|o| o.label.kind != CaseKind::None && o.label.ratio.is_finite());
    let headline = |r: f64| if rated { r >= 2.0 } else { true };
    let at2 = score(outcomes, headline);
    let unlabelled = outcomes
        .iter()
        .filter(|o| o.label.kind == CaseKind::Unlabelled)
        .count();
    let failed = outcomes.iter().filter(|o| o.error.is_some()).count();
    let mut timings: Vec<(&str, usize)> = Vec::new();
    for o in outcomes.iter().filter(|o| !o.input_timing.is_empty()) {
        match timings.iter_mut().find(|(t, _)| *t == o.input_timing) {
            Some((_, n)) => *n += 1,
            None => timings.push((&o.input_timing, 1)),
        }
    }
    let timings: Vec<String> = timings.iter().map(|(t, n)| format!("{n} {t}")).collect();
    s.push_str(&format!(
        "gap-bench: {} datasets ({unlabelled} without a label, {failed} not diagnosed; \
         inputs read as {})\n\n{}\n",
        outcomes.len(),
        if timings.is_empty() {
            "-".to_string()
        } else {
            timings.join(", ")
        },
        if rated {
            "At effect-to-noise ratio >= 2 (targets in brackets):"
        } else {
            "Every labelled dataset (the labels give no effect-to-noise ratio):"
        }
    ));
    let mut rows = vec![
        vec![
            "top-1 attribution".into(),
            pct(at2.top1),
            ">= 90 %".into(),
            at2.singles.to_string(),
        ],
        vec![
            "top-3 attribution".into(),
            pct(at2.top3),
            ">= 98 %".into(),
            at2.singles.to_string(),
        ],
        vec![
            if at2.mean_confusable.is_nan() {
                "top-1 up to a confusable set".into()
            } else {
                format!(
                    "top-1 up to a confusable set (mean {:.2} others)",
                    at2.mean_confusable
                )
            },
            pct(at2.top1_up_to_confusable),
            "-".into(),
            at2.singles.to_string(),
        ],
        vec![
            "channel localisation".into(),
            pct(at2.localisation),
            ">= 95 %".into(),
            at2.singles.to_string(),
        ],
        vec![
            "false attribution (no effect)".into(),
            pct(at2.false_attribution),
            "<= 5 %".into(),
            at2.nones.to_string(),
        ],
        vec![
            "unknown recall".into(),
            pct(at2.unknown_recall),
            ">= 80 %".into(),
            at2.unknowns.to_string(),
        ],
        vec![
            "median held-out shrink".into(),
            fixed3(at2.median_shrink),
            ">= 0.8".into(),
            at2.singles.to_string(),
        ],
        vec![
            "pair: both in top 3".into(),
            pct(at2.pair_in_top3),
            ">= 80 %".into(),
            at2.pairs.to_string(),
        ],
    ];
    if at2.estimated > 0 {
        rows.push(vec![
            "estimator error, effect added / user's model (median, correct verdicts)".into(),
            fixed3(at2.median_estimation_ratio),
            "-".into(),
            at2.estimated.to_string(),
        ]);
    }
    s.push_str(&format_table(
        &["metric", "measured", "target", "datasets"],
        &rows,
    ));
    let mut ratios: Vec<f64> = outcomes
        .iter()
        .filter(|o| o.label.kind == CaseKind::Single)
        .map(|o| o.label.ratio)
        .collect();
    ratios.sort_by(f64::total_cmp);
    ratios.dedup_by(|a, b| a == b || (a.is_nan() && b.is_nan()));
    s.push_str("\nSingle effects per effect-to-noise ratio:\n");
    let rows: Vec<Vec<String>> = ratios
        .iter()
        .map(|&r| {
            let sc = score(outcomes, |x| x == r || (x.is_nan() && r.is_nan()));
            vec![
                if r.is_nan() {
                    "unrated".into()
                } else {
                    format!("{r}")
                },
                sc.singles.to_string(),
                pct(sc.top1),
                pct(sc.top3),
                pct(sc.localisation),
                fixed3(sc.median_shrink),
                pct(sc.unknown_recall),
                pct(sc.pair_in_top3),
            ]
        })
        .collect();
    s.push_str(&format_table(
        &[
            "ratio",
            "datasets",
            "top-1",
            "top-3",
            "localisation",
            "median shrink",
            "unknown recall",
            "pair in top 3",
        ],
        &rows,
    ));
    let mut effects: Vec<String> = outcomes
        .iter()
        .filter(|o| o.label.kind == CaseKind::Single)
        .map(|o| effect_family(&o.label.effects[0]))
        .collect();
    effects.sort();
    effects.dedup();
    s.push_str(&format!(
        "\nPer effect{} (generic effects over every channel):\n",
        if rated { ", ratio >= 2" } else { "" }
    ));
    let rows: Vec<Vec<String>> = effects
        .iter()
        .map(|e| {
            let sub: Vec<Outcome> = outcomes
                .iter()
                .filter(|o| {
                    o.label.kind == CaseKind::Single && effect_family(&o.label.effects[0]) == *e
                })
                .cloned()
                .collect();
            let sc = score(&sub, headline);
            let lo = score(&sub, |r| r < 2.0);
            vec![
                e.clone(),
                sc.singles.to_string(),
                pct(sc.top1),
                pct(sc.top3),
                pct(sc.localisation),
                fixed3(sc.median_shrink),
                pct(lo.top1),
            ]
        })
        .collect();
    s.push_str(&format_table(
        &[
            "effect",
            "datasets",
            "top-1",
            "top-3",
            "localisation",
            "median shrink",
            "top-1 below 2",
        ],
        &rows,
    ));
    let misses: Vec<&Outcome> = outcomes
        .iter()
        .filter(|o| {
            o.label.kind != CaseKind::Unlabelled
                && o.error.is_none()
                && !o.top1()
                && (o.label.kind == CaseKind::None || headline(o.label.ratio))
        })
        .collect();
    if !misses.is_empty() {
        s.push_str(&format!(
            "\nMisses{} (dataset: verdict; top 3):\n",
            if rated { " at ratio >= 2" } else { "" }
        ));
        for o in misses {
            let confusable = if o.confusable.is_empty() {
                String::new()
            } else {
                format!(" (confusable: {})", o.confusable.join(", "))
            };
            s.push_str(&format!(
                "  {}: {}{confusable}; {}\n",
                o.name,
                o.verdict,
                o.top3.join(", ")
            ));
        }
    }
    let listed = |s: &mut String, title: &str, rows: Vec<String>| {
        if !rows.is_empty() {
            s.push_str(&format!("\n{title}:\n"));
            for r in rows {
                s.push_str(&format!("  {r}\n"));
            }
        }
    };
    listed(
        &mut s,
        "Not diagnosed (each a miss of its label's kind)",
        outcomes
            .iter()
            .filter_map(|o| Some(format!("{}: {}", o.name, o.error.as_ref()?)))
            .collect(),
    );
    listed(
        &mut s,
        "Without a label (dataset: verdict; top 3)",
        outcomes
            .iter()
            .filter(|o| o.label.kind == CaseKind::Unlabelled && o.error.is_none())
            .map(|o| format!("{}: {}; {}", o.name, o.verdict, o.top3.join(", ")))
            .collect(),
    );
    s
}

fn effect_family(name: &str) -> String {
    name.split(':').next().unwrap_or(name).to_string()
}

/// Generates (or reads), diagnoses and summarises; writes `bench.json` and `summary.txt`
/// to `out` when given, and the datasets to `write` when given.
pub fn run_bench(
    opts: &BenchOptions,
    datasets_dir: Option<&Path>,
    write: Option<&Path>,
    out: Option<&Path>,
) -> Result<(Vec<Outcome>, String), SimError> {
    let mut datasets = Vec::new();
    match datasets_dir {
        Some(dir) => datasets = read_datasets(dir)?,
        None => {
            for p in &opts.plants {
                datasets.extend(generate(p, opts)?);
            }
        }
    }
    if let Some(w) = write {
        write_datasets(w, &datasets)?;
    }
    let outcomes: Vec<Outcome> = datasets.par_iter().map(outcome).collect();
    let text = summary(&outcomes);
    if let Some(o) = out {
        write_json(&o.join("bench.json"), &outcomes)?;
        write_text(&o.join("summary.txt"), &text)?;
    }
    Ok((outcomes, text))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_noise_shape_has_unit_variance_and_its_own_tails_and_correlation() {
        // (shape, share of samples beyond 3 std, lag-1 correlation); a share rather
        // than the kurtosis, whose estimate the t5's rare extremes dominate.
        let expected = [
            (NoiseShape::Gaussian, 0.0027, 0.0),
            (NoiseShape::Uniform, 0.0, 0.0),
            (NoiseShape::Laplace, 0.01437, 0.0),
            (NoiseShape::StudentT5, 0.01172, 0.0),
            (NoiseShape::Ar1, 0.0027, 0.5),
        ];
        for (shape, beyond_3, correlation) in expected {
            let mut rng: SimRng = stream_rng(5, 13);
            let mut previous = 0.0;
            let e: Vec<f64> = (0..400_000)
                .map(|_| {
                    previous = shape.sample(&mut rng, previous);
                    previous
                })
                .collect();
            let n = e.len() as f64;
            let mean = e.iter().sum::<f64>() / n;
            let var = e.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
            let lag1 = e
                .windows(2)
                .map(|w| (w[0] - mean) * (w[1] - mean))
                .sum::<f64>()
                / n;
            let share = e.iter().filter(|v| v.abs() > 3.0).count() as f64 / n;
            assert!(mean.abs() < 0.01, "{shape:?} mean {mean}");
            assert!((var - 1.0).abs() < 0.03, "{shape:?} variance {var}");
            // Binomial std of the share: below 2e-4 at these counts.
            assert!(
                (share - beyond_3).abs() < 8e-4,
                "{shape:?} beyond 3 std {share}"
            );
            assert!(
                (lag1 / var - correlation).abs() < 0.01,
                "{shape:?} lag 1 {lag1}"
            );
        }
    }

    /// Per plant, a catalogue effect whose smallest bench magnitude leaves the truth as
    /// good as nominal.
    const VANISHING: [(&str, &str, f64); 4] = [
        ("reaction_wheel", "coulomb_friction", 1e-9),
        ("dc_motor", "coulomb_friction", 1e-7),
        ("valve", "internal_leak", 1e-12),
        ("scooter", "motor_resistance_drift", 0.0),
    ];

    #[test]
    fn a_vanishing_plant_effect_has_a_vanishing_ratio_for_every_input_and_model() {
        // The ratio is measured against the user's model replayed from the clean run's
        // start: whatever the inputs and the drawn parameters, that replay is the truth
        // without the effect. (A window-fitted start put a smooth wheel record at 31.)
        for excitation in [Excitation::Steps, Excitation::Smooth, Excitation::Ramps] {
            for model_spread in [0.0, 0.4] {
                let vary = Variation {
                    excitation,
                    model_spread,
                    ..Variation::default()
                };
                for (plant, effect, magnitude) in VANISHING {
                    let bp = bench_plant(plant, vary).unwrap();
                    let base = bp.clean(5, &[]);
                    let spec = Spec {
                        plant_effects: vec![(effect.to_string(), magnitude)],
                        generic: Vec::new(),
                    };
                    let (enr, _) = spec_enr(bp.as_ref(), 5, &base, &spec);
                    // Not 0: the motor and scooter truths take 4x finer steps than the model.
                    assert!(
                        enr < 0.1,
                        "{plant} {excitation:?} spread {model_spread}: {enr}"
                    );
                }
            }
        }
    }

    #[test]
    fn ramps_are_continuous_within_their_range_and_pass_through_their_levels() {
        let mut rng = stream_rng(3, 11);
        let t: Vec<f64> = (0..6000).map(|k| k as f64 * 0.05).collect();
        let r = ramp_signal(&mut rng, &t, 1.0, 2.0, (20.0, 120.0));
        assert_eq!(r.len(), t.len());
        assert!(r.iter().all(|v| (-1.0..=3.0).contains(v)));
        // The steepest ramp crosses the whole range in the shortest duration.
        let steepest = 4.0 / 20.0 * 0.05;
        assert!(
            r.windows(2)
                .all(|w| (w[1] - w[0]).abs() <= steepest + 1e-12)
        );
        // Kinks: the slope changes, and a 300 s record holds at least 2 of them.
        let slopes: Vec<f64> = r.windows(2).map(|w| w[1] - w[0]).collect();
        let kinks = slopes
            .windows(2)
            .filter(|s| (s[1] - s[0]).abs() > 1e-9)
            .count();
        assert!((2..=30).contains(&kinks), "{kinks} kinks");
    }

    #[test]
    fn labels_from_elsewhere_name_effects_as_the_diagnoser_does() {
        let read = |text: &str| toml::from_str::<Label>(text).unwrap().normalised();
        let l = read("kind = \"single\"\neffects = [\"Dead-Zone\"]\nchannel = \"speed\"").unwrap();
        assert_eq!(l.effects, ["dead_zone:speed"]);
        assert_eq!(l.channel.as_deref(), Some("y:speed"));
        assert!(l.ratio.is_nan());
        let l = read("kind = \"pair\"\neffects = [\"quantization:y:pb\", \"choked_flow\"]\nchannel = \"y:pt\"\nratio = 4").unwrap();
        assert_eq!(l.effects, ["quantisation:pb", "choked_flow"]);
        assert_eq!(l.ratio, 4.0);
        let e = read("kind = \"pair\"\neffects = [\"cogging\"]").unwrap_err();
        assert!(e.contains("a `pair` label needs 2 effect name(s)"), "{e}");
        assert_eq!(
            read("kind = \"unknown\"\neffects = [\"Warp\"]")
                .unwrap()
                .effects,
            ["Warp"]
        );
    }

    #[test]
    fn model_spread_draws_each_dataset_its_own_plant_and_writes_it_to_the_meta_file() {
        let vary = Variation {
            model_spread: 0.4,
            ..Variation::default()
        };
        let bp = bench_plant("dc_motor", vary).unwrap();
        let (a, b) = (bp.model(1), bp.model(2));
        assert_eq!(a.len(), 5);
        assert_ne!(a, b);
        let defaults = DcMotorPlant.default_params();
        for (name, v) in &a {
            let ratio = v / defaults[*name];
            assert!(
                ((-0.4f64).exp()..=0.4f64.exp()).contains(&ratio),
                "{name}: {ratio}"
            );
        }
        let meta = meta_text(bp.as_ref(), 1);
        assert!(meta.contains("[model]\nresistance = "), "{meta}");
        assert_eq!(
            bench_plant("dc_motor", Variation::default())
                .unwrap()
                .model(1),
            []
        );
    }
}
