//! EOL prediction by propagating each particle (or sigma point) to its own end of life under
//! hypothesised future inputs (Daigle & Goebel 2011, Algorithm 3), and the weighted RUL
//! distribution that results.

use crate::error::{Error, check_dt};
use crate::model::Stochastic;
use crate::random::standard_normal;
use crate::real::{Real, all_finite, cast};
use crate::stats::{Summary, summarise};
use nalgebra::SVector;
use rand_core::Rng;

/// The end-of-life threshold function `T_EOL(x)`: true once a functional requirement is
/// violated.
pub trait EndOfLife<T: Real, const NX: usize> {
    /// Whether state `x` (including its parameters) is at or past end of life.
    fn reached(&self, x: &SVector<T, NX>) -> bool;
}

/// How the prediction is run.
#[derive(Clone, Copy, Debug)]
pub struct PredictionSettings<T: Real, const NX: usize> {
    /// Prediction step (the model's time unit: seconds, cycles, ...).
    pub dt: T,
    /// Horizon in steps; samples that do not reach EOL get [`Real::MAX_FINITE`].
    pub max_steps: u32,
    /// Sample process noise during prediction (`Stochastic::sample_step`) or not (`step`).
    pub process_noise: bool,
    /// Per-step random walk of the state entries during prediction (the paper's
    /// `theta_{k+1} ~ p(theta | theta_k)`); zero keeps parameters fixed.
    pub random_walk_std: SVector<T, NX>,
}

impl<T: Real, const NX: usize> PredictionSettings<T, NX> {
    /// Deterministic prediction with step `dt` and a horizon of `max_steps`.
    pub fn deterministic(dt: T, max_steps: u32) -> Self {
        Self {
            dt,
            max_steps,
            process_noise: false,
            random_walk_std: SVector::zeros(),
        }
    }
}

/// Propagates every state in `states` until `eol` is reached, writing the time to EOL
/// (`steps * dt`) of sample `i` into `out[i]`. Inputs come from `future_input(k)` for
/// prediction step `k`. Returns how many samples reached EOL within the horizon
/// (`Err(HorizonExceeded)` when none did; `out` is filled either way).
pub fn predict_eol<T, M, E, R, F, const NX: usize, const NU: usize>(
    model: &M,
    eol: &E,
    states: &[SVector<T, NX>],
    mut future_input: F,
    settings: &PredictionSettings<T, NX>,
    rng: &mut R,
    out: &mut [T],
) -> Result<usize, Error>
where
    T: Real,
    M: Stochastic<T, NX, NU>,
    E: EndOfLife<T, NX>,
    R: Rng + ?Sized,
    F: FnMut(u32) -> SVector<T, NU>,
{
    check_dt(settings.dt)?;
    if out.len() < states.len() {
        return Err(Error::InvalidParameter(
            "output buffer shorter than the state set",
        ));
    }
    let mut reached = 0usize;
    for (x0, time) in states.iter().zip(out.iter_mut()) {
        let mut x = *x0;
        let mut k = 0u32;
        let mut done = eol.reached(&x);
        while !done && k < settings.max_steps {
            let u = future_input(k);
            if !all_finite(u.as_slice()) {
                return Err(Error::NonFiniteInput);
            }
            x = if settings.process_noise {
                model.sample_step(&x, &u, settings.dt, rng)
            } else {
                model.step(&x, &u, settings.dt)
            };
            for (v, s) in x.iter_mut().zip(settings.random_walk_std.iter()) {
                if *s > T::zero() {
                    *v += *s * standard_normal::<T, R>(rng);
                }
            }
            k = k.saturating_add(1);
            // A diverged trajectory is treated as having failed (conservative).
            done = !all_finite(x.as_slice()) || eol.reached(&x);
        }
        *time = if done {
            reached = reached.saturating_add(1);
            cast::<T>(f64::from(k)) * settings.dt
        } else {
            T::MAX_FINITE
        };
    }
    if reached == 0 && !states.is_empty() {
        return Err(Error::HorizonExceeded);
    }
    Ok(reached)
}

/// Weighted RUL summary from per-sample times to EOL and their weights, in the caller's
/// buffer. Samples beyond the horizon are kept at `MAX_FINITE`, so upper percentiles show
/// them honestly while the median stays meaningful if most samples reached EOL.
pub fn rul_distribution<T: Real>(
    times: &[T],
    weights: &[T],
    buf: &mut [(T, T)],
) -> Option<Summary<T>> {
    let n = times.len().min(weights.len()).min(buf.len());
    for ((slot, &t), &w) in buf.iter_mut().zip(times).zip(weights).take(n) {
        *slot = (t, w);
    }
    summarise(buf.get_mut(..n)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Model;
    use nalgebra::{Vector1, Vector2};
    use rand_core::SeedableRng;
    use rand_xoshiro::Xoshiro256PlusPlus;

    /// Linear damage d' = w: EOL when d >= 1, so time to EOL is (1 - d0) / w exactly.
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
    struct Threshold;
    impl EndOfLife<f64, 2> for Threshold {
        fn reached(&self, x: &Vector2<f64>) -> bool {
            x[0] >= 1.0
        }
    }

    #[test]
    fn eol_of_linear_damage_is_exact_to_one_step() {
        let states = [
            Vector2::new(0.0, 0.01),
            Vector2::new(0.5, 0.02),
            Vector2::new(0.2, 0.0),
        ];
        let mut out = [0.0; 3];
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(1);
        let settings = PredictionSettings::deterministic(0.5, 1000);
        let reached = predict_eol(
            &LinearDamage,
            &Threshold,
            &states,
            |_| Vector1::new(0.0),
            &settings,
            &mut rng,
            &mut out,
        )
        .unwrap();
        assert_eq!(reached, 2);
        assert!((out[0] - 100.0).abs() <= 0.5 + 1e-9, "{}", out[0]);
        assert!((out[1] - 25.0).abs() <= 0.5 + 1e-9, "{}", out[1]);
        assert_eq!(out[2], f64::MAX);
        let mut buf = [(0.0, 0.0); 3];
        let s = rul_distribution(&out, &[0.45, 0.45, 0.1], &mut buf).unwrap();
        assert!(s.p05 <= s.median && s.median <= s.p95);
        assert!((s.median - 25.0).abs() < 1.0 || (s.median - 100.0).abs() < 1.0);
    }

    #[test]
    fn bad_settings_are_errors() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(1);
        let mut out = [0.0; 1];
        let states = [Vector2::new(0.0, 0.01)];
        let r = predict_eol(
            &LinearDamage,
            &Threshold,
            &states,
            |_| Vector1::new(0.0),
            &PredictionSettings::deterministic(0.0, 10),
            &mut rng,
            &mut out,
        );
        assert_eq!(r, Err(Error::InvalidTimeStep));
        let r = predict_eol(
            &LinearDamage,
            &Threshold,
            &states,
            |_| Vector1::new(f64::NAN),
            &PredictionSettings::deterministic(1.0, 10),
            &mut rng,
            &mut out,
        );
        assert_eq!(r, Err(Error::NonFiniteInput));
    }
}
