//! Per-run two-step RMSPE of Table 6 split before / after the fault (diagnosis):
//! `cargo run --release -p prognos-sim --example wheel_step2_sweep -- SEED RUNS`.
use prognos_core::filter::adaptive::Method;
use prognos_sim::reaction_wheel::{FaultScenario, Step2Settings, run_step2};
fn main() {
    let base: u64 = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(2000);
    let runs: u64 = std::env::args()
        .nth(2)
        .and_then(|s| s.parse().ok())
        .unwrap_or(20);
    for sc in [
        FaultScenario::ExcessiveLoss,
        FaultScenario::InsufficientInjection,
    ] {
        let mut tot = (0.0, 0.0);
        for seed in base..base + runs {
            let o = run_step2(&Step2Settings::new(Method::Apf), sc, seed);
            let err = |k: usize| {
                let (e, t) = (o.two_step[k], o.truth[k]);
                (100.0 * (e.0 - t.0) / t.0, 100.0 * (e.1 - t.1) / t.1)
            };
            let rms = |r: std::ops::Range<usize>| {
                let n = r.len() as f64;
                let (mut a, mut b) = (0.0, 0.0);
                for k in r {
                    let (x, y) = err(k);
                    a += x * x;
                    b += y * y;
                }
                ((a / n).sqrt(), (b / n).sqrt())
            };
            let pre = rms(5..39);
            let post = rms(40..50);
            let late = rms(50..90);
            tot.0 += o.two_step_rmspe.0;
            tot.1 += o.two_step_rmspe.1;
            println!(
                "{sc:?} {seed} all {:.2}/{:.2} pre {:.2}/{:.2} post10 {:.2}/{:.2} late {:.2}/{:.2} kf {:.2}/{:.2}",
                o.two_step_rmspe.0,
                o.two_step_rmspe.1,
                pre.0,
                pre.1,
                post.0,
                post.1,
                late.0,
                late.1,
                o.kalman_rmspe.0,
                o.kalman_rmspe.1
            );
        }
        println!(
            "{sc:?} mean {:.2}/{:.2}",
            tot.0 / runs as f64,
            tot.1 / runs as f64
        );
    }
}
