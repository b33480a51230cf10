//! Random variates from a caller-supplied `rand_core::Rng`: the core owns no generator, so
//! every run is reproducible from the caller's seed.

use crate::real::{Real, cast};
use rand_core::Rng;

/// Uniform variate on [0, 1) from the top 53 bits of one 64-bit draw (f64) or the top 24
/// (f32, converted in single precision: no software double on the M4F).
#[inline]
pub fn uniform01<T: Real, R: Rng + ?Sized>(rng: &mut R) -> T {
    let v = T::unit_from_bits(rng.next_u64());
    if v >= T::one() {
        T::one() - T::EPSILON
    } else {
        v
    }
}

/// Uniform variate on the open interval (0, 1), safe for logarithms.
#[inline]
pub fn uniform_open01<T: Real, R: Rng + ?Sized>(rng: &mut R) -> T {
    T::open_unit_from_bits(rng.next_u64())
}

/// Standard normal variate by Marsaglia's polar method (no trigonometry, which is costly on
/// the M4F; rejection happens with probability 1 - pi/4).
pub fn standard_normal<T: Real, R: Rng + ?Sized>(rng: &mut R) -> T {
    let two: T = cast(2.0);
    loop {
        let a = two * uniform01::<T, R>(rng) - T::one();
        let b = two * uniform01::<T, R>(rng) - T::one();
        let s = a * a + b * b;
        if s > T::zero() && s < T::one() {
            return a * (-two * s.ln() / s).sqrt();
        }
    }
}

/// Normal variate with the given mean and standard deviation.
#[inline]
pub fn normal<T: Real, R: Rng + ?Sized>(rng: &mut R, mean: T, std: T) -> T {
    mean + std * standard_normal::<T, R>(rng)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand_core::SeedableRng;
    use rand_xoshiro::Xoshiro256PlusPlus;

    #[test]
    fn normal_moments() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(7);
        let n = 200_000;
        let (mut s1, mut s2, mut s4) = (0.0, 0.0, 0.0);
        for _ in 0..n {
            let z: f64 = standard_normal(&mut rng);
            s1 += z;
            s2 += z * z;
            s4 += z * z * z * z;
        }
        let nf = n as f64;
        assert!((s1 / nf).abs() < 0.01);
        assert!((s2 / nf - 1.0).abs() < 0.015);
        assert!((s4 / nf - 3.0).abs() < 0.08);
    }

    #[test]
    fn uniform_in_range() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(1);
        for _ in 0..10_000 {
            let u: f32 = uniform01(&mut rng);
            assert!((0.0..1.0).contains(&u));
            let v: f64 = uniform_open01(&mut rng);
            assert!(v > 0.0 && v < 1.0);
        }
    }
}
