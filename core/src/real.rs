//! The scalar abstraction: f32 on the microcontroller, f64 on the host.

use nalgebra::{ArrayStorage, RealField, SVector};

/// `SVector::zeros()` usable in constants.
pub const fn zero_vector<T: Real, const N: usize>() -> SVector<T, N> {
    SVector::from_array_storage(ArrayStorage([[T::ZERO; N]; 1]))
}

/// A floating-point scalar the core computes in (implemented for `f32` and `f64`).
pub trait Real: RealField + Copy + Default + PartialOrd {
    /// Largest finite value, used as a sentinel for "never" (e.g. an EOL beyond the horizon).
    const MAX_FINITE: Self;
    /// Smallest positive normal value, the floor for divisions and variances.
    const MIN_POSITIVE: Self;
    /// Machine epsilon.
    const EPSILON: Self;
    /// 0, usable in constants (the placeholders of statically allocated filters).
    const ZERO: Self;
    /// Converts to f64 (reporting, metrics on the host).
    fn as_f64(self) -> f64;
    /// True when neither NaN nor infinite.
    fn finite(self) -> bool;
    /// True for NaN.
    fn nan(self) -> bool;
    /// Sine for hot paths: single-precision [`crate::fastmath`] in f32, the ordinary `sin` in
    /// f64 (so that host results are unchanged).
    fn fast_sin(self) -> Self;
    /// Cosine for hot paths (see [`Real::fast_sin`]).
    fn fast_cos(self) -> Self;
    /// `e^x` for hot paths (see [`Real::fast_sin`]).
    fn fast_exp(self) -> Self;
    /// Hyperbolic tangent for hot paths (see [`Real::fast_sin`]).
    fn fast_tanh(self) -> Self;
    /// A uniform value in [0, 1) from the top bits of a 64-bit random draw (as many bits as
    /// the mantissa holds, converted without leaving the type's precision).
    fn unit_from_bits(bits: u64) -> Self;
    /// A uniform value in (0, 1) from the top bits of a 64-bit random draw.
    fn open_unit_from_bits(bits: u64) -> Self;
}

impl Real for f64 {
    const MAX_FINITE: Self = f64::MAX;
    const MIN_POSITIVE: Self = f64::MIN_POSITIVE;
    const EPSILON: Self = f64::EPSILON;
    const ZERO: Self = 0.0;
    #[inline]
    fn as_f64(self) -> f64 {
        self
    }
    #[inline]
    fn finite(self) -> bool {
        self.is_finite()
    }
    #[inline]
    fn nan(self) -> bool {
        self.is_nan()
    }
    #[inline]
    fn fast_sin(self) -> Self {
        nalgebra::ComplexField::sin(self)
    }
    #[inline]
    fn fast_cos(self) -> Self {
        nalgebra::ComplexField::cos(self)
    }
    #[inline]
    fn fast_exp(self) -> Self {
        nalgebra::ComplexField::exp(self)
    }
    #[inline]
    fn fast_tanh(self) -> Self {
        nalgebra::ComplexField::tanh(self)
    }
    #[inline]
    fn unit_from_bits(bits: u64) -> Self {
        (bits >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }
    #[inline]
    fn open_unit_from_bits(bits: u64) -> Self {
        ((bits >> 11) as f64 + 0.5) * (1.0 / (1u64 << 53) as f64)
    }
}

impl Real for f32 {
    const MAX_FINITE: Self = f32::MAX;
    const MIN_POSITIVE: Self = f32::MIN_POSITIVE;
    const EPSILON: Self = f32::EPSILON;
    const ZERO: Self = 0.0;
    #[inline]
    fn as_f64(self) -> f64 {
        f64::from(self)
    }
    #[inline]
    fn finite(self) -> bool {
        self.is_finite()
    }
    #[inline]
    fn nan(self) -> bool {
        self.is_nan()
    }
    #[inline]
    fn fast_sin(self) -> Self {
        crate::fastmath::sin(self)
    }
    #[inline]
    fn fast_cos(self) -> Self {
        crate::fastmath::cos(self)
    }
    #[inline]
    fn fast_exp(self) -> Self {
        crate::fastmath::exp(self)
    }
    #[inline]
    fn fast_tanh(self) -> Self {
        crate::fastmath::tanh(self)
    }
    #[inline]
    fn unit_from_bits(bits: u64) -> Self {
        // 24 bits: exact in f32, at most 1 - 2^-24.
        ((bits >> 40) as u32) as f32 * (1.0 / (1u32 << 24) as f32)
    }
    #[inline]
    fn open_unit_from_bits(bits: u64) -> Self {
        // 23 bits plus a half: exact in f32, within [2^-24, 1 - 2^-24].
        (((bits >> 41) as u32) as f32 + 0.5) * (1.0 / (1u32 << 23) as f32)
    }
}

/// Converts an f64 constant or parameter into the scalar type of generic code.
#[inline]
pub fn cast<T: Real>(v: f64) -> T {
    nalgebra::convert(v)
}

/// True when every entry of the slice is finite.
#[inline]
pub fn all_finite<T: Real>(values: &[T]) -> bool {
    values.iter().all(|v| v.finite())
}
