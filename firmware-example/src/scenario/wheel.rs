//! Reaction-wheel firmware scenario, shared by the firmware (f32, on QEMU) and the host
//! reference run (f64, `tests/tests/firmware_scenario.rs` includes this file by path).
//!
//! 300 s at 20 Hz (6000 samples) of the Ithaco type-A wheel at a constant 3 V command while
//! the lubricant temperature follows one orbital cycle, `30 + 4 sin(2 pi t / 300 s)` degC.
//! The lubricant-consumption gauge reports every 20 s (15 intervals, so the two-step loss
//! filters see 15 consumptions and 14 ratios); at the end the RUL to a consumption threshold
//! of 4 uL at a planned 30 degC is predicted. The loss is the paper's (b = 37 degC,
//! beta = 7.494e-6 mL/s); the interval and threshold are scaled down from the paper's
//! 4 minutes and months so that the run finishes in CI.
//!
//! The plant integrates the wheel (RK4 at the sample interval) with torque ripple (exact
//! integral over the step through single-precision cos), the lubricant torque noise, and the
//! loss. The sensors quantise: current 16-bit at 2^-12 A, speed 24-bit at 2^-13 rad/s, the
//! gauge a 32-bit counter of 2^-40 mL. All scales are powers of two, so the conversion from
//! counts is exact in f32 and f64 alike.

use nalgebra::{ComplexField, SVector, Vector3};
use prognos_core::Error;
use prognos_core::model::rk4;
use prognos_core::pipeline::reaction_wheel::{ReactionWheel, ReactionWheelConfig};
use prognos_core::plants::reaction_wheel::WheelParams;
use prognos_core::random::normal;
use prognos_core::real::{Real, cast};
use prognos_core::stats::Summary;
use rand_core::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;

/// Temperature particles of the step-1 APF.
pub const N: usize = 128;
/// Particles of each loss-parameter filter.
pub const M: usize = 128;
/// Sample interval (s): 20 Hz.
pub const DT: f64 = 0.05;
/// Samples in the run (300 s).
pub const STEPS: u32 = 6000;
/// Samples per consumption interval (20 s).
pub const INTERVAL_SAMPLES: u32 = 400;
/// Command voltage (V).
pub const COMMAND_V: f64 = 3.0;
/// Lubricant temperature cycle: mean, amplitude (degC), period (s).
pub const TEMPERATURE_CYCLE: (f64, f64, f64) = (30.0, 4.0, 300.0);
/// True loss parameters: b (degC), beta (mL/s).
pub const TRUE_LOSS: (f64, f64) = (37.0, 7.494e-6);
/// Relative standard deviation of one gauge interval reading.
pub const GAUGE_RELATIVE_NOISE: f64 = 0.0025;
/// Sensor noise: current (A) and speed (rad/s) standard deviations.
pub const SENSOR_STD: (f64, f64) = (0.03, 0.003);
/// RUL: consumption threshold (mL), planned temperature (degC), step (s), step limit.
pub const RUL_THRESHOLD_ML: f64 = 4.0e-3;
pub const RUL_TEMPERATURE_C: f64 = 30.0;
pub const RUL_STEP_S: f64 = 2.0;
pub const RUL_MAX_STEPS: u32 = 100_000;
/// Seeds of the plant (sensor and gauge noise) and of the filters.
pub const PLANT_SEED: u64 = 0x5EED_0007_0001;
pub const FILTER_SEED: u64 = 0x5EED_0007_0002;

/// Current LSB (A): 16-bit signed, +-8 A.
pub const CURRENT_LSB_A: f64 = 1.0 / 4096.0;
/// Speed LSB (rad/s): 24-bit signed, +-1024 rad/s.
pub const SPEED_LSB_RAD_S: f64 = 1.0 / 8192.0;
/// Gauge LSB (mL): 32-bit unsigned counter.
pub const GAUGE_LSB_ML: f64 = 1.0 / 1_099_511_627_776.0; // 2^-40

/// What the sensor front-end latches after a sample: raw counts.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct WheelCounts {
    /// Motor current, 16-bit two's complement.
    pub current: i16,
    /// Wheel speed, 24-bit two's complement (sign-extended here).
    pub speed: i32,
    /// Gauge counter, valid when `gauge_ready`.
    pub gauge: u32,
    /// A new gauge reading closes a consumption interval.
    pub gauge_ready: bool,
}

/// One converted measurement: `[I_m (A), omega_m (rad/s)]` and the gauge reading (mL).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WheelMeasurement<T> {
    pub current: T,
    pub speed: T,
    pub consumption: Option<T>,
}

/// The driver's conversion from counts (exact: power-of-two scales).
pub fn convert<T: Real>(counts: &WheelCounts) -> WheelMeasurement<T> {
    WheelMeasurement {
        current: cast::<T>(CURRENT_LSB_A) * cast::<T>(f64::from(counts.current)),
        speed: cast::<T>(SPEED_LSB_RAD_S) * cast::<T>(f64::from(counts.speed)),
        consumption: counts
            .gauge_ready
            .then(|| cast::<T>(GAUGE_LSB_ML) * cast::<T>(f64::from(counts.gauge))),
    }
}

fn quantise(value: f64, lsb: f64, bits: u32) -> i32 {
    let limit = f64::from((1u32 << (bits - 1)) - 1);
    let c = ComplexField::round(value / lsb).clamp(-limit - 1.0, limit);
    c as i32
}

/// The simulated wheel, lubricant and sensors, in scalar `T`.
#[derive(Clone, Debug)]
pub struct WheelPlant<T: Real> {
    params: WheelParams<T>,
    current: T,
    speed: T,
    angle: T,
    /// Sample index of the state.
    k: u32,
    /// True cumulative consumption (mL).
    consumed: T,
    /// True consumption since the last gauge reading (mL).
    interval_consumed: T,
    /// What the gauge has reported so far (mL, with its per-interval noise).
    gauge_ml: T,
    rng: Xoshiro256PlusPlus,
}

impl<T: Real> WheelPlant<T> {
    /// The wheel at its steady state for the command at the initial temperature.
    pub fn new() -> Self {
        Self::with_seed(PLANT_SEED)
    }

    /// As [`WheelPlant::new`] with another seed of the sensor and gauge noise (host
    /// campaigns over seeds).
    pub fn with_seed(seed: u64) -> Self {
        let params = WheelParams::<T>::ithaco_type_a();
        let (current, speed) =
            params.unlimited_steady_state(cast(COMMAND_V), Self::temperature_at(0));
        Self {
            params,
            current,
            speed,
            angle: T::zero(),
            k: 0,
            consumed: T::zero(),
            interval_consumed: T::zero(),
            gauge_ml: T::zero(),
            rng: Xoshiro256PlusPlus::seed_from_u64(seed),
        }
    }

    /// Time of sample `k` (s), from the index so that nothing drifts.
    pub fn time_at(k: u32) -> T {
        cast(f64::from(k) * DT)
    }

    /// True lubricant temperature at sample `k` (degC).
    pub fn temperature_at(k: u32) -> T {
        let (mean, amplitude, period) = TEMPERATURE_CYCLE;
        let phase = core::f64::consts::TAU * (f64::from(k) * DT / period);
        cast::<T>(mean) + cast::<T>(amplitude) * cast::<T>(phase).fast_sin()
    }

    /// Command voltage (V).
    pub fn command(&self) -> T {
        cast(COMMAND_V)
    }

    /// Sample index of the current state.
    pub fn index(&self) -> u32 {
        self.k
    }

    /// True cumulative consumption (mL).
    pub fn consumed(&self) -> T {
        self.consumed
    }

    /// Advances one sample interval.
    pub fn advance(&mut self) {
        let p = self.params;
        let dt: T = cast(DT);
        let half: T = cast(0.5);
        let temperature = Self::temperature_at(self.k);
        let command = self.command();
        let t_mid = Self::time_at(self.k) + half * dt;
        let noise = p.lubricant_torque_noise(t_mid, T::zero());
        let x0 = Vector3::new(self.current, self.speed, T::zero());
        let x1 = rk4(
            |s: &SVector<T, 3>| {
                let (di, dw) = p.derivatives(s.x, s.y, temperature, command, noise);
                Vector3::new(di, dw, T::zero())
            },
            &x0,
            dt,
            1,
        );
        let mean_speed = half * (x0.y + x1.y);
        let angle_end = self.angle + mean_speed * dt;
        // Torque ripple B K_t I sin(3 N theta): exact integral over the step at mean speed.
        let k_ripple = cast::<T>(3.0) * p.poles;
        let arg = k_ripple * mean_speed * dt;
        let integral = if arg.abs() > cast(1e-4) {
            ((k_ripple * self.angle).fast_cos() - (k_ripple * angle_end).fast_cos())
                / (k_ripple * mean_speed)
        } else {
            (k_ripple * self.angle).fast_sin() * dt
        };
        let mean_current = half * (x0.x + x1.x);
        let speed =
            x1.y + p.torque_constant * mean_current * p.torque_ripple * integral / p.inertia;
        let tau: T = cast(core::f64::consts::TAU);
        self.angle = angle_end - tau * (angle_end / tau).floor();
        self.current = x1.x;
        self.speed = speed;
        let (b, beta) = TRUE_LOSS;
        let loss = cast::<T>(beta) * (-cast::<T>(b) / temperature).fast_exp() * dt;
        self.consumed += loss;
        self.interval_consumed += loss;
        self.k += 1;
    }

    /// Samples the sensors at the current state: noisy, quantised counts. Every
    /// [`INTERVAL_SAMPLES`] samples (and at the first) the gauge reports too.
    pub fn sample(&mut self) -> WheelCounts {
        let (current_std, speed_std) = SENSOR_STD;
        let current = normal(&mut self.rng, self.current, cast(current_std));
        let speed = normal(&mut self.rng, self.speed, cast(speed_std));
        let gauge_ready = self.k.is_multiple_of(INTERVAL_SAMPLES);
        if gauge_ready && self.k > 0 {
            let noisy = normal(
                &mut self.rng,
                self.interval_consumed,
                self.interval_consumed * cast(GAUGE_RELATIVE_NOISE),
            );
            self.gauge_ml += noisy;
            self.interval_consumed = T::zero();
        }
        let gauge = ComplexField::round(self.gauge_ml.as_f64() / GAUGE_LSB_ML).max(0.0);
        WheelCounts {
            current: quantise(current.as_f64(), CURRENT_LSB_A, 16) as i16,
            speed: quantise(speed.as_f64(), SPEED_LSB_RAD_S, 24),
            gauge: if gauge < 4_294_967_295.0 {
                gauge as u32
            } else {
                u32::MAX
            },
            gauge_ready,
        }
    }

    /// RUL (s) of the true loss from now to the threshold at the planned temperature.
    pub fn true_rul(&self) -> f64 {
        let (b, beta) = TRUE_LOSS;
        let rate = beta * ComplexField::exp(-b / RUL_TEMPERATURE_C);
        (RUL_THRESHOLD_ML - self.consumed.as_f64()) / rate
    }
}

impl<T: Real> Default for WheelPlant<T> {
    fn default() -> Self {
        Self::new()
    }
}

/// The pipeline's settings for this scenario (sensor noise as the plant's).
pub fn config<T: Real>() -> Result<ReactionWheelConfig<T>, Error> {
    ReactionWheelConfig::new(cast(SENSOR_STD.0), cast(SENSOR_STD.1))
}

/// The pipeline's random stream.
pub fn filter_rng() -> Xoshiro256PlusPlus {
    Xoshiro256PlusPlus::seed_from_u64(FILTER_SEED)
}

/// One pipeline step on converted counts at sample `k`.
pub fn step<T: Real>(
    pipeline: &mut ReactionWheel<T, N, M>,
    k: u32,
    command: T,
    y: &WheelMeasurement<T>,
    rng: &mut Xoshiro256PlusPlus,
) -> Result<(), Error> {
    let t = WheelPlant::<T>::time_at(k);
    let (a, b) = (y.current, y.speed);
    match y.consumption {
        Some(x) => pipeline.step(t, command, Some(&[a, b, x]), rng)?,
        None => pipeline.step(t, command, Some(&[a, b]), rng)?,
    };
    Ok(())
}

/// Caller-provided work space of the RUL prediction.
pub struct RulBuffers<T: Real> {
    pub states: [Vector3<T>; M],
    pub times: [T; M],
    pub pairs: [(T, T); M],
}

impl<T: Real> RulBuffers<T> {
    pub fn new() -> Self {
        Self {
            states: [Vector3::zeros(); M],
            times: [T::zero(); M],
            pairs: [(T::zero(), T::zero()); M],
        }
    }
}

impl<T: Real> Default for RulBuffers<T> {
    fn default() -> Self {
        Self::new()
    }
}

/// The final RUL distribution (s) to the threshold at the planned temperature.
pub fn predict_rul<T: Real>(
    pipeline: &ReactionWheel<T, N, M>,
    buffers: &mut RulBuffers<T>,
    rng: &mut Xoshiro256PlusPlus,
) -> Result<Summary<T>, Error> {
    let planned: T = cast(RUL_TEMPERATURE_C);
    pipeline.rul(
        cast(RUL_THRESHOLD_ML),
        |_| planned,
        cast(RUL_STEP_S),
        RUL_MAX_STEPS,
        &mut buffers.states,
        &mut buffers.times,
        &mut buffers.pairs,
        rng,
    )
}
