//! The cloud half (Barbieri et al. 2021, "Remote-computing on PC"): symmetric Itakura-Saito
//! HI against the reference model, smoothed by a trailing mean, prognosis triggered at
//! `T_prog`, the change to the polynomial stage detected by `T_diff`, a SIR particle filter
//! (the core's [`ParticleFilter`]) learning `b` then `c` of Eq. (30), and the RUL to `T_EoL`.

use super::EdgeCloudConfig;
use nalgebra::{SVector, Vector1, Vector2};
use prognos_core::filter::particle::{ParticleFilter, PfConfig};
use prognos_core::health::{
    DegradationStage, PiecewiseHiModel, StageInput, symmetric_itakura_saito,
};
use prognos_core::learn::ar::ArModel;
use prognos_core::prognose::eol::rul_distribution;
use prognos_core::random::uniform01;
use rand_core::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;
use std::collections::VecDeque;

/// AR order and extra instruments (n = q = 8 in the paper).
pub const ORDER: usize = 8;
/// Particles of the degradation filter.
pub const PARTICLES: usize = 1000;

type Filter = ParticleFilter<f64, 2, PARTICLES>;

/// The RUL prediction at one model time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RulPrediction {
    /// Weighted mean RUL over the particles, s (the paper's `r_hat`).
    pub mean_s: f64,
    /// Weighted median, 5th and 95th percentiles, s.
    pub median_s: f64,
    pub p05_s: f64,
    pub p95_s: f64,
    /// Filtered mean of `b` (1/min) and `c` (1/min^2).
    pub b: f64,
    pub c: f64,
}

/// What the cloud made of one received model.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CloudStep {
    /// Raw symmetric I-S HI (None until the reference exists).
    pub hi_raw: Option<f64>,
    /// Trailing mean over the smoothing window.
    pub hi_smoothed: Option<f64>,
    /// Degradation stage once prognosis was triggered.
    pub stage: Option<DegradationStage>,
    /// RUL prediction once prognosis was triggered.
    pub rul: Option<RulPrediction>,
}

/// The cloud prognoser state for one bearing.
pub struct CloudPrognoser {
    config: EdgeCloudConfig,
    reference_sum: SVector<f64, ORDER>,
    reference_variance_sum: f64,
    reference_count: usize,
    reference: Option<ArModel<f64, ORDER>>,
    recent: VecDeque<f64>,
    previous_smoothed: Option<f64>,
    trigger_s: Option<f64>,
    change: Option<(f64, f64)>,
    filter: Box<Filter>,
    model: PiecewiseHiModel<f64>,
    rng: Xoshiro256PlusPlus,
    weights: Vec<f64>,
    times: Vec<f64>,
    summary_buf: Vec<(f64, f64)>,
}

fn minutes(seconds: f64) -> f64 {
    seconds / 60.0
}

fn log_uniform(rng: &mut Xoshiro256PlusPlus, range: [f64; 2]) -> f64 {
    let u: f64 = uniform01(rng);
    (range[0].ln() + u * (range[1].ln() - range[0].ln())).exp()
}

impl CloudPrognoser {
    /// A cloud prognoser with the given settings (validated by the caller).
    pub fn new(config: &EdgeCloudConfig) -> Result<Self, prognos_core::Error> {
        let pf_config = PfConfig {
            resample_threshold: 0.5,
            lower: SVector::from([config.b_prior[0] * 0.1, config.c_prior[0] * 0.1]),
            ..PfConfig::default()
        };
        let filter = Box::new(Filter::new(Vector2::new(0.0, 0.0), pf_config)?);
        Ok(Self {
            config: config.clone(),
            reference_sum: SVector::zeros(),
            reference_variance_sum: 0.0,
            reference_count: 0,
            reference: None,
            recent: VecDeque::new(),
            previous_smoothed: None,
            trigger_s: None,
            change: None,
            filter,
            model: PiecewiseHiModel {
                trigger_level: config.prog_threshold,
                b_walk_std: config.b_walk_var.sqrt(),
                c_walk_std: config.c_walk_var.sqrt(),
                relative_noise: config.relative_noise,
                absolute_noise: config.absolute_noise,
            },
            rng: Xoshiro256PlusPlus::seed_from_u64(config.seed),
            weights: vec![0.0; PARTICLES],
            times: vec![0.0; PARTICLES],
            summary_buf: vec![(0.0, 0.0); PARTICLES],
        })
    }

    /// Time prognosis was triggered, s.
    pub fn trigger_s(&self) -> Option<f64> {
        self.trigger_s
    }

    /// Time of the detected change to the polynomial stage, s.
    pub fn change_s(&self) -> Option<f64> {
        self.change.map(|(t, _)| t)
    }

    fn spectral_model(&self, model: &ArModel<f64, ORDER>) -> ArModel<f64, ORDER> {
        if self.config.use_noise_variance {
            *model
        } else {
            model.with_unit_variance()
        }
    }

    /// Processes one model received at time `t_s`.
    pub fn on_model(
        &mut self,
        t_s: f64,
        received: &ArModel<f64, ORDER>,
    ) -> Result<CloudStep, prognos_core::Error> {
        let mut step = CloudStep {
            hi_raw: None,
            hi_smoothed: None,
            stage: None,
            rul: None,
        };
        let Some(reference) = self.reference else {
            self.reference_sum += received.theta;
            self.reference_variance_sum += received.noise_variance;
            self.reference_count += 1;
            if self.reference_count >= self.config.reference_models {
                let n = self.reference_count as f64;
                self.reference = Some(ArModel {
                    theta: self.reference_sum / n,
                    noise_variance: self.reference_variance_sum / n,
                    residual_count: received.residual_count,
                });
            }
            return Ok(step);
        };
        let hi = symmetric_itakura_saito(
            &self.spectral_model(received),
            &self.spectral_model(&reference),
            self.config.spectrum_points,
        )?;
        self.recent.push_back(hi);
        while self.recent.len() > self.config.smoothing_window {
            self.recent.pop_front();
        }
        let smoothed = self.recent.iter().sum::<f64>() / self.recent.len() as f64;
        step.hi_raw = Some(hi);
        step.hi_smoothed = Some(smoothed);
        let previous = self.previous_smoothed.replace(smoothed);

        if self.trigger_s.is_none() {
            if smoothed < self.config.prog_threshold {
                return Ok(step);
            }
            self.trigger_s = Some(t_s);
            let (b_prior, c_prior) = (self.config.b_prior, self.config.c_prior);
            self.filter.init_with(&mut self.rng, |_, rng| {
                Vector2::new(log_uniform(rng, b_prior), log_uniform(rng, c_prior))
            })?;
        } else if self.change.is_none()
            && previous.is_some_and(|p| smoothed - p > self.config.diff_threshold)
        {
            self.change = Some((t_s, smoothed));
            if self.config.redraw_c_at_change {
                // `c` is unobserved before the change, but resampling on `b` has thinned its
                // prior draws to a few values: draw it afresh from its prior.
                let c_prior = self.config.c_prior;
                for x in self.filter.particles_mut().iter_mut() {
                    x.y = log_uniform(&mut self.rng, c_prior);
                }
            }
        }
        let trigger_s = self.trigger_s.unwrap_or(t_s);
        let input = match self.change {
            None => StageInput {
                stage: DegradationStage::Exponential,
                since_trigger: minutes(t_s - trigger_s),
                since_change: 0.0,
                change_level: 0.0,
            },
            Some((change_s, level)) => StageInput {
                stage: DegradationStage::Polynomial,
                since_trigger: minutes(t_s - trigger_s),
                since_change: minutes(t_s - change_s),
                change_level: level,
            },
        };
        step.stage = Some(input.stage);
        let dt = minutes(self.config.snapshot_period_s);
        self.filter.step(
            &self.model,
            &input.to_input(),
            Some(Vector1::new(smoothed).as_slice()),
            dt,
            &mut self.rng,
        )?;
        step.rul = self.predict_rul(&input);
        Ok(step)
    }

    fn predict_rul(&mut self, input: &StageInput<f64>) -> Option<RulPrediction> {
        let cap_min = minutes(self.config.max_rul_s);
        for (i, (time, weight)) in self.times.iter_mut().zip(&mut self.weights).enumerate() {
            let x = self.filter.particles().get(i)?;
            *time = self
                .model
                .time_to_threshold(x, input, self.config.eol_threshold)
                .min(cap_min);
            *weight = self.filter.weight(i);
        }
        let summary = rul_distribution(&self.times, &self.weights, &mut self.summary_buf)?;
        let mean = self.filter.mean();
        Some(RulPrediction {
            mean_s: summary.mean * 60.0,
            median_s: summary.median * 60.0,
            p05_s: summary.p05 * 60.0,
            p95_s: summary.p95 * 60.0,
            b: mean.x,
            c: mean.y,
        })
    }
}
