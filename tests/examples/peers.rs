//! The Rust side of `bench/peers.sh` (our estimators against progpy 1.9.0 and filterpy 1.4.5
//! on the same machine, in the same invocation). Writes into `--out DIR`:
//!
//! - `valve_measurements.csv`: the noisy valve samples both particle filters process (truth
//!   at a 2 ms step, progpy's default state: external leaks of 1e-5 m^2, open command at 0);
//! - `rust.json`: our timings and results: PF step at N = 500 (dt = 0.01 s, one model step per
//!   filter step, no quiescent shortcut), prediction to EOL of 100 samples (spring
//!   wear, dt = 0.01 s, full physics), UKF step on filterpy's drag-radar reference, and the
//!   valve's opening/closing times at dt = 0.01 s and at a fine-dt reference.
//!
//! Run: `cargo run --release -p prognos-tests --example peers -- --out bench/out`
//! (`--steps`, `--reps` change the work; the defaults are what docs/results.md reports).

use nalgebra::{Matrix2, Matrix4, SVector, Vector2, Vector4};
use prognos_core::filter::particle::{ParticleFilter, PfConfig};
use prognos_core::filter::ukf::{SigmaParams, Ukf};
use prognos_core::plants::valve::{
    CycleTiming, Integrator, MeasurementSet, PROGPY_LIMITS, ProcessNoise, Requirements,
    SensorNoise, Valve, ValveParams, idx, simulate_cycle,
};
use prognos_core::prognose::{PredictionSettings, predict_eol};
use prognos_core::random::standard_normal;
use prognos_tests::drag_radar::DragRadar;
use prognos_tests::reference::{Table, read_settings, reference_path};
use rand_core::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;
use serde_json::json;
use std::fmt::Write as _;
use std::path::PathBuf;
use std::time::Instant;

/// Particle count of the comparison (as the valve paper and the progpy measurement).
const PARTICLES: usize = 500;
/// Filter and prediction time step [s]: one model step per filter step on both sides.
const DT: f64 = 0.01;
/// Prediction samples.
const SAMPLES: usize = 100;
/// Spring wear of the prediction [1/m^2] and the initial spring constants: sample `j` starts
/// with `k_min + (k_nominal - k_min) (MARGIN_LOW + (1 - MARGIN_LOW) (j + 0.5) / SAMPLES)`, so
/// the samples reach progpy's `kMin` after about one to three cycles.
pub const WEAR_SPRING: f64 = 4.0;
pub const MARGIN_LOW: f64 = 0.3;
pub const K_NOMINAL: f64 = 48000.0;
/// Fluid pressures [Pa] and cycle period [s] (open command for the first half).
const FLUID: [f64; 2] = [3.5e5, 2.0e5];
const PERIOD: f64 = 30.0;

struct Args {
    out: PathBuf,
    steps: usize,
    reps: usize,
}

fn parse_args() -> Args {
    let mut args = Args {
        out: PathBuf::from("bench/out"),
        steps: 200,
        reps: 20,
    };
    let mut it = std::env::args().skip(1);
    while let Some(a) = it.next() {
        let value = it.next().unwrap_or_else(|| panic!("{a} needs a value"));
        match a.as_str() {
            "--out" => args.out = PathBuf::from(value),
            "--steps" => args.steps = value.parse().expect("--steps: a count"),
            "--reps" => args.reps = value.parse().expect("--reps: a count"),
            other => panic!("unknown argument {other}"),
        }
    }
    args
}

/// progpy's default initial state (closed, at rest, external leaks 1e-5 m^2) in our layout,
/// with the given internal leak area and wear.
fn progpy_default_state(params: &ValveParams<f64>, a_i: f64, wear: [f64; 5]) -> SVector<f64, 14> {
    let mut x = params.nominal_state(6000.0, 48000.0, wear);
    x[idx::A_ET] = 1e-5;
    x[idx::A_EB] = 1e-5;
    x[idx::A_I] = a_i;
    x
}

fn command(params: &ValveParams<f64>, t: f64) -> SVector<f64, 4> {
    params.command_input(t.rem_euclid(PERIOD) < PERIOD / 2.0, FLUID[0], FLUID[1])
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        f64::NAN
    } else if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Our valve physics with progpy's constants: semi-implicit, one sub-step per `dt`, no
/// quiescent fast-forward (the like-for-like setting).
fn filter_params(dt: f64) -> ValveParams<f64> {
    ValveParams {
        max_substep: dt,
        ..ValveParams::progpy_stable()
    }
}

struct ValveSamples {
    csv: String,
    inputs: Vec<SVector<f64, 4>>,
    measurements: Vec<[f64; 4]>,
    truth_x: Vec<f64>,
}

fn valve_samples(steps: usize) -> ValveSamples {
    let truth_params = ValveParams {
        max_substep: 0.002,
        ..ValveParams::progpy_stable()
    };
    let noise = SensorNoise::<f64>::default();
    let mut state = progpy_default_state(&truth_params, 0.0, [0.0; 5]);
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(2026);
    let mut csv = String::from("k,t,pL,pR,uTop,uBot,x,Q,pT,pB,iB,iT,truth_x\n");
    let (mut inputs, mut measurements, mut truth_x) = (Vec::new(), Vec::new(), Vec::new());
    for k in 0..steps {
        let t = (k + 1) as f64 * DT;
        let u = command(&truth_params, k as f64 * DT);
        state = truth_params.advance(&state, &u, DT);
        let [x, p_t, p_b, f, open, closed] = truth_params.outputs(&state, &u);
        let mut g = |s: f64| s * standard_normal::<f64, _>(&mut rng);
        let y = [
            x + g(noise.x),
            f + g(noise.f),
            p_t + g(noise.p),
            p_b + g(noise.p),
        ];
        let top_supply = u[2] > u[3];
        let _ = writeln!(
            csv,
            "{k},{t:?},{:?},{:?},{},{},{:?},{:?},{:?},{:?},{},{},{:?}",
            u[0],
            u[1],
            u8::from(top_supply),
            u8::from(!top_supply),
            y[0],
            y[1],
            y[2],
            y[3],
            closed,
            open,
            state[idx::X]
        );
        inputs.push(u);
        measurements.push(y);
        truth_x.push(state[idx::X]);
    }
    ValveSamples {
        csv,
        inputs,
        measurements,
        truth_x,
    }
}

/// Filter noise assumed by both filters: position 1 mm, flow 0.03 m^3/s, pressures 30 kPa.
fn filter_noise() -> SensorNoise<f64> {
    SensorNoise {
        x: 1e-3,
        f: 3e-2,
        p: 3e4,
        discrete: 0.3,
    }
}

struct PfResult {
    step_seconds: f64,
    position_rmse: f64,
    final_mean_x: f64,
}

fn run_pf(samples: &ValveSamples, reps: usize) -> PfResult {
    let params = filter_params(DT);
    let model = Valve {
        params,
        measurements: MeasurementSet::All,
        sensor_noise: filter_noise(),
        // Velocity noise only (1e-3 m/s per step while moving), which progpy's additive
        // `dt * N(0, 0.1)` on `v` matches; gas-mass noise has no common form (ours is relative).
        process_noise: ProcessNoise {
            v: 0.01,
            ..ProcessNoise::default()
        },
    };
    let x0 = progpy_default_state(&params, 0.0, [0.0; 5]);
    let mut lower = SVector::<f64, 14>::repeat(-f64::MAX);
    for i in idx::M_TOP..=idx::A_EB {
        lower[i] = 0.0;
    }
    let config = PfConfig {
        lower,
        ..PfConfig::default()
    };
    let fresh = Box::new(ParticleFilter::<f64, 14, PARTICLES>::new(x0, config).expect("config"));
    let mut per_step = Vec::new();
    let mut result = PfResult {
        step_seconds: f64::NAN,
        position_rmse: f64::NAN,
        final_mean_x: f64::NAN,
    };
    for rep in 0..reps.max(1) {
        let mut pf = fresh.clone();
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(7 + rep as u64);
        let mut sq = 0.0;
        let start = Instant::now();
        for ((u, y), truth) in samples
            .inputs
            .iter()
            .zip(&samples.measurements)
            .zip(&samples.truth_x)
        {
            let _ = pf.step(&model, u, Some(&y[..]), DT, &mut rng);
            if rep == 0 {
                let e = pf.mean()[idx::X] - truth;
                sq += e * e;
            }
        }
        per_step.push(start.elapsed().as_secs_f64() / samples.inputs.len() as f64);
        if rep == 0 {
            result.position_rmse = (sq / samples.inputs.len() as f64).sqrt();
            result.final_mean_x = pf.mean()[idx::X];
        }
    }
    result.step_seconds = median(per_step);
    result
}

struct PredictionResult {
    seconds: f64,
    eol: Vec<f64>,
    /// `(sample, EOL)` at the fine reference step for every fifth sample.
    reference: Vec<(usize, f64)>,
}

/// Fine step of the EOL reference [s].
const REFERENCE_DT: f64 = 1e-4;

/// Initial spring constant of prediction sample `j` (the same formula in `bench/peers.py`).
fn initial_spring(j: usize) -> f64 {
    let k_min = PROGPY_LIMITS.k_min;
    let fraction = MARGIN_LOW + (1.0 - MARGIN_LOW) * (j as f64 + 0.5) / SAMPLES as f64;
    k_min + (K_NOMINAL - k_min) * fraction
}

fn run_prediction(reps: usize) -> PredictionResult {
    let params = filter_params(DT);
    let model = Valve::new(params, MeasurementSet::All);
    let states: Vec<SVector<f64, 14>> = (0..SAMPLES)
        .map(|j| {
            let mut x = progpy_default_state(&params, 0.0, [0.0, WEAR_SPRING, 0.0, 0.0, 0.0]);
            x[idx::K] = initial_spring(j);
            x
        })
        .collect();
    let settings = PredictionSettings::deterministic(DT, 40_000);
    let mut eol = vec![0.0; SAMPLES];
    let mut times = Vec::new();
    for _ in 0..reps.max(1) {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(0);
        let start = Instant::now();
        predict_eol(
            &model,
            &PROGPY_LIMITS,
            &states,
            |k| command(&params, f64::from(k) * DT),
            &settings,
            &mut rng,
            &mut eol,
        )
        .expect("samples reach EOL");
        times.push(start.elapsed().as_secs_f64());
    }
    // Reference EOL: the same physics at a 100 times finer step.
    let fine = filter_params(REFERENCE_DT);
    let fine_model = Valve::new(fine, MeasurementSet::All);
    let fine_settings = PredictionSettings::deterministic(REFERENCE_DT, 2_000_000);
    let picked: Vec<usize> = (0..SAMPLES).step_by(5).collect();
    let fine_states: Vec<SVector<f64, 14>> = picked.iter().map(|&j| states[j]).collect();
    let mut fine_eol = vec![0.0; fine_states.len()];
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(0);
    predict_eol(
        &fine_model,
        &PROGPY_LIMITS,
        &fine_states,
        |k| command(&fine, f64::from(k) * REFERENCE_DT),
        &fine_settings,
        &mut rng,
        &mut fine_eol,
    )
    .expect("reference samples reach EOL");
    PredictionResult {
        seconds: median(times),
        eol,
        reference: picked.into_iter().zip(fine_eol).collect(),
    }
}

struct UkfResult {
    step_seconds: f64,
    final_state: Vector4<f64>,
}

fn run_ukf(reps: usize) -> UkfResult {
    let setup = read_settings(&reference_path("filterpy_ukf_setup.csv"));
    let table = Table::read(&reference_path("filterpy_ukf_reference.csv"));
    let get = |n: &str| setup[n];
    let model = DragRadar { drag: get("drag") };
    let params = SigmaParams {
        alpha: get("alpha"),
        beta: get("beta"),
        kappa: get("kappa"),
    };
    let x0 = Vector4::from_fn(|i, _| get(&format!("x0_{i}")));
    let p0 = Matrix4::from_fn(|i, j| get(&format!("p0_{i}{j}")));
    let q = Matrix4::from_fn(|i, j| get(&format!("q_{i}{j}")));
    let r = Matrix2::from_fn(|i, j| get(&format!("r_{i}{j}")));
    let rows: Vec<(Vector2<f64>, [f64; 2], f64)> = table
        .rows
        .iter()
        .map(|row| {
            let c = |n: &str| row[table.column(n)];
            (Vector2::new(c("u0"), c("u1")), [c("z0"), c("z1")], c("dt"))
        })
        .collect();
    let fresh = Ukf::<f64, 4, 9>::new(x0, p0, q, params).expect("valid filter");
    let mut per_step = Vec::new();
    let mut final_state = x0;
    for _ in 0..reps.max(1) * 10 {
        let mut ukf = fresh.clone();
        let start = Instant::now();
        for (u, z, dt) in &rows {
            ukf.predict(&model, u, *dt).expect("predict");
            ukf.update(&model, u, z, &r).expect("update");
        }
        per_step.push(start.elapsed().as_secs_f64() / rows.len() as f64);
        final_state = *ukf.state();
    }
    UkfResult {
        step_seconds: median(per_step),
        final_state,
    }
}

fn timing(params: &ValveParams<f64>, dt: f64, a_e: f64) -> CycleTiming<f64> {
    let params = ValveParams {
        max_substep: dt,
        ..*params
    };
    let req = Requirements {
        dt,
        ..Requirements::default()
    };
    let mut s = progpy_default_state(&params, 0.0, [0.0; 5]);
    s[idx::A_ET] = a_e;
    s[idx::A_EB] = a_e;
    simulate_cycle(&params, &req, &s).0
}

fn main() {
    let args = parse_args();
    std::fs::create_dir_all(&args.out).expect("output folder");
    let samples = valve_samples(args.steps);
    std::fs::write(args.out.join("valve_measurements.csv"), &samples.csv).expect("write csv");

    let pf = run_pf(&samples, args.reps);
    let prediction = run_prediction(3);
    let ukf = run_ukf(args.reps);

    let semi = ValveParams::progpy_stable();
    let euler = ValveParams {
        integrator: Integrator::ProgpyEuler,
        ..semi
    };
    let mut timings = Vec::new();
    for (case, a_e) in [("progpy default state", 1e-5), ("leak-free", 0.0)] {
        for (name, params, dt) in [
            ("ours (semi-implicit), dt 0.01", &semi, 0.01),
            ("progpy's Euler in Rust, dt 0.01", &euler, 0.01),
            ("reference: semi-implicit, dt 1e-5", &semi, 1e-5),
            ("reference: progpy's Euler, dt 1e-5", &euler, 1e-5),
        ] {
            let t = timing(params, dt, a_e);
            timings.push(json!({
                "case": case, "model": name, "dt": dt,
                "open_s": t.t_open, "close_s": t.t_close,
            }));
        }
    }
    let reached: Vec<f64> = prediction
        .eol
        .iter()
        .copied()
        .filter(|t| *t < 1e300)
        .collect();
    let out = json!({
        "particles": PARTICLES,
        "dt": DT,
        "pf": {
            "steps": samples.inputs.len(),
            "step_seconds": pf.step_seconds,
            "position_rmse_m": pf.position_rmse,
            "final_mean_x_m": pf.final_mean_x,
            "final_truth_x_m": samples.truth_x.last(),
        },
        "prediction": {
            "samples": SAMPLES,
            "wear_spring": WEAR_SPRING,
            "margin_low": MARGIN_LOW,
            "k_nominal": K_NOMINAL,
            "seconds": prediction.seconds,
            "eol_s": prediction.eol,
            "reference_dt": REFERENCE_DT,
            "eol_reference_s": prediction.reference,
            "reached": reached.len(),
        },
        "ukf": {
            "step_seconds": ukf.step_seconds,
            "final_state": ukf.final_state.as_slice(),
        },
        "timings": timings,
        "sensor_noise": {"x": filter_noise().x, "f": filter_noise().f, "p": filter_noise().p, "discrete": filter_noise().discrete},
        "limits": {"k_min": PROGPY_LIMITS.k_min},
    });
    let text = serde_json::to_string_pretty(&out).expect("json");
    std::fs::write(args.out.join("rust.json"), &text).expect("write json");
    println!(
        "ours: PF step (N = {PARTICLES}) {:.1} us, prediction of {SAMPLES} samples to EOL {:.3} s (EOL {:.2}..{:.2} s), UKF step {:.2} us",
        pf.step_seconds * 1e6,
        prediction.seconds,
        reached.iter().copied().fold(f64::INFINITY, f64::min),
        reached.iter().copied().fold(0.0, f64::max),
        ukf.step_seconds * 1e6
    );
    println!("wrote {}", args.out.join("rust.json").display());
}
