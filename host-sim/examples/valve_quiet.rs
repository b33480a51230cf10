//! Cycle timing of the filter model (10 ms) against the truth plant (2 ms) at several
//! bottom-leak sizes: the discretisation bias the filter sees through the timing.
use prognos_core::plants::valve::{Requirements, ValveParams, simulate_cycle};
fn main() {
    let model = ValveParams::<f64>::progpy_stable();
    let truth = ValveParams {
        max_substep: 0.002,
        ..model
    };
    let reqs = [
        Requirements {
            dt: 0.01,
            ..Requirements::default()
        },
        Requirements {
            dt: 0.002,
            ..Requirements::default()
        },
    ];
    for a in [0.0, 2e-6, 4e-6, 6e-6, 8e-6, 1e-5, 1.1e-5] {
        let mut row = String::new();
        for (p, req) in [&model, &truth].into_iter().zip(&reqs) {
            let mut s = p.nominal_state(6000.0, 48000.0, [0.0; 5]);
            s[8] = a;
            let (_, s1) = simulate_cycle(p, req, &s);
            let (t, _) = simulate_cycle(p, req, &s1);
            row.push_str(&format!(
                "  open {:.3} (1: {:.3}) close {:.3}",
                t.t_open, t.t_open1, t.t_close
            ));
        }
        println!("A_eb {a:.1e}: model{row}");
    }
}
