//! Prognostics metrics against analytic values and naive independent implementations.

use prognos_core::metrics::{
    HorizonBand, alpha_lambda_accuracy, convergence, prognostic_horizon, within_alpha,
};
use proptest::prelude::*;
use proptest::test_runner::RngSeed;

/// Saxena's convergence of M(t) = exp(-t) on [0, T] sampled on a fine grid approaches the
/// centroid of the exact area: x_c = int t M / int M, y_c = int M^2 / (2 int M).
#[test]
fn convergence_of_exponential_decay_matches_the_analytic_centroid() {
    let big_t: f64 = 10.0;
    let e = (-big_t).exp();
    let area = 1.0 - e;
    let xc = (1.0 - (big_t + 1.0) * e) / area;
    let yc = (1.0 - e * e) / 4.0 / area;
    let exact = (xc * xc + yc * yc).sqrt();
    let error = |n: usize| {
        let times: Vec<f64> = (0..=n).map(|i| big_t * i as f64 / n as f64).collect();
        let values: Vec<f64> = times.iter().map(|t| (-t).exp()).collect();
        (convergence(&times, &values).unwrap() - exact).abs()
    };
    let (e1, e2) = (error(2000), error(4000));
    println!("convergence error: n=2000 {e1:.3e}, n=4000 {e2:.3e} (exact {exact:.6})");
    assert!(e2 < 2e-3 * exact, "{e2}");
    // Left-endpoint rectangles: first-order convergence.
    assert!(
        ((e1 / e2).log2() - 1.0).abs() < 0.1,
        "order {}",
        (e1 / e2).log2()
    );
}

/// The definition read literally: the first time index from which every later prediction is
/// inside the band, in O(n^2).
fn naive_horizon(times: &[f64], truth: &[f64], pred: &[f64], eol: f64, alpha: f64) -> Option<f64> {
    let inside = |i: usize| (truth[i] - pred[i]).abs() <= alpha * eol;
    (0..times.len())
        .find(|&k| (k..times.len()).all(inside))
        .map(|k| eol - times[k])
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: 256,
        rng_seed: RngSeed::Fixed(7101),
        failure_persistence: None,
        ..ProptestConfig::default()
    })]

    #[test]
    fn prognostic_horizon_matches_the_definition(
        errors in prop::collection::vec(-30.0..30.0f64, 1..40),
        alpha in 0.01..0.5f64,
    ) {
        let n = errors.len();
        let eol = 10.0 * n as f64;
        let times: Vec<f64> = (0..n).map(|k| 10.0 * k as f64).collect();
        let truth: Vec<f64> = times.iter().map(|t| eol - t).collect();
        let pred: Vec<f64> = truth.iter().zip(&errors).map(|(t, e)| t + e).collect();
        let ph = prognostic_horizon(&times, &truth, &pred, eol, alpha, HorizonBand::FractionOfEol);
        prop_assert_eq!(ph, naive_horizon(&times, &truth, &pred, eol, alpha));
        // Alpha-lambda accuracy is the fraction of points inside the relative band.
        let hits = truth.iter().zip(&pred).filter(|&(&t, &p)| {
            p >= (1.0 - alpha) * t && p <= (1.0 + alpha) * t
        }).count();
        let acc = alpha_lambda_accuracy(&truth, &pred, alpha).unwrap();
        prop_assert!((acc - hits as f64 / n as f64).abs() < 1e-15);
        prop_assert_eq!(
            truth.iter().zip(&pred).filter(|&(&t, &p)| within_alpha(t, p, alpha)).count(),
            hits
        );
    }
}
