//! One valve prognostics experiment (N = 500), for tuning and timing:
//! `cargo run --release -p prognos-sim --example valve_one -- <mode 0-4> <set 0-3> <seed>
//! [truth step us] [filter step us] [asynchronous 0/1] [discrete noise /100] [walk /1e-5] [damage walk /100]
//! [travel poll of the discrete sensors, ms; 0 = one reading per 0.1 s sample]`.

use prognos_core::plants::valve::{DamageMode, MeasurementSet};
use prognos_sim::valve::{ValveSetup, run_experiment, table2_experiment};

fn main() {
    let args: Vec<usize> = std::env::args()
        .skip(1)
        .map(|a| a.parse().expect("integer argument"))
        .collect();
    let mode = DamageMode::ALL[*args.first().unwrap_or(&4)];
    let set = MeasurementSet::ALL[*args.get(1).unwrap_or(&0)];
    let seed = *args.get(2).unwrap_or(&1) as u64;
    let mut setup = ValveSetup::new();
    if let Some(h) = args.get(4) {
        // Optional filter-model step in microseconds (the rate table follows it).
        setup.params.max_substep = *h as f64 * 1e-6;
        setup.table = prognos_core::plants::valve::DamageRateTable::compute(
            &setup.params,
            &setup.requirements,
            &setup.thresholds,
        );
    }
    let mut exp = table2_experiment(&setup, mode, set, seed);
    if let Some(p) = args.get(9) {
        exp.travel_poll_dt = (*p > 0).then_some(*p as f64 * 1e-3);
    }
    if let Some(w) = args.get(8) {
        // Optional damage random walk per cycle relative to one cycle's increment, in 1/100.
        exp.damage_walk_rel = *w as f64 * 0.01;
    }
    if let Some(w) = args.get(7) {
        // Optional wear random walk relative to its magnitude, in 1e-5.
        exp.random_walk_rel = *w as f64 * 1e-5;
    }
    if let Some(d) = args.get(6) {
        // Optional assumed noise of the discrete sensors, in hundredths.
        exp.filter_noise.discrete = *d as f64 * 0.01;
    }
    if let Some(a) = args.get(5) {
        exp.asynchronous_commands = *a != 0;
    }
    if let Some(h) = args.get(3) {
        // Optional truth step in microseconds (10000 = the filter's physics).
        exp.truth_substep = *h as f64 * 1e-6;
    }
    eprintln!(
        "{} {}: true wear {:?}",
        mode.name(),
        set.name(),
        exp.true_wear
    );
    let r = run_experiment::<500>(&setup, &exp);
    println!(
        "EOL {} PRMSE_w {:.2} RMAD_w {:.2} C_w {:.2} RA {:.2} RMAD_RUL {:.2} ({:.1} s)",
        r.true_eol,
        r.prmse_w[0],
        r.rmad_w[0],
        r.convergence_w[0],
        r.mean_ra(),
        r.mean_rmad_rul(),
        r.seconds
    );
    let w_true = exp.true_wear[mode.wear_index() - 9];
    let ratios: Vec<String> = r.estimate_per_cycle[0]
        .iter()
        .step_by(5)
        .map(|e| format!("{:.3}", e / w_true))
        .collect();
    println!("w_hat / w* every 5 cycles: {}", ratios.join(" "));
    let errors: Vec<String> = r.damage_estimate_per_cycle[0]
        .iter()
        .zip(&r.true_damage_per_cycle[0])
        .step_by(5)
        .map(|(e, t)| format!("{:+.2e}", e - t))
        .collect();
    println!(
        "damage estimate - truth every 5 cycles: {}",
        errors.join(" ")
    );
    for p in &r.predictions {
        println!(
            "  t_P {:5.1} RUL* {:6.2} median {:6.2} mean {:6.2} p01 {:6.2} RA {:6.2} RMAD {:5.2}",
            p.t_p, p.true_rul, p.median_rul, p.mean_rul, p.lower_99, p.ra, p.rmad
        );
    }
}
