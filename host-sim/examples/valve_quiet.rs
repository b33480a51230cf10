//! Settled chamber pressures of the filter model (10 ms, fast-forward) against the truth
//! plant (2 ms) at several leak sizes: the bias the filter sees through pressure sensors.
use prognos_core::plants::valve::SensorNoise;
use prognos_sim::valve::{SAMPLE_DT, SAMPLES_PER_CYCLE, TruthValve, ValveSetup, cycle_input};
fn main() {
    let setup = ValveSetup::new();
    for (name, idx, a) in [
        ("A_i", 6, 1e-6),
        ("A_i", 6, 2e-6),
        ("A_et", 7, 2e-6),
        ("A_et", 7, 2e-5),
        ("A_eb", 8, 5e-6),
    ] {
        for fast in [true, false] {
            let mut p = setup.params;
            if !fast {
                p.quiescent_rate_tol = 0.0;
            }
            let mut truth = TruthValve::new([0.0; 5], SensorNoise::default());
            // The fine truth the filter noise was sized for (campaigns now use 10 ms).
            truth.params.max_substep = 0.002;
            truth.state[idx] = a;
            let mut s = p.nominal_state(6000.0, 48000.0, [0.0; 5]);
            s[idx] = a;
            let mut worst = [0.0f64; 2];
            for cycle in 0..2 {
                for k in 0..SAMPLES_PER_CYCLE {
                    let u = cycle_input(&p, k);
                    s = p.advance(&s, &u, SAMPLE_DT);
                    truth.advance(&u, SAMPLE_DT);
                    let (m, t) = (p.outputs(&s, &u), truth.params.outputs(&truth.state, &u));
                    if cycle == 1 && (k % 150) > 60 {
                        worst[0] = worst[0].max((m[1] - t[1]).abs());
                        worst[1] = worst[1].max((m[2] - t[2]).abs());
                    }
                }
            }
            println!(
                "{name} {a:e} fast-forward {fast}: settled |dpt| {:.0} Pa |dpb| {:.0} Pa",
                worst[0], worst[1]
            );
        }
    }
}
