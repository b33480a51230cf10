//! Candidate effects: the generic sensor catalogue, the replay with candidates added,
//! parameter fitting on the training blocks and held-out scoring.
//!
//! A candidate is one or two [`Component`]s: a plant effect (switched on in the plant's
//! replay, its parameters fitted) or a generic sensor effect on one measured channel
//! (applied to the replayed output, so it costs no new replay). Fitting minimises the
//! noise-weighted squared residual on the training blocks by a bounded coordinate search
//! (a grid over the whole range, then golden-section refinement in the best bracket), which
//! copes with the non-smooth effects (quantisation, dead zone, saturation) where a gradient
//! method would stall. Scores are held-out Gaussian log-likelihoods (per-channel variance
//! from the training residuals) minus `k/2 ln n_train` (BIC-like).

use crate::gap::estimate::{ChannelSensor, Estimates, Sensors};
use crate::gap::plant::{EffectSpec, GapPlant, Params, PlantData, Scale, Side, Simulation};
use crate::gap::start::{StartSensitivity, refit_start, start_sensitivities};
use crate::gap::stats::{
    ar1_equivalent_samples, chi2_sf, gaussian_equivalent_samples, holm, ljung_box, variance_ratio_p,
};
use argmin::core::{CostFunction, Executor, State};
use argmin::solver::neldermead::NelderMead;
use serde::Serialize;
use std::collections::BTreeMap;

/// A fitted sensor on one channel whose reading scatters around its mean by more than the
/// noise in places (a quantiser near a threshold, a dead zone with noise before it near its
/// edge), with the parameters its reading variance needs and its input: the candidate's
/// replay of that channel without it. Or the noise through a fitted lag, whose innovations
/// have one variance.
pub enum NoisySensorReplay {
    /// Step, noise before it and the variance of the noise after it (none on a lattice);
    /// the input is shifted so that it rounds to the nearest multiple of the step (see
    /// [`GenericKind::Quantisation`]).
    Quantiser {
        step: f64,
        noise: f64,
        after: f64,
        input: Vec<f64>,
    },
    /// Width, shift and noise before it (see [`GenericKind::DeadZone`]), and the channel's
    /// noise variance.
    DeadZone {
        width: f64,
        shift: f64,
        noise: f64,
        channel_variance: f64,
        input: Vec<f64>,
    },
    /// The innovations' variance of a first-order lag that the noise passed through (see
    /// [`Problem::noise_through_lag`]).
    LaggedNoise { innovation_variance: f64 },
}

impl NoisySensorReplay {
    /// The reading's variance at sample `k` ([`quantised_variance`], [`dead_zone_moments`]).
    pub fn variance(&self, k: usize) -> f64 {
        let at = |input: &[f64]| input.get(k).copied().unwrap_or(f64::NAN);
        match self {
            Self::Quantiser {
                step,
                noise,
                after,
                input,
            } => quantised_variance(at(input), *step, *noise) + after,
            // No less than the channel's noise: a dead zone may explain jumps at its edge,
            // but not readings quieter than the noise (a noise-free record's hard stop at 0,
            // progpy's closed valve, read as a zeroing deadband).
            Self::DeadZone {
                width,
                shift,
                noise,
                channel_variance,
                input,
            } => dead_zone_moments(at(input), *width, *shift, *noise)
                .1
                .max(*channel_variance),
            Self::LaggedNoise {
                innovation_variance,
            } => *innovation_variance,
        }
    }
}

/// Samples per window of [`innovation_means_p`]: 5 s at the wheel's 20 Hz, long against
/// the ripple's swing (far above the sample rate, aliased anywhere) and short against the
/// seconds between command steps.
const INNOVATION_WINDOW: usize = 100;

/// p-value that innovations (`measured - predicted`, variance `variance(k)`) have no mean
/// over windows of [`INNOVATION_WINDOW`] samples: the sum of the squared standardised
/// window sums against chi-square. A replay that tracks its readings through random kicks
/// follows a slow misfit (a sensor drift, a load step) only after each kick and lags it in
/// between, where its innovations keep their sign; per sample that lag hides in the noise.
fn innovation_means_p(measured: &[f64], predicted: &[f64], variance: impl Fn(usize) -> f64) -> f64 {
    let (mut statistic, mut windows) = (0.0, 0usize);
    for start in (0..measured.len()).step_by(INNOVATION_WINDOW) {
        let end = (start + INNOVATION_WINDOW).min(measured.len());
        let (mut sum, mut n) = (0.0, 0usize);
        for k in start..end {
            let z = (measured[k] - predicted[k]) / variance(k).sqrt();
            if z.is_finite() {
                sum += z;
                n += 1;
            }
        }
        // A short tail window says little and would count as a whole one.
        if n >= INNOVATION_WINDOW / 2 {
            statistic += sum * sum / n as f64;
            windows += 1;
        }
    }
    if windows == 0 {
        return 1.0;
    }
    chi2_sf(statistic, windows as f64)
}

/// The spread a replay adds to channel `c`'s readings, if any ([`Simulation::variances`]).
fn added_variance(sim: &Simulation, c: usize) -> Option<&Vec<f64>> {
    sim.variances.get(c).and_then(Option::as_ref)
}

/// `ln N(r; 0, variance)`.
fn gaussian_log_density(r: f64, variance: f64) -> f64 {
    -0.5 * (std::f64::consts::TAU * variance).ln() - 0.5 * r * r / variance
}

/// The generic, plant-independent sensor effects.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum GenericKind {
    /// `y = y_model + b`.
    SensorBias,
    /// `y = (1 + s) y_model`.
    SensorScale,
    /// `y = c + q round((y_model + e - c) / q - h)` with sensor noise `e` of std `s` before
    /// the quantiser, thresholds `h` steps above round-to-nearest (`h = 0.5`: floor, as a
    /// truncating converter does) and the readings' lattice offset `c` (read from the data,
    /// not fitted); predicted by its conditional mean (see [`quantised_mean`]).
    Quantisation,
    /// `y(t) = y_model(t - d)`.
    MeasurementDelay,
    /// `y = clamp(y_model + e, l, L)` on average over sensor noise `e` before the clip;
    /// `l = -L` and no noise before it unless they pay.
    OutputSaturation,
    /// `y = sign(y_model) max(|y_model| - d, 0)`.
    DeadZone,
    /// First-order sensor lag with time constant `tau`.
    FirstOrderLag,
}

impl GenericKind {
    /// Every generic effect.
    pub const ALL: [GenericKind; 7] = [
        GenericKind::SensorBias,
        GenericKind::SensorScale,
        GenericKind::Quantisation,
        GenericKind::MeasurementDelay,
        GenericKind::OutputSaturation,
        GenericKind::DeadZone,
        GenericKind::FirstOrderLag,
    ];

    /// Name used in verdicts (followed by `:<channel>`).
    pub fn name(self) -> &'static str {
        match self {
            GenericKind::SensorBias => "sensor_bias",
            GenericKind::SensorScale => "sensor_scale",
            GenericKind::Quantisation => "quantisation",
            GenericKind::MeasurementDelay => "measurement_delay",
            GenericKind::OutputSaturation => "output_saturation",
            GenericKind::DeadZone => "dead_zone",
            GenericKind::FirstOrderLag => "first_order_lag",
        }
    }

    /// The kind called `name`.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.iter().copied().find(|k| k.name() == name)
    }

    /// What the effect does to a measured channel.
    pub fn doc(self) -> &'static str {
        match self {
            GenericKind::SensorBias => "`y = y_model + bias`",
            GenericKind::SensorScale => "`y = (1 + scale_error) y_model`",
            GenericKind::Quantisation => {
                "`y = c + step round((y_model + e - c) / step - threshold)`, sensor noise `e` \
                 (std `noise_std`) before the quantiser, `threshold` in steps above \
                 round-to-nearest (0.5: floor; 0 unless another threshold pays for its \
                 parameter), `c` the readings' lattice offset"
            }
            GenericKind::MeasurementDelay => "`y(t) = y_model(t - delay_s)`",
            GenericKind::OutputSaturation => {
                "`y = clamp(y_model + e, lower_limit, limit)` on average over sensor noise `e` \
                 (std `noise_std`) before the clip; `lower_limit = -limit` (a symmetric range) \
                 and `noise_std = 0` unless they pay for their parameters"
            }
            GenericKind::DeadZone => {
                "`y = 0` where `abs(z) < width`, else `z - sign(z) shift width`, with `z = \
                 y_model + e`, on average over sensor noise `e` (std `noise_std`) before the \
                 zone; `shift = 1` (the shifted dead zone `sign(y_model) max(abs(y_model) - \
                 width, 0)`) and `noise_std = 0` unless they pay for their parameters \
                 (`shift = 0`: readings zeroed below `width`, as a low-flow cutoff); on a \
                 channel read exactly 0 ten times or more the zone comes after the noise \
                 and `noise_std` is the channel's noise"
            }
            GenericKind::FirstOrderLag => "first-order sensor lag, time constant `tau_s`",
        }
    }

    /// The generic catalogue as a Markdown table.
    pub fn describe_all() -> String {
        let mut s = String::from(
            "Candidates on every measured channel `y:<c>` of every plant, named `<effect>:<c>` \
             in verdicts (they are not catalogue effects, so not for `sim_effects`):\n\n| effect | parameters | model |\n|---|---|---|\n",
        );
        for k in Self::ALL {
            s.push_str(&format!(
                "| `{}` | {} | {} |\n",
                k.name(),
                k.param_names()
                    .iter()
                    .map(|p| format!("`{p}`"))
                    .collect::<Vec<_>>()
                    .join(", "),
                k.doc()
            ));
        }
        s
    }

    /// Parameter names in the ranking.
    pub fn param_names(self) -> &'static [&'static str] {
        match self {
            GenericKind::SensorBias => &["bias"],
            GenericKind::SensorScale => &["scale_error"],
            GenericKind::Quantisation => &["step", "noise_std", "threshold"],
            GenericKind::MeasurementDelay => &["delay_s"],
            GenericKind::OutputSaturation => &["limit", "lower_limit", "noise_std"],
            GenericKind::DeadZone => &["width", "shift", "noise_std"],
            GenericKind::FirstOrderLag => &["tau_s"],
        }
    }

    /// Search ranges (one per parameter) for a channel whose replayed output reaches
    /// `amplitude` (max |y|), whose measurements span `span` and whose noise is `sigma`.
    pub fn ranges(self, amplitude: f64, span: f64, sigma: f64, dt: f64) -> Vec<(f64, f64, Scale)> {
        let a = amplitude.max(sigma);
        match self {
            GenericKind::SensorBias => {
                let b = (0.5 * span).max(10.0 * sigma);
                vec![(-b, b, Scale::Linear)]
            }
            GenericKind::SensorScale => vec![(-0.9, 3.0, Scale::Linear)],
            GenericKind::Quantisation => vec![
                (0.05 * sigma, (0.25 * span).max(sigma), Scale::Log),
                (1e-3 * sigma, 2.0 * sigma, Scale::Log),
                (-0.5, 0.5, Scale::Linear),
            ],
            GenericKind::MeasurementDelay => vec![(0.01 * dt, 200.0 * dt, Scale::Log)],
            GenericKind::OutputSaturation => {
                vec![
                    (0.05 * a, a, Scale::Linear),
                    (-a, -0.05 * a, Scale::Linear),
                    (0.0, 1.5 * sigma, Scale::Linear),
                ]
            }
            // From below the noise: on a precise sensor with a large swing a tenth of a
            // thousandth of the swing is still many noise stds.
            GenericKind::DeadZone => vec![
                ((1e-4 * a).min(0.1 * sigma), 0.5 * a, Scale::Log),
                (0.0, 1.0, Scale::Linear),
                (0.0, 1.5 * sigma, Scale::Linear),
            ],
            GenericKind::FirstOrderLag => vec![(0.1 * dt, 200.0 * dt, Scale::Log)],
        }
    }

    /// Per parameter, where it adds nothing to the effect's simpler form (a
    /// round-to-nearest quantiser, a symmetric clip, a shifted dead zone), or `None`. Such a
    /// parameter is held there unless freeing it lowers the training cost by more than its
    /// BIC penalty.
    pub fn neutral_values(self) -> &'static [Option<Neutral>] {
        match self {
            GenericKind::Quantisation => &[None, None, Some(Neutral::At(0.0))],
            GenericKind::OutputSaturation => {
                &[None, Some(Neutral::MinusPrevious), Some(Neutral::At(0.0))]
            }
            GenericKind::DeadZone => &[None, Some(Neutral::At(1.0)), Some(Neutral::At(0.0))],
            _ => &[None],
        }
    }

    /// The reading of model output `v` under an effect that is a static map of it (bias,
    /// scale, clip, dead zone) with `params` as in [`GenericKind::apply`]; `None` for a
    /// quantiser (a random rounding) and the effects with memory.
    pub fn static_reading(self, params: &[f64], v: f64) -> Option<f64> {
        let p = params.first().copied().unwrap_or(0.0);
        match self {
            GenericKind::SensorBias => Some(v + p),
            GenericKind::SensorScale => Some(v * (1.0 + p)),
            GenericKind::OutputSaturation => Some(clipped_mean(
                v,
                params.get(1).copied().unwrap_or(-p),
                p,
                params.get(2).copied().unwrap_or(0.0),
            )),
            GenericKind::DeadZone => Some(
                dead_zone_moments(
                    v,
                    p,
                    params.get(1).copied().unwrap_or(1.0),
                    params.get(2).copied().unwrap_or(0.0),
                )
                .0,
            ),
            GenericKind::Quantisation
            | GenericKind::MeasurementDelay
            | GenericKind::FirstOrderLag => None,
        }
    }

    /// Applies the effect with parameters `params` (in [`GenericKind::param_names`] order;
    /// missing ones take their neutral value, else 0; a quantiser's lattice offset `c`
    /// follows its parameters) to a replayed output sampled every `dt`.
    pub fn apply(self, params: &[f64], y: &[f64], dt: f64) -> Vec<f64> {
        let p = params.first().copied().unwrap_or(0.0);
        match self {
            GenericKind::Quantisation => {
                let noise = params.get(1).copied().unwrap_or(0.0);
                let shift = quantiser_shift(params);
                let lattice = params.get(3).copied().unwrap_or(0.0);
                y.iter()
                    .map(|v| lattice + quantised_mean(v - shift, p, noise))
                    .collect()
            }
            GenericKind::MeasurementDelay => {
                let shift = (p / dt).max(0.0);
                let whole = shift.floor() as usize;
                let frac = shift - shift.floor();
                (0..y.len())
                    .map(|k| {
                        let a = y[k.saturating_sub(whole)];
                        let b = y[k.saturating_sub(whole + 1)];
                        (1.0 - frac) * a + frac * b
                    })
                    .collect()
            }
            GenericKind::SensorBias
            | GenericKind::SensorScale
            | GenericKind::OutputSaturation
            | GenericKind::DeadZone => y
                .iter()
                .map(|&v| self.static_reading(params, v).unwrap_or(v))
                .collect(),
            GenericKind::FirstOrderLag => {
                let alpha = 1.0 - (-dt / p.max(1e-12)).exp();
                let mut out = Vec::with_capacity(y.len());
                let mut state = y.first().copied().unwrap_or(0.0);
                for &v in y {
                    state += alpha * (v - state);
                    out.push(state);
                }
                out
            }
        }
    }
}

/// Where an extension parameter sits when it adds nothing to its effect's simpler form.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Neutral {
    /// At this value (a quantiser's threshold 0: round to nearest).
    At(f64),
    /// At minus the parameter before it (a clip's lower limit: a symmetric range).
    MinusPrevious,
}

/// Mean reading of a sensor clipped to `[lo, hi]` whose input is `v` plus Gaussian noise of
/// std `s` (a censored Gaussian's mean): near a limit the clip cuts the noise on one side,
/// so the mean reading falls short of `clamp(v, lo, hi)` by up to `0.4 s`.
pub fn clipped_mean(v: f64, lo: f64, hi: f64, s: f64) -> f64 {
    if !(s > 0.0 && lo < hi) {
        return v.max(lo).min(hi);
    }
    let cdf = |x: f64| 0.5 * libm::erfc(-x / std::f64::consts::SQRT_2);
    let pdf = |x: f64| (-0.5 * x * x).exp() / (std::f64::consts::TAU).sqrt();
    let (a, b) = ((lo - v) / s, (hi - v) / s);
    let mean = lo * cdf(a) + hi * (1.0 - cdf(b)) + v * (cdf(b) - cdf(a)) + s * (pdf(a) - pdf(b));
    if mean.is_finite() {
        mean
    } else {
        v.max(lo).min(hi)
    }
}

/// Mean and variance of the reading of a dead zone of `width` and `shift` (see
/// [`GenericKind::DeadZone`]) whose input is `v` plus Gaussian noise of std `s`: a mixture
/// of the zone's zero and the two truncated Gaussian tails beyond it, each shifted by
/// `shift width` towards zero. Near an edge the reading is zero or about the edge at random,
/// a variance of up to a quarter of the edge squared, which no mean prediction removes.
pub fn dead_zone_moments(v: f64, width: f64, shift: f64, s: f64) -> (f64, f64) {
    let exact = || {
        let mean = if v.abs() < width {
            0.0
        } else {
            v - v.signum() * shift * width
        };
        (mean, 0.0)
    };
    if !(s > 0.0 && width > 0.0 && v.is_finite()) {
        return exact();
    }
    let tail = |x: f64| 0.5 * libm::erfc(x / std::f64::consts::SQRT_2);
    let pdf = |x: f64| (-0.5 * x * x).exp() / (std::f64::consts::TAU).sqrt();
    let c = shift * width;
    // Per branch: probability, conditional mean and variance of the reading.
    let mut branches = [(0.0, 0.0, 0.0); 3];
    for (i, (a, sign)) in [((width - v) / s, 1.0), ((width + v) / s, -1.0)]
        .into_iter()
        .enumerate()
    {
        let p = tail(a);
        let lambda = pdf(a) / p;
        if p > 0.0 && lambda.is_finite() {
            // `z` beyond the edge at `sign width`: a Gaussian truncated at standardised `a`.
            let mean = v + sign * (s * lambda - c);
            let var = (s * s * (1.0 + a * lambda - lambda * lambda)).max(0.0);
            branches[i] = (p, mean, var);
        }
    }
    branches[2].0 = (1.0 - branches[0].0 - branches[1].0).max(0.0);
    let mean: f64 = branches.iter().map(|(p, m, _)| p * m).sum();
    let var: f64 = branches
        .iter()
        .map(|(p, m, w)| p * (w + (m - mean).powi(2)))
        .sum();
    if mean.is_finite() && var.is_finite() {
        (mean, var)
    } else {
        exact()
    }
}

/// The index of a dead zone's `noise_std` among its parameters.
const DEAD_ZONE_NOISE: usize = 2;

/// Readings exactly 0 that mark a deadband applied after the noise: a noisy sensor never
/// reads exactly 0, but a record may hold a few zeros as fill values.
const ZEROS_OF_A_DEADBAND: usize = 10;

/// The index of a quantiser's noise before it among its parameters.
const QUANTISER_NOISE: usize = 1;

/// Lags of the Ljung-Box tests that tell noise read through a fitted lag from noise after
/// it ([`Problem::noise_through_lag`]).
const LAG_WHITENESS_LAGS: usize = 10;

/// Ljung-Box p-value below which a residual is not white ([`Problem::noise_through_lag`]).
const LAG_WHITENESS_P: f64 = 0.01;

/// Whether a fitted component at `values` is a [`NoisySensorReplay`]'s sensor: a quantiser
/// or a dead zone, with noise before it (without, it is a static map read with the
/// channel's noise after it).
fn is_noisy_sensor(component: &Component, values: &[f64]) -> bool {
    let noise = match component {
        Component::Generic(GenericKind::Quantisation, _) => QUANTISER_NOISE,
        Component::Generic(GenericKind::DeadZone, _) => DEAD_ZONE_NOISE,
        _ => return false,
    };
    values.get(noise).is_some_and(|s| *s > 0.0)
}

/// What a quantiser with `params` (step, noise, threshold, lattice offset) subtracts from its
/// input before rounding to the nearest multiple of the step: `c + h q`.
fn quantiser_shift(params: &[f64]) -> f64 {
    let at = |i: usize| params.get(i).copied().unwrap_or(0.0);
    at(3) + at(2) * at(0)
}

/// The offset `c` of a lattice `c + j q` that the readings `y` lie on (their circular mean
/// residue modulo `q`, in `[-q/2, q/2]`; 0 when nothing is finite).
pub fn lattice_offset(y: &[f64], q: f64) -> f64 {
    let (mut sin, mut cos) = (0.0, 0.0);
    for v in y.iter().filter(|v| v.is_finite()) {
        let phase = std::f64::consts::TAU * (v / q - (v / q).round());
        sin += phase.sin();
        cos += phase.cos();
    }
    if sin == 0.0 && cos == 0.0 {
        return 0.0;
    }
    q * sin.atan2(cos) / std::f64::consts::TAU
}

/// Expected reading of a quantiser of step `q` whose input is `v` plus Gaussian noise of
/// std `s`: `sum_j q j P(round((v + e) / q) = j)`. With noise of a few steps the reading's
/// mean is (nearly) `v` and the quantiser adds variance, not a staircase; with `s` -> 0 it
/// is `q round(v / q)`.
pub fn quantised_mean(v: f64, q: f64, s: f64) -> f64 {
    let q = q.max(1e-300);
    let r = s / q;
    if r.is_nan() || r <= 1e-9 {
        return q * (v / q).round();
    }
    if r >= 0.5 {
        // Fourier series of the rounding error, each harmonic damped by the noise:
        // q round(x) = q x - (q / pi) sum_k (-1)^(k+1) sin(2 pi k x) / k, x = v / q.
        let x = v / q;
        let mut acc = 0.0;
        for k in 1..=3 {
            let kf = k as f64;
            let damp = (-2.0 * std::f64::consts::PI.powi(2) * kf * kf * r * r).exp();
            let sign = if k % 2 == 1 { 1.0 } else { -1.0 };
            acc += sign * damp * (std::f64::consts::TAU * kf * x).sin() / kf;
        }
        return v - q / std::f64::consts::PI * acc;
    }
    lattice_moments(v, q, s).0
}

/// Mean and variance of the reading of [`quantised_mean`]'s quantiser summed over the few
/// lattice points that carry the probability (noise below half a step).
fn lattice_moments(v: f64, q: f64, s: f64) -> (f64, f64) {
    let centre = (v / q).round();
    let reach = (6.0 * s / q).ceil() + 1.0;
    // Beyond 2^53 steps from zero `j + 1 == j`: a loop stepping `j` by one never ended (a
    // diverging replay hung the fit). There the steps are far below the float spacing.
    if !(centre.is_finite() && reach.is_finite()) || centre.abs() > 1e15 || reach > 1e6 {
        return (q * centre, 0.0);
    }
    let cdf = |x: f64| 0.5 * libm::erfc(-x / std::f64::consts::SQRT_2);
    let (mut m1, mut m2) = (0.0, 0.0);
    let points = (2.0 * reach) as u64;
    for i in 0..=points {
        let j = centre - reach + i as f64;
        let p = cdf((q * (j + 0.5) - v) / s) - cdf((q * (j - 0.5) - v) / s);
        m1 += q * j * p;
        m2 += (q * j).powi(2) * p;
    }
    (m1, (m2 - m1 * m1).max(0.0))
}

/// Variance of that reading around [`quantised_mean`]: what is left after the candidate's
/// prediction when the quantiser is the whole gap (near a threshold the reading jumps a
/// whole step at random). Dithered (noise of half a step or more): `s^2 + q^2 / 12`.
pub fn quantised_variance(v: f64, q: f64, s: f64) -> f64 {
    let q = q.max(1e-300);
    let r = s / q;
    if r.is_nan() || r <= 1e-9 {
        0.0
    } else if r >= 0.5 {
        s * s + q * q / 12.0
    } else {
        lattice_moments(v, q, s).1
    }
}

/// One part of a candidate.
#[derive(Clone, Debug, PartialEq)]
pub enum Component {
    /// The plant effect with this index in the problem's plant catalogue.
    Plant(usize),
    /// A generic effect on the output channel with this index.
    Generic(GenericKind, usize),
}

/// A parameter being fitted: which component, its name and range.
#[derive(Clone, Debug, PartialEq)]
struct Dim {
    component: usize,
    name: String,
    lo: f64,
    hi: f64,
    scale: Scale,
    /// See [`GenericKind::neutral_values`].
    neutral: Option<Neutral>,
    /// Held at its neutral value (searched over no range).
    pinned: bool,
}

/// Everything the candidates are fitted and scored against.
#[derive(Clone)]
pub struct Problem<'a> {
    /// The plant.
    pub plant: &'a dyn GapPlant,
    /// The data.
    pub data: &'a PlantData,
    /// Model parameters: defaults overridden by `[model]`.
    pub base: Params,
    /// Effects the user's model includes.
    pub sim_effects: Vec<String>,
    /// Candidate plant effects (the plant catalogue less `sim_effects` and effects whose
    /// inputs are absent).
    pub plant_effects: Vec<EffectSpec>,
    /// Output channel names.
    pub outputs: Vec<String>,
    /// Measured values per output channel.
    pub measured: Vec<Vec<f64>>,
    /// Per channel, the step and offset of the lattice its readings lie on (see
    /// [`channel_lattices`]).
    pub lattices: Vec<Option<(f64, f64)>>,
    /// Per channel off a lattice, the step and offset of a lattice its readings scatter
    /// about (a quantiser before the noise; see [`staircase_lattice`]).
    pub staircases: Vec<Option<(f64, f64)>>,
    /// Per channel, whether a deadband after the noise zeroed its readings (see
    /// [`zeroed_channels`]).
    pub zeroed: Vec<bool>,
    /// Noise std per channel.
    pub sigma: Vec<f64>,
    /// Effective degrees of freedom of each sigma (infinite when declared in meta).
    pub sigma_dof: Vec<f64>,
    /// Kurtosis of each channel's noise: 3 (Gaussian) unless the diagnosis found its tails
    /// heavier ([`crate::gap::stats::heavy_tailed_noise`]).
    pub noise_kurtosis: Vec<f64>,
    /// AR(1) coefficient of each channel's noise: 0 (white) unless the diagnosis found its
    /// samples correlated ([`crate::gap::stats::ar1_from_differences`]).
    pub noise_ar1: Vec<f64>,
    /// Training samples.
    pub train: Vec<bool>,
    /// Held-out samples.
    pub test: Vec<bool>,
    /// The replay of the user's model, initial condition refitted (see [`Problem::predict`]).
    pub nominal: Simulation,
    /// The replay of the user's model from the measured initial condition.
    pub nominal_raw: Simulation,
    /// Sensitivity of the replay to the initial value of each output channel that the
    /// plant initialises from the data.
    pub init_sensitivity: Vec<StartSensitivity>,
}

/// A fitted and scored candidate.
#[derive(Clone, Debug, Serialize)]
pub struct Evaluation {
    /// Effect name (`a+b` for a pair; generic effects as `kind:channel`).
    pub effect: String,
    /// Component names.
    pub components: Vec<String>,
    /// Fitted parameters by name.
    pub params: Vec<(String, f64)>,
    /// Held-out log-likelihood minus the parameter penalty, relative to the user's model
    /// (nats; positive = better than the model).
    pub score: f64,
    /// Held-out gap of the user's model (see [`Problem::gap`]).
    pub gap_before: f64,
    /// Held-out gap with the fitted effect added.
    pub gap_after: f64,
    /// `1 - gap_after / gap_before`.
    pub shrink: f64,
    /// RMS error of the open-loop replay's states against the truth columns (held-out,
    /// each column in units of its own std), with the user's model.
    pub replay_error_before: Option<f64>,
    /// The same with the fitted effect.
    pub replay_error_after: Option<f64>,
    /// The same for the plant's estimator ([`GapPlant::estimate`], closed loop on the
    /// measurements) with the user's model and sensors.
    pub estimation_error_before: Option<f64>,
    /// The estimator's error with the fitted effect in its model and sensors.
    pub estimation_error_after: Option<f64>,
    /// Holm-adjusted p-value of the held-out block (and channel) whose residual variance
    /// exceeds the noise the most (see [`Problem::worst_block_p`]).
    pub worst_block_p: f64,
    /// The replay's outputs are innovations ([`Simulation::innovations`]).
    #[serde(skip)]
    pub innovations: bool,
    /// Training cost at the fit (sum of squared standardised residuals).
    #[serde(skip)]
    pub train_cost: f64,
    /// Raw held-out log-likelihood minus penalty (for pair comparisons).
    #[serde(skip)]
    pub absolute_score: f64,
    /// Held-out log-likelihood per batch of [`HELD_OUT_BATCHES`] (how well the held-out
    /// data separate two candidates, see [`separation`]).
    #[serde(skip)]
    pub batch_ll: Vec<f64>,
    /// The components and fitted values, to replay the candidate.
    #[serde(skip)]
    pub fitted: Vec<(Component, Vec<f64>)>,
    /// Per channel: (training RSS, training count, held-out RSS, held-out count) of the
    /// fitted replay (diagnostics for `gap-bench`'s `bench.json`).
    #[serde(skip)]
    pub channel_rss: Vec<[f64; 4]>,
}

impl Evaluation {
    /// Whether `other` adds the same effects, in any order (a pair is named after its
    /// members' ranking, which two folds need not share).
    pub fn same_effects(&self, other: &Evaluation) -> bool {
        fn sorted(e: &Evaluation) -> Vec<&str> {
            let mut c: Vec<&str> = e.components.iter().map(String::as_str).collect();
            c.sort_unstable();
            c
        }
        sorted(self) == sorted(other)
    }
}

impl<'a> Problem<'a> {
    /// Name of a component.
    pub fn component_name(&self, c: &Component) -> String {
        match c {
            Component::Plant(i) => self.plant_effects[*i].name.to_string(),
            Component::Generic(kind, ch) => format!("{}:{}", kind.name(), self.outputs[*ch]),
        }
    }

    /// The step and offset of the lattice channel `ch` reads on ([`Problem::lattices`]) or
    /// scatters about ([`Problem::staircases`]), if any.
    fn lattice_of(&self, ch: usize) -> Option<(f64, f64)> {
        self.lattices[ch].or(self.staircases[ch])
    }

    /// Every single-component candidate.
    pub fn single_candidates(&self) -> Vec<Component> {
        let mut out: Vec<Component> = (0..self.plant_effects.len())
            .map(Component::Plant)
            .collect();
        for (ch, channel) in self.outputs.iter().enumerate() {
            for kind in GenericKind::ALL {
                // A plant effect that is the same prediction under the plant's own name
                // stands in for it (two names for one fit would split the ranking).
                let replaced = self.plant_effects.iter().any(|e| {
                    e.replaces_generic
                        .iter()
                        .any(|(k, c)| *k == kind.name() && c == channel)
                });
                // A quantiser's readings lie on its lattice whatever the noise before it
                // (`y = q round((y_model + e) / q)`), or scatter about one with the noise
                // after it; else its conditional mean is only a periodic distortion that
                // mimics other effects.
                let impossible = kind == GenericKind::Quantisation && self.lattice_of(ch).is_none();
                if !replaced && !impossible {
                    out.push(Component::Generic(kind, ch));
                }
            }
        }
        out
    }

    fn dims(&self, components: &[Component]) -> Vec<Dim> {
        let mut dims = Vec::new();
        for (ci, c) in components.iter().enumerate() {
            match c {
                Component::Plant(i) => {
                    for r in &self.plant_effects[*i].fit {
                        let model = self.base.get(r.name).copied();
                        let (lo, hi) = match (r.side, model) {
                            (Side::BelowModel, Some(m)) => (r.lo.min(m), r.hi.min(m)),
                            (Side::AboveModel, Some(m)) => (r.lo.max(m), r.hi.max(m)),
                            _ => (r.lo, r.hi),
                        };
                        dims.push(Dim {
                            component: ci,
                            name: r.name.to_string(),
                            lo,
                            hi,
                            scale: r.scale,
                            neutral: None,
                            pinned: false,
                        });
                    }
                }
                Component::Generic(kind, ch) => {
                    let amplitude = self.nominal.outputs[*ch]
                        .iter()
                        .fold(0.0f64, |m, v| m.max(v.abs()));
                    let finite = self.measured[*ch].iter().filter(|v| v.is_finite());
                    let (lo, hi) = finite.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
                        (a.min(v), b.max(v))
                    });
                    let span = (hi - lo).max(0.0);
                    let sigma = self.sigma[*ch];
                    let mut ranges = kind.ranges(amplitude, span, sigma, self.data.dt);
                    if let (GenericKind::Quantisation, Some((q, _))) = (kind, self.lattice_of(*ch))
                    {
                        // The readings give the step to float precision; over thousands of
                        // steps a step off by a fraction of a percent misplaces the lattice.
                        ranges[0] = (q, q, Scale::Linear);
                    }
                    // Readings exactly 0, again and again, off a lattice: no noise comes
                    // after a deadband that zeroes them, so the noise before it is the
                    // channel's, measured off the other readings. Fitted, it fell to 0
                    // where the training blocks cross the edge only where a hard edge
                    // agrees (a mean and variance misjudge the two-valued reading there).
                    if *kind == GenericKind::DeadZone && self.zeroed[*ch] {
                        ranges[DEAD_ZONE_NOISE] = (sigma, sigma, Scale::Linear);
                    }
                    for ((name, (lo, hi, scale)), neutral) in kind
                        .param_names()
                        .iter()
                        .zip(ranges)
                        .zip(kind.neutral_values())
                    {
                        let neutral = match neutral {
                            Some(Neutral::At(v)) => Some(Neutral::At(v.clamp(lo, hi))),
                            n => *n,
                        };
                        dims.push(Dim {
                            component: ci,
                            name: name.to_string(),
                            lo,
                            hi,
                            scale,
                            neutral,
                            pinned: false,
                        });
                    }
                }
            }
        }
        dims
    }

    /// A quantiser's fitted values followed by its channel's lattice offset (other kinds'
    /// values unchanged).
    fn with_lattice(&self, kind: GenericKind, ch: usize, values: &[f64]) -> Vec<f64> {
        let mut v = values.to_vec();
        if kind == GenericKind::Quantisation {
            v.resize(3, 0.0);
            v.push(self.lattice_of(ch).map_or(0.0, |(_, offset)| offset));
        }
        v
    }

    /// Applies the generic components of `fitted` to a replay.
    fn apply_generic(
        &self,
        mut outputs: Vec<Vec<f64>>,
        fitted: &[(Component, Vec<f64>)],
    ) -> Vec<Vec<f64>> {
        for (c, values) in fitted {
            if let Component::Generic(kind, ch) = c {
                let y = &mut outputs[*ch];
                *y = kind.apply(&self.with_lattice(*kind, *ch, values), y, self.data.dt);
            }
        }
        outputs
    }

    /// The replay from the measured initial condition, then the generic components, with
    /// the initial condition refitted on the training samples (Gauss-Newton on the linear
    /// sensitivity, see [`refit_start`]): the first measurement carries noise and, under a
    /// sensor effect (bias, scale, saturation, ...), the effect itself, which a slow plant
    /// would carry through the whole record.
    /// A quantiser, and a dead zone that jumps at its edge (`shift < 1`), are applied after
    /// the refit: through a staircase or a jump one Gauss-Newton step lands anywhere (a
    /// record that starts inside a zeroing deadband moved its start by the whole zone).
    /// A quantiser's rounding averages out of the fit without it (all but its thresholds'
    /// offset, a bias of `-threshold step`, which the refit sees); readings inside a dead
    /// zone are left out of the fit.
    fn with_refitted_start(&self, raw: Simulation, fitted: &[(Component, Vec<f64>)]) -> Simulation {
        let (after_refit, others): (Vec<_>, Vec<_>) = fitted.iter().cloned().partition(|(c, v)| {
            matches!(c, Component::Generic(GenericKind::Quantisation, _))
                || matches!(c, Component::Generic(GenericKind::DeadZone, _))
                    && v.get(1).is_some_and(|shift| *shift < 1.0)
        });
        // What a quantiser's rounding leaves on average is its thresholds' offset: the
        // refit sees it as a bias, which comes off again before the quantiser acts.
        let offsets: Vec<(usize, f64)> = after_refit
            .iter()
            .filter_map(|(c, v)| match c {
                Component::Generic(GenericKind::Quantisation, ch) => Some((
                    *ch,
                    v.get(2).copied().unwrap_or(0.0) * v.first().copied().unwrap_or(0.0),
                )),
                _ => None,
            })
            .collect();
        // Readings inside a dead zone applied after the refit say nothing about the start
        // the refit can see.
        let mut zoned = std::borrow::Cow::Borrowed(&self.measured);
        for (c, v) in &after_refit {
            if let Component::Generic(GenericKind::DeadZone, ch) = c {
                let width = v.first().copied().unwrap_or(0.0);
                for y in zoned.to_mut()[*ch].iter_mut() {
                    if y.abs() < width {
                        *y = f64::NAN;
                    }
                }
            }
        }
        let mut outputs = refit_start(
            &raw.outputs,
            &self.init_sensitivity,
            &zoned,
            &self.sigma,
            |k| self.train[k],
            |outputs| {
                let mut out = self.apply_generic(outputs, &others);
                for &(ch, offset) in &offsets {
                    out[ch].iter_mut().for_each(|v| *v -= offset);
                }
                out
            },
        );
        for &(ch, offset) in &offsets {
            outputs[ch].iter_mut().for_each(|v| *v += offset);
        }
        Simulation {
            outputs: self.apply_generic(outputs, &after_refit),
            states: raw.states,
            variances: raw.variances,
            innovations: raw.innovations,
        }
    }

    /// Replays the model with the candidate's components at `values` (one vector per
    /// component, in `dims` order).
    pub fn predict(&self, fitted: &[(Component, Vec<f64>)]) -> Result<Simulation, String> {
        let plant_parts: Vec<&(Component, Vec<f64>)> = fitted
            .iter()
            .filter(|(c, _)| matches!(c, Component::Plant(_)))
            .collect();
        let raw = if plant_parts.is_empty() {
            self.nominal_raw.clone()
        } else {
            let (params, active) = self.model_with(fitted);
            self.plant.simulate(&params, &active, self.data)?
        };
        Ok(self.with_refitted_start(raw, fitted))
    }

    /// The user's model with the plant components of `fitted` added: its parameters and
    /// active effects.
    fn model_with(&self, fitted: &[(Component, Vec<f64>)]) -> (Params, Vec<&str>) {
        let mut params = self.base.clone();
        let mut active: Vec<&str> = self.sim_effects.iter().map(String::as_str).collect();
        for (c, values) in fitted {
            if let Component::Plant(i) = c {
                let spec = &self.plant_effects[*i];
                active.push(spec.name);
                for (r, v) in spec.fit.iter().zip(values) {
                    params.insert(r.name.to_string(), *v);
                }
            }
        }
        (params, active)
    }

    /// The plant's estimator ([`GapPlant::estimate`]) run over the record with the model and
    /// sensors of `fitted` (empty: the user's model), scored against the truth columns as
    /// [`Problem::truth_error`] scores a replay. `None` without truth columns or without an
    /// estimator for the plant; `Err` when the estimator fails on this model.
    pub fn estimation_error(
        &self,
        fitted: &[(Component, Vec<f64>)],
    ) -> Option<Result<f64, String>> {
        if self.data.truth.is_empty() {
            return None;
        }
        Some(
            self.run_estimator(fitted)?
                .and_then(|e| self.estimates_error(&e)),
        )
    }

    /// The plant's estimator over the record with `fitted` in its model and sensors
    /// (`None`: the plant has none).
    pub fn run_estimator(
        &self,
        fitted: &[(Component, Vec<f64>)],
    ) -> Option<Result<Estimates, String>> {
        let (params, active) = self.model_with(fitted);
        // A lag's replay tells whether the noise went through it.
        let has_lag = fitted
            .iter()
            .any(|(c, _)| matches!(c, Component::Generic(GenericKind::FirstOrderLag, _)));
        let replay = if has_lag {
            self.predict(fitted).ok()
        } else {
            None
        };
        let channels = (0..self.outputs.len())
            .map(|ch| {
                let effects: Vec<(GenericKind, Vec<f64>)> = fitted
                    .iter()
                    .filter_map(|(c, v)| match c {
                        Component::Generic(kind, c) if *c == ch => {
                            let mut values = self.with_lattice(*kind, ch, v);
                            if let (GenericKind::FirstOrderLag, Some(sim)) = (kind, &replay)
                                && let Some(before) = self.noise_before_lag(sim, fitted, ch)
                            {
                                values.push(before);
                            }
                            Some((*kind, values))
                        }
                        _ => None,
                    })
                    .collect();
                ChannelSensor::new(
                    &self.measured[ch],
                    self.sigma[ch],
                    self.data.dt,
                    &effects,
                    self.lattices[ch].is_some(),
                )
            })
            .collect();
        self.plant
            .estimate(&params, &active, self.data, &Sensors { channels })
    }

    /// [`Problem::states_error`] of an estimator's run.
    fn estimates_error(&self, estimates: &Estimates) -> Result<f64, String> {
        self.states_error(&estimates.states)
            .ok_or_else(|| "no truth column is an estimated state".to_string())
    }

    /// Fills [`Evaluation::estimation_error_before`] and `_after` of the reported ranking
    /// and pairs from `user` (the estimator's run with the user's model, made once by the
    /// caller) and one run per candidate; nothing without truth columns.
    pub fn add_estimation_errors(
        &self,
        ranking: &mut [Evaluation],
        pairs: &mut [Evaluation],
        user: Option<&Result<Estimates, String>>,
    ) {
        let Some(user) = user.filter(|_| !self.data.truth.is_empty()) else {
            return;
        };
        let before = user
            .as_ref()
            .ok()
            .and_then(|e| self.estimates_error(e).ok());
        for e in ranking.iter_mut().chain(pairs.iter_mut()) {
            e.estimation_error_before = before;
            e.estimation_error_after = self.estimation_error(&e.fitted).and_then(Result::ok);
        }
    }

    /// The same problem on `data` (the record read under another
    /// [`crate::gap::plant::InputTiming`]): the user's model replayed on it, its start
    /// sensitivities measured and its start refitted.
    pub fn replayed_on<'b>(&self, data: &'b PlantData) -> Result<Problem<'b>, String>
    where
        'a: 'b,
    {
        let active: Vec<&str> = self.sim_effects.iter().map(String::as_str).collect();
        let raw = self.plant.simulate(&self.base, &active, data)?;
        let starts: Vec<(String, f64)> = self
            .outputs
            .iter()
            .cloned()
            .zip(self.sigma.iter().copied())
            .collect();
        let init_sensitivity = start_sensitivities(data, &starts, &raw.outputs, |moved| {
            self.plant
                .simulate(&self.base, &active, moved)
                .ok()
                .map(|sim| sim.outputs)
        });
        let mut problem = Problem {
            plant: self.plant,
            data,
            nominal: raw.clone(),
            nominal_raw: raw,
            init_sensitivity,
            ..self.clone()
        };
        problem.refit_nominal();
        Ok(problem)
    }

    /// Chi-square of `sim` over the training samples (each channel's squared residuals
    /// over its noise variance), and its expectation under the noise alone (the number of
    /// finite training readings).
    pub fn train_chi2(&self, sim: &Simulation) -> (f64, usize) {
        let terms = self
            .channel_rss(sim, &self.train)
            .iter()
            .map(|(_, n)| n)
            .sum();
        (self.train_cost(sim), terms)
    }

    /// The user's model with its initial condition refitted (the baseline of every score).
    pub fn refit_nominal(&mut self) {
        self.nominal = self.with_refitted_start(self.nominal_raw.clone(), &[]);
    }

    /// Per-channel (sum of squared residuals, count) over the samples in `mask`.
    pub fn channel_rss(&self, sim: &Simulation, mask: &[bool]) -> Vec<(f64, usize)> {
        self.measured
            .iter()
            .zip(&sim.outputs)
            .map(|(y, m)| {
                let mut rss = 0.0;
                let mut n = 0;
                for k in 0..y.len() {
                    if mask[k] && y[k].is_finite() {
                        let r = y[k] - m[k];
                        rss += if r.is_finite() { r * r } else { f64::INFINITY };
                        n += 1;
                    }
                }
                (rss, n)
            })
            .collect()
    }

    /// Per channel: (training RSS, count, held-out RSS, count) of `sim`.
    pub fn rss_split(&self, sim: &Simulation) -> Vec<[f64; 4]> {
        self.channel_rss(sim, &self.train)
            .iter()
            .zip(self.channel_rss(sim, &self.test))
            .map(|((a, na), (b, nb))| [*a, *na as f64, b, nb as f64])
            .collect()
    }

    fn train_cost(&self, sim: &Simulation) -> f64 {
        self.channel_rss(sim, &self.train)
            .iter()
            .zip(&self.sigma)
            .map(|((rss, _), s)| rss / (s * s))
            .sum()
    }

    /// Held-out gap: `sqrt(sum_c max(0, MSE_c / sigma_c^2 - 1))`, the residual beyond the
    /// noise in noise units (0 when the model explains the data to within its noise).
    pub fn gap(&self, sim: &Simulation) -> f64 {
        self.channel_rss(sim, &self.test)
            .iter()
            .zip(&self.sigma)
            .map(|((rss, n), s)| (rss / (*n).max(1) as f64 / (s * s) - 1.0).max(0.0))
            .sum::<f64>()
            .sqrt()
    }

    /// [`Problem::gap`] of a candidate's replay `sim`, where a noisy sensor among its
    /// components also predicts the reading's variance: the residual of its channel is
    /// measured against the larger of the noise and that variance (a coarse quantiser near a
    /// threshold reads a whole step off at random, which no mean prediction removes and
    /// which is the noise of a quantised sensor, not a gap).
    /// `sensors` is [`Problem::noisy_sensors`] of those components.
    pub fn gap_of(&self, sim: &Simulation, sensors: &[Option<NoisySensorReplay>]) -> f64 {
        let mut total = 0.0;
        for (c, (y, m)) in self.measured.iter().zip(&sim.outputs).enumerate() {
            let s2 = self
                .noise_beside_spread(sim, c)
                .unwrap_or(self.sigma[c] * self.sigma[c]);
            let sensor = sensors.get(c).and_then(Option::as_ref);
            let added = added_variance(sim, c);
            let (mut acc, mut n) = (0.0, 0usize);
            for k in 0..y.len() {
                if !(self.test[k] && y[k].is_finite()) {
                    continue;
                }
                let var = match sensor {
                    Some(sensor) => s2.max(sensor.variance(k)),
                    None => s2,
                } + added.map_or(0.0, |a| a[k]);
                let r = y[k] - m[k];
                acc += if r.is_finite() {
                    r * r / var
                } else {
                    f64::INFINITY
                };
                n += 1;
            }
            total += (acc / n.max(1) as f64 - 1.0).max(0.0);
        }
        total.sqrt()
    }

    /// Whether the residual `sim` leaves is noise block by block: for every contiguous
    /// held-out block and channel, the p-value that its mean squared standardised residual
    /// exceeds 1 (against a noisy sensor's predicted variance where one is fitted, as in
    /// [`Problem::gap_of`]); returns the smallest, Holm-adjusted over all of them.
    pub fn worst_block_p(&self, sim: &Simulation, sensors: &[Option<NoisySensorReplay>]) -> f64 {
        let mut blocks: Vec<(usize, usize)> = Vec::new();
        for (k, &held) in self.test.iter().enumerate() {
            match blocks.last_mut() {
                Some((_, end)) if held && *end == k => *end = k + 1,
                _ if held => blocks.push((k, k + 1)),
                _ => {}
            }
        }
        let mut p = Vec::new();
        for (c, (y, m)) in self.measured.iter().zip(&sim.outputs).enumerate() {
            let s2 = self
                .noise_beside_spread(sim, c)
                .unwrap_or(self.sigma[c] * self.sigma[c]);
            let sensor = sensors.get(c).and_then(Option::as_ref);
            let added = added_variance(sim, c);
            for &(a, b) in &blocks {
                let (mut acc, mut n) = (0.0, 0usize);
                for k in a..b {
                    let r = y[k] - m[k];
                    if !r.is_finite() {
                        continue;
                    }
                    let var = match sensor {
                        Some(sensor) => s2.max(sensor.variance(k)),
                        None => s2,
                    } + added.map_or(0.0, |a| a[k]);
                    acc += r * r / var;
                    n += 1;
                }
                if n > 0 {
                    p.push(variance_ratio_p(
                        acc / n as f64,
                        self.gaussian_samples(c, n),
                        self.sigma_dof[c],
                    ));
                }
                if let Some(spread) = added.filter(|_| sim.innovations) {
                    p.push(innovation_means_p(&y[a..b], &m[a..b], |k| {
                        s2 + spread[a + k]
                    }));
                }
            }
        }
        holm(&p).into_iter().fold(1.0, f64::min)
    }

    /// How many independent Gaussian samples a mean of `n` consecutive squared standardised
    /// residuals of channel `c` is worth (`n` unless its noise is heavy-tailed or
    /// correlated; see [`crate::gap::stats::gaussian_equivalent_samples`] and
    /// [`crate::gap::stats::ar1_equivalent_samples`]).
    pub fn gaussian_samples(&self, c: usize, n: usize) -> f64 {
        let kurtosis = self.noise_kurtosis.get(c).copied().unwrap_or(3.0);
        let phi = self.noise_ar1.get(c).copied().unwrap_or(0.0);
        let independent = gaussian_equivalent_samples(n as f64, kurtosis);
        if phi == 0.0 {
            independent
        } else {
            ar1_equivalent_samples(independent, phi)
        }
    }

    /// The smallest held-out gap that noise cannot produce: three standard deviations of
    /// `sum_c (MSE_c / sigma_c^2 - 1)` when the model is right (each term has variance
    /// `2 / n_c + 2 / dof_c`, the held-out count (its Gaussian equivalent,
    /// [`Problem::gaussian_samples`]) and the noise estimate's degrees of freedom), as a gap (square root). Below it, a candidate's shrink is meaningless and
    /// only its likelihood tells whether it explains something (an effect on the noise's
    /// distribution, such as a coarse quantiser, rather than on the mean).
    pub fn gap_resolution(&self) -> f64 {
        let var: f64 = self
            .channel_rss(&self.nominal, &self.test)
            .iter()
            .zip(&self.sigma_dof)
            .enumerate()
            .map(|(c, ((_, n), dof))| 2.0 / self.gaussian_samples(c, (*n).max(1)) + 2.0 / dof)
            .sum();
        (3.0 * var.sqrt()).sqrt()
    }

    /// The held-out log-likelihood of [`Problem::held_out_score`] (no penalty) split into
    /// [`HELD_OUT_BATCHES`] runs of consecutive held-out samples.
    pub fn held_out_batches(&self, sim: &Simulation, predicted: &[Option<Vec<f64>>]) -> Vec<f64> {
        let train = self.channel_rss(sim, &self.train);
        let held: Vec<usize> = (0..self.test.len()).filter(|&k| self.test[k]).collect();
        let mut out = vec![0.0; HELD_OUT_BATCHES];
        for (c, ((y, m), s)) in self
            .measured
            .iter()
            .zip(&sim.outputs)
            .zip(&self.sigma)
            .enumerate()
        {
            let (rss_tr, n_tr) = train[c];
            let var = (rss_tr / n_tr.max(1) as f64).max(0.5 * s * s);
            let norm = 0.5 * (std::f64::consts::TAU * var).ln();
            let own = predicted.get(c).and_then(Option::as_ref);
            for (i, &k) in held.iter().enumerate() {
                if y[k].is_finite() {
                    let r = y[k] - m[k];
                    let ll = if !r.is_finite() {
                        f64::NEG_INFINITY
                    } else if let Some(v) = own {
                        gaussian_log_density(r, v[k])
                    } else {
                        -norm - 0.5 * r * r / var
                    };
                    out[i * HELD_OUT_BATCHES / held.len().max(1)] += ll;
                }
            }
        }
        out
    }

    /// Held-out Gaussian log-likelihood with per-channel variance from the training
    /// residuals (per sample from `predicted` where a candidate predicts it, see
    /// [`Problem::predicted_variances`]), minus `k/2 ln n_train`.
    pub fn held_out_score(
        &self,
        sim: &Simulation,
        k: usize,
        predicted: &[Option<Vec<f64>>],
    ) -> f64 {
        let train = self.channel_rss(sim, &self.train);
        let test = self.channel_rss(sim, &self.test);
        let mut ll = 0.0;
        let mut n_train = 0;
        for (c, (((rss_tr, n_tr), (rss_te, n_te)), s)) in
            train.iter().zip(&test).zip(&self.sigma).enumerate()
        {
            if let Some(v) = predicted.get(c).and_then(Option::as_ref) {
                let (y, m) = (&self.measured[c], &sim.outputs[c]);
                for j in 0..y.len() {
                    if self.test[j] && y[j].is_finite() {
                        let r = y[j] - m[j];
                        ll += gaussian_log_density(r, v[j]);
                    }
                }
                n_train += n_tr;
                continue;
            }
            // Floored at half the noise variance: on noise-free (simulated) data a perfect fit
            // would otherwise make any held-out residual infinitely unlikely.
            let var = (rss_tr / (*n_tr).max(1) as f64).max(0.5 * s * s);
            ll -= 0.5 * *n_te as f64 * (std::f64::consts::TAU * var).ln() + 0.5 * rss_te / var;
            n_train += n_tr;
        }
        let score = ll - 0.5 * k as f64 * (n_train.max(2) as f64).ln();
        if score.is_finite() {
            score
        } else {
            f64::NEG_INFINITY
        }
    }

    /// The sensor noise variance beside the spread a replay adds to channel `c`
    /// ([`Simulation::variances`]), by maximum likelihood on the training samples and at
    /// most the channel's noise estimate: that estimate, taken from the readings, already
    /// holds the spread's average (`None` without a spread).
    fn noise_beside_spread(&self, sim: &Simulation, c: usize) -> Option<f64> {
        let added = added_variance(sim, c)?;
        let (y, m) = (&self.measured[c], &sim.outputs[c]);
        let terms: Vec<(f64, f64)> = (0..y.len())
            .filter(|&k| self.train[k])
            .map(|k| ((y[k] - m[k]).powi(2), added[k]))
            .filter(|(r2, a)| r2.is_finite() && a.is_finite())
            .collect();
        let s2 = self.sigma[c] * self.sigma[c];
        let cost = |ln_v: f64| -> f64 {
            let v = ln_v.exp();
            terms
                .iter()
                .map(|(r2, a)| (v + a).ln() + r2 / (v + a))
                .sum()
        };
        // Golden section on the log variance between 1e-4 and 1 times the estimate.
        let (mut lo, mut hi) = ((1e-4 * s2).ln(), s2.ln());
        let g = 0.5 * (5f64.sqrt() - 1.0);
        let (mut x1, mut x2) = (hi - g * (hi - lo), lo + g * (hi - lo));
        let (mut f1, mut f2) = (cost(x1), cost(x2));
        for _ in 0..40 {
            if f1 <= f2 {
                (hi, x2, f2) = (x2, x1, f1);
                x1 = hi - g * (hi - lo);
                f1 = cost(x1);
            } else {
                (lo, x1, f1) = (x1, x2, f2);
                x2 = lo + g * (hi - lo);
                f2 = cost(x2);
            }
        }
        let best = if cost(s2.ln()) < f1.min(f2) {
            s2.ln()
        } else {
            0.5 * (x1 + x2)
        };
        Some(best.exp())
    }

    /// Per channel, the noisy sensor among `fitted` on it, if any: a quantiser, or a dead
    /// zone with noise before it (see [`NoisySensorReplay`]).
    pub fn noisy_sensors(
        &self,
        fitted: &[(Component, Vec<f64>)],
    ) -> Vec<Option<NoisySensorReplay>> {
        (0..self.measured.len())
            .map(|c| self.noisy_sensor_on(fitted, c))
            .collect()
    }

    fn noisy_sensor_on(
        &self,
        fitted: &[(Component, Vec<f64>)],
        c: usize,
    ) -> Option<NoisySensorReplay> {
        let at = fitted.iter().position(|(comp, v)| {
            matches!(comp, Component::Generic(_, ch) if *ch == c) && is_noisy_sensor(comp, v)
        })?;
        let (Component::Generic(kind, _), v) = &fitted[at] else {
            return None;
        };
        let v = self.with_lattice(*kind, c, v);
        let others: Vec<(Component, Vec<f64>)> = fitted
            .iter()
            .enumerate()
            .filter(|(i, _)| *i != at)
            .map(|(_, f)| f.clone())
            .collect();
        // Alone, its input is the user's model's replay (no new replay nor start refit).
        let input = if others.is_empty() {
            self.nominal.outputs.get(c)?.clone()
        } else {
            self.predict(&others).ok()?.outputs.get(c)?.clone()
        };
        Some(match kind {
            GenericKind::Quantisation => {
                let shift = quantiser_shift(&v);
                NoisySensorReplay::Quantiser {
                    step: v[0],
                    noise: v[1],
                    after: match self.lattices[c] {
                        Some(_) => 0.0,
                        None => self.sigma[c] * self.sigma[c],
                    },
                    input: input.iter().map(|y| y - shift).collect(),
                }
            }
            _ => NoisySensorReplay::DeadZone {
                width: v[0],
                shift: v.get(1).copied().unwrap_or(1.0),
                noise: v.get(2).copied().unwrap_or(0.0),
                channel_variance: self.sigma[c] * self.sigma[c],
                input,
            },
        })
    }

    /// Where the sensor noise of channel `c` went through a first-order lag fitted among
    /// `fitted` (a sensor's filter on its noisy signal, `y = lag(x + e)`), the one-step
    /// predictions of the readings and their innovations' variance on the training samples;
    /// `None` where it did not. Through the lag the noise is low-passed: the replay's
    /// residual `r` keeps its sign from sample to sample and its variance is not the
    /// channel's, so no test on it per sample holds; its innovations
    /// `r_k - (1 - alpha) r_(k-1)` are the noise itself, white, and the one-step predictions
    /// `replay_k + (1 - alpha) r_(k-1)` leave exactly them. Taken only where the residual is
    /// not white and its innovations are (Ljung-Box over [`LAG_WHITENESS_LAGS`] lags at
    /// [`LAG_WHITENESS_P`]): with the noise after the lag the innovations alternate, and a
    /// slow gap the lag misses keeps its sign in them too.
    fn noise_through_lag(
        &self,
        sim: &Simulation,
        fitted: &[(Component, Vec<f64>)],
        c: usize,
    ) -> Option<(Vec<f64>, f64)> {
        let tau = fitted.iter().find_map(|(comp, v)| match comp {
            Component::Generic(GenericKind::FirstOrderLag, ch) if *ch == c => v.first().copied(),
            _ => None,
        })?;
        let keep = (-self.data.dt / tau.max(1e-12)).exp();
        let (y, m) = (&self.measured[c], &sim.outputs[c]);
        let r: Vec<f64> = y.iter().zip(m).map(|(y, m)| y - m).collect();
        let (mut residual, mut innovations) = (Vec::new(), Vec::new());
        for k in 1..r.len() {
            if self.train[k] && self.train[k - 1] && r[k].is_finite() && r[k - 1].is_finite() {
                residual.push(r[k]);
                innovations.push(r[k] - keep * r[k - 1]);
            }
        }
        if innovations.len() <= 4 * LAG_WHITENESS_LAGS
            || ljung_box(&residual, LAG_WHITENESS_LAGS).1 >= LAG_WHITENESS_P
            || ljung_box(&innovations, LAG_WHITENESS_LAGS).1 < LAG_WHITENESS_P
        {
            return None;
        }
        let variance = innovations.iter().map(|v| v * v).sum::<f64>() / innovations.len() as f64;
        let predictions = (0..r.len())
            .map(|k| match k.checked_sub(1).map(|j| r[j]) {
                Some(previous) if previous.is_finite() => m[k] + keep * previous,
                _ => m[k],
            })
            .collect();
        Some((predictions, variance))
    }

    /// Where the sensor noise of channel `c` went through a lag fitted among `fitted`
    /// ([`Problem::noise_through_lag`] on its replay `sim`), the std of that noise before
    /// the lag: undoing the lag leaves that noise, white (noise added after a lag is
    /// amplified by the undoing instead).
    fn noise_before_lag(
        &self,
        sim: &Simulation,
        fitted: &[(Component, Vec<f64>)],
        c: usize,
    ) -> Option<f64> {
        let tau = fitted.iter().find_map(|(comp, v)| match comp {
            Component::Generic(GenericKind::FirstOrderLag, ch) if *ch == c => v.first().copied(),
            _ => None,
        })?;
        let (_, innovation_variance) = self.noise_through_lag(sim, fitted, c)?;
        // The innovations are the noise before the lag times alpha.
        let alpha = 1.0 - (-self.data.dt / tau.max(1e-12)).exp();
        Some(innovation_variance.sqrt() / alpha.max(1e-12))
    }

    /// Per channel, the reading variance per sample that a noisy sensor among `fitted`
    /// predicts ([`NoisySensorReplay::variance`], floored at half the noise variance):
    /// between a quantiser's thresholds the reading is certain, on one it is a coin flip
    /// between two steps, so one variance for the channel misjudges both (`None` without
    /// such a sensor). `sensors` is [`Problem::noisy_sensors`] of the candidate's components.
    /// A replay that adds a spread of its own ([`Simulation::variances`]) adds it to the
    /// sensor noise's variance on its channel.
    pub fn predicted_variances(
        &self,
        sensors: &[Option<NoisySensorReplay>],
        sim: &Simulation,
    ) -> Vec<Option<Vec<f64>>> {
        (0..self.measured.len())
            .map(|c| {
                let s2 = self.sigma[c] * self.sigma[c];
                let added = added_variance(sim, c);
                let base: Vec<f64> = match sensors.get(c).and_then(Option::as_ref) {
                    Some(sensor) => (0..self.measured[c].len())
                        .map(|k| sensor.variance(k).max(0.5 * s2))
                        .collect(),
                    None => vec![self.noise_beside_spread(sim, c)?; added?.len()],
                };
                Some(match added {
                    Some(a) => base.iter().zip(a).map(|(b, a)| b + a).collect(),
                    None => base,
                })
            })
            .collect()
    }

    /// RMS over truth columns (each relative to its own RMS over the data) of the replayed
    /// states' error on the held-out samples; `None` without truth columns in common.
    pub fn truth_error(&self, sim: &Simulation) -> Option<f64> {
        self.states_error(&sim.states)
    }

    /// [`Problem::truth_error`] of states by name.
    fn states_error(&self, states: &BTreeMap<String, Vec<f64>>) -> Option<f64> {
        let mut acc = 0.0;
        let mut count = 0usize;
        for (name, x) in &self.data.truth {
            let Some(est) = states.get(name) else {
                continue;
            };
            let finite: Vec<f64> = x.iter().copied().filter(|v| v.is_finite()).collect();
            // Relative to the column's RMS: a speed to its swing, a parameter (constant, or
            // moving a little with temperature) to its value; an all-zero column absolutely.
            let rms =
                (finite.iter().map(|v| v * v).sum::<f64>() / finite.len().max(1) as f64).sqrt();
            let scale = if rms > 0.0 { rms } else { 1.0 };
            for k in 0..x.len() {
                if self.test[k] && x[k].is_finite() && est[k].is_finite() {
                    acc += ((x[k] - est[k]) / scale).powi(2);
                    count += 1;
                }
            }
        }
        (count > 0).then(|| (acc / count as f64).sqrt())
    }

    fn cost_at(&self, components: &[Component], dims: &[Dim], theta: &[f64]) -> f64 {
        let fitted = assemble(components, dims, theta);
        let Ok(sim) = self.predict(&fitted) else {
            return f64::INFINITY;
        };
        let noisy = fitted.iter().any(|(c, v)| is_noisy_sensor(c, v));
        let spread = sim.variances.iter().any(Option::is_some);
        let c = if noisy || spread {
            self.likelihood_train_cost(&sim, &fitted)
        } else {
            self.train_cost(&sim)
        };
        if c.is_finite() { c } else { f64::INFINITY }
    }

    /// [`Problem::train_cost`] with a quantiser's or a spread's channel scored as the
    /// held-out score does, by its per-sample reading variance (`-2 ln` likelihood up to a
    /// constant): by squared error alone, a quantiser whose mean misses a few steps is
    /// fitted with a noise that smooths its mean, which the likelihood then rejects, and a
    /// spread (which leaves the mean alone) is not fitted at all.
    fn likelihood_train_cost(&self, sim: &Simulation, fitted: &[(Component, Vec<f64>)]) -> f64 {
        let predicted = self.predicted_variances(&self.noisy_sensors(fitted), sim);
        let train = self.channel_rss(sim, &self.train);
        let mut cost = 0.0;
        for (c, ((rss, _), s)) in train.iter().zip(&self.sigma).enumerate() {
            let s2 = s * s;
            let Some(v) = predicted.get(c).and_then(Option::as_ref) else {
                cost += rss / s2;
                continue;
            };
            let (y, m) = (&self.measured[c], &sim.outputs[c]);
            for k in 0..y.len() {
                if self.train[k] && y[k].is_finite() {
                    let r = y[k] - m[k];
                    cost += r * r / v[k] + (v[k] / s2).ln();
                }
            }
        }
        cost
    }

    /// Fits `components` (starting from `start` when given, else from the grid) and scores
    /// them on the held-out blocks.
    pub fn fit(&self, components: &[Component], start: Option<&[f64]>) -> Option<Evaluation> {
        self.fit_with(components, start, false)
    }

    /// [`Problem::fit`] from `start`, then polished jointly by Nelder-Mead: a pair's
    /// parameters can trade off along a valley (a leak area against a seal stiffness) that
    /// coordinate passes crawl along.
    pub fn refine(&self, components: &[Component], start: &[f64]) -> Option<Evaluation> {
        self.fit_with(components, Some(start), true)
    }

    fn fit_with(
        &self,
        components: &[Component],
        start: Option<&[f64]>,
        polish: bool,
    ) -> Option<Evaluation> {
        let dims = self.dims(components);
        // First with every extension parameter at its neutral value (the simpler effect),
        // then with them free: kept only when that pays for their BIC penalty.
        let pinned: Vec<Dim> = dims
            .iter()
            .map(|d| Dim {
                pinned: d.neutral.is_some(),
                ..d.clone()
            })
            .collect();
        let mut theta: Vec<f64> = match start {
            Some(s) if s.len() == dims.len() => s.to_vec(),
            _ => dims.iter().map(|d| to_value(d, 0.5)).collect(),
        };
        let start_theta = theta.clone();
        resolve_pinned(&pinned, &mut theta);
        let free = pinned.iter().filter(|d| searched(d)).count();
        // From a start (pairs refined from their singles' fits): one coarser pass.
        let (passes, grid, golden) = match (free, start.is_some()) {
            (_, true) => (1, 7, 10),
            (0 | 1, false) => (1, 13, 32),
            _ => (2, 13, 32),
        };
        let mut best = self.cost_at(components, &pinned, &theta);
        self.coordinate_passes(
            components,
            &pinned,
            &mut theta,
            &mut best,
            start.is_some(),
            (passes, grid, golden),
        );
        if polish && free >= 2 && best.is_finite() {
            (theta, best) = self.polish(components, &pinned, theta, best);
        }
        // Extension parameters held at their neutral values (not counted in the penalty).
        let mut held = dims.iter().filter(|d| d.neutral.is_some()).count();
        if pinned != dims && best.is_finite() {
            resolve_pinned(&pinned, &mut theta);
            let from_start = start.is_some().then_some(start_theta.as_slice());
            let (wide, wide_best) = self.free_extensions(
                components,
                (&dims, &pinned),
                (&theta, best),
                from_start,
                polish,
            );
            let mut neutral = wide.clone();
            resolve_pinned(&pinned, &mut neutral);
            // BIC: each parameter costs ln n_train in training cost (squared noise units).
            let penalty = (self.train_chi2(&self.nominal).1.max(2) as f64).ln();
            // Only the extensions the freed fit moved off their neutral values count.
            let moved = wide.iter().zip(&neutral).filter(|(w, n)| w != n).count();
            if moved > 0 && wide_best + moved as f64 * penalty < best {
                (theta, best) = (wide, wide_best);
                held -= moved;
            }
        }
        if !best.is_finite() {
            return None;
        }
        let fitted = assemble(components, &dims, &theta);
        let mut sim = self.predict(&fitted).ok()?;
        let before = self.gap(&self.nominal);
        // One replay without each noisy sensor, shared by the gap and the score.
        let mut sensors = self.noisy_sensors(&fitted);
        // A lag the noise went through too is read as its one-step predictions, their
        // innovation variance a fitted parameter.
        let mut lagged_noise = 0;
        for (c, sensor) in sensors.iter_mut().enumerate() {
            if sensor.is_some() {
                continue;
            }
            if let Some((predictions, innovation_variance)) =
                self.noise_through_lag(&sim, &fitted, c)
            {
                *sensor = Some(NoisySensorReplay::LaggedNoise {
                    innovation_variance,
                });
                sim.outputs[c] = predictions;
                sim.innovations = true;
                lagged_noise += 1;
            }
        }
        let after = self.gap_of(&sim, &sensors);
        let predicted = self.predicted_variances(&sensors, &sim);
        let nominal_score = self.held_out_score(&self.nominal, 0, &[]);
        // A spread's noise level is fitted too (see `noise_beside_spread`), as is the
        // innovation variance of noise through a lag.
        let spread = sim.variances.iter().filter(|v| v.is_some()).count() + lagged_noise;
        let absolute = self.held_out_score(&sim, dims.len() - held + spread, &predicted);
        let names: Vec<String> = components.iter().map(|c| self.component_name(c)).collect();
        Some(Evaluation {
            effect: names.join("+"),
            components: names,
            params: dims
                .iter()
                .zip(&theta)
                .map(|(d, v)| {
                    let owner = self.component_name(&components[d.component]);
                    let name = if matches!(components[d.component], Component::Generic(..)) {
                        format!("{owner}.{}", d.name)
                    } else {
                        d.name.clone()
                    };
                    (name, *v)
                })
                .collect(),
            score: absolute - nominal_score,
            gap_before: before,
            gap_after: after,
            shrink: if before > 0.0 {
                1.0 - after / before
            } else {
                0.0
            },
            replay_error_before: self.truth_error(&self.nominal),
            replay_error_after: self.truth_error(&sim),
            estimation_error_before: None,
            estimation_error_after: None,
            worst_block_p: self.worst_block_p(&sim, &sensors),
            innovations: sim.innovations,
            train_cost: best,
            absolute_score: absolute,
            batch_ll: self.held_out_batches(&sim, &predicted),
            channel_rss: self.rss_split(&sim),
            fitted,
        })
    }

    /// The fit with the extension parameters free, from `theta` (the fit with them held at
    /// neutral under `pinned`, of training cost `best`), returned with its training cost. A
    /// pair (`start` given) also tries its singles' extensions; a single whose simpler fit
    /// leaves a gap on its channel also refits its other parameters with the extensions
    /// held at the [`extension_profiles`], since an extension can matter that much only
    /// far from the simpler fit (a zeroing deadband only with a wide zone, which a shifted
    /// dead zone cannot fit).
    fn free_extensions(
        &self,
        components: &[Component],
        (dims, pinned): (&[Dim], &[Dim]),
        (theta, best): (&[f64], f64),
        start: Option<&[f64]>,
        polish: bool,
    ) -> (Vec<f64>, f64) {
        let mut wide = theta.to_vec();
        let mut wide_best = best;
        if let Some(start) = start {
            let mut from_start = theta.to_vec();
            for ((w, d), s) in from_start.iter_mut().zip(dims).zip(start) {
                if d.neutral.is_some() {
                    *w = *s;
                }
            }
            let cost = self.cost_at(components, dims, &from_start);
            if cost < wide_best {
                (wide, wide_best) = (from_start, cost);
            }
        } else if self.leaves_a_gap_on_its_channels(components, pinned, theta) {
            for held_at in extension_profiles(pinned) {
                let profile_dims: Vec<Dim> = pinned
                    .iter()
                    .zip(&held_at)
                    .map(|(p, at)| match at {
                        Some(v) => Dim {
                            lo: *v,
                            hi: *v,
                            pinned: false,
                            ..p.clone()
                        },
                        None => p.clone(),
                    })
                    .collect();
                let mut profile = theta.to_vec();
                for (value, at) in profile.iter_mut().zip(&held_at) {
                    if let Some(v) = at {
                        *value = *v;
                    }
                }
                let mut cost = self.cost_at(components, &profile_dims, &profile);
                self.coordinate_passes(
                    components,
                    &profile_dims,
                    &mut profile,
                    &mut cost,
                    false,
                    (1, 13, 32),
                );
                if cost < wide_best {
                    (wide, wide_best) = (profile, cost);
                }
            }
        }
        self.coordinate_passes(
            components,
            dims,
            &mut wide,
            &mut wide_best,
            true,
            (1, 7, 10),
        );
        if polish {
            (wide, wide_best) = self.polish(components, dims, wide, wide_best);
        }
        (wide, wide_best)
    }

    /// Whether the generic components at `theta` leave a training misfit on a channel they
    /// act on: a mean squared standardised residual over [`PROFILE_EXCESS`], or one
    /// residual beyond [`PROFILE_OUTLIER`] noise std (a misfit at a few transitions, which
    /// the mean over a long record dilutes).
    fn leaves_a_gap_on_its_channels(
        &self,
        components: &[Component],
        dims: &[Dim],
        theta: &[f64],
    ) -> bool {
        let Ok(sim) = self.predict(&assemble(components, dims, theta)) else {
            return true;
        };
        components.iter().any(|c| {
            let Component::Generic(_, ch) = c else {
                return false;
            };
            let (y, m, s) = (&self.measured[*ch], &sim.outputs[*ch], self.sigma[*ch]);
            let (mut sum, mut n, mut worst) = (0.0, 0usize, 0.0f64);
            for k in (0..y.len()).filter(|&k| self.train[k] && y[k].is_finite()) {
                let z = (y[k] - m[k]) / s;
                sum += z * z;
                n += 1;
                worst = worst.max(z.abs());
            }
            !(sum <= PROFILE_EXCESS * n as f64 && worst <= PROFILE_OUTLIER)
        })
    }

    /// Coordinate line searches over the dims whose range is not a point (`passes`, `grid`
    /// and `golden` in [`Problem::line_search`]'s sense), moving `theta` where the cost
    /// does not rise.
    fn coordinate_passes(
        &self,
        components: &[Component],
        dims: &[Dim],
        theta: &mut [f64],
        best: &mut f64,
        from_start: bool,
        (passes, grid, golden): (usize, usize, usize),
    ) {
        // From two singles' fits, each of which took the whole gap, the added (second)
        // member is searched first, with the first held at its fit: forward selection.
        // Searched first, the first member would fall to whatever the second's fit left.
        let order: Vec<usize> = if from_start {
            (0..dims.len()).rev().collect()
        } else {
            (0..dims.len()).collect()
        };
        for _ in 0..passes {
            for &i in order.iter().filter(|&&i| searched(&dims[i])) {
                let (value, cost) = self.line_search(components, dims, theta, i, grid, golden);
                // A tie moves too: on a plateau the line search keeps the value that
                // changes the model least, which the start need not be.
                if cost <= *best {
                    *best = cost;
                    theta[i] = value;
                }
            }
        }
    }

    /// Nelder-Mead on the unit cube from `theta` (cost `best`); returns the better of the two.
    fn polish(
        &self,
        components: &[Component],
        dims: &[Dim],
        theta: Vec<f64>,
        best: f64,
    ) -> (Vec<f64>, f64) {
        let start: Vec<f64> = dims
            .iter()
            .zip(&theta)
            .map(|(d, v)| to_unit(d, *v))
            .collect();
        let mut simplex = vec![start.clone()];
        for i in 0..start.len() {
            let mut v = start.clone();
            v[i] += if v[i] > 1.0 - POLISH_STEP {
                -POLISH_STEP
            } else {
                POLISH_STEP
            };
            simplex.push(v);
        }
        let cost = UnitCost {
            problem: self,
            components,
            dims,
        };
        let run = NelderMead::new(simplex)
            .with_sd_tolerance(POLISH_TOLERANCE)
            .and_then(|solver| {
                Executor::new(cost, solver)
                    .configure(|s| s.max_iters(POLISH_ITERS))
                    .run()
            });
        let Ok(result) = run else {
            return (theta, best);
        };
        let state = result.state();
        match state.get_best_param() {
            Some(u) if state.get_best_cost() < best => (
                dims.iter().zip(u).map(|(d, u)| to_value(d, *u)).collect(),
                state.get_best_cost(),
            ),
            _ => (theta, best),
        }
    }

    /// Coordinate `i`: a `grid`-point grid over its range, then `golden` golden-section
    /// steps in the bracket around the best grid point (see [`grid_then_golden`]).
    fn line_search(
        &self,
        components: &[Component],
        dims: &[Dim],
        theta: &[f64],
        i: usize,
        grid: usize,
        golden: usize,
    ) -> (f64, f64) {
        let d = &dims[i];
        let mut probe = theta.to_vec();
        let mut eval = |u: f64| {
            probe[i] = to_value(d, u);
            self.cost_at(components, dims, &probe)
        };
        let mut probe = theta.to_vec();
        let mut change = |u: f64| {
            probe[i] = to_value(d, u);
            self.change_from_nominal(components, dims, &probe)
        };
        let (u, c) = grid_then_golden(&mut eval, 0.0, 1.0, grid, golden, Some(&mut change));
        (to_value(d, u), c)
    }

    /// How far the model with `theta` departs from the user's model over the whole record
    /// (inputs are known everywhere), in squared noise units: among values the training
    /// data cannot tell apart, the fit keeps the one that changes the model least, so a
    /// threshold the training blocks never reach is not guessed just above their range.
    fn change_from_nominal(&self, components: &[Component], dims: &[Dim], theta: &[f64]) -> f64 {
        let fitted = assemble(components, dims, theta);
        let Ok(sim) = self.predict(&fitted) else {
            return f64::INFINITY;
        };
        let mut sum = 0.0;
        for ((a, b), s) in sim
            .outputs
            .iter()
            .zip(&self.nominal.outputs)
            .zip(&self.sigma)
        {
            for (x, y) in a.iter().zip(b) {
                let d = (x - y) / s;
                if d.is_finite() {
                    sum += d * d;
                }
            }
        }
        sum
    }
}

/// A single's extension parameters are profiled (refitted at the [`extension_profiles`])
/// only when its simpler fit leaves its channel's mean squared standardised training
/// residual above this: a noise estimate 10 % off reads 1.2, a fit that misses a zeroing
/// deadband's zone thousands.
const PROFILE_EXCESS: f64 = 1.5;
/// ... or when one residual lies beyond this many noise std (noise reaches it once in
/// 5e8 samples).
const PROFILE_OUTLIER: f64 = 6.0;

/// Golden-section steps beyond the asked number while the bracket is not yet flat ...
const GOLDEN_EXTRA: usize = 16;
/// ... to this many training-cost units (squared noise units: half a nat).
const GOLDEN_FLAT: f64 = 1.0;

/// Minimises `eval` over `[lo, hi]`: a `grid`-point grid, then `golden` golden-section
/// steps in the bracket around the best grid point. When the best cost is shared by
/// several grid points (a plateau: a range of the parameter that changes nothing, such as
/// a critical ratio below every ratio the orifices see), the minimum can hide between the
/// plateau's edge and the next grid point: with `prefer` given, those brackets are
/// searched the same way, and else the plateau's end that `prefer` ranks lower is kept.
/// Returns the best point and its cost.
fn grid_then_golden(
    eval: &mut dyn FnMut(f64) -> f64,
    lo: f64,
    hi: f64,
    grid: usize,
    golden: usize,
    prefer: Option<&mut dyn FnMut(f64) -> f64>,
) -> (f64, f64) {
    let grid = grid.max(2);
    let step = (hi - lo) / (grid - 1) as f64;
    let at = |g: usize| lo + g as f64 * step;
    let costs: Vec<f64> = (0..grid).map(|g| eval(at(g))).collect();
    let (mut g_best, c_best) = costs
        .iter()
        .copied()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .unwrap_or((0, f64::INFINITY));
    let tied = |g: usize| (costs[g] - c_best).abs() <= 1e-12 * c_best.abs().max(1e-300);
    // A periodic parameter searched over whole periods costs the same at both ends and
    // inside, to rounding: the edge's bracket holds only one side of the minimum.
    if g_best == 0 || g_best == grid - 1 {
        let same = |g: usize| (costs[g] - c_best).abs() <= 1e-9 * c_best.abs().max(1e-300);
        if let Some(g) = (1..grid - 1).find(|&g| same(g)) {
            g_best = g;
        }
    }
    let (mut p0, mut p1) = (g_best, g_best);
    while p0 > 0 && tied(p0 - 1) {
        p0 -= 1;
    }
    while p1 + 1 < grid && tied(p1 + 1) {
        p1 += 1;
    }
    let mut best = (at(g_best), c_best);
    if let Some(prefer) = prefer
        && p1 > p0
        && c_best.is_finite()
    {
        if prefer(at(p1)) < prefer(at(p0)) {
            best.0 = at(p1);
        } else {
            best.0 = at(p0);
        }
        let brackets = [
            (p1 + 1 < grid).then(|| (at(p1), at(p1 + 1))),
            (p0 > 0).then(|| (at(p0 - 1), at(p0))),
        ];
        for (a, b) in brackets.into_iter().flatten() {
            let found = grid_then_golden(eval, a, b, golden.max(3), golden, None);
            if found.1 < best.1 {
                best = found;
            }
        }
        return best;
    }
    let mut a = at(g_best.saturating_sub(1));
    let mut b = at((g_best + 1).min(grid - 1));
    let ratio = 0.5 * (5f64.sqrt() - 1.0);
    let mut x1 = b - ratio * (b - a);
    let mut x2 = a + ratio * (b - a);
    let mut f1 = eval(x1);
    let mut f2 = eval(x2);
    // Past `golden` steps, go on while the bracket's two points still differ by more than
    // `GOLDEN_FLAT`: a narrow valley (a pair's coarse pass, whose start is two singles' fits)
    // is otherwise left 0.004 wide in a parameter whose optimum sits 0.0002 from the start.
    let mut step = 0;
    while step < golden || (step < golden + GOLDEN_EXTRA && (f1 - f2).abs() > GOLDEN_FLAT) {
        step += 1;
        if f1 <= f2 {
            b = x2;
            x2 = x1;
            f2 = f1;
            x1 = b - ratio * (b - a);
            f1 = eval(x1);
        } else {
            a = x1;
            x1 = x2;
            f1 = f2;
            x2 = a + ratio * (b - a);
            f2 = eval(x2);
        }
    }
    let (u, c) = if f1 <= f2 { (x1, f1) } else { (x2, f2) };
    if c < best.1 { (u, c) } else { best }
}

/// Per channel of `measured`, the step ([`lattice_step`]) and offset ([`lattice_offset`])
/// of the lattice its readings lie on, if they lie on one.
pub fn channel_lattices(measured: &[Vec<f64>]) -> Vec<Option<(f64, f64)>> {
    measured
        .iter()
        .map(|y| lattice_step(y).map(|q| (q, lattice_offset(y, q))))
        .collect()
}

/// Per channel of `measured` off a lattice (`lattices` as [`channel_lattices`] gives
/// them), the step and offset of a lattice its readings scatter about
/// ([`staircase_lattice`]).
pub fn channel_staircases(
    measured: &[Vec<f64>],
    lattices: &[Option<(f64, f64)>],
) -> Vec<Option<(f64, f64)>> {
    measured
        .iter()
        .zip(lattices)
        .map(|(y, lattice)| match lattice {
            Some(_) => None,
            None => staircase_lattice(y),
        })
        .collect()
}

/// Bins of the readings' histogram whose spectrum [`staircase_lattice`] searches.
const STAIRCASE_BINS: usize = 1 << 19;

/// Least mean resultant length of the readings modulo a staircase's step: a quantiser
/// before noise of std `s` gives `exp(-2 pi^2 s^2 / q^2)`, 0.19 at `q = sqrt 12 s` (an
/// effect-to-noise ratio of 1), 0.66 at ratio 2.
const STAIRCASE_RESULTANT: f64 = 0.3;

/// The step `q` and offset `c` of a lattice `c + j q` that the readings `y` scatter about,
/// as a quantiser before the noise leaves them: modulo the right step the distinct finite
/// readings bunch about one residue. Each reading is weighted by the inverse of the number
/// of readings within 1/40 of their span of it, so that every stretch of the span counts
/// alike (a record that dwells at a few levels bunches at any step much wider than the
/// noise). The step is the spatial frequency at which the weighted mean resultant length
/// is largest (the spectrum of the weighted histogram, refined on the readings), taken down
/// to a subharmonic that bunches nearly as tightly (a coarse staircase bunches almost as
/// tightly at twice its frequency). Accepted with at least three levels across the
/// readings, a resultant of [`STAIRCASE_RESULTANT`], and `n_eff R^2` beyond the largest
/// noise resultant of the searched frequencies by `exp(-20)`.
pub fn staircase_lattice(y: &[f64]) -> Option<(f64, f64)> {
    let mut values: Vec<f64> = y.iter().copied().filter(|v| v.is_finite()).collect();
    values.sort_by(f64::total_cmp);
    // Readings repeated exactly (a clip's limit, a deadband's zero) would bunch at every
    // frequency.
    values.dedup();
    let n = values.len();
    let (lo, hi) = (*values.first()?, *values.last()?);
    let span = hi - lo;
    if n < 20 || span <= 0.0 {
        return None;
    }
    let width = span / (STAIRCASE_BINS - 1) as f64;
    let bins: Vec<usize> = values
        .iter()
        .map(|v| (((v - lo) / width).round() as usize).min(STAIRCASE_BINS - 1))
        .collect();
    let reach = span / 40.0;
    let weights: Vec<f64> = values
        .iter()
        .map(|v| {
            let from = values.partition_point(|u| *u < v - reach);
            let to = values.partition_point(|u| *u <= v + reach);
            1.0 / (to - from).max(1) as f64
        })
        .collect();
    let (sum, sum_sq) = weights
        .iter()
        .fold((0.0, 0.0), |(a, b), w| (a + w, b + w * w));
    let effective = sum * sum / sum_sq;
    let padded = 2 * STAIRCASE_BINS;
    let mut spectrum = vec![rustfft::num_complex::Complex::<f64>::new(0.0, 0.0); padded];
    for (bin, w) in bins.iter().zip(&weights) {
        spectrum[*bin].re += w;
    }
    rustfft::FftPlanner::new()
        .plan_fft_forward(padded)
        .process(&mut spectrum);
    // Frequency k / (padded width): at least three levels, at least eight bins a step.
    let frequency = |k: usize| k as f64 / (padded as f64 * width);
    let (k_lo, k_hi) = ((3.0 / (span * frequency(1))).ceil() as usize, padded / 8);
    let k_best =
        (k_lo..=k_hi).max_by(|a, b| spectrum[*a].norm_sqr().total_cmp(&spectrum[*b].norm_sqr()))?;
    let resultant = |f: f64| {
        let (mut sin, mut cos) = (0.0, 0.0);
        for (v, w) in values.iter().zip(&weights) {
            let phase = std::f64::consts::TAU * f * (v - lo);
            sin += w * phase.sin();
            cos += w * phase.cos();
        }
        (sin * sin + cos * cos).sqrt() / sum
    };
    // The peak between the neighbouring frequencies of the spectrum.
    let refined = |f: f64| {
        let half = frequency(1);
        let mut cost = |u: f64| -resultant(f + (u - 0.5) * 2.0 * half);
        let (u, c) = grid_then_golden(&mut cost, 0.0, 1.0, 5, 30, None);
        (f + (u - 0.5) * 2.0 * half, -c)
    };
    let (mut f, mut r) = refined(frequency(k_best));
    // A staircase far wider than the noise bunches nearly as tightly at twice its
    // frequency; its subharmonics do not bunch at all.
    for m in (2..=8).rev() {
        let low = f / m as f64;
        if low < frequency(k_lo) {
            continue;
        }
        let (f_low, r_low) = refined(low);
        if r >= STAIRCASE_RESULTANT && r_low >= r - 0.25 * (1.0 - r) {
            (f, r) = (f_low, r_low);
            break;
        }
    }
    let searched = (k_hi - k_lo + 1) as f64;
    if r < STAIRCASE_RESULTANT || effective * r * r < searched.ln() + 20.0 {
        return None;
    }
    let q = 1.0 / f;
    Some((q, lattice_offset(&values, q)))
}

/// Per channel of `measured` with `lattices` as [`channel_lattices`] gives them, whether
/// its readings are off a lattice and at least [`ZEROS_OF_A_DEADBAND`] of them exactly 0:
/// the mark of a deadband applied after the noise.
pub fn zeroed_channels(measured: &[Vec<f64>], lattices: &[Option<(f64, f64)>]) -> Vec<bool> {
    measured
        .iter()
        .zip(lattices)
        .map(|(y, lattice)| {
            lattice.is_none() && y.iter().filter(|v| **v == 0.0).count() >= ZEROS_OF_A_DEADBAND
        })
        .collect()
}

/// The step of the lattice a quantised channel's values lie on: the smallest nonzero
/// difference between consecutive samples, accepted when at least 90 % of the nonzero
/// differences are integer multiples of it (to 1e-6) and it is not a float rounding step.
/// A coarse quantiser may change level too seldom for that (16 changes in 6000 samples of
/// a wheel current read on three levels): then the gaps between the distinct values, when
/// each value repeats at least 20 times on average (noisy continuous readings never
/// repeat exactly).
pub fn lattice_step(y: &[f64]) -> Option<f64> {
    let scale = y
        .iter()
        .filter(|v| v.is_finite())
        .fold(0.0f64, |m, v| m.max(v.abs()));
    let rounding = 1e-9 * scale.max(1e-300);
    let diffs: Vec<f64> = y
        .windows(2)
        .map(|w| (w[1] - w[0]).abs())
        .filter(|d| d.is_finite() && *d > rounding)
        .collect();
    if diffs.len() < 20 {
        let mut levels: Vec<f64> = y.iter().copied().filter(|v| v.is_finite()).collect();
        let n = levels.len();
        levels.sort_by(f64::total_cmp);
        levels.dedup_by(|a, b| (*a - *b).abs() <= rounding);
        if levels.len() < 2 || n < 20 * levels.len() {
            return None;
        }
        let gaps: Vec<f64> = levels.windows(2).map(|w| w[1] - w[0]).collect();
        return on_lattice(&gaps, 1.0);
    }
    on_lattice(&diffs, 0.9)
}

/// The smallest of `diffs` when at least `share` of them are integer multiples of it.
fn on_lattice(diffs: &[f64], share: f64) -> Option<f64> {
    let q = diffs.iter().copied().fold(f64::INFINITY, f64::min);
    let on = diffs
        .iter()
        .filter(|d| {
            let r = *d / q;
            (r - r.round()).abs() < 1e-6 * r.max(1.0)
        })
        .count();
    (q.is_finite() && q > 0.0 && on as f64 >= share * diffs.len() as f64).then_some(q)
}

/// Batches of consecutive held-out samples for [`separation`]: each spans a twentieth of
/// the held-out data, far longer than the residuals' correlation in the built-in plants, so
/// batch sums are nearly independent.
pub const HELD_OUT_BATCHES: usize = 20;

/// How clearly the held-out data prefer `a` to `b`, in standard errors of their score
/// difference `D`: the larger of two estimates. (1) Measurement noise alone: with Gaussian
/// residuals and `a` right, `D` is `sum delta^2 / 2 sigma^2` over the predictions'
/// difference `delta` with variance twice that, so `z = sqrt(D / 2)`. (2) The spread of the
/// per-batch log-likelihood differences (a batch-means form of Vuong's test for non-nested
/// models), which also covers model error; alone it cannot exceed 1 when all the evidence
/// sits in one batch (a single transient), hence (1). Below [`MIN_EVIDENCE`] nats only (1)
/// counts: two all but equal predictions differ consistently in every batch, which makes
/// (2) large for no evidence (three offsets of a one-signed speed within 1e-5 nats were
/// reported as separated). NaN without batches.
pub fn separation(a: &Evaluation, b: &Evaluation) -> f64 {
    let diff = a.absolute_score - b.absolute_score;
    let by_noise = if diff > 0.0 { (0.5 * diff).sqrt() } else { 0.0 };
    let by_batches = batch_separation(a, b);
    if by_batches.is_nan() {
        by_batches
    } else if diff.abs() < MIN_EVIDENCE {
        by_noise
    } else {
        by_batches.max(by_noise)
    }
}

/// A held-out log-likelihood difference (nats) below which two candidates are not told
/// apart by how consistently it is spread (a likelihood ratio below e: "not worth more
/// than a bare mention" on Jeffreys' scale).
pub const MIN_EVIDENCE: f64 = 1.0;

fn batch_separation(a: &Evaluation, b: &Evaluation) -> f64 {
    let d: Vec<f64> = a
        .batch_ll
        .iter()
        .zip(&b.batch_ll)
        .map(|(x, y)| x - y)
        .collect();
    let n = d.len();
    if n < 2 {
        return f64::NAN;
    }
    let mean = d.iter().sum::<f64>() / n as f64;
    let var = d.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
    let se = (n as f64 * var).sqrt();
    let diff = a.absolute_score - b.absolute_score;
    if se > 0.0 {
        diff / se
    } else if diff == 0.0 {
        0.0
    } else {
        diff.signum() * f64::INFINITY
    }
}

/// Nelder-Mead's first simplex edge (unit-cube coordinates).
const POLISH_STEP: f64 = 0.02;
/// Stop when the simplex's costs agree to this std (noise-weighted squares).
const POLISH_TOLERANCE: f64 = 1e-3;
/// At most this many Nelder-Mead iterations.
const POLISH_ITERS: u64 = 150;

/// The training cost on the unit cube; outside it, the cost at the nearest face plus a
/// steep penalty, so the simplex comes back.
struct UnitCost<'p, 'a> {
    problem: &'p Problem<'a>,
    components: &'p [Component],
    dims: &'p [Dim],
}

impl CostFunction for UnitCost<'_, '_> {
    type Param = Vec<f64>;
    type Output = f64;
    fn cost(&self, u: &Vec<f64>) -> Result<f64, argmin::core::Error> {
        let outside: f64 = u.iter().map(|v| (v - v.clamp(0.0, 1.0)).powi(2)).sum();
        let theta: Vec<f64> = self
            .dims
            .iter()
            .zip(u)
            .map(|(d, u)| to_value(d, *u))
            .collect();
        let c = self.problem.cost_at(self.components, self.dims, &theta);
        Ok(c + 1e6 * outside * (1.0 + c.abs()))
    }
}

/// The inverse of [`to_value`], clamped to [0, 1].
fn to_unit(d: &Dim, v: f64) -> f64 {
    let u = match d.scale {
        Scale::Linear => (v - d.lo) / (d.hi - d.lo),
        Scale::Log => (v / d.lo).ln() / (d.hi / d.lo).ln(),
    };
    if u.is_finite() {
        u.clamp(0.0, 1.0)
    } else {
        0.5
    }
}

/// Maps `u` in [0, 1] to the parameter's range.
fn to_value(d: &Dim, u: f64) -> f64 {
    let u = u.clamp(0.0, 1.0);
    match d.scale {
        Scale::Linear => d.lo + u * (d.hi - d.lo),
        Scale::Log => (d.lo.ln() + u * (d.hi.ln() - d.lo.ln())).exp(),
    }
}

/// The points at which [`Problem::free_extensions`] profiles the other parameters: per
/// dim, the value an extension is held at (`None`: not an extension, fitted as before).
/// Each extension takes its neutral value or its range's ends and middle, jointly with the
/// others (a zeroing deadband after the noise needs both `shift = 0` and the noise), every
/// combination but the all-neutral one.
fn extension_profiles(dims: &[Dim]) -> Vec<Vec<Option<f64>>> {
    let mut points: Vec<Vec<Option<f64>>> = vec![vec![]];
    for d in dims {
        let values: Vec<Option<f64>> = match d.neutral {
            Some(Neutral::At(neutral)) => {
                let mut v = vec![neutral];
                for u in [0.0, 0.5, 1.0] {
                    let x = to_value(d, u);
                    if !v.contains(&x) {
                        v.push(x);
                    }
                }
                v.into_iter().map(Some).collect()
            }
            _ => vec![None],
        };
        points = points
            .iter()
            .flat_map(|p| {
                values.iter().map(move |v| {
                    let mut q = p.clone();
                    q.push(*v);
                    q
                })
            })
            .collect();
    }
    let all_neutral = |p: &Vec<Option<f64>>| {
        p.iter().zip(dims).all(|(v, d)| match (v, d.neutral) {
            (Some(v), Some(Neutral::At(n))) => *v == n,
            _ => true,
        })
    };
    points.retain(|p| !all_neutral(p));
    points
}

/// Whether the fit searches `d`: its range is not a point and it is not pinned.
fn searched(d: &Dim) -> bool {
    d.lo < d.hi && !d.pinned
}

/// Sets each pinned dim of `theta` to its neutral value.
fn resolve_pinned(dims: &[Dim], theta: &mut [f64]) {
    for i in 0..dims.len().min(theta.len()) {
        match (dims[i].pinned, dims[i].neutral) {
            (true, Some(Neutral::At(v))) => theta[i] = v,
            (true, Some(Neutral::MinusPrevious)) if i > 0 => theta[i] = -theta[i - 1],
            _ => {}
        }
    }
}

fn assemble(components: &[Component], dims: &[Dim], theta: &[f64]) -> Vec<(Component, Vec<f64>)> {
    let mut theta = theta.to_vec();
    resolve_pinned(dims, &mut theta);
    components
        .iter()
        .enumerate()
        .map(|(ci, c)| {
            let values = dims
                .iter()
                .zip(&theta)
                .filter(|(d, _)| d.component == ci)
                .map(|(_, v)| *v)
                .collect();
            (c.clone(), values)
        })
        .collect()
}

/// Flattened fitted values of an evaluation, in the order `fit` expects as a start.
pub fn flat_values(e: &Evaluation) -> Vec<f64> {
    e.fitted
        .iter()
        .flat_map(|(_, v)| v.iter().copied())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn generic_effects_do_what_they_say() {
        let y = [0.0, 1.0, 2.0, 3.0, -3.0];
        assert_eq!(GenericKind::SensorBias.apply(&[0.5], &y, 1.0)[1], 1.5);
        assert_eq!(
            GenericKind::SensorScale.apply(&[0.1], &y, 1.0)[3],
            3.0 * 1.1
        );
        assert_eq!(
            GenericKind::Quantisation.apply(&[2.0, 0.0], &y, 1.0),
            vec![0.0, 2.0, 2.0, 4.0, -4.0]
        );
        assert_eq!(GenericKind::MeasurementDelay.apply(&[1.5], &y, 1.0)[3], 1.5);
        assert_eq!(GenericKind::OutputSaturation.apply(&[2.5], &y, 1.0)[3], 2.5);
        assert_eq!(
            GenericKind::OutputSaturation.apply(&[2.5], &y, 1.0)[4],
            -2.5
        );
        assert_eq!(
            GenericKind::OutputSaturation.apply(&[2.5, -1.0], &y, 1.0),
            vec![0.0, 1.0, 2.0, 2.5, -1.0]
        );
        // At a limit the clip halves the noise: the mean reading is s / sqrt(2 pi) short.
        let at_limit = GenericKind::OutputSaturation.apply(&[2.5, -2.5, 0.1], &[2.5], 1.0)[0];
        assert!((at_limit - (2.5 - 0.1 / std::f64::consts::TAU.sqrt())).abs() < 1e-12);
        let inside = GenericKind::OutputSaturation.apply(&[2.5, -2.5, 0.1], &[0.3], 1.0)[0];
        assert!((inside - 0.3).abs() < 1e-12);
        for k in GenericKind::ALL {
            assert_eq!(k.param_names().len(), k.neutral_values().len(), "{k:?}");
        }
        assert_eq!(
            GenericKind::DeadZone.apply(&[1.5], &y, 1.0),
            vec![0.0, 0.0, 0.5, 1.5, -1.5]
        );
        assert_eq!(
            GenericKind::DeadZone.apply(&[1.5, 0.0], &y, 1.0),
            vec![0.0, 0.0, 2.0, 3.0, -3.0]
        );
        let lag = GenericKind::FirstOrderLag.apply(&[1.0], &[0.0, 1.0, 1.0], 1.0);
        assert!((lag[1] - (1.0 - (-1.0f64).exp())).abs() < 1e-12);
        for k in GenericKind::ALL {
            assert_eq!(GenericKind::from_name(k.name()), Some(k));
            assert_eq!(k.param_names().len(), k.ranges(1.0, 1.0, 0.1, 0.1).len());
        }
    }

    #[test]
    fn line_search_finds_a_sharp_minimum_beside_a_plateau() {
        // Flat (no effect) up to 0.42, a narrow valley at 0.43, rising after: no grid point
        // of 13 lies in the valley; the plateau's edge bracket holds it.
        let mut f = |u: f64| {
            if u < 0.42 {
                100.0
            } else {
                100.0 - 50.0 * (-((u - 0.43) / 0.004).powi(2)).exp() + 400.0 * (u - 0.42)
            }
        };
        let (u, c) = grid_then_golden(&mut f, 0.0, 1.0, 13, 16, Some(&mut |_| 0.0));
        assert!((u - 0.43).abs() < 2e-3 && c < 60.0, "{u} {c}");
        let (u, c) = grid_then_golden(&mut f, 0.0, 1.0, 13, 16, None);
        assert!(
            c >= 100.0 - 1e-9,
            "without the edge search the valley is missed: {u} {c}"
        );
    }

    #[test]
    fn a_periodic_minimum_near_the_period_edge_is_found_inside_the_range() {
        // A phase over two periods with its minimum at -0.21 rad: the grid points -2 pi, 0
        // and 2 pi cost the same to rounding, and the first of them, an edge, bracketed
        // only [-2 pi, -2 pi + step], so the fit ended on the edge.
        let tau = std::f64::consts::TAU;
        let phase = |u: f64| -tau + 2.0 * tau * u;
        let mut cost = |u: f64| 1.0 - (phase(u) + 0.21).cos();
        let (u, c) = grid_then_golden(&mut cost, 0.0, 1.0, 13, 32, Some(&mut |_| 0.0));
        let wrapped = (phase(u) + 0.21).rem_euclid(tau);
        assert!(
            wrapped.min(tau - wrapped) < 1e-3 && c < 1e-6,
            "{} {c}",
            phase(u)
        );
    }

    #[test]
    fn on_a_plateau_the_line_search_keeps_the_end_that_changes_the_model_least() {
        // A threshold the training data never reach: every value above 0.3 fits alike.
        // The model changes less the higher the threshold (it bites later off-training).
        let mut cost = |u: f64| if u < 0.3 { 10.0 + (0.3 - u) } else { 10.0 };
        let (u, c) = grid_then_golden(&mut cost, 0.0, 1.0, 13, 16, Some(&mut |u| 1.0 - u));
        assert_eq!((u, c), (1.0, 10.0));
        // Change growing with the value: the plateau's lower end.
        let (u, _) = grid_then_golden(&mut cost, 0.0, 1.0, 13, 16, Some(&mut |u| u));
        assert!((u - 4.0 / 12.0).abs() < 1e-12, "{u}");
    }

    #[test]
    fn separation_counts_noise_and_batch_spread() {
        let eval = |score: f64, batches: Vec<f64>| Evaluation {
            effect: String::new(),
            components: Vec::new(),
            params: Vec::new(),
            score,
            gap_before: 0.0,
            gap_after: 0.0,
            shrink: 0.0,
            replay_error_before: None,
            replay_error_after: None,
            estimation_error_before: None,
            estimation_error_after: None,
            worst_block_p: 1.0,
            innovations: false,
            train_cost: 0.0,
            absolute_score: score,
            batch_ll: batches,
            fitted: Vec::new(),
            channel_rss: Vec::new(),
        };
        // All 50 nats of evidence in one batch: the batch spread alone says z = 1, the
        // noise says sqrt(25) = 5.
        let mut one = vec![0.0; HELD_OUT_BATCHES];
        one[3] = 50.0;
        let (a, b) = (eval(50.0, one), eval(0.0, vec![0.0; HELD_OUT_BATCHES]));
        assert!((separation(&a, &b) - 5.0).abs() < 1e-12);
        // Spread evenly and consistently: the batches separate them far more clearly.
        let even: Vec<f64> = (0..HELD_OUT_BATCHES)
            .map(|i| 2.5 + 0.01 * i as f64)
            .collect();
        let total: f64 = even.iter().sum();
        let c = eval(total, even);
        assert!(separation(&c, &b) > 50.0);
        // A consistent but negligible difference (1e-6 nats per batch) is no separation.
        let tiny: Vec<f64> = vec![1e-6; HELD_OUT_BATCHES];
        let total: f64 = tiny.iter().sum();
        let d = eval(total, tiny);
        assert!(batch_separation(&d, &b) > 1e6);
        assert!(separation(&d, &b) < 0.01, "{}", separation(&d, &b));
        // Equal candidates are not separated; the worse one has z <= 0.
        assert_eq!(separation(&b, &b), 0.0);
        assert!(separation(&b, &a) <= 0.0);
    }

    #[test]
    fn a_lattice_is_found_from_its_level_changes_or_its_few_levels() {
        let q = 0.843_666_581_772_868_6;
        // Many level changes: the smallest change.
        let busy: Vec<f64> = (0..400).map(|k| q * (k % 5) as f64 + 0.1).collect();
        assert!((lattice_step(&busy).unwrap() - q).abs() < 1e-12);
        // A current read on three levels, changing 16 times in 6000 samples.
        let coarse: Vec<f64> = (0..6000)
            .map(|k| q * (((k / 375) % 3) as f64 - 1.0))
            .collect();
        assert!((lattice_step(&coarse).unwrap() - q).abs() < 1e-12);
        // Held values off a lattice (levels 0, 1, 2.5), and noisy readings, are none.
        let off: Vec<f64> = (0..6000).map(|k| [0.0, 1.0, 2.5][(k / 375) % 3]).collect();
        assert_eq!(lattice_step(&off), None);
        let noisy: Vec<f64> = (0..6000).map(|k| (0.37 * k as f64).sin()).collect();
        assert_eq!(lattice_step(&noisy), None);
    }

    #[test]
    fn lattice_sum_ends_far_from_zero() {
        // 1e30 steps from zero: stepping a float index by one never advanced (a hang).
        let (m, var) = lattice_moments(1e27, 1e-3, 1e-4);
        assert!(m.is_finite() && var == 0.0, "{m} {var}");
        assert_eq!(quantised_variance(1e27, 1e-3, 1e-4), 0.0);
    }

    #[test]
    fn dead_zone_moments_match_a_sampled_noisy_dead_zone() {
        use prognos_core::random::standard_normal;
        use rand_core::SeedableRng;
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(3);
        let noise: Vec<f64> = (0..200_000)
            .map(|_| standard_normal::<f64, _>(&mut rng))
            .collect();
        // Inside, on and beyond each edge, zeroing and shifted, noise of 0.3 on a zone of 2.
        for shift in [0.0, 0.4, 1.0] {
            for v in [-2.6, -2.0, -1.7, 0.0, 0.5, 1.9, 2.0, 2.2, 3.5] {
                let readings: Vec<f64> = noise
                    .iter()
                    .map(|e| {
                        GenericKind::DeadZone.apply(&[2.0, shift, 0.0], &[v + 0.3 * e], 1.0)[0]
                    })
                    .collect();
                let n = readings.len() as f64;
                let mean = readings.iter().sum::<f64>() / n;
                let var = readings.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / n;
                let (m, w) = dead_zone_moments(v, 2.0, shift, 0.3);
                assert!((m - mean).abs() < 0.01, "{shift} {v}: {m} {mean}");
                assert!(
                    (w - var).abs() < 0.02 * var.max(0.05),
                    "{shift} {v}: {w} {var}"
                );
            }
        }
        // Without noise: the map itself, and no spread.
        assert_eq!(dead_zone_moments(2.5, 2.0, 0.0, 0.0), (2.5, 0.0));
        assert_eq!(dead_zone_moments(1.5, 2.0, 1.0, 0.0), (0.0, 0.0));
        // Far beyond the edge: the noise alone, without the cancellation of big squares.
        let (m, w) = dead_zone_moments(1e6, 2.0, 1.0, 1e-3);
        assert!(
            (m - (1e6 - 2.0)).abs() < 1e-6 && (w / 1e-6 - 1.0).abs() < 1e-6,
            "{m} {w}"
        );
    }

    #[test]
    fn quantised_variance_is_zero_between_thresholds_and_a_coin_flip_on_one() {
        // Far from a threshold with little noise the reading is certain.
        assert!(quantised_variance(0.0, 1.0, 0.05) < 1e-12);
        // On a threshold it reads 0 or 1 with equal chance: variance q^2 / 4.
        assert!((quantised_variance(0.5, 1.0, 0.01) - 0.25).abs() < 1e-6);
        // Dithered: Sheppard's correction.
        assert!((quantised_variance(0.3, 1.0, 2.0) - (4.0 + 1.0 / 12.0)).abs() < 1e-12);
        // The direct sum meets it where the two branches meet.
        let v = quantised_variance(0.3, 1.0, 0.4999);
        assert!((v - (0.25 + 1.0 / 12.0)).abs() < 0.01, "{v}");
    }

    #[test]
    fn a_quantiser_floors_with_its_threshold_and_reads_on_its_lattice() {
        let y = [0.2, 0.7, 1.2, -0.2, -0.7, 2.99];
        let q = GenericKind::Quantisation;
        // Threshold half a step up: floor, as a truncating converter reads.
        let floor: Vec<f64> = y.iter().map(|v: &f64| v.floor()).collect();
        assert_eq!(q.apply(&[1.0, 0.0, 0.5, 0.0], &y, 1.0), floor);
        // Lattice 0.25 + j: the nearest such point.
        assert_eq!(
            q.apply(&[1.0, 0.0, 0.0, 0.25], &y, 1.0),
            [0.25, 0.25, 1.25, 0.25, -0.75, 3.25]
        );
        // The lattice offset is read back from the readings, also across the wrap at q/2.
        for c in [0.0, 0.1, -0.3, 0.49, -0.5] {
            let readings: Vec<f64> = (-40..40).map(|j| 0.02 * j as f64 + 0.02 * c).collect();
            let back = lattice_offset(&readings, 0.02);
            let wrapped = (back - 0.02 * c) / 0.02;
            assert!((wrapped - wrapped.round()).abs() < 1e-9, "{c}: {back}");
        }
    }

    #[test]
    fn quantised_mean_is_the_staircase_without_noise_and_smooth_with_it() {
        assert_eq!(quantised_mean(0.7, 1.0, 0.0), 1.0);
        // Noise of two steps dithers the quantiser: the mean reading is the input.
        assert!((quantised_mean(0.3, 1.0, 2.0) - 0.3).abs() < 1e-3);
        // A fifth of a step of noise: between the staircase (0) and the input (0.3).
        let m = quantised_mean(0.3, 1.0, 0.2);
        assert!(m > 0.05 && m < 0.25, "{m}");
        // Symmetric about a lattice point.
        assert!((quantised_mean(-0.3, 1.0, 0.2) + m).abs() < 1e-12);
        // The series and the direct sum agree where they meet.
        let (a, b) = (
            quantised_mean(0.3, 1.0, 0.4999),
            quantised_mean(0.3, 1.0, 0.5),
        );
        assert!((a - b).abs() < 1e-4, "{a} vs {b}");
    }

    #[test]
    fn a_staircase_under_noise_gives_its_step_and_smooth_readings_none() {
        // A sweep over 40 steps of 0.3, read with noise of std 0.05 after the quantiser.
        let mut state = 12345u64;
        let mut noise = || {
            // Sum of four uniforms: near-Gaussian, std 0.05.
            (0..4)
                .map(|_| {
                    state = state
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
                })
                .sum::<f64>()
                * 0.05
                * 3f64.sqrt()
        };
        let step = 0.3;
        let sweep: Vec<f64> = (0..3000)
            .map(|k| 6.0 * (k as f64 / 400.0).sin() + 0.1)
            .collect();
        let read: Vec<f64> = sweep
            .iter()
            .map(|v| step * (v / step).round() + noise())
            .collect();
        let (q, offset) = staircase_lattice(&read).unwrap();
        assert!((q / step - 1.0).abs() < 1e-3, "{q}");
        assert!(offset.abs() < 0.01, "{offset}");
        let smooth: Vec<f64> = sweep.iter().map(|v| v + noise()).collect();
        assert_eq!(staircase_lattice(&smooth), None);
    }

    #[test]
    fn a_dead_zone_is_profiled_at_every_joint_shift_and_noise_but_the_neutral_one() {
        let kind = GenericKind::DeadZone;
        let dims: Vec<Dim> = kind
            .param_names()
            .iter()
            .zip(kind.ranges(10.0, 20.0, 2.0, 0.01))
            .zip(kind.neutral_values())
            .map(|((name, (lo, hi, scale)), neutral)| Dim {
                component: 0,
                name: name.to_string(),
                lo,
                hi,
                scale,
                neutral: *neutral,
                pinned: false,
            })
            .collect();
        let profiles = extension_profiles(&dims);
        // Shift {1, 0, 0.5} times noise {0, 1.5, 3}, the width fitted in each.
        assert_eq!(profiles.len(), 8, "{profiles:?}");
        assert!(profiles.iter().all(|p| p[0].is_none()));
        assert!(!profiles.contains(&vec![None, Some(1.0), Some(0.0)]));
        // The zeroing deadband after the noise: shift 0 with the noise on.
        assert!(profiles.contains(&vec![None, Some(0.0), Some(3.0)]));
        assert!(profiles.contains(&vec![None, Some(0.0), Some(0.0)]));
        assert!(profiles.contains(&vec![None, Some(1.0), Some(1.5)]));
    }
}
