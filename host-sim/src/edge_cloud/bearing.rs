//! Reader of the PRONOSTIA bearing format (`data/pronostia/README.md`): one row per snapshot,
//! `idx`, `t_s`, `h0..h255`, `v0..v255`. Every problem is reported with the file, the 1-based
//! line and the 1-based character column where the offending field starts (or where the
//! missing one should have started).

use super::EdgeCloudError;
use std::path::{Path, PathBuf};

/// Samples per axis in one snapshot (0.1 s at 2560 Hz).
pub const SNAPSHOT_LEN: usize = 256;

/// One snapshot of both accelerometers.
#[derive(Clone, Debug, PartialEq)]
pub struct Snapshot {
    /// 1-based snapshot number.
    pub idx: u64,
    /// Nominal time, s.
    pub t_s: f64,
    /// Horizontal acceleration, g.
    pub horizontal: [f64; SNAPSHOT_LEN],
    /// Vertical acceleration, g.
    pub vertical: [f64; SNAPSHOT_LEN],
}

/// A whole run-to-failure record; the last snapshot is the end of life.
#[derive(Clone, Debug)]
pub struct BearingRecord {
    pub path: PathBuf,
    pub snapshots: Vec<Snapshot>,
}

impl BearingRecord {
    /// Time of the last snapshot (the end of life), s.
    pub fn end_of_life_s(&self) -> f64 {
        self.snapshots.last().map_or(0.0, |s| s.t_s)
    }

    /// File stem, e.g. `Bearing1_1`.
    pub fn name(&self) -> String {
        self.path
            .file_stem()
            .map_or_else(|| "bearing".into(), |s| s.to_string_lossy().into_owned())
    }
}

fn parse_error(path: &Path, line: usize, column: usize, message: String) -> EdgeCloudError {
    EdgeCloudError::Parse {
        path: path.to_path_buf(),
        line,
        column,
        message,
    }
}

/// Reads and validates a bearing file.
pub fn load_bearing(path: &Path) -> Result<BearingRecord, EdgeCloudError> {
    let text = std::fs::read_to_string(path).map_err(|source| EdgeCloudError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse_bearing(path, &text)
}

/// Parses bearing text (`path` is only used in messages).
pub fn parse_bearing(path: &Path, text: &str) -> Result<BearingRecord, EdgeCloudError> {
    let expected_fields = 2 + 2 * SNAPSHOT_LEN;
    let mut lines = text.split('\n').enumerate();
    let header = lines
        .next()
        .map(|(_, l)| l.trim_end_matches('\r'))
        .unwrap_or("");
    check_header(path, header)?;
    let mut snapshots: Vec<Snapshot> = Vec::new();
    for (index, raw) in lines {
        let line_no = index + 1;
        let line = raw.trim_end_matches('\r');
        if line.is_empty() {
            continue;
        }
        let mut values = [0.0f64; 2 + 2 * SNAPSHOT_LEN];
        let mut count = 0usize;
        let mut column = 1usize;
        for field in line.split(',') {
            if count >= expected_fields {
                return Err(parse_error(
                    path,
                    line_no,
                    column,
                    format!("more than {expected_fields} fields"),
                ));
            }
            let trimmed = field.trim();
            let value: f64 = trimmed.parse().map_err(|_| {
                parse_error(
                    path,
                    line_no,
                    column,
                    format!("`{trimmed}` is not a number"),
                )
            })?;
            if !value.is_finite() {
                return Err(parse_error(
                    path,
                    line_no,
                    column,
                    format!("`{trimmed}` is not finite"),
                ));
            }
            if let Some(slot) = values.get_mut(count) {
                *slot = value;
            }
            count += 1;
            column += field.chars().count() + 1;
        }
        if count < expected_fields {
            return Err(parse_error(
                path,
                line_no,
                line.chars().count() + 1,
                format!("row has {count} fields, expected {expected_fields} (truncated?)"),
            ));
        }
        let (idx_value, t_s) = (values[0], values[1]);
        if idx_value < 1.0 || idx_value.fract() != 0.0 {
            return Err(parse_error(
                path,
                line_no,
                1,
                format!("idx `{idx_value}` is not a positive integer"),
            ));
        }
        if let Some(prev) = snapshots.last()
            && t_s <= prev.t_s
        {
            let col = line.find(',').map_or(1, |p| p + 2);
            return Err(parse_error(
                path,
                line_no,
                col,
                format!("t_s {t_s} does not increase (previous {})", prev.t_s),
            ));
        }
        let mut horizontal = [0.0; SNAPSHOT_LEN];
        let mut vertical = [0.0; SNAPSHOT_LEN];
        horizontal.copy_from_slice(&values[2..2 + SNAPSHOT_LEN]);
        vertical.copy_from_slice(&values[2 + SNAPSHOT_LEN..]);
        snapshots.push(Snapshot {
            idx: idx_value as u64,
            t_s,
            horizontal,
            vertical,
        });
    }
    if snapshots.is_empty() {
        return Err(parse_error(
            path,
            2,
            1,
            "no snapshot rows after the header".into(),
        ));
    }
    Ok(BearingRecord {
        path: path.to_path_buf(),
        snapshots,
    })
}

fn check_header(path: &Path, header: &str) -> Result<(), EdgeCloudError> {
    let expected = std::iter::once("idx".to_string())
        .chain(std::iter::once("t_s".to_string()))
        .chain((0..SNAPSHOT_LEN).map(|i| format!("h{i}")))
        .chain((0..SNAPSHOT_LEN).map(|i| format!("v{i}")));
    let mut column = 1usize;
    let mut fields = header.split(',');
    for want in expected {
        match fields.next() {
            Some(got) if got.trim() == want => column += got.chars().count() + 1,
            Some(got) => {
                return Err(parse_error(
                    path,
                    1,
                    column,
                    format!("header field `{}`, expected `{want}`", got.trim()),
                ));
            }
            None => {
                return Err(parse_error(
                    path,
                    1,
                    header.chars().count() + 1,
                    format!("header ends before `{want}`"),
                ));
            }
        }
    }
    if fields.next().is_some() {
        return Err(parse_error(path, 1, column, "extra header fields".into()));
    }
    Ok(())
}
