//! Tests of the trained GP, the GP-UKF and the IMM against known functions.

use super::prognosis::BearingGp;
use super::train::{Dataset, GP_POINTS, TrainedGp, greedy_inducing, train, train_sparse};
use nalgebra::{Matrix1, SVector, Vector1, Vector2};
use prognos_core::filter::imm::Imm;
use prognos_core::filter::ukf::SigmaParams;
use prognos_core::learn::gp::{GpTransition, GpUkf, StateThreshold, sample_rul};
use prognos_core::prognose::rul_distribution;
use prognos_core::random::{standard_normal, uniform01};
use rand_core::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;

/// Noisy samples of `r' - r = f(r, du)` over r in [0, 1.1], du in [0, 0.4].
fn dataset(f: impl Fn(f64, f64) -> f64, noise: f64, seed: u64) -> Dataset {
    dataset_of(GP_POINTS, f, noise, seed)
}

fn dataset_of(n: usize, f: impl Fn(f64, f64) -> f64, noise: f64, seed: u64) -> Dataset {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut d = Dataset::default();
    for _ in 0..n {
        let r = 1.1 * uniform01::<f64, _>(&mut rng);
        let du = 0.4 * uniform01::<f64, _>(&mut rng);
        d.inputs.push([r, du]);
        d.targets
            .push(f(r, du) + noise * standard_normal::<f64, _>(&mut rng));
    }
    d
}

fn known(r: f64, du: f64) -> f64 {
    0.01 + 0.02 * r * r + 0.03 * du
}

fn trained(f: impl Fn(f64, f64) -> f64, seed: u64) -> (TrainedGp, Box<BearingGp>) {
    let gp = train(&dataset(f, 1e-4, seed), GP_POINTS).unwrap();
    let core = gp.to_core::<GP_POINTS>().unwrap();
    (gp, core)
}

#[test]
fn core_gp_predictor_equals_dense_gp() {
    let (gp, core) = trained(known, 1);
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(2);
    for _ in 0..50 {
        let x = [
            uniform01::<f64, _>(&mut rng),
            0.4 * uniform01::<f64, _>(&mut rng),
        ];
        let (mean, var) = gp.predict_dense(&x);
        let p = core.predict(&Vector2::new(x[0], x[1])).unwrap();
        assert!(
            (p.mean - mean).abs() < 1e-9 * (1.0 + mean.abs()),
            "{} {mean}",
            p.mean
        );
        assert!(
            (p.latent_variance - var.max(0.0)).abs() < 1e-9 * gp.hyper.signal_variance + 1e-12,
            "{} {var}",
            p.latent_variance
        );
        // And it learned the function.
        assert!(
            (mean - known(x[0], x[1])).abs() < 1e-3,
            "{mean} {}",
            known(x[0], x[1])
        );
        assert!(!p.extrapolating);
    }
    // Far outside the training box: flagged, wider than the prior.
    let far = core.predict(&Vector2::new(5.0, 0.1)).unwrap();
    assert!(far.extrapolating && far.latent_variance > gp.hyper.signal_variance);
    // The exported constants compile-round-trip as text.
    let src = gp.to_rust_source("BEARING_GP");
    assert!(src.contains("pub const BEARING_GP_ALPHA: [f64; 64]"));
}

#[test]
fn gp_ukf_tracks_a_known_function_and_predicts_its_rul() {
    let (_, gp) = trained(known, 3);
    let std = 0.03;
    let transition = GpTransition {
        gps: [&*gp],
        measurement_std: Vector1::new(std),
    };
    let mut f: GpUkf<f64, 1, 1, 2, GP_POINTS, 3> = GpUkf::new(
        transition,
        Vector1::new(0.0),
        Matrix1::new(std * std),
        Matrix1::new(std * std),
        SigmaParams::default(),
    )
    .unwrap();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(4);
    let du: Vec<f64> = (0..200)
        .map(|_| 0.4 * uniform01::<f64, _>(&mut rng))
        .collect();
    let mut r = 0.0;
    let (mut se, mut n) = (0.0, 0);
    for (k, &du_k) in du.iter().enumerate().take(25) {
        r += known(r, du_k);
        let z = r + std * standard_normal::<f64, _>(&mut rng);
        f.step(&Vector1::new(du_k), &[z]).unwrap();
        if k >= 5 {
            se += (f.state()[0] - r).powi(2);
            n += 1;
        }
    }
    let rmse = (se / n as f64).sqrt();
    assert!(rmse < 0.5 * std, "rmse {rmse}");
    // True remaining cycles to r >= 1 under the same future loads.
    let (mut rt, mut steps) = (r, 0usize);
    while rt < 1.0 {
        rt += known(rt, du[25 + steps]);
        steps += 1;
    }
    let mut states = vec![Vector1::new(0.0); 200];
    let mut times = vec![0.0; 200];
    sample_rul(
        f.transition(),
        f.state(),
        f.covariance(),
        &StateThreshold {
            index: 0,
            level: 1.0,
        },
        |s| Vector1::new(du[25 + s as usize]),
        1000,
        &mut rng,
        &mut states,
        &mut times,
    )
    .unwrap();
    let mut buf = vec![(0.0, 0.0); 200];
    let s = rul_distribution(&times, &vec![1.0; 200], &mut buf).unwrap();
    assert!(
        (s.median - steps as f64).abs() <= 0.1 * steps as f64,
        "median {} true {steps}",
        s.median
    );
    assert!(s.p05 <= s.median && s.median <= s.p95);
    // The truth lies within the 90 % interval (widened by the one-cycle resolution).
    assert!(s.p05 - 1.0 <= steps as f64 && steps as f64 <= s.p95 + 1.0);
}

#[test]
fn imm_of_gp_ukfs_picks_the_model_that_generates_the_data() {
    let slow = |r: f64, du: f64| 0.005 + 0.005 * r + 0.01 * du;
    let fast = |r: f64, du: f64| 0.03 + 0.01 * r + 0.01 * du;
    let (_, gp_slow) = trained(slow, 5);
    let (_, gp_fast) = trained(fast, 6);
    let std = 0.01;
    fn make(gp: &BearingGp, std: f64) -> GpUkf<'_, f64, 1, 1, 2, GP_POINTS, 3> {
        GpUkf::new(
            GpTransition {
                gps: [gp],
                measurement_std: Vector1::new(std),
            },
            Vector1::new(0.0),
            Matrix1::new(std * std),
            Matrix1::new(std * std),
            SigmaParams::default(),
        )
        .unwrap()
    }
    let filters = [make(&gp_slow, std), make(&gp_fast, std)];
    let mut imm = Imm::new(
        filters,
        SVector::from([0.5, 0.5]),
        Imm::<f64, GpUkf<f64, 1, 1, 2, GP_POINTS, 3>, 1, 2>::uniform_switching(0.95),
    )
    .unwrap();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(7);
    let mut r = 0.0;
    let (mut right, mut counted) = (0, 0);
    for k in 0..60 {
        let du = 0.4 * uniform01::<f64, _>(&mut rng);
        // Slow for 30 cycles, then fast.
        let mode = usize::from(k >= 30);
        r += if mode == 0 { slow(r, du) } else { fast(r, du) };
        let z = r + std * standard_normal::<f64, _>(&mut rng);
        let rep = imm.step(&Vector1::new(du), &[z]).unwrap();
        if k % 30 >= 8 {
            counted += 1;
            if rep.probabilities[mode] > 0.8 {
                right += 1;
            }
        }
    }
    assert!(right as f64 >= 0.9 * counted as f64, "{right} of {counted}");
}

#[test]
fn rate_state_learns_an_unseen_units_rate_where_the_plain_gp_ukf_cannot() {
    use prognos_core::learn::gp_rate::{RateScaledGpUkf, RateScaledTransition};
    // The GP learned `known`; the unit degrades 1.4 times faster (theta = ln 1.4 = 0.34).
    let (_, gp) = trained(known, 8);
    let faster = |r: f64, du: f64| 1.4 * known(r, du);
    let std = 0.02;
    let mut plain: GpUkf<f64, 1, 1, 2, GP_POINTS, 3> = GpUkf::new(
        GpTransition {
            gps: [&*gp],
            measurement_std: Vector1::new(std),
        },
        Vector1::new(0.0),
        Matrix1::new(std * std),
        Matrix1::new(std * std),
        SigmaParams::default(),
    )
    .unwrap();
    let mut rated: RateScaledGpUkf<f64, 2, 1, 2, GP_POINTS, 5> = RateScaledGpUkf::new(
        RateScaledTransition {
            gp: &*gp,
            measurement_std: std,
            pivot: 0.5,
        },
        Vector2::new(0.0, 0.0),
        nalgebra::Matrix2::new(std * std, 0.0, 0.0, 0.1),
        std * std,
        1e-5,
        SigmaParams::default(),
    )
    .unwrap();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(9);
    let du: Vec<f64> = (0..300)
        .map(|_| 0.4 * uniform01::<f64, _>(&mut rng))
        .collect();
    let mut r = 0.0;
    let mut k = 0;
    while r < 0.5 {
        r += faster(r, du[k]);
        let z = r + std * standard_normal::<f64, _>(&mut rng);
        plain.step(&Vector1::new(du[k]), &[z]).unwrap();
        rated.step(&Vector1::new(du[k]), &[z]).unwrap();
        k += 1;
    }
    let theta = rated.state()[1];
    assert!((theta - 1.4f64.ln()).abs() < 0.1, "theta {theta}");
    let (mut rt, mut steps) = (r, 0usize);
    while rt < 1.0 {
        rt += faster(rt, du[k + steps]);
        steps += 1;
    }
    let threshold = StateThreshold {
        index: 0,
        level: 1.0,
    };
    let median = |times: &[f64]| {
        let mut buf = vec![(0.0, 0.0); times.len()];
        rul_distribution(times, &vec![1.0; times.len()], &mut buf)
            .unwrap()
            .median
    };
    let mut times = vec![0.0; 200];
    let mut states1 = vec![Vector1::new(0.0); 200];
    sample_rul(
        plain.transition(),
        plain.state(),
        plain.covariance(),
        &threshold,
        |s| Vector1::new(du[k + s as usize]),
        1000,
        &mut rng,
        &mut states1,
        &mut times,
    )
    .unwrap();
    let plain_median = median(&times);
    let mut states2 = vec![Vector2::new(0.0, 0.0); 200];
    sample_rul(
        rated.transition(),
        rated.state(),
        rated.covariance(),
        &threshold,
        |s| Vector1::new(du[k + s as usize]),
        1000,
        &mut rng,
        &mut states2,
        &mut times,
    )
    .unwrap();
    let rated_median = median(&times);
    let truth = steps as f64;
    assert!(
        (rated_median - truth).abs() <= 0.1 * truth,
        "rate state: median {rated_median}, true {truth}"
    );
    // The fixed-rate GP-UKF keeps the training unit's pace: about 1.4 times too long.
    assert!(
        plain_median > 1.2 * truth,
        "plain: median {plain_median}, true {truth}"
    );
}

#[test]
fn sparse_gp_matches_the_fitc_formulas_and_beats_a_subset_of_the_data() {
    use nalgebra::{DMatrix, DVector};
    let noise = 4e-3;
    let data = dataset_of(600, known, noise, 21);
    let gp = train_sparse(&data, GP_POINTS).unwrap();
    let core = gp.to_core::<GP_POINTS>().unwrap();
    // Textbook FITC (Snelson & Ghahramani 2006) from the same hyperparameters and inducing
    // inputs: mean k_*^T A^-1 K_mn L^-1 y, variance k_** - q_** + k_*^T A^-1 k_*.
    let h = gp.hyper;
    let k = |a: &[f64; 2], b: &[f64; 2]| {
        let q = ((a[0] - b[0]) / h.length_scales[0]).powi(2)
            + ((a[1] - b[1]) / h.length_scales[1]).powi(2);
        h.signal_variance * (-0.5 * q).exp()
    };
    let (picked, residual) = greedy_inducing(&h, &data.inputs, GP_POINTS);
    let z: Vec<[f64; 2]> = picked.iter().map(|&i| data.inputs[i]).collect();
    assert_eq!(z, gp.inputs);
    let (n, m) = (data.inputs.len(), z.len());
    let kmm = DMatrix::from_fn(m, m, |i, j| {
        k(&z[i], &z[j])
            + if i == j {
                1e-6 * h.signal_variance
            } else {
                0.0
            }
    });
    let knm = DMatrix::from_fn(n, m, |i, j| k(&data.inputs[i], &z[j]));
    let lam = DMatrix::from_diagonal(&DVector::from_iterator(
        n,
        residual.iter().map(|d| 1.0 / (h.noise_variance + d)),
    ));
    let a_inv = (&kmm + knm.transpose() * &lam * &knm)
        .try_inverse()
        .unwrap();
    let kmm_inv = kmm.clone().try_inverse().unwrap();
    let y = DVector::from_iterator(n, data.targets.iter().map(|v| v - gp.mean_offset));
    let w = &a_inv * knm.transpose() * &lam * y;
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(22);
    let sod = train(&data, GP_POINTS)
        .unwrap()
        .to_core::<GP_POINTS>()
        .unwrap();
    let (mut err_sparse, mut err_sod) = (0.0, 0.0);
    for _ in 0..200 {
        let x = [
            uniform01::<f64, _>(&mut rng),
            0.4 * uniform01::<f64, _>(&mut rng),
        ];
        let ks = DVector::from_iterator(m, z.iter().map(|zi| k(&x, zi)));
        let mean = gp.mean_offset + ks.dot(&w);
        let var = h.signal_variance - ks.dot(&(&kmm_inv * &ks)) + ks.dot(&(&a_inv * &ks));
        let p = core.predict(&Vector2::new(x[0], x[1])).unwrap();
        assert!((p.mean - mean).abs() < 1e-7, "{} {mean}", p.mean);
        assert!(
            (p.latent_variance - var.max(0.0)).abs() < 1e-6 * h.signal_variance,
            "{} {var}",
            p.latent_variance
        );
        let truth = known(x[0], x[1]);
        err_sparse += (p.mean - truth).abs();
        err_sod += (sod.predict(&Vector2::new(x[0], x[1])).unwrap().mean - truth).abs();
    }
    // All 600 noisy pairs pin the function down better than 64 of them.
    assert!(
        err_sparse < 0.7 * err_sod,
        "sparse {err_sparse}, subset {err_sod}"
    );
}
