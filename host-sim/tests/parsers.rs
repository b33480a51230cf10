//! Property tests of every host parser (issue 9): scenario TOML, recorded-data CSV, sidecar
//! meta TOML and PRONOSTIA bearing files, fed valid files with random edits (deleted,
//! inserted and replaced characters, truncation, swapped lines) and arbitrary text. A parser
//! never panics; it either accepts the text or returns a bad-input error naming the file and
//! a 1-based line and column that lie inside the text.

use prognos_sim::dataio::{parse_meta, parse_recording};
use prognos_sim::edge_cloud::EdgeCloudError;
use prognos_sim::edge_cloud::bearing::parse_bearing;
use prognos_sim::error::SimError;
use prognos_sim::scenario::Scenario;
use proptest::prelude::*;
use proptest::test_runner::RngSeed;
use std::path::{Path, PathBuf};

fn config(cases: u32, seed: u64) -> ProptestConfig {
    ProptestConfig {
        cases,
        rng_seed: RngSeed::Fixed(seed),
        failure_persistence: None,
        ..ProptestConfig::default()
    }
}

fn repo_file(relative: &str) -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(relative);
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

const RECORDING: &str =
    "t,u:load,y:damage,x:damage\n0,1,0.01,0.0\n1,1,0.02,0.011\n2,1.5,NaN,0.02\n3,1,0.05,0.04\n";
const META: &str = "plant = \"linear_degradation\"\ndt = 1.0\ndescription = \"test\"\n[units]\n\"y:damage\" = \"1\"\n";

/// A valid bearing file of three snapshots in the PRONOSTIA layout.
fn bearing_text() -> String {
    let mut header = vec!["idx".to_string(), "t_s".to_string()];
    header.extend((0..256).map(|i| format!("h{i}")));
    header.extend((0..256).map(|i| format!("v{i}")));
    let mut text = header.join(",");
    text.push('\n');
    for k in 0..3 {
        let mut row = vec![(k + 1).to_string(), format!("{}", 10 * (k + 1))];
        row.extend((0..512).map(|i| format!("{:.3}", ((i * 7 + k) as f64 * 0.1).sin())));
        text.push_str(&row.join(","));
        text.push('\n');
    }
    text
}

/// One edit of a text, at a position given as a fraction of its length.
#[derive(Clone, Debug)]
enum Edit {
    Delete(f64, usize),
    Insert(f64, String),
    Replace(f64, char),
    Truncate(f64),
    SwapLines(f64, f64),
}

fn edit() -> impl Strategy<Value = Edit> {
    let hostile = prop::sample::select(vec![
        ",", "\n", "\r\n", "\"", "=", "[", "]", "{", "}", "#", "NaN", "inf", "-1e400", "1e999",
        "é", "\u{feff}", "\0", "\t", "'''", "[[x]]", "= 1", "x:", "y:", "u:", ",,", "  ",
    ]);
    prop_oneof![
        (0.0..1.0f64, 1..8usize).prop_map(|(p, n)| Edit::Delete(p, n)),
        (0.0..1.0f64, hostile).prop_map(|(p, s)| Edit::Insert(p, s.to_string())),
        (0.0..1.0f64, "\\PC{1,6}").prop_map(|(p, s)| Edit::Insert(p, s)),
        (0.0..1.0f64, any::<char>()).prop_map(|(p, c)| Edit::Replace(p, c)),
        (0.0..1.0f64).prop_map(Edit::Truncate),
        (0.0..1.0f64, 0.0..1.0f64).prop_map(|(a, b)| Edit::SwapLines(a, b)),
    ]
}

fn char_index(text: &str, fraction: f64) -> usize {
    let n = text.chars().count();
    let k = ((n as f64) * fraction) as usize;
    text.char_indices().nth(k).map_or(text.len(), |(i, _)| i)
}

fn apply(text: &str, edits: &[Edit]) -> String {
    let mut t = text.to_string();
    for e in edits {
        match e {
            Edit::Delete(p, n) => {
                let start = char_index(&t, *p);
                let end = t[start..]
                    .char_indices()
                    .nth(*n)
                    .map_or(t.len(), |(i, _)| start + i);
                t.replace_range(start..end, "");
            }
            Edit::Insert(p, s) => {
                let at = char_index(&t, *p);
                t.insert_str(at, s);
            }
            Edit::Replace(p, c) => {
                let at = char_index(&t, *p);
                if let Some(old) = t[at..].chars().next() {
                    t.replace_range(at..at + old.len_utf8(), &c.to_string());
                }
            }
            Edit::Truncate(p) => {
                let at = char_index(&t, *p);
                t.truncate(at);
            }
            Edit::SwapLines(a, b) => {
                let mut lines: Vec<&str> = t.split('\n').collect();
                let n = lines.len();
                let (i, j) = (((n as f64) * a) as usize, ((n as f64) * b) as usize);
                if i < n && j < n {
                    lines.swap(i, j);
                }
                t = lines.join("\n");
            }
        }
    }
    t
}

/// The location must name the file and lie inside the text (the column may point one past
/// the end of its line, where a missing field should start).
fn check_location(
    path: &Path,
    text: &str,
    line: usize,
    column: usize,
    shown: &str,
) -> Result<(), TestCaseError> {
    let lines: Vec<&str> = text.split('\n').collect();
    prop_assert!(
        line >= 1 && line <= lines.len(),
        "line {line} of {}: {shown}",
        lines.len()
    );
    let width = lines[line - 1].chars().count();
    prop_assert!(
        column >= 1 && column <= width + 1,
        "column {column} of {width}: {shown}"
    );
    let prefix = format!("{}:{line}:{column}: ", path.display());
    prop_assert!(shown.starts_with(&prefix), "{shown}");
    Ok(())
}

fn check_sim(path: &Path, text: &str, result: Result<(), SimError>) -> Result<(), TestCaseError> {
    match result {
        Ok(()) => Ok(()),
        Err(e @ SimError::BadInput { .. }) => {
            let shown = e.to_string();
            let SimError::BadInput { line, column, .. } = e else {
                unreachable!()
            };
            check_location(path, text, line, column, &shown)
        }
        Err(e) => Err(TestCaseError::fail(format!("not a bad-input error: {e}"))),
    }
}

proptest! {
    #![proptest_config(config(256, 9101))]

    #[test]
    fn scenario_toml(edits in prop::collection::vec(edit(), 1..6)) {
        let path = PathBuf::from("scenarios/edited.toml");
        let text = apply(&repo_file("scenarios/linear_degradation.toml"), &edits);
        check_sim(&path, &text, Scenario::parse(&path, &text).map(|_| ()))?;
    }

    #[test]
    fn recording_csv(edits in prop::collection::vec(edit(), 1..6)) {
        let path = PathBuf::from("recorded.csv");
        let text = apply(RECORDING, &edits);
        check_sim(&path, &text, parse_recording(&path, &text).map(|_| ()))?;
    }

    #[test]
    fn meta_toml(edits in prop::collection::vec(edit(), 1..6)) {
        let path = PathBuf::from("recorded.csv.meta.toml");
        let text = apply(META, &edits);
        check_sim(&path, &text, parse_meta(&path, &text).map(|_| ()))?;
    }

    #[test]
    fn arbitrary_text_everywhere(text in "\\PC{0,200}") {
        let path = PathBuf::from("any.txt");
        check_sim(&path, &text, Scenario::parse(&path, &text).map(|_| ()))?;
        check_sim(&path, &text, parse_recording(&path, &text).map(|_| ()))?;
        check_sim(&path, &text, parse_meta(&path, &text).map(|_| ()))?;
        check_bearing(&path, &text)?;
    }
}

fn check_bearing(path: &Path, text: &str) -> Result<(), TestCaseError> {
    match parse_bearing(path, text) {
        Ok(_) => Ok(()),
        Err(e @ EdgeCloudError::Parse { .. }) => {
            let shown = e.to_string();
            let EdgeCloudError::Parse { line, column, .. } = e else {
                unreachable!()
            };
            check_location(path, text, line, column, &shown)
        }
        Err(e) => Err(TestCaseError::fail(format!("not a parse error: {e}"))),
    }
}

proptest! {
    #![proptest_config(config(96, 9102))]

    #[test]
    fn bearing_csv(edits in prop::collection::vec(edit(), 1..6)) {
        let path = PathBuf::from("Bearing9_9.csv");
        let text = apply(&bearing_text(), &edits);
        check_bearing(&path, &text)?;
    }
}

/// The unedited files parse, so the edited cases start from valid input.
#[test]
fn unedited_files_parse() {
    let p = PathBuf::from("x");
    Scenario::parse(&p, &repo_file("scenarios/linear_degradation.toml")).unwrap();
    parse_recording(&p, RECORDING).unwrap();
    parse_meta(&p, META).unwrap();
    assert_eq!(
        parse_bearing(&p, &bearing_text()).unwrap().snapshots.len(),
        3
    );
}
