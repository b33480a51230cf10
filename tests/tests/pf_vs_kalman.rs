//! On a linear-Gaussian model the Kalman filter is the exact posterior; a SIR particle filter
//! with N = 2000 must track its mean to a small fraction of the posterior standard deviation
//! and its variance to a few percent.

use nalgebra::{SVector, Vector1, Vector2};
use prognos_core::Real;
use prognos_core::filter::particle::{ParticleFilter, PfConfig};
use prognos_core::filter::resample::Resampling;
use prognos_core::model::Stochastic;
use prognos_tests::linear_gaussian::{KalmanFilter, LinearGaussian, input, oscillator};
use rand_core::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;

const N: usize = 2000;
const STEPS: usize = 200;

/// Agreement of a PF in scalar `T` with the f64 Kalman filter, per state entry:
/// time-averaged |PF mean - KF mean| / KF std, and time-averaged |PF var / KF var - 1|.
struct Agreement {
    mean_error_in_std: [f64; 2],
    variance_rel_error: [f64; 2],
}

fn run<T: Real>(scheme: Resampling, seed: u64) -> Agreement {
    let model = oscillator();
    let model_t: LinearGaussian<T, 2, 1> = model.cast();
    let c = |v: f64| prognos_core::cast::<T>(v);
    let x0 = Vector2::new(1.0, 0.0);
    let p0_std = Vector2::new(0.5, 0.5);
    let mut kf = KalmanFilter::new(x0, nalgebra::Matrix2::from_diagonal(&p0_std.map(|s| s * s)));
    let config = PfConfig {
        resampling: scheme,
        resample_threshold: c(0.5),
        ..PfConfig::default()
    };
    let mut pf = ParticleFilter::<T, 2, N>::new(x0.map(c), config).unwrap();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    pf.init_gaussian(&x0.map(c), &p0_std.map(c), &mut rng)
        .unwrap();
    // The truth and its measurements come from a separate stream.
    let mut world = Xoshiro256PlusPlus::seed_from_u64(seed ^ 0x5eed);
    let mut truth = Vector2::new(1.5, -0.3);
    let mut mean_err = [0.0; 2];
    let mut var_err = [0.0; 2];
    for k in 0..STEPS {
        let u = input(k);
        truth = model.sample_step(&truth, &Vector1::new(u), 1.0, &mut world);
        let y = model.sample_measurement(&truth, &mut world);
        kf.predict(&model, u);
        kf.update(&model, &y);
        let report = pf
            .step(
                &model_t,
                &Vector1::new(c(u)),
                Some(&[c(y[0])]),
                T::one(),
                &mut rng,
            )
            .unwrap();
        assert!(report.fused);
        let m: SVector<f64, 2> = pf.mean().map(|v| v.as_f64());
        let p = pf.covariance().map(|v| v.as_f64());
        for i in 0..2 {
            let kf_var = kf.p[(i, i)];
            mean_err[i] += (m[i] - kf.x[i]).abs() / kf_var.sqrt();
            var_err[i] += (p[(i, i)] / kf_var - 1.0).abs();
        }
    }
    Agreement {
        mean_error_in_std: mean_err.map(|e| e / STEPS as f64),
        variance_rel_error: var_err.map(|e| e / STEPS as f64),
    }
}

fn check(label: &str, a: &Agreement, mean_bound: f64, var_bound: f64) {
    println!(
        "{label}: mean error/KF std {:.4} {:.4}, |var/KF var - 1| {:.4} {:.4}",
        a.mean_error_in_std[0],
        a.mean_error_in_std[1],
        a.variance_rel_error[0],
        a.variance_rel_error[1]
    );
    for i in 0..2 {
        assert!(
            a.mean_error_in_std[i] < mean_bound,
            "{label}: state {i} mean error {} KF std",
            a.mean_error_in_std[i]
        );
        assert!(
            a.variance_rel_error[i] < var_bound,
            "{label}: state {i} variance error {}",
            a.variance_rel_error[i]
        );
    }
}

#[test]
fn particle_filter_matches_kalman_filter_f64() {
    for (scheme, seed) in [
        (Resampling::Systematic, 1),
        (Resampling::Stratified, 2),
        (Resampling::Residual, 3),
        (Resampling::Multinomial, 4),
    ] {
        let a = run::<f64>(scheme, seed);
        check(&format!("f64 {scheme:?}"), &a, 0.1, 0.1);
    }
}

#[test]
fn particle_filter_matches_kalman_filter_f32() {
    let a = run::<f32>(Resampling::Systematic, 5);
    check("f32 Systematic", &a, 0.15, 0.15);
}

/// The same model without a predicted measurement: the PF must then report no innovation
/// and otherwise behave bit for bit as with it.
struct Opaque(LinearGaussian<f64, 2, 1>);
impl prognos_core::model::Model<f64, 2, 1> for Opaque {
    fn step(&self, x: &Vector2<f64>, u: &Vector1<f64>, dt: f64) -> Vector2<f64> {
        self.0.step(x, u, dt)
    }
}
impl Stochastic<f64, 2, 1> for Opaque {
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
        self.0.sample_step(x, u, dt, rng)
    }
    fn log_likelihood(&self, x: &Vector2<f64>, u: &Vector1<f64>, y: &[f64]) -> f64 {
        self.0.log_likelihood(x, u, y)
    }
}

/// The PF's innovation (prior-weighted predicted measurement) and its variance against the
/// Kalman filter's exact `y - H x^-` and `S = H P^- H^T + R`.
#[test]
fn particle_filter_innovation_matches_kalman_filter() {
    let model = oscillator();
    let x0 = Vector2::new(1.0, 0.0);
    let p0_std = Vector2::new(0.5, 0.5);
    let mut kf = KalmanFilter::new(x0, nalgebra::Matrix2::from_diagonal(&p0_std.map(|s| s * s)));
    let config = PfConfig {
        resample_threshold: 0.5,
        ..PfConfig::default()
    };
    let mut pf = ParticleFilter::<f64, 2, N>::new(x0, config).unwrap();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(9);
    pf.init_gaussian(&x0, &p0_std, &mut rng).unwrap();
    let mut blind = pf.clone();
    let mut blind_rng = rng.clone();
    let opaque = Opaque(model.clone());
    let mut world = Xoshiro256PlusPlus::seed_from_u64(9 ^ 0x5eed);
    let mut truth = Vector2::new(1.5, -0.3);
    let (mut mean_err, mut var_err, mut ratio_err) = (0.0, 0.0, 0.0);
    for k in 0..STEPS {
        let u = input(k);
        truth = model.sample_step(&truth, &Vector1::new(u), 1.0, &mut world);
        let y = model.sample_measurement(&truth, &mut world);
        kf.predict(&model, u);
        let s = (model.h * kf.p * model.h.transpose() + model.r)[0];
        let e = y[0] - (model.h * kf.x)[0];
        kf.update(&model, &y);
        let uu = Vector1::new(u);
        let report = pf.step(&model, &uu, Some(&[y[0]]), 1.0, &mut rng).unwrap();
        let plain = blind
            .step(&opaque, &uu, Some(&[y[0]]), 1.0, &mut blind_rng)
            .unwrap();
        assert_eq!(report.channels, 1);
        assert_eq!((plain.channels, plain.test_ratio), (0, 0.0));
        assert_eq!(pf.particles(), blind.particles());
        assert_eq!(pf.log_weights(), blind.log_weights());
        assert_eq!(report.log_evidence, plain.log_evidence);
        mean_err += (report.innovation[0] - e).abs() / s.sqrt();
        var_err += (report.innovation_variance[0] / s - 1.0).abs();
        ratio_err += (report.test_ratio - e * e / s).abs();
        assert!(
            (report.test_ratio - report.innovation[0].powi(2) / report.innovation_variance[0])
                .abs()
                < 1e-12
        );
    }
    let n = STEPS as f64;
    let (mean_err, var_err, ratio_err) = (mean_err / n, var_err / n, ratio_err / n);
    println!(
        "innovation error/sqrt(S) {mean_err:.4}, |var/S - 1| {var_err:.4}, |ratio - e^2/S| {ratio_err:.4}"
    );
    assert!(mean_err < 0.05, "{mean_err}");
    assert!(var_err < 0.1, "{var_err}");
    assert!(ratio_err < 0.1, "{ratio_err}");
}
