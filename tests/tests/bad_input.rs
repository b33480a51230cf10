//! Issue 2 "Bad input": a non-finite measurement, a measurement of the wrong length, a bad
//! dt or input is an error that leaves the filter exactly as it was (checked bit for bit and
//! by continuing both the touched filter and an untouched clone); a measurement no particle
//! can explain is skipped with a flag, never turned into NaN.

use nalgebra::{SVector, Vector1, Vector2};
use prognos_core::Error;
use prognos_core::filter::particle::{ParticleFilter, PfConfig};
use prognos_core::filter::ukf::{SigmaParams, Ukf};
use prognos_core::model::{Model, Stochastic};
use prognos_core::safeguard::Flags;
use prognos_tests::linear_gaussian::{LinearGaussian, input, oscillator};
use rand_core::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;

const N: usize = 300;
type Pf = ParticleFilter<f64, 2, N>;

fn pf_bits(pf: &Pf) -> (Vec<[u64; 2]>, Vec<u64>) {
    (
        pf.particles()
            .iter()
            .map(|p| [p[0].to_bits(), p[1].to_bits()])
            .collect(),
        pf.log_weights().iter().map(|w| w.to_bits()).collect(),
    )
}

fn ukf_bits(ukf: &Ukf<f64, 2, 5>) -> Vec<u64> {
    ukf.state()
        .iter()
        .chain(ukf.covariance().iter())
        .map(|v| v.to_bits())
        .collect()
}

/// A PF that has run a few steps (non-uniform weights, resampled particles).
fn warmed_up_pf(model: &LinearGaussian<f64, 2, 1>) -> (Pf, Xoshiro256PlusPlus) {
    let config = PfConfig {
        resample_threshold: 0.5,
        ..PfConfig::default()
    };
    let mut pf = Pf::new(Vector2::zeros(), config).unwrap();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(9);
    pf.init_gaussian(&Vector2::new(1.0, 0.0), &Vector2::new(0.5, 0.5), &mut rng)
        .unwrap();
    for k in 0..10 {
        let y = [(0.3 * k as f64).cos()];
        pf.step(model, &Vector1::new(input(k)), Some(&y), 1.0, &mut rng)
            .unwrap();
    }
    (pf, rng)
}

#[test]
fn particle_filter_rejects_bad_input_and_stays_unchanged() {
    let model = oscillator();
    let (mut pf, rng) = warmed_up_pf(&model);
    let untouched = pf.clone();
    let before = pf_bits(&pf);
    let u = Vector1::new(0.1);
    let good = [0.5];
    let mut bad_rng = rng.clone();
    let len = |got| Error::MeasurementLength { expected: 1, got };
    let cases: Vec<(&str, Result<_, Error>, Error)> = vec![
        (
            "NaN measurement",
            pf.step(&model, &u, Some(&[f64::NAN]), 1.0, &mut bad_rng)
                .map(|_| ()),
            Error::NonFiniteMeasurement,
        ),
        (
            "infinite measurement",
            pf.step(&model, &u, Some(&[f64::INFINITY]), 1.0, &mut bad_rng)
                .map(|_| ()),
            Error::NonFiniteMeasurement,
        ),
        (
            "empty measurement",
            pf.step(&model, &u, Some(&[]), 1.0, &mut bad_rng)
                .map(|_| ()),
            len(0),
        ),
        (
            "two-channel measurement",
            pf.step(&model, &u, Some(&[0.5, 0.5]), 1.0, &mut bad_rng)
                .map(|_| ()),
            len(2),
        ),
        (
            "dt = 0",
            pf.step(&model, &u, Some(&good), 0.0, &mut bad_rng)
                .map(|_| ()),
            Error::InvalidTimeStep,
        ),
        (
            "dt < 0",
            pf.step(&model, &u, Some(&good), -0.5, &mut bad_rng)
                .map(|_| ()),
            Error::InvalidTimeStep,
        ),
        (
            "dt NaN",
            pf.step(&model, &u, None, f64::NAN, &mut bad_rng)
                .map(|_| ()),
            Error::InvalidTimeStep,
        ),
        (
            "NaN input",
            pf.step(
                &model,
                &Vector1::new(f64::NAN),
                Some(&good),
                1.0,
                &mut bad_rng,
            )
            .map(|_| ()),
            Error::NonFiniteInput,
        ),
        (
            "update with NaN",
            pf.update(&model, &u, &[f64::NAN], &mut bad_rng).map(|_| ()),
            Error::NonFiniteMeasurement,
        ),
        (
            "update with wrong length",
            pf.update(&model, &u, &[1.0, 2.0, 3.0], &mut bad_rng)
                .map(|_| ()),
            len(3),
        ),
        (
            "predict with dt = 0",
            pf.predict(&model, &u, 0.0, &mut bad_rng).map(|_| ()),
            Error::InvalidTimeStep,
        ),
        (
            "predict with dt = -inf",
            pf.predict(&model, &u, f64::NEG_INFINITY, &mut bad_rng)
                .map(|_| ()),
            Error::InvalidTimeStep,
        ),
    ];
    for (label, result, expected) in cases {
        assert_eq!(result, Err(expected), "{label}");
    }
    assert_eq!(
        pf_bits(&pf),
        before,
        "bad input changed the particle filter"
    );
    // Hidden state too: the touched filter and the clone continue identically.
    let mut clone = untouched;
    let (mut rng_a, mut rng_b) = (rng.clone(), rng);
    for k in 10..20 {
        let y = [(0.3 * k as f64).cos()];
        let u = Vector1::new(input(k));
        let a = pf.step(&model, &u, Some(&y), 1.0, &mut rng_a).unwrap();
        let b = clone.step(&model, &u, Some(&y), 1.0, &mut rng_b).unwrap();
        assert_eq!(a, b);
    }
    assert_eq!(pf_bits(&pf), pf_bits(&clone));
}

#[test]
fn ukf_rejects_bad_input_and_stays_unchanged() {
    let model = oscillator();
    let mut ukf = Ukf::<f64, 2, 5>::new(
        Vector2::new(1.0, 0.0),
        nalgebra::Matrix2::new(0.5, 0.1, 0.1, 0.4),
        model.q,
        SigmaParams::default(),
    )
    .unwrap();
    for k in 0..5 {
        let u = Vector1::new(input(k));
        ukf.predict(&model, &u, 1.0).unwrap();
        ukf.update(&model, &u, &[(0.3 * k as f64).cos()], &model.r)
            .unwrap();
    }
    // Leave it between predict and update, where the propagated sigma points are live state.
    ukf.predict(&model, &Vector1::new(0.2), 1.0).unwrap();
    let untouched = ukf.clone();
    let before = ukf_bits(&ukf);
    let u = Vector1::new(0.1);
    let r = model.r;
    let len = |got| Error::MeasurementLength { expected: 1, got };
    let cases: Vec<(&str, Result<(), Error>, Error)> = vec![
        (
            "predict dt = 0",
            ukf.predict(&model, &u, 0.0).map(|_| ()),
            Error::InvalidTimeStep,
        ),
        (
            "predict dt < 0",
            ukf.predict(&model, &u, -1.0).map(|_| ()),
            Error::InvalidTimeStep,
        ),
        (
            "predict dt NaN",
            ukf.predict(&model, &u, f64::NAN).map(|_| ()),
            Error::InvalidTimeStep,
        ),
        (
            "predict NaN input",
            ukf.predict(&model, &Vector1::new(f64::NAN), 1.0)
                .map(|_| ()),
            Error::NonFiniteInput,
        ),
        (
            "update NaN",
            ukf.update(&model, &u, &[f64::NAN], &r).map(|_| ()),
            Error::NonFiniteMeasurement,
        ),
        (
            "update -inf",
            ukf.update(&model, &u, &[f64::NEG_INFINITY], &r).map(|_| ()),
            Error::NonFiniteMeasurement,
        ),
        (
            "update empty",
            ukf.update(&model, &u, &[], &r).map(|_| ()),
            len(0),
        ),
        (
            "update two channels",
            ukf.update(&model, &u, &[1.0, 2.0], &r).map(|_| ()),
            len(2),
        ),
        (
            "update NaN R",
            ukf.update(&model, &u, &[1.0], &nalgebra::Matrix1::new(f64::NAN))
                .map(|_| ()),
            Error::InvalidParameter("r"),
        ),
    ];
    for (label, result, expected) in cases {
        assert_eq!(result, Err(expected), "{label}");
    }
    assert_eq!(ukf_bits(&ukf), before, "bad input changed the UKF");
    let mut clone = untouched;
    for k in 0..5 {
        let u = Vector1::new(input(k));
        let y = [0.1 * k as f64];
        let a = ukf.update(&model, &u, &y, &r).unwrap();
        let b = clone.update(&model, &u, &y, &r).unwrap();
        assert_eq!(a, b);
        ukf.predict(&model, &u, 1.0).unwrap();
        clone.predict(&model, &u, 1.0).unwrap();
    }
    assert_eq!(ukf_bits(&ukf), ukf_bits(&clone));
}

/// The oscillator with a likelihood that no particle can satisfy (or that is NaN).
struct Hopeless {
    inner: LinearGaussian<f64, 2, 1>,
    nan: bool,
}

impl Model<f64, 2, 1> for Hopeless {
    fn step(&self, x: &Vector2<f64>, u: &Vector1<f64>, dt: f64) -> Vector2<f64> {
        self.inner.step(x, u, dt)
    }
}

impl Stochastic<f64, 2, 1> for Hopeless {
    fn measurement_len(&self) -> usize {
        1
    }
    fn sample_step<R: rand_core::Rng + ?Sized>(
        &self,
        x: &Vector2<f64>,
        u: &Vector1<f64>,
        dt: f64,
        rng: &mut R,
    ) -> Vector2<f64> {
        self.inner.sample_step(x, u, dt, rng)
    }
    fn log_likelihood(&self, _x: &Vector2<f64>, _u: &Vector1<f64>, _y: &[f64]) -> f64 {
        if self.nan {
            f64::NAN
        } else {
            f64::NEG_INFINITY
        }
    }
}

fn assert_finite_and_normalised(pf: &Pf, label: &str) {
    assert!(
        pf.particles()
            .iter()
            .all(|p| p.iter().all(|v| v.is_finite())),
        "{label}: non-finite particle"
    );
    let total: f64 = (0..N).map(|i| pf.weight(i)).sum();
    assert!(
        (total - 1.0).abs() < 1e-12,
        "{label}: weights sum to {total}"
    );
    let m: SVector<f64, 2> = pf.mean();
    assert!(m.iter().all(|v| v.is_finite()), "{label}: mean {m:?}");
    assert!(
        pf.covariance().iter().all(|v| v.is_finite()),
        "{label}: covariance"
    );
}

#[test]
fn weight_collapse_becomes_a_flagged_predict_only_step() {
    let model = oscillator();
    for nan in [false, true] {
        let hopeless = Hopeless {
            inner: model.clone(),
            nan,
        };
        let (mut pf, rng) = warmed_up_pf(&model);
        let mut predict_only = pf.clone();
        let (mut rng_a, mut rng_b) = (rng.clone(), rng);
        for k in 0..5 {
            let u = Vector1::new(input(k));
            let report = pf
                .step(&hopeless, &u, Some(&[0.3]), 1.0, &mut rng_a)
                .unwrap();
            assert!(
                report.flags.contains(Flags::WEIGHT_COLLAPSE_RECOVERED),
                "nan={nan}"
            );
            assert!(!report.fused);
            assert!(!report.flags.contains(Flags::RESAMPLED));
            // Exactly what a step without a measurement does.
            predict_only
                .step(&model, &u, None, 1.0, &mut rng_b)
                .unwrap();
            assert_eq!(pf_bits(&pf), pf_bits(&predict_only), "nan={nan}, step {k}");
            assert_finite_and_normalised(&pf, "after collapse");
        }
        // And the filter keeps working afterwards.
        let report = pf
            .step(&model, &Vector1::new(0.0), Some(&[0.3]), 1.0, &mut rng_a)
            .unwrap();
        assert!(report.fused);
        assert_finite_and_normalised(&pf, "after recovery");
    }
}

#[test]
fn extreme_measurements_never_produce_nan() {
    let model = oscillator();
    let (mut pf, mut rng) = warmed_up_pf(&model);
    // 1e150 gives finite but enormous negative log-likelihoods (log-sum-exp must cope);
    // 1e200 overflows the squared residual to -inf everywhere (weight collapse).
    for (k, y) in [1e150, -1e150, 1e200, f64::MAX, -f64::MAX, 1e-300, 0.0]
        .into_iter()
        .enumerate()
    {
        let report = pf
            .step(&model, &Vector1::new(input(k)), Some(&[y]), 1.0, &mut rng)
            .unwrap();
        assert!(!report.log_evidence.is_nan(), "y = {y}");
        assert!(
            !report.ess.is_nan() && report.ess >= 1.0 - 1e-9,
            "y = {y}: ess {}",
            report.ess
        );
        if y.abs() >= 1e200 {
            assert!(
                report.flags.contains(Flags::WEIGHT_COLLAPSE_RECOVERED),
                "y = {y}"
            );
        } else {
            assert!(report.fused, "y = {y}");
        }
        assert_finite_and_normalised(&pf, &format!("y = {y}"));
    }
}
