//! Long-run stability (issue 9): each on-board pipeline runs in f32 for many steps against a
//! truth plant or signal generator that can run forever, and every step is checked: no `Err`
//! on clean data, no NaN or infinity in the report, no covariance blow-up. `prognos soak`
//! prints one line per pipeline with the throughput.
//!
//! What one "step" is: one 20 Hz sample for the reaction wheel, one 50 Hz sample for the
//! scooter, one vibration sample for the edge monitor (a snapshot every 256 samples, when
//! the AR model is identified on the 12-snapshot buffer).

use crate::plants::reaction_wheel::{TruthWheel, WheelSensors};
use crate::plants::scooter::{Profile, ScooterPlant, SensorNoise};
use prognos_core::filter::adaptive_ukf::Adaptation;
use prognos_core::pipeline::edge::{EdgeConfig, EdgeMonitor};
use prognos_core::pipeline::reaction_wheel::{ReactionWheel, ReactionWheelConfig};
use prognos_core::pipeline::scooter::{Scooter, ScooterConfig};
use prognos_core::plants::reaction_wheel::{IntervalExposure, SAMPLE_INTERVAL_S};
use prognos_core::random::standard_normal;
use prognos_core::real::Real;
use prognos_core::safeguard::Flags;
use rand_core::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;
use std::time::{Duration, Instant};

/// The pipelines `prognos soak` knows.
pub const SYSTEMS: [&str; 3] = ["reaction_wheel", "scooter", "edge"];

/// The outcome of one soak.
#[derive(Clone, Debug, PartialEq)]
pub struct SoakReport {
    pub system: &'static str,
    /// Steps run (fewer than asked when the soak stopped at a failure).
    pub steps: u64,
    /// Steps that returned `Err` (none is expected on clean data).
    pub errors: u64,
    /// Steps on which a safeguard other than resampling acted (informational), and the
    /// union of all flags seen.
    pub flagged: u64,
    pub flags_seen: Flags,
    /// Largest tracked variance seen (temperature variance, largest UKF variance, or the
    /// largest AR coefficient magnitude for the edge monitor) and its limit.
    pub worst: f64,
    pub limit: f64,
    /// The first failure, if any: step and what was wrong.
    pub failure: Option<String>,
    /// Wall time of the whole soak and of the pipeline steps alone.
    pub total: Duration,
    pub pipeline: Duration,
}

impl SoakReport {
    pub fn passed(&self) -> bool {
        self.failure.is_none() && self.errors == 0
    }

    /// Pipeline steps per second (the pipeline's own time, without the truth plant).
    pub fn steps_per_second(&self) -> f64 {
        self.steps as f64 / self.pipeline.as_secs_f64().max(1e-9)
    }

    pub fn line(&self) -> String {
        format!(
            "{:<15} {:>11} steps  {:>12.0} steps/s (pipeline; {:.1} s total)  errors {}  flagged {} (flags {:#06x})  worst {:.3e} (limit {:.1e})  {}",
            self.system,
            self.steps,
            self.steps_per_second(),
            self.total.as_secs_f64(),
            self.errors,
            self.flagged,
            self.flags_seen.bits(),
            self.worst,
            self.limit,
            match &self.failure {
                None if self.errors == 0 => "PASS".to_string(),
                None => "FAIL: errors on clean data".to_string(),
                Some(f) => format!("FAIL: {f}"),
            }
        )
    }
}

/// Runs the soak of `system` (one of [`SYSTEMS`]) for `steps` steps.
pub fn soak(system: &str, steps: u64, seed: u64) -> Option<SoakReport> {
    match system {
        "reaction_wheel" => Some(reaction_wheel(steps, seed)),
        "scooter" => Some(scooter(steps, seed)),
        "edge" => Some(edge(steps, seed)),
        _ => None,
    }
}

struct Tracker {
    report: SoakReport,
    started: Instant,
}

impl Tracker {
    fn new(system: &'static str, limit: f64) -> Self {
        Self {
            report: SoakReport {
                system,
                steps: 0,
                errors: 0,
                flagged: 0,
                flags_seen: Flags::NONE,
                worst: 0.0,
                limit,
                failure: None,
                total: Duration::ZERO,
                pipeline: Duration::ZERO,
            },
            started: Instant::now(),
        }
    }

    /// Records one checked quantity; returns false (and the failure) when it is not finite
    /// or above the limit.
    fn check(&mut self, step: u64, what: &str, value: f64) -> bool {
        if value.is_finite() && value.abs() > self.report.worst {
            self.report.worst = value.abs();
        }
        if !value.is_finite() || value.abs() > self.report.limit {
            self.report.failure = Some(format!("step {step}: {what} = {value:e}"));
            return false;
        }
        true
    }

    fn flag(&mut self, flags: Flags) {
        self.report.flags_seen.insert(flags);
        if flags.bits() & !Flags::RESAMPLED.bits() != 0 {
            self.report.flagged += 1;
        }
    }

    /// Counts a step that returned an error; the first one is the run's failure.
    fn error(&mut self, step: u64, error: &dyn std::fmt::Display) {
        self.report.errors += 1;
        if self.report.failure.is_none() {
            self.report.failure = Some(format!("step {step}: {error}"));
        }
    }

    fn finish(mut self, steps: u64) -> SoakReport {
        self.report.steps = steps;
        self.report.total = self.started.elapsed();
        self.report
    }
}

/// Reaction wheel: orbital temperature cycle (25 +- 5 degC, 90 min), command alternating
/// between 1 V and 3 V every 200 s, a cumulative-consumption reading every 4 minutes.
fn reaction_wheel(steps: u64, seed: u64) -> SoakReport {
    let mut tracker = Tracker::new("reaction_wheel", 1e4);
    let mut plant_rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed ^ 0x50a4);
    let sensors = WheelSensors::HIGH_NOISE;
    let dt = SAMPLE_INTERVAL_S;
    let config =
        match ReactionWheelConfig::<f32>::new(sensors.current_std as f32, sensors.speed_std as f32)
        {
            Ok(c) => c,
            Err(e) => {
                tracker.report.failure = Some(format!("config: {e}"));
                return tracker.finish(0);
            }
        };
    let mut pipeline = match ReactionWheel::<f32, 100, 50>::new(config, &mut rng) {
        Ok(p) => p,
        Err(e) => {
            tracker.report.failure = Some(format!("new: {e}"));
            return tracker.finish(0);
        }
    };
    let temperature = |t: f64| 25.0 + 5.0 * (std::f64::consts::TAU * t / 5400.0).sin();
    let command = |t: f64| {
        if ((t / 200.0) as u64).is_multiple_of(2) {
            1.0
        } else {
            3.0
        }
    };
    let interval = (240.0 / dt).round() as u64;
    let (b, beta) = (37.0, 7.494e-6);
    let mut wheel = TruthWheel::new();
    wheel.settle(command(0.0), temperature(0.0));
    let mut reading = 0.0f64;
    let mut done = 0;
    for k in 0..steps {
        let t = k as f64 * dt;
        if k > 0 {
            wheel.step(command(t - dt), temperature(t - dt), dt);
        }
        let y = sensors.measure(&wheel, &mut plant_rng);
        let closes = k > 0 && k.is_multiple_of(interval);
        if closes {
            let exposure = IntervalExposure::constant(240.0, temperature(t)).ok();
            let c = exposure.map_or(0.0, |e| e.consumption(b, beta));
            let noise: f64 = standard_normal(&mut plant_rng);
            reading += c * (1.0 + 0.01 * noise).max(0.5);
        }
        let y3 = [y[0] as f32, y[1] as f32, reading as f32];
        let ys = if closes { &y3[..] } else { &y3[..2] };
        let started = Instant::now();
        let result = pipeline.step(t as f32, command(t) as f32, Some(ys), &mut rng);
        tracker.report.pipeline += started.elapsed();
        done = k + 1;
        match result {
            Ok(r) => {
                tracker.flag(r.flags);
                let var = f64::from(r.temperature_std).powi(2);
                if !(tracker.check(k, "temperature", f64::from(r.temperature))
                    && tracker.check(k, "temperature variance", var)
                    && tracker.check(k, "b", f64::from(r.b))
                    && tracker.check(k, "beta", f64::from(r.beta)))
                {
                    break;
                }
            }
            Err(e) => {
                tracker.error(k, &e);
                break;
            }
        }
    }
    tracker.finish(done)
}

/// Scooter: the experiment-1 plant (faults, usage change) run past its profile at 50 Hz.
fn scooter(steps: u64, seed: u64) -> SoakReport {
    let mut tracker = Tracker::new("scooter", 1e6);
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut plant = ScooterPlant::new(Profile::EXPERIMENT1, SensorNoise::default(), &mut rng);
    let dt = crate::scooter::DT;
    let mut pipeline = match Scooter::<f32>::new(0.0, ScooterConfig::new(Adaptation::Enhanced)) {
        Ok(p) => p,
        Err(e) => {
            tracker.report.failure = Some(format!("new: {e}"));
            return tracker.finish(0);
        }
    };
    let mut done = 0;
    for k in 1..=steps {
        let (u, y) = plant.sample(dt, &mut rng);
        let t = k as f64 * dt;
        let ys = [y[0] as f32, y[1] as f32, y[2] as f32];
        let started = Instant::now();
        let result = pipeline.step(t as f32, u as f32, &ys);
        tracker.report.pipeline += started.elapsed();
        done = k;
        match result {
            Ok(r) => {
                tracker.flag(r.flags);
                let p = pipeline.filter().ukf().covariance();
                let worst_var = p.diagonal().iter().fold(0.0f64, |a, &v| {
                    if v.is_finite() {
                        a.max(f64::from(v))
                    } else {
                        f64::NAN
                    }
                });
                let state_ok = r.state.iter().all(|v| v.finite());
                if !(tracker.check(k, "largest variance", worst_var)
                    && tracker.check(k, "state finite", if state_ok { 0.0 } else { f64::NAN }))
                {
                    break;
                }
            }
            Err(e) => {
                tracker.error(k, &e);
                break;
            }
        }
    }
    tracker.finish(done)
}

/// Edge monitor: an AR(2) vibration signal whose resonance drifts slowly (a wearing
/// bearing), 256-sample snapshots into a 12-snapshot buffer, AR(8) with 8 extra instruments.
fn edge(steps: u64, seed: u64) -> SoakReport {
    const L: usize = 256;
    let mut tracker = Tracker::new("edge", 1e3);
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut monitor = match EdgeMonitor::<f32, 8, 8, 12, L>::new(EdgeConfig::default()) {
        Ok(m) => m,
        Err(e) => {
            tracker.report.failure = Some(format!("new: {e}"));
            return tracker.finish(0);
        }
    };
    let mut snapshot = [0.0f32; L];
    let (mut y1, mut y2) = (0.0f64, 0.0f64);
    let mut done = 0;
    for k in 0..steps {
        // Pole radius 0.9, angle drifting between 0.6 and 0.9 rad over 10^6 samples.
        let angle = 0.75 + 0.15 * (k as f64 * std::f64::consts::TAU / 1e6).sin();
        let (a1, a2) = (2.0 * 0.9 * angle.cos(), -0.81);
        let e: f64 = standard_normal(&mut rng);
        let y = a1 * y1 + a2 * y2 + e;
        (y2, y1) = (y1, y);
        let slot = (k % L as u64) as usize;
        snapshot[slot] = y as f32;
        done = k + 1;
        if slot + 1 < L {
            continue;
        }
        let started = Instant::now();
        let result = monitor.push_snapshot(&snapshot);
        tracker.report.pipeline += started.elapsed();
        match result {
            Ok(Some(r)) => {
                let worst = r.model.theta.iter().fold(0.0f64, |a, &v| {
                    if v.finite() {
                        a.max(f64::from(v).abs())
                    } else {
                        f64::NAN
                    }
                });
                let hi = r.hi_nrmse.map_or(0.0, f64::from);
                if !(tracker.check(k, "largest AR coefficient", worst)
                    && tracker.check(k, "HI_NRMSE", hi)
                    && tracker.check(k, "noise variance", f64::from(r.model.noise_variance)))
                {
                    break;
                }
            }
            Ok(None) => {}
            Err(e) => {
                tracker.report.errors += 1;
                if tracker.report.failure.is_none() {
                    tracker.report.failure = Some(format!("sample {k}: {e}"));
                }
                break;
            }
        }
    }
    tracker.finish(done)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn short_soaks_pass_and_count_their_steps() {
        for (system, steps) in [("reaction_wheel", 6000), ("scooter", 3000), ("edge", 4096)] {
            let r = soak(system, steps, 1).unwrap();
            assert!(r.passed(), "{}", r.line());
            assert_eq!(r.steps, steps, "{}", r.line());
            assert!(r.worst > 0.0 && r.worst < r.limit, "{}", r.line());
        }
        assert!(soak("nonexistent", 10, 1).is_none());
    }

    #[test]
    fn a_blow_up_is_reported_as_a_failure() {
        let mut t = Tracker::new("x", 10.0);
        assert!(t.check(0, "v", 3.0));
        assert!(!t.check(1, "v", 11.0));
        assert!(t.report.failure.as_deref().unwrap().contains("step 1"));
        let mut t = Tracker::new("x", 10.0);
        assert!(!t.check(0, "v", f64::NAN));
    }
}
