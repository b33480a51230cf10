//! The lockstep runner: each sample the scenario gives the inputs, the truth plant advances,
//! the sensor measures, the estimator (a core pipeline) steps, and one row is logged. The
//! estimator only ever sees `(t, u, y)`; the truth goes to the log alone.
//!
//! Timing convention (the same as progpy's): the input `u_k = u(t_k)` is held over the
//! interval `(t_{k-1}, t_k]`; at sample `k > 0` the plant advances from `t_{k-1}` to `t_k`
//! under `u_k`, is measured at `t_k`, and the estimator gets `step(t_k, u_k, y_k)`. At k = 0
//! nothing advances. Recorded CSV data rows have the same meaning.
//!
//! Log columns: `t`, `u:*`, `y:*`, `x:*` (truth), `est:*` (estimate mean), `est_sd:*`
//! (estimate standard deviation), `rul:mean`, `rul:median`, `rul:lower`, `rul:upper`
//! (predicted RUL summary; lower/upper are the estimator's interval, 5th/95th percentiles
//! by convention), `rul:true` (from the truth EOL, filled after the run) and `rejected`
//! (1 when the estimator refused the sample and left its state unchanged).

use crate::dataio::{Recording, TimeSeries};
use crate::error::SimError;
use crate::scenario::{InputProfile, Scenario, SensorFaults};
use rand_core::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// The random generator of the host simulator.
pub type SimRng = Xoshiro256PlusPlus;

/// Independent random streams of one run, derived from the run seed with [`stream_rng`].
pub mod stream {
    /// Truth plant process noise and effect randomness.
    pub const PLANT: u64 = 1;
    /// Sensor noise.
    pub const SENSOR: u64 = 2;
    /// The estimator's own sampling (particle filter, prediction).
    pub const ESTIMATOR: u64 = 3;
    /// Injected sensor faults (`[sensor_faults]`), apart from the sensor noise.
    pub const FAULTS: u64 = 4;
}

/// SplitMix64 mix of a seed and an index: well-separated seeds for runs and streams.
pub fn mix_seed(seed: u64, index: u64) -> u64 {
    let mut z = seed ^ index.wrapping_add(1).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    for _ in 0..2 {
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
    }
    z
}

/// The generator of stream `stream` (see [`stream`]) of the run with seed `run_seed`.
pub fn stream_rng(run_seed: u64, stream: u64) -> SimRng {
    SimRng::seed_from_u64(mix_seed(run_seed, stream))
}

/// A standard normal variate from the host generator (the core's polar method, so host and
/// core draw identically).
pub fn standard_normal(rng: &mut SimRng) -> f64 {
    prognos_core::random::standard_normal::<f64, _>(rng)
}

/// A uniform variate on [0, 1).
pub fn uniform(rng: &mut SimRng) -> f64 {
    prognos_core::random::uniform01::<f64, _>(rng)
}

/// The higher-fidelity simulator of a system: the truth the estimator never sees.
pub trait TruthPlant: Send {
    /// Names of the truth states, logged as `x:<name>` in this order.
    fn state_names(&self) -> Vec<String>;
    /// Current truth values, in [`TruthPlant::state_names`] order.
    fn state(&self) -> Vec<f64>;
    /// Advances from `t` to `t + dt` under input `u` (in the input source's order).
    fn advance(&mut self, t: f64, dt: f64, u: &[f64], rng: &mut SimRng);
    /// True once the truth has reached its end-of-life condition.
    fn end_of_life(&self) -> bool;
}

/// Turns the truth into measurements (noise, bias, quantisation, discrete switches, ...).
pub trait Sensor: Send {
    /// Names of the measurement channels, logged as `y:<name>` in this order.
    fn channel_names(&self) -> Vec<String>;
    /// Measures `truth` (in the plant's state order) at time `t` under input `u`.
    fn measure(&mut self, t: f64, u: &[f64], truth: &[f64], rng: &mut SimRng) -> Vec<f64>;
}

/// Gives the input vector at each sample time.
pub trait InputSource: Send {
    /// Names of the input channels, logged as `u:<name>` in this order.
    fn input_names(&self) -> Vec<String>;
    /// The inputs at time `t`.
    fn inputs(&mut self, t: f64) -> Vec<f64>;
}

/// What an estimator reports after a sample.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct EstimatorStep {
    /// Estimated mean of each state in [`Estimator::estimate_names`] order.
    pub mean: Vec<f64>,
    /// Estimated standard deviation of each state, same order.
    pub std: Vec<f64>,
    /// Predicted remaining useful life, when the estimator predicts at this sample.
    pub rul: Option<RulSummary>,
}

/// A summary of a predicted RUL distribution, in seconds from the current sample.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RulSummary {
    pub mean: f64,
    pub median: f64,
    /// Lower bound of the reported interval (5th percentile by convention).
    pub lower: f64,
    /// Upper bound of the reported interval (95th percentile by convention).
    pub upper: f64,
}

/// The on-board side: wraps a core pipeline. It sees only `(t, u, y)`.
pub trait Estimator: Send {
    /// Names of the estimated states, logged as `est:<name>` / `est_sd:<name>`. A name equal
    /// to a truth state name is compared with it in the metrics.
    fn estimate_names(&self) -> Vec<String>;
    /// Processes one sample. An error means the sample was rejected and the estimator is
    /// unchanged (the core's contract); the runner logs it and goes on.
    fn step(&mut self, t: f64, u: &[f64], y: &[f64]) -> Result<EstimatorStep, prognos_core::Error>;
}

/// Everything one simulated run needs, built by a system from a scenario and a run seed.
pub struct Simulation {
    pub inputs: Box<dyn InputSource>,
    pub plant: Box<dyn TruthPlant>,
    pub sensor: Box<dyn Sensor>,
    pub estimator: Box<dyn Estimator>,
}

/// Timing and seeding of one run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RunSettings {
    pub dt: f64,
    /// Samples after t = 0.
    pub samples: usize,
    pub stop_at_eol: bool,
    /// The run seed; the plant and sensor streams derive from it.
    pub seed: u64,
    /// Faults injected between the sensor and the estimator.
    pub faults: SensorFaults,
}

impl RunSettings {
    /// Settings of run `run` of `scenario`.
    pub fn for_run(scenario: &Scenario, run: usize) -> Self {
        RunSettings {
            dt: scenario.dt,
            samples: scenario.samples(),
            stop_at_eol: scenario.stop_at_eol,
            seed: scenario.run_seed(run),
            faults: scenario.sensor_faults,
        }
    }
}

/// The log of one run.
#[derive(Clone, Debug, PartialEq)]
pub struct RunRecord {
    /// One row per sample, columns as described in the module docs.
    pub series: TimeSeries,
    /// Time at which the truth reached end of life, if it did.
    pub true_eol: Option<f64>,
    /// Samples the estimator rejected.
    pub rejected_steps: usize,
    /// The first rejection's message, for the report.
    pub first_rejection: Option<String>,
    /// The run seed.
    pub seed: u64,
    /// Samples touched by each injected sensor fault (`[sensor_faults]`).
    pub injected: InjectedFaults,
}

/// Runs one simulation in lockstep.
pub fn run_lockstep(sim: &mut Simulation, settings: &RunSettings) -> Result<RunRecord, SimError> {
    let mut plant_rng = stream_rng(settings.seed, stream::PLANT);
    let mut sensor_rng = stream_rng(settings.seed, stream::SENSOR);
    let mut injector = FaultInjector::new(settings.faults, settings.seed);
    let input_names = sim.inputs.input_names();
    let channel_names = sim.sensor.channel_names();
    let state_names = sim.plant.state_names();
    let mut log = Logger::new(
        &input_names,
        &channel_names,
        &state_names,
        &sim.estimator.estimate_names(),
    );
    let mut true_eol = None;
    for k in 0..=settings.samples {
        // The log keeps the nominal time; the estimator sees the (jittered) sample time.
        let t = k as f64 * settings.dt;
        let u = sim.inputs.inputs(t);
        check_len("input source", &u, input_names.len())?;
        if k > 0 {
            sim.plant
                .advance(t - settings.dt, settings.dt, &u, &mut plant_rng);
        }
        let x = sim.plant.state();
        check_len("truth plant", &x, state_names.len())?;
        let mut y = sim.sensor.measure(t, &u, &x, &mut sensor_rng);
        check_len("sensor", &y, channel_names.len())?;
        let t_seen = injector.apply(t, settings.dt, &mut y);
        let result = sim.estimator.step(t_seen, &u, &y);
        log.push(t, &u, &y, &x, result)?;
        if true_eol.is_none() && sim.plant.end_of_life() {
            true_eol = Some(t);
            if settings.stop_at_eol {
                break;
            }
        }
    }
    let mut record = log.finish(true_eol, settings.seed);
    record.injected = injector.counts;
    Ok(record)
}

/// How many samples each injected fault touched in a run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct InjectedFaults {
    pub dropouts: usize,
    pub outliers: usize,
    pub stuck: usize,
    pub nan_burst: usize,
    pub biased: usize,
    pub jittered: usize,
}

impl InjectedFaults {
    /// Samples with any fault.
    pub fn total(&self) -> usize {
        self.dropouts + self.outliers + self.stuck + self.nan_burst + self.biased + self.jittered
    }
}

/// Applies [`SensorFaults`] to each sample, on its own random stream ([`stream::FAULTS`]).
/// Every variate is drawn every sample, so the fault pattern of one kind does not depend on
/// whether another kind is configured.
#[derive(Clone, Debug)]
pub struct FaultInjector {
    faults: SensorFaults,
    rng: SimRng,
    stuck_left: usize,
    burst_left: usize,
    last_good: Vec<f64>,
    pub counts: InjectedFaults,
}

impl FaultInjector {
    pub fn new(faults: SensorFaults, run_seed: u64) -> Self {
        FaultInjector {
            faults,
            rng: stream_rng(run_seed, stream::FAULTS),
            stuck_left: 0,
            burst_left: 0,
            last_good: Vec::new(),
            counts: InjectedFaults::default(),
        }
    }

    /// Applies the faults to the measurement `y` taken at `t` and returns the sample time the
    /// estimator is told.
    pub fn apply(&mut self, t: f64, dt: f64, y: &mut [f64]) -> f64 {
        let f = self.faults;
        let draws = [
            uniform(&mut self.rng),
            uniform(&mut self.rng),
            uniform(&mut self.rng),
            uniform(&mut self.rng),
        ];
        let spike = standard_normal(&mut self.rng);
        let jitter = standard_normal(&mut self.rng);
        if f.is_off() {
            return t;
        }
        if self.stuck_left == 0 && draws[2] < f.stuck_probability && f.stuck_samples > 0 {
            self.stuck_left = f.stuck_samples;
        }
        if self.burst_left == 0 && draws[3] < f.nan_burst_probability && f.nan_burst_samples > 0 {
            self.burst_left = f.nan_burst_samples;
        }
        if let Some(t0) = f.bias_jump_time
            && t >= t0
            && f.bias_jump != 0.0
        {
            y.iter_mut().for_each(|v| *v += f.bias_jump);
            self.counts.biased += 1;
        }
        if self.stuck_left > 0 && self.last_good.len() == y.len() {
            self.stuck_left -= 1;
            y.copy_from_slice(&self.last_good);
            self.counts.stuck += 1;
        } else {
            self.stuck_left = self.stuck_left.saturating_sub(1);
            if draws[1] < f.outlier_probability {
                y.iter_mut().for_each(|v| *v += f.outlier_std * spike);
                self.counts.outliers += 1;
            }
            if y.iter().all(|v| v.is_finite()) {
                self.last_good = y.to_vec();
            }
        }
        if self.burst_left > 0 {
            self.burst_left -= 1;
            y.iter_mut().for_each(|v| *v = f64::NAN);
            self.counts.nan_burst += 1;
        } else if draws[0] < f.dropout_probability {
            y.iter_mut().for_each(|v| *v = f64::NAN);
            self.counts.dropouts += 1;
        }
        if f.jitter_std > 0.0 {
            self.counts.jittered += 1;
            let limit = 0.4 * dt;
            t + (f.jitter_std * jitter).clamp(-limit, limit)
        } else {
            t
        }
    }
}

/// Runs an estimator over recorded data (no truth plant). The recording's `u:` and `y:`
/// columns must match the estimator's expected channels by name; `x:` columns are carried
/// into the log so metrics can compare. `true_eol` may come from the data's documentation.
pub fn replay(
    estimator: &mut dyn Estimator,
    recording: &Recording,
    input_names: &[String],
    channel_names: &[String],
    true_eol: Option<f64>,
) -> Result<RunRecord, SimError> {
    let find = |role: &str, names: &[String]| -> Result<Vec<usize>, SimError> {
        names
            .iter()
            .map(|n| {
                recording
                    .series
                    .column_index(&format!("{role}:{n}"))
                    .ok_or_else(|| SimError::Run(format!("recording has no column `{role}:{n}`")))
            })
            .collect()
    };
    let u_idx = find("u", input_names)?;
    let y_idx = find("y", channel_names)?;
    let x_idx = find("x", &recording.truth)?;
    let mut log = Logger::new(
        input_names,
        channel_names,
        &recording.truth,
        &estimator.estimate_names(),
    );
    let pick = |row: &[f64], idx: &[usize]| -> Vec<f64> {
        idx.iter()
            .map(|&i| row.get(i).copied().unwrap_or(f64::NAN))
            .collect()
    };
    for row in &recording.series.rows {
        let t = row.first().copied().unwrap_or(f64::NAN);
        let (u, y, x) = (pick(row, &u_idx), pick(row, &y_idx), pick(row, &x_idx));
        let result = estimator.step(t, &u, &y);
        log.push(t, &u, &y, &x, result)?;
    }
    Ok(log.finish(true_eol, 0))
}

fn check_len(what: &str, values: &[f64], expected: usize) -> Result<(), SimError> {
    if values.len() == expected {
        Ok(())
    } else {
        Err(SimError::Run(format!(
            "{what} gave {} values, expected {expected}",
            values.len()
        )))
    }
}

/// Builds log rows in the fixed column layout.
struct Logger {
    series: TimeSeries,
    estimates: usize,
    last: EstimatorStep,
    rejected: usize,
    first_rejection: Option<String>,
}

impl Logger {
    fn new(
        inputs: &[String],
        channels: &[String],
        states: &[String],
        estimates: &[String],
    ) -> Self {
        let mut header = vec!["t".to_string()];
        header.extend(inputs.iter().map(|n| format!("u:{n}")));
        header.extend(channels.iter().map(|n| format!("y:{n}")));
        header.extend(states.iter().map(|n| format!("x:{n}")));
        header.extend(estimates.iter().map(|n| format!("est:{n}")));
        header.extend(estimates.iter().map(|n| format!("est_sd:{n}")));
        header.extend(
            [
                "rul:mean",
                "rul:median",
                "rul:lower",
                "rul:upper",
                "rul:true",
                "rejected",
            ]
            .map(String::from),
        );
        Logger {
            series: TimeSeries::new(header),
            estimates: estimates.len(),
            last: EstimatorStep {
                mean: vec![f64::NAN; estimates.len()],
                std: vec![f64::NAN; estimates.len()],
                rul: None,
            },
            rejected: 0,
            first_rejection: None,
        }
    }

    fn push(
        &mut self,
        t: f64,
        u: &[f64],
        y: &[f64],
        x: &[f64],
        result: Result<EstimatorStep, prognos_core::Error>,
    ) -> Result<(), SimError> {
        let rejected = match result {
            Ok(step) => {
                check_len("estimator mean", &step.mean, self.estimates)?;
                check_len("estimator std", &step.std, self.estimates)?;
                self.last = step;
                false
            }
            Err(e) => {
                self.rejected += 1;
                self.first_rejection
                    .get_or_insert_with(|| format!("t = {t}: {e}"));
                // The estimator is unchanged: its last estimate still stands, without a
                // fresh prediction.
                self.last.rul = None;
                true
            }
        };
        let mut row = Vec::with_capacity(self.series.header.len());
        row.push(t);
        row.extend_from_slice(u);
        row.extend_from_slice(y);
        row.extend_from_slice(x);
        row.extend_from_slice(&self.last.mean);
        row.extend_from_slice(&self.last.std);
        match self.last.rul {
            Some(r) => row.extend_from_slice(&[r.mean, r.median, r.lower, r.upper]),
            None => row.extend_from_slice(&[f64::NAN; 4]),
        }
        row.push(f64::NAN);
        row.push(if rejected { 1.0 } else { 0.0 });
        self.series.rows.push(row);
        Ok(())
    }

    fn finish(mut self, true_eol: Option<f64>, seed: u64) -> RunRecord {
        let true_col = self.series.header.len() - 2;
        for row in &mut self.series.rows {
            let t = row.first().copied().unwrap_or(f64::NAN);
            if let Some(cell) = row.get_mut(true_col) {
                *cell = true_eol.map_or(f64::NAN, |eol| eol - t);
            }
        }
        RunRecord {
            series: self.series,
            true_eol,
            rejected_steps: self.rejected,
            first_rejection: self.first_rejection,
            seed,
            injected: InjectedFaults::default(),
        }
    }
}

/// Inputs from the scenario's `[inputs]` profiles.
pub struct ProfileInputs {
    names: Vec<String>,
    profiles: Vec<InputProfile>,
}

impl ProfileInputs {
    /// Takes the profiles of exactly the channels `expected` (in that order) from the
    /// scenario; a missing or unexpected channel is an error located in the file.
    pub fn from_scenario(scenario: &Scenario, expected: &[&str]) -> Result<Self, SimError> {
        if let Some(extra) = scenario
            .inputs
            .keys()
            .find(|k| !expected.contains(&k.as_str()))
        {
            return Err(scenario.error_at(
                &["inputs", extra],
                format!(
                    "system `{}` has no input `{extra}` (inputs: {})",
                    scenario.system,
                    expected.join(", ")
                ),
            ));
        }
        let mut profiles = Vec::with_capacity(expected.len());
        for name in expected {
            let profile = scenario.inputs.get(*name).ok_or_else(|| {
                scenario.error_at(&["inputs"], format!("missing profile for input `{name}`"))
            })?;
            profiles.push(profile.clone());
        }
        Ok(ProfileInputs {
            names: expected.iter().map(|s| s.to_string()).collect(),
            profiles,
        })
    }
}

impl InputSource for ProfileInputs {
    fn input_names(&self) -> Vec<String> {
        self.names.clone()
    }
    fn inputs(&mut self, t: f64) -> Vec<f64> {
        self.profiles.iter().map(|p| p.value(t)).collect()
    }
}

/// One sensor channel of a scenario's `[sensors.<name>]` table.
///
/// Continuous: `y = quantise(scale * x + bias + noise_std * N(0,1))`. Discrete (with
/// `threshold`): `y = 1` when the noisy value is at or above the threshold, else 0 (or the
/// reverse with `invert = true`), e.g. a valve's open/closed limit switches. With
/// `dropout_probability` a sample is lost (NaN).
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SensorChannel {
    /// The truth state this channel measures.
    pub source: String,
    #[serde(default)]
    pub noise_std: f64,
    #[serde(default)]
    pub bias: f64,
    #[serde(default = "one")]
    pub scale: f64,
    /// Quantisation step (0 = none).
    #[serde(default)]
    pub quantum: f64,
    #[serde(default)]
    pub threshold: Option<f64>,
    #[serde(default)]
    pub invert: bool,
    #[serde(default)]
    pub dropout_probability: f64,
}

fn one() -> f64 {
    1.0
}

impl SensorChannel {
    /// A plain Gaussian channel.
    pub fn gaussian(source: &str, noise_std: f64) -> Self {
        SensorChannel {
            source: source.to_string(),
            noise_std,
            bias: 0.0,
            scale: 1.0,
            quantum: 0.0,
            threshold: None,
            invert: false,
            dropout_probability: 0.0,
        }
    }

    fn measure(&self, truth: f64, rng: &mut SimRng) -> f64 {
        // Draw every variate every sample so that the noise sequence does not depend on
        // the dropout pattern or on the channel kind.
        let noise = standard_normal(rng);
        let drop = uniform(rng);
        let value = self.scale * truth + self.bias + self.noise_std * noise;
        let value = match self.threshold {
            Some(th) => {
                if (value >= th) != self.invert {
                    1.0
                } else {
                    0.0
                }
            }
            None if self.quantum > 0.0 => (value / self.quantum).round() * self.quantum,
            None => value,
        };
        if drop < self.dropout_probability {
            f64::NAN
        } else {
            value
        }
    }
}

/// A sensor made of independent [`SensorChannel`]s.
pub struct ChannelSensor {
    names: Vec<String>,
    channels: Vec<(usize, SensorChannel)>,
}

impl ChannelSensor {
    /// Builds from `(name, channel)` pairs; `states` are the plant's truth state names.
    pub fn new(channels: Vec<(String, SensorChannel)>, states: &[String]) -> Result<Self, String> {
        let mut names = Vec::new();
        let mut resolved = Vec::new();
        for (name, channel) in channels {
            let index = states
                .iter()
                .position(|s| *s == channel.source)
                .ok_or_else(|| format!("channel `{name}`: no truth state `{}`", channel.source))?;
            names.push(name);
            resolved.push((index, channel));
        }
        Ok(ChannelSensor {
            names,
            channels: resolved,
        })
    }

    /// Reads the scenario's `[sensors]` section, which must define exactly the channels
    /// `expected` (taken in that order); errors are located in the scenario file.
    pub fn from_scenario(
        scenario: &Scenario,
        expected: &[&str],
        states: &[String],
    ) -> Result<Self, SimError> {
        let mut table: BTreeMap<String, SensorChannel> = scenario.section("sensors")?;
        if let Some(extra) = table.keys().find(|k| !expected.contains(&k.as_str())) {
            return Err(scenario.error_at(
                &["sensors", extra],
                format!(
                    "unknown sensor channel `{extra}` (channels: {})",
                    expected.join(", ")
                ),
            ));
        }
        let mut channels = Vec::new();
        for name in expected {
            let channel = table.remove(*name).ok_or_else(|| {
                scenario.error_at(&["sensors"], format!("missing sensor channel `{name}`"))
            })?;
            if !states.contains(&channel.source) {
                return Err(scenario.error_at(
                    &["sensors", name, "source"],
                    format!(
                        "no truth state `{}` (states: {})",
                        channel.source,
                        states.join(", ")
                    ),
                ));
            }
            for (key, value) in [
                ("noise_std", channel.noise_std),
                ("quantum", channel.quantum),
            ] {
                if !(value.is_finite() && value >= 0.0) {
                    return Err(scenario.error_at(
                        &["sensors", name, key],
                        format!("`{key}` must be a non-negative number"),
                    ));
                }
            }
            if !(0.0..=1.0).contains(&channel.dropout_probability) {
                return Err(scenario.error_at(
                    &["sensors", name, "dropout_probability"],
                    "`dropout_probability` must be in [0, 1]",
                ));
            }
            channels.push((name.to_string(), channel));
        }
        ChannelSensor::new(channels, states).map_err(|m| scenario.error_at(&["sensors"], m))
    }
}

impl Sensor for ChannelSensor {
    fn channel_names(&self) -> Vec<String> {
        self.names.clone()
    }
    fn measure(&mut self, _t: f64, _u: &[f64], truth: &[f64], rng: &mut SimRng) -> Vec<f64> {
        self.channels
            .iter()
            .map(|(i, c)| c.measure(truth.get(*i).copied().unwrap_or(f64::NAN), rng))
            .collect()
    }
}

/// Draws `n` standard normals (for plants that need a vector of process noise).
pub fn normals(rng: &mut SimRng, n: usize) -> Vec<f64> {
    (0..n).map(|_| standard_normal(rng)).collect()
}

/// Re-export so systems need not depend on `rand_core` to call `next_u64`.
pub fn next_u64(rng: &mut SimRng) -> u64 {
    rng.next_u64()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn discrete_and_quantised_channels() {
        let mut rng = SimRng::seed_from_u64(1);
        let mut switch = SensorChannel::gaussian("x", 0.0);
        switch.threshold = Some(0.5);
        assert_eq!(switch.measure(0.7, &mut rng), 1.0);
        assert_eq!(switch.measure(0.3, &mut rng), 0.0);
        switch.invert = true;
        assert_eq!(switch.measure(0.7, &mut rng), 0.0);
        let mut q = SensorChannel::gaussian("x", 0.0);
        q.quantum = 0.25;
        q.bias = 0.1;
        assert_eq!(q.measure(1.0, &mut rng), 1.0);
        assert_eq!(q.measure(1.1, &mut rng), 1.25);
        let mut lossy = SensorChannel::gaussian("x", 0.0);
        lossy.dropout_probability = 0.3;
        let lost = (0..10_000)
            .filter(|_| lossy.measure(1.0, &mut rng).is_nan())
            .count();
        assert!((2700..3300).contains(&lost), "{lost}");
    }

    #[test]
    fn gaussian_channel_noise_has_the_right_spread() {
        let mut rng = SimRng::seed_from_u64(2);
        let c = SensorChannel::gaussian("x", 0.5);
        let n = 20_000;
        let samples: Vec<f64> = (0..n).map(|_| c.measure(3.0, &mut rng)).collect();
        let mean = samples.iter().sum::<f64>() / n as f64;
        let var = samples.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n as f64;
        assert!((mean - 3.0).abs() < 0.02, "{mean}");
        assert!((var.sqrt() - 0.5).abs() < 0.01, "{var}");
    }

    #[test]
    fn seeds_and_streams_differ() {
        assert_ne!(mix_seed(1, 0), mix_seed(1, 1));
        assert_ne!(mix_seed(0, 1), mix_seed(1, 0));
        let a = stream_rng(5, stream::PLANT).next_u64();
        let b = stream_rng(5, stream::SENSOR).next_u64();
        assert_ne!(a, b);
        assert_eq!(a, stream_rng(5, stream::PLANT).next_u64());
    }
}
