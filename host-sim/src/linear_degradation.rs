//! A small, exactly solvable test system that exercises the whole host machinery before the
//! paper systems land: scalar damage growing linearly under a load input,
//! `d_{k+1} = d_k + r u_k dt + q sqrt(dt) w_k`, measured with Gaussian noise, end of life
//! when `d >= threshold`. Two estimators of `(d, r)` (the rate is unknown):
//! - `kind = "kalman"`: an exact two-state Kalman filter; the RUL distribution comes from the
//!   Gaussian predictive distribution of `d` at each future time (see `docs/deviations.md`,
//!   "host-sim linear degradation").
//! - `kind = "particle"`: the core's SIR particle filter with [`PARTICLES`] particles and
//!   the core's EOL prediction (`prognose::predict_eol`) under the mean past load.

use crate::error::SimError;
use crate::lockstep::{
    ChannelSensor, Estimator, EstimatorStep, ProfileInputs, RulSummary, SimRng, Simulation,
    TruthPlant, standard_normal, stream, stream_rng,
};
use crate::registry::{EmbeddedScenario, System};
use crate::scenario::Scenario;
use nalgebra::{SVector, Vector1, Vector2};
use prognos_core::filter::particle::{ParticleFilter, PfConfig};
use prognos_core::model::{Model, Stochastic, gaussian_log_likelihood};
use prognos_core::prognose::{EndOfLife, PredictionSettings, predict_eol, rul_distribution};
use rand_core::Rng;
use serde::Deserialize;

/// Particle count of the particle-filter estimator.
pub const PARTICLES: usize = 300;

/// Which estimator the scenario's `[filter]` asks for.
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum FilterKind {
    #[default]
    Kalman,
    Particle,
}

/// The registry entry.
pub struct LinearDegradation;

/// `[plant]`: the truth.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct PlantSettings {
    /// Damage at t = 0.
    pub initial_damage: f64,
    /// Mean damage rate per unit load per second.
    pub rate: f64,
    /// Run-to-run spread of the true rate (each run draws its rate once).
    pub rate_std: f64,
    /// Process noise intensity: damage noise std over one second.
    pub process_noise_std: f64,
    /// End of life when damage reaches this.
    pub threshold: f64,
}

impl Default for PlantSettings {
    fn default() -> Self {
        PlantSettings {
            initial_damage: 0.0,
            rate: 0.002,
            rate_std: 0.0,
            process_noise_std: 0.0,
            threshold: 1.0,
        }
    }
}

/// `[filter]`: the estimator's assumptions and the prediction settings.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct FilterSettings {
    /// `"kalman"` (default) or `"particle"`.
    pub kind: FilterKind,
    pub initial_damage: f64,
    pub initial_damage_std: f64,
    pub initial_rate: f64,
    pub initial_rate_std: f64,
    /// Random-walk std of the rate over one second.
    pub rate_walk_std: f64,
    /// Assumed damage process noise std over one second.
    pub process_noise_std: f64,
    /// Assumed measurement noise std.
    pub measurement_std: f64,
    /// End-of-life threshold the prediction uses.
    pub threshold: f64,
    /// Predict the RUL every this many samples (0 = never).
    pub predict_every: usize,
    /// Longest RUL the prediction looks for, seconds.
    pub horizon: f64,
    /// Load assumed for the future; absent = the mean of the loads seen so far.
    pub future_load: Option<f64>,
    /// Particle filter only: step of the EOL prediction, seconds.
    pub prediction_dt: f64,
    /// Particle filter only: roughening constant of the rate (Gordon et al.), which keeps
    /// the static rate from collapsing onto a few particles.
    pub roughening: f64,
    /// Kalman only: gate on the normalised innovation squared (e.g. 10.83, the 99.9 %
    /// point of chi-square with 1 dof). A measurement beyond it is rejected as an outlier
    /// (`Err`, state unchanged, logged as rejected); absent = no gate.
    pub gate: Option<f64>,
}

impl Default for FilterSettings {
    fn default() -> Self {
        FilterSettings {
            kind: FilterKind::Kalman,
            initial_damage: 0.0,
            initial_damage_std: 0.05,
            initial_rate: 0.002,
            initial_rate_std: 0.002,
            rate_walk_std: 0.0,
            process_noise_std: 0.0,
            measurement_std: 0.02,
            threshold: 1.0,
            predict_every: 10,
            horizon: 10_000.0,
            future_load: None,
            prediction_dt: 5.0,
            roughening: 0.1,
            gate: None,
        }
    }
}

/// The truth: damage and its (hidden) rate.
pub struct LinearPlant {
    damage: f64,
    rate: f64,
    settings: PlantSettings,
}

impl LinearPlant {
    /// Draws the run's true rate from `rng`.
    pub fn new(settings: PlantSettings, rng: &mut SimRng) -> Self {
        let rate = settings.rate + settings.rate_std * standard_normal(rng);
        LinearPlant {
            damage: settings.initial_damage,
            rate,
            settings,
        }
    }
}

impl TruthPlant for LinearPlant {
    fn state_names(&self) -> Vec<String> {
        vec!["damage".into(), "rate".into()]
    }
    fn state(&self) -> Vec<f64> {
        vec![self.damage, self.rate]
    }
    fn advance(&mut self, _t: f64, dt: f64, u: &[f64], rng: &mut SimRng) {
        let load = u.first().copied().unwrap_or(0.0);
        let noise = self.settings.process_noise_std * dt.sqrt() * standard_normal(rng);
        self.damage += self.rate * load * dt + noise;
    }
    fn end_of_life(&self) -> bool {
        self.damage >= self.settings.threshold
    }
}

/// Exact Kalman filter on `(damage, rate)` with RUL prediction.
pub struct LinearKalman {
    mean: [f64; 2],
    cov: [[f64; 2]; 2],
    last_t: Option<f64>,
    samples: usize,
    load_sum: f64,
    settings: FilterSettings,
}

impl LinearKalman {
    pub fn new(settings: FilterSettings) -> Self {
        LinearKalman {
            mean: [settings.initial_damage, settings.initial_rate],
            cov: [
                [settings.initial_damage_std.powi(2), 0.0],
                [0.0, settings.initial_rate_std.powi(2)],
            ],
            last_t: None,
            samples: 0,
            load_sum: 0.0,
            settings,
        }
    }

    /// Current mean and covariance.
    pub fn state(&self) -> ([f64; 2], [[f64; 2]; 2]) {
        (self.mean, self.cov)
    }

    /// Probability that the damage has crossed the threshold `tau` seconds ahead under a
    /// constant `load`: the Gaussian predictive marginal of `d(t + tau)`.
    pub fn crossing_probability(&self, tau: f64, load: f64) -> f64 {
        let s = &self.settings;
        let [d, r] = self.mean;
        let [[pdd, pdr], [_, prr]] = self.cov;
        let mean = d + r * load * tau;
        let var = pdd
            + 2.0 * tau * load * pdr
            + tau * tau * load * load * prr
            + s.process_noise_std.powi(2) * tau
            + s.rate_walk_std.powi(2) * load * load * tau.powi(3) / 3.0;
        if var <= 0.0 {
            return if mean >= s.threshold { 1.0 } else { 0.0 };
        }
        0.5 * libm::erfc(-(mean - s.threshold) / (2.0 * var).sqrt())
    }

    /// RUL summary (5th, 50th, 95th percentiles and mean) under a constant future `load`;
    /// quantiles past the horizon are reported as the horizon.
    pub fn predict_rul(&self, load: f64) -> RulSummary {
        let horizon = self.settings.horizon;
        let quantile = |p: f64| -> f64 {
            if self.crossing_probability(0.0, load) >= p {
                return 0.0;
            }
            if self.crossing_probability(horizon, load) < p {
                return horizon;
            }
            let (mut lo, mut hi) = (0.0, horizon);
            for _ in 0..60 {
                let mid = 0.5 * (lo + hi);
                if self.crossing_probability(mid, load) < p {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            0.5 * (lo + hi)
        };
        // Mean = integral of the survival function over the horizon (trapezoid rule).
        let steps = 2000;
        let h = horizon / steps as f64;
        let survival = |k: usize| 1.0 - self.crossing_probability(k as f64 * h, load);
        let mean =
            h * ((1..steps).map(survival).sum::<f64>() + 0.5 * (survival(0) + survival(steps)));
        RulSummary {
            mean,
            median: quantile(0.5),
            lower: quantile(0.05),
            upper: quantile(0.95),
        }
    }
}

impl Estimator for LinearKalman {
    fn estimate_names(&self) -> Vec<String> {
        vec!["damage".into(), "rate".into()]
    }

    fn step(&mut self, t: f64, u: &[f64], y: &[f64]) -> Result<EstimatorStep, prognos_core::Error> {
        use prognos_core::Error;
        let load = *u.first().ok_or(Error::InputLength {
            expected: 1,
            got: 0,
        })?;
        let z = *y.first().ok_or(Error::MeasurementLength {
            expected: 1,
            got: 0,
        })?;
        if !load.is_finite() {
            return Err(Error::NonFiniteInput);
        }
        if !z.is_finite() {
            return Err(Error::NonFiniteMeasurement);
        }
        let dt = match self.last_t {
            Some(last) if t.partial_cmp(&last) != Some(std::cmp::Ordering::Greater) => {
                return Err(Error::InvalidTimeStep);
            }
            Some(last) => t - last,
            None => 0.0,
        };
        let s = &self.settings;
        // Predict: x = F x, P = F P F' + Q with F = [[1, load dt], [0, 1]].
        let a = load * dt;
        let [d, r] = self.mean;
        let [[p00, p01], [_, p11]] = self.cov;
        let mut m = [d + a * r, r];
        let q_d = s.process_noise_std.powi(2) * dt;
        let q_r = s.rate_walk_std.powi(2) * dt;
        let mut c = [
            [p00 + 2.0 * a * p01 + a * a * p11 + q_d, p01 + a * p11],
            [p01 + a * p11, p11 + q_r],
        ];
        // Update with y = d + v, v ~ N(0, R).
        let innovation_var = c[0][0] + s.measurement_std.powi(2);
        if innovation_var.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
            return Err(Error::NotPositiveDefinite);
        }
        let innovation = z - m[0];
        if let Some(gate) = s.gate
            && innovation * innovation / innovation_var > gate
        {
            return Err(Error::OutOfRange(
                "measurement (outside the innovation gate)",
            ));
        }
        let k = [c[0][0] / innovation_var, c[1][0] / innovation_var];
        m = [m[0] + k[0] * innovation, m[1] + k[1] * innovation];
        c = [
            [(1.0 - k[0]) * c[0][0], (1.0 - k[0]) * c[0][1]],
            [c[1][0] - k[1] * c[0][0], c[1][1] - k[1] * c[0][1]],
        ];
        let sym = 0.5 * (c[0][1] + c[1][0]);
        self.mean = m;
        self.cov = [[c[0][0], sym], [sym, c[1][1]]];
        self.last_t = Some(t);
        self.samples += 1;
        self.load_sum += load;
        let future_load = s.future_load.unwrap_or(self.load_sum / self.samples as f64);
        let predict = s.predict_every > 0 && (self.samples - 1).is_multiple_of(s.predict_every);
        Ok(EstimatorStep {
            mean: self.mean.to_vec(),
            std: vec![
                self.cov[0][0].max(0.0).sqrt(),
                self.cov[1][1].max(0.0).sqrt(),
            ],
            rul: predict.then(|| self.predict_rul(future_load)),
        })
    }
}

/// The estimation model of the particle filter: `x = (d, r)`, `u = (load)`.
#[derive(Clone, Copy, Debug)]
pub struct LinearModel {
    pub process_noise_std: f64,
    pub measurement_std: f64,
    pub threshold: f64,
}

impl Model<f64, 2, 1> for LinearModel {
    fn step(&self, x: &Vector2<f64>, u: &Vector1<f64>, dt: f64) -> Vector2<f64> {
        Vector2::new(x[0] + x[1] * u[0] * dt, x[1])
    }
}

impl Stochastic<f64, 2, 1> for LinearModel {
    fn measurement_len(&self) -> usize {
        1
    }
    fn sample_step<R: Rng + ?Sized>(
        &self,
        x: &Vector2<f64>,
        u: &Vector1<f64>,
        dt: f64,
        rng: &mut R,
    ) -> Vector2<f64> {
        let mut next = self.step(x, u, dt);
        next[0] += self.process_noise_std
            * dt.sqrt()
            * prognos_core::random::standard_normal::<f64, R>(rng);
        next
    }
    fn log_likelihood(&self, x: &Vector2<f64>, _u: &Vector1<f64>, y: &[f64]) -> f64 {
        gaussian_log_likelihood(y, &[x[0]], &[self.measurement_std])
    }
}

impl EndOfLife<f64, 2> for LinearModel {
    fn reached(&self, x: &Vector2<f64>) -> bool {
        x[0] >= self.threshold
    }
}

/// The core's particle filter and EOL prediction on [`LinearModel`].
pub struct LinearParticle {
    pf: Box<ParticleFilter<f64, 2, PARTICLES>>,
    model: LinearModel,
    rng: SimRng,
    last_t: Option<f64>,
    samples: usize,
    load_sum: f64,
    settings: FilterSettings,
}

impl LinearParticle {
    /// `dt` is the scenario's sample time (the random walk and roughening are per step).
    pub fn new(
        settings: FilterSettings,
        dt: f64,
        mut rng: SimRng,
    ) -> Result<Self, prognos_core::Error> {
        let config = PfConfig {
            random_walk_std: SVector::from([0.0, settings.rate_walk_std * dt.sqrt()]),
            roughening: SVector::from([0.0, settings.roughening]),
            lower: SVector::from([f64::MIN, 0.0]),
            ..PfConfig::default()
        };
        let mean = Vector2::new(settings.initial_damage, settings.initial_rate);
        let mut pf = Box::new(ParticleFilter::new(mean, config)?);
        pf.init_gaussian(
            &mean,
            &Vector2::new(settings.initial_damage_std, settings.initial_rate_std),
            &mut rng,
        )?;
        Ok(LinearParticle {
            pf,
            model: LinearModel {
                process_noise_std: settings.process_noise_std,
                measurement_std: settings.measurement_std,
                threshold: settings.threshold,
            },
            rng,
            last_t: None,
            samples: 0,
            load_sum: 0.0,
            settings,
        })
    }

    fn predict_rul(&mut self, load: f64) -> Option<RulSummary> {
        let s = &self.settings;
        let settings = PredictionSettings {
            dt: s.prediction_dt,
            max_steps: (s.horizon / s.prediction_dt).ceil() as u32,
            process_noise: true,
            random_walk_std: SVector::from([0.0, s.rate_walk_std * s.prediction_dt.sqrt()]),
        };
        let mut times = [0.0; PARTICLES];
        // Every particle past the horizon is reported as the horizon (censored), the same
        // convention as the Kalman estimator.
        let _ = predict_eol(
            &self.model,
            &self.model,
            self.pf.particles(),
            |_| Vector1::new(load),
            &settings,
            &mut self.rng,
            &mut times,
        );
        for t in &mut times {
            *t = t.min(s.horizon);
        }
        let weights: Vec<f64> = (0..PARTICLES).map(|i| self.pf.weight(i)).collect();
        let mut buf = [(0.0, 0.0); PARTICLES];
        let summary = rul_distribution(&times, &weights, &mut buf)?;
        Some(RulSummary {
            mean: summary.mean,
            median: summary.median,
            lower: summary.p05,
            upper: summary.p95,
        })
    }
}

impl Estimator for LinearParticle {
    fn estimate_names(&self) -> Vec<String> {
        vec!["damage".into(), "rate".into()]
    }

    fn step(&mut self, t: f64, u: &[f64], y: &[f64]) -> Result<EstimatorStep, prognos_core::Error> {
        use prognos_core::Error;
        let load = *u.first().ok_or(Error::InputLength {
            expected: 1,
            got: 0,
        })?;
        let u = Vector1::new(load);
        match self.last_t {
            None => {
                self.pf.update(&self.model, &u, y, &mut self.rng)?;
            }
            Some(last) => {
                self.pf
                    .step(&self.model, &u, Some(y), t - last, &mut self.rng)?;
            }
        }
        self.last_t = Some(t);
        self.samples += 1;
        self.load_sum += load;
        let mean = self.pf.mean();
        let cov = self.pf.covariance();
        let every = self.settings.predict_every;
        let rul = if every > 0 && (self.samples - 1).is_multiple_of(every) {
            let future = self
                .settings
                .future_load
                .unwrap_or(self.load_sum / self.samples as f64);
            self.predict_rul(future)
        } else {
            None
        };
        Ok(EstimatorStep {
            mean: vec![mean[0], mean[1]],
            std: vec![cov[(0, 0)].max(0.0).sqrt(), cov[(1, 1)].max(0.0).sqrt()],
            rul,
        })
    }
}

impl System for LinearDegradation {
    fn name(&self) -> &'static str {
        "linear_degradation"
    }

    fn description(&self) -> &'static str {
        "scalar linear damage growth, exact Kalman filter (machinery test system)"
    }

    fn demo_scenario(&self) -> Option<EmbeddedScenario> {
        Some(EmbeddedScenario {
            path: "host-sim/scenarios/linear_degradation.toml",
            text: include_str!("../scenarios/linear_degradation.toml"),
        })
    }

    fn build(&self, scenario: &Scenario, seed: u64) -> Result<Simulation, SimError> {
        let plant_settings: PlantSettings = scenario.section("plant")?;
        let filter: FilterSettings = scenario.section("filter")?;
        for (key, value) in [
            ("rate_std", plant_settings.rate_std),
            ("process_noise_std", plant_settings.process_noise_std),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(scenario.error_at(&["plant", key], format!("`{key}` must be >= 0")));
            }
        }
        for (key, value) in [
            ("initial_damage_std", filter.initial_damage_std),
            ("initial_rate_std", filter.initial_rate_std),
            ("rate_walk_std", filter.rate_walk_std),
            ("process_noise_std", filter.process_noise_std),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(scenario.error_at(&["filter", key], format!("`{key}` must be >= 0")));
            }
        }
        if !(filter.measurement_std.is_finite() && filter.measurement_std > 0.0) {
            return Err(scenario.error_at(
                &["filter", "measurement_std"],
                "`measurement_std` must be > 0",
            ));
        }
        if !(filter.horizon.is_finite() && filter.horizon > 0.0) {
            return Err(scenario.error_at(&["filter", "horizon"], "`horizon` must be > 0"));
        }
        if !(filter.prediction_dt.is_finite() && filter.prediction_dt > 0.0) {
            return Err(
                scenario.error_at(&["filter", "prediction_dt"], "`prediction_dt` must be > 0")
            );
        }
        // The truth rate is drawn from the plant stream so it is part of the run's truth.
        let mut rate_rng = stream_rng(seed, stream::PLANT ^ 0x5eed);
        let plant = LinearPlant::new(plant_settings, &mut rate_rng);
        let sensor = ChannelSensor::from_scenario(scenario, &["damage"], &plant.state_names())?;
        let inputs = ProfileInputs::from_scenario(scenario, &["load"])?;
        Ok(Simulation {
            inputs: Box::new(inputs),
            plant: Box::new(plant),
            sensor: Box::new(sensor),
            estimator: match filter.kind {
                FilterKind::Kalman => Box::new(LinearKalman::new(filter)),
                FilterKind::Particle => Box::new(
                    LinearParticle::new(filter, scenario.dt, stream_rng(seed, stream::ESTIMATOR))
                        .map_err(|e| scenario.error_at(&["filter"], e.to_string()))?,
                ),
            },
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand_core::SeedableRng;

    fn filter() -> FilterSettings {
        FilterSettings {
            initial_damage: 0.0,
            initial_damage_std: 1.0,
            initial_rate: 0.0,
            initial_rate_std: 1.0,
            rate_walk_std: 0.0,
            process_noise_std: 0.0,
            measurement_std: 0.1,
            threshold: 1.0,
            predict_every: 1,
            horizon: 1000.0,
            future_load: None,
            ..FilterSettings::default()
        }
    }

    #[test]
    fn kalman_matches_least_squares_line_fit() {
        // Without process noise and with a diffuse prior, the KF equals the weighted least
        // squares fit of y = d0 + r t (prior adds a tiny regularisation).
        let mut kf = LinearKalman::new(FilterSettings {
            initial_damage_std: 1e4,
            initial_rate_std: 1e4,
            ..filter()
        });
        let ys = [0.11, 0.18, 0.33, 0.39, 0.52, 0.58, 0.71];
        let ts: Vec<f64> = (0..ys.len()).map(|k| k as f64).collect();
        for (t, y) in ts.iter().zip(ys) {
            kf.step(*t, &[1.0], &[y]).unwrap();
        }
        let n = ys.len() as f64;
        let (st, sy) = (ts.iter().sum::<f64>(), ys.iter().sum::<f64>());
        let stt = ts.iter().map(|t| t * t).sum::<f64>();
        let sty = ts.iter().zip(ys).map(|(t, y)| t * y).sum::<f64>();
        let slope = (n * sty - st * sy) / (n * stt - st * st);
        let intercept = (sy - slope * st) / n;
        let (m, c) = kf.state();
        let t_last = ts[ts.len() - 1];
        assert!((m[1] - slope).abs() < 1e-6, "{} vs {slope}", m[1]);
        assert!((m[0] - (intercept + slope * t_last)).abs() < 1e-6);
        // Slope variance of least squares: sigma^2 / sum (t - mean t)^2.
        let sxx = stt - st * st / n;
        assert!((c[1][1] - 0.01 / sxx).abs() < 1e-8);
    }

    #[test]
    fn rul_quantiles_match_closed_form_without_uncertainty() {
        let mut kf = LinearKalman::new(filter());
        kf.mean = [0.2, 0.01];
        kf.cov = [[0.0, 0.0], [0.0, 0.0]];
        let r = kf.predict_rul(2.0);
        // Deterministic crossing at (1 - 0.2) / (0.01 * 2) = 40 s.
        assert!((r.median - 40.0).abs() < 1e-6);
        assert!((r.lower - 40.0).abs() < 1e-6 && (r.upper - 40.0).abs() < 1e-6);
        assert!((r.mean - 40.0).abs() < 0.5);
        // With only rate uncertainty, RUL = 0.8 / (2 r) with r ~ N(0.01, 0.001^2):
        // the p-quantile of RUL is 0.8 / (2 q_{1-p}(r)).
        kf.cov = [[0.0, 0.0], [0.0, 1e-6]];
        let r = kf.predict_rul(2.0);
        let z95 = 1.6448536269514722;
        assert!((r.lower - 0.8 / (2.0 * (0.01 + z95 * 0.001))).abs() < 1e-4);
        assert!((r.upper - 0.8 / (2.0 * (0.01 - z95 * 0.001))).abs() < 1e-4);
    }

    #[test]
    fn rejects_bad_samples_and_stays_unchanged() {
        let mut kf = LinearKalman::new(filter());
        kf.step(0.0, &[1.0], &[0.1]).unwrap();
        let before = kf.state();
        assert_eq!(
            kf.step(1.0, &[1.0], &[f64::NAN]),
            Err(prognos_core::Error::NonFiniteMeasurement)
        );
        assert_eq!(
            kf.step(0.0, &[1.0], &[0.2]),
            Err(prognos_core::Error::InvalidTimeStep)
        );
        assert_eq!(kf.state(), before);
    }

    #[test]
    fn truth_rate_spread_is_drawn() {
        let mut rng = SimRng::seed_from_u64(4);
        let settings = PlantSettings {
            rate_std: 0.001,
            ..PlantSettings::default()
        };
        let rates: Vec<f64> = (0..4000)
            .map(|_| LinearPlant::new(settings.clone(), &mut rng).rate)
            .collect();
        let mean = rates.iter().sum::<f64>() / rates.len() as f64;
        let sd =
            (rates.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / rates.len() as f64).sqrt();
        assert!((mean - 0.002).abs() < 5e-5 && (sd - 0.001).abs() < 5e-5);
    }
}
