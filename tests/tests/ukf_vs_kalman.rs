//! The unscented transform is exact for linear maps, so on a linear-Gaussian model the UKF
//! must reproduce the Kalman filter to round-off: mean and covariance, prior and posterior.

use nalgebra::{SMatrix, SVector, Vector1};
use prognos_core::filter::ukf::{SigmaParams, Ukf};
use prognos_tests::linear_gaussian::{KalmanFilter, input, tracker3};
use rand_core::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;

/// Largest entry-wise difference relative to max(1, |reference|).
fn max_rel_diff<const R: usize, const C: usize>(
    a: &SMatrix<f64, R, C>,
    reference: &SMatrix<f64, R, C>,
) -> f64 {
    a.iter()
        .zip(reference.iter())
        .map(|(x, r)| (x - r).abs() / r.abs().max(1.0))
        .fold(0.0, f64::max)
}

fn run(params: SigmaParams<f64>) -> (f64, f64) {
    let model = tracker3();
    let x0 = SVector::<f64, 3>::new(1.0, -0.5, 0.2);
    let p0 = SMatrix::<f64, 3, 3>::new(2.0, 0.3, 0.0, 0.3, 1.0, 0.1, 0.0, 0.1, 0.5);
    let mut kf = KalmanFilter::new(x0, p0);
    let mut ukf = Ukf::<f64, 3, 7>::new(x0, p0, model.q, params).unwrap();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(11);
    let mut truth = SVector::<f64, 3>::new(0.0, 0.0, 0.0);
    let (mut worst_x, mut worst_p) = (0.0f64, 0.0f64);
    for k in 0..300 {
        let u = input(k);
        truth = prognos_core::model::Stochastic::sample_step(
            &model,
            &truth,
            &Vector1::new(u),
            1.0,
            &mut rng,
        );
        let y = model.sample_measurement(&truth, &mut rng);
        kf.predict(&model, u);
        ukf.predict(&model, &Vector1::new(u), 1.0).unwrap();
        worst_x = worst_x.max(max_rel_diff(ukf.state(), &kf.x));
        worst_p = worst_p.max(max_rel_diff(ukf.covariance(), &kf.p));
        // Skip every fifth update so predict-predict sequences are covered too.
        if k % 5 != 4 {
            kf.update(&model, &y);
            let report = ukf
                .update(&model, &Vector1::new(u), y.as_slice(), &model.r)
                .unwrap();
            assert!(report.fused);
            worst_x = worst_x.max(max_rel_diff(ukf.state(), &kf.x));
            worst_p = worst_p.max(max_rel_diff(ukf.covariance(), &kf.p));
        }
    }
    (worst_x, worst_p)
}

#[test]
fn ukf_equals_kalman_filter_on_linear_model() {
    for params in [
        SigmaParams::default(),
        SigmaParams {
            alpha: 1.0,
            beta: 0.0,
            kappa: 2.0,
        },
        SigmaParams {
            alpha: 0.3,
            beta: 2.0,
            kappa: 1.0,
        },
    ] {
        let (dx, dp) = run(params);
        println!("{params:?}: max rel diff mean {dx:.3e}, covariance {dp:.3e}");
        assert!(dx < 1e-9, "{params:?}: mean differs by {dx:e}");
        assert!(dp < 1e-9, "{params:?}: covariance differs by {dp:e}");
    }
}

/// With alpha = 1e-3 the central weights are about -1/alpha^2 = -1e6, so the weighted sums
/// cancel and round-off is amplified about a millionfold: the agreement is bounded by that,
/// not by 1e-9. (filterpy has the same conditioning.)
#[test]
fn ukf_with_tiny_alpha_matches_kalman_filter_to_conditioning() {
    let params = SigmaParams {
        alpha: 1e-3,
        beta: 2.0,
        kappa: 0.0,
    };
    let (dx, dp) = run(params);
    println!("{params:?}: max rel diff mean {dx:.3e}, covariance {dp:.3e}");
    assert!(dx < 1e-6, "mean differs by {dx:e}");
    assert!(dp < 1e-6, "covariance differs by {dp:e}");
}
