//! End-to-end checks of the electric-scooter pipeline against the truth plant
//! (Yu et al. 2020, experiments 1 and 2).

use prognos_core::filter::adaptive_ukf::Adaptation;
use prognos_sim::plants::scooter::Profile;
use prognos_sim::scooter::{DESIGNED_RUL, estimates, run, run_with};

#[test]
fn aeukf_tracks_every_interval_and_the_plain_filters_lag() {
    for (profile, seed) in [(Profile::EXPERIMENT1, 3), (Profile::EXPERIMENT2, 4)] {
        let trace = run(profile, Adaptation::Enhanced, seed);
        let e = estimates(&profile, &trace);
        for ((_, _, truth), est) in profile.beta_intervals.iter().zip(&e.beta) {
            assert!((est - truth).abs() < 0.02, "beta {est} vs {truth}");
        }
        // R_rv absorbs the drawn uncertainty of the other frictions (about 4 % per run).
        assert!((e.r_rv / 0.469 - 1.0).abs() < 0.08, "R_rv {}", e.r_rv);
        assert!((e.k1 / 10.02 - 1.0).abs() < 0.05, "K1 {}", e.k1);
        // Fault estimation starts just after the first fault (t = 10 s), not before.
        let activation = trace.activation.expect("fault detected");
        assert!((10.0..10.5).contains(&activation), "{activation}");
        let lagging = run(profile, Adaptation::None, seed);
        let l = estimates(&profile, &lagging);
        let (_, _, second) = profile.beta_intervals[1];
        assert!(
            (l.beta[1] - second).abs() > 0.05,
            "UKF should lag: {}",
            l.beta[1]
        );
    }
}

#[test]
fn sequential_prognosis_matches_the_designed_ruls() {
    let trace = run(Profile::EXPERIMENT1, Adaptation::Enhanced, 5);
    let usage1 = trace
        .predictions
        .iter()
        .find(|p| p.usage == 1)
        .expect("usage 1");
    let usage2 = trace
        .predictions
        .iter()
        .find(|p| p.usage == 2)
        .expect("reactivated");
    for (p, truth, min_ra) in [
        (usage1, DESIGNED_RUL[0], 95.0),
        (usage2, DESIGNED_RUL[1], 92.0),
    ] {
        assert_eq!(p.samples.len(), 80);
        let mean = p.samples.iter().sum::<f64>() / 80.0;
        let ra = 100.0 * (1.0 - (truth - mean).abs() / truth);
        assert!(ra >= min_ra, "usage {} RA {ra}", p.usage);
        let mut s = p.samples.clone();
        s.sort_by(f64::total_cmp);
        assert!(
            s[1] <= truth && truth <= s[78],
            "{truth} outside [{}, {}]",
            s[1],
            s[78]
        );
    }
    assert!(!trace.refused_reactivation);
    // Experiment 2: the change after the usage switch is non-monotonic, so no reactivation.
    let trace2 = run(Profile::EXPERIMENT2, Adaptation::Enhanced, 5);
    assert!(trace2.refused_reactivation);
    assert!(trace2.predictions.iter().all(|p| p.usage == 1));
    let p = &trace2.predictions[0];
    assert!((p.rul - DESIGNED_RUL[2]).abs() < 0.5, "{}", p.rul);
}

#[test]
fn f32_pipeline_stays_within_one_percent_of_f64() {
    let profile = Profile::EXPERIMENT1;
    let a = run_with::<f64>(profile, Adaptation::Enhanced, 6);
    let b = run_with::<f32>(profile, Adaptation::Enhanced, 6);
    let (ea, eb) = (estimates(&profile, &a), estimates(&profile, &b));
    for (x, y) in ea.beta.iter().zip(&eb.beta) {
        assert!((x - y).abs() / x < 0.01, "beta f64 {x} f32 {y}");
    }
    assert!(
        (ea.r_rv - eb.r_rv).abs() / ea.r_rv < 0.01,
        "{} {}",
        ea.r_rv,
        eb.r_rv
    );
    assert!((ea.k1 - eb.k1).abs() / ea.k1 < 0.01);
    let ra = a.predictions.iter().find(|p| p.usage == 1).unwrap().rul;
    let rb = b.predictions.iter().find(|p| p.usage == 1).unwrap().rul;
    assert!((ra - rb).abs() / ra < 0.01, "RUL f64 {ra} f32 {rb}");
}

#[test]
fn arrs_are_consistent_without_faults_and_give_cv_110_with_the_compound_fault() {
    use prognos_core::diagnose::scooter::{ScooterArr, fault, suspected_faults};
    use prognos_sim::plants::scooter::{ScooterPlant, SensorNoise};
    use rand_core::SeedableRng;
    for seed in 0..3 {
        let mut healthy = Profile::EXPERIMENT1;
        healthy.friction_fault.0 = f64::INFINITY;
        healthy.beta_intervals = [(f64::INFINITY, f64::INFINITY, 1.0); 4];
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(seed);
        let mut plant = ScooterPlant::new(healthy, SensorNoise::default(), &mut rng);
        let mut arr = ScooterArr::<f64>::nominal();
        for _ in 0..1500 {
            let (u, y) = plant.sample(0.02, &mut rng);
            let r = arr.step(u, &[y[0], y[1], y[2]], 0.02).unwrap();
            assert_eq!(r.cv, 0, "false alarm at {} s: {:?}", plant.time, r);
        }
    }
    let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(9);
    let mut plant = ScooterPlant::new(Profile::EXPERIMENT1, SensorNoise::default(), &mut rng);
    let mut arr = ScooterArr::<f64>::nominal();
    let mut cv_counts = [0usize; 8];
    for _ in 0..750 {
        let (u, y) = plant.sample(0.02, &mut rng);
        let r = arr.step(u, &[y[0], y[1], y[2]], 0.02).unwrap();
        if plant.time > 11.0 {
            cv_counts[usize::from(r.cv)] += 1;
        }
    }
    // Between 11 and 15 s the coherence vector is [1 1 0] (bits 0 and 1) nearly always.
    let total: usize = cv_counts.iter().sum();
    assert!(
        cv_counts[0b011] as f64 > 0.95 * total as f64,
        "{cv_counts:?}"
    );
    assert_eq!(
        suspected_faults(0b011),
        fault::BETA_THETA_R | fault::R_RV | fault::K1
    );
}
