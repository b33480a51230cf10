//! The paper's two-step particle filter of the lubricant-loss parameters (Eqs. 31-34): a PF of
//! `b` on the ratio of consecutive interval consumptions (which does not depend on `beta`),
//! then a PF of `beta` on the interval consumption given the first filter's `b`.
//!
//! One implementation for the on-board pipeline (`pipeline::ReactionWheel`) and the host's
//! Table 6/7 reproductions. Both filters use the adaptive resampling of section 3.1.1.
//!
//! Consecutive ratios share a reading, so the first filter scores each ratio conditional on
//! the earlier ones ([`LossRatioModel`]); without that the ratios, treated as white noise,
//! lose most of what the levels say about `b` (their sum telescopes to one level
//! difference) and count each reading's noise twice. See `docs/deviations.md`.

use super::reaction_wheel::{BETA_UNIT, IntervalExposure, LossRateModel, LossRatioModel};
use crate::Error;
use crate::filter::adaptive::{AdaptiveConfig, AdaptiveFilter, Method};
use crate::filter::particle::PfConfig;
use crate::model::Stochastic;
use crate::real::{Real, cast};
use crate::safeguard::Flags;
use nalgebra::SVector;
use rand_core::Rng;

/// Settings of the two-step filter.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TwoStepConfig<T> {
    /// Relative (log-normal) noise the filters assume for one consumption measurement.
    pub relative_noise: T,
    /// Random walk per interval of b (degC) and beta (1e-6 mL/s).
    pub walk: (T, T),
    /// Prior mean and std of b (degC).
    pub prior_b: (T, T),
    /// Prior mean and std of beta (1e-6 mL/s).
    pub prior_beta: (T, T),
    /// Spread of b (degC) and beta (1e-6 mL/s) when a filter is confused (a change).
    pub change_spread: (T, T),
    /// Relative change of the consumption level (of `beta`) that the ratio bridging a declared
    /// change may contain.
    pub level_change: T,
    /// Adaptive resampling's `p_eff` and judging window (section 3.1.1) of both filters.
    pub confusion: (T, u32),
}

impl<T: Real> TwoStepConfig<T> {
    /// All zeros: the configuration of [`TwoStepLoss::UNSET`].
    pub const UNSET: Self = Self {
        relative_noise: T::ZERO,
        walk: (T::ZERO, T::ZERO),
        prior_b: (T::ZERO, T::ZERO),
        prior_beta: (T::ZERO, T::ZERO),
        change_spread: (T::ZERO, T::ZERO),
        level_change: T::ZERO,
        confusion: (T::ZERO, 0),
    };

    /// The given noise, walks and priors with the default change handling: a confused
    /// filter is judged at every interval (`p_eff` 1e-3, 3.7 sigma for the best particle) and
    /// spread by 10 degC in `b` (the Kalman filter's enhancement) and 0.4e-6 mL/s in `beta`;
    /// the confusing ratio may hold a 20 % level change (Table 4's faults change `beta` by
    /// 7 %; 10 % attributed too much of the jump to `b`, docs/results.md).
    pub fn new(relative_noise: T, walk: (T, T), prior_b: (T, T), prior_beta: (T, T)) -> Self {
        Self {
            relative_noise,
            walk,
            prior_b,
            prior_beta,
            change_spread: (cast(10.0), cast(0.4)),
            level_change: cast(0.2),
            confusion: (cast(1e-3), 1),
        }
    }
}

/// Most consecutive readings a ratio bridges over after declared changes.
const MAX_BRIDGED: u32 = 2;

fn loss_config<T: Real, const NX: usize>(
    walk: SVector<T, NX>,
    lower: SVector<T, NX>,
    upper: SVector<T, NX>,
) -> PfConfig<T, NX> {
    PfConfig {
        random_walk_std: walk,
        lower,
        upper,
        ..PfConfig::default()
    }
}

/// Adaptive resampling with a spread of `spread` when the filter is confused (a change).
fn loss_adaptive<T: Real, const NX: usize>(
    spread: SVector<T, NX>,
    (likelihood_threshold, min_window): (T, u32),
) -> AdaptiveConfig<T, NX> {
    AdaptiveConfig {
        method: Method::AdaptiveResampling,
        ess_threshold: cast(0.5),
        likelihood_threshold,
        min_window,
        spread_std: spread,
        improvement_offset: T::zero(),
        improvement_ess: T::one(),
    }
}

/// The two-step PF with `M` particles per filter.
#[derive(Clone, Debug)]
pub struct TwoStepLoss<T: Real, const M: usize> {
    relative_noise: T,
    /// Variance of this interval's `ln(consumption)` error: `relative_noise^2` plus what the
    /// temperature estimate's own uncertainty does to `exp(-b/T)`.
    reading_variance: T,
    /// Relative random walk of the consumption level per interval (`beta`'s walk over its
    /// prior mean): how fast the ratio filter forgets the readings it conditions on.
    level_walk: T,
    level_change: T,
    /// Variance of the previous reading's noise given the ratios so far (the same for every
    /// particle; the estimates are the ratio filter's second state entry).
    carried_variance: T,
    /// `[b (degC), estimated ln integral + noise of the previous reading]`.
    ratio: AdaptiveFilter<T, 2, M>,
    /// `beta` given `b = conditioned_b`.
    rate: AdaptiveFilter<T, 1, M>,
    /// The `b` the rate filter's particles are conditioned on (the ratio filter's last mean).
    conditioned_b: Option<T>,
    /// Mean `1/T` of the intervals so far: where `beta` given `b` is held fixed when `b` moves.
    reference_inverse_temperature: T,
    intervals: u32,
    /// The previous interval's consumption (mL), if usable.
    previous: Option<T>,
    /// Readings skipped since the one the ratios continue from: a reading at which a change
    /// was declared may mix the old and the new parameters, so the next ratio bridges over it.
    bridged: u32,
    /// Mean and std of `beta` before the declared change the ratios are bridging over.
    beta_before_change: (T, T),
    /// The last reading is in doubt until the next ratio has decided whether it was an outlier
    /// (against the state in `*_before`): see [`TwoStepLoss::outlier_explains`].
    pending: Pending<T>,
    /// Both filters and the scalars as they were before the latest reading that started a
    /// bridge (copied in place each interval, so nothing large passes through the stack).
    ratio_before: AdaptiveFilter<T, 2, M>,
    rate_before: AdaptiveFilter<T, 1, M>,
    scalars_before: Scalars<T>,
}

/// The ratio and rate filters, the `b` the rate filter is conditioned on and the reference
/// `1/T`: what pairing particles needs.
type PairedState<'a, T, const M: usize> = (
    &'a AdaptiveFilter<T, 2, M>,
    &'a AdaptiveFilter<T, 1, M>,
    Option<T>,
    T,
);

/// What the last reading did, while it is in doubt.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Pending<T> {
    /// Nothing in doubt (the start, after a verdict, or while bridging).
    None,
    /// It declared a change.
    Change,
    /// It was fused, with this log evidence of its ratio (without the Gaussian's constant).
    Fused(T),
}

/// The small part of [`TwoStepLoss`]'s state that an outlier verdict restores.
#[derive(Clone, Copy, Debug)]
struct Scalars<T> {
    carried_variance: T,
    conditioned_b: Option<T>,
    reference_inverse_temperature: T,
    intervals: u32,
    previous: Option<T>,
}

impl<T: Real> Scalars<T> {
    const UNSET: Self = Self {
        carried_variance: T::ZERO,
        conditioned_b: None,
        reference_inverse_temperature: T::ZERO,
        intervals: 0,
        previous: None,
    };
}

impl<T: Real, const M: usize> TwoStepLoss<T, M> {
    /// An all-zero placeholder for static storage: [`TwoStepLoss::reset`] it before use.
    pub const UNSET: Self = Self {
        relative_noise: T::ZERO,
        reading_variance: T::ZERO,
        level_walk: T::ZERO,
        level_change: T::ZERO,
        carried_variance: T::ZERO,
        ratio: AdaptiveFilter::UNSET,
        rate: AdaptiveFilter::UNSET,
        conditioned_b: None,
        reference_inverse_temperature: T::ZERO,
        intervals: 0,
        previous: None,
        bridged: 0,
        beta_before_change: (T::ZERO, T::ZERO),
        pending: Pending::None,
        ratio_before: AdaptiveFilter::UNSET,
        rate_before: AdaptiveFilter::UNSET,
        scalars_before: Scalars::UNSET,
    };

    /// Filters with particles drawn from the priors (`b` first, then `beta`).
    pub fn new<R: Rng + ?Sized>(config: TwoStepConfig<T>, rng: &mut R) -> Result<Self, Error> {
        let mut filter = Self::UNSET;
        filter.reset(config, rng)?;
        Ok(filter)
    }

    /// Re-initialises in place to what [`TwoStepLoss::new`] builds (the same draws).
    pub fn reset<R: Rng + ?Sized>(
        &mut self,
        config: TwoStepConfig<T>,
        rng: &mut R,
    ) -> Result<(), Error> {
        if !(config.relative_noise.finite() && config.relative_noise > T::zero()) {
            return Err(Error::InvalidParameter("relative_noise"));
        }
        if !(config.level_change.finite() && config.level_change >= T::zero()) {
            return Err(Error::InvalidParameter("level_change"));
        }
        let (b0, bs) = config.prior_b;
        let (beta0, betas) = config.prior_beta;
        if !(beta0.finite() && beta0 > T::zero()) {
            return Err(Error::InvalidParameter("prior_beta"));
        }
        let unbounded = T::MAX_FINITE;
        self.ratio.reset(
            SVector::from([b0, T::zero()]),
            loss_config(
                SVector::from([config.walk.0, T::zero()]),
                SVector::from([T::zero(), -unbounded]),
                SVector::from([cast(150.0), unbounded]),
            ),
            loss_adaptive(
                SVector::from([config.change_spread.0, T::zero()]),
                config.confusion,
            ),
        )?;
        self.ratio.filter_mut().init_gaussian(
            &SVector::from([b0, T::zero()]),
            &SVector::from([bs, T::zero()]),
            rng,
        )?;
        self.rate.reset(
            SVector::from([beta0]),
            loss_config(
                SVector::from([config.walk.1]),
                SVector::from([cast::<T>(0.01)]),
                SVector::from([cast::<T>(100.0)]),
            ),
            loss_adaptive(SVector::from([config.change_spread.1]), config.confusion),
        )?;
        self.rate.filter_mut().init_gaussian(
            &SVector::from([beta0]),
            &SVector::from([betas]),
            rng,
        )?;
        self.relative_noise = config.relative_noise;
        self.reading_variance = config.relative_noise * config.relative_noise;
        self.level_walk = config.walk.1 / beta0;
        self.level_change = config.level_change;
        self.carried_variance = config.relative_noise * config.relative_noise;
        self.conditioned_b = None;
        self.reference_inverse_temperature = T::zero();
        self.intervals = 0;
        self.previous = None;
        self.bridged = 0;
        self.beta_before_change = (T::zero(), T::zero());
        self.pending = Pending::None;
        self.remember();
        Ok(())
    }

    /// Copies the state into `*_before` (before a reading that may declare a change).
    fn remember(&mut self) {
        self.ratio_before.copy_state_from(&self.ratio);
        self.rate_before.copy_state_from(&self.rate);
        self.scalars_before = Scalars {
            carried_variance: self.carried_variance,
            conditioned_b: self.conditioned_b,
            reference_inverse_temperature: self.reference_inverse_temperature,
            intervals: self.intervals,
            previous: self.previous,
        };
    }

    /// Whether the reading in doubt was an outlier (e.g. a wrong interval temperature), from
    /// this ratio at even prior odds. Outlier: the remembered cloud (before that reading)
    /// scores the ratio bridging over it, without a level change. Against it:
    /// - after a declared change, the spread cloud scores the same bridging ratio with the
    ///   level change allowed (the reading in doubt left out under both: it may mix the old
    ///   and the new parameters);
    /// - after a fused reading, that reading's evidence plus this ratio's on the current cloud,
    ///   while under the outlier hypothesis the reading gets the density at the `p_eff`
    ///   confusion level (what the adaptive resampling calls confusing). An ordinary reading's
    ///   evidence is far above that level, so only a reading the filter could barely fit and
    ///   that the next one contradicts is taken for an outlier.
    fn outlier_explains(&self, now: &IntervalExposure<T>, consumption: T) -> bool {
        if self.pending == Pending::None {
            return false;
        }
        let (Some(before), Some(previous)) = (self.scalars_before.previous, self.previous) else {
            return false;
        };
        // Over the reading in doubt, and (after a fused one) from it.
        let (bridging_ratio, next_ratio) =
            ((consumption / before).ln(), (consumption / previous).ln());
        let u = now.as_input();
        let reading_variance = self.reading_variance;
        let level_walk_variance = self.level_walk * self.level_walk;
        let model = LossRatioModel;
        let half: T = cast(0.5);
        // Log evidence of a ratio, with the Gaussian's `-ln(S)/2` (the variances differ).
        let evidence = |filter: &AdaptiveFilter<T, 2, M>, log_ratio: T, variance: T| {
            let u4 = SVector::<T, 4>::from([u.x, u.y, u.z, variance]);
            let ratio = [log_ratio.exp()];
            filter
                .filter()
                .log_expected_likelihood(|p| model.log_likelihood(p, &u4, &ratio))
                - half * variance.ln()
        };
        // Two intervals of level walk from the reading the bridge continues from.
        let bridging = reading_variance
            + level_walk_variance
            + level_walk_variance
            + self.scalars_before.carried_variance;
        // The outlier hypothesis's evidence, and its best particle in the same pass: without
        // the reading in doubt nothing may look confusing, else it is a change.
        let u4 = SVector::<T, 4>::from([u.x, u.y, u.z, bridging]);
        let ratio = [bridging_ratio.exp()];
        let mut best = T::min_value().unwrap_or(-T::MAX_FINITE);
        let outlier = self.ratio_before.filter().log_expected_likelihood(|p| {
            let log_likelihood = model.log_likelihood(p, &u4, &ratio);
            best = best.max(log_likelihood);
            log_likelihood
        }) - half * bridging.ln();
        let confusing = self.ratio.config().likelihood_threshold.ln();
        if !(best >= confusing) {
            return false;
        }
        let kept = match self.pending {
            Pending::None => return false,
            Pending::Change => evidence(
                &self.ratio,
                bridging_ratio,
                bridging + self.level_change * self.level_change,
            ),
            Pending::Fused(log_evidence) => {
                let next = reading_variance + level_walk_variance + self.carried_variance;
                // The outlier term's confusion-level density, moved to this side.
                log_evidence - confusing + evidence(&self.ratio, next_ratio, next)
            }
        };
        outlier.finite() && outlier >= kept
    }

    /// Back to the state before the reading in doubt, with that reading skipped: the next
    /// ratio bridges over it without a level change.
    fn restore(&mut self) {
        self.ratio.copy_state_from(&self.ratio_before);
        self.rate.copy_state_from(&self.rate_before);
        let before = self.scalars_before;
        self.carried_variance = before.carried_variance;
        self.conditioned_b = before.conditioned_b;
        self.reference_inverse_temperature = before.reference_inverse_temperature;
        self.intervals = before.intervals;
        self.previous = before.previous;
        self.bridged = 1;
    }

    /// The next ratio is scored as if only this interval's reading were known (its noise has
    /// the full variance): at the start and after a rejected interval.
    fn forget_readings(&mut self, now: &IntervalExposure<T>) {
        self.carried_variance = self.reading_variance;
        self.bridged = 0;
        self.pending = Pending::None;
        for p in self.ratio.filter_mut().particles_mut().iter_mut() {
            p.y = LossRatioModel::log_integral(p.x, now).unwrap_or(T::zero());
        }
    }

    /// The ratio filter's step on `ln(consumption / previous)`, then the carried estimates.
    /// Also says whether the filter was confused (a change declared); then nothing is carried
    /// and the next ratio bridges over this reading. `across_change`: the readings bridged
    /// over (if any) followed a declared change, so a level change is allowed too.
    fn update_ratio<R: Rng + ?Sized>(
        &mut self,
        now: &IntervalExposure<T>,
        log_ratio: T,
        across_change: bool,
        rng: &mut R,
    ) -> (Flags, bool) {
        let started_bridge = self.bridged == 0;
        self.pending = Pending::None;
        let reading_variance = self.reading_variance;
        let level_walk_variance = self.level_walk * self.level_walk;
        let mut innovation_variance =
            reading_variance + level_walk_variance + self.carried_variance;
        if self.bridged > 0 {
            // The skipped intervals' level walk, and across a declared change a level (beta)
            // change as well as b's.
            let skipped: T = cast(f64::from(self.bridged));
            innovation_variance += skipped * level_walk_variance;
            if across_change {
                innovation_variance += self.level_change * self.level_change;
            }
        }
        let u = now.as_input();
        let u4 = SVector::<T, 4>::from([u.x, u.y, u.z, innovation_variance]);
        let step = self.ratio.step(
            &LossRatioModel,
            &u4,
            Some(&[log_ratio.exp()]),
            T::one(),
            T::zero(),
            rng,
        );
        match step {
            Ok(report) if report.filter.fused && report.spread => {
                if self.bridged >= MAX_BRIDGED {
                    // Confused again and again: start afresh from this reading.
                    self.forget_readings(now);
                    return (Flags::NONE, false);
                }
                // For this interval's estimate only (undone at the next ratio): the ratio
                // scored again on the spread particles, allowing a level change as well as b's.
                if self.bridged == 0 {
                    innovation_variance += self.level_change * self.level_change;
                }
                let model = LossRatioModel;
                let u4 = SVector::<T, 4>::from([u.x, u.y, u.z, innovation_variance]);
                let ratio = [log_ratio.exp()];
                self.ratio
                    .filter_mut()
                    .reweight(|p, log_weight| log_weight + model.log_likelihood(p, &u4, &ratio));
                self.bridged = self.bridged.saturating_add(1);
                if started_bridge && !across_change {
                    self.pending = Pending::Change;
                }
                (Flags::NONE, true)
            }
            Ok(report) if report.filter.fused => {
                if started_bridge {
                    self.pending = Pending::Fused(report.filter.log_evidence);
                }
                let gain = reading_variance / innovation_variance;
                for p in self.ratio.filter_mut().particles_mut().iter_mut() {
                    if let Some(log_integral) = LossRatioModel::log_integral(p.x, now) {
                        p.y = LossRatioModel::carry(p.y, log_ratio, log_integral, gain);
                    }
                }
                self.carried_variance = reading_variance * (T::one() - gain);
                self.bridged = 0;
                (Flags::NONE, false)
            }
            // The ratio was not used: the earlier readings no longer bear on the next one.
            Ok(_) => {
                self.forget_readings(now);
                (Flags::NONE, false)
            }
            Err(_) => {
                self.forget_readings(now);
                (Flags::MEASUREMENT_REJECTED, false)
            }
        }
    }

    /// One interval: its temperature exposure and measured consumption (mL). A rejected
    /// update leaves that filter unchanged and is flagged; the next interval retries.
    pub fn update<R: Rng + ?Sized>(
        &mut self,
        exposure: IntervalExposure<T>,
        consumption: T,
        rng: &mut R,
    ) -> Flags {
        self.update_with_temperature_std(exposure, consumption, T::zero(), rng)
    }

    /// [`TwoStepLoss::update`] with the standard deviation (degC) of the interval's temperature
    /// estimate, beyond what `relative_noise` already allows for (e.g. the posterior spread
    /// of a temperature burst that did not converge). It widens this reading's error by
    /// `b sigma_T / T^2` (the sensitivity of `ln exp(-b/T)`), at the current `b` estimate, so a
    /// reading at a doubtful temperature moves neither `b` nor `beta` much. A non-finite or
    /// negative std is taken as zero.
    pub fn update_with_temperature_std<R: Rng + ?Sized>(
        &mut self,
        exposure: IntervalExposure<T>,
        consumption: T,
        temperature_std: T,
        rng: &mut R,
    ) -> Flags {
        let extra = if temperature_std > T::zero() {
            let sensitivity = self.ratio.filter().mean().x
                * exposure.mean_inverse_temperature
                * exposure.mean_inverse_temperature
                * temperature_std;
            if sensitivity.finite() {
                sensitivity * sensitivity
            } else {
                T::zero()
            }
        } else {
            T::zero()
        };
        self.reading_variance = self.relative_noise * self.relative_noise + extra;
        let mut flags = Flags::NONE;
        let u = exposure.as_input();
        let usable = consumption.finite() && consumption > T::zero();
        let mut changed = false;
        let mut bridged_over = false;
        match self.previous {
            Some(_) if usable => {
                if self.bridged > 0 {
                    // Undo the re-scoring of the ratio that declared the change: this ratio,
                    // over the same earlier reading, carries its information.
                    self.ratio.filter_mut().reweight(|_, _| T::zero());
                }
                let mut across_change = self.bridged > 0;
                if self.outlier_explains(&exposure, consumption) {
                    // The reading in doubt was an outlier, not a change.
                    self.restore();
                    across_change = false;
                    flags.insert(Flags::MEASUREMENT_REJECTED);
                }
                let Some(previous) = self.previous else {
                    return flags;
                };
                let log_ratio = (consumption / previous).ln();
                if self.bridged == 0 {
                    self.remember();
                }
                bridged_over = across_change;
                let (ratio_flags, spread) =
                    self.update_ratio(&exposure, log_ratio, across_change, rng);
                flags.insert(ratio_flags);
                changed = spread;
            }
            _ if usable => self.forget_readings(&exposure),
            _ => {}
        }
        let b_hat = self.ratio.filter().mean().x;
        if changed {
            // The ratio filter was spread in b at an unchanged level: beta given the new b
            // starts from its old value, spread, and the reference restarts here.
            if !bridged_over {
                let rate = self.rate.filter();
                self.beta_before_change =
                    (rate.mean().x, rate.covariance().x.max(T::zero()).sqrt());
            }
            self.conditioned_b = None;
            self.intervals = 0;
            flags.insert(self.rate.declare_change(rng));
        } else if bridged_over {
            // The reading bridged over may mix the old and the new parameters: beta given b
            // restarts from before the change and the reference from here.
            let (mean, std) = self.beta_before_change;
            let spread = self.rate.config().spread_std.x;
            let std = (std * std + spread * spread).sqrt();
            if self
                .rate
                .filter_mut()
                .init_gaussian(&SVector::from([mean]), &SVector::from([std]), rng)
                .is_ok()
            {
                self.rate.reset_history();
                self.conditioned_b = None;
                self.intervals = 0;
            }
        }
        if usable && exposure.mean_inverse_temperature.finite() {
            self.intervals = self.intervals.saturating_add(1);
            let n: T = cast(f64::from(self.intervals));
            self.reference_inverse_temperature +=
                (exposure.mean_inverse_temperature - self.reference_inverse_temperature) / n;
        }
        self.condition_rate_on(b_hat);
        let u4 = SVector::<T, 4>::from([u.x, u.y, u.z, b_hat]);
        let model = LossRateModel {
            relative_noise: self.reading_variance.sqrt(),
        };
        if self
            .rate
            .step(&model, &u4, Some(&[consumption]), T::one(), T::zero(), rng)
            .is_err()
        {
            flags.insert(Flags::MEASUREMENT_REJECTED);
        }
        if !changed {
            // After a change `previous` stays: the next ratio bridges over this reading.
            self.previous = usable.then_some(consumption);
        }
        flags
    }

    /// Moves the rate filter's particles from `beta` given the previous `b` to `beta` given
    /// `b`, keeping the consumption at the reference temperature: Eq. 34's `beta` is
    /// conditional on `b`, and the two are strongly correlated through the levels
    /// (`ln beta = ln rate(T) + b / T`).
    fn condition_rate_on(&mut self, b: T) {
        if let Some(before) = self.conditioned_b {
            let factor = ((b - before) * self.reference_inverse_temperature).exp();
            let (lower, upper) = (cast::<T>(0.01), cast::<T>(100.0));
            if factor.finite() {
                for p in self.rate.filter_mut().particles_mut().iter_mut() {
                    p.x = (p.x * factor).max(lower).min(upper);
                }
            }
        }
        self.conditioned_b = Some(b);
    }

    /// Estimates `(b in degC, beta in mL/s)`.
    pub fn parameters(&self) -> (T, T) {
        (
            self.ratio.filter().mean().x,
            self.rate.filter().mean().x * cast(BETA_UNIT),
        )
    }

    /// Particle `i` as `(b in degC, beta in 1e-6 mL/s, weight)`: the two filters' particles
    /// paired by index (independent after resampling), weight the product of theirs; `beta`
    /// is moved to the paired `b` as in [`TwoStepLoss::condition_rate_on`].
    pub fn particle(&self, i: usize) -> Option<(T, T, T)> {
        Self::paired(self.current(), i)
    }

    /// All particles as [`TwoStepLoss::particle`].
    pub fn particles(&self) -> impl Iterator<Item = (T, T, T)> + '_ {
        (0..M).filter_map(|i| self.particle(i))
    }

    /// The particles to predict from: [`TwoStepLoss::particles`], except while a change
    /// declared at the last reading awaits the next one's verdict (change or outlier); then
    /// the particles from before that reading. The cloud in doubt is `b` spread by 10 degC
    /// and weighed by one ratio, the widest posterior the filter holds, while waiting one
    /// 4-minute interval costs a months-long prediction nothing.
    pub fn confirmed_particles(&self) -> impl Iterator<Item = (T, T, T)> + '_ {
        let state = if self.pending == Pending::Change {
            let before = &self.scalars_before;
            (
                &self.ratio_before,
                &self.rate_before,
                before.conditioned_b,
                before.reference_inverse_temperature,
            )
        } else {
            self.current()
        };
        (0..M).filter_map(move |i| Self::paired(state, i))
    }

    /// The filters, `conditioned_b` and reference `1/T` as they stand.
    fn current(&self) -> PairedState<'_, T, M> {
        (
            &self.ratio,
            &self.rate,
            self.conditioned_b,
            self.reference_inverse_temperature,
        )
    }

    fn paired(
        (ratio, rate, conditioned_b, reference): PairedState<'_, T, M>,
        i: usize,
    ) -> Option<(T, T, T)> {
        let b = ratio.filter().particles().get(i)?.x;
        let conditioned = conditioned_b.unwrap_or(b);
        let beta = rate.filter().particles().get(i)?.x * ((b - conditioned) * reference).exp();
        Some((b, beta, ratio.filter().weight(i) * rate.filter().weight(i)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand_core::SeedableRng;
    use rand_xoshiro::Xoshiro256PlusPlus;

    #[test]
    fn learns_b_and_beta_from_exact_intervals_and_rejects_bad_noise() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(9);
        let config = TwoStepConfig::new(0.01, (0.1, 0.01), (35.0, 8.0), (7.0, 1.5));
        let mut bad = config;
        bad.relative_noise = f64::NAN;
        assert!(TwoStepLoss::<f64, 200>::new(bad, &mut rng).is_err());
        let mut filter = TwoStepLoss::<f64, 200>::new(config, &mut rng).unwrap();
        let (b, beta) = (37.0, 7.494e-6);
        for k in 0..120 {
            let temp: f64 = 30.0 + 4.0 * (k as f64 * 0.26).sin();
            let e = IntervalExposure::constant(240.0, temp).unwrap();
            let flags = filter.update(e, e.consumption(b, beta), &mut rng);
            assert!(!flags.contains(Flags::MEASUREMENT_REJECTED));
        }
        let (b_hat, beta_hat) = filter.parameters();
        assert!((b_hat - b).abs() / b < 0.05, "b {b_hat}");
        assert!((beta_hat - beta).abs() / beta < 0.05, "beta {beta_hat}");
        let total: f64 = filter.particles().map(|p| p.2).sum();
        assert_eq!(filter.particles().count(), 200);
        assert!(total > 0.0 && total.is_finite());
    }

    /// A change in the last quarter of an interval: that reading mixes the old and the new
    /// parameters, and `b` and `beta` must still settle on the new values within 10 % from the
    /// third interval on. With exact readings the code before the bridging passes this too; the
    /// double declaration the bridging removes needs noisy temperatures and is checked on
    /// Table 6 runs (`reaction_wheel::tests::two_step_pf_stays_within_two_percent_on_table6_runs`
    /// in prognos-sim, seed 7011).
    #[test]
    fn recovers_from_a_change_inside_an_interval_without_overshoot() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(21);
        let config = TwoStepConfig::new(0.01, (0.05, 0.002), (35.0, 8.0), (7.0, 1.5));
        let mut filter = TwoStepLoss::<f64, 500>::new(config, &mut rng).unwrap();
        let (old, new) = ((37.0, 7.494e-6), (49.0, 7.0e-6));
        let exposure = |k: usize| {
            let temp: f64 = 30.0 + 4.0 * (k as f64 * 0.26).sin();
            IntervalExposure::constant(240.0, temp).unwrap()
        };
        let mut worst_b_after = 0.0f64;
        for k in 0..90 {
            let e = exposure(k);
            let y = match k {
                0..40 => e.consumption(old.0, old.1),
                40 => 0.75 * e.consumption(old.0, old.1) + 0.25 * e.consumption(new.0, new.1),
                _ => e.consumption(new.0, new.1),
            };
            let flags = filter.update(e, y, &mut rng);
            assert!(!flags.contains(Flags::MEASUREMENT_REJECTED));
            let (b, beta) = filter.parameters();
            assert!(b.is_finite() && beta.is_finite());
            if k == 39 {
                assert!((b - old.0).abs() / old.0 < 0.05, "b before the change {b}");
            }
            if k >= 43 {
                worst_b_after = worst_b_after.max((b - new.0).abs() / new.0);
            }
        }
        let (b, beta) = filter.parameters();
        assert!(
            worst_b_after < 0.1,
            "b after the change errs by up to {worst_b_after}"
        );
        assert!((b - new.0).abs() / new.0 < 0.03, "b {b}");
        assert!((beta - new.1).abs() / new.1 < 0.05, "beta {beta}");
    }

    /// Noisy readings, and every 25 intervals one interval's temperature wrong by 3 degC (a
    /// thermometer burst) while the consumption follows the true one. Each burst surprises
    /// the filter (or declares a change); the next ratio, bridging over that reading, must find
    /// no change, restore the filter and flag the reading, so that `b` and `beta` stay on the
    /// unchanged parameters: `b` ends at 36.81 for 37 and errs by 0.27 % on average from
    /// interval 100; without the restore it ends at 35.09 and errs by 5.2 %.
    #[test]
    fn wrong_interval_temperatures_are_rejected_as_outliers_not_changes() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(5);
        let config = TwoStepConfig::new(0.01, (0.05, 0.002), (35.0, 8.0), (7.0, 1.5));
        let mut filter = TwoStepLoss::<f64, 500>::new(config, &mut rng).unwrap();
        let (b, beta) = (37.0, 7.494e-6);
        let mut flagged = [false; 210];
        let (mut late_error, mut late) = (0.0, 0.0);
        for (k, flagged) in flagged.iter_mut().enumerate() {
            let temp: f64 = 30.0 + 4.0 * (k as f64 * 0.26).sin();
            let truth = IntervalExposure::constant(240.0, temp).unwrap();
            let error = if k % 25 == 24 { 3.0 } else { 0.0 };
            let measured = IntervalExposure::constant(240.0, temp + error).unwrap();
            let noise = 1.0 + 0.01 * crate::random::standard_normal::<f64, _>(&mut rng);
            let flags = filter.update(measured, truth.consumption(b, beta) * noise, &mut rng);
            *flagged = flags.contains(Flags::MEASUREMENT_REJECTED);
            if k >= 100 {
                late_error += (filter.parameters().0 - b).abs() / b;
                late += 1.0;
            }
        }
        let after_bursts = (0..210).filter(|k| k % 25 == 0 && *k > 0);
        let rejected = after_bursts.clone().filter(|k| flagged[*k]).count();
        assert_eq!(rejected, after_bursts.count(), "flagged {flagged:?}");
        let (b_hat, beta_hat) = filter.parameters();
        assert!((b_hat - b).abs() / b < 0.02, "b {b_hat}");
        assert!((beta_hat - beta).abs() / beta < 0.03, "beta {beta_hat}");
        let late_error = late_error / late;
        assert!(
            late_error < 0.02,
            "b errs by {late_error} on average from interval 100"
        );
    }

    /// As above, but the thermometer says how unsure it is: 3 degC std on the wrong intervals,
    /// 0.07 degC on the others (a burst that did not converge, as Table 6 runs show). The
    /// estimate of `b` must not move at a wrong interval, before the next ratio can judge it:
    /// by at most 0.3 % of `b` (0.075 % measured); told nothing, it moves by 4.6 %.
    #[test]
    fn a_reading_at_an_unsure_temperature_moves_b_little() {
        let run = |(unsure, usual): (f64, f64)| {
            let mut rng = Xoshiro256PlusPlus::seed_from_u64(5);
            let config = TwoStepConfig::new(0.01, (0.05, 0.002), (35.0, 8.0), (7.0, 1.5));
            let mut filter = TwoStepLoss::<f64, 500>::new(config, &mut rng).unwrap();
            let b = 37.0;
            let mut largest_move = 0.0f64;
            for k in 0..210 {
                let temp: f64 = 30.0 + 4.0 * (k as f64 * 0.26).sin();
                let truth = IntervalExposure::constant(240.0, temp).unwrap();
                let wrong = k % 25 == 24;
                let (error, std) = if wrong { (3.0, unsure) } else { (0.0, usual) };
                let measured = IntervalExposure::constant(240.0, temp + error).unwrap();
                let noise = 1.0 + 0.01 * crate::random::standard_normal::<f64, _>(&mut rng);
                let consumption = truth.consumption(b, 7.494e-6) * noise;
                let before = filter.parameters().0;
                filter.update_with_temperature_std(measured, consumption, std, &mut rng);
                if wrong {
                    largest_move = largest_move.max((filter.parameters().0 - before).abs() / b);
                }
            }
            largest_move
        };
        let (told, untold) = (run((3.0, 0.07)), run((0.0, 0.0)));
        assert!(told < 0.003, "told: b moves by {told} at a wrong interval");
        assert!(untold > 10.0 * told, "untold: {untold}, told: {told}");
        // A std that means nothing counts as zero.
        assert!(run((f64::NAN, -1.0)) == untold);
    }

    /// While a declared change awaits the next reading, predictions use the particles from
    /// before it; once the next reading has decided, the current ones.
    #[test]
    fn predictions_wait_for_a_declared_change_to_be_confirmed() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(21);
        let config = TwoStepConfig::new(0.01, (0.05, 0.002), (35.0, 8.0), (7.0, 1.5));
        let mut filter = TwoStepLoss::<f64, 200>::new(config, &mut rng).unwrap();
        let exposure = |k: usize| {
            let temp: f64 = 30.0 + 4.0 * (k as f64 * 0.26).sin();
            IntervalExposure::constant(240.0, temp).unwrap()
        };
        let mut declared = 0;
        for k in 0..60 {
            let mut before = [(0.0, 0.0, 0.0); 200];
            for (slot, p) in before.iter_mut().zip(filter.particles()) {
                *slot = p;
            }
            let e = exposure(k);
            let (b, beta) = if k < 40 {
                (37.0, 7.494e-6)
            } else {
                (49.0, 7.0e-6)
            };
            filter.update(e, e.consumption(b, beta), &mut rng);
            if filter.pending == Pending::Change {
                declared += 1;
                assert!(filter.confirmed_particles().eq(before.iter().copied()));
                assert!(!filter.particles().eq(before.iter().copied()));
            } else {
                assert!(filter.confirmed_particles().eq(filter.particles()));
            }
        }
        assert!(declared >= 1);
    }
}
