//! Fixed-size Gaussian-process predictor (squared-exponential ARD kernel, Anger et al. 2012
//! Eqs. 5-7) whose weights are trained on the host and shipped as constants, and the GP-UKF of
//! their Table 2 built on [`crate::filter::ukf::Ukf`].
//!
//! The host computes, for `M` training (or inducing) inputs `X`, the lower Cholesky factor
//! `L L^T = K(X, X) + sigma_n^2 I` and `alpha = (K + sigma_n^2 I)^-1 (y - m)` with a constant
//! mean `m` (a sparse GP, e.g. FITC with `M` inducing inputs, fits the same form with its own
//! `alpha` and `L L^T = C`; see the bearing host training). On board the mean is
//! `m + k_*^T alpha` (Eq. 6) and the latent variance
//! `k(x_*, x_*) - |L^-1 k_*|^2` (Eq. 7): one kernel row and one triangular solve, no
//! allocation. Size: `(M (D + 1) + M^2 + 3 D + 4) * size_of::<T>()` bytes (M = 64, D = 2, f32:
//! about 17 KB; keep it in a `static`).

use crate::error::Error;
use crate::filter::imm::{ModeFilter, ModeUpdate};
use crate::filter::ukf::{SigmaParams, Ukf};
use crate::model::{Model, Observe, Stochastic};
use crate::prognose::{EndOfLife, PredictionSettings, predict_eol};
use crate::random::standard_normal;
use crate::real::{Real, all_finite, cast};
use crate::safeguard::Flags;
use nalgebra::{Cholesky, SMatrix, SVector};
use rand_core::Rng;

/// Squared-exponential kernel with automatic relevance determination (Eq. 5 with
/// `W = diag(1 / l_d^2)`), and the observation noise of Eq. 4.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SeArd<T: Real, const D: usize> {
    /// Length scale `l_d` of each input.
    pub length_scales: SVector<T, D>,
    /// Signal variance `sigma_f^2`.
    pub signal_variance: T,
    /// Noise variance `sigma_n^2`.
    pub noise_variance: T,
}

impl<T: Real, const D: usize> SeArd<T, D> {
    /// `k(a, b) = sigma_f^2 exp(-1/2 sum ((a_d - b_d) / l_d)^2)`.
    pub fn kernel(&self, a: &SVector<T, D>, b: &SVector<T, D>) -> T {
        let mut q = T::zero();
        for ((&ai, &bi), &l) in a.iter().zip(b.iter()).zip(self.length_scales.iter()) {
            let z = (ai - bi) / l;
            q += z * z;
        }
        self.signal_variance * (-(q * cast(0.5))).exp()
    }

    fn validate(&self) -> Result<(), Error> {
        if !self
            .length_scales
            .iter()
            .all(|&l| l.finite() && l > T::zero())
        {
            return Err(Error::InvalidParameter("GP length scales"));
        }
        if !(self.signal_variance.finite() && self.signal_variance > T::zero()) {
            return Err(Error::InvalidParameter("GP signal variance"));
        }
        if !(self.noise_variance.finite() && self.noise_variance >= T::zero()) {
            return Err(Error::InvalidParameter("GP noise variance"));
        }
        Ok(())
    }
}

/// One GP prediction.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct GpPrediction<T> {
    /// Predictive mean (Eq. 6 plus the constant mean).
    pub mean: T,
    /// Latent (function) variance (Eq. 7), widened when extrapolating.
    pub latent_variance: T,
    /// Observation noise variance `sigma_n^2` learned with the GP.
    pub noise_variance: T,
    /// The query lay outside the training inputs by more than the allowed margin: the mean is
    /// the GP's mean at the nearest point of the training box, the variance is widened.
    pub extrapolating: bool,
    /// Squared distance outside the training box, in length scales.
    pub outside: T,
}

impl<T: Real> GpPrediction<T> {
    /// Variance of a new noisy output: latent plus noise.
    pub fn variance(&self) -> T {
        self.latent_variance + self.noise_variance
    }
}

/// A GP with `M` stored inputs of dimension `D`.
#[derive(Clone, Debug, PartialEq)]
pub struct GaussianProcess<T: Real, const D: usize, const M: usize> {
    kernel: SeArd<T, D>,
    inputs: [SVector<T, D>; M],
    alpha: SVector<T, M>,
    chol_lower: SMatrix<T, M, M>,
    mean_offset: T,
    lower: SVector<T, D>,
    upper: SVector<T, D>,
    margin: T,
}

impl<T: Real, const D: usize, const M: usize> GaussianProcess<T, D, M> {
    /// Builds the predictor from host-trained weights given in f64 (the form they are shipped
    /// in as constants): `inputs[i]` the training inputs, `alpha`, the row-major lower
    /// Cholesky factor of `K + sigma_n^2 I`, and the constant mean. Checks that everything is
    /// finite and the factor has a positive diagonal. The allowed extrapolation margin is half
    /// a length scale ([`GaussianProcess::set_margin`]).
    pub fn from_f64(
        length_scales: &[f64; D],
        signal_variance: f64,
        noise_variance: f64,
        inputs: &[[f64; D]; M],
        alpha: &[f64; M],
        chol_lower: &[[f64; M]; M],
        mean_offset: f64,
    ) -> Result<Self, Error> {
        let kernel = SeArd {
            length_scales: SVector::from_fn(|i, _| {
                cast(length_scales.get(i).copied().unwrap_or(f64::NAN))
            }),
            signal_variance: cast(signal_variance),
            noise_variance: cast(noise_variance),
        };
        kernel.validate()?;
        let mut pts = [SVector::<T, D>::zeros(); M];
        for (p, row) in pts.iter_mut().zip(inputs.iter()) {
            for (v, &r) in p.iter_mut().zip(row.iter()) {
                *v = cast(r);
            }
        }
        let mut a = SVector::<T, M>::zeros();
        for (v, &r) in a.iter_mut().zip(alpha.iter()) {
            *v = cast(r);
        }
        let mut l = SMatrix::<T, M, M>::zeros();
        for (i, row) in chol_lower.iter().enumerate() {
            for (j, &r) in row.iter().enumerate().take(i.saturating_add(1)) {
                if let Some(v) = l.get_mut((i, j)) {
                    *v = cast(r);
                }
            }
        }
        Self::new(kernel, pts, a, l, cast(mean_offset))
    }

    /// Builds the predictor from weights already in `T`.
    pub fn new(
        kernel: SeArd<T, D>,
        inputs: [SVector<T, D>; M],
        alpha: SVector<T, M>,
        chol_lower: SMatrix<T, M, M>,
        mean_offset: T,
    ) -> Result<Self, Error> {
        kernel.validate()?;
        if M == 0 {
            return Err(Error::InsufficientData);
        }
        if !inputs.iter().all(|p| all_finite(p.as_slice()))
            || !all_finite(alpha.as_slice())
            || !all_finite(chol_lower.as_slice())
            || !mean_offset.finite()
        {
            return Err(Error::InvalidParameter("GP weights are not finite"));
        }
        if !chol_lower.diagonal().iter().all(|&d| d > T::zero()) {
            return Err(Error::NotPositiveDefinite);
        }
        let mut lower = SVector::<T, D>::repeat(T::MAX_FINITE);
        let mut upper = SVector::<T, D>::repeat(-T::MAX_FINITE);
        for p in inputs.iter() {
            for ((lo, hi), &v) in lower.iter_mut().zip(upper.iter_mut()).zip(p.iter()) {
                *lo = lo.min(v);
                *hi = hi.max(v);
            }
        }
        Ok(Self {
            kernel,
            inputs,
            alpha,
            chol_lower,
            mean_offset,
            lower,
            upper,
            margin: cast(0.5),
        })
    }

    /// How far (in length scales) a query may leave the training box before it is flagged.
    pub fn set_margin(&mut self, margin: T) -> Result<(), Error> {
        if !(margin.finite() && margin >= T::zero()) {
            return Err(Error::InvalidParameter("GP margin"));
        }
        self.margin = margin;
        Ok(())
    }

    /// The kernel and noise hyperparameters.
    pub fn kernel(&self) -> &SeArd<T, D> {
        &self.kernel
    }

    /// Lowest and highest training input per dimension.
    pub fn input_box(&self) -> (&SVector<T, D>, &SVector<T, D>) {
        (&self.lower, &self.upper)
    }

    /// Mean and variance at `x` (Eqs. 6-7). Non-finite inputs are an error. A query more than
    /// the margin outside the training box is flagged `extrapolating`: its mean is taken at the
    /// nearest point of the box (no silent trend extrapolation) and its latent variance is
    /// raised to at least the prior variance, times `1 + distance^2` in length scales.
    pub fn predict(&self, x: &SVector<T, D>) -> Result<GpPrediction<T>, Error> {
        if !all_finite(x.as_slice()) {
            return Err(Error::NonFiniteInput);
        }
        let mut query = *x;
        let mut outside = T::zero();
        for (((q, &lo), &hi), &l) in query
            .iter_mut()
            .zip(self.lower.iter())
            .zip(self.upper.iter())
            .zip(self.kernel.length_scales.iter())
        {
            let excess = if *q < lo {
                lo - *q
            } else if *q > hi {
                *q - hi
            } else {
                T::zero()
            };
            let z = excess / l;
            outside += z * z;
            *q = q.max(lo).min(hi);
        }
        let extrapolating = outside > self.margin * self.margin;
        let point = if extrapolating { &query } else { x };
        let mut k_star = SVector::<T, M>::zeros();
        for (k, xi) in k_star.iter_mut().zip(self.inputs.iter()) {
            *k = self.kernel.kernel(point, xi);
        }
        let mean = self.mean_offset + k_star.dot(&self.alpha);
        let v = self
            .chol_lower
            .solve_lower_triangular(&k_star)
            .ok_or(Error::NotPositiveDefinite)?;
        let prior = self.kernel.signal_variance;
        let mut latent = (prior - v.norm_squared()).max(T::zero());
        if extrapolating {
            latent = latent.max(prior) * (T::one() + outside);
        }
        Ok(GpPrediction {
            mean,
            latent_variance: latent,
            noise_variance: self.kernel.noise_variance,
            extrapolating,
            outside,
        })
    }
}

/// The non-finite value a transition returns when the GP rejects a query.
fn diverged<T: Real>() -> T {
    T::MAX_FINITE * cast(2.0)
}

/// Compile-time check that the GP input is the state followed by the input.
struct InputSize<const D: usize, const NX: usize, const NU: usize>;
impl<const D: usize, const NX: usize, const NU: usize> InputSize<D, NX, NU> {
    const OK: () = assert!(D == NX + NU, "GP input size D must equal NX + NU");
}

/// GP input `(x, u)`.
pub fn gp_input<T: Real, const D: usize, const NX: usize, const NU: usize>(
    x: &SVector<T, NX>,
    u: &SVector<T, NU>,
) -> SVector<T, D> {
    let () = InputSize::<D, NX, NU>::OK;
    let mut v = SVector::<T, D>::zeros();
    for (dst, src) in v.iter_mut().zip(x.iter().chain(u.iter())) {
        *dst = *src;
    }
    v
}

/// Dynamic GP transition (Eqs. 9-11): state entry `i` advances by the mean of GP `i`
/// evaluated at `(x, u)`. The measurement is the state itself (Table 2, line 6) with standard
/// deviations `measurement_std` (used by [`Stochastic::log_likelihood`]).
#[derive(Clone, Copy, Debug)]
pub struct GpTransition<'a, T: Real, const D: usize, const M: usize, const NX: usize> {
    pub gps: [&'a GaussianProcess<T, D, M>; NX],
    pub measurement_std: SVector<T, NX>,
}

impl<'a, T: Real, const D: usize, const M: usize, const NX: usize> GpTransition<'a, T, D, M, NX> {
    /// Per-state predictions at `(x, u)`; `extrapolating` when any GP extrapolates.
    pub fn predict<const NU: usize>(
        &self,
        x: &SVector<T, NX>,
        u: &SVector<T, NU>,
    ) -> Result<(SVector<T, NX>, SVector<T, NX>, bool), Error> {
        let input = gp_input::<T, D, NX, NU>(x, u);
        let mut mean = SVector::<T, NX>::zeros();
        let mut var = SVector::<T, NX>::zeros();
        let mut extrapolating = false;
        for ((gp, m), v) in self.gps.iter().zip(mean.iter_mut()).zip(var.iter_mut()) {
            let p = gp.predict(&input)?;
            *m = p.mean;
            *v = p.variance();
            extrapolating |= p.extrapolating;
        }
        Ok((mean, var, extrapolating))
    }
}

impl<T: Real, const D: usize, const M: usize, const NX: usize, const NU: usize> Model<T, NX, NU>
    for GpTransition<'_, T, D, M, NX>
{
    /// `x + GP_mu(x, u)`; NaN when the GP rejects the query (the filter then reports
    /// [`Error::NonFiniteState`]). `dt` is one cycle by construction of the training data.
    fn step(&self, x: &SVector<T, NX>, u: &SVector<T, NU>, _dt: T) -> SVector<T, NX> {
        match self.predict(x, u) {
            Ok((mean, _, _)) => x + mean,
            Err(_) => SVector::repeat(diverged::<T>()),
        }
    }
}

impl<T: Real, const D: usize, const M: usize, const NX: usize, const NU: usize>
    Observe<T, NX, NU, NX> for GpTransition<'_, T, D, M, NX>
{
    fn observe(&self, x: &SVector<T, NX>, _u: &SVector<T, NU>) -> SVector<T, NX> {
        *x
    }
}

impl<T: Real, const D: usize, const M: usize, const NX: usize, const NU: usize>
    Stochastic<T, NX, NU> for GpTransition<'_, T, D, M, NX>
{
    fn measurement_len(&self) -> usize {
        NX
    }

    /// One draw from the GP's predictive distribution: `x + mean + sqrt(var) N(0, 1)`.
    fn sample_step<R: Rng + ?Sized>(
        &self,
        x: &SVector<T, NX>,
        u: &SVector<T, NU>,
        _dt: T,
        rng: &mut R,
    ) -> SVector<T, NX> {
        match self.predict(x, u) {
            Ok((mean, var, _)) => {
                let mut next = x + mean;
                for (n, v) in next.iter_mut().zip(var.iter()) {
                    *n += v.sqrt() * standard_normal::<T, R>(rng);
                }
                next
            }
            Err(_) => SVector::repeat(diverged::<T>()),
        }
    }

    fn log_likelihood(&self, x: &SVector<T, NX>, _u: &SVector<T, NU>, y: &[T]) -> T {
        crate::model::gaussian_log_likelihood(y, x.as_slice(), self.measurement_std.as_slice())
    }
}

/// What one GP-UKF step did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GpUkfReport<T: Real, const NX: usize> {
    pub innovation: SVector<T, NX>,
    pub innovation_cov: SMatrix<T, NX, NX>,
    /// `ln N(innovation; 0, S)`, the mode likelihood of the IMM (Table 3, line 7).
    pub log_likelihood: T,
    /// Normalised innovation squared `e^T S^-1 e` (the test ratio, chi-square with NX dof).
    pub nis: T,
    /// Whether the measurement was fused (false when the UKF's gate rejected it).
    pub fused: bool,
    /// The GP was queried outside its training range at the prior mean.
    pub extrapolating: bool,
    pub flags: Flags,
}

/// GP-UKF (Table 2): the lead's UKF with the GP mean as transition and the GP variance at the
/// prior mean as process noise `Q_k`; the measurement is the state with noise covariance `R`.
#[derive(Clone, Debug)]
pub struct GpUkf<
    'a,
    T: Real,
    const NX: usize,
    const NU: usize,
    const D: usize,
    const M: usize,
    const NS: usize,
> {
    ukf: Ukf<T, NX, NS>,
    transition: GpTransition<'a, T, D, M, NX>,
    r: SMatrix<T, NX, NX>,
}

impl<'a, T: Real, const NX: usize, const NU: usize, const D: usize, const M: usize, const NS: usize>
    GpUkf<'a, T, NX, NU, D, M, NS>
{
    /// A GP-UKF with prior `N(x0, p0)` and measurement noise `r`.
    pub fn new(
        transition: GpTransition<'a, T, D, M, NX>,
        x0: SVector<T, NX>,
        p0: SMatrix<T, NX, NX>,
        r: SMatrix<T, NX, NX>,
        params: SigmaParams<T>,
    ) -> Result<Self, Error> {
        if !all_finite(r.as_slice()) || Cholesky::new(r).is_none() {
            return Err(Error::InvalidParameter("r"));
        }
        let ukf = Ukf::new(x0, p0, SMatrix::zeros(), params)?;
        Ok(Self { ukf, transition, r })
    }

    pub fn state(&self) -> &SVector<T, NX> {
        self.ukf.state()
    }
    pub fn covariance(&self) -> &SMatrix<T, NX, NX> {
        self.ukf.covariance()
    }
    pub fn transition(&self) -> &GpTransition<'a, T, D, M, NX> {
        &self.transition
    }

    /// The prediction of one cycle with input `u` (Table 2, lines 2-4), on a copy: the
    /// predicted filter, its flags and whether the GP extrapolated.
    fn predicted(&self, u: &SVector<T, NU>) -> Result<(Ukf<T, NX, NS>, Flags, bool), Error> {
        if !all_finite(u.as_slice()) {
            return Err(Error::NonFiniteInput);
        }
        // Table 2, line 3: Q_k from the GP variance at the prior mean.
        let (_, var, extrapolating) = self.transition.predict(self.ukf.state(), u)?;
        let q = SMatrix::<T, NX, NX>::from_diagonal(&var);
        let mut ukf = self.ukf.clone();
        ukf.set_process_noise(q)?;
        let flags = ukf.predict(&self.transition, u, T::one())?;
        Ok((ukf, flags, extrapolating))
    }

    /// A cycle without a measurement: the prediction alone. Errors leave the filter
    /// unchanged; returns whether the GP extrapolated.
    pub fn predict_only(&mut self, u: &SVector<T, NU>) -> Result<bool, Error> {
        let (ukf, _, extrapolating) = self.predicted(u)?;
        self.ukf = ukf;
        Ok(extrapolating)
    }

    /// One cycle: predict with input `u` (the load difference of the cycle that just ended),
    /// then fuse measurement `z`. Errors leave the filter unchanged.
    pub fn step(&mut self, u: &SVector<T, NU>, z: &[T]) -> Result<GpUkfReport<T, NX>, Error> {
        if z.len() != NX {
            return Err(Error::MeasurementLength {
                expected: NX,
                got: z.len(),
            });
        }
        if !all_finite(z) {
            return Err(Error::NonFiniteMeasurement);
        }
        let (mut ukf, mut flags, extrapolating) = self.predicted(u)?;
        let report = ukf.update(&self.transition, u, z, &self.r)?;
        flags.insert(report.flags);
        let chol = Cholesky::new(report.innovation_cov).ok_or(Error::NotPositiveDefinite)?;
        let log_det = chol
            .l()
            .diagonal()
            .iter()
            .fold(T::zero(), |a, &d| a + d.ln())
            * cast(2.0);
        let two_pi: T = cast(core::f64::consts::TAU);
        let log_likelihood =
            -(report.nis + log_det + cast::<T>(NX as f64) * two_pi.ln()) * cast(0.5);
        self.ukf = ukf;
        Ok(GpUkfReport {
            innovation: report.innovation,
            innovation_cov: report.innovation_cov,
            log_likelihood,
            nis: report.nis,
            fused: report.fused,
            extrapolating,
            flags,
        })
    }
}

impl<T: Real, const NX: usize, const NU: usize, const D: usize, const M: usize, const NS: usize>
    ModeFilter<T, NX> for GpUkf<'_, T, NX, NU, D, M, NS>
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

/// End of life when state entry `index` reaches `level` (the failure threshold r_feat = 1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StateThreshold<T> {
    pub index: usize,
    pub level: T,
}

impl<T: Real, const NX: usize> EndOfLife<T, NX> for StateThreshold<T> {
    fn reached(&self, x: &SVector<T, NX>) -> bool {
        x.get(self.index).is_none_or(|&v| !(v < self.level))
    }
}

/// RUL samples of a GP model (a [`GpTransition`] or the rate-scaled
/// [`super::gp_rate::RateScaledTransition`]) from the estimate `N(mean, cov)`: draws `states.len()` states,
/// propagates each with draws from the GP predictive distribution until the threshold (or
/// `max_steps` cycles), and writes each one's cycles to failure into `times` (`MAX_FINITE`
/// beyond the horizon). Summarise with [`crate::prognose::rul_distribution`]. Returns how many
/// samples reached the threshold.
#[allow(clippy::too_many_arguments)]
pub fn sample_rul<T, G, E, F, R, const NX: usize, const NU: usize>(
    transition: &G,
    mean: &SVector<T, NX>,
    cov: &SMatrix<T, NX, NX>,
    eol: &E,
    future_input: F,
    max_steps: u32,
    rng: &mut R,
    states: &mut [SVector<T, NX>],
    times: &mut [T],
) -> Result<usize, Error>
where
    T: Real,
    G: Stochastic<T, NX, NU>,
    E: EndOfLife<T, NX>,
    F: FnMut(u32) -> SVector<T, NU>,
    R: Rng + ?Sized,
{
    if !all_finite(mean.as_slice()) || !all_finite(cov.as_slice()) {
        return Err(Error::NonFiniteState);
    }
    let l = Cholesky::new(*cov).ok_or(Error::NotPositiveDefinite)?.l();
    for s in states.iter_mut() {
        let z = SVector::<T, NX>::from_fn(|_, _| standard_normal::<T, R>(rng));
        *s = mean + l * z;
    }
    let settings = PredictionSettings {
        dt: T::one(),
        max_steps,
        process_noise: true,
        random_walk_std: SVector::zeros(),
    };
    predict_eol(transition, eol, states, future_input, &settings, rng, times)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Vector1, Vector2};

    fn one_point_gp() -> GaussianProcess<f64, 2, 1> {
        // One training point (0, 0) with y = 2, sf^2 = 1, sn^2 = 0.25, mean 0.5:
        // alpha = (2 - 0.5) / 1.25, L = sqrt(1.25).
        GaussianProcess::from_f64(
            &[1.0, 2.0],
            1.0,
            0.25,
            &[[0.0, 0.0]],
            &[1.5 / 1.25],
            &[[1.25f64.sqrt()]],
            0.5,
        )
        .unwrap()
    }

    #[test]
    fn one_point_gp_matches_closed_form() {
        let gp = one_point_gp();
        let x = Vector2::new(0.3, -0.4);
        let k = (-0.5 * (0.3f64.powi(2) + (0.4f64 / 2.0).powi(2))).exp();
        let p = gp.predict(&x).unwrap();
        assert!((p.mean - (0.5 + k * 1.5 / 1.25)).abs() < 1e-12);
        assert!((p.latent_variance - (1.0 - k * k / 1.25)).abs() < 1e-12);
        assert!(!p.extrapolating);
    }

    #[test]
    fn extrapolation_is_flagged_and_widened_and_nan_rejected() {
        let gp = one_point_gp();
        let far = gp.predict(&Vector2::new(3.0, 0.0)).unwrap();
        assert!(far.extrapolating);
        // Mean taken at the box (the training point), variance above the prior.
        assert!((far.mean - 2.0 + 1.5 * (1.0 - 1.0 / 1.25)).abs() < 1e-12);
        assert!(far.latent_variance >= 1.0 * (1.0 + 9.0) - 1e-12);
        assert_eq!(
            gp.predict(&Vector2::new(f64::NAN, 0.0)),
            Err(Error::NonFiniteInput)
        );
        let bad = GaussianProcess::<f64, 2, 1>::from_f64(
            &[1.0, -1.0],
            1.0,
            0.1,
            &[[0.0, 0.0]],
            &[1.0],
            &[[1.0]],
            0.0,
        );
        assert!(bad.is_err());
    }

    #[test]
    fn gp_ukf_rejects_bad_measurements_unchanged_and_works_in_f32() {
        let gp32 = GaussianProcess::<f32, 2, 1>::from_f64(
            &[1.0, 1.0],
            1e-4,
            1e-6,
            &[[0.5, 0.5]],
            &[0.0],
            &[[1.0e-2]],
            0.01,
        )
        .unwrap();
        let transition = GpTransition {
            gps: [&gp32],
            measurement_std: Vector1::new(0.05f32),
        };
        let mut f: GpUkf<f32, 1, 1, 2, 1, 3> = GpUkf::new(
            transition,
            Vector1::new(0.5),
            nalgebra::Matrix1::new(0.01),
            nalgebra::Matrix1::new(0.0025),
            SigmaParams::default(),
        )
        .unwrap();
        let before = (*f.state(), *f.covariance());
        assert_eq!(
            f.step(&Vector1::new(0.5), &[f32::NAN]).map(|_| ()),
            Err(Error::NonFiniteMeasurement)
        );
        assert_eq!(
            f.step(&Vector1::new(f32::INFINITY), &[0.5]).map(|_| ()),
            Err(Error::NonFiniteInput)
        );
        assert_eq!((*f.state(), *f.covariance()), before);
        let rep = f.step(&Vector1::new(0.5), &[0.52]).unwrap();
        assert!(rep.log_likelihood.is_finite());
        // Prior mean 0.51, so the estimate lies between it and the measurement.
        assert!(f.state()[0] > 0.51 && f.state()[0] < 0.52);
    }
}
