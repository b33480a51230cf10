//! The reaction wheel as a gap plant (Eqs. 1-6 of the wheel paper, with the rotor angle as a
//! state).
//!
//! Nominal model (every catalogue effect off): the current follows the command at once
//! (`I = G_d (V + f3 + f5)`, with `f3`/`f5` only when those effects are on), and
//! `J dw/dt = K_t I - c_v w` with the viscous coefficient `viscous_coefficient` at
//! `reference_temperature`. Inputs: `u:command` (V), optional `u:temperature` (degC, needed
//! by `viscous_temperature`), optional `u:angle` (rad, the commutation angle; without it
//! ripple and cogging, far above the sample rate, have no phase to replay and are fitted as
//! the spread they add to the sampled speed). Outputs: `y:current` (A), `y:speed` (rad/s).
//!
//! Catalogue (each switched on by name; the fitted parameters are model parameters):
//! `coulomb_friction` (`tau_c sign(w)`), `torque_ripple` (motor torque times
//! `1 + B sin(3 N theta)`), `cogging` (`C sin(N theta / 2)`), `driver_lowpass` (first-order
//! current lag, bandwidth `w_d`), `backemf_limit` (the f3 voltage headroom, fitted through
//! `bus_voltage`), `speed_limiter` (the f5 overspeed feedback, fitted through `overspeed`),
//! `lubricant_torque_noise` (`J theta_a w_a^2 sin(w_a t + phase)`), `viscous_temperature`
//! (`c_v(T) = c_v(T_ref) - viscous_slope (T - T_ref)`, the paper's `c0 - c1 (T + 30)`).

use crate::gap::estimate::{Estimates, FilterSetup, Sensors, StepModel, run_ukf};
use crate::gap::plant::{
    EffectSpec, FitRange, GapPlant, InputTiming, MotionThresholds, ParamSpec, Params, PlantData,
    Regime, Scale, Side, Simulation, motion_regimes, param,
};
use crate::plants::reaction_wheel::{RippleTorques, ripple_step};
use nalgebra::{Vector1, Vector2, Vector4};
use prognos_core::plants::reaction_wheel::WheelParams;
use std::collections::BTreeMap;

/// The reaction wheel gap plant.
#[derive(Clone, Copy, Debug, Default)]
pub struct WheelGapPlant;

/// Every wheel parameter with its default (Table 2 as read in `docs/deviations.md`).
pub const WHEEL_PARAMETERS: &[ParamSpec] = &[
    ParamSpec {
        name: "drive_gain",
        default: 0.19,
        doc: "driver gain G_d (A/V)",
    },
    ParamSpec {
        name: "driver_bandwidth",
        default: 9.0,
        doc: "driver bandwidth w_d (rad/s), driver_lowpass",
    },
    ParamSpec {
        name: "torque_constant",
        default: 0.029,
        doc: "K_t (N m/A)",
    },
    ParamSpec {
        name: "back_emf",
        default: 0.029,
        doc: "K_e (V s/rad)",
    },
    ParamSpec {
        name: "speed_limiter_gain",
        default: 95.0,
        doc: "K_s (V s/rad), speed_limiter",
    },
    ParamSpec {
        name: "overspeed",
        default: 690.0,
        doc: "w_s (rad/s), speed_limiter",
    },
    ParamSpec {
        name: "coulomb_friction",
        default: 0.002,
        doc: "tau_c (N m), coulomb_friction",
    },
    ParamSpec {
        name: "coulomb_smoothing",
        default: 0.5,
        doc: "speed scale of the smooth sign (rad/s)",
    },
    ParamSpec {
        name: "inertia",
        default: 0.0077,
        doc: "J (kg m^2)",
    },
    ParamSpec {
        name: "poles",
        default: 36.0,
        doc: "N motor poles",
    },
    ParamSpec {
        name: "torque_ripple",
        default: 0.22,
        doc: "B (fraction), torque_ripple",
    },
    ParamSpec {
        name: "cogging",
        default: 0.0,
        doc: "C (N m), cogging",
    },
    ParamSpec {
        name: "input_resistance",
        default: 2.0,
        doc: "R_in (ohm), backemf_limit",
    },
    ParamSpec {
        name: "voltage_feedback_gain",
        default: 0.5,
        doc: "K_f (V/V), backemf_limit",
    },
    ParamSpec {
        name: "bus_voltage",
        default: 28.0,
        doc: "V_bus (V), backemf_limit",
    },
    ParamSpec {
        name: "bridge_resistance",
        default: 2.0,
        doc: "R_B (ohm), backemf_limit",
    },
    ParamSpec {
        name: "quiescent_power",
        default: 3.0,
        doc: "P_q (W), backemf_limit",
    },
    ParamSpec {
        name: "noise_angle",
        default: 0.05,
        doc: "theta_a (rad), lubricant_torque_noise",
    },
    ParamSpec {
        name: "noise_frequency",
        default: 0.2,
        doc: "w_a (rad/s), lubricant_torque_noise",
    },
    ParamSpec {
        name: "noise_phase",
        default: 0.0,
        doc: "phase (rad), lubricant_torque_noise",
    },
    ParamSpec {
        name: "viscous_coefficient",
        default: 3.84e-5,
        doc: "c_v at reference_temperature (N m s/rad)",
    },
    ParamSpec {
        name: "viscous_slope",
        default: 2.0e-7,
        doc: "c1 (N m s/rad/degC), viscous_temperature",
    },
    ParamSpec {
        name: "reference_temperature",
        default: 23.0,
        doc: "T_ref (degC) of viscous_coefficient",
    },
];

/// The wheel's own catalogue.
pub fn wheel_effects() -> Vec<EffectSpec> {
    let one = EffectSpec::single;
    let mut viscous = one(
        "viscous_temperature",
        "viscous coefficient falls with lubricant temperature",
        "viscous_slope",
        1e-12,
        1e-5,
        Scale::Log,
    );
    viscous.needs_inputs.push("temperature");
    vec![
        one(
            "coulomb_friction",
            "dry bearing friction tau_c sign(w)",
            "coulomb_friction",
            1e-8,
            1e-1,
            Scale::Log,
        ),
        one(
            "torque_ripple",
            "motor torque times 1 + B sin(3 N theta)",
            "torque_ripple",
            1e-3,
            1e4,
            Scale::Log,
        ),
        one(
            "cogging",
            "cogging torque C sin(N theta / 2)",
            "cogging",
            1e-8,
            1e-1,
            Scale::Log,
        ),
        one(
            "driver_lowpass",
            "first-order current lag, bandwidth w_d",
            "driver_bandwidth",
            0.05,
            1000.0,
            Scale::Log,
        ),
        one(
            "backemf_limit",
            "f3 voltage-headroom feedback (through V_bus)",
            "bus_voltage",
            8.0,
            60.0,
            Scale::Linear,
        ),
        one(
            "speed_limiter",
            "f5 overspeed feedback (through w_s)",
            "overspeed",
            10.0,
            1200.0,
            Scale::Linear,
        ),
        EffectSpec {
            name: "lubricant_torque_noise",
            doc: "periodic lubricant torque J theta_a w_a^2 sin(w_a t + phase)",
            fit: vec![
                FitRange {
                    name: "noise_angle",
                    lo: 1e-7,
                    hi: 10.0,
                    scale: Scale::Log,
                    side: Side::Either,
                },
                // Two periods: every phase then has a representative at least half a
                // period from either end of the search (over one period, a phase near
                // 0 = 2 pi sat at the grid's edge and was fitted as 0).
                FitRange {
                    name: "noise_phase",
                    lo: -std::f64::consts::TAU,
                    hi: std::f64::consts::TAU,
                    scale: Scale::Linear,
                    side: Side::Either,
                },
            ],
            needs_inputs: Vec::new(),
            replaces_generic: Vec::new(),
        },
        viscous,
    ]
}

/// Which effects a replay has on.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct On {
    coulomb: bool,
    ripple: bool,
    cogging: bool,
    lowpass: bool,
    emf: bool,
    limiter: bool,
    noise: bool,
    viscous_t: bool,
}

impl On {
    fn from(active: &[&str]) -> Self {
        let has = |n: &str| active.contains(&n);
        Self {
            coulomb: has("coulomb_friction"),
            ripple: has("torque_ripple"),
            cogging: has("cogging"),
            lowpass: has("driver_lowpass"),
            emf: has("backemf_limit"),
            limiter: has("speed_limiter"),
            noise: has("lubricant_torque_noise"),
            viscous_t: has("viscous_temperature"),
        }
    }
}

/// Variance of the sampled speed that a ripple and a cogging torque of unknown phase add
/// at mean current `current` and speed `speed` over a step `dt`. A torque `T sin(k theta)`
/// makes the speed swing by `T / (J k w) cos(k theta)` around its mean; with the phase
/// unknown the reading sits anywhere on that swing, variance half its amplitude squared.
/// Near standstill the swing is capped at what the torque moves the speed in one step.
fn unknown_phase_variance(
    p: WheelParams<f64>,
    ripple: bool,
    cogging: bool,
    current: f64,
    speed: f64,
    dt: f64,
) -> f64 {
    periodic_torques(p, ripple, cogging, current)
        .map(|(torque, k)| {
            let a = torque / p.inertia * (1.0 / (k * speed.abs()).max(f64::MIN_POSITIVE)).min(dt);
            0.5 * a * a
        })
        .sum()
}

/// The amplitude `T` and angular order `k` of each angle-periodic torque `T sin(k theta)`
/// that is on: the ripple (`K_t I B`, `3 N`) and cogging (`C`, `N / 2`).
fn periodic_torques(
    p: WheelParams<f64>,
    ripple: bool,
    cogging: bool,
    current: f64,
) -> impl Iterator<Item = (f64, f64)> {
    let ripple = ripple.then(|| {
        (
            (p.torque_constant * current * p.torque_ripple).abs(),
            3.0 * p.poles,
        )
    });
    let cogging = cogging.then(|| (p.cogging.abs(), 0.5 * p.poles));
    ripple.into_iter().chain(cogging)
}

/// Variance of the lasting kick that ripple and cogging of unknown phase give the mean
/// speed when it passes through zero with acceleration `acceleration`. Near standstill the
/// angle-periodic torque `T sin(k theta)` no longer averages out: with `theta` quadratic in
/// time through the turning point, its impulse is a Fresnel integral, `T / J sqrt(2 pi /
/// (k |a|))` times the sine of an unknown phase (variance `pi (T / J)^2 / (k |a|)`). Capped
/// at the impulse of ten samples of the full torque, for a crossing too slow for that
/// picture.
fn crossing_kick(
    p: WheelParams<f64>,
    ripple: bool,
    cogging: bool,
    current: f64,
    acceleration: f64,
    dt: f64,
) -> f64 {
    periodic_torques(p, ripple, cogging, current)
        .map(|(torque, k)| {
            let impulse = torque / p.inertia;
            let fresnel = std::f64::consts::PI * impulse * impulse
                / (k * acceleration.abs()).max(f64::MIN_POSITIVE);
            fresnel.min(0.5 * (impulse * 10.0 * dt).powi(2))
        })
        .sum()
}

/// The smallest current jump within one sample, relative to the current's range over the
/// record, that counts as a command step ([`track_kicks`]).
const KICK_JUMP: f64 = 0.05;

/// The mean speed's offset from the kicks of a ripple of unknown phase
/// ([`UnknownPhase::kick`]), tracked by a scalar Kalman filter on the measured speed: each
/// kick is a random step of the offset, which decays with the wheel's `J / c_v`. The
/// replayed speed becomes the one-step prediction (replay plus predicted offset) and its
/// spread grows by the offset's predicted variance, so the held-out likelihood scores the
/// innovations. Without kicks (cogging, a driver lag) nothing changes. Returns whether it
/// tracked.
fn track_kicks(
    w: &Wheel,
    data: &PlantData,
    measured: &[f64],
    unknown_phase: &[UnknownPhase],
    current: &[f64],
    speed: &mut [f64],
    spread: &mut [f64],
) -> bool {
    // A current jump kicks only at a command step (a zero crossing always kicks): a
    // current that moves a little every sample (a smooth command held per sample) kicks by
    // as little each time, a random walk far below one step's kick, and the filter would
    // chase the readings' own swing instead (aliased, it is slow wherever the speed sweeps
    // past a multiple of the sample rate).
    let (lo, hi) = current
        .iter()
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| {
            (lo.min(v), hi.max(v))
        });
    let least_jump = KICK_JUMP * (hi - lo);
    let kicks: Vec<f64> = unknown_phase
        .iter()
        .map(|u| {
            u.crossing
                + if u.jump.abs() >= least_jump {
                    u.kick
                } else {
                    0.0
                }
        })
        .collect();
    if kicks.iter().all(|&k| k <= 0.0) {
        return false;
    }
    // The readings' noise estimate holds the typical spread: the sensor's own is the rest.
    let Some((sigma, _)) = crate::gap::stats::noise_std_from_differences(measured) else {
        return false;
    };
    // Typical, not mean: that estimate leaves out the few samples near standstill, where
    // the spread is many times its median.
    let typical = crate::gap::stats::median(spread).unwrap_or(0.0);
    let sensor = (sigma * sigma - typical).max(0.1 * sigma * sigma);
    let decay = (-w.viscous / w.p.inertia * data.dt.max(0.0)).exp();
    let (mut offset, mut variance) = (0.0, 0.0);
    for k in 0..speed.len().min(measured.len()) {
        let kick = kicks.get(k).copied().unwrap_or(0.0);
        offset *= decay;
        variance = decay * decay * variance + kick;
        speed[k] += offset;
        let reading = sensor + spread[k];
        spread[k] += variance;
        let innovation = measured[k] - speed[k];
        if innovation.is_finite() && variance > 0.0 {
            let gain = variance / (variance + reading);
            offset += gain * innovation;
            variance *= 1.0 - gain;
        }
    }
    true
}

#[derive(Clone, Copy)]
struct Wheel {
    p: WheelParams<f64>,
    on: On,
    viscous: f64,
    viscous_slope: f64,
    reference_temperature: f64,
    noise_phase: f64,
}

impl Wheel {
    /// The wheel with `params`; positive inertia and viscous coefficient required.
    fn new(params: &Params, on: On) -> Result<Self, String> {
        let mut p = WheelParams::<f64>::ithaco_type_a();
        let g = |n: &str| param(params, n);
        p.drive_gain = g("drive_gain");
        p.driver_bandwidth = g("driver_bandwidth");
        p.torque_constant = g("torque_constant");
        p.back_emf = g("back_emf");
        p.speed_limiter_gain = g("speed_limiter_gain");
        p.overspeed = g("overspeed");
        p.coulomb_friction = g("coulomb_friction");
        p.coulomb_smoothing = g("coulomb_smoothing").max(1e-9);
        p.inertia = g("inertia");
        p.poles = g("poles");
        p.torque_ripple = g("torque_ripple");
        p.cogging = g("cogging");
        p.input_resistance = g("input_resistance");
        p.voltage_feedback_gain = g("voltage_feedback_gain");
        p.bus_voltage = g("bus_voltage");
        p.bridge_resistance = g("bridge_resistance");
        p.quiescent_power = g("quiescent_power");
        p.noise_angle = g("noise_angle");
        p.noise_frequency = g("noise_frequency");
        let wheel = Self {
            p,
            on,
            viscous: g("viscous_coefficient"),
            viscous_slope: g("viscous_slope"),
            reference_temperature: g("reference_temperature"),
            noise_phase: g("noise_phase"),
        };
        if !(wheel.p.inertia > 0.0 && wheel.viscous > 0.0) {
            return Err("inertia and viscous_coefficient must be positive".into());
        }
        Ok(wheel)
    }

    fn viscous_at(&self, temperature: f64) -> f64 {
        if self.on.viscous_t {
            (self.viscous - self.viscous_slope * (temperature - self.reference_temperature))
                .max(self.p.viscous_floor)
        } else {
            self.viscous
        }
    }

    fn feedback(&self, current: f64, speed: f64) -> f64 {
        let mut v = 0.0;
        if self.on.emf {
            v += self.p.emf_limit_feedback(current, speed);
        }
        if self.on.limiter {
            v -= self.p.speed_limit_feedback(speed);
        }
        v
    }

    fn rhs(&self, current: f64, speed: f64, visc: f64, command: f64, extra: f64) -> (f64, f64) {
        let p = &self.p;
        let di = if self.on.lowpass {
            p.driver_bandwidth
                * (p.drive_gain * (command + self.feedback(current, speed)) - current)
        } else {
            0.0
        };
        let coulomb = if self.on.coulomb {
            p.coulomb_torque(speed)
        } else {
            0.0
        };
        (
            di,
            (p.torque_constant * current - visc * speed - coulomb + extra) / p.inertia,
        )
    }
}

/// What a replay reads from the record, checked once.
struct Record<'a> {
    t: &'a [f64],
    command: &'a [f64],
    temperature: Option<&'a [f64]>,
    angle: Option<&'a [f64]>,
    /// Without the measured angle the ripple's and cogging's phase is unknown: far above
    /// the sample rate they are a spread of the sampled speed, not a value to replay.
    spread: bool,
    /// Recorded `At` the command, the driver's algebraic current already follows it.
    current_at_row: bool,
}

impl<'a> Record<'a> {
    fn new(w: &Wheel, data: &'a PlantData) -> Result<Self, String> {
        let angle = data.input("angle");
        Ok(Self {
            t: &data.t,
            command: data.input("command").ok_or("missing u:command")?,
            temperature: data.input("temperature"),
            angle,
            spread: angle.is_none() && (w.on.ripple || w.on.cogging),
            current_at_row: data.input_timing == InputTiming::At && !w.on.lowpass,
        })
    }
}

/// The wheel between samples: current, speed (with the ripple's swing), rotor angle, the
/// swing the ripple adds to the speed around its mean, and the current at the end of the
/// last step (before a new command moves it).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct WheelState {
    current: f64,
    speed: f64,
    angle: f64,
    swing: f64,
    end_current: f64,
}

/// What a ripple or cogging of unknown phase adds to a step ([`Record::spread`]): the
/// variance of the speed sampled at its end, and the variance of the lasting kick a jump
/// of the ripple torque at its start gives the mean speed. The speed is continuous, so
/// when the torque jumps at an unknown angle the mean takes up the change of the swing:
/// `dT cos(k theta) / (J k w)`, a random offset that then decays with the wheel.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct UnknownPhase {
    reading: f64,
    kick: f64,
    /// The current's jump at the step's start that makes the kick.
    jump: f64,
    /// The variance of the kick a passage through zero speed within the step gives the
    /// mean speed ([`crossing_kick`]).
    crossing: f64,
}

impl Wheel {
    /// The state at the record's first sample: its measured speed (and current, when the
    /// driver lags), the measured angle.
    fn initial_state(&self, rec: &Record, data: &PlantData) -> WheelState {
        let algebraic = self.p.drive_gain * rec.command.first().copied().unwrap_or(0.0);
        let current = if self.on.lowpass {
            data.first_output("current").unwrap_or(algebraic)
        } else {
            algebraic
        };
        WheelState {
            current,
            speed: data.first_output("speed").unwrap_or(0.0),
            angle: rec.angle.and_then(|a| a.first().copied()).unwrap_or(0.0),
            swing: 0.0,
            end_current: current,
        }
    }

    /// The state as sample `k` shows it: the sample at t_k shows the current of the
    /// previous step (the command of step k acts from t_k on, zero-order hold), unless the
    /// record is taken `At` the command and the driver's current follows it at once.
    fn show(&self, rec: &Record, k: usize, s: &mut WheelState) {
        if rec.current_at_row {
            for _ in 0..3 {
                s.current =
                    self.p.drive_gain * (rec.command[k] + self.feedback(s.current, s.speed));
            }
        }
    }

    /// From sample `k` to `k + 1`; with the ripple's phase unknown, also what it adds to
    /// the speed ([`UnknownPhase`], zero otherwise).
    fn advance(&self, rec: &Record, k: usize, s: WheelState) -> (WheelState, UnknownPhase) {
        let p = &self.p;
        let on = self.on;
        let v = rec.command[k];
        let dt = rec.t[k + 1] - rec.t[k];
        let visc = self.viscous_at(rec.temperature.map_or(self.reference_temperature, |t| t[k]));
        let extra = if on.noise {
            p.inertia
                * p.noise_angle
                * p.noise_frequency
                * p.noise_frequency
                * (p.noise_frequency * (rec.t[k] + 0.5 * dt) + self.noise_phase).sin()
        } else {
            0.0
        };
        // Sub-steps keep RK4 accurate for a fast driver (w_d h <= 1, inside its stability
        // limit 2.8) and let the limiter feedback follow the speed.
        let substeps = if on.lowpass {
            (p.driver_bandwidth * dt).ceil().max(1.0) as usize
        } else if on.emf || on.limiter {
            4
        } else {
            1
        };
        let h = dt / substeps as f64;
        let algebraic = |current: &mut f64, speed: f64| {
            for _ in 0..3 {
                *current = p.drive_gain * (v + self.feedback(*current, speed));
            }
        };
        let (mut current, mut speed) = (s.current, s.speed);
        if !on.lowpass {
            algebraic(&mut current, speed);
        }
        let (i0, w0) = (current, speed);
        for sub in 0..substeps {
            if !on.lowpass && sub > 0 {
                algebraic(&mut current, speed);
            }
            let (ci, cw) = (current, speed);
            let (a1, b1) = self.rhs(ci, cw, visc, v, extra);
            let (a2, b2) = self.rhs(ci + 0.5 * h * a1, cw + 0.5 * h * b1, visc, v, extra);
            let (a3, b3) = self.rhs(ci + 0.5 * h * a2, cw + 0.5 * h * b2, visc, v, extra);
            let (a4, b4) = self.rhs(ci + h * a3, cw + h * b3, visc, v, extra);
            current = ci + h / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4);
            speed = cw + h / 6.0 * (b1 + 2.0 * b2 + 2.0 * b3 + b4);
        }
        let mut angle = rec.angle.map_or(s.angle, |a| a[k]);
        // The ripple's swing left out, as the truth wheel does (`ripple_step`).
        let mean_speed = 0.5 * (w0 + speed) - s.swing;
        if rec.spread {
            let spread = UnknownPhase {
                reading: unknown_phase_variance(
                    *p,
                    on.ripple,
                    on.cogging,
                    0.5 * (i0 + current),
                    mean_speed,
                    dt,
                ),
                kick: unknown_phase_variance(
                    *p,
                    on.ripple,
                    false,
                    i0 - s.end_current,
                    mean_speed,
                    dt,
                ),
                jump: i0 - s.end_current,
                crossing: if w0 * speed < 0.0 {
                    crossing_kick(
                        *p,
                        on.ripple,
                        on.cogging,
                        0.5 * (i0 + current),
                        (speed - w0) / dt,
                        dt,
                    )
                } else {
                    0.0
                },
            };
            angle += mean_speed * dt;
            let next = WheelState {
                current,
                speed,
                angle,
                swing: s.swing,
                end_current: current,
            };
            return (next, spread);
        }
        // The measured angle pins the phase at the step's end too: otherwise a replayed
        // speed error dw puts the ripple 3 N dw dt off (5 rad for 1 rad/s at 20 Hz), and
        // the fitted ripple itself moves the speed. Taken within half a turn of the
        // replayed end, so the whole turns between samples follow the replayed speed.
        let predicted_end = angle + mean_speed * dt;
        let angle_end = match rec.angle {
            Some(a) if a[k + 1].is_finite() => {
                let turn = std::f64::consts::TAU;
                let off = (a[k + 1] - predicted_end).rem_euclid(turn);
                predicted_end + if off > 0.5 * turn { off - turn } else { off }
            }
            _ => predicted_end,
        };
        // Ripple and cogging oscillate far above the sample rate: exact integral of
        // sin(k theta) over the step at the mean speed.
        let torques = RippleTorques {
            ripple: if on.ripple {
                [i0, current].map(|i| p.torque_constant * i * p.torque_ripple)
            } else {
                [0.0; 2]
            },
            cogging: if on.cogging { p.cogging } else { 0.0 },
            poles: p.poles,
            inertia: p.inertia,
        };
        // The torques act along the measured angle's path: near standstill the replayed
        // speed is relatively far off, and the integral at it, between measured ends,
        // would be inconsistent with them (many times too large at a zero crossing).
        let travelled = (angle_end - angle) / dt;
        let (change, swing) = ripple_step(&torques, angle, angle_end, travelled, dt);
        let next = WheelState {
            current,
            speed: speed + change,
            angle: angle_end.rem_euclid(std::f64::consts::TAU),
            swing,
            end_current: current,
        };
        (next, UnknownPhase::default())
    }
}

/// The wheel's estimator: the core's UKF on `[current, speed, ripple swing, c_v]` with the
/// replay's equations, the viscous coefficient tracked as a random walk as the wheel
/// paper's filter tracks the lubricant's friction. Estimates of `current`, `speed` and
/// the `viscous_coefficient` acting at each sample (at the record's temperature when
/// `viscous_temperature` is on): an unmodelled friction shows as `c_v` drifting to absorb
/// it.
pub fn estimate_wheel(
    params: &Params,
    active: &[&str],
    data: &PlantData,
    sensors: &Sensors,
) -> Result<Estimates, String> {
    const CURRENT: usize = 0;
    const SPEED: usize = 1;
    const SWING: usize = 2;
    const VISCOUS: usize = 3;
    let wheel = Wheel::new(params, On::from(active))?;
    let rec = Record::new(&wheel, data)?;
    let mut sensors = sensors.clone();
    if rec.spread {
        // A ripple of unknown phase is read as the spread it adds to the sampled speed.
        let replay = WheelGapPlant.simulate(params, active, data)?;
        let spread = replay
            .variances
            .get(1)
            .cloned()
            .flatten()
            .unwrap_or_default();
        let mean = spread.iter().sum::<f64>() / spread.len().max(1) as f64;
        if let Some(c) = sensors.channels.get_mut(1) {
            c.sigma = (c.sigma * c.sigma + mean).sqrt();
        }
    }
    let floor = wheel.p.viscous_floor;
    let model = StepModel {
        // The input is the sample index: the step reads command, temperature and angle
        // from the record.
        step: |x: &Vector4<f64>, u: &Vector1<f64>, _dt: f64| {
            let k = u[0] as usize;
            let mut w = wheel;
            w.viscous = x[VISCOUS].max(floor);
            let s = WheelState {
                current: x[CURRENT],
                speed: x[SPEED],
                angle: rec.angle.map_or(0.0, |a| a[k]),
                swing: x[SWING],
                end_current: x[CURRENT],
            };
            let (mut next, _) = w.advance(&rec, k, s);
            w.show(&rec, k + 1, &mut next);
            Vector4::new(next.current, next.speed, next.swing, x[VISCOUS])
        },
        outputs: |x: &Vector4<f64>, _: usize| Vector2::new(x[CURRENT], x[SPEED]),
    };
    let variance = |c: usize| {
        sensors
            .channels
            .get(c)
            .map_or(1.0, |s| s.sigma * s.sigma)
            .max(1e-12)
    };
    let dt = data.dt.max(1e-12);
    let mut start = wheel.initial_state(&rec, data);
    wheel.show(&rec, 0, &mut start);
    let c_v = wheel.viscous;
    let setup = FilterSetup {
        x0: Vector4::new(start.current, start.speed, 0.0, c_v),
        p0: Vector4::new(
            variance(0),
            variance(1),
            1e-6 * variance(1),
            (0.1 * c_v).powi(2),
        ),
        // The model is trusted to a tenth of each sensor's noise per sample (the driver's
        // algebraic current, without its lag, to a hundredth of that); c_v may move by
        // 1 % in 10 s.
        q_rate: Vector4::new(
            if wheel.on.lowpass { 0.01 } else { 1e-4 } * variance(0) / dt,
            0.01 * variance(1) / dt,
            1e-6 * variance(1) / dt,
            (0.01 * c_v).powi(2) / 10.0,
        ),
        bounds: Some((
            Vector4::new(
                f64::NEG_INFINITY,
                f64::NEG_INFINITY,
                f64::NEG_INFINITY,
                floor,
            ),
            Vector4::new(f64::INFINITY, f64::INFINITY, f64::INFINITY, 100.0 * c_v),
        )),
    };
    let mut est = run_ukf::<_, _, 4, 9, 1, 2>(
        &model,
        &setup,
        &data.t,
        |k| Vector1::new(k as f64),
        &sensors,
        &[
            ("current", CURRENT),
            ("speed", SPEED),
            ("viscous_coefficient", VISCOUS),
        ],
    )?;
    if let Some(c) = est.states.get_mut("viscous_coefficient") {
        for (k, c) in c.iter_mut().enumerate() {
            let temperature = rec
                .temperature
                .map_or(wheel.reference_temperature, |t| t[k]);
            let mut w = wheel;
            w.viscous = *c;
            *c = w.viscous_at(temperature);
        }
    }
    Ok(est)
}

impl GapPlant for WheelGapPlant {
    fn name(&self) -> &'static str {
        "reaction_wheel"
    }

    fn parameters(&self) -> Vec<ParamSpec> {
        WHEEL_PARAMETERS.to_vec()
    }

    fn required_inputs(&self) -> Vec<&'static str> {
        vec!["command"]
    }

    fn optional_inputs(&self) -> Vec<(&'static str, &'static str)> {
        vec![
            ("temperature", "viscous_temperature"),
            (
                "angle",
                "the commutation angle; without it ripple and cogging have no phase \
                 and are fitted as the spread they add to the sampled speed, and the \
                 offset they leave in the mean speed (a ripple at each command step, \
                 both at each zero crossing) is tracked on the measured speed",
            ),
        ]
    }

    fn feedthrough(&self) -> bool {
        true
    }

    fn sampled_inputs(&self) -> Vec<&'static str> {
        vec!["angle", "temperature"]
    }

    fn outputs(&self) -> Vec<&'static str> {
        vec!["current", "speed"]
    }

    fn units(&self) -> Vec<(&'static str, &'static str)> {
        vec![
            ("u:command", "V"),
            ("u:temperature", "degC"),
            ("u:angle", "rad"),
            ("y:current", "A"),
            ("y:speed", "rad/s"),
        ]
    }

    fn effects(&self) -> Vec<EffectSpec> {
        wheel_effects()
    }

    fn simulate(
        &self,
        params: &Params,
        active: &[&str],
        data: &PlantData,
    ) -> Result<Simulation, String> {
        let w = Wheel::new(params, On::from(active))?;
        let rec = Record::new(&w, data)?;
        let n = data.len();
        let mut s = w.initial_state(&rec, data);
        let mut out_i = Vec::with_capacity(n);
        let mut out_w = Vec::with_capacity(n);
        let mut unknown_phase = vec![UnknownPhase::default(); if rec.spread { n } else { 0 }];
        for k in 0..n {
            w.show(&rec, k, &mut s);
            out_i.push(s.current);
            out_w.push(s.speed);
            if k + 1 == n {
                break;
            }
            let added;
            (s, added) = w.advance(&rec, k, s);
            if let Some(v) = unknown_phase.get_mut(k + 1) {
                *v = added;
            }
            if !(s.speed.is_finite() && s.current.is_finite()) {
                return Err(format!("replay diverged at t = {}", data.t[k]));
            }
        }
        let mut var_w: Vec<f64> = unknown_phase.iter().map(|u| u.reading).collect();
        let innovations = match data.output("speed").filter(|_| rec.spread) {
            Some(measured) => track_kicks(
                &w,
                data,
                measured,
                &unknown_phase,
                &out_i,
                &mut out_w,
                &mut var_w,
            ),
            None => false,
        };
        let mut states = BTreeMap::new();
        states.insert("current".to_string(), out_i.clone());
        states.insert("speed".to_string(), out_w.clone());
        Ok(Simulation {
            outputs: vec![out_i, out_w],
            states,
            variances: if rec.spread {
                vec![None, Some(var_w)]
            } else {
                Vec::new()
            },
            innovations,
        })
    }

    fn estimate(
        &self,
        params: &Params,
        active: &[&str],
        data: &PlantData,
        sensors: &Sensors,
    ) -> Option<Result<Estimates, String>> {
        Some(estimate_wheel(params, active, data, sensors))
    }

    fn initial_window(&self) -> f64 {
        // The speed forgets its initial error over J / c_v = 200 s: pin it to 1/sqrt(40)
        // of the noise with the first 2 s (40 samples at 20 Hz).
        2.0
    }

    fn regimes(&self, data: &PlantData, nominal: &Simulation) -> Vec<Regime> {
        let n = data.len();
        let speed: Vec<f64> = data
            .output("speed")
            .map_or_else(|| nominal.outputs[1].clone(), <[f64]>::to_vec);
        let sim_speed = &nominal.outputs[1];
        let command = data.input("command").unwrap_or(&[]);
        let mut since_step = vec![f64::INFINITY; n];
        let mut last = f64::NEG_INFINITY;
        for (k, since) in since_step.iter_mut().enumerate() {
            if k > 0 && command.get(k) != command.get(k - 1) {
                last = data.t[k];
            }
            *since = data.t[k] - last;
        }
        let limits = MotionThresholds {
            zero: 5.0,
            low: 50.0,
            high: 400.0,
            acceleration: 0.5,
        };
        let mut out = motion_regimes(&data.t, &speed, sim_speed, Some(limits));
        out.push(Regime::from_fn("after_command_step", n, |k| {
            since_step[k] < 1.0
        }));
        if let Some(temp) = data.input("temperature")
            && let Some(mid) = crate::gap::stats::median(temp)
        {
            out.push(Regime::from_fn("warm", n, |k| temp[k] > mid));
            out.push(Regime::from_fn("cool", n, |k| temp[k] <= mid));
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plants::reaction_wheel::{TruthWheel, WheelEffects};

    fn profile(n: usize) -> PlantData {
        let dt = 0.05;
        let mut d = PlantData {
            dt,
            ..Default::default()
        };
        d.t = (0..n).map(|k| k as f64 * dt).collect();
        let cmd: Vec<f64> = (0..n).map(|k| if k < n / 2 { 3.0 } else { -2.0 }).collect();
        d.inputs.insert("command".into(), cmd);
        d
    }

    /// Runs a settled truth wheel over `command` at 20 Hz: its current, speed and angle at
    /// each sample, before that sample's step.
    fn record(truth: &mut TruthWheel, command: &[f64]) -> [Vec<f64>; 3] {
        truth.settle(command[0], 23.0);
        let mut out = [Vec::new(), Vec::new(), Vec::new()];
        for &v in command {
            out[0].push(truth.current);
            out[1].push(truth.speed);
            out[2].push(truth.angle);
            truth.step(v, 23.0, 0.05);
        }
        out
    }

    #[test]
    fn replay_matches_the_truth_plant_with_the_same_effects() {
        let n = 2000;
        let mut data = profile(n);
        let mut truth = TruthWheel::new();
        truth.effects = WheelEffects {
            driver_lowpass: true,
            coulomb_friction: true,
            ..WheelEffects::none()
        };
        let [i, w, _] = record(&mut truth, &data.inputs["command"]);
        data.outputs.insert("current".into(), i);
        data.outputs.insert("speed".into(), w.clone());
        let plant = WheelGapPlant;
        let params = plant.default_params();
        let sim = plant
            .simulate(&params, &["driver_lowpass", "coulomb_friction"], &data)
            .unwrap();
        let err = sim.outputs[1]
            .iter()
            .zip(&w)
            .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
        assert!(err < 1e-6, "{err}");
        let without = plant.simulate(&params, &["driver_lowpass"], &data).unwrap();
        let gap = without.outputs[1]
            .iter()
            .zip(&w)
            .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
        assert!(gap > 1.0, "coulomb friction must matter: {gap}");
    }

    #[test]
    fn ripple_and_cogging_replay_with_the_measured_angle() {
        let n = 3000;
        let mut data = profile(n);
        let mut truth = TruthWheel::new();
        truth.effects = WheelEffects {
            torque_ripple: true,
            cogging: true,
            ..WheelEffects::none()
        };
        truth.params.torque_ripple = 50.0;
        truth.params.cogging = 1e-3;
        let [i, w, a] = record(&mut truth, &data.inputs["command"]);
        data.outputs.insert("current".into(), i);
        data.outputs.insert("speed".into(), w.clone());
        data.inputs.insert("angle".into(), a);
        let plant = WheelGapPlant;
        let mut params = plant.default_params();
        params.insert("torque_ripple".into(), 50.0);
        params.insert("cogging".into(), 1e-3);
        let sim = plant
            .simulate(&params, &["torque_ripple", "cogging"], &data)
            .unwrap();
        let err = sim.outputs[1]
            .iter()
            .zip(&w)
            .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
        let off = plant.simulate(&params, &[], &data).unwrap();
        let effect = off.outputs[1]
            .iter()
            .zip(&w)
            .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
        assert!(effect > 5e-3, "{effect}");
        assert!(err < 1e-3 * effect, "{err} vs {effect}");
    }

    #[test]
    fn without_the_angle_ripple_is_a_spread_of_the_speed_not_a_replayed_value() {
        // Far above the sample rate and with its phase unknown, the ripple leaves the mean
        // replay alone and predicts the speed's spread: half the squared swing
        // K_t I B / (J 3 N w).
        let data = profile(400);
        let plant = WheelGapPlant;
        let mut params = plant.default_params();
        params.insert("torque_ripple".into(), 300.0);
        let on = plant.simulate(&params, &["torque_ripple"], &data).unwrap();
        let off = plant.simulate(&params, &[], &data).unwrap();
        assert_eq!(on.outputs, off.outputs);
        assert!(off.variances.is_empty());
        let spread = on.variances[1].as_ref().unwrap();
        assert!(on.variances[0].is_none());
        for k in [100, 190, 390] {
            // The step into sample k, at its mean current and speed.
            let mean = |c: usize| 0.5 * (on.outputs[c][k - 1] + on.outputs[c][k]);
            let (i, w) = (mean(0), mean(1));
            let swing = 0.029 * i * 300.0 / (0.0077 * 108.0 * w);
            let expected = 0.5 * swing * swing;
            assert!(
                (spread[k] - expected).abs() < 0.05 * expected && expected > 1e-4,
                "{k}: {} vs {expected}",
                spread[k]
            );
        }
    }

    #[test]
    fn a_strong_ripple_behind_a_driver_lag_replays_a_finely_integrated_wheel() {
        // B = 167 behind a 140 rad/s driver lag: at the command step the current falls
        // within one sample, and a ripple integrated at the step's mean current left a
        // lasting 6e-3 rad/s speed offset (two noise stds). The truth takes 40 steps a
        // sample, close to the continuous wheel.
        let (n, dt, sub) = (4000, 0.05, 40);
        let mut data = profile(n);
        let command = data.inputs["command"].clone();
        let mut truth = TruthWheel::new();
        truth.effects = WheelEffects {
            torque_ripple: true,
            driver_lowpass: true,
            ..WheelEffects::none()
        };
        truth.params.torque_ripple = 167.0;
        truth.params.driver_bandwidth = 140.0;
        truth.settle(command[0], 23.0);
        let (mut current, mut speed, mut angle) = (vec![], vec![], vec![]);
        for &v in &command {
            current.push(truth.current);
            speed.push(truth.speed);
            angle.push(truth.angle);
            for _ in 0..sub {
                truth.step(v, 23.0, dt / sub as f64);
            }
        }
        data.outputs.insert("current".into(), current);
        data.outputs.insert("speed".into(), speed.clone());
        data.inputs.insert("angle".into(), angle);
        let plant = WheelGapPlant;
        let mut params = plant.default_params();
        params.insert("torque_ripple".into(), 167.0);
        params.insert("driver_bandwidth".into(), 140.0);
        let rms = |effects: &[&str]| {
            let sim = plant.simulate(&params, effects, &data).unwrap();
            let sum: f64 = (0..n).map(|k| (sim.outputs[1][k] - speed[k]).powi(2)).sum();
            (sum / n as f64).sqrt()
        };
        let error = rms(&["torque_ripple", "driver_lowpass"]);
        let without = rms(&["driver_lowpass"]);
        assert!(without > 5e-3, "the ripple must matter: {without}");
        assert!(error < 3e-4, "{error} (without the ripple {without})");
    }

    #[test]
    fn without_the_angle_command_steps_kick_the_mean_speed_and_the_replay_tracks_them() {
        // B = 300, the command stepping every 10 s: each step jumps the ripple torque at an
        // angle the record does not hold, and the mean speed keeps the swing's change.
        let n = 4000;
        let mut data = profile(n);
        let levels = [3.0, 1.0, 2.5, 0.5, 3.5, 1.5];
        let command: Vec<f64> = (0..n).map(|k| levels[(k / 200) % levels.len()]).collect();
        data.inputs.insert("command".into(), command.clone());
        let mut truth = TruthWheel::new();
        truth.effects = WheelEffects {
            torque_ripple: true,
            ..WheelEffects::none()
        };
        truth.params.torque_ripple = 300.0;
        let [i, w, _] = record(&mut truth, &command);
        data.outputs.insert("current".into(), i);
        data.outputs.insert("speed".into(), w.clone());
        let plant = WheelGapPlant;
        let mut params = plant.default_params();
        params.insert("torque_ripple".into(), 300.0);
        let rms = |sim: &Simulation| {
            let sum: f64 = (0..n).map(|k| (sim.outputs[1][k] - w[k]).powi(2)).sum();
            (sum / n as f64).sqrt()
        };
        let tracked = plant.simulate(&params, &["torque_ripple"], &data).unwrap();
        let untracked = plant.simulate(&params, &[], &data).unwrap();
        assert!(tracked.innovations && !untracked.innovations);
        let spread = tracked.variances[1].as_ref().unwrap();
        let typical = crate::gap::stats::median(spread).unwrap().sqrt();
        let (e_tracked, e_untracked) = (rms(&tracked), rms(&untracked));
        assert!(
            e_untracked > 2.0 * typical,
            "{e_untracked} vs swing {typical}"
        );
        // Tracked, what is left is the swing itself (0.0091 against 0.0085 here).
        assert!(e_tracked < 1.25 * typical, "{e_tracked} vs swing {typical}");
        // A command that moves a little every sample kicks by as little: nothing to track.
        let smooth: Vec<f64> = (0..n).map(|k| 2.0 + (0.002 * k as f64).sin()).collect();
        data.inputs.insert("command".into(), smooth);
        let sim = plant.simulate(&params, &["torque_ripple"], &data).unwrap();
        assert!(!sim.innovations);
    }

    #[test]
    fn a_crossing_kick_has_the_variance_of_the_fresnel_impulse() {
        // Through zero speed at 2 rad/s^2, theta = theta0 + a t^2 / 2: the impulse of
        // C sin(k theta) / J over the crossing, integrated finely for 64 phases, against
        // pi (C / J)^2 / (k a).
        let mut p = WheelParams::<f64>::ithaco_type_a();
        p.cogging = 1e-3;
        let (a, k) = (2.0, 0.5 * p.poles);
        let (h, span) = (1e-4, 6.0);
        let phases = 64;
        let mut sum = 0.0;
        for j in 0..phases {
            let theta0 = std::f64::consts::TAU * j as f64 / phases as f64;
            let steps = (2.0 * span / h) as usize;
            let impulse: f64 = (0..steps)
                .map(|i| {
                    let t = -span + (i as f64 + 0.5) * h;
                    (k * (theta0 + 0.5 * a * t * t)).sin()
                })
                .sum::<f64>()
                * h
                * p.cogging
                / p.inertia;
            sum += impulse * impulse;
        }
        let measured = sum / phases as f64;
        let predicted = crossing_kick(p, false, true, 0.0, a, 0.05);
        assert!(
            (measured / predicted - 1.0).abs() < 0.05,
            "{measured} vs {predicted}"
        );
    }

    #[test]
    fn ripple_keeps_its_phase_when_the_model_speed_is_off() {
        // A model whose viscous coefficient is 3 % off runs several rad/s from the truth;
        // the ripple it adds must still be the truth's (phase from the measured angle).
        let n = 3000;
        let mut data = profile(n);
        let run = |ripple: bool| {
            let mut truth = TruthWheel::new();
            truth.effects = WheelEffects {
                torque_ripple: ripple,
                ..WheelEffects::none()
            };
            truth.params.torque_ripple = 50.0;
            record(&mut truth, &data.inputs["command"])
        };
        let [_, with, angle] = run(true);
        let [_, without, _] = run(false);
        data.outputs.insert("speed".into(), with.clone());
        data.inputs.insert("angle".into(), angle);
        let plant = WheelGapPlant;
        let mut params = plant.default_params();
        params.insert("torque_ripple".into(), 50.0);
        params.insert("viscous_coefficient".into(), 1.03 * 3.84e-5);
        let on = plant.simulate(&params, &["torque_ripple"], &data).unwrap();
        let off = plant.simulate(&params, &[], &data).unwrap();
        let speed_error = off.outputs[1]
            .iter()
            .zip(&without)
            .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
        assert!(speed_error > 3.0, "the model must be off: {speed_error}");
        let (mut err, mut size) = (0.0f64, 0.0f64);
        for k in 0..n {
            let truth_ripple = with[k] - without[k];
            err = err.max((on.outputs[1][k] - off.outputs[1][k] - truth_ripple).abs());
            size = size.max(truth_ripple.abs());
        }
        assert!(size > 5e-3, "{size}");
        assert!(err < 0.05 * size, "{err} vs {size}");
    }

    #[test]
    fn the_estimator_tracks_a_viscous_coefficient_the_model_got_wrong() {
        // The model's c_v is 10 % high; with seeded noise on both readings the tracked
        // c_v must end within 1 % of the wheel's, and the speed beat its readings.
        use crate::gap::estimate::ChannelSensor;
        use prognos_core::random::standard_normal;
        use rand_core::SeedableRng;
        let n = 4000;
        let mut data = profile(n);
        let mut truth = TruthWheel::new();
        truth.effects = WheelEffects::none();
        let [i, w, _] = record(&mut truth, &data.inputs["command"]);
        let truth_viscous = truth.viscous(23.0);
        let sigma = [2e-3, 0.05];
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(21);
        let mut channels = Vec::new();
        for (c, (name, clean)) in [("current", &i), ("speed", &w)].into_iter().enumerate() {
            let y: Vec<f64> = clean
                .iter()
                .map(|v| v + sigma[c] * standard_normal::<f64, _>(&mut rng))
                .collect();
            channels.push(ChannelSensor::new(&y, sigma[c], data.dt, &[], false));
            data.outputs.insert(name.into(), y);
        }
        let mut params = WheelGapPlant.default_params();
        params.insert("viscous_coefficient".into(), 1.1 * truth_viscous);
        let est = estimate_wheel(&params, &[], &data, &Sensors { channels })
            .unwrap()
            .states;
        let c_v = est["viscous_coefficient"][n - 1];
        assert!(
            (c_v / truth_viscous - 1.0).abs() < 0.01,
            "{c_v} vs {truth_viscous}"
        );
        let rms = |a: &[f64]| {
            (a.iter().zip(&w).map(|(x, y)| (x - y).powi(2)).sum::<f64>() / n as f64).sqrt()
        };
        let (estimated, read) = (rms(&est["speed"]), rms(&data.outputs["speed"]));
        assert!(estimated < 0.5 * read, "{estimated} vs {read}");
    }
}
