//! Health indicators from AR models of signals (Barbieri et al. 2021, Eqs. 17-19) and the
//! piecewise exponential-then-polynomial degradation model of the indicator (Eqs. 30-33).

use crate::error::Error;
use crate::learn::ar::{ArModel, power_spectrum};
use crate::model::{Model, Stochastic, gaussian_log_likelihood};
use crate::random::normal;
use crate::real::{Real, cast};
use nalgebra::{SVector, Vector2, Vector4};
use rand_core::Rng;

/// `HI_NRMSE = sqrt(||theta - theta_nom|| / ||theta_nom||)`, Eq. (17), the local indicator the
/// edge computes. `Err(InvalidParameter)` when the reference is zero or not finite.
pub fn nrmse<T: Real, const N: usize>(
    theta: &SVector<T, N>,
    reference: &SVector<T, N>,
) -> Result<T, Error> {
    let norm_ref = reference.norm();
    if !(norm_ref.finite() && norm_ref > T::zero()) {
        return Err(Error::InvalidParameter("reference model"));
    }
    let value = ((theta - reference).norm() / norm_ref).sqrt();
    if value.finite() {
        Ok(value)
    } else {
        Err(Error::NonFiniteState)
    }
}

/// The midpoint frequency grid of `points` samples on `(0, pi)` the spectral distances
/// integrate over (their mean approximates `1/pi` times the integral).
fn grid_frequency<T: Real>(i: usize, points: usize) -> T {
    T::pi() * cast::<T>((i as f64 + 0.5) / points as f64)
}

/// Itakura-Saito divergence `D(1|0)` of Eq. (19), averaged over normalised frequency on a
/// `points`-sample midpoint grid of `(0, pi)` (the paper leaves the frequency integral
/// implicit). Not symmetric.
pub fn itakura_saito<T: Real, const N: usize>(
    model: &ArModel<T, N>,
    reference: &ArModel<T, N>,
    points: usize,
) -> Result<T, Error> {
    spectral_mean(model, reference, points, |r| r - r.ln() - T::one())
}

/// Symmetric Itakura-Saito distance `HI_I-S = (D(1|0) + D(0|1)) / 2`, Eq. (18): the mean of
/// `(r + 1/r) / 2 - 1` with `r = S_1 / S_0`. Zero for identical spectra, symmetric, positive.
pub fn symmetric_itakura_saito<T: Real, const N: usize>(
    model: &ArModel<T, N>,
    reference: &ArModel<T, N>,
    points: usize,
) -> Result<T, Error> {
    let half: T = cast(0.5);
    spectral_mean(model, reference, points, |r| {
        half * (r + T::one() / r) - T::one()
    })
}

fn spectral_mean<T: Real, const N: usize>(
    model: &ArModel<T, N>,
    reference: &ArModel<T, N>,
    points: usize,
    term: impl Fn(T) -> T,
) -> Result<T, Error> {
    if points == 0 {
        return Err(Error::InvalidParameter("points"));
    }
    let mut acc = T::zero();
    for i in 0..points {
        let w = grid_frequency::<T>(i, points);
        let s1 = power_spectrum(&model.theta, model.noise_variance, w);
        let s0 = power_spectrum(&reference.theta, reference.noise_variance, w);
        if !(s1 > T::zero() && s0 > T::zero() && s1 < T::MAX_FINITE && s0 < T::MAX_FINITE) {
            return Err(Error::OutOfRange("AR spectrum"));
        }
        acc += term(s1 / s0);
    }
    let value = acc / cast(points as f64);
    if value.finite() {
        Ok(value)
    } else {
        Err(Error::NonFiniteState)
    }
}

/// The two stages of Eq. (30).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DegradationStage {
    /// `HI = a exp(b (t - t_prog))` with `a = T_prog`.
    Exponential,
    /// `HI = c (t - T_change)^2 + d` with `d = HI(T_change)`.
    Polynomial,
}

/// The operating point of [`PiecewiseHiModel`] at one time step, packed into the model input
/// vector `u = [stage, t - t_prog, t - T_change, d]` (times in the model's time unit).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StageInput<T: Real> {
    pub stage: DegradationStage,
    /// Time since prognosis was triggered.
    pub since_trigger: T,
    /// Time since the change point (zero in the exponential stage).
    pub since_change: T,
    /// `d = HI(T_change)` (unused in the exponential stage).
    pub change_level: T,
}

impl<T: Real> StageInput<T> {
    /// Packs into the model input vector.
    pub fn to_input(&self) -> Vector4<T> {
        let stage = match self.stage {
            DegradationStage::Exponential => T::zero(),
            DegradationStage::Polynomial => T::one(),
        };
        Vector4::new(
            stage,
            self.since_trigger,
            self.since_change,
            self.change_level,
        )
    }

    fn from_input(u: &Vector4<T>) -> Self {
        let stage = if u.x > cast(0.5) {
            DegradationStage::Polynomial
        } else {
            DegradationStage::Exponential
        };
        Self {
            stage,
            since_trigger: u.y,
            since_change: u.z,
            change_level: u.w,
        }
    }
}

/// Piecewise degradation model of the smoothed HI (Eqs. 30-33) for joint parameter learning
/// with a particle filter. State `x = [b, c]`; both are positive random walks (Eqs. 32-33)
/// conditioned on positivity by reflection at zero. Only the parameter of the current stage
/// walks: the filter learns `b` first and `c` after the change.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PiecewiseHiModel<T: Real> {
    /// `a = T_prog`, the trigger threshold the exponential starts from.
    pub trigger_level: T,
    /// Standard deviation of the random walk of `b` per step (`sqrt(1e-5)` in the paper).
    pub b_walk_std: T,
    /// Standard deviation of the random walk of `c` per step (`sqrt(1e-5)` in the paper).
    pub c_walk_std: T,
    /// Measurement noise std of the smoothed HI relative to its observed value.
    pub relative_noise: T,
    /// Floor of the measurement noise std (HI units).
    pub absolute_noise: T,
}

impl<T: Real> PiecewiseHiModel<T> {
    /// The HI the parameters `x = [b, c]` predict at operating point `input`.
    pub fn predict(&self, x: &Vector2<T>, input: &StageInput<T>) -> T {
        match input.stage {
            DegradationStage::Exponential => self.trigger_level * (x.x * input.since_trigger).exp(),
            DegradationStage::Polynomial => {
                x.y * input.since_change * input.since_change + input.change_level
            }
        }
    }

    /// Time from `input` until the HI these parameters predict reaches `threshold`, in closed
    /// form (zero when it is already there). `T::MAX_FINITE` when it never does (`b` or `c`
    /// not positive).
    pub fn time_to_threshold(&self, x: &Vector2<T>, input: &StageInput<T>, threshold: T) -> T {
        let remaining = match input.stage {
            DegradationStage::Exponential => {
                if x.x.partial_cmp(&T::zero()) != Some(core::cmp::Ordering::Greater)
                    || self.trigger_level.partial_cmp(&T::zero())
                        != Some(core::cmp::Ordering::Greater)
                {
                    return T::MAX_FINITE;
                }
                (threshold / self.trigger_level).ln() / x.x - input.since_trigger
            }
            DegradationStage::Polynomial => {
                let rise = threshold - input.change_level;
                if rise <= T::zero() {
                    return T::zero();
                }
                if x.y.partial_cmp(&T::zero()) != Some(core::cmp::Ordering::Greater) {
                    return T::MAX_FINITE;
                }
                (rise / x.y).sqrt() - input.since_change
            }
        };
        if remaining.finite() {
            remaining.max(T::zero())
        } else {
            T::MAX_FINITE
        }
    }
}

impl<T: Real> Model<T, 2, 4> for PiecewiseHiModel<T> {
    fn step(&self, x: &Vector2<T>, _u: &Vector4<T>, _dt: T) -> Vector2<T> {
        *x
    }
}

impl<T: Real> Stochastic<T, 2, 4> for PiecewiseHiModel<T> {
    fn measurement_len(&self) -> usize {
        1
    }

    fn sample_step<R: Rng + ?Sized>(
        &self,
        x: &Vector2<T>,
        u: &Vector4<T>,
        _dt: T,
        rng: &mut R,
    ) -> Vector2<T> {
        match StageInput::from_input(u).stage {
            DegradationStage::Exponential => {
                Vector2::new(normal(rng, x.x, self.b_walk_std).abs(), x.y)
            }
            DegradationStage::Polynomial => {
                Vector2::new(x.x, normal(rng, x.y, self.c_walk_std).abs())
            }
        }
    }

    fn log_likelihood(&self, x: &Vector2<T>, u: &Vector4<T>, y: &[T]) -> T {
        let input = StageInput::from_input(u);
        let predicted = self.predict(x, &input);
        let observed = y.first().copied().unwrap_or_else(T::zero);
        let std = self.relative_noise * observed.abs() + self.absolute_noise;
        let ll = gaussian_log_likelihood(&[observed], &[predicted], &[std]);
        if ll.finite() { ll } else { -T::MAX_FINITE }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::f64::consts::PI;

    fn model<const N: usize>(theta: [f64; N], var: f64) -> ArModel<f64, N> {
        ArModel {
            theta: SVector::from_column_slice(&theta),
            noise_variance: var,
            residual_count: 1000,
        }
    }

    #[test]
    fn nrmse_matches_formula() {
        let a = SVector::<f64, 2>::new(3.0, 4.0);
        let b = SVector::<f64, 2>::new(3.0, 5.0);
        let hi = nrmse(&b, &a).unwrap();
        assert!((hi - (1.0f64 / 5.0).sqrt()).abs() < 1e-15);
        assert_eq!(nrmse(&a, &a).unwrap(), 0.0);
        assert!(nrmse(&a, &SVector::zeros()).is_err());
    }

    #[test]
    fn itakura_saito_zero_for_identical_and_symmetric() {
        let m0 = model([-1.2, 0.5, 0.1], 1.0);
        let m1 = model([-0.4, 0.2, -0.3], 1.0);
        assert!(symmetric_itakura_saito(&m0, &m0, 256).unwrap().abs() < 1e-15);
        assert!(itakura_saito(&m0, &m0, 256).unwrap().abs() < 1e-15);
        let d01 = symmetric_itakura_saito(&m0, &m1, 256).unwrap();
        let d10 = symmetric_itakura_saito(&m1, &m0, 256).unwrap();
        assert!(d01 > 0.1);
        assert!((d01 - d10).abs() < 1e-12 * d01);
        // The one-sided divergence is not symmetric, and the symmetric one is their mean.
        let a = itakura_saito(&m1, &m0, 256).unwrap();
        let b = itakura_saito(&m0, &m1, 256).unwrap();
        assert!((a - b).abs() > 1e-3);
        assert!((0.5 * (a + b) - d01).abs() < 1e-12 * d01);
    }

    #[test]
    fn itakura_saito_of_ar1_against_white_noise_matches_closed_form() {
        // S1 = 1/|1 + a e^{-jw}|^2, S0 = 1: the mean of r + 1/r over [0, pi] is
        // 1/(1-a^2) + (1 + a^2), so HI = (1/(1-a^2) + 1 + a^2)/2 - 1.
        let a = 0.5;
        let m1 = model([a], 1.0);
        let m0 = model([0.0], 1.0);
        let hi = symmetric_itakura_saito(&m1, &m0, 4096).unwrap();
        let exact = 0.5 * (1.0 / (1.0 - a * a) + 1.0 + a * a) - 1.0;
        assert!((hi - exact).abs() < 1e-9, "{hi} vs {exact}");
        // A pure gain change sigma^2 = g: HI = (g + 1/g)/2 - 1 at every frequency.
        let hi_gain = symmetric_itakura_saito(&model([0.3], 4.0), &model([0.3], 1.0), 64).unwrap();
        assert!((hi_gain - (0.5 * (4.0 + 0.25) - 1.0)).abs() < 1e-12);
        let _ = PI;
    }

    #[test]
    fn piecewise_model_predicts_and_inverts() {
        let m = PiecewiseHiModel {
            trigger_level: 0.1,
            b_walk_std: 0.0,
            c_walk_std: 0.0,
            relative_noise: 0.1,
            absolute_noise: 0.01,
        };
        let x = Vector2::new(0.2, 0.5);
        let exp = StageInput {
            stage: DegradationStage::Exponential,
            since_trigger: 3.0,
            since_change: 0.0,
            change_level: 0.0,
        };
        assert!((m.predict(&x, &exp) - 0.1 * 0.6f64.exp()).abs() < 1e-15);
        let t = m.time_to_threshold(&x, &exp, 10.0);
        assert!((t - (100f64.ln() / 0.2 - 3.0)).abs() < 1e-12);
        let poly = StageInput {
            stage: DegradationStage::Polynomial,
            since_trigger: 10.0,
            since_change: 1.0,
            change_level: 2.0,
        };
        assert!((m.predict(&x, &poly) - 2.5).abs() < 1e-15);
        let t = m.time_to_threshold(&x, &poly, 10.0);
        assert!((t - (4.0 - 1.0)).abs() < 1e-12);
        assert_eq!(
            m.time_to_threshold(&Vector2::new(0.0, 0.5), &exp, 10.0),
            f64::MAX
        );
        // Round trip through the input vector.
        assert_eq!(StageInput::from_input(&poly.to_input()), poly);
    }
}
