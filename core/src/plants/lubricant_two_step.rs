//! The paper's two-step particle filter of the lubricant-loss parameters (Eqs. 31-34): a PF of
//! `b` on the ratio of consecutive interval consumptions (which does not depend on `beta`),
//! then a PF of `beta` on the interval consumption given the first filter's `b`.
//!
//! One implementation for the on-board pipeline (`pipeline::ReactionWheel`) and the host's
//! Table 6/7 reproductions. Both filters use the adaptive resampling of section 3.1.1.

use super::reaction_wheel::{BETA_UNIT, IntervalExposure, LossRateModel, LossRatioModel};
use crate::Error;
use crate::filter::adaptive::{AdaptiveConfig, AdaptiveFilter, Method};
use crate::filter::particle::PfConfig;
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
}

impl<T: Real> TwoStepConfig<T> {
    /// All zeros: the configuration of [`TwoStepLoss::UNSET`].
    pub const UNSET: Self = Self {
        relative_noise: T::ZERO,
        walk: (T::ZERO, T::ZERO),
        prior_b: (T::ZERO, T::ZERO),
        prior_beta: (T::ZERO, T::ZERO),
    };
}

fn loss_config<T: Real>(walk: T, lower: T, upper: T) -> PfConfig<T, 1> {
    PfConfig {
        random_walk_std: SVector::from([walk]),
        lower: SVector::from([lower]),
        upper: SVector::from([upper]),
        ..PfConfig::default()
    }
}

/// Adaptive resampling with a spread of `spread` when the filter is confused (a change).
fn loss_adaptive<T: Real>(spread: T) -> AdaptiveConfig<T, 1> {
    AdaptiveConfig {
        method: Method::AdaptiveResampling,
        ess_threshold: cast(0.5),
        likelihood_threshold: cast(0.05),
        min_window: 3,
        spread_std: SVector::from([spread]),
        improvement_offset: T::zero(),
        improvement_ess: T::one(),
    }
}

/// The two-step PF with `M` particles per filter.
#[derive(Clone, Debug)]
pub struct TwoStepLoss<T: Real, const M: usize> {
    relative_noise: T,
    ratio: AdaptiveFilter<T, 1, M>,
    rate: AdaptiveFilter<T, 1, M>,
    previous: Option<(IntervalExposure<T>, T)>,
}

impl<T: Real, const M: usize> TwoStepLoss<T, M> {
    /// An all-zero placeholder for static storage: [`TwoStepLoss::reset`] it before use.
    pub const UNSET: Self = Self {
        relative_noise: T::ZERO,
        ratio: AdaptiveFilter::UNSET,
        rate: AdaptiveFilter::UNSET,
        previous: None,
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
        let (b0, bs) = config.prior_b;
        let (beta0, betas) = config.prior_beta;
        self.ratio.reset(
            SVector::from([b0]),
            loss_config(config.walk.0, T::zero(), cast(150.0)),
            loss_adaptive(cast(4.0)),
        )?;
        self.ratio
            .filter_mut()
            .init_gaussian(&SVector::from([b0]), &SVector::from([bs]), rng)?;
        self.rate.reset(
            SVector::from([beta0]),
            loss_config(config.walk.1, cast(0.01), cast(100.0)),
            loss_adaptive(cast(0.4)),
        )?;
        self.rate.filter_mut().init_gaussian(
            &SVector::from([beta0]),
            &SVector::from([betas]),
            rng,
        )?;
        self.relative_noise = config.relative_noise;
        self.previous = None;
        Ok(())
    }

    /// One interval: its temperature exposure and measured consumption (mL). A rejected
    /// update leaves that filter unchanged and is flagged; the next interval retries.
    pub fn update<R: Rng + ?Sized>(
        &mut self,
        exposure: IntervalExposure<T>,
        consumption: T,
        rng: &mut R,
    ) -> Flags {
        let mut flags = Flags::NONE;
        let noise = self.relative_noise;
        let one = T::one();
        let u = exposure.as_input();
        if let Some((before, previous_consumption)) = self.previous {
            let bu = before.as_input();
            let u6 = SVector::<T, 6>::from([u.x, u.y, u.z, bu.x, bu.y, bu.z]);
            let ratio = consumption / previous_consumption;
            let model = LossRatioModel {
                relative_noise: noise,
            };
            if self
                .ratio
                .step(&model, &u6, Some(&[ratio]), one, T::zero(), rng)
                .is_err()
            {
                flags.insert(Flags::MEASUREMENT_REJECTED);
            }
        }
        let b_hat = self.ratio.filter().mean().x;
        let u4 = SVector::<T, 4>::from([u.x, u.y, u.z, b_hat]);
        let model = LossRateModel {
            relative_noise: noise,
        };
        if self
            .rate
            .step(&model, &u4, Some(&[consumption]), one, T::zero(), rng)
            .is_err()
        {
            flags.insert(Flags::MEASUREMENT_REJECTED);
        }
        self.previous = Some((exposure, consumption));
        flags
    }

    /// Estimates `(b in degC, beta in mL/s)`.
    pub fn parameters(&self) -> (T, T) {
        (
            self.ratio.filter().mean().x,
            self.rate.filter().mean().x * cast(BETA_UNIT),
        )
    }

    /// Particle `i` as `(b in degC, beta in 1e-6 mL/s, weight)`: the two filters' particles
    /// paired by index (independent after resampling), weight the product of theirs.
    pub fn particle(&self, i: usize) -> Option<(T, T, T)> {
        let b = self.ratio.filter().particles().get(i)?.x;
        let beta = self.rate.filter().particles().get(i)?.x;
        Some((
            b,
            beta,
            self.ratio.filter().weight(i) * self.rate.filter().weight(i),
        ))
    }

    /// All particles as [`TwoStepLoss::particle`].
    pub fn particles(&self) -> impl Iterator<Item = (T, T, T)> + '_ {
        (0..M).filter_map(|i| self.particle(i))
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
        let config = TwoStepConfig {
            relative_noise: 0.01,
            walk: (0.1, 0.01),
            prior_b: (35.0, 8.0),
            prior_beta: (7.0, 1.5),
        };
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
}
