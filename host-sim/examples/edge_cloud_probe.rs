//! What the six learning bearings show before their end of life, without prognosis:
//! `cargo run --release -p prognos-sim --example edge_cloud_probe [-- OUT_DIR]`.
//! Per snapshot (written to `OUT_DIR/<bearing>.csv`, default `out/probe`): horizontal and
//! vertical RMS and kurtosis, and the smoothed symmetric Itakura-Saito HI of both channels
//! with and without the noise variance against the paper's fixed reference, and of the
//! horizontal channel against a lagging reference (the mean of the 11 models that end 30 min
//! earlier). Prints the tables of `docs/results.md`: the indicators at 80 % of life, and
//! Bearing3_2 over its last 70 min.

use prognos_core::health::symmetric_itakura_saito;
use prognos_core::learn::ar::ArModel;
use prognos_sim::edge_cloud::bearing::{BearingRecord, load_bearing};
use prognos_sim::edge_cloud::cloud::{CloudPrognoser, ORDER};
use prognos_sim::edge_cloud::{Channel, EdgeCloudConfig, PAPER_TABLE1_PH_MIN, run_edge};
use std::fmt::Write as _;
use std::path::PathBuf;

/// Models between the lagging reference and the current model (30 min).
const LAG_MODELS: usize = 180;

/// Per-snapshot indicators of one bearing.
struct Probe {
    t_min: Vec<f64>,
    h_rms: Vec<f64>,
    h_kurtosis: Vec<f64>,
    v_rms: Vec<f64>,
    /// h with variance, h shape, v with variance, v shape, h with variance vs lagging ref.
    hi: [Vec<Option<f64>>; 5],
}

fn rms_kurtosis(x: &[f64]) -> (f64, f64) {
    let n = x.len() as f64;
    let mean = x.iter().sum::<f64>() / n;
    let var = x.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
    let m4 = x.iter().map(|v| (v - mean).powi(4)).sum::<f64>() / n;
    (
        (x.iter().map(|v| v * v).sum::<f64>() / n).sqrt(),
        m4 / (var * var),
    )
}

fn mean_model(models: &[ArModel<f64, ORDER>]) -> ArModel<f64, ORDER> {
    let n = models.len() as f64;
    ArModel {
        theta: models
            .iter()
            .map(|m| m.theta)
            .sum::<nalgebra::SVector<f64, ORDER>>()
            / n,
        noise_variance: models.iter().map(|m| m.noise_variance).sum::<f64>() / n,
        residual_count: models.first().map_or(0, |m| m.residual_count),
    }
}

fn trailing_mean(values: &[Option<f64>], window: usize) -> Vec<Option<f64>> {
    let mut recent = std::collections::VecDeque::new();
    values
        .iter()
        .map(|v| {
            v.map(|x| {
                recent.push_back(x);
                if recent.len() > window {
                    recent.pop_front();
                }
                recent.iter().sum::<f64>() / recent.len() as f64
            })
        })
        .collect()
}

fn probe(record: &BearingRecord) -> Probe {
    let base = EdgeCloudConfig::default();
    let mut hi: [Vec<Option<f64>>; 5] = Default::default();
    for (k, (channel, use_noise_variance)) in [
        (Channel::Horizontal, true),
        (Channel::Horizontal, false),
        (Channel::Vertical, true),
        (Channel::Vertical, false),
    ]
    .into_iter()
    .enumerate()
    {
        let config = EdgeCloudConfig {
            channel,
            use_noise_variance,
            // Never triggers: the HI only.
            prog_threshold: 1e12,
            eol_threshold: 2e12,
            ..base.clone()
        };
        let edge = run_edge(record, &config).expect("edge");
        let mut cloud = CloudPrognoser::new(&config).expect("cloud");
        hi[k] = edge
            .iter()
            .map(|e| {
                e.sent
                    .and_then(|m| cloud.on_model(e.t_s, &m).ok().and_then(|s| s.hi_smoothed))
            })
            .collect();
        if k == 0 {
            let sent: Vec<_> = edge.iter().map(|e| e.sent).collect();
            let models: Vec<_> = sent.iter().flatten().copied().collect();
            let mut index = 0usize;
            let lagged: Vec<Option<f64>> = sent
                .iter()
                .map(|s| {
                    s.map(|m| {
                        let end = index.saturating_sub(LAG_MODELS);
                        let window = if end == 0 {
                            &models[..base.reference_models.min(models.len())]
                        } else {
                            &models[end.saturating_sub(10)..=end]
                        };
                        index += 1;
                        symmetric_itakura_saito(&m, &mean_model(window), base.spectrum_points)
                            .unwrap_or(f64::NAN)
                    })
                })
                .collect();
            hi[4] = trailing_mean(&lagged, base.smoothing_window);
        }
    }
    let (mut h_rms, mut h_kurtosis, mut v_rms) = (Vec::new(), Vec::new(), Vec::new());
    for s in &record.snapshots {
        let (r, k) = rms_kurtosis(&s.horizontal);
        h_rms.push(r);
        h_kurtosis.push(k);
        v_rms.push(rms_kurtosis(&s.vertical).0);
    }
    Probe {
        t_min: record.snapshots.iter().map(|s| s.t_s / 60.0).collect(),
        h_rms,
        h_kurtosis,
        v_rms,
        hi,
    }
}

impl Probe {
    /// Mean of `values` over snapshots with `from <= t < to` (min).
    fn mean(&self, values: &[f64], from: f64, to: f64) -> f64 {
        let v: Vec<f64> = self
            .t_min
            .iter()
            .zip(values)
            .filter(|(t, _)| (from..to).contains(*t))
            .map(|(_, v)| *v)
            .collect();
        v.iter().sum::<f64>() / v.len().max(1) as f64
    }

    /// The last value of HI `k` at or before `t` (min).
    fn hi_at(&self, k: usize, t: f64) -> f64 {
        self.t_min
            .iter()
            .zip(&self.hi[k])
            .filter(|(tt, _)| **tt <= t + 1e-9)
            .filter_map(|(_, v)| *v)
            .next_back()
            .unwrap_or(f64::NAN)
    }
}

fn write_csv(path: &std::path::Path, p: &Probe) {
    let mut text =
        String::from("t_min,h_rms,h_kurtosis,v_rms,hi_h,hi_h_shape,hi_v,hi_v_shape,hi_h_lagged\n");
    for i in 0..p.t_min.len() {
        let _ = write!(
            text,
            "{:.3},{:.5},{:.3},{:.5}",
            p.t_min[i], p.h_rms[i], p.h_kurtosis[i], p.v_rms[i]
        );
        for col in &p.hi {
            let v = col.get(i).copied().flatten();
            let _ = write!(
                text,
                ",{}",
                v.map_or_else(String::new, |x| format!("{x:.5}"))
            );
        }
        text.push('\n');
    }
    std::fs::write(path, text).expect("write");
}

fn main() {
    let out = PathBuf::from(
        std::env::args()
            .nth(1)
            .unwrap_or_else(|| "out/probe".into()),
    );
    std::fs::create_dir_all(&out).expect("output dir");
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../data/pronostia");
    println!(
        "| bearing | life (min) | 80 % of life (min) | h RMS reference (g) | h RMS 75-80 % | max 1-min h RMS 30-80 % | HI at 80 % | max HI 30-80 % | 1-min h RMS first > 2x reference | HI first > 2 |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|");
    let mut last = None;
    for (name, _) in PAPER_TABLE1_PH_MIN {
        let record = load_bearing(&root.join(format!("{name}.csv"))).expect("bearing file");
        let p = probe(&record);
        write_csv(&out.join(format!("{name}.csv")), &p);
        let life = record.end_of_life_s() / 60.0;
        let t80 = 0.8 * life;
        // The snapshots behind the reference models (models 151-160 end at 26.8-28.3 min).
        let reference = p.mean(&p.h_rms, 26.7, 28.4);
        let minute = |t: f64| p.mean(&p.h_rms, t, t + 1.0);
        let max_rms = (0..)
            .map(|i| 0.3 * life + f64::from(i) / 6.0)
            .take_while(|t| *t + 1.0 <= t80)
            .map(minute)
            .fold(0.0, f64::max);
        let max_hi = p
            .t_min
            .iter()
            .zip(&p.hi[0])
            .filter(|(t, _)| (0.3 * life..=t80).contains(*t))
            .filter_map(|(_, v)| *v)
            .fold(0.0, f64::max);
        let first_rms = (0..)
            .map(|i| 30.0 + f64::from(i) / 6.0)
            .take_while(|t| *t < life)
            .find(|t| minute(*t) > 2.0 * reference);
        let first_hi = p
            .t_min
            .iter()
            .zip(&p.hi[0])
            .find(|(_, v)| v.is_some_and(|x| x > 2.0))
            .map(|(t, _)| *t);
        let pct = |t: Option<f64>| {
            t.map_or_else(
                || "never".into(),
                |t| format!("{t:.1} min ({:.0} %)", 100.0 * t / life),
            )
        };
        println!(
            "| {name} | {life:.1} | {t80:.1} | {reference:.3} | {:.3} | {max_rms:.3} | {:.2} | {max_hi:.2} | {} | {} |",
            p.mean(&p.h_rms, 0.75 * life, t80),
            p.hi_at(0, t80),
            pct(first_rms),
            pct(first_hi),
        );
        last = Some((p, life));
    }
    let Some((p, life)) = last else { return };
    println!(
        "\nBearing3_2 (1-min means before t; HIs smoothed):\n\n| t (min) | true RUL (min) | h RMS (g) | h kurtosis | v RMS (g) | HI h | HI h shape only | HI v | HI h vs 30-min-old reference |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    for t in [
        100.0, 200.0, 230.0, 237.0, 240.0, 245.0, 250.0, 252.67, 255.0, 260.0, 263.0, 265.0, 267.0,
        269.0,
    ] {
        println!(
            "| {t:.1} | {:.1} | {:.3} | {:.1} | {:.3} | {:.2} | {:.2} | {:.2} | {:.2} |",
            life - t,
            p.mean(&p.h_rms, t - 1.0, t),
            p.mean(&p.h_kurtosis, t - 1.0, t),
            p.mean(&p.v_rms, t - 1.0, t),
            p.hi_at(0, t),
            p.hi_at(1, t),
            p.hi_at(2, t),
            p.hi_at(4, t),
        );
    }
    let early = p
        .t_min
        .iter()
        .zip(&p.hi[4])
        .filter(|(t, _)| **t < 0.3 * life)
        .filter_map(|(_, v)| *v)
        .fold(0.0, f64::max);
    println!("\nBearing3_2: max lagging-reference HI before 30 % of life: {early:.2}");
}
