//! The valve pipeline in single precision (as on the Cortex-M4F) against double precision:
//! the same truth plant, measurements and seeds, the particle filter computing in f32 or f64.

use prognos_core::plants::valve::idx;
use prognos_sim::valve::{
    RunResult, SAMPLE_DT, SAMPLES_PER_CYCLE, ValveSetup, cycle_input, fast_bottom_leak_experiment,
    run_experiment_in,
};

/// Bottom external leak growing five times faster than in Table 2 (EOL near 20 cycles), all
/// continuous sensors, 200 particles, predictions at cycles 6, 10 and 14.
fn run<T: prognos_core::Real>() -> (RunResult, f64) {
    let setup = ValveSetup::new();
    let exp = fast_bottom_leak_experiment(&setup, 7);
    let w_true = exp.true_wear[4];
    (run_experiment_in::<T, 200>(&setup, &exp), w_true)
}

/// The filter model itself: one 30 s cycle of the campaign's physics (quiescent shortcut on)
/// from the same damaged state, sample by sample, in f32 and f64.
#[test]
fn f32_valve_model_follows_f64_through_a_cycle() {
    let setup = ValveSetup::new();
    let p64 = setup.params;
    let p32 = p64.cast_to::<f32>();
    let mut s64 = p64.nominal_state(6000.0, 40000.0, [0.0, 0.2, 0.0, 0.0, 1.0e-8]);
    s64[idx::A_EB] = 5.0e-6;
    let mut s32 = s64.map(|v| v as f32);
    let (mut worst_x, mut worst_p) = (0.0f64, 0.0f64);
    for k in 0..SAMPLES_PER_CYCLE {
        let u = cycle_input(&p64, k);
        s64 = p64.advance(&s64, &u, SAMPLE_DT);
        s32 = p32.advance(&s32, &u.map(|v| v as f32), SAMPLE_DT as f32);
        let o64 = p64.outputs(&s64, &u);
        let o32 = p32.outputs(&s32, &u.map(|v| v as f32));
        worst_x = worst_x.max((f64::from(o32[0]) - o64[0]).abs());
        worst_p = worst_p.max((f64::from(o32[2]) - o64[2]).abs());
    }
    // Position within 0.5 mm (of a 38 mm stroke) and pressures within 1 % of supply.
    assert!(worst_x < 5.0e-4, "position differs by {worst_x} m");
    assert!(
        worst_p < 0.01 * p64.p_supply,
        "bottom pressure differs by {worst_p} Pa"
    );
    for i in [idx::K, idx::A_EB] {
        let (a, b) = (f64::from(s32[i]), s64[i]);
        assert!(
            (a - b).abs() <= 1e-4 * b.abs(),
            "state {i}: f32 {a} vs f64 {b}"
        );
    }
}

/// The whole estimation run. A particle filter's resampling amplifies rounding differences
/// into a different (equally valid) particle cloud, so sample-by-sample equality is not
/// expected; the quantities the pipeline reports agree: the wear estimate averaged over the
/// cycles after convergence and the median RUL at every prediction point within 1 %.
#[test]
fn f32_valve_run_is_within_one_percent_of_f64() {
    let (double, w_true) = run::<f64>();
    let (single, _) = run::<f32>();
    assert_eq!(single.true_eol, double.true_eol);
    let w64 = &double.estimate_per_cycle[0];
    let w32 = &single.estimate_per_cycle[0];
    assert_eq!(w32.len(), w64.len());
    let settled = |w: &[f64]| w[4..].iter().sum::<f64>() / (w.len() - 4) as f64;
    let (m32, m64) = (settled(w32), settled(w64));
    println!(
        "mean wear after cycle 4: f32 {:.4} f64 {:.4} of the truth; PRMSE_w f32 {:.2} f64 {:.2}",
        m32 / w_true,
        m64 / w_true,
        single.prmse_w[0],
        double.prmse_w[0]
    );
    assert!(
        (m32 - m64).abs() <= 0.01 * m64,
        "mean wear f32 {m32:e} vs f64 {m64:e}"
    );
    // Every end-of-cycle estimate of both runs stays within 5 % of the truth after cycle 4.
    for (c, (a, b)) in w32.iter().zip(w64).enumerate().skip(4) {
        assert!(
            (a - w_true).abs() < 0.05 * w_true,
            "f32 cycle {c}: {a:e} vs {w_true:e}"
        );
        assert!(
            (b - w_true).abs() < 0.05 * w_true,
            "f64 cycle {c}: {b:e} vs {w_true:e}"
        );
    }
    assert_eq!(single.predictions.len(), 3);
    assert_eq!(double.predictions.len(), 3);
    for (p32, p64) in single.predictions.iter().zip(&double.predictions) {
        println!(
            "t_P {}: median RUL f32 {} f64 {} (true {}); mean f32 {:.2} f64 {:.2}",
            p64.t_p, p32.median_rul, p64.median_rul, p64.true_rul, p32.mean_rul, p64.mean_rul
        );
        assert!(
            (p32.median_rul - p64.median_rul).abs() <= 0.01 * p64.median_rul,
            "median RUL at {}: f32 {} vs f64 {}",
            p64.t_p,
            p32.median_rul,
            p64.median_rul
        );
    }
}
