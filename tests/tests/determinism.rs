//! Same seed, same bits: the filters own no randomness, so a run is a pure function of the
//! caller's seed.

use nalgebra::{Vector1, Vector2};
use prognos_core::filter::particle::{ParticleFilter, PfConfig};
use prognos_core::filter::resample::Resampling;
use prognos_core::model::Stochastic;
use prognos_tests::linear_gaussian::{input, oscillator};
use rand_core::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;

const N: usize = 500;

/// Runs the PF 60 steps from `seed` and returns its particles and log weights as raw bits.
fn run(seed: u64, scheme: Resampling) -> (Vec<[u64; 2]>, Vec<u64>) {
    let model = oscillator();
    let config = PfConfig {
        resampling: scheme,
        resample_threshold: 0.7,
        random_walk_std: Vector2::new(0.0, 0.01),
        roughening: Vector2::new(0.05, 0.0),
        ..PfConfig::default()
    };
    let mut pf = ParticleFilter::<f64, 2, N>::new(Vector2::zeros(), config).unwrap();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    pf.init_gaussian(&Vector2::new(1.0, 0.0), &Vector2::new(0.5, 0.5), &mut rng)
        .unwrap();
    // The measurements are fixed (seed 0) so only the filter's own stream changes with `seed`.
    let mut world = Xoshiro256PlusPlus::seed_from_u64(0);
    let mut truth = Vector2::new(1.0, 0.0);
    let mut resampled = 0;
    for k in 0..60 {
        let u = Vector1::new(input(k));
        truth = model.sample_step(&truth, &u, 1.0, &mut world);
        let y = model.sample_measurement(&truth, &mut world);
        let report = pf
            .step(&model, &u, Some(y.as_slice()), 1.0, &mut rng)
            .unwrap();
        if report
            .flags
            .contains(prognos_core::safeguard::Flags::RESAMPLED)
        {
            resampled += 1;
        }
    }
    assert!(
        resampled > 5,
        "the run must exercise resampling ({resampled})"
    );
    let particles = pf
        .particles()
        .iter()
        .map(|p| [p[0].to_bits(), p[1].to_bits()])
        .collect();
    let weights = pf.log_weights().iter().map(|w| w.to_bits()).collect();
    (particles, weights)
}

#[test]
fn same_seed_gives_bit_identical_particles_and_weights() {
    for scheme in [
        Resampling::Systematic,
        Resampling::Stratified,
        Resampling::Residual,
        Resampling::Multinomial,
    ] {
        let a = run(42, scheme);
        let b = run(42, scheme);
        assert_eq!(a, b, "{scheme:?}: two runs with seed 42 differ");
        let c = run(43, scheme);
        let differing = a.0.iter().zip(&c.0).filter(|(x, y)| x != y).count();
        assert!(
            differing > N * 9 / 10,
            "{scheme:?}: seed 43 should move nearly every particle, moved {differing}"
        );
        // Weights differ too, unless both runs just resampled (uniform weights).
        let uniform = |w: &Vec<u64>| w.iter().all(|&b| b == w[0]);
        if !(uniform(&a.1) && uniform(&c.1)) {
            assert_ne!(a.1, c.1, "{scheme:?}: weights identical across seeds");
        }
    }
}
