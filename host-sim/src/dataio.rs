//! Recorded data: CSV time series with a header row (`t`, inputs `u:<name>`, measurements
//! `y:<name>`, optional truth `x:<name>`), and the sidecar `<file>.meta.toml` naming the
//! plant, the sample time and the units.
//!
//! Every reader reports a bad file with its path, 1-based line and column
//! ([`SimError::BadInput`]) and never panics on any bytes.

use crate::error::{SimError, line_column, read_input};
use serde::Deserialize;
use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};

/// A row-major table of `f64` columns with named headers: the in-memory form of every CSV
/// the host reads or writes (recorded data, lockstep logs).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TimeSeries {
    /// Column names, e.g. `t`, `u:cmd`, `y:pressure`, `x:leak_area`, `est:leak_area`.
    pub header: Vec<String>,
    /// One entry per sample; every row has `header.len()` values.
    pub rows: Vec<Vec<f64>>,
}

impl TimeSeries {
    /// An empty series with the given header.
    pub fn new(header: Vec<String>) -> Self {
        TimeSeries {
            header,
            rows: Vec::new(),
        }
    }

    /// Index of the column called `name`.
    pub fn column_index(&self, name: &str) -> Option<usize> {
        self.header.iter().position(|h| h == name)
    }

    /// A copy of the column called `name` (missing cells, if any, read as NaN).
    pub fn column(&self, name: &str) -> Option<Vec<f64>> {
        let i = self.column_index(name)?;
        Some(
            self.rows
                .iter()
                .map(|r| r.get(i).copied().unwrap_or(f64::NAN))
                .collect(),
        )
    }

    /// The names after `prefix:` of the columns with that prefix, in header order
    /// (`names_with_prefix("y")` gives the measurement channel names).
    pub fn names_with_prefix(&self, prefix: &str) -> Vec<String> {
        self.header
            .iter()
            .filter_map(|h| {
                h.split_once(':')
                    .filter(|(p, _)| *p == prefix)
                    .map(|(_, n)| n.to_string())
            })
            .collect()
    }

    /// Writes the series as CSV (values in Rust's shortest round-trip form; NaN as `NaN`).
    pub fn write_csv<W: Write>(&self, out: W) -> std::io::Result<()> {
        let mut writer = csv::Writer::from_writer(out);
        writer.write_record(&self.header)?;
        let mut cells: Vec<String> = Vec::with_capacity(self.header.len());
        for row in &self.rows {
            cells.clear();
            cells.extend(row.iter().map(|v| format!("{v}")));
            writer.write_record(&cells)?;
        }
        writer.flush()?;
        Ok(())
    }
}

/// Recorded data read from CSV: the table plus the channel names by role.
#[derive(Clone, Debug, PartialEq)]
pub struct Recording {
    /// The whole table, header included.
    pub series: TimeSeries,
    /// Input channel names (`u:<name>`), in file order.
    pub inputs: Vec<String>,
    /// Measurement channel names (`y:<name>`), in file order.
    pub measurements: Vec<String>,
    /// Truth channel names (`x:<name>`), in file order; empty for real data.
    pub truth: Vec<String>,
}

impl Recording {
    /// Column indices of `role:name` for each name, in order.
    pub fn indices(&self, role: &str, names: &[String]) -> Vec<usize> {
        names
            .iter()
            .filter_map(|n| self.series.column_index(&format!("{role}:{n}")))
            .collect()
    }
}

/// Reads and checks a recorded-data CSV file.
pub fn read_recording(path: &Path) -> Result<Recording, SimError> {
    let text = read_input(path)?;
    parse_recording(path, &text)
}

/// Parses recorded-data CSV text; `path` is only used in error messages.
///
/// Rules: the first header cell is `t`; every other header cell is `u:`, `y:` or `x:`
/// followed by a non-empty name, without duplicates; at least one `y:` column. Every row
/// has as many fields as the header; every field is a number (`NaN`, or an empty field
/// outside `t`, marks a dropped sample); `t` is finite and strictly increasing. Blank lines
/// are skipped.
pub fn parse_recording(path: &Path, text: &str) -> Result<Recording, SimError> {
    parse_table(path, text, true)
}

/// Reads any numeric CSV whose first header cell is `t` (e.g. a lockstep log with `est:`
/// and `rul:` columns), with the same checks as [`read_recording`] except the header roles.
pub fn read_series(path: &Path) -> Result<TimeSeries, SimError> {
    let text = read_input(path)?;
    parse_table(path, &text, false).map(|r| r.series)
}

fn parse_table(path: &Path, text: &str, recording: bool) -> Result<Recording, SimError> {
    let bad = |offset: usize, message: String| SimError::at_offset(path, text, offset, message);
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(false)
        .flexible(true)
        .from_reader(text.as_bytes());
    let mut record = csv::ByteRecord::new();
    let mut header: Option<(Vec<String>, usize)> = None;
    let mut series = TimeSeries::default();
    let mut last_t = f64::NEG_INFINITY;
    loop {
        let more = reader.read_byte_record(&mut record).map_err(|e| {
            let offset = e.position().map_or(0, |p| p.byte() as usize);
            bad(offset, format!("malformed CSV: {e}"))
        })?;
        if !more {
            break;
        }
        let start = record.position().map_or(0, |p| p.byte() as usize);
        let field_offset = |i: usize| field_start(text, start, i);
        match &header {
            None => {
                let names = parse_header(&record, &field_offset, &bad, recording)?;
                header = Some((names, start));
            }
            Some((names, _)) => {
                if record.len() != names.len() {
                    let (offset, what) = if record.len() > names.len() {
                        (field_offset(names.len()), "extra field")
                    } else {
                        (record_end(text, start), "missing field")
                    };
                    return Err(bad(
                        offset,
                        format!(
                            "{what}: row has {} fields, header has {}",
                            record.len(),
                            names.len()
                        ),
                    ));
                }
                let mut row = Vec::with_capacity(names.len());
                for (i, raw) in record.iter().enumerate() {
                    let cell = std::str::from_utf8(raw).unwrap_or("\u{fffd}").trim();
                    if cell.is_empty() && i > 0 {
                        // A missing sample as pandas and spreadsheets write it.
                        row.push(f64::NAN);
                        continue;
                    }
                    let value: f64 = cell.parse().map_err(|_| {
                        bad(
                            field_offset(i),
                            format!(
                                "column `{}`: `{}` is not a number",
                                names.get(i).map_or("?", String::as_str),
                                cell.chars().take(40).collect::<String>()
                            ),
                        )
                    })?;
                    row.push(value);
                }
                let t = row.first().copied().unwrap_or(f64::NAN);
                if !t.is_finite() {
                    return Err(bad(field_offset(0), "time `t` is not finite".into()));
                }
                if t <= last_t {
                    return Err(bad(
                        field_offset(0),
                        format!("time `t` = {t} does not increase (previous {last_t})"),
                    ));
                }
                last_t = t;
                series.rows.push(row);
            }
        }
    }
    let Some((names, header_offset)) = header else {
        return Err(bad(
            0,
            "empty file: expected a header row starting with `t`".into(),
        ));
    };
    let split = |role: &str| -> Vec<String> {
        names
            .iter()
            .filter_map(|h| h.strip_prefix(role).map(str::to_string))
            .collect()
    };
    let measurements = split("y:");
    if recording && measurements.is_empty() {
        return Err(bad(
            header_offset,
            "header has no measurement column `y:<name>`".into(),
        ));
    }
    let inputs = split("u:");
    let truth = split("x:");
    series.header = names;
    Ok(Recording {
        series,
        inputs,
        measurements,
        truth,
    })
}

fn parse_header(
    record: &csv::ByteRecord,
    field_offset: &dyn Fn(usize) -> usize,
    bad: &dyn Fn(usize, String) -> SimError,
    recording: bool,
) -> Result<Vec<String>, SimError> {
    let mut names: Vec<String> = Vec::with_capacity(record.len());
    for (i, raw) in record.iter().enumerate() {
        let name = std::str::from_utf8(raw)
            .map_err(|_| bad(field_offset(i), "header cell is not UTF-8".into()))?
            .trim()
            .to_string();
        // A spreadsheet's UTF-8 byte-order mark, and numpy's `savetxt(header=...)`, which
        // writes the header as a comment (`# t,...`), come before the first cell.
        let name = if i == 0 {
            let name = name.trim_start_matches('\u{feff}');
            name.strip_prefix('#').unwrap_or(name).trim().to_string()
        } else {
            name
        };
        if i == 0 {
            if name != "t" {
                return Err(bad(
                    field_offset(0),
                    format!("first header cell must be `t`, found `{name}`"),
                ));
            }
        } else {
            let valid = if recording {
                ["u:", "y:", "x:"]
                    .iter()
                    .any(|p| name.strip_prefix(p).is_some_and(|rest| !rest.is_empty()))
            } else {
                !name.is_empty() && name != "t"
            };
            if !valid {
                return Err(bad(
                    field_offset(i),
                    format!("header cell `{name}` must be `u:<name>`, `y:<name>` or `x:<name>`"),
                ));
            }
            if names.contains(&name) {
                return Err(bad(field_offset(i), format!("duplicate column `{name}`")));
            }
        }
        names.push(name);
    }
    Ok(names)
}

/// Byte offset of the start of field `index` of the record starting at byte `start`,
/// scanning the raw text with CSV quoting rules (so quoted commas do not count).
fn field_start(text: &str, start: usize, index: usize) -> usize {
    let bytes = text.as_bytes();
    let mut field = 0;
    let mut in_quotes = false;
    let mut i = start.min(bytes.len());
    while i < bytes.len() && field < index {
        match bytes.get(i) {
            Some(b'"') => in_quotes = !in_quotes,
            Some(b',') if !in_quotes => field += 1,
            Some(b'\n') if !in_quotes => break,
            _ => {}
        }
        i += 1;
    }
    i
}

/// Byte offset of the end of the line (before `\r\n` / `\n`) that starts at `start`.
fn record_end(text: &str, start: usize) -> usize {
    let rest = text.get(start..).unwrap_or("");
    let len = rest.find('\n').unwrap_or(rest.len());
    let line = rest.get(..len).unwrap_or("");
    start + line.strip_suffix('\r').unwrap_or(line).len()
}

/// The sidecar `<file>.meta.toml` of a recorded-data file.
#[derive(Clone, Debug, PartialEq)]
pub struct Meta {
    /// The plant (system) the data comes from, as named in the system registry.
    pub plant: String,
    /// The nominal sample time in seconds.
    pub dt: f64,
    /// Units per column name (e.g. `"y:pressure" = "Pa"`).
    pub units: BTreeMap<String, String>,
    /// Free text: where the data comes from.
    pub description: Option<String>,
}

/// Path of the sidecar of `data`: `<data>.meta.toml`.
pub fn meta_path(data: &Path) -> PathBuf {
    let mut name = data.as_os_str().to_owned();
    name.push(".meta.toml");
    PathBuf::from(name)
}

/// Reads the sidecar of `data` if it exists.
pub fn read_meta(data: &Path) -> Result<Option<Meta>, SimError> {
    let path = meta_path(data);
    if !path.exists() {
        return Ok(None);
    }
    let text = read_input(&path)?;
    parse_meta(&path, &text).map(Some)
}

/// Parses sidecar text; `path` is only used in error messages.
pub fn parse_meta(path: &Path, text: &str) -> Result<Meta, SimError> {
    #[derive(Deserialize)]
    #[serde(deny_unknown_fields)]
    struct RawMeta {
        plant: String,
        dt: toml::Spanned<f64>,
        #[serde(default)]
        units: BTreeMap<String, String>,
        #[serde(default)]
        description: Option<String>,
    }
    let raw: RawMeta = toml::from_str(text).map_err(|e| toml_error(path, text, &e))?;
    let dt = *raw.dt.get_ref();
    if !(dt.is_finite() && dt > 0.0) {
        return Err(SimError::at_offset(
            path,
            text,
            raw.dt.span().start,
            format!("`dt` must be a positive number, found {dt}"),
        ));
    }
    Ok(Meta {
        plant: raw.plant,
        dt,
        units: raw.units,
        description: raw.description,
    })
}

/// Converts a TOML error to [`SimError::BadInput`] at the error's span.
pub fn toml_error(path: &Path, text: &str, error: &toml::de::Error) -> SimError {
    let offset = error.span().map_or(0, |s| s.start);
    let (line, column) = line_column(text, offset);
    SimError::BadInput {
        path: path.to_path_buf(),
        line,
        column,
        message: error.message().trim().to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn p() -> &'static Path {
        Path::new("data.csv")
    }

    fn location(e: SimError) -> (usize, usize, String) {
        match e {
            SimError::BadInput {
                line,
                column,
                message,
                ..
            } => (line, column, message),
            other => panic!("expected BadInput, got {other}"),
        }
    }

    #[test]
    fn reads_valid_file() {
        let text = "t,u:cmd,y:p,x:leak\n0,1,2.5,0\n0.5,1,NaN,1e-3\n\n1.0,0,2.25,2e-3\n";
        let rec = parse_recording(p(), text).unwrap();
        assert_eq!(rec.inputs, vec!["cmd"]);
        assert_eq!(rec.measurements, vec!["p"]);
        assert_eq!(rec.truth, vec!["leak"]);
        assert_eq!(rec.series.rows.len(), 3);
        assert_eq!(rec.series.column("x:leak").unwrap(), vec![0.0, 1e-3, 2e-3]);
        assert!(rec.series.rows[1][2].is_nan());
    }

    #[test]
    fn a_header_written_as_a_comment_or_after_a_byte_order_mark_is_read() {
        // numpy.savetxt(..., header="t,u:cmd,y:p", delimiter=",") with its default comments.
        let rec = parse_recording(p(), "# t,u:cmd,y:p\n0,1,2.5\n0.5,1,2.0\n").unwrap();
        assert_eq!(rec.series.header, vec!["t", "u:cmd", "y:p"]);
        assert_eq!(rec.series.rows[1], vec![0.5, 1.0, 2.0]);
        let rec = parse_recording(p(), "\u{feff}t,y:p\n0,1\n").unwrap();
        assert_eq!(rec.series.header, vec!["t", "y:p"]);
        let (line, column, message) =
            location(parse_recording(p(), "# time,y:p\n0,1\n").unwrap_err());
        assert_eq!((line, column), (1, 1));
        assert!(message.contains("found `time`"), "{message}");
    }

    #[test]
    fn an_empty_field_is_a_missing_sample_except_in_t() {
        let text = "t,u:cmd,y:p\n0,1,2.5\n0.5,, \n1.0,0,2.25\n";
        let rec = parse_recording(p(), text).unwrap();
        assert!(rec.series.rows[1][1].is_nan() && rec.series.rows[1][2].is_nan());
        assert_eq!(rec.series.rows[2], vec![1.0, 0.0, 2.25]);
        let (line, column, message) =
            location(parse_recording(p(), "t,y:p\n0,1\n,2\n").unwrap_err());
        assert_eq!((line, column), (3, 1));
        assert!(message.contains("`t`"), "{message}");
    }

    #[test]
    fn bad_number_names_line_and_column() {
        let text = "t,u:cmd,y:p\n0,1,2\n1,1x,3\n";
        let (line, column, message) = location(parse_recording(p(), text).unwrap_err());
        assert_eq!((line, column), (3, 3));
        assert!(message.contains("u:cmd"), "{message}");
    }

    #[test]
    fn quoted_commas_do_not_shift_the_column() {
        let text = "t,y:p,u:a\n0,\"1,5\",2\n";
        let (line, column, _) = location(parse_recording(p(), text).unwrap_err());
        assert_eq!((line, column), (2, 3));
        let text = "t,y:p,u:a\n0,\"1\",zz\n";
        let (line, column, _) = location(parse_recording(p(), text).unwrap_err());
        assert_eq!((line, column), (2, 7));
    }

    #[test]
    fn field_count_and_header_errors() {
        let (l, c, m) = location(parse_recording(p(), "t,y:p\n0,1,9\n").unwrap_err());
        assert_eq!((l, c), (2, 5));
        assert!(m.contains("extra field"));
        let (l, c, m) = location(parse_recording(p(), "t,y:p,u:c\n0,1\r\n").unwrap_err());
        assert_eq!((l, c), (2, 4));
        assert!(m.contains("missing field"));
        let (l, c, _) = location(parse_recording(p(), "t,y:p,z:q\n").unwrap_err());
        assert_eq!((l, c), (1, 7));
        let (l, c, _) = location(parse_recording(p(), "time,y:p\n").unwrap_err());
        assert_eq!((l, c), (1, 1));
        let (l, c, _) = location(parse_recording(p(), "t,y:p,y:p\n").unwrap_err());
        assert_eq!((l, c), (1, 7));
        let (l, _, m) = location(parse_recording(p(), "t,u:a\n0,1\n").unwrap_err());
        assert_eq!(l, 1);
        assert!(m.contains("measurement"));
        let (l, c, m) = location(parse_recording(p(), "t,y:p\n0,1\n0,2\n").unwrap_err());
        assert_eq!((l, c), (3, 1));
        assert!(m.contains("does not increase"));
        let (l, c, _) = location(parse_recording(p(), "").unwrap_err());
        assert_eq!((l, c), (1, 1));
    }

    #[test]
    fn meta_sidecar() {
        let meta = parse_meta(
            Path::new("d.csv.meta.toml"),
            "plant = \"valve\"\ndt = 0.01\n[units]\n\"y:p\" = \"Pa\"\n",
        )
        .unwrap();
        assert_eq!(meta.plant, "valve");
        assert_eq!(meta.units.get("y:p").map(String::as_str), Some("Pa"));
        let (l, c, m) = location(
            parse_meta(Path::new("m"), "plant = \"valve\"\ndt = 0.01\ncolour = 3\n").unwrap_err(),
        );
        assert_eq!((l, c), (3, 1));
        assert!(m.contains("colour"), "{m}");
        let (l, c, _) =
            location(parse_meta(Path::new("m"), "plant = \"v\"\ndt = -1.0\n").unwrap_err());
        assert_eq!((l, c), (2, 6));
        assert_eq!(
            meta_path(Path::new("dir/run.csv")),
            PathBuf::from("dir/run.csv.meta.toml")
        );
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(512))]

        #[test]
        fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
            let text = String::from_utf8_lossy(&bytes);
            if let Err(e) = parse_recording(p(), &text) {
                let (line, column, _) = location(e);
                prop_assert!(line >= 1 && column >= 1);
                prop_assert!(line <= text.matches('\n').count() + 1);
            }
            let _ = parse_meta(p(), &text);
        }

        #[test]
        fn csv_like_text_never_panics(text in "[ty:ux,0-9.\"\\n\\r eNa-]{0,200}") {
            if let Err(e) = parse_recording(p(), &text) {
                let (line, column, _) = location(e);
                prop_assert!(line >= 1 && column >= 1);
            }
        }

        #[test]
        fn write_then_read_round_trips(
            rows in proptest::collection::vec(proptest::collection::vec(-1e12f64..1e12, 2), 1..30)
        ) {
            let mut series = TimeSeries::new(vec!["t".into(), "u:a".into(), "y:b".into()]);
            for (k, r) in rows.iter().enumerate() {
                series.rows.push(vec![k as f64 * 0.1, r[0], r[1]]);
            }
            let mut buf = Vec::new();
            series.write_csv(&mut buf).unwrap();
            let rec = parse_recording(p(), std::str::from_utf8(&buf).unwrap()).unwrap();
            prop_assert_eq!(rec.series, series);
        }

        #[test]
        fn corrupted_cell_is_located(
            rows in 1usize..8, cols in 1usize..5, bad_row in 0usize..8, bad_col in 0usize..5
        ) {
            let bad_row = bad_row % rows;
            let bad_col = bad_col % (cols + 1);
            let mut header = vec!["t".to_string()];
            header.extend((0..cols).map(|i| format!("y:c{i}")));
            let mut text = header.join(",") + "\n";
            let mut expected_column = 0;
            for r in 0..rows {
                let mut cells: Vec<String> = (0..=cols).map(|c| format!("{}.5", r * 10 + c)).collect();
                if r == bad_row {
                    expected_column = cells[..bad_col].iter().map(|c| c.len() + 1).sum::<usize>() + 1;
                    cells[bad_col] = "oops".into();
                }
                text += &(cells.join(",") + "\n");
            }
            let (line, column, _) = location(parse_recording(p(), &text).unwrap_err());
            prop_assert_eq!((line, column), (bad_row + 2, expected_column));
        }
    }
}
