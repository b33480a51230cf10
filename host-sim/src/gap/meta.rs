//! The gap diagnoser's sidecar `<data>.meta.toml`.
//!
//! ```toml
//! plant = "reaction_wheel"        # a built-in gap plant (see `gap::plant::builtin_plant`)
//! dt = 0.05                       # nominal sample time (s); without it, the data's median step
//! sim_effects = ["driver_lowpass"] # catalogue effects the user's model already includes
//! input_timing = "before"        # before | at | after | auto (default; see `gap::plant::InputTiming`)
//! description = "free text"
//! [units]                          # per column, e.g. "y:speed" = "rpm" (converted, `gap::units`)
//! [model]                          # parameter values; anything not given takes the default
//! [noise]                          # optional sensor noise std per channel, e.g. "y:speed" = 3e-3
//! ```
//! Every entry keeps its byte offset so that a bad name is reported at its line and column.
//! An unknown top-level key is not an error (a preparer's own notes, say `seed`): it is
//! ignored with a warning at its line and column. Unknown names *inside* `[model]` and
//! `sim_effects` are errors, since they would change the diagnosis.

use crate::dataio::{meta_path, toml_error};
use crate::error::{SimError, read_input};
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// A value with the byte offset of its entry in the meta file.
#[derive(Clone, Debug, PartialEq)]
pub struct Located<T> {
    /// The value.
    pub value: T,
    /// Byte offset of the entry (the key for tables, the value for arrays).
    pub offset: usize,
}

/// Parsed sidecar of a gap-diagnosis data file.
#[derive(Clone, Debug, PartialEq)]
pub struct GapMeta {
    /// Where it was read from.
    pub path: PathBuf,
    /// The file text (for error positions).
    pub text: String,
    /// Plant name.
    pub plant: Located<String>,
    /// Sample time (s); `None` takes the median step of the data's `t`.
    pub dt: Option<f64>,
    /// Units per column name.
    pub units: BTreeMap<String, Located<String>>,
    /// Model parameter values.
    pub model: BTreeMap<String, Located<f64>>,
    /// Effects the user's model already includes.
    pub sim_effects: Vec<Located<String>>,
    /// Declared sensor noise std per column (`y:<name>`).
    pub noise: BTreeMap<String, Located<f64>>,
    /// Free text.
    pub description: Option<String>,
    /// `input_timing`: `before`, `at`, `after` or `auto` (the default: chosen from the
    /// data), see [`crate::gap::plant::InputTiming`].
    pub input_timing: Option<Located<String>>,
    /// Ignored entries, each as `file:line:column: message`.
    pub warnings: Vec<String>,
}

impl GapMeta {
    /// A bad-input error at `offset` of this file.
    pub fn error_at(&self, offset: usize, message: impl Into<String>) -> SimError {
        SimError::at_offset(&self.path, &self.text, offset, message)
    }
}

/// Start of the line that holds `offset` plus its indentation: where a `key = value` entry
/// begins when `offset` points at the value.
fn key_offset(text: &str, offset: usize) -> usize {
    let before = text.get(..offset.min(text.len())).unwrap_or("");
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    let line = text.get(line_start..).unwrap_or("");
    line_start + (line.len() - line.trim_start().len())
}

/// Where the top-level key or table `key` is written (0 when not found: a quoted or
/// dotted spelling).
fn top_level_key_offset(text: &str, key: &str) -> usize {
    let mut offset = 0;
    for line in text.split_inclusive('\n') {
        let indent = line.len() - line.trim_start().len();
        let body = line.trim_start();
        let named = body
            .strip_prefix('[')
            .map_or(body, |b| b.trim_start_matches('['))
            .trim_start();
        if let Some(rest) = named.strip_prefix(key)
            && rest.trim_start().starts_with(['=', ']', '.'])
        {
            return offset + indent;
        }
        offset += line.len();
    }
    0
}

/// The meta file of `data` when none is given: `<data>.meta.toml` (`run.csv.meta.toml`)
/// or, when that does not exist, `<stem>.meta.toml` (`run.meta.toml`).
pub fn find_gap_meta(data: &Path) -> PathBuf {
    let beside = meta_path(data);
    if beside.exists() {
        return beside;
    }
    let stem = data.with_extension("meta.toml");
    if stem.exists() { stem } else { beside }
}

/// Reads the meta file at `meta` or, when `None`, beside `data` ([`find_gap_meta`]).
pub fn read_gap_meta(data: &Path, meta: Option<&Path>) -> Result<GapMeta, SimError> {
    let path = meta.map_or_else(|| find_gap_meta(data), Path::to_path_buf);
    if !path.exists() {
        let also = match meta {
            Some(_) => String::new(),
            None => format!(" (or `{}`)", data.with_extension("meta.toml").display()),
        };
        return Err(SimError::Unreadable {
            path: path.clone(),
            message: format!(
                "missing meta file: `prognos gap` needs `{}`{also} (plant, dt, [model]) \
                 beside the data, or --meta FILE",
                path.display()
            ),
        });
    }
    let text = read_input(&path)?;
    parse_gap_meta(&path, &text)
}

/// Parses meta text; `path` is used in error messages.
pub fn parse_gap_meta(path: &Path, text: &str) -> Result<GapMeta, SimError> {
    #[derive(Deserialize)]
    struct Raw {
        plant: toml::Spanned<String>,
        #[serde(default)]
        dt: Option<toml::Spanned<f64>>,
        #[serde(default)]
        units: BTreeMap<String, toml::Spanned<String>>,
        #[serde(default)]
        model: BTreeMap<String, toml::Spanned<f64>>,
        #[serde(default)]
        sim_effects: Vec<toml::Spanned<String>>,
        #[serde(default)]
        noise: BTreeMap<String, toml::Spanned<f64>>,
        #[serde(default)]
        description: Option<String>,
        #[serde(default)]
        input_timing: Option<toml::Spanned<String>>,
        #[serde(flatten)]
        unknown: BTreeMap<String, toml::Value>,
    }
    let raw: Raw = toml::from_str(text).map_err(|e| toml_error(path, text, &e))?;
    let at = |offset: usize, message: String| SimError::at_offset(path, text, offset, message);
    let dt = match &raw.dt {
        Some(d) => {
            let dt = *d.get_ref();
            if !(dt.is_finite() && dt > 0.0) {
                return Err(at(
                    d.span().start,
                    format!("`dt` must be a positive number, found {dt}"),
                ));
            }
            Some(dt)
        }
        None => None,
    };
    let warnings = raw
        .unknown
        .keys()
        .map(|k| {
            at(
                top_level_key_offset(text, k),
                format!(
                    "ignored unknown key `{k}` (read: plant, dt, sim_effects, input_timing, \
                     description, [units], [model], [noise])"
                ),
            )
            .to_string()
        })
        .collect();
    let keyed = |m: BTreeMap<String, toml::Spanned<f64>>,
                 what: &str|
     -> Result<BTreeMap<String, Located<f64>>, SimError> {
        let mut out = BTreeMap::new();
        for (k, v) in m {
            let offset = key_offset(text, v.span().start);
            let value = *v.get_ref();
            if !value.is_finite() {
                return Err(at(offset, format!("{what} `{k}` must be finite")));
            }
            out.insert(k, Located { value, offset });
        }
        Ok(out)
    };
    let model = keyed(raw.model, "model parameter")?;
    let noise = keyed(raw.noise, "noise std")?;
    for (k, v) in &noise {
        if v.value <= 0.0 {
            return Err(at(v.offset, format!("noise std `{k}` must be positive")));
        }
    }
    Ok(GapMeta {
        path: path.to_path_buf(),
        text: text.to_string(),
        plant: Located {
            value: raw.plant.get_ref().clone(),
            offset: raw.plant.span().start,
        },
        dt,
        units: raw
            .units
            .into_iter()
            .map(|(k, v)| {
                let offset = key_offset(text, v.span().start);
                (
                    k,
                    Located {
                        value: v.into_inner(),
                        offset,
                    },
                )
            })
            .collect(),
        model,
        sim_effects: raw
            .sim_effects
            .into_iter()
            .map(|s| Located {
                offset: s.span().start,
                value: s.into_inner(),
            })
            .collect(),
        noise,
        description: raw.description,
        input_timing: raw.input_timing.map(|s| Located {
            offset: s.span().start,
            value: s.into_inner(),
        }),
        warnings,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn model_keys_are_located_at_their_line() {
        let text = "plant = \"dc_motor\"\ndt = 0.01\n[model]\n  resistance = 2.5\n";
        let m = parse_gap_meta(Path::new("m.toml"), text).unwrap();
        let e = m.error_at(m.model["resistance"].offset, "x");
        assert_eq!(e.to_string(), "m.toml:4:3: x");
        assert_eq!(m.model["resistance"].value, 2.5);
    }

    #[test]
    fn an_unknown_top_level_key_is_a_warning_at_its_line_and_dt_may_be_left_out() {
        let text = "plant = \"dc_motor\"\nseed = 3\n[truth]\neffect = \"x\"\n";
        let m = parse_gap_meta(Path::new("m.toml"), text).unwrap();
        assert_eq!(m.dt, None);
        assert_eq!(m.warnings.len(), 2, "{:?}", m.warnings);
        assert!(
            m.warnings[0].starts_with("m.toml:2:1: ignored unknown key `seed`"),
            "{:?}",
            m.warnings
        );
        assert!(m.warnings[1].starts_with("m.toml:3:"), "{:?}", m.warnings);
    }

    #[test]
    fn negative_dt_is_rejected_at_the_value() {
        let e = parse_gap_meta(Path::new("m.toml"), "plant = \"x\"\ndt = -1\n").unwrap_err();
        assert_eq!(e.exit_code(), 2);
        assert!(e.to_string().starts_with("m.toml:2:6:"), "{e}");
    }
}
