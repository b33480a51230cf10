//! Allocation-free summaries of weighted samples, computed in place on caller buffers.

use crate::real::{Real, cast};
use core::cmp::Ordering;

fn by_value<T: Real>(a: &(T, T), b: &(T, T)) -> Ordering {
    a.0.partial_cmp(&b.0).unwrap_or(Ordering::Equal)
}

/// Sorts `(value, weight)` pairs by value in place (NaN values compare equal; callers filter them).
pub fn sort_by_value<T: Real>(samples: &mut [(T, T)]) {
    samples.sort_unstable_by(by_value);
}

/// Sorts plain values in place.
pub fn sort_values<T: Real>(values: &mut [T]) {
    values.sort_unstable_by(|a, b| a.partial_cmp(b).unwrap_or(Ordering::Equal));
}

/// Largest weight, by which sums of weights are scaled so they cannot overflow.
fn weight_scale<T: Real>(samples: &[(T, T)]) -> T {
    samples.iter().fold(T::zero(), |m, s| m.max(s.1))
}

/// Weighted mean of `(value, weight)` pairs; `None` when the weights sum to zero.
pub fn weighted_mean<T: Real>(samples: &[(T, T)]) -> Option<T> {
    let scale = weight_scale(samples);
    if !(scale > T::zero()) {
        return None;
    }
    let (mut sw, mut swx) = (T::zero(), T::zero());
    for &(x, w) in samples {
        let w = w / scale;
        sw += w;
        swx += w * x;
    }
    if sw > T::zero() { Some(swx / sw) } else { None }
}

/// Weighted quantile `q` in [0, 1] of pairs already sorted by value: the smallest value whose
/// cumulative weight reaches `q` of the total. `None` for empty input or zero total weight.
pub fn weighted_quantile_sorted<T: Real>(sorted: &[(T, T)], q: T) -> Option<T> {
    let scale = weight_scale(sorted);
    if !(scale > T::zero()) {
        return None;
    }
    let total = sorted.iter().fold(T::zero(), |acc, s| acc + s.1 / scale);
    if !(total > T::zero()) {
        return None;
    }
    let target = q.max(T::zero()).min(T::one()) * total;
    let mut cum = T::zero();
    let mut last = None;
    for &(x, w) in sorted {
        cum += w / scale;
        last = Some(x);
        if cum >= target && w > T::zero() {
            return Some(x);
        }
    }
    last
}

/// Median of plain values; sorts `values` in place. `None` when empty.
pub fn median_in_place<T: Real>(values: &mut [T]) -> Option<T> {
    sort_values(values);
    let n = values.len();
    if n == 0 {
        return None;
    }
    let mid = n / 2;
    if n % 2 == 1 {
        values.get(mid).copied()
    } else {
        let a = values.get(mid.wrapping_sub(1)).copied()?;
        let b = values.get(mid).copied()?;
        Some((a + b) * cast(0.5))
    }
}

/// Median absolute deviation from the median; reorders `values`. `None` when empty.
pub fn mad_in_place<T: Real>(values: &mut [T]) -> Option<(T, T)> {
    let med = median_in_place(values)?;
    for v in values.iter_mut() {
        *v = (*v - med).abs();
    }
    let mad = median_in_place(values)?;
    Some((med, mad))
}

/// Summary of a weighted distribution: what a prognoser reports about an RUL or EOL.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Summary<T> {
    pub mean: T,
    pub median: T,
    /// 1st, 5th, 25th, 75th, 95th and 99th percentiles.
    pub p01: T,
    pub p05: T,
    pub p25: T,
    pub p75: T,
    pub p95: T,
    pub p99: T,
    /// Weighted relative median absolute deviation, percent of the median.
    pub rmad: T,
}

/// Summarises weighted samples in place (the buffer is reordered and its weights kept).
/// Non-finite values or weights are ignored. `None` when nothing remains.
pub fn summarise<T: Real>(samples: &mut [(T, T)]) -> Option<Summary<T>> {
    // Move usable samples to the front.
    let mut n = 0usize;
    for i in 0..samples.len() {
        let ok = samples
            .get(i)
            .is_some_and(|s| s.0.finite() && s.1.finite() && s.1 >= T::zero());
        if ok {
            samples.swap(n, i);
            n = n.saturating_add(1);
        }
    }
    let usable = samples.get_mut(..n)?;
    sort_by_value(usable);
    let q = |p: f64| weighted_quantile_sorted(usable, cast(p));
    let median = q(0.5)?;
    let mut summary = Summary {
        mean: weighted_mean(usable)?,
        median,
        p01: q(0.01)?,
        p05: q(0.05)?,
        p25: q(0.25)?,
        p75: q(0.75)?,
        p95: q(0.95)?,
        p99: q(0.99)?,
        rmad: T::zero(),
    };
    // Weighted MAD: replace values by |x - median| and take the weighted median again.
    for s in usable.iter_mut() {
        s.0 = (s.0 - median).abs();
    }
    sort_by_value(usable);
    let mad = weighted_quantile_sorted(usable, cast(0.5))?;
    summary.rmad = if median.abs() > T::MIN_POSITIVE {
        cast::<T>(100.0) * mad / median.abs()
    } else {
        T::zero()
    };
    Some(summary)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_and_mad() {
        let mut v = [5.0, 1.0, 3.0, 2.0, 4.0];
        assert_eq!(median_in_place(&mut v), Some(3.0));
        let mut v = [1.0, 2.0, 3.0, 4.0];
        assert_eq!(median_in_place(&mut v), Some(2.5));
        let mut v = [1.0, 2.0, 3.0, 4.0, 100.0];
        assert_eq!(mad_in_place(&mut v), Some((3.0, 1.0)));
        assert_eq!(median_in_place::<f64>(&mut []), None);
    }

    #[test]
    fn summary_of_uniform_weights_matches_order_statistics() {
        let mut s: [(f64, f64); 100] = core::array::from_fn(|i| ((99 - i) as f64, 1.0));
        let sum = summarise(&mut s).unwrap();
        assert!((sum.mean - 49.5).abs() < 1e-12);
        assert_eq!(sum.median, 49.0);
        assert_eq!(sum.p05, 4.0);
        assert_eq!(sum.p95, 94.0);
        assert!(sum.p01 <= sum.p05 && sum.p05 <= sum.p25 && sum.p75 <= sum.p95);
        // |x - 49| has weighted median 25 (values 0..=50 once or twice).
        assert!(
            (sum.rmad - 100.0 * 25.0 / 49.0).abs() < 1e-9,
            "{}",
            sum.rmad
        );
    }

    #[test]
    fn summary_ignores_nonfinite() {
        let mut s = [
            (1.0, 1.0),
            (f64::NAN, 1.0),
            (3.0, f64::INFINITY),
            (2.0, 1.0),
        ];
        let sum = summarise(&mut s).unwrap();
        assert!((sum.mean - 1.5).abs() < 1e-12);
        assert!(summarise::<f64>(&mut [(f64::NAN, 1.0)]).is_none());
    }
}
