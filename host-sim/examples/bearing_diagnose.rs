//! Per-prediction dump of the bearing campaign's IMM of 8 GP-UKFs, for diagnosing where in life
//! the alpha band is missed. Usage:
//! cargo run --release -p prognos-sim --example bearing_diagnose -- [first_seed] [trials] > out.csv
use prognos_sim::bearing::prognosis::{BearingGp, PrognosisSettings, prognose};
use prognos_sim::bearing::train::{Dataset, GP_POINTS, feature_noise_variance, train};
use prognos_sim::bearing::trial::{Trial, TrialGenerator};
use rayon::prelude::*;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let first_seed: u64 = args.get(1).map_or(Ok(100), |s| s.parse())?;
    let count: usize = args.get(2).map_or(Ok(60), |s| s.parse())?;
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
    let rows: Vec<String> = test_set
        .par_iter()
        .map(|t| {
            let p = prognose(std::array::from_fn::<_, 8, _>(g), t, &settings)?;
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
