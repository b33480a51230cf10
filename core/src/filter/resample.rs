//! Resampling schemes as offspring counts, applied in place without a second particle buffer.
//!
//! Every scheme turns normalised weights into offspring counts `c_i` with `sum c_i = N` and
//! `E[c_i] = N w_i`; [`apply_counts`] then rewrites the particle array in place.

use crate::random::{uniform_open01, uniform01};
use crate::real::{Real, cast};
use rand_core::Rng;

/// Resampling scheme.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Resampling {
    /// One uniform offset, N evenly spaced positions (Kitagawa 1996; the valve paper's Alg. 2).
    #[default]
    Systematic,
    /// One uniform draw in each of N strata.
    Stratified,
    /// floor(N w_i) deterministic copies, the remainder drawn multinomially.
    Residual,
    /// N independent draws from the weights.
    Multinomial,
}

/// Sorted uniforms on [0, 1) in increasing order, generated one at a time in O(1) memory
/// (from the descending order statistics U_(k) = U_(k+1) V^(1/k), mirrored by 1 - U).
struct AscendingUniforms<T> {
    remaining: usize,
    current: T,
}

impl<T: Real> AscendingUniforms<T> {
    fn new(count: usize) -> Self {
        Self {
            remaining: count,
            current: T::one(),
        }
    }
    fn next<R: Rng + ?Sized>(&mut self, rng: &mut R) -> T {
        let k = self.remaining.max(1);
        let v: T = uniform_open01(rng);
        self.current *= (v.ln() / cast::<T>(k as f64)).exp();
        self.remaining = self.remaining.saturating_sub(1);
        T::one() - self.current
    }
}

/// Computes offspring counts for normalised `weights` (sum 1) into `counts` (same length).
/// Non-finite or negative weights count as zero.
pub fn offspring_counts<T: Real, R: Rng + ?Sized>(
    scheme: Resampling,
    weights: &[T],
    counts: &mut [u32],
    rng: &mut R,
) {
    let n = weights.len().min(counts.len());
    for c in counts.iter_mut() {
        *c = 0;
    }
    if n == 0 {
        return;
    }
    let weights = weights.get(..n).unwrap_or(&[]);
    let nf: T = cast(n as f64);
    let total = weights.iter().fold(T::zero(), |a, &w| {
        if w.finite() && w > T::zero() {
            a + w
        } else {
            a
        }
    });
    if !(total > T::zero()) {
        // Degenerate input: keep every particle once.
        for c in counts.iter_mut().take(n) {
            *c = 1;
        }
        return;
    }
    // Clean, rescaled weights are read through this closure so bad entries never propagate.
    let clean = |w: T| {
        if w.finite() && w > T::zero() {
            w / total
        } else {
            T::zero()
        }
    };
    match scheme {
        Resampling::Systematic => {
            let u0: T = uniform01(rng);
            let mut buf_iter = weights.iter().map(|&w| clean(w));
            walk_positions(&mut buf_iter, counts, n, |j| (u0 + cast(j as f64)) / nf);
        }
        Resampling::Stratified => {
            let mut buf_iter = weights.iter().map(|&w| clean(w));
            walk_positions(&mut buf_iter, counts, n, |j| {
                (uniform01::<T, R>(rng) + cast(j as f64)) / nf
            });
        }
        Resampling::Multinomial => {
            let mut order = AscendingUniforms::<T>::new(n);
            let mut buf_iter = weights.iter().map(|&w| clean(w));
            walk_positions(&mut buf_iter, counts, n, |_| order.next(rng));
        }
        Resampling::Residual => {
            let mut assigned = 0usize;
            for (c, &w) in counts.iter_mut().zip(weights) {
                let copies = libm::floor((clean(w) * nf).as_f64()).max(0.0) as u32;
                *c = copies;
                assigned = assigned.saturating_add(copies as usize);
            }
            let rest = n.saturating_sub(assigned);
            if rest > 0 {
                let restf: T = cast(rest as f64);
                let mut order = AscendingUniforms::<T>::new(rest);
                let mut residual = weights.iter().map(|&w| {
                    let nw = clean(w) * nf;
                    (nw - nw.floor()) / restf
                });
                walk_positions(&mut residual, counts, rest, |_| order.next(rng));
            }
        }
    }
}

/// Walks the cumulative weights (read from an iterator, so no weight buffer is needed) with
/// non-decreasing positions, adding one offspring to the particle each position falls in.
fn walk_positions<T: Real>(
    weights: &mut impl Iterator<Item = T>,
    counts: &mut [u32],
    draws: usize,
    mut next_position: impl FnMut(usize) -> T,
) {
    let last = counts.len().saturating_sub(1);
    let mut i = 0usize;
    let mut cum = weights.next().unwrap_or_else(T::zero);
    for j in 0..draws {
        let u = next_position(j);
        while u >= cum && i < last {
            match weights.next() {
                Some(w) => {
                    i = i.saturating_add(1);
                    cum += w;
                }
                None => break,
            }
        }
        if let Some(c) = counts.get_mut(i) {
            *c = c.saturating_add(1);
        }
    }
}

/// Rewrites `particles` so that particle `i` appears `counts[i]` times, in place: survivors stay
/// in their slot, extra copies fill the slots of particles with no offspring.
pub fn apply_counts<P: Copy>(particles: &mut [P], counts: &[u32]) {
    let n = particles.len().min(counts.len());
    let mut hole = 0usize;
    for i in 0..n {
        let copies = counts.get(i).copied().unwrap_or(0);
        if copies < 2 {
            continue;
        }
        let Some(&source) = particles.get(i) else {
            continue;
        };
        for _ in 1..copies {
            while hole < n && counts.get(hole).copied().unwrap_or(1) != 0 {
                hole = hole.saturating_add(1);
            }
            if let Some(slot) = particles.get_mut(hole) {
                *slot = source;
                hole = hole.saturating_add(1);
            } else {
                return;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand_core::SeedableRng;
    use rand_xoshiro::Xoshiro256PlusPlus;

    const SCHEMES: [Resampling; 4] = [
        Resampling::Systematic,
        Resampling::Stratified,
        Resampling::Residual,
        Resampling::Multinomial,
    ];

    #[test]
    fn counts_sum_to_n_and_apply_in_place() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(3);
        let w = [0.5, 0.0, 0.25, 0.0, 0.125, 0.125, 0.0, 0.0];
        for scheme in SCHEMES {
            let mut counts = [0u32; 8];
            offspring_counts(scheme, &w, &mut counts, &mut rng);
            assert_eq!(counts.iter().sum::<u32>(), 8, "{scheme:?}");
            assert_eq!(counts[1] + counts[3] + counts[6] + counts[7], 0);
            let mut p = [0usize, 1, 2, 3, 4, 5, 6, 7];
            apply_counts(&mut p, &counts);
            for (i, &c) in counts.iter().enumerate() {
                assert_eq!(p.iter().filter(|&&x| x == i).count() as u32, c);
            }
        }
    }
}
