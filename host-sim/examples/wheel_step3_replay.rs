//! Table 7's loss side on stored thermometer readings: `cargo run --release -p prognos-sim
//! --example wheel_step3_replay -- [first seed] [runs]`. The burst thermometer dominates the
//! cost of a three-month run; its readings are computed once per (scenario, seed) and kept
//! in `target/wheel-readings/` (delete it when the thermometer changes). Replaying them is
//! bit-identical to `run_step3`. Prints per-run predictions, the thermometer's error
//! statistics and the Table 7 summary of the log-linear Kalman filter. `REPLAY_DAYS` (default
//! 60.1) sets the simulated days: the predictions at days 30 and 60 are those of the 90-day run.
use prognos_core::filter::adaptive::Method;
use prognos_sim::reaction_wheel::{
    BurstReading, DAY_S, FaultScenario, INTERVAL_S, RulPrediction, Step3Settings,
    run_step3_from_readings, step3_readings,
};
use rayon::prelude::*;
use std::path::PathBuf;

fn cache_path(scenario: FaultScenario, seed: u64) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../target/wheel-readings");
    let _ = std::fs::create_dir_all(&dir);
    dir.join(format!("{scenario:?}-{seed}.bin"))
}

fn readings(settings: &Step3Settings, scenario: FaultScenario, seed: u64) -> Vec<BurstReading> {
    let needed = (settings.days * DAY_S / INTERVAL_S).round() as usize;
    // Diagnosis: a synthetic thermometer, the truth plus white Gaussian noise of this std.
    if let Some(sigma) = std::env::var("REPLAY_SYNTHETIC")
        .ok()
        .and_then(|v| v.parse::<f64>().ok())
    {
        use rand_core::SeedableRng;
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(seed ^ 0x5EED);
        let burst = settings.step2.thermometer.burst_s;
        return (0..needed)
            .map(|k| {
                let t = k as f64 * INTERVAL_S + 0.5 * (INTERVAL_S - burst) + burst;
                BurstReading {
                    estimate: scenario.long_temperature(t)
                        + sigma * prognos_core::random::standard_normal::<f64, _>(&mut rng),
                    std: sigma,
                }
            })
            .collect();
    }
    let path = cache_path(scenario, seed);
    if let Ok(bytes) = std::fs::read(&path) {
        let values: Vec<f64> = bytes
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().unwrap_or([0; 8])))
            .collect();
        let stored: Vec<BurstReading> = values
            .chunks_exact(2)
            .map(|p| BurstReading {
                estimate: p[0],
                std: p[1],
            })
            .collect();
        // A longer record holds the shorter one as its prefix (the thermometer is causal).
        if stored.len() >= needed {
            return stored;
        }
    }
    let r = step3_readings(settings, scenario, seed);
    let bytes: Vec<u8> = r
        .iter()
        .flat_map(|x| [x.estimate.to_le_bytes(), x.std.to_le_bytes()])
        .flatten()
        .collect();
    let _ = std::fs::write(&path, bytes);
    r
}

/// Thermometer errors against the truth at the burst's end: RMS, share beyond 0.6 degC,
/// lag-1 autocorrelation, RMS of the normalised error `e / std`.
fn thermometer_stats(scenario: FaultScenario, r: &[BurstReading], burst_s: f64) -> [f64; 4] {
    let errors: Vec<(f64, f64)> = r
        .iter()
        .enumerate()
        .map(|(k, x)| {
            let t = k as f64 * INTERVAL_S + 0.5 * (INTERVAL_S - burst_s) + burst_s;
            (x.estimate - scenario.long_temperature(t), x.std)
        })
        .collect();
    let n = errors.len().max(1) as f64;
    let ms = errors.iter().map(|e| e.0 * e.0).sum::<f64>() / n;
    let big = errors.iter().filter(|e| e.0.abs() > 0.6).count() as f64 / n;
    let lag1 = errors.windows(2).map(|w| w[0].0 * w[1].0).sum::<f64>() / n / ms.max(1e-300);
    let z = (errors
        .iter()
        .map(|e| (e.0 / e.1.max(1e-3)).powi(2))
        .sum::<f64>()
        / n)
        .sqrt();
    [ms.sqrt(), 100.0 * big, lag1, z]
}

fn main() {
    let args: Vec<u64> = std::env::args()
        .skip(1)
        .filter_map(|s| s.parse().ok())
        .collect();
    let first = args.first().copied().unwrap_or(3000);
    let runs = args.get(1).copied().unwrap_or(20);
    let verbose = std::env::var_os("REPLAY_VERBOSE").is_some();
    let mut settings = Step3Settings::new(Method::Apf);
    // The predictions at days 30 and 60 need only the first 60 days of the three months.
    settings.days = std::env::var("REPLAY_DAYS")
        .ok()
        .and_then(|d| d.parse().ok())
        .unwrap_or(60.1);
    let env = |name: &str| std::env::var(name).ok().and_then(|v| v.parse::<f64>().ok());
    settings.kalman_only = std::env::var_os("REPLAY_ALL").is_none();
    if let Some(v) = env("REPLAY_POSTERIOR_STD") {
        settings.step2.posterior_temperature_std = v > 0.0;
    }
    if let Some(v) = env("REPLAY_BIAS") {
        settings.step2.kalman_bias_compensation = v > 0.0;
    }
    if let Some(v) = env("REPLAY_CUSUM_CAP") {
        settings.step2.kalman_change_increment_cap = v;
    }
    if let Some(v) = env("REPLAY_TEMPERATURE_STD") {
        settings.step2.temperature_std = v;
    }
    let mut covered_all = 0;
    let mut total = 0;
    for scenario in [
        FaultScenario::ExcessiveLoss,
        FaultScenario::InsufficientInjection,
    ] {
        let rows: Vec<_> = (first..first + runs)
            .into_par_iter()
            .map(|seed| {
                let r = readings(&settings, scenario, seed);
                let stats = thermometer_stats(scenario, &r, settings.step2.thermometer.burst_s);
                (
                    seed,
                    stats,
                    run_step3_from_readings(&settings, scenario, seed, &r),
                )
            })
            .collect();
        let mut per_day: [Vec<RulPrediction>; 2] = [Vec::new(), Vec::new()];
        let mut changes = 0;
        let mut thermo = [0.0; 4];
        for (seed, stats, o) in &rows {
            changes += o.kalman_changes;
            for (a, b) in thermo.iter_mut().zip(stats) {
                *a += b / runs as f64;
            }
            for (i, p) in o.kalman_predictions.iter().enumerate() {
                if let Some(v) = per_day.get_mut(i) {
                    v.push(*p);
                }
            }
            if verbose {
                let preds: Vec<String> = o
                    .kalman_predictions
                    .iter()
                    .map(|p| {
                        format!(
                            "d{} {:.2}% {} [{:.3} {:.3} {:.3}]",
                            p.day,
                            p.error(),
                            if p.covered() { "in " } else { "OUT" },
                            p.p05,
                            p.median,
                            p.p95
                        )
                    })
                    .collect();
                println!(
                    "{scenario:?} {seed} thermo rms {:.2} big {:.1}% lag1 {:.2} z {:.2} changes {} | {}",
                    stats[0],
                    stats[1],
                    stats[2],
                    stats[3],
                    o.kalman_changes,
                    preds.join(" | ")
                );
            }
        }
        println!(
            "{scenario:?}: thermometer rms {:.3} degC, {:.1} % beyond 0.6, lag-1 {:.2}, z-rms {:.2}; {:.1} changes per run ({:.0} days)",
            thermo[0],
            thermo[1],
            thermo[2],
            thermo[3],
            f64::from(changes) / runs as f64,
            settings.days
        );
        for v in &per_day {
            let n = v.len().max(1) as f64;
            let covered = v.iter().filter(|p| p.covered()).count();
            covered_all += covered;
            total += v.len();
            println!(
                "  day {:.0}: mean {:.2} % max {:.2} %, covered {}/{} mean width {:.2} d",
                v.first().map_or(f64::NAN, |p| p.day),
                v.iter().map(RulPrediction::error).sum::<f64>() / n,
                v.iter().map(RulPrediction::error).fold(0.0, f64::max),
                covered,
                v.len(),
                v.iter().map(|p| p.p95 - p.p05).sum::<f64>() / n,
            );
        }
    }
    println!(
        "covered {covered_all}/{total} = {:.1} %",
        100.0 * covered_all as f64 / total.max(1) as f64
    );
}
