//! Truth plant of the Ithaco type-A reaction wheel with every effect switchable, its sensors,
//! and the paper's temperature/command profile (Table 3, as read in `docs/deviations.md`).
//!
//! Independent of the core's estimation model except for the parameter table: the equations
//! are written out again here, with the wheel angle as an extra state so that torque ripple
//! and cogging can be applied (integrated analytically over each step, because they
//! oscillate at kHz and RK4 at 0.05 s cannot resolve them).

use prognos_core::plants::reaction_wheel::WheelParams;
use prognos_core::random::normal;
use rand_core::Rng;

/// Which physical effects the truth plant simulates. `all()` is the paper's model.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct WheelEffects {
    /// First-order driver lag (bandwidth 9 rad/s); off: the current follows the command at once.
    pub driver_lowpass: bool,
    /// Back-EMF / bus-current voltage limiting (Eqs. 1, 5).
    pub emf_limiting: bool,
    /// Overspeed limiter above 690 rad/s.
    pub speed_limiter: bool,
    /// Coulomb (dry) bearing friction.
    pub coulomb_friction: bool,
    /// Viscous friction depends on lubricant temperature; off: frozen at 23 degC.
    pub viscous_temperature: bool,
    /// Motor torque ripple `B sin(3 N theta)`.
    pub torque_ripple: bool,
    /// Cogging torque `C sin(N theta / 2)`.
    pub cogging: bool,
    /// Lubricant torque noise (Eq. 3).
    pub torque_noise: bool,
}

impl WheelEffects {
    /// Every effect on.
    pub const fn all() -> Self {
        Self {
            driver_lowpass: true,
            emf_limiting: true,
            speed_limiter: true,
            coulomb_friction: true,
            viscous_temperature: true,
            torque_ripple: true,
            cogging: true,
            torque_noise: true,
        }
    }

    /// Every effect off: the nominal wheel.
    pub const fn none() -> Self {
        Self {
            driver_lowpass: false,
            emf_limiting: false,
            speed_limiter: false,
            coulomb_friction: false,
            viscous_temperature: false,
            torque_ripple: false,
            cogging: false,
            torque_noise: false,
        }
    }
}

/// Temperature at which the viscous coefficient is frozen when `viscous_temperature` is off.
pub const FROZEN_VISCOUS_TEMPERATURE_C: f64 = 23.0;

/// Truth wheel state and configuration.
#[derive(Clone, Debug)]
pub struct TruthWheel {
    /// Physical parameters.
    pub params: WheelParams<f64>,
    /// Effects simulated.
    pub effects: WheelEffects,
    /// Phase of the lubricant torque noise (rad).
    pub noise_phase: f64,
    /// Motor current (A).
    pub current: f64,
    /// Wheel speed (rad/s).
    pub speed: f64,
    /// Wheel angle (rad), kept in [0, 2 pi).
    pub angle: f64,
    /// Time (s).
    pub time: f64,
    /// The part of `speed` that is the ripple's and cogging's swing at the current angle
    /// (rad/s): the step's mean speed leaves it out (see [`ripple_step`]).
    pub ripple_swing: f64,
}

impl TruthWheel {
    /// A wheel with every effect on, at rest at t = 0.
    pub fn new() -> Self {
        Self {
            params: WheelParams::ithaco_type_a(),
            effects: WheelEffects::all(),
            noise_phase: 0.0,
            current: 0.0,
            speed: 0.0,
            angle: 0.0,
            time: 0.0,
            ripple_swing: 0.0,
        }
    }

    /// Sets current and speed to the steady state for `command_v` at `temperature_c` (no
    /// limiter active), found by running the plant until it settles.
    pub fn settle(&mut self, command_v: f64, temperature_c: f64) {
        let c = self.viscous(temperature_c);
        let coulomb = if self.effects.coulomb_friction {
            self.params.coulomb_friction
        } else {
            0.0
        };
        self.current = self.params.drive_gain * command_v;
        self.speed = ((self.params.torque_constant * self.current - coulomb) / c).max(0.0);
        self.ripple_swing = 0.0;
    }

    /// The viscous coefficient acting at `temperature_c` (frozen at
    /// [`FROZEN_VISCOUS_TEMPERATURE_C`] unless `viscous_temperature` is on).
    pub fn viscous(&self, temperature_c: f64) -> f64 {
        let t = if self.effects.viscous_temperature {
            temperature_c
        } else {
            FROZEN_VISCOUS_TEMPERATURE_C
        };
        (self.params.viscous_base - self.params.viscous_slope * (t + 30.0))
            .max(self.params.viscous_floor)
    }

    /// The current a sample taken as `command_v` is applied would read: the driver's
    /// algebraic current following it at once, or the lagging current state.
    pub fn current_following(&self, command_v: f64) -> f64 {
        if self.effects.driver_lowpass {
            return self.current;
        }
        let mut current = self.current;
        for _ in 0..3 {
            current = self.params.drive_gain * (command_v + self.feedback(current, self.speed));
        }
        current
    }

    /// Command-voltage feedback from the limiters (V).
    fn feedback(&self, current: f64, speed: f64) -> f64 {
        let p = &self.params;
        let mut v = 0.0;
        if self.effects.emf_limiting {
            let vb = p.bus_voltage;
            let bus_current = (current * current * p.bridge_resistance
                + 0.04 * current.abs() * vb
                + p.quiescent_power
                + speed * current * p.back_emf)
                / (vb - 1.0);
            let drop = if bus_current > 0.0 {
                1.0 + p.input_resistance * bus_current
            } else {
                0.0
            };
            let headroom = p.voltage_feedback_gain * (vb - 6.0 - drop - (p.back_emf * speed).abs());
            if headroom <= 0.0 {
                v += headroom;
            }
        }
        if self.effects.speed_limiter {
            let excess = speed.abs() - p.overspeed;
            if excess >= 0.0 {
                v -= speed.signum() * p.speed_limiter_gain * excess;
            }
        }
        v
    }

    /// `(dI/dt, domega/dt)`; with the driver lag off the current is algebraic and `dI/dt` is 0.
    fn rhs(&self, current: f64, speed: f64, visc: f64, command: f64, extra: f64) -> (f64, f64) {
        let p = &self.params;
        let di = if self.effects.driver_lowpass {
            p.driver_bandwidth
                * (p.drive_gain * (command + self.feedback(current, speed)) - current)
        } else {
            0.0
        };
        let coulomb = if self.effects.coulomb_friction {
            p.coulomb_friction * (speed / p.coulomb_smoothing).tanh()
        } else {
            0.0
        };
        let torque = p.torque_constant * current - visc * speed - coulomb + extra;
        (di, torque / p.inertia)
    }

    /// Advances by `dt` (RK4) under `command_v` with the lubricant at `temperature_c`.
    pub fn step(&mut self, command_v: f64, temperature_c: f64, dt: f64) {
        let p = self.params;
        let visc = self.viscous(temperature_c);
        let extra = if self.effects.torque_noise {
            p.inertia
                * p.noise_angle
                * p.noise_frequency
                * p.noise_frequency
                * (p.noise_frequency * (self.time + 0.5 * dt) + self.noise_phase).sin()
        } else {
            0.0
        };
        if !self.effects.driver_lowpass {
            // Algebraic current: a few fixed-point passes through the limiter feedback.
            for _ in 0..3 {
                self.current = p.drive_gain * (command_v + self.feedback(self.current, self.speed));
            }
        }
        let (i0, w0) = (self.current, self.speed);
        let (a1, b1) = self.rhs(i0, w0, visc, command_v, extra);
        let (a2, b2) = self.rhs(
            i0 + 0.5 * dt * a1,
            w0 + 0.5 * dt * b1,
            visc,
            command_v,
            extra,
        );
        let (a3, b3) = self.rhs(
            i0 + 0.5 * dt * a2,
            w0 + 0.5 * dt * b2,
            visc,
            command_v,
            extra,
        );
        let (a4, b4) = self.rhs(i0 + dt * a3, w0 + dt * b3, visc, command_v, extra);
        let current = i0 + dt / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4);
        let mut speed = w0 + dt / 6.0 * (b1 + 2.0 * b2 + 2.0 * b3 + b4);
        let mean_speed = 0.5 * (w0 + speed) - self.ripple_swing;
        let angle_end = self.angle + mean_speed * dt;
        let ripple = RippleTorques {
            ripple: if self.effects.torque_ripple {
                [i0, current].map(|i| p.torque_constant * i * p.torque_ripple)
            } else {
                [0.0; 2]
            },
            cogging: if self.effects.cogging { p.cogging } else { 0.0 },
            poles: p.poles,
            inertia: p.inertia,
        };
        let (change, swing) = ripple_step(&ripple, self.angle, angle_end, mean_speed, dt);
        speed += change;
        self.ripple_swing = swing;
        self.current = current;
        self.speed = speed;
        self.angle = angle_end.rem_euclid(core::f64::consts::TAU);
        self.time += dt;
    }
}

/// The ripple torque `ripple sin(3 N theta)` and cogging torque `cogging sin(N theta / 2)`
/// over one step, and what they act on.
#[derive(Clone, Copy, Debug)]
pub struct RippleTorques {
    /// Ripple amplitude (N m), K_t I B, at the step's start and end (the current moves
    /// within a step behind a driver lag or after a command step).
    pub ripple: [f64; 2],
    /// Cogging amplitude C (N m).
    pub cogging: f64,
    /// Motor poles N.
    pub poles: f64,
    /// Wheel inertia J (kg m^2).
    pub inertia: f64,
}

/// The speed change of one step from `angle` to `angle_end` at the wheel's smooth mean
/// speed `mean_speed`, and the swing those torques leave in the speed at `angle_end`:
/// `-T / (J k w) cos(k theta)` for each torque whose swing is under a tenth of the speed,
/// else 0. The change is the integral of `T(t) sin(k theta)` to first order in
/// `1 / (k w)`: `(T0 cos(k theta0) - T1 cos(k theta1)) / (J k w)` with the torque at each
/// end (exact for a constant torque; a torque that moves within the step, integrated at its
/// mean, would leave a lasting speed offset of `(T0 - T1) / (J k w)` at a command step).
///
/// The mean speed must leave the previous swing out: a mean that holds it correlates
/// `1 / w` with `cos(k theta)`, and a ripple that averages to nothing would drive the
/// wheel by about `T^2 / (2 J^2 k^2 w^3)` per step, more the finer the steps (at 5 rad/s
/// with B = 345, 0.5 rad/s at 20 Hz steps and 9 rad/s at 800 Hz).
pub fn ripple_step(
    torques: &RippleTorques,
    angle: f64,
    angle_end: f64,
    mean_speed: f64,
    dt: f64,
) -> (f64, f64) {
    let mut change = 0.0;
    let mut swing = 0.0;
    for ([start, torque], k) in [
        (torques.ripple, 3.0 * torques.poles),
        ([torques.cogging; 2], 0.5 * torques.poles),
    ] {
        if start == 0.0 && torque == 0.0 {
            continue;
        }
        let turned = k * mean_speed * dt;
        if turned.abs() > 1e-6 {
            change += (start * (k * angle).cos() - torque * (k * angle_end).cos())
                / (k * mean_speed * torques.inertia);
        } else {
            change += 0.5 * (start + torque) * (k * angle).sin() * dt / torques.inertia;
        }
        // The swing's amplitude against the speed: near standstill the first-order swing
        // no longer describes the motion and the step integrates it as it comes.
        let relative = torque / (torques.inertia * k * mean_speed * mean_speed);
        if relative.abs() < 0.1 {
            swing -= torque * (k * angle_end).cos() / (k * mean_speed * torques.inertia);
        }
    }
    (change, swing)
}

impl Default for TruthWheel {
    fn default() -> Self {
        Self::new()
    }
}

/// Additive white Gaussian sensor noise on motor current and wheel speed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WheelSensors {
    /// Current noise standard deviation (A).
    pub current_std: f64,
    /// Speed noise standard deviation (rad/s).
    pub speed_std: f64,
}

impl WheelSensors {
    /// Table 5's low-noise case.
    pub const LOW_NOISE: Self = Self {
        current_std: 3e-2,
        speed_std: 3e-3,
    };
    /// Table 5's high-noise case.
    pub const HIGH_NOISE: Self = Self {
        current_std: 1.3e-1,
        speed_std: 3e-3,
    };

    /// One noisy `[I_m, omega_m]` sample.
    pub fn measure<R: Rng + ?Sized>(&self, wheel: &TruthWheel, rng: &mut R) -> [f64; 2] {
        [
            normal(rng, wheel.current, self.current_std),
            normal(rng, wheel.speed, self.speed_std),
        ]
    }
}

/// The step-1 validation profile (Table 3 as read in `docs/deviations.md`): lubricant
/// temperature and command voltage at time `t`, advanced one sample at a time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Table3Profile {
    temperature: f64,
    time: f64,
}

impl Table3Profile {
    /// Duration of the validation run (s).
    pub const DURATION_S: f64 = 500.0;

    /// The profile at t = 0.
    pub fn new() -> Self {
        Self {
            temperature: 23.0,
            time: 0.0,
        }
    }

    /// Command at time `t` (V).
    pub fn command(t: f64) -> f64 {
        if t < 250.0 { 1.0 } else { 3.0 }
    }

    /// Current `(t, T_lub, V_comm)`.
    pub fn current(&self) -> (f64, f64, f64) {
        (self.time, self.temperature, Self::command(self.time))
    }

    /// Advances the profile by `dt`.
    pub fn advance(&mut self, dt: f64) {
        let t = self.time + dt;
        // Index arithmetic on the sample grid avoids float drift at the 50 s step.
        let k = (t / dt).round();
        let t_step = (50.0 / dt).round();
        self.temperature = if k < t_step {
            23.0
        } else if (k - t_step).abs() < 0.5 {
            31.0
        } else if t < 300.0 {
            self.temperature * (3e-4 * dt).exp()
        } else {
            self.temperature * (-3e-4 * dt).exp()
        };
        self.time = t;
    }
}

impl Default for Table3Profile {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steady_speed_matches_torque_balance() {
        // K_t G_d V = tau_c + c_v(T) omega, with c_v(23) = 38.4 uN m s: omega = 91.41 rad/s.
        let mut wheel = TruthWheel::new();
        wheel.effects.torque_noise = false;
        wheel.speed = 10.0;
        for _ in 0..(3000.0 / 0.05) as usize {
            wheel.step(1.0, 23.0, 0.05);
        }
        let expected: f64 = (0.029 * 0.19 * 1.0 - 0.002) / 3.84e-5;
        assert!((expected - 91.406).abs() < 1e-2);
        assert!((wheel.speed - expected).abs() < 0.01, "{}", wheel.speed);
        assert!((wheel.current - 0.19).abs() < 1e-9);
    }

    #[test]
    fn back_emf_limit_caps_speed_at_full_command() {
        let mut wheel = TruthWheel::new();
        wheel.effects.torque_noise = false;
        wheel.settle(5.0, 23.0);
        let free = wheel.speed;
        for _ in 0..(2000.0 / 0.05) as usize {
            wheel.step(5.0, 23.0, 0.05);
        }
        assert!(wheel.speed < free - 1.0, "{} vs {}", wheel.speed, free);
        wheel.effects.emf_limiting = false;
        wheel.settle(5.0, 23.0);
        for _ in 0..(2000.0 / 0.05) as usize {
            wheel.step(5.0, 23.0, 0.05);
        }
        assert!((wheel.speed - free).abs() < 0.05);
    }

    #[test]
    fn a_strong_ripple_moves_the_wheel_the_same_whatever_the_step() {
        // B = 345 at 5 rad/s: the speed swings by T / (J 3 N w), about 0.17 rad/s, around a
        // mean the ripple does not move. With the swing inside the step's mean speed, the
        // wheel drifted by 0.47, 3.0 and 9.0 rad/s at 1, 4 and 40 steps per 0.05 s.
        let offsets: Vec<(f64, f64)> = [1usize, 4, 40]
            .iter()
            .map(|&sub| {
                let mut with = TruthWheel::new();
                with.effects.torque_noise = false;
                with.params.torque_ripple = 345.0;
                with.settle(0.4, 23.0);
                let mut without = with.clone();
                without.effects.torque_ripple = false;
                let (mut sum, mut sum2, n) = (0.0, 0.0, 2000);
                for _ in 0..n {
                    for _ in 0..sub {
                        with.step(0.4, 23.0, 0.05 / sub as f64);
                        without.step(0.4, 23.0, 0.05 / sub as f64);
                    }
                    let d = with.speed - without.speed;
                    sum += d;
                    sum2 += d * d;
                }
                let mean = sum / n as f64;
                (mean, (sum2 / n as f64 - mean * mean).sqrt())
            })
            .collect();
        let swing = 0.029 * 0.19 * 0.4 * 345.0 / (0.0077 * 108.0 * 5.313);
        for (mean, rms) in &offsets {
            // The offset is the start's swing (cos 0 = 1), the spread half its square.
            assert!((mean - swing).abs() < 0.3 * swing, "{offsets:?} vs {swing}");
            assert!(
                (rms - swing / 2f64.sqrt()).abs() < 0.1 * swing,
                "{offsets:?}"
            );
        }
    }

    #[test]
    fn ripple_averages_out() {
        let mut with = TruthWheel::new();
        with.effects.torque_noise = false;
        with.settle(1.0, 23.0);
        let mut without = with.clone();
        without.effects.torque_ripple = false;
        let mut max_diff: f64 = 0.0;
        for _ in 0..2000 {
            with.step(1.0, 23.0, 0.05);
            without.step(1.0, 23.0, 0.05);
            max_diff = max_diff.max((with.speed - without.speed).abs());
        }
        assert!(max_diff > 0.0 && max_diff < 1e-3, "{max_diff}");
    }

    #[test]
    fn profile_is_bounded_with_step_at_50s() {
        let mut p = Table3Profile::new();
        let (mut t_max, mut at_49, mut at_51) = (0.0f64, 0.0, 0.0);
        while p.current().0 < Table3Profile::DURATION_S {
            p.advance(0.05);
            let (t, temp, _) = p.current();
            t_max = t_max.max(temp);
            if (t - 49.0).abs() < 1e-6 {
                at_49 = temp;
            }
            if (t - 51.0).abs() < 1e-6 {
                at_51 = temp;
            }
        }
        assert_eq!(at_49, 23.0);
        assert!((at_51 - 31.0 * (3e-4f64 * 1.0).exp()).abs() < 1e-3);
        assert!(
            (t_max - 31.0 * (3e-4f64 * 250.0).exp()).abs() < 0.01,
            "{t_max}"
        );
        assert_eq!(Table3Profile::command(249.0), 1.0);
        assert_eq!(Table3Profile::command(250.0), 3.0);
    }
}
