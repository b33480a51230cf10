use prognos_core::filter::adaptive::Method;
use prognos_sim::reaction_wheel::{BurstThermometer, FaultScenario, INTERVAL_S, Step3Settings};
fn main() {
    let s = Step3Settings::new(Method::Apf);
    let days: f64 = std::env::args()
        .nth(1)
        .and_then(|v| v.parse().ok())
        .unwrap_or(2.0);
    for seed in 3000..3004u64 {
        for sc in [
            FaultScenario::ExcessiveLoss,
            FaultScenario::InsufficientInjection,
        ] {
            let mut th = BurstThermometer::<32>::new(s.step2.thermometer, seed).unwrap();
            let n = (days * 86400.0 / INTERVAL_S) as usize;
            let (mut se, mut maxe, mut big) = (0.0f64, 0.0f64, 0usize);
            for k in 0..n {
                let t0 = k as f64 * INTERVAL_S;
                let burst = s.step2.thermometer.burst_s;
                let start = t0 + 0.5 * (INTERVAL_S - burst);
                let est = th.burst(start, |t| sc.long_temperature(t));
                let e = est - sc.long_temperature(start + burst);
                se += e * e;
                maxe = maxe.max(e.abs());
                if e.abs() > 0.6 {
                    big += 1;
                }
            }
            println!(
                "seed {seed} {sc:?} rms {:.3} max {:.2} >0.6: {big}/{n}",
                (se / n as f64).sqrt(),
                maxe
            );
        }
    }
}
