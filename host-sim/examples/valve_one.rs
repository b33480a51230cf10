//! One valve prognostics experiment (N = 500), for tuning and timing:
//! `cargo run --release -p prognos-sim --example valve_one -- <mode 0-4> <set 0-3> <seed>`.

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
    let setup = ValveSetup::new();
    let exp = table2_experiment(&setup, mode, set, seed);
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
    for p in &r.predictions {
        println!(
            "  t_P {:5.1} RUL* {:6.2} median {:6.2} mean {:6.2} p01 {:6.2} RA {:6.2} RMAD {:5.2}",
            p.t_p, p.true_rul, p.median_rul, p.mean_rul, p.lower_99, p.ra, p.rmad
        );
    }
}
