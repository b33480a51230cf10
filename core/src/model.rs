//! Model traits a plant or degradation model implements, and a fixed-step RK4 integrator.
//!
//! A model's state vector holds its dynamic states and, for joint state-parameter
//! estimation, its unknown parameters (which the model leaves constant in `step`; the filter's
//! random walk moves them).

use crate::real::{Real, cast};
use nalgebra::SVector;
use rand_core::Rng;

/// Deterministic discrete-time transition `x_{k+1} = f(x_k, u_k, dt)`.
pub trait Model<T: Real, const NX: usize, const NU: usize> {
    /// Advances the state by `dt` under input `u` (held constant over the step).
    fn step(&self, x: &SVector<T, NX>, u: &SVector<T, NU>, dt: T) -> SVector<T, NX>;
}

/// Deterministic measurement function `y = h(x, u)`, for Kalman-type filters.
pub trait Observe<T: Real, const NX: usize, const NU: usize, const NY: usize> {
    /// The noise-free measurement of state `x` under input `u`.
    fn observe(&self, x: &SVector<T, NX>, u: &SVector<T, NU>) -> SVector<T, NY>;
}

/// Stochastic extension for sampling-based filters: sample process noise, score a measurement.
///
/// Measurements are slices so that a model can be configured with any subset of its sensors
/// (e.g. the valve's `{open, closed}` set) and so that discrete or non-Gaussian sensors fit.
pub trait Stochastic<T: Real, const NX: usize, const NU: usize>: Model<T, NX, NU> {
    /// Number of measurement channels [`Stochastic::log_likelihood`] expects.
    fn measurement_len(&self) -> usize;

    /// Propagates one step with process noise drawn from `rng` (default: no process noise).
    fn sample_step<R: Rng + ?Sized>(
        &self,
        x: &SVector<T, NX>,
        u: &SVector<T, NU>,
        dt: T,
        rng: &mut R,
    ) -> SVector<T, NX> {
        let _ = rng;
        self.step(x, u, dt)
    }

    /// `ln p(y | x, u)` up to a constant common to all states. The filter has already checked
    /// that `y` has [`Stochastic::measurement_len`] finite entries. May return `-inf` for an
    /// impossible state, never NaN for a finite state.
    fn log_likelihood(&self, x: &SVector<T, NX>, u: &SVector<T, NU>, y: &[T]) -> T;

    /// The noise-free measurement of `x` into `predicted` and each channel's measurement-noise
    /// variance into `noise_variance` (both [`Stochastic::measurement_len`] long), from which
    /// a particle filter reports its innovation. `false` (the default) when the sensor has no
    /// such form (e.g. a discrete sensor); the report then carries no innovation.
    fn predicted_measurement(
        &self,
        x: &SVector<T, NX>,
        u: &SVector<T, NU>,
        predicted: &mut [T],
        noise_variance: &mut [T],
    ) -> bool {
        let _ = (x, u, predicted, noise_variance);
        false
    }
}

/// Log-density (without the constant) of independent Gaussian sensors: `-1/2 sum ((y-m)/s)^2`.
/// Pairs `y`, `predicted` and `std` element-wise; extra entries of the longer slices are ignored.
#[inline]
pub fn gaussian_log_likelihood<T: Real>(y: &[T], predicted: &[T], std: &[T]) -> T {
    let half: T = cast(0.5);
    let mut acc = T::zero();
    for ((&yi, &mi), &si) in y.iter().zip(predicted).zip(std) {
        let z = (yi - mi) / si;
        acc -= half * z * z;
    }
    acc
}

/// Fixed-step classical Runge-Kutta integration of `dx/dt = f(x)` over `dt` in `substeps`
/// equal sub-steps (at least one). Inputs are held by the closure.
#[inline]
pub fn rk4<T: Real, const N: usize, F>(
    f: F,
    x: &SVector<T, N>,
    dt: T,
    substeps: u32,
) -> SVector<T, N>
where
    F: Fn(&SVector<T, N>) -> SVector<T, N>,
{
    let steps = substeps.max(1);
    let h = dt / cast::<T>(f64::from(steps));
    let half_h = h * cast(0.5);
    let sixth_h = h / cast(6.0);
    let two: T = cast(2.0);
    let mut state = *x;
    for _ in 0..steps {
        let k1 = f(&state);
        let k2 = f(&(state + k1 * half_h));
        let k3 = f(&(state + k2 * half_h));
        let k4 = f(&(state + k3 * h));
        state += (k1 + k2 * two + k3 * two + k4) * sixth_h;
    }
    state
}

/// Explicit Euler integration in `substeps` sub-steps, for models whose reference
/// implementation uses it (e.g. progpy's valve) or whose right-hand side is discontinuous.
#[inline]
pub fn euler<T: Real, const N: usize, F>(
    f: F,
    x: &SVector<T, N>,
    dt: T,
    substeps: u32,
) -> SVector<T, N>
where
    F: Fn(&SVector<T, N>) -> SVector<T, N>,
{
    let steps = substeps.max(1);
    let h = dt / cast::<T>(f64::from(steps));
    let mut state = *x;
    for _ in 0..steps {
        state += f(&state) * h;
    }
    state
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector2;

    #[test]
    fn rk4_harmonic_oscillator_is_fourth_order() {
        // x'' = -x: exact solution cos(t), -sin(t).
        let f = |s: &Vector2<f64>| Vector2::new(s[1], -s[0]);
        let x0 = Vector2::new(1.0, 0.0);
        let err = |n| {
            let x = rk4(f, &x0, 1.0, n);
            ((x[0] - 1f64.cos()).powi(2) + (x[1] + 1f64.sin()).powi(2)).sqrt()
        };
        let (e10, e20) = (err(10), err(20));
        assert!(e10 < 1e-6, "{e10}");
        let order = (e10 / e20).log2();
        assert!((order - 4.0).abs() < 0.2, "order {order}");
    }

    #[test]
    fn euler_is_first_order() {
        let f = |s: &Vector2<f64>| Vector2::new(-s[0], 0.0);
        let x0 = Vector2::new(1.0, 0.0);
        let e1 = (euler(f, &x0, 1.0, 100)[0] - (-1f64).exp()).abs();
        let e2 = (euler(f, &x0, 1.0, 200)[0] - (-1f64).exp()).abs();
        assert!(((e1 / e2).log2() - 1.0).abs() < 0.05);
    }

    #[test]
    fn gaussian_log_likelihood_matches_formula() {
        let ll: f64 = gaussian_log_likelihood(&[1.0, 2.0], &[0.0, 0.0], &[1.0, 2.0]);
        assert!((ll - (-0.5 * (1.0 + 1.0))).abs() < 1e-15);
    }
}
