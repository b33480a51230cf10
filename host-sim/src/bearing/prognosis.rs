//! GP-UKF / IMM prognosis of one trial: the core filters run cycle by cycle on the measured
//! feature; at the prediction times every mode's estimate is propagated to the failure
//! threshold `r_feat = 1` with draws from its GP (core `sample_rul`), and the modes' samples,
//! weighted by the mode probabilities, form the RUL distribution (core `rul_distribution`).

use super::train::{GP_INPUTS, GP_POINTS};
use super::trial::Trial;
use nalgebra::{Matrix1, SMatrix, SVector, Vector1};
use prognos_core::filter::imm::{Imm, ModeFilter};
use prognos_core::filter::ukf::SigmaParams;
use prognos_core::learn::gp::{GaussianProcess, GpTransition, GpUkf, StateThreshold, sample_rul};
use prognos_core::learn::gp_rate::{FeatureNoise, RateScaledGpUkf, RateScaledTransition};
use prognos_core::model::Stochastic;
use prognos_core::prognose::rul_distribution;
use rand_core::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;

/// The bearing GP predictor.
pub type BearingGp = GaussianProcess<f64, GP_INPUTS, GP_POINTS>;
type Filter<'a> = GpUkf<'a, f64, 1, 1, GP_INPUTS, GP_POINTS, 3>;
type RateFilter<'a, const NX: usize, const NS: usize> =
    RateScaledGpUkf<'a, f64, NX, 1, GP_INPUTS, GP_POINTS, NS>;

/// Prognosis settings.
#[derive(Clone, Copy, Debug)]
pub struct PrognosisSettings {
    /// Measurement noise variance of the feature (the UKF's `R`).
    pub measurement_variance: f64,
    /// First prediction cycle and spacing (the paper: cycle 2, then every 10 cycles).
    pub first_prediction: usize,
    pub prediction_spacing: usize,
    /// RUL samples per mode.
    pub samples_per_mode: usize,
    /// IMM probability of staying in a mode per cycle.
    pub stay_probability: f64,
    /// Horizon of the RUL propagation (cycles).
    pub horizon: u32,
    /// Modes with a probability below this are not propagated (their weight is renormalised).
    pub min_mode_probability: f64,
    /// NIS gate of the IMM ([`Imm::step_gated`]): a feature no mode explains is not fused.
    /// `None`: every finite feature is fused. A non-finite feature (a missing sample) is
    /// always a predict-only cycle.
    pub outlier_gate: Option<f64>,
    /// Measurement noise law of the rate-scaled GP-UKF (`None`: the constant
    /// `measurement_variance`).
    pub rate_feature_noise: Option<FeatureNoise<f64>>,
    pub seed: u64,
}

impl Default for PrognosisSettings {
    fn default() -> Self {
        Self {
            measurement_variance: 0.01,
            first_prediction: 2,
            prediction_spacing: 10,
            samples_per_mode: 40,
            stay_probability: 0.98,
            horizon: 1500,
            min_mode_probability: 1e-3,
            outlier_gate: None,
            rate_feature_noise: None,
            seed: 7,
        }
    }
}

/// One RUL prediction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RulPrediction {
    pub cycle: usize,
    pub true_rul: f64,
    pub median: f64,
    pub p05: f64,
    pub p95: f64,
    /// Fused feature estimate at the prediction time.
    pub estimate: f64,
}

/// The prognosis of one trial.
#[derive(Clone, Debug)]
pub struct TrialPrognosis {
    pub eol: usize,
    pub predictions: Vec<RulPrediction>,
    /// Mode probabilities after each cycle.
    pub mode_probabilities: Vec<Vec<f64>>,
    /// Fused feature estimate after each cycle.
    pub estimates: Vec<f64>,
    /// Cycles in which some mode's GP extrapolated.
    pub extrapolating_cycles: usize,
    /// Cycles whose feature was missing or rejected by the outlier gate (predict-only).
    pub rejected_cycles: usize,
}

/// A mode of the bearing IMM: a GP-UKF (state `r`) or the rate-scaled GP-UKF (state
/// `[r, theta]`), with the transition its RUL samples are propagated through.
pub trait BearingMode<const NX: usize>: ModeFilter<f64, NX, Input = Vector1<f64>> {
    type Transition: Stochastic<f64, NX, 1>;
    fn rul_transition(&self) -> &Self::Transition;
    /// Whether the GP is queried outside its training range at the current estimate.
    fn extrapolating(&self, u: &Vector1<f64>) -> bool;
}

impl<'a> BearingMode<1> for Filter<'a> {
    type Transition = GpTransition<'a, f64, GP_INPUTS, GP_POINTS, 1>;
    fn rul_transition(&self) -> &Self::Transition {
        self.transition()
    }
    fn extrapolating(&self, u: &Vector1<f64>) -> bool {
        self.transition()
            .predict(self.state(), u)
            .map(|p| p.2)
            .unwrap_or(true)
    }
}

impl<'a, const NX: usize, const NS: usize> BearingMode<NX> for RateFilter<'a, NX, NS> {
    type Transition = RateScaledTransition<'a, f64, GP_INPUTS, GP_POINTS>;
    fn rul_transition(&self) -> &Self::Transition {
        self.transition()
    }
    fn extrapolating(&self, u: &Vector1<f64>) -> bool {
        self.transition()
            .predict(self.state(), u)
            .map(|p| p.extrapolating)
            .unwrap_or(true)
    }
}

/// Runs an IMM of `K` GP-UKFs (K = 1 is the plain GP-UKF) over `trial` up to its EOL.
pub fn prognose<const K: usize>(
    gps: [&BearingGp; K],
    trial: &Trial,
    settings: &PrognosisSettings,
) -> anyhow::Result<TrialPrognosis> {
    let r = settings.measurement_variance;
    let std = r.sqrt();
    let z0 = trial.feature[0];
    let filters: [Filter<'_>; K] = {
        let mut v = Vec::with_capacity(K);
        for gp in gps.iter() {
            let transition = GpTransition {
                gps: [*gp],
                measurement_std: Vector1::new(std),
            };
            v.push(
                GpUkf::new(
                    transition,
                    Vector1::new(z0),
                    Matrix1::new(r),
                    Matrix1::new(r),
                    SigmaParams::default(),
                )
                .map_err(|e| anyhow::anyhow!("{e}"))?,
            );
        }
        v.try_into().map_err(|_| anyhow::anyhow!("filter count"))?
    };
    prognose_with(filters, trial, settings)
}

/// Prior of a unit's log-rate polynomial `theta` relative to one GP (from the training
/// units), as a state prior whose entry 0 (the feature) the prognosis sets from the first
/// measurement.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RatePrior<const NX: usize> {
    pub mean: SVector<f64, NX>,
    pub covariance: SMatrix<f64, NX, NX>,
    /// Damage at which `theta_0` is the log rate.
    pub pivot: f64,
}

/// Runs an IMM of `K` rate-scaled GP-UKFs (state `[r, theta..]`, `theta` starting at each
/// GP's prior) over `trial`; `rate_walk_variance` is the per-cycle random walk of `theta`.
pub fn prognose_rate_scaled<const NX: usize, const NS: usize, const K: usize>(
    gps: [(&BearingGp, RatePrior<NX>); K],
    rate_walk_variance: f64,
    trial: &Trial,
    settings: &PrognosisSettings,
) -> anyhow::Result<TrialPrognosis> {
    let r = settings.measurement_variance;
    let z0 = trial.feature[0];
    let filters: [RateFilter<'_, NX, NS>; K] = {
        let mut v = Vec::with_capacity(K);
        for (gp, prior) in gps.iter() {
            let (mut x0, mut p0) = (prior.mean, prior.covariance);
            x0[0] = z0;
            p0.row_mut(0).fill(0.0);
            p0.column_mut(0).fill(0.0);
            let noise = settings
                .rate_feature_noise
                .unwrap_or(FeatureNoise::constant(r));
            p0[(0, 0)] = noise.expected_variance(z0, 0.0);
            let mut f = RateScaledGpUkf::new(
                RateScaledTransition {
                    gp: *gp,
                    measurement_std: r.sqrt(),
                    pivot: prior.pivot,
                },
                x0,
                p0,
                r,
                rate_walk_variance,
                SigmaParams::default(),
            )
            .map_err(|e| anyhow::anyhow!("{e}"))?;
            f.set_feature_noise(noise)
                .map_err(|e| anyhow::anyhow!("{e}"))?;
            v.push(f);
        }
        v.try_into().map_err(|_| anyhow::anyhow!("filter count"))?
    };
    prognose_with(filters, trial, settings)
}

/// The filtering and prediction loop shared by both kinds of mode.
fn prognose_with<const NX: usize, const K: usize, F: BearingMode<NX>>(
    filters: [F; K],
    trial: &Trial,
    settings: &PrognosisSettings,
) -> anyhow::Result<TrialPrognosis> {
    let mut imm: Imm<f64, F, NX, K> = Imm::new(
        filters,
        SVector::from([1.0 / K as f64; K]),
        Imm::<f64, F, NX, K>::uniform_switching(settings.stay_probability),
    )
    .map_err(|e| anyhow::anyhow!("{e}"))?;
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(settings.seed ^ trial.seed);
    let threshold = StateThreshold {
        index: 0,
        level: 1.0,
    };
    let n = settings.samples_per_mode;
    let mut out = TrialPrognosis {
        eol: trial.eol,
        predictions: Vec::new(),
        mode_probabilities: vec![imm.probabilities().iter().copied().collect()],
        estimates: vec![imm.state()[0]],
        extrapolating_cycles: 0,
        rejected_cycles: 0,
    };
    let mut states = vec![SVector::<f64, NX>::zeros(); n];
    let mut times = vec![0.0; n * K];
    let mut weights = vec![0.0; n * K];
    let mut buf = vec![(0.0, 0.0); n * K];
    for k in 1..trial.eol {
        let u = Vector1::new(trial.load_diff[k - 1]);
        if imm.filters().iter().any(|f| f.extrapolating(&u)) {
            out.extrapolating_cycles += 1;
        }
        let z = trial.feature[k];
        let report = match settings.outlier_gate {
            _ if !z.is_finite() => imm.predict(&u),
            Some(gate) => imm.step_gated(&u, &[z], gate),
            None => imm.step(&u, &[z]),
        }
        .map_err(|e| anyhow::anyhow!("cycle {k}: {e}"))?;
        if !report.fused {
            out.rejected_cycles += 1;
        }
        out.mode_probabilities
            .push(imm.probabilities().iter().copied().collect());
        out.estimates.push(imm.state()[0]);
        let due = k >= settings.first_prediction
            && (k - settings.first_prediction).is_multiple_of(settings.prediction_spacing.max(1));
        if !due {
            continue;
        }
        let probs = *imm.probabilities();
        let kept: f64 = probs
            .iter()
            .filter(|&&p| p >= settings.min_mode_probability)
            .sum();
        for (j, f) in imm.filters().iter().enumerate() {
            let p = probs[j];
            let (t, w) = (
                &mut times[j * n..(j + 1) * n],
                &mut weights[j * n..(j + 1) * n],
            );
            if p < settings.min_mode_probability {
                t.fill(f64::MAX);
                w.fill(0.0);
                continue;
            }
            let load = &trial.load_diff;
            let res = sample_rul(
                f.rul_transition(),
                &f.mode_state(),
                &f.mode_covariance(),
                &threshold,
                |s| Vector1::new(*load.get(k + s as usize).unwrap_or(&0.0)),
                settings.horizon,
                &mut rng,
                &mut states,
                t,
            );
            if let Err(e) = res
                && e != prognos_core::Error::HorizonExceeded
            {
                anyhow::bail!("cycle {k}: {e}");
            }
            w.fill(p / kept / n as f64);
        }
        let summary = rul_distribution(&times, &weights, &mut buf)
            .ok_or_else(|| anyhow::anyhow!("no RUL samples"))?;
        // Samples beyond the horizon carry MAX_FINITE; report them as the horizon.
        let horizon = f64::from(settings.horizon);
        out.predictions.push(RulPrediction {
            cycle: k,
            true_rul: (trial.eol - k) as f64,
            median: summary.median.min(horizon),
            p05: summary.p05.min(horizon),
            p95: summary.p95.min(horizon),
            estimate: imm.state()[0],
        });
    }
    Ok(out)
}

/// The paper's metrics of one trial's predictions.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrialMetrics {
    /// Average bias (Eq. 26), cycles.
    pub ab: f64,
    /// Mean squared error (Eq. 28), cycles^2.
    pub mse: f64,
    /// Mean absolute percentage error (Eq. 27), percent.
    pub mape: f64,
    /// Fraction of predictions inside the +-20 % band (Eq. 31).
    pub alpha_lambda: f64,
    /// Prognostic horizon (Eqs. 29-30) with the constant band `+-5 %` of the EOL (Saxena et
    /// al.), as a fraction of the prediction range (0 when the last prediction is outside).
    pub ph: f64,
}

/// Metrics of a prognosis (predictions with the RUL median as point estimate).
pub fn metrics(p: &TrialPrognosis) -> Option<TrialMetrics> {
    use prognos_core::metrics::*;
    let truth: Vec<f64> = p.predictions.iter().map(|q| q.true_rul).collect();
    let pred: Vec<f64> = p.predictions.iter().map(|q| q.median).collect();
    let times: Vec<f64> = p.predictions.iter().map(|q| q.cycle as f64).collect();
    let first = *times.first()?;
    let range = p.eol as f64 - first;
    let ph = prognostic_horizon(
        &times,
        &truth,
        &pred,
        p.eol as f64,
        0.05,
        HorizonBand::FractionOfEol,
    )
    .map_or(0.0, |h| h / range);
    Some(TrialMetrics {
        ab: average_bias(&truth, &pred)?,
        mse: mean_squared_error(&truth, &pred)?,
        mape: mean_absolute_percentage_error(&truth, &pred)?,
        alpha_lambda: alpha_lambda_accuracy(&truth, &pred, 0.2)?,
        ph,
    })
}
