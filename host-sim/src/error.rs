//! The host simulator's error type and the mapping to process exit codes.

use std::path::{Path, PathBuf};

/// Why a host command failed. [`SimError::exit_code`] maps it to the CLI's exit status:
/// 2 for bad input files, 1 for everything else.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// A malformed input file (scenario, CSV, sidecar). Line and column are 1-based; the
    /// column counts characters, not bytes.
    #[error("{}:{line}:{column}: {message}", path.display())]
    BadInput {
        path: PathBuf,
        line: usize,
        column: usize,
        message: String,
    },
    /// An input file that could not be read at all (missing, unreadable, not UTF-8).
    #[error("{}: cannot read: {message}", path.display())]
    Unreadable { path: PathBuf, message: String },
    /// Writing an output file failed.
    #[error("{}: cannot write: {source}", path.display())]
    Output {
        path: PathBuf,
        source: std::io::Error,
    },
    /// The estimator or a plant failed in a way the run cannot continue from.
    #[error("{0}")]
    Run(String),
}

impl SimError {
    /// Exit status for the CLI: 2 for bad or unreadable input files, 1 otherwise.
    pub fn exit_code(&self) -> i32 {
        match self {
            SimError::BadInput { .. } | SimError::Unreadable { .. } => 2,
            SimError::Output { .. } | SimError::Run(_) => 1,
        }
    }

    /// A bad-input error at a byte offset of `text`, converted to line and column.
    pub fn at_offset(path: &Path, text: &str, offset: usize, message: impl Into<String>) -> Self {
        let (line, column) = line_column(text, offset);
        SimError::BadInput {
            path: path.to_path_buf(),
            line,
            column,
            message: message.into(),
        }
    }
}

/// 1-based line and character column of byte `offset` in `text` (clamped to the text; an
/// offset inside a multi-byte character counts as that character).
pub fn line_column(text: &str, offset: usize) -> (usize, usize) {
    let mut end = offset.min(text.len());
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    let before = &text[..end];
    let line = before.matches('\n').count() + 1;
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    let column = before[line_start..].chars().count() + 1;
    (line, column)
}

/// Reads a whole input file as UTF-8, mapping failures to [`SimError::Unreadable`] (or to
/// [`SimError::BadInput`] at the first invalid byte for non-UTF-8 content).
pub fn read_input(path: &Path) -> Result<String, SimError> {
    let bytes = std::fs::read(path).map_err(|e| SimError::Unreadable {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    String::from_utf8(bytes).map_err(|e| {
        let valid = e.utf8_error().valid_up_to();
        let bytes = e.as_bytes();
        let text = String::from_utf8_lossy(&bytes[..valid]);
        SimError::at_offset(path, &text, valid, "file is not valid UTF-8")
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn line_column_counts_from_one() {
        let text = "ab\ncdé\nf";
        assert_eq!(line_column(text, 0), (1, 1));
        assert_eq!(line_column(text, 2), (1, 3));
        assert_eq!(line_column(text, 3), (2, 1));
        // 'é' is two bytes (5 and 6), so the 'f' after the newline is byte 8.
        assert_eq!(line_column(text, 8), (3, 1));
        assert_eq!(line_column(text, 6), (2, 3));
        assert_eq!(line_column(text, 7), (2, 4));
        assert_eq!(line_column(text, 100), (3, 2));
    }

    #[test]
    fn exit_codes() {
        let bad = SimError::at_offset(Path::new("a.toml"), "x", 0, "oops");
        assert_eq!(bad.exit_code(), 2);
        assert_eq!(bad.to_string(), "a.toml:1:1: oops");
        assert_eq!(SimError::Run("x".into()).exit_code(), 1);
    }
}
