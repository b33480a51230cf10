//! Readers for the committed reference files in `tests/reference/`.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// Path of a file in `tests/reference/`.
pub fn reference_path(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("reference")
        .join(name)
}

/// A numeric CSV table with a header row.
#[derive(Clone, Debug)]
pub struct Table {
    pub header: Vec<String>,
    pub rows: Vec<Vec<f64>>,
}

impl Table {
    /// Reads a CSV file whose cells after the header are all numbers. Panics with the path,
    /// line and column of a bad cell (this is test code: a bad reference file is a failure).
    pub fn read(path: &Path) -> Table {
        let text = std::fs::read_to_string(path)
            .unwrap_or_else(|e| panic!("{}: cannot read: {e}", path.display()));
        let mut lines = text.lines();
        let header: Vec<String> = lines
            .next()
            .unwrap_or_else(|| panic!("{}: empty file", path.display()))
            .split(',')
            .map(str::to_owned)
            .collect();
        let rows = lines
            .enumerate()
            .filter(|(_, l)| !l.trim().is_empty())
            .map(|(i, line)| {
                let cells: Vec<f64> = line
                    .split(',')
                    .enumerate()
                    .map(|(j, cell)| {
                        cell.trim().parse().unwrap_or_else(|e| {
                            panic!("{}:{}:{}: {cell:?}: {e}", path.display(), i + 2, j + 1)
                        })
                    })
                    .collect();
                assert_eq!(
                    cells.len(),
                    header.len(),
                    "{}:{}: wrong number of cells",
                    path.display(),
                    i + 2
                );
                cells
            })
            .collect();
        Table { header, rows }
    }

    /// Index of the named column.
    pub fn column(&self, name: &str) -> usize {
        self.header
            .iter()
            .position(|h| h == name)
            .unwrap_or_else(|| panic!("no column {name:?}"))
    }
}

/// Reads a `name,value` CSV into a map.
pub fn read_settings(path: &Path) -> HashMap<String, f64> {
    let text = std::fs::read_to_string(path)
        .unwrap_or_else(|e| panic!("{}: cannot read: {e}", path.display()));
    text.lines()
        .enumerate()
        .skip(1)
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(i, line)| {
            let (name, value) = line
                .split_once(',')
                .unwrap_or_else(|| panic!("{}:{}: expected name,value", path.display(), i + 1));
            let v = value.trim().parse().unwrap_or_else(|e| {
                panic!(
                    "{}:{}:{}: {value:?}: {e}",
                    path.display(),
                    i + 1,
                    name.len() + 2
                )
            });
            (name.trim().to_owned(), v)
        })
        .collect()
}
