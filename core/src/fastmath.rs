//! Single-precision sine, cosine, exponential and tanh for the Cortex-M4F.
//!
//! `libm::sinf` reduces its argument in f64, which the M4F's single-precision FPU emulates in
//! software (about 1,200 instructions a call). These functions stay in f32: Cody-Waite
//! reduction by pi/2 with a three-part constant (exact products for |x| < 8192), then the
//! Cephes minimax polynomials on [-pi/4, pi/4]; exp reduces by ln 2 and scales by building
//! the exponent bits. Accuracy, asserted by the tests against libm's f64 functions:
//!
//! | function | range | max error |
//! |---|---|---|
//! | [`sin`], [`cos`] | \|x\| <= 8192 | 1.0e-7 absolute (measured 7.8e-8) |
//! | [`sin`], [`cos`] | \|x\| > 8192 | libm's (falls back to `libm::sinf`/`cosf`) |
//! | [`exp`] | -87 <= x <= 88 | 1.2e-7 relative, 1 ulp (measured 8.0e-8) |
//! | [`tanh`] | all x | 1.0e-7 absolute (measured 8.4e-8); 2.0e-7 relative for \|x\| >= 0.55 |
//!
//! Generic code reaches them through [`crate::Real::fast_sin`] and friends: f32 maps to these,
//! f64 to the ordinary double-precision functions (so host f64 results do not change).

/// Beyond this |x| the three-part reduction is no longer exact and libm takes over.
const REDUCTION_LIMIT: f32 = 8192.0;
const TWO_OVER_PI: f32 = core::f32::consts::FRAC_2_PI;
// pi/2 split so that k * PIO2_HI and k * PIO2_MID are exact for k < 2^13 (Cephes DP1..3 x 2).
const PIO2_HI: f32 = 1.570_312_5;
const PIO2_MID: f32 = 4.837_513e-4;
const PIO2_LO: f32 = 7.549_79e-8;

#[inline(always)]
fn sin_kernel(r: f32) -> f32 {
    let z = r * r;
    ((-1.951_529_6e-4 * z + 8.332_161e-3) * z - 1.666_665_5e-1) * z * r + r
}

#[inline(always)]
fn cos_kernel(r: f32) -> f32 {
    let z = r * r;
    ((2.443_315_7e-5 * z - 1.388_731_6e-3) * z + 4.166_664_6e-2) * z * z - 0.5 * z + 1.0
}

/// `x = k pi/2 + r` with |r| <= pi/4 (plus rounding); returns `(k mod 4, r)`.
#[inline(always)]
fn reduce(x: f32) -> (u32, f32) {
    let k = rint(x * TWO_OVER_PI);
    let r = ((x - k * PIO2_HI) - k * PIO2_MID) - k * PIO2_LO;
    // k is integral and |k| < 2^13 here, so the cast is exact; wrapping keeps the quadrant.
    (k as i32 as u32 & 3, r)
}

/// Round to nearest integer without libm (|x| < 2^22 here).
#[inline(always)]
fn rint(x: f32) -> f32 {
    const MAGIC: f32 = 12_582_912.0; // 1.5 * 2^23
    if x >= 0.0 {
        (x + MAGIC) - MAGIC
    } else {
        (x - MAGIC) + MAGIC
    }
}

/// Sine and cosine of `x` (radians) together, sharing the reduction.
#[inline]
pub fn sin_cos(x: f32) -> (f32, f32) {
    if !(x.abs() <= REDUCTION_LIMIT) {
        // NaN, infinities and huge arguments: libm's full reduction.
        return (libm::sinf(x), libm::cosf(x));
    }
    let (quadrant, r) = reduce(x);
    let (s, c) = (sin_kernel(r), cos_kernel(r));
    match quadrant {
        0 => (s, c),
        1 => (c, -s),
        2 => (-s, -c),
        _ => (-c, s),
    }
}

/// Sine of `x` (radians); see the module table for accuracy.
#[inline]
pub fn sin(x: f32) -> f32 {
    if !(x.abs() <= REDUCTION_LIMIT) {
        return libm::sinf(x);
    }
    let (quadrant, r) = reduce(x);
    match quadrant {
        0 => sin_kernel(r),
        1 => cos_kernel(r),
        2 => -sin_kernel(r),
        _ => -cos_kernel(r),
    }
}

/// Cosine of `x` (radians); see the module table for accuracy.
#[inline]
pub fn cos(x: f32) -> f32 {
    if !(x.abs() <= REDUCTION_LIMIT) {
        return libm::cosf(x);
    }
    let (quadrant, r) = reduce(x);
    match quadrant {
        0 => cos_kernel(r),
        1 => -sin_kernel(r),
        2 => -cos_kernel(r),
        _ => sin_kernel(r),
    }
}

/// `e^x`; overflows to infinity above 88.72, underflows to 0 below -103.9 (subnormals in
/// between), NaN stays NaN.
#[inline]
pub fn exp(x: f32) -> f32 {
    const LN2_HI: f32 = 0.693_359_4; // exact in 9 bits
    const LN2_LO: f32 = -2.121_944_4e-4;
    const LOG2E: f32 = core::f32::consts::LOG2_E;
    if x.is_nan() {
        return x;
    }
    if x > 88.722_84 {
        return f32::INFINITY;
    }
    if x < -103.972_08 {
        return 0.0;
    }
    let k = rint(x * LOG2E);
    let r = (x - k * LN2_HI) - k * LN2_LO;
    let p = r
        * r
        * (((((1.987_569_1e-4 * r + 1.398_199_9e-3) * r + 8.333_452e-3) * r + 4.166_579_6e-2) * r
            + 1.666_666_5e-1)
            * r
            + 0.5)
        + r
        + 1.0;
    // k in [-150, 128]: scale in two exact power-of-two steps so subnormals come out right.
    let k = k as i32;
    let half = k / 2;
    p * pow2(half) * pow2(k.saturating_sub(half))
}

/// `2^k` for k in [-126, 127], built from the exponent bits.
#[inline(always)]
fn pow2(k: i32) -> f32 {
    let biased = k.saturating_add(127).clamp(1, 254) as u32;
    f32::from_bits(biased << 23)
}

/// Hyperbolic tangent through [`exp`]: `1 - 2 / (e^{2x} + 1)` for |x| >= 0.55, the odd Taylor
/// polynomial (to x^9) below 0.25, where the subtraction would cancel.
#[inline]
pub fn tanh(x: f32) -> f32 {
    let a = x.abs();
    if a.is_nan() {
        return x;
    }
    let t = if a < 0.25 {
        let z = a * a;
        a * (1.0 + z * (-1.0 / 3.0 + z * (2.0 / 15.0 + z * (-17.0 / 315.0 + z * (62.0 / 2835.0)))))
    } else if a > 9.0 {
        1.0
    } else {
        1.0 - 2.0 / (exp(2.0 * a) + 1.0)
    };
    if x < 0.0 { -t } else { t }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `count` points evenly over [lo, hi] (endpoints included).
    fn grid(lo: f32, hi: f32, count: u32) -> impl Iterator<Item = f32> {
        (0..=count).map(move |i| lo + (hi - lo) * (i as f32 / count as f32))
    }

    #[test]
    fn sin_and_cos_match_libm_within_1e_7() {
        let mut worst: f64 = 0.0;
        // The ranges used: ripple arguments up to ~700 rad, noise phases, and the full limit.
        for x in grid(-8192.0, 8192.0, 2_000_000).chain(grid(-7.0, 7.0, 200_000)) {
            let xd = f64::from(x);
            let (s, c) = sin_cos(x);
            worst = worst
                .max((f64::from(sin(x)) - libm::sin(xd)).abs())
                .max((f64::from(cos(x)) - libm::cos(xd)).abs())
                .max((f64::from(s) - libm::sin(xd)).abs())
                .max((f64::from(c) - libm::cos(xd)).abs());
        }
        assert!(worst < 1.0e-7, "worst absolute error {worst:e}");
        // Outside the reduction range and at special values libm's results are returned.
        assert_eq!(sin(1.0e6), libm::sinf(1.0e6));
        assert_eq!(cos(-3.0e5), libm::cosf(-3.0e5));
        assert!(sin(f32::NAN).is_nan() && cos(f32::INFINITY).is_nan());
        assert_eq!(sin(0.0), 0.0);
        assert_eq!(cos(0.0), 1.0);
    }

    #[test]
    fn exp_matches_libm_within_one_ulp() {
        let mut worst: f64 = 0.0;
        for x in grid(-87.0, 88.0, 2_000_000).chain(grid(-1.0, 1.0, 100_000)) {
            let exact = libm::exp(f64::from(x));
            worst = worst.max((f64::from(exp(x)) - exact).abs() / exact);
        }
        assert!(worst < 1.2e-7, "worst relative error {worst:e}");
        assert_eq!(exp(0.0), 1.0);
        assert_eq!(exp(100.0), f32::INFINITY);
        assert_eq!(exp(-200.0), 0.0);
        assert!(exp(f32::NAN).is_nan());
        // Subnormal results keep about 3 significant digits at e^-100 (3.7e-44).
        let tiny = f64::from(exp(-100.0));
        assert!((tiny / libm::exp(-100.0) - 1.0).abs() < 0.05, "{tiny:e}");
    }

    #[test]
    fn tanh_matches_libm() {
        let (mut worst_abs, mut worst_rel): (f64, f64) = (0.0, 0.0);
        for x in grid(-12.0, 12.0, 1_000_000).chain(grid(-0.6, 0.6, 100_000)) {
            let exact = libm::tanh(f64::from(x));
            let err = (f64::from(tanh(x)) - exact).abs();
            worst_abs = worst_abs.max(err);
            if x.abs() >= 0.55 {
                worst_rel = worst_rel.max(err / exact.abs());
            }
        }
        assert!(worst_abs < 1.0e-7, "worst absolute error {worst_abs:e}");
        assert!(worst_rel < 2.0e-7, "worst relative error {worst_rel:e}");
        assert_eq!(tanh(0.0), 0.0);
        assert_eq!(tanh(-50.0), -1.0);
        assert!(tanh(f32::NAN).is_nan());
    }
}
