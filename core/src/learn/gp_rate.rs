//! GP-UKF with an online degradation-rate state: the dynamic GP learned on other trials gives
//! the shape of the increment `mu(r, u)`, and a per-unit log rate scale `theta` (estimated by
//! the same UKF) stretches it, `r' = r + e^theta mu(r, u)`. An IMM of fixed-rate models can
//! only pick among the rates it was trained on and forgets through its mode switching; the
//! rate state integrates the evidence of the whole history and moves to an unseen unit's rate.
//!
//! State `[r, theta_0, .., theta_{NX-2}]`: the log rate scale is a polynomial in the damage,
//! `theta(r) = theta_0 + theta_1 (r - pivot) + ..`; with NX = 2 a constant rate, with NX = 3 a
//! tilt as well (a unit whose growth accelerates more, or less, than the GP's training units).
//! Measurement `r` (noise variance constant or growing with `r`, [`FeatureNoise`]). The `theta` entries follow a random walk with
//! variance `rate_walk_variance` per cycle each. Allocation-free like [`super::gp`].

use super::gp::{GaussianProcess, GpPrediction};
use crate::error::Error;
use crate::filter::imm::{ModeFilter, ModeUpdate};
use crate::filter::ukf::{SigmaParams, Ukf};
use crate::model::{Model, Observe, Stochastic, gaussian_log_likelihood};
use crate::random::standard_normal;
use crate::real::{Real, all_finite, cast};
use crate::safeguard::Flags;
use nalgebra::{Matrix1, SMatrix, SVector, Vector1};
use rand_core::Rng;

/// Largest `|theta|` the transition uses (a scale of `e^8`, about 3000, is far outside any
/// plausible rate; the clamp keeps `e^theta` finite for wild sigma points).
pub const MAX_LOG_RATE: f64 = 8.0;

/// Measurement noise of the feature that grows with the feature, `var(r) = floor + growth r^2`:
/// an additive part (background noise in the band) and a part proportional to the fault
/// line's amplitude (impulse amplitude scatter and arrival jitter). `growth = 0` is a
/// constant `R`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FeatureNoise<T> {
    pub floor: T,
    pub growth: T,
}

impl<T: Real> FeatureNoise<T> {
    /// A constant variance.
    pub fn constant(variance: T) -> Self {
        Self {
            floor: variance,
            growth: T::zero(),
        }
    }

    /// `E[var(r)]` for `r ~ N(mean, variance)`: `floor + growth (mean^2 + variance)`.
    pub fn expected_variance(&self, mean: T, variance: T) -> T {
        self.floor + self.growth * (mean * mean + variance.max(T::zero()))
    }

    fn validate(&self) -> Result<(), Error> {
        let floor_ok = self.floor.finite() && self.floor > T::zero();
        let growth_ok = self.growth.finite() && self.growth >= T::zero();
        if !(floor_ok && growth_ok) {
            return Err(Error::InvalidParameter("r"));
        }
        Ok(())
    }
}

/// Compile-time check that the GP input is `r` followed by the input.
struct InputSize<const D: usize, const NU: usize>;
impl<const D: usize, const NU: usize> InputSize<D, NU> {
    const OK: () = assert!(D == NU + 1, "GP input size D must equal 1 + NU");
}

/// Compile-time check that the state holds `r` and at least one log-rate term.
struct StateSize<const NX: usize>;
impl<const NX: usize> StateSize<NX> {
    const OK: () = assert!(NX >= 2, "the rate-scaled state is [r, theta_0, ..]");
}

/// The feature entry `r` of the state.
fn feature<T: Real, const NX: usize>(x: &SVector<T, NX>) -> T {
    let () = StateSize::<NX>::OK;
    x.iter()
        .next()
        .copied()
        .unwrap_or(T::MAX_FINITE * cast(2.0))
}

/// Transition `[r, theta] -> [r + e^theta(r) mu(r, u), theta]` with the GP's mean `mu`.
#[derive(Clone, Copy, Debug)]
pub struct RateScaledTransition<'a, T: Real, const D: usize, const M: usize> {
    pub gp: &'a GaussianProcess<T, D, M>,
    /// Standard deviation of the measured `r` (for [`Stochastic::log_likelihood`]).
    pub measurement_std: T,
    /// Damage at which `theta_0` is the log rate (the tilt terms vanish there).
    pub pivot: T,
}

impl<T: Real, const D: usize, const M: usize> RateScaledTransition<'_, T, D, M> {
    /// `e^theta(r)` with the exponent clamped to `+-MAX_LOG_RATE`.
    pub fn scale<const NX: usize>(&self, x: &SVector<T, NX>) -> T {
        let bound: T = cast(MAX_LOG_RATE);
        let d = feature(x) - self.pivot;
        let (mut theta, mut power) = (T::zero(), T::one());
        for &c in x.iter().skip(1) {
            theta += c * power;
            power *= d;
        }
        theta.max(-bound).min(bound).exp()
    }

    /// The GP at `(r, u)`.
    pub fn predict<const NX: usize, const NU: usize>(
        &self,
        x: &SVector<T, NX>,
        u: &SVector<T, NU>,
    ) -> Result<GpPrediction<T>, Error> {
        let () = InputSize::<D, NU>::OK;
        let mut input = SVector::<T, D>::zeros();
        for (dst, src) in input
            .iter_mut()
            .zip(core::iter::once(feature(x)).chain(u.iter().copied()))
        {
            *dst = src;
        }
        self.gp.predict(&input)
    }
}

/// A non-finite state: the filter reports [`Error::NonFiniteState`] when the GP rejects a query.
fn diverged<T: Real, const NX: usize>() -> SVector<T, NX> {
    SVector::repeat(T::MAX_FINITE * cast(2.0))
}

impl<T: Real, const D: usize, const M: usize, const NX: usize, const NU: usize> Model<T, NX, NU>
    for RateScaledTransition<'_, T, D, M>
{
    fn step(&self, x: &SVector<T, NX>, u: &SVector<T, NU>, _dt: T) -> SVector<T, NX> {
        match self.predict(x, u) {
            Ok(p) => {
                let mut next = *x;
                if let Some(r) = next.get_mut(0) {
                    *r += self.scale(x) * p.mean;
                }
                next
            }
            Err(_) => diverged(),
        }
    }
}

impl<T: Real, const D: usize, const M: usize, const NX: usize, const NU: usize>
    Observe<T, NX, NU, 1> for RateScaledTransition<'_, T, D, M>
{
    fn observe(&self, x: &SVector<T, NX>, _u: &SVector<T, NU>) -> Vector1<T> {
        Vector1::new(feature(x))
    }
}

impl<T: Real, const D: usize, const M: usize, const NX: usize, const NU: usize>
    Stochastic<T, NX, NU> for RateScaledTransition<'_, T, D, M>
{
    fn measurement_len(&self) -> usize {
        1
    }

    /// One draw of the increment from the GP's predictive distribution, stretched by the
    /// unit's rate: `r + e^theta (mu + sqrt(var) N(0, 1))`; `theta` is kept (the rate of a
    /// propagated sample is the one drawn from the posterior).
    fn sample_step<R: Rng + ?Sized>(
        &self,
        x: &SVector<T, NX>,
        u: &SVector<T, NU>,
        _dt: T,
        rng: &mut R,
    ) -> SVector<T, NX> {
        match self.predict(x, u) {
            Ok(p) => {
                let increment = p.mean + p.variance().sqrt() * standard_normal::<T, R>(rng);
                let mut next = *x;
                if let Some(r) = next.get_mut(0) {
                    *r += self.scale(x) * increment;
                }
                next
            }
            Err(_) => diverged(),
        }
    }

    fn log_likelihood(&self, x: &SVector<T, NX>, _u: &SVector<T, NU>, y: &[T]) -> T {
        gaussian_log_likelihood(y, &[feature(x)], &[self.measurement_std])
    }
}

/// What one step of the rate-scaled GP-UKF did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RateScaledReport<T: Real> {
    pub innovation: T,
    pub innovation_variance: T,
    /// Normalised innovation squared, the test ratio of an outlier gate.
    pub nis: T,
    /// `ln N(innovation; 0, S)`, the mode likelihood in an IMM.
    pub log_likelihood: T,
    /// The GP was queried outside its training range at the prior mean.
    pub extrapolating: bool,
    pub flags: Flags,
}

/// The GP-UKF over `[r, theta]` (Table 2 of Anger et al. with the augmented rate state);
/// `NS = 2 NX + 1` sigma points.
#[derive(Clone, Debug)]
pub struct RateScaledGpUkf<
    'a,
    T: Real,
    const NX: usize,
    const NU: usize,
    const D: usize,
    const M: usize,
    const NS: usize,
> {
    ukf: Ukf<T, NX, NS>,
    transition: RateScaledTransition<'a, T, D, M>,
    noise: FeatureNoise<T>,
    rate_walk_variance: T,
}

impl<'a, T: Real, const NX: usize, const NU: usize, const D: usize, const M: usize, const NS: usize>
    RateScaledGpUkf<'a, T, NX, NU, D, M, NS>
{
    /// Prior `N(x0, p0)` over `[r, theta]` (the `theta` prior is the spread of rates over the
    /// training units), measurement noise variance `r_var` (constant; see
    /// [`RateScaledGpUkf::set_feature_noise`]), rate random walk variance per cycle.
    pub fn new(
        transition: RateScaledTransition<'a, T, D, M>,
        x0: SVector<T, NX>,
        p0: SMatrix<T, NX, NX>,
        r_var: T,
        rate_walk_variance: T,
        params: SigmaParams<T>,
    ) -> Result<Self, Error> {
        let noise = FeatureNoise::constant(r_var);
        noise.validate()?;
        if !(rate_walk_variance.finite() && rate_walk_variance >= T::zero()) {
            return Err(Error::InvalidParameter("rate walk variance"));
        }
        let ukf = Ukf::new(x0, p0, SMatrix::zeros(), params)?;
        Ok(Self {
            ukf,
            transition,
            noise,
            rate_walk_variance,
        })
    }

    /// Replaces the constant measurement variance by a law that grows with `r`; an invalid law
    /// is an error and changes nothing.
    pub fn set_feature_noise(&mut self, noise: FeatureNoise<T>) -> Result<(), Error> {
        noise.validate()?;
        self.noise = noise;
        Ok(())
    }

    pub fn feature_noise(&self) -> &FeatureNoise<T> {
        &self.noise
    }

    pub fn state(&self) -> &SVector<T, NX> {
        self.ukf.state()
    }
    pub fn covariance(&self) -> &SMatrix<T, NX, NX> {
        self.ukf.covariance()
    }
    pub fn transition(&self) -> &RateScaledTransition<'a, T, D, M> {
        &self.transition
    }

    /// The prediction of one cycle with input `u`, on a copy: the predicted filter, its
    /// flags and whether the GP extrapolated.
    fn predicted(&self, u: &SVector<T, NU>) -> Result<(Ukf<T, NX, NS>, Flags, bool), Error> {
        if !all_finite(u.as_slice()) {
            return Err(Error::NonFiniteInput);
        }
        // Q from the GP variance at the prior mean, stretched like the mean.
        let x = *self.ukf.state();
        let p = self.transition.predict(&x, u)?;
        let scale = self.transition.scale(&x);
        let mut q = SMatrix::<T, NX, NX>::identity() * self.rate_walk_variance;
        if let Some(q_rr) = q.get_mut((0, 0)) {
            *q_rr = scale * scale * p.variance();
        }
        let mut ukf = self.ukf.clone();
        ukf.set_process_noise(q)?;
        let flags = ukf.predict(&self.transition, u, T::one())?;
        Ok((ukf, flags, p.extrapolating))
    }

    /// A cycle without a measurement: the prediction alone. Errors leave the filter
    /// unchanged; returns whether the GP extrapolated.
    pub fn predict_only(&mut self, u: &SVector<T, NU>) -> Result<bool, Error> {
        let (ukf, _, extrapolating) = self.predicted(u)?;
        self.ukf = ukf;
        Ok(extrapolating)
    }

    /// One cycle: predict with input `u`, then fuse measurement `z` (one value). Errors leave
    /// the filter unchanged.
    pub fn step(&mut self, u: &SVector<T, NU>, z: &[T]) -> Result<RateScaledReport<T>, Error> {
        if z.len() != 1 {
            return Err(Error::MeasurementLength {
                expected: 1,
                got: z.len(),
            });
        }
        if !all_finite(z) {
            return Err(Error::NonFiniteMeasurement);
        }
        let (mut ukf, mut flags, extrapolating) = self.predicted(u)?;
        // R at the prior of r: the noise law's expectation over the predicted r.
        let (r_mean, r_var) = (
            feature(ukf.state()),
            ukf.covariance().get((0, 0)).copied().unwrap_or(T::zero()),
        );
        let r_noise = self.noise.expected_variance(r_mean, r_var);
        let report = ukf.update(&self.transition, u, z, &Matrix1::new(r_noise))?;
        flags.insert(report.flags);
        let s = report.innovation_cov.x;
        if !(s > T::zero()) {
            return Err(Error::NotPositiveDefinite);
        }
        let two_pi: T = cast(core::f64::consts::TAU);
        let log_likelihood = -(report.nis + s.ln() + two_pi.ln()) * cast(0.5);
        self.ukf = ukf;
        Ok(RateScaledReport {
            innovation: report.innovation.x,
            innovation_variance: s,
            nis: report.nis,
            log_likelihood,
            extrapolating,
            flags,
        })
    }
}

impl<T: Real, const NX: usize, const NU: usize, const D: usize, const M: usize, const NS: usize>
    ModeFilter<T, NX> for RateScaledGpUkf<'_, T, NX, NU, D, M, NS>
{
    type Input = SVector<T, NU>;

    fn mode_state(&self) -> SVector<T, NX> {
        *self.ukf.state()
    }
    fn mode_covariance(&self) -> SMatrix<T, NX, NX> {
        *self.ukf.covariance()
    }
    fn reinitialise(&mut self, x: &SVector<T, NX>, p: &SMatrix<T, NX, NX>) -> Result<(), Error> {
        self.ukf.set_estimate(*x, *p)
    }
    fn filter_step(&mut self, input: &SVector<T, NU>, z: &[T]) -> Result<ModeUpdate<T>, Error> {
        self.step(input, z).map(|r| ModeUpdate {
            log_likelihood: r.log_likelihood,
            nis: r.nis,
        })
    }
    fn predict_step(&mut self, input: &SVector<T, NU>) -> Result<(), Error> {
        self.predict_only(input).map(|_| ())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filter::ukf::SigmaParams;
    use crate::learn::gp::{StateThreshold, sample_rul};
    use nalgebra::{Matrix2, Vector2};
    use rand_core::SeedableRng;
    use rand_xoshiro::Xoshiro256PlusPlus;

    /// A flat GP: mean increment 0.01 everywhere (one point, zero weight), tiny variance.
    fn flat_gp() -> GaussianProcess<f64, 2, 1> {
        GaussianProcess::from_f64(
            &[10.0, 10.0],
            1e-8,
            1e-8,
            &[[0.5, 0.5]],
            &[0.0],
            &[[(2e-8f64).sqrt()]],
            0.01,
        )
        .unwrap()
    }

    fn filter(gp: &GaussianProcess<f64, 2, 1>) -> RateScaledGpUkf<'_, f64, 2, 1, 2, 1, 5> {
        RateScaledGpUkf::new(
            RateScaledTransition {
                gp,
                measurement_std: 0.02,
                pivot: 0.5,
            },
            Vector2::new(0.0, 0.0),
            Matrix2::new(4e-4, 0.0, 0.0, 0.25),
            4e-4,
            1e-6,
            SigmaParams::default(),
        )
        .unwrap()
    }

    #[test]
    fn learns_an_unseen_units_rate_and_predicts_its_rul() {
        let gp = flat_gp();
        let mut f = filter(&gp);
        // The unit degrades 1.5 times faster than the GP's training unit: theta = ln 1.5.
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(11);
        let mut r = 0.0;
        for _ in 0..40 {
            r += 0.015;
            let z = r + 0.02 * standard_normal::<f64, _>(&mut rng);
            f.step(&Vector1::new(0.5), &[z]).unwrap();
        }
        let theta = f.state()[1];
        assert!((theta - 1.5f64.ln()).abs() < 0.05, "theta {theta}");
        // True RUL to r = 1 from r = 0.6: 0.4 / 0.015 = 26.7 cycles.
        let mut states = [Vector2::<f64>::zeros(); 100];
        let mut times = [0.0; 100];
        sample_rul(
            f.transition(),
            f.state(),
            f.covariance(),
            &StateThreshold {
                index: 0,
                level: 1.0,
            },
            |_| Vector1::new(0.5),
            500,
            &mut rng,
            &mut states,
            &mut times,
        )
        .unwrap();
        let mut buf = [(0.0, 0.0); 100];
        let s = crate::prognose::rul_distribution(&times, &[1.0; 100], &mut buf).unwrap();
        assert!((s.median - 27.0).abs() <= 2.0, "median {}", s.median);
    }

    #[test]
    fn a_noise_law_growing_with_r_trusts_late_measurements_less() {
        let law = FeatureNoise::<f64> {
            floor: 1e-4,
            growth: 4e-3,
        };
        // E[floor + growth r^2] over r ~ N(0.5, 0.01).
        assert!((law.expected_variance(0.5, 0.01) - (1e-4 + 4e-3 * 0.26)).abs() < 1e-12);
        let gp = flat_gp();
        let mut constant = filter(&gp);
        let before = constant.clone();
        assert!(
            constant
                .set_feature_noise(FeatureNoise {
                    floor: 0.0,
                    growth: 1.0
                })
                .is_err()
        );
        assert!(
            constant
                .set_feature_noise(FeatureNoise {
                    floor: 1e-4,
                    growth: f64::NAN
                })
                .is_err()
        );
        assert_eq!(constant.feature_noise(), before.feature_noise());
        constant
            .set_feature_noise(FeatureNoise::constant(law.floor))
            .unwrap();
        let mut growing = constant.clone();
        growing.set_feature_noise(law).unwrap();
        // Both start at r = 0.9 with the same prior; one measurement 0.05 above the prior.
        for f in [&mut constant, &mut growing] {
            f.ukf.set_state(Vector2::new(0.9, 0.0)).unwrap();
            f.ukf
                .set_covariance(Matrix2::new(1e-3, 0.0, 0.0, 0.01))
                .unwrap();
            f.step(&Vector1::new(0.5), &[0.96]).unwrap();
        }
        let (c, g) = (constant.state()[0], growing.state()[0]);
        // Prior mean 0.91. Constant R = 1e-4: gain about 0.9; growing R about 3.4e-3: gain
        // about 0.23.
        assert!(
            c > 0.95 && g < 0.93 && g > 0.91,
            "constant {c}, growing {g}"
        );
        // At r near 0 the law is the floor and both filters agree.
        let mut a = filter(&gp);
        a.set_feature_noise(FeatureNoise::constant(law.floor))
            .unwrap();
        let mut b = a.clone();
        b.set_feature_noise(law).unwrap();
        a.step(&Vector1::new(0.5), &[0.02]).unwrap();
        b.step(&Vector1::new(0.5), &[0.02]).unwrap();
        assert!((a.state()[0] - b.state()[0]).abs() < 1e-4);
    }

    #[test]
    fn bad_input_is_rejected_and_leaves_the_filter_unchanged() {
        let gp = flat_gp();
        let mut f = filter(&gp);
        f.step(&Vector1::new(0.5), &[0.01]).unwrap();
        let before = (*f.state(), *f.covariance());
        assert_eq!(
            f.step(&Vector1::new(0.5), &[f64::NAN]).map(|_| ()),
            Err(Error::NonFiniteMeasurement)
        );
        assert_eq!(
            f.step(&Vector1::new(f64::INFINITY), &[0.01]).map(|_| ()),
            Err(Error::NonFiniteInput)
        );
        assert_eq!(
            f.step(&Vector1::new(0.5), &[0.01, 0.02]).map(|_| ()),
            Err(Error::MeasurementLength {
                expected: 1,
                got: 2
            })
        );
        assert_eq!((*f.state(), *f.covariance()), before);
        // A wild rate is clamped, not overflowed.
        let t = f.transition();
        let x: Vector2<f64> = <RateScaledTransition<'_, f64, 2, 1> as Model<f64, 2, 1>>::step(
            t,
            &Vector2::new(0.5, 1e6),
            &Vector1::new(0.5),
            1.0,
        );
        assert!(x.iter().all(|v| v.is_finite()));
        assert!(
            RateScaledGpUkf::<f64, 2, 1, 2, 1, 5>::new(
                *t,
                Vector2::zeros(),
                Matrix2::identity(),
                -1.0,
                0.0,
                SigmaParams::default()
            )
            .is_err()
        );
    }
}
