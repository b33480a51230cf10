//! The valve paper's Table 2 and Table 3 campaigns, printed beside the paper's numbers.
//! `cargo run --release -p prognos-sim --example valve_tables -- table2 [runs] [seed]`
//! `cargo run --release -p prognos-sim --example valve_tables -- table3 [seed]`
//! `cargo run --release -p prognos-sim --example valve_tables -- table3-diag [seed] [step] [poll ms] [damage-noise decay cycles, 0: constant] [joint EOL 0/1] [wear kernel 0/1]`
//! `cargo run --release -p prognos-sim --example valve_tables -- table2-set <set 0-3> [runs] [seed] [mode 0-4, all if absent]`

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let which = args.first().map(String::as_str).unwrap_or("table2");
    let num = |i: usize, default: u64| -> u64 {
        args.get(i)
            .map_or(default, |a| a.parse().expect("integer argument"))
    };
    match which {
        "table2" => {
            let result = prognos_sim::valve::table2(num(1, 5) as usize, num(2, 1));
            print!("{}", result.render());
        }
        "table2-set" => {
            // Table 2's cells of one measurement set (optionally one mode), same seeds.
            use prognos_core::plants::valve::{DamageMode, MeasurementSet};
            let set = MeasurementSet::ALL[num(1, 3) as usize];
            let mode = args.get(4).map(|_| DamageMode::ALL[num(4, 0) as usize]);
            let result = prognos_sim::valve::table2_cells(num(2, 5) as usize, num(3, 1), |m, s| {
                s == set && mode.is_none_or(|only| only == m)
            });
            print!("{}", result.render());
        }
        "table3" => {
            let result = prognos_sim::valve::table3(num(1, 1));
            print!("{}", result.render());
        }
        "table3-diag" => {
            // Table 3 (N = 2000), printing every estimated wear every `step` cycles.
            let setup = prognos_sim::valve::ValveSetup::new();
            let mut exp = prognos_sim::valve::table3_experiment(&setup, num(1, 1));
            if let Some(ms) = args.get(3) {
                // Optional travel poll of the discrete sensors in ms (0: one reading per sample).
                let ms: f64 = ms.parse().expect("number");
                exp.travel_poll_dt = (ms > 0.0).then_some(ms * 1e-3);
            }
            if let Some(t0) = args.get(4) {
                // Optional damage-noise decay constant in cycles (0: constant noise).
                let t0: f64 = t0.parse().expect("number");
                exp.damage_noise_decay_cycles = (t0 > 0.0).then_some(t0);
            }
            if let Some(flag) = args.get(5) {
                // Optional: 0 turns the joint-requirement EOL off (per-mode thresholds).
                exp.joint_requirement_eol = flag != "0";
            }
            if let Some(flag) = args.get(6) {
                // Optional: 0 turns the once-per-cycle wear kernel move off.
                exp.wear_kernel_move = flag != "0";
            }
            let run = prognos_sim::valve::run_experiment::<2000>(&setup, &exp);
            let step = num(2, 5) as usize;
            for (mode, est) in exp.estimated.iter().zip(&run.estimate_per_cycle) {
                let i = mode.wear_index() - 9;
                let scale = if exp.true_wear[i] > 0.0 {
                    exp.true_wear[i]
                } else {
                    exp.wear_reference[i]
                };
                let v: Vec<String> = est
                    .iter()
                    .step_by(step)
                    .map(|e| format!("{:.3}", e / scale))
                    .collect();
                println!("{:>22} (/ {:.3e}): {}", mode.name(), scale, v.join(" "));
            }
            // Damage error of the modes with true wear, in cycles of their true increment.
            for (k, mode) in exp.estimated.iter().enumerate() {
                let w = exp.true_wear[mode.wear_index() - 9];
                if w <= 0.0 {
                    continue;
                }
                let per_cycle = w * setup.table.work_at(*mode, 0.0);
                let v: Vec<String> = run.damage_estimate_per_cycle[k]
                    .iter()
                    .zip(&run.true_damage_per_cycle[k])
                    .step_by(step)
                    .map(|(e, t)| format!("{:+.2}", (e - t) / per_cycle))
                    .collect();
                println!("{:>22} damage error (cycles): {}", mode.name(), v.join(" "));
            }
            for p in &run.predictions {
                println!(
                    "t_P {:5.1} RUL* {:5.2} median {:5.2} RA {:6.2} p01 {:5.2}",
                    p.t_p, p.true_rul, p.median_rul, p.ra, p.lower_99
                );
            }
            println!("{:.1} s", run.seconds);
        }
        other => {
            eprintln!("unknown table `{other}` (table2 or table3)");
            std::process::exit(2);
        }
    }
}
