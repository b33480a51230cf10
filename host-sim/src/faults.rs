//! Fault-injection experiment (issue 9): RUL error of each system with an RUL under 5 %
//! dropouts plus 1 % outliers, against clean runs of the same seeds (same plant and sensor
//! noise; the faults come from their own random stream). `prognos faults` prints the table
//! that `docs/results.md` quotes.
//!
//! Systems: the linear test system (lockstep runner, Kalman filter with an innovation gate),
//! the scooter (AEUKF pipeline with its spike hold, experiment 1, both RUL predictions), the
//! reaction wheel (`pipeline::ReactionWheel` over the firmware's 300 s scenario, faults on the
//! current and speed samples, the RUL at the end) and the valve (its cycle-level runner, the
//! Table 2 bottom-leak experiment on the pressure sensors) and the bearing (the GP-UKF with
//! the online log-rate state on generated trials, faults on the vibration feature).

use crate::campaign::simulate;
use crate::lockstep::{InjectedFaults, RunRecord};
use crate::plants::scooter::Profile;
use crate::registry::{EmbeddedScenario, Registry};
use crate::scenario::SensorFaults;
use crate::scooter::{DESIGNED_RUL, run_with_faults};
use prognos_core::filter::adaptive_ukf::Adaptation;
use rayon::prelude::*;

/// The linear test system with the innovation gate and the fault options of the experiment.
pub const LINEAR_FAULTS: EmbeddedScenario = EmbeddedScenario {
    path: "host-sim/scenarios/linear_degradation_faults.toml",
    text: include_str!("../scenarios/linear_degradation_faults.toml"),
};

/// One row of the table: a system under one fault case over `runs` seeds.
#[derive(Clone, Debug, PartialEq)]
pub struct FaultRow {
    pub system: &'static str,
    pub case: String,
    pub runs: usize,
    /// Runs that failed or produced no RUL prediction.
    pub lost: usize,
    /// Mean over runs of the run's mean absolute RUL error (s).
    pub rul_error: f64,
    /// Samples rejected by the estimator, summed over runs.
    pub rejected: usize,
    /// Injected faults, summed over runs.
    pub injected: InjectedFaults,
}

/// The faults of the experiment: 5 % dropouts and 1 % outliers of `outlier_std`.
pub fn dropouts_and_outliers(outlier_std: f64) -> SensorFaults {
    SensorFaults {
        dropout_probability: 0.05,
        outlier_probability: 0.01,
        outlier_std,
        ..SensorFaults::default()
    }
}

/// Mean absolute error of the predicted mean RUL against the true RUL over a run's
/// predictions before end of life; `None` without predictions.
pub fn mean_rul_error(record: &RunRecord) -> Option<f64> {
    let h = &record.series.header;
    let predicted = h.iter().position(|c| c == "rul:mean")?;
    let truth = h.iter().position(|c| c == "rul:true")?;
    let errors: Vec<f64> = record
        .series
        .rows
        .iter()
        .filter_map(|r| {
            let (p, t) = (*r.get(predicted)?, *r.get(truth)?);
            (p.is_finite() && t.is_finite() && t > 0.0).then_some((p - t).abs())
        })
        .collect();
    (!errors.is_empty()).then(|| errors.iter().sum::<f64>() / errors.len() as f64)
}

fn add(a: &mut InjectedFaults, b: &InjectedFaults) {
    a.dropouts += b.dropouts;
    a.outliers += b.outliers;
    a.stuck += b.stuck;
    a.nan_burst += b.nan_burst;
    a.biased += b.biased;
    a.jittered += b.jittered;
}

fn summarise(
    system: &'static str,
    case: &str,
    results: Vec<Option<(f64, usize, InjectedFaults)>>,
) -> FaultRow {
    let runs = results.len();
    let kept: Vec<_> = results.into_iter().flatten().collect();
    let mut injected = InjectedFaults::default();
    for (_, _, i) in &kept {
        add(&mut injected, i);
    }
    FaultRow {
        system,
        case: case.to_string(),
        runs,
        lost: runs - kept.len(),
        rul_error: kept.iter().map(|k| k.0).sum::<f64>() / kept.len().max(1) as f64,
        rejected: kept.iter().map(|k| k.1).sum(),
        injected,
    }
}

/// The linear test system: clean, faulty with the innovation gate, faulty without it.
pub fn linear_rows(runs: usize, seed: u64) -> Vec<FaultRow> {
    let registry = Registry::builtin();
    let gated = LINEAR_FAULTS.text;
    let ungated = gated.replace("gate = 10.83", "");
    let cases: [(&str, &str, bool); 3] = [
        ("clean", gated, false),
        ("5 % dropouts + 1 % outliers (NIS gate)", gated, true),
        ("5 % dropouts + 1 % outliers (no gate)", &ungated, true),
    ];
    cases
        .iter()
        .map(|(case, text, faulty)| {
            let Ok(mut scenario) =
                crate::scenario::Scenario::parse(std::path::Path::new(LINEAR_FAULTS.path), text)
            else {
                return summarise("linear test system", case, vec![None; runs]);
            };
            scenario.seed = seed;
            if !faulty {
                scenario.sensor_faults = SensorFaults::default();
            }
            let results = (0..runs)
                .into_par_iter()
                .map(|run| {
                    let (record, _) = simulate(&registry, &scenario, run).ok()?;
                    let error = mean_rul_error(&record)?;
                    Some((error, record.rejected_steps, record.injected))
                })
                .collect();
            summarise("linear test system", case, results)
        })
        .collect()
}

/// The scooter, experiment 1: both RUL predictions (usage 1 and the reactivated usage 2)
/// against the designed RULs, mean of the Monte-Carlo samples.
pub fn scooter_rows(runs: usize, seed: u64) -> Vec<FaultRow> {
    // Outliers of 0.05 (50 times the rear encoder's noise, below the glitch detector's jump
    // limit, so they reach the filter).
    let cases = [
        ("clean", SensorFaults::default()),
        ("5 % dropouts + 1 % outliers", dropouts_and_outliers(0.05)),
        (
            "5 % dropouts only",
            SensorFaults {
                dropout_probability: 0.05,
                ..SensorFaults::default()
            },
        ),
        (
            "1 % outliers only",
            SensorFaults {
                outlier_probability: 0.01,
                outlier_std: 0.05,
                ..SensorFaults::default()
            },
        ),
    ];
    cases
        .iter()
        .map(|(case, faults)| {
            let results = (0..runs)
                .into_par_iter()
                .map(|run| {
                    let run_seed = crate::lockstep::mix_seed(seed, run as u64);
                    let trace = run_with_faults::<f64>(
                        Profile::EXPERIMENT1,
                        Adaptation::Enhanced,
                        run_seed,
                        *faults,
                    );
                    let mut errors = Vec::new();
                    for usage in [1u8, 2] {
                        let p = trace.predictions.iter().find(|p| p.usage == usage)?;
                        if p.samples.is_empty() {
                            return None;
                        }
                        let mean = p.samples.iter().sum::<f64>() / p.samples.len() as f64;
                        errors.push((mean - DESIGNED_RUL[usize::from(usage) - 1]).abs());
                    }
                    let error = errors.iter().sum::<f64>() / errors.len() as f64;
                    Some((error, trace.rejected, InjectedFaults::default()))
                })
                .collect();
            summarise("scooter (experiment 1)", case, results)
        })
        .collect()
}

/// The firmware's reaction-wheel scenario (plant, sensors, gauge, RUL settings), shared with
/// the firmware and its host reference test.
#[allow(dead_code)]
#[path = "../../firmware-example/src/scenario/wheel.rs"]
mod wheel_scenario;

/// The reaction wheel: `pipeline::ReactionWheel` (f64) over the firmware's 300 s scenario,
/// each run with its own plant and filter seeds; the faults hit the current and speed
/// samples (a dropout is a predict-only step; a dropped gauge reading merges its interval
/// into the next, the gauge being cumulative). Error: the final median RUL against the truth.
pub fn wheel_rows(runs: usize, seed: u64) -> Vec<FaultRow> {
    use prognos_core::pipeline::ReactionWheel;
    use rand_core::SeedableRng;
    use wheel_scenario as w;
    // Outliers of 0.15 (50 times the speed noise, 5 times the current noise).
    let cases = [
        ("clean", SensorFaults::default()),
        ("5 % dropouts + 1 % outliers", dropouts_and_outliers(0.15)),
    ];
    cases
        .iter()
        .map(|(case, faults)| {
            let results = (0..runs)
                .into_par_iter()
                .map(|run| {
                    let run_seed = crate::lockstep::mix_seed(seed, run as u64);
                    let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(run_seed);
                    let mut pipeline =
                        ReactionWheel::<f64, { w::N }, { w::M }>::new(w::config().ok()?, &mut rng)
                            .ok()?;
                    let mut plant = w::WheelPlant::<f64>::with_seed(run_seed ^ 0x00D1_5EA5E);
                    let mut injector = crate::lockstep::FaultInjector::new(*faults, run_seed);
                    let mut rejected = 0;
                    for k in 0..=w::STEPS {
                        if k > 0 {
                            plant.advance();
                        }
                        let y = w::convert::<f64>(&plant.sample());
                        let t = f64::from(k) * w::DT;
                        let mut wheel = [y.current, y.speed];
                        let told = injector.apply(t, w::DT, &mut wheel);
                        let measurement: Option<Vec<f64>> = wheel
                            .iter()
                            .all(|v| v.is_finite())
                            .then(|| wheel.iter().copied().chain(y.consumption).collect());
                        // An error rejects the sample and leaves the pipeline usable (e.g. a
                        // missing first sample: nothing to predict from yet); go on.
                        match pipeline.step(told, plant.command(), measurement.as_deref(), &mut rng)
                        {
                            Ok(report) if report.fused => {}
                            _ => rejected += 1,
                        }
                    }
                    let mut buffers = w::RulBuffers::<f64>::new();
                    let rul = w::predict_rul(&pipeline, &mut buffers, &mut rng).ok()?;
                    Some((
                        (rul.median - plant.true_rul()).abs(),
                        rejected,
                        injector.counts,
                    ))
                })
                .collect();
            summarise("reaction wheel (300 s scenario)", case, results)
        })
        .collect()
}

/// The valve: the Table 2 bottom-external-leak experiment with the pressure sensors
/// `{p_t, p_b}` (N = 500), faults on both pressures (outliers of 2.5e5 Pa, 50 times the
/// sensor noise; a dropout is a predict-only step). Error: mean over the prediction points
/// of |median RUL - true RUL| (cycles).
pub fn valve_rows(runs: usize, seed: u64) -> Vec<FaultRow> {
    use crate::valve::{ValveSetup, run_experiment, table2_experiment};
    use prognos_core::plants::valve::{DamageMode, MeasurementSet};
    let setup = ValveSetup::new();
    let cases = [
        ("clean", SensorFaults::default()),
        ("5 % dropouts + 1 % outliers", dropouts_and_outliers(2.5e5)),
    ];
    cases
        .iter()
        .map(|(case, faults)| {
            let results = (0..runs)
                .into_par_iter()
                .map(|run| {
                    let run_seed = crate::lockstep::mix_seed(seed, run as u64);
                    let mut exp = table2_experiment(
                        &setup,
                        DamageMode::BottomLeak,
                        MeasurementSet::Pressures,
                        run_seed,
                    );
                    exp.sensor_faults = *faults;
                    let r = run_experiment::<500>(&setup, &exp);
                    if r.predictions.is_empty() {
                        return None;
                    }
                    let error = r
                        .predictions
                        .iter()
                        .map(|p| (p.median_rul - p.true_rul).abs())
                        .sum::<f64>()
                        / r.predictions.len() as f64;
                    error
                        .is_finite()
                        .then_some((error, r.rejected_samples, r.injected))
                })
                .collect();
            summarise("valve (bottom leak, {p_t, p_b}; cycles)", case, results)
        })
        .collect()
}

/// The bearing: the campaign's method (one sparse GP on 8 training trials, GP-UKF with the online
/// log-rate state, the IMM's NIS gate at the chi-square 99.9 % point in both cases) on
/// `runs` test trials, faults on the feature from cycle 1 on (cycle 0 initialises the
/// filter): outliers of 1.0, ten times the feature's noise std and the whole normalised
/// range; a dropout is a predict-only cycle. Error: mean over the predictions of
/// |median RUL - true RUL| (cycles).
pub fn bearing_rows(runs: usize, seed: u64) -> Vec<FaultRow> {
    use crate::bearing::prognosis::{PrognosisSettings, prognose_rate_scaled};
    use crate::bearing::tables::{RATE_WALK_VARIANCE, gp_for, rate_state_prior};
    use crate::bearing::train::feature_noise_variance;
    use crate::bearing::trial::TrialGenerator;
    const TRAINING: u64 = 8;
    let generator = TrialGenerator::new();
    let lost = |case: &str| summarise(BEARING, case, vec![None; runs]);
    let trials: Vec<_> = (0..TRAINING + runs as u64)
        .into_par_iter()
        .map(|i| generator.trial(seed.wrapping_add(i)))
        .collect();
    let (training, test) = trials.split_at(TRAINING as usize);
    let training: Vec<_> = training.iter().collect();
    let Ok(gp) = gp_for(&training) else {
        return vec![lost("clean"), lost(FAULTY)];
    };
    let Ok(prior) = rate_state_prior::<2>(&gp, &training) else {
        return vec![lost("clean"), lost(FAULTY)];
    };
    let settings = PrognosisSettings {
        measurement_variance: feature_noise_variance(&training),
        outlier_gate: Some(10.83),
        ..PrognosisSettings::default()
    };
    let cases = [
        ("clean", SensorFaults::default()),
        (FAULTY, dropouts_and_outliers(1.0)),
    ];
    cases
        .iter()
        .map(|(case, faults)| {
            let results = test
                .par_iter()
                .map(|trial| {
                    let mut trial = trial.clone();
                    let mut injector = crate::lockstep::FaultInjector::new(*faults, trial.seed);
                    for (k, z) in trial.feature.iter_mut().enumerate().skip(1) {
                        let mut y = [*z];
                        injector.apply(k as f64, 1.0, &mut y);
                        *z = y[0];
                    }
                    let p = prognose_rate_scaled::<2, 5, 1>(
                        [(&*gp, prior)],
                        RATE_WALK_VARIANCE,
                        &trial,
                        &settings,
                    )
                    .ok()?;
                    let n = p.predictions.len();
                    let error = p
                        .predictions
                        .iter()
                        .map(|q| (q.median - q.true_rul).abs())
                        .sum::<f64>()
                        / n as f64;
                    (n > 0 && error.is_finite()).then_some((
                        error,
                        p.rejected_cycles,
                        injector.counts,
                    ))
                })
                .collect();
            summarise(BEARING, case, results)
        })
        .collect()
}

const BEARING: &str = "bearing (GP-UKF with log-rate state; cycles)";
const FAULTY: &str = "5 % dropouts + 1 % outliers";

/// The markdown table of [`linear_rows`], [`scooter_rows`], [`wheel_rows`], [`valve_rows`]
/// and [`bearing_rows`], with the ratio to the clean
/// error of the same system and the target (at most 2x, no run lost).
pub fn table(runs: usize, seed: u64, system: Option<&str>) -> anyhow::Result<String> {
    type Rows = fn(usize, u64) -> Vec<FaultRow>;
    const SYSTEMS: [(&str, Rows); 5] = [
        ("linear", linear_rows),
        ("scooter", scooter_rows),
        ("wheel", wheel_rows),
        ("valve", valve_rows),
        ("bearing", bearing_rows),
    ];
    if let Some(name) = system {
        anyhow::ensure!(
            SYSTEMS.iter().any(|(n, _)| *n == name),
            "unknown system '{name}' (known: linear, scooter, wheel, valve, bearing)"
        );
    }
    let mut out = String::from(
        "| system | case | runs | lost | mean abs RUL error (s) | vs clean | rejected samples (kept runs) | target (<= 2x, 0 lost) |\n|---|---|---|---|---|---|---|---|\n",
    );
    for (_, rows) in SYSTEMS
        .iter()
        .filter(|(n, _)| system.is_none_or(|s| s == *n))
    {
        let rows = rows(runs, seed);
        let clean = rows.first().map_or(f64::NAN, |r| r.rul_error);
        for r in &rows {
            let ratio = r.rul_error / clean;
            let verdict = if r.case == "clean" {
                "-".to_string()
            } else if ratio <= 2.0 && r.lost == 0 {
                "met".to_string()
            } else {
                "NOT met".to_string()
            };
            out.push_str(&format!(
                "| {} | {} | {} | {} | {:.3} | {:.2}x | {} | {} |\n",
                r.system, r.case, r.runs, r.lost, r.rul_error, ratio, r.rejected, verdict
            ));
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn faulty_linear_runs_lose_nothing_and_reject_what_was_injected() {
        let rows = linear_rows(3, 7);
        let (clean, gated) = (&rows[0], &rows[1]);
        assert_eq!(clean.lost, 0);
        // The 99.9 % gate rejects about one clean sample in a thousand (~500 per run).
        assert!(clean.rejected <= 5, "{clean:?}");
        assert_eq!(clean.injected.total(), 0);
        assert_eq!(gated.lost, 0);
        // Every dropout is rejected; outliers mostly are (some spikes are small).
        assert!(gated.injected.dropouts > 0 && gated.injected.outliers > 0);
        assert!(gated.rejected >= gated.injected.dropouts, "{gated:?}");
        assert!(gated.rejected <= gated.injected.dropouts + gated.injected.outliers + 5);
        assert!(gated.rul_error <= 2.0 * clean.rul_error, "{rows:?}");
    }

    #[test]
    fn faulty_scooter_runs_lose_nothing_and_stay_within_twice_the_clean_error() {
        // The documented table's runs (0 lost, 1.61x; with 5 runs the ratio is 2.8x: the
        // clean error is 0.03-0.04 s, so a single moved prediction dominates a small sample).
        let rows = scooter_rows(20, 20261201);
        let (clean, faulty) = (&rows[0], &rows[1]);
        assert_eq!((clean.lost, clean.rejected), (0, 0), "{rows:?}");
        assert_eq!(faulty.lost, 0, "{rows:?}");
        assert!(faulty.rejected > 0, "{rows:?}");
        assert!(faulty.rul_error <= 2.0 * clean.rul_error, "{rows:?}");
        assert!(clean.rul_error < 0.1, "{rows:?}");
    }

    #[test]
    fn faulty_bearing_runs_lose_nothing_and_reject_the_dropouts() {
        let rows = bearing_rows(4, 20261201);
        let (clean, faulty) = (&rows[0], &rows[1]);
        assert_eq!((clean.lost, faulty.lost), (0, 0), "{rows:?}");
        assert_eq!(clean.injected.total(), 0);
        assert!(faulty.injected.dropouts > 0 && faulty.injected.outliers > 0);
        // Dropouts are predict-only; outliers of 1.0 against a 0.1 noise std are mostly gated.
        assert!(faulty.rejected >= faulty.injected.dropouts, "{rows:?}");
        assert!(faulty.rul_error <= 2.0 * clean.rul_error, "{rows:?}");
    }

    #[test]
    fn faulty_wheel_runs_lose_nothing_and_keep_the_rul_within_two_percent() {
        let rows = wheel_rows(3, 20261201);
        let (clean, faulty) = (&rows[0], &rows[1]);
        assert_eq!((clean.lost, faulty.lost), (0, 0), "{rows:?}");
        assert_eq!(clean.injected.total(), 0);
        assert!(faulty.injected.dropouts > 0 && faulty.injected.outliers > 0);
        // Every dropout is a predict-only step, reported as not fused.
        assert!(faulty.rejected >= faulty.injected.dropouts, "{rows:?}");
        // The true RUL is about 1530 s: both within 2 % (30 s).
        assert!(
            clean.rul_error < 30.0 && faulty.rul_error < 30.0,
            "{rows:?}"
        );
    }
}
