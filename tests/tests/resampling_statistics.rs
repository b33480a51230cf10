//! Statistical checks of the four resampling schemes: unbiased offspring counts
//! (E[c_i] = N w_i), the deterministic count bounds each scheme guarantees, and the weighted
//! mean preserved in expectation.

use prognos_core::filter::resample::{Resampling, offspring_counts};
use rand_core::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;

const N: usize = 50;
const REPS: usize = 4000;

/// Irregular weights: a few heavy particles, many light ones, exact zeros and a tiny one.
fn weights() -> [f64; N] {
    let mut w: [f64; N] = core::array::from_fn(|i| {
        let x = i as f64;
        match i % 7 {
            0 => 0.0,
            3 => 1e-6,
            _ => 1.0 + (1.7 * x).sin() + 0.05 * x,
        }
    });
    w[10] = 9.0;
    w[31] = 5.5;
    let total: f64 = w.iter().sum();
    w.map(|v| v / total)
}

/// A per-particle value whose weighted mean the resampled set must keep in expectation.
fn value(i: usize) -> f64 {
    (i as f64 * 0.37).cos() * 10.0 + i as f64
}

fn check_scheme(scheme: Resampling, seed: u64) {
    let w = weights();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut counts = [0u32; N];
    let mut sum = [0.0f64; N];
    let mut sum_sq = [0.0f64; N];
    let mut means = Vec::with_capacity(REPS);
    for _ in 0..REPS {
        offspring_counts(scheme, &w, &mut counts, &mut rng);
        assert_eq!(counts.iter().sum::<u32>() as usize, N, "{scheme:?}");
        for (i, (&c, &wi)) in counts.iter().zip(&w).enumerate() {
            let expected = N as f64 * wi;
            let (lo, hi) = match scheme {
                // Evenly spaced positions: an interval of length N w holds floor or ceil of it.
                Resampling::Systematic => (expected.floor(), expected.ceil()),
                // One position per stratum: at most one stratum each side is partial.
                Resampling::Stratified => {
                    ((expected.floor() - 1.0).max(0.0), expected.ceil() + 1.0)
                }
                // floor(N w) copies are deterministic; the rest is at most the remainder.
                Resampling::Residual => (expected.floor(), N as f64),
                Resampling::Multinomial => (0.0, N as f64),
            };
            let cf = f64::from(c);
            assert!(
                cf >= lo && cf <= hi,
                "{scheme:?}: particle {i} has {c} offspring, N w = {expected}"
            );
            if wi == 0.0 {
                assert_eq!(c, 0, "{scheme:?}: zero-weight particle {i} got offspring");
            }
            sum[i] += cf;
            sum_sq[i] += cf * cf;
        }
        let resampled_mean = counts
            .iter()
            .enumerate()
            .map(|(i, &c)| f64::from(c) * value(i))
            .sum::<f64>()
            / N as f64;
        means.push(resampled_mean);
    }
    let reps = REPS as f64;
    let mut worst_z = 0.0f64;
    for (i, &wi) in w.iter().enumerate() {
        let mean = sum[i] / reps;
        let var = (sum_sq[i] / reps - mean * mean).max(0.0) * reps / (reps - 1.0);
        let expected = N as f64 * wi;
        // Five standard errors, plus 5/REPS for counts that are almost never non-zero
        // (their sample variance can be 0 while N w is tiny but positive).
        let bound = 5.0 * (var / reps).sqrt() + 5.0 / reps;
        assert!(
            (mean - expected).abs() <= bound,
            "{scheme:?}: particle {i}: mean count {mean} vs N w = {expected} (bound {bound})"
        );
        if var > 0.0 {
            worst_z = worst_z.max((mean - expected).abs() / (var / reps).sqrt());
        }
    }
    let target: f64 = w.iter().enumerate().map(|(i, &wi)| wi * value(i)).sum();
    let m = means.iter().sum::<f64>() / reps;
    let sd = (means.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / (reps - 1.0)).sqrt();
    let z_mean = (m - target).abs() / (sd / reps.sqrt()).max(1e-300);
    println!(
        "{scheme:?}: worst count z-score {worst_z:.2}; resampled mean {m:.5} vs weighted mean {target:.5} (z = {z_mean:.2}, sd per draw {sd:.4})"
    );
    assert!(z_mean < 5.0, "{scheme:?}: resampled mean {m} vs {target}");
}

#[test]
fn systematic_counts_are_unbiased_and_within_floor_ceil() {
    check_scheme(Resampling::Systematic, 101);
}

#[test]
fn stratified_counts_are_unbiased_and_within_one_of_floor_ceil() {
    check_scheme(Resampling::Stratified, 102);
}

#[test]
fn residual_counts_are_unbiased_and_at_least_floor() {
    check_scheme(Resampling::Residual, 103);
}

#[test]
fn multinomial_counts_are_unbiased_with_binomial_variance() {
    check_scheme(Resampling::Multinomial, 104);
    // Multinomial counts are Binomial(N, w_i): check the variance too.
    let w = weights();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(105);
    let mut counts = [0u32; N];
    let (i, wi) = (10, w[10]);
    let (mut s, mut s2) = (0.0, 0.0);
    for _ in 0..REPS {
        offspring_counts(Resampling::Multinomial, &w, &mut counts, &mut rng);
        let c = f64::from(counts[i]);
        s += c;
        s2 += c * c;
    }
    let reps = REPS as f64;
    let var = s2 / reps - (s / reps).powi(2);
    let binomial = N as f64 * wi * (1.0 - wi);
    println!("multinomial var of particle {i}: {var:.4} vs binomial {binomial:.4}");
    // The sample variance of 4000 draws has a relative standard error of about 2.3 %.
    assert!((var / binomial - 1.0).abs() < 0.12, "{var} vs {binomial}");
}
