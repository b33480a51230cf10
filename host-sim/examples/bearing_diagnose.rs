//! Per-prediction dump of the bearing campaign's IMM of 8 GP-UKFs, for diagnosing where in life
//! the alpha band is missed. Usage:
//! cargo run --release -p prognos-sim --example bearing_diagnose -- [first_seed] [trials]
//!     [imm8 | pooled-rate | pooled-tilt | imm8-rate] [rate walk variance] [sod | sparse]
//!     [constant | growing] > out.csv
//! `sod`: GPs on 64 points spread in time; `sparse`: FITC on all points, 64 inducing inputs.
//! `growing`: the rate-scaled filters use the feature noise law fitted on the training trials.
//! The summary (median MAPE and alpha-lambda, band share by fifth of life) goes to stderr.
use prognos_sim::bearing::prognosis::{
    BearingGp, PrognosisSettings, RatePrior, TrialMetrics, metrics, prognose, prognose_rate_scaled,
};
use prognos_sim::bearing::tables::{RATE_PIVOT, rate_state_prior};
use prognos_sim::bearing::train::{
    Dataset, GP_POINTS, feature_noise_law, feature_noise_variance, rate_prior, train, train_sparse,
};
use prognos_sim::bearing::trial::{Trial, TrialGenerator};
use rayon::prelude::*;

/// One test trial: its CSV rows, metrics, and (in band, predictions) by fifth of life.
type TrialDump = (String, TrialMetrics, [(usize, usize); 5]);

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let first_seed: u64 = args.get(1).map_or(Ok(100), |s| s.parse())?;
    let count: usize = args.get(2).map_or(Ok(60), |s| s.parse())?;
    let mode = args.get(3).map_or("imm8", |s| s.as_str()).to_string();
    let walk: f64 = args.get(4).map_or(Ok(1e-5), |s| s.parse())?;
    let sparse = args.get(5).is_some_and(|s| s == "sparse");
    let growing = args.get(6).is_some_and(|s| s == "growing");
    let fit_gp = |d: &Dataset| {
        if sparse {
            train_sparse(d, GP_POINTS)
        } else {
            train(d, GP_POINTS)
        }
    };
    let generator = TrialGenerator::new();
    let trials: Vec<Trial> = (0..count as u64)
        .into_par_iter()
        .map(|i| generator.trial(first_seed + i))
        .collect();
    let (train_set, test_set) = trials.split_at(8);
    let refs: Vec<&Trial> = train_set.iter().collect();
    let law = feature_noise_law(&refs);
    eprintln!("feature noise law {law:?}");
    let settings = PrognosisSettings {
        measurement_variance: feature_noise_variance(&refs),
        rate_feature_noise: growing.then_some(law),
        ..PrognosisSettings::default()
    };
    let gps: Vec<Box<BearingGp>> = train_set
        .par_iter()
        .map(|t| fit_gp(&Dataset::from_trials(&[t]))?.to_core::<GP_POINTS>())
        .collect::<anyhow::Result<_>>()?;
    let g = |i: usize| &*gps[i];
    let pooled = fit_gp(&Dataset::from_trials(&refs))?.to_core::<GP_POINTS>()?;
    let training = &refs;
    let prior2 = |gp: &BearingGp| rate_state_prior::<2>(gp, training);
    let prior3 = |gp: &BearingGp| rate_state_prior::<3>(gp, training);
    let fit = rate_prior::<3>(&pooled, &refs, RATE_PIVOT, 0.0)?;
    eprintln!("pooled rate + tilt per trial {:?}", fit.per_trial);
    let pooled2 = prior2(&pooled)?;
    let pooled3 = prior3(&pooled)?;
    let priors: Vec<RatePrior<2>> = gps
        .iter()
        .map(|g| prior2(g))
        .collect::<anyhow::Result<_>>()?;
    let rows: Vec<TrialDump> = test_set
        .par_iter()
        .map(|t| {
            let p = match mode.as_str() {
                "pooled-rate" => {
                    prognose_rate_scaled::<2, 5, 1>([(&*pooled, pooled2)], walk, t, &settings)?
                }
                "pooled-tilt" => {
                    prognose_rate_scaled::<3, 7, 1>([(&*pooled, pooled3)], walk, t, &settings)?
                }
                "imm8-rate" => prognose_rate_scaled::<2, 5, 8>(
                    std::array::from_fn::<_, 8, _>(|i| (g(i), priors[i])),
                    walk,
                    t,
                    &settings,
                )?,
                _ => prognose(std::array::from_fn::<_, 8, _>(g), t, &settings)?,
            };
            let mut s = String::new();
            let mut fifths = [(0usize, 0usize); 5];
            for q in &p.predictions {
                let f = ((5 * q.cycle) / t.eol).min(4);
                fifths[f].1 += 1;
                if (q.median - q.true_rul).abs() <= 0.2 * q.true_rul {
                    fifths[f].0 += 1;
                }
                let truth = (t.pitting[q.cycle] - 5.0) / 65.0;
                s.push_str(&format!(
                    "{},{},{},{},{},{},{},{},{},{:.4},{:.4},{:.4}\n",
                    t.seed,
                    t.eol,
                    q.cycle,
                    q.true_rul,
                    q.median,
                    q.p05,
                    q.p95,
                    q.estimate,
                    truth,
                    t.params.rate,
                    t.params.progressivity,
                    t.params.load_sensitivity
                ));
            }
            let m = metrics(&p).ok_or_else(|| anyhow::anyhow!("no predictions"))?;
            Ok((s, m, fifths))
        })
        .collect::<anyhow::Result<_>>()?;
    println!("seed,eol,cycle,true_rul,median,p05,p95,estimate,truth,rate,q,s");
    let mut band = [(0usize, 0usize); 5];
    for (r, _, f) in &rows {
        print!("{r}");
        for (b, x) in band.iter_mut().zip(f) {
            b.0 += x.0;
            b.1 += x.1;
        }
    }
    let median = |f: fn(&TrialMetrics) -> f64| {
        let mut v: Vec<f64> = rows.iter().map(|r| f(&r.1)).collect();
        prognos_core::metrics::median(&mut v).unwrap_or(f64::NAN)
    };
    let mean_al = rows.iter().map(|r| r.1.alpha_lambda).sum::<f64>() / rows.len().max(1) as f64;
    let shares: Vec<String> = band
        .iter()
        .map(|(a, b)| format!("{:.2}", *a as f64 / (*b).max(1) as f64))
        .collect();
    eprintln!(
        "SUMMARY seed {first_seed} {mode} sparse={sparse} growing={growing}: median MAPE {:.1} \
         alpha-lambda {:.2} (mean {:.2}) band by fifth [{}]",
        median(|m| m.mape),
        median(|m| m.alpha_lambda),
        mean_al,
        shares.join(", ")
    );
    eprintln!("R = {}", settings.measurement_variance);
    Ok(())
}
