//! The pneumatic valve as a gap plant (Daigle & Goebel 2011, the core's `plants::valve`
//! with progpy's constants).
//!
//! Inputs (progpy's trace format): `u:pl`, `u:pr` (Pa), `u:top_port_supply`,
//! `u:bottom_port_supply` (1 = port at supply, 0 = vented); a row's input is the one
//! applied during the step that ends at that row. Outputs: `y:x` (m), `y:pt`, `y:pb` (Pa),
//! `y:q` (m^3/s); the discrete `y:open`/`y:closed` are not replayed. The damage variables
//! are model parameters (`friction`, `spring`, the three leak areas), so the catalogue's
//! effects are departures of those from the user's values: `friction_increase`,
//! `spring_weakening`, `internal_leak`, `top_external_leak`, `bottom_external_leak`, and
//! `seal_contact` (flexible seals of stiffness `seal_stiffness` instead of hard stops), and
//! `choked_flow`: the orifices choke below the critical pressure ratio
//! `critical_pressure_ratio` (downstream/upstream, ISO 6358's `b`; the core's
//! `Choking::CriticalRatio`). The project's model chokes isentropically (the default
//! 0.5283, gamma = 1.4), so `choked_flow` is a candidate only for a user's model whose
//! orifices never choke (`critical_pressure_ratio = 0` in `[model]`): the candidate adds the
//! choked regime and fits `b`, which the isentropic nozzle puts at 0.528 and real orifices
//! lower.

use crate::gap::estimate::{Estimates, FilterSetup, Sensors, StepModel, run_ukf};
use crate::gap::plant::{
    EffectSpec, GapPlant, InputTiming, ParamSpec, Params, PlantData, Regime, Scale, Side,
    Simulation, param,
};
use nalgebra::{SVector, Vector1, Vector4};
use prognos_core::plants::valve::{Choking, Contact, Integrator, NU, NX, ValveParams, idx};
use std::collections::BTreeMap;

/// The valve gap plant.
#[derive(Clone, Copy, Debug, Default)]
pub struct ValveGapPlant;

/// The isentropic critical pressure ratio `(2 / (gamma + 1))^(gamma / (gamma - 1))` for
/// gamma = 1.4: the default `critical_pressure_ratio`, which selects the core's
/// [`Choking::Isentropic`] law exactly.
pub const ISENTROPIC_CRITICAL_RATIO: f64 = 0.528_281_787_717_174_2;

/// The orifice law for a `critical_pressure_ratio` of `b`.
pub fn choking_for(b: f64) -> Choking<f64> {
    if (b - ISENTROPIC_CRITICAL_RATIO).abs() < 1e-9 {
        Choking::Isentropic
    } else {
        Choking::CriticalRatio(b)
    }
}

/// Parameters with defaults (progpy's `PneumaticValveBase`, undamaged).
pub const VALVE_PARAMETERS: &[ParamSpec] = &[
    ParamSpec {
        name: "friction",
        default: 6000.0,
        doc: "friction coefficient r (N s/m), friction_increase",
    },
    ParamSpec {
        name: "spring",
        default: 48000.0,
        doc: "spring constant k (N/m), spring_weakening",
    },
    ParamSpec {
        name: "internal_leak_area",
        default: 0.0,
        doc: "A_i (m^2), internal_leak",
    },
    ParamSpec {
        name: "top_leak_area",
        default: 0.0,
        doc: "A_et (m^2), top_external_leak",
    },
    ParamSpec {
        name: "bottom_leak_area",
        default: 0.0,
        doc: "A_eb (m^2), bottom_external_leak",
    },
    ParamSpec {
        name: "seal_stiffness",
        default: 1.0e9,
        doc: "k_c (N/m) of the flexible seals, seal_contact",
    },
    ParamSpec {
        name: "critical_pressure_ratio",
        default: ISENTROPIC_CRITICAL_RATIO,
        doc: "downstream/upstream pressure ratio below which the orifices choke (default: \
              isentropic, 0.5283; 0: they never choke), choked_flow",
    },
    ParamSpec {
        name: "supply_pressure",
        default: 5.272_420_892_278_395e6,
        doc: "p_s (Pa)",
    },
    ParamSpec {
        name: "progpy_euler",
        default: 0.0,
        doc: "1: progpy's explicit Euler; 0: the semi-implicit scheme",
    },
];

/// The valve's own catalogue.
pub fn valve_effects() -> Vec<EffectSpec> {
    let one = |name, doc, p, lo, hi| EffectSpec::single(name, doc, p, lo, hi, Scale::Log);
    vec![
        // Named wear: friction grows and the spring weakens with spring work (the
        // valve paper's damage modes), so each is fitted on its own side of the model's
        // value; a "weakening" to a stiffer spring explains nothing physical.
        one(
            "friction_increase",
            "friction coefficient r rises above the model's",
            "friction",
            1.0e3,
            1.0e5,
        )
        .toward(Side::AboveModel),
        one(
            "spring_weakening",
            "spring constant k falls below the model's",
            "spring",
            1.0e3,
            1.0e5,
        )
        .toward(Side::BelowModel),
        one(
            "internal_leak",
            "leak across the piston, area A_i",
            "internal_leak_area",
            1e-10,
            1e-4,
        ),
        one(
            "top_external_leak",
            "leak from the top chamber, area A_et",
            "top_leak_area",
            1e-10,
            1e-4,
        ),
        one(
            "bottom_external_leak",
            "leak from the bottom chamber, area A_eb",
            "bottom_leak_area",
            1e-10,
            1e-4,
        ),
        one(
            "seal_contact",
            "flexible end seals of stiffness k_c instead of hard stops",
            "seal_stiffness",
            1e6,
            1e11,
        ),
        EffectSpec::single(
            "choked_flow",
            "the orifices choke below a critical pressure ratio b (the model's never choke)",
            "critical_pressure_ratio",
            0.01,
            0.95,
            Scale::Log,
        ),
    ]
}

/// Whether a model with these parameters already chokes (then `choked_flow` is no
/// candidate).
pub fn model_chokes(params: &Params) -> bool {
    let b = param(params, "critical_pressure_ratio");
    b > 0.0 && b < 1.0
}

/// What the bench's truth adds to a replay (all off by default): finer steps and two
/// departures outside the catalogue.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TruthExtras {
    /// Divides the largest internal step.
    pub substep_factor: u32,
    /// From this time on (s) ...
    pub supply_drop_from: f64,
    /// ... the supply pressure is this fraction lower.
    pub supply_drop: f64,
    /// The true inlet pressure exceeds the recorded `u:pl` by this (Pa).
    pub inlet_offset: f64,
}

impl Default for TruthExtras {
    fn default() -> Self {
        Self {
            substep_factor: 1,
            supply_drop_from: f64::INFINITY,
            supply_drop: 0.0,
            inlet_offset: 0.0,
        }
    }
}

impl TruthExtras {
    fn supply_factor(&self, t: f64) -> f64 {
        if t >= self.supply_drop_from {
            1.0 - self.supply_drop
        } else {
            1.0
        }
    }
}

/// What a valve replay reads: the model's parameters with `active` effects on, the
/// record's inputs and the bench's `extras`.
struct ValveRecord<'a> {
    vp: ValveParams<f64>,
    t: &'a [f64],
    pl: &'a [f64],
    pr: &'a [f64],
    top: &'a [f64],
    bottom: &'a [f64],
    extras: &'a TruthExtras,
}

impl<'a> ValveRecord<'a> {
    fn new(
        params: &Params,
        active: &[&str],
        data: &'a PlantData,
        extras: &'a TruthExtras,
    ) -> Result<Self, String> {
        let g = |n: &str| param(params, n);
        let mut vp = ValveParams::<f64>::progpy();
        vp.max_substep /= f64::from(extras.substep_factor.max(1));
        vp.p_supply = g("supply_pressure");
        vp.choking = choking_for(g("critical_pressure_ratio"));
        vp.integrator = if g("progpy_euler") >= 0.5 {
            Integrator::ProgpyEuler
        } else {
            Integrator::SemiImplicit
        };
        if active.contains(&"seal_contact") {
            vp.contact = Contact::Seal {
                k_c: g("seal_stiffness"),
            };
        }
        let input = |name: &str| data.input(name).ok_or(format!("missing u:{name}"));
        Ok(Self {
            vp,
            t: &data.t,
            pl: input("pl")?,
            pr: input("pr")?,
            top: input("top_port_supply")?,
            bottom: input("bottom_port_supply")?,
            extras,
        })
    }

    /// The input of row `k`: the one acting over the step that ends there.
    fn input(&self, k: usize) -> SVector<f64, NU> {
        let vp = &self.vp;
        let supply = vp.p_supply * self.extras.supply_factor(self.t[k]);
        let port = |on: f64| if on >= 0.5 { supply } else { vp.p_atm };
        SVector::from([
            self.pl[k] + self.extras.inlet_offset,
            self.pr[k],
            port(self.top[k]),
            port(self.bottom[k]),
        ])
    }

    /// The state at the first sample: the measured position and pressures (supply above,
    /// atmosphere below without them), the damage at the model's values.
    fn initial_state(&self, params: &Params, data: &PlantData) -> SVector<f64, NX> {
        let g = |n: &str| param(params, n);
        let vp = &self.vp;
        let x0 = data.first_output("x").unwrap_or(0.0).clamp(0.0, vp.l_s);
        let pt0 = data.first_output("pt").unwrap_or(vp.p_supply);
        let pb0 = data.first_output("pb").unwrap_or(vp.p_atm);
        let mut s = SVector::<f64, NX>::zeros();
        s[idx::X] = x0;
        s[idx::M_TOP] = vp.mass_top_for(x0, pt0);
        s[idx::M_BOT] = vp.mass_bottom_for(x0, pb0);
        s[idx::R] = g("friction");
        s[idx::K] = g("spring");
        s[idx::A_I] = g("internal_leak_area");
        s[idx::A_ET] = g("top_leak_area");
        s[idx::A_EB] = g("bottom_leak_area");
        s
    }
}

/// One replay of the valve with `active` effects, plus the bench's `extras`.
pub fn simulate_valve(
    params: &Params,
    active: &[&str],
    data: &PlantData,
    extras: &TruthExtras,
) -> Result<Simulation, String> {
    let rec = ValveRecord::new(params, active, data, extras)?;
    let mut s = rec.initial_state(params, data);
    let n = data.len();
    let mut out: Vec<Vec<f64>> = (0..4).map(|_| Vec::with_capacity(n)).collect();
    let (mut velocity, mut m_top, mut m_bot) = (
        Vec::with_capacity(n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
    );
    for k in 0..n {
        let o = rec.vp.outputs(&s, &rec.input(k));
        for (c, v) in out.iter_mut().zip(o) {
            c.push(v);
        }
        velocity.push(s[idx::V]);
        m_top.push(s[idx::M_TOP]);
        m_bot.push(s[idx::M_BOT]);
        if k + 1 == n {
            break;
        }
        s = rec
            .vp
            .advance(&s, &rec.input(k + 1), data.t[k + 1] - data.t[k]);
        if !s.iter().all(|v| v.is_finite()) {
            return Err(format!("replay diverged at t = {}", data.t[k]));
        }
    }
    let mut states = BTreeMap::new();
    states.insert("x".to_string(), out[0].clone());
    states.insert("v".to_string(), velocity);
    states.insert("m_top".to_string(), m_top);
    states.insert("m_bot".to_string(), m_bot);
    Ok(Simulation {
        outputs: out,
        states,
        variances: Vec::new(),
        innovations: false,
    })
}

/// The damage the valve's estimator tracks: its state name (progpy's, as the reference
/// traces' truth columns `x:r`, `x:k` spell it) and the model parameter it starts from.
pub const ESTIMATED_DAMAGE: [(&str, &str); 2] = [("r", "friction"), ("k", "spring")];

/// The valve's estimator: the core's UKF on the valve's position, velocity and gas masses
/// with the sliding damage of the valve paper (friction `r`, spring `k`) tracked as random
/// walks, the leak areas at the model's values. Estimates of `x`, `v`, `m_top`, `m_bot`,
/// `r` and `k` (the truth columns of progpy's traces): an unmodelled effect shows as the
/// damage drifting to absorb it.
pub fn estimate_valve(
    params: &Params,
    active: &[&str],
    data: &PlantData,
    sensors: &Sensors,
) -> Result<Estimates, String> {
    /// Estimated: position, velocity, both gas masses, friction, spring.
    const EST: [usize; 6] = [idx::X, idx::V, idx::M_TOP, idx::M_BOT, idx::R, idx::K];
    let extras = TruthExtras::default();
    let mut rec = ValveRecord::new(params, active, data, &extras)?;
    // Always the semi-implicit step: progpy's explicit Euler is stable only while
    // r h / m < 2 (1.8 at r = 9000 and its 0.01 s step), and sigma points with a larger
    // friction would oscillate without bound.
    rec.vp.integrator = Integrator::SemiImplicit;
    let full0 = rec.initial_state(params, data);
    let vp = &rec.vp;
    let hard_stops = vp.contact == Contact::HardStops;
    let to_full = |z: &SVector<f64, 6>| {
        let mut s = full0;
        for (i, &j) in EST.iter().enumerate() {
            s[j] = z[i];
        }
        // Sigma points stay physical: inside the stroke (hard stops; a seal yields),
        // positive gas and damage.
        if hard_stops {
            s[idx::X] = s[idx::X].clamp(0.0, vp.l_s);
        }
        for j in [idx::M_TOP, idx::M_BOT, idx::R, idx::K] {
            s[j] = s[j].max(1e-3 * full0[j].abs().max(1e-12));
        }
        s
    };
    let from_full = |s: &SVector<f64, NX>| SVector::<f64, 6>::from_fn(|i, _| s[EST[i]]);
    let model = StepModel {
        // The input is the sample index the step ends at (the row's input acts over it).
        step: |z: &SVector<f64, 6>, u: &Vector1<f64>, dt: f64| {
            let k = u[0] as usize;
            from_full(&vp.advance(&to_full(z), &rec.input(k), dt))
        },
        outputs: |z: &SVector<f64, 6>, k: usize| {
            let o = vp.outputs(&to_full(z), &rec.input(k));
            Vector4::new(o[0], o[1], o[2], o[3])
        },
    };
    let sigma = |c: usize| {
        sensors
            .channels
            .get(c)
            .map(|s| s.sigma)
            .filter(|s| s.is_finite() && *s > 0.0)
    };
    let x0 = from_full(&full0);
    // A gas mass is as uncertain as its chamber's pressure reading (1 kPa without one).
    let x = full0[idx::X];
    let dp = |c: usize| sigma(c).unwrap_or(1e3);
    let top_sd =
        vp.mass_top_for(x, vp.pressure_top(x, full0[idx::M_TOP]) + dp(1)) - full0[idx::M_TOP];
    let bottom_sd =
        vp.mass_bottom_for(x, vp.pressure_bottom(x, full0[idx::M_BOT]) + dp(2)) - full0[idx::M_BOT];
    let sd0 = SVector::<f64, 6>::from([
        sigma(0).unwrap_or(1e-4),
        1e-3,
        top_sd.abs().max(1e-12),
        bottom_sd.abs().max(1e-12),
        0.1 * x0[4].abs(),
        0.1 * x0[5].abs(),
    ]);
    let dt = data.dt.max(1e-12);
    let sd_per_sample =
        SVector::<f64, 6>::from([0.1 * sd0[0], 1e-4, 0.1 * sd0[2], 0.1 * sd0[3], 0.0, 0.0]);
    // The model is trusted to a tenth of each reading's noise per sample; the damage may
    // move by 1 % in 10 s.
    let mut q_rate = sd_per_sample.component_mul(&sd_per_sample) / dt;
    q_rate[4] = (0.01 * x0[4]).powi(2) / 10.0;
    q_rate[5] = (0.01 * x0[5]).powi(2) / 10.0;
    let mut lo = SVector::<f64, 6>::repeat(f64::NEG_INFINITY);
    let mut hi = SVector::<f64, 6>::repeat(f64::INFINITY);
    if hard_stops {
        (lo[0], hi[0]) = (0.0, vp.l_s);
    }
    for i in 2..6 {
        lo[i] = 1e-3 * x0[i].abs();
        hi[i] = 100.0 * x0[i].abs().max(1e-12);
    }
    let setup = FilterSetup {
        x0,
        p0: sd0.component_mul(&sd0),
        q_rate,
        bounds: Some((lo, hi)),
    };
    let names = [
        ("x", 0),
        ("v", 1),
        ("m_top", 2),
        ("m_bot", 3),
        (ESTIMATED_DAMAGE[0].0, 4),
        (ESTIMATED_DAMAGE[1].0, 5),
    ];
    run_ukf::<_, _, 6, 13, 1, 4>(
        &model,
        &setup,
        &data.t,
        |k| Vector1::new((k + 1) as f64),
        sensors,
        &names,
    )
}

impl GapPlant for ValveGapPlant {
    fn name(&self) -> &'static str {
        "valve"
    }

    fn parameters(&self) -> Vec<ParamSpec> {
        VALVE_PARAMETERS.to_vec()
    }

    fn required_inputs(&self) -> Vec<&'static str> {
        vec!["pl", "pr", "top_port_supply", "bottom_port_supply"]
    }

    fn outputs(&self) -> Vec<&'static str> {
        vec!["x", "pt", "pb", "q"]
    }

    fn native_timing(&self) -> InputTiming {
        // progpy's simulate_to saves with each time the input that acted over the step
        // ending at it; the replay reads it so.
        InputTiming::After
    }

    fn units(&self) -> Vec<(&'static str, &'static str)> {
        vec![
            ("u:pl", "Pa"),
            ("u:pr", "Pa"),
            ("u:top_port_supply", "1"),
            ("u:bottom_port_supply", "1"),
            ("y:x", "m"),
            ("y:pt", "Pa"),
            ("y:pb", "Pa"),
            ("y:q", "m^3/s"),
        ]
    }

    fn effects(&self) -> Vec<EffectSpec> {
        valve_effects()
    }

    fn model_effects(&self, params: &Params) -> Vec<&'static str> {
        if model_chokes(params) {
            vec!["choked_flow"]
        } else {
            Vec::new()
        }
    }

    fn simulate(
        &self,
        params: &Params,
        active: &[&str],
        data: &PlantData,
    ) -> Result<Simulation, String> {
        simulate_valve(params, active, data, &TruthExtras::default())
    }

    fn estimate(
        &self,
        params: &Params,
        active: &[&str],
        data: &PlantData,
        sensors: &Sensors,
    ) -> Option<Result<Estimates, String>> {
        Some(estimate_valve(params, active, data, sensors))
    }

    fn regimes(&self, data: &PlantData, nominal: &Simulation) -> Vec<Regime> {
        let n = data.len();
        let x = &nominal.outputs[0];
        let l_s = 0.0381;
        let open_cmd = data
            .input("bottom_port_supply")
            .map_or(vec![false; n], |b| b.iter().map(|v| *v >= 0.5).collect());
        let v = nominal
            .states
            .get("v")
            .cloned()
            .unwrap_or_else(|| vec![0.0; n]);
        vec![
            Regime::from_fn("opening", n, |k| open_cmd[k] && x[k] < l_s - 1e-3),
            Regime::from_fn("closing", n, |k| !open_cmd[k] && x[k] > 1e-3),
            Regime::from_fn("open", n, |k| x[k] >= l_s - 1e-3),
            Regime::from_fn("closed", n, |k| x[k] <= 1e-3),
            Regime::from_fn("moving", n, |k| v[k].abs() > 1e-4),
            Regime::from_fn("open_command", n, |k| open_cmd[k]),
            Regime::from_fn("close_command", n, |k| !open_cmd[k]),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gap::estimate::ChannelSensor;
    use prognos_core::random::standard_normal;
    use rand_core::SeedableRng;

    /// A valve cycled open and shut every 4 s for 60 s at 20 Hz, its readings from a
    /// truth valve with `friction`, with seeded noise of the bench's levels.
    fn cycled(friction: f64, seed: u64) -> (PlantData, BTreeMap<String, Vec<f64>>, Sensors) {
        let dt = 0.05;
        let n = 1200;
        let mut data = PlantData {
            dt,
            ..Default::default()
        };
        data.t = (0..n).map(|k| k as f64 * dt).collect();
        let open: Vec<f64> = (0..n)
            .map(|k| f64::from(k >= 40 && (k / 80) % 2 == 0))
            .collect();
        data.inputs.insert("pl".into(), vec![3.5e5; n]);
        data.inputs.insert("pr".into(), vec![1.5e5; n]);
        data.inputs.insert(
            "top_port_supply".into(),
            open.iter().map(|o| 1.0 - o).collect(),
        );
        data.inputs.insert("bottom_port_supply".into(), open);
        let mut truth_params = ValveGapPlant.default_params();
        truth_params.insert("friction".into(), friction);
        let truth = simulate_valve(&truth_params, &[], &data, &TruthExtras::default()).unwrap();
        let sigma = [1e-4, 5e3, 5e3, 5e-3];
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(seed);
        let mut channels = Vec::new();
        for (c, name) in ["x", "pt", "pb", "q"].into_iter().enumerate() {
            let y: Vec<f64> = truth.outputs[c]
                .iter()
                .map(|v| v + sigma[c] * standard_normal::<f64, _>(&mut rng))
                .collect();
            channels.push(ChannelSensor::new(&y, sigma[c], dt, &[], false));
            data.outputs.insert(name.into(), y);
        }
        (data, truth.states, Sensors { channels })
    }

    fn rms_error(a: &[f64], b: &[f64]) -> f64 {
        (a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>() / a.len() as f64).sqrt()
    }

    #[test]
    fn the_estimator_finds_a_friction_the_model_got_wrong() {
        // The model says 6000 N s/m; the valve has 9000. By the record's end the tracked
        // friction must be within 2 % of it, and the position within its noise.
        let (data, truth, sensors) = cycled(9000.0, 11);
        let params = ValveGapPlant.default_params();
        let est = estimate_valve(&params, &[], &data, &sensors)
            .unwrap()
            .states;
        let friction = est["r"].last().copied().unwrap();
        assert!((friction - 9000.0).abs() < 0.02 * 9000.0, "{friction}");
        let x_error = rms_error(&est["x"], &truth["x"]);
        assert!(x_error < 1e-4, "{x_error}");
    }

    #[test]
    fn with_the_right_model_the_estimate_beats_the_readings() {
        let (data, truth, sensors) = cycled(6000.0, 12);
        let params = ValveGapPlant.default_params();
        let run = estimate_valve(&params, &[], &data, &sensors).unwrap();
        // A consistent filter: every channel's standardised innovations near unit variance.
        for (c, z) in run.innovations.iter().enumerate() {
            let nis = z.iter().map(|v| v * v).sum::<f64>() / z.len() as f64;
            assert!((0.8..1.25).contains(&nis), "channel {c}: {nis}");
        }
        let est = run.states;
        let x_error = rms_error(&est["x"], &truth["x"]);
        let reading_error = rms_error(&data.outputs["x"], &truth["x"]);
        assert!(
            x_error < 0.3 * reading_error,
            "{x_error} vs {reading_error}"
        );
        let friction = est["r"].last().copied().unwrap();
        assert!((friction - 6000.0).abs() < 0.02 * 6000.0, "{friction}");
    }
}
