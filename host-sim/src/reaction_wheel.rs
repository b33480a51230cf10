//! Reaction-wheel campaigns: step 1 (lubricant temperature, Table 5) of Alidadi & Rahimi
//! (2023), run in lockstep against the truth plant of [`crate::plants::reaction_wheel`].

use crate::plants::reaction_wheel::{Table3Profile, TruthWheel, WheelSensors};
use nalgebra::{SVector, Vector2, Vector3};
use prognos_core::filter::adaptive::{AdaptiveConfig, AdaptiveFilter, Method};
use prognos_core::filter::particle::{ParticleFilter, PfConfig};
use prognos_core::plants::lubricant_kalman::{LossKalman, LossKalmanConfig};
use prognos_core::plants::lubricant_two_step::{TwoStepConfig, TwoStepLoss};
use prognos_core::plants::reaction_wheel::{SAMPLE_INTERVAL_S, WheelTemperatureModel};
use prognos_core::{Real, cast};
use rand_core::{Rng, SeedableRng};
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

// ---------------------------------------------------------------------------------------
// Multi-rate temperature estimation: short 20 Hz bursts, one per 4-minute interval.
// ---------------------------------------------------------------------------------------

/// Settings of the burst thermometer (see `docs/architecture.md`, "Reaction wheel multi-rate").
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BurstSettings {
    /// Step-1 filter settings (method, sensors, walks).
    pub filter: Step1Settings,
    /// Burst length (s).
    pub burst_s: f64,
    /// Temperature spread added to the particles between bursts (degC): what the lubricant
    /// temperature may drift in one interval.
    pub gap_spread: f64,
    /// Wheel command during the bursts (V).
    pub command_v: f64,
}

impl BurstSettings {
    /// Defaults: 10 s bursts at 3 V, 1 degC between-burst spread.
    pub fn new(method: Method) -> Self {
        let mut filter = Step1Settings::new(method, WheelSensors::LOW_NOISE);
        // Each burst re-synchronises the speed particles, so the speed needs no slack for
        // re-synchronisation, and any speed noise would mask the temperature signal.
        filter.speed_process_std = 2e-5;
        Self {
            filter,
            burst_s: 10.0,
            gap_spread: 1.0,
            // At 3 V the wheel spins 4x faster than at 1 V, and the temperature's effect on
            // the speed grows with the speed: 16x the information per burst.
            command_v: 3.0,
        }
    }
}

/// A step-1 filter that estimates the lubricant temperature in short bursts: at each burst
/// the truth wheel runs at 20 Hz for `burst_s` seconds, the filter re-synchronises its
/// speed/current particles to the first sample, keeps its temperature particles (spread by
/// `gap_spread`), and reports the posterior mean at the end of the burst.
pub struct BurstThermometer<const N: usize> {
    filter: AdaptiveFilter<f64, 3, N>,
    model: WheelTemperatureModel<f64>,
    settings: BurstSettings,
    truth_rng: Xoshiro256PlusPlus,
    filter_rng: Xoshiro256PlusPlus,
    history: [Option<(f64, f64)>; 2],
}

impl<const N: usize> BurstThermometer<N> {
    /// A thermometer with a prior `N(prior.0, prior.1^2)` on the temperature.
    pub fn new(settings: BurstSettings, seed: u64) -> Option<Self> {
        let f = settings.filter;
        let mut model =
            WheelTemperatureModel::<f64>::new(f.sensors.current_std, f.sensors.speed_std).ok()?;
        model.temperature_walk = f.temperature_walk;
        model.speed_process_std = f.speed_process_std;
        let pf_config = PfConfig::<f64, 3> {
            lower: Vector3::new(-5.0, -1000.0, -40.0),
            upper: Vector3::new(5.0, 1000.0, 150.0),
            ..PfConfig::default()
        };
        let pf = ParticleFilter::<f64, 3, N>::new(Vector3::zeros(), pf_config).ok()?;
        let filter = AdaptiveFilter::new(
            pf,
            AdaptiveConfig {
                method: f.method,
                ess_threshold: f.ess_threshold,
                likelihood_threshold: f.likelihood_threshold,
                min_window: 20,
                spread_std: Vector3::new(0.0, f.spread_speed, f.spread_temperature),
                improvement_offset: f.apf_offset,
                improvement_ess: f.apf_ess,
            },
        )
        .ok()?;
        let mut filter_rng = Xoshiro256PlusPlus::seed_from_u64(seed ^ 0x5151_7A7A);
        let mut thermometer = Self {
            filter,
            model,
            settings,
            truth_rng: Xoshiro256PlusPlus::seed_from_u64(seed),
            filter_rng: Xoshiro256PlusPlus::seed_from_u64(0),
            history: [None, None],
        };
        let (m, sd) = f.prior_temperature;
        thermometer
            .filter
            .filter_mut()
            .init_gaussian(
                &Vector3::new(0.0, 0.0, m),
                &Vector3::new(0.0, 0.0, sd),
                &mut filter_rng,
            )
            .ok()?;
        thermometer.filter_rng = filter_rng;
        Some(thermometer)
    }

    /// Runs one burst starting at `t_start` with the true temperature `temperature(t)`;
    /// returns the temperature estimate (degC) at the end of the burst.
    pub fn burst(&mut self, t_start: f64, temperature: impl Fn(f64) -> f64) -> f64 {
        let dt = SAMPLE_INTERVAL_S;
        let command = self.settings.command_v;
        let sensors = self.settings.filter.sensors;
        let mut wheel = TruthWheel::new();
        wheel.settle(command, temperature(t_start));
        wheel.time = t_start;
        let first = sensors.measure(&wheel, &mut self.truth_rng);
        let gap = self.settings.gap_spread;
        // Between bursts the temperature particles follow the trend of the last two burst
        // estimates (linear extrapolation), then spread by the allowed drift.
        let shift = match self.history {
            [Some((t1, x1)), Some((t2, x2))] if t2 > t1 => (x2 - x1) / (t2 - t1) * (t_start - t2),
            _ => 0.0,
        };
        let rng = &mut self.filter_rng;
        for p in self.filter.filter_mut().particles_mut().iter_mut() {
            p.x = 0.19 * command;
            p.y =
                first[1] + sensors.speed_std * prognos_core::random::standard_normal::<f64, _>(rng);
            p.z += shift + gap * prognos_core::random::standard_normal::<f64, _>(rng);
        }
        self.filter.reset_history();
        let steps = (self.settings.burst_s / dt).round() as usize;
        let mut t = t_start;
        for _ in 0..steps {
            wheel.step(command, temperature(t), dt);
            let y = sensors.measure(&wheel, &mut self.truth_rng);
            let u = Vector2::new(command, t);
            let gain = self.settings.filter.improvement_gain(command);
            // A rejected sample is skipped (the filter is unchanged by an error).
            let _ = self
                .filter
                .step(&self.model, &u, Some(&y), dt, gain, &mut self.filter_rng);
            t += dt;
        }
        let estimate = self.filter.filter().mean().z;
        self.history = [self.history[1], Some((t, estimate))];
        estimate
    }

    /// Posterior standard deviation of the temperature (degC) after the last burst: the
    /// weighted spread of the particles.
    pub fn posterior_std(&self) -> f64 {
        self.filter
            .filter()
            .covariance()
            .get((2, 2))
            .map_or(0.0, |v| v.max(0.0).sqrt())
    }
}

// ---------------------------------------------------------------------------------------
// Step 2: lubricant-loss parameters (Table 6).
// ---------------------------------------------------------------------------------------

/// Length of one consumption interval (s): 4 minutes.
pub const INTERVAL_S: f64 = 240.0;

/// Fault scenario of Table 4.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FaultScenario {
    /// Excessive lubricant loss: b 37 -> 25 degC, beta 7.494e-6 -> 8.054e-6 mL/s at 159 min.
    ExcessiveLoss,
    /// Insufficient injection: b 37 -> 49 degC, beta 7.494e-6 -> 7.0e-6 mL/s at 159 min.
    InsufficientInjection,
}

impl FaultScenario {
    /// True `(b, beta)` at time `t` (s).
    pub fn parameters(self, t: f64) -> (f64, f64) {
        if t <= 159.0 * 60.0 {
            (37.0, 7.494e-6)
        } else {
            match self {
                FaultScenario::ExcessiveLoss => (25.0, 8.054e-6),
                FaultScenario::InsufficientInjection => (49.0, 7.0e-6),
            }
        }
    }
}

/// Lubricant temperature of the step-2 runs (degC): an orbital thermal cycle of +-4 degC
/// around 30 degC with a 95-minute period.
pub fn orbital_temperature(t: f64) -> f64 {
    30.0 + 4.0 * (core::f64::consts::TAU * t / 5700.0).sin()
}

/// True consumption over `[t0, t0 + INTERVAL_S]` (mL) by 1-s midpoint sums of Eq. 29.
pub fn interval_consumption(
    t0: f64,
    params: impl Fn(f64) -> (f64, f64),
    temperature: impl Fn(f64) -> f64,
) -> f64 {
    let mut sum = 0.0;
    for j in 0..INTERVAL_S as usize {
        let t = t0 + j as f64 + 0.5;
        let (b, beta) = params(t);
        sum += beta * (-b / temperature(t)).exp();
    }
    sum
}

/// Settings of a step-2 run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Step2Settings {
    /// Temperature estimation (burst thermometer).
    pub thermometer: BurstSettings,
    /// Number of 4-minute intervals.
    pub intervals: usize,
    /// Relative (log-normal) noise of a consumption measurement.
    pub relative_noise: f64,
    /// Relative noise the loss filters assume: the measurement noise plus the effect of the
    /// temperature-estimate error on `exp(-b/T)` (`b sigma_T / T^2`, ~0.8 % for 0.2 degC).
    pub assumed_noise: f64,
    /// Random walk per interval of `b` (degC) and `beta` (1e-6 mL/s) of the one-step PF.
    pub walk: (f64, f64),
    /// The same for the two-step PF; `beta`'s walk over its prior mean is also the level walk
    /// that sets how many readings the ratio filter conditions on (about 1 / sqrt(walk^2 /
    /// noise^2), about 35 intervals here).
    pub two_step_walk: (f64, f64),
    /// Prior mean and std of `b` and of `beta` (1e-6 mL/s).
    pub prior_b: (f64, f64),
    /// Prior of beta.
    pub prior_beta: (f64, f64),
    /// Intervals skipped at the start of the RMSPE (prior burn-in).
    pub burn_in: usize,
    /// Standard deviation of the burst temperature estimate (degC) that the log-linear
    /// Kalman filter treats as an error in its input variable.
    pub temperature_std: f64,
    /// Random walk per interval of the Kalman filter's `[b (degC), ln beta]`.
    pub kalman_walk: (f64, f64),
    /// The Kalman filter takes each burst's own posterior standard deviation, combined in
    /// quadrature with `temperature_std`, as that interval's temperature error.
    pub posterior_temperature_std: bool,
    /// The Kalman filter compensates the errors-in-variables bias of `b`
    /// ([`LossKalmanConfig::bias_compensation`]).
    pub kalman_bias_compensation: bool,
    /// Largest NIS one interval adds to the Kalman filter's CUSUM
    /// ([`LossKalmanConfig::change_increment_cap`]).
    pub kalman_change_increment_cap: f64,
}

impl Step2Settings {
    /// Defaults: 90 intervals (6 h), 0.25 % consumption noise.
    pub fn new(temperature_method: Method) -> Self {
        Self {
            thermometer: BurstSettings::new(temperature_method),
            intervals: 90,
            relative_noise: 0.0025,
            assumed_noise: 0.01,
            walk: (0.1, 0.01),
            two_step_walk: (0.05, 0.002),
            prior_b: (35.0, 8.0),
            prior_beta: (7.0, 1.5),
            burn_in: 5,
            temperature_std: 0.05,
            kalman_walk: (0.02, 0.0005),
            posterior_temperature_std: false,
            kalman_bias_compensation: false,
            kalman_change_increment_cap: 25.0,
        }
    }
}

/// Parameter estimates of one step-2 run, per interval.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Step2Outcome {
    /// Time at the end of each interval (s).
    pub time: Vec<f64>,
    /// Estimated and true temperature per interval (degC).
    pub temperature: Vec<(f64, f64)>,
    /// True `(b, beta)` per interval.
    pub truth: Vec<(f64, f64)>,
    /// Two-step estimates `(b, beta)`.
    pub two_step: Vec<(f64, f64)>,
    /// One-step estimates `(b, beta)`.
    pub one_step: Vec<(f64, f64)>,
    /// Log-linear Kalman filter estimates `(b, beta)` (ours).
    pub kalman: Vec<(f64, f64)>,
    /// RMSPE (percent) of b and beta, two-step.
    pub two_step_rmspe: (f64, f64),
    /// RMSPE (percent) of b and beta, one-step.
    pub one_step_rmspe: (f64, f64),
    /// RMSPE (percent) of b and beta, log-linear Kalman filter.
    pub kalman_rmspe: (f64, f64),
    /// The same three RMSPEs `[two-step, one-step, Kalman]` including the interval in which
    /// the fault occurs (see `docs/deviations.md`: no causal estimator can know the new
    /// parameters at the end of the interval whose last minute they governed).
    pub rmspe_with_change_interval: [(f64, f64); 3],
    /// Intervals left out of the RMSPE: those whose true parameters change inside them.
    pub change_intervals: Vec<usize>,
}

/// Particle count of the step-2 filters.
pub const STEP2_PARTICLES: usize = 500;

/// The two-step and one-step parameter filters of the paper and our log-linear Kalman
/// filter, fed one interval at a time.
pub struct LossEstimators {
    kalman: LossKalman<f64>,
    two_step: TwoStepLoss<f64, STEP2_PARTICLES>,
    joint: AdaptiveFilter<f64, 2, STEP2_PARTICLES>,
    joint_model: prognos_core::plants::reaction_wheel::LossJointModel<f64>,
    rng: Xoshiro256PlusPlus,
    /// Only the Kalman filter runs (diagnosis of the loss side; the paper's filters keep
    /// their priors).
    pub kalman_only: bool,
}

fn adaptive_config<const NX: usize>(spread: SVector<f64, NX>) -> AdaptiveConfig<f64, NX> {
    AdaptiveConfig {
        method: Method::AdaptiveResampling,
        ess_threshold: 0.5,
        likelihood_threshold: 0.05,
        min_window: 3,
        spread_std: spread,
        improvement_offset: 0.0,
        improvement_ess: 1.0,
    }
}

impl LossEstimators {
    /// Filters with the settings' priors and walks.
    pub fn new(s: &Step2Settings, seed: u64) -> Option<Self> {
        use prognos_core::plants::reaction_wheel::LossJointModel;
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed ^ 0xB0B0_1234);
        let two_step = TwoStepLoss::new(
            TwoStepConfig::new(s.assumed_noise, s.two_step_walk, s.prior_b, s.prior_beta),
            &mut rng,
        )
        .ok()?;
        let cfg2 = PfConfig::<f64, 2> {
            random_walk_std: Vector2::new(s.walk.0, s.walk.1),
            lower: Vector2::new(0.0, 0.01),
            upper: Vector2::new(150.0, 100.0),
            ..PfConfig::default()
        };
        let mut joint_pf =
            ParticleFilter::new(Vector2::new(s.prior_b.0, s.prior_beta.0), cfg2).ok()?;
        joint_pf
            .init_gaussian(
                &Vector2::new(s.prior_b.0, s.prior_beta.0),
                &Vector2::new(s.prior_b.1, s.prior_beta.1),
                &mut rng,
            )
            .ok()?;
        let kalman_config = LossKalmanConfig {
            walk: Vector2::new(s.kalman_walk.0, s.kalman_walk.1),
            bias_compensation: s.kalman_bias_compensation,
            change_increment_cap: s.kalman_change_increment_cap,
            ..LossKalmanConfig::new(s.relative_noise, s.temperature_std).ok()?
        };
        let kalman = LossKalman::new(
            kalman_config,
            s.prior_b.0,
            s.prior_b.1,
            s.prior_beta.0 * prognos_core::plants::reaction_wheel::BETA_UNIT,
            s.prior_beta.1 / s.prior_beta.0,
        )
        .ok()?;
        Some(Self {
            kalman,
            two_step,
            joint: AdaptiveFilter::new(joint_pf, adaptive_config(Vector2::new(4.0, 0.4))).ok()?,
            joint_model: LossJointModel {
                relative_noise: s.assumed_noise,
            },
            rng,
            kalman_only: false,
        })
    }

    /// Feeds one interval: its estimated temperature exposure, measured consumption (mL) and
    /// the temperature burst's posterior std (degC), which widens the two-step PF's reading
    /// ([`TwoStepLoss::update_with_temperature_std`]).
    pub fn push(
        &mut self,
        exposure: prognos_core::plants::reaction_wheel::IntervalExposure<f64>,
        consumption: f64,
        burst_std: f64,
    ) {
        let std = self.kalman.config().temperature_std;
        self.push_with_temperature_std(exposure, consumption, std, burst_std);
    }

    /// [`Self::push`] with this interval's standard deviation of the temperature estimate
    /// (degC) for the Kalman filter's errors in variables.
    pub fn push_with_temperature_std(
        &mut self,
        exposure: prognos_core::plants::reaction_wheel::IntervalExposure<f64>,
        consumption: f64,
        temperature_std: f64,
        burst_std: f64,
    ) {
        // A rejected interval leaves the filter unchanged: nothing to do but go on.
        let _ = self
            .kalman
            .update_with_temperature_std(&exposure, consumption, temperature_std);
        if self.kalman_only {
            return;
        }
        let u = exposure.as_input();
        let _ = self.joint.step(
            &self.joint_model,
            &u,
            Some(&[consumption]),
            1.0,
            0.0,
            &mut self.rng,
        );
        // Rejected updates are flagged inside and leave the filters unchanged: go on.
        let _ = self.two_step.update_with_temperature_std(
            exposure,
            consumption,
            burst_std,
            &mut self.rng,
        );
    }

    /// Two-step estimate `(b, beta in mL/s)`.
    pub fn two_step(&self) -> (f64, f64) {
        self.two_step.parameters()
    }

    /// Changes declared by the Kalman filter's detector so far.
    pub fn kalman_changes(&self) -> u32 {
        self.kalman.changes_detected()
    }

    /// Log-linear Kalman filter estimate `(b, beta in mL/s)`.
    pub fn kalman(&self) -> (f64, f64) {
        self.kalman.parameters()
    }

    /// `count` samples `(b, beta in 1e-6 mL/s)` of the Kalman filter's Gaussian posterior
    /// (the point estimate repeated if its covariance is not positive definite).
    pub fn kalman_samples(&self, count: usize, rng: &mut impl Rng) -> Vec<(f64, f64)> {
        match self.kalman.posterior_samples(rng) {
            Ok(samples) => samples.take(count).collect(),
            Err(_) => {
                let x = self.kalman.state();
                vec![(x.x, x.y.exp()); count]
            }
        }
    }

    /// One-step estimate `(b, beta in mL/s)`.
    pub fn one_step(&self) -> (f64, f64) {
        let m = self.joint.filter().mean();
        (m.x, m.y * prognos_core::plants::reaction_wheel::BETA_UNIT)
    }

    /// Paired posterior samples `(b, beta in 1e-6 mL/s)` of the two-step filters to predict
    /// from ([`TwoStepLoss::confirmed_particles`]).
    pub fn two_step_particles(&self) -> impl Iterator<Item = (f64, f64)> + '_ {
        self.two_step
            .confirmed_particles()
            .map(|(b, beta, _)| (b, beta))
    }
}

fn rmspe_pairs(
    est: &[(f64, f64)],
    truth: &[(f64, f64)],
    skip: usize,
    excluded: &[usize],
) -> (f64, f64) {
    let (mut sb, mut sbeta, mut n) = (0.0, 0.0, 0.0);
    for (_, (e, t)) in est
        .iter()
        .zip(truth)
        .enumerate()
        .skip(skip)
        .filter(|(k, _)| !excluded.contains(k))
    {
        sb += ((e.0 - t.0) / t.0).powi(2);
        sbeta += ((e.1 - t.1) / t.1).powi(2);
        n += 1.0;
    }
    let n = f64::max(n, 1.0);
    (100.0 * (sb / n).sqrt(), 100.0 * (sbeta / n).sqrt())
}

/// One step-2 run: burst temperature estimation per interval, then the two-step and the
/// one-step parameter filters on the measured consumption.
pub fn run_step2(settings: &Step2Settings, scenario: FaultScenario, seed: u64) -> Step2Outcome {
    use prognos_core::plants::reaction_wheel::IntervalExposure;
    let Some(mut thermometer) = BurstThermometer::<100>::new(settings.thermometer, seed) else {
        return Step2Outcome::default();
    };
    let Some(mut estimators) = LossEstimators::new(settings, seed) else {
        return Step2Outcome::default();
    };
    let mut noise_rng = Xoshiro256PlusPlus::seed_from_u64(seed ^ 0x00C0_FFEE);
    let mut out = Step2Outcome::default();
    for k in 0..settings.intervals {
        let t0 = k as f64 * INTERVAL_S;
        let mid = t0 + 0.5 * (INTERVAL_S - settings.thermometer.burst_s);
        let t_hat = thermometer.burst(mid, orbital_temperature);
        let truth_consumption =
            interval_consumption(t0, |t| scenario.parameters(t), orbital_temperature);
        let measured = truth_consumption
            * (settings.relative_noise
                * prognos_core::random::standard_normal::<f64, _>(&mut noise_rng))
            .exp();
        if let Ok(exposure) = IntervalExposure::constant(INTERVAL_S, t_hat) {
            estimators.push(exposure, measured, thermometer.posterior_std());
        }
        let t_end = t0 + INTERVAL_S;
        if scenario.parameters(t0) != scenario.parameters(t_end - 1.0) {
            out.change_intervals.push(k);
        }
        out.time.push(t_end);
        out.temperature
            .push((t_hat, orbital_temperature(t0 + 0.5 * INTERVAL_S)));
        out.truth.push(scenario.parameters(t_end - 1.0));
        out.two_step.push(estimators.two_step());
        out.one_step.push(estimators.one_step());
        out.kalman.push(estimators.kalman());
    }
    let skip = settings.burn_in;
    let excluded = &out.change_intervals;
    out.two_step_rmspe = rmspe_pairs(&out.two_step, &out.truth, skip, excluded);
    out.one_step_rmspe = rmspe_pairs(&out.one_step, &out.truth, skip, excluded);
    out.kalman_rmspe = rmspe_pairs(&out.kalman, &out.truth, skip, excluded);
    out.rmspe_with_change_interval =
        [&out.two_step, &out.one_step, &out.kalman].map(|e| rmspe_pairs(e, &out.truth, skip, &[]));
    out
}

/// The paper's Table 6: RMSPE of (b, beta) for scenario 1 and 2, per methodology.
pub const PAPER_TABLE6: [(&str, [f64; 4]); 3] = [
    ("APF + two-step PF", [3.947, 2.051, 1.920, 2.709]),
    ("PF + two-step PF", [5.081, 3.586, 3.726, 4.707]),
    ("APF + one-step PF", [136.999, 23.896, 66.172, 24.303]),
];

/// Runs Table 6 (`runs` seeds, in parallel) and formats it beside the paper's numbers.
pub fn table6(runs: usize, base_seed: u64) -> String {
    let jobs: Vec<(Method, FaultScenario, u64)> = [Method::Apf, Method::Plain]
        .iter()
        .flat_map(|&m| {
            [
                FaultScenario::ExcessiveLoss,
                FaultScenario::InsufficientInjection,
            ]
            .into_iter()
            .flat_map(move |s| (0..runs as u64).map(move |r| (m, s, base_seed + r)))
        })
        .collect();
    let results: Vec<_> = jobs
        .par_iter()
        .map(|&(m, s, seed)| {
            let o = run_step2(&Step2Settings::new(m), s, seed);
            (
                m,
                s,
                [o.two_step_rmspe, o.one_step_rmspe, o.kalman_rmspe],
                o.rmspe_with_change_interval,
            )
        })
        .collect();
    let mean_of = |m: Method, s: FaultScenario, estimator: usize, with_change: bool| {
        let v: Vec<(f64, f64)> = results
            .iter()
            .filter(|r| r.0 == m && r.1 == s)
            .filter_map(|r| {
                if with_change { &r.3 } else { &r.2 }
                    .get(estimator)
                    .copied()
            })
            .collect();
        let n = v.len().max(1) as f64;
        (
            v.iter().map(|x| x.0).sum::<f64>() / n,
            v.iter().map(|x| x.1).sum::<f64>() / n,
        )
    };
    // (temperature method, estimator: 0 two-step, 1 one-step, 2 log-linear KF, paper row)
    let rows = [
        (Method::Apf, 0usize, 0usize),
        (Method::Plain, 0, 1),
        (Method::Apf, 1, 2),
        (Method::Apf, 2, 3),
        (Method::Plain, 2, 4),
    ];
    let header = "| methodology | S1 b (ours) | S1 beta (ours) | S2 b (ours) | S2 beta (ours) | paper S1 b / beta | paper S2 b / beta |\n|---|---|---|---|---|---|---|\n";
    let mut out = String::new();
    for with_change in [false, true] {
        out.push_str(if with_change {
            "\nThe same, including the interval in which the fault occurs:\n\n"
        } else {
            "RMSPE after the 5-interval burn-in, without the interval in which the fault occurs:\n\n"
        });
        out.push_str(header);
        for (m, estimator, paper_row) in rows {
            let a = mean_of(m, FaultScenario::ExcessiveLoss, estimator, with_change);
            let b = mean_of(
                m,
                FaultScenario::InsufficientInjection,
                estimator,
                with_change,
            );
            let (name, p) = PAPER_TABLE6
                .get(paper_row)
                .map(|&(name, p)| (name, p.map(|v| format!("{v:.2}"))))
                .unwrap_or((
                    if m == Method::Apf {
                        "APF + log-linear KF (ours)"
                    } else {
                        "PF + log-linear KF (ours)"
                    },
                    ["-"; 4].map(String::from),
                ));
            out.push_str(&format!(
                "| {name} | {:.2} % | {:.2} % | {:.2} % | {:.2} % | {} / {} % | {} / {} % |\n",
                a.0, a.1, b.0, b.1, p[0], p[1], p[2], p[3]
            ));
        }
    }
    out.push_str(&format!("\n{runs} runs per cell.\n"));
    out
}

// ---------------------------------------------------------------------------------------
// Step 3: RUL over three months (Table 7), multi-rate.
// ---------------------------------------------------------------------------------------

/// Seconds per day.
pub const DAY_S: f64 = 86_400.0;

impl FaultScenario {
    /// Lubricant temperature of the three-month run (degC): scenario 1 a seasonal cycle
    /// (30 +- 5 degC, 30-day period), scenario 2 a rise from 28 to 34 degC over 90 days; both
    /// with the +-4 degC orbital cycle (95 min) on top.
    pub fn long_temperature(self, t: f64) -> f64 {
        let orbit = 4.0 * (core::f64::consts::TAU * t / 5700.0).sin();
        match self {
            FaultScenario::ExcessiveLoss => {
                30.0 + 5.0 * (core::f64::consts::TAU * t / (30.0 * DAY_S)).sin() + orbit
            }
            FaultScenario::InsufficientInjection => 28.0 + 6.0 * t / (90.0 * DAY_S) + orbit,
        }
    }

    /// Healthy loss parameters that the injection must compensate (scenario 2).
    pub const HEALTHY: (f64, f64) = (37.0, 7.494e-6);

    /// Health-indicator rate at `t` for true parameters `(b, beta)`: scenario 1 the loss rate,
    /// scenario 2 the healthy loss minus the injection.
    fn indicator_rate(self, b: f64, beta: f64, temperature: f64) -> f64 {
        let rate = beta * (-b / temperature).exp();
        match self {
            FaultScenario::ExcessiveLoss => rate,
            FaultScenario::InsufficientInjection => {
                Self::HEALTHY.1 * (-Self::HEALTHY.0 / temperature).exp() - rate
            }
        }
    }
}

/// Health indicator for RUL prediction: state `[HI (mL), b, beta (1e-6 mL/s)]`, input the
/// lubricant temperature; scenario 1 accumulates the loss, scenario 2 the deficit.
struct IndicatorModel(FaultScenario);

impl prognos_core::model::Model<f64, 3, 1> for IndicatorModel {
    fn step(&self, x: &Vector3<f64>, u: &SVector<f64, 1>, dt: f64) -> Vector3<f64> {
        let rate = self.0.indicator_rate(
            x.y,
            x.z * prognos_core::plants::reaction_wheel::BETA_UNIT,
            u.x,
        );
        Vector3::new(x.x + rate * dt, x.y, x.z)
    }
}

impl prognos_core::model::Stochastic<f64, 3, 1> for IndicatorModel {
    fn measurement_len(&self) -> usize {
        0
    }
    fn log_likelihood(&self, _: &Vector3<f64>, _: &SVector<f64, 1>, _: &[f64]) -> f64 {
        0.0
    }
}

struct Threshold(f64);

impl prognos_core::prognose::eol::EndOfLife<f64, 3> for Threshold {
    fn reached(&self, x: &Vector3<f64>) -> bool {
        x.x >= self.0
    }
}

/// Settings of a step-3 run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Step3Settings {
    /// Loss-parameter filters (priors, walks, noise) and the thermometer.
    pub step2: Step2Settings,
    /// Days at which the RUL is predicted.
    pub prediction_days: [f64; 2],
    /// Day at which the true health indicator reaches the threshold (sets the threshold).
    pub eol_day: f64,
    /// Days simulated.
    pub days: f64,
    /// Runs the log-linear Kalman filter alone (diagnosis: the paper's filters and their
    /// predictions are skipped).
    pub kalman_only: bool,
}

impl Step3Settings {
    /// Defaults: 4-s bursts with 32 particles per 4-minute interval, predictions at days 30
    /// and 60, end of life at day 80, 90 days simulated.
    pub fn new(temperature_method: Method) -> Self {
        let mut step2 = Step2Settings::new(temperature_method);
        step2.thermometer.burst_s = 4.0;
        step2.thermometer.gap_spread = 2.0;
        // Thousands of intervals: a slower walk (the adaptive spreading handles the fault).
        step2.walk = (0.02, 0.002);
        step2.two_step_walk = step2.walk;
        // 4-s bursts with 32 particles err by a few tenths of a degree.
        step2.temperature_std = 0.2;
        step2.kalman_walk = (0.004, 0.0001);
        // Burst errors (0.6 degC RMS, independent of the temperature) would pull b towards
        // zero by about 4 % (docs/results.md, Table 7).
        step2.kalman_bias_compensation = true;
        // Heavy-tailed burst errors (99 % within 2.6 degC, single ones 7-14 degC) in pairs
        // made about 100 false change declarations per 60 days. Clipping each interval's CUSUM
        // increment at 9 (3 sigma) takes 6 or more large innovations (under half an hour)
        // for a change, negligible against tens of thousands of intervals (docs/results.md,
        // Table 7); Table 6's 90 intervals keep the gate, where the delay costs accuracy.
        step2.kalman_change_increment_cap = 9.0;
        Self {
            step2,
            prediction_days: [30.0, 60.0],
            eol_day: 80.0,
            days: 90.0,
            kalman_only: false,
        }
    }
}

/// RUL prediction at one time.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RulPrediction {
    /// Prediction time (days).
    pub day: f64,
    /// True RUL (days).
    pub truth: f64,
    /// Predicted RUL: median, 5th and 95th percentiles (days).
    pub median: f64,
    /// 5th percentile (days).
    pub p05: f64,
    /// 95th percentile (days).
    pub p95: f64,
}

impl RulPrediction {
    /// Percentage error of the median.
    pub fn error(&self) -> f64 {
        100.0 * (self.median - self.truth).abs() / self.truth
    }
    /// The 90 % interval covers the truth.
    pub fn covered(&self) -> bool {
        self.p05 <= self.truth && self.truth <= self.p95
    }
}

/// Outcome of one three-month run.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Step3Outcome {
    /// Predictions at the settings' days (two-step PF, the paper's method).
    pub predictions: Vec<RulPrediction>,
    /// Predictions at the settings' days from the log-linear Kalman filter (ours).
    pub kalman_predictions: Vec<RulPrediction>,
    /// Final two-step estimates `(b, beta)`.
    pub final_parameters: (f64, f64),
    /// Changes declared by the Kalman filter's detector over the run (one true fault).
    pub kalman_changes: u32,
    /// Wall time of the run (s).
    pub seconds: f64,
}

/// One burst's temperature reading: the posterior mean and standard deviation (degC).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BurstReading {
    /// Posterior mean at the end of the burst (degC).
    pub estimate: f64,
    /// Posterior standard deviation (degC).
    pub std: f64,
}

/// The step-3 thermometer pass alone: one burst per 4-minute interval over the settings'
/// days. It draws from its own random streams, so [`run_step3_from_readings`] on its output
/// is bit-identical to [`run_step3`] (the split lets the loss side be studied on stored
/// readings).
pub fn step3_readings(
    settings: &Step3Settings,
    scenario: FaultScenario,
    seed: u64,
) -> Vec<BurstReading> {
    let intervals = (settings.days * DAY_S / INTERVAL_S).round() as usize;
    let Some(mut thermometer) = BurstThermometer::<32>::new(settings.step2.thermometer, seed)
    else {
        return Vec::new();
    };
    let burst = settings.step2.thermometer.burst_s;
    (0..intervals)
        .map(|k| {
            let t0 = k as f64 * INTERVAL_S;
            let estimate = thermometer.burst(t0 + 0.5 * (INTERVAL_S - burst), |t| {
                scenario.long_temperature(t)
            });
            BurstReading {
                estimate,
                std: thermometer.posterior_std(),
            }
        })
        .collect()
}

/// One three-month run: per 4-minute interval a 20 Hz temperature burst, the consumption
/// measurement and the two-step loss filters; RUL predictions at the given days.
pub fn run_step3(settings: &Step3Settings, scenario: FaultScenario, seed: u64) -> Step3Outcome {
    let start = std::time::Instant::now();
    let readings = step3_readings(settings, scenario, seed);
    let mut out = run_step3_from_readings(settings, scenario, seed, &readings);
    out.seconds = start.elapsed().as_secs_f64();
    out
}

/// The loss-estimation and RUL part of [`run_step3`] on the thermometer's readings (one per
/// interval; a run with fewer readings than intervals returns an empty outcome).
pub fn run_step3_from_readings(
    settings: &Step3Settings,
    scenario: FaultScenario,
    seed: u64,
    readings: &[BurstReading],
) -> Step3Outcome {
    use prognos_core::plants::reaction_wheel::IntervalExposure;
    use prognos_core::prognose::eol::{PredictionSettings, predict_eol};
    let start = std::time::Instant::now();
    let temperature = |t: f64| scenario.long_temperature(t);
    let params = |t: f64| scenario.parameters(t);
    let intervals = (settings.days * DAY_S / INTERVAL_S).round() as usize;
    let eol_interval = (settings.eol_day * DAY_S / INTERVAL_S).round() as usize;
    // True health indicator per interval end (1-s sums).
    let mut truth_hi = Vec::with_capacity(eol_interval + 1);
    let mut hi = 0.0;
    for k in 0..eol_interval {
        let t0 = k as f64 * INTERVAL_S;
        for j in 0..INTERVAL_S as usize {
            let t = t0 + j as f64 + 0.5;
            let (b, beta) = params(t);
            hi += scenario.indicator_rate(b, beta, temperature(t));
        }
        truth_hi.push(hi);
    }
    let threshold = hi;
    if readings.len() < intervals {
        return Step3Outcome::default();
    }
    let Some(mut estimators) = LossEstimators::new(&settings.step2, seed) else {
        return Step3Outcome::default();
    };
    estimators.kalman_only = settings.kalman_only;
    let mut noise_rng = Xoshiro256PlusPlus::seed_from_u64(seed ^ 0x0DD_BA11);
    let mut out = Step3Outcome::default();
    let mut measured_hi = 0.0;
    let debug = std::env::var_os("WHEEL_DEBUG").is_some();
    for (k, reading) in readings.iter().take(intervals).enumerate() {
        let t0 = k as f64 * INTERVAL_S;
        let t_hat = reading.estimate;
        let temperature_std = if settings.step2.posterior_temperature_std {
            settings.step2.temperature_std.hypot(reading.std)
        } else {
            settings.step2.temperature_std
        };
        let consumed = interval_consumption(t0, params, temperature);
        let measured = consumed
            * (settings.step2.relative_noise
                * prognos_core::random::standard_normal::<f64, _>(&mut noise_rng))
            .exp();
        if let Ok(exposure) = IntervalExposure::constant(INTERVAL_S, t_hat) {
            estimators.push_with_temperature_std(exposure, measured, temperature_std, reading.std);
        }
        measured_hi += match scenario {
            FaultScenario::ExcessiveLoss => measured,
            FaultScenario::InsufficientInjection => {
                let (hb, hbeta) = FaultScenario::HEALTHY;
                interval_consumption(t0, |_| (hb, hbeta), temperature) - measured
            }
        };
        let t_end = t0 + INTERVAL_S;
        if debug && k % 90 == 0 {
            let (b, beta) = estimators.two_step();
            let (kb, kbeta) = estimators.kalman();
            eprintln!(
                "{:.2} d T {:.2}/{:.2} b {:.2} beta {:.3} kf b {:.2} beta {:.3}",
                t_end / DAY_S,
                t_hat,
                temperature(t0 + 0.5 * INTERVAL_S),
                b,
                beta * 1e6,
                kb,
                kbeta * 1e6
            );
        }
        for &day in &settings.prediction_days {
            if ((day * DAY_S - t_end) / INTERVAL_S).abs() < 0.5 {
                let predict = |samples: &mut dyn Iterator<Item = (f64, f64)>| {
                    let states: Vec<Vector3<f64>> = samples
                        .map(|(b, beta)| Vector3::new(measured_hi, b, beta))
                        .collect();
                    let mut times = vec![0.0; states.len()];
                    let step = 4.0 * INTERVAL_S;
                    let horizon = ((settings.days * 2.0 * DAY_S) / step) as u32;
                    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
                    predict_eol(
                        &IndicatorModel(scenario),
                        &Threshold(threshold),
                        &states,
                        |i| {
                            SVector::<f64, 1>::from([temperature(
                                t_end + (f64::from(i) + 0.5) * step,
                            )])
                        },
                        &PredictionSettings::deterministic(step, horizon),
                        &mut rng,
                        &mut times,
                    )
                    .ok()?;
                    let mut days: Vec<f64> = times.iter().map(|t| t / DAY_S).collect();
                    days.sort_by(f64::total_cmp);
                    let q = |p: f64| {
                        days.get(((days.len().max(1) - 1) as f64 * p).round() as usize)
                            .copied()
                            .unwrap_or(f64::NAN)
                    };
                    Some(RulPrediction {
                        day,
                        truth: settings.eol_day - day,
                        median: q(0.5),
                        p05: q(0.05),
                        p95: q(0.95),
                    })
                };
                if !settings.kalman_only
                    && let Some(p) = predict(&mut estimators.two_step_particles())
                {
                    out.predictions.push(p);
                }
                let mut sample_rng = Xoshiro256PlusPlus::seed_from_u64(seed ^ 0x4B41_4C4D);
                let samples = estimators.kalman_samples(STEP2_PARTICLES, &mut sample_rng);
                if let Some(p) = predict(&mut samples.into_iter()) {
                    out.kalman_predictions.push(p);
                }
            }
        }
    }
    let _ = truth_hi;
    out.final_parameters = estimators.two_step();
    out.kalman_changes = estimators.kalman_changes();
    out.seconds = start.elapsed().as_secs_f64();
    out
}

/// The paper's Table 7: lower, upper and average RUL error (percent) for scenario 1 and 2.
pub const PAPER_TABLE7: [(&str, [f64; 6]); 3] = [
    (
        "APF + two-step PF",
        [0.137, 0.552, 0.346, 0.308, 4.322, 2.343],
    ),
    (
        "PF + two-step PF",
        [0.868, 2.088, 1.578, 0.428, 4.780, 2.453],
    ),
    (
        "APF + one-step PF",
        [2.308, 8.561, 6.137, 6.675, 16.442, 11.602],
    ),
];

/// Runs Table 7 for APF + two-step PF (`runs` seeds per scenario, in parallel).
pub fn table7(runs: usize, base_seed: u64) -> String {
    let jobs: Vec<(FaultScenario, u64)> = [
        FaultScenario::ExcessiveLoss,
        FaultScenario::InsufficientInjection,
    ]
    .into_iter()
    .flat_map(|s| (0..runs as u64).map(move |r| (s, base_seed + r)))
    .collect();
    let results: Vec<(FaultScenario, Step3Outcome)> = jobs
        .par_iter()
        .map(|&(s, seed)| (s, run_step3(&Step3Settings::new(Method::Apf), s, seed)))
        .collect();
    let mut out = String::from(
        "| estimator | scenario | prediction day | RUL error min | max | mean | 90 % interval covers | s per run | paper min / max / mean |\n|---|---|---|---|---|---|---|---|---|\n",
    );
    for kalman in [false, true] {
        for (si, s) in [
            FaultScenario::ExcessiveLoss,
            FaultScenario::InsufficientInjection,
        ]
        .into_iter()
        .enumerate()
        {
            for pi in 0..2 {
                let preds: Vec<RulPrediction> = results
                    .iter()
                    .filter(|r| r.0 == s)
                    .filter_map(|r| {
                        if kalman {
                            &r.1.kalman_predictions
                        } else {
                            &r.1.predictions
                        }
                        .get(pi)
                        .copied()
                    })
                    .collect();
                let secs: f64 = results
                    .iter()
                    .filter(|r| r.0 == s)
                    .map(|r| r.1.seconds)
                    .sum::<f64>()
                    / runs.max(1) as f64;
                let errors: Vec<f64> = preds.iter().map(RulPrediction::error).collect();
                let n = errors.len().max(1) as f64;
                let p = PAPER_TABLE7[0].1;
                out.push_str(&format!(
                "| {} | {} | {} | {:.2} % | {:.2} % | {:.2} % | {}/{} | {:.1} | {:.2} / {:.2} / {:.2} % |\n",
                if kalman { "APF + log-linear KF (ours)" } else { "APF + two-step PF" },
                if si == 0 { "1 (excessive loss)" } else { "2 (insufficient injection)" },
                preds.first().map_or(f64::NAN, |p| p.day),
                errors.iter().copied().fold(f64::INFINITY, f64::min),
                errors.iter().copied().fold(0.0, f64::max),
                errors.iter().sum::<f64>() / n,
                preds.iter().filter(|p| p.covered()).count(),
                preds.len(),
                secs,
                p[3 * si],
                p[3 * si + 1],
                p[3 * si + 2],
            ));
            }
        }
    }
    out
}

/// Runs `pipeline::ReactionWheel` (scalar `T`) through the Table 3 scenario for `duration`
/// seconds; returns the temperature estimates (degC) and the truth.
pub fn run_pipeline<T: Real>(
    sensors: WheelSensors,
    duration: f64,
    seed: u64,
) -> Result<(Vec<f64>, Vec<f64>), prognos_core::Error> {
    use prognos_core::pipeline::reaction_wheel::{ReactionWheel, ReactionWheelConfig};
    let dt = SAMPLE_INTERVAL_S;
    let mut truth_rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed ^ 0xFEED);
    let config = ReactionWheelConfig::<T>::new(cast(sensors.current_std), cast(sensors.speed_std))?;
    let mut pipeline = ReactionWheel::<T, 100, 50>::new(config, &mut rng)?;
    let mut profile = Table3Profile::new();
    let mut wheel = TruthWheel::new();
    let (_, temp0, cmd0) = profile.current();
    wheel.settle(cmd0, temp0);
    let y0 = sensors.measure(&wheel, &mut truth_rng);
    pipeline.step(
        T::zero(),
        cast(cmd0),
        Some(&[cast(y0[0]), cast(y0[1])]),
        &mut rng,
    )?;
    let (mut est, mut truth) = (Vec::new(), Vec::new());
    for _ in 0..(duration / dt).round() as usize {
        let (_, temperature, command) = profile.current();
        wheel.step(command, temperature, dt);
        profile.advance(dt);
        let (t, true_temp, next_command) = profile.current();
        let y = sensors.measure(&wheel, &mut truth_rng);
        let r = pipeline.step(
            cast(t),
            cast(next_command),
            Some(&[cast(y[0]), cast(y[1])]),
            &mut rng,
        )?;
        est.push(r.temperature.as_f64());
        truth.push(true_temp);
    }
    Ok((est, truth))
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
    fn two_step_pf_stays_within_two_percent_on_table6_runs() {
        // Four fresh-seed Table 6 runs per scenario (seeds 7000-7003: about 1.1 % for b and
        // 1.2 % for beta; the two-step PF with white ratio noise made 4.5-8 %), and seed 7011,
        // where the fault's partial jump and its rest were declared as two changes before the
        // ratios bridged over the mixed reading (19.4 / 13.7 % in S1, 9.5 / 13.2 % in S2), and
        // seed 9115, where a thermometer burst dragged `b` before each reading was held in
        // doubt until the next one (4.54 / 4.05 % in S1, 5.02 / 7.98 % in S2), and seed
        // 123472, where a burst that did not converge moved `b` from 26 to 13 degC before its
        // reading was widened by the burst's posterior std (5.54 / 4.32 % in S1, 3.16 / 4.63 %
        // in S2; now 1.78 / 1.69 % and 1.43 / 1.95 %).
        let settings = Step2Settings::new(Method::Apf);
        for scenario in [
            FaultScenario::ExcessiveLoss,
            FaultScenario::InsufficientInjection,
        ] {
            let (mut b, mut beta, mut one_step_b) = (0.0, 0.0, 0.0);
            for seed in 7000..7004 {
                let o = run_step2(&settings, scenario, seed);
                b += o.two_step_rmspe.0 / 4.0;
                beta += o.two_step_rmspe.1 / 4.0;
                one_step_b += o.one_step_rmspe.0 / 4.0;
            }
            assert!(
                b < 2.0 && beta < 2.0,
                "{scenario:?}: b {b:.2} %, beta {beta:.2} %"
            );
            assert!(
                one_step_b > b,
                "{scenario:?}: one-step b {one_step_b:.2} % vs {b:.2} %"
            );
            for seed in [7011, 9115, 123472] {
                let (b, beta) = run_step2(&settings, scenario, seed).two_step_rmspe;
                assert!(
                    b < 3.0 && beta < 3.0,
                    "{scenario:?} seed {seed}: b {b:.2} %, beta {beta:.2} %"
                );
            }
        }
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

    #[test]
    fn pipeline_tracks_temperature_in_f32_and_f64() {
        let (e64, truth) = run_pipeline::<f64>(WheelSensors::HIGH_NOISE, 150.0, 9).unwrap();
        let (e32, _) = run_pipeline::<f32>(WheelSensors::HIGH_NOISE, 150.0, 9).unwrap();
        let late = 2000..truth.len();
        let rel = |a: &[f64]| {
            late.clone()
                .map(|k| ((a[k] - truth[k]) / truth[k]).abs())
                .fold(0.0, f64::max)
        };
        assert!(rel(&e64) < 0.02, "f64 worst late error {}", rel(&e64));
        assert!(rel(&e32) < 0.02, "f32 worst late error {}", rel(&e32));
        // The two runs draw different particles (rounding changes the random walks), so the
        // gap is judged as an RMS over the window; the worst sample is bounded more loosely.
        let n = late.len() as f64;
        let rms_gap = (late
            .clone()
            .map(|k| ((e32[k] - e64[k]) / truth[k]).powi(2))
            .sum::<f64>()
            / n)
            .sqrt();
        let worst_gap = late
            .map(|k| (e32[k] - e64[k]).abs() / truth[k])
            .fold(0.0, f64::max);
        assert!(rms_gap < 0.01, "f32/f64 RMS gap {rms_gap}");
        assert!(worst_gap < 0.02, "f32/f64 worst gap {worst_gap}");
    }
}
