//! Grid over the cloud thresholds on the six learning bearings, one edge pass per bearing:
//! `cargo run --release -p prognos-sim --example edge_cloud_tune`. Prints, per setting, the
//! PH of each bearing (min) and how many bearings meet each target.

use prognos_sim::edge_cloud::bearing::load_bearing;
use prognos_sim::edge_cloud::{EdgeCloudConfig, run_cloud, run_edge};
use std::path::PathBuf;

const PAPER: [(&str, f64); 6] = [
    ("Bearing1_1", 136.5),
    ("Bearing1_2", 2.0),
    ("Bearing2_1", 3.5),
    ("Bearing2_2", 2.17),
    ("Bearing3_1", 1.17),
    ("Bearing3_2", 20.0),
];

fn main() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../data/pronostia");
    let base = EdgeCloudConfig::default();
    let data: Vec<_> = PAPER
        .iter()
        .map(|(name, paper)| {
            let record = load_bearing(&root.join(format!("{name}.csv"))).expect("bearing file");
            let edge = run_edge(&record, &base).expect("edge");
            (record, edge, *paper)
        })
        .collect();
    let grid_eol = [50.0];
    let grid_diff = [0.1];
    let grid_prog = [0.5];
    let grid_window = [6usize, 12];
    let grid_seed = [1u64, 2, 3, 4];
    for &eol in &grid_eol {
        for &diff in &grid_diff {
            for &prog in &grid_prog {
                for &window in &grid_window {
                    for &seed in &grid_seed {
                        let config = EdgeCloudConfig {
                            eol_threshold: eol,
                            diff_threshold: diff,
                            prog_threshold: prog,
                            smoothing_window: window,
                            seed,
                            ..base.clone()
                        };
                        let mut line = format!(
                            "eol {eol:>4} diff {diff:>4} prog {prog:>4} window {window:>2} seed {seed} |"
                        );
                        let (mut beats, mut band) = (0, 0);
                        for (record, edge, paper) in &data {
                            let run = run_cloud(record, edge, &config).expect("cloud");
                            let ph = run.summary.prognostic_horizon_s.map_or(0.0, |p| p / 60.0);
                            beats += usize::from(ph >= *paper);
                            band += usize::from(run.summary.prognostic_horizon_fraction >= 0.2);
                            line += &format!(" {ph:>6.1}");
                        }
                        println!("{line} | >=paper {beats}/6, last20% {band}/6");
                    }
                }
            }
        }
    }
}
