//! Lubricant-loss parameters by an exact log-linear Kalman filter (beyond the wheel paper).
//!
//! The consumption of one interval is `y = beta * sum_j exp(-b/T_j) dt`, so its logarithm is
//! linear in `theta = [b, ln(beta / BETA_UNIT)]` up to the second-order exposure term:
//! `ln y = ln(duration) + ln beta - b m + ln(1 + b^2 v / 2)`, with `m` and `v` the mean and
//! variance of `1/T` over the interval. A Kalman filter on `theta` (the exposure term
//! linearised at the estimate, a change of under 1e-6) is the exact posterior of the paper's
//! model with log-normal measurement noise, and uses the spread of the temperature over the
//! whole record, whereas the paper's ratio of consecutive intervals (Eq. 31) only sees the
//! small temperature change from one interval to the next. Two additions make it usable on
//! board:
//! - errors in variables: the temperature is itself an estimate with standard deviation
//!   `sigma_T`, which moves `m` by `sigma_T m^2` and the prediction by `b sigma_T m^2`; that
//!   enters the measurement variance;
//! - abrupt faults (Table 4): a CUSUM of the normalised innovation squared detects a change
//!   and enhances the covariance once (flagged [`Flags::COVARIANCE_ENHANCED`]); an isolated
//!   innovation beyond the gate is rejected ([`Flags::MEASUREMENT_REJECTED`]) so that a single
//!   outlier does not move the estimate;
//! - the measurement variance adapts (covariance matching, as the AUKF of the scooter paper):
//!   an exponentially weighted mean of `innovation^2 - H P H^T` over the fused, change-free
//!   intervals raises `R` above its nominal value when the temperature estimate errs more than
//!   `temperature_std` says, so the change detector does not fire on every orbit.

use nalgebra::{Matrix2, Vector2};

use super::reaction_wheel::{BETA_UNIT, IntervalExposure};
use crate::random::standard_normal;
use crate::real::zero_vector;
use crate::safeguard::{Flags, floor_variances, symmetrise};
use crate::{Error, Real, cast};
use rand_core::Rng;

/// Settings of [`LossKalman`].
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LossKalmanConfig<T> {
    /// Relative (log-normal) standard deviation of one consumption measurement.
    pub relative_noise: T,
    /// Standard deviation of the temperature estimate that forms the exposure (degC).
    pub temperature_std: T,
    /// Random walk per interval of `[b (degC), ln beta]`.
    pub walk: Vector2<T>,
    /// CUSUM reference: the NIS excess over this value accumulates (about 4 for one channel).
    pub change_drift: T,
    /// CUSUM threshold that declares a change and enhances the covariance (above
    /// `gate - change_drift`, so that it takes more than one rejected measurement).
    pub change_threshold: T,
    /// Standard deviations added to `[b, ln beta]` when a change is declared.
    pub enhancement: Vector2<T>,
    /// NIS above which a measurement that does not complete a change is rejected.
    pub gate: T,
    /// Largest NIS one interval adds to the CUSUM (Huber-type clipping, at most `gate`):
    /// below the gate a change then needs `change_threshold / (cap - change_drift)`
    /// large innovations, so that a few heavy-tailed input errors cannot declare one
    /// while a true, persistent change still does.
    pub change_increment_cap: T,
    /// Forgetting factor of the measurement-variance estimate (0 keeps `R` nominal).
    pub noise_adaptation: T,
    /// Compensate the errors-in-variables bias: a temperature estimate with independent
    /// errors makes the regressor `1/T` noisy, which pulls `b` towards zero by the share of
    /// the regressor's spread that is error. The update then removes the error's expected
    /// contribution to the information and to the score (bias-compensated least squares),
    /// with the error variance of `1/T` taken as `(temperature_std m^2)^2` plus the
    /// adapted excess variance divided by `b^2` (the excess is attributed to the
    /// temperature estimate).
    pub bias_compensation: bool,
}

impl<T: Real> LossKalmanConfig<T> {
    /// All zeros: the placeholder of [`LossKalman::UNSET`].
    pub const UNSET: Self = Self {
        relative_noise: T::ZERO,
        temperature_std: T::ZERO,
        walk: zero_vector(),
        change_drift: T::ZERO,
        change_threshold: T::ZERO,
        enhancement: zero_vector(),
        gate: T::ZERO,
        change_increment_cap: T::ZERO,
        noise_adaptation: T::ZERO,
        bias_compensation: false,
    };

    /// Defaults for 4-minute intervals: slow walks, a gate of 25 (5 sigma), a change declared
    /// on a CUSUM of 30 (two consecutive gated innovations, or a longer run of 3-sigma ones),
    /// enhanced by 10 degC in `b` and 0.1 in `ln beta`.
    pub fn new(relative_noise: T, temperature_std: T) -> Result<Self, Error> {
        let config = Self {
            relative_noise,
            temperature_std,
            walk: Vector2::new(cast(0.02), cast(0.0005)),
            change_drift: cast(4.0),
            change_threshold: cast(30.0),
            enhancement: Vector2::new(cast(10.0), cast(0.1)),
            gate: cast(25.0),
            change_increment_cap: cast(25.0),
            noise_adaptation: cast(1.0 / 48.0),
            bias_compensation: false,
        };
        config.check()?;
        Ok(config)
    }

    fn check(&self) -> Result<(), Error> {
        let positive = |v: T| v.finite() && v > T::zero();
        let non_negative = |v: T| v.finite() && v >= T::zero();
        if !positive(self.relative_noise) {
            return Err(Error::InvalidParameter("relative_noise"));
        }
        if !non_negative(self.temperature_std) {
            return Err(Error::InvalidParameter("temperature_std"));
        }
        if !(non_negative(self.walk.x) && non_negative(self.walk.y)) {
            return Err(Error::InvalidParameter("walk"));
        }
        if !(non_negative(self.change_drift) && positive(self.change_threshold)) {
            return Err(Error::InvalidParameter("change detector"));
        }
        if !(non_negative(self.enhancement.x) && non_negative(self.enhancement.y)) {
            return Err(Error::InvalidParameter("enhancement"));
        }
        if !positive(self.gate) {
            return Err(Error::InvalidParameter("gate"));
        }
        if !(positive(self.change_increment_cap) && self.change_increment_cap <= self.gate) {
            return Err(Error::InvalidParameter("change_increment_cap"));
        }
        if !(non_negative(self.noise_adaptation) && self.noise_adaptation < T::one()) {
            return Err(Error::InvalidParameter("noise_adaptation"));
        }
        Ok(())
    }
}

/// What one [`LossKalman::update`] did.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LossKalmanReport<T> {
    /// Innovation of `ln y` against the prediction (before any enhancement).
    pub innovation: T,
    /// Its variance (after any enhancement).
    pub innovation_variance: T,
    /// Normalised innovation squared before any enhancement.
    pub nis: T,
    /// Whether the measurement was fused.
    pub fused: bool,
    /// Whether a change was declared (covariance enhanced) at this interval.
    pub change_detected: bool,
    /// Safeguards that acted.
    pub flags: Flags,
}

/// The log-linear loss-parameter filter: state `[b (degC), ln(beta / 1e-6 mL/s)]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LossKalman<T: Real> {
    config: LossKalmanConfig<T>,
    state: Vector2<T>,
    covariance: Matrix2<T>,
    cusum: T,
    changes: u32,
    /// Estimated measurement variance beyond the nominal one (covariance matching).
    excess_variance: T,
}

impl<T: Real> LossKalman<T> {
    /// An all-zero placeholder for static storage, replaced on reset.
    pub const UNSET: Self = Self {
        config: LossKalmanConfig::UNSET,
        state: zero_vector(),
        covariance: Matrix2::from_array_storage(nalgebra::ArrayStorage([[T::ZERO; 2]; 2])),
        cusum: T::ZERO,
        changes: 0,
        excess_variance: T::ZERO,
    };

    /// A filter with prior means `b0` (degC) and `beta0` (mL/s) and prior standard deviations
    /// `b_std` (degC) and `beta_rel_std` (relative, i.e. of `ln beta`).
    pub fn new(
        config: LossKalmanConfig<T>,
        b0: T,
        b_std: T,
        beta0: T,
        beta_rel_std: T,
    ) -> Result<Self, Error> {
        config.check()?;
        let positive = |v: T| v.finite() && v > T::zero();
        if !(b0.finite() && positive(b_std) && positive(beta0) && positive(beta_rel_std)) {
            return Err(Error::InvalidParameter("prior"));
        }
        let log_beta = (beta0 / cast(BETA_UNIT)).ln();
        if !log_beta.finite() {
            return Err(Error::InvalidParameter("prior"));
        }
        Ok(Self {
            config,
            state: Vector2::new(b0, log_beta),
            covariance: Matrix2::new(
                b_std * b_std,
                T::zero(),
                T::zero(),
                beta_rel_std * beta_rel_std,
            ),
            cusum: T::zero(),
            changes: 0,
            excess_variance: T::zero(),
        })
    }

    /// Estimate `(b (degC), beta (mL/s))`.
    pub fn parameters(&self) -> (T, T) {
        (self.state.x, self.state.y.exp() * cast(BETA_UNIT))
    }

    /// State `[b, ln(beta / 1e-6)]`.
    pub fn state(&self) -> &Vector2<T> {
        &self.state
    }

    /// Covariance of the state.
    pub fn covariance(&self) -> &Matrix2<T> {
        &self.covariance
    }

    /// An endless stream of samples `(b (degC), beta (1e-6 mL/s))` of the Gaussian posterior
    /// of `[b, ln beta]`, for RUL prediction. `Err` if the covariance is not positive definite.
    pub fn posterior_samples<'a, R: Rng + ?Sized>(
        &self,
        rng: &'a mut R,
    ) -> Result<impl Iterator<Item = (T, T)> + 'a, Error>
    where
        T: 'a,
    {
        let mean = self.state;
        let l = self
            .covariance
            .cholesky()
            .ok_or(Error::NotPositiveDefinite)?
            .l();
        Ok(core::iter::repeat_with(move || {
            let z = Vector2::new(standard_normal::<T, R>(rng), standard_normal::<T, R>(rng));
            let sample = mean + l * z;
            (sample.x, sample.y.exp())
        }))
    }

    /// Measurement variance estimated beyond the nominal one (covariance matching).
    pub fn excess_variance(&self) -> T {
        self.excess_variance
    }

    /// The bias-compensated update in information form: with `h` the regressor built from
    /// the estimated `1/T` and `Sigma = diag(var(1/T error), 0)` its error covariance,
    /// `Lambda' = P^-1 + (h h^T - Sigma) / r` and
    /// `theta' = theta + Lambda'^-1 (h nu + Sigma theta) / r`, whose score has zero mean
    /// under independent regressor errors (the plain update's has `-b var / r`). Returns
    /// false, changing nothing, when the compensated information is not positive definite
    /// (too little spread of the temperature yet); the caller then falls back to the plain
    /// update.
    fn compensated_update(
        &mut self,
        h: &Vector2<T>,
        innovation: T,
        r: T,
        inverse_temperature_std: T,
    ) -> bool {
        let b = self.state.x;
        let b_floor: T = cast(1.0);
        let mut error_var = inverse_temperature_std * inverse_temperature_std;
        if b.abs() > b_floor {
            error_var += self.excess_variance / (b * b);
        }
        let Some(information) = self.covariance.try_inverse() else {
            return false;
        };
        let sigma = Matrix2::new(error_var, T::zero(), T::zero(), T::zero());
        let updated = information + (h * h.transpose() - sigma) / r;
        let det = updated.determinant();
        let information_b = updated.get((0, 0)).copied().unwrap_or_else(T::zero);
        if !(det.finite() && det > T::zero() && information_b > T::zero()) {
            return false;
        }
        let Some(covariance) = updated.try_inverse() else {
            return false;
        };
        let score = (h * innovation + Vector2::new(error_var * b, T::zero())) / r;
        let state = self.state + covariance * score;
        if !(state.iter().all(|v| v.finite()) && covariance.iter().all(|v| v.finite())) {
            return false;
        }
        self.state = state;
        self.covariance = covariance;
        true
    }

    /// How many changes the detector has declared so far.
    pub fn changes_detected(&self) -> u32 {
        self.changes
    }

    /// The settings.
    pub fn config(&self) -> &LossKalmanConfig<T> {
        &self.config
    }

    /// One interval: its exposure (from the estimated temperature) and the measured
    /// consumption (mL). A bad exposure or a non-positive or non-finite consumption is an
    /// `Err` and leaves the filter unchanged.
    pub fn update(
        &mut self,
        exposure: &IntervalExposure<T>,
        consumption: T,
    ) -> Result<LossKalmanReport<T>, Error> {
        self.update_with_temperature_std(exposure, consumption, self.config.temperature_std)
    }

    /// [`Self::update`] with this interval's own standard deviation of the temperature
    /// estimate (degC) in place of the configured one: a thermometer that reports its
    /// posterior spread per interval. A negative or non-finite value is an `Err`.
    pub fn update_with_temperature_std(
        &mut self,
        exposure: &IntervalExposure<T>,
        consumption: T,
        temperature_std: T,
    ) -> Result<LossKalmanReport<T>, Error> {
        exposure.check()?;
        if !(temperature_std.finite() && temperature_std >= T::zero()) {
            return Err(Error::InvalidParameter("temperature_std"));
        }
        if !consumption.finite() {
            return Err(Error::NonFiniteMeasurement);
        }
        if !(consumption > T::zero()) {
            return Err(Error::OutOfRange("consumption"));
        }
        let mut next = *self;
        let mut flags = Flags::NONE;

        // Predict: random walk.
        next.covariance +=
            Matrix2::from_diagonal(&next.config.walk.component_mul(&next.config.walk));

        // Linearised measurement of ln y at the estimate.
        let (b, log_beta) = (next.state.x, next.state.y);
        let m = exposure.mean_inverse_temperature;
        let v = exposure.var_inverse_temperature;
        let half: T = cast(0.5);
        let curvature = T::one() + half * b * b * v;
        if !(curvature > T::zero()) {
            return Err(Error::OutOfRange("loss exponent b"));
        }
        let unit: T = cast(BETA_UNIT);
        let predicted = (exposure.duration * unit).ln() + log_beta - b * m + curvature.ln();
        let h = Vector2::new(-m + b * v / curvature, T::one());
        let temperature_term = b * temperature_std * m * m;
        let r = next.config.relative_noise * next.config.relative_noise
            + temperature_term * temperature_term
            + next.excess_variance;
        let innovation = consumption.ln() - predicted;
        let mut s = (h.transpose() * next.covariance * h).x + r;
        if !(s.finite() && s > T::zero()) {
            return Err(Error::NotPositiveDefinite);
        }
        let nis = innovation * innovation / s;
        if !nis.finite() {
            return Err(Error::NonFiniteState);
        }

        // CUSUM change detector on the NIS, each increment capped (at most at the gate) so
        // that one outlier alone cannot declare a change.
        next.cusum = (next.cusum + nis.min(next.config.change_increment_cap)
            - next.config.change_drift)
            .max(T::zero());
        let change_detected = next.cusum > next.config.change_threshold;
        if change_detected {
            let e = next.config.enhancement;
            next.covariance += Matrix2::from_diagonal(&e.component_mul(&e));
            next.cusum = T::zero();
            next.changes = next.changes.saturating_add(1);
            flags.insert(Flags::COVARIANCE_ENHANCED);
            s = (h.transpose() * next.covariance * h).x + r;
        }
        let fused = change_detected || nis <= next.config.gate;
        if fused && !change_detected {
            // Covariance matching: E[innovation^2] = H P H^T + R.
            let hph = s - r;
            let sample = innovation * innovation - hph - (r - next.excess_variance);
            let lambda = next.config.noise_adaptation;
            next.excess_variance =
                ((T::one() - lambda) * next.excess_variance + lambda * sample).max(T::zero());
        }
        let compensated = fused
            && next.config.bias_compensation
            && next.compensated_update(&h, innovation, r, temperature_std * m * m);
        if fused && !compensated {
            // Joseph-form update: stays symmetric positive semi-definite under round-off.
            let gain = next.covariance * h / s;
            next.state += gain * innovation;
            let i_kh = Matrix2::identity() - gain * h.transpose();
            next.covariance =
                i_kh * next.covariance * i_kh.transpose() + gain * gain.transpose() * r;
        } else if !fused {
            flags.insert(Flags::MEASUREMENT_REJECTED);
        }
        if symmetrise(&mut next.covariance) {
            flags.insert(Flags::COVARIANCE_SYMMETRISED);
        }
        if floor_variances(&mut next.covariance, T::MIN_POSITIVE) {
            flags.insert(Flags::VARIANCE_FLOOR);
        }
        if !(next.state.iter().all(|v| v.finite()) && next.covariance.iter().all(|v| v.finite())) {
            return Err(Error::NonFiniteState);
        }
        *self = next;
        Ok(LossKalmanReport {
            innovation,
            innovation_variance: s,
            nis,
            fused,
            change_detected,
            flags,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn consumption(b: f64, beta: f64, temperature: f64) -> f64 {
        IntervalExposure::constant(240.0, temperature)
            .unwrap()
            .consumption(b, beta)
    }

    #[test]
    fn recovers_exact_parameters_from_noise_free_data() {
        let config = LossKalmanConfig::new(0.0025, 0.0).unwrap();
        let mut kf = LossKalman::new(config, 30.0, 10.0, 6e-6, 0.3).unwrap();
        for k in 0..200 {
            let temperature = 30.0 + 4.0 * (k as f64 * 0.26).sin();
            let e = IntervalExposure::constant(240.0, temperature).unwrap();
            let report = kf
                .update(&e, consumption(37.0, 7.494e-6, temperature))
                .unwrap();
            assert!(report.fused || k < 2);
        }
        let (b, beta) = kf.parameters();
        assert!((b - 37.0).abs() < 0.05, "b = {b}");
        assert!((beta / 7.494e-6 - 1.0).abs() < 2e-3, "beta = {beta}");
        let p = kf.covariance();
        assert!(p[(0, 0)] > 0.0 && p[(1, 1)] > 0.0 && (p[(0, 1)] - p[(1, 0)]).abs() < 1e-15);
    }

    #[test]
    fn a_step_change_is_detected_and_tracked() {
        let config = LossKalmanConfig::new(0.0025, 0.0).unwrap();
        let mut kf = LossKalman::new(config, 37.0, 2.0, 7.494e-6, 0.05).unwrap();
        let mut detections = 0;
        for k in 0..120 {
            let temperature = 30.0 + 4.0 * (k as f64 * 0.26).sin();
            let (b, beta) = if k < 40 {
                (37.0, 7.494e-6)
            } else {
                (25.0, 8.054e-6)
            };
            let e = IntervalExposure::constant(240.0, temperature).unwrap();
            if kf
                .update(&e, consumption(b, beta, temperature))
                .unwrap()
                .change_detected
            {
                detections += 1;
            }
        }
        assert!(detections >= 1);
        let (b, beta) = kf.parameters();
        assert!((b - 25.0).abs() < 0.1, "b = {b}");
        assert!((beta / 8.054e-6 - 1.0).abs() < 5e-3, "beta = {beta}");
    }

    #[test]
    fn a_capped_cusum_ignores_outlier_pairs_but_still_detects_a_step() {
        // Pairs of consecutive 5 % outliers (heavy-tailed input errors) every 30 intervals,
        // then a persistent step in the parameters at interval 600.
        let run = |cap: f64| {
            let config = LossKalmanConfig {
                change_increment_cap: cap,
                ..LossKalmanConfig::new(0.0025, 0.0).unwrap()
            };
            let mut kf = LossKalman::new(config, 37.0, 2.0, 7.494e-6, 0.05).unwrap();
            let mut before_step = 0;
            for k in 0..700 {
                let temperature = 30.0 + 4.0 * (k as f64 * 0.26).sin();
                let (b, beta) = if k < 600 {
                    (37.0, 7.494e-6)
                } else {
                    (25.0, 8.054e-6)
                };
                let outlier = (100..600).contains(&k) && k % 30 < 2;
                let y = consumption(b, beta, temperature) * if outlier { 1.05 } else { 1.0 };
                let e = IntervalExposure::constant(240.0, temperature).unwrap();
                let report = kf.update(&e, y).unwrap();
                if report.change_detected && k < 600 {
                    before_step += 1;
                }
            }
            (before_step, kf.changes_detected(), kf.parameters())
        };
        let (false_uncapped, _, _) = run(25.0);
        assert!(false_uncapped >= 10, "uncapped: {false_uncapped}");
        let (false_capped, total, (b, beta)) = run(9.0);
        assert_eq!(false_capped, 0);
        assert!(total >= 1);
        assert!((b - 25.0).abs() < 0.2, "b = {b}");
        assert!((beta / 8.054e-6 - 1.0).abs() < 1e-2, "beta = {beta}");
        let bad_cap = LossKalmanConfig {
            change_increment_cap: 30.0,
            ..LossKalmanConfig::new(0.0025, 0.0).unwrap()
        };
        assert!(LossKalman::new(bad_cap, 37.0, 2.0, 7.494e-6, 0.05).is_err());
    }

    #[test]
    fn bad_samples_leave_the_filter_unchanged() {
        let config = LossKalmanConfig::new(0.0025, 0.05).unwrap();
        let mut kf = LossKalman::new(config, 37.0, 2.0, 7.494e-6, 0.05).unwrap();
        let before = kf;
        let e = IntervalExposure::constant(240.0, 30.0).unwrap();
        assert_eq!(kf.update(&e, f64::NAN), Err(Error::NonFiniteMeasurement));
        assert_eq!(kf.update(&e, -1.0), Err(Error::OutOfRange("consumption")));
        let bad = IntervalExposure { duration: 0.0, ..e };
        assert_eq!(kf.update(&bad, 1e-4), Err(Error::InvalidTimeStep));
        assert_eq!(kf, before);
        // Converged, an isolated outlier is rejected, not fused, and declares no change.
        for k in 0..100 {
            let temperature = 30.0 + 4.0 * (k as f64 * 0.26).sin();
            let e = IntervalExposure::constant(240.0, temperature).unwrap();
            kf.update(&e, consumption(37.0, 7.494e-6, temperature))
                .unwrap();
        }
        let converged = *kf.state();
        let report = kf
            .update(&e, consumption(37.0, 7.494e-6, 30.0) * 1.05)
            .unwrap();
        assert!(!report.fused && report.flags.contains(Flags::MEASUREMENT_REJECTED));
        assert!(!report.change_detected);
        assert_eq!(kf.state(), &converged);
        assert!(LossKalmanConfig::new(0.0, 0.05).is_err());
        assert!(LossKalman::new(config, 37.0, 2.0, -1.0, 0.05).is_err());
    }

    #[test]
    fn bias_compensation_removes_the_pull_of_a_noisy_thermometer_on_b() {
        use rand_core::SeedableRng;
        // Independent 0.6 degC errors on a +-4 degC cycle: the plain filter's b is pulled
        // towards zero by about 0.36 / (8 + 0.36) = 4 %.
        let run = |compensate: bool, seed: u64| {
            let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(seed);
            let config = LossKalmanConfig {
                walk: Vector2::new(1e-4, 1e-6),
                noise_adaptation: 0.0,
                bias_compensation: compensate,
                ..LossKalmanConfig::new(0.0025, 0.6).unwrap()
            };
            let mut kf = LossKalman::new(config, 37.0, 2.0, 7.494e-6, 0.05).unwrap();
            for k in 0..4000 {
                let temperature = 30.0 + 4.0 * (k as f64 * 0.26).sin();
                let noise = 0.6 * crate::random::standard_normal::<f64, _>(&mut rng);
                let e = IntervalExposure::constant(240.0, temperature + noise).unwrap();
                kf.update(&e, consumption(37.0, 7.494e-6, temperature))
                    .unwrap();
            }
            kf.parameters().0
        };
        for seed in [5, 6] {
            let plain = run(false, seed);
            let compensated = run(true, seed);
            assert!(plain < 36.2, "plain b {plain}");
            assert!(
                (compensated - 37.0).abs() < 0.4,
                "compensated b {compensated}"
            );
        }
    }

    #[test]
    fn measurement_variance_adapts_so_that_noise_alone_declares_no_change() {
        use rand_core::SeedableRng;
        // Data four times noisier than the configuration says (a poor thermometer).
        let run = |adaptation: f64| {
            let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(11);
            let config = LossKalmanConfig {
                noise_adaptation: adaptation,
                ..LossKalmanConfig::new(0.0025, 0.0).unwrap()
            };
            let mut kf = LossKalman::new(config, 37.0, 2.0, 7.494e-6, 0.05).unwrap();
            for k in 0..3000 {
                let temperature = 30.0 + 4.0 * (k as f64 * 0.26).sin();
                let e = IntervalExposure::constant(240.0, temperature).unwrap();
                let noise = 0.01 * crate::random::standard_normal::<f64, _>(&mut rng);
                kf.update(&e, consumption(37.0, 7.494e-6, temperature) * noise.exp())
                    .unwrap();
            }
            kf
        };
        let adaptive = run(1.0 / 48.0);
        let fixed = run(0.0);
        assert!(
            fixed.changes_detected() > 20,
            "fixed R: {}",
            fixed.changes_detected()
        );
        assert!(
            adaptive.changes_detected() <= 2,
            "adaptive R: {}",
            adaptive.changes_detected()
        );
        let excess = adaptive.excess_variance();
        assert!(
            (excess / (0.01f64.powi(2) - 0.0025f64.powi(2)) - 1.0).abs() < 0.5,
            "{excess}"
        );
        assert!((adaptive.parameters().0 - 37.0).abs() < 0.5);
    }
}
