//! SVG plots of runs and campaigns (plotters' SVG backend; text is emitted as SVG `<text>`,
//! so no system fonts are needed). Every plot is written atomically.

use crate::dataio::TimeSeries;
use crate::error::SimError;
use crate::output::write_text;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::ops::Range;
use std::path::Path;

type Area<'a> = DrawingArea<SVGBackend<'a>, Shift>;

const FONT: &str = "sans-serif";
const TRUTH: RGBColor = RGBColor(0, 0, 0);
const ESTIMATE: RGBColor = RGBColor(31, 119, 180);
const CONE: RGBColor = RGBColor(44, 160, 44);

fn render<F>(path: &Path, size: (u32, u32), draw: F) -> Result<(), SimError>
where
    F: FnOnce(&Area<'_>) -> Result<(), String>,
{
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, size).into_drawing_area();
        root.fill(&WHITE)
            .map_err(|e| e.to_string())
            .and_then(|_| draw(&root))
            .and_then(|_| root.present().map_err(|e| e.to_string()))
            .map_err(|m| SimError::Run(format!("{}: plotting failed: {m}", path.display())))?;
    }
    write_text(path, &svg)
}

/// Finite min..max of the values, padded by 5% (a unit range around a constant).
fn range_of<'a>(values: impl IntoIterator<Item = &'a f64>) -> Range<f64> {
    let (lo, hi) = values
        .into_iter()
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| {
            (lo.min(v), hi.max(v))
        });
    if !lo.is_finite() {
        return 0.0..1.0;
    }
    if hi - lo < 1e-12 * lo.abs().max(1.0) {
        return lo - 0.5 * lo.abs().max(1.0)..hi + 0.5 * hi.abs().max(1.0);
    }
    let pad = 0.05 * (hi - lo);
    lo - pad..hi + pad
}

fn points(t: &[f64], v: &[f64]) -> Vec<(f64, f64)> {
    t.iter()
        .zip(v)
        .filter(|(a, b)| a.is_finite() && b.is_finite())
        .map(|(&a, &b)| (a, b))
        .collect()
}

/// Polygon of the band between `lower` and `upper` over the samples where both are finite.
fn band(t: &[f64], lower: &[f64], upper: &[f64]) -> Vec<(f64, f64)> {
    let rows: Vec<(f64, f64, f64)> = t
        .iter()
        .zip(lower.iter().zip(upper))
        .filter(|(a, (l, u))| a.is_finite() && l.is_finite() && u.is_finite())
        .map(|(&a, (&l, &u))| (a, l, u))
        .collect();
    let mut poly: Vec<(f64, f64)> = rows.iter().map(|&(a, _, u)| (a, u)).collect();
    poly.extend(rows.iter().rev().map(|&(a, l, _)| (a, l)));
    poly
}

fn err<E: std::fmt::Display>(e: E) -> String {
    e.to_string()
}

/// One panel per estimated state `est:<name>`: the estimate with a shaded +-2 sd band and,
/// when logged, the truth `x:<name>`. Returns false (and writes nothing) without estimates.
pub fn plot_estimates(path: &Path, series: &TimeSeries) -> Result<bool, SimError> {
    let names = series.names_with_prefix("est");
    if names.is_empty() {
        return Ok(false);
    }
    let t = series.column("t").unwrap_or_default();
    let height = 260 * names.len() as u32;
    render(path, (900, height), |root| {
        let panels = root.split_evenly((names.len(), 1));
        for (panel, name) in panels.iter().zip(&names) {
            let mean = series.column(&format!("est:{name}")).unwrap_or_default();
            let sd = series.column(&format!("est_sd:{name}")).unwrap_or_default();
            let truth = series.column(&format!("x:{name}"));
            let lower: Vec<f64> = mean.iter().zip(&sd).map(|(m, s)| m - 2.0 * s).collect();
            let upper: Vec<f64> = mean.iter().zip(&sd).map(|(m, s)| m + 2.0 * s).collect();
            let y_range = range_of(
                mean.iter()
                    .chain(&lower)
                    .chain(&upper)
                    .chain(truth.iter().flatten()),
            );
            let mut chart = ChartBuilder::on(panel)
                .caption(name, (FONT, 18))
                .margin(8)
                .x_label_area_size(32)
                .y_label_area_size(70)
                .build_cartesian_2d(range_of(&t), y_range)
                .map_err(err)?;
            chart
                .configure_mesh()
                .x_desc("t [s]")
                .light_line_style(WHITE)
                .draw()
                .map_err(err)?;
            chart
                .draw_series(std::iter::once(Polygon::new(
                    band(&t, &lower, &upper),
                    ESTIMATE.mix(0.2).filled(),
                )))
                .map_err(err)?
                .label("estimate +-2 sd")
                .legend(|(x, y)| {
                    Rectangle::new([(x, y - 4), (x + 18, y + 4)], ESTIMATE.mix(0.2).filled())
                });
            if let Some(truth) = &truth {
                chart
                    .draw_series(LineSeries::new(points(&t, truth), TRUTH.stroke_width(2)))
                    .map_err(err)?
                    .label("truth")
                    .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], TRUTH));
            }
            chart
                .draw_series(LineSeries::new(points(&t, &mean), ESTIMATE.stroke_width(2)))
                .map_err(err)?
                .label("estimate")
                .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], ESTIMATE));
            chart
                .configure_series_labels()
                .position(SeriesLabelPosition::UpperLeft)
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .draw()
                .map_err(err)?;
        }
        Ok(())
    })?;
    Ok(true)
}

/// One panel per input `u:*` and measurement `y:*` channel.
pub fn plot_signals(path: &Path, series: &TimeSeries) -> Result<(), SimError> {
    let columns: Vec<String> = series
        .header
        .iter()
        .filter(|h| h.starts_with("u:") || h.starts_with("y:"))
        .cloned()
        .collect();
    let t = series.column("t").unwrap_or_default();
    let height = 200 * columns.len().max(1) as u32;
    render(path, (900, height), |root| {
        let panels = root.split_evenly((columns.len().max(1), 1));
        for (panel, name) in panels.iter().zip(&columns) {
            let v = series.column(name).unwrap_or_default();
            let mut chart = ChartBuilder::on(panel)
                .caption(name, (FONT, 16))
                .margin(8)
                .x_label_area_size(30)
                .y_label_area_size(70)
                .build_cartesian_2d(range_of(&t), range_of(&v))
                .map_err(err)?;
            chart
                .configure_mesh()
                .x_desc("t [s]")
                .light_line_style(WHITE)
                .draw()
                .map_err(err)?;
            chart
                .draw_series(LineSeries::new(points(&t, &v), ESTIMATE))
                .map_err(err)?;
        }
        Ok(())
    })
}

/// RUL against time: the true RUL with its alpha cone `(1 +- alpha) RUL*`, and the predicted
/// median with its lower..upper band. Returns false (and writes nothing) when the run has
/// neither a prediction nor a true RUL.
pub fn plot_rul(path: &Path, series: &TimeSeries, alpha: f64) -> Result<bool, SimError> {
    let t = series.column("t").unwrap_or_default();
    let col = |n: &str| series.column(n).unwrap_or_else(|| vec![f64::NAN; t.len()]);
    let (truth, median, lower, upper) = (
        col("rul:true"),
        col("rul:median"),
        col("rul:lower"),
        col("rul:upper"),
    );
    let any = |v: &[f64]| v.iter().any(|x| x.is_finite());
    if !any(&truth) && !any(&median) {
        return Ok(false);
    }
    // Scale to the truth and the median, not to intervals censored at a long horizon;
    // clamp everything drawn to the visible range.
    let finite_max = |v: &[f64], k: f64| {
        v.iter()
            .filter(|x| x.is_finite())
            .fold(0.0_f64, |a, &x| a.max(k * x))
    };
    let y_max = if any(&truth) {
        finite_max(&truth, 1.3 * (1.0 + alpha))
    } else {
        finite_max(&median, 1.5)
    }
    .max(1e-9);
    let clamp = |v: &[f64]| -> Vec<f64> { v.iter().map(|x| x.clamp(0.0, y_max)).collect() };
    let cone_lo = clamp(&truth.iter().map(|r| (1.0 - alpha) * r).collect::<Vec<_>>());
    let cone_hi = clamp(&truth.iter().map(|r| (1.0 + alpha) * r).collect::<Vec<_>>());
    let (median, lower, upper) = (clamp(&median), clamp(&lower), clamp(&upper));
    render(path, (900, 520), |root| {
        let mut chart = ChartBuilder::on(root)
            .caption(format!("RUL (alpha = {alpha})"), (FONT, 20))
            .margin(10)
            .x_label_area_size(36)
            .y_label_area_size(70)
            .build_cartesian_2d(range_of(&t), 0.0..y_max.max(1e-9))
            .map_err(err)?;
        chart
            .configure_mesh()
            .x_desc("t [s]")
            .y_desc("RUL [s]")
            .light_line_style(WHITE)
            .draw()
            .map_err(err)?;
        if any(&truth) {
            chart
                .draw_series(std::iter::once(Polygon::new(
                    band(&t, &cone_lo, &cone_hi),
                    CONE.mix(0.3).filled(),
                )))
                .map_err(err)?
                .label(format!("true RUL +-{:.0}%", alpha * 100.0))
                .legend(|(x, y)| {
                    Rectangle::new([(x, y - 4), (x + 18, y + 4)], CONE.mix(0.3).filled())
                });
        }
        if any(&median) {
            chart
                .draw_series(std::iter::once(Polygon::new(
                    band(&t, &lower, &upper),
                    ESTIMATE.mix(0.25).filled(),
                )))
                .map_err(err)?
                .label("predicted interval")
                .legend(|(x, y)| {
                    Rectangle::new([(x, y - 4), (x + 18, y + 4)], ESTIMATE.mix(0.25).filled())
                });
        }
        if any(&truth) {
            chart
                .draw_series(LineSeries::new(points(&t, &truth), TRUTH.stroke_width(2)))
                .map_err(err)?
                .label("true RUL")
                .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], TRUTH));
        }
        if any(&median) {
            chart
                .draw_series(LineSeries::new(
                    points(&t, &median),
                    ESTIMATE.stroke_width(2),
                ))
                .map_err(err)?
                .label("predicted median")
                .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], ESTIMATE));
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(err)?;
        Ok(())
    })?;
    Ok(true)
}

/// Bin counts of the finite values over `bins` equal bins spanning their range.
pub fn histogram_counts(values: &[f64], bins: usize) -> (Range<f64>, Vec<usize>) {
    let bins = bins.max(1);
    let finite: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
    let range = range_of(&finite);
    let width = (range.end - range.start) / bins as f64;
    let mut counts = vec![0usize; bins];
    for v in finite {
        let i = (((v - range.start) / width).floor() as usize).min(bins - 1);
        if let Some(c) = counts.get_mut(i) {
            *c += 1;
        }
    }
    (range, counts)
}

/// Histogram of the finite values.
pub fn plot_histogram(
    path: &Path,
    values: &[f64],
    title: &str,
    x_label: &str,
    bins: usize,
) -> Result<(), SimError> {
    let (range, counts) = histogram_counts(values, bins);
    let width = (range.end - range.start) / counts.len() as f64;
    let top = counts.iter().copied().max().unwrap_or(0).max(1) as f64 * 1.1;
    render(path, (800, 480), |root| {
        let mut chart = ChartBuilder::on(root)
            .caption(title, (FONT, 20))
            .margin(10)
            .x_label_area_size(36)
            .y_label_area_size(50)
            .build_cartesian_2d(range.clone(), 0.0..top)
            .map_err(err)?;
        chart
            .configure_mesh()
            .x_desc(x_label)
            .y_desc("runs")
            .light_line_style(WHITE)
            .draw()
            .map_err(err)?;
        chart
            .draw_series(counts.iter().enumerate().map(|(i, &c)| {
                let x0 = range.start + i as f64 * width;
                Rectangle::new(
                    [(x0, 0.0), (x0 + width, c as f64)],
                    ESTIMATE.mix(0.7).filled(),
                )
            }))
            .map_err(err)?;
        Ok(())
    })
}

/// One series of a log-log plot: name, points `(x, y)` (positive), and an optional fitted
/// power law `(slope, intercept)` of `log10 y = intercept + slope log10 x`, drawn dashed.
pub struct LogLogSeries {
    pub name: String,
    pub points: Vec<(f64, f64)>,
    pub fit: Option<(f64, f64)>,
}

/// Log-log plot of several series (markers joined by lines, fits dashed), with a legend.
pub fn plot_loglog(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[LogLogSeries],
) -> Result<(), SimError> {
    const COLORS: [RGBColor; 4] = [
        ESTIMATE,
        RGBColor(214, 39, 40),
        CONE,
        RGBColor(148, 103, 189),
    ];
    let positive = |v: f64| v.is_finite() && v > 0.0;
    let all: Vec<(f64, f64)> = series
        .iter()
        .flat_map(|s| s.points.iter().copied())
        .filter(|&(x, y)| positive(x) && positive(y))
        .collect();
    let bounds = |pick: fn(&(f64, f64)) -> f64| {
        let (lo, hi) = all
            .iter()
            .map(pick)
            .fold((f64::INFINITY, 0.0f64), |(l, h), v| (l.min(v), h.max(v)));
        if lo.is_finite() && hi > lo {
            lo / 1.5..hi * 1.5
        } else {
            1.0..10.0
        }
    };
    let (xr, yr) = (bounds(|p| p.0), bounds(|p| p.1));
    render(path, (800, 520), |root| {
        let mut chart = ChartBuilder::on(root)
            .caption(title, (FONT, 18))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(70)
            .build_cartesian_2d(xr.clone().log_scale(), yr.clone().log_scale())
            .map_err(err)?;
        let label = |v: &f64| {
            if *v >= 1.0 {
                format!("{v:.0}")
            } else {
                format!("{v}")
            }
        };
        chart
            .configure_mesh()
            .x_desc(x_label)
            .y_desc(y_label)
            .x_label_formatter(&label)
            .y_label_formatter(&label)
            .draw()
            .map_err(err)?;
        for (s, color) in series.iter().zip(COLORS.iter().cycle()) {
            let pts: Vec<(f64, f64)> = s
                .points
                .iter()
                .copied()
                .filter(|&(x, y)| positive(x) && positive(y))
                .collect();
            let color = *color;
            chart
                .draw_series(LineSeries::new(pts.clone(), color))
                .map_err(err)?
                .label(s.name.as_str())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color));
            chart
                .draw_series(pts.iter().map(|&p| Circle::new(p, 4, color.filled())))
                .map_err(err)?;
            if let Some((slope, intercept)) = s.fit {
                let (x0, x1) = pts.iter().fold((f64::INFINITY, 0.0f64), |(l, h), p| {
                    (l.min(p.0), h.max(p.0))
                });
                let line = |x: f64| (x, 10f64.powf(intercept + slope * x.log10()));
                chart
                    .draw_series(DashedLineSeries::new(
                        [line(x0), line(x1)],
                        6,
                        4,
                        color.stroke_width(1),
                    ))
                    .map_err(err)?;
            }
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .position(SeriesLabelPosition::UpperLeft)
            .draw()
            .map_err(err)?;
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn histogram_counts_every_finite_value_once() {
        let values = [0.0, 0.1, 0.2, 0.9, 1.0, f64::NAN, 0.5];
        let (range, counts) = histogram_counts(&values, 4);
        assert_eq!(counts.iter().sum::<usize>(), 6);
        assert!(range.start < 0.0 && range.end > 1.0);
        assert_eq!(counts, vec![3, 0, 1, 2]);
        let (_, single) = histogram_counts(&[2.0, 2.0], 3);
        assert_eq!(single.iter().sum::<usize>(), 2);
    }

    #[test]
    fn band_skips_missing_rows() {
        let t = [0.0, 1.0, 2.0];
        let p = band(&t, &[0.0, f64::NAN, 1.0], &[2.0, 3.0, 4.0]);
        assert_eq!(p, vec![(0.0, 2.0), (2.0, 4.0), (2.0, 1.0), (0.0, 0.0)]);
    }

    #[test]
    fn plots_are_valid_svg() {
        let dir = std::env::temp_dir().join(format!("prognos-plot-{}", std::process::id()));
        let mut s = TimeSeries::new(
            [
                "t",
                "u:a",
                "y:b",
                "x:d",
                "est:d",
                "est_sd:d",
                "rul:median",
                "rul:lower",
                "rul:upper",
                "rul:true",
            ]
            .map(String::from)
            .to_vec(),
        );
        for k in 0..50 {
            let t = k as f64;
            let r = 50.0 - t;
            s.rows.push(vec![
                t,
                1.0,
                t * 0.1,
                t * 0.1,
                t * 0.1 + 0.01,
                0.05,
                r + 2.0,
                r - 3.0,
                r + 5.0,
                r,
            ]);
        }
        assert!(plot_estimates(&dir.join("e.svg"), &s).unwrap());
        assert!(plot_rul(&dir.join("r.svg"), &s, 0.2).unwrap());
        plot_signals(&dir.join("s.svg"), &s).unwrap();
        plot_histogram(&dir.join("h.svg"), &[1.0, 2.0, 2.5], "h", "x", 5).unwrap();
        for f in ["e.svg", "r.svg", "s.svg", "h.svg"] {
            let text = std::fs::read_to_string(dir.join(f)).unwrap();
            assert!(
                text.starts_with("<svg") && text.trim_end().ends_with("</svg>"),
                "{f}"
            );
            assert!(text.contains("<polyline") || text.contains("<rect"), "{f}");
        }
        let svg = std::fs::read_to_string(dir.join("r.svg")).unwrap();
        assert!(svg.contains("predicted median") && svg.contains("<polygon"));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
