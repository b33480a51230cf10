//! Smoothed Itakura-Saito HI of both accelerometers, with and without the noise variance, on
//! the six learning bearings (no prognosis): `cargo run --release -p prognos-sim --example
//! edge_cloud_probe -- OUT_DIR` writes `OUT_DIR/<bearing>.csv`.

use prognos_sim::edge_cloud::bearing::load_bearing;
use prognos_sim::edge_cloud::cloud::CloudPrognoser;
use prognos_sim::edge_cloud::{Channel, EdgeCloudConfig, run_edge};
use std::fmt::Write as _;
use std::path::PathBuf;

const BEARINGS: [&str; 6] = [
    "Bearing1_1",
    "Bearing1_2",
    "Bearing2_1",
    "Bearing2_2",
    "Bearing3_1",
    "Bearing3_2",
];

fn main() {
    let out = PathBuf::from(
        std::env::args()
            .nth(1)
            .unwrap_or_else(|| "out/probe".into()),
    );
    std::fs::create_dir_all(&out).expect("output dir");
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../data/pronostia");
    for name in BEARINGS {
        let record = load_bearing(&root.join(format!("{name}.csv"))).expect("bearing file");
        let mut columns: Vec<Vec<Option<f64>>> = Vec::new();
        for channel in [Channel::Horizontal, Channel::Vertical] {
            for use_noise_variance in [true, false] {
                let config = EdgeCloudConfig {
                    channel,
                    use_noise_variance,
                    prog_threshold: 1e12,
                    eol_threshold: 2e12,
                    ..EdgeCloudConfig::default()
                };
                let edge = run_edge(&record, &config).expect("edge");
                if use_noise_variance {
                    let mut m = String::new();
                    for e in &edge {
                        if let Some(model) = e.sent {
                            let _ = write!(m, "{}", e.t_s);
                            for a in model.theta.iter() {
                                let _ = write!(m, ",{a}");
                            }
                            let _ = writeln!(m, ",{}", model.noise_variance);
                        }
                    }
                    let tag = if channel == Channel::Horizontal {
                        "h"
                    } else {
                        "v"
                    };
                    std::fs::write(out.join(format!("{name}_models_{tag}.csv")), m).expect("write");
                }
                let mut cloud = CloudPrognoser::new(&config).expect("cloud");
                let col = edge
                    .iter()
                    .map(|e| {
                        e.sent.and_then(|m| {
                            cloud.on_model(e.t_s, &m).ok().and_then(|s| s.hi_smoothed)
                        })
                    })
                    .collect();
                columns.push(col);
            }
        }
        let mut text = String::from("t_min,h_var,h_shape,v_var,v_shape\n");
        for (i, snap) in record.snapshots.iter().enumerate() {
            let _ = write!(text, "{:.3}", snap.t_s / 60.0);
            for col in &columns {
                let v = col.get(i).copied().flatten();
                let _ = write!(
                    text,
                    ",{}",
                    v.map_or_else(String::new, |x| format!("{x:.5}"))
                );
            }
            text.push('\n');
        }
        std::fs::write(out.join(format!("{name}.csv")), text).expect("write");
        eprintln!("{name} done");
    }
}
