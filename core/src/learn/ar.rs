//! Autoregressive (AR) models of signals: recursive least squares (RLS), the overdetermined
//! recursive instrumental variable method (ORIV, Friedlander 1984; Barbieri et al. 2021,
//! Algorithm 1, Eqs. 1-13), FPE/MDL order criteria (Eqs. 14-16) and the AR power spectrum.
//!
//! Conventions follow the paper: `y(t) + a_1 y(t-1) + ... + a_n y(t-n) = e(t)`, regressor
//! `phi(t) = [-y(t-1) .. -y(t-n)]`, parameters `theta = [a_1 .. a_n]`.
//!
//! Sizes (f32, n = q = 8): [`Oriv`] holds `theta` (8), `P` (8x8), `R` (16x8), `rho` (16) and a
//! lag history of 32 samples: about 0.8 KB; it never allocates.

use crate::error::Error;
use crate::real::{Real, cast};
use crate::safeguard::{Flags, guarded_div, symmetrise};
use nalgebra::{Matrix2, SMatrix, SVector, Vector2};

/// An identified AR model of order `N`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ArModel<T: Real, const N: usize> {
    /// `[a_1 .. a_n]` of `A(z^-1) = 1 + a_1 z^-1 + ... + a_n z^-n`.
    pub theta: SVector<T, N>,
    /// Driving-noise variance estimate: the mean squared residual `J` (Eq. 16).
    pub noise_variance: T,
    /// Number of residuals `J` was averaged over (the `N` of Eqs. 14-16).
    pub residual_count: usize,
}

impl<T: Real, const N: usize> ArModel<T, N> {
    /// The same polynomial with unit driving-noise variance: the spectral *shape* that the
    /// edge transmits (only `theta` crosses the network).
    pub fn with_unit_variance(&self) -> Self {
        Self {
            noise_variance: T::one(),
            ..*self
        }
    }

    /// Final prediction error, Eq. (14).
    pub fn fpe(&self) -> Result<T, Error> {
        final_prediction_error(self.noise_variance, N, self.residual_count)
    }

    /// Minimum description length, Eq. (15).
    pub fn mdl(&self) -> Result<T, Error> {
        minimum_description_length(self.noise_variance, N, self.residual_count)
    }

    /// Power spectral density at normalised angular frequency `omega` (rad/sample), see
    /// [`power_spectrum`].
    pub fn spectrum(&self, omega: T) -> T {
        power_spectrum(&self.theta, self.noise_variance, omega)
    }
}

/// AR power spectral density `sigma^2 / |A(e^{j omega})|^2` at normalised angular frequency
/// `omega` in rad/sample (`omega = 2 pi f / f_s`). Two-sided convention: the mean over
/// `omega` in `[0, pi]` equals the process variance. Returns `+inf` on a zero of `A`.
pub fn power_spectrum<T: Real, const N: usize>(
    theta: &SVector<T, N>,
    noise_variance: T,
    omega: T,
) -> T {
    let (s1, c1) = omega.sin_cos();
    // e^{-j k omega} by repeated rotation: one sin/cos pair per call (trig is costly on the M4F).
    let (mut ck, mut sk) = (c1, s1);
    let (mut re, mut im) = (T::one(), T::zero());
    for &a in theta.iter() {
        re += a * ck;
        im -= a * sk;
        let next_c = ck * c1 - sk * s1;
        sk = sk * c1 + ck * s1;
        ck = next_c;
    }
    let mag2 = re * re + im * im;
    if mag2 > T::zero() {
        noise_variance / mag2
    } else {
        T::MAX_FINITE
    }
}

/// Final prediction error `(N + n) / (N - n) * J`, Eq. (14).
pub fn final_prediction_error<T: Real>(loss: T, order: usize, count: usize) -> Result<T, Error> {
    if count <= order {
        return Err(Error::InsufficientData);
    }
    let (nn, n): (T, T) = (cast(count as f64), cast(order as f64));
    Ok((nn + n) / (nn - n) * loss)
}

/// Minimum description length `N log J + n log N`, Eq. (15).
pub fn minimum_description_length<T: Real>(
    loss: T,
    order: usize,
    count: usize,
) -> Result<T, Error> {
    if count <= order || loss.partial_cmp(&T::zero()) != Some(core::cmp::Ordering::Greater) {
        return Err(Error::InsufficientData);
    }
    let (nn, n): (T, T) = (cast(count as f64), cast(order as f64));
    Ok(nn * loss.ln() + n * nn.ln())
}

/// The order with the smallest criterion value among `(order, value)` pairs (first on ties).
pub fn best_order<T: Real>(criteria: impl IntoIterator<Item = (usize, T)>) -> Option<usize> {
    let mut best: Option<(usize, T)> = None;
    for (order, value) in criteria {
        if !value.finite() {
            continue;
        }
        match best {
            Some((_, b)) if value >= b => {}
            _ => best = Some((order, value)),
        }
    }
    best.map(|(order, _)| order)
}

/// Combined FPE/MDL choice: the more parsimonious of the two minimisers (MDL is consistent,
/// FPE tends to over-fit; taking the smaller keeps the model the PLC must identify small).
pub fn combined_order(fpe_order: usize, mdl_order: usize) -> usize {
    fpe_order.min(mdl_order)
}

/// Classic recursive least squares for `y = phi^T theta + e`, initialised with
/// `theta = 0`, `P = psi I`.
#[derive(Clone, Copy, Debug)]
pub struct Rls<T: Real, const N: usize> {
    theta: SVector<T, N>,
    p: SMatrix<T, N, N>,
}

impl<T: Real, const N: usize> Rls<T, N> {
    /// New estimator; `psi` must be positive and finite.
    pub fn new(psi: T) -> Result<Self, Error> {
        if !(psi.finite() && psi > T::zero()) {
            return Err(Error::InvalidParameter("psi"));
        }
        Ok(Self {
            theta: SVector::zeros(),
            p: SMatrix::identity() * psi,
        })
    }

    /// Current estimate.
    pub fn theta(&self) -> &SVector<T, N> {
        &self.theta
    }

    /// One update with regressor `phi` and sample `y`. Non-finite data leaves it unchanged.
    pub fn update(&mut self, phi: &SVector<T, N>, y: T) -> Result<(), Error> {
        if !y.finite() || !phi.iter().all(|v| v.finite()) {
            return Err(Error::NonFiniteMeasurement);
        }
        let p_phi = self.p * phi;
        let denom = T::one() + phi.dot(&p_phi);
        if !(denom.finite() && denom > T::zero()) {
            return Err(Error::NotPositiveDefinite);
        }
        let gain = p_phi / denom;
        let theta = self.theta + gain * (y - phi.dot(&self.theta));
        let p = self.p - gain * p_phi.transpose();
        let p = (p + p.transpose()) * cast::<T>(0.5);
        if !theta.iter().chain(p.iter()).all(|v| v.finite()) {
            return Err(Error::NonFiniteState);
        }
        self.theta = theta;
        self.p = p;
        Ok(())
    }
}

/// Identifies an AR(`N`) model from a window by recursive least squares (the `q = 0`,
/// no-instrument baseline). Same checks and residual statistics as [`identify`].
pub fn identify_ls<T: Real, const N: usize, I>(samples: I, psi: T) -> Result<ArModel<T, N>, Error>
where
    I: Iterator<Item = T> + Clone,
{
    check_window(samples.clone(), &WindowCheck::default())?;
    let mut rls = Rls::<T, N>::new(psi)?;
    let mut lags = SVector::<T, N>::zeros();
    for (seen, y) in samples.clone().enumerate() {
        if seen >= N {
            rls.update(&(-lags), y)?;
        }
        lags = shift_in(&lags, y).0;
    }
    residual_model(samples, rls.theta)
}

/// Settings of ORIV (Algorithm 1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OrivConfig<T: Real> {
    /// Initial `P(0) = psi I` (Eq. 13); the paper uses 10.
    pub psi: T,
    /// Extra delay `d` of the instruments: `[-y(t-1-d) .. -y(t-n-q-d)]`. The paper's Eq. (6)
    /// is `d = 0`. With additive white measurement noise the equation error is MA(n), so
    /// `d >= n` makes the estimate consistent. At most `n + q`.
    pub instrument_delay: usize,
}

impl<T: Real> Default for OrivConfig<T> {
    fn default() -> Self {
        Self {
            psi: cast(10.0),
            instrument_delay: 0,
        }
    }
}

/// What one ORIV update did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct OrivReport<T> {
    /// One-step prediction error `y - phi^T theta` with the estimate before the update.
    pub innovation: T,
    /// Its variance, `sigma^2 (1 + phi^T P phi)`, with `sigma^2` the running mean of the
    /// normalised squared prediction errors (the first update uses `sigma^2 = 1`).
    pub innovation_variance: T,
    /// `innovation^2 / innovation_variance` (about chi-square with 1 dof when the model fits).
    pub test_ratio: T,
    /// False while the lag history is still filling (before `tau_0`): nothing was estimated.
    pub fused: bool,
    /// Safeguards that acted (`P` symmetrised beyond round-off).
    pub flags: Flags,
}

/// Overdetermined recursive instrumental variable estimator (Algorithm 1) for AR(`N`) with
/// `Q` extra instruments. The instrument vector `[-y(t-1-d) .. -y(t-N-Q-d)]` is stored in two
/// blocks (`N` and `Q` rows) so that both sizes stay plain const generics.
#[derive(Clone, Copy, Debug)]
pub struct Oriv<T: Real, const N: usize, const Q: usize> {
    theta: SVector<T, N>,
    p: SMatrix<T, N, N>,
    r_head: SMatrix<T, N, N>,
    r_tail: SMatrix<T, Q, N>,
    rho_head: SVector<T, N>,
    rho_tail: SVector<T, Q>,
    // Lags 1..2(N+Q) in four blocks of N, Q, N, Q samples (newest first).
    lag_a: SVector<T, N>,
    lag_b: SVector<T, Q>,
    lag_c: SVector<T, N>,
    lag_d: SVector<T, Q>,
    seen: usize,
    delay: usize,
    updates: usize,
    // Sum of `e^2 / (1 + phi^T P phi)` over the updates (noise level for the test ratio).
    normalised_error_sum: T,
}

impl<T: Real, const N: usize, const Q: usize> Oriv<T, N, Q> {
    /// New estimator initialised as Eq. (13): `theta = 0`, `P = psi I`, `rho = 0`, `R = 0`.
    pub fn new(config: &OrivConfig<T>) -> Result<Self, Error> {
        if N == 0 {
            return Err(Error::InvalidParameter("order"));
        }
        if !(config.psi.finite() && config.psi > T::zero()) {
            return Err(Error::InvalidParameter("psi"));
        }
        if config.instrument_delay > N.saturating_add(Q) {
            return Err(Error::InvalidParameter("instrument_delay"));
        }
        Ok(Self {
            theta: SVector::zeros(),
            p: SMatrix::identity() * config.psi,
            r_head: SMatrix::zeros(),
            r_tail: SMatrix::zeros(),
            rho_head: SVector::zeros(),
            rho_tail: SVector::zeros(),
            lag_a: SVector::zeros(),
            lag_b: SVector::zeros(),
            lag_c: SVector::zeros(),
            lag_d: SVector::zeros(),
            seen: 0,
            delay: config.instrument_delay,
            updates: 0,
            normalised_error_sum: T::zero(),
        })
    }

    /// Current estimate `theta(t)`.
    pub fn theta(&self) -> &SVector<T, N> {
        &self.theta
    }

    /// Number of parameter updates so far (samples from `tau_0 = n + q + d + 1` on).
    pub fn updates(&self) -> usize {
        self.updates
    }

    fn lag(&self, k: usize) -> T {
        // k is 1-based; the four blocks hold lags 1..=2(N+Q).
        let pick = |v: Option<&T>| v.copied().unwrap_or_else(T::zero);
        if k == 0 {
            T::zero()
        } else if k <= N {
            pick(self.lag_a.get(k.saturating_sub(1)))
        } else if k <= N.saturating_add(Q) {
            pick(self.lag_b.get(k.saturating_sub(N).saturating_sub(1)))
        } else if k <= N.saturating_mul(2).saturating_add(Q) {
            pick(
                self.lag_c
                    .get(k.saturating_sub(N).saturating_sub(Q).saturating_sub(1)),
            )
        } else {
            pick(
                self.lag_d.get(
                    k.saturating_sub(N.saturating_mul(2))
                        .saturating_sub(Q)
                        .saturating_sub(1),
                ),
            )
        }
    }

    fn push_lag(&mut self, y: T) {
        let (a, out) = shift_in(&self.lag_a, y);
        let (b, out) = shift_in(&self.lag_b, out);
        let (c, out) = shift_in(&self.lag_c, out);
        let (d, _) = shift_in(&self.lag_d, out);
        self.lag_a = a;
        self.lag_b = b;
        self.lag_c = c;
        self.lag_d = d;
        self.seen = self.seen.saturating_add(1);
    }

    /// One ORIV step (Algorithm 1, steps 1-9) with the new sample `y(t)`. Before `tau_0` it
    /// only fills the lag history. A non-finite sample, a singular 2x2 gain system or a
    /// non-finite result returns `Err` and leaves the estimator unchanged.
    pub fn update(&mut self, y: T) -> Result<OrivReport<T>, Error> {
        if !y.finite() {
            return Err(Error::NonFiniteMeasurement);
        }
        if self.seen < N.saturating_add(Q).saturating_add(self.delay) {
            self.push_lag(y);
            return Ok(OrivReport::default());
        }
        let phi: SVector<T, N> = SVector::from_fn(|i, _| -self.lag(i.saturating_add(1)));
        let z_head: SVector<T, N> =
            SVector::from_fn(|i, _| -self.lag(i.saturating_add(1).saturating_add(self.delay)));
        let z_tail: SVector<T, Q> = SVector::from_fn(|i, _| {
            -self.lag(
                i.saturating_add(1)
                    .saturating_add(N)
                    .saturating_add(self.delay),
            )
        });
        // 1-4
        let eta = self.r_head.tr_mul(&z_head) + self.r_tail.tr_mul(&z_tail);
        let big_phi = SMatrix::<T, N, 2>::from_columns(&[eta, phi]);
        let zz = z_head.norm_squared() + z_tail.norm_squared();
        let lambda = Matrix2::new(-zz, T::one(), T::one(), T::zero());
        let v = Vector2::new(z_head.dot(&self.rho_head) + z_tail.dot(&self.rho_tail), y);
        // 5: K = P Phi [Lambda + Phi^T P Phi]^-1
        let p_phi = self.p * big_phi;
        let s = lambda + big_phi.tr_mul(&p_phi);
        let s_inv = invert_2x2(&s)?;
        let gain = p_phi * s_inv;
        // 6-9
        let theta = self.theta + gain * (v - big_phi.tr_mul(&self.theta));
        let mut p = self.p - gain * p_phi.transpose();
        let mut flags = Flags::NONE;
        if symmetrise(&mut p) {
            flags.insert(Flags::COVARIANCE_SYMMETRISED);
        }
        if !theta.iter().chain(p.iter()).all(|x| x.finite()) {
            return Err(Error::NonFiniteState);
        }
        let innovation = y - phi.dot(&self.theta);
        let spread = T::one() + phi.dot(&(self.p * phi));
        let sigma2 = if self.updates == 0 {
            T::one()
        } else {
            self.normalised_error_sum / cast::<T>(self.updates as f64)
        };
        let innovation_variance = sigma2 * spread;
        let test_ratio = guarded_div(
            innovation * innovation,
            innovation_variance,
            T::MIN_POSITIVE,
        );
        let normalised_error_sum = self.normalised_error_sum
            + guarded_div(innovation * innovation, spread, T::MIN_POSITIVE);
        if !(normalised_error_sum.finite() && test_ratio.finite()) {
            return Err(Error::NonFiniteState);
        }
        self.normalised_error_sum = normalised_error_sum;
        self.theta = theta;
        self.p = p;
        self.r_head += z_head * phi.transpose();
        self.r_tail += z_tail * phi.transpose();
        self.rho_head += z_head * y;
        self.rho_tail += z_tail * y;
        self.updates = self.updates.saturating_add(1);
        self.push_lag(y);
        Ok(OrivReport {
            innovation,
            innovation_variance,
            test_ratio,
            fused: true,
            flags,
        })
    }
}

fn invert_2x2<T: Real>(s: &Matrix2<T>) -> Result<Matrix2<T>, Error> {
    let (a, b, c, d) = (s.m11, s.m12, s.m21, s.m22);
    let det = a * d - b * c;
    let scale = (a * d).abs() + (b * c).abs();
    if !(det.finite() && scale.finite()) || det.abs() <= scale * T::EPSILON || det == T::zero() {
        return Err(Error::OutOfRange("ORIV gain system (singular)"));
    }
    Ok(Matrix2::new(d, -b, -c, a) / det)
}

/// Shifts `x` into the front of `block`; returns the new block and the sample pushed out of
/// the back (`x` itself for an empty block).
fn shift_in<T: Real, const M: usize>(block: &SVector<T, M>, x: T) -> (SVector<T, M>, T) {
    if M == 0 {
        return (*block, x);
    }
    let out = block.get(M.saturating_sub(1)).copied().unwrap_or(x);
    let shifted = SVector::from_fn(|i, _| {
        if i == 0 {
            x
        } else {
            block
                .get(i.saturating_sub(1))
                .copied()
                .unwrap_or_else(T::zero)
        }
    });
    (shifted, out)
}

/// What [`check_window`] rejects.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WindowCheck<T: Real> {
    /// A window whose variance is at or below this (in signal units squared) is flat.
    pub min_variance: T,
    /// A window with more than this fraction of samples pinned at its maximum or minimum
    /// value is saturated (clipped by the sensor or the converter).
    pub max_pinned_fraction: T,
}

impl<T: Real> Default for WindowCheck<T> {
    fn default() -> Self {
        Self {
            min_variance: cast(1e-12),
            max_pinned_fraction: cast(0.05),
        }
    }
}

/// Rejects a window that cannot give a meaningful AR model: non-finite samples
/// (`NonFiniteMeasurement`), too few samples (`InsufficientData`), a flat window
/// (`OutOfRange("signal window (flat)")`) or a saturated one
/// (`OutOfRange("signal window (saturated)")`).
pub fn check_window<T: Real, I: Iterator<Item = T> + Clone>(
    samples: I,
    check: &WindowCheck<T>,
) -> Result<(), Error> {
    let (mut count, mut sum) = (0usize, T::zero());
    let (mut lo, mut hi) = (T::MAX_FINITE, -T::MAX_FINITE);
    for y in samples.clone() {
        if !y.finite() {
            return Err(Error::NonFiniteMeasurement);
        }
        count = count.saturating_add(1);
        sum += y;
        lo = lo.min(y);
        hi = hi.max(y);
    }
    if count < 2 {
        return Err(Error::InsufficientData);
    }
    let n: T = cast(count as f64);
    let mean = sum / n;
    let variance = samples
        .clone()
        .fold(T::zero(), |acc, y| acc + (y - mean) * (y - mean))
        / n;
    let relative_floor = mean * mean * cast(1e-12);
    if variance <= check.min_variance || variance <= relative_floor {
        return Err(Error::OutOfRange("signal window (flat)"));
    }
    let tolerance = (hi - lo) * cast(1e-9);
    let pinned = samples
        .filter(|&y| y >= hi - tolerance || y <= lo + tolerance)
        .count();
    if cast::<T>(pinned as f64) > check.max_pinned_fraction * n && pinned > 2 {
        return Err(Error::OutOfRange("signal window (saturated)"));
    }
    Ok(())
}

/// Identifies an AR(`N`) model of a window by ORIV with `Q` extra instruments, then computes
/// the residual loss `J` (Eq. 16) over the same window with the final estimate. The window is
/// first screened by [`check_window`]; any failure returns `Err` and no model.
pub fn identify<T: Real, const N: usize, const Q: usize, I>(
    samples: I,
    config: &OrivConfig<T>,
    check: &WindowCheck<T>,
) -> Result<ArModel<T, N>, Error>
where
    I: Iterator<Item = T> + Clone,
{
    check_window(samples.clone(), check)?;
    let mut oriv = Oriv::<T, N, Q>::new(config)?;
    for y in samples.clone() {
        oriv.update(y)?;
    }
    if oriv.updates() == 0 {
        return Err(Error::InsufficientData);
    }
    residual_model(samples, oriv.theta)
}

/// Residual loss of `theta` over the samples that have all `N` lags.
fn residual_model<T: Real, const N: usize, I: Iterator<Item = T>>(
    samples: I,
    theta: SVector<T, N>,
) -> Result<ArModel<T, N>, Error> {
    let mut lags = SVector::<T, N>::zeros();
    let (mut seen, mut count, mut sum) = (0usize, 0usize, T::zero());
    for y in samples {
        if seen >= N {
            let e = y + lags.dot(&theta);
            sum += e * e;
            count = count.saturating_add(1);
        }
        lags = shift_in(&lags, y).0;
        seen = seen.saturating_add(1);
    }
    if count == 0 {
        return Err(Error::InsufficientData);
    }
    let loss = sum / cast(count as f64);
    if !loss.finite() || !theta.iter().all(|v| v.finite()) {
        return Err(Error::NonFiniteState);
    }
    Ok(ArModel {
        theta,
        noise_variance: loss,
        residual_count: count,
    })
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use crate::random::standard_normal;
    use core::f64::consts::PI;
    use rand_core::SeedableRng;
    use rand_xoshiro::Xoshiro256PlusPlus;
    use std::vec::Vec;

    /// Simulates `y(t) = -sum a_k y(t-k) + e(t)` (unit-variance e) after a burn-in, plus an
    /// additive MA(1) measurement noise `v(t) = noise_std (w(t) + ma w(t-1))`.
    fn simulate<const N: usize>(
        theta: [f64; N],
        len: usize,
        noise_std: f64,
        ma: f64,
        seed: u64,
    ) -> Vec<f64> {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        let mut out = Vec::with_capacity(len);
        let mut lags = [0.0; N];
        let mut w_prev = 0.0;
        for t in 0..(len + 500) {
            let e: f64 = standard_normal(&mut rng);
            let x = e - theta.iter().zip(&lags).map(|(a, y)| a * y).sum::<f64>();
            lags.rotate_right(1);
            lags[0] = x;
            let w: f64 = standard_normal(&mut rng);
            let v = noise_std * (w + ma * w_prev);
            w_prev = w;
            if t >= 500 {
                out.push(x + v);
            }
        }
        out
    }

    fn max_abs_error<const N: usize>(estimate: &SVector<f64, N>, truth: &[f64; N]) -> f64 {
        estimate
            .iter()
            .zip(truth)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max)
    }

    /// A(z) with poles 0.9 e^{+-j pi/4} and 0.7 e^{+-j 2pi/3}.
    fn ar4_truth() -> [f64; 4] {
        let (r1, w1, r2, w2) = (0.9f64, PI / 4.0, 0.7f64, 2.0 * PI / 3.0);
        let p = [1.0, -2.0 * r1 * w1.cos(), r1 * r1];
        let q = [1.0, -2.0 * r2 * w2.cos(), r2 * r2];
        let mut a = [0.0; 5];
        for i in 0..3 {
            for j in 0..3 {
                a[i + j] += p[i] * q[j];
            }
        }
        [a[1], a[2], a[3], a[4]]
    }

    #[test]
    fn rls_and_oriv_recover_ar4_coefficients() {
        let truth = ar4_truth();
        let len = 20_000;
        let y = simulate(truth, len, 0.0, 0.0, 11);
        let window = y[..len].iter().copied();
        let ls: ArModel<f64, 4> = identify_ls(window.clone(), 10.0).unwrap();
        let oriv: ArModel<f64, 4> =
            identify::<f64, 4, 4, _>(window, &OrivConfig::default(), &WindowCheck::default())
                .unwrap();
        assert!(max_abs_error(&ls.theta, &truth) < 0.03, "{:?}", ls.theta);
        assert!(
            max_abs_error(&oriv.theta, &truth) < 0.03,
            "{:?}",
            oriv.theta
        );
        // Unit driving noise: the residual loss estimates it.
        assert!((ls.noise_variance - 1.0).abs() < 0.05);
        assert!((oriv.noise_variance - 1.0).abs() < 0.05);
    }

    #[test]
    fn oriv_is_consistent_under_coloured_measurement_noise_where_ls_is_biased() {
        // AR(2) seen through MA(1) measurement noise: the equation error is MA(3), so plain
        // LS is biased and ORIV with instruments delayed by d = n + 1 = 3 is consistent.
        let truth = [-1.5, 0.8];
        let len = 100_000;
        let y = simulate(truth, len, 1.5, 0.8, 5);
        let window = y[..len].iter().copied();
        let ls: ArModel<f64, 2> = identify_ls(window.clone(), 10.0).unwrap();
        let config = OrivConfig {
            psi: 10.0,
            instrument_delay: 3,
        };
        let oriv: ArModel<f64, 2> =
            identify::<f64, 2, 2, _>(window, &config, &WindowCheck::default()).unwrap();
        let ls_err = max_abs_error(&ls.theta, &truth);
        let iv_err = max_abs_error(&oriv.theta, &truth);
        assert!(ls_err > 0.15, "LS should be biased, error {ls_err}");
        assert!(iv_err < 0.05, "ORIV error {iv_err}, theta {:?}", oriv.theta);
    }

    #[test]
    fn oriv_in_f32_recovers_ar2() {
        let truth = [-1.5, 0.8];
        let y = simulate(truth, 6144, 0.0, 0.0, 3);
        let window = y[..6144].iter().map(|&v| v as f32);
        let m: ArModel<f32, 2> =
            identify::<f32, 2, 2, _>(window, &OrivConfig::default(), &WindowCheck::default())
                .unwrap();
        assert!((m.theta[0] + 1.5).abs() < 0.05 && (m.theta[1] - 0.8).abs() < 0.05);
    }

    macro_rules! criteria_for_orders {
        ($window:expr, $($n:literal),*) => {{
            let mut fpe = [(0usize, 0.0f64); 6];
            let mut mdl = [(0usize, 0.0f64); 6];
            let mut slot = 0;
            $(
                let m: ArModel<f64, $n> = identify::<f64, $n, $n, _>(
                    $window.clone(), &OrivConfig::default(), &WindowCheck::default()).unwrap();
                fpe[slot] = ($n, m.fpe().unwrap());
                mdl[slot] = ($n, m.mdl().unwrap());
                slot += 1;
            )*
            let _ = slot;
            (fpe, mdl)
        }};
    }

    #[test]
    fn fpe_and_mdl_pick_the_true_order() {
        // AR(3) with a strong third coefficient, as many samples as the edge buffer holds.
        let truth = [-0.6, 0.3, 0.5];
        for seed in [1u64, 2, 3] {
            let y = simulate(truth, 3072, 0.0, 0.0, seed);
            let window = y[..3072].iter().copied();
            let (fpe, mdl) = criteria_for_orders!(window, 1, 2, 3, 4, 5, 6);
            let mdl_order = best_order(mdl).unwrap();
            let fpe_order = best_order(fpe).unwrap();
            assert_eq!(mdl_order, 3, "seed {seed}: {mdl:?}");
            assert!(fpe_order >= 3, "seed {seed}: {fpe:?}");
            assert_eq!(combined_order(fpe_order, mdl_order), 3);
        }
    }

    #[test]
    fn criteria_match_their_formulas() {
        let fpe: f64 = final_prediction_error(2.0, 2, 10).unwrap();
        assert!((fpe - 2.0 * 12.0 / 8.0).abs() < 1e-12);
        let mdl: f64 = minimum_description_length(2.0, 2, 10).unwrap();
        assert!((mdl - (10.0 * 2f64.ln() + 2.0 * 10f64.ln())).abs() < 1e-12);
        assert!(final_prediction_error(1.0f64, 5, 5).is_err());
        assert!(minimum_description_length(0.0f64, 1, 5).is_err());
    }

    #[test]
    fn spectrum_matches_analytic_ar1_and_ar2() {
        let a = 0.6;
        let m1 = SVector::<f64, 1>::new(a);
        let (r, w0) = (0.8f64, 1.1f64);
        let (a1, a2) = (-2.0 * r * w0.cos(), r * r);
        let m2 = SVector::<f64, 2>::new(a1, a2);
        for i in 0..=64 {
            let w = PI * i as f64 / 64.0;
            let s1 = power_spectrum(&m1, 2.0, w);
            let exact1 = 2.0 / (1.0 + a * a + 2.0 * a * w.cos());
            assert!((s1 - exact1).abs() < 1e-12 * exact1);
            // |A|^2 for AR(2) as a closed-form trigonometric polynomial.
            let mag2 = 1.0
                + a1 * a1
                + a2 * a2
                + 2.0 * a1 * (1.0 + a2) * w.cos()
                + 2.0 * a2 * (2.0 * w).cos();
            let s2 = power_spectrum(&m2, 1.0, w);
            assert!((s2 - 1.0 / mag2).abs() < 1e-10 / mag2);
        }
        // Parseval: the mean of the spectrum over [0, pi] is the AR(1) variance s^2/(1-a^2).
        let k = 20_000;
        let mean = (0..k)
            .map(|i| power_spectrum(&m1, 2.0, PI * (i as f64 + 0.5) / k as f64))
            .sum::<f64>()
            / k as f64;
        assert!((mean - 2.0 / (1.0 - a * a)).abs() < 1e-6);
    }

    #[test]
    fn flat_saturated_and_nan_windows_are_rejected() {
        let check = WindowCheck::<f64>::default();
        let cfg = OrivConfig::default();
        let flat = [0.25f64; 3072];
        assert_eq!(
            identify::<f64, 8, 8, _>(flat.iter().copied(), &cfg, &check),
            Err(Error::OutOfRange("signal window (flat)"))
        );
        // A sine clipped at +-0.5: a third of the samples sit on the rails.
        let clipped: [f64; 3072] =
            core::array::from_fn(|i| (0.3 * i as f64).sin().clamp(-0.5, 0.5));
        assert_eq!(
            identify::<f64, 8, 8, _>(clipped.iter().copied(), &cfg, &check),
            Err(Error::OutOfRange("signal window (saturated)"))
        );
        let mut with_nan = simulate(ar4_truth(), 3072, 0.0, 0.0, 9);
        with_nan[100] = f64::NAN;
        assert_eq!(
            identify::<f64, 8, 8, _>(with_nan[..3072].iter().copied(), &cfg, &check),
            Err(Error::NonFiniteMeasurement)
        );
        // A healthy signal passes.
        let good = simulate(ar4_truth(), 3072, 0.0, 0.0, 9);
        assert!(check_window(good[..3072].iter().copied(), &check).is_ok());
    }

    #[test]
    fn oriv_rejects_bad_sample_and_parameters_unchanged() {
        let mut oriv = Oriv::<f64, 2, 2>::new(&OrivConfig::default()).unwrap();
        let y = simulate([-1.5, 0.8], 200, 0.0, 0.0, 4);
        for &v in &y[..200] {
            oriv.update(v).unwrap();
        }
        let before = *oriv.theta();
        assert_eq!(oriv.update(f64::INFINITY), Err(Error::NonFiniteMeasurement));
        assert_eq!(*oriv.theta(), before);
        assert!(
            Oriv::<f64, 2, 2>::new(&OrivConfig {
                psi: -1.0,
                instrument_delay: 0
            })
            .is_err()
        );
        assert!(
            Oriv::<f64, 2, 2>::new(&OrivConfig {
                psi: 10.0,
                instrument_delay: 5
            })
            .is_err()
        );
    }
}
