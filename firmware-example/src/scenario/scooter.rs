//! Electric-scooter firmware scenario, shared by the firmware (f32, on QEMU) and the host
//! reference run (f64, `tests/tests/firmware_scenario.rs` includes this file by path).
//!
//! Experiment 1 of Yu et al. (2020), as in `host-sim`'s `Profile::EXPERIMENT1`, with the
//! nominal Table 3 parameters: 32 s at 50 Hz (1600 samples), four intermittent rear-encoder
//! faults of falling efficiency, an abrupt rear-friction fault at 10 s and a usage change
//! from 1 V to 1.2 V at 19.8 s. The pipeline detects the faults, estimates them with the
//! AEUKF and predicts the RUL of the encoder at the first disappearance (usage 1) and again
//! after the usage change (usage 2, reactivation).
//!
//! The plant integrates the drivetrain with RK4 in 8 sub-steps per sample. The encoders and
//! the body-speed sensor are 24-bit signed registers at 2^-12 rad/s and 2^-16 m/s (powers of
//! two, so the conversion is exact in f32 and f64).

use nalgebra::{ComplexField, Vector6};
use prognos_core::Error;
use prognos_core::filter::adaptive_ukf::Adaptation;
use prognos_core::pipeline::scooter::{Scooter, ScooterConfig, ScooterReport};
use prognos_core::plants::scooter::{OMEGA_F, OMEGA_R, ScooterParams, V_M};
use prognos_core::random::normal;
use prognos_core::real::{Real, cast};
use rand_core::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;

/// Sample interval (s): 50 Hz.
pub const DT: f64 = 0.02;
/// Samples in the run (32 s).
pub const STEPS: u32 = 1600;
/// RK4 sub-steps of the plant per sample.
pub const PLANT_SUBSTEPS: u32 = 8;
/// Intermittent rear-encoder efficiency `(appears, disappears, value)`; 1 outside.
pub const BETA_INTERVALS: [(f64, f64, f64); 4] = [
    (10.0, 15.56, 0.94),
    (18.0, 21.16, 0.78),
    (24.0, 27.08, 0.55),
    (28.5, 30.94, 0.3),
];
/// Abrupt rear viscous-friction fault `(onset s, R_rv)`.
pub const FRICTION_FAULT: (f64, f64) = (10.0, 0.469);
/// Usage: input before and after the change (V), and the change time (s).
pub const USAGE: (f64, f64, f64) = (1.0, 1.2, 19.8);
/// Sensor noise standard deviations: rear (rad/s), body (m/s), front (rad/s).
pub const SENSOR_STD: [f64; 3] = [1e-3, 1e-4, 1e-3];
/// Register LSBs: rear and front encoder speed (rad/s), body speed (m/s).
pub const SPEED_LSB: [f64; 3] = [1.0 / 4096.0, 1.0 / 65536.0, 1.0 / 4096.0];
/// Seed of the sensor noise.
pub const PLANT_SEED: u64 = 0x5EED_0007_0003;

/// Raw 24-bit counts (sign-extended) `[rear, body, front]`.
pub type ScooterCounts = [i32; 3];

/// The driver's conversion from counts to `[omega_r, v_m, omega_f]`.
pub fn convert<T: Real>(counts: &ScooterCounts) -> [T; 3] {
    let mut y = [T::zero(); 3];
    for ((v, c), lsb) in y.iter_mut().zip(counts).zip(SPEED_LSB) {
        *v = cast::<T>(lsb) * cast::<T>(f64::from(*c));
    }
    y
}

fn quantise(value: f64, lsb: f64) -> i32 {
    let limit = f64::from((1u32 << 23) - 1);
    ComplexField::round(value / lsb).clamp(-limit - 1.0, limit) as i32
}

/// The simulated scooter and its sensors, in scalar `T`.
#[derive(Clone, Debug)]
pub struct ScooterPlant<T: Real> {
    params: ScooterParams<T>,
    state: Vector6<T>,
    k: u32,
    input: T,
    rng: Xoshiro256PlusPlus,
}

impl<T: Real> ScooterPlant<T> {
    /// The scooter at rest.
    pub fn new() -> Self {
        Self {
            params: ScooterParams::nominal(),
            state: Vector6::zeros(),
            k: 0,
            input: cast(USAGE.0),
            rng: Xoshiro256PlusPlus::seed_from_u64(PLANT_SEED),
        }
    }

    /// Time of sample `k` (s), from the index.
    pub fn time_at(k: u32) -> f64 {
        f64::from(k) * DT
    }

    /// Sample index of the state.
    pub fn index(&self) -> u32 {
        self.k
    }

    /// The input held over the last step (V).
    pub fn input(&self) -> T {
        self.input
    }

    /// Advances one sample interval under the profile's input (zero-order hold).
    pub fn advance(&mut self) {
        let t = Self::time_at(self.k);
        let (before, after, change) = USAGE;
        let u = if t >= change { after } else { before };
        let r_rv = if t >= FRICTION_FAULT.0 {
            cast(FRICTION_FAULT.1)
        } else {
            self.params.r_rv
        };
        self.input = cast(u);
        self.state = self.params.advance(
            &self.state,
            self.input,
            r_rv,
            self.params.k1,
            cast(DT),
            PLANT_SUBSTEPS,
        );
        self.k += 1;
    }

    /// Samples the sensors at the current state: the rear encoder sees `beta omega_r`.
    pub fn sample(&mut self) -> ScooterCounts {
        let t = Self::time_at(self.k);
        let beta = BETA_INTERVALS
            .iter()
            .find(|(a, d, _)| t >= *a && t < *d)
            .map_or(1.0, |i| i.2);
        let truth = [
            cast::<T>(beta) * self.state[OMEGA_R],
            self.state[V_M],
            self.state[OMEGA_F],
        ];
        let mut counts = [0; 3];
        for ((c, x), (std, lsb)) in counts
            .iter_mut()
            .zip(truth)
            .zip(SENSOR_STD.iter().zip(SPEED_LSB))
        {
            let y = normal(&mut self.rng, x, cast(*std));
            *c = quantise(y.as_f64(), lsb);
        }
        counts
    }
}

impl<T: Real> Default for ScooterPlant<T> {
    fn default() -> Self {
        Self::new()
    }
}

/// The pipeline of this scenario (AEUKF, the paper's tuning).
pub fn pipeline<T: Real>() -> Result<Scooter<T>, Error> {
    Scooter::new(T::zero(), ScooterConfig::new(Adaptation::Enhanced))
}

/// One pipeline step on converted counts at sample `k` with the input `u` held since the
/// previous sample.
pub fn step<T: Real>(
    pipeline: &mut Scooter<T>,
    k: u32,
    u: T,
    y: &[T; 3],
) -> Result<ScooterReport<T>, Error> {
    pipeline.step(cast(ScooterPlant::<T>::time_at(k)), u, y)
}
