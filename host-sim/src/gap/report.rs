//! The diagnosis written out: `verdict.json`, `report.md` and a self-contained
//! `report.html` whose figures are inline SVG (residual heat map per channel and regime,
//! residual spectrum with the flagged band, ranking bar chart, before/after overlays on a
//! held-out block, and the heat map of the plant estimator's innovations). Every file is
//! written atomically.

use crate::error::SimError;
use crate::gap::analysis::{Cell, EstimatorCheck, TestResult};
use crate::gap::diagnose::{Diagnosis, Overlay};
use crate::output::{write_json, write_text};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// How many ranking entries the bar chart and tables show.
const SHOWN: usize = 12;

/// Writes the three files into `dir`; returns their paths.
pub fn write_report(dir: &Path, d: &Diagnosis) -> Result<Vec<PathBuf>, SimError> {
    let json = dir.join("verdict.json");
    let md = dir.join("report.md");
    let html = dir.join("report.html");
    write_json(&json, d)?;
    write_text(&md, &markdown(d))?;
    write_text(&html, &html_page(d))?;
    Ok(vec![json, md, html])
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

fn summary_lines(d: &Diagnosis) -> Vec<String> {
    let l = &d.location;
    let mut out = vec![
        format!("plant: {}", d.plant),
        format!("verdict: {}", d.verdict),
        format!(
            "where: channel {}, regime {}, window [{:.2}, {:.2}] s, band [{:.4}, {:.4}] Hz",
            l.channel, l.regime, l.window[0], l.window[1], l.band_hz[0], l.band_hz[1]
        ),
        format!(
            "channel NIS {:.3} (Holm-adjusted p = {:.3e}); gap significant: {}",
            l.statistic, l.p_value, l.significant
        ),
    ];
    if !d.confusable.is_empty() {
        out.push(format!(
            "not separated from the verdict by the held-out data (score gap, standard errors): {}",
            d.confusable
                .iter()
                .map(|c| format!("{} ({:.1} nats, {:.1})", c.effect, c.score_gap, c.z))
                .collect::<Vec<_>>()
                .join(", ")
        ));
    }
    if let Some(t) = &l.strongest_test {
        out.push(format!(
            "strongest test: {} on {} ({}), statistic {:.3}, adjusted p = {:.3e}",
            t.test, t.channel, t.scope, t.statistic, t.p_adjusted
        ));
    }
    out.push(format!(
        "samples: {} ({} training, {} held out: the {} blocks); noise: {}",
        d.samples[0],
        d.samples[1],
        d.samples[2],
        d.held_out_blocks,
        d.noise
            .iter()
            .map(|n| format!("{} {:.4e} ({})", n.channel, n.std, n.source))
            .collect::<Vec<_>>()
            .join(", ")
    ));
    out.extend(d.warnings.iter().map(|w| format!("warning: {w}")));
    out
}

fn fmt_opt(v: Option<f64>) -> String {
    v.map_or("-".into(), |x| format!("{x:.4}"))
}

/// The Markdown report.
pub fn markdown(d: &Diagnosis) -> String {
    let mut s = String::from("# Sim-to-real gap diagnosis\n\n");
    for line in summary_lines(d) {
        let _ = writeln!(s, "- {line}");
    }
    s.push_str("\n## Ranking (held-out)\n\n| # | effect | score (nats) | gap before | gap after | shrink | replay error before / after | estimation error before / after | parameters |\n|---|---|---|---|---|---|---|---|---|\n");
    for (i, e) in d.ranking.iter().take(SHOWN).enumerate() {
        let params: Vec<String> = e
            .params
            .iter()
            .map(|(n, v)| format!("{n} = {v:.4e}"))
            .collect();
        let _ = writeln!(
            s,
            "| {} | {} | {:.1} | {:.3} | {:.3} | {:.3} | {} / {} | {} / {} | {} |",
            i + 1,
            e.effect,
            e.score,
            e.gap_before,
            e.gap_after,
            e.shrink,
            fmt_opt(e.replay_error_before),
            fmt_opt(e.replay_error_after),
            fmt_opt(e.estimation_error_before),
            fmt_opt(e.estimation_error_after),
            params.join(", ")
        );
    }
    if !d.pairs.is_empty() {
        s.push_str("\n## Pairs tried (held-out)\n\n| effect | score (nats) | gap after | shrink |\n|---|---|---|---|\n");
        for e in &d.pairs {
            let _ = writeln!(
                s,
                "| {} | {:.1} | {:.3} | {:.3} |",
                e.effect, e.score, e.gap_after, e.shrink
            );
        }
    }
    s.push_str("\n## Residual per channel and regime (mean squared standardised residual; 1 = noise)\n\n| channel | regime | samples | NIS |\n|---|---|---|---|\n");
    for c in &d.cells {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {:.3} |",
            c.channel, c.regime, c.samples, c.nis
        );
    }
    s.push_str("\n## Tests rejected at 1 % after Holm's correction\n\n| test | channel | scope | statistic | adjusted p |\n|---|---|---|---|---|\n");
    for t in d
        .tests
        .iter()
        .filter(|t| t.p_adjusted < crate::gap::analysis::ALPHA)
    {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {:.3} | {:.3e} |",
            t.test, t.channel, t.scope, t.statistic, t.p_adjusted
        );
    }
    if let Some(e) = &d.estimator {
        s.push_str("\n## The plant's estimator with the user's model (innovations; reported, not used to decide)\n\n");
        match &e.error {
            Some(message) => {
                let _ = writeln!(s, "The estimator could not run: {message}");
            }
            None => {
                s.push_str(
                    "| test | channel | scope | statistic | adjusted p |\n|---|---|---|---|---|\n",
                );
                for t in estimator_summary(e) {
                    let _ = writeln!(
                        s,
                        "| {} | {} | {} | {:.3} | {:.3e} |",
                        t.test, t.channel, t.scope, t.statistic, t.p_adjusted
                    );
                }
            }
        }
    }
    s.push_str("\nFigures: see report.html.\n");
    s
}

/// The estimator's tests worth a line: each channel's overall `nis` and whiteness, and
/// every regime rejected after Holm's correction.
fn estimator_summary(e: &EstimatorCheck) -> impl Iterator<Item = &TestResult> {
    e.tests.iter().filter(|t| {
        t.scope == "all" || t.test == "persistence" || t.p_adjusted < crate::gap::analysis::ALPHA
    })
}

fn color(v: f64) -> String {
    // 1 (noise) -> white, >= 10 -> red, on a log scale.
    let x = (v.max(1e-9).log10()).clamp(0.0, 1.0);
    let g = (255.0 * (1.0 - x)) as u8;
    format!("rgb(255,{g},{g})")
}

fn heat_map(cells: &[Cell]) -> String {
    let channels: Vec<&str> = {
        let mut v: Vec<&str> = cells.iter().map(|c| c.channel.as_str()).collect();
        v.dedup();
        v
    };
    let regimes: Vec<&str> = {
        let mut v: Vec<&str> = Vec::new();
        for c in cells {
            if !v.contains(&c.regime.as_str()) {
                v.push(&c.regime);
            }
        }
        v
    };
    let (cw, ch, left, top) = (70.0, 18.0, 190.0, 30.0);
    let w = left + cw * channels.len() as f64 + 20.0;
    let h = top + ch * regimes.len() as f64 + 20.0;
    let mut s = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"{h}\" font-family=\"sans-serif\" font-size=\"11\">"
    );
    for (j, c) in channels.iter().enumerate() {
        let _ = write!(
            s,
            "<text x=\"{}\" y=\"20\" text-anchor=\"middle\">{}</text>",
            left + cw * (j as f64 + 0.5),
            esc(c)
        );
    }
    for (i, r) in regimes.iter().enumerate() {
        let y = top + ch * i as f64;
        let _ = write!(
            s,
            "<text x=\"{}\" y=\"{}\" text-anchor=\"end\">{}</text>",
            left - 6.0,
            y + 13.0,
            esc(r)
        );
        for (j, c) in channels.iter().enumerate() {
            if let Some(cell) = cells.iter().find(|x| x.channel == *c && x.regime == *r) {
                let x = left + cw * j as f64;
                let _ = write!(
                    s,
                    "<rect x=\"{x}\" y=\"{y}\" width=\"{cw}\" height=\"{ch}\" fill=\"{}\" stroke=\"#ccc\"><title>{} {}: {:.3}</title></rect><text x=\"{}\" y=\"{}\" text-anchor=\"middle\">{:.2}</text>",
                    color(cell.nis),
                    esc(c),
                    esc(r),
                    cell.nis,
                    x + cw / 2.0,
                    y + 13.0,
                    cell.nis
                );
            }
        }
    }
    s.push_str("</svg>");
    s
}

struct Axes {
    x0: f64,
    x1: f64,
    y0: f64,
    y1: f64,
    w: f64,
    h: f64,
    log_x: bool,
    log_y: bool,
}

impl Axes {
    const L: f64 = 60.0;
    const T: f64 = 15.0;
    fn px(&self, x: f64) -> f64 {
        let f = if self.log_x {
            (x.ln() - self.x0.ln()) / (self.x1.ln() - self.x0.ln())
        } else {
            (x - self.x0) / (self.x1 - self.x0)
        };
        Self::L + f * (self.w - Self::L - 10.0)
    }
    fn py(&self, y: f64) -> f64 {
        let f = if self.log_y {
            (y.max(self.y0).ln() - self.y0.ln()) / (self.y1.ln() - self.y0.ln())
        } else {
            (y - self.y0) / (self.y1 - self.y0)
        };
        Self::T + (1.0 - f) * (self.h - Self::T - 30.0)
    }
    fn frame(&self, xlabel: &str, ylabel: &str) -> String {
        format!(
            "<rect x=\"{l}\" y=\"{t}\" width=\"{}\" height=\"{}\" fill=\"none\" stroke=\"#444\"/>\
             <text x=\"{}\" y=\"{}\" text-anchor=\"middle\">{}</text>\
             <text x=\"12\" y=\"{}\" transform=\"rotate(-90 12 {})\" text-anchor=\"middle\">{}</text>\
             <text x=\"{l}\" y=\"{}\" font-size=\"10\">{:.3e}</text><text x=\"{}\" y=\"{}\" font-size=\"10\" text-anchor=\"end\">{:.3e}</text>\
             <text x=\"{}\" y=\"{}\" font-size=\"10\" text-anchor=\"end\">{:.3e}</text><text x=\"{}\" y=\"{}\" font-size=\"10\" text-anchor=\"end\">{:.3e}</text>",
            self.w - Self::L - 10.0,
            self.h - Self::T - 30.0,
            (self.w + Self::L) / 2.0,
            self.h - 4.0,
            esc(xlabel),
            self.h / 2.0,
            self.h / 2.0,
            esc(ylabel),
            self.h - 18.0,
            self.x0,
            self.w - 10.0,
            self.h - 18.0,
            self.x1,
            Self::L - 3.0,
            self.h - 30.0,
            self.y0,
            Self::L - 3.0,
            Self::T + 10.0,
            self.y1,
            l = Self::L,
            t = Self::T,
        )
    }
    fn polyline(&self, xs: &[f64], ys: &[f64], color: &str) -> String {
        let pts: Vec<String> = xs
            .iter()
            .zip(ys)
            .filter(|(x, y)| x.is_finite() && y.is_finite())
            .map(|(x, y)| format!("{:.1},{:.1}", self.px(*x), self.py(*y)))
            .collect();
        format!(
            "<polyline fill=\"none\" stroke=\"{color}\" stroke-width=\"1.2\" points=\"{}\"/>",
            pts.join(" ")
        )
    }
}

fn spectrum_svg(d: &Diagnosis) -> String {
    let pts: Vec<(f64, f64)> = d
        .spectrum
        .iter()
        .copied()
        .filter(|(f, p)| *f > 0.0 && *p > 0.0)
        .collect();
    if pts.len() < 2 {
        return String::from("<p>(no spectrum)</p>");
    }
    // Smooth by averaging over log-spaced groups so the figure stays small.
    let groups = 200usize.min(pts.len());
    let (f0, f1) = (pts[0].0, pts[pts.len() - 1].0);
    let mut xs = Vec::new();
    let mut ys = Vec::new();
    for g in 0..groups {
        let lo = f0 * (f1 / f0).powf(g as f64 / groups as f64);
        let hi = f0 * (f1 / f0).powf((g + 1) as f64 / groups as f64);
        let sel: Vec<f64> = pts
            .iter()
            .filter(|(f, _)| *f >= lo && (*f < hi || g + 1 == groups))
            .map(|(_, p)| *p)
            .collect();
        if !sel.is_empty() {
            xs.push((lo * hi).sqrt());
            ys.push(sel.iter().sum::<f64>() / sel.len() as f64);
        }
    }
    let ymax = ys.iter().fold(1.0f64, |m, v| m.max(*v)) * 1.5;
    let ymin = ys.iter().fold(1.0f64, |m, v| m.min(*v)).max(ymax * 1e-6) / 1.5;
    let a = Axes {
        x0: f0,
        x1: f1,
        y0: ymin,
        y1: ymax,
        w: 640.0,
        h: 280.0,
        log_x: true,
        log_y: true,
    };
    let band = d.location.band_hz;
    let mut s = String::from(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"640\" height=\"280\" font-family=\"sans-serif\" font-size=\"11\">",
    );
    if band[1] > band[0] && band[0] > 0.0 {
        let _ = write!(
            s,
            "<rect x=\"{:.1}\" y=\"{}\" width=\"{:.1}\" height=\"{}\" fill=\"#fdd\"/>",
            a.px(band[0]),
            Axes::T,
            a.px(band[1]) - a.px(band[0]),
            280.0 - Axes::T - 30.0
        );
    }
    let _ = write!(s, "{}", a.polyline(&[f0, f1], &[1.0, 1.0], "#888"));
    s.push_str(&a.polyline(&xs, &ys, "#c00"));
    s.push_str(&a.frame(
        "frequency (Hz), flagged band shaded",
        "power / white-noise level",
    ));
    s.push_str("</svg>");
    s
}

fn ranking_svg(d: &Diagnosis) -> String {
    let shown: Vec<_> = d.ranking.iter().take(SHOWN).collect();
    let (left, bar, width) = (250.0, 18.0, 300.0);
    let h = 20.0 + bar * shown.len() as f64;
    let mut s = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{}\" height=\"{h}\" font-family=\"sans-serif\" font-size=\"11\">",
        left + width + 120.0
    );
    for (i, e) in shown.iter().enumerate() {
        let y = 10.0 + bar * i as f64;
        let frac = e.shrink.clamp(0.0, 1.0);
        let fill = if e.effect == d.verdict {
            "#c33"
        } else {
            "#69c"
        };
        let _ = write!(
            s,
            "<text x=\"{}\" y=\"{}\" text-anchor=\"end\">{}</text><rect x=\"{left}\" y=\"{y}\" width=\"{:.1}\" height=\"{}\" fill=\"{fill}\"/><text x=\"{}\" y=\"{}\">shrink {:.2}, score {:.0}</text>",
            left - 6.0,
            y + 13.0,
            esc(&e.effect),
            frac * width,
            bar - 3.0,
            left + frac * width + 4.0,
            y + 13.0,
            e.shrink,
            e.score
        );
    }
    s.push_str("</svg>");
    s
}

fn overlay_svg(o: &Overlay) -> String {
    if o.t.len() < 2 {
        return String::new();
    }
    let all = o
        .measured
        .iter()
        .chain(&o.nominal)
        .chain(&o.corrected)
        .filter(|v| v.is_finite());
    let (lo, hi) = all.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
        (a.min(*v), b.max(*v))
    });
    let pad = ((hi - lo) * 0.05).max(1e-12);
    let a = Axes {
        x0: o.t[0],
        x1: o.t[o.t.len() - 1],
        y0: lo - pad,
        y1: hi + pad,
        w: 640.0,
        h: 260.0,
        log_x: false,
        log_y: false,
    };
    let mut s = String::from(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"640\" height=\"260\" font-family=\"sans-serif\" font-size=\"11\">",
    );
    s.push_str(&a.polyline(&o.t, &o.measured, "#999"));
    s.push_str(&a.polyline(&o.t, &o.nominal, "#36c"));
    if !o.corrected.is_empty() {
        s.push_str(&a.polyline(&o.t, &o.corrected, "#c33"));
    }
    s.push_str(&a.frame("time (s), held-out block", &o.channel));
    s.push_str("<text x=\"70\" y=\"28\" fill=\"#999\">measured</text><text x=\"140\" y=\"28\" fill=\"#36c\">model</text><text x=\"190\" y=\"28\" fill=\"#c33\">model + verdict effect</text></svg>");
    s
}

/// The self-contained HTML report.
pub fn html_page(d: &Diagnosis) -> String {
    let mut s = String::from(
        "<!DOCTYPE html><html><head><meta charset=\"utf-8\"><title>Gap diagnosis</title><style>body{font-family:sans-serif;max-width:1000px;margin:auto}table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:2px 6px;font-size:12px}</style></head><body><h1>Sim-to-real gap diagnosis</h1><ul>",
    );
    for line in summary_lines(d) {
        let _ = write!(s, "<li>{}</li>", esc(&line));
    }
    s.push_str("</ul><h2>Ranking (held-out shrink; verdict in red)</h2>");
    s.push_str(&ranking_svg(d));
    s.push_str("<table><tr><th>#</th><th>effect</th><th>score</th><th>gap before</th><th>gap after</th><th>shrink</th><th>estimation error before / after</th><th>parameters</th></tr>");
    for (i, e) in d.ranking.iter().take(SHOWN).enumerate() {
        let params: Vec<String> = e
            .params
            .iter()
            .map(|(n, v)| format!("{n} = {v:.4e}"))
            .collect();
        let _ = write!(
            s,
            "<tr><td>{}</td><td>{}</td><td>{:.1}</td><td>{:.3}</td><td>{:.3}</td><td>{:.3}</td><td>{} / {}</td><td>{}</td></tr>",
            i + 1,
            esc(&e.effect),
            e.score,
            e.gap_before,
            e.gap_after,
            e.shrink,
            fmt_opt(e.estimation_error_before),
            fmt_opt(e.estimation_error_after),
            esc(&params.join(", "))
        );
    }
    s.push_str("</table><h2>Residual per channel and regime</h2><p>Mean squared standardised residual (1 = noise level).</p>");
    s.push_str(&heat_map(&d.cells));
    if let Some(e) = &d.estimator {
        s.push_str("<h2>The plant's estimator with the user's model</h2><p>Mean squared standardised innovation per channel and regime (1 = consistent filter); reported beside the replay, not used to decide.</p>");
        match &e.error {
            Some(message) => {
                let _ = write!(s, "<p>The estimator could not run: {}</p>", esc(message));
            }
            None => {
                s.push_str("<table><tr><th>test</th><th>channel</th><th>scope</th><th>statistic</th><th>adjusted p</th></tr>");
                for t in estimator_summary(e) {
                    let _ = write!(
                        s,
                        "<tr><td>{}</td><td>{}</td><td>{}</td><td>{:.3}</td><td>{:.3e}</td></tr>",
                        esc(&t.test),
                        esc(&t.channel),
                        esc(&t.scope),
                        t.statistic,
                        t.p_adjusted
                    );
                }
                s.push_str("</table>");
                s.push_str(&heat_map(&e.cells));
            }
        }
    }
    s.push_str("<h2>Residual spectrum of the located channel</h2>");
    s.push_str(&spectrum_svg(d));
    s.push_str("<h2>Before / after on a held-out block</h2>");
    for o in &d.overlays {
        s.push_str(&overlay_svg(o));
    }
    s.push_str("</body></html>\n");
    s
}
