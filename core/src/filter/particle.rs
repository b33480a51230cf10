//! Sampling-importance-resampling (SIR) particle filter with a const-generic particle count.
//!
//! Weights live in the log domain and are normalised by log-sum-exp, so likelihoods never
//! underflow; resampling happens when the effective sample size falls below a threshold; the
//! parameter part of the state follows a random walk for joint state-parameter estimation.

use super::resample::{Resampling, apply_counts, offspring_counts};
use crate::error::{Error, check_dt};
use crate::model::Stochastic;
use crate::random::standard_normal;
use crate::real::{Real, all_finite, cast, zero_vector};
use crate::safeguard::{Flags, log_sum_exp};
use crate::stats::{Summary, summarise};
use nalgebra::{SMatrix, SVector};
use rand_core::Rng;

/// Particle-filter settings.
#[derive(Clone, Copy, Debug)]
pub struct PfConfig<T: Real, const NX: usize> {
    /// Resampling scheme.
    pub resampling: Resampling,
    /// Resample when ESS < `resample_threshold * N` (1.0 resamples every step, as the valve paper).
    pub resample_threshold: T,
    /// Standard deviation of the per-step Gaussian random walk of each state entry (zero for
    /// dynamic states; the parameter entries' walk drives joint parameter estimation).
    pub random_walk_std: SVector<T, NX>,
    /// Roughening constant K per entry (Gordon et al. 1993): after resampling, each entry gets
    /// jitter of std `K * range * N^(-1/NX)`. Zero disables it for that entry.
    pub roughening: SVector<T, NX>,
    /// Lower bounds of the state (use `-MAX_FINITE` for none); particles are clamped into bounds.
    pub lower: SVector<T, NX>,
    /// Upper bounds of the state.
    pub upper: SVector<T, NX>,
}

impl<T: Real, const NX: usize> Default for PfConfig<T, NX> {
    fn default() -> Self {
        Self {
            resampling: Resampling::Systematic,
            resample_threshold: T::one(),
            random_walk_std: SVector::zeros(),
            roughening: SVector::zeros(),
            lower: SVector::repeat(-T::MAX_FINITE),
            upper: SVector::repeat(T::MAX_FINITE),
        }
    }
}

impl<T: Real, const NX: usize> PfConfig<T, NX> {
    /// All-zero settings of a [`ParticleFilter::UNSET`] placeholder (not a usable configuration:
    /// bounds `[0, 0]`).
    pub const UNSET: Self = Self {
        resampling: Resampling::Systematic,
        resample_threshold: T::ZERO,
        random_walk_std: zero_vector(),
        roughening: zero_vector(),
        lower: zero_vector(),
        upper: zero_vector(),
    };

    fn validate(&self) -> Result<(), Error> {
        if !(self.resample_threshold >= T::zero() && self.resample_threshold <= T::one()) {
            return Err(Error::InvalidParameter("resample_threshold"));
        }
        let nonneg = |v: &SVector<T, NX>| v.iter().all(|s| s.finite() && *s >= T::zero());
        if !nonneg(&self.random_walk_std) {
            return Err(Error::InvalidParameter("random_walk_std"));
        }
        if !nonneg(&self.roughening) {
            return Err(Error::InvalidParameter("roughening"));
        }
        if self
            .lower
            .iter()
            .zip(self.upper.iter())
            .any(|(l, u)| !(l <= u))
        {
            return Err(Error::InvalidParameter("lower/upper bounds"));
        }
        Ok(())
    }
}

/// What one filter step did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PfReport<T> {
    /// Effective sample size after the weight update, before any resampling.
    pub ess: T,
    /// The measurement was used to reweight the particles.
    pub fused: bool,
    /// `ln sum_i w_i p(y | x_i)`: the log evidence of the measurement (consistency monitors
    /// and gap diagnosis use it); `-inf` when the measurement was not fused.
    pub log_evidence: T,
    /// Largest single-particle log-likelihood.
    pub max_log_likelihood: T,
    /// Innovation `y - E[h(x)]` per channel under the prior weights (the first `channels`
    /// entries; none when the model has no [`Stochastic::predicted_measurement`] or more than
    /// [`PF_INNOVATION_CHANNELS`] channels).
    pub innovation: [T; PF_INNOVATION_CHANNELS],
    /// Its variance: the weighted spread of the particles' `h(x_i)` plus the sensor noise.
    pub innovation_variance: [T; PF_INNOVATION_CHANNELS],
    pub channels: usize,
    /// Test ratio: the normalised innovation squared `sum innovation^2 / variance` over the
    /// channels (channels treated as independent); 0 without channels.
    pub test_ratio: T,
    /// Safeguards and actions taken (resampling, roughening, recoveries).
    pub flags: Flags,
}

/// Measurement channels a [`PfReport`] holds the innovation of.
pub const PF_INNOVATION_CHANNELS: usize = 4;

/// SIR particle filter over `N` particles of an `NX`-dimensional state.
///
/// Size: `N * (NX + 3) * size_of::<T>()` bytes plus the config (e.g. 14 states, N = 500, f64:
/// about 68 KiB). On a microcontroller keep it in a `static`.
#[derive(Clone)]
pub struct ParticleFilter<T: Real, const NX: usize, const N: usize> {
    particles: [SVector<T, NX>; N],
    log_weights: [T; N],
    // Work buffers, overwritten before every use: not part of the filter's state.
    scratch: [T; N],
    counts: [u32; N],
    config: PfConfig<T, NX>,
}

/// Shows the state (particles, weights, configuration), not the work buffers, so that two
/// filters in the same state print the same.
impl<T: Real, const NX: usize, const N: usize> core::fmt::Debug for ParticleFilter<T, NX, N> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("ParticleFilter")
            .field("particles", &self.particles)
            .field("log_weights", &self.log_weights)
            .field("config", &self.config)
            .finish_non_exhaustive()
    }
}

impl<T: Real, const NX: usize, const N: usize> ParticleFilter<T, NX, N> {
    const NONEMPTY: () = assert!(N > 0 && NX > 0, "need at least one particle and one state");

    /// An all-zero placeholder for static storage, built at compile time so that a large
    /// filter never passes through the stack: [`ParticleFilter::reset`] it in place before use.
    pub const UNSET: Self = Self {
        particles: [zero_vector(); N],
        log_weights: [T::ZERO; N],
        scratch: [T::ZERO; N],
        counts: [0; N],
        config: PfConfig::UNSET,
    };

    /// A filter with all particles at `x0` and uniform weights.
    pub fn new(x0: SVector<T, NX>, config: PfConfig<T, NX>) -> Result<Self, Error> {
        let mut filter = Self::UNSET;
        filter.reset(x0, config)?;
        Ok(filter)
    }

    /// Re-initialises the filter in place, as [`ParticleFilter::new`] would build it: all
    /// particles at `x0`, uniform weights. Bad settings are an error and change nothing.
    pub fn reset(&mut self, x0: SVector<T, NX>, config: PfConfig<T, NX>) -> Result<(), Error> {
        let () = Self::NONEMPTY;
        config.validate()?;
        if !all_finite(x0.as_slice()) {
            return Err(Error::InvalidParameter("x0"));
        }
        self.particles.fill(x0);
        self.reset_weights();
        self.scratch.fill(T::zero());
        self.counts.fill(0);
        self.config = config;
        Ok(())
    }

    /// Re-initialises particles from independent Gaussians `mean + std * z`, clamped to the
    /// bounds, with uniform weights.
    pub fn init_gaussian<R: Rng + ?Sized>(
        &mut self,
        mean: &SVector<T, NX>,
        std: &SVector<T, NX>,
        rng: &mut R,
    ) -> Result<(), Error> {
        if !all_finite(mean.as_slice()) || !std.iter().all(|s| s.finite() && *s >= T::zero()) {
            return Err(Error::InvalidParameter("initial mean/std"));
        }
        let (lower, upper) = (self.config.lower, self.config.upper);
        for p in self.particles.iter_mut() {
            for ((x, m), s) in p.iter_mut().zip(mean.iter()).zip(std.iter()) {
                *x = *m + *s * standard_normal::<T, R>(rng);
            }
            clamp_into(p, &lower, &upper);
        }
        self.reset_weights();
        Ok(())
    }

    /// Re-initialises particle `i` from `init(i, rng)`, with uniform weights. A non-finite
    /// particle is an error and leaves the earlier particles replaced (call again to retry).
    pub fn init_with<R: Rng + ?Sized>(
        &mut self,
        rng: &mut R,
        mut init: impl FnMut(usize, &mut R) -> SVector<T, NX>,
    ) -> Result<(), Error> {
        for (i, p) in self.particles.iter_mut().enumerate() {
            let x = init(i, rng);
            if !all_finite(x.as_slice()) {
                return Err(Error::InvalidParameter("initial particle"));
            }
            *p = x;
        }
        self.reset_weights();
        Ok(())
    }

    fn reset_weights(&mut self) {
        let uniform = -cast::<T>(N as f64).ln();
        self.log_weights.fill(uniform);
    }

    /// The particles.
    pub fn particles(&self) -> &[SVector<T, NX>; N] {
        &self.particles
    }

    /// Mutable access to the particles (for model-specific projections); weights are kept.
    pub fn particles_mut(&mut self) -> &mut [SVector<T, NX>; N] {
        &mut self.particles
    }

    /// Normalised log-weights (their log-sum-exp is 0).
    pub fn log_weights(&self) -> &[T; N] {
        &self.log_weights
    }

    /// Normalised linear weight of particle `i` (0 for an index out of range).
    pub fn weight(&self, i: usize) -> T {
        self.log_weights.get(i).map_or(T::zero(), |lw| lw.exp())
    }

    /// The configuration.
    pub fn config(&self) -> &PfConfig<T, NX> {
        &self.config
    }

    /// Replaces the configuration (validated; unchanged on error).
    pub fn set_config(&mut self, config: PfConfig<T, NX>) -> Result<(), Error> {
        config.validate()?;
        self.config = config;
        Ok(())
    }

    /// Effective sample size `1 / sum w_i^2`.
    pub fn ess(&self) -> T {
        let s = self.log_weights.iter().fold(T::zero(), |a, &lw| {
            let w = lw.exp();
            a + w * w
        });
        if s > T::zero() {
            T::one() / s
        } else {
            T::zero()
        }
    }

    /// Weighted mean of the particles.
    pub fn mean(&self) -> SVector<T, NX> {
        let mut m = SVector::<T, NX>::zeros();
        for (p, lw) in self.particles.iter().zip(self.log_weights.iter()) {
            m += p * lw.exp();
        }
        m
    }

    /// Weighted mean and variance of state entry `index` in one pass (deviations from the
    /// first particle, so a small spread about a large mean keeps its digits in f32); `None`
    /// for a bad index.
    pub fn moments_of(&self, index: usize) -> Option<(T, T)> {
        let origin = *self.particles.first()?.get(index)?;
        let (mut sum, mut sum_sq) = (T::zero(), T::zero());
        for (p, lw) in self.particles.iter().zip(self.log_weights.iter()) {
            let d = *p.get(index)? - origin;
            let w = lw.exp();
            sum += w * d;
            sum_sq += w * d * d;
        }
        Some((origin + sum, (sum_sq - sum * sum).max(T::zero())))
    }

    /// Weighted covariance of the particles.
    pub fn covariance(&self) -> SMatrix<T, NX, NX> {
        let m = self.mean();
        let mut c = SMatrix::<T, NX, NX>::zeros();
        for (p, lw) in self.particles.iter().zip(self.log_weights.iter()) {
            let d = p - m;
            c += d * d.transpose() * lw.exp();
        }
        c
    }

    /// Weighted summary (mean, median, percentiles, RMAD) of state entry `index`, using the
    /// caller's buffer (no allocation). `None` for a bad index.
    pub fn summary_of(&self, index: usize, buf: &mut [(T, T); N]) -> Option<Summary<T>> {
        if index >= NX {
            return None;
        }
        for ((slot, p), lw) in buf
            .iter_mut()
            .zip(self.particles.iter())
            .zip(&self.log_weights)
        {
            *slot = (p.get(index).copied().unwrap_or_else(T::zero), lw.exp());
        }
        summarise(buf)
    }

    /// Prediction: propagates every particle through the model with process noise and the
    /// parameter random walk. Errors (bad `u` or `dt`) leave the filter unchanged. A particle
    /// whose new state is non-finite keeps its old state and loses its weight (flagged); if
    /// every particle diverges the step is discarded with [`Error::NonFiniteState`].
    pub fn predict<M, R, const NU: usize>(
        &mut self,
        model: &M,
        u: &SVector<T, NU>,
        dt: T,
        rng: &mut R,
    ) -> Result<Flags, Error>
    where
        M: Stochastic<T, NX, NU>,
        R: Rng + ?Sized,
    {
        check_dt(dt)?;
        if !all_finite(u.as_slice()) {
            return Err(Error::NonFiniteInput);
        }
        let mut flags = Flags::NONE;
        let mut survivors = 0usize;
        let (walk, lower, upper) = (
            self.config.random_walk_std,
            self.config.lower,
            self.config.upper,
        );
        for (p, ok) in self.particles.iter_mut().zip(self.scratch.iter_mut()) {
            let mut next = model.sample_step(p, u, dt, rng);
            // Slice iterators: nalgebra's matrix iterators cost several times more per entry
            // in this per-particle loop (callgrind, docs/results.md); same order, same result.
            for (x, s) in next.as_mut_slice().iter_mut().zip(walk.as_slice()) {
                if *s > T::zero() {
                    *x += *s * standard_normal::<T, R>(rng);
                }
            }
            if clamp_into(&mut next, &lower, &upper) {
                flags.insert(Flags::BOUNDS_CLAMPED);
            }
            if all_finite(next.as_slice()) {
                *p = next;
                *ok = T::zero();
                survivors = survivors.saturating_add(1);
            } else {
                *ok = T::min_value().unwrap_or(-T::MAX_FINITE);
            }
        }
        if survivors == 0 {
            return Err(Error::NonFiniteState);
        }
        if survivors < N {
            flags.insert(Flags::NONFINITE_PARTICLES_DROPPED);
            for (lw, penalty) in self.log_weights.iter_mut().zip(self.scratch.iter()) {
                *lw += *penalty;
            }
            self.normalise();
        }
        Ok(flags)
    }

    /// Measurement update: reweights by `ln p(y | x_i)` and resamples when the ESS is low.
    /// A measurement of the wrong length or with a non-finite entry is an error and leaves the
    /// filter unchanged. If every particle's likelihood is zero the measurement is skipped (the
    /// step becomes predict-only) and [`Flags::WEIGHT_COLLAPSE_RECOVERED`] is set.
    pub fn update<M, R, const NU: usize>(
        &mut self,
        model: &M,
        u: &SVector<T, NU>,
        y: &[T],
        rng: &mut R,
    ) -> Result<PfReport<T>, Error>
    where
        M: Stochastic<T, NX, NU>,
        R: Rng + ?Sized,
    {
        check_measurement(y, model.measurement_len())?;
        if !all_finite(u.as_slice()) {
            return Err(Error::NonFiniteInput);
        }
        let neg_inf = T::min_value().unwrap_or(-T::MAX_FINITE);
        // A true -inf (not -MAX_FINITE): a zero likelihood must stay zero in the sums below.
        let zero_likelihood: T = cast(f64::NEG_INFINITY);
        let mut max_ll = neg_inf;
        let mut max_total = zero_likelihood;
        for ((p, ll), lw) in self
            .particles
            .iter()
            .zip(self.scratch.iter_mut())
            .zip(&self.log_weights)
        {
            let l = model.log_likelihood(p, u, y);
            // NaN likelihoods (a model bug or an impossible state) count as zero likelihood.
            let l = if l.nan() { zero_likelihood } else { l };
            let total = *lw + l;
            // -inf + inf is NaN: also a zero.
            *ll = if total.nan() { zero_likelihood } else { total };
            if l > max_ll {
                max_ll = l;
            }
            if *ll > max_total {
                max_total = *ll;
            }
        }
        let mut report = PfReport {
            ess: T::zero(),
            fused: false,
            log_evidence: neg_inf,
            max_log_likelihood: max_ll,
            flags: Flags::NONE,
            ..PfReport::default()
        };
        self.innovation(model, u, y, &mut report);
        if !max_total.finite() {
            report.flags.insert(Flags::WEIGHT_COLLAPSE_RECOVERED);
            report.ess = self.ess();
            return Ok(report);
        }
        // Shift by the largest term before the log-sum-exp: with log-likelihoods of -1e300 the
        // particles' differences would otherwise be absorbed and the weights not sum to one.
        for s in self.scratch.iter_mut() {
            *s -= max_total;
        }
        let log_sum = log_sum_exp(&self.scratch);
        for (lw, s) in self.log_weights.iter_mut().zip(self.scratch.iter()) {
            *lw = *s - log_sum;
        }
        let log_evidence = max_total + log_sum;
        report.fused = true;
        report.log_evidence = log_evidence;
        report.ess = self.ess();
        if report.ess < self.config.resample_threshold * cast(N as f64) {
            report.flags.insert(self.resample(rng));
        }
        Ok(report)
    }

    /// Fills the report's innovation from the particles' predicted measurements under the
    /// current (prior) weights: weighted mean and spread in one pass (West's weighted
    /// incremental form), plus the sensor noise. Reads the particles only.
    fn innovation<M, const NU: usize>(
        &self,
        model: &M,
        u: &SVector<T, NU>,
        y: &[T],
        report: &mut PfReport<T>,
    ) where
        M: Stochastic<T, NX, NU>,
    {
        const C: usize = PF_INNOVATION_CHANNELS;
        let channels = y.len();
        if channels > C {
            return;
        }
        let (mut mean, mut m2, mut noise) = ([T::zero(); C], [T::zero(); C], [T::zero(); C]);
        let mut predicted = [T::zero(); C];
        let mut total = T::zero();
        for (p, lw) in self.particles.iter().zip(self.log_weights.iter()) {
            let (Some(h), Some(r)) = (predicted.get_mut(..channels), noise.get_mut(..channels))
            else {
                return;
            };
            if !model.predicted_measurement(p, u, h, r) {
                return;
            }
            let w = lw.exp();
            if !(w > T::zero()) || !all_finite(h) {
                continue;
            }
            total += w;
            let share = w / total;
            for ((m, s), h) in mean.iter_mut().zip(m2.iter_mut()).zip(predicted.iter()) {
                let delta = *h - *m;
                *m += delta * share;
                *s += w * delta * (*h - *m);
            }
        }
        if !(total > T::zero()) {
            return;
        }
        let mut ratio = T::zero();
        for (j, yj) in y.iter().enumerate() {
            let (Some(m), Some(s), Some(r)) = (mean.get(j), m2.get(j), noise.get(j)) else {
                return;
            };
            let e = *yj - *m;
            let v = *s / total + *r;
            if let (Some(slot_e), Some(slot_v)) = (
                report.innovation.get_mut(j),
                report.innovation_variance.get_mut(j),
            ) {
                *slot_e = e;
                *slot_v = v;
            }
            if v > T::zero() {
                ratio += e * e / v;
            }
        }
        report.channels = channels;
        report.test_ratio = ratio;
    }

    /// One full step: predict over `dt`, then update with `y` if present (`None` is a
    /// predict-only step, e.g. for a missing sample). Validates everything before changing
    /// anything, so an error leaves the filter unchanged.
    pub fn step<M, R, const NU: usize>(
        &mut self,
        model: &M,
        u: &SVector<T, NU>,
        y: Option<&[T]>,
        dt: T,
        rng: &mut R,
    ) -> Result<PfReport<T>, Error>
    where
        M: Stochastic<T, NX, NU>,
        R: Rng + ?Sized,
    {
        if let Some(y) = y {
            check_measurement(y, model.measurement_len())?;
        }
        let predict_flags = self.predict(model, u, dt, rng)?;
        let mut report = match y {
            Some(y) => self.update(model, u, y, rng)?,
            None => PfReport {
                ess: self.ess(),
                log_evidence: T::min_value().unwrap_or(-T::MAX_FINITE),
                max_log_likelihood: T::min_value().unwrap_or(-T::MAX_FINITE),
                ..PfReport::default()
            },
        };
        report.flags.insert(predict_flags);
        Ok(report)
    }

    /// Resamples now with the configured scheme (uniform weights afterwards), then roughens.
    pub fn resample<R: Rng + ?Sized>(&mut self, rng: &mut R) -> Flags {
        for (w, lw) in self.scratch.iter_mut().zip(self.log_weights.iter()) {
            *w = lw.exp();
        }
        offspring_counts(self.config.resampling, &self.scratch, &mut self.counts, rng);
        apply_counts(&mut self.particles, &self.counts);
        self.reset_weights();
        let mut flags = Flags::RESAMPLED;
        if self.roughen(rng) {
            flags.insert(Flags::ROUGHENED);
        }
        flags
    }

    /// Replaces each particle's normalised log-weight by `f(particle, log_weight)` and
    /// renormalises (for weight mutations such as `filter::adaptive`'s sample improvement).
    /// If no new weight is positive and finite the weights stay unchanged and `false` is
    /// returned. NaN results count as zero weight.
    pub fn reweight(&mut self, mut f: impl FnMut(&SVector<T, NX>, T) -> T) -> bool {
        let neg_inf = T::min_value().unwrap_or(-T::MAX_FINITE);
        for ((s, p), lw) in self
            .scratch
            .iter_mut()
            .zip(self.particles.iter())
            .zip(self.log_weights.iter())
        {
            let v = f(p, *lw);
            *s = if v.nan() { neg_inf } else { v };
        }
        let total = log_sum_exp(&self.scratch);
        if !total.finite() {
            return false;
        }
        for (lw, s) in self.log_weights.iter_mut().zip(self.scratch.iter()) {
            *lw = *s - total;
        }
        true
    }

    /// `ln sum_i w_i exp(f(particle_i))`: the log evidence of a measurement whose
    /// log-likelihood under each particle is `f` (weights and particles unchanged). Computed in
    /// one pass without a buffer; `-inf` (the type's lowest) when no term is finite.
    pub fn log_expected_likelihood(&self, mut f: impl FnMut(&SVector<T, NX>) -> T) -> T {
        let lowest = T::min_value().unwrap_or(-T::MAX_FINITE);
        let (mut max, mut sum) = (lowest, T::zero());
        for (p, lw) in self.particles.iter().zip(self.log_weights.iter()) {
            let v = *lw + f(p);
            if !v.finite() {
                continue;
            }
            if v > max {
                sum = sum * (max - v).exp() + T::one();
                max = v;
            } else {
                sum += (v - max).exp();
            }
        }
        if sum > T::zero() {
            max + sum.ln()
        } else {
            lowest
        }
    }

    /// Copies `other`'s particles, weights and configuration into `self` in place (a
    /// snapshot that does not pass a whole filter through the stack).
    pub fn copy_state_from(&mut self, other: &Self) {
        self.particles.copy_from_slice(&other.particles);
        self.log_weights.copy_from_slice(&other.log_weights);
        self.config = other.config;
    }

    /// Roughening: Gaussian jitter proportional to each entry's particle range.
    fn roughen<R: Rng + ?Sized>(&mut self, rng: &mut R) -> bool {
        if self.config.roughening.iter().all(|k| *k == T::zero()) {
            return false;
        }
        let mut lo = SVector::<T, NX>::repeat(T::MAX_FINITE);
        let mut hi = SVector::<T, NX>::repeat(-T::MAX_FINITE);
        for p in self.particles.iter() {
            lo = lo.inf(p);
            hi = hi.sup(p);
        }
        let shrink = cast::<T>(N as f64).powf(-T::one() / cast(NX as f64));
        let std = (hi - lo).component_mul(&self.config.roughening) * shrink;
        let (lower, upper) = (self.config.lower, self.config.upper);
        for p in self.particles.iter_mut() {
            for (x, s) in p.as_mut_slice().iter_mut().zip(std.as_slice()) {
                if *s > T::zero() {
                    *x += *s * standard_normal::<T, R>(rng);
                }
            }
            clamp_into(p, &lower, &upper);
        }
        true
    }

    fn normalise(&mut self) {
        let total = log_sum_exp(&self.log_weights);
        if total.finite() {
            for lw in self.log_weights.iter_mut() {
                *lw -= total;
            }
        } else {
            self.reset_weights();
        }
    }
}

/// A measurement must have the model's channel count and finite entries.
fn check_measurement<T: Real>(y: &[T], expected: usize) -> Result<(), Error> {
    if y.len() != expected {
        return Err(Error::MeasurementLength {
            expected,
            got: y.len(),
        });
    }
    if !all_finite(y) {
        return Err(Error::NonFiniteMeasurement);
    }
    Ok(())
}

/// Clamps `x` into `[lower, upper]` entry-wise; true when anything moved.
fn clamp_into<T: Real, const NX: usize>(
    x: &mut SVector<T, NX>,
    lower: &SVector<T, NX>,
    upper: &SVector<T, NX>,
) -> bool {
    let mut moved = false;
    // Slices, not nalgebra's matrix iterators: this runs for every particle at every step.
    let entries = x.as_mut_slice().iter_mut();
    for ((v, l), u) in entries.zip(lower.as_slice()).zip(upper.as_slice()) {
        if *v < *l {
            *v = *l;
            moved = true;
        } else if *v > *u {
            *v = *u;
            moved = true;
        }
    }
    moved
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector1;
    use rand_core::SeedableRng;
    use rand_xoshiro::Xoshiro256PlusPlus;

    /// One-pass moments agree with `mean`/`covariance` in f64, and keep a 0.07 spread about
    /// 30 in f32 (where `E[x^2] - E[x]^2` without the shift would lose it).
    #[test]
    fn moments_of_one_entry_match_mean_and_covariance() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(4);
        let mut filter =
            ParticleFilter::<f64, 3, 100>::new(nalgebra::Vector3::zeros(), PfConfig::default())
                .unwrap();
        filter
            .init_gaussian(
                &nalgebra::Vector3::new(1.0, -2.0, 30.0),
                &nalgebra::Vector3::new(0.5, 1.0, 0.07),
                &mut rng,
            )
            .unwrap();
        assert!(filter.reweight(|p, lw| lw - 0.5 * p.x * p.x));
        let (mean, variance) = filter.moments_of(2).unwrap();
        assert!((mean - filter.mean().z).abs() < 1e-12);
        let exact = filter.covariance()[(2, 2)];
        assert!((variance - exact).abs() < 1e-12 * exact);
        assert!(filter.moments_of(3).is_none());
        let mut single =
            ParticleFilter::<f32, 3, 100>::new(nalgebra::Vector3::zeros(), PfConfig::default())
                .unwrap();
        single
            .init_gaussian(
                &nalgebra::Vector3::new(1.0, -2.0, 30.0),
                &nalgebra::Vector3::new(0.5, 1.0, 0.07),
                &mut rng,
            )
            .unwrap();
        let (_, variance) = single.moments_of(2).unwrap();
        let exact = single.covariance()[(2, 2)];
        assert!(
            (variance - exact).abs() < 1e-3 * exact,
            "{variance} vs {exact}"
        );
    }

    #[test]
    fn expected_likelihood_is_the_weighted_mean_and_copies_are_exact() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(3);
        let mut filter =
            ParticleFilter::<f64, 1, 64>::new(Vector1::new(0.0), PfConfig::default()).unwrap();
        filter
            .init_gaussian(&Vector1::new(1.0), &Vector1::new(2.0), &mut rng)
            .unwrap();
        assert!(filter.reweight(|p, lw| lw - 0.3 * p.x * p.x));
        let f = |p: &Vector1<f64>| -0.5 * (p.x - 0.7) * (p.x - 0.7) - 400.0;
        let direct: f64 = (0..64)
            .map(|i| filter.weight(i) * f(&filter.particles()[i]).exp())
            .sum();
        let streamed = filter.log_expected_likelihood(f);
        assert!(
            (streamed - direct.ln()).abs() < 1e-12,
            "{streamed} {}",
            direct.ln()
        );
        assert_eq!(
            filter.log_expected_likelihood(|_| f64::NEG_INFINITY),
            f64::MIN
        );
        let mut copy = ParticleFilter::<f64, 1, 64>::UNSET;
        copy.copy_state_from(&filter);
        assert_eq!(copy.particles(), filter.particles());
        assert_eq!(copy.log_weights(), filter.log_weights());
    }
}
