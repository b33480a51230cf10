//! Robustness of the cloud settings on the six learning bearings, one edge pass per bearing:
//! `cargo run --release -p prognos-sim --example edge_cloud_tune`. Runs the default setting
//! and each threshold moved to a lower and a higher neighbour (one at a time), each with and
//! without redrawing `c` at the change, on seeds 1-4. Prints the PH of each bearing (min) and
//! how many bearings meet each target.

use prognos_sim::edge_cloud::bearing::load_bearing;
use prognos_sim::edge_cloud::{EdgeCloudConfig, PAPER_TABLE1_PH_MIN, run_cloud, run_edge};
use std::path::PathBuf;

fn settings(base: &EdgeCloudConfig) -> Vec<(String, EdgeCloudConfig)> {
    let mut out = vec![("default".to_string(), base.clone())];
    for eol in [30.0, 80.0] {
        let c = EdgeCloudConfig {
            eol_threshold: eol,
            ..base.clone()
        };
        out.push((format!("eol {eol}"), c));
    }
    for diff in [0.05, 0.2] {
        let c = EdgeCloudConfig {
            diff_threshold: diff,
            ..base.clone()
        };
        out.push((format!("diff {diff}"), c));
    }
    for prog in [0.3, 0.8] {
        let c = EdgeCloudConfig {
            prog_threshold: prog,
            ..base.clone()
        };
        out.push((format!("prog {prog}"), c));
    }
    let c = EdgeCloudConfig {
        smoothing_window: 6,
        ..base.clone()
    };
    out.push(("window 6".into(), c));
    out
}

fn main() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../data/pronostia");
    let base = EdgeCloudConfig::default();
    let data: Vec<_> = PAPER_TABLE1_PH_MIN
        .iter()
        .map(|(name, paper)| {
            let record = load_bearing(&root.join(format!("{name}.csv"))).expect("bearing file");
            let edge = run_edge(&record, &base).expect("edge");
            (record, edge, *paper)
        })
        .collect();
    println!("setting        redraw seed |  1_1    1_2    2_1    2_2    3_1    3_2 | targets");
    for (label, setting) in settings(&base) {
        for redraw in [true, false] {
            for seed in 1u64..=4 {
                let config = EdgeCloudConfig {
                    redraw_c_at_change: redraw,
                    seed,
                    ..setting.clone()
                };
                let mut line = format!("{label:<14} {:<6} {seed}    |", u8::from(redraw));
                let (mut beats, mut band) = (0, 0);
                for (record, edge, paper) in &data {
                    let run = run_cloud(record, edge, &config).expect("cloud");
                    let ph = run.summary.prognostic_horizon_s.map_or(0.0, |p| p / 60.0);
                    beats += usize::from(ph >= *paper);
                    band += usize::from(run.summary.prognostic_horizon_fraction >= 0.2);
                    line += &format!(" {ph:>6.2}");
                }
                println!("{line} | >=paper {beats}/6, last20% {band}/6");
            }
        }
    }
}
