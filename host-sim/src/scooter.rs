//! Electric-scooter campaigns (Yu et al. 2020): the truth plant in lockstep with the core's
//! FDI and UKF/AUKF/AEUKF, and the reproduction of Tables 4 and 6.

use crate::lockstep::FaultInjector;
use crate::plants::scooter::{Profile, ScooterPlant, SensorNoise};
use crate::scenario::SensorFaults;
use prognos_core::filter::adaptive_ukf::Adaptation;
use prognos_core::pipeline::scooter::{Scooter, ScooterConfig};
use prognos_core::plants::scooter::{BETA_THETA_R, K1, R_RV};
use prognos_core::prognose::sequential::Outcome;
use prognos_core::real::{Real, cast};
use rand_core::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;

/// Monte-Carlo samples per RUL prediction (the paper's M).
pub const MONTE_CARLO_SAMPLES: usize = 80;
/// Sampling time (s).
pub const DT: f64 = 0.02;
/// One RUL prediction made during a run (Eqs. 16-18 with M = 80).
#[derive(Clone, Debug)]
pub struct RulPrediction {
    /// Usage index (1 under `Upsilon_f`, 2 after the first reactivation).
    pub usage: u8,
    /// Time of the prediction (`t_d1` or the reactivation moment).
    pub time: f64,
    /// Deterministic RUL of the identified segment and the Monte-Carlo samples.
    pub rul: f64,
    pub samples: Vec<f64>,
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
    /// Times at which the pipeline recognised a fault event.
    pub detections: Vec<f64>,
    /// Time fault estimation was activated.
    pub activation: Option<f64>,
    /// RUL predictions, and whether a reactivation was refused by Eq. 9.
    pub predictions: Vec<RulPrediction>,
    pub refused_reactivation: bool,
    /// Samples the pipeline rejected (only with injected faults).
    pub rejected: usize,
}

/// Runs one experiment with one filter variant: the truth plant in lockstep with the core's
/// [`Scooter`] pipeline in scalar type `T`.
pub fn run_with<T: Real>(profile: Profile, mode: Adaptation, seed: u64) -> RunTrace {
    run_with_faults::<T>(profile, mode, seed, SensorFaults::default())
}

/// [`run_with`] with sensor faults injected between the plant's sensors and the pipeline
/// (the host's [`FaultInjector`], seeded from `seed`). A sample the pipeline rejects leaves
/// it unchanged (the next sample predicts over the gap) and is counted in
/// `RunTrace::rejected`; with no faults every sample must be accepted.
pub fn run_with_faults<T: Real>(
    profile: Profile,
    mode: Adaptation,
    seed: u64,
    faults: SensorFaults,
) -> RunTrace {
    let mut injector = FaultInjector::new(faults, seed);
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut plant = ScooterPlant::new(profile, SensorNoise::default(), &mut rng);
    let mut mc_rng = Xoshiro256PlusPlus::seed_from_u64(seed ^ 0x005e_ed0f_4a11);
    let mut pipe = Scooter::<T>::new(T::zero(), ScooterConfig::new(mode)).expect("valid config");
    let mut trace = RunTrace::default();
    let steps = (profile.duration / DT).round() as usize;
    for k in 1..=steps {
        let (u, y) = plant.sample(DT, &mut rng);
        // Time from the sample index: no drift from accumulating dt.
        let t = k as f64 * DT;
        let mut y = [y[0], y[1], y[2]];
        let t_seen = injector.apply(t, DT, &mut y);
        let ys = [cast::<T>(y[0]), cast::<T>(y[1]), cast::<T>(y[2])];
        let report = match pipe.step(cast(t_seen), cast(u), &ys) {
            Ok(r) => r,
            Err(e) => {
                assert!(!faults.is_off(), "clean sample rejected: {e}");
                trace.rejected += 1;
                continue;
            }
        };
        if report.spike_dropped {
            assert!(!faults.is_off(), "clean sample dropped as a spike at {t}");
            trace.rejected += 1;
        }
        if report.active && trace.activation.is_none() {
            trace.activation = Some(t);
        }
        if report.event.is_some() {
            trace.detections.push(t);
        }
        match report.outcome {
            Some(Outcome::Predicted(segment)) => {
                let mut samples = [T::zero(); MONTE_CARLO_SAMPLES];
                let ok = pipe
                    .prognoser()
                    .rul_samples(&mut mc_rng, &mut samples)
                    .is_ok();
                trace.predictions.push(RulPrediction {
                    usage: segment.usage,
                    time: t,
                    rul: segment.rul().as_f64(),
                    samples: if ok {
                        samples
                            .iter()
                            .map(|v| v.as_f64())
                            .filter(|v| *v < 1e30)
                            .collect()
                    } else {
                        Vec::new()
                    },
                });
            }
            Some(Outcome::NotReactivated(_)) => trace.refused_reactivation = true,
            _ => {}
        }
        let x = report.state;
        trace.time.push(t);
        trace.beta.push(x[BETA_THETA_R].as_f64());
        trace.beta_var.push(report.beta_variance.as_f64());
        trace.r_rv.push(x[R_RV].as_f64());
        trace.k1.push(x[K1].as_f64());
        trace.psi.push(report.arr.psi.as_f64());
        trace.cv.push(report.arr.cv);
    }
    trace
}

/// [`run_with`] in f64.
pub fn run(profile: Profile, mode: Adaptation, seed: u64) -> RunTrace {
    run_with::<f64>(profile, mode, seed)
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
    let intervals = if experiment == 1 { 3 } else { 4 };
    [
        ("AEUKF", Adaptation::Enhanced),
        ("AUKF", Adaptation::CovarianceMatching),
        ("UKF", Adaptation::None),
    ]
    .iter()
    .map(|(name, mode)| {
        let per_run: Vec<RunEstimates> = (0..runs as u64)
            .map(|r| estimates(&profile, &run(profile, *mode, seed + r)))
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

/// Designed RULs: experiment 1 under usage 1 and 2, experiment 2 under usage 1.
pub const DESIGNED_RUL: [f64; 3] = [18.98, 3.86, 14.8];

/// The paper's Table 5 (RA, RSD in %; `None` where the paper marks the prediction
/// unacceptable): rows exp1/usage1, exp1/usage2, exp2/usage1; filters AEUKF, AUKF, UKF.
pub const PAPER_TABLE5: [[(Option<f64>, Option<f64>); 3]; 3] = [
    [
        (Some(94.15), Some(9.32)),
        (Some(93.94), Some(9.06)),
        (Some(90.57), Some(9.57)),
    ],
    [(Some(90.71), Some(11.59)), (None, None), (None, None)],
    [
        (Some(95.07), Some(8.28)),
        (Some(93.51), Some(8.25)),
        (Some(90.68), Some(8.31)),
    ],
];

/// Prognosis summary of one (experiment, usage, filter) cell over the runs.
#[derive(Clone, Debug)]
pub struct PrognosisCell {
    pub filter: &'static str,
    /// Runs in which a prediction was made.
    pub predicted: usize,
    pub runs: usize,
    /// Mean over runs of the Monte-Carlo mean RUL, of RA (%) and of RSD (%).
    pub mean_rul: f64,
    pub ra: f64,
    pub rsd: f64,
    /// Fraction of runs whose 95 % interval (2.5-97.5 percentiles) holds the true RUL.
    pub coverage: f64,
    /// Runs in which Eq. 9 refused a reactivation.
    pub refused: usize,
}

fn percentile(sorted: &[f64], q: f64) -> f64 {
    let idx = ((sorted.len() - 1) as f64 * q).round() as usize;
    sorted[idx.min(sorted.len() - 1)]
}

/// Table 5: sequential prognosis over `runs` seeded runs per filter.
pub fn table5(runs: usize, seed: u64) -> Vec<(u8, u8, Vec<PrognosisCell>)> {
    use prognos_core::metrics::{relative_accuracy, relative_std};
    let cases = [(1u8, 1u8, 0usize), (1, 2, 1), (2, 1, 2)];
    let filters = [
        ("AEUKF", Adaptation::Enhanced),
        ("AUKF", Adaptation::CovarianceMatching),
        ("UKF", Adaptation::None),
    ];
    let traces: Vec<Vec<Vec<RunTrace>>> = [Profile::EXPERIMENT1, Profile::EXPERIMENT2]
        .iter()
        .map(|profile| {
            filters
                .iter()
                .map(|(_, mode)| {
                    (0..runs as u64)
                        .map(|r| run(*profile, *mode, seed + r))
                        .collect()
                })
                .collect()
        })
        .collect();
    cases
        .iter()
        .map(|&(experiment, usage, truth_index)| {
            let truth = DESIGNED_RUL[truth_index];
            let cells = filters
                .iter()
                .enumerate()
                .map(|(fi, (name, _))| {
                    let runs_here = &traces[usize::from(experiment - 1)][fi];
                    let (mut rul, mut ra, mut rsd, mut covered, mut n) = (0.0, 0.0, 0.0, 0, 0);
                    for trace in runs_here {
                        let Some(p) = trace.predictions.iter().find(|p| p.usage == usage) else {
                            continue;
                        };
                        if p.samples.len() < 2 {
                            continue;
                        }
                        let mean = p.samples.iter().sum::<f64>() / p.samples.len() as f64;
                        let mut sorted = p.samples.clone();
                        sorted.sort_by(f64::total_cmp);
                        let (lo, hi) = (percentile(&sorted, 0.025), percentile(&sorted, 0.975));
                        rul += mean;
                        ra += relative_accuracy(truth, mean).unwrap_or(f64::NAN);
                        rsd += relative_std(&p.samples).unwrap_or(f64::NAN);
                        covered += usize::from(lo <= truth && truth <= hi);
                        n += 1;
                    }
                    let d = n.max(1) as f64;
                    PrognosisCell {
                        filter: name,
                        predicted: n,
                        runs,
                        mean_rul: rul / d,
                        ra: ra / d,
                        rsd: rsd / d,
                        coverage: covered as f64 / d,
                        refused: runs_here.iter().filter(|t| t.refused_reactivation).count(),
                    }
                })
                .collect();
            (experiment, usage, cells)
        })
        .collect()
}

/// Table 5 as text, ours beside the paper's.
pub fn table5_text(runs: usize, seed: u64) -> String {
    use std::fmt::Write;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "Table 5 ({runs} runs, M = {MONTE_CARLO_SAMPLES}): RA and RSD in %, ours (paper)"
    );
    for (row, (experiment, usage, cells)) in table5(runs, seed).iter().enumerate() {
        let truth = DESIGNED_RUL[row];
        for (col, c) in cells.iter().enumerate() {
            let (pra, prsd) = PAPER_TABLE5[row][col];
            let show = |v: Option<f64>| v.map_or("x".to_string(), |x| format!("{x:.2}"));
            let _ = writeln!(
                out,
                "  exp {experiment} usage {usage} {:<6} RUL* {truth:>5.2}  mean RUL {:>6.2}  RA {:>6.2} ({:>5})  RSD {:>5.2} ({:>5})  in 95% CI {:>3.0}%  predicted {}/{}  refused reactivation {}",
                c.filter,
                c.mean_rul,
                c.ra,
                show(pra),
                c.rsd,
                show(prsd),
                100.0 * c.coverage,
                c.predicted,
                c.runs,
                c.refused
            );
        }
    }
    out
}

/// A short demo for `prognos demo`: one run of each experiment through the AEUKF pipeline,
/// summarised as text (estimates per interval, RUL predictions, reactivation decisions).
pub fn demo_summary(seed: u64) -> String {
    use std::fmt::Write;
    let mut out = String::new();
    for (name, profile) in [
        ("experiment 1", Profile::EXPERIMENT1),
        ("experiment 2", Profile::EXPERIMENT2),
    ] {
        let trace = run(profile, Adaptation::Enhanced, seed);
        let e = estimates(&profile, &trace);
        let _ = writeln!(
            out,
            "scooter {name}: fault estimation active from {:.2} s",
            trace.activation.unwrap_or(f64::NAN)
        );
        for ((a, d, truth), est) in profile.beta_intervals.iter().zip(&e.beta) {
            let _ = writeln!(
                out,
                "  beta_theta_r [{a:5.2}, {d:5.2}) s: {est:.4} (true {truth})"
            );
        }
        let _ = writeln!(
            out,
            "  R_rv {:.4} (true 0.469), K1 {:.3} (nominal 10.02)",
            e.r_rv, e.k1
        );
        for p in &trace.predictions {
            let mean = p.samples.iter().sum::<f64>() / p.samples.len().max(1) as f64;
            let _ = writeln!(
                out,
                "  RUL at {:.2} s (usage {}): {:.2} s, Monte-Carlo mean {:.2} s over {} samples",
                p.time,
                p.usage,
                p.rul,
                mean,
                p.samples.len()
            );
        }
        if trace.refused_reactivation {
            let _ = writeln!(
                out,
                "  prognoser not reactivated: degradation non-monotonic after the usage change"
            );
        }
    }
    out
}
