//! Electric-scooter campaigns (Yu et al. 2020): the truth plant in lockstep with the core's
//! FDI and UKF/AUKF/AEUKF, and the reproduction of Tables 4 and 6.

use crate::plants::scooter::{Profile, ScooterPlant, SensorNoise};
use nalgebra::{SMatrix, SVector, Vector1};
use prognos_core::diagnose::scooter::ScooterArr;
use prognos_core::filter::adaptive_ukf::{Adaptation, AdaptiveConfig, AdaptiveUkf};
use prognos_core::filter::ukf::{SigmaParams, Ukf};
use prognos_core::plants::scooter::{BETA_THETA_R, K1, NS, NX, NY, R_RV, ScooterModel};
use rand_core::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;

/// Sampling time (s).
pub const DT: f64 = 0.02;
/// Covariance-matching window (samples).
pub const WINDOW: usize = 25;
/// Auxiliary-detector threshold `Psi_0` (paper: 760).
pub const PSI_THRESHOLD: f64 = 760.0;

/// The scooter's adaptive filter type.
pub type ScooterFilter = AdaptiveUkf<f64, NX, NS, NY, WINDOW>;

/// Filter tuning shared by the three variants.
#[derive(Clone, Copy, Debug)]
pub struct Tuning {
    pub p0: SVector<f64, NX>,
    pub q0: SVector<f64, NX>,
    pub r0: SVector<f64, NY>,
    pub tau: f64,
    pub q_floor: SVector<f64, NX>,
    pub q_ceiling: SVector<f64, NX>,
    pub r_floor: SVector<f64, NY>,
}

impl Default for Tuning {
    fn default() -> Self {
        Self {
            p0: SVector::<f64, NX>::from_column_slice(&[
                1e-4, 1e-4, 1e-6, 1e-4, 1e-4, 1e-4, 0.05, 0.3, 0.01,
            ]),
            q0: SVector::<f64, NX>::from_column_slice(&[
                1e-8, 1e-6, 1e-10, 1e-8, 1e-8, 1e-6, 1e-10, 1e-10, 1e-10,
            ]),
            r0: SVector::<f64, NY>::new(1e-6, 1e-8, 1e-6),
            tau: 5.0,
            q_floor: SVector::<f64, NX>::from_column_slice(&[
                1e-12, 1e-10, 1e-14, 1e-12, 1e-12, 1e-10, 1e-10, 1e-10, 1e-12,
            ]),
            q_ceiling: SVector::<f64, NX>::from_column_slice(&[
                1e-6, 1e-6, 1e-8, 1e-6, 1e-6, 1e-6, 1e-6, 1e-6, 1e-9,
            ]),
            r_floor: SVector::<f64, NY>::new(1e-8, 1e-10, 1e-8),
        }
    }
}

/// Builds a filter of the given variant at the nominal rest state.
pub fn build_filter(mode: Adaptation, tuning: &Tuning) -> ScooterFilter {
    let model = ScooterModel::<f64>::nominal();
    let ukf = Ukf::new(
        model.nominal_state(),
        SMatrix::from_diagonal(&tuning.p0),
        SMatrix::from_diagonal(&tuning.q0),
        SigmaParams::default(),
    )
    .expect("valid scooter tuning");
    AdaptiveUkf::new(
        ukf,
        SMatrix::from_diagonal(&tuning.r0),
        AdaptiveConfig {
            enhance_mask: SVector::<f64, NX>::from_column_slice(&[
                0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0,
            ]),
            lower: SVector::<f64, NX>::from_column_slice(&[
                -1e9, -1e9, -1e9, -1e9, -1e9, -1e9, 0.05, 0.0, 5.0,
            ]),
            upper: SVector::<f64, NX>::from_column_slice(&[
                1e9, 1e9, 1e9, 1e9, 1e9, 1e9, 1.5, 5.0, 20.0,
            ]),
            ..AdaptiveConfig::new(
                mode,
                tuning.tau,
                tuning.q_floor,
                tuning.q_ceiling,
                tuning.r_floor,
            )
        },
    )
    .expect("valid adaptive configuration")
}

/// Time series of one run.
#[derive(Clone, Debug, Default)]
pub struct RunTrace {
    pub time: Vec<f64>,
    pub beta: Vec<f64>,
    pub beta_var: Vec<f64>,
    pub r_rv: Vec<f64>,
    pub k1: Vec<f64>,
    pub psi: Vec<f64>,
    pub cv: Vec<u8>,
    /// Times at which the auxiliary detector fired (rising edges).
    pub detections: Vec<f64>,
    /// Time of the first persistent inconsistency (fault estimation activated).
    pub activation: Option<f64>,
}

/// Runs one experiment with one filter variant, in lockstep with the truth plant.
pub fn run(profile: Profile, mode: Adaptation, tuning: &Tuning, seed: u64) -> RunTrace {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut plant = ScooterPlant::new(profile, SensorNoise::default(), &mut rng);
    let model = ScooterModel::<f64>::nominal();
    let mut filter = build_filter(mode, tuning);
    let mut arr = ScooterArr::<f64>::nominal();
    let mut trace = RunTrace::default();
    let steps = (profile.duration / DT).round() as usize;
    let mut inconsistent_run = 0u32;
    let mut above = false;
    for _ in 0..steps {
        let (u, y) = plant.sample(DT, &mut rng);
        let t = plant.time;
        let report = arr
            .step(u, &[y[0], y[1], y[2]], DT)
            .expect("finite samples");
        inconsistent_run = if report.cv != 0 {
            inconsistent_run + 1
        } else {
            0
        };
        if trace.activation.is_none() && inconsistent_run >= 10 {
            trace.activation = Some(t);
            // Fault estimation starts: re-open the fault-parameter covariances (P0).
            let mut p = *filter.ukf().covariance();
            for i in BETA_THETA_R..NX {
                for j in 0..NX {
                    if i != j {
                        p[(i, j)] = 0.0;
                        p[(j, i)] = 0.0;
                    }
                }
                p[(i, i)] = tuning.p0[i];
            }
            filter.ukf_mut().set_covariance(p).expect("P0 block is PD");
        }
        let fire = report.psi >= PSI_THRESHOLD;
        if fire && !above {
            trace.detections.push(t);
        }
        let enhance = fire && trace.activation.is_some();
        above = fire;
        filter
            .step(&model, &Vector1::new(u), y.as_slice(), DT, enhance)
            .expect("filter step");
        let x = filter.ukf().state();
        trace.time.push(t);
        trace.beta.push(x[BETA_THETA_R]);
        trace
            .beta_var
            .push(filter.ukf().covariance()[(BETA_THETA_R, BETA_THETA_R)]);
        trace.r_rv.push(x[R_RV]);
        trace.k1.push(x[K1]);
        trace.psi.push(report.psi);
        trace.cv.push(report.cv);
    }
    trace
}

/// Mean of `values` over the samples whose time lies in `[from, to)`.
pub fn window_mean(time: &[f64], values: &[f64], from: f64, to: f64) -> f64 {
    let (sum, n) = time
        .iter()
        .zip(values)
        .filter(|(t, _)| **t >= from && **t < to)
        .fold((0.0, 0usize), |(s, n), (_, v)| (s + v, n + 1));
    if n == 0 { f64::NAN } else { sum / n as f64 }
}

/// Per-run estimates that Tables 4 and 6 average: `beta_theta_r` in each fault interval
/// (mean over the second half of the interval), `R_rv` and `K1` (means from 2 s after the
/// first fault to the end of the run).
#[derive(Clone, Debug)]
pub struct RunEstimates {
    pub beta: Vec<f64>,
    pub r_rv: f64,
    pub k1: f64,
}

/// Summarises one run of `profile`.
pub fn estimates(profile: &Profile, trace: &RunTrace) -> RunEstimates {
    let beta = profile
        .beta_intervals
        .iter()
        .map(|(a, d, _)| window_mean(&trace.time, &trace.beta, 0.5 * (a + d), *d))
        .collect();
    let from = profile.friction_fault.0 + 2.0;
    RunEstimates {
        beta,
        r_rv: window_mean(&trace.time, &trace.r_rv, from, f64::INFINITY),
        k1: window_mean(&trace.time, &trace.k1, from, f64::INFINITY),
    }
}

/// Mean and sample standard deviation.
pub fn mean_std(values: &[f64]) -> (f64, f64) {
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
    (mean, var.sqrt())
}

/// One row of Table 4 / 6: means and standard deviations of the columns
/// `[beta L1.., R_rv, K1]` over the runs.
#[derive(Clone, Debug)]
pub struct TableRow {
    pub filter: &'static str,
    pub mean: Vec<f64>,
    pub std: Vec<f64>,
}

/// Reproduces Table 4 (`experiment = 1`) or Table 6 (`experiment = 2`) over `runs` seeded
/// runs per filter (seeds `seed..seed + runs`, the same plants for every filter).
pub fn table(experiment: u8, runs: usize, seed: u64) -> Vec<TableRow> {
    let profile = if experiment == 1 {
        Profile::EXPERIMENT1
    } else {
        Profile::EXPERIMENT2
    };
    let tuning = Tuning::default();
    let intervals = if experiment == 1 { 3 } else { 4 };
    [
        ("AEUKF", Adaptation::Enhanced),
        ("AUKF", Adaptation::CovarianceMatching),
        ("UKF", Adaptation::None),
    ]
    .iter()
    .map(|(name, mode)| {
        let per_run: Vec<RunEstimates> = (0..runs as u64)
            .map(|r| estimates(&profile, &run(profile, *mode, &tuning, seed + r)))
            .collect();
        let mut columns: Vec<Vec<f64>> = (0..intervals)
            .map(|i| per_run.iter().map(|e| e.beta[i]).collect())
            .collect();
        columns.push(per_run.iter().map(|e| e.r_rv).collect());
        columns.push(per_run.iter().map(|e| e.k1).collect());
        let (mean, std) = columns.iter().map(|c| mean_std(c)).unzip();
        TableRow {
            filter: name,
            mean,
            std,
        }
    })
    .collect()
}

/// The paper's Table 4 (means, then standard deviations) for AEUKF, AUKF, UKF.
pub const PAPER_TABLE4: [(&str, [f64; 5], [f64; 5]); 3] = [
    (
        "AEUKF",
        [0.94, 0.79, 0.56, 0.463, 10.02],
        [0.0011, 0.0012, 0.0011, 0.0012, 0.06],
    ),
    (
        "AUKF",
        [0.96, 0.85, 0.62, 0.477, 10.09],
        [0.0016, 0.0016, 0.0017, 0.0015, 0.11],
    ),
    (
        "UKF",
        [0.96, 0.91, 0.70, 0.487, 9.88],
        [0.0022, 0.0021, 0.0022, 0.0023, 0.14],
    ),
];
/// The paper's Table 6.
pub const PAPER_TABLE6: [(&str, [f64; 6], [f64; 6]); 3] = [
    (
        "AEUKF",
        [0.92, 0.72, 0.83, 0.76, 0.462, 9.98],
        [0.0011, 0.0013, 0.0011, 0.0012, 0.0013, 0.06],
    ),
    (
        "AUKF",
        [0.92, 0.81, 0.83, 0.85, 0.448, 9.93],
        [0.0016, 0.0017, 0.0015, 0.0017, 0.0019, 0.12],
    ),
    (
        "UKF",
        [0.93, 0.89, 0.84, 0.86, 0.443, 10.12],
        [0.0022, 0.0022, 0.0023, 0.0021, 0.0023, 0.13],
    ),
];

/// A paper row: filter, means, standard deviations.
type PaperRow = (&'static str, Vec<f64>, Vec<f64>);

/// Tables 4 and 6 as text, ours beside the paper's.
pub fn tables(runs: usize, seed: u64) -> String {
    use std::fmt::Write;
    let mut out = String::new();
    for experiment in [1u8, 2] {
        let rows = table(experiment, runs, seed);
        let (truth, paper): (Vec<f64>, Vec<PaperRow>) = if experiment == 1 {
            (
                vec![0.94, 0.78, 0.55, 0.469, 10.02],
                PAPER_TABLE4
                    .iter()
                    .map(|(n, m, s)| (*n, m.to_vec(), s.to_vec()))
                    .collect(),
            )
        } else {
            (
                vec![0.92, 0.70, 0.82, 0.76, 0.469, 10.02],
                PAPER_TABLE6
                    .iter()
                    .map(|(n, m, s)| (*n, m.to_vec(), s.to_vec()))
                    .collect(),
            )
        };
        let _ = writeln!(
            out,
            "Table {} (experiment {experiment}, {runs} runs): columns beta L1..L{}, R_rv, K1",
            if experiment == 1 { 4 } else { 6 },
            truth.len() - 2
        );
        let fmt = |v: &[f64]| v.iter().map(|x| format!("{x:>9.4}")).collect::<String>();
        let _ = writeln!(out, "  actual            {}", fmt(&truth));
        for (row, (_, pm, ps)) in rows.iter().zip(paper.iter()) {
            let _ = writeln!(out, "  {:<6} mean ours  {}", row.filter, fmt(&row.mean));
            let _ = writeln!(out, "  {:<6} mean paper {}", row.filter, fmt(pm));
            let _ = writeln!(out, "  {:<6} std  ours  {}", row.filter, fmt(&row.std));
            let _ = writeln!(out, "  {:<6} std  paper {}", row.filter, fmt(ps));
        }
    }
    out
}
