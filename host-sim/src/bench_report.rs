//! `prognos bench-report`: reads criterion's results (`<criterion dir>/**/new/benchmark.json`
//! and `estimates.json`, written by `cargo bench -p prognos-tests --bench filters`), prints the
//! per-step costs, the particle filter's log-log scaling slope and the filter overhead ratio
//! `PF step / (N x one model step)`, and draws the scaling plots.
//!
//! Times are criterion's median of the per-iteration sample means: on a shared machine the
//! median is far less sensitive to other jobs than the mean or the regression slope.

use crate::error::SimError;
use crate::output::{format_table, write_text};
use crate::plot::{LogLogSeries, plot_loglog};
use serde_json::Value;
use std::path::{Path, PathBuf};

/// One benchmark's result.
#[derive(Clone, Debug, PartialEq)]
pub struct BenchEntry {
    /// Criterion group (e.g. `pf_valve`).
    pub group: String,
    /// Function or parameter within the group (e.g. `512` or `drag_radar_nx4`).
    pub id: String,
    /// Median time per iteration [ns] and its 95 % confidence interval.
    pub median_ns: f64,
    pub low_ns: f64,
    pub high_ns: f64,
}

impl BenchEntry {
    /// The numeric parameter (particle count, K, M, order), if the id is a number.
    pub fn param(&self) -> Option<f64> {
        self.id.parse().ok()
    }
}

/// Reads every benchmark under `dir` (recursively), sorted by group and parameter.
pub fn collect(dir: &Path) -> Result<Vec<BenchEntry>, SimError> {
    let mut files = Vec::new();
    find_benchmarks(dir, &mut files).map_err(|e| SimError::Unreadable {
        path: dir.to_path_buf(),
        message: e.to_string(),
    })?;
    let mut entries = Vec::new();
    for new_dir in files {
        let read = |name: &str| -> Result<Value, SimError> {
            let path = new_dir.join(name);
            let text = std::fs::read_to_string(&path).map_err(|e| SimError::Unreadable {
                path: path.clone(),
                message: e.to_string(),
            })?;
            serde_json::from_str(&text).map_err(|e| SimError::BadInput {
                path,
                line: e.line(),
                column: e.column(),
                message: e.to_string(),
            })
        };
        let meta = read("benchmark.json")?;
        let estimates = read("estimates.json")?;
        let group = meta["group_id"].as_str().unwrap_or("").to_string();
        let id = meta["value_str"]
            .as_str()
            .or_else(|| meta["function_id"].as_str())
            .unwrap_or("")
            .to_string();
        let median = &estimates["median"];
        let number = |v: &Value| v.as_f64().unwrap_or(f64::NAN);
        entries.push(BenchEntry {
            group,
            id,
            median_ns: number(&median["point_estimate"]),
            low_ns: number(&median["confidence_interval"]["lower_bound"]),
            high_ns: number(&median["confidence_interval"]["upper_bound"]),
        });
    }
    entries.sort_by(|a, b| {
        a.group
            .cmp(&b.group)
            .then_with(|| match (a.param(), b.param()) {
                (Some(x), Some(y)) => x.total_cmp(&y),
                _ => a.id.cmp(&b.id),
            })
    });
    Ok(entries)
}

fn find_benchmarks(dir: &Path, out: &mut Vec<PathBuf>) -> std::io::Result<()> {
    for entry in std::fs::read_dir(dir)? {
        let path = entry?.path();
        if !path.is_dir() {
            continue;
        }
        if path.file_name().is_some_and(|n| n == "new") && path.join("benchmark.json").is_file() {
            out.push(path);
        } else {
            find_benchmarks(&path, out)?;
        }
    }
    Ok(())
}

/// Least-squares power law `y = 10^intercept x^slope` through positive points:
/// `(slope, intercept, r^2)` in log10-log10 space; `None` with fewer than two points.
pub fn fit_power_law(points: &[(f64, f64)]) -> Option<(f64, f64, f64)> {
    let logs: Vec<(f64, f64)> = points
        .iter()
        .filter(|(x, y)| *x > 0.0 && *y > 0.0 && x.is_finite() && y.is_finite())
        .map(|(x, y)| (x.log10(), y.log10()))
        .collect();
    if logs.len() < 2 {
        return None;
    }
    let n = logs.len() as f64;
    let mx = logs.iter().map(|p| p.0).sum::<f64>() / n;
    let my = logs.iter().map(|p| p.1).sum::<f64>() / n;
    let sxx: f64 = logs.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxy: f64 = logs.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let syy: f64 = logs.iter().map(|p| (p.1 - my).powi(2)).sum();
    if sxx <= 0.0 {
        return None;
    }
    let slope = sxy / sxx;
    let r2 = if syy > 0.0 {
        sxy * sxy / (sxx * syy)
    } else {
        1.0
    };
    Some((slope, my - slope * mx, r2))
}

/// The overhead ratio at one particle count.
#[derive(Clone, Debug, PartialEq)]
pub struct Overhead {
    pub model: String,
    pub particles: f64,
    /// PF step [ns].
    pub pf_ns: f64,
    /// N x `sample_step` over the same particles and samples [ns].
    pub model_ns: f64,
    /// N x (`sample_step` + `log_likelihood`) [ns].
    pub model_ll_ns: Option<f64>,
}

impl Overhead {
    /// PF step / (N x one model step).
    pub fn ratio(&self) -> f64 {
        self.pf_ns / self.model_ns
    }
    /// PF step / (N x (model step + likelihood)).
    pub fn ratio_with_likelihood(&self) -> Option<f64> {
        self.model_ll_ns.map(|m| self.pf_ns / m)
    }
}

/// Points `(parameter, median)` of a group.
pub fn series(entries: &[BenchEntry], group: &str) -> Vec<(f64, f64)> {
    entries
        .iter()
        .filter(|e| e.group == group)
        .filter_map(|e| e.param().map(|p| (p, e.median_ns)))
        .collect()
}

/// Overhead ratios for `model` (`pf_<model>`, `model_<model>`, `model_ll_<model>` groups) at
/// every particle count measured in both of the first two.
pub fn overheads(entries: &[BenchEntry], model: &str) -> Vec<Overhead> {
    let pf = series(entries, &format!("pf_{model}"));
    let only = series(entries, &format!("model_{model}"));
    let with_ll = series(entries, &format!("model_ll_{model}"));
    only.iter()
        .filter_map(|&(n, model_ns)| {
            let pf_ns = pf.iter().find(|p| p.0 == n)?.1;
            Some(Overhead {
                model: model.to_string(),
                particles: n,
                pf_ns,
                model_ns,
                model_ll_ns: with_ll.iter().find(|p| p.0 == n).map(|p| p.1),
            })
        })
        .collect()
}

fn fmt_time(ns: f64) -> String {
    if !ns.is_finite() {
        "-".into()
    } else if ns >= 1e6 {
        format!("{:.3} ms", ns / 1e6)
    } else if ns >= 1e3 {
        format!("{:.2} us", ns / 1e3)
    } else {
        format!("{ns:.1} ns")
    }
}

/// The report text: every benchmark, the PF scaling fits and the overhead ratios.
pub fn render(entries: &[BenchEntry]) -> String {
    let rows: Vec<Vec<String>> = entries
        .iter()
        .map(|e| {
            let per_particle = if e.group.starts_with("pf_") || e.group.starts_with("model_") {
                e.param().map_or("-".into(), |n| fmt_time(e.median_ns / n))
            } else {
                "-".into()
            };
            vec![
                e.group.clone(),
                e.id.clone(),
                fmt_time(e.median_ns),
                format!("{} .. {}", fmt_time(e.low_ns), fmt_time(e.high_ns)),
                per_particle,
            ]
        })
        .collect();
    let mut out = String::from("Per-step cost (criterion median, 95 % interval)\n");
    out += &format_table(&["group", "id", "median", "95 % CI", "per particle"], &rows);
    out += "\nScaling fits (log10 time = a + slope log10 parameter)\n";
    let mut fit_rows = Vec::new();
    for (group, what) in [
        ("pf_valve", "N"),
        ("pf_wheel", "N"),
        ("model_valve", "N"),
        ("gp_predict", "M"),
        ("imm", "K"),
        ("oriv", "order"),
    ] {
        let pts = series(entries, group);
        if let Some((slope, _, r2)) = fit_power_law(&pts) {
            fit_rows.push(vec![
                group.to_string(),
                what.to_string(),
                pts.len().to_string(),
                format!("{slope:.3}"),
                format!("{r2:.4}"),
            ]);
        }
    }
    out += &format_table(&["group", "parameter", "points", "slope", "r^2"], &fit_rows);
    out += "\nFilter overhead ratio PF step / (N x one model step) (target <= 1.5)\n";
    let mut ratio_rows = Vec::new();
    for model in ["valve", "wheel"] {
        for o in overheads(entries, model) {
            ratio_rows.push(vec![
                o.model.clone(),
                format!("{}", o.particles),
                fmt_time(o.pf_ns),
                fmt_time(o.model_ns),
                format!("{:.3}", o.ratio()),
                o.ratio_with_likelihood()
                    .map_or("-".into(), |r| format!("{r:.3}")),
            ]);
        }
    }
    out += &format_table(
        &[
            "model",
            "N",
            "PF step",
            "N model steps",
            "ratio",
            "ratio incl. likelihood",
        ],
        &ratio_rows,
    );
    out
}

/// Collects, prints and writes `summary.txt` and the SVG plots into `out_dir`. Returns the
/// written files.
pub fn run(criterion_dir: &Path, out_dir: &Path) -> Result<(String, Vec<PathBuf>), SimError> {
    let entries = collect(criterion_dir)?;
    if entries.is_empty() {
        return Err(SimError::Run(format!(
            "{}: no criterion results (run `cargo bench -p prognos-tests --bench filters` first)",
            criterion_dir.display()
        )));
    }
    let text = render(&entries);
    let mut files = Vec::new();
    let summary = out_dir.join("summary.txt");
    write_text(&summary, &text)?;
    files.push(summary);
    // Plotted in microseconds (the fit's slope does not depend on the unit).
    let with_fit = |name: &str, group: &str| {
        let points: Vec<(f64, f64)> = series(&entries, group)
            .into_iter()
            .map(|(x, ns)| (x, ns * 1e-3))
            .collect();
        let fit = fit_power_law(&points);
        LogLogSeries {
            name: match fit {
                Some((slope, _, _)) => format!("{name} (slope {slope:.2})"),
                None => name.to_string(),
            },
            fit: fit.map(|(s, a, _)| (s, a)),
            points,
        }
    };
    let plots = [
        (
            "pf_scaling.svg",
            "Particle filter step cost against N",
            "particles N",
            vec![
                with_fit("valve PF step", "pf_valve"),
                with_fit("valve: N model steps", "model_valve"),
                with_fit("reaction wheel PF step", "pf_wheel"),
            ],
        ),
        (
            "gp_scaling.svg",
            "GP prediction (mean and variance) against training size",
            "training points M",
            vec![with_fit("GP predict", "gp_predict")],
        ),
        (
            "imm_scaling.svg",
            "IMM step of K GP-UKFs (M = 64) against K",
            "modes K",
            vec![with_fit("IMM step", "imm")],
        ),
    ];
    for (file, title, x_label, series) in plots {
        if series.iter().all(|s| s.points.is_empty()) {
            continue;
        }
        let path = out_dir.join(file);
        plot_loglog(&path, title, x_label, "time per step [us]", &series)?;
        files.push(path);
    }
    Ok((text, files))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn power_law_fit_recovers_exponent() {
        let pts: Vec<(f64, f64)> = [64.0, 128.0, 256.0, 512.0]
            .iter()
            .map(|&n: &f64| (n, 3.0 * n.powf(1.02)))
            .collect();
        let (slope, intercept, r2) = fit_power_law(&pts).unwrap();
        assert!((slope - 1.02).abs() < 1e-12);
        assert!((intercept - 3f64.log10()).abs() < 1e-12);
        assert!((r2 - 1.0).abs() < 1e-12);
        assert!(fit_power_law(&pts[..1]).is_none());
    }

    fn write_bench(root: &Path, group: &str, id: &str, median: f64) {
        let dir = root.join(group).join(id).join("new");
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(
            dir.join("benchmark.json"),
            format!(r#"{{"group_id":"{group}","function_id":null,"value_str":"{id}"}}"#),
        )
        .unwrap();
        std::fs::write(
            dir.join("estimates.json"),
            format!(
                r#"{{"median":{{"point_estimate":{median},"confidence_interval":{{"lower_bound":{},"upper_bound":{}}}}}}}"#,
                median * 0.9,
                median * 1.1
            ),
        )
        .unwrap();
    }

    #[test]
    fn collects_criterion_layout_and_computes_overhead() {
        let root = std::env::temp_dir().join(format!("prognos-bench-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        write_bench(&root, "pf_valve", "64", 1200.0);
        write_bench(&root, "pf_valve", "128", 2400.0);
        write_bench(&root, "model_valve", "64", 1000.0);
        write_bench(&root, "model_ll_valve", "64", 1100.0);
        write_bench(&root, "ukf", "drag_radar_nx4", 2000.0);
        // A criterion `base` copy must not be read twice.
        let base = root.join("ukf").join("drag_radar_nx4").join("base");
        std::fs::create_dir_all(&base).unwrap();
        let entries = collect(&root).unwrap();
        assert_eq!(entries.len(), 5);
        let o = overheads(&entries, "valve");
        assert_eq!(o.len(), 1);
        assert!((o[0].ratio() - 1.2).abs() < 1e-12);
        assert!((o[0].ratio_with_likelihood().unwrap() - 1200.0 / 1100.0).abs() < 1e-12);
        let text = render(&entries);
        assert!(text.contains("1.200"), "{text}");
        let out = root.join("out");
        let (_, files) = run(&root, &out).unwrap();
        assert!(files.iter().any(|f| f.ends_with("pf_scaling.svg")));
        let svg = std::fs::read_to_string(out.join("pf_scaling.svg")).unwrap();
        assert!(svg.contains("slope 1.00"), "fitted slope in the legend");
        std::fs::remove_dir_all(&root).unwrap();
    }
}
