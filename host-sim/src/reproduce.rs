//! `prognos reproduce TABLE`: regenerates a paper's result table with the actual pipeline on
//! simulated (or, for the edge-cloud scheme, real) data, printed beside the paper's numbers.
//! Also the paper systems' parts of `prognos demo`.

use crate::dataio::TimeSeries;
use crate::error::SimError;
use crate::output::{format_table, write_csv, write_text};
use crate::plants::reaction_wheel::WheelSensors;
use clap::ValueEnum;
use prognos_core::filter::adaptive::Method;
use std::path::Path;

/// The tables `prognos reproduce` knows.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Table {
    /// Pneumatic valve, Table 2: 5 faults x 4 measurement sets (N = 500).
    ValveTable2,
    /// Pneumatic valve, Table 3: bottom external leak, all five wears estimated (N = 2000).
    ValveTable3,
    /// Reaction wheel, Table 5: temperature RMSPE and coverage of PF / adaptive PF / APF.
    WheelTable5,
    /// Reaction wheel, Table 6: one-step vs two-step lubricant-loss parameter estimation.
    WheelTable6,
    /// Reaction wheel, Table 7: RUL error for both fault scenarios.
    WheelTable7,
    /// Bearing, Tables 4-6 on four generated trials and a campaign (`--runs` trials, 8 for
    /// training).
    BearingTables,
    /// Electric scooter, Tables 4 and 6 (fault-parameter estimates) and 5 (RA, RSD).
    ScooterTables,
}

impl Table {
    /// Seed used when `--seed` is not given: the one `docs/results.md` was measured with.
    pub fn default_seed(self) -> u64 {
        match self {
            Table::ValveTable2 | Table::ValveTable3 | Table::ScooterTables => 1,
            Table::WheelTable5 => 1000,
            Table::WheelTable6 => 2000,
            Table::WheelTable7 => 3000,
            Table::BearingTables => 100,
        }
    }

    /// Runs used when `--runs` is not given (the issues' minimum).
    pub fn default_runs(self) -> usize {
        match self {
            Table::ValveTable2 => 5,
            Table::ValveTable3 => 1,
            Table::BearingTables => 60,
            _ => 20,
        }
    }
}

/// Regenerates `table` with `runs` Monte-Carlo runs from `seed`; returns the printed text.
pub fn reproduce(table: Table, runs: usize, seed: u64) -> String {
    let started = std::time::Instant::now();
    let mut text = match table {
        Table::ValveTable2 => crate::valve::table2(runs, seed).render(),
        Table::ValveTable3 => crate::valve::table3(seed).render(),
        Table::WheelTable5 => {
            use crate::reaction_wheel::{TABLE5_PARTICLES, format_table5, table5};
            let mut cells = table5(&[100], &[Method::Plain], runs, seed);
            cells.extend(table5(
                &TABLE5_PARTICLES,
                &[Method::AdaptiveResampling, Method::Apf],
                runs,
                seed,
            ));
            format_table5(&cells)
        }
        Table::WheelTable6 => crate::reaction_wheel::table6(runs, seed),
        Table::WheelTable7 => crate::reaction_wheel::table7(runs, seed),
        Table::BearingTables => {
            use crate::bearing::{CampaignConfig, tables, trial::TrialGenerator};
            let campaign = CampaignConfig {
                trials: runs,
                first_seed: seed,
                ..CampaignConfig::default()
            };
            match tables(&TrialGenerator::new(), campaign) {
                Ok(t) => t.to_markdown(),
                Err(e) => format!("bearing tables failed: {e}\n"),
            }
        }
        Table::ScooterTables => {
            let mut s = crate::scooter::tables(runs, seed);
            s.push_str(&crate::scooter::table5_text(runs, seed));
            s
        }
    };
    text.push_str(&format!(
        "\n{runs} runs from seed {seed}, {:.1} s\n",
        started.elapsed().as_secs_f64()
    ));
    text
}

/// The paper systems' demo runs: one short run each, a summary printed and written with its
/// time series under `out/<system>/`.
pub fn paper_demos(out: &Path, only: Option<&str>) -> Result<Vec<String>, SimError> {
    let mut summaries = Vec::new();
    let wanted = |name: &str| only.is_none_or(|o| o == name);
    if wanted("valve") {
        summaries.push(valve_demo(&out.join("valve"))?);
    }
    if wanted("reaction_wheel") {
        summaries.push(reaction_wheel_demo(&out.join("reaction_wheel"))?);
    }
    if wanted("scooter") {
        let text = crate::scooter::demo_summary(1);
        write_text(&out.join("scooter").join("summary.txt"), &text)?;
        summaries.push(text);
    }
    Ok(summaries)
}

/// `pipeline::ReactionWheel` through the Table 3 temperature profile in f64 and f32.
fn reaction_wheel_demo(dir: &Path) -> Result<String, SimError> {
    let duration = 300.0;
    let seed = 7;
    let run = |f32_run: bool| {
        let result = if f32_run {
            crate::reaction_wheel::run_pipeline::<f32>(WheelSensors::HIGH_NOISE, duration, seed)
        } else {
            crate::reaction_wheel::run_pipeline::<f64>(WheelSensors::HIGH_NOISE, duration, seed)
        };
        result.map_err(|e| SimError::Run(format!("reaction wheel pipeline: {e}")))
    };
    let (est64, truth) = run(false)?;
    let (est32, _) = run(true)?;
    let rmspe = |est: &[f64]| prognos_core::metrics::rmspe(est, &truth).unwrap_or(f64::NAN);
    let mut series = TimeSeries::new(
        [
            "t",
            "x:lubricant_temperature",
            "est:temperature_f64",
            "est:temperature_f32",
        ]
        .map(String::from)
        .to_vec(),
    );
    let dt = prognos_core::plants::reaction_wheel::SAMPLE_INTERVAL_S;
    for (k, ((e64, e32), tr)) in est64.iter().zip(&est32).zip(&truth).enumerate() {
        series.rows.push(vec![(k + 1) as f64 * dt, *tr, *e64, *e32]);
    }
    write_csv(&dir.join("run.csv"), &series)?;
    let rows = vec![
        vec!["f64".into(), format!("{:.3}", rmspe(&est64))],
        vec!["f32".into(), format!("{:.3}", rmspe(&est32))],
    ];
    let text = format!(
        "reaction wheel: lubricant temperature from speed and current (APF, {duration} s, high noise)\n{}",
        format_table(&["scalar", "temperature RMSPE %"], &rows)
    );
    write_text(&dir.join("summary.txt"), &text)?;
    Ok(text)
}

/// One valve run (Table 2's bottom external leak, discrete `{open, closed}` sensors only, as on
/// the real valve, N = 500): wear estimate per cycle, RUL predictions, CSV and RUL plot.
fn valve_demo(dir: &Path) -> Result<String, SimError> {
    use crate::valve::{ValveSetup, run_experiment, table2_experiment};
    use prognos_core::plants::valve::{DamageMode, MeasurementSet};
    let setup = ValveSetup::new();
    let mode = DamageMode::BottomLeak;
    let exp = table2_experiment(&setup, mode, MeasurementSet::Discrete, 1);
    let result = run_experiment::<500>(&setup, &exp);
    let w_true = exp.true_wear[mode.wear_index() - prognos_core::plants::valve::idx::W_R];
    let mut wear = TimeSeries::new(["t", "x:wear", "est:wear"].map(String::from).to_vec());
    for (k, w) in result
        .estimate_per_cycle
        .first()
        .into_iter()
        .flatten()
        .enumerate()
    {
        wear.rows.push(vec![(k + 1) as f64, w_true, *w]);
    }
    write_csv(&dir.join("wear.csv"), &wear)?;
    let mut rul = TimeSeries::new(
        [
            "t",
            "rul:true",
            "rul:mean",
            "rul:median",
            "rul:lower",
            "rul:upper",
        ]
        .map(String::from)
        .to_vec(),
    );
    let mut rows = Vec::new();
    for p in &result.predictions {
        rul.rows.push(vec![
            p.t_p,
            p.true_rul,
            p.mean_rul,
            p.median_rul,
            p.lower_99,
            f64::NAN,
        ]);
        rows.push(vec![
            format!("{:.1}", p.t_p),
            format!("{:.1}", p.true_rul),
            format!("{:.1}", p.median_rul),
            format!("{:.1}", p.lower_99),
            format!("{:.1}", p.ra),
            format!("{:.1}", p.rmad),
        ]);
    }
    write_csv(&dir.join("rul.csv"), &rul)?;
    crate::plot::plot_rul(&dir.join("rul.svg"), &rul, 0.1)?;
    let text = format!(
        "pneumatic valve: bottom external leak, {{open, closed}} sensors, N = 500 (true EOL at cycle {:.0})\n\
         wear PRMSE {:.2} %, mean RA {:.2} %, mean RMAD_RUL {:.2} %, {:.1} s\n{}",
        result.true_eol,
        result.prmse_w.first().copied().unwrap_or(f64::NAN),
        result.mean_ra(),
        result.mean_rmad_rul(),
        result.seconds,
        format_table(
            &[
                "t_P [cycles]",
                "RUL*",
                "median RUL",
                "99 % lower",
                "RA %",
                "RMAD %"
            ],
            &rows
        )
    );
    write_text(&dir.join("summary.txt"), &text)?;
    Ok(text)
}
