//! Electric scooter of Yu et al. (2020), section 2: current-driven DC motor, reducer, rear
//! wheel, transmission shafts `K1`/`K2`, body and front wheel, measured by two wheel encoders
//! and a body-speed sensor whose efficiency factors scale the true velocities.
//!
//! Dynamic state `[theta_r, omega_r, s_m, v_m, theta_f, omega_f]` (rad, rad/s, m, m/s, rad,
//! rad/s). The estimation model augments it with the fault parameters
//! `[beta_theta_r, R_rv, K1]` (state size 9), which `step` leaves constant.

use crate::model::{Model, Observe, rk4};
use crate::real::{Real, cast};
use nalgebra::{SVector, Vector3, Vector6};

/// Index of the rear-wheel angle in the state.
pub const THETA_R: usize = 0;
/// Index of the rear-wheel angular velocity.
pub const OMEGA_R: usize = 1;
/// Index of the body displacement.
pub const S_M: usize = 2;
/// Index of the body speed.
pub const V_M: usize = 3;
/// Index of the front-wheel angle.
pub const THETA_F: usize = 4;
/// Index of the front-wheel angular velocity.
pub const OMEGA_F: usize = 5;
/// Index of the rear-encoder efficiency factor `beta_theta_r` (augmented state).
pub const BETA_THETA_R: usize = 6;
/// Index of the rear-wheel viscous friction `R_rv` (augmented state).
pub const R_RV: usize = 7;
/// Index of the rear shaft stiffness `K1` (augmented state).
pub const K1: usize = 8;
/// Augmented state size.
pub const NX: usize = 9;
/// Sigma points of a UKF over the augmented state.
pub const NS: usize = 2 * NX + 1;
/// Measurements: rear-wheel speed, body speed, front-wheel speed.
pub const NY: usize = 3;

/// Angle (rad) beyond which [`rebase_angles`] moves the angle reference: about five wheel
/// turns, so that in f32 the angles keep a resolution of a few microradians.
pub const REBASE_ANGLE: f64 = 32.0;

/// Only the shaft twists `theta_r - s_m / N4` and `s_m / N4 - theta_f` enter the dynamics, so
/// the angles may be measured from any common reference. When `|theta_f|` exceeds
/// [`REBASE_ANGLE`], this moves the reference to the front wheel's angle: `theta_f` becomes
/// 0, `theta_r` and `s_m / N4` drop by the same amount (the twists change only by the
/// rounding of `N4 * theta_f`). Without it the absolute angles grow without bound and lose
/// their resolution (in f32 after a few hours of riding). Returns whether it shifted.
pub fn rebase_angles<T: Real>(theta_r: &mut T, s_m: &mut T, theta_f: &mut T, n4: T) -> bool {
    let reference = *theta_f;
    if !(reference.abs() > cast::<T>(REBASE_ANGLE)) {
        return false;
    }
    *theta_r -= reference;
    *s_m -= n4 * reference;
    *theta_f = T::zero();
    true
}

/// Physical parameters (Table 3 nominal values by default).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScooterParams<T> {
    /// Voltage-to-current constant N1 (A/V).
    pub n1: T,
    /// Current-to-torque ratio N2 (Nm/A).
    pub n2: T,
    /// Reduction ratio N3 (motor speed = rear-wheel speed / N3).
    pub n3: T,
    /// Wheel radius N4 (m).
    pub n4: T,
    /// Motor viscous friction (Nms/rad).
    pub r_mv: T,
    /// Motor Coulomb friction (Nm).
    pub r_mc: T,
    /// Motor inertia (kg m^2).
    pub j_m: T,
    /// Body mass (kg).
    pub m: T,
    /// Rear-wheel inertia (kg m^2).
    pub j_r: T,
    /// Front-wheel inertia (kg m^2).
    pub j_f: T,
    /// Rear-wheel viscous friction (Nms/rad).
    pub r_rv: T,
    /// Rear-wheel Coulomb friction (Nm).
    pub r_rc: T,
    /// Front-wheel viscous friction (Nms/rad).
    pub r_fv: T,
    /// Front-wheel Coulomb friction (Nm).
    pub r_fc: T,
    /// Rear transmission shaft stiffness (Nm/rad).
    pub k1: T,
    /// Front transmission shaft stiffness (Nm/rad).
    pub k2: T,
    /// Speed scale (rad/s) of the smooth sign `tanh(w / scale)` used for Coulomb friction.
    pub sign_scale: T,
}

impl<T: Real> ScooterParams<T> {
    /// Table 3 nominal values.
    pub fn nominal() -> Self {
        Self {
            n1: cast(3.0),
            n2: cast(0.0666),
            n3: cast(1.0 / 18.0),
            n4: cast(0.115),
            r_mv: cast(1.725e-3),
            r_mc: cast(5.635e-2),
            j_m: cast(5.03e-4),
            m: cast(20.7),
            j_r: cast(4.87e-3),
            j_f: cast(6.97e-3),
            r_rv: cast(3.545e-2),
            r_rc: cast(5.955e-2),
            r_fv: cast(1.02e-3),
            r_fc: cast(1.857e-3),
            k1: cast(10.02),
            k2: cast(10.07),
            sign_scale: cast(0.05),
        }
    }

    /// Rear-wheel side inertia including the motor reflected through the reducer.
    pub fn rear_inertia(&self) -> T {
        self.j_r + self.j_m / (self.n3 * self.n3)
    }
    /// Rear-wheel side viscous friction including the reflected motor friction.
    pub fn rear_viscous(&self, r_rv: T) -> T {
        r_rv + self.r_mv / (self.n3 * self.n3)
    }
    /// Rear-wheel side Coulomb friction including the reflected motor friction.
    pub fn rear_coulomb(&self) -> T {
        self.r_rc + self.r_mc / self.n3
    }
    /// Rear-wheel drive torque for motor-driver input `u` (V).
    pub fn drive_torque(&self, u: T) -> T {
        self.n1 * self.n2 * u / self.n3
    }
    /// Smooth sign used for Coulomb friction (continuous, so RK4 and sigma points behave).
    pub fn sign(&self, w: T) -> T {
        (w / self.sign_scale).fast_tanh()
    }

    /// Time derivative of the dynamic state with rear viscous friction `r_rv` and rear shaft
    /// stiffness `k1` (which may differ from the stored ones: they are fault parameters).
    pub fn derivative(&self, x: &Vector6<T>, u: T, r_rv: T, k1: T) -> Vector6<T> {
        let twist_rear = x[THETA_R] - x[S_M] / self.n4;
        let twist_front = x[S_M] / self.n4 - x[THETA_F];
        let torque_rear = k1 * twist_rear;
        let torque_front = self.k2 * twist_front;
        let (wr, wf) = (x[OMEGA_R], x[OMEGA_F]);
        let rear_acc = (self.drive_torque(u)
            - self.rear_coulomb() * self.sign(wr)
            - self.rear_viscous(r_rv) * wr
            - torque_rear)
            / self.rear_inertia();
        let body_acc = (torque_rear - torque_front) / (self.n4 * self.m);
        let front_acc = (torque_front - self.r_fc * self.sign(wf) - self.r_fv * wf) / self.j_f;
        Vector6::new(wr, rear_acc, x[V_M], body_acc, wf, front_acc)
    }

    /// One step of length `dt` by RK4 in `substeps` sub-steps.
    pub fn advance(
        &self,
        x: &Vector6<T>,
        u: T,
        r_rv: T,
        k1: T,
        dt: T,
        substeps: u32,
    ) -> Vector6<T> {
        rk4(|s| self.derivative(s, u, r_rv, k1), x, dt, substeps)
    }
}

impl<T: Real> Default for ScooterParams<T> {
    fn default() -> Self {
        Self::nominal()
    }
}

/// The scooter's augmented estimation model (state size [`NX`], one input `u` in volts,
/// measurements `[beta_theta_r * omega_r, v_m, omega_f]`).
#[derive(Clone, Copy, Debug)]
pub struct ScooterModel<T> {
    /// Known parameters (nominal); `r_rv` and `k1` here are ignored in favour of the state.
    pub params: ScooterParams<T>,
    /// RK4 sub-steps per filter step (the front-wheel mode is near 6 Hz).
    pub substeps: u32,
    /// Lower bound applied to `R_rv` and `K1` sigma points so that a wide covariance cannot
    /// produce a negative friction or stiffness.
    pub parameter_floor: T,
}

impl<T: Real> ScooterModel<T> {
    /// Nominal model with 2 RK4 sub-steps.
    pub fn nominal() -> Self {
        Self {
            params: ScooterParams::nominal(),
            substeps: 2,
            parameter_floor: cast(1e-3),
        }
    }

    /// Nominal augmented state at rest: zero motion, `beta = 1`, nominal `R_rv` and `K1`.
    pub fn nominal_state(&self) -> SVector<T, NX> {
        let mut x = SVector::<T, NX>::zeros();
        x.fixed_rows_mut::<3>(BETA_THETA_R).copy_from(&Vector3::new(
            T::one(),
            self.params.r_rv,
            self.params.k1,
        ));
        x
    }
}

impl<T: Real> Default for ScooterModel<T> {
    fn default() -> Self {
        Self::nominal()
    }
}

/// Splits an augmented state into its dynamic part.
pub fn dynamic_part<T: Real>(x: &SVector<T, NX>) -> Vector6<T> {
    x.fixed_rows::<6>(0).into_owned()
}

impl<T: Real> Model<T, NX, 1> for ScooterModel<T> {
    fn step(&self, x: &SVector<T, NX>, u: &SVector<T, 1>, dt: T) -> SVector<T, NX> {
        let r_rv = x[R_RV].max(self.parameter_floor);
        let k1 = x[K1].max(self.parameter_floor);
        let next = self
            .params
            .advance(&dynamic_part(x), u[0], r_rv, k1, dt, self.substeps);
        let mut out = *x;
        out.fixed_rows_mut::<6>(0).copy_from(&next);
        out
    }
}

impl<T: Real> Observe<T, NX, 1, NY> for ScooterModel<T> {
    fn observe(&self, x: &SVector<T, NX>, _u: &SVector<T, 1>) -> SVector<T, NY> {
        Vector3::new(x[BETA_THETA_R] * x[OMEGA_R], x[V_M], x[OMEGA_F])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector1;

    /// Steady state of the drivetrain, solved independently: the shafts carry only the front
    /// wheel's friction, so the rear wheel balances drive torque against its own friction.
    fn steady_rear_speed(p: &ScooterParams<f64>, u: f64, r_rv: f64) -> f64 {
        // omega_r = (tau - coulomb - front losses) / viscous, iterate the small front term.
        let mut w = 0.0;
        for _ in 0..50 {
            let front = p.r_fc * (w / p.sign_scale).tanh() + p.r_fv * w;
            w = (p.drive_torque(u) - p.rear_coulomb() - front) / p.rear_viscous(r_rv);
        }
        w
    }

    #[test]
    fn reaches_the_analytic_steady_state_and_rolls_without_slip() {
        let model = ScooterModel::<f64>::nominal();
        let mut x = model.nominal_state();
        let u = Vector1::new(1.0);
        for _ in 0..1500 {
            x = model.step(&x, &u, 0.02);
        }
        let w = steady_rear_speed(&model.params, 1.0, model.params.r_rv);
        assert!((x[OMEGA_R] - w).abs() < 1e-3 * w, "{} vs {w}", x[OMEGA_R]);
        assert!((x[V_M] - w * model.params.n4).abs() < 1e-3 * w * 0.115);
        assert!((x[OMEGA_F] - w).abs() < 1e-3 * w);
        // Roughly 4.26 rad/s at 1 V with Table 3 values.
        assert!((w - 4.26).abs() < 0.05, "{w}");
    }

    #[test]
    fn friction_fault_slows_the_rear_wheel_and_beta_scales_the_encoder() {
        let model = ScooterModel::<f64>::nominal();
        let mut x = model.nominal_state();
        x[R_RV] = 0.469;
        x[BETA_THETA_R] = 0.78;
        let u = Vector1::new(1.0);
        for _ in 0..1500 {
            x = model.step(&x, &u, 0.02);
        }
        let w = steady_rear_speed(&model.params, 1.0, 0.469);
        assert!((x[OMEGA_R] - w).abs() < 1e-3 * w);
        let y = model.observe(&x, &u);
        assert!((y[0] - 0.78 * x[OMEGA_R]).abs() < 1e-12);
        assert!(y[0] < 0.8 * steady_rear_speed(&model.params, 1.0, model.params.r_rv));
    }

    #[test]
    fn rebased_angles_leave_the_dynamics_unchanged() {
        let model = ScooterModel::<f64>::nominal();
        let mut x = model.nominal_state();
        let u = Vector1::new(1.0);
        for _ in 0..1500 {
            x = model.step(&x, &u, 0.02);
        }
        assert!(x[THETA_F] > REBASE_ANGLE, "{}", x[THETA_F]);
        let mut shifted = x;
        let (mut a, mut b, mut c) = (shifted[THETA_R], shifted[S_M], shifted[THETA_F]);
        assert!(rebase_angles(&mut a, &mut b, &mut c, model.params.n4));
        (shifted[THETA_R], shifted[S_M], shifted[THETA_F]) = (a, b, c);
        assert_eq!(shifted[THETA_F], 0.0);
        let twists = |x: &SVector<f64, NX>| {
            let s = x[S_M] / model.params.n4;
            (x[THETA_R] - s, s - x[THETA_F])
        };
        let (t1, t2) = (twists(&x), twists(&shifted));
        assert!((t1.0 - t2.0).abs() < 1e-12 && (t1.1 - t2.1).abs() < 1e-12);
        // Velocities after another 10 s agree to round-off; the angles differ by the shift.
        let (mut p, mut q) = (x, shifted);
        for _ in 0..500 {
            p = model.step(&p, &u, 0.02);
            q = model.step(&q, &u, 0.02);
        }
        for i in [OMEGA_R, V_M, OMEGA_F] {
            assert!((p[i] - q[i]).abs() < 1e-9, "{i}: {} {}", p[i], q[i]);
        }
        assert!((p[THETA_F] - q[THETA_F] - x[THETA_F]).abs() < 1e-9);
        // Small angles are left alone.
        let (mut a, mut b, mut c) = (1.0, 0.1, 1.0);
        assert!(!rebase_angles(&mut a, &mut b, &mut c, 0.115));
        assert_eq!((a, b, c), (1.0, 0.1, 1.0));
    }

    #[test]
    fn f32_model_tracks_f64() {
        let m64 = ScooterModel::<f64>::nominal();
        let m32 = ScooterModel::<f32>::nominal();
        let (mut a, mut b) = (m64.nominal_state(), m32.nominal_state());
        for _ in 0..500 {
            a = m64.step(&a, &Vector1::new(1.0), 0.02);
            b = m32.step(&b, &Vector1::new(1.0f32), 0.02);
        }
        assert!((a[OMEGA_R] - f64::from(b[OMEGA_R])).abs() < 1e-3 * a[OMEGA_R]);
    }
}
