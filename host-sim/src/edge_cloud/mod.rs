//! Edge-cloud prognosis of bearings (Barbieri et al. 2021) on PRONOSTIA-format files: the
//! core's edge monitor (ORIV AR models on a 12-snapshot FIFO buffer, HI_NRMSE backup alarm)
//! feeds the cloud prognoser (symmetric Itakura-Saito HI, particle filter on the piecewise
//! degradation model, RUL to `T_EoL`), then the prognostic horizon is scored.
//!
//! [`run_bearing`] is the whole method on one file; [`analyse_bearing`] is the same without
//! writing anything.

pub mod bearing;
pub mod cloud;
mod output;

use bearing::{BearingRecord, SNAPSHOT_LEN, load_bearing};
use cloud::{CloudPrognoser, ORDER, RulPrediction};
use prognos_core::health::DegradationStage;
use prognos_core::learn::ar::{ArModel, OrivConfig, WindowCheck};
use prognos_core::metrics::{HorizonBand, prognostic_horizon};
use prognos_core::pipeline::edge::{EdgeConfig, EdgeMonitor};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The six PRONOSTIA learning bearings (`data/pronostia/<name>.csv`) with Table 1 of
/// Barbieri et al. (2021): prognostic horizon in minutes, alpha = 0.2.
pub const PAPER_TABLE1_PH_MIN: [(&str, f64); 6] = [
    ("Bearing1_1", 136.5),
    ("Bearing1_2", 2.0),
    ("Bearing2_1", 3.5),
    ("Bearing2_2", 2.17),
    ("Bearing3_1", 1.17),
    ("Bearing3_2", 20.0),
];

/// Snapshots in the edge buffer (12 x 0.1 s).
pub const BUFFER_SNAPSHOTS: usize = 12;

/// Errors of the edge-cloud run. [`EdgeCloudError::exit_code`] gives the CLI status.
#[derive(Debug, thiserror::Error)]
pub enum EdgeCloudError {
    /// A malformed bearing or config file.
    #[error("{}:{line}:{column}: {message}", path.display())]
    Parse {
        path: PathBuf,
        line: usize,
        column: usize,
        message: String,
    },
    /// A file could not be read or written.
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// A configuration value is out of range.
    #[error("invalid configuration: {0}")]
    Config(String),
    /// The estimator core refused the data.
    #[error("estimator: {0}")]
    Core(#[from] prognos_core::Error),
    /// Plot rendering failed.
    #[error("plot {}: {message}", path.display())]
    Plot { path: PathBuf, message: String },
}

impl EdgeCloudError {
    /// 2 for bad input (file contents or configuration), 1 otherwise.
    pub fn exit_code(&self) -> i32 {
        match self {
            Self::Parse { .. } | Self::Config(_) => 2,
            Self::Io { .. } | Self::Core(_) | Self::Plot { .. } => 1,
        }
    }
}

/// Which accelerometer the edge models.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Channel {
    Horizontal,
    Vertical,
}

/// Settings of the whole method (a TOML file with any subset of these keys). Defaults are the
/// paper's values, except the thresholds `prog_threshold`, `diff_threshold`, `eol_threshold`
/// and `nrmse_alarm`, the HI noise and `use_noise_variance`, which were set once for all six
/// learning bearings (see `docs/deviations.md`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EdgeCloudConfig {
    /// Accelerometer the edge models.
    pub channel: Channel,
    /// ORIV `P(0) = psi I` (Eq. 13).
    pub psi: f64,
    /// ORIV instrument delay (0 = the paper's Eq. 6).
    pub instrument_delay: usize,
    /// Models made before transmission starts (grease warm-up; 150 = 1500 s in the paper).
    pub warmup_models: usize,
    /// Models averaged into the reference.
    pub reference_models: usize,
    /// Backup alarm threshold on HI_NRMSE (paper range [1, 1.1], default 1.1).
    pub nrmse_alarm: f64,
    /// Frequency grid of the Itakura-Saito integral.
    pub spectrum_points: usize,
    /// Include the driving-noise variance in the spectra, so the HI sees the vibration level
    /// and not only the spectral shape (the edge then sends `n + 1` REALs per model).
    pub use_noise_variance: bool,
    /// Trailing-mean window of the HI (12 in the paper).
    pub smoothing_window: usize,
    /// `T_prog`: prognosis starts when the smoothed HI reaches it (paper 0.1, default 0.5).
    pub prog_threshold: f64,
    /// `T_diff`: a first difference of the smoothed HI above it switches to the polynomial
    /// stage (paper 0.2, default 0.1).
    pub diff_threshold: f64,
    /// `T_EoL`: the HI level that defines the predicted end of life (paper 10, default 50).
    pub eol_threshold: f64,
    /// Random-walk variance of `b` per step, 1/min^2 (1e-5 in the paper).
    pub b_walk_var: f64,
    /// Random-walk variance of `c` per step, 1/min^4 (1e-5 in the paper).
    pub c_walk_var: f64,
    /// Log-uniform prior range of `b`, 1/min.
    pub b_prior: [f64; 2],
    /// Log-uniform prior range of `c`, 1/min^2.
    pub c_prior: [f64; 2],
    /// Draw `c` afresh from its prior at the detected change (resampling during the
    /// exponential stage has thinned its draws from the trigger to a few values).
    pub redraw_c_at_change: bool,
    /// Measurement noise std of the smoothed HI, relative part.
    pub relative_noise: f64,
    /// Measurement noise std of the smoothed HI, absolute floor.
    pub absolute_noise: f64,
    /// RUL predictions are capped here, s.
    pub max_rul_s: f64,
    /// Time between snapshots, s.
    pub snapshot_period_s: f64,
    /// Prognostic-horizon accuracy `alpha` (Eq. 35).
    pub alpha: f64,
    /// Seed of the particle filter's generator.
    pub seed: u64,
    /// Results go to `<output_dir>/<bearing file stem>/`.
    pub output_dir: PathBuf,
}

impl Default for EdgeCloudConfig {
    fn default() -> Self {
        Self {
            channel: Channel::Horizontal,
            psi: 10.0,
            instrument_delay: 0,
            warmup_models: 150,
            reference_models: 10,
            nrmse_alarm: 1.1,
            spectrum_points: 256,
            use_noise_variance: true,
            smoothing_window: 12,
            prog_threshold: 0.5,
            diff_threshold: 0.1,
            eol_threshold: 50.0,
            b_walk_var: 1e-5,
            c_walk_var: 1e-5,
            b_prior: [1e-3, 1.0],
            c_prior: [1e-3, 10.0],
            redraw_c_at_change: true,
            relative_noise: 0.2,
            absolute_noise: 0.01,
            max_rul_s: 1e6,
            snapshot_period_s: 10.0,
            alpha: 0.2,
            seed: 1,
            output_dir: PathBuf::from("out/edge-cloud"),
        }
    }
}

impl EdgeCloudConfig {
    /// Reads a TOML config; syntax and type errors carry line and column.
    pub fn from_toml_file(path: &Path) -> Result<Self, EdgeCloudError> {
        let text = std::fs::read_to_string(path).map_err(|source| EdgeCloudError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let config: Self = toml::from_str(&text).map_err(|e| {
            let (line, column) = e
                .span()
                .map_or((1, 1), |span| line_column(&text, span.start));
            EdgeCloudError::Parse {
                path: path.to_path_buf(),
                line,
                column,
                message: e.message().to_string(),
            }
        })?;
        config.validate()?;
        Ok(config)
    }

    /// Checks ranges.
    pub fn validate(&self) -> Result<(), EdgeCloudError> {
        let positive = [
            ("psi", self.psi),
            ("nrmse_alarm", self.nrmse_alarm),
            ("prog_threshold", self.prog_threshold),
            ("diff_threshold", self.diff_threshold),
            ("eol_threshold", self.eol_threshold),
            (
                "relative_noise + absolute_noise",
                self.relative_noise + self.absolute_noise,
            ),
            ("max_rul_s", self.max_rul_s),
            ("snapshot_period_s", self.snapshot_period_s),
            ("alpha", self.alpha),
            ("b_prior[0]", self.b_prior[0]),
            ("c_prior[0]", self.c_prior[0]),
        ];
        for (name, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(EdgeCloudError::Config(format!("`{name}` must be positive")));
            }
        }
        let nonneg = [
            ("b_walk_var", self.b_walk_var),
            ("c_walk_var", self.c_walk_var),
            ("relative_noise", self.relative_noise),
            ("absolute_noise", self.absolute_noise),
        ];
        for (name, v) in nonneg {
            if !(v.is_finite() && v >= 0.0) {
                return Err(EdgeCloudError::Config(format!("`{name}` must be >= 0")));
            }
        }
        if !(self.b_prior[1] >= self.b_prior[0] && self.c_prior[1] >= self.c_prior[0]) {
            return Err(EdgeCloudError::Config(
                "prior ranges must be [low, high]".into(),
            ));
        }
        if self.eol_threshold <= self.prog_threshold {
            return Err(EdgeCloudError::Config(
                "`eol_threshold` must exceed `prog_threshold`".into(),
            ));
        }
        if self.reference_models == 0 || self.smoothing_window == 0 || self.spectrum_points == 0 {
            return Err(EdgeCloudError::Config(
                "`reference_models`, `smoothing_window` and `spectrum_points` must be >= 1".into(),
            ));
        }
        if self.instrument_delay > 2 * ORDER {
            return Err(EdgeCloudError::Config(format!(
                "`instrument_delay` must be <= {}",
                2 * ORDER
            )));
        }
        Ok(())
    }

    fn edge_config(&self) -> EdgeConfig<f64> {
        EdgeConfig {
            oriv: OrivConfig {
                psi: self.psi,
                instrument_delay: self.instrument_delay,
            },
            check: WindowCheck::default(),
            warmup_models: self.warmup_models,
            reference_models: self.reference_models,
            nrmse_alarm: self.nrmse_alarm,
        }
    }
}

fn line_column(text: &str, offset: usize) -> (usize, usize) {
    let before = text.get(..offset).unwrap_or(text);
    let line = before.matches('\n').count() + 1;
    let column = before
        .rsplit('\n')
        .next()
        .map_or(1, |l| l.chars().count() + 1);
    (line, column)
}

/// One row of the per-snapshot series.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SeriesRow {
    pub t_s: f64,
    /// The edge rejected this snapshot (flat, saturated or ORIV failure) and held its model.
    pub edge_rejected: bool,
    pub hi_nrmse: Option<f64>,
    pub nrmse_alarm: bool,
    pub hi_raw: Option<f64>,
    pub hi_smoothed: Option<f64>,
    pub stage: Option<DegradationStage>,
    pub rul: Option<RulPrediction>,
    /// Actual RUL `t_EoL - t`, s.
    pub true_rul_s: f64,
}

/// Traffic from the edge to the cloud.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct DataRate {
    /// Raw signal streamed as 4-byte REALs, B/s.
    pub raw_bytes_per_s: f64,
    /// Model parameters (`n` REALs per snapshot period), B/s.
    pub model_bytes_per_s: f64,
    /// Raw / model.
    pub reduction: f64,
}

impl DataRate {
    /// The paper's accounting: one channel streamed at 2560 Hz against the model's REALs
    /// (`n`, plus the noise variance when the HI uses it) every snapshot period.
    pub fn for_config(config: &EdgeCloudConfig) -> Self {
        let sample_rate = SNAPSHOT_LEN as f64 / 0.1;
        let raw = sample_rate * 4.0;
        let reals = ORDER + usize::from(config.use_noise_variance);
        let model = reals as f64 * 4.0 / config.snapshot_period_s;
        Self {
            raw_bytes_per_s: raw,
            model_bytes_per_s: model,
            reduction: raw / model,
        }
    }
}

/// Scores of one bearing.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct BearingSummary {
    pub bearing: String,
    pub end_of_life_s: f64,
    pub snapshots: usize,
    pub edge_rejections: usize,
    pub trigger_s: Option<f64>,
    pub change_s: Option<f64>,
    pub first_nrmse_alarm_s: Option<f64>,
    pub predictions: usize,
    /// Prognostic horizon with the band `alpha * t_EoL` (Eqs. 34-35), s; None when the last
    /// prediction is outside the band or there is none.
    pub prognostic_horizon_s: Option<f64>,
    /// PH as a fraction of the life.
    pub prognostic_horizon_fraction: f64,
    pub alpha: f64,
    pub data_rate: DataRate,
}

/// A whole analysed bearing.
#[derive(Clone, Debug)]
pub struct BearingRun {
    pub summary: BearingSummary,
    pub series: Vec<SeriesRow>,
}

/// What the edge did with one snapshot.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EdgeRow {
    pub t_s: f64,
    /// The snapshot was rejected (flat, saturated, ORIV failure); the last model is held.
    pub edge_rejected: bool,
    pub hi_nrmse: Option<f64>,
    pub nrmse_alarm: bool,
    /// The model sent to the cloud at this time (the held one after a rejection).
    pub sent: Option<ArModel<f64, ORDER>>,
}

/// The edge half over a whole record: one row per snapshot.
pub fn run_edge(
    record: &BearingRecord,
    config: &EdgeCloudConfig,
) -> Result<Vec<EdgeRow>, EdgeCloudError> {
    config.validate()?;
    let mut edge = EdgeMonitor::<f64, ORDER, ORDER, BUFFER_SNAPSHOTS, SNAPSHOT_LEN>::new(
        config.edge_config(),
    )?;
    let mut transmitting = false;
    let mut rows = Vec::with_capacity(record.snapshots.len());
    for snap in &record.snapshots {
        let signal = match config.channel {
            Channel::Horizontal => &snap.horizontal,
            Channel::Vertical => &snap.vertical,
        };
        let mut row = EdgeRow {
            t_s: snap.t_s,
            edge_rejected: false,
            hi_nrmse: None,
            nrmse_alarm: false,
            sent: None,
        };
        match edge.push_snapshot(signal) {
            Ok(Some(r)) => {
                row.hi_nrmse = r.hi_nrmse;
                row.nrmse_alarm = r.alarm;
                transmitting |= r.transmit;
                row.sent = r.transmit.then_some(r.model);
            }
            Ok(None) => {}
            Err(_) => {
                // The edge holds its last good model and sends it again.
                row.edge_rejected = true;
                row.sent = edge.model().copied().filter(|_| transmitting);
            }
        }
        rows.push(row);
    }
    Ok(rows)
}

/// Runs edge and cloud over a loaded record.
pub fn analyse_bearing(
    record: &BearingRecord,
    config: &EdgeCloudConfig,
) -> Result<BearingRun, EdgeCloudError> {
    let edge_rows = run_edge(record, config)?;
    run_cloud(record, &edge_rows, config)
}

/// The cloud half and the scoring over the edge's rows (cloud settings only are used, so
/// one edge pass serves many cloud configurations when tuning).
pub fn run_cloud(
    record: &BearingRecord,
    edge_rows: &[EdgeRow],
    config: &EdgeCloudConfig,
) -> Result<BearingRun, EdgeCloudError> {
    config.validate()?;
    let mut cloud = CloudPrognoser::new(config)?;
    let eol = record.end_of_life_s();
    let mut series = Vec::with_capacity(edge_rows.len());
    for e in edge_rows {
        let mut row = SeriesRow {
            t_s: e.t_s,
            edge_rejected: e.edge_rejected,
            hi_nrmse: e.hi_nrmse,
            nrmse_alarm: e.nrmse_alarm,
            hi_raw: None,
            hi_smoothed: None,
            stage: None,
            rul: None,
            true_rul_s: eol - e.t_s,
        };
        if let Some(model) = e.sent {
            let step = cloud.on_model(e.t_s, &model)?;
            row.hi_raw = step.hi_raw;
            row.hi_smoothed = step.hi_smoothed;
            row.stage = step.stage;
            row.rul = step.rul;
        }
        series.push(row);
    }
    let rejections = series.iter().filter(|r| r.edge_rejected).count();
    let predicted: Vec<&SeriesRow> = series.iter().filter(|r| r.rul.is_some()).collect();
    let times: Vec<f64> = predicted.iter().map(|r| r.t_s).collect();
    let truth: Vec<f64> = predicted.iter().map(|r| r.true_rul_s).collect();
    let estimate: Vec<f64> = predicted
        .iter()
        .map(|r| r.rul.map_or(f64::NAN, |p| p.mean_s))
        .collect();
    let ph = prognostic_horizon(
        &times,
        &truth,
        &estimate,
        eol,
        config.alpha,
        HorizonBand::FractionOfEol,
    );
    let summary = BearingSummary {
        bearing: record.name(),
        end_of_life_s: eol,
        snapshots: record.snapshots.len(),
        edge_rejections: rejections,
        trigger_s: cloud.trigger_s(),
        change_s: cloud.change_s(),
        first_nrmse_alarm_s: series.iter().find(|r| r.nrmse_alarm).map(|r| r.t_s),
        predictions: predicted.len(),
        prognostic_horizon_s: ph,
        prognostic_horizon_fraction: ph.map_or(0.0, |p| p / eol.max(f64::MIN_POSITIVE)),
        alpha: config.alpha,
        data_rate: DataRate::for_config(config),
    };
    Ok(BearingRun { summary, series })
}

/// Runs the whole method on one bearing file and writes `hi.csv`, `rul.csv`, `summary.json`,
/// `hi.svg` and `rul.svg` into `<config.output_dir>/<file stem>/`, each atomically (temporary
/// file in the same directory, then rename). Returns the analysis and the output directory.
pub fn run_bearing(
    csv_path: &Path,
    config: &EdgeCloudConfig,
) -> Result<(BearingRun, PathBuf), EdgeCloudError> {
    config.validate()?;
    let record = load_bearing(csv_path)?;
    let run = analyse_bearing(&record, config)?;
    let dir = config.output_dir.join(record.name());
    output::write_all(&dir, &run, config)?;
    Ok((run, dir))
}

/// What `prognos edge-cloud --bearing-csv FILE [--config FILE]` does: runs [`run_bearing`],
/// prints a short summary on stdout or the error on stderr, and returns the exit status
/// (0, 2 for a malformed bearing or config file, 1 for other failures).
pub fn cli_edge_cloud(bearing_csv: &Path, config_file: Option<&Path>) -> i32 {
    let result = config_file
        .map_or_else(
            || Ok(EdgeCloudConfig::default()),
            EdgeCloudConfig::from_toml_file,
        )
        .and_then(|config| run_bearing(bearing_csv, &config).map(|r| (r, config)));
    match result {
        Ok(((run, dir), config)) => {
            let s = &run.summary;
            let minutes = |v: Option<f64>| {
                v.map_or_else(|| "none".into(), |t| format!("{:.2} min", t / 60.0))
            };
            println!("bearing            {}", s.bearing);
            println!(
                "end of life        {:.2} min ({} snapshots)",
                s.end_of_life_s / 60.0,
                s.snapshots
            );
            println!("prognosis trigger  {}", minutes(s.trigger_s));
            println!("stage change       {}", minutes(s.change_s));
            println!("HI_NRMSE alarm     {}", minutes(s.first_nrmse_alarm_s));
            println!(
                "prognostic horizon {} (alpha {}, {:.1} % of life)",
                minutes(s.prognostic_horizon_s),
                config.alpha,
                100.0 * s.prognostic_horizon_fraction
            );
            println!(
                "edge to cloud      {:.1} B/s of model parameters vs {:.0} B/s raw ({:.0}x less)",
                s.data_rate.model_bytes_per_s, s.data_rate.raw_bytes_per_s, s.data_rate.reduction
            );
            println!("rejected snapshots {}", s.edge_rejections);
            println!("outputs            {}", dir.display());
            0
        }
        Err(e) => {
            eprintln!("error: {e}");
            e.exit_code()
        }
    }
}
