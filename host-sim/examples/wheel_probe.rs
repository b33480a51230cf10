use prognos_core::filter::adaptive::Method;
use prognos_sim::plants::reaction_wheel::WheelSensors;
use prognos_sim::reaction_wheel::{Step1Settings, run_step1_f64};
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args.get(1).map_or(100, |s| s.parse().unwrap());
    let runs: u64 = args.get(2).map_or(3, |s| s.parse().unwrap());
    for high in [false, true] {
        for m in [Method::Plain, Method::AdaptiveResampling, Method::Apf] {
            let sensors = if high {
                WheelSensors::HIGH_NOISE
            } else {
                WheelSensors::LOW_NOISE
            };
            let mut s = Step1Settings::new(m, sensors);
            let env = |k: &str, d: f64| std::env::var(k).ok().map_or(d, |v| v.parse().unwrap());
            s.speed_process_std = env("SPS", s.speed_process_std);
            s.spread_speed = env("SPW", s.spread_speed);
            s.spread_temperature = env("SPT", s.spread_temperature);
            s.likelihood_threshold = env("PEFF", s.likelihood_threshold);
            s.temperature_walk = env("TW", s.temperature_walk);
            s.apf_gain = env("GAIN", s.apf_gain);
            s.apf_offset = env("OFF", s.apf_offset);
            s.ess_threshold = env("ESS", s.ess_threshold);
            s.apf_ess = env("AESS", s.apf_ess);
            let t0 = std::time::Instant::now();
            let (mut r, mut c, mut sp) = (0.0, 0.0, 0);
            for seed in 0..runs {
                let o = run_step1_f64(&s, n, seed);
                r += o.rmspe;
                c += o.coverage;
                sp += o.spreads;
                if seed == 0 && args.get(3).is_some() {
                    for k in (0..o.estimate.len()).step_by(200) {
                        println!(
                            "{:.1} {:.3} {:.3} [{:.3} {:.3}]",
                            k as f64 * 0.05,
                            o.truth[k],
                            o.estimate[k],
                            o.interval[k].0,
                            o.interval[k].1
                        );
                    }
                }
            }
            println!(
                "high={high} {m:?}: rmspe {:.3} cov {:.1} spreads {} ({:.2}s/run)",
                r / runs as f64,
                c / runs as f64,
                sp,
                t0.elapsed().as_secs_f64() / runs as f64
            );
        }
    }
}
