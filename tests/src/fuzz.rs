//! Fuzz harnesses shared by the stable proptest suite (`tests/tests/fuzz_steps.rs`, run in
//! CI) and the cargo-fuzz targets (`fuzz/`, nightly). Each harness builds one filter or
//! pipeline in a fixed, seeded state, feeds it a sequence of steps decoded from a [`Feed`]
//! (any `f64`, NaN, infinities, subnormals and huge magnitudes included; `dt` of zero,
//! negative or enormous) and checks the contract of the core after every step:
//!
//! - `Ok`: the state is finite (and covariances symmetric PSD, weights normalised);
//! - `Err`: the state is unchanged, compared bit for bit (`{:?}` of the whole object, whose
//!   floats print in shortest round-trip form, so equal strings mean equal bits up to NaN
//!   payloads).
//!
//! A panic anywhere is a failure by itself. A harness returns `Err(description)` for a
//! violated property.

// `!(a < b)` rejects NaN together with out-of-range values: deliberate.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use crate::drag_radar::DragRadar;
use crate::linear_gaussian::{LinearGaussian, oscillator};
use nalgebra::{Matrix1, Matrix2, SMatrix, SVector, Vector1, Vector2, Vector4};
use prognos_core::filter::adaptive_ukf::{Adaptation, AdaptiveConfig, AdaptiveUkf};
use prognos_core::filter::imm::Imm;
use prognos_core::filter::particle::{ParticleFilter, PfConfig};
use prognos_core::filter::resample::Resampling;
use prognos_core::filter::ukf::{SigmaParams, Ukf};
use prognos_core::learn::ar::{Oriv, OrivConfig};
use prognos_core::learn::gp::{GaussianProcess, GpTransition, GpUkf};
use prognos_core::learn::gp_rate::{RateScaledGpUkf, RateScaledTransition};
use prognos_core::pipeline::edge::{EdgeConfig, EdgeMonitor};
use prognos_core::pipeline::reaction_wheel::{ReactionWheel, ReactionWheelConfig};
use prognos_core::pipeline::scooter::{Scooter, ScooterConfig};
use prognos_core::{Error, Real};
use rand_core::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;

/// Steps per harness run: long enough for resampling, adaptation windows and IMM switching.
pub const MAX_STEPS: usize = 48;

/// A stream of `f64` inputs; reads past the end give 0.
#[derive(Clone, Debug)]
pub struct Feed<'a> {
    values: &'a [f64],
    next: usize,
}

impl<'a> Feed<'a> {
    pub fn new(values: &'a [f64]) -> Self {
        Self { values, next: 0 }
    }

    /// Decodes fuzzer bytes: each 9-byte chunk is a selector byte and 8 payload bytes. Most
    /// selectors give an ordinary value in [-8, 8) (so the filters also run their normal
    /// path), the others the payload's raw bit pattern (NaN, infinities, subnormals, huge).
    pub fn decode(bytes: &[u8]) -> Vec<f64> {
        bytes
            .chunks_exact(9)
            .map(|c| {
                let mut payload = [0u8; 8];
                payload.copy_from_slice(&c[1..]);
                if c[0] < 192 {
                    (i64::from_le_bytes(payload) as f64) / (i64::MAX as f64) * 8.0
                } else {
                    f64::from_bits(u64::from_le_bytes(payload))
                }
            })
            .collect()
    }

    pub fn is_empty(&self) -> bool {
        self.next >= self.values.len()
    }

    fn raw(&mut self) -> f64 {
        let v = self.values.get(self.next).copied().unwrap_or(0.0);
        self.next += 1;
        v
    }

    /// `nominal + spread * v` for an ordinary `v` (|v| <= 8); NaN, infinities, subnormals and
    /// large magnitudes pass through unchanged, so they reach the filter as they are.
    pub fn around(&mut self, nominal: f64, spread: f64) -> f64 {
        let v = self.raw();
        let subnormal = v != 0.0 && v.abs() < f64::MIN_POSITIVE;
        if v.is_finite() && v.abs() <= 8.0 && !subnormal {
            nominal + spread * v
        } else {
            v
        }
    }

    /// A time step: mostly `nominal * (1 + |v|/8)`, sometimes whatever the value is (zero,
    /// negative, subnormal, huge, NaN).
    pub fn dt(&mut self, nominal: f64) -> f64 {
        let v = self.raw();
        if v.is_finite() && (0.0..=8.0).contains(&v) && !(v != 0.0 && v < f64::MIN_POSITIVE) {
            nominal * (1.0 + v / 8.0)
        } else if v.is_finite() && (-8.0..0.0).contains(&v) && v > -1.0 {
            // A small negative value: an exactly zero step.
            0.0
        } else {
            v
        }
    }

    /// A decision (e.g. "this sample is missing"), true for about one value in eight.
    pub fn rare(&mut self) -> bool {
        let v = self.raw();
        !(v.is_finite() && v.abs() <= 7.0)
    }
}

fn state_bits<S: core::fmt::Debug>(s: &S) -> String {
    format!("{s:?}")
}

/// On `Err` the object must be exactly as before the step.
fn check_unchanged<S: core::fmt::Debug>(
    label: &str,
    before: &str,
    after: &S,
    err: &dyn core::fmt::Display,
) -> Result<(), String> {
    if state_bits(after) != before {
        return Err(format!("{label}: Err({err}) but the state changed"));
    }
    Ok(())
}

fn all_finite<T: Real>(v: impl IntoIterator<Item = T>) -> bool {
    v.into_iter().all(|x| x.finite())
}

/// Symmetric to round-off and positive semi-definite (up to `rel_tol` times the largest entry).
pub fn check_symmetric_psd<const N: usize>(
    label: &str,
    p: &SMatrix<f64, N, N>,
    rel_tol: f64,
) -> Result<(), String> {
    let scale = p.amax().max(f64::MIN_POSITIVE);
    let asym = (p - p.transpose()).amax();
    if !(asym <= rel_tol * scale) {
        return Err(format!("{label}: asymmetry {asym:e} of scale {scale:e}"));
    }
    // PSD to round-off: the Cholesky factorisation of P + tol I exists.
    let loaded = (p + p.transpose()) * 0.5 + SMatrix::<f64, N, N>::identity() * (rel_tol * scale);
    if loaded.cholesky().is_none() {
        return Err(format!("{label}: not positive semi-definite: {p}"));
    }
    Ok(())
}

/// SIR particle filter on the linear oscillator, in `T` (f64 and f32).
pub fn particle_filter<T: Real>(feed: &mut Feed<'_>) -> Result<(), String> {
    const N: usize = 64;
    let c = |v: f64| prognos_core::cast::<T>(v);
    let model: LinearGaussian<T, 2, 1> = oscillator().cast();
    let scheme = [
        Resampling::Systematic,
        Resampling::Stratified,
        Resampling::Residual,
        Resampling::Multinomial,
    ][(feed.around(0.0, 1.0).abs() as usize) % 4];
    let config = PfConfig {
        resampling: scheme,
        resample_threshold: c(0.5),
        random_walk_std: Vector2::new(c(0.0), c(0.01)),
        roughening: Vector2::new(c(0.02), c(0.0)),
        ..PfConfig::default()
    };
    let mut pf =
        ParticleFilter::<T, 2, N>::new(Vector2::zeros(), config).map_err(|e| e.to_string())?;
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(11);
    pf.init_gaussian(
        &Vector2::new(c(1.0), c(0.0)),
        &Vector2::new(c(0.5), c(0.5)),
        &mut rng,
    )
    .map_err(|e| e.to_string())?;
    let tolerance = if T::EPSILON.as_f64() > 1e-10 {
        1e-5
    } else {
        1e-6
    };
    for k in 0..MAX_STEPS {
        if feed.is_empty() {
            break;
        }
        let missing = feed.rare();
        let y = [c(feed.around(0.0, 2.0))];
        let u = Vector1::new(c(feed.around(0.0, 1.0)));
        let dt = c(feed.dt(1.0));
        let before = state_bits(&pf);
        let label = format!("PF step {k}");
        match pf.step(&model, &u, (!missing).then_some(&y[..]), dt, &mut rng) {
            Ok(report) => {
                if report.ess.nan() || report.log_evidence.nan() {
                    return Err(format!("{label}: NaN in the report {report:?}"));
                }
                if !pf.particles().iter().all(|p| all_finite(p.iter().copied())) {
                    return Err(format!("{label}: non-finite particle"));
                }
                let total: f64 = (0..N).map(|i| pf.weight(i).as_f64()).sum();
                if !((total - 1.0).abs() < tolerance) {
                    return Err(format!("{label}: weights sum to {total}"));
                }
            }
            Err(e) => check_unchanged(&label, &before, &pf, &e)?,
        }
    }
    Ok(())
}

fn ukf_step_checked<const NX: usize, const NS: usize, const NU: usize, const NY: usize, M>(
    label: &str,
    ukf: &mut Ukf<f64, NX, NS>,
    model: &M,
    u: &SVector<f64, NU>,
    y: &[f64],
    dt: f64,
    r: &SMatrix<f64, NY, NY>,
) -> Result<(), String>
where
    M: prognos_core::model::Model<f64, NX, NU> + prognos_core::model::Observe<f64, NX, NU, NY>,
{
    let before = state_bits(ukf);
    match ukf.predict(model, u, dt) {
        Ok(_) => check_ukf_state(&format!("{label} predict"), ukf)?,
        Err(e) => return check_unchanged(&format!("{label} predict"), &before, ukf, &e),
    }
    let before = state_bits(ukf);
    match ukf.update(model, u, y, r) {
        Ok(report) => {
            if report.nis.nan() {
                return Err(format!("{label} update: NaN NIS"));
            }
            check_ukf_state(&format!("{label} update"), ukf)
        }
        Err(e) => check_unchanged(&format!("{label} update"), &before, ukf, &e),
    }
}

fn check_ukf_state<const NX: usize, const NS: usize>(
    label: &str,
    ukf: &Ukf<f64, NX, NS>,
) -> Result<(), String> {
    if !all_finite(ukf.state().iter().copied()) || !all_finite(ukf.covariance().iter().copied()) {
        return Err(format!("{label}: non-finite state or covariance"));
    }
    check_symmetric_psd(label, ukf.covariance(), 1e-9)
}

/// UKF predict/update on the linear oscillator and on the nonlinear drag-radar target.
pub fn ukf(feed: &mut Feed<'_>) -> Result<(), String> {
    let lin = oscillator();
    let mut a = Ukf::<f64, 2, 5>::new(
        Vector2::new(1.0, 0.0),
        Matrix2::identity() * 0.25,
        lin.q,
        SigmaParams::default(),
    )
    .map_err(|e| e.to_string())?;
    let radar = DragRadar { drag: 0.01 };
    let mut b = Ukf::<f64, 4, 9>::new(
        Vector4::new(100.0, 50.0, -1.0, 1.0),
        SMatrix::<f64, 4, 4>::from_diagonal(&Vector4::new(4.0, 4.0, 0.25, 0.25)),
        SMatrix::<f64, 4, 4>::identity() * 1e-3,
        SigmaParams::default(),
    )
    .map_err(|e| e.to_string())?;
    let r_radar = Matrix2::new(0.25, 0.0, 0.0, 1e-4);
    for k in 0..MAX_STEPS {
        if feed.is_empty() {
            break;
        }
        let u = Vector1::new(feed.around(0.0, 1.0));
        let y = [feed.around(0.0, 2.0)];
        let dt = feed.dt(1.0);
        ukf_step_checked(&format!("UKF step {k}"), &mut a, &lin, &u, &y, dt, &lin.r)?;
        let u2 = Vector2::new(feed.around(0.0, 0.1), feed.around(0.0, 0.1));
        let y2 = [feed.around(110.0, 2.0), feed.around(0.46, 0.02)];
        let dt2 = feed.dt(0.1);
        ukf_step_checked(
            &format!("radar UKF step {k}"),
            &mut b,
            &radar,
            &u2,
            &y2,
            dt2,
            &r_radar,
        )?;
    }
    Ok(())
}

/// AUKF (covariance matching) or AEUKF (matching and enhancement) steps on the oscillator.
pub fn adaptive_ukf(feed: &mut Feed<'_>, mode: Adaptation) -> Result<(), String> {
    let lin = oscillator();
    let ukf = Ukf::<f64, 2, 5>::new(
        Vector2::new(1.0, 0.0),
        Matrix2::identity() * 0.25,
        lin.q,
        SigmaParams::default(),
    )
    .map_err(|e| e.to_string())?;
    let config = AdaptiveConfig::new(
        mode,
        5.0,
        Vector2::repeat(1e-8),
        Vector2::repeat(1.0),
        Vector1::new(1e-6),
    );
    let mut f =
        AdaptiveUkf::<f64, 2, 5, 1, 6>::new(ukf, lin.r, config).map_err(|e| e.to_string())?;
    for k in 0..MAX_STEPS {
        if feed.is_empty() {
            break;
        }
        let enhance = feed.rare();
        let u = Vector1::new(feed.around(0.0, 1.0));
        let y = [feed.around(0.0, 2.0)];
        let dt = feed.dt(1.0);
        let before = state_bits(&f);
        let label = format!("{mode:?} step {k}");
        match f.step(&lin, &u, &y, dt, enhance) {
            Ok(_) => {
                check_ukf_state(&label, f.ukf())?;
                let r = f.measurement_noise();
                if !all_finite(r.iter().copied()) || !(r[(0, 0)] > 0.0) {
                    return Err(format!("{label}: matched R = {r}"));
                }
                check_symmetric_psd(&format!("{label} Q"), f.ukf().process_noise(), 1e-9)?;
            }
            Err(e) => check_unchanged(&label, &before, &f, &e)?,
        }
    }
    Ok(())
}

/// A one-dimensional GP: `x_{k+1} - x_k` learned from three points of a slow drift in the
/// inputs `(x, u)`.
fn drift_gp() -> Result<GaussianProcess<f64, 2, 3>, String> {
    let (alpha, chol) = drift_gp_training();
    GaussianProcess::from_f64(
        &[1.0, 1.0],
        1e-2,
        1e-4,
        &[[0.0, 0.0], [0.5, 0.5], [1.0, 1.0]],
        &alpha,
        &chol,
        0.01,
    )
    .map_err(|e| e.to_string())
}

/// Solves `(K + sn^2 I) alpha = y - mean` for the three training points of [`drift_gp`].
fn drift_gp_training() -> ([f64; 3], [[f64; 3]; 3]) {
    let xs: [[f64; 2]; 3] = [[0.0, 0.0], [0.5, 0.5], [1.0, 1.0]];
    let ys = [0.01, 0.02, 0.04];
    let (sf2, sn2, mean): (f64, f64, f64) = (1e-2, 1e-4, 0.01);
    let k = SMatrix::<f64, 3, 3>::from_fn(|i, j| {
        let d: f64 = (0..2).map(|m| (xs[i][m] - xs[j][m]).powi(2)).sum();
        sf2 * (-0.5 * d).exp() + if i == j { sn2 } else { 0.0 }
    });
    let chol = k
        .cholesky()
        .map(|c| c.l())
        .unwrap_or_else(SMatrix::identity);
    let rhs = SVector::<f64, 3>::from_fn(|i, _| ys[i] - mean);
    let alpha = k
        .cholesky()
        .map(|c| c.solve(&rhs))
        .unwrap_or_else(SVector::zeros);
    (
        [alpha[0], alpha[1], alpha[2]],
        core::array::from_fn(|i| core::array::from_fn(|j| chol[(i, j)])),
    )
}

/// GP-UKF alone and an IMM over two GP-UKFs (slow and fast mode), as in the bearing pipeline.
pub fn gp_ukf_imm(feed: &mut Feed<'_>) -> Result<(), String> {
    let gp = drift_gp()?;
    let slow = GpTransition {
        gps: [&gp],
        measurement_std: Vector1::new(0.05),
    };
    let make = |x0: f64| {
        GpUkf::<f64, 1, 1, 2, 3, 3>::new(
            slow,
            Vector1::new(x0),
            Matrix1::new(0.01),
            Matrix1::new(0.0025),
            SigmaParams::default(),
        )
        .map_err(|e| e.to_string())
    };
    let mut single = make(0.2)?;
    let mut imm = Imm::<f64, _, 1, 2>::new(
        [make(0.2)?, make(0.3)?],
        Vector2::new(0.5, 0.5),
        Imm::<f64, GpUkf<f64, 1, 1, 2, 3, 3>, 1, 2>::uniform_switching(0.95),
    )
    .map_err(|e| e.to_string())?;
    for k in 0..MAX_STEPS {
        if feed.is_empty() {
            break;
        }
        let u = Vector1::new(feed.around(0.1, 0.05));
        let short = feed.rare();
        let z = [feed.around(0.2 + 0.01 * k as f64, 0.05)];
        let z: &[f64] = if short { &[] } else { &z };
        let label = format!("GP-UKF step {k}");
        let before = state_bits(&single);
        match single.step(&u, z) {
            Ok(r) => {
                if r.nis.nan() || r.log_likelihood.nan() {
                    return Err(format!("{label}: NaN in {r:?}"));
                }
                if !all_finite(single.state().iter().copied())
                    || !(single.covariance()[(0, 0)] >= 0.0)
                {
                    return Err(format!("{label}: state {:?}", single.state()));
                }
            }
            Err(e) => check_unchanged(&label, &before, &single, &e)?,
        }
        let label = format!("IMM step {k}");
        let before = state_bits(&imm);
        // Plain, gated (the gate itself from the feed) and predict-only cycles.
        let result = match k % 3 {
            0 => imm.step(&u, z),
            1 => imm.step_gated(&u, z, feed.around(10.83, 10.0)),
            _ => imm.predict(&u),
        };
        match result {
            Ok(r) => {
                let total: f64 = r.probabilities.sum();
                if !((total - 1.0).abs() < 1e-9) || r.probabilities.iter().any(|&p| !(p >= 0.0)) {
                    return Err(format!("{label}: mode probabilities {:?}", r.probabilities));
                }
                if !all_finite(imm.state().iter().copied()) {
                    return Err(format!("{label}: state {:?}", imm.state()));
                }
                check_symmetric_psd(&label, imm.covariance(), 1e-9)?;
            }
            Err(e) => check_unchanged(&label, &before, &imm, &e)?,
        }
    }
    Ok(())
}

/// The GP-UKF with the online log-rate state `[r, theta]` (the bearing's unseen-trial filter).
pub fn gp_rate_ukf(feed: &mut Feed<'_>) -> Result<(), String> {
    let gp = drift_gp()?;
    let mut filter = RateScaledGpUkf::<f64, 2, 1, 2, 3, 5>::new(
        RateScaledTransition {
            gp: &gp,
            measurement_std: 0.05,
            pivot: 0.5,
        },
        Vector2::new(0.2, 0.0),
        Matrix2::new(0.01, 0.0, 0.0, 0.1),
        0.0025,
        1e-5,
        SigmaParams::default(),
    )
    .map_err(|e| e.to_string())?;
    for k in 0..MAX_STEPS {
        if feed.is_empty() {
            break;
        }
        let u = Vector1::new(feed.around(0.1, 0.05));
        let short = feed.rare();
        let z = [feed.around(0.2 + 0.01 * k as f64, 0.05)];
        let z: &[f64] = if short { &[] } else { &z };
        let label = format!("rate-scaled GP-UKF step {k}");
        let before = state_bits(&filter);
        match filter.step(&u, z) {
            Ok(r) => {
                if r.log_likelihood.nan() || r.innovation_variance.nan() {
                    return Err(format!("{label}: NaN in {r:?}"));
                }
                if !all_finite(filter.state().iter().copied()) {
                    return Err(format!("{label}: state {:?}", filter.state()));
                }
                check_symmetric_psd(&label, filter.covariance(), 1e-9)?;
            }
            Err(e) => check_unchanged(&label, &before, &filter, &e)?,
        }
    }
    Ok(())
}

/// ORIV AR(2) with two extra instruments on an AR(2) signal with arbitrary samples mixed in.
pub fn oriv(feed: &mut Feed<'_>) -> Result<(), String> {
    let mut est = Oriv::<f64, 2, 2>::new(&OrivConfig::default()).map_err(|e| e.to_string())?;
    let (mut y1, mut y2) = (0.0, 0.0);
    for k in 0..4 * MAX_STEPS {
        if feed.is_empty() {
            break;
        }
        let y = feed.around(1.2 * y1 - 0.5 * y2, 0.1);
        let label = format!("ORIV step {k}");
        let before = state_bits(&est);
        match est.update(y) {
            Ok(r) => {
                if !all_finite(est.theta().iter().copied())
                    || !all_finite([r.innovation, r.innovation_variance, r.test_ratio])
                {
                    return Err(format!("{label}: theta {:?}, report {r:?}", est.theta()));
                }
                (y2, y1) = (y1, y.clamp(-1e3, 1e3));
            }
            Err(e) => check_unchanged(&label, &before, &est, &e)?,
        }
    }
    Ok(())
}

/// `pipeline::ReactionWheel` at 20 Hz with missing samples and interval readings.
pub fn reaction_wheel(feed: &mut Feed<'_>) -> Result<(), String> {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(5);
    let config = ReactionWheelConfig::new(0.03, 0.003).map_err(|e| e.to_string())?;
    let mut p = ReactionWheel::<f64, 32, 16>::new(config, &mut rng).map_err(|e| e.to_string())?;
    let (mut t, mut reading) = (0.0, 0.0);
    for k in 0..MAX_STEPS {
        if feed.is_empty() {
            break;
        }
        let next_t = t + feed.dt(0.05);
        let command = feed.around(1.0, 0.3);
        let missing = feed.rare();
        let closes = feed.rare();
        let current = feed.around(0.19, 0.01);
        let speed = feed.around(91.4, 0.5);
        let next_reading = reading + feed.around(0.0, 1e-4).abs();
        let y3 = [current, speed, next_reading];
        let y = if missing {
            None
        } else if closes {
            Some(&y3[..])
        } else {
            Some(&y3[..2])
        };
        let label = format!("reaction wheel step {k}");
        let before = state_bits(&p);
        match p.step(next_t, command, y, &mut rng) {
            Ok(r) => {
                if !all_finite([r.temperature, r.temperature_std, r.b, r.beta]) {
                    return Err(format!("{label}: {r:?}"));
                }
                t = next_t;
                if closes && !missing {
                    reading = next_reading;
                }
            }
            Err(e) => check_unchanged(&label, &before, &p, &e)?,
        }
    }
    Ok(())
}

/// `pipeline::Scooter` (AEUKF, ARRs, sequential prognosis) at its 100 Hz rate.
pub fn scooter(feed: &mut Feed<'_>) -> Result<(), String> {
    let mut p = Scooter::<f64>::new(0.0, ScooterConfig::new(Adaptation::Enhanced))
        .map_err(|e| e.to_string())?;
    let mut t = 0.0;
    for k in 0..MAX_STEPS {
        if feed.is_empty() {
            break;
        }
        let next_t = t + feed.dt(0.01);
        let u = feed.around(0.5, 0.1);
        let y = [
            feed.around(10.0, 0.5),
            feed.around(1.0, 0.05),
            feed.around(10.0, 0.5),
        ];
        let short = feed.rare();
        let y: &[f64] = if short { &y[..2] } else { &y };
        let label = format!("scooter step {k}");
        let before = state_bits(&p);
        let estimator_before = (state_bits(p.filter()), state_bits(p.prognoser()));
        match p.step(next_t, u, y) {
            Ok(r) => {
                if !all_finite(r.state.iter().copied()) || r.beta_variance.nan() {
                    return Err(format!("{label}: {:?}", r.state));
                }
                check_symmetric_psd(&label, p.filter().ukf().covariance(), 1e-9)?;
                t = next_t;
            }
            // Documented exception: a rejected jump is remembered (so that a real level
            // change is accepted on the next agreeing sample); the estimator is untouched.
            Err(e @ Error::OutOfRange("measurement jump (encoder glitch)")) => {
                if (state_bits(p.filter()), state_bits(p.prognoser())) != estimator_before {
                    return Err(format!("{label}: Err({e}) but the estimator changed"));
                }
            }
            Err(e) => check_unchanged(&label, &before, &p, &e)?,
        }
    }
    Ok(())
}

/// `pipeline::edge::EdgeMonitor` (ORIV on a circular snapshot buffer) with AR(2) snapshots.
pub fn edge(feed: &mut Feed<'_>) -> Result<(), String> {
    let config = EdgeConfig {
        reference_models: 2,
        ..EdgeConfig::default()
    };
    let mut m = EdgeMonitor::<f64, 2, 2, 3, 32>::new(config).map_err(|e| e.to_string())?;
    let mut noise = Xoshiro256PlusPlus::seed_from_u64(3);
    for k in 0..MAX_STEPS / 4 {
        if feed.is_empty() {
            break;
        }
        let mut snapshot = [0.0; 32];
        let (mut y1, mut y2) = (0.0, 0.0);
        for s in snapshot.iter_mut() {
            let e: f64 = prognos_core::random::standard_normal(&mut noise);
            let clean = 1.2 * y1 - 0.5 * y2 + e;
            // Every fourth sample comes from the feed (arbitrary values in a real signal).
            *s = if feed.rare() {
                feed.around(clean, 1.0)
            } else {
                clean
            };
            (y2, y1) = (y1, clean);
        }
        let label = format!("edge snapshot {k}");
        let before = state_bits(&m);
        match m.push_snapshot(&snapshot) {
            Ok(Some(r)) => {
                if !all_finite(r.model.theta.iter().copied())
                    || r.hi_nrmse.is_some_and(|h| !h.finite())
                {
                    return Err(format!("{label}: {r:?}"));
                }
            }
            Ok(None) => {}
            Err(e) => check_unchanged(&label, &before, &m, &e)?,
        }
    }
    Ok(())
}
