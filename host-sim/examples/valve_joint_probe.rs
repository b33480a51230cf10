//! Opening and closing times of one cycle with the bottom leak near its threshold and the
//! spring slightly weakened (the interaction behind `Experiment::joint_requirement_eol`).
//! `cargo run --release -p prognos-sim --example valve_joint_probe`
use prognos_core::plants::valve::{PROGPY_THRESHOLDS, idx, simulate_cycle};

fn main() {
    let setup = prognos_sim::valve::ValveSetup::new();
    let p = setup.params;
    let req = setup.requirements;
    let th = PROGPY_THRESHOLDS;
    // The threshold procedure: settle half a cycle closed, then one timed cycle.
    let run = |k: f64, a_eb: f64| {
        let mut s = p.nominal_state(6000.0, k, [0.0; 5]);
        s[idx::A_EB] = a_eb;
        let u = p.command_input(false, req.fluid[0], req.fluid[1]);
        for _ in 0..1500 {
            s = p.advance(&s, &u, req.dt);
        }
        simulate_cycle(&p, &req, &s).0
    };
    // One cycle of Table 3's leak growth [m^2].
    let per_cycle = 3.0e-7;
    println!(
        "threshold A_eb+ {:.4e} m^2, k- {:.1} N/m",
        th.a_eb_max, th.k_min
    );
    println!(
        "spring weakening [N/m]  A_eb [cycles from threshold]  t_open [s]  t_close [s]  closes on supply loss"
    );
    for dk in [0.0, 500.0, 1000.0, 2000.0, 4000.0] {
        for cycles in [-10.0, -5.0, -3.0, -2.0, -1.0, 0.0, 1.0] {
            let t = run(48000.0 - dk, th.a_eb_max + cycles * per_cycle);
            println!(
                "{dk:6.0}                  {cycles:+5.1}                         {:6.3}      {:6.3}       {}",
                t.t_open, t.t_close, t.closes_on_supply_loss
            );
        }
    }
}
