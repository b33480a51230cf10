//! Single runs and Monte-Carlo campaigns: simulate, score, and write CSV, JSON and plots.
//!
//! Scores come from the run log: state RMSE and +-2 sd coverage against the truth, and the
//! RUL scores of `prognos_core::metrics` (relative accuracy and alpha-lambda at
//! lambda = 0.25/0.5/0.75, alpha accuracy over all predictions, prognostic horizon, MAPE,
//! average bias).

use crate::dataio::read_series;
use crate::error::SimError;
use crate::lockstep::{RunRecord, RunSettings, run_lockstep};
use crate::output::{remove_stale_temporaries, write_csv, write_json};
use crate::plot;
use crate::registry::Registry;
use crate::scenario::Scenario;
use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};

/// The lambda fractions of `[t_p, EOL]` at which RUL accuracy is scored.
pub const LAMBDAS: [f64; 3] = [0.25, 0.5, 0.75];

/// Scores of one run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunMetrics {
    pub run: usize,
    pub seed: u64,
    /// Logged rows.
    pub rows: usize,
    pub true_eol: Option<f64>,
    pub rejected_steps: usize,
    /// RMSE of `est:<name>` against `x:<name>` over rows where both are finite.
    pub state_rmse: BTreeMap<String, f64>,
    /// Fraction of rows with the truth within the estimate +-2 sd.
    pub state_coverage_2sd: BTreeMap<String, f64>,
    /// RUL scores, when the run has both a truth EOL and predictions.
    pub rul: Option<RulMetrics>,
}

/// RUL scores of one run (alpha-lambda framework, Saxena et al.).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RulMetrics {
    pub alpha: f64,
    /// Time of the first prediction, `t_p`.
    pub first_prediction: f64,
    pub points: Vec<LambdaPoint>,
    /// `EOL - t` of the earliest prediction after which every prediction stays within
    /// `+- alpha * EOL` of the true RUL; `None` if the last prediction is outside.
    pub prognostic_horizon: Option<f64>,
    /// Fraction of all predictions before EOL within `(1 +- alpha) RUL*`.
    pub alpha_accuracy: f64,
    /// Mean absolute percentage error of the median over all predictions before EOL.
    pub mape: Option<f64>,
    /// Mean of `RUL* - RUL` (positive: predicted failure too early).
    pub average_bias: Option<f64>,
}

/// The prediction at `t_lambda = t_p + lambda (EOL - t_p)`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LambdaPoint {
    pub lambda: f64,
    pub t: f64,
    pub true_rul: f64,
    pub predicted_median: f64,
    /// `100 (1 - |RUL* - RUL| / RUL*)`, percent.
    pub relative_accuracy: f64,
    /// Median within `(1 +- alpha) RUL*`.
    pub within_alpha: bool,
}

impl RunMetrics {
    /// Scores a run log.
    pub fn from_record(run: usize, record: &RunRecord, alpha: f64) -> Self {
        let s = &record.series;
        let mut state_rmse = BTreeMap::new();
        let mut state_coverage_2sd = BTreeMap::new();
        for name in s.names_with_prefix("est") {
            let (Some(est), Some(truth)) = (
                s.column(&format!("est:{name}")),
                s.column(&format!("x:{name}")),
            ) else {
                continue;
            };
            let sd = s
                .column(&format!("est_sd:{name}"))
                .unwrap_or_else(|| vec![f64::NAN; est.len()]);
            let (mut n, mut sq, mut covered) = (0usize, 0.0, 0usize);
            for ((e, x), d) in est.iter().zip(&truth).zip(&sd) {
                if e.is_finite() && x.is_finite() {
                    n += 1;
                    sq += (e - x).powi(2);
                    if (e - x).abs() <= 2.0 * d {
                        covered += 1;
                    }
                }
            }
            if n > 0 {
                state_rmse.insert(name.clone(), (sq / n as f64).sqrt());
                state_coverage_2sd.insert(name, covered as f64 / n as f64);
            }
        }
        RunMetrics {
            run,
            seed: record.seed,
            rows: s.rows.len(),
            true_eol: record.true_eol,
            rejected_steps: record.rejected_steps,
            state_rmse,
            state_coverage_2sd,
            rul: record
                .true_eol
                .and_then(|eol| rul_metrics(record, eol, alpha)),
        }
    }

    /// `(name, value)` pairs of every scalar score, for aggregation and histograms.
    pub fn flatten(&self) -> Vec<(String, f64)> {
        let mut out = vec![("rejected_steps".to_string(), self.rejected_steps as f64)];
        if let Some(eol) = self.true_eol {
            out.push(("true_eol".into(), eol));
        }
        for (n, v) in &self.state_rmse {
            out.push((format!("rmse:{n}"), *v));
        }
        for (n, v) in &self.state_coverage_2sd {
            out.push((format!("coverage_2sd:{n}"), *v));
        }
        if let Some(r) = &self.rul {
            for p in &r.points {
                out.push((format!("ra@{}", p.lambda), p.relative_accuracy));
                out.push((
                    format!("alpha_lambda@{}", p.lambda),
                    if p.within_alpha { 1.0 } else { 0.0 },
                ));
            }
            out.push((
                "prognostic_horizon".into(),
                r.prognostic_horizon.unwrap_or(0.0),
            ));
            out.push(("alpha_accuracy".into(), r.alpha_accuracy));
            if let Some(v) = r.mape {
                out.push(("rul_mape".into(), v));
            }
            if let Some(v) = r.average_bias {
                out.push(("rul_average_bias".into(), v));
            }
        }
        out
    }
}

fn rul_metrics(record: &RunRecord, eol: f64, alpha: f64) -> Option<RulMetrics> {
    use prognos_core::metrics;
    let s = &record.series;
    let t = s.column("t")?;
    let median = s.column("rul:median")?;
    // Rows with a prediction made before EOL.
    let (times, predicted): (Vec<f64>, Vec<f64>) = t
        .iter()
        .zip(&median)
        .filter(|(ti, m)| m.is_finite() && **ti < eol)
        .map(|(&ti, &m)| (ti, m))
        .unzip();
    let true_rul: Vec<f64> = times.iter().map(|ti| eol - ti).collect();
    let t_p = *times.first()?;
    let points = LAMBDAS
        .iter()
        .filter_map(|&lambda| {
            let t_lambda = t_p + lambda * (eol - t_p);
            // The latest prediction made at or before t_lambda.
            let i = times
                .iter()
                .take_while(|ti| **ti <= t_lambda + 1e-9)
                .count();
            let i = i.checked_sub(1)?;
            let (ti, m, r) = (times[i], predicted[i], true_rul[i]);
            Some(LambdaPoint {
                lambda,
                t: ti,
                true_rul: r,
                predicted_median: m,
                relative_accuracy: metrics::relative_accuracy(r, m)?,
                within_alpha: metrics::within_alpha(r, m, alpha),
            })
        })
        .collect();
    Some(RulMetrics {
        alpha,
        first_prediction: t_p,
        points,
        prognostic_horizon: metrics::prognostic_horizon(
            &times,
            &true_rul,
            &predicted,
            eol,
            alpha,
            metrics::HorizonBand::FractionOfEol,
        ),
        alpha_accuracy: metrics::alpha_lambda_accuracy(&true_rul, &predicted, alpha)?,
        mape: metrics::mean_absolute_percentage_error(&true_rul, &predicted),
        average_bias: metrics::average_bias(&true_rul, &predicted),
    })
}

/// Mean, standard deviation and range of one score over runs.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Stats {
    pub count: usize,
    pub mean: f64,
    pub std: f64,
    pub min: f64,
    pub max: f64,
}

impl Stats {
    /// Statistics of the finite values (None if there are none).
    pub fn of(values: &[f64]) -> Option<Stats> {
        let v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
        if v.is_empty() {
            return None;
        }
        let n = v.len() as f64;
        let mean = v.iter().sum::<f64>() / n;
        let var = if v.len() > 1 {
            v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)
        } else {
            0.0
        };
        Some(Stats {
            count: v.len(),
            mean,
            std: var.sqrt(),
            min: v.iter().copied().fold(f64::INFINITY, f64::min),
            max: v.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        })
    }
}

/// Aggregates per-run scores by name.
pub fn aggregate(runs: &[RunMetrics]) -> BTreeMap<String, Stats> {
    let mut by_name: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    for r in runs {
        for (name, value) in r.flatten() {
            by_name.entry(name).or_default().push(value);
        }
    }
    by_name
        .into_iter()
        .filter_map(|(n, v)| Stats::of(&v).map(|s| (n, s)))
        .collect()
}

/// Simulates run `run` of `scenario` (seed [`Scenario::run_seed`]`(run)`).
pub fn simulate(
    registry: &Registry,
    scenario: &Scenario,
    run: usize,
) -> Result<(RunRecord, RunMetrics), SimError> {
    let system = registry.resolve(scenario)?;
    let settings = RunSettings::for_run(scenario, run);
    let mut sim = system.build(scenario, settings.seed)?;
    let record = run_lockstep(&mut sim, &settings)?;
    let metrics = RunMetrics::from_record(run, &record, scenario.alpha);
    Ok((record, metrics))
}

/// The files of a single run written by [`write_run`].
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RunFiles {
    pub csv: PathBuf,
    pub json: PathBuf,
    /// Plots that were drawn.
    pub plots: Vec<PathBuf>,
}

/// Writes `timeseries.csv`, `metrics.json` and (with `plots`) `signals.svg`,
/// `estimates.svg`, `rul.svg` into `dir`, each atomically.
pub fn write_run(
    dir: &Path,
    record: &RunRecord,
    metrics: &RunMetrics,
    alpha: f64,
    plots: bool,
) -> Result<RunFiles, SimError> {
    let files = RunFiles {
        csv: dir.join("timeseries.csv"),
        json: dir.join("metrics.json"),
        plots: Vec::new(),
    };
    write_csv(&files.csv, &record.series)?;
    write_json(&files.json, metrics)?;
    let mut files = files;
    if plots {
        files.plots = draw_run_plots(dir, "", &record.series, alpha)?;
    }
    Ok(files)
}

fn draw_run_plots(
    dir: &Path,
    suffix: &str,
    series: &crate::dataio::TimeSeries,
    alpha: f64,
) -> Result<Vec<PathBuf>, SimError> {
    let mut drawn = Vec::new();
    let signals = dir.join(format!("signals{suffix}.svg"));
    plot::plot_signals(&signals, series)?;
    drawn.push(signals);
    let estimates = dir.join(format!("estimates{suffix}.svg"));
    if plot::plot_estimates(&estimates, series)? {
        drawn.push(estimates);
    }
    let rul = dir.join(format!("rul{suffix}.svg"));
    if plot::plot_rul(&rul, series, alpha)? {
        drawn.push(rul);
    }
    Ok(drawn)
}

/// How to run a campaign.
#[derive(Clone, Debug, PartialEq)]
pub struct CampaignOptions {
    /// Number of runs (the scenario's `runs` when `None`).
    pub runs: Option<usize>,
    /// Output folder: `runs/run_NNNN.{csv,json}`, `summary.json`, plots.
    pub out_dir: PathBuf,
    /// Skip runs whose CSV and JSON are both present and readable.
    pub resume: bool,
    /// Show a progress bar (it is hidden anyway when stdout is not a terminal).
    pub progress: bool,
    /// Draw plots.
    pub plots: bool,
    /// Worker threads (rayon's default when `None`).
    pub jobs: Option<usize>,
}

/// The campaign's `summary.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CampaignSummary {
    pub scenario: String,
    pub system: String,
    pub base_seed: u64,
    pub alpha: f64,
    pub runs: usize,
    /// Runs taken from a previous, interrupted invocation (`--resume`).
    pub resumed: usize,
    pub aggregate: BTreeMap<String, Stats>,
    pub per_run: Vec<RunMetrics>,
}

/// Paths of run `run`'s files in a campaign folder.
pub fn run_paths(out_dir: &Path, run: usize) -> (PathBuf, PathBuf) {
    let runs = out_dir.join("runs");
    (
        runs.join(format!("run_{run:04}.csv")),
        runs.join(format!("run_{run:04}.json")),
    )
}

/// A finished run's metrics if both its files exist and its JSON parses with the right
/// seed. The JSON is written after the CSV, both atomically, so a present JSON means a
/// complete CSV.
fn finished_run(out_dir: &Path, run: usize, seed: u64) -> Option<RunMetrics> {
    let (csv, json) = run_paths(out_dir, run);
    if !csv.is_file() {
        return None;
    }
    let text = std::fs::read_to_string(json).ok()?;
    let metrics: RunMetrics = serde_json::from_str(&text).ok()?;
    (metrics.run == run && metrics.seed == seed).then_some(metrics)
}

/// Runs `runs` seeds of `scenario` in parallel and writes every run's CSV and JSON as it
/// finishes, then `summary.json` and the plots. Results do not depend on thread count or
/// scheduling: run `i` always uses seed [`Scenario::run_seed`]`(i)`.
pub fn run_campaign(
    registry: &Registry,
    scenario: &Scenario,
    options: &CampaignOptions,
) -> Result<CampaignSummary, SimError> {
    let system = registry.resolve(scenario)?;
    // Fail fast on a bad scenario section, before any output exists.
    drop(system.build(scenario, scenario.run_seed(0))?);
    let runs = options.runs.unwrap_or(scenario.runs).max(1);
    let out = &options.out_dir;
    remove_stale_temporaries(out);
    remove_stale_temporaries(&out.join("runs"));

    let bar = if options.progress && std::io::stdout().is_terminal() {
        ProgressBar::new(runs as u64)
    } else {
        ProgressBar::hidden()
    };
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} runs  {elapsed} (eta {eta})")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let work = || -> Vec<Result<(RunMetrics, bool), SimError>> {
        (0..runs)
            .into_par_iter()
            .map(|run| {
                let seed = scenario.run_seed(run);
                let result = match finished_run(out, run, seed).filter(|_| options.resume) {
                    Some(m) => Ok((m, true)),
                    None => simulate(registry, scenario, run).and_then(|(record, metrics)| {
                        let (csv, json) = run_paths(out, run);
                        write_csv(&csv, &record.series)?;
                        write_json(&json, &metrics)?;
                        Ok((metrics, false))
                    }),
                };
                bar.inc(1);
                result
            })
            .collect()
    };
    let results = match options.jobs {
        Some(jobs) => rayon::ThreadPoolBuilder::new()
            .num_threads(jobs.max(1))
            .build()
            .map_err(|e| SimError::Run(format!("cannot start worker threads: {e}")))?
            .install(work),
        None => work(),
    };
    bar.finish_and_clear();
    let mut per_run = Vec::with_capacity(runs);
    let mut resumed = 0;
    for result in results {
        let (metrics, was_resumed) = result?;
        resumed += usize::from(was_resumed);
        per_run.push(metrics);
    }
    let summary = CampaignSummary {
        scenario: scenario.name.clone(),
        system: scenario.system.clone(),
        base_seed: scenario.seed,
        alpha: scenario.alpha,
        runs,
        resumed,
        aggregate: aggregate(&per_run),
        per_run,
    };
    if options.plots {
        let (csv0, _) = run_paths(out, 0);
        let series = read_series(&csv0)?;
        draw_run_plots(out, "_run0000", &series, scenario.alpha)?;
        for name in summary.aggregate.keys() {
            let wanted = name == "true_eol"
                || name.starts_with("ra@")
                || name.starts_with("rmse:")
                || name == "prognostic_horizon";
            if !wanted {
                continue;
            }
            let values: Vec<f64> = summary
                .per_run
                .iter()
                .filter_map(|m| m.flatten().into_iter().find(|(n, _)| n == name))
                .map(|(_, v)| v)
                .collect();
            let file: String = name
                .chars()
                .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
                .collect();
            plot::plot_histogram(
                &out.join(format!("hist_{file}.svg")),
                &values,
                &format!("{} over {} runs", name, values.len()),
                name,
                (values.len() as f64).sqrt().ceil().clamp(5.0, 30.0) as usize,
            )?;
        }
    }
    write_json(&out.join("summary.json"), &summary)?;
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataio::TimeSeries;

    #[test]
    fn rul_scores_of_a_known_prediction_sequence() {
        // EOL at t = 100; predictions every 10 s from t = 10, 10% late (RUL over-predicted)
        // until t = 40, then exact.
        let mut series = TimeSeries::new(
            ["t", "x:d", "est:d", "est_sd:d", "rul:median", "rul:true"]
                .map(String::from)
                .to_vec(),
        );
        for k in 0..=100 {
            let t = k as f64;
            let true_rul = 100.0 - t;
            let median = if k % 10 != 0 || k == 0 {
                f64::NAN
            } else if t <= 40.0 {
                1.1 * true_rul
            } else {
                true_rul
            };
            series.rows.push(vec![t, t, t + 0.5, 1.0, median, true_rul]);
        }
        let record = RunRecord {
            series,
            true_eol: Some(100.0),
            rejected_steps: 0,
            first_rejection: None,
            seed: 1,
            injected: Default::default(),
        };
        let m = RunMetrics::from_record(0, &record, 0.05);
        assert!((m.state_rmse["d"] - 0.5).abs() < 1e-12);
        assert_eq!(m.state_coverage_2sd["d"], 1.0);
        let r = m.rul.unwrap();
        assert_eq!(r.first_prediction, 10.0);
        // t_lambda = 10 + lambda * 90: 32.5 -> prediction at 30; 55 -> 50; 77.5 -> 70.
        let at: Vec<f64> = r.points.iter().map(|p| p.t).collect();
        assert_eq!(at, vec![30.0, 50.0, 70.0]);
        assert!((r.points[0].relative_accuracy - 90.0).abs() < 1e-9);
        assert!(!r.points[0].within_alpha && r.points[1].within_alpha);
        assert!((r.points[1].relative_accuracy - 100.0).abs() < 1e-9);
        // Band +-0.05 * 100 = 5: the 10% errors at t = 10..40 are 9, 8, 7, 6 > 5, so the
        // horizon starts at t = 50.
        assert_eq!(r.prognostic_horizon, Some(50.0));
        // 5 of 9 predictions (t = 50..90) are within 5% of RUL*.
        assert!((r.alpha_accuracy - 5.0 / 9.0).abs() < 1e-12);
        assert!((r.mape.unwrap() - 40.0 / 9.0).abs() < 1e-9);
    }
}
