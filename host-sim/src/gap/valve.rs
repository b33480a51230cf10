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

use crate::gap::plant::{
    EffectSpec, GapPlant, InputTiming, ParamSpec, Params, PlantData, Regime, Scale, Side,
    Simulation, param,
};
use nalgebra::SVector;
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

/// One replay of the valve with `active` effects, plus the bench's `extras`.
pub fn simulate_valve(
    params: &Params,
    active: &[&str],
    data: &PlantData,
    extras: &TruthExtras,
) -> Result<Simulation, String> {
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
    let (pl, pr, top, bottom) = (
        input("pl")?,
        input("pr")?,
        input("top_port_supply")?,
        input("bottom_port_supply")?,
    );
    let u_at = |k: usize| -> SVector<f64, NU> {
        let supply = vp.p_supply * extras.supply_factor(data.t[k]);
        let port = |on: f64| if on >= 0.5 { supply } else { vp.p_atm };
        SVector::from([
            pl[k] + extras.inlet_offset,
            pr[k],
            port(top[k]),
            port(bottom[k]),
        ])
    };
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
    let n = data.len();
    let mut out: Vec<Vec<f64>> = (0..4).map(|_| Vec::with_capacity(n)).collect();
    let mut velocity = Vec::with_capacity(n);
    for k in 0..n {
        let o = vp.outputs(&s, &u_at(k));
        for (c, v) in out.iter_mut().zip(o) {
            c.push(v);
        }
        velocity.push(s[idx::V]);
        if k + 1 == n {
            break;
        }
        s = vp.advance(&s, &u_at(k + 1), data.t[k + 1] - data.t[k]);
        if !s.iter().all(|v| v.is_finite()) {
            return Err(format!("replay diverged at t = {}", data.t[k]));
        }
    }
    let mut states = BTreeMap::new();
    states.insert("x".to_string(), out[0].clone());
    states.insert("v".to_string(), velocity);
    Ok(Simulation {
        outputs: out,
        states,
        variances: Vec::new(),
    })
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
