//! Property tests over random inputs, extreme values included:
//! PF weights stay normalised, UKF covariances stay symmetric positive semi-definite, RUL
//! summaries have ordered percentiles (and EOL times of a linear damage model are exact).

use nalgebra::{Matrix4, Vector1, Vector2, Vector4};
use prognos_core::filter::particle::{ParticleFilter, PfConfig};
use prognos_core::filter::resample::Resampling;
use prognos_core::filter::ukf::{SigmaParams, Ukf};
use prognos_core::model::{Model, Stochastic};
use prognos_core::prognose::{EndOfLife, PredictionSettings, predict_eol, rul_distribution};
use prognos_core::stats::Summary;
use prognos_core::{Error, Real};
use prognos_tests::drag_radar::DragRadar;
use prognos_tests::linear_gaussian::{LinearGaussian, oscillator};
use proptest::prelude::*;
use proptest::test_runner::RngSeed;
use rand_core::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;

/// A fixed seed per property so every run explores the same cases (and CI is reproducible);
/// no regression files are written.
fn config(cases: u32, seed: u64) -> ProptestConfig {
    ProptestConfig {
        cases,
        rng_seed: RngSeed::Fixed(seed),
        failure_persistence: None,
        ..ProptestConfig::default()
    }
}

/// Measurements: mostly ordinary, sometimes any f64 at all (huge, tiny, NaN, infinite).
fn measurement() -> impl Strategy<Value = f64> {
    prop_oneof![
        6 => -5.0..5.0f64,
        1 => prop::num::f64::ANY,
        1 => prop::sample::select(vec![1e150, -1e200, f64::MAX, f64::MIN_POSITIVE, 0.0]),
    ]
}

fn scheme() -> impl Strategy<Value = Resampling> {
    prop::sample::select(vec![
        Resampling::Systematic,
        Resampling::Stratified,
        Resampling::Residual,
        Resampling::Multinomial,
    ])
}

fn check_pf_weights<T: Real>(
    seed: u64,
    scheme: Resampling,
    threshold: f64,
    ys: &[(Option<f64>, f64)],
    tolerance: f64,
) -> Result<(), TestCaseError> {
    const N: usize = 200;
    let model: LinearGaussian<T, 2, 1> = oscillator().cast();
    let c = |v: f64| prognos_core::cast::<T>(v);
    let config = PfConfig {
        resampling: scheme,
        resample_threshold: c(threshold),
        random_walk_std: Vector2::new(c(0.0), c(0.01)),
        roughening: Vector2::new(c(0.02), c(0.0)),
        ..PfConfig::default()
    };
    let mut pf = ParticleFilter::<T, 2, N>::new(Vector2::zeros(), config).unwrap();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    pf.init_gaussian(
        &Vector2::new(c(1.0), c(0.0)),
        &Vector2::new(c(0.5), c(0.5)),
        &mut rng,
    )
    .unwrap();
    for (k, &(y, dt)) in ys.iter().enumerate() {
        let y_t = y.map(|v| [c(v)]);
        let result = pf.step(
            &model,
            &Vector1::new(c(0.1)),
            y_t.as_ref().map(|a| a.as_slice()),
            c(dt),
            &mut rng,
        );
        let y_finite = y_t.is_none_or(|a| a[0].finite());
        if y_finite {
            let report = result.map_err(|e| TestCaseError::fail(format!("step {k}: {e}")))?;
            prop_assert!(!report.ess.nan() && !report.log_evidence.nan());
        } else {
            prop_assert_eq!(result, Err(Error::NonFiniteMeasurement));
        }
        let total: f64 = (0..N).map(|i| pf.weight(i).as_f64()).sum();
        prop_assert!(
            (total - 1.0).abs() < tolerance,
            "step {} (y = {:?}): weights sum to {}",
            k,
            y,
            total
        );
        prop_assert!(pf.particles().iter().all(|p| p.iter().all(|v| v.finite())));
    }
    Ok(())
}

proptest! {
    #![proptest_config(config(64, 7001))]

    #[test]
    fn pf_weights_sum_to_one_after_every_update(
        seed in any::<u64>(),
        scheme in scheme(),
        threshold in 0.0..=1.0f64,
        ys in prop::collection::vec((prop::option::weighted(0.9, measurement()), 0.01..5.0f64), 1..40),
    ) {
        check_pf_weights::<f64>(seed, scheme, threshold, &ys, 1e-6)?;
    }

    /// f32 has 24-bit weights: the normalisation holds to single-precision round-off.
    #[test]
    fn pf_weights_sum_to_one_after_every_update_f32(
        seed in any::<u64>(),
        scheme in scheme(),
        threshold in 0.0..=1.0f64,
        ys in prop::collection::vec((prop::option::weighted(0.9, -5.0..5.0f64), 0.01..5.0f64), 1..40),
    ) {
        check_pf_weights::<f32>(seed, scheme, threshold, &ys, 1e-5)?;
    }
}

/// Symmetric and positive semi-definite up to round-off relative to the largest entry.
fn assert_symmetric_psd(p: &Matrix4<f64>) -> Result<(), TestCaseError> {
    prop_assert!(
        p.iter().all(|v| v.is_finite()),
        "non-finite covariance {}",
        p
    );
    prop_assert_eq!(p, &p.transpose(), "asymmetric covariance");
    let scale = p.amax().max(f64::MIN_POSITIVE);
    let min_eig = p.symmetric_eigenvalues().min();
    prop_assert!(min_eig >= -1e-9 * scale, "eigenvalue {} of {}", min_eig, p);
    Ok(())
}

proptest! {
    #![proptest_config(config(64, 7002))]

    #[test]
    fn ukf_covariance_stays_symmetric_psd_on_nonlinear_model(
        alpha in 0.1..1.0f64,
        kappa in 0.0..2.0f64,
        p0_diag in prop::array::uniform4(0.01..100.0f64),
        steps in prop::collection::vec(
            ((measurement(), -3.0..3.0f64), 0.01..2.0f64, (-2.0..2.0f64, -2.0..2.0f64)),
            1..60,
        ),
    ) {
        let model = DragRadar { drag: 0.01 };
        let q = Matrix4::from_diagonal(&Vector4::new(0.01, 0.01, 0.05, 0.05));
        let r = nalgebra::Matrix2::new(1.0, 0.0, 0.0, 1e-4);
        let params = SigmaParams { alpha, beta: 2.0, kappa };
        let mut ukf = Ukf::<f64, 4, 9>::new(
            Vector4::new(100.0, 50.0, 8.0, 4.0),
            Matrix4::from_diagonal(&Vector4::from(p0_diag)),
            q,
            params,
        ).unwrap();
        for ((range, bearing), dt, (ax, ay)) in steps {
            let u = Vector2::new(ax, ay);
            // Errors are allowed (a diverged model, a lost factorisation) but must leave P intact.
            let before = *ukf.covariance();
            if ukf.predict(&model, &u, dt).is_err() {
                prop_assert_eq!(ukf.covariance(), &before);
            }
            assert_symmetric_psd(ukf.covariance())?;
            let before = *ukf.covariance();
            if ukf.update(&model, &u, &[range, bearing], &r).is_err() {
                prop_assert_eq!(ukf.covariance(), &before);
            }
            assert_symmetric_psd(ukf.covariance())?;
        }
    }
}

/// Damage grows linearly at rate `x[1]`; end of life at damage 1.
struct LinearDamage;
impl Model<f64, 2, 1> for LinearDamage {
    fn step(&self, x: &Vector2<f64>, _u: &Vector1<f64>, dt: f64) -> Vector2<f64> {
        Vector2::new(x[0] + x[1] * dt, x[1])
    }
}
impl Stochastic<f64, 2, 1> for LinearDamage {
    fn measurement_len(&self) -> usize {
        1
    }
    fn log_likelihood(&self, _x: &Vector2<f64>, _u: &Vector1<f64>, _y: &[f64]) -> f64 {
        0.0
    }
}
struct DamageOne;
impl EndOfLife<f64, 2> for DamageOne {
    fn reached(&self, x: &Vector2<f64>) -> bool {
        x[0] >= 1.0
    }
}

fn assert_ordered(s: &Summary<f64>, lo: f64, hi: f64) -> Result<(), TestCaseError> {
    let p = [s.p01, s.p05, s.p25, s.median, s.p75, s.p95, s.p99];
    prop_assert!(
        p.windows(2).all(|w| w[0] <= w[1]),
        "percentiles not ordered: {:?}",
        s
    );
    prop_assert!(
        lo <= s.p01 && s.p99 <= hi,
        "percentiles outside [{}, {}]: {:?}",
        lo,
        hi,
        s
    );
    prop_assert!(!s.mean.is_nan() && s.rmad >= 0.0, "{:?}", s);
    Ok(())
}

proptest! {
    #![proptest_config(config(128, 7003))]

    #[test]
    fn rul_summary_percentiles_are_ordered(
        samples in prop::collection::vec(
            (prop_oneof![8 => 0.0..1e4f64, 1 => Just(f64::MAX), 1 => prop::num::f64::ANY],
             prop_oneof![8 => 0.0..1.0f64, 1 => Just(0.0), 1 => prop::num::f64::ANY]),
            1..300,
        ),
    ) {
        let times: Vec<f64> = samples.iter().map(|s| s.0).collect();
        let weights: Vec<f64> = samples.iter().map(|s| s.1).collect();
        let mut buf = vec![(0.0, 0.0); samples.len()];
        let usable: Vec<f64> = samples
            .iter()
            .filter(|(t, w)| t.is_finite() && w.is_finite() && *w >= 0.0)
            .map(|s| s.0)
            .collect();
        let positive = samples
            .iter()
            .any(|(t, w)| t.is_finite() && w.is_finite() && *w > 0.0);
        match rul_distribution(&times, &weights, &mut buf) {
            Some(s) => {
                let lo = usable.iter().copied().fold(f64::INFINITY, f64::min);
                let hi = usable.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                assert_ordered(&s, lo, hi)?;
                // The weighted mean sums w * t with weights scaled to at most 1, which cannot
                // overflow while |t| <= 1e300 (300 samples at most).
                if usable.iter().all(|t| t.abs() <= 1e300) {
                    let tol = 1e-9 * lo.abs().max(hi.abs());
                    prop_assert!(s.mean >= lo - tol && s.mean <= hi + tol, "{:?}", s);
                }
            }
            None => prop_assert!(!positive, "summary missing although a sample has weight"),
        }
    }

    #[test]
    fn eol_times_are_exact_and_rul_summary_ordered(
        states in prop::collection::vec((0.0..0.99f64, 1e-3..0.5f64), 1..200),
        weights in prop::collection::vec(0.0..1.0f64, 200),
        dt in 0.05..2.0f64,
    ) {
        let xs: Vec<Vector2<f64>> = states.iter().map(|&(d, w)| Vector2::new(d, w)).collect();
        let mut times = vec![0.0; xs.len()];
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(0);
        let settings = PredictionSettings::deterministic(dt, 100_000);
        let reached = predict_eol(
            &LinearDamage, &DamageOne, &xs, |_| Vector1::new(0.0), &settings, &mut rng, &mut times,
        ).unwrap();
        prop_assert_eq!(reached, xs.len());
        for (&(d, w), &t) in states.iter().zip(&times) {
            let exact = (1.0 - d) / w;
            // The first whole step at or past the exact crossing.
            prop_assert!(t >= exact - 1e-9 * exact && t < exact + dt + 1e-9 * exact,
                "d0 {} rate {}: predicted {} exact {}", d, w, t, exact);
        }
        let mut buf = vec![(0.0, 0.0); xs.len()];
        let w = &weights[..xs.len()];
        if let Some(s) = rul_distribution(&times, w, &mut buf) {
            let lo = times.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = times.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            assert_ordered(&s, lo, hi)?;
        }
    }
}
