//! The `prognos` command line. To add a command: add a variant to [`Command`] and a match
//! arm in [`execute`]. To add a system: register it in [`crate::registry::Registry::builtin`].
//!
//! Exit status: 0 on success, 2 for a bad or unreadable input file (the message names the
//! file, line and column), 1 for any other failure.

use crate::campaign::{CampaignOptions, LAMBDAS, RunMetrics, run_campaign, simulate, write_run};
use crate::dataio::{read_meta, read_recording};
use crate::error::SimError;
use crate::lockstep::replay;
use crate::output::{fmt_num, format_table};
use crate::registry::Registry;
use crate::scenario::Scenario;
use clap::{Parser, Subcommand};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

/// Model-based prognostics: simulate, estimate, predict remaining useful life.
#[derive(Debug, Parser)]
#[command(name = "prognos", version, about)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

/// The subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Run every registered system's demo scenario once: simulate a degrading system,
    /// estimate, predict RUL, print a summary table, write CSV, JSON and plots.
    Demo {
        /// Output folder (one subfolder per system).
        #[arg(long, default_value = "out/demo")]
        out: PathBuf,
        /// Only this system.
        #[arg(long)]
        system: Option<String>,
        /// Skip the SVG plots.
        #[arg(long)]
        no_plots: bool,
    },
    /// Simulate one run of a scenario.
    Run {
        /// Scenario TOML file.
        scenario: PathBuf,
        /// Output folder [default: out/<scenario name>].
        #[arg(long)]
        out: Option<PathBuf>,
        /// Which Monte-Carlo run's seed to use (run N of a campaign gives the same result).
        #[arg(long, default_value_t = 0)]
        run: usize,
        /// Skip the SVG plots.
        #[arg(long)]
        no_plots: bool,
    },
    /// Run many seeds of a scenario in parallel and summarise the metrics.
    Campaign {
        /// Scenario TOML file.
        scenario: PathBuf,
        /// Number of runs [default: the scenario's `runs`].
        #[arg(long)]
        runs: Option<usize>,
        /// Keep the runs a previous, interrupted campaign finished.
        #[arg(long)]
        resume: bool,
        /// Output folder [default: out/campaign/<scenario name>].
        #[arg(long)]
        out: Option<PathBuf>,
        /// Worker threads [default: all cores].
        #[arg(long)]
        jobs: Option<usize>,
        /// Skip the SVG plots.
        #[arg(long)]
        no_plots: bool,
        /// Never show a progress bar.
        #[arg(long)]
        no_progress: bool,
    },
    /// Run a scenario's estimator over recorded data (CSV with `t`, `u:*`, `y:*`, `x:*`).
    Replay {
        /// Scenario TOML file naming the system and the filter settings.
        scenario: PathBuf,
        /// Recorded data CSV (an optional `<file>.meta.toml` sidecar is checked).
        data: PathBuf,
        /// Output folder [default: out/replay/<scenario name>].
        #[arg(long)]
        out: Option<PathBuf>,
        /// Skip the SVG plots.
        #[arg(long)]
        no_plots: bool,
    },
    /// List the registered systems.
    Systems,
    /// Regenerate a paper's result table (printed beside the paper's numbers).
    Reproduce {
        /// Which table.
        #[arg(value_enum)]
        table: crate::reproduce::Table,
        /// Monte-Carlo runs [default: 20].
        #[arg(long)]
        runs: Option<usize>,
        /// Base seed [default: the seed docs/results.md was measured with].
        #[arg(long)]
        seed: Option<u64>,
        /// Also write the text to this file (atomically).
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Long-run stability: run each on-board pipeline in f32 for many steps against a truth
    /// plant, checking every step for errors, NaN/infinity and covariance blow-up; prints
    /// steps per second. Exit status 1 if any pipeline fails.
    Soak {
        /// Steps per pipeline.
        #[arg(long, default_value_t = 10_000_000)]
        steps: u64,
        /// Only this pipeline (reaction_wheel, scooter, edge).
        #[arg(long)]
        system: Option<String>,
        /// Seed of the truth plants' and the filters' random streams.
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
    /// Fault injection: RUL error with 5 % dropouts and 1 % outliers against clean runs of
    /// the same seeds, for each system wired to the injector (markdown table).
    Faults {
        /// Runs (seeds) per case.
        #[arg(long, default_value_t = 20)]
        runs: usize,
        /// Base seed.
        #[arg(long, default_value_t = 20261201)]
        seed: u64,
        /// Only this system (linear, scooter, wheel, valve, bearing); all by default.
        #[arg(long)]
        system: Option<String>,
        /// Also write the table to this file (atomically).
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Sim-to-real gap diagnosis of recorded data against the model named in its meta file:
    /// where the model disagrees, which unmodelled effect explains it, how far it shrinks.
    /// Writes verdict.json, report.md and report.html.
    Gap {
        /// Recorded data CSV (`t`, `u:*`, `y:*`, optional `x:*`).
        #[arg(long)]
        data: PathBuf,
        /// Output folder.
        #[arg(long)]
        out: PathBuf,
        /// Meta file [default: `<data>.meta.toml` beside the data].
        #[arg(long)]
        meta: Option<PathBuf>,
    },
    /// Prints every built-in gap plant's inputs, outputs, `[model]` parameters and effect
    /// catalogue, and the generic sensor effects (Markdown, as in docs/gap.md).
    GapPlants,
    /// Proves `prognos gap` on generated data whose effect it is not told about (or on a
    /// folder of labelled datasets) and prints attribution, localisation and shrink.
    GapBench {
        /// Plants to generate for (comma separated).
        #[arg(
            long,
            default_value = "reaction_wheel,valve,scooter,dc_motor",
            value_delimiter = ','
        )]
        plants: Vec<String>,
        /// Seeds per effect and ratio.
        #[arg(long, default_value_t = 3)]
        seeds: usize,
        /// Effect-to-noise ratios (comma separated).
        #[arg(long, default_value = "0.5,1,2,4,8", value_delimiter = ',')]
        ratios: Vec<f64>,
        /// Base seed.
        #[arg(long, default_value_t = 2026)]
        seed: u64,
        /// Only these catalogue effects for the single-effect sets (comma separated).
        #[arg(long, value_delimiter = ',')]
        only: Vec<String>,
        /// Per plant: no-effect sets, pair sets, and sets per out-of-catalogue effect.
        #[arg(long, default_value_t = 12)]
        extra_sets: usize,
        /// Input profile of the generated records: `steps` (held levels) or `smooth` (sums
        /// of slow sinusoids; valve: other hold times and a drifting supply).
        #[arg(long, value_enum, default_value_t = crate::gap::bench::Excitation::Steps)]
        excitation: crate::gap::bench::Excitation,
        /// Per dataset, draw the plant's physical parameters within a factor
        /// exp(+-SPREAD) of the defaults (truth and the meta file's [model] alike).
        #[arg(long, default_value_t = 0.0, value_parser = non_negative_number)]
        model_spread: f64,
        /// Scale every sensor's noise std by this factor (effects are placed at their
        /// ratio to the scaled noise).
        #[arg(long, default_value_t = 1.0, value_parser = positive_number)]
        noise_scale: f64,
        /// Scale the sample time by this factor (records keep their duration).
        #[arg(long, default_value_t = 1.0, value_parser = positive_number)]
        sample_time_scale: f64,
        /// Distribution of every sensor's noise (its std unchanged): `gaussian`, or
        /// `uniform`, `laplace`, `student-t5` (heavy tails) and `ar1` (correlated, 0.5)
        /// to see how far the diagnoser's white Gaussian noise model carries.
        #[arg(long, value_enum, default_value_t = crate::gap::bench::NoiseShape::Gaussian)]
        noise_shape: crate::gap::bench::NoiseShape,
        /// How the written rows relate inputs and samples: `before` (the row's input acts
        /// after its sample), `at` (outputs that follow the input at once show it) or
        /// `after` (the row's input acted over the step ending at its sample) [default:
        /// each plant's own: `after` for the valve, as progpy writes, else `before`].
        #[arg(long, value_enum)]
        input_timing: Option<crate::gap::plant::InputTiming>,
        /// Write the truth plant's states as `x:<name>` columns: the diagnosis then runs
        /// the plant's estimator with the user's model and with the verdict's effect, and
        /// the bench reports the median ratio of their errors.
        #[arg(long)]
        truth_columns: bool,
        /// Diagnose the labelled datasets in this folder instead of generating.
        #[arg(long)]
        datasets: Option<PathBuf>,
        /// Also write the generated datasets to this folder.
        #[arg(long)]
        write_datasets: Option<PathBuf>,
        /// Write bench.json and summary.txt here.
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Edge-cloud prognosis (AR model-of-signals on the edge, particle filter in the cloud)
    /// of one bearing vibration file (PRONOSTIA format, see data/pronostia/README.md).
    EdgeCloud {
        /// Bearing vibration CSV.
        #[arg(long)]
        bearing_csv: PathBuf,
        /// Configuration TOML (thresholds, output folder); defaults are the tuned values.
        #[arg(long)]
        config: Option<PathBuf>,
    },
    /// Summarise criterion results of `cargo bench -p prognos-tests --bench filters`: table,
    /// PF scaling slope, filter overhead ratio, log-log plots.
    BenchReport {
        /// Criterion output folder [default: $CARGO_TARGET_DIR/criterion or target/criterion].
        #[arg(long)]
        criterion: Option<PathBuf>,
        /// Folder for summary.txt and the SVG plots.
        #[arg(long, default_value = "docs/bench")]
        out: PathBuf,
    },
}

/// Parses the process arguments, runs the command, prints any error, returns the status.
pub fn main_with(registry: Registry) -> ExitCode {
    let cli = Cli::parse();
    if let Command::EdgeCloud {
        bearing_csv,
        config,
    } = &cli.command
    {
        let status = crate::edge_cloud::cli_edge_cloud(bearing_csv, config.as_deref());
        return ExitCode::from(u8::try_from(status).unwrap_or(1));
    }
    match execute(&registry, cli.command) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(e.exit_code() as u8)
        }
    }
}

/// Runs one command.
pub fn execute(registry: &Registry, command: Command) -> Result<(), SimError> {
    match command {
        Command::Demo {
            out,
            system,
            no_plots,
        } => demo(registry, &out, system.as_deref(), !no_plots),
        Command::Run {
            scenario,
            out,
            run,
            no_plots,
        } => {
            let scenario = Scenario::load(&scenario)?;
            let out = out.unwrap_or_else(|| Path::new("out").join(&scenario.name));
            let started = Instant::now();
            let (record, metrics) = simulate(registry, &scenario, run)?;
            let elapsed = started.elapsed().as_secs_f64();
            let files = write_run(&out, &record, &metrics, scenario.alpha, !no_plots)?;
            print!(
                "{}",
                metrics_table(&[(scenario.name.as_str(), &metrics, elapsed)])
            );
            if let Some(first) = &record.first_rejection {
                println!(
                    "{} samples rejected by the estimator; first: {first}",
                    record.rejected_steps
                );
            }
            print_files(&files.csv, &files.json, &files.plots);
            Ok(())
        }
        Command::Campaign {
            scenario,
            runs,
            resume,
            out,
            jobs,
            no_plots,
            no_progress,
        } => {
            let scenario = Scenario::load(&scenario)?;
            let out_dir =
                out.unwrap_or_else(|| Path::new("out").join("campaign").join(&scenario.name));
            let started = Instant::now();
            let summary = run_campaign(
                registry,
                &scenario,
                &CampaignOptions {
                    runs,
                    out_dir: out_dir.clone(),
                    resume,
                    progress: !no_progress,
                    plots: !no_plots,
                    jobs,
                },
            )?;
            let rows: Vec<Vec<String>> = summary
                .aggregate
                .iter()
                .map(|(name, s)| {
                    vec![
                        name.clone(),
                        s.count.to_string(),
                        fmt_num(Some(s.mean)),
                        fmt_num(Some(s.std)),
                        fmt_num(Some(s.min)),
                        fmt_num(Some(s.max)),
                    ]
                })
                .collect();
            println!(
                "campaign `{}` ({}): {} runs ({} resumed) in {:.1} s",
                summary.scenario,
                summary.system,
                summary.runs,
                summary.resumed,
                started.elapsed().as_secs_f64()
            );
            print!(
                "{}",
                format_table(&["metric", "runs", "mean", "std", "min", "max"], &rows)
            );
            println!("wrote {}", out_dir.join("summary.json").display());
            Ok(())
        }
        Command::Replay {
            scenario,
            data,
            out,
            no_plots,
        } => {
            let scenario = Scenario::load(&scenario)?;
            let system = registry.resolve(&scenario)?;
            let recording = read_recording(&data)?;
            if let Some(meta) = read_meta(&data)?
                && meta.plant != scenario.system
            {
                {
                    return Err(SimError::Run(format!(
                        "{}: data is from plant `{}`, scenario `{}` simulates `{}`",
                        crate::dataio::meta_path(&data).display(),
                        meta.plant,
                        scenario.path.display(),
                        scenario.system
                    )));
                }
            }
            let mut sim = system.build(&scenario, scenario.run_seed(0))?;
            let started = Instant::now();
            let record = replay(
                sim.estimator.as_mut(),
                &recording,
                &sim.inputs.input_names(),
                &sim.sensor.channel_names(),
                None,
            )?;
            let elapsed = started.elapsed().as_secs_f64();
            let metrics = RunMetrics::from_record(0, &record, scenario.alpha);
            let out = out.unwrap_or_else(|| Path::new("out").join("replay").join(&scenario.name));
            let files = write_run(&out, &record, &metrics, scenario.alpha, !no_plots)?;
            print!(
                "{}",
                metrics_table(&[(scenario.name.as_str(), &metrics, elapsed)])
            );
            print_files(&files.csv, &files.json, &files.plots);
            Ok(())
        }
        Command::Systems => {
            let rows: Vec<Vec<String>> = registry
                .systems()
                .map(|s| {
                    vec![
                        s.name().to_string(),
                        s.demo_scenario().map_or("-".into(), |d| d.path.to_string()),
                        s.description().to_string(),
                    ]
                })
                .collect();
            print!(
                "{}",
                format_table(&["system", "demo scenario", "description"], &rows)
            );
            Ok(())
        }
        Command::Reproduce {
            table,
            runs,
            seed,
            out,
        } => {
            let text = crate::reproduce::reproduce(
                table,
                runs.unwrap_or(table.default_runs()),
                seed.unwrap_or(table.default_seed()),
            );
            print!("{text}");
            if let Some(path) = out {
                crate::output::write_text(&path, &text)?;
            }
            Ok(())
        }
        Command::BenchReport { criterion, out } => {
            let criterion = criterion.unwrap_or_else(|| {
                std::env::var_os("CARGO_TARGET_DIR")
                    .map_or_else(|| PathBuf::from("target"), PathBuf::from)
                    .join("criterion")
            });
            let (text, files) = crate::bench_report::run(&criterion, &out)?;
            print!("{text}");
            for f in files {
                println!("wrote {}", f.display());
            }
            Ok(())
        }
        Command::Faults {
            runs,
            seed,
            system,
            out,
        } => {
            let text = crate::faults::table(runs, seed, system.as_deref())
                .map_err(|e| SimError::Run(e.to_string()))?;
            print!("{text}");
            if let Some(path) = out {
                crate::output::write_text(&path, &text)?;
            }
            Ok(())
        }
        Command::Soak {
            steps,
            system,
            seed,
        } => {
            let systems: Vec<&str> = match system.as_deref() {
                Some(name) if crate::soak::SYSTEMS.contains(&name) => vec![name],
                Some(name) => {
                    return Err(SimError::Run(format!(
                        "unknown soak system `{name}` (known: {})",
                        crate::soak::SYSTEMS.join(", ")
                    )));
                }
                None => crate::soak::SYSTEMS.to_vec(),
            };
            let mut failed = Vec::new();
            for name in systems {
                let Some(report) = crate::soak::soak(name, steps, seed) else {
                    continue;
                };
                println!("{}", report.line());
                if !report.passed() {
                    failed.push(name);
                }
            }
            if failed.is_empty() {
                Ok(())
            } else {
                Err(SimError::Run(format!("soak failed: {}", failed.join(", "))))
            }
        }
        Command::Gap { data, out, meta } => {
            let started = Instant::now();
            let diagnosis = crate::gap::diagnose_files(&data, meta.as_deref())?;
            for w in &diagnosis.warnings {
                eprintln!("warning: {w}");
            }
            let files = crate::gap::report::write_report(&out, &diagnosis)?;
            let l = &diagnosis.location;
            println!("plant: {}", diagnosis.plant);
            println!("verdict: {}", diagnosis.verdict);
            println!(
                "where: {} / {} / window [{:.2}, {:.2}] s / band [{:.4}, {:.4}] Hz (NIS {:.3}, adjusted p {:.2e})",
                l.channel,
                l.regime,
                l.window[0],
                l.window[1],
                l.band_hz[0],
                l.band_hz[1],
                l.statistic,
                l.p_value
            );
            let rows: Vec<Vec<String>> = diagnosis
                .ranking
                .iter()
                .take(5)
                .map(|e| {
                    vec![
                        e.effect.clone(),
                        format!("{:.1}", e.score),
                        format!("{:.3}", e.gap_before),
                        format!("{:.3}", e.gap_after),
                        format!("{:.3}", e.shrink),
                    ]
                })
                .collect();
            print!(
                "{}",
                format_table(
                    &["effect", "score", "gap before", "gap after", "shrink"],
                    &rows
                )
            );
            println!("({:.1} s)", started.elapsed().as_secs_f64());
            for f in files {
                println!("wrote {}", f.display());
            }
            Ok(())
        }
        Command::GapPlants => {
            print!("{}", crate::gap::plant_reference());
            Ok(())
        }
        Command::GapBench {
            plants,
            seeds,
            ratios,
            seed,
            only,
            extra_sets,
            excitation,
            model_spread,
            noise_scale,
            sample_time_scale,
            noise_shape,
            input_timing,
            truth_columns,
            datasets,
            write_datasets,
            out,
        } => {
            let opts = crate::gap::bench::BenchOptions {
                plants,
                seeds,
                ratios,
                seed,
                only,
                extra_sets,
                excitation,
                model_spread,
                noise_scale,
                sample_time_scale,
                input_timing,
                truth_columns,
                noise_shape,
            };
            let started = Instant::now();
            let (_, text) = crate::gap::bench::run_bench(
                &opts,
                datasets.as_deref(),
                write_datasets.as_deref(),
                out.as_deref(),
            )?;
            print!("{text}");
            println!("({:.1} s)", started.elapsed().as_secs_f64());
            Ok(())
        }
        Command::EdgeCloud { .. } => Err(SimError::Run(
            "edge-cloud is handled before dispatch".into(),
        )),
    }
}

/// `prognos demo`: one run of each registered system's demo scenario.
pub fn demo(
    registry: &Registry,
    out: &Path,
    only: Option<&str>,
    plots: bool,
) -> Result<(), SimError> {
    let paper_systems = ["valve", "reaction_wheel", "scooter"];
    if let Some(name) = only
        && registry.get(name).is_none()
        && !paper_systems.contains(&name)
    {
        return Err(SimError::Run(format!("unknown system `{name}`")));
    }
    let mut results = Vec::new();
    for system in registry.systems() {
        if only.is_some_and(|n| n != system.name()) {
            continue;
        }
        let Some(embedded) = system.demo_scenario() else {
            continue;
        };
        let scenario = embedded.load()?;
        let started = Instant::now();
        let (record, metrics) = simulate(registry, &scenario, 0)?;
        let elapsed = started.elapsed().as_secs_f64();
        let files = write_run(
            &out.join(system.name()),
            &record,
            &metrics,
            scenario.alpha,
            plots,
        )?;
        results.push((system.name(), metrics, elapsed, files));
    }
    let paper = crate::reproduce::paper_demos(out, only)?;
    if results.is_empty() && paper.is_empty() {
        return Err(SimError::Run("no system has a demo".into()));
    }
    if !results.is_empty() {
        let rows: Vec<(&str, &RunMetrics, f64)> =
            results.iter().map(|(n, m, e, _)| (*n, m, *e)).collect();
        print!("{}", metrics_table(&rows));
        for (_, _, _, files) in &results {
            print_files(&files.csv, &files.json, &files.plots);
        }
    }
    for text in &paper {
        println!("\n{text}");
    }
    println!("wrote {}", out.display());
    Ok(())
}

/// One row per run: EOL, RUL accuracy at lambda = 0.5, alpha-lambda passes, prognostic
/// horizon, state RMSEs, rejected samples, wall time.
pub fn metrics_table(rows: &[(&str, &RunMetrics, f64)]) -> String {
    let mid = LAMBDAS.iter().position(|l| *l == 0.5).unwrap_or(0);
    let body: Vec<Vec<String>> = rows
        .iter()
        .map(|(name, m, seconds)| {
            let point = m.rul.as_ref().and_then(|r| r.points.get(mid));
            let passes = m.rul.as_ref().map_or("-".to_string(), |r| {
                format!(
                    "{}/{}",
                    r.points.iter().filter(|p| p.within_alpha).count(),
                    r.points.len()
                )
            });
            let rmse = m
                .state_rmse
                .iter()
                .map(|(n, v)| format!("{n}={}", fmt_num(Some(*v))))
                .collect::<Vec<_>>()
                .join(" ");
            vec![
                name.to_string(),
                m.rows.to_string(),
                fmt_num(m.true_eol),
                fmt_num(point.map(|p| p.true_rul)),
                fmt_num(point.map(|p| p.predicted_median)),
                fmt_num(point.map(|p| p.relative_accuracy)),
                passes,
                fmt_num(m.rul.as_ref().and_then(|r| r.prognostic_horizon)),
                if rmse.is_empty() { "-".into() } else { rmse },
                m.rejected_steps.to_string(),
                format!("{:.3}", seconds),
            ]
        })
        .collect();
    format_table(
        &[
            "system",
            "samples",
            "true EOL [s]",
            "RUL* @0.5",
            "RUL @0.5",
            "RA @0.5",
            "alpha-lambda",
            "PH [s]",
            "state RMSE",
            "rejected",
            "wall [s]",
        ],
        &body,
    )
}

fn print_files(csv: &Path, json: &Path, plots: &[PathBuf]) {
    println!("wrote {}", csv.display());
    println!("wrote {}", json.display());
    for p in plots {
        println!("wrote {}", p.display());
    }
}

/// A finite number above zero (a scale factor).
fn positive_number(text: &str) -> Result<f64, String> {
    let v: f64 = text
        .parse()
        .map_err(|e| format!("`{text}` is not a number: {e}"))?;
    if v.is_finite() && v > 0.0 {
        Ok(v)
    } else {
        Err(format!("must be a finite number above 0, found {text}"))
    }
}

/// A finite number at or above zero (a spread).
fn non_negative_number(text: &str) -> Result<f64, String> {
    let v: f64 = text
        .parse()
        .map_err(|e| format!("`{text}` is not a number: {e}"))?;
    if v.is_finite() && v >= 0.0 {
        Ok(v)
    } else {
        Err(format!(
            "must be a finite number at or above 0, found {text}"
        ))
    }
}
