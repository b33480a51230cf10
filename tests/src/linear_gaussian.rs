//! Linear-Gaussian test models and an exact Kalman filter to check the core filters against.
//!
//! `x_{k+1} = F x_k + B u_k + w_k`, `w ~ N(0, Q)`; `y_k = H x_k + v_k`, `v ~ N(0, R)`. The
//! matrices describe one sampling period, so the model ignores `dt`. For this model the Kalman
//! filter is the exact posterior, which a particle filter must approach as N grows and a UKF
//! must reproduce to round-off.

use nalgebra::{Cholesky, SMatrix, SVector};
use prognos_core::Real;
use prognos_core::model::{Model, Observe, Stochastic};
use prognos_core::random::standard_normal;
use rand_core::Rng;

/// A linear-Gaussian state-space model with one scalar input.
#[derive(Clone, Debug)]
pub struct LinearGaussian<T: Real, const NX: usize, const NY: usize> {
    pub f: SMatrix<T, NX, NX>,
    pub b: SVector<T, NX>,
    pub h: SMatrix<T, NY, NX>,
    pub q: SMatrix<T, NX, NX>,
    pub r: SMatrix<T, NY, NY>,
    q_factor: SMatrix<T, NX, NX>,
    r_factor: SMatrix<T, NY, NY>,
    r_inv: SMatrix<T, NY, NY>,
}

impl<T: Real, const NX: usize, const NY: usize> LinearGaussian<T, NX, NY> {
    /// Builds the model; `q` and `r` must be positive definite.
    pub fn new(
        f: SMatrix<T, NX, NX>,
        b: SVector<T, NX>,
        h: SMatrix<T, NY, NX>,
        q: SMatrix<T, NX, NX>,
        r: SMatrix<T, NY, NY>,
    ) -> Self {
        let q_factor = Cholesky::new(q).expect("Q positive definite").l();
        let r_chol = Cholesky::new(r).expect("R positive definite");
        Self {
            f,
            b,
            h,
            q,
            r,
            q_factor,
            r_factor: r_chol.l(),
            r_inv: r_chol.inverse(),
        }
    }

    /// The same model in another scalar type.
    pub fn cast<U: Real>(&self) -> LinearGaussian<U, NX, NY> {
        let c = |v: T| prognos_core::cast::<U>(v.as_f64());
        LinearGaussian::new(
            self.f.map(c),
            self.b.map(c),
            self.h.map(c),
            self.q.map(c),
            self.r.map(c),
        )
    }

    /// Draws a measurement of state `x`.
    pub fn sample_measurement<R: Rng + ?Sized>(
        &self,
        x: &SVector<T, NX>,
        rng: &mut R,
    ) -> SVector<T, NY> {
        let z = SVector::<T, NY>::from_fn(|_, _| standard_normal::<T, R>(rng));
        self.h * x + self.r_factor * z
    }
}

impl<T: Real, const NX: usize, const NY: usize> Model<T, NX, 1> for LinearGaussian<T, NX, NY> {
    fn step(&self, x: &SVector<T, NX>, u: &SVector<T, 1>, _dt: T) -> SVector<T, NX> {
        self.f * x + self.b * u[0]
    }
}

impl<T: Real, const NX: usize, const NY: usize> Observe<T, NX, 1, NY>
    for LinearGaussian<T, NX, NY>
{
    fn observe(&self, x: &SVector<T, NX>, _u: &SVector<T, 1>) -> SVector<T, NY> {
        self.h * x
    }
}

impl<T: Real, const NX: usize, const NY: usize> Stochastic<T, NX, 1> for LinearGaussian<T, NX, NY> {
    fn measurement_len(&self) -> usize {
        NY
    }

    fn sample_step<R: Rng + ?Sized>(
        &self,
        x: &SVector<T, NX>,
        u: &SVector<T, 1>,
        dt: T,
        rng: &mut R,
    ) -> SVector<T, NX> {
        let z = SVector::<T, NX>::from_fn(|_, _| standard_normal::<T, R>(rng));
        self.step(x, u, dt) + self.q_factor * z
    }

    fn log_likelihood(&self, x: &SVector<T, NX>, _u: &SVector<T, 1>, y: &[T]) -> T {
        let y = SVector::<T, NY>::from_iterator(y.iter().copied());
        let e = y - self.h * x;
        -(e.transpose() * self.r_inv * e)[0] * prognos_core::cast(0.5)
    }

    fn predicted_measurement(
        &self,
        x: &SVector<T, NX>,
        _u: &SVector<T, 1>,
        predicted: &mut [T],
        noise_variance: &mut [T],
    ) -> bool {
        for (slot, v) in predicted.iter_mut().zip((self.h * x).iter()) {
            *slot = *v;
        }
        for (slot, v) in noise_variance.iter_mut().zip(self.r.diagonal().iter()) {
            *slot = *v;
        }
        true
    }
}

/// The exact Kalman filter for [`LinearGaussian`], in f64 (Joseph-form covariance update).
#[derive(Clone, Debug)]
pub struct KalmanFilter<const NX: usize, const NY: usize> {
    pub x: SVector<f64, NX>,
    pub p: SMatrix<f64, NX, NX>,
}

impl<const NX: usize, const NY: usize> KalmanFilter<NX, NY> {
    pub fn new(x0: SVector<f64, NX>, p0: SMatrix<f64, NX, NX>) -> Self {
        Self { x: x0, p: p0 }
    }

    pub fn predict(&mut self, m: &LinearGaussian<f64, NX, NY>, u: f64) {
        self.x = m.f * self.x + m.b * u;
        self.p = m.f * self.p * m.f.transpose() + m.q;
    }

    pub fn update(&mut self, m: &LinearGaussian<f64, NX, NY>, y: &SVector<f64, NY>) {
        let s = m.h * self.p * m.h.transpose() + m.r;
        let s_inv = s.try_inverse().expect("S invertible");
        let k = self.p * m.h.transpose() * s_inv;
        self.x += k * (y - m.h * self.x);
        let i_kh = SMatrix::<f64, NX, NX>::identity() - k * m.h;
        self.p = i_kh * self.p * i_kh.transpose() + k * m.r * k.transpose();
    }
}

/// A damped oscillator observed in position: two states, one measurement, one input.
/// The prior and measurement noise are of similar size, so the likelihood is informative but
/// not so peaked that a 2000-particle SIR filter degenerates.
pub fn oscillator() -> LinearGaussian<f64, 2, 1> {
    let dt = 0.1;
    let (omega, zeta) = (1.0, 0.1);
    let f = SMatrix::<f64, 2, 2>::new(1.0, dt, -omega * omega * dt, 1.0 - 2.0 * zeta * omega * dt);
    LinearGaussian::new(
        f,
        SVector::<f64, 2>::new(0.0, dt),
        SMatrix::<f64, 1, 2>::new(1.0, 0.0),
        SMatrix::<f64, 2, 2>::new(0.01, 0.002, 0.002, 0.02),
        SMatrix::<f64, 1, 1>::new(0.25),
    )
}

/// A three-state, two-measurement model with correlated noises (for the UKF-vs-KF test:
/// full matrices exercise every term of the unscented transform).
pub fn tracker3() -> LinearGaussian<f64, 3, 2> {
    let f = SMatrix::<f64, 3, 3>::new(1.0, 0.1, 0.005, 0.0, 1.0, 0.1, -0.02, 0.0, 0.97);
    let h = SMatrix::<f64, 2, 3>::new(1.0, 0.0, 0.0, 0.3, 1.0, -0.5);
    let q = SMatrix::<f64, 3, 3>::new(0.004, 0.001, 0.0, 0.001, 0.01, 0.002, 0.0, 0.002, 0.03);
    let r = SMatrix::<f64, 2, 2>::new(0.5, 0.1, 0.1, 0.3);
    LinearGaussian::new(f, SVector::<f64, 3>::new(0.0, 0.05, 0.1), h, q, r)
}

/// A deterministic input sequence (so the input path of the models is exercised).
pub fn input(k: usize) -> f64 {
    (0.05 * k as f64).sin()
}
