//! Worked example of a user plant: a brushed DC motor driving an inertial load (not one of
//! the papers' systems). Copy this file to diagnose your own system: declare the
//! parameters, the inputs and outputs, the plant's own candidate effects, a replay, and
//! the regimes worth telling apart; then register it in
//! [`crate::gap::plant::builtin_plant`]. The generic sensor catalogue comes for free.
//!
//! Model: `L di/dt = V - R i - K w - V_b sign(i)`, `J dw/dt = K i - b w - tau_c sign(w) -
//! tau_load`. Inputs `u:voltage` (V) and optional `u:load_torque` (N m); outputs
//! `y:current` (A), `y:speed` (rad/s). Own catalogue: `coulomb_friction` (`tau_c`) and
//! `brush_drop` (`V_b`, the brush contact voltage drop); both are off in the nominal model.
//! Its estimator ([`estimate_motor`], the core's UKF on the same equations) shows how a
//! plant reports the downstream estimation error of its truth columns.

use crate::gap::estimate::{Estimates, FilterSetup, Sensors, StepModel, run_ukf};
use crate::gap::plant::{
    EffectSpec, GapPlant, ParamSpec, Params, PlantData, Regime, Scale, Simulation, motion_regimes,
    param, substeps_for,
};
use nalgebra::Vector2;
use prognos_core::model::rk4;
use std::collections::BTreeMap;

/// The DC motor example plant.
#[derive(Clone, Copy, Debug, Default)]
pub struct DcMotorPlant;

/// Parameters with defaults (a 12 V, 50 W class motor).
pub const DC_MOTOR_PARAMETERS: &[ParamSpec] = &[
    ParamSpec {
        name: "resistance",
        default: 2.0,
        doc: "armature resistance R (ohm)",
    },
    ParamSpec {
        name: "inductance",
        default: 0.01,
        doc: "armature inductance L (H)",
    },
    ParamSpec {
        name: "motor_constant",
        default: 0.05,
        doc: "torque / back-EMF constant K (N m/A = V s/rad)",
    },
    ParamSpec {
        name: "inertia",
        default: 1.0e-4,
        doc: "rotor plus load inertia J (kg m^2)",
    },
    ParamSpec {
        name: "viscous_friction",
        default: 1.0e-5,
        doc: "b (N m s/rad)",
    },
    ParamSpec {
        name: "coulomb_friction",
        default: 0.005,
        doc: "tau_c (N m), coulomb_friction",
    },
    ParamSpec {
        name: "brush_drop",
        default: 0.5,
        doc: "V_b (V), brush_drop",
    },
    ParamSpec {
        name: "sign_smoothing",
        default: 0.5,
        doc: "speed/current scale of the smooth sign (rad/s, A)",
    },
    ParamSpec {
        name: "max_step",
        default: 0.001,
        doc: "longest RK4 step (s), whatever the sample time",
    },
];

/// The motor's own catalogue.
pub fn dc_motor_effects() -> Vec<EffectSpec> {
    vec![
        EffectSpec::single(
            "coulomb_friction",
            "dry friction tau_c sign(w)",
            "coulomb_friction",
            1e-7,
            1.0,
            Scale::Log,
        ),
        EffectSpec::single(
            "brush_drop",
            "brush contact drop V_b sign(i)",
            "brush_drop",
            1e-4,
            5.0,
            Scale::Log,
        ),
    ]
}

/// The motor's equations at one parameter set.
#[derive(Clone, Copy, Debug)]
struct MotorDynamics {
    r: f64,
    l: f64,
    k: f64,
    j: f64,
    b: f64,
    tau_c: f64,
    v_b: f64,
    smooth: f64,
}

impl MotorDynamics {
    /// The parameters with `active` effects on; positive `R`, `L` and `J` required.
    fn new(params: &Params, active: &[&str]) -> Result<Self, String> {
        let g = |n: &str| param(params, n);
        let on = |effect: &str| {
            if active.contains(&effect) {
                g(effect)
            } else {
                0.0
            }
        };
        let m = Self {
            r: g("resistance"),
            l: g("inductance"),
            k: g("motor_constant"),
            j: g("inertia"),
            b: g("viscous_friction"),
            tau_c: on("coulomb_friction"),
            v_b: on("brush_drop"),
            smooth: g("sign_smoothing").max(1e-9),
        };
        if !(m.r > 0.0 && m.l > 0.0 && m.j > 0.0) {
            return Err("resistance, inductance and inertia must be positive".into());
        }
        Ok(m)
    }

    /// `(di/dt, dw/dt)` at current `i`, speed `w`, voltage `v` and load torque `tl`.
    fn derivative(&self, i: f64, w: f64, v: f64, tl: f64) -> (f64, f64) {
        let di = (v - self.r * i - self.k * w - self.v_b * (i / self.smooth).tanh()) / self.l;
        let dw = (self.k * i - self.b * w - self.tau_c * (w / self.smooth).tanh() - tl) / self.j;
        (di, dw)
    }
}

/// One replay of the motor. `extra_torque(t)` is a disturbance torque the caller adds (the
/// bench's out-of-catalogue effect; zero for the diagnosis).
pub fn simulate_motor(
    params: &Params,
    active: &[&str],
    data: &PlantData,
    substep_factor: u32,
    extra_torque: &dyn Fn(f64) -> f64,
) -> Result<Simulation, String> {
    let motor = MotorDynamics::new(params, active)?;
    let max_step = param(params, "max_step");
    let voltage = data.input("voltage").ok_or("missing u:voltage")?;
    let load = data.input("load_torque");
    let n = data.len();
    let mut w = data.first_output("speed").unwrap_or(0.0);
    let mut i = data.first_output("current").unwrap_or(0.0);
    let (mut out_i, mut out_w) = (Vec::with_capacity(n), Vec::with_capacity(n));
    let rhs = |i: f64, w: f64, v: f64, tl: f64| motor.derivative(i, w, v, tl);
    for s in 0..n {
        out_i.push(i);
        out_w.push(w);
        if s + 1 == n {
            break;
        }
        let dt = data.t[s + 1] - data.t[s];
        let substeps = substeps_for(dt, max_step) * substep_factor.max(1);
        let h = dt / substeps as f64;
        let v = voltage[s];
        for m in 0..substeps {
            let t_mid = data.t[s] + (m as f64 + 0.5) * h;
            let tl = load.map_or(0.0, |x| x[s]) + extra_torque(t_mid);
            let (a1, b1) = rhs(i, w, v, tl);
            let (a2, b2) = rhs(i + 0.5 * h * a1, w + 0.5 * h * b1, v, tl);
            let (a3, b3) = rhs(i + 0.5 * h * a2, w + 0.5 * h * b2, v, tl);
            let (a4, b4) = rhs(i + h * a3, w + h * b3, v, tl);
            i += h / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4);
            w += h / 6.0 * (b1 + 2.0 * b2 + 2.0 * b3 + b4);
        }
        if !(i.is_finite() && w.is_finite()) {
            return Err(format!("replay diverged at t = {}", data.t[s]));
        }
    }
    let mut states = BTreeMap::new();
    states.insert("current".to_string(), out_i.clone());
    states.insert("speed".to_string(), out_w.clone());
    Ok(Simulation {
        outputs: vec![out_i, out_w],
        states,
        variances: Vec::new(),
        innovations: false,
    })
}

/// The motor's estimator: the core's UKF on `[current, speed]` with the same equations,
/// trusting the model to a tenth of each sensor's noise per sample (a user plant states
/// its own estimator here; this one is the simplest that closes the loop on the readings).
pub fn estimate_motor(
    params: &Params,
    active: &[&str],
    data: &PlantData,
    sensors: &Sensors,
) -> Result<Estimates, String> {
    let motor = MotorDynamics::new(params, active)?;
    let max_step = param(params, "max_step");
    let voltage = data.input("voltage").ok_or("missing u:voltage")?;
    let load = data.input("load_torque");
    let model = StepModel {
        step: |x: &Vector2<f64>, u: &Vector2<f64>, dt: f64| {
            let rhs = |s: &Vector2<f64>| {
                let (di, dw) = motor.derivative(s[0], s[1], u[0], u[1]);
                Vector2::new(di, dw)
            };
            rk4(rhs, x, dt, substeps_for(dt, max_step))
        },
        outputs: |x: &Vector2<f64>, _: usize| *x,
    };
    let variance = |c: usize| sensors.channels.get(c).map_or(1.0, |s| s.sigma * s.sigma);
    let dt = data.dt.max(1e-12);
    let setup = FilterSetup {
        x0: Vector2::new(
            data.first_output("current").unwrap_or(0.0),
            data.first_output("speed").unwrap_or(0.0),
        ),
        p0: Vector2::new(variance(0), variance(1)),
        q_rate: Vector2::new(0.01 * variance(0) / dt, 0.01 * variance(1) / dt),
        bounds: None,
    };
    let input = |k: usize| {
        let at = |u: Option<&[f64]>| u.and_then(|u| u.get(k)).copied().unwrap_or(0.0);
        Vector2::new(at(Some(voltage)), at(load))
    };
    run_ukf::<_, _, 2, 5, 2, 2>(
        &model,
        &setup,
        &data.t,
        input,
        sensors,
        &[("current", 0), ("speed", 1)],
    )
}

impl GapPlant for DcMotorPlant {
    fn name(&self) -> &'static str {
        "dc_motor"
    }

    fn parameters(&self) -> Vec<ParamSpec> {
        DC_MOTOR_PARAMETERS.to_vec()
    }

    fn required_inputs(&self) -> Vec<&'static str> {
        vec!["voltage"]
    }

    fn optional_inputs(&self) -> Vec<(&'static str, &'static str)> {
        vec![("load_torque", "a known load on the shaft; 0 without it")]
    }

    fn outputs(&self) -> Vec<&'static str> {
        vec!["current", "speed"]
    }

    fn units(&self) -> Vec<(&'static str, &'static str)> {
        vec![
            ("u:voltage", "V"),
            ("u:load_torque", "Nm"),
            ("y:current", "A"),
            ("y:speed", "rad/s"),
        ]
    }

    fn effects(&self) -> Vec<EffectSpec> {
        dc_motor_effects()
    }

    fn simulate(
        &self,
        params: &Params,
        active: &[&str],
        data: &PlantData,
    ) -> Result<Simulation, String> {
        simulate_motor(params, active, data, 1, &|_| 0.0)
    }

    fn estimate(
        &self,
        params: &Params,
        active: &[&str],
        data: &PlantData,
        sensors: &Sensors,
    ) -> Option<Result<Estimates, String>> {
        Some(estimate_motor(params, active, data, sensors))
    }

    fn regimes(&self, data: &PlantData, nominal: &Simulation) -> Vec<Regime> {
        let (i, w) = (&nominal.outputs[0], &nominal.outputs[1]);
        let mut out = motion_regimes(&data.t, w, w, None);
        out.push(Regime::from_fn("braking", data.len(), |k| {
            i[k] * w[k] < 0.0
        }));
        out
    }
}
