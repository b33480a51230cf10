use prognos_core::filter::adaptive::Method;
use prognos_sim::reaction_wheel::{FaultScenario, Step3Settings, run_step3};
fn main() {
    let seed: u64 = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(1);
    let days: f64 = std::env::args()
        .nth(2)
        .and_then(|s| s.parse().ok())
        .unwrap_or(90.0);
    for sc in [
        FaultScenario::ExcessiveLoss,
        FaultScenario::InsufficientInjection,
    ] {
        let mut s = Step3Settings::new(Method::Apf);
        s.days = days;
        let o = run_step3(&s, sc, seed);
        println!(
            "{sc:?} two {:?} kf {:?} final {:?} {:.1}s",
            o.predictions, o.kalman_predictions, o.final_parameters, o.seconds
        );
    }
}
