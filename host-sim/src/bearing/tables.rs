//! Anger et al. 2012 Tables 4-6 on four generated trials, and a campaign of many generated
//! trials (train on a few, test on the rest).

use super::prognosis::{
    BearingGp, PrognosisSettings, RatePrior, TrialMetrics, metrics, prognose, prognose_rate_scaled,
};
use super::train::{Dataset, GP_POINTS, feature_noise_variance, rate_prior, train_sparse};
use super::trial::{Trial, TrialGenerator};
use nalgebra::{SMatrix, SVector};
use rayon::prelude::*;
use std::fmt::Write as _;

/// The paper's numbers, for the side-by-side tables: (label, AB, MSE, MAPE, alpha-lambda, PH).
/// A row of the paper's tables: (label, AB, MSE, MAPE, alpha-lambda, PH).
pub type PaperRow = (&'static str, f64, f64, f64, f64, f64);

pub const PAPER_TABLE4: [PaperRow; 4] = [
    ("Data Set 1", -0.21, 21.79, 19.52, 1.0, 0.86),
    ("Data Set 2", 0.0, 10.87, 13.11, 1.0, 1.0),
    ("Data Set 3", -3.48, 78.71, 24.55, 1.0, 0.81),
    ("Data Set 4", -2.28, 56.44, 23.86, 1.0, 0.84),
];
pub const PAPER_TABLE5: [PaperRow; 4] = [
    ("Tr 2 Test 1", 44.64, 3522.93, 242.65, 0.0, 0.07),
    ("Tr 2 Test 4", 8.64, 544.8, 116.60, 0.0, 0.04),
    ("Tr 3 Test 1", 22.79, 1514.79, 151.34, 0.0, 0.071),
    ("Tr 3 Test 4", -28.12, 1172.28, 149.59, 0.0, 0.28),
];
pub const PAPER_TABLE6: [PaperRow; 2] = [
    ("Tr 2,3 Test 1", 25.0, 1841.14, 160.54, 0.0, 0.07),
    ("Tr 2,3 Test 4", -7.0, 895.32, 132.99, 0.04, 0.12),
];

/// One row of a reproduced table.
#[derive(Clone, Debug)]
pub struct Row {
    pub label: String,
    pub metrics: TrialMetrics,
}

/// Median (and mean) metrics of one estimator over the campaign's test trials.
#[derive(Clone, Debug)]
pub struct CampaignRow {
    pub label: String,
    pub trials: usize,
    pub median: TrialMetrics,
    pub mean: TrialMetrics,
    /// Fraction of test trials whose MAPE is at most 60 %.
    pub mape_le_60: f64,
}

/// Everything `tables` computes.
#[derive(Clone, Debug)]
pub struct Tables {
    pub table4: Vec<Row>,
    pub table5: Vec<Row>,
    pub table6: Vec<Row>,
    pub campaign: Vec<CampaignRow>,
    pub campaign_trials: usize,
    pub campaign_training: usize,
    pub measurement_variance: f64,
}

/// Campaign size.
#[derive(Clone, Copy, Debug)]
pub struct CampaignConfig {
    /// Total generated trials (training + test).
    pub trials: usize,
    /// Trials used for training (one GP each; the IMM uses all of them).
    pub training: usize,
    /// First seed of the campaign's trials (the paper trials use seeds 1-4).
    pub first_seed: u64,
}

impl Default for CampaignConfig {
    fn default() -> Self {
        Self {
            trials: 60,
            training: 8,
            first_seed: 100,
        }
    }
}

/// The GP of `trials`: FITC on all their pairs with `GP_POINTS` inducing inputs.
pub fn gp_for(trials: &[&Trial]) -> anyhow::Result<Box<BearingGp>> {
    train_sparse(&Dataset::from_trials(trials), GP_POINTS)?.to_core::<GP_POINTS>()
}

fn run<const K: usize>(
    gps: [&BearingGp; K],
    t: &Trial,
    s: &PrognosisSettings,
) -> anyhow::Result<TrialMetrics> {
    metrics(&prognose(gps, t, s)?).ok_or_else(|| anyhow::anyhow!("no predictions"))
}

/// Per-cycle random-walk variance of the rate state (std 0.003 per cycle, about 0.05 over a
/// life: the rate is a property of the unit and drifts only slowly).
pub const RATE_WALK_VARIANCE: f64 = 1e-5;
/// Damage at which the rate-tilt polynomial is centred (middle of the feature range).
pub const RATE_PIVOT: f64 = 0.5;

/// The state prior of the rate-scaled GP-UKF with `NX - 1` log-rate terms, from the training
/// units' rates relative to `gp` (see [`rate_prior`]).
pub fn rate_state_prior<const NX: usize>(
    gp: &BearingGp,
    training: &[&Trial],
) -> anyhow::Result<RatePrior<NX>> {
    let fit = rate_prior::<NX>(gp, training, RATE_PIVOT, 0.0)?;
    let (mean, cov) = (&fit.mean, &fit.covariance);
    let mut m = SVector::<f64, NX>::zeros();
    let mut c = SMatrix::<f64, NX, NX>::zeros();
    for i in 0..NX - 1 {
        m[i + 1] = mean[i];
        for j in 0..NX - 1 {
            c[(i + 1, j + 1)] = cov[i][j];
        }
    }
    Ok(RatePrior {
        mean: m,
        covariance: c,
        pivot: RATE_PIVOT,
    })
}

fn summarise(label: &str, rows: &[TrialMetrics]) -> CampaignRow {
    let med = |f: fn(&TrialMetrics) -> f64| {
        let mut v: Vec<f64> = rows.iter().map(f).collect();
        prognos_core::metrics::median(&mut v).unwrap_or(f64::NAN)
    };
    let mean =
        |f: fn(&TrialMetrics) -> f64| rows.iter().map(f).sum::<f64>() / rows.len().max(1) as f64;
    CampaignRow {
        label: label.to_string(),
        trials: rows.len(),
        median: TrialMetrics {
            ab: med(|m| m.ab),
            mse: med(|m| m.mse),
            mape: med(|m| m.mape),
            alpha_lambda: med(|m| m.alpha_lambda),
            ph: med(|m| m.ph),
        },
        mean: TrialMetrics {
            ab: mean(|m| m.ab),
            mse: mean(|m| m.mse),
            mape: mean(|m| m.mape),
            alpha_lambda: mean(|m| m.alpha_lambda),
            ph: mean(|m| m.ph),
        },
        mape_le_60: rows.iter().filter(|m| m.mape <= 60.0).count() as f64
            / rows.len().max(1) as f64,
    }
}

/// Reproduces Tables 4-6 on generated trials 1-4 and runs the campaign.
pub fn tables(generator: &TrialGenerator, campaign: CampaignConfig) -> anyhow::Result<Tables> {
    let paper: Vec<Trial> = (1..=4)
        .into_par_iter()
        .map(|s| generator.trial(s))
        .collect();
    let all: Vec<&Trial> = paper.iter().collect();
    let settings = PrognosisSettings {
        measurement_variance: feature_noise_variance(&all),
        ..PrognosisSettings::default()
    };
    let gps: Vec<Box<BearingGp>> = paper
        .par_iter()
        .map(|t| gp_for(&[t]))
        .collect::<anyhow::Result<_>>()?;
    let table4 = (0..4)
        .into_par_iter()
        .map(|i| {
            Ok(Row {
                label: format!("Data Set {}", i + 1),
                metrics: run([&*gps[i]], &paper[i], &settings)?,
            })
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let pairs = [(1usize, 0usize), (1, 3), (2, 0), (2, 3)];
    let table5 = pairs
        .par_iter()
        .map(|&(tr, te)| {
            Ok(Row {
                label: format!("Tr {} Test {}", tr + 1, te + 1),
                metrics: run([&*gps[tr]], &paper[te], &settings)?,
            })
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let table6 = [0usize, 3]
        .par_iter()
        .map(|&te| {
            Ok(Row {
                label: format!("Tr 2,3 Test {}", te + 1),
                metrics: run([&*gps[1], &*gps[2]], &paper[te], &settings)?,
            })
        })
        .collect::<anyhow::Result<Vec<_>>>()?;

    // Campaign.
    let trials: Vec<Trial> = (0..campaign.trials as u64)
        .into_par_iter()
        .map(|i| generator.trial(campaign.first_seed + i))
        .collect();
    let (train_set, test_set) = trials.split_at(campaign.training.min(trials.len()));
    let train_refs: Vec<&Trial> = train_set.iter().collect();
    let c_settings = PrognosisSettings {
        measurement_variance: feature_noise_variance(&train_refs),
        ..settings
    };
    let c_gps: Vec<Box<BearingGp>> = train_set
        .par_iter()
        .map(|t| gp_for(&[t]))
        .collect::<anyhow::Result<_>>()?;
    anyhow::ensure!(
        c_gps.len() >= 8,
        "the campaign needs at least 8 training trials"
    );
    let pooled = gp_for(&train_refs)?;
    let eval = |f: &(dyn Fn(&Trial) -> anyhow::Result<TrialMetrics> + Sync)| {
        test_set
            .par_iter()
            .map(f)
            .collect::<anyhow::Result<Vec<TrialMetrics>>>()
    };
    let g = |i: usize| &*c_gps[i];
    let single = eval(&|t| run([g(0)], t, &c_settings))?;
    let imm2 = eval(&|t| run([g(0), g(1)], t, &c_settings))?;
    let imm8 = eval(&|t| run(std::array::from_fn::<_, 8, _>(g), t, &c_settings))?;
    let sticky = PrognosisSettings {
        stay_probability: 0.998,
        ..c_settings
    };
    let imm8_sticky = eval(&|t| run(std::array::from_fn::<_, 8, _>(g), t, &sticky))?;
    let imm16_sticky = if c_gps.len() >= 16 {
        Some(eval(&|t| {
            run(std::array::from_fn::<_, 16, _>(g), t, &sticky)
        })?)
    } else {
        None
    };
    let pooled_rows = eval(&|t| run([&*pooled], t, &c_settings))?;
    let rate_prior2 = rate_state_prior::<2>(&pooled, &train_refs)?;
    let rate_prior3 = rate_state_prior::<3>(&pooled, &train_refs)?;
    let metrics_of =
        |p: anyhow::Result<_>| metrics(&p?).ok_or_else(|| anyhow::anyhow!("no predictions"));
    let rate_rows = eval(&|t| {
        metrics_of(prognose_rate_scaled::<2, 5, 1>(
            [(&*pooled, rate_prior2)],
            RATE_WALK_VARIANCE,
            t,
            &c_settings,
        ))
    })?;
    let tilt_rows = eval(&|t| {
        metrics_of(prognose_rate_scaled::<3, 7, 1>(
            [(&*pooled, rate_prior3)],
            RATE_WALK_VARIANCE,
            t,
            &c_settings,
        ))
    })?;
    let mut rows = vec![
        summarise("GP-UKF, trained on 1 trial", &single),
        summarise("IMM of 2 GP-UKFs (paper's set-up)", &imm2),
        summarise("IMM of 8 GP-UKFs (one per training trial)", &imm8),
        summarise("IMM of 8 GP-UKFs, stay probability 0.998", &imm8_sticky),
        summarise("GP-UKF, one GP on all training trials", &pooled_rows),
        summarise(
            "GP-UKF with online log-rate state, one GP on all training trials",
            &rate_rows,
        ),
        summarise(
            "GP-UKF with online log-rate and rate-tilt states, one GP on all training trials",
            &tilt_rows,
        ),
    ];
    if let Some(r) = imm16_sticky {
        rows.push(summarise("IMM of 16 GP-UKFs, stay probability 0.998", &r));
    }
    Ok(Tables {
        table4,
        table5,
        table6,
        campaign: rows,
        campaign_trials: test_set.len(),
        campaign_training: train_set.len(),
        measurement_variance: settings.measurement_variance,
    })
}

fn fmt_row(s: &mut String, label: &str, m: &TrialMetrics, paper: Option<&PaperRow>) {
    let _ = write!(
        s,
        "| {label} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} |",
        m.ab, m.mse, m.mape, m.alpha_lambda, m.ph
    );
    if let Some(p) = paper {
        let _ = write!(
            s,
            " {:.2} | {:.2} | {:.2} | {:.2} | {:.2} |",
            p.1, p.2, p.3, p.4, p.5
        );
    }
    s.push('\n');
}

impl Tables {
    /// Markdown tables with the paper's values beside ours.
    pub fn to_markdown(&self) -> String {
        let mut s = String::new();
        let head = "| trial | AB | MSE | MAPE % | alpha-lambda | PH | paper AB | paper MSE | paper MAPE % | paper alpha-lambda | paper PH |\n|---|---|---|---|---|---|---|---|---|---|---|\n";
        let sections: [(&str, &Vec<Row>, &[PaperRow]); 3] = [
            (
                "Table 4: GP-UKF trained and tested on the same trial",
                &self.table4,
                &PAPER_TABLE4,
            ),
            (
                "Table 5: GP-UKF tested on a trial it was not trained on",
                &self.table5,
                &PAPER_TABLE5,
            ),
            (
                "Table 6: IMM of the GP-UKFs trained on trials 2 and 3",
                &self.table6,
                &PAPER_TABLE6,
            ),
        ];
        for (title, rows, paper) in sections {
            let _ = writeln!(s, "#### {title}\n");
            s.push_str(head);
            for (r, p) in rows.iter().zip(paper.iter()) {
                fmt_row(&mut s, &r.label, &r.metrics, Some(p));
            }
            s.push('\n');
        }
        let _ = writeln!(
            s,
            "#### Campaign: {} training trials, {} test trials (medians over test trials)\n",
            self.campaign_training, self.campaign_trials
        );
        s.push_str("| estimator | AB | MSE | MAPE % | alpha-lambda | PH | mean MAPE % | mean alpha-lambda | share MAPE <= 60 % |\n|---|---|---|---|---|---|---|---|---|\n");
        for c in &self.campaign {
            let m = &c.median;
            let _ = writeln!(
                s,
                "| {} | {:.2} | {:.1} | {:.1} | {:.2} | {:.2} | {:.1} | {:.2} | {:.2} |",
                c.label,
                m.ab,
                m.mse,
                m.mape,
                m.alpha_lambda,
                m.ph,
                c.mean.mape,
                c.mean.alpha_lambda,
                c.mape_le_60
            );
        }
        s
    }
}
