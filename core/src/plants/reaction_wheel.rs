//! Ithaco type-A reaction wheel (Alidadi & Rahimi 2023, Eqs. 1-6, Table 2) and the lubricant
//! loss model (Eqs. 7-9, 29).
//!
//! Step 1 estimates the lubricant temperature from wheel speed and motor current: the particle
//! state is `[I_m (A), omega_m (rad/s), T_lub (degC)]`, the input `[V_comm (V), t (s)]` (time
//! drives the lubricant torque noise of Eq. 3). Readings of garbled formulas are listed in
//! `docs/deviations.md` under "Reaction wheel".
//!
//! The torque ripple and cogging terms of Eq. 5 oscillate at 18-108 times the shaft frequency
//! (kHz at the speeds used) and cannot be integrated at 20 Hz; their integral over one step
//! changes the speed by less than 1e-4 rad/s, so the estimation model omits them. The host
//! truth plant integrates their effect analytically per step.

use crate::error::Error;
use crate::model::{Model, Stochastic, gaussian_log_likelihood, rk4};
use crate::random::normal;
use crate::real::{Real, cast};
use nalgebra::{SVector, Vector2, Vector3};
use rand_core::Rng;

/// Lowest and highest command voltage the driver accepts (Table 2).
pub const COMMAND_RANGE_V: (f64, f64) = (0.0, 5.0);
/// Sample interval of the paper's simulation (s).
pub const SAMPLE_INTERVAL_S: f64 = 0.05;

/// Physical parameters of the wheel (SI units; temperatures in degC).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WheelParams<T> {
    /// Driver gain `G_d` (A/V).
    pub drive_gain: T,
    /// Driver -3 dB bandwidth `omega_d` (rad/s).
    pub driver_bandwidth: T,
    /// Motor torque constant `K_t` (N m/A).
    pub torque_constant: T,
    /// Back-EMF constant `K_e` (V s/rad).
    pub back_emf: T,
    /// Speed limiter feedback gain `K_s` (V s/rad).
    pub speed_limiter_gain: T,
    /// Overspeed threshold `omega_s` (rad/s).
    pub overspeed: T,
    /// Coulomb friction torque `tau_c` (N m).
    pub coulomb_friction: T,
    /// Flywheel inertia `J` (kg m^2).
    pub inertia: T,
    /// Number of motor poles `N`.
    pub poles: T,
    /// Motor torque ripple fraction (Table 2's `B` = 0.22, dimensionless: it multiplies
    /// `K_t I_m` in Eq. 4).
    pub torque_ripple: T,
    /// Cogging torque amplitude (Table 2's `C`, N m; 0 for the type A wheel).
    pub cogging: T,
    /// Input filter resistance `R_in` (ohm).
    pub input_resistance: T,
    /// Voltage feedback gain `K_f` (V/V).
    pub voltage_feedback_gain: T,
    /// Lubricant torque noise angular deviation `theta_a` (rad).
    pub noise_angle: T,
    /// Lubricant torque noise frequency `omega_a` (rad/s).
    pub noise_frequency: T,
    /// Bus voltage `V_bus` (V); not in Table 2, Bialke's nominal 28 V bus.
    pub bus_voltage: T,
    /// Motor bridge resistance `R_B` (ohm) of Eq. 1.
    pub bridge_resistance: T,
    /// Quiescent electronics power `P_q` (W) of Eq. 1.
    pub quiescent_power: T,
    /// Viscous friction constant term, see [`WheelParams::viscous_coefficient`]:
    /// `c_v(T) = viscous_base - viscous_slope * (T + 30)` (N m s/rad).
    pub viscous_base: T,
    /// Temperature slope of the viscous coefficient (N m s/rad/degC).
    pub viscous_slope: T,
    /// Floor of the viscous coefficient (N m s/rad), reached only far above 150 degC.
    pub viscous_floor: T,
    /// Speed scale of the smooth `sign(omega)` used for Coulomb friction (rad/s).
    pub coulomb_smoothing: T,
}

impl<T: Real> WheelParams<T> {
    /// All zeros: the placeholder inside statically allocated pipelines, replaced on reset.
    pub const UNSET: Self = Self {
        drive_gain: T::ZERO,
        driver_bandwidth: T::ZERO,
        torque_constant: T::ZERO,
        back_emf: T::ZERO,
        speed_limiter_gain: T::ZERO,
        overspeed: T::ZERO,
        coulomb_friction: T::ZERO,
        inertia: T::ZERO,
        poles: T::ZERO,
        torque_ripple: T::ZERO,
        cogging: T::ZERO,
        input_resistance: T::ZERO,
        voltage_feedback_gain: T::ZERO,
        noise_angle: T::ZERO,
        noise_frequency: T::ZERO,
        bus_voltage: T::ZERO,
        bridge_resistance: T::ZERO,
        quiescent_power: T::ZERO,
        viscous_base: T::ZERO,
        viscous_slope: T::ZERO,
        viscous_floor: T::ZERO,
        coulomb_smoothing: T::ZERO,
    };

    /// Table 2 with the readings of `docs/deviations.md`.
    pub fn ithaco_type_a() -> Self {
        Self {
            drive_gain: cast(0.19),
            driver_bandwidth: cast(9.0),
            torque_constant: cast(0.029),
            back_emf: cast(0.029),
            speed_limiter_gain: cast(95.0),
            overspeed: cast(690.0),
            coulomb_friction: cast(0.002),
            inertia: cast(0.0077),
            poles: cast(36.0),
            torque_ripple: cast(0.22),
            cogging: T::zero(),
            input_resistance: cast(2.0),
            voltage_feedback_gain: cast(0.5),
            noise_angle: cast(0.05),
            noise_frequency: cast(0.2),
            bus_voltage: cast(28.0),
            bridge_resistance: cast(2.0),
            quiescent_power: cast(3.0),
            viscous_base: cast(4.9e-5),
            viscous_slope: cast(2.0e-7),
            viscous_floor: cast(2.0e-6),
            coulomb_smoothing: cast(0.5),
        }
    }

    /// Viscous friction coefficient `c_v(T)` (N m s/rad), Eq. 2 read as
    /// `1e-3 * (0.049 - 0.0002 (T + 30))`: 38.4 uN m s/rad at 23 degC, falling 0.52 %/degC.
    #[inline]
    pub fn viscous_coefficient(&self, temperature_c: T) -> T {
        let thirty: T = cast(30.0);
        let c = self.viscous_base - self.viscous_slope * (temperature_c + thirty);
        if c > self.viscous_floor {
            c
        } else {
            self.viscous_floor
        }
    }

    /// Bus current of Eq. 1 (A).
    #[inline]
    pub fn bus_current(&self, current: T, speed: T) -> T {
        let v = self.bus_voltage;
        let loss: T = cast(0.04);
        (current * current * self.bridge_resistance
            + loss * current.abs() * v
            + self.quiescent_power
            + speed * current * self.back_emf)
            / (v - T::one())
    }

    /// Back-EMF / bus-current limiting feedback `f_3` (V, never positive): the headroom
    /// voltage of Eq. 5 when it is negative, else zero.
    #[inline]
    pub fn emf_limit_feedback(&self, current: T, speed: T) -> T {
        let six: T = cast(6.0);
        let bus_current = self.bus_current(current, speed);
        let input_drop = if bus_current > T::zero() {
            T::one() + self.input_resistance * bus_current
        } else {
            T::zero()
        };
        let headroom = self.voltage_feedback_gain
            * (self.bus_voltage - six - input_drop - (self.back_emf * speed).abs());
        if headroom <= T::zero() {
            headroom
        } else {
            T::zero()
        }
    }

    /// Speed limiter feedback `f_5` (V), signed so that it always opposes the speed.
    #[inline]
    pub fn speed_limit_feedback(&self, speed: T) -> T {
        let excess = speed.abs() - self.overspeed;
        if excess >= T::zero() {
            let sign = if speed >= T::zero() {
                T::one()
            } else {
                -T::one()
            };
            sign * self.speed_limiter_gain * excess
        } else {
            T::zero()
        }
    }

    /// Lubricant torque noise of Eq. 3, read as `J theta_a omega_a^2 sin(omega_a t + phase)`.
    #[inline]
    pub fn lubricant_torque_noise(&self, t: T, phase: T) -> T {
        self.inertia
            * self.noise_angle
            * self.noise_frequency
            * self.noise_frequency
            * (self.noise_frequency * t + phase).fast_sin()
    }

    /// Smooth `sign(omega)` for Coulomb friction (tanh with a small speed scale), so that
    /// RK4 at 0.05 s does not chatter at standstill.
    #[inline]
    pub fn coulomb_torque(&self, speed: T) -> T {
        let x = speed / self.coulomb_smoothing;
        // tanh(20) = 1 - 8e-18: skip the transcendental away from standstill.
        let limit: T = cast(20.0);
        if x > limit {
            self.coulomb_friction
        } else if x < -limit {
            -self.coulomb_friction
        } else {
            self.coulomb_friction * x.fast_tanh()
        }
    }

    /// Right-hand side of Eq. 4 without ripple and cogging: `(dI/dt, domega/dt)`.
    #[inline]
    pub fn derivatives(
        &self,
        current: T,
        speed: T,
        temperature_c: T,
        command_v: T,
        extra_torque: T,
    ) -> (T, T) {
        let feedback = self.emf_limit_feedback(current, speed) - self.speed_limit_feedback(speed);
        let di = self.driver_bandwidth * (self.drive_gain * (command_v + feedback) - current);
        let torque = self.torque_constant * current
            - self.viscous_coefficient(temperature_c) * speed
            - self.coulomb_torque(speed)
            + extra_torque;
        (di, torque / self.inertia)
    }

    /// Steady state `(I_m, omega_m)` for a constant command when no limiter is active:
    /// `I = G_d V`, `omega = (K_t I - tau_c) / c_v(T)` (positive speeds).
    pub fn unlimited_steady_state(&self, command_v: T, temperature_c: T) -> (T, T) {
        let current = self.drive_gain * command_v;
        let torque = self.torque_constant * current - self.coulomb_friction;
        let speed = torque / self.viscous_coefficient(temperature_c);
        (current, if speed > T::zero() { speed } else { T::zero() })
    }
}

/// Step-1 estimation model: wheel dynamics with the lubricant temperature as a random-walk
/// state. State `[I_m, omega_m, T_lub]`, input `[V_comm, t]`, measurement `[I_m, omega_m]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WheelTemperatureModel<T> {
    /// Wheel parameters.
    pub wheel: WheelParams<T>,
    /// Phase of the lubricant torque noise (rad); 0 as in Eq. 3.
    pub noise_phase: T,
    /// Whether the model includes the lubricant torque noise.
    pub include_torque_noise: bool,
    /// Temperature random-walk intensity (degC/sqrt(s)).
    pub temperature_walk: T,
    /// Speed process noise per step (rad/s), absorbing unmodelled torques.
    pub speed_process_std: T,
    /// Current process noise per step (A).
    pub current_process_std: T,
    /// Assumed current sensor noise (A).
    pub current_sensor_std: T,
    /// Assumed speed sensor noise (rad/s).
    pub speed_sensor_std: T,
    /// RK4 sub-steps per call.
    pub substeps: u32,
}

impl<T: Real> WheelTemperatureModel<T> {
    /// All zeros: the placeholder inside statically allocated pipelines, replaced on reset.
    pub const UNSET: Self = Self {
        wheel: WheelParams::UNSET,
        noise_phase: T::ZERO,
        include_torque_noise: false,
        temperature_walk: T::ZERO,
        speed_process_std: T::ZERO,
        current_process_std: T::ZERO,
        current_sensor_std: T::ZERO,
        speed_sensor_std: T::ZERO,
        substeps: 0,
    };

    /// The model with the given sensor noise and default process noise.
    pub fn new(current_sensor_std: T, speed_sensor_std: T) -> Result<Self, Error> {
        if !(current_sensor_std.finite() && current_sensor_std > T::zero()) {
            return Err(Error::InvalidParameter("current_sensor_std"));
        }
        if !(speed_sensor_std.finite() && speed_sensor_std > T::zero()) {
            return Err(Error::InvalidParameter("speed_sensor_std"));
        }
        Ok(Self {
            wheel: WheelParams::ithaco_type_a(),
            noise_phase: T::zero(),
            include_torque_noise: true,
            temperature_walk: cast(0.02),
            speed_process_std: cast(1.0e-3),
            current_process_std: cast(1.0e-4),
            current_sensor_std,
            speed_sensor_std,
            substeps: 1,
        })
    }

    /// Checks one input sample `[V_comm, t]`: finite, command within 0-5 V.
    pub fn check_input(u: &Vector2<T>) -> Result<(), Error> {
        if !(u.x.finite() && u.y.finite()) {
            return Err(Error::NonFiniteInput);
        }
        if u.x < cast(COMMAND_RANGE_V.0) || u.x > cast(COMMAND_RANGE_V.1) {
            return Err(Error::OutOfRange("command voltage"));
        }
        Ok(())
    }

    /// Checks one measurement `[I_m, omega_m]`: finite and physically possible
    /// (|I| <= 5 A, |omega| <= 1000 rad/s).
    pub fn check_measurement(y: &[T]) -> Result<(), Error> {
        if y.len() != 2 {
            return Err(Error::MeasurementLength {
                expected: 2,
                got: y.len(),
            });
        }
        if !y.iter().all(|v| v.finite()) {
            return Err(Error::NonFiniteMeasurement);
        }
        let mut it = y.iter();
        if let (Some(&i), Some(&w)) = (it.next(), it.next()) {
            if i.abs() > cast(5.0) {
                return Err(Error::OutOfRange("motor current"));
            }
            if w.abs() > cast(1000.0) {
                return Err(Error::OutOfRange("wheel speed"));
            }
        }
        Ok(())
    }
}

impl<T: Real> Model<T, 3, 2> for WheelTemperatureModel<T> {
    fn step(&self, x: &Vector3<T>, u: &Vector2<T>, dt: T) -> Vector3<T> {
        let (command, t0) = (u.x, u.y);
        let temperature = x.z;
        // Time enters only through the torque noise; evaluate it at mid-step (its period is
        // 31 s, so this is exact to 1e-6 relative).
        let extra = if self.include_torque_noise {
            self.wheel
                .lubricant_torque_noise(t0 + dt * cast(0.5), self.noise_phase)
        } else {
            T::zero()
        };
        let wheel = &self.wheel;
        let f = |s: &SVector<T, 3>| {
            let (di, dw) = wheel.derivatives(s.x, s.y, temperature, command, extra);
            Vector3::new(di, dw, T::zero())
        };
        rk4(f, x, dt, self.substeps)
    }
}

impl<T: Real> Stochastic<T, 3, 2> for WheelTemperatureModel<T> {
    fn measurement_len(&self) -> usize {
        2
    }

    fn sample_step<R: Rng + ?Sized>(
        &self,
        x: &Vector3<T>,
        u: &Vector2<T>,
        dt: T,
        rng: &mut R,
    ) -> Vector3<T> {
        let mut next = self.step(x, u, dt);
        next.x = normal(rng, next.x, self.current_process_std);
        next.y = normal(rng, next.y, self.speed_process_std);
        next.z = normal(rng, next.z, self.temperature_walk * dt.sqrt());
        next
    }

    fn log_likelihood(&self, x: &Vector3<T>, _u: &Vector2<T>, y: &[T]) -> T {
        gaussian_log_likelihood(
            y,
            &[x.x, x.y],
            &[self.current_sensor_std, self.speed_sensor_std],
        )
    }

    fn predicted_measurement(
        &self,
        x: &Vector3<T>,
        _u: &Vector2<T>,
        predicted: &mut [T],
        noise_variance: &mut [T],
    ) -> bool {
        let (i, w) = (self.current_sensor_std, self.speed_sensor_std);
        for (slot, v) in predicted.iter_mut().zip([x.x, x.y]) {
            *slot = v;
        }
        for (slot, v) in noise_variance.iter_mut().zip([i * i, w * w]) {
            *slot = v;
        }
        true
    }
}

/// Lubricant loss rate of Eq. 7 without noise: `beta exp(-b / T)` (mL/s, T in degC).
///
/// Eq. 29 prints `exp(+b/T)`; Eqs. 7, 8 and 32 use `exp(-b/T)`, which makes a larger `b` a
/// smaller loss as Table 4's fault scenarios require.
#[inline]
pub fn lubricant_loss_rate<T: Real>(b: T, beta: T, temperature_c: T) -> T {
    beta * (-b / temperature_c).fast_exp()
}

/// Per-interval summary of the lubricant temperature for Eqs. 29-34: the sum of
/// `exp(-b/T_j) dt` over an interval is approximated from the mean and variance of `1/T_j`
/// by a second-order expansion, exact to `O(b^3 var(1/T)^{3/2})` (about 1e-7 relative for a
/// 4-minute interval), so that particles with any `b` can be scored without storing 4800
/// samples.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IntervalExposure<T> {
    /// Interval duration (s).
    pub duration: T,
    /// Mean of `1/T_j` over the interval (1/degC).
    pub mean_inverse_temperature: T,
    /// Variance of `1/T_j` over the interval.
    pub var_inverse_temperature: T,
}

impl<T: Real> IntervalExposure<T> {
    /// An interval at constant temperature.
    pub fn constant(duration: T, temperature_c: T) -> Result<Self, Error> {
        if !(duration.finite() && duration > T::zero()) {
            return Err(Error::InvalidTimeStep);
        }
        if !(temperature_c.finite() && temperature_c > T::zero()) {
            return Err(Error::OutOfRange("lubricant temperature"));
        }
        Ok(Self {
            duration,
            mean_inverse_temperature: T::one() / temperature_c,
            var_inverse_temperature: T::zero(),
        })
    }

    /// `sum_j exp(-b/T_j) dt` over the interval.
    #[inline]
    pub fn integral(&self, b: T) -> T {
        let half: T = cast(0.5);
        self.duration
            * (-b * self.mean_inverse_temperature).fast_exp()
            * (T::one() + half * b * b * self.var_inverse_temperature)
    }

    /// Lubricant consumed over the interval (Eq. 29/30): `beta * integral(b)` (mL).
    #[inline]
    pub fn consumption(&self, b: T, beta: T) -> T {
        beta * self.integral(b)
    }
}

/// Accumulates temperature samples of one interval into an [`IntervalExposure`]
/// (Welford's algorithm on `1/T`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ExposureAccumulator<T> {
    duration: T,
    count: u32,
    mean: T,
    m2: T,
    /// Time integral of the temperature estimate's variance (degC^2 s).
    estimate_variance: T,
}

impl<T: Real> Default for ExposureAccumulator<T> {
    fn default() -> Self {
        Self::EMPTY
    }
}

impl<T: Real> ExposureAccumulator<T> {
    /// No samples yet.
    pub const EMPTY: Self = Self {
        duration: T::ZERO,
        count: 0,
        mean: T::ZERO,
        m2: T::ZERO,
        estimate_variance: T::ZERO,
    };

    /// Adds a temperature held for `dt` seconds. Rejects non-positive or non-finite values.
    pub fn push(&mut self, temperature_c: T, dt: T) -> Result<(), Error> {
        crate::error::check_dt(dt)?;
        if !(temperature_c.finite() && temperature_c > T::zero()) {
            return Err(Error::OutOfRange("lubricant temperature"));
        }
        let inverse = T::one() / temperature_c;
        self.count = self.count.saturating_add(1);
        let n: T = cast(f64::from(self.count));
        let delta = inverse - self.mean;
        self.mean += delta / n;
        self.m2 += delta * (inverse - self.mean);
        self.duration += dt;
        Ok(())
    }

    /// [`ExposureAccumulator::push`] of a temperature estimate with its variance (degC^2):
    /// a non-finite or negative variance counts as zero.
    pub fn push_estimate(&mut self, temperature_c: T, variance: T, dt: T) -> Result<(), Error> {
        self.push(temperature_c, dt)?;
        if variance.finite() && variance > T::zero() {
            self.estimate_variance += variance * dt;
        }
        Ok(())
    }

    /// Root of the time-mean variance of the estimates pushed so far (degC): the interval
    /// mean's error std when the estimate's errors are fully correlated over the interval,
    /// as a filter's are over minutes. Zero before any sample.
    pub fn estimate_std(&self) -> T {
        if self.duration > T::zero() {
            (self.estimate_variance / self.duration).sqrt()
        } else {
            T::zero()
        }
    }

    /// The summary of the samples pushed so far, and a reset for the next interval.
    pub fn take(&mut self) -> Result<IntervalExposure<T>, Error> {
        if self.count == 0 {
            return Err(Error::InsufficientData);
        }
        let n: T = cast(f64::from(self.count));
        let out = IntervalExposure {
            duration: self.duration,
            mean_inverse_temperature: self.mean,
            var_inverse_temperature: self.m2 / n,
        };
        *self = Self::default();
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand_core::SeedableRng;
    use rand_xoshiro::Xoshiro256PlusPlus;

    #[test]
    fn viscous_coefficient_is_positive_and_falls_with_temperature() {
        let p = WheelParams::<f64>::ithaco_type_a();
        let c23 = p.viscous_coefficient(23.0);
        assert!((c23 - 3.84e-5).abs() < 1e-12);
        assert!(p.viscous_coefficient(31.0) < c23);
        assert!(p.viscous_coefficient(1000.0) >= p.viscous_floor);
    }

    #[test]
    fn model_reaches_analytic_steady_state() {
        let model = WheelTemperatureModel::<f64>::new(0.03, 0.003).unwrap();
        let mut m = model;
        m.include_torque_noise = false;
        let mut x = Vector3::new(0.0, 50.0, 23.0);
        let u = Vector2::new(1.0, 0.0);
        for _ in 0..40_000 {
            x = m.step(&x, &u, 0.05);
        }
        let (i, w) = m.wheel.unlimited_steady_state(1.0, 23.0);
        assert!((x.x - i).abs() < 1e-9);
        assert!((x.y - w).abs() < 1e-3 * w, "{} vs {}", x.y, w);
        assert!(w > 80.0 && w < 100.0);
    }

    #[test]
    fn speed_limiter_holds_overspeed() {
        let mut m = WheelTemperatureModel::<f64>::new(0.03, 0.003).unwrap();
        m.include_torque_noise = false;
        m.wheel.viscous_base = 1.0e-5; // free-running speed far above 690 rad/s
        m.wheel.bus_voltage = 60.0; // keep the EMF limit out of the way
        let mut x = Vector3::new(0.0, 600.0, 23.0);
        let u = Vector2::new(5.0, 0.0);
        for _ in 0..20_000 {
            x = m.step(&x, &u, 0.05);
        }
        assert!(x.y > 690.0 && x.y < 700.0, "{}", x.y);
    }

    #[test]
    fn sampling_with_zero_noise_matches_step_and_likelihood_peaks_at_truth() {
        let mut m = WheelTemperatureModel::<f64>::new(0.03, 0.003).unwrap();
        m.temperature_walk = 0.0;
        m.speed_process_std = 0.0;
        m.current_process_std = 0.0;
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(3);
        let x = Vector3::new(0.19, 90.0, 25.0);
        let u = Vector2::new(1.0, 3.0);
        assert_eq!(m.sample_step(&x, &u, 0.05, &mut rng), m.step(&x, &u, 0.05));
        assert_eq!(m.log_likelihood(&x, &u, &[0.19, 90.0]), 0.0);
        assert!(m.log_likelihood(&x, &u, &[0.19, 90.01]) < -5.0);
    }

    #[test]
    fn bad_samples_are_rejected() {
        type M = WheelTemperatureModel<f64>;
        assert_eq!(
            M::check_input(&Vector2::new(f64::NAN, 0.0)),
            Err(Error::NonFiniteInput)
        );
        assert!(M::check_input(&Vector2::new(5.5, 0.0)).is_err());
        assert!(M::check_input(&Vector2::new(-0.1, 0.0)).is_err());
        assert!(M::check_input(&Vector2::new(2.5, 0.0)).is_ok());
        assert!(M::check_measurement(&[0.1, f64::INFINITY]).is_err());
        assert!(M::check_measurement(&[0.1]).is_err());
        assert!(M::check_measurement(&[0.1, 5000.0]).is_err());
        assert!(M::new(0.0, 0.003).is_err());
    }

    #[test]
    fn exposure_expansion_matches_direct_sum() {
        let (b, dt) = (37.0, 0.05);
        let mut acc = ExposureAccumulator::<f64>::default();
        let mut direct = 0.0;
        for j in 0..4800 {
            let temp = 30.0 + 2.0 * (j as f64 / 4800.0 * 6.0).sin();
            direct += (-b / temp).exp() * dt;
            acc.push(temp, dt).unwrap();
        }
        let e = acc.take().unwrap();
        assert!((e.integral(b) / direct - 1.0).abs() < 1e-5);
        assert_eq!(acc.take(), Err(Error::InsufficientData));
        assert!(acc.push(f64::NAN, dt).is_err());
        // The estimate's std is the root of the time-mean variance; nothing left after take.
        acc.push_estimate(30.0, 0.04, 1.0).unwrap();
        acc.push_estimate(30.0, 0.16, 3.0).unwrap();
        acc.push_estimate(30.0, f64::NAN, 1.0).unwrap();
        assert!((acc.estimate_std() - (0.52f64 / 5.0).sqrt()).abs() < 1e-15);
        acc.take().unwrap();
        assert_eq!(acc.estimate_std(), 0.0);
        let c = IntervalExposure::constant(240.0, 30.0).unwrap();
        let rate: f64 = lubricant_loss_rate(37.0, 7.494e-6, 30.0);
        assert!((c.consumption(37.0, 7.494e-6) - 240.0 * rate).abs() < 1e-18);
    }
}

/// Scale of the loss-rate state: the filters carry `beta` in units of 1e-6 mL/s so that it is
/// of order one in f32.
pub const BETA_UNIT: f64 = 1e-6;

/// Checks a consumption sample (mL): finite and positive.
fn consumption_log<T: Real>(y: &[T]) -> Option<T> {
    let v = *y.first()?;
    if v.finite() && v > T::zero() {
        Some(v.ln())
    } else {
        None
    }
}

fn exposure_from<T: Real>(mean_inv: T, var_inv: T, duration: T) -> IntervalExposure<T> {
    IntervalExposure {
        duration,
        mean_inverse_temperature: mean_inv,
        var_inverse_temperature: var_inv,
    }
}

impl<T: Real> IntervalExposure<T> {
    /// The exposure as a filter input `[mean(1/T), var(1/T), duration]`.
    pub fn as_input(&self) -> nalgebra::Vector3<T> {
        nalgebra::Vector3::new(
            self.mean_inverse_temperature,
            self.var_inverse_temperature,
            self.duration,
        )
    }

    /// Checks that the exposure is usable (finite, positive duration and 1/T, var >= 0).
    pub fn check(&self) -> Result<(), Error> {
        if !(self.duration.finite() && self.duration > T::zero()) {
            return Err(Error::InvalidTimeStep);
        }
        if !(self.mean_inverse_temperature.finite() && self.mean_inverse_temperature > T::zero()) {
            return Err(Error::OutOfRange("lubricant temperature"));
        }
        if !(self.var_inverse_temperature.finite() && self.var_inverse_temperature >= T::zero()) {
            return Err(Error::OutOfRange("lubricant temperature variance"));
        }
        Ok(())
    }
}

/// One-step PF model of Eq. 30: state `[b (degC), beta (1e-6 mL/s)]` (constant; the filter's
/// random walk moves it), input the interval exposure `[mean(1/T), var(1/T), duration]`,
/// measurement the consumption of the interval (mL) with log-normal noise.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LossJointModel<T> {
    /// Relative (log-normal) standard deviation of a consumption measurement.
    pub relative_noise: T,
}

impl<T: Real> Model<T, 2, 3> for LossJointModel<T> {
    fn step(&self, x: &Vector2<T>, _u: &Vector3<T>, _dt: T) -> Vector2<T> {
        *x
    }
}

impl<T: Real> Stochastic<T, 2, 3> for LossJointModel<T> {
    fn measurement_len(&self) -> usize {
        1
    }
    fn log_likelihood(&self, x: &Vector2<T>, u: &Vector3<T>, y: &[T]) -> T {
        let Some(log_y) = consumption_log(y) else {
            return T::min_value().unwrap_or(-T::MAX_FINITE);
        };
        let e = exposure_from(u.x, u.y, u.z);
        let beta = x.y * cast(BETA_UNIT);
        if !(beta > T::zero()) {
            return T::min_value().unwrap_or(-T::MAX_FINITE);
        }
        let predicted = e.consumption(x.x, beta).ln();
        gaussian_log_likelihood(&[log_y], &[predicted], &[self.relative_noise])
    }
}

/// First PF of the two-step scheme (Eqs. 31-33) on the log ratio of consecutive interval
/// consumptions, `ln(y_k / y_k-1)`, which does not depend on `beta`.
///
/// Consecutive ratios share a reading, so their noise `e_k - e_k-1` is MA(1), not white. The
/// state is `[b, c]`, where `c` is the particle's estimate of the previous reading's log
/// consumption without `beta`, `ln integral_k-1(b_k-1) + e_k-1`, given the ratios so far along
/// its `b` path (a scalar Kalman filter per particle, [`LossRatioModel::carry`], whose variance
/// is common to all). Each ratio is scored conditional on the earlier ones: mean
/// `ln integral_k(b) - c`, variance `S_k`. Input `[mean(1/T), var(1/T), duration, S_k]` of
/// the current interval.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LossRatioModel;

impl LossRatioModel {
    /// `ln integral(b)` of the interval (`None` if not positive and finite).
    #[inline]
    pub fn log_integral<T: Real>(b: T, exposure: &IntervalExposure<T>) -> Option<T> {
        let integral = exposure.integral(b);
        (integral.finite() && integral > T::zero()).then(|| integral.ln())
    }

    /// The carried estimate after the ratio with innovation `log_ratio - log_integral + c`:
    /// a scalar Kalman update of the current reading's noise with gain
    /// `reading_variance / S_k`.
    #[inline]
    pub fn carry<T: Real>(carried: T, log_ratio: T, log_integral: T, gain: T) -> T {
        log_integral + gain * (log_ratio - log_integral + carried)
    }
}

impl<T: Real> Model<T, 2, 4> for LossRatioModel {
    fn step(&self, x: &SVector<T, 2>, _u: &SVector<T, 4>, _dt: T) -> SVector<T, 2> {
        *x
    }
}

impl<T: Real> Stochastic<T, 2, 4> for LossRatioModel {
    fn measurement_len(&self) -> usize {
        1
    }
    fn log_likelihood(&self, x: &SVector<T, 2>, u: &SVector<T, 4>, y: &[T]) -> T {
        let floor = T::min_value().unwrap_or(-T::MAX_FINITE);
        let Some(log_ratio) = consumption_log(y) else {
            return floor;
        };
        let innovation_variance = u.w;
        if !(innovation_variance > T::zero()) {
            return floor;
        }
        let Some(log_integral) = Self::log_integral(x.x, &exposure_from(u.x, u.y, u.z)) else {
            return floor;
        };
        gaussian_log_likelihood(
            &[log_ratio],
            &[log_integral - x.y],
            &[innovation_variance.sqrt()],
        )
    }
}

/// Second PF of the two-step scheme (Eq. 34): state `[beta (1e-6 mL/s)]`, input
/// `[mean(1/T), var(1/T), duration, b_hat]`, measurement the interval consumption (mL).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LossRateModel<T> {
    /// Relative (log-normal) standard deviation of a consumption measurement.
    pub relative_noise: T,
}

impl<T: Real> Model<T, 1, 4> for LossRateModel<T> {
    fn step(&self, x: &SVector<T, 1>, _u: &SVector<T, 4>, _dt: T) -> SVector<T, 1> {
        *x
    }
}

impl<T: Real> Stochastic<T, 1, 4> for LossRateModel<T> {
    fn measurement_len(&self) -> usize {
        1
    }
    fn log_likelihood(&self, x: &SVector<T, 1>, u: &SVector<T, 4>, y: &[T]) -> T {
        let Some(log_y) = consumption_log(y) else {
            return T::min_value().unwrap_or(-T::MAX_FINITE);
        };
        let beta = x.x * cast(BETA_UNIT);
        if !(beta > T::zero()) {
            return T::min_value().unwrap_or(-T::MAX_FINITE);
        }
        let e = exposure_from(u.x, u.y, u.z);
        let predicted = e.consumption(u.w, beta).ln();
        gaussian_log_likelihood(&[log_y], &[predicted], &[self.relative_noise])
    }
}

/// Cumulative lubricant consumption for RUL prediction: state `[X (mL), b, beta (1e-6 mL/s)]`,
/// input `[T_lub (degC)]` held over the step, `X += beta exp(-b/T) dt`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LossAccumulationModel;

impl<T: Real> Model<T, 3, 1> for LossAccumulationModel {
    fn step(&self, x: &Vector3<T>, u: &SVector<T, 1>, dt: T) -> Vector3<T> {
        let rate = lubricant_loss_rate(x.y, x.z * cast(BETA_UNIT), u.x);
        Vector3::new(x.x + rate * dt, x.y, x.z)
    }
}

impl<T: Real> Stochastic<T, 3, 1> for LossAccumulationModel {
    fn measurement_len(&self) -> usize {
        0
    }
    fn log_likelihood(&self, _x: &Vector3<T>, _u: &SVector<T, 1>, _y: &[T]) -> T {
        T::zero()
    }
}
