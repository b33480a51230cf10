//! Unscented Kalman filter with a const-generic sigma-point count, in the form of van der
//! Merwe's scaled unscented transform (the form filterpy's `UnscentedKalmanFilter` uses: the
//! prediction ends by drawing fresh sigma points from the prior mean and covariance, Q
//! included, and the update transforms those through the measurement function; reusing the
//! propagated points would leave Q out of the innovation and cross covariances).
//!
//! Joint state-parameter estimation augments the state with the parameters: the model leaves
//! them constant and `Q` gives them a random-walk variance.

use crate::error::{Error, check_dt};
use crate::model::{Model, Observe};
use crate::real::{Real, all_finite, cast};
use crate::safeguard::{Flags, symmetrise};
use nalgebra::{Cholesky, SMatrix, SVector};

/// Scaled unscented transform parameters (alpha, beta, kappa).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SigmaParams<T> {
    pub alpha: T,
    pub beta: T,
    pub kappa: T,
}

impl<T: Real> Default for SigmaParams<T> {
    /// alpha = 1e-3 is customary but numerically delicate in f32; 0.5 is a robust default.
    fn default() -> Self {
        Self {
            alpha: cast(0.5),
            beta: cast(2.0),
            kappa: T::zero(),
        }
    }
}

/// What one measurement update did (`NY` channels).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct UkfReport<T: Real, const NY: usize> {
    /// Innovation `y - h(x^-)`.
    pub innovation: SVector<T, NY>,
    /// Innovation covariance `S`.
    pub innovation_cov: SMatrix<T, NY, NY>,
    /// Normalised innovation squared `nu^T S^-1 nu` (chi-square with NY degrees of freedom).
    pub nis: T,
    /// Whether the measurement was fused (false when rejected by the gate).
    pub fused: bool,
    /// Safeguards that acted.
    pub flags: Flags,
}

/// UKF over an `NX`-dimensional state with `NS = 2 NX + 1` sigma points (checked at compile
/// time). Size: about `(3 NX + 2 NX^2 + NS (NX + 2)) * size_of::<T>()` bytes.
#[derive(Clone)]
pub struct Ukf<T: Real, const NX: usize, const NS: usize> {
    x: SVector<T, NX>,
    p: SMatrix<T, NX, NX>,
    q: SMatrix<T, NX, NX>,
    sigmas: [SVector<T, NX>; NS],
    wm: [T; NS],
    wc: [T; NS],
    lambda: T,
    /// The sigma points were drawn from the current prior (x, P) by the last prediction.
    propagated: bool,
    /// NIS gate: measurements with a larger NIS are rejected (`MAX_FINITE` disables it).
    gate: T,
}

/// Shows the estimate and the settings; the sigma-point cache (and its validity flag) is a
/// function of `(x, P)` and is left out, so that equal estimates print equally.
impl<T: Real, const NX: usize, const NS: usize> core::fmt::Debug for Ukf<T, NX, NS> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Ukf")
            .field("x", &self.x)
            .field("p", &self.p)
            .field("q", &self.q)
            .field("wm", &self.wm)
            .field("wc", &self.wc)
            .field("lambda", &self.lambda)
            .field("gate", &self.gate)
            .finish_non_exhaustive()
    }
}

impl<T: Real, const NX: usize, const NS: usize> Ukf<T, NX, NS> {
    const SIGMA_COUNT: () = assert!(NS == 2 * NX + 1, "a UKF needs NS = 2 NX + 1 sigma points");

    /// A filter with mean `x0`, covariance `p0`, process noise `q` and sigma-point parameters.
    /// `p0` must be positive definite and `q` symmetric positive semi-definite.
    pub fn new(
        x0: SVector<T, NX>,
        p0: SMatrix<T, NX, NX>,
        q: SMatrix<T, NX, NX>,
        params: SigmaParams<T>,
    ) -> Result<Self, Error> {
        let () = Self::SIGMA_COUNT;
        if !all_finite(x0.as_slice()) || !all_finite(p0.as_slice()) || !all_finite(q.as_slice()) {
            return Err(Error::InvalidParameter("x0, p0 or q is not finite"));
        }
        let n: T = cast(NX as f64);
        let (a, b, k) = (params.alpha, params.beta, params.kappa);
        if !(a > T::zero()) || !b.finite() || !k.finite() {
            return Err(Error::InvalidParameter("sigma parameters"));
        }
        let lambda = a * a * (n + k) - n;
        if !(n + lambda > T::zero()) {
            return Err(Error::InvalidParameter(
                "sigma parameters give n + lambda <= 0",
            ));
        }
        if Cholesky::new(p0).is_none() {
            return Err(Error::NotPositiveDefinite);
        }
        let w_rest = T::one() / (cast::<T>(2.0) * (n + lambda));
        let mut wm = [w_rest; NS];
        let mut wc = [w_rest; NS];
        if let (Some(m0), Some(c0)) = (wm.first_mut(), wc.first_mut()) {
            *m0 = lambda / (n + lambda);
            *c0 = lambda / (n + lambda) + (T::one() - a * a + b);
        }
        Ok(Self {
            x: x0,
            p: p0,
            q,
            sigmas: [x0; NS],
            wm,
            wc,
            lambda,
            propagated: false,
            gate: T::MAX_FINITE,
        })
    }

    /// State estimate.
    pub fn state(&self) -> &SVector<T, NX> {
        &self.x
    }
    /// State covariance.
    pub fn covariance(&self) -> &SMatrix<T, NX, NX> {
        &self.p
    }
    /// Process noise covariance.
    pub fn process_noise(&self) -> &SMatrix<T, NX, NX> {
        &self.q
    }
    /// Replaces the process noise (adaptive filters); must be finite.
    pub fn set_process_noise(&mut self, q: SMatrix<T, NX, NX>) -> Result<(), Error> {
        if !all_finite(q.as_slice()) {
            return Err(Error::InvalidParameter("q"));
        }
        self.q = q;
        Ok(())
    }
    /// Replaces the state covariance (e.g. covariance enhancement); must be positive definite.
    pub fn set_covariance(&mut self, p: SMatrix<T, NX, NX>) -> Result<(), Error> {
        if !all_finite(p.as_slice()) || Cholesky::new(p).is_none() {
            return Err(Error::NotPositiveDefinite);
        }
        self.p = p;
        self.propagated = false;
        Ok(())
    }
    /// Replaces the state estimate; must be finite.
    pub fn set_state(&mut self, x: SVector<T, NX>) -> Result<(), Error> {
        if !all_finite(x.as_slice()) {
            return Err(Error::InvalidParameter("x"));
        }
        self.x = x;
        self.propagated = false;
        Ok(())
    }
    /// Replaces state and covariance together (e.g. an IMM's mixing); an invalid pair is an
    /// error and changes neither.
    pub fn set_estimate(&mut self, x: SVector<T, NX>, p: SMatrix<T, NX, NX>) -> Result<(), Error> {
        if !all_finite(x.as_slice()) {
            return Err(Error::InvalidParameter("x"));
        }
        self.set_covariance(p)?;
        self.x = x;
        Ok(())
    }
    /// Sets the NIS gate (reject measurements whose NIS exceeds it).
    pub fn set_gate(&mut self, gate: T) {
        self.gate = if gate > T::zero() {
            gate
        } else {
            T::MAX_FINITE
        };
    }
    /// Mean weights of the sigma points.
    pub fn mean_weights(&self) -> &[T; NS] {
        &self.wm
    }
    /// Covariance weights of the sigma points.
    pub fn cov_weights(&self) -> &[T; NS] {
        &self.wc
    }

    /// Sigma points of `N(x, P)`: `x`, then `x +- columns of chol((n + lambda) P)`.
    /// Writes the sigma points of `(x, p)` into `out`; on error (`p` not positive definite)
    /// `out` is left as it was. Filling in place keeps the 2 NX + 1 points off the stack.
    fn fill_sigma_points(
        lambda: T,
        x: &SVector<T, NX>,
        p: &SMatrix<T, NX, NX>,
        out: &mut [SVector<T, NX>; NS],
    ) -> Result<(), Error> {
        let n: T = cast(NX as f64);
        let l = Cholesky::new(*p * (n + lambda))
            .ok_or(Error::NotPositiveDefinite)?
            .l();
        if let Some(first) = out.first_mut() {
            *first = *x;
        }
        for (k, col) in l.column_iter().enumerate() {
            if let Some(s) = out.get_mut(k.saturating_add(1)) {
                *s = x + col;
            }
            if let Some(s) = out.get_mut(NX.saturating_add(k).saturating_add(1)) {
                *s = x - col;
            }
        }
        Ok(())
    }

    /// Puts back an estimate saved before a failed step (crate-internal rollback: the
    /// values were the filter's own, so they are not checked again). The sigma-point cache is
    /// invalidated and rebuilt from `(x, p)` when next needed.
    pub(crate) fn restore_estimate(&mut self, x: SVector<T, NX>, p: SMatrix<T, NX, NX>) {
        self.x = x;
        self.p = p;
        self.propagated = false;
    }

    /// Time update through the model over `dt`. Errors (bad input, `dt`, a covariance that
    /// is not positive definite, a model that diverges) leave the filter unchanged.
    pub fn predict<M, const NU: usize>(
        &mut self,
        model: &M,
        u: &SVector<T, NU>,
        dt: T,
    ) -> Result<Flags, Error>
    where
        M: Model<T, NX, NU>,
    {
        check_dt(dt)?;
        if !all_finite(u.as_slice()) {
            return Err(Error::NonFiniteInput);
        }
        let mut pts = [self.x; NS];
        Self::fill_sigma_points(self.lambda, &self.x, &self.p, &mut pts)?;
        for s in pts.iter_mut() {
            *s = model.step(s, u, dt);
            if !all_finite(s.as_slice()) {
                return Err(Error::NonFiniteState);
            }
        }
        let mut x = SVector::<T, NX>::zeros();
        for (s, w) in pts.iter().zip(self.wm.iter()) {
            x += s * *w;
        }
        let mut p = self.q;
        for (s, w) in pts.iter().zip(self.wc.iter()) {
            let d = s - x;
            p += d * d.transpose() * *w;
        }
        let mut flags = Flags::NONE;
        if symmetrise(&mut p) {
            flags.insert(Flags::COVARIANCE_SYMMETRISED);
        }
        // Finite sigma points can still overflow in the outer products.
        if !all_finite(x.as_slice()) || !all_finite(p.as_slice()) {
            return Err(Error::NonFiniteState);
        }
        // The prior's sigma points go straight into the cache (left as it was on error).
        Self::fill_sigma_points(self.lambda, &x, &p, &mut self.sigmas)?;
        self.x = x;
        self.p = p;
        self.propagated = true;
        Ok(flags)
    }

    /// Measurement update with measurement `y` (length `NY`) and its noise covariance `r`.
    /// Errors leave the filter unchanged, including a posterior covariance that is not
    /// positive definite ([`Error::NotPositiveDefinite`]). A measurement whose NIS exceeds the gate is not
    /// fused (`fused = false`, [`Flags::MEASUREMENT_REJECTED`]).
    pub fn update<M, const NU: usize, const NY: usize>(
        &mut self,
        model: &M,
        u: &SVector<T, NU>,
        y: &[T],
        r: &SMatrix<T, NY, NY>,
    ) -> Result<UkfReport<T, NY>, Error>
    where
        M: Observe<T, NX, NU, NY>,
    {
        if y.len() != NY {
            return Err(Error::MeasurementLength {
                expected: NY,
                got: y.len(),
            });
        }
        if !all_finite(y) {
            return Err(Error::NonFiniteMeasurement);
        }
        if !all_finite(u.as_slice()) {
            return Err(Error::NonFiniteInput);
        }
        if !all_finite(r.as_slice()) {
            return Err(Error::InvalidParameter("r"));
        }
        let y = SVector::<T, NY>::from_iterator(y.iter().copied());
        // The cache holds the sigma points of the current (x, P) whenever `propagated`;
        // refilling it from (x, P) changes no estimate, so it may happen before an error.
        if !self.propagated {
            Self::fill_sigma_points(self.lambda, &self.x, &self.p, &mut self.sigmas)?;
            self.propagated = true;
        }
        let sigmas = &self.sigmas;
        let mut hs = [SVector::<T, NY>::zeros(); NS];
        for (h, s) in hs.iter_mut().zip(sigmas.iter()) {
            *h = model.observe(s, u);
            if !all_finite(h.as_slice()) {
                return Err(Error::NonFiniteState);
            }
        }
        let mut zp = SVector::<T, NY>::zeros();
        for (h, w) in hs.iter().zip(self.wm.iter()) {
            zp += h * *w;
        }
        let mut s_cov = *r;
        let mut pxz = SMatrix::<T, NX, NY>::zeros();
        for ((h, s), w) in hs.iter().zip(sigmas.iter()).zip(self.wc.iter()) {
            let dz = h - zp;
            s_cov += dz * dz.transpose() * *w;
            pxz += (s - self.x) * dz.transpose() * *w;
        }
        // Finite predicted measurements can still overflow in the outer products.
        if !all_finite(s_cov.as_slice()) || !all_finite(pxz.as_slice()) {
            return Err(Error::NonFiniteState);
        }
        let chol = Cholesky::new(s_cov).ok_or(Error::NotPositiveDefinite)?;
        let innovation = y - zp;
        let nis = innovation.dot(&chol.solve(&innovation));
        // An innovation too large to square (NaN from inf - inf or 0 * inf) is infinitely
        // implausible: it fails the gate below (flagged as rejected), never reaches the state.
        let nis = if nis.nan() { T::MAX_FINITE } else { nis };
        let mut report = UkfReport {
            innovation,
            innovation_cov: s_cov,
            nis,
            fused: false,
            flags: Flags::NONE,
        };
        if !(nis <= self.gate) {
            report.flags.insert(Flags::MEASUREMENT_REJECTED);
            return Ok(report);
        }
        // K = Pxz S^-1, via the Cholesky factor: K^T = S^-1 Pxz^T.
        let gain = chol.solve(&pxz.transpose()).transpose();
        let x = self.x + gain * innovation;
        let mut p = self.p - gain * s_cov * gain.transpose();
        if symmetrise(&mut p) {
            report.flags.insert(Flags::COVARIANCE_SYMMETRISED);
        }
        if !all_finite(x.as_slice()) || !all_finite(p.as_slice()) {
            return Err(Error::NonFiniteState);
        }
        // `P - K S K^T` can lose definiteness to cancellation (e.g. after a wild measurement
        // threw the state far out); keep the last valid estimate rather than store it.
        if Cholesky::new(p).is_none() {
            return Err(Error::NotPositiveDefinite);
        }
        self.x = x;
        self.p = p;
        self.propagated = false;
        report.fused = true;
        Ok(report)
    }
}
