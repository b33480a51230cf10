//! Per-seed step-3 RUL errors (Kalman filter and two-step PF) and change detections
//! (diagnosis of Table 7's spread): `-- FIRST_SEED COUNT DAYS`.
use prognos_core::filter::adaptive::Method;
use prognos_sim::reaction_wheel::{FaultScenario, Step3Settings, run_step3};
use rayon::prelude::*;
fn main() {
    let args: Vec<u64> = std::env::args()
        .skip(1)
        .filter_map(|s| s.parse().ok())
        .collect();
    let (first, count, days) = (
        args.first().copied().unwrap_or(3000),
        args.get(1).copied().unwrap_or(20),
        args.get(2).copied().unwrap_or(31),
    );
    for scenario in [
        FaultScenario::ExcessiveLoss,
        FaultScenario::InsufficientInjection,
    ] {
        let rows: Vec<_> = (first..first + count)
            .into_par_iter()
            .map(|seed| {
                let mut s = Step3Settings::new(Method::Apf);
                s.days = days as f64;
                (seed, run_step3(&s, scenario, seed))
            })
            .collect();
        for (seed, o) in rows {
            let describe = |predictions: &[_]| -> Vec<String> {
                predictions
                    .iter()
                    .map(|p: &prognos_sim::reaction_wheel::RulPrediction| {
                    format!(
                        "day {} err {:.2} % covered {} (truth {:.3} d, median {:.3}, 90 % {:.3}-{:.3})",
                        p.day,
                        p.error(),
                        p.covered(),
                        p.truth,
                        p.median,
                        p.p05,
                        p.p95
                    )
                    })
                    .collect()
            };
            println!(
                "{scenario:?} seed {seed} changes {} kf {} two-step {}",
                o.kalman_changes,
                describe(&o.kalman_predictions).join("; "),
                describe(&o.predictions).join("; ")
            );
        }
    }
}
