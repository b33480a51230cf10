use prognos_core::filter::adaptive::Method;
use prognos_sim::reaction_wheel::{FaultScenario, Step2Settings, run_step2};
fn main() {
    let seed: u64 = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(1);
    // Optional interval range to print in full, e.g. `150 200`.
    let range: Vec<usize> = std::env::args()
        .skip(2)
        .filter_map(|s| s.parse().ok())
        .collect();
    for sc in [
        FaultScenario::ExcessiveLoss,
        FaultScenario::InsufficientInjection,
    ] {
        let t0 = std::time::Instant::now();
        let o = run_step2(&Step2Settings::new(Method::Apf), sc, seed);
        for k in (0..o.time.len()).filter(|k| match range.as_slice() {
            [from, to] => (*from..*to).contains(k),
            _ => *k < 12 || (38..52).contains(k) || k % 10 == 0,
        }) {
            println!(
                "{:.0} T {:.2}/{:.2} two ({:.2},{:.3}) kf ({:.2},{:.3}) truth ({:.1},{:.3})",
                o.time[k] / 60.0,
                o.temperature[k].0,
                o.temperature[k].1,
                o.two_step[k].0,
                o.two_step[k].1 * 1e6,
                o.kalman[k].0,
                o.kalman[k].1 * 1e6,
                o.truth[k].0,
                o.truth[k].1 * 1e6
            );
        }
        println!(
            "{sc:?} two {:?} kf {:?} {:.1}s",
            o.two_step_rmspe,
            o.kalman_rmspe,
            t0.elapsed().as_secs_f64()
        );
    }
}
