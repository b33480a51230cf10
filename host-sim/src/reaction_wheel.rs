//! Reaction-wheel campaigns: step 1 (lubricant temperature, Table 5) of Alidadi & Rahimi
//! (2023), run in lockstep against the truth plant of [`crate::plants::reaction_wheel`].

use crate::plants::reaction_wheel::{Table3Profile, TruthWheel, WheelSensors};
use nalgebra::{Vector2, Vector3};
use prognos_core::filter::adaptive::{AdaptiveConfig, AdaptiveFilter, Method};
use prognos_core::filter::particle::{ParticleFilter, PfConfig};
use prognos_core::plants::reaction_wheel::{SAMPLE_INTERVAL_S, WheelTemperatureModel};
use prognos_core::{Real, cast};
use rand_core::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;
use rayon::prelude::*;

/// Filter settings of step 1 (shared by the three methods).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Step1Settings {
    /// Filter variant.
    pub method: Method,
    /// Sensor noise of the truth (the filter assumes the same values).
    pub sensors: WheelSensors,
    /// Simulated duration (s).
    pub duration: f64,
    /// Prior mean and standard deviation of the lubricant temperature (degC).
    pub prior_temperature: (f64, f64),
    /// Temperature random-walk intensity of the filter model (degC/sqrt(s)).
    pub temperature_walk: f64,
    /// Speed process noise per step (rad/s).
    pub speed_process_std: f64,
    /// ESS fraction that triggers resampling.
    pub ess_threshold: f64,
    /// `p_eff` of the adaptive resampling.
    pub likelihood_threshold: f64,
    /// Temperature jitter when the particles are spread (degC).
    pub spread_temperature: f64,
    /// Speed jitter when the particles are spread (rad/s), so that the speed state can
    /// re-synchronise with the measurement.
    pub spread_speed: f64,
    /// `c_1` at 1 V; `c_1(V) = apf_gain * 10^(1 - V)` (Eq. 28's growth rate falls tenfold per volt).
    pub apf_gain: f64,
    /// `c_2` of Eq. 28.
    pub apf_offset: f64,
    /// The sample improvement acts when ESS >= `apf_ess * N` after the update.
    pub apf_ess: f64,
}

impl Step1Settings {
    /// Defaults for a method and noise level.
    pub fn new(method: Method, sensors: WheelSensors) -> Self {
        Self {
            method,
            sensors,
            duration: Table3Profile::DURATION_S,
            prior_temperature: (25.0, 4.0),
            temperature_walk: 0.05,
            speed_process_std: 2e-4,
            spread_speed: 0.01,
            ess_threshold: 0.5,
            likelihood_threshold: 0.1,
            spread_temperature: 3.0,
            apf_gain: 1.0,
            apf_offset: 0.6,
            apf_ess: 0.9,
        }
    }

    /// `c_1(V)` of the sample improvement.
    pub fn improvement_gain(&self, command_v: f64) -> f64 {
        self.apf_gain * 10f64.powf(1.0 - command_v)
    }
}

/// Result of one step-1 run.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Step1Outcome {
    /// RMSPE of the temperature estimate over the run (percent).
    pub rmspe: f64,
    /// Fraction of samples whose true temperature lies in the 95 % interval (percent).
    pub coverage: f64,
    /// Estimated temperature per sample.
    pub estimate: Vec<f64>,
    /// True temperature per sample.
    pub truth: Vec<f64>,
    /// Lower and upper ends of the 95 % interval per sample.
    pub interval: Vec<(f64, f64)>,
    /// Number of spreading resamplings.
    pub spreads: usize,
}

/// Weighted 2.5 % and 97.5 % quantiles of the temperature particles.
fn interval_95<T: Real, const N: usize>(
    filter: &ParticleFilter<T, 3, N>,
    buf: &mut Vec<(f64, f64)>,
) -> (f64, f64) {
    buf.clear();
    buf.extend(
        filter
            .particles()
            .iter()
            .zip(filter.log_weights().iter())
            .map(|(p, lw)| (p.z.as_f64(), lw.as_f64().exp())),
    );
    buf.sort_by(|a, b| a.0.total_cmp(&b.0));
    let total: f64 = buf.iter().map(|s| s.1).sum();
    let quantile = |q: f64| {
        let mut cum = 0.0;
        for &(x, w) in buf.iter() {
            cum += w;
            if cum >= q * total {
                return x;
            }
        }
        buf.last().map_or(f64::NAN, |s| s.0)
    };
    (quantile(0.025), quantile(0.975))
}

/// One lockstep run of the Table 3 scenario with `N` particles in scalar type `T`.
pub fn run_step1<T: Real, const N: usize>(settings: &Step1Settings, seed: u64) -> Step1Outcome {
    let dt = SAMPLE_INTERVAL_S;
    let mut truth_rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut filter_rng = Xoshiro256PlusPlus::seed_from_u64(seed ^ 0x9E37_79B9_7F4A_7C15);
    let mut profile = Table3Profile::new();
    let mut wheel = TruthWheel::new();
    let (_, temp0, cmd0) = profile.current();
    wheel.settle(cmd0, temp0);

    let sensors = settings.sensors;
    let mut model =
        match WheelTemperatureModel::<T>::new(cast(sensors.current_std), cast(sensors.speed_std)) {
            Ok(m) => m,
            Err(_) => return Step1Outcome::default(),
        };
    model.temperature_walk = cast(settings.temperature_walk);
    model.speed_process_std = cast(settings.speed_process_std);

    let pf_config = PfConfig::<T, 3> {
        lower: Vector3::new(cast(-5.0), cast(-1000.0), cast(-40.0)),
        upper: Vector3::new(cast(5.0), cast(1000.0), cast(150.0)),
        ..PfConfig::default()
    };
    let first = sensors.measure(&wheel, &mut truth_rng);
    let Ok(pf) = ParticleFilter::<T, 3, N>::new(Vector3::zeros(), pf_config) else {
        return Step1Outcome::default();
    };
    let adaptive_config = AdaptiveConfig {
        method: settings.method,
        ess_threshold: cast(settings.ess_threshold),
        likelihood_threshold: cast(settings.likelihood_threshold),
        min_window: 20,
        spread_std: Vector3::new(
            T::zero(),
            cast(settings.spread_speed),
            cast(settings.spread_temperature),
        ),
        improvement_offset: cast(settings.apf_offset),
        improvement_ess: cast(settings.apf_ess),
    };
    let Ok(mut filter) = AdaptiveFilter::new(pf, adaptive_config) else {
        return Step1Outcome::default();
    };
    let mean0 = Vector3::new(
        cast(settings_current(cmd0)),
        cast(first[1]),
        cast(settings.prior_temperature.0),
    );
    let std0 = Vector3::new(
        cast(1e-3),
        cast(sensors.speed_std),
        cast(settings.prior_temperature.1),
    );
    if filter
        .filter_mut()
        .init_gaussian(&mean0, &std0, &mut filter_rng)
        .is_err()
    {
        return Step1Outcome::default();
    }

    let steps = (settings.duration / dt).round() as usize;
    let mut out = Step1Outcome {
        estimate: Vec::with_capacity(steps),
        truth: Vec::with_capacity(steps),
        ..Step1Outcome::default()
    };
    let mut buf = Vec::with_capacity(N);
    let (mut sq, mut covered) = (0.0, 0usize);
    for _ in 0..steps {
        let (t, temperature, command) = profile.current();
        wheel.step(command, temperature, dt);
        profile.advance(dt);
        let y = sensors.measure(&wheel, &mut truth_rng);
        let u = Vector2::new(cast::<T>(command), cast::<T>(t));
        let y_t = [cast::<T>(y[0]), cast::<T>(y[1])];
        let gain = settings.improvement_gain(command);
        match filter.step(
            &model,
            &u,
            Some(&y_t),
            cast(dt),
            cast(gain),
            &mut filter_rng,
        ) {
            Ok(r) => out.spreads += usize::from(r.spread),
            Err(_) => continue,
        }
        let (_, true_temp, _) = profile.current();
        let est = filter.filter().mean().z.as_f64();
        let (lo, hi) = interval_95(filter.filter(), &mut buf);
        sq += ((est - true_temp) / true_temp).powi(2);
        covered += usize::from(lo <= true_temp && true_temp <= hi);
        out.estimate.push(est);
        out.truth.push(true_temp);
        out.interval.push((lo, hi));
    }
    let n = out.estimate.len().max(1) as f64;
    out.rmspe = 100.0 * (sq / n).sqrt();
    out.coverage = 100.0 * covered as f64 / n;
    out
}

/// Nominal driver current for a command (A): `G_d V`.
fn settings_current(command_v: f64) -> f64 {
    0.19 * command_v
}

/// Particle counts of Table 5.
pub const TABLE5_PARTICLES: [usize; 7] = [50, 100, 150, 200, 250, 300, 350];

/// Runs one step-1 configuration in f64 for a particle count from [`TABLE5_PARTICLES`].
pub fn run_step1_f64(settings: &Step1Settings, particles: usize, seed: u64) -> Step1Outcome {
    match particles {
        50 => run_step1::<f64, 50>(settings, seed),
        100 => run_step1::<f64, 100>(settings, seed),
        150 => run_step1::<f64, 150>(settings, seed),
        200 => run_step1::<f64, 200>(settings, seed),
        250 => run_step1::<f64, 250>(settings, seed),
        300 => run_step1::<f64, 300>(settings, seed),
        _ => run_step1::<f64, 350>(settings, seed),
    }
}

/// One cell of Table 5: mean RMSPE and coverage over the runs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Table5Cell {
    /// Particle count.
    pub particles: usize,
    /// Low (false) or high (true) noise.
    pub high_noise: bool,
    /// Filter variant.
    pub method: Method,
    /// Mean RMSPE over the runs (percent).
    pub rmspe: f64,
    /// Mean 95 % interval coverage over the runs (percent).
    pub coverage: f64,
}

/// The paper's Table 5 (PF & adaptive resampling, APF) for low and high noise, per N.
pub const PAPER_TABLE5: [(usize, [f64; 4]); 7] = [
    (50, [2.359, 2.554, 3.596, 3.048]),
    (100, [2.216, 2.471, 3.118, 2.691]),
    (150, [2.012, 2.292, 2.745, 2.697]),
    (200, [1.983, 2.340, 2.742, 2.605]),
    (250, [2.015, 2.378, 2.735, 2.589]),
    (300, [1.935, 2.436, 2.707, 2.496]),
    (350, [1.919, 2.305, 2.748, 2.480]),
];

/// Runs the Table 5 campaign (`runs` seeds per cell, in parallel) for the given particle
/// counts and methods, at both noise levels. Cells come out ordered by N, noise, method.
pub fn table5(
    particles: &[usize],
    methods: &[Method],
    runs: usize,
    base_seed: u64,
) -> Vec<Table5Cell> {
    let mut jobs = Vec::new();
    for &n in particles {
        for high in [false, true] {
            for &method in methods {
                for run in 0..runs {
                    jobs.push((n, high, method, run));
                }
            }
        }
    }
    let results: Vec<_> = jobs
        .par_iter()
        .map(|&(n, high, method, run)| {
            let sensors = if high {
                WheelSensors::HIGH_NOISE
            } else {
                WheelSensors::LOW_NOISE
            };
            let settings = Step1Settings::new(method, sensors);
            let o = run_step1_f64(&settings, n, base_seed + run as u64);
            ((n, high, method), o.rmspe, o.coverage)
        })
        .collect();
    let mut cells = Vec::new();
    for &n in particles {
        for high in [false, true] {
            for &method in methods {
                let (mut r, mut c, mut k) = (0.0, 0.0, 0usize);
                for (key, rm, cv) in &results {
                    if *key == (n, high, method) {
                        r += rm;
                        c += cv;
                        k += 1;
                    }
                }
                let k = k.max(1) as f64;
                cells.push(Table5Cell {
                    particles: n,
                    high_noise: high,
                    method,
                    rmspe: r / k,
                    coverage: c / k,
                });
            }
        }
    }
    cells
}

/// Formats Table 5 cells beside the paper's numbers: one row per (N, noise, method), RMSPE
/// and coverage in percent; the paper reports RMSPE only, for "PF & adaptive resampling" and
/// "APF".
pub fn format_table5(cells: &[Table5Cell]) -> String {
    let mut s = String::from(
        "| N | noise | method | RMSPE (ours) | 95 % coverage (ours) | RMSPE (paper) |\n|---|---|---|---|---|---|\n",
    );
    for c in cells {
        let paper = PAPER_TABLE5
            .iter()
            .find(|(n, _)| *n == c.particles)
            .and_then(|(_, v)| {
                let offset = if c.high_noise { 2 } else { 0 };
                match c.method {
                    Method::AdaptiveResampling => v.get(offset).copied(),
                    Method::Apf => v.get(offset + 1).copied(),
                    Method::Plain => None,
                }
            });
        let paper = paper.map_or_else(|| "-".to_string(), |p| format!("{p:.3} %"));
        s.push_str(&format!(
            "| {} | {} | {} | {:.3} % | {:.1} % | {} |\n",
            c.particles,
            if c.high_noise { "high" } else { "low" },
            method_name(c.method),
            c.rmspe,
            c.coverage,
            paper
        ));
    }
    s
}

/// Short name of a step-1 method as the paper writes it.
pub fn method_name(method: Method) -> &'static str {
    match method {
        Method::Plain => "PF",
        Method::AdaptiveResampling => "PF & adaptive resampling",
        Method::Apf => "APF",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn short(method: Method) -> Step1Settings {
        let mut s = Step1Settings::new(method, WheelSensors::HIGH_NOISE);
        s.duration = 150.0;
        s
    }

    #[test]
    fn apf_tracks_the_temperature_step_and_plain_pf_does_not() {
        let apf = run_step1::<f64, 100>(&short(Method::Apf), 7);
        let plain = run_step1::<f64, 100>(&short(Method::Plain), 7);
        assert!(apf.rmspe < 3.0, "APF RMSPE {}", apf.rmspe);
        assert!(apf.coverage > 70.0, "APF coverage {}", apf.coverage);
        assert!(
            plain.rmspe > 3.0 * apf.rmspe,
            "plain {} apf {}",
            plain.rmspe,
            apf.rmspe
        );
        // After the step at 50 s has been absorbed, the estimate is within 0.5 degC.
        let late = &apf.estimate[2400..];
        let truth = &apf.truth[2400..];
        let worst = late
            .iter()
            .zip(truth)
            .map(|(e, t)| (e - t).abs())
            .fold(0.0, f64::max);
        assert!(worst < 0.5, "worst late error {worst}");
    }

    #[test]
    fn f32_filter_stays_within_one_percent_of_f64() {
        let s = short(Method::Apf);
        let a = run_step1::<f64, 100>(&s, 3);
        let b = run_step1::<f32, 100>(&s, 3);
        assert_eq!(a.estimate.len(), b.estimate.len());
        // Compare once both have absorbed the step (t > 100 s).
        let worst = a.estimate[2000..]
            .iter()
            .zip(&b.estimate[2000..])
            .zip(&a.truth[2000..])
            .map(|((x, y), t)| (x - y).abs() / t)
            .fold(0.0, f64::max);
        assert!(worst < 0.01, "worst relative f32/f64 gap {worst}");
        assert!(b.estimate.iter().all(|v| v.is_finite()));
    }
}
