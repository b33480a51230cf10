//! Output files that are either complete or absent: every write goes to a temporary file in
//! the destination folder, is flushed to disk, and is then renamed over the destination.
//! Also the fixed-width summary table the commands print.

use crate::dataio::TimeSeries;
use crate::error::SimError;
use serde::Serialize;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Marker in temporary file names, so stale ones from an interrupted process can be found.
pub const TEMP_MARKER: &str = ".prognos-tmp-";

static COUNTER: AtomicU64 = AtomicU64::new(0);

/// Writes `path` atomically: `write` fills a temporary file next to it, which replaces
/// `path` only if `write` succeeds. Parent folders are created. On failure the temporary is
/// removed and `path` is untouched.
pub fn write_atomic<F>(path: &Path, write: F) -> Result<(), SimError>
where
    F: FnOnce(&mut BufWriter<File>) -> std::io::Result<()>,
{
    let fail = |source| SimError::Output {
        path: path.to_path_buf(),
        source,
    };
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    std::fs::create_dir_all(&dir).map_err(fail)?;
    let file_name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "out".into());
    let temp = dir.join(format!(
        ".{file_name}{TEMP_MARKER}{}-{}",
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::Relaxed)
    ));
    let result = (|| {
        let mut writer = BufWriter::new(File::create(&temp)?);
        write(&mut writer)?;
        let file = writer.into_inner().map_err(|e| e.into_error())?;
        file.sync_all()?;
        std::fs::rename(&temp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&temp);
    }
    result.map_err(fail)
}

/// Writes a time series as CSV, atomically.
pub fn write_csv(path: &Path, series: &TimeSeries) -> Result<(), SimError> {
    write_atomic(path, |w| series.write_csv(w))
}

/// Writes pretty JSON, atomically.
pub fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<(), SimError> {
    write_atomic(path, |w| {
        serde_json::to_writer_pretty(&mut *w, value)?;
        w.write_all(b"\n")
    })
}

/// Writes text (e.g. an SVG document), atomically.
pub fn write_text(path: &Path, text: &str) -> Result<(), SimError> {
    write_atomic(path, |w| w.write_all(text.as_bytes()))
}

/// Removes temporary files left in `dir` by an interrupted process (not recursive).
pub fn remove_stale_temporaries(dir: &Path) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let name = entry.file_name();
        let name = name.to_string_lossy();
        if name.starts_with('.') && name.contains(TEMP_MARKER) {
            let _ = std::fs::remove_file(entry.path());
        }
    }
}

/// A fixed-width text table: the first column left-aligned, the others right-aligned,
/// every column as wide as its widest cell.
pub fn format_table(headers: &[&str], rows: &[Vec<String>]) -> String {
    let columns = headers.len();
    let mut widths: Vec<usize> = headers.iter().map(|h| h.chars().count()).collect();
    for row in rows {
        for (w, cell) in widths.iter_mut().zip(row) {
            *w = (*w).max(cell.chars().count());
        }
    }
    let line = |cells: &mut dyn Iterator<Item = &str>| -> String {
        let mut out = String::new();
        for (i, (cell, w)) in cells.zip(&widths).enumerate() {
            if i > 0 {
                out.push_str("  ");
            }
            let pad = w.saturating_sub(cell.chars().count());
            if i == 0 {
                out.push_str(cell);
                out.push_str(&" ".repeat(pad));
            } else {
                out.push_str(&" ".repeat(pad));
                out.push_str(cell);
            }
        }
        out.trim_end().to_string() + "\n"
    };
    let mut out = line(&mut headers.iter().copied());
    let rule: Vec<String> = widths.iter().map(|w| "-".repeat(*w)).collect();
    out += &line(&mut rule.iter().map(String::as_str));
    for row in rows {
        let mut cells = row.iter().map(String::as_str).chain(std::iter::repeat(""));
        out += &line(&mut cells.by_ref().take(columns));
    }
    out
}

/// Formats a number for tables: `-` for NaN/None, 4 significant digits otherwise.
pub fn fmt_num(value: Option<f64>) -> String {
    match value {
        Some(v) if v.is_finite() => {
            if v != 0.0 && (v.abs() >= 1e5 || v.abs() < 1e-3) {
                format!("{v:.3e}")
            } else {
                let digits = (3 - v.abs().log10().floor().max(0.0) as i32).max(0) as usize;
                format!("{v:.digits$}")
            }
        }
        _ => "-".to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("prognos-output-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        dir
    }

    #[test]
    fn failed_write_leaves_nothing_and_keeps_old_file() {
        let dir = scratch("atomic");
        let path = dir.join("a.txt");
        write_text(&path, "old").unwrap();
        let err = write_atomic(&path, |w| {
            w.write_all(b"partial")?;
            Err(std::io::Error::other("disk on fire"))
        })
        .unwrap_err();
        assert_eq!(err.exit_code(), 1);
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "old");
        let names: Vec<_> = std::fs::read_dir(&dir).unwrap().flatten().collect();
        assert_eq!(names.len(), 1, "temporary left behind");
        write_json(&dir.join("b.json"), &vec![1, 2]).unwrap();
        let v: Vec<i32> =
            serde_json::from_str(&std::fs::read_to_string(dir.join("b.json")).unwrap()).unwrap();
        assert_eq!(v, vec![1, 2]);
        std::fs::write(dir.join(format!(".c{TEMP_MARKER}1-1")), "x").unwrap();
        remove_stale_temporaries(&dir);
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 2);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn table_is_aligned() {
        let t = format_table(
            &["system", "rmse"],
            &[
                vec!["a".into(), "1.5".into()],
                vec!["longer".into(), "10.25".into()],
            ],
        );
        assert_eq!(
            t,
            "system   rmse\n------  -----\na         1.5\nlonger  10.25\n"
        );
        assert_eq!(fmt_num(Some(12.3456)), "12.35");
        assert_eq!(fmt_num(Some(f64::NAN)), "-");
        assert_eq!(fmt_num(None), "-");
        assert_eq!(fmt_num(Some(1.5e-5)), "1.500e-5");
    }
}
