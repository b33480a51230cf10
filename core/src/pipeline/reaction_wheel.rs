//! Reaction-wheel prognoser (Alidadi & Rahimi 2023): APF lubricant temperature at the wheel's
//! sample rate -> interval exposure -> two-step PF for the lubricant-loss parameters -> RUL.
//! Beside the paper's two-step PF, every interval also updates the log-linear Kalman filter of
//! `plants::lubricant_kalman` (ours: exact for the loss model, a few hundred flops per
//! interval); [`ReactionWheel::rul_kalman`] predicts from its posterior.
//!
//! One [`ReactionWheel::step`] per sample with the command voltage and the measurement
//! `[I_m, omega_m]` or, at the end of a consumption interval, `[I_m, omega_m, X]` where `X` is
//! the cumulative lubricant-consumption reading (mL). `None` is a missing sample: the filter
//! predicts only (documented predict-only step). Bad data returns an error and changes nothing.
//!
//! Size: the step-1 filter holds `N` 3-state particles and the two loss filters `M` scalar
//! particles each; `N = 100, M = 200` in f32 is about 9 KiB.

use crate::error::Error;
use crate::filter::adaptive::{AdaptiveConfig, AdaptiveFilter, Method};
use crate::filter::particle::{PfConfig, PfReport};
use crate::plants::lubricant_kalman::{LossKalman, LossKalmanConfig};
use crate::plants::lubricant_two_step::{TwoStepConfig, TwoStepLoss};
use crate::plants::reaction_wheel::{
    BETA_UNIT, ExposureAccumulator, IntervalExposure, LossAccumulationModel, WheelTemperatureModel,
};
use crate::prognose::eol::{EndOfLife, PredictionSettings, predict_eol, rul_distribution};
use crate::real::{Real, cast};
use crate::safeguard::Flags;
use crate::stats::Summary;
use nalgebra::{SVector, Vector2, Vector3};
use rand_core::Rng;

/// Settings of the whole pipeline.
#[derive(Clone, Copy, Debug)]
pub struct ReactionWheelConfig<T: Real> {
    /// Step-1 estimation model (sensor noise, process noise).
    pub wheel_model: WheelTemperatureModel<T>,
    /// Step-1 adaptive layer (method, thresholds, spreads).
    pub temperature_filter: AdaptiveConfig<T, 3>,
    /// Prior mean and std of the lubricant temperature (degC).
    pub prior_temperature: (T, T),
    /// `c_1` at 1 V of the sample improvement; `c_1(V) = gain 10^(1 - V)`.
    pub improvement_gain: T,
    /// Relative noise of a consumption reading difference.
    pub loss_relative_noise: T,
    /// Random walk per interval of b (degC) and beta (1e-6 mL/s).
    pub loss_walk: (T, T),
    /// Priors (mean, std) of b and beta (1e-6 mL/s).
    pub prior_b: (T, T),
    /// Prior of beta.
    pub prior_beta: (T, T),
    /// Log-linear Kalman filter of the loss parameters (ours).
    pub loss_kalman: LossKalmanConfig<T>,
}

impl<T: Real> ReactionWheelConfig<T> {
    /// All zeros: the configuration of [`ReactionWheel::UNSET`] (not a usable one).
    pub const UNSET: Self = Self {
        wheel_model: WheelTemperatureModel::UNSET,
        temperature_filter: AdaptiveConfig::UNSET,
        prior_temperature: (T::ZERO, T::ZERO),
        improvement_gain: T::ZERO,
        loss_relative_noise: T::ZERO,
        loss_walk: (T::ZERO, T::ZERO),
        prior_b: (T::ZERO, T::ZERO),
        prior_beta: (T::ZERO, T::ZERO),
        loss_kalman: LossKalmanConfig::UNSET,
    };

    /// The settings used for the paper's scenarios, for given sensor noise.
    pub fn new(current_std: T, speed_std: T) -> Result<Self, Error> {
        let mut wheel_model = WheelTemperatureModel::new(current_std, speed_std)?;
        wheel_model.temperature_walk = cast(0.05);
        wheel_model.speed_process_std = cast(2e-4);
        Ok(Self {
            wheel_model,
            temperature_filter: AdaptiveConfig {
                method: Method::Apf,
                ess_threshold: cast(0.5),
                likelihood_threshold: cast(0.1),
                min_window: 20,
                spread_std: Vector3::new(T::zero(), cast(0.01), cast(3.0)),
                improvement_offset: cast(0.6),
                improvement_ess: cast(0.9),
            },
            prior_temperature: (cast(25.0), cast(4.0)),
            improvement_gain: T::one(),
            loss_relative_noise: cast(0.0025),
            loss_walk: (cast(0.1), cast(0.01)),
            prior_b: (cast(35.0), cast(8.0)),
            prior_beta: (cast(7.0), cast(1.5)),
            // The interval mean of 20 Hz temperature estimates errs by a few hundredths.
            loss_kalman: LossKalmanConfig::new(cast(0.0025), cast(0.05))?,
        })
    }
}

/// What one pipeline step reports.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ReactionWheelReport<T> {
    /// Lubricant temperature estimate (degC) and its posterior standard deviation.
    pub temperature: T,
    /// Posterior standard deviation of the temperature (degC).
    pub temperature_std: T,
    /// The sample was missing: the temperature filter only predicted.
    pub predict_only: bool,
    /// The wheel measurement reweighted the temperature particles (false when missing or
    /// when every particle's likelihood collapsed: see `flags`).
    pub fused: bool,
    /// Log evidence of the wheel measurement under the temperature filter (if not
    /// fused: the lowest value): the filter's test statistic for outliers.
    pub log_evidence: T,
    /// A consumption interval was closed and the loss filters updated.
    pub interval_closed: bool,
    /// Two-step estimate of b (degC).
    pub b: T,
    /// Two-step estimate of beta (mL/s).
    pub beta: T,
    /// Log-linear Kalman filter estimate of b (degC).
    pub kalman_b: T,
    /// Log-linear Kalman filter estimate of beta (mL/s).
    pub kalman_beta: T,
    /// Safeguards that acted.
    pub flags: Flags,
}

/// The reaction-wheel prognoser with `N` temperature particles and `M` loss-parameter
/// particles per loss filter.
#[derive(Clone, Debug)]
pub struct ReactionWheel<T: Real, const N: usize, const M: usize> {
    config: ReactionWheelConfig<T>,
    temperature: AdaptiveFilter<T, 3, N>,
    two_step: TwoStepLoss<T, M>,
    kalman: LossKalman<T>,
    exposure: ExposureAccumulator<T>,
    last_reading: Option<T>,
    last: Option<(T, T)>,
    /// False in [`ReactionWheel::UNSET`] and after a failed [`ReactionWheel::reset`].
    configured: bool,
}

/// End of life: cumulative consumption reaches the threshold.
struct ConsumptionThreshold<T>(T);

impl<T: Real> EndOfLife<T, 3> for ConsumptionThreshold<T> {
    fn reached(&self, x: &Vector3<T>) -> bool {
        x.x >= self.0
    }
}

impl<T: Real, const N: usize, const M: usize> ReactionWheel<T, N, M> {
    /// An unset placeholder, all zeros, built at compile time: a `static` holding it lives
    /// in `.bss`, and [`ReactionWheel::reset`] configures it in place, so that the filters
    /// never pass through the stack (firmware start-up). Every step before that is an
    /// [`Error::NotConfigured`].
    pub const UNSET: Self = Self {
        config: ReactionWheelConfig::UNSET,
        temperature: AdaptiveFilter::UNSET,
        two_step: TwoStepLoss::UNSET,
        kalman: LossKalman::UNSET,
        exposure: ExposureAccumulator::EMPTY,
        last_reading: None,
        last: None,
        configured: false,
    };

    /// A prognoser with particles drawn from the priors.
    pub fn new<R: Rng + ?Sized>(
        config: ReactionWheelConfig<T>,
        rng: &mut R,
    ) -> Result<Self, Error> {
        let mut pipeline = Self::UNSET;
        pipeline.reset(config, rng)?;
        Ok(pipeline)
    }

    /// Re-initialises the prognoser in place to what [`ReactionWheel::new`] builds (the same
    /// random draws). On an error the pipeline is left unset ([`Error::NotConfigured`] until
    /// a successful reset).
    pub fn reset<R: Rng + ?Sized>(
        &mut self,
        config: ReactionWheelConfig<T>,
        rng: &mut R,
    ) -> Result<(), Error> {
        self.configured = false;
        let (b0, bs) = config.prior_b;
        let (beta0, betas) = config.prior_beta;
        let beta_unit: T = cast(BETA_UNIT);
        self.kalman = LossKalman::new(
            config.loss_kalman,
            b0,
            bs,
            beta0 * beta_unit,
            if beta0 > T::zero() {
                betas / beta0
            } else {
                T::zero()
            },
        )?;
        self.temperature.reset(
            Vector3::zeros(),
            PfConfig {
                lower: Vector3::new(cast(-5.0), cast(-1000.0), cast(-40.0)),
                upper: Vector3::new(cast(5.0), cast(1000.0), cast(150.0)),
                ..PfConfig::default()
            },
            config.temperature_filter,
        )?;
        self.two_step.reset(
            TwoStepConfig::new(
                config.loss_relative_noise,
                config.loss_walk,
                config.prior_b,
                config.prior_beta,
            ),
            rng,
        )?;
        self.config = config;
        self.exposure = ExposureAccumulator::EMPTY;
        self.last_reading = None;
        self.last = None;
        self.configured = true;
        Ok(())
    }

    /// Mean and variance of the temperature particles (degC, degC^2).
    fn temperature_moments(&self) -> (T, T) {
        self.temperature
            .filter()
            .moments_of(2)
            .unwrap_or((T::zero(), T::zero()))
    }

    /// The report, with the temperature's `(mean, variance)` as the step computed them.
    fn report(
        &self,
        (temperature, var): (T, T),
        predict_only: bool,
        interval_closed: bool,
        flags: Flags,
        filter: Option<&PfReport<T>>,
    ) -> ReactionWheelReport<T> {
        let (b, beta) = self.loss_parameters();
        let (kalman_b, kalman_beta) = self.kalman.parameters();
        ReactionWheelReport {
            temperature,
            temperature_std: if var > T::zero() {
                var.sqrt()
            } else {
                T::zero()
            },
            predict_only,
            fused: filter.is_some_and(|r| r.fused),
            log_evidence: filter
                .map_or(T::min_value().unwrap_or(-T::MAX_FINITE), |r| r.log_evidence),
            interval_closed,
            b,
            beta,
            kalman_b,
            kalman_beta,
            flags,
        }
    }

    /// The log-linear Kalman filter of the loss parameters.
    pub fn loss_kalman(&self) -> &LossKalman<T> {
        &self.kalman
    }

    /// Two-step estimates `(b in degC, beta in mL/s)`.
    pub fn loss_parameters(&self) -> (T, T) {
        self.two_step.parameters()
    }

    /// The step-1 filter (particles, summaries).
    pub fn temperature_filter(&self) -> &AdaptiveFilter<T, 3, N> {
        &self.temperature
    }

    /// One sample at time `t` (s) with command `command_v` (0-5 V) and measurement `y`:
    /// `[I_m, omega_m]`, `[I_m, omega_m, X]` (X: cumulative consumption reading, mL, closes
    /// the interval since the previous reading) or `None` (missing sample: predict-only).
    /// Times must increase. Errors leave the pipeline unchanged.
    pub fn step<R: Rng + ?Sized>(
        &mut self,
        t: T,
        command_v: T,
        y: Option<&[T]>,
        rng: &mut R,
    ) -> Result<ReactionWheelReport<T>, Error> {
        if !self.configured {
            return Err(Error::NotConfigured);
        }
        if !t.finite() {
            return Err(Error::InvalidTimeStep);
        }
        WheelTemperatureModel::<T>::check_input(&Vector2::new(command_v, t))?;
        let reading = match y {
            Some(y) => {
                if y.len() != 2 && y.len() != 3 {
                    return Err(Error::MeasurementLength {
                        expected: 2,
                        got: y.len(),
                    });
                }
                let wheel = y.get(..2).ok_or(Error::InsufficientData)?;
                WheelTemperatureModel::<T>::check_measurement(wheel)?;
                match y.get(2) {
                    Some(&x) => {
                        let floor = self.last_reading.unwrap_or_else(T::zero);
                        if !x.finite() {
                            return Err(Error::NonFiniteMeasurement);
                        }
                        if x < floor {
                            return Err(Error::OutOfRange("cumulative consumption"));
                        }
                        Some(x)
                    }
                    None => None,
                }
            }
            None => None,
        };
        let Some((t_prev, command_prev)) = self.last else {
            // First sample: initialise the wheel particles on it.
            let Some(y) = y else {
                return Err(Error::InsufficientData);
            };
            let speed = y.get(1).copied().ok_or(Error::InsufficientData)?;
            let (m, s) = self.config.prior_temperature;
            let current = self.config.wheel_model.wheel.drive_gain * command_v;
            self.temperature.filter_mut().init_gaussian(
                &Vector3::new(current, speed, m),
                &Vector3::new(cast(1e-3), self.config.wheel_model.speed_sensor_std, s),
                rng,
            )?;
            self.last = Some((t, command_v));
            self.last_reading = reading;
            let moments = self.temperature_moments();
            return Ok(self.report(moments, false, false, Flags::NONE, None));
        };
        let dt = t - t_prev;
        if !(dt > T::zero()) {
            return Err(Error::InvalidTimeStep);
        }
        let u = Vector2::new(command_prev, t_prev);
        let gain = self.config.improvement_gain * cast::<T>(10.0).powf(T::one() - command_prev);
        let wheel_y = y.and_then(|y| y.get(..2));
        let r = self
            .temperature
            .step(&self.config.wheel_model, &u, wheel_y, dt, gain, rng)?;
        let mut flags = r.filter.flags;
        // The exposure rejects a non-positive temperature estimate (possible only below
        // 0 degC); such a sample is left out of the interval and flagged.
        let moments = self.temperature_moments();
        let (t_hat, t_variance) = moments;
        if self.exposure.push_estimate(t_hat, t_variance, dt).is_err() {
            flags.insert(Flags::MEASUREMENT_REJECTED);
        }
        let mut closed = false;
        if let Some(x) = reading {
            if let Some(previous) = self.last_reading {
                let consumption = x - previous;
                let temperature_std = self.exposure.estimate_std();
                if consumption > T::zero()
                    && let Ok(exposure) = self.exposure.take()
                {
                    flags.insert(self.update_loss(exposure, consumption, temperature_std, rng));
                    closed = true;
                }
            } else {
                self.exposure = ExposureAccumulator::default();
            }
            self.last_reading = Some(x);
        }
        self.last = Some((t, command_v));
        Ok(self.report(moments, wheel_y.is_none(), closed, flags, Some(&r.filter)))
    }

    fn update_loss<R: Rng + ?Sized>(
        &mut self,
        exposure: IntervalExposure<T>,
        consumption: T,
        temperature_std: T,
        rng: &mut R,
    ) -> Flags {
        let mut flags = Flags::NONE;
        match self.kalman.update(&exposure, consumption) {
            Ok(report) => flags.insert(report.flags),
            Err(_) => flags.insert(Flags::MEASUREMENT_REJECTED),
        }
        flags.insert(self.two_step.update_with_temperature_std(
            exposure,
            consumption,
            temperature_std,
            rng,
        ));
        flags
    }

    /// RUL distribution (s): time until the cumulative consumption reaches `threshold` (mL)
    /// from the last reading, with the future lubricant temperature `future_temperature(k)`
    /// for prediction step `k` of length `step_s`, over at most `max_steps` steps. Uses the
    /// two-step posterior (b and beta particles paired by index after resampling), as it was
    /// before a change still in doubt ([`TwoStepLoss::confirmed_particles`]).
    #[allow(clippy::too_many_arguments)]
    pub fn rul<R: Rng + ?Sized>(
        &self,
        threshold: T,
        future_temperature: impl FnMut(u32) -> T,
        step_s: T,
        max_steps: u32,
        states: &mut [Vector3<T>; M],
        times: &mut [T; M],
        buf: &mut [(T, T); M],
        rng: &mut R,
    ) -> Result<Summary<T>, Error> {
        let x0 = self.last_reading.ok_or(Error::InsufficientData)?;
        let mut weights = [T::zero(); M];
        for ((s, w), (b, beta, weight)) in states
            .iter_mut()
            .zip(weights.iter_mut())
            .zip(self.two_step.confirmed_particles())
        {
            *s = Vector3::new(x0, b, beta);
            *w = weight;
        }
        Self::rul_of_states(
            threshold,
            future_temperature,
            (step_s, max_steps),
            states,
            &weights,
            times,
            buf,
            rng,
        )
    }

    /// Propagates `states` (`[X, b, beta]`) to the consumption threshold and summarises the
    /// weighted end-of-life times: the part [`Self::rul`] and [`Self::rul_kalman`] share.
    #[allow(clippy::too_many_arguments)]
    fn rul_of_states<R: Rng + ?Sized>(
        threshold: T,
        mut future_temperature: impl FnMut(u32) -> T,
        (step_s, max_steps): (T, u32),
        states: &[Vector3<T>; M],
        weights: &[T; M],
        times: &mut [T; M],
        buf: &mut [(T, T); M],
        rng: &mut R,
    ) -> Result<Summary<T>, Error> {
        predict_eol(
            &LossAccumulationModel,
            &ConsumptionThreshold(threshold),
            states.as_slice(),
            |k| SVector::<T, 1>::from([future_temperature(k)]),
            &PredictionSettings::deterministic(step_s, max_steps),
            rng,
            times.as_mut_slice(),
        )?;
        rul_distribution(times.as_slice(), weights, buf.as_mut_slice())
            .ok_or(Error::InsufficientData)
    }

    /// RUL distribution (s) as [`Self::rul`], from `M` samples of the log-linear Kalman
    /// filter's Gaussian posterior of `[b, ln beta]` (equal weights).
    #[allow(clippy::too_many_arguments)]
    pub fn rul_kalman<R: Rng + ?Sized>(
        &self,
        threshold: T,
        future_temperature: impl FnMut(u32) -> T,
        step_s: T,
        max_steps: u32,
        states: &mut [Vector3<T>; M],
        times: &mut [T; M],
        buf: &mut [(T, T); M],
        rng: &mut R,
    ) -> Result<Summary<T>, Error> {
        let x0 = self.last_reading.ok_or(Error::InsufficientData)?;
        for (s, (b, beta)) in states
            .iter_mut()
            .zip(self.kalman.posterior_samples(&mut *rng)?)
        {
            *s = Vector3::new(x0, b, beta);
        }
        let weights = [T::one() / cast::<T>(M as f64); M];
        Self::rul_of_states(
            threshold,
            future_temperature,
            (step_s, max_steps),
            states,
            &weights,
            times,
            buf,
            rng,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand_core::SeedableRng;
    use rand_xoshiro::Xoshiro256PlusPlus;

    fn pipeline() -> (ReactionWheel<f64, 50, 50>, Xoshiro256PlusPlus) {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(4);
        let cfg = ReactionWheelConfig::new(0.03, 0.003).unwrap();
        (ReactionWheel::new(cfg, &mut rng).unwrap(), rng)
    }

    #[test]
    fn bad_input_is_rejected_and_changes_nothing() {
        let (mut p, mut rng) = pipeline();
        assert_eq!(
            p.step(0.0, 1.0, None, &mut rng).unwrap_err(),
            Error::InsufficientData
        );
        p.step(0.0, 1.0, Some(&[0.19, 91.4]), &mut rng).unwrap();
        let before = p.temperature_filter().filter().mean();
        let cases: [(f64, f64, &[f64]); 7] = [
            (0.05, f64::NAN, &[0.19, 91.4]),
            (0.05, 5.5, &[0.19, 91.4]),
            (0.05, -0.5, &[0.19, 91.4]),
            (0.05, 1.0, &[f64::NAN, 91.4]),
            (0.05, 1.0, &[0.19, 1.0e6]),
            (0.05, 1.0, &[0.19]),
            (0.0, 1.0, &[0.19, 91.4]),
        ];
        for (t, u, y) in cases {
            assert!(p.step(t, u, Some(y), &mut rng).is_err(), "{t} {u} {y:?}");
        }
        assert!(
            p.step(f64::INFINITY, 1.0, Some(&[0.19, 91.4]), &mut rng)
                .is_err()
        );
        assert!(
            p.step(0.05, 1.0, Some(&[0.19, 91.4, -1.0]), &mut rng)
                .is_err()
        );
        assert_eq!(p.temperature_filter().filter().mean(), before);
        // A missing sample is a documented predict-only step with a finite state.
        let r = p.step(0.05, 1.0, None, &mut rng).unwrap();
        assert!(r.predict_only && r.temperature.is_finite() && r.temperature_std.is_finite());
    }

    #[test]
    fn loss_filters_learn_from_intervals_and_rul_is_finite() {
        // Feed the loss filters exact interval consumption at a cycling temperature.
        let (mut p, mut rng) = pipeline();
        let (b, beta) = (37.0, 7.494e-6);
        let mut x = 0.0;
        for k in 0..120 {
            let temp: f64 = 30.0 + 4.0 * (k as f64 * 0.26).sin();
            let e = IntervalExposure::constant(240.0, temp).unwrap();
            let c = e.consumption(b, beta);
            x += c;
            p.update_loss(e, c, 0.0, &mut rng);
        }
        p.last_reading = Some(x);
        let (b_hat, beta_hat) = p.loss_parameters();
        assert!((b_hat - b).abs() / b < 0.05, "b {b_hat}");
        assert!((beta_hat - beta).abs() / beta < 0.05, "beta {beta_hat}");
        let mut states = [Vector3::zeros(); 50];
        let mut times = [0.0; 50];
        let mut buf = [(0.0, 0.0); 50];
        // 1 mL more at a constant 30 degC: RUL = 1 / (beta exp(-b/30)).
        let expected = 1.0 / (beta * (-b / 30.0f64).exp());
        let s = p
            .rul(
                x + 1.0,
                |_| 30.0,
                3600.0,
                200_000,
                &mut states,
                &mut times,
                &mut buf,
                &mut rng,
            )
            .unwrap();
        assert!(
            (s.median - expected).abs() / expected < 0.1,
            "{} vs {expected}",
            s.median
        );
        let (kb, kbeta) = p.loss_kalman().parameters();
        assert!((kb - b).abs() / b < 0.005, "kalman b {kb}");
        assert!((kbeta - beta).abs() / beta < 0.005, "kalman beta {kbeta}");
        let k = p
            .rul_kalman(
                x + 1.0,
                |_| 30.0,
                3600.0,
                200_000,
                &mut states,
                &mut times,
                &mut buf,
                &mut rng,
            )
            .unwrap();
        assert!(
            (k.median - expected).abs() / expected < 0.01,
            "{} vs {expected}",
            k.median
        );
        assert!(k.p05 <= k.median && k.median <= k.p95);
    }

    #[test]
    fn unset_placeholder_errs_until_reset_and_then_matches_new() {
        let mut unset = ReactionWheel::<f64, 50, 50>::UNSET;
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(4);
        let y = [0.19, 91.4];
        assert_eq!(
            unset.step(0.0, 1.0, Some(&y), &mut rng).unwrap_err(),
            Error::NotConfigured
        );
        // A rejected configuration leaves it unset.
        let mut bad = ReactionWheelConfig::new(0.03, 0.003).unwrap();
        bad.prior_b.1 = -1.0;
        assert!(unset.reset(bad, &mut rng).is_err());
        assert_eq!(
            unset.step(0.0, 1.0, Some(&y), &mut rng).unwrap_err(),
            Error::NotConfigured
        );
        // Reset in place draws what `new` draws: the two run bit-identically.
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(4);
        let cfg = ReactionWheelConfig::new(0.03, 0.003).unwrap();
        unset.reset(cfg, &mut rng).unwrap();
        let (mut built, mut built_rng) = pipeline();
        for k in 0..200 {
            let t = 0.05 * k as f64;
            let yk = [0.19 + 1e-3 * (k % 7) as f64, 91.4 + 0.01 * k as f64];
            let a = unset.step(t, 1.0, Some(&yk), &mut rng).unwrap();
            let b = built.step(t, 1.0, Some(&yk), &mut built_rng).unwrap();
            assert_eq!(a, b, "step {k}");
        }
        assert!(unset.two_step.particles().eq(built.two_step.particles()));
    }
}
