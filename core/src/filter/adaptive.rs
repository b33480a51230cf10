//! Adaptive resampling and adaptive sample improvement of Alidadi & Rahimi (2023), built on
//! the SIR filter of [`super::particle`] (its weights, resampling and roughening are reused).
//!
//! * **Adaptive resampling** (section 3.1.1): the largest single-particle likelihood
//!   `max_i p(y_k | x_k^i)` is averaged over the steps since the last resampling. When that
//!   mean falls below `p_eff` the particles are "confused" (none explains the data, e.g. after
//!   an abrupt change): the filter resamples and then spreads the particles wider
//!   (`spread_std`), instead of only duplicating them. Otherwise it resamples when the ESS is
//!   low, as a plain PF does.
//! * **Adaptive sample improvement** (section 3.1.2, Eqs. 19-20, 28): when the state hardly
//!   changes the measurement, the posterior weights are nearly uniform and resampling cannot
//!   narrow the interval. The normalised weight `w_i` is mutated through a logistic function
//!   of `beta_i = 1/N - w_i` with an input-dependent growth rate `c_1(u)` and an offset
//!   `c_2`:  `w_i <- 1 / (1 + exp(c_1 (N beta_i + c_2 sign(beta_i))))`, which is at most 1,
//!   above 1/2 for particles better than average and below 1/2 for worse ones, with a
//!   contrast of at least `exp(c_1 c_2)` between the two groups. It acts only when the
//!   update left the weights nearly uniform (`improvement_ess`): applied to an already
//!   informative likelihood it would flatten the weights instead. The printed Eq. 28 has the
//!   sign of the exponent reversed (it gives negative weights); see `docs/deviations.md`.
//!
//! The likelihood is taken as the model's `exp(log_likelihood)`, which for Gaussian sensors
//! (no normalising constant) lies in (0, 1], so `p_eff` is scale-free.

use super::particle::{ParticleFilter, PfConfig, PfReport};
use crate::error::Error;
use crate::model::Stochastic;
use crate::random::standard_normal;
use crate::real::{Real, cast, zero_vector};
use crate::safeguard::Flags;
use nalgebra::SVector;
use rand_core::Rng;

/// Which of the paper's three filters to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Method {
    /// Plain SIR: resample when the ESS is low.
    Plain,
    /// SIR with adaptive resampling (section 3.1.1).
    AdaptiveResampling,
    /// Adaptive resampling plus adaptive sample improvement: the paper's APF.
    Apf,
}

/// Settings of the adaptive layer.
#[derive(Clone, Copy, Debug)]
pub struct AdaptiveConfig<T: Real, const NX: usize> {
    /// Filter variant.
    pub method: Method,
    /// Resample when ESS < `ess_threshold * N`.
    pub ess_threshold: T,
    /// `p_eff`: threshold on the mean of `max_i p(y|x_i)` since the last resampling, in (0, 1).
    pub likelihood_threshold: T,
    /// Steps without resampling after which the mean is judged even if the ESS is fine.
    pub min_window: u32,
    /// Standard deviation of the Gaussian jitter added to each state entry when the particles
    /// are spread.
    pub spread_std: SVector<T, NX>,
    /// Offset `c_2` of the weight mutation (in units of the mean weight 1/N).
    pub improvement_offset: T,
    /// The mutation acts only when the update left the weights nearly uniform:
    /// ESS >= `improvement_ess * N` (section 3.1.2's case of a state that hardly changes the
    /// measurement). 0 mutates at every step.
    pub improvement_ess: T,
}

impl<T: Real, const NX: usize> AdaptiveConfig<T, NX> {
    /// All-zero settings of an [`AdaptiveFilter::UNSET`] placeholder.
    pub const UNSET: Self = Self {
        method: Method::Plain,
        ess_threshold: T::ZERO,
        likelihood_threshold: T::ZERO,
        min_window: 0,
        spread_std: zero_vector(),
        improvement_offset: T::ZERO,
        improvement_ess: T::ZERO,
    };

    fn validate(&self) -> Result<(), Error> {
        if !(self.ess_threshold >= T::zero() && self.ess_threshold <= T::one()) {
            return Err(Error::InvalidParameter("ess_threshold"));
        }
        if !(self.likelihood_threshold >= T::zero() && self.likelihood_threshold < T::one()) {
            return Err(Error::InvalidParameter("likelihood_threshold"));
        }
        if !self
            .spread_std
            .iter()
            .all(|s| s.finite() && *s >= T::zero())
        {
            return Err(Error::InvalidParameter("spread_std"));
        }
        if !(self.improvement_offset.finite() && self.improvement_offset >= T::zero()) {
            return Err(Error::InvalidParameter("improvement_offset"));
        }
        if !(self.improvement_ess >= T::zero() && self.improvement_ess <= T::one()) {
            return Err(Error::InvalidParameter("improvement_ess"));
        }
        Ok(())
    }
}

/// What one adaptive step did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AdaptiveReport<T> {
    /// The underlying filter's report (ESS before resampling, evidence, flags).
    pub filter: PfReport<T>,
    /// The particles were resampled and spread (confusion detected).
    pub spread: bool,
    /// The weights were mutated by the sample-improvement step.
    pub improved: bool,
}

/// A particle filter with the paper's adaptive resampling and sample improvement.
#[derive(Clone, Debug)]
pub struct AdaptiveFilter<T: Real, const NX: usize, const N: usize> {
    filter: ParticleFilter<T, NX, N>,
    config: AdaptiveConfig<T, NX>,
    likelihood_sum: T,
    likelihood_count: u32,
}

impl<T: Real, const NX: usize, const N: usize> AdaptiveFilter<T, NX, N> {
    /// An all-zero placeholder for static storage (see [`ParticleFilter::UNSET`]):
    /// [`AdaptiveFilter::reset`] it in place before use.
    pub const UNSET: Self = Self {
        filter: ParticleFilter::UNSET,
        config: AdaptiveConfig::UNSET,
        likelihood_sum: T::ZERO,
        likelihood_count: 0,
    };

    /// Wraps `filter`; its own ESS-triggered resampling is switched off (this layer decides
    /// when to resample), its resampling scheme, roughening, walks and bounds are kept.
    pub fn new(
        mut filter: ParticleFilter<T, NX, N>,
        config: AdaptiveConfig<T, NX>,
    ) -> Result<Self, Error> {
        config.validate()?;
        let mut pf_config = *filter.config();
        pf_config.resample_threshold = T::zero();
        filter.set_config(pf_config)?;
        Ok(Self {
            filter,
            config,
            likelihood_sum: T::zero(),
            likelihood_count: 0,
        })
    }

    /// Re-initialises in place what [`AdaptiveFilter::new`] would build from
    /// `ParticleFilter::new(x0, filter_config)` and `config`. Bad settings are an error and
    /// change nothing.
    pub fn reset(
        &mut self,
        x0: SVector<T, NX>,
        mut filter_config: PfConfig<T, NX>,
        config: AdaptiveConfig<T, NX>,
    ) -> Result<(), Error> {
        config.validate()?;
        filter_config.resample_threshold = T::zero();
        self.filter.reset(x0, filter_config)?;
        self.config = config;
        self.likelihood_sum = T::zero();
        self.likelihood_count = 0;
        Ok(())
    }

    /// The underlying particle filter (particles, weights, summaries).
    pub fn filter(&self) -> &ParticleFilter<T, NX, N> {
        &self.filter
    }

    /// Mutable access to the underlying filter (re-initialisation between bursts).
    pub fn filter_mut(&mut self) -> &mut ParticleFilter<T, NX, N> {
        &mut self.filter
    }

    /// The adaptive settings.
    pub fn config(&self) -> &AdaptiveConfig<T, NX> {
        &self.config
    }

    /// Copies `other`'s whole state into `self` in place (see
    /// [`ParticleFilter::copy_state_from`]).
    pub fn copy_state_from(&mut self, other: &Self) {
        self.filter.copy_state_from(&other.filter);
        self.config = other.config;
        self.likelihood_sum = other.likelihood_sum;
        self.likelihood_count = other.likelihood_count;
    }

    /// Forgets the likelihood history (call after re-initialising the particles).
    pub fn reset_history(&mut self) {
        self.likelihood_sum = T::zero();
        self.likelihood_count = 0;
    }

    /// One step: predict, update with `y` (`None`: predict-only), then the adaptive layer.
    /// `improvement_gain` is `c_1(u_k)` for the sample improvement (ignored unless the method
    /// is [`Method::Apf`]; must be finite and non-negative). Errors leave the filter unchanged.
    pub fn step<M, R, const NU: usize>(
        &mut self,
        model: &M,
        u: &SVector<T, NU>,
        y: Option<&[T]>,
        dt: T,
        improvement_gain: T,
        rng: &mut R,
    ) -> Result<AdaptiveReport<T>, Error>
    where
        M: Stochastic<T, NX, NU>,
        R: Rng + ?Sized,
    {
        if !(improvement_gain.finite() && improvement_gain >= T::zero()) {
            return Err(Error::InvalidParameter("improvement_gain"));
        }
        let report = self.filter.step(model, u, y, dt, rng)?;
        let mut out = AdaptiveReport {
            filter: report,
            spread: false,
            improved: false,
        };
        if !report.fused {
            return Ok(out);
        }
        let adaptive = self.config.method != Method::Plain;
        if adaptive {
            let max_likelihood = report.max_log_likelihood.min(T::zero()).exp();
            self.likelihood_sum += max_likelihood;
            self.likelihood_count = self.likelihood_count.saturating_add(1);
        }
        let n: T = cast(N as f64);
        if self.config.method == Method::Apf
            && improvement_gain > T::zero()
            && self.filter.ess() >= self.config.improvement_ess * n
        {
            out.improved = self.improve(improvement_gain);
        }
        let ess_low = self.filter.ess() < self.config.ess_threshold * n;
        // The mean is judged at every ESS-triggered resampling, and also when a long window
        // without resampling has gone by.
        let confused = adaptive
            && (ess_low || self.likelihood_count >= self.config.min_window.max(1))
            && self.likelihood_sum / cast(f64::from(self.likelihood_count.max(1)))
                < self.config.likelihood_threshold;
        if confused || ess_low {
            out.filter.flags.insert(self.filter.resample(rng));
            if confused {
                self.spread(rng);
                out.spread = true;
            }
            self.reset_history();
        }
        Ok(out)
    }

    /// Treats the particles as confused now (a change known from elsewhere): resamples,
    /// spreads them by `spread_std` and forgets the likelihood history.
    pub fn declare_change<R: Rng + ?Sized>(&mut self, rng: &mut R) -> Flags {
        let flags = self.filter.resample(rng);
        self.spread(rng);
        self.reset_history();
        flags
    }

    /// The logistic weight mutation (Eq. 20 as read in the module docs).
    fn improve(&mut self, gain: T) -> bool {
        let n: T = cast(N as f64);
        let offset = self.config.improvement_offset;
        self.filter.reweight(|_, log_weight| {
            // N beta = 1 - N w: negative for particles better than average.
            let n_beta = T::one() - n * log_weight.exp();
            let shifted = if n_beta > T::zero() {
                n_beta + offset
            } else if n_beta < T::zero() {
                n_beta - offset
            } else {
                n_beta
            };
            // ln(1 / (1 + e^z)) computed without overflow.
            let z = gain * shifted;
            let softplus = z.max(T::zero()) + (T::one() + (-z.abs()).exp()).ln();
            -softplus
        })
    }

    /// Gaussian jitter of `spread_std` on every particle, clamped to the filter's bounds.
    fn spread<R: Rng + ?Sized>(&mut self, rng: &mut R) {
        let config = *self.filter.config();
        let std = self.config.spread_std;
        for p in self.filter.particles_mut().iter_mut() {
            for (((x, s), lo), hi) in p
                .iter_mut()
                .zip(std.iter())
                .zip(config.lower.iter())
                .zip(config.upper.iter())
            {
                if *s > T::zero() {
                    *x += *s * standard_normal::<T, R>(rng);
                    if *x < *lo {
                        *x = *lo;
                    } else if *x > *hi {
                        *x = *hi;
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filter::particle::PfConfig;
    use crate::model::{Model, gaussian_log_likelihood};
    use nalgebra::{SVector, Vector1};
    use rand_core::SeedableRng;
    use rand_xoshiro::Xoshiro256PlusPlus;

    /// A constant observed directly with unit noise, with a random-walk state.
    struct Constant;
    impl Model<f64, 1, 1> for Constant {
        fn step(&self, x: &Vector1<f64>, _u: &Vector1<f64>, _dt: f64) -> Vector1<f64> {
            *x
        }
    }
    impl Stochastic<f64, 1, 1> for Constant {
        fn measurement_len(&self) -> usize {
            1
        }
        fn log_likelihood(&self, x: &Vector1<f64>, _u: &Vector1<f64>, y: &[f64]) -> f64 {
            gaussian_log_likelihood(y, &[x.x], &[0.2])
        }
    }

    fn make(method: Method) -> AdaptiveFilter<f64, 1, 200> {
        let cfg = PfConfig {
            random_walk_std: SVector::from([0.02]),
            ..PfConfig::default()
        };
        let pf = ParticleFilter::<f64, 1, 200>::new(SVector::from([0.0]), cfg).unwrap();
        AdaptiveFilter::new(
            pf,
            AdaptiveConfig {
                method,
                ess_threshold: 0.5,
                likelihood_threshold: 0.05,
                min_window: 5,
                spread_std: SVector::from([3.0]),
                improvement_offset: 0.6,
                improvement_ess: 0.0,
            },
        )
        .unwrap()
    }

    /// Steps after a jump of the true value from 0 to 10 until the estimate is within 0.5.
    fn recovery_steps(method: Method) -> usize {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(11);
        let mut f = make(method);
        let u = Vector1::new(0.0);
        for _ in 0..50 {
            f.step(&Constant, &u, Some(&[0.0]), 1.0, 0.0, &mut rng)
                .unwrap();
        }
        for k in 0..2000 {
            f.step(&Constant, &u, Some(&[10.0]), 1.0, 0.0, &mut rng)
                .unwrap();
            if (f.filter().mean().x - 10.0).abs() < 0.5 {
                return k;
            }
        }
        2000
    }

    #[test]
    fn adaptive_resampling_recovers_from_a_jump_much_faster() {
        let plain = recovery_steps(Method::Plain);
        let adaptive = recovery_steps(Method::AdaptiveResampling);
        assert!(adaptive < 30, "adaptive {adaptive}");
        assert!(plain > 5 * adaptive, "plain {plain} adaptive {adaptive}");
    }

    #[test]
    fn sample_improvement_sharpens_nearly_uniform_weights() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(5);
        let mut f = make(Method::Apf);
        f.filter_mut()
            .init_gaussian(&SVector::from([0.0]), &SVector::from([0.01]), &mut rng)
            .unwrap();
        // Measurement far less informative than the spread: weights almost uniform.
        let before: f64 = {
            let mut g = f.clone();
            g.filter
                .update(&Constant, &Vector1::new(0.0), &[0.5], &mut rng)
                .unwrap();
            g.filter.ess()
        };
        let mut g = f.clone();
        g.filter
            .update(&Constant, &Vector1::new(0.0), &[0.5], &mut rng)
            .unwrap();
        assert!(g.improve(2.0));
        let after = g.filter.ess();
        assert!(before > 190.0, "{before}");
        assert!(after < 0.9 * before, "{after} vs {before}");
        // The better half (closer to 0.5, i.e. larger x) gained weight: the mean moved up.
        assert!(g.filter.mean().x > f.filter.mean().x);
        // Total weight stays normalised.
        let total: f64 = (0..200).map(|i| g.filter.weight(i)).sum();
        assert!((total - 1.0).abs() < 1e-12);
    }

    #[test]
    fn bad_input_leaves_filter_unchanged() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(1);
        let mut f = make(Method::Apf);
        let before = f.filter().mean();
        let u = Vector1::new(0.0);
        assert!(
            f.step(&Constant, &u, Some(&[f64::NAN]), 1.0, 1.0, &mut rng)
                .is_err()
        );
        assert!(
            f.step(&Constant, &u, Some(&[0.0]), 1.0, f64::NAN, &mut rng)
                .is_err()
        );
        assert!(
            f.step(&Constant, &u, Some(&[0.0]), -1.0, 1.0, &mut rng)
                .is_err()
        );
        assert_eq!(f.filter().mean(), before);
        let r = f.step(&Constant, &u, None, 1.0, 1.0, &mut rng).unwrap();
        assert!(!r.filter.fused && f.filter().mean().x.is_finite());
    }
}
