//! Model mismatch between the truth plant (2 ms) and the filter model (10 ms, fast-forward).
use prognos_core::plants::valve::SensorNoise;
use prognos_sim::valve::{SAMPLE_DT, SAMPLES_PER_CYCLE, TruthValve, ValveSetup, cycle_input};
fn main() {
    let setup = ValveSetup::new();
    let p = setup.params;
    for wear in [
        [0.0; 5],
        [0.0, 0.0, 0.0, 0.0, 3.7e-9],
        [0.0, 0.0, 0.0, 0.0, 1e-8],
    ] {
        let mut truth = TruthValve::new(wear, SensorNoise::default());
        let mut s = p.nominal_state(6000.0, 48000.0, wear);
        let mut worst = [0.0f64; 4];
        let t0 = std::time::Instant::now();
        let mut quiet = 0;
        for _cycle in 0..30 {
            for k in 0..SAMPLES_PER_CYCLE {
                let u = cycle_input(&p, k);
                if p.is_quiescent(&s, &u) {
                    quiet += 1;
                }
                s = p.advance(&s, &u, SAMPLE_DT);
                truth.advance(&u, SAMPLE_DT);
                let a = p.outputs(&s, &u);
                let b = truth.params.outputs(&truth.state, &u);
                for (w, i) in worst.iter_mut().zip([0, 1, 2, 3]) {
                    *w = w.max((a[i] - b[i]).abs());
                }
            }
        }
        println!(
            "{wear:?}: max |dx| {:.2e} |dpt| {:.0} |dpb| {:.0} |df| {:.2e}; quiescent {:.0}%, {:.3} ms per cycle (model + truth)",
            worst[0],
            worst[1],
            worst[2],
            worst[3],
            quiet as f64 / 90.0,
            t0.elapsed().as_secs_f64() * 1000.0 / 30.0
        );
    }
}
