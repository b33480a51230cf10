//! Per-prediction dump of the bearing campaign's IMM of 8 GP-UKFs, for diagnosing where in life
//! the alpha band is missed. Usage:
//! cargo run --release -p prognos-sim --example bearing_diagnose -- [first_seed] [trials]
//!     [imm8 | pooled-rate | pooled-tilt | imm8-rate] [rate walk variance] > out.csv
use prognos_sim::bearing::prognosis::{
    BearingGp, PrognosisSettings, RatePrior, prognose, prognose_rate_scaled,
};
use prognos_sim::bearing::tables::{RATE_PIVOT, rate_state_prior};
use prognos_sim::bearing::train::{Dataset, GP_POINTS, feature_noise_variance, rate_prior, train};
use prognos_sim::bearing::trial::{Trial, TrialGenerator};
use rayon::prelude::*;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let first_seed: u64 = args.get(1).map_or(Ok(100), |s| s.parse())?;
    let count: usize = args.get(2).map_or(Ok(60), |s| s.parse())?;
    let mode = args.get(3).map_or("imm8", |s| s.as_str()).to_string();
    let walk: f64 = args.get(4).map_or(Ok(1e-5), |s| s.parse())?;
    let generator = TrialGenerator::new();
    let trials: Vec<Trial> = (0..count as u64)
        .into_par_iter()
        .map(|i| generator.trial(first_seed + i))
        .collect();
    let (train_set, test_set) = trials.split_at(8);
    let refs: Vec<&Trial> = train_set.iter().collect();
    let settings = PrognosisSettings {
        measurement_variance: feature_noise_variance(&refs),
        ..PrognosisSettings::default()
    };
    let gps: Vec<Box<BearingGp>> = train_set
        .par_iter()
        .map(|t| train(&Dataset::from_trials(&[t]), GP_POINTS)?.to_core::<GP_POINTS>())
        .collect::<anyhow::Result<_>>()?;
    let g = |i: usize| &*gps[i];
    let pooled = train(&Dataset::from_trials(&refs), GP_POINTS)?.to_core::<GP_POINTS>()?;
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
    let rows: Vec<String> = test_set
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
            for q in &p.predictions {
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
            Ok(s)
        })
        .collect::<anyhow::Result<_>>()?;
    println!("seed,eol,cycle,true_rul,median,p05,p95,estimate,truth,rate,q,s");
    for r in rows {
        print!("{r}");
    }
    eprintln!("R = {}", settings.measurement_variance);
    Ok(())
}
