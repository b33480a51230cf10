//! Result files of one bearing, each written atomically.

use super::{BearingRun, EdgeCloudConfig, EdgeCloudError};
use plotters::prelude::*;
use prognos_core::health::DegradationStage;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

fn io_error(path: &Path, source: std::io::Error) -> EdgeCloudError {
    EdgeCloudError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Writes `contents` to `path` via a temporary file in the same directory and a rename.
fn write_atomic(path: &Path, contents: &str) -> Result<(), EdgeCloudError> {
    let tmp = temp_path(path);
    std::fs::write(&tmp, contents).map_err(|e| io_error(&tmp, e))?;
    std::fs::rename(&tmp, path).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        io_error(path, e)
    })
}

fn temp_path(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map_or_else(|| "out".into(), |n| n.to_string_lossy().into_owned());
    path.with_file_name(format!(".{name}.{}.tmp", std::process::id()))
}

fn opt(v: Option<f64>) -> String {
    v.map_or_else(String::new, |x| format!("{x}"))
}

pub(super) fn write_all(
    dir: &Path,
    run: &BearingRun,
    config: &EdgeCloudConfig,
) -> Result<(), EdgeCloudError> {
    std::fs::create_dir_all(dir).map_err(|e| io_error(dir, e))?;

    let mut hi =
        String::from("t_s,edge_rejected,hi_nrmse,nrmse_alarm,hi_is_raw,hi_is_smoothed,stage\n");
    for r in &run.series {
        let stage = match r.stage {
            None => "",
            Some(DegradationStage::Exponential) => "exponential",
            Some(DegradationStage::Polynomial) => "polynomial",
        };
        let _ = writeln!(
            hi,
            "{},{},{},{},{},{},{}",
            r.t_s,
            u8::from(r.edge_rejected),
            opt(r.hi_nrmse),
            u8::from(r.nrmse_alarm),
            opt(r.hi_raw),
            opt(r.hi_smoothed),
            stage
        );
    }
    write_atomic(&dir.join("hi.csv"), &hi)?;

    let mut rul = String::from(
        "t_s,true_rul_s,rul_mean_s,rul_median_s,rul_p05_s,rul_p95_s,b_per_min,c_per_min2\n",
    );
    for r in &run.series {
        if let Some(p) = r.rul {
            let _ = writeln!(
                rul,
                "{},{},{},{},{},{},{},{}",
                r.t_s, r.true_rul_s, p.mean_s, p.median_s, p.p05_s, p.p95_s, p.b, p.c
            );
        }
    }
    write_atomic(&dir.join("rul.csv"), &rul)?;

    let summary = serde_json::json!({
        "summary": run.summary,
        "config": config,
    });
    let text = serde_json::to_string_pretty(&summary)
        .map_err(|e| EdgeCloudError::Config(format!("cannot serialise summary: {e}")))?;
    write_atomic(&dir.join("summary.json"), &(text + "\n"))?;

    write_atomic(
        &dir.join("hi.svg"),
        &hi_plot(run, config, &dir.join("hi.svg"))?,
    )?;
    write_atomic(
        &dir.join("rul.svg"),
        &rul_plot(run, config, &dir.join("rul.svg"))?,
    )?;
    Ok(())
}

fn plot_error(path: &Path, e: impl std::fmt::Display) -> EdgeCloudError {
    EdgeCloudError::Plot {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

fn hi_plot(
    run: &BearingRun,
    config: &EdgeCloudConfig,
    path: &Path,
) -> Result<String, EdgeCloudError> {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (900, 500)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| plot_error(path, e))?;
        let minutes = |t: f64| t / 60.0;
        let x_max = minutes(run.summary.end_of_life_s).max(1.0);
        let y_max = run
            .series
            .iter()
            .filter_map(|r| r.hi_smoothed)
            .fold(config.eol_threshold, f64::max)
            * 1.1;
        let log_floor = 1e-3;
        let mut chart = ChartBuilder::on(&root)
            .caption(
                format!("{}: smoothed I-S health indicator", run.summary.bearing),
                ("sans-serif", 20),
            )
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(0.0..x_max, (log_floor..y_max).log_scale())
            .map_err(|e| plot_error(path, e))?;
        chart
            .configure_mesh()
            .x_desc("time (min)")
            .y_desc("HI")
            .draw()
            .map_err(|e| plot_error(path, e))?;
        let clamp = |v: f64| v.max(log_floor);
        chart
            .draw_series(LineSeries::new(
                run.series
                    .iter()
                    .filter_map(|r| r.hi_raw.map(|h| (minutes(r.t_s), clamp(h)))),
                RGBColor(170, 170, 220),
            ))
            .map_err(|e| plot_error(path, e))?;
        chart
            .draw_series(LineSeries::new(
                run.series
                    .iter()
                    .filter_map(|r| r.hi_smoothed.map(|h| (minutes(r.t_s), clamp(h)))),
                BLUE.stroke_width(2),
            ))
            .map_err(|e| plot_error(path, e))?;
        for level in [config.prog_threshold, config.eol_threshold] {
            chart
                .draw_series(LineSeries::new(
                    [(0.0, level), (x_max, level)],
                    BLACK.stroke_width(1),
                ))
                .map_err(|e| plot_error(path, e))?;
        }
        root.present().map_err(|e| plot_error(path, e))?;
    }
    Ok(svg)
}

fn rul_plot(
    run: &BearingRun,
    config: &EdgeCloudConfig,
    path: &Path,
) -> Result<String, EdgeCloudError> {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (900, 500)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| plot_error(path, e))?;
        let eol_min = run.summary.end_of_life_s / 60.0;
        let start = run
            .series
            .iter()
            .find(|r| r.rul.is_some())
            .map_or(0.0, |r| r.t_s / 60.0);
        let y_max = (eol_min - start).max(1.0) * 1.5;
        let mut chart = ChartBuilder::on(&root)
            .caption(
                format!(
                    "{}: RUL (PH {} min, alpha {})",
                    run.summary.bearing,
                    run.summary
                        .prognostic_horizon_s
                        .map_or_else(|| "none".into(), |p| format!("{:.1}", p / 60.0)),
                    config.alpha
                ),
                ("sans-serif", 20),
            )
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(start..eol_min.max(start + 1.0), 0.0..y_max)
            .map_err(|e| plot_error(path, e))?;
        chart
            .configure_mesh()
            .x_desc("time (min)")
            .y_desc("RUL (min)")
            .draw()
            .map_err(|e| plot_error(path, e))?;
        let band = config.alpha * eol_min;
        let truth = |t: f64| eol_min - t;
        for offset in [-band, band] {
            chart
                .draw_series(LineSeries::new(
                    [
                        (start, truth(start) + offset),
                        (eol_min, truth(eol_min) + offset),
                    ],
                    RGBColor(120, 120, 120),
                ))
                .map_err(|e| plot_error(path, e))?;
        }
        chart
            .draw_series(LineSeries::new(
                [(start, truth(start)), (eol_min, 0.0)],
                RGBColor(230, 120, 0).stroke_width(2),
            ))
            .map_err(|e| plot_error(path, e))?;
        chart
            .draw_series(LineSeries::new(
                run.series
                    .iter()
                    .filter_map(|r| r.rul.map(|p| (r.t_s / 60.0, (p.mean_s / 60.0).min(y_max)))),
                BLUE.stroke_width(2),
            ))
            .map_err(|e| plot_error(path, e))?;
        root.present().map_err(|e| plot_error(path, e))?;
    }
    Ok(svg)
}
