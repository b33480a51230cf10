//! The electric scooter as a gap plant (Yu et al. 2020, section 2; the core's
//! `plants::scooter` equations with Table 3's nominal values).
//!
//! Input `u:voltage` (V, the motor-driver input; a row's input is the one held during the
//! step that ends at that row, as the project's scooter traces record it). Outputs
//! `y:rear_speed` (rad/s, rear encoder: `beta_theta_r omega_r`), `y:body_speed` (m/s, body
//! speed sensor: `beta_v v_m`), `y:front_speed` (rad/s, front encoder). States compared with
//! truth columns: `omega_r`, `v_m`, `omega_f`.
//!
//! Every fault is a model parameter, so the catalogue's effects are departures of those
//! from the user's values: `rear_coulomb_friction` (`rear_coulomb`, the wheel's own part
//! of the rear dry friction), `front_coulomb_friction` (`front_coulomb`),
//! `shaft_compliance` (`rear_shaft_stiffness` K1), `encoder_efficiency` (`beta_theta_r`),
//! `speed_sensor_efficiency` (`beta_v`) and `motor_resistance_drift` (`resistance_drift`
//! `d`: the driver's voltage-to-current constant becomes `N1 / (1 + d)`, as a winding whose
//! resistance grew by the factor `1 + d` draws that much less current). The two
//! efficiencies *are* sensor scales of their channels, so they replace the generic
//! `sensor_scale` there.

use crate::gap::estimate::{Estimates, FilterSetup, Sensors, StepModel, run_ukf};
use crate::gap::plant::{
    EffectSpec, GapPlant, MotionThresholds, ParamSpec, Params, PlantData, Regime, Scale,
    Simulation, motion_regimes, param, substeps_for,
};
use nalgebra::SVector;
use nalgebra::{Vector1, Vector3, Vector6};
use prognos_core::filter::adaptive_ukf::Adaptation;
use prognos_core::model::Model;
use prognos_core::model::rk4;
use prognos_core::pipeline::scooter::ScooterConfig;
use prognos_core::plants::scooter::{
    BETA_THETA_R, K1, NS as ESTIMATOR_NS, NX as ESTIMATOR_NX, OMEGA_F, OMEGA_R, R_RV, S_M,
    ScooterModel, ScooterParams, THETA_F, THETA_R, V_M,
};
use std::collections::BTreeMap;

/// The scooter gap plant.
#[derive(Clone, Copy, Debug, Default)]
pub struct ScooterGapPlant;

/// Parameters with defaults (Table 3 nominal values, ideal sensors).
pub const SCOOTER_PARAMETERS: &[ParamSpec] = &[
    ParamSpec {
        name: "drive_gain",
        default: 3.0,
        doc: "voltage-to-current constant N1 (A/V)",
    },
    ParamSpec {
        name: "torque_ratio",
        default: 0.0666,
        doc: "current-to-torque ratio N2 (N m/A)",
    },
    ParamSpec {
        name: "reduction",
        default: 1.0 / 18.0,
        doc: "reduction ratio N3",
    },
    ParamSpec {
        name: "wheel_radius",
        default: 0.115,
        doc: "N4 (m)",
    },
    ParamSpec {
        name: "motor_viscous",
        default: 1.725e-3,
        doc: "motor viscous friction (N m s/rad)",
    },
    ParamSpec {
        name: "motor_coulomb",
        default: 5.635e-2,
        doc: "motor Coulomb friction (N m)",
    },
    ParamSpec {
        name: "motor_inertia",
        default: 5.03e-4,
        doc: "J_m (kg m^2)",
    },
    ParamSpec {
        name: "mass",
        default: 20.7,
        doc: "body mass m (kg)",
    },
    ParamSpec {
        name: "rear_inertia",
        default: 4.87e-3,
        doc: "J_r (kg m^2)",
    },
    ParamSpec {
        name: "front_inertia",
        default: 6.97e-3,
        doc: "J_f (kg m^2)",
    },
    ParamSpec {
        name: "rear_viscous",
        default: 3.545e-2,
        doc: "R_rv (N m s/rad)",
    },
    ParamSpec {
        name: "rear_coulomb",
        default: 5.955e-2,
        doc: "R_rc (N m), rear_coulomb_friction",
    },
    ParamSpec {
        name: "front_viscous",
        default: 1.02e-3,
        doc: "R_fv (N m s/rad)",
    },
    ParamSpec {
        name: "front_coulomb",
        default: 1.857e-3,
        doc: "R_fc (N m), front_coulomb_friction",
    },
    ParamSpec {
        name: "rear_shaft_stiffness",
        default: 10.02,
        doc: "K1 (N m/rad), shaft_compliance",
    },
    ParamSpec {
        name: "front_shaft_stiffness",
        default: 10.07,
        doc: "K2 (N m/rad)",
    },
    ParamSpec {
        name: "sign_smoothing",
        default: 0.05,
        doc: "speed scale of the smooth sign of the Coulomb terms (rad/s)",
    },
    ParamSpec {
        name: "beta_theta_r",
        default: 1.0,
        doc: "rear encoder efficiency, encoder_efficiency",
    },
    ParamSpec {
        name: "beta_v",
        default: 1.0,
        doc: "body speed sensor efficiency, speed_sensor_efficiency",
    },
    ParamSpec {
        name: "resistance_drift",
        default: 0.0,
        doc: "relative motor resistance increase d, motor_resistance_drift",
    },
    ParamSpec {
        name: "max_step",
        default: 0.0025,
        doc: "longest RK4 step (s), whatever the sample time (the front-wheel mode is near \
              6 Hz; at 0.01 s the replay's own error exceeds the sensors' noise)",
    },
];

/// The scooter's own catalogue.
pub fn scooter_effects() -> Vec<EffectSpec> {
    let mut encoder = EffectSpec::single(
        "encoder_efficiency",
        "rear encoder reads beta_theta_r times the rear-wheel speed",
        "beta_theta_r",
        0.2,
        1.5,
        Scale::Linear,
    );
    encoder.replaces_generic = vec![("sensor_scale", "rear_speed")];
    let mut body = EffectSpec::single(
        "speed_sensor_efficiency",
        "body speed sensor reads beta_v times the body speed",
        "beta_v",
        0.2,
        1.5,
        Scale::Linear,
    );
    body.replaces_generic = vec![("sensor_scale", "body_speed")];
    vec![
        EffectSpec::single(
            "rear_coulomb_friction",
            "rear-wheel dry friction R_rc departs from the model's",
            "rear_coulomb",
            1e-4,
            10.0,
            Scale::Log,
        ),
        EffectSpec::single(
            "front_coulomb_friction",
            "front-wheel dry friction R_fc departs from the model's",
            "front_coulomb",
            1e-5,
            1.0,
            Scale::Log,
        ),
        EffectSpec::single(
            "shaft_compliance",
            "rear transmission shaft stiffness K1 departs from the model's",
            "rear_shaft_stiffness",
            0.05,
            1000.0,
            Scale::Log,
        ),
        encoder,
        body,
        EffectSpec::single(
            "motor_resistance_drift",
            "motor resistance grows by 1 + d: drive current N1 u / (1 + d)",
            "resistance_drift",
            -0.5,
            3.0,
            Scale::Linear,
        ),
    ]
}

/// The core's parameters from the gap plant's.
pub fn scooter_params(params: &Params) -> ScooterParams<f64> {
    let g = |n: &str| param(params, n);
    ScooterParams {
        n1: g("drive_gain") / (1.0 + g("resistance_drift")).max(1e-6),
        n2: g("torque_ratio"),
        n3: g("reduction"),
        n4: g("wheel_radius"),
        r_mv: g("motor_viscous"),
        r_mc: g("motor_coulomb"),
        j_m: g("motor_inertia"),
        m: g("mass"),
        j_r: g("rear_inertia"),
        j_f: g("front_inertia"),
        r_rv: g("rear_viscous"),
        r_rc: g("rear_coulomb"),
        r_fv: g("front_viscous"),
        r_fc: g("front_coulomb"),
        k1: g("rear_shaft_stiffness"),
        k2: g("front_shaft_stiffness"),
        sign_scale: g("sign_smoothing"),
    }
}

/// The core's parameters and the two sensor efficiencies, checked.
fn checked_params(params: &Params) -> Result<(ScooterParams<f64>, f64, f64), String> {
    let p = scooter_params(params);
    let positive = [p.n3, p.n4, p.m, p.j_f, p.k1, p.k2, p.rear_inertia()];
    if !positive.iter().all(|v| *v > 0.0) {
        return Err(
            "reduction, wheel radius, mass, inertias and stiffnesses must be positive".into(),
        );
    }
    let (beta_r, beta_v) = (param(params, "beta_theta_r"), param(params, "beta_v"));
    if beta_r.abs() < 1e-9 || beta_v.abs() < 1e-9 {
        return Err("sensor efficiencies must be nonzero".into());
    }
    Ok((p, beta_r, beta_v))
}

/// The state the replay (and the estimator) start from: the speeds from the first
/// readings, the shafts twisted by the torques that carry the front wheel's steady friction.
fn initial_state(
    p: &ScooterParams<f64>,
    beta_r: f64,
    beta_v: f64,
    data: &PlantData,
) -> Vector6<f64> {
    let mut x = Vector6::<f64>::zeros();
    x[OMEGA_R] = data.first_output("rear_speed").map_or(0.0, |v| v / beta_r);
    x[V_M] = data.first_output("body_speed").map_or(0.0, |v| v / beta_v);
    x[OMEGA_F] = data.first_output("front_speed").unwrap_or(x[V_M] / p.n4);
    let front_torque = p.r_fc * p.sign(x[OMEGA_F]) + p.r_fv * x[OMEGA_F];
    x[THETA_F] = -front_torque / p.k2;
    x[S_M] = 0.0;
    x[THETA_R] = front_torque / p.k1;
    x
}

/// One replay. `substep_factor` multiplies the model's sub-steps (the bench's truth runs
/// finer); `body_force(t)` is a force (N) on the body the caller adds (the bench's
/// out-of-catalogue effects; zero for the diagnosis).
pub fn simulate_scooter(
    params: &Params,
    data: &PlantData,
    substep_factor: u32,
    body_force: &dyn Fn(f64) -> f64,
) -> Result<Simulation, String> {
    let (p, beta_r, beta_v) = checked_params(params)?;
    let max_step = param(params, "max_step");
    let voltage = data.input("voltage").ok_or("missing u:voltage")?;
    let n = data.len();
    let mut x = initial_state(&p, beta_r, beta_v, data);
    let mut out: Vec<Vec<f64>> = (0..3).map(|_| Vec::with_capacity(n)).collect();
    let mut states: Vec<Vec<f64>> = (0..3).map(|_| Vec::with_capacity(n)).collect();
    for k in 0..n {
        out[0].push(beta_r * x[OMEGA_R]);
        out[1].push(beta_v * x[V_M]);
        out[2].push(x[OMEGA_F]);
        states[0].push(x[OMEGA_R]);
        states[1].push(x[V_M]);
        states[2].push(x[OMEGA_F]);
        if k + 1 == n {
            break;
        }
        let dt = data.t[k + 1] - data.t[k];
        let u = voltage[k + 1];
        let force = body_force(data.t[k] + 0.5 * dt);
        let rhs = |s: &Vector6<f64>| {
            let mut d = p.derivative(s, u, p.r_rv, p.k1);
            d[V_M] += force / p.m;
            d
        };
        x = rk4(
            rhs,
            &x,
            dt,
            substeps_for(dt, max_step) * substep_factor.max(1),
        );
        if !x.iter().all(|v| v.is_finite()) {
            return Err(format!("replay diverged at t = {}", data.t[k]));
        }
    }
    let mut named = BTreeMap::new();
    for (name, s) in ["omega_r", "v_m", "omega_f"].iter().zip(states) {
        named.insert(name.to_string(), s);
    }
    Ok(Simulation {
        outputs: out,
        states: named,
        variances: Vec::new(),
        innovations: false,
    })
}

/// Fault parameters the scooter's estimator tracks (augmented states of the core's
/// [`ScooterModel`]), by the `[model]` name a truth column `x:<name>` gives them.
pub const ESTIMATED_PARAMETERS: [(&str, usize); 3] = [
    ("beta_theta_r", BETA_THETA_R),
    ("rear_viscous", R_RV),
    ("rear_shaft_stiffness", K1),
];

/// The pipeline's bounds on the fault parameters, widened to hold the model's own values
/// with room on either side (a fitted shaft stiffness may lie below the pipeline's floor).
fn parameter_bounds(
    config: &ScooterConfig<f64>,
    x0: &SVector<f64, ESTIMATOR_NX>,
) -> (SVector<f64, ESTIMATOR_NX>, SVector<f64, ESTIMATOR_NX>) {
    let (mut lo, mut hi) = (config.adaptive.lower, config.adaptive.upper);
    for (_, i) in ESTIMATED_PARAMETERS {
        lo[i] = lo[i].min(0.5 * x0[i]);
        hi[i] = hi[i].max(2.0 * x0[i]);
    }
    (lo, hi)
}

/// The project's scooter estimator over the record: the core's [`ScooterModel`] (six
/// dynamic states and the fault parameters `beta_theta_r`, `R_rv`, `K1` of the paper's
/// AEUKF) in the core's UKF with the on-board pipeline's initial covariance and process
/// noise (its adaptation off), the model's other parameters at `params`. Estimates of
/// `omega_r`, `v_m`, `omega_f` and the three fault parameters: an unmodelled effect shows
/// as a fault parameter drifting to absorb it.
pub fn estimate_scooter(
    params: &Params,
    data: &PlantData,
    sensors: &Sensors,
) -> Result<Estimates, String> {
    let (p, beta_r, beta_v) = checked_params(params)?;
    let max_step = param(params, "max_step");
    let voltage = data.input("voltage").ok_or("missing u:voltage")?;
    let config = ScooterConfig::<f64>::new(Adaptation::Enhanced);
    let mut x0 = SVector::<f64, ESTIMATOR_NX>::zeros();
    x0.fixed_rows_mut::<6>(0)
        .copy_from(&initial_state(&p, beta_r, beta_v, data));
    x0[BETA_THETA_R] = beta_r;
    x0[R_RV] = p.r_rv;
    x0[K1] = p.k1;
    let mut p0 = config.p0;
    // The measured speeds start within their readings' noise.
    for (state, channel, scale) in [(OMEGA_R, 0, beta_r), (V_M, 1, beta_v), (OMEGA_F, 2, 1.0)] {
        if let Some(c) = sensors
            .channels
            .get(channel)
            .filter(|c| c.sigma.is_finite())
        {
            p0[state] = (c.sigma / scale.abs().max(1e-9)).powi(2).max(1e-12);
        }
    }
    let model = StepModel {
        step: |x: &SVector<f64, ESTIMATOR_NX>, u: &Vector1<f64>, dt: f64| {
            let core = ScooterModel {
                params: p,
                substeps: substeps_for(dt, max_step),
                parameter_floor: 1e-3,
            };
            Model::step(&core, x, u, dt)
        },
        outputs: |x: &SVector<f64, ESTIMATOR_NX>, _: usize| {
            Vector3::new(x[BETA_THETA_R] * x[OMEGA_R], beta_v * x[V_M], x[OMEGA_F])
        },
    };
    let setup = FilterSetup {
        x0,
        p0,
        // The pipeline's per-step variances are for its 0.02 s steps.
        q_rate: config.q0 / 0.02,
        bounds: Some(parameter_bounds(&config, &x0)),
    };
    // The replay's row convention: the step ending at row k + 1 holds row k + 1's voltage.
    let input = |k: usize| Vector1::new(voltage.get(k + 1).copied().unwrap_or(0.0));
    let mut names = vec![("omega_r", OMEGA_R), ("v_m", V_M), ("omega_f", OMEGA_F)];
    names.extend(ESTIMATED_PARAMETERS);
    run_ukf::<_, _, ESTIMATOR_NX, ESTIMATOR_NS, 1, 3>(
        &model, &setup, &data.t, input, sensors, &names,
    )
}

impl GapPlant for ScooterGapPlant {
    fn name(&self) -> &'static str {
        "scooter"
    }

    fn parameters(&self) -> Vec<ParamSpec> {
        SCOOTER_PARAMETERS.to_vec()
    }

    fn required_inputs(&self) -> Vec<&'static str> {
        vec!["voltage"]
    }

    fn outputs(&self) -> Vec<&'static str> {
        vec!["rear_speed", "body_speed", "front_speed"]
    }

    fn units(&self) -> Vec<(&'static str, &'static str)> {
        vec![
            ("u:voltage", "V"),
            ("y:rear_speed", "rad/s"),
            ("y:body_speed", "m/s"),
            ("y:front_speed", "rad/s"),
        ]
    }

    fn effects(&self) -> Vec<EffectSpec> {
        scooter_effects()
    }

    fn simulate(
        &self,
        params: &Params,
        _active: &[&str],
        data: &PlantData,
    ) -> Result<Simulation, String> {
        simulate_scooter(params, data, 1, &|_| 0.0)
    }

    fn estimate(
        &self,
        params: &Params,
        _active: &[&str],
        data: &PlantData,
        sensors: &Sensors,
    ) -> Option<Result<Estimates, String>> {
        Some(estimate_scooter(params, data, sensors))
    }

    fn regimes(&self, data: &PlantData, nominal: &Simulation) -> Vec<Regime> {
        let n = data.len();
        let body = &nominal.outputs[1];
        let speed: Vec<f64> = data
            .output("body_speed")
            .map_or_else(|| body.clone(), <[f64]>::to_vec);
        let accel = crate::gap::plant::derivative(&data.t, body);
        let th = MotionThresholds::relative(body, &accel);
        let mut out = motion_regimes(&data.t, &speed, body, Some(th));
        let voltage = data.input("voltage").unwrap_or(&[]);
        let drive = |k: usize| voltage.get(k).copied().unwrap_or(0.0);
        out.push(Regime::from_fn("braking", n, |k| drive(k) * body[k] < 0.0));
        out.push(Regime::from_fn("coasting", n, |k| drive(k) == 0.0));
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector1;
    use prognos_core::model::Model;
    use prognos_core::plants::scooter::{K1, R_RV, ScooterModel};

    fn profile(n: usize, dt: f64) -> PlantData {
        let mut d = PlantData {
            dt,
            ..Default::default()
        };
        d.t = (0..n).map(|k| k as f64 * dt).collect();
        let u = (0..n).map(|k| if k < n / 2 { 1.5 } else { -0.5 }).collect();
        d.inputs.insert("voltage".into(), u);
        d
    }

    #[test]
    fn the_replay_is_as_accurate_at_a_coarse_sample_rate() {
        // Steps of at most `max_step` whatever the sample time: at 0.04 s (twice the
        // default) the replay still agrees with a 40x finer one far below the sensor noise
        // (1e-3 rad/s on the wheels). Eight steps per sample, as before, are 1e-4 off on
        // the front wheel here, and failed a gap-bench `none` record at 0.04 s (`unknown`).
        let plant = ScooterGapPlant;
        let data = profile(750, 0.04);
        let coarse = plant.simulate(&plant.default_params(), &[], &data).unwrap();
        let mut fine = plant.default_params();
        fine.insert("max_step".into(), 0.0025 / 40.0);
        let fine = plant.simulate(&fine, &[], &data).unwrap();
        for (a, b) in coarse.outputs.iter().zip(&fine.outputs) {
            let err = a
                .iter()
                .zip(b)
                .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
            assert!(err < 1e-4, "{err}");
        }
        assert_eq!(crate::gap::plant::substeps_for(0.04, 0.0025), 16);
        assert_eq!(
            crate::gap::plant::substeps_for(0.020000000000000018, 0.0025),
            8
        );
        assert_eq!(crate::gap::plant::substeps_for(0.001, 0.0025), 1);
    }

    #[test]
    fn nominal_replay_matches_the_core_model_from_rest() {
        let (n, dt) = (1500, 0.02);
        let data = profile(n, dt);
        let model = ScooterModel::<f64>::nominal();
        let mut x = model.nominal_state();
        let mut rear = vec![x[OMEGA_R]];
        for k in 1..n {
            x = model.step(&x, &Vector1::new(data.inputs["voltage"][k]), dt);
            rear.push(x[OMEGA_R]);
        }
        assert_eq!((x[R_RV], x[K1]), (model.params.r_rv, model.params.k1));
        let plant = ScooterGapPlant;
        // The core model's own step is RK4 at 2 sub-steps; the replay's default is finer.
        let mut params = plant.default_params();
        params.insert("max_step".into(), dt / 2.0);
        let sim = plant.simulate(&params, &[], &data).unwrap();
        let err = sim.outputs[0]
            .iter()
            .zip(&rear)
            .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
        let top = rear.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        assert!(top > 3.0, "{top}");
        assert!(err < 1e-9 * top, "{err}");
    }

    #[test]
    fn each_effect_changes_the_replay_and_efficiencies_scale_their_channel() {
        let data = profile(1500, 0.02);
        let plant = ScooterGapPlant;
        let base = plant.default_params();
        let nominal = plant.simulate(&base, &[], &data).unwrap();
        for e in scooter_effects() {
            let mut p = base.clone();
            let r = &e.fit[0];
            let v = if r.scale == Scale::Log {
                (r.lo * r.hi).sqrt()
            } else {
                r.lo + 0.3 * (r.hi - r.lo)
            };
            p.insert(r.name.to_string(), v);
            let sim = plant.simulate(&p, &[e.name], &data).unwrap();
            let change: f64 = sim
                .outputs
                .iter()
                .zip(&nominal.outputs)
                .map(|(a, b)| a.iter().zip(b).map(|(x, y)| (x - y).abs()).sum::<f64>())
                .sum();
            assert!(change > 1e-3, "{} changes nothing", e.name);
        }
        let mut p = base.clone();
        p.insert("beta_theta_r".into(), 0.8);
        let sim = plant.simulate(&p, &[], &data).unwrap();
        for (a, b) in sim.outputs[0].iter().zip(&nominal.outputs[0]).skip(1) {
            assert!((a - 0.8 * b).abs() < 1e-9 * (1.0 + b.abs()));
        }
    }
}
