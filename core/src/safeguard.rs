//! Numerical safeguards in one place, and the flags that report them.
//!
//! No repair is silent: every function here that changes a value tells the caller, and filters
//! copy that into the [`Flags`] of their step report.

use crate::real::{Real, cast};
use nalgebra::SMatrix;

/// Which safeguards acted during a step (a small bit set).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Flags(u16);

impl Flags {
    /// No safeguard acted.
    pub const NONE: Flags = Flags(0);
    /// The particle set was resampled.
    pub const RESAMPLED: Flags = Flags(1);
    /// Roughening jitter was added after resampling.
    pub const ROUGHENED: Flags = Flags(1 << 1);
    /// Every particle's likelihood was zero: the measurement was skipped (predict-only step).
    pub const WEIGHT_COLLAPSE_RECOVERED: Flags = Flags(1 << 2);
    /// Some particles diverged to non-finite states; they kept their old state with zero weight.
    pub const NONFINITE_PARTICLES_DROPPED: Flags = Flags(1 << 3);
    /// A state or parameter was clamped to its configured bounds.
    pub const BOUNDS_CLAMPED: Flags = Flags(1 << 4);
    /// A covariance was made symmetric (its asymmetry exceeded round-off).
    pub const COVARIANCE_SYMMETRISED: Flags = Flags(1 << 5);
    /// A variance was raised to its floor.
    pub const VARIANCE_FLOOR: Flags = Flags(1 << 6);
    /// The measurement was rejected by a gate or as an outlier.
    pub const MEASUREMENT_REJECTED: Flags = Flags(1 << 7);
    /// A covariance lost positive definiteness and was repaired (diagonal loading).
    pub const CHOLESKY_REPAIRED: Flags = Flags(1 << 8);
    /// A covariance was enlarged by an adaptive rule.
    pub const COVARIANCE_ENHANCED: Flags = Flags(1 << 9);

    /// True when every flag of `other` is set here.
    #[inline]
    pub const fn contains(self, other: Flags) -> bool {
        self.0 & other.0 == other.0
    }
    /// Sets the flags of `other`.
    #[inline]
    pub fn insert(&mut self, other: Flags) {
        self.0 |= other.0;
    }
    /// The union of two flag sets.
    #[inline]
    pub const fn union(self, other: Flags) -> Flags {
        Flags(self.0 | other.0)
    }
    /// True when no flag is set.
    #[inline]
    pub const fn is_empty(self) -> bool {
        self.0 == 0
    }
    /// The raw bits (for logging).
    #[inline]
    pub const fn bits(self) -> u16 {
        self.0
    }
}

/// Replaces `m` by `(m + m^T)/2`. Returns true when the asymmetry was larger than round-off
/// (relative 1e-9 for f64, 1e-4 for f32), i.e. when the repair deserves a flag.
pub fn symmetrise<T: Real, const N: usize>(m: &mut SMatrix<T, N, N>) -> bool {
    let half: T = cast(0.5);
    let scale = m.amax().max(T::MIN_POSITIVE);
    let tol = scale * T::EPSILON.sqrt() * cast(0.01);
    let mut significant = false;
    for i in 0..N {
        for j in i.saturating_add(1)..N {
            let (a, b) = (m[(i, j)], m[(j, i)]);
            if (a - b).abs() > tol {
                significant = true;
            }
            let avg = (a + b) * half;
            m[(i, j)] = avg;
            m[(j, i)] = avg;
        }
    }
    significant
}

/// Raises every diagonal entry of `m` to at least `floor`. Returns true if any was raised.
pub fn floor_variances<T: Real, const N: usize>(m: &mut SMatrix<T, N, N>, floor: T) -> bool {
    let mut raised = false;
    for i in 0..N {
        if !(m[(i, i)] >= floor) {
            m[(i, i)] = floor;
            raised = true;
        }
    }
    raised
}

/// `num / den` with `den` kept at least `eps` away from zero (sign preserved).
#[inline]
pub fn guarded_div<T: Real>(num: T, den: T, eps: T) -> T {
    let d = if den.abs() < eps {
        if den < T::zero() { -eps } else { eps }
    } else {
        den
    };
    num / d
}

/// `ln(sum(exp(v)))` computed stably; `-inf` for an empty slice or all `-inf`.
pub fn log_sum_exp<T: Real>(values: &[T]) -> T {
    let max = values
        .iter()
        .copied()
        .fold(T::min_value().unwrap_or(-T::MAX_FINITE), |a, b| a.max(b));
    if !max.finite() {
        return max;
    }
    let sum = values
        .iter()
        .fold(T::zero(), |acc, &v| acc + (v - max).exp());
    max + sum.ln()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Matrix2;

    #[test]
    fn symmetrise_flags_only_real_asymmetry() {
        let mut m = Matrix2::new(1.0, 0.5, 0.5 + 1e-17, 1.0);
        assert!(!symmetrise(&mut m));
        let mut m = Matrix2::new(1.0, 0.5, 0.6, 1.0);
        assert!(symmetrise(&mut m));
        assert_eq!(m[(0, 1)], m[(1, 0)]);
        assert!((m[(0, 1)] - 0.55f64).abs() < 1e-15);
    }

    #[test]
    fn log_sum_exp_is_stable() {
        let v = [-1000.0f64, -1000.0];
        assert!((log_sum_exp(&v) - (-1000.0 + 2f64.ln())).abs() < 1e-12);
        assert_eq!(log_sum_exp::<f64>(&[f64::NEG_INFINITY]), f64::NEG_INFINITY);
    }

    #[test]
    fn variance_floor_catches_nan() {
        let mut m = Matrix2::new(f64::NAN, 0.0, 0.0, 1.0);
        assert!(floor_variances(&mut m, 1e-9));
        assert_eq!(m[(0, 0)], 1e-9);
    }
}
