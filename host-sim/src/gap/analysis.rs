//! *Where*: the user's model replayed over the data, residuals standardised by the noise,
//! and a family of tests, each asking whether part of the residual is more than noise:
//! - `nis`: mean squared standardised residual per channel against 1 (chi-square with the
//!   uncertainty of an estimated noise level, see [`crate::gap::stats::variance_ratio_p`]), overall, per
//!   regime (plant labels plus quartiles of every input and replayed output) and per time
//!   window (tenths of the record);
//! - `band`: periodogram power per frequency band against the white-noise level;
//! - `ljung_box`: residual whiteness (lags 1-20);
//! - `input_xcorr`: residual-input cross-correlation (lags 0-10).
//!
//! `nis` counts a mean of `n` squared residuals as worth fewer samples when the noise is
//! heavy-tailed or correlated ([`Problem::gaussian_samples`]); the last three whiten a
//! correlated noise first (the spectrum is then the whitened residual's).
//!
//! Holm's step-down correction over all tests controls the family-wise false-alarm rate.
//! The location reported is the channel with the largest excess residual, and within it the
//! regime, window and band with the largest excess.
//!
//! Beside the replay, the plant's estimator runs over the data with the user's model
//! ([`innovation_tests`]): its standardised innovations get the `nis` (overall and per
//! regime) and `persistence` (do they keep their sign longer than white noise?) tests as
//! their own family. They are reported, not used to decide:
//! a closed-loop estimator absorbs slow gaps into its tracked parameters, so its innovations
//! show what the filter in the field would see (an inconsistent filter), not what is missing.

use crate::gap::effects::Problem;
use crate::gap::plant::Regime;
use crate::gap::stats::{
    ar1_whitened, holm, ljung_box, normal_sf, periodogram, persistence, variance_ratio_p,
};
use serde::Serialize;

/// Family-wise false-alarm rate over all tests of one diagnosis.
pub const ALPHA: f64 = 0.01;
/// Number of time windows.
pub const WINDOWS: usize = 10;
/// Number of frequency bands (log-spaced).
pub const BANDS: usize = 8;
/// Smallest number of samples a regime needs to be tested.
pub const MIN_REGIME_SAMPLES: usize = 30;

/// One hypothesis test.
#[derive(Clone, Debug, Serialize)]
pub struct TestResult {
    /// `nis`, `band`, `ljung_box` or `input_xcorr`.
    pub test: String,
    /// Channel (`y:<name>`).
    pub channel: String,
    /// What part of the data: `all`, a regime label, `window [t0, t1]`, `band [f0, f1] Hz`,
    /// or the input name.
    pub scope: String,
    /// Test statistic (mean squared standardised residual for `nis` and `band`, Q for
    /// Ljung-Box, max |rho| sqrt(n) for cross-correlation).
    pub statistic: f64,
    /// Unadjusted p-value.
    pub p_value: f64,
    /// Holm-adjusted p-value.
    pub p_adjusted: f64,
}

impl TestResult {
    /// A test's result before Holm's correction of its family.
    fn unadjusted(test: &str, channel: &str, scope: String, statistic: f64, p: f64) -> Self {
        Self {
            test: test.into(),
            channel: channel.into(),
            scope,
            statistic,
            p_value: p.max(f64::MIN_POSITIVE),
            p_adjusted: 1.0,
        }
    }
}

/// Mean of `z^2` over the finite samples `mask` selects, and their count.
fn mean_square(z: &[f64], mask: &dyn Fn(usize) -> bool) -> (f64, usize) {
    let (mut s, mut m) = (0.0, 0usize);
    for (k, v) in z.iter().enumerate() {
        if v.is_finite() && mask(k) {
            s += v * v;
            m += 1;
        }
    }
    (s / m.max(1) as f64, m)
}

/// Residual summary of one channel and regime (the heat map's cell).
#[derive(Clone, Debug, Serialize)]
pub struct Cell {
    /// Channel.
    pub channel: String,
    /// Regime label.
    pub regime: String,
    /// Samples in the regime.
    pub samples: usize,
    /// Mean squared standardised residual (1 = noise).
    pub nis: f64,
}

/// Where the gap lies.
#[derive(Clone, Debug, Serialize)]
pub struct Location {
    /// Channel with the largest excess residual.
    pub channel: String,
    /// Regime of that channel with the largest excess (`all` when none stands out).
    pub regime: String,
    /// Window with the largest excess [t0, t1] (s).
    pub window: [f64; 2],
    /// Band with the largest excess [f0, f1] (Hz).
    pub band_hz: [f64; 2],
    /// The channel's overall `nis` statistic.
    pub statistic: f64,
    /// Its Holm-adjusted p-value.
    pub p_value: f64,
    /// Whether any test rejected at [`ALPHA`] after Holm's correction on a channel whose
    /// overall `nis` exceeds 1.
    pub significant: bool,
    /// The smallest adjusted p-value of all tests and the test behind it.
    pub strongest_test: Option<TestResult>,
}

/// Everything the *where* step found.
#[derive(Clone, Debug, Serialize)]
pub struct WhereReport {
    /// The location.
    pub location: Location,
    /// Every test.
    pub tests: Vec<TestResult>,
    /// Heat-map cells.
    pub cells: Vec<Cell>,
    /// Periodogram of the located channel's standardised residual: (Hz, power).
    #[serde(skip)]
    pub spectrum: Vec<(f64, f64)>,
    /// What each channel's tests found (to locate the gap on another channel).
    #[serde(skip)]
    per_channel: Vec<ChannelFindings>,
}

impl WhereReport {
    /// Moves the location to `channel` (`y:<name>`), with that channel's regime, window,
    /// band, statistic and spectrum; no change for a channel without findings.
    pub fn relocate(&mut self, channel: &str) {
        let Some(f) = self.per_channel.iter().find(|f| f.channel == channel) else {
            return;
        };
        self.location = locate(
            f,
            &self.tests,
            self.location.significant,
            self.location.strongest_test.clone(),
        );
        self.spectrum = f.spectrum.clone();
    }
}

/// The location on the channel of `f`.
fn locate(
    f: &ChannelFindings,
    tests: &[TestResult],
    significant: bool,
    strongest_test: Option<TestResult>,
) -> Location {
    let regime = f
        .regime_excess
        .iter()
        .filter(|(label, _, _)| {
            tests
                .iter()
                .any(|t| t.channel == f.channel && t.scope == *label && t.p_adjusted < ALPHA)
        })
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .map_or("all".to_string(), |r| r.0.clone());
    Location {
        channel: f.channel.clone(),
        regime,
        window: f
            .windows
            .iter()
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .map_or([0.0, 0.0], |w| w.0),
        band_hz: f
            .bands
            .iter()
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .map_or([0.0, 0.0], |b| b.0),
        statistic: f.overall,
        p_value: tests[f.overall_index].p_adjusted,
        significant,
        strongest_test,
    }
}

fn quartile_regimes(name: &str, x: &[f64]) -> Vec<Regime> {
    let mut v: Vec<f64> = x.iter().copied().filter(|v| v.is_finite()).collect();
    if v.len() < 8 {
        return Vec::new();
    }
    v.sort_by(f64::total_cmp);
    let q = |f: f64| v[((v.len() - 1) as f64 * f) as usize];
    let edges = [f64::NEG_INFINITY, q(0.25), q(0.5), q(0.75), f64::INFINITY];
    if edges[1] == edges[3] {
        return Vec::new();
    }
    (0..4)
        .map(|b| Regime {
            label: format!("q{}({name})", b + 1),
            mask: x
                .iter()
                .map(|&v| {
                    (b == 0 && v <= edges[1])
                        || (b > 0 && v > edges[b] && (v <= edges[b + 1] || b == 3))
                })
                .collect(),
        })
        .collect()
}

/// The plant estimator's consistency on the data with the user's model.
#[derive(Clone, Debug, Serialize)]
pub struct EstimatorCheck {
    /// `nis` of the standardised innovations per channel, overall and per regime, and their
    /// `persistence` (one-sided whiteness); Holm-adjusted within this family.
    pub tests: Vec<TestResult>,
    /// Heat-map cells of the innovations' `nis`.
    #[serde(skip)]
    pub cells: Vec<Cell>,
    /// Why the estimator could not run on this record, if it could not.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

impl EstimatorCheck {
    /// The estimator failed with `message`: nothing tested.
    pub fn failed(message: &str) -> Self {
        Self {
            tests: Vec::new(),
            cells: Vec::new(),
            error: Some(message.to_string()),
        }
    }
}

/// Tests the estimator's standardised `innovations` (one per output channel of `problem`):
/// with a right model and noise they are standard normal (`nis` 1) and white.
pub fn innovation_tests(problem: &Problem, innovations: &[Vec<f64>]) -> EstimatorCheck {
    let regimes = all_regimes(problem);
    let mut tests = Vec::new();
    let mut cells = Vec::new();
    for (c, name) in problem.outputs.iter().enumerate() {
        let Some(z) = innovations.get(c) else {
            continue;
        };
        let channel = format!("y:{name}");
        let dof = problem.sigma_dof[c];
        let nis = |mask: &dyn Fn(usize) -> bool| mean_square(z, mask);
        let mut push = |test: &str, scope: String, statistic: f64, p: f64| {
            tests.push(TestResult::unadjusted(test, &channel, scope, statistic, p));
        };
        let (overall, m_all) = nis(&|_| true);
        if m_all == 0 {
            continue;
        }
        push(
            "nis",
            "all".into(),
            overall,
            variance_ratio_p(overall, problem.gaussian_samples(c, m_all), dof),
        );
        for r in &regimes {
            let (v, m) = nis(&|k| r.mask.get(k).copied().unwrap_or(false));
            if m >= MIN_REGIME_SAMPLES && m < m_all {
                push(
                    "nis",
                    r.label.clone(),
                    v,
                    variance_ratio_p(v, problem.gaussian_samples(c, m), dof),
                );
                cells.push(Cell {
                    channel: channel.clone(),
                    regime: r.label.clone(),
                    samples: m,
                    nis: v,
                });
            }
        }
        let finite: Vec<f64> = z.iter().copied().filter(|v| v.is_finite()).collect();
        // Persistence, not Ljung-Box: every filter here trusts its model less than
        // noise-free simulated truth warrants (its process noise is a margin), so it
        // over-corrects and its innovations alternate (Ljung-Box Q 135 and 156 on two
        // nominal wheel records, lag-1 autocorrelation -0.3 to -0.57 on the scooter's); a
        // slow effect the filter lags behind makes them linger instead. An oscillating
        // one is left to `nis`.
        let (z, p) = persistence(&finite, 20);
        push("persistence", "lags 1-20".into(), z, p);
    }
    let p: Vec<f64> = tests.iter().map(|t| t.p_value).collect();
    for (t, a) in tests.iter_mut().zip(holm(&p)) {
        t.p_adjusted = a;
    }
    EstimatorCheck {
        tests,
        cells,
        error: None,
    }
}

/// The regimes tested: the plant's labels, then quartiles of inputs and replayed outputs.
pub fn all_regimes(problem: &Problem) -> Vec<Regime> {
    let mut out = problem.plant.regimes(problem.data, &problem.nominal);
    for (name, u) in &problem.data.inputs {
        out.extend(quartile_regimes(&format!("u:{name}"), u));
    }
    for (name, y) in problem.outputs.iter().zip(&problem.nominal.outputs) {
        out.extend(quartile_regimes(&format!("sim:{name}"), y));
    }
    out
}

/// Runs every test on the user's model's residuals.
pub fn analyse(problem: &Problem) -> WhereReport {
    let data = problem.data;
    let n = data.len();
    let regimes = all_regimes(problem);
    let mut tests: Vec<TestResult> = Vec::new();
    let mut cells = Vec::new();
    let mut per_channel: Vec<ChannelFindings> = Vec::new();
    for (c, name) in problem.outputs.iter().enumerate() {
        let channel = format!("y:{name}");
        let sigma = problem.sigma[c];
        let dof = problem.sigma_dof[c];
        let z: Vec<f64> = (0..n)
            .map(|k| (problem.measured[c][k] - problem.nominal.outputs[c][k]) / sigma)
            .collect();
        let nis = |mask: &dyn Fn(usize) -> bool| mean_square(&z, mask);
        let overall_index = tests.len();
        let mut local: Vec<TestResult> = Vec::new();
        let mut push = |test: &str, scope: String, statistic: f64, p: f64| {
            local.push(TestResult::unadjusted(test, &channel, scope, statistic, p));
        };
        let (overall, m_all) = nis(&|_| true);
        push(
            "nis",
            "all".into(),
            overall,
            variance_ratio_p(overall, problem.gaussian_samples(c, m_all), dof),
        );
        let mut regime_excess: Vec<(String, f64, usize)> = Vec::new();
        for r in &regimes {
            let (v, m) = nis(&|k| r.mask[k]);
            if m >= MIN_REGIME_SAMPLES && m < m_all {
                push(
                    "nis",
                    r.label.clone(),
                    v,
                    variance_ratio_p(v, problem.gaussian_samples(c, m), dof),
                );
                regime_excess.push((r.label.clone(), v, m));
                cells.push(Cell {
                    channel: channel.clone(),
                    regime: r.label.clone(),
                    samples: m,
                    nis: v,
                });
            }
        }
        let mut windows = Vec::new();
        for w in 0..WINDOWS {
            let (a, b) = (w * n / WINDOWS, ((w + 1) * n / WINDOWS).min(n));
            if b <= a {
                continue;
            }
            let (v, m) = nis(&|k| k >= a && k < b);
            let span = [data.t[a], data.t[b - 1]];
            push(
                "nis",
                format!("window [{:.3}, {:.3}]", span[0], span[1]),
                v,
                variance_ratio_p(v, problem.gaussian_samples(c, m), dof),
            );
            windows.push((span, v));
        }
        let finite: Vec<f64> = z
            .iter()
            .map(|v| if v.is_finite() { *v } else { 0.0 })
            .collect();
        // Noise correlated from sample to sample is whitened first: its spectrum is not
        // flat, nor its autocorrelation zero.
        let phi = problem.noise_ar1[c];
        let finite = if phi == 0.0 {
            finite
        } else {
            ar1_whitened(&finite, phi)
        };
        let (freqs, power) = periodogram(&finite, data.dt);
        let mut bands = Vec::new();
        if let (Some(&f_lo), Some(&f_hi)) = (freqs.first(), freqs.last()) {
            let edges: Vec<f64> = (0..=BANDS)
                .map(|b| f_lo * (f_hi / f_lo).powf(b as f64 / BANDS as f64))
                .collect();
            for b in 0..BANDS {
                let in_band: Vec<f64> = freqs
                    .iter()
                    .zip(&power)
                    .filter(|(f, _)| **f >= edges[b] && (**f < edges[b + 1] || b + 1 == BANDS))
                    .map(|(_, p)| *p)
                    .collect();
                if in_band.is_empty() {
                    continue;
                }
                let v = in_band.iter().sum::<f64>() / in_band.len() as f64;
                let p = variance_ratio_p(v, 2.0 * in_band.len() as f64, dof);
                push(
                    "band",
                    format!("band [{:.4}, {:.4}] Hz", edges[b], edges[b + 1]),
                    v,
                    p,
                );
                bands.push(([edges[b], edges[b + 1]], v));
            }
        }
        let (q, p) = ljung_box(&finite, 20);
        push("ljung_box", "lags 1-20".into(), q, p);
        for (uname, u) in &data.inputs {
            let mean = u.iter().sum::<f64>() / n.max(1) as f64;
            let uc: Vec<f64> = u.iter().map(|v| v - mean).collect();
            let su = uc.iter().map(|v| v * v).sum::<f64>().sqrt();
            let zm = finite.iter().sum::<f64>() / n.max(1) as f64;
            let zc: Vec<f64> = finite.iter().map(|v| v - zm).collect();
            let sz = zc.iter().map(|v| v * v).sum::<f64>().sqrt();
            if su <= 0.0 || sz <= 0.0 {
                continue;
            }
            let lags = 11usize;
            let max_stat = (0..lags)
                .map(|l| {
                    let s: f64 = (l..n).map(|k| zc[k] * uc[k - l]).sum();
                    (s / (su * sz)).abs() * (n as f64).sqrt()
                })
                .fold(0.0f64, f64::max);
            let p_one = (2.0 * normal_sf(max_stat)).min(1.0);
            let p = 1.0 - (1.0 - p_one).powi(lags as i32);
            push(
                "input_xcorr",
                format!("u:{uname}"),
                max_stat,
                if p > 0.0 { p } else { lags as f64 * p_one },
            );
        }
        tests.extend(local);
        per_channel.push(ChannelFindings {
            channel,
            overall,
            overall_index,
            regime_excess,
            windows,
            bands,
            spectrum: freqs.into_iter().zip(power).collect(),
        });
    }
    let p: Vec<f64> = tests.iter().map(|t| t.p_value).collect();
    for (t, a) in tests.iter_mut().zip(holm(&p)) {
        t.p_adjusted = a;
    }
    // A rejected test counts only on a channel whose residual exceeds the noise level
    // overall: structure far below the noise (e.g. integration-scheme differences on
    // noise-free data) is not a gap.
    let overall: Vec<(String, f64)> = per_channel
        .iter()
        .map(|f| (f.channel.clone(), f.overall))
        .collect();
    let significant = tests
        .iter()
        .any(|t| t.p_adjusted < ALPHA && overall.iter().any(|(c, v)| *c == t.channel && *v > 1.0));
    let strongest_test = tests
        .iter()
        .min_by(|a, b| {
            a.p_adjusted
                .total_cmp(&b.p_adjusted)
                .then(b.statistic.total_cmp(&a.statistic))
        })
        .cloned();
    let best = per_channel
        .iter()
        .max_by(|a, b| a.overall.total_cmp(&b.overall));
    let location = match best {
        Some(f) => locate(f, &tests, significant, strongest_test),
        None => Location {
            channel: String::new(),
            regime: "all".into(),
            window: [0.0, 0.0],
            band_hz: [0.0, 0.0],
            statistic: 0.0,
            p_value: 1.0,
            significant,
            strongest_test,
        },
    };
    let spectrum = best.map(|f| f.spectrum.clone()).unwrap_or_default();
    WhereReport {
        location,
        tests,
        cells,
        spectrum,
        per_channel,
    }
}

#[derive(Clone, Debug)]
struct ChannelFindings {
    channel: String,
    overall: f64,
    overall_index: usize,
    regime_excess: Vec<(String, f64, usize)>,
    windows: Vec<([f64; 2], f64)>,
    bands: Vec<([f64; 2], f64)>,
    spectrum: Vec<(f64, f64)>,
}

/// The per-channel overall `nis` of a where report, for callers that want it by name.
pub fn channel_nis(report: &WhereReport, channel: &str) -> Option<f64> {
    report
        .tests
        .iter()
        .find(|t| t.test == "nis" && t.scope == "all" && t.channel == channel)
        .map(|t| t.statistic)
}
