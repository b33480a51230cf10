//! Stable fallback of the cargo-fuzz targets in `fuzz/` (issue 9): every filter step and every
//! pipeline `step` fed arbitrary inputs (ordinary values mixed with NaN, infinities,
//! subnormals, huge magnitudes; zero, negative and enormous `dt`). The harnesses in
//! `prognos_tests::fuzz` check that nothing panics and that each step either leaves a finite
//! state (normalised weights, symmetric PSD covariances) or returns `Err` with the object
//! unchanged bit for bit. Seeded: every run explores the same cases.

use prognos_core::filter::adaptive_ukf::Adaptation;
use prognos_tests::fuzz::{self, Feed};
use proptest::prelude::*;
use proptest::test_runner::RngSeed;

/// `PROGNOS_FUZZ_CASES` raises the case count for a deeper local run (CI uses the default).
fn config(cases: u32, seed: u64) -> ProptestConfig {
    let cases = std::env::var("PROGNOS_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(cases);
    ProptestConfig {
        cases,
        rng_seed: RngSeed::Fixed(seed),
        failure_persistence: None,
        ..ProptestConfig::default()
    }
}

/// Mostly ordinary values in [-8, 8] (read by the harnesses as nominal + spread * v), one in
/// eight chosen among the hostile ones, one in sixteen any bit pattern at all.
fn value() -> impl Strategy<Value = f64> {
    prop_oneof![
        14 => -8.0..8.0f64,
        2 => prop::sample::select(vec![
            f64::NAN,
            -f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::MAX,
            f64::MIN,
            1e300,
            -1e200,
            1e30,
            f64::MIN_POSITIVE,
            5e-324,
            -5e-324,
            0.0,
            -0.0,
            100.0,
            -100.0,
        ]),
        1 => prop::num::f64::ANY,
    ]
}

fn values(len: usize) -> impl Strategy<Value = Vec<f64>> {
    prop::collection::vec(value(), 1..len)
}

fn run(harness: fn(&mut Feed<'_>) -> Result<(), String>, v: &[f64]) -> Result<(), TestCaseError> {
    harness(&mut Feed::new(v)).map_err(TestCaseError::fail)
}

proptest! {
    #![proptest_config(config(48, 9001))]

    #[test]
    fn particle_filter_f64(v in values(200)) {
        run(fuzz::particle_filter::<f64>, &v)?;
    }

    #[test]
    fn particle_filter_f32(v in values(200)) {
        run(fuzz::particle_filter::<f32>, &v)?;
    }

    #[test]
    fn ukf_linear_and_nonlinear(v in values(400)) {
        run(fuzz::ukf, &v)?;
    }

    #[test]
    fn aukf_covariance_matching(v in values(200)) {
        run(|f| fuzz::adaptive_ukf(f, Adaptation::CovarianceMatching), &v)?;
    }

    #[test]
    fn aeukf_enhanced(v in values(200)) {
        run(|f| fuzz::adaptive_ukf(f, Adaptation::Enhanced), &v)?;
    }

    #[test]
    fn gp_ukf_and_imm(v in values(200)) {
        run(fuzz::gp_ukf_imm, &v)?;
    }

    #[test]
    fn gp_ukf_with_rate_state(v in values(200)) {
        run(fuzz::gp_rate_ukf, &v)?;
    }

    #[test]
    fn oriv(v in values(400)) {
        run(fuzz::oriv, &v)?;
    }

    #[test]
    fn reaction_wheel_pipeline(v in values(350)) {
        run(fuzz::reaction_wheel, &v)?;
    }

    #[test]
    fn scooter_pipeline(v in values(300)) {
        run(fuzz::scooter, &v)?;
    }

    #[test]
    fn edge_pipeline(v in values(600)) {
        run(fuzz::edge, &v)?;
    }

    /// The byte decoder of the cargo-fuzz targets drives the same harnesses.
    #[test]
    fn fuzzer_byte_decoding(bytes in prop::collection::vec(any::<u8>(), 0..900)) {
        let v = Feed::decode(&bytes);
        run(fuzz::particle_filter::<f64>, &v)?;
        run(fuzz::scooter, &v)?;
    }
}
