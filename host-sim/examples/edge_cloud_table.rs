//! Runs the edge-cloud method on the six PRONOSTIA learning bearings and prints the
//! prognostic horizon beside the paper's Table 1:
//! `cargo run --release -p prognos-sim --example edge_cloud_table [-- CONFIG.toml]`.

use prognos_sim::edge_cloud::{EdgeCloudConfig, PAPER_TABLE1_PH_MIN, run_bearing};
use std::path::PathBuf;

fn main() {
    let config = match std::env::args().nth(1) {
        Some(p) => match EdgeCloudConfig::from_toml_file(&PathBuf::from(p)) {
            Ok(c) => c,
            Err(e) => {
                eprintln!("{e}");
                std::process::exit(e.exit_code());
            }
        },
        None => EdgeCloudConfig::default(),
    };
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../data/pronostia");
    println!(
        "| bearing | life (min) | trigger (min) | change (min) | PH (min) | paper PH (min) | PH >= paper | PH / life | last 20 % in band |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    let mut rate = None;
    for (name, paper) in PAPER_TABLE1_PH_MIN {
        let path = root.join(format!("{name}.csv"));
        match run_bearing(&path, &config) {
            Ok((run, _)) => {
                let s = &run.summary;
                let ph_min = s.prognostic_horizon_s.map_or(0.0, |p| p / 60.0);
                let m =
                    |v: Option<f64>| v.map_or_else(|| "-".into(), |t| format!("{:.1}", t / 60.0));
                println!(
                    "| {name} | {:.1} | {} | {} | {:.2} | {paper} | {} | {:.3} | {} |",
                    s.end_of_life_s / 60.0,
                    m(s.trigger_s),
                    m(s.change_s),
                    ph_min,
                    if ph_min >= paper { "yes" } else { "no" },
                    s.prognostic_horizon_fraction,
                    if s.prognostic_horizon_fraction >= 0.2 {
                        "yes"
                    } else {
                        "no"
                    },
                );
                rate = Some(s.data_rate);
            }
            Err(e) => {
                eprintln!("{e}");
                std::process::exit(e.exit_code());
            }
        }
    }
    if let Some(r) = rate {
        println!(
            "\ndata rate: raw signal {:.0} B/s, model parameters {:.1} B/s, {:.0} times less",
            r.raw_bytes_per_s, r.model_bytes_per_s, r.reduction
        );
    }
}
