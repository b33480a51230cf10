//! Issue 8: `prognos gap` end to end on generated data whose effect it is not told about,
//! its bad-input errors (exit status 2, file:line:column), and a small bounded gap-bench.

use prognos_sim::gap::bench::{
    BenchOptions, CaseKind, Dataset, Excitation, NoiseShape, Outcome, generate, run_bench, run_one,
    score,
};
use prognos_sim::gap::plant::InputTiming;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// A fresh folder under the system's temporary folder, removed when dropped.
struct Scratch(PathBuf);

impl std::ops::Deref for Scratch {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.0
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn scratch(name: &str) -> Scratch {
    let dir = std::env::temp_dir().join(format!("prognos-gap-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    Scratch(dir)
}

fn prognos(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_prognos"))
        .args(args)
        .output()
        .unwrap()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Generated sets of one plant, one seed per cell: the single-effect sets of `only` (every
/// catalogue effect when empty) at `ratios`, and `extra_sets` of each other kind.
fn generated(
    plant: &str,
    only: &[&str],
    ratios: &[f64],
    seed: u64,
    extra_sets: usize,
) -> Vec<Dataset> {
    let opts = BenchOptions {
        plants: vec![plant.into()],
        seeds: 1,
        ratios: ratios.to_vec(),
        seed,
        only: only.iter().map(|e| e.to_string()).collect(),
        extra_sets,
        ..BenchOptions::default()
    };
    generate(plant, &opts).unwrap()
}

/// The pair set among `generated(plant, &[only], &[ratio], seed, 1)`.
fn first_pair(plant: &str, only: &str, ratio: f64, seed: u64) -> Dataset {
    generated(plant, &[only], &[ratio], seed, 1)
        .into_iter()
        .find(|d| d.label.kind == CaseKind::Pair)
        .unwrap()
}

/// The set called `name` among `sets`.
fn named(sets: Vec<Dataset>, name: &str) -> Dataset {
    sets.into_iter().find(|d| d.name == name).unwrap()
}

fn one(plant: &str, effect: &str, ratio: f64) -> Dataset {
    generated(plant, &[effect], &[ratio], 7, 0).remove(0)
}

fn write(dir: &Path, d: &Dataset) -> PathBuf {
    let csv = dir.join("data.csv");
    std::fs::write(&csv, &d.csv).unwrap();
    std::fs::write(dir.join("data.csv.meta.toml"), &d.meta).unwrap();
    csv
}

/// Writes `d` into `dir`, runs `prognos gap` on it into `dir/out`, and parses the verdict.
fn diagnose(dir: &Path, d: &Dataset) -> (PathBuf, serde_json::Value) {
    let csv = write(dir, d);
    let out = dir.join("out");
    let o = prognos(&["gap", "--data", s(&csv), "--out", s(&out)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let verdict =
        serde_json::from_str(&std::fs::read_to_string(out.join("verdict.json")).unwrap()).unwrap();
    (out, verdict)
}

/// Runs `prognos gap` on `data` with the meta file `meta` into `out` and parses the verdict.
fn gap_with_meta(data: &Path, meta: &Path, out: &Path) -> serde_json::Value {
    let o = prognos(&["gap", "--data", s(data), "--meta", s(meta), "--out", s(out)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_str(&std::fs::read_to_string(out.join("verdict.json")).unwrap()).unwrap()
}

/// Diagnoses `d` and checks that the verdict is `verdict` (a pair in either order) and that
/// it shrinks the held-out gap by more than `min_shrink`.
fn assert_found(d: &Dataset, verdict: &str, min_shrink: f64) -> Outcome {
    let o = run_one(d).unwrap();
    let sorted = |v: &str| {
        let mut parts: Vec<String> = v.split('+').map(str::to_string).collect();
        parts.sort();
        parts
    };
    assert_eq!(
        sorted(&o.verdict),
        sorted(verdict),
        "verdict {}, top 3: {:?}",
        o.verdict,
        o.top3
    );
    assert!(o.shrink > min_shrink, "shrink {}", o.shrink);
    o
}

#[test]
fn gap_finds_lubricant_torque_noise_in_wheel_data_and_writes_the_report() {
    let dir = scratch("wheel");
    let d = one("reaction_wheel", "lubricant_torque_noise", 4.0);
    assert_eq!(d.label.channel.as_deref(), Some("y:speed"));
    let (out, verdict) = diagnose(&dir, &d);
    assert_eq!(verdict["plant"], "reaction_wheel");
    assert_eq!(verdict["verdict"], "lubricant_torque_noise");
    assert_eq!(verdict["where"]["channel"], "y:speed");
    assert_eq!(verdict["where"]["significant"], true);
    let top = &verdict["ranking"][0];
    assert_eq!(top["effect"], "lubricant_torque_noise");
    let shrink = top["shrink"].as_f64().unwrap();
    assert!(shrink > 0.8, "held-out shrink {shrink}");
    // Amplitude and phase fitted; the phase inside its range.
    assert_eq!(top["params"].as_array().unwrap().len(), 2);
    let phase = top["params"][1][1].as_f64().unwrap();
    assert!((0.0..=std::f64::consts::TAU).contains(&phase), "{phase}");
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(
        html.matches("<svg").count() >= 4,
        "heat map, spectrum, ranking, overlay"
    );
    assert!(html.contains("lubricant_torque_noise"));
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(md.contains("| 1 | lubricant_torque_noise |"), "{md}");
}

#[test]
fn gap_says_none_on_nominal_motor_data() {
    // `only` naming no effect leaves only the extra sets.
    let sets = generated("dc_motor", &["no-such-effect"], &[], 7, 1);
    let none = sets
        .iter()
        .find(|x| x.label.kind == CaseKind::None)
        .unwrap();
    let o = run_one(none).unwrap();
    assert_eq!(o.verdict, "none", "top 3: {:?}", o.top3);
}

#[test]
fn every_estimators_innovations_pass_on_nominal_data_and_the_motors_fail_with_friction() {
    // The plant's estimator runs with the user's model on every record: on nominal data
    // its innovations pass their tests (the wheel's and the scooter's failed two-sided
    // Ljung-Box on every nominal record, their process noise over-correcting), with an
    // unmodelled Coulomb friction the motor's do not.
    let estimator_rejects = |d: &Dataset, name: &str| {
        let dir = scratch(name);
        let (out, v) = diagnose(&dir, d);
        let tests = v["estimator"]["tests"].as_array().unwrap();
        assert!(
            tests.iter().any(|t| t["test"] == "persistence"),
            "{tests:?}"
        );
        let report = std::fs::read_to_string(out.join("report.md")).unwrap();
        assert!(report.contains("The plant's estimator with the user's model"));
        tests
            .iter()
            .filter(|t| t["p_adjusted"].as_f64().unwrap() < 0.01)
            .map(|t| format!("{} {} {}", t["test"], t["channel"], t["scope"]))
            .collect::<Vec<_>>()
    };
    for plant in ["dc_motor", "reaction_wheel", "scooter", "valve"] {
        let sets = generated(plant, &["no-such-effect"], &[], 7, 1);
        let none = sets
            .iter()
            .find(|x| x.label.kind == CaseKind::None)
            .unwrap();
        let rejected = estimator_rejects(none, &format!("estimator-none-{plant}"));
        assert!(rejected.is_empty(), "{plant}: {rejected:?}");
    }
    let friction = one("dc_motor", "coulomb_friction", 4.0);
    assert!(!estimator_rejects(&friction, "estimator-friction").is_empty());
}

#[test]
fn gap_finds_the_scooter_encoder_efficiency_under_its_own_name() {
    // The rear encoder's efficiency is a sensor scale of y:rear_speed; the scooter names it,
    // so the generic candidate stands aside and the verdict is the plant's effect.
    let d = one("scooter", "encoder_efficiency", 4.0);
    assert_eq!(d.label.channel.as_deref(), Some("y:rear_speed"));
    let o = run_one(&d).unwrap();
    assert_eq!(o.verdict, "encoder_efficiency", "top 3: {:?}", o.top3);
    assert_eq!(o.channel, "y:rear_speed");
    assert!(o.shrink > 0.8, "shrink {}", o.shrink);
    assert!(!o.top3.iter().any(|e| e == "sensor_scale:rear_speed"));
}

#[test]
fn scooter_noise_is_estimated_from_the_residual_and_the_shrink_is_measured() {
    // The scooter's front wheel oscillates near 6 Hz: second differences of the raw signal
    // over-estimate the sensor noise (1e-3 rad/s, 1e-4 m/s) several times, which hid every
    // gap below the noise (shrink 0). The model's residual gives the sensors' own level.
    let dir = scratch("scooter-noise");
    let d = one("scooter", "rear_coulomb_friction", 2.0);
    let (_, verdict) = diagnose(&dir, &d);
    let truth = [1e-3, 1e-4, 1e-3];
    for (level, want) in verdict["noise"].as_array().unwrap().iter().zip(truth) {
        let got = level["std"].as_f64().unwrap();
        assert!((got / want - 1.0).abs() < 0.15, "{level} vs {want}");
        assert_eq!(level["source"], "residual differences");
    }
    assert_eq!(verdict["verdict"], "rear_coulomb_friction");
    let top = &verdict["ranking"][0];
    assert!(top["gap_before"].as_f64().unwrap() > 1.0, "{top:#}");
    assert!(top["shrink"].as_f64().unwrap() > 0.8, "{top:#}");
}

#[test]
fn gap_finds_a_coarse_quantiser_by_likelihood_on_motor_data() {
    // Steps of about seven noise std: the noise estimated from the data absorbs the
    // quantiser's variance, so only the quantised likelihood shows it.
    let d = one("dc_motor", "quantisation", 2.0);
    let o = run_one(&d).unwrap();
    assert_eq!(o.verdict, d.label.effects[0], "top 3: {:?}", o.top3);
    assert_eq!(Some(o.channel.as_str()), d.label.channel.as_deref());
}

fn bad(dir: &Path, csv_text: &str, meta_text: Option<&str>) -> (i32, String) {
    let csv = dir.join("data.csv");
    std::fs::write(&csv, csv_text).unwrap();
    let meta = dir.join("data.csv.meta.toml");
    let _ = std::fs::remove_file(&meta);
    if let Some(m) = meta_text {
        std::fs::write(&meta, m).unwrap();
    }
    let o = prognos(&["gap", "--data", s(&csv), "--out", s(&dir.join("out"))]);
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

#[test]
fn bad_input_exits_2_and_says_which_and_where() {
    let dir = scratch("bad");
    let good = one("dc_motor", "coulomb_friction", 4.0);
    let meta_path = dir.join("data.csv.meta.toml");
    let m = s(&meta_path).to_string();
    let c = s(&dir.join("data.csv")).to_string();

    let (code, err) = bad(&dir, &good.csv, None);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("missing meta file") && err.contains(&m),
        "{err}"
    );

    let (code, err) = bad(&dir, &good.csv, Some("plant = \"toaster\"\ndt = 0.01\n"));
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains(&format!("{m}:1:9: unknown plant `toaster`")),
        "{err}"
    );

    let text = "plant = \"dc_motor\"\ndt = 0.01\n[model]\nresistance = 2.0\nresistanse = 2.1\n";
    let (code, err) = bad(&dir, &good.csv, Some(text));
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains(&format!("{m}:5:1: unknown parameter `resistanse`")),
        "{err}"
    );

    let text = "plant = \"dc_motor\"\ndt = 0.01\nsim_effects = [\"brush_drop\", \"warp_drive\"]\n";
    let (code, err) = bad(&dir, &good.csv, Some(text));
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains(&format!("{m}:3:30: unknown effect `warp_drive`")),
        "{err}"
    );
    let text = "plant = \"dc_motor\"\ndt = 0.01\nsim_effects = [\"sensor_bias:speed\"]\n";
    let (code, err) = bad(&dir, &good.csv, Some(text));
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains(&format!(
            "{m}:3:16: generic sensor effect (a model does not include it: correct the \
             readings) `sensor_bias:speed`"
        )),
        "{err}"
    );

    let text = "plant = \"dc_motor\"\ndt = 0.01\n[units]\n\"y:torque\" = \"N m\"\n";
    let (code, err) = bad(&dir, &good.csv, Some(text));
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains(&format!(
            "{m}:4:1: channel `y:torque` named in the meta file is not a column of {c}"
        )),
        "{err}"
    );

    let no_voltage = good.csv.replacen("u:voltage", "u:volts", 1);
    let (code, err) = bad(&dir, &no_voltage, Some(&good.meta));
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains(&format!(
            "{c}:1:1: plant `dc_motor` needs the input column `u:voltage`"
        )),
        "{err}"
    );

    let short: String = good
        .csv
        .lines()
        .take(51)
        .map(|l| format!("{l}\n"))
        .collect();
    let (code, err) = bad(&dir, &short, Some(&good.meta));
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains(&format!("{c}:51:1: too little data to split: 50 samples")),
        "{err}"
    );
}

#[test]
fn gap_reads_a_stem_named_meta_file_and_warns_about_what_it_ignores() {
    // Independently prepared data: `data.meta.toml` (not `data.csv.meta.toml`) without
    // `dt`, a preparer's own key, and a column the plant does not read. The diagnosis runs;
    // each ignored thing is a warning at its line and column, on stderr and in the verdict.
    let dir = scratch("stem-meta");
    let d = one("dc_motor", "coulomb_friction", 4.0);
    let csv: String = d
        .csv
        .lines()
        .enumerate()
        .map(|(i, l)| format!("{l},{}\n", if i == 0 { "u:spare" } else { "1" }))
        .collect();
    let data = dir.join("data.csv");
    std::fs::write(&data, csv).unwrap();
    let meta: String = d
        .meta
        .lines()
        .filter(|l| !l.starts_with("dt ="))
        .map(|l| format!("{l}\n"))
        .collect();
    std::fs::write(dir.join("data.meta.toml"), format!("seed = 17\n{meta}")).unwrap();
    let out = dir.join("out");
    let o = prognos(&["gap", "--data", s(&data), "--out", s(&out)]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    let m = s(&dir.join("data.meta.toml")).to_string();
    assert!(
        err.contains(&format!("warning: {m}:1:1: ignored unknown key `seed`")),
        "{err}"
    );
    let column = d.csv.lines().next().unwrap().len() + 2;
    assert!(
        err.contains(&format!(
            "warning: {}:1:{column}: ignored column `u:spare`",
            s(&data)
        )),
        "{err}"
    );
    let verdict: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("verdict.json")).unwrap()).unwrap();
    assert_eq!(verdict["verdict"], "coulomb_friction");
    assert_eq!(verdict["warnings"].as_array().unwrap().len(), 2);
}

#[test]
fn gap_bench_on_a_folder_goes_past_unlabelled_and_bad_datasets() {
    // A folder prepared by someone else: a subfolder, stem-named sidecars, a label naming a
    // sensor effect without its channel and no ratio, a set without a label, one without a
    // meta file and one too short to split. Every set is reported; none stops the bench.
    let dir = scratch("bench-folder");
    std::fs::create_dir_all(dir.join("sub")).unwrap();
    let scale = one("dc_motor", "sensor_scale", 4.0);
    let channel = scale.label.channel.clone().unwrap();
    std::fs::write(dir.join("sub/scale.csv"), &scale.csv).unwrap();
    std::fs::write(dir.join("sub/scale.meta.toml"), &scale.meta).unwrap();
    std::fs::write(
        dir.join("sub/scale.label.toml"),
        format!("kind = \"single\"\neffects = [\"Sensor-Scale\"]\nchannel = \"{channel}\"\n"),
    )
    .unwrap();
    let none = generated("dc_motor", &["brush_drop"], &[4.0], 7, 1)
        .into_iter()
        .find(|d| d.label.kind == CaseKind::None)
        .unwrap();
    std::fs::write(dir.join("unlabelled.csv"), &none.csv).unwrap();
    std::fs::write(dir.join("unlabelled.csv.meta.toml"), &none.meta).unwrap();
    std::fs::write(dir.join("no-meta.csv"), &none.csv).unwrap();
    std::fs::write(dir.join("no-meta.csv.label.toml"), "kind = \"none\"\n").unwrap();
    let short: String = none
        .csv
        .lines()
        .take(100)
        .map(|l| format!("{l}\n"))
        .collect();
    std::fs::write(dir.join("short.csv"), short).unwrap();
    std::fs::write(dir.join("short.csv.meta.toml"), &none.meta).unwrap();
    std::fs::write(dir.join("short.csv.label.toml"), "kind = \"none\"\n").unwrap();

    let (outcomes, text) =
        run_bench(&BenchOptions::default(), Some(&dir), None, Some(&dir)).unwrap();
    let by_name = |n: &str| outcomes.iter().find(|o| o.name == n).unwrap();
    assert_eq!(outcomes.len(), 4, "{text}");
    let scale_outcome = by_name("sub/scale");
    let expected = format!("sensor_scale:{}", channel.trim_start_matches("y:"));
    assert_eq!(scale_outcome.label.effects, std::slice::from_ref(&expected));
    assert_eq!(scale_outcome.verdict, expected, "{text}");
    assert_eq!(by_name("unlabelled").label.kind, CaseKind::Unlabelled);
    assert_eq!(by_name("unlabelled").verdict, "none", "{text}");
    let no_meta = by_name("no-meta");
    assert_eq!(no_meta.verdict, "error");
    assert!(
        no_meta
            .error
            .as_deref()
            .unwrap()
            .contains("missing meta file"),
        "{text}"
    );
    assert!(
        by_name("short")
            .error
            .as_deref()
            .unwrap()
            .contains("short.csv:100:1: too little data to split: 99 samples"),
        "{text}"
    );
    // Both unreadable sets are `none` misses; the unlabelled one is not scored.
    let sc = score(&outcomes, |_| true);
    assert_eq!((sc.nones, sc.false_attribution), (2, 1.0));
    assert!(
        text.contains("(1 without a label, 2 not diagnosed; inputs read as 2 before)"),
        "{text}"
    );
    assert!(
        text.contains("Every labelled dataset (the labels give no"),
        "{text}"
    );
    assert!(dir.join("bench.json").exists());
}

/// `csv` without its column `name`.
fn without_column(csv: &str, name: &str) -> String {
    let header = csv.lines().next().unwrap();
    let column = header.split(',').position(|c| c == name).unwrap();
    csv.lines()
        .map(|l| {
            let cells: Vec<&str> = l
                .split(',')
                .enumerate()
                .filter(|(i, _)| *i != column)
                .map(|(_, c)| c)
                .collect();
            format!("{}\n", cells.join(","))
        })
        .collect()
}

#[test]
fn a_ripple_is_found_without_the_measured_angle() {
    // Without `u:angle` the ripple, 8.6 kHz at 500 rad/s against 20 Hz samples, has no
    // phase to replay: it is a speed spread growing with current over speed, and each
    // command step kicks the mean speed by the swing's change at an unknown angle, a
    // random offset tracked on the measured speed. Before the kicks were tracked both
    // sets were `unknown` (B = 25.8 and 145.1; now fitted 26.9 and 145.3).
    for d in generated("reaction_wheel", &["torque_ripple"], &[2.0, 8.0], 7, 0) {
        let truth = d.label.truth["torque_ripple"];
        let csv = without_column(&d.csv, "u:angle");
        let d = Dataset { csv, ..d };
        let dir = scratch(&format!("ripple-no-angle-{}", d.name));
        let (_, verdict) = diagnose(&dir, &d);
        assert_eq!(verdict["verdict"], "torque_ripple", "{}", d.name);
        assert_eq!(verdict["where"]["channel"], "y:speed", "{}", d.name);
        let fitted = verdict["ranking"][0]["params"][0][1].as_f64().unwrap();
        assert!(
            (fitted / truth - 1.0).abs() < 0.1,
            "{}: fitted {fitted}, truth {truth}",
            d.name
        );
    }
}

#[test]
fn a_small_ripple_felt_through_zero_speed_is_fitted_without_the_measured_angle() {
    // B = 0.105 at ratio 4: far above the sample rate it is nothing, but through zero
    // speed the torque no longer averages out and leaves a lasting kick (a Fresnel
    // integral of unknown phase). Without that kick the best ripple fit was B = 7.0, 67
    // times the truth, and the verdict `cogging`; cogging, kicked the same way at a
    // crossing, stays close behind.
    let d = generated(
        "reaction_wheel",
        &["torque_ripple"],
        &[2.0, 4.0, 8.0],
        2026,
        0,
    )
    .into_iter()
    .find(|d| d.name.contains("-r4-"))
    .unwrap();
    let truth = d.label.truth["torque_ripple"];
    assert!(truth < 0.2, "{truth}");
    let d = Dataset {
        csv: without_column(&d.csv, "u:angle"),
        ..d
    };
    let dir = scratch("small-ripple-no-angle");
    let (_, verdict) = diagnose(&dir, &d);
    let ranking = verdict["ranking"].as_array().unwrap();
    let ripple = ranking[..2]
        .iter()
        .find(|e| e["effect"] == "torque_ripple")
        .unwrap_or_else(|| panic!("not in the top 2: {ranking:?}"));
    let fitted = ripple["params"][0][1].as_f64().unwrap();
    assert!(
        (fitted / truth - 1.0).abs() < 0.2,
        "fitted {fitted}, truth {truth}"
    );
    assert!(ripple["worst_block_p"].as_f64().unwrap() > 0.01);
    let v = verdict["verdict"].as_str().unwrap();
    assert!(v == "torque_ripple" || v == "cogging", "{v}");
}

#[test]
fn a_drifting_speed_sensor_is_unknown_not_a_bias() {
    // A linear drift of the speed reading (outside the catalogue), RMS 4 times the noise,
    // on the seed-77 bench's `none` wheel, with and without `u:angle`. A speed bias removed 80.5 % of it held out but
    // left a block at p 2e-24; it was the verdict, a single that removed over 80 % being
    // exempt from the block test.
    let d = generated("reaction_wheel", &["coulomb_friction"], &[4.0], 77, 1)
        .into_iter()
        .find(|d| d.label.kind == CaseKind::None)
        .unwrap();
    let mut lines = d.csv.lines();
    let header = lines.next().unwrap();
    let cols: Vec<&str> = header.split(',').collect();
    let speed = cols.iter().position(|c| *c == "y:speed").unwrap();
    let rows: Vec<Vec<f64>> = lines
        .map(|l| l.split(',').map(|c| c.parse().unwrap()).collect())
        .collect();
    let y: Vec<f64> = rows.iter().map(|r| r[speed]).collect();
    let mut d2: Vec<f64> = y
        .windows(3)
        .map(|w| (w[2] - 2.0 * w[1] + w[0]).abs())
        .collect();
    d2.sort_by(f64::total_cmp);
    let noise = d2[d2.len() / 2] / 0.6745 / 6f64.sqrt();
    let (t0, t1) = (rows[0][0], rows[rows.len() - 1][0]);
    let amplitude = 4.0 * noise * 12f64.sqrt();
    let csv: String = std::iter::once(format!("{header}\n"))
        .chain(rows.iter().map(|r| {
            let mut r = r.clone();
            r[speed] += amplitude * ((r[0] - t0) / (t1 - t0) - 0.5);
            let cells: Vec<String> = r.iter().map(|v| v.to_string()).collect();
            format!("{}\n", cells.join(","))
        }))
        .collect();
    let no_angle = without_column(&csv, "u:angle");
    let o = run_one(&Dataset { csv, ..d.clone() }).unwrap();
    assert_eq!(o.verdict, "unknown", "top 3: {:?}", o.top3);
    // Without the angle a ripple's kicks, tracked on the measured speed, follow the drift
    // at each command step; between steps they lag it, which the window means show.
    let o = run_one(&Dataset { csv: no_angle, ..d }).unwrap();
    assert_eq!(o.verdict, "unknown", "without u:angle, top 3: {:?}", o.top3);
}

#[test]
fn small_gap_bench_attributes_localises_and_rejects() {
    // Bounded: DC motor, two catalogue effects and two sensor effects at ratio 4, one seed,
    // plus one no-effect set, one pair and one set per out-of-catalogue effect.
    let sets = generated(
        "dc_motor",
        &[
            "coulomb_friction",
            "brush_drop",
            "sensor_scale",
            "measurement_delay",
        ],
        &[4.0],
        11,
        1,
    );
    assert_eq!(
        sets.iter()
            .filter(|d| d.label.kind == CaseKind::Single)
            .count(),
        4
    );
    let outcomes: Vec<_> = sets.iter().map(|d| run_one(d).unwrap()).collect();
    let sc = score(&outcomes, |r| r >= 2.0);
    assert_eq!(sc.top1, 1.0, "{outcomes:#?}");
    assert_eq!(sc.localisation, 1.0, "{outcomes:#?}");
    assert!(sc.median_shrink > 0.8, "{}", sc.median_shrink);
    assert_eq!(sc.false_attribution, 0.0, "{outcomes:#?}");
}

#[test]
fn gap_finds_choked_flow_when_the_model_never_chokes() {
    // The bench's valve model lacks choking (`critical_pressure_ratio = 0` in every valve
    // meta file); this truth's orifices choke below a critical ratio set for ratio 4.
    let d = one("valve", "choked_flow", 4.0);
    assert!(
        d.meta.contains("critical_pressure_ratio = 0.0"),
        "{}",
        d.meta
    );
    let o = run_one(&d).unwrap();
    assert_eq!(o.verdict, "choked_flow", "top 3: {:?}", o.top3);
    assert_eq!(Some(o.channel.as_str()), d.label.channel.as_deref());
    assert!(o.shrink > 0.8, "shrink {}", o.shrink);
}

#[test]
fn gap_recovers_the_isentropic_critical_ratio_from_progpy_data() {
    // progpy's valve chokes as an isentropic nozzle. Told that its orifices never choke,
    // our model is off; `choked_flow` explains it with b = (2 / 2.4)^3.5 = 0.528. Told
    // nothing, the model chokes already and `choked_flow` is no candidate.
    let data = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../data/progpy-valve/nominal_leak_free_dt0.01.csv");
    let dir = scratch("choked");
    let told = |name: &str, model: &str| {
        let meta = dir.join(format!("{name}.meta.toml"));
        std::fs::write(
            &meta,
            format!(
                "plant = \"valve\"\ndt = 0.01\n[model]\nprogpy_euler = 1\n{model}[noise]\n\
                 \"y:x\" = 1.0e-4\n\"y:pt\" = 5.0e3\n\"y:pb\" = 5.0e3\n\"y:q\" = 5.0e-3\n"
            ),
        )
        .unwrap();
        gap_with_meta(&data, &meta, &dir.join(name))
    };
    let v = told("unchoked", "critical_pressure_ratio = 0\n");
    assert_eq!(v["verdict"], "choked_flow", "{:#}", v["ranking"][0]);
    let top = &v["ranking"][0];
    assert_eq!(top["params"][0][0], "critical_pressure_ratio");
    let b = top["params"][0][1].as_f64().unwrap();
    assert!((b / 0.528_281_8 - 1.0).abs() < 0.02, "b = {b}");
    assert!(top["shrink"].as_f64().unwrap() > 0.9, "{top:#}");
    // Located in the declared noise units (the noise-free trace's residual is no noise
    // level: in its units the closely fitted y:x came out first).
    assert_eq!(v["where"]["channel"], "y:pb");
    let v = told("default", "");
    assert_eq!(v["verdict"], "none");
    assert!(
        v["ranking"]
            .as_array()
            .unwrap()
            .iter()
            .all(|e| e["effect"] != "choked_flow")
    );
    assert!(
        v["sim_effects"]
            .as_array()
            .unwrap()
            .iter()
            .any(|e| e == "choked_flow")
    );
}

#[test]
fn gap_says_unknown_for_an_inlet_sensor_offset_a_stiffer_spring_would_fit() {
    // A weakening spring only weakens: the pair spring_weakening (k above the model's)
    // + sensor_scale:q that explained this set is no physical explanation.
    let sets = generated("valve", &["spring_weakening"], &[4.0], 7, 1);
    let d = sets
        .iter()
        .find(|d| {
            d.label
                .effects
                .iter()
                .any(|e| e == "inlet_pressure_sensor_offset")
        })
        .unwrap();
    let o = run_one(d).unwrap();
    assert_eq!(o.verdict, "unknown", "top 3: {:?}", o.top3);
    // The catalogue's own spring_weakening set is still found.
    let w = sets
        .iter()
        .find(|d| d.label.kind == CaseKind::Single)
        .unwrap();
    assert_eq!(run_one(w).unwrap().verdict, "spring_weakening");
}

#[test]
fn gap_finds_a_leak_and_seal_pair_whose_parameters_trade_off() {
    // Leak area and seal stiffness trade off along a valley that one coordinate pass
    // crawls along (shrink 0.66, verdict `unknown`); the joint polish reaches the pair.
    let d = &first_pair("valve", "friction_increase", 4.0, 7);
    assert_eq!(d.label.effects, ["top_external_leak", "seal_contact"]);
    assert_found(d, "top_external_leak+seal_contact", 0.8);
}

#[test]
fn gap_finds_a_pair_whose_best_single_mimic_is_neither_member() {
    // On a one-signed wheel speed a speed bias mimics Coulomb friction and outscores both
    // true effects alone; the pairs were formed only with the best single (the bias), so
    // viscous_temperature + coulomb_friction was never fitted and the verdict was `unknown`.
    let d = &first_pair("reaction_wheel", "coulomb_friction", 2.0, 21);
    assert_eq!(d.label.effects, ["viscous_temperature", "coulomb_friction"]);
    let o = assert_found(d, "viscous_temperature+coulomb_friction", 0.9);
    assert_eq!(
        o.top3[0], "sensor_bias:speed",
        "the mimic leads the singles"
    );
}

#[test]
fn gap_finds_a_pair_of_two_singles_ranked_below_sensor_mimics() {
    // Friction and a weaker spring at ratio 8 each: alone neither shrinks the gap by more
    // than 0.06, and four sensor delays and lags on y:x and y:q outscore both, so they were
    // the 5th and 6th singles and never fitted together (verdict `unknown`).
    let d = &named(
        generated("valve", &["friction_increase"], &[2.0], 21, 3),
        "valve-pair-friction_increase+spring_weakening-r8-s2",
    );
    assert_found(d, "friction_increase+spring_weakening", 0.9);
}

#[test]
fn gap_refines_enough_pairs_to_reach_one_the_coarse_pass_ranks_low() {
    // Rear Coulomb friction and a rear encoder reading 0.1 % low: one coarse pass from the
    // singles' fits ranked the pair below four rear_coulomb + sensor pairs, so it was not
    // among the pairs refined, and the verdict was `unknown`.
    let sets = generated("scooter", &["no-such-effect"], &[2.0], 99, 3);
    let d = sets
        .iter()
        .find(|d| d.label.kind == CaseKind::Pair && d.label.ratio == 8.0)
        .unwrap();
    assert_eq!(
        d.label.effects,
        ["encoder_efficiency", "rear_coulomb_friction"]
    );
    assert_found(d, "encoder_efficiency+rear_coulomb_friction", 0.9);
}

#[test]
fn gap_pairs_singles_that_fit_the_training_blocks_but_lose_alone() {
    // A driver lag and a temperature-dependent viscosity at ratio 2: each alone fits the
    // training blocks best of all singles but bends to the other's missing part and loses
    // 300-540 nats held out (ranks 16 and 19), so no pair held both (verdict `unknown`).
    let d = &first_pair("reaction_wheel", "no-such-effect", 2.0, 77);
    assert_eq!(d.label.effects, ["viscous_temperature", "driver_lowpass"]);
    let o = run_one(d).unwrap();
    // The lag is confusable with a speed-sensor lag or delay (docs/gap.md).
    let lag = [
        "driver_lowpass",
        "measurement_delay:speed",
        "first_order_lag:speed",
    ];
    assert!(
        lag.iter()
            .any(|l| o.verdict == format!("{l}+viscous_temperature")),
        "{o:#?}"
    );
    assert!(o.shrink > 0.8, "{o:#?}");
}

#[test]
fn a_pair_whose_regime_only_the_first_fold_holds_out_is_taken_from_the_second() {
    // Cogging and a temperature-dependent viscosity at ratio 8 on a wheel slowing through
    // zero speed: the zero crossing, where cogging is felt most, lies in held-out block 9.
    // Fitted on the even blocks the pair shrinks the gap by 0.943 but block 9 keeps
    // p 1e-226 (verdict `unknown`); fitted on the odd blocks the same pair passes.
    let d = &named(
        generated("reaction_wheel", &["no-such-effect"], &[2.0], 77, 12),
        "reaction_wheel-pair-viscous_temperature+cogging-r8-s11",
    );
    let o = assert_found(d, "cogging+viscous_temperature", 0.9);
    assert_eq!(o.channel, "y:speed");
}

#[test]
fn a_single_that_mimics_a_load_step_on_average_is_not_the_verdict() {
    // A load torque stepping in midway (outside the catalogue) on smooth wheel inputs:
    // viscous_temperature's slow change shrank the held-out gap by 0.72 on average and was
    // the verdict, though one held-out block kept a residual far above the noise.
    let opts = BenchOptions {
        plants: vec!["reaction_wheel".into()],
        seeds: 1,
        ratios: vec![2.0],
        seed: 23,
        only: vec!["coulomb_friction".into()],
        extra_sets: 1,
        excitation: Excitation::Smooth,
        ..BenchOptions::default()
    };
    let sets = generate("reaction_wheel", &opts).unwrap();
    let d = sets
        .iter()
        .find(|d| d.name == "reaction_wheel-unknown-load_torque_step_midway-r2-s0")
        .unwrap();
    let o = run_one(d).unwrap();
    assert_eq!(o.verdict, "unknown", "top 3: {:?}", o.top3);
}

#[test]
fn gap_finds_torque_ripple_while_the_model_speed_is_off() {
    // The set of the session-9 wm1 bench: the ripple's phase came from the replayed speed,
    // so its fit shrank the gap by 0.64 only and the verdict was `unknown`. Since the truth
    // integrates the ripple torque at both ends of a step, this ripple shows mostly near
    // the zero crossings, which fall in training blocks: the held-out gap before is below
    // the gap resolution, so its shrink (about 0.5) says little. What a drifting phase
    // would spoil is the fitted amplitude and noise in every held-out block.
    let dir = scratch("ripple-speed-off");
    let d = &named(
        generated("reaction_wheel", &[], &[2.0, 4.0], 2026, 0),
        "reaction_wheel-torque_ripple-r4-s0",
    );
    let (_, v) = diagnose(&dir, d);
    assert_eq!(v["verdict"], "torque_ripple", "{}", v["ranking"][0]);
    let top = &v["ranking"][0];
    let fitted = top["params"][0][1].as_f64().unwrap();
    let truth = d.label.truth["torque_ripple"];
    assert!(
        (fitted / truth - 1.0).abs() < 0.03,
        "fitted {fitted}, truth {truth}"
    );
    assert!(top["worst_block_p"].as_f64().unwrap() > 0.05, "{top}");
    assert!(top["gap_after"].as_f64().unwrap() < top["gap_before"].as_f64().unwrap());
}

#[test]
fn gap_fits_a_lubricant_torque_phase_near_zero() {
    // The periodic torque's phase was searched over one period [0, 2 pi] from the middle;
    // a truth phase of -0.2 rad (= 6.1) tied the grid's two ends and the fit stopped on
    // the edge at 0: shrink 0.79, one held-out block far above the noise.
    let d = &named(
        generated("reaction_wheel", &[], &[2.0, 4.0], 2026, 0),
        "reaction_wheel-lubricant_torque_noise-r4-s0",
    );
    assert_found(d, "lubricant_torque_noise", 0.9);
}

#[test]
fn gap_finds_a_clip_of_the_one_peak_by_swapping_the_folds() {
    // The clipped peak lies in a held-out block, so the training blocks show nothing to
    // fit and the first fold answers `unknown`; fitted on the odd blocks, the clip is found.
    let dir = scratch("clip");
    let d = one("scooter", "output_saturation", 4.0);
    let (_, v) = diagnose(&dir, &d);
    let effect = format!(
        "output_saturation:{}",
        d.label.channel.as_deref().unwrap().trim_start_matches("y:")
    );
    assert_eq!(
        v["verdict"],
        effect.as_str(),
        "{}",
        v["ranking"][0]["effect"]
    );
    assert_eq!(v["held_out_blocks"], "even (from 2)");
    // The generator clips symmetrically: a lower limit of its own does not pay.
    let params = &v["ranking"][0]["params"];
    assert_eq!(params[1][0], format!("{effect}.lower_limit").as_str());
    assert_eq!(params[1][1].as_f64(), params[0][1].as_f64().map(|l| -l));
}

#[test]
fn gap_finds_both_external_leaks_in_progpy_default_state_trace() {
    // progpy's default state has both external leaks (1e-5 m^2); against a leak-free model
    // the pair is recovered, on progpy's Euler scheme and on our semi-implicit one. On ours
    // one block of the first fold's held-out half keeps the schemes' difference (block
    // p = 7e-5); the second fold agrees on the pair and passes every block.
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/progpy-valve");
    let data = root.join("nominal_progpy_default_state_dt0.01.csv");
    for (scheme, folds) in [("_euler", "odd"), ("", "even (from 2)")] {
        let meta = root.join(format!(
            "gap/nominal_progpy_default_state{scheme}.meta.toml"
        ));
        let v = gap_with_meta(&data, &meta, &scratch("progpy-leaks").join("out"));
        assert_external_leaks(&v);
        assert_eq!(v["held_out_blocks"], folds);
    }
}

#[test]
fn on_progpys_friction_trace_the_valve_estimator_is_closer_with_the_effect_added() {
    // progpy's r = 9000 N s/m trace (truth columns x:x ... x:r, x:k) against our model at
    // r = 6000: the project's valve estimator runs with the user's model and with the
    // verdict's fitted friction, and is scored on the truth columns it estimates.
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/progpy-valve");
    let v = gap_with_meta(
        &root.join("friction_r9000_dt0.01.csv"),
        &root.join("gap/friction_r9000.meta.toml"),
        &scratch("progpy-friction-estimator").join("out"),
    );
    assert_eq!(v["verdict"], "friction_increase");
    let top = &v["ranking"][0];
    let before = top["estimation_error_before"].as_f64().unwrap();
    let after = top["estimation_error_after"].as_f64().unwrap();
    // Measured 0.138 -> 0.117 (the tracked r: 21 % -> 6 % off).
    assert!(after < 0.9 * before, "{before} -> {after}");
    assert!(after < 0.2, "{after}");
}

fn assert_external_leaks(v: &serde_json::Value) {
    assert_eq!(v["verdict"], "top_external_leak+bottom_external_leak");
    let pair = v["pairs"]
        .as_array()
        .unwrap()
        .iter()
        .find(|e| e["effect"] == v["verdict"])
        .unwrap();
    for p in pair["params"].as_array().unwrap() {
        let area = p[1].as_f64().unwrap();
        assert!((area / 1e-5 - 1.0).abs() < 1e-3, "{p}");
    }
    assert!(pair["shrink"].as_f64().unwrap() > 0.99, "{pair:#}");
    assert_eq!(v["where"]["channel"], "y:pb");
}

#[test]
fn a_valve_verdict_is_located_where_it_changes_the_model_most() {
    // The gap is located where the explaining effect changes the model most: the residual's
    // own NIS also carries each channel's noise-estimate error, and the valve's four
    // channels are close. This quantised y:pt (the bench's --seed 7 folder) was located on
    // y:q by the residual.
    let sets = generated("valve", &[], &[2.0, 4.0], 7, 0);
    let d = sets
        .iter()
        .find(|d| d.name == "valve-quantisation-r4-s0")
        .unwrap();
    assert_eq!(d.label.channel.as_deref(), Some("y:pt"));
    let o = run_one(d).unwrap();
    assert_eq!(o.verdict, "quantisation:pt", "{o:#?}");
    assert_eq!(o.channel, "y:pt", "{o:#?}");
    // These move y:x and y:pb within a few per cent of each other in noise units. The
    // pressures' noise from second differences also carries their fast transients (5-10 %
    // high), which put both on y:x; the explained residual's RMS is the noise itself.
    for effect in ["friction_increase", "internal_leak"] {
        let name = format!("valve-{effect}-r4-s0");
        let d = sets.iter().find(|d| d.name == name).unwrap();
        assert_eq!(d.label.channel.as_deref(), Some("y:pb"), "{name}");
        let o = run_one(d).unwrap();
        assert_eq!(o.verdict, effect, "{o:#?}");
        assert_eq!(o.channel, "y:pb", "{o:#?}");
    }
}

#[test]
fn docs_gap_md_lists_every_plant_as_the_code_declares_it() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/gap.md");
    let page = std::fs::read_to_string(&path).unwrap();
    let printed = prognos(&["gap-plants"]);
    assert!(printed.status.success());
    let reference = String::from_utf8(printed.stdout).unwrap();
    assert_eq!(reference, prognos_sim::gap::plant_reference());
    assert!(
        page.ends_with(&reference),
        "docs/gap.md is out of date: regenerate its reference part with `prognos gap-plants`"
    );
    for plant in ["reaction_wheel", "valve", "scooter", "dc_motor"] {
        assert!(reference.contains(&format!("### `{plant}`")), "{plant}");
    }
}

#[test]
fn a_quantised_fast_channel_takes_its_noise_from_the_residual_not_its_curvature() {
    // An encoder-like front wheel speed: step 3.5e-3 rad/s over noise 2.5e-4 while the
    // wheel oscillates, so the raw second differences (about 1e-2) measure the signal. Kept
    // at that level, the quantiser was no gap at all (verdict `none`).
    let opts = BenchOptions {
        plants: vec!["scooter".into()],
        seeds: 3,
        ratios: vec![4.0],
        seed: 2026,
        only: vec!["quantisation".into()],
        extra_sets: 0,
        noise_scale: 0.25,
        ..BenchOptions::default()
    };
    let sets = generate("scooter", &opts).unwrap();
    let d = sets
        .iter()
        .find(|d| d.label.channel.as_deref() == Some("y:front_speed"))
        .unwrap();
    let dir = scratch("scooter-quantised");
    let (_, verdict) = diagnose(&dir, d);
    assert_eq!(verdict["verdict"], "quantisation:front_speed");
    let front = &verdict["noise"][2];
    let std = front["std"].as_f64().unwrap();
    // At least the rounding (q / sqrt 12 = 1.0e-3), far below the raw estimate.
    assert!((9e-4..2e-3).contains(&std), "{front}");
}

/// The dataset `name` of the valve's single-effect sets (one seed, ratios 2 and 4, base
/// seed 2026) generated with `options`' sensor and sample-time variation. The whole set is
/// generated, as the dataset seeds follow the order of the sets.
fn valve_set(name: &str, options: BenchOptions) -> Dataset {
    let opts = BenchOptions {
        plants: vec!["valve".into()],
        seeds: 1,
        ratios: vec![2.0, 4.0],
        seed: 2026,
        extra_sets: 0,
        ..options
    };
    generate("valve", &opts)
        .unwrap()
        .into_iter()
        .find(|d| d.name == name)
        .unwrap()
}

#[test]
fn a_coarse_quantiser_over_little_noise_is_fitted_with_that_noise() {
    // Valve bottom pressure on a lattice of 3.3e5 Pa over 2e4 Pa of noise. The start was
    // refitted through the quantiser's staircase, which only a smooth (noisy) quantiser
    // survived: fitted with 1.3e5 Pa of noise, it scored below the model (-230) and the
    // verdict was a pair with choked_flow.
    let options = BenchOptions {
        noise_scale: 4.0,
        ..BenchOptions::default()
    };
    let d = valve_set("valve-quantisation-r4-s0", options);
    assert_eq!(d.label.channel.as_deref(), Some("y:pb"));
    let dir = scratch("valve-quantised");
    let (_, verdict) = diagnose(&dir, &d);
    assert_eq!(verdict["verdict"], "quantisation:pb");
    let noise = verdict["ranking"][0]["params"][1][1].as_f64().unwrap();
    assert!(noise < 8e4, "pre-quantiser noise {noise}");
}

#[test]
fn a_clip_just_below_the_supply_is_found_at_a_fast_sample_rate() {
    // The valve's top pressure clipped 0.6 % below the supply, sampled every 25 ms. The
    // start was refitted by a full Gauss-Newton step through the clip, which threw a
    // clipped start far off: every clip level but the top one looked terrible, and the
    // verdict was sensor_scale:pt+output_saturation:pt.
    let options = BenchOptions {
        sample_time_scale: 0.5,
        ..BenchOptions::default()
    };
    let d = valve_set("valve-output_saturation-r4-s0", options);
    assert_eq!(d.label.channel.as_deref(), Some("y:pt"));
    assert_found(&d, "output_saturation:pt", 0.8);
}

/// The first `none` set of `plant` (base seed 5) written with `input_timing`.
fn none_set(plant: &str, input_timing: InputTiming) -> Dataset {
    none_set_with(
        plant,
        BenchOptions {
            input_timing: Some(input_timing),
            ..BenchOptions::default()
        },
    )
}

/// The first `none` set of `plant` (base seed 5) generated with `options`' variation.
fn none_set_with(plant: &str, options: BenchOptions) -> Dataset {
    let opts = BenchOptions {
        plants: vec![plant.into()],
        seeds: 1,
        ratios: vec![],
        seed: 5,
        only: vec!["no-such-effect".into()],
        extra_sets: 1,
        ..options
    };
    generate(plant, &opts)
        .unwrap()
        .into_iter()
        .find(|d| d.label.kind == CaseKind::None)
        .unwrap()
}

#[test]
fn heavy_tailed_or_correlated_noise_is_noise_not_an_unexplained_gap() {
    // Student-t noise (5 degrees of freedom) and AR(1) noise (coefficient 0.5) of the
    // bench's std: under the white Gaussian tests the t5's few wild readings failed windows
    // and its trimmed noise estimate came out low, the AR(1)'s came out at 0.65 of its std
    // and no whiteness test held, and 11 and 12 of 12 no-effect sets were `unknown`
    // (docs/results.md, session 29).
    let dir = scratch("noise-shapes");
    for (shape, plants, note) in [
        (
            NoiseShape::StudentT5,
            &["valve", "dc_motor", "scooter"][..],
            "heavier than a Gaussian",
        ),
        (
            NoiseShape::Ar1,
            &["valve", "dc_motor"][..],
            "correlated from sample to sample",
        ),
    ] {
        let mut repeated = 0;
        for plant in plants {
            let options = BenchOptions {
                noise_shape: shape,
                ..BenchOptions::default()
            };
            let d = none_set_with(plant, options);
            let (_, verdict) = diagnose(&dir, &d);
            assert_eq!(verdict["verdict"], "none", "{shape:?} {plant}: {verdict:#}");
            let warnings = verdict["warnings"].as_array().unwrap();
            repeated += warnings.iter().any(|w| w.as_str().unwrap().contains(note)) as usize;
        }
        // The white Gaussian tests alone said `unknown` on at least one of them.
        assert!(repeated > 0, "{shape:?}");
    }
}

#[test]
fn records_of_other_input_timings_are_read_as_they_were_written() {
    // Rows that show the input acting over the step ending at them (the lockstep runner's
    // log), or a wheel current that already follows the row's command (y_k = C x_k + D u_k),
    // were replayed one row off: each of these `none` sets was `unknown`. The valve replays
    // progpy's rows (`after`); a textbook loop's (`before`) was one row off the other way.
    let dir = scratch("timing");
    for (plant, timing, name) in [
        ("reaction_wheel", InputTiming::At, "at"),
        ("reaction_wheel", InputTiming::After, "after"),
        ("valve", InputTiming::After, "after"),
        ("valve", InputTiming::Before, "before"),
        ("dc_motor", InputTiming::After, "after"),
        ("scooter", InputTiming::Before, "before"),
    ] {
        let d = none_set(plant, timing);
        let (_, verdict) = diagnose(&dir, &d);
        assert_eq!(verdict["verdict"], "none", "{plant} {name}: {verdict:#}");
        assert_eq!(verdict["input_timing"]["timing"], name, "{plant}");
        assert_eq!(verdict["input_timing"]["source"], "data", "{plant}");
    }
}

#[test]
fn a_declared_input_timing_is_kept_and_a_bad_one_is_refused_at_its_line() {
    let dir = scratch("timing-declared");
    let d = none_set("dc_motor", InputTiming::After);
    let csv = write(&dir, &d);
    // Declared as written: the same reading, no alternatives tried.
    let meta = dir.join("after.meta.toml");
    std::fs::write(&meta, format!("{}input_timing = \"after\"\n", d.meta)).unwrap();
    let verdict = gap_with_meta(&csv, &meta, &dir.join("out-after"));
    assert_eq!(verdict["verdict"], "none");
    assert_eq!(verdict["input_timing"]["source"], "meta");
    assert_eq!(verdict["input_timing"]["chi2"].as_array().unwrap().len(), 1);
    // Declared wrongly, the model is one row off and the gap is real.
    let meta = dir.join("before.meta.toml");
    std::fs::write(&meta, format!("input_timing = \"before\"\n{}", d.meta)).unwrap();
    let verdict = gap_with_meta(&csv, &meta, &dir.join("out-before"));
    assert_ne!(verdict["verdict"], "none");
    let text = format!("input_timing = \"sideways\"\n{}", d.meta);
    let (code, err) = bad(&dir, &d.csv, Some(&text));
    assert_eq!(code, 2, "{err}");
    let m = s(&dir.join("data.csv.meta.toml")).to_string();
    assert!(
        err.contains(&format!("{m}:1:16: unknown input_timing `sideways`")),
        "{err}"
    );
}

/// `csv` with each column in `units` ((column, unit, scale, offset)) rewritten as
/// `value * scale + offset`.
fn in_other_units(csv: &str, units: &[(&str, &str, f64, f64)]) -> String {
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let mut out = header.join(",") + "\n";
    for line in lines {
        let cells: Vec<String> = line
            .split(',')
            .zip(&header)
            .map(
                |(cell, name)| match units.iter().find(|(c, ..)| c == name) {
                    Some((_, _, scale, offset)) => {
                        format!("{}", cell.parse::<f64>().unwrap() * scale + offset)
                    }
                    None => cell.to_string(),
                },
            )
            .collect();
        out.push_str(&(cells.join(",") + "\n"));
    }
    out
}

#[test]
fn columns_in_other_units_are_converted_and_a_wrong_dimension_is_refused() {
    // The same wheel record logged in ms, rpm, mA, kelvin and degrees, its speed noise declared
    // in rpm: read through `[units]`, the diagnosis is the SI one. Unread, the rpm are a
    // speed sensor scale of 9.5 and the verdict is off.
    let dir = scratch("units");
    let d = one("reaction_wheel", "viscous_temperature", 4.0);
    let (_, si) = diagnose(&dir, &d);
    assert_eq!(
        si["verdict"], "viscous_temperature",
        "{:#}",
        si["ranking"][0]
    );
    let rpm = 60.0 / (2.0 * std::f64::consts::PI);
    let units = [
        ("t", "ms", 1e3, 0.0),
        ("y:speed", "rpm", rpm, 0.0),
        ("y:current", "mA", 1e3, 0.0),
        ("u:temperature", "K", 1.0, 273.15),
        ("u:angle", "deg", 180.0 / std::f64::consts::PI, 0.0),
    ];
    let csv = dir.join("logged.csv");
    std::fs::write(&csv, in_other_units(&d.csv, &units)).unwrap();
    let speed_noise = si["noise"]
        .as_array()
        .unwrap()
        .iter()
        .find(|n| n["channel"] == "y:speed")
        .unwrap()["std"]
        .as_f64()
        .unwrap();
    let mut table = String::from("[units]\n");
    for (column, unit, ..) in &units {
        if d.csv.lines().next().unwrap().contains(column) {
            table.push_str(&format!("\"{column}\" = \"{unit}\"\n"));
        }
    }
    let meta = dir.join("logged.meta.toml");
    std::fs::write(
        &meta,
        format!(
            "{}{table}[noise]\n\"y:speed\" = {}\n",
            d.meta,
            speed_noise * rpm
        ),
    )
    .unwrap();
    let v = gap_with_meta(&csv, &meta, &dir.join("out-units"));
    assert_eq!(v["verdict"], si["verdict"]);
    let fitted = |v: &serde_json::Value| v["ranking"][0]["params"][0][1].as_f64().unwrap();
    assert!(
        (fitted(&v) / fitted(&si) - 1.0).abs() < 1e-3,
        "{} vs {}",
        fitted(&v),
        fitted(&si)
    );
    let noise = &v["noise"].as_array().unwrap()[1];
    assert_eq!(
        (&noise["channel"], &noise["source"]),
        (&"y:speed".into(), &"meta".into())
    );
    assert!((noise["std"].as_f64().unwrap() / speed_noise - 1.0).abs() < 1e-12);
    let warnings = v["warnings"].to_string();
    assert!(
        warnings.contains("`y:speed` read in rpm and converted to rad/s"),
        "{warnings}"
    );
    // Without `[units]` the ms are refused against `dt` and the rpm taken for rad/s.
    let meta = dir.join("unread.meta.toml");
    std::fs::write(&meta, &d.meta).unwrap();
    let o = prognos(&[
        "gap",
        "--data",
        s(&csv),
        "--meta",
        s(&meta),
        "--out",
        s(&dir.join("o")),
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("`dt` = 0.05 but the samples"));
    let csv = dir.join("logged-in-s.csv");
    std::fs::write(&csv, in_other_units(&d.csv, &units[1..])).unwrap();
    let v = gap_with_meta(&csv, &meta, &dir.join("out-unread"));
    assert_ne!(v["verdict"], si["verdict"]);
    // A unit of another dimension is refused at its line; an unknown one is read as the
    // plant's, with a warning at its line.
    let text = format!("{}[units]\n\"y:speed\" = \"kPa\"\n", d.meta);
    let (code, err) = bad(&dir, &d.csv, Some(&text));
    assert_eq!(code, 2, "{err}");
    let line = text.lines().count();
    let m = s(&dir.join("data.csv.meta.toml")).to_string();
    assert!(
        err.contains(&format!(
            "{m}:{line}:1: `y:speed` is given in `kPa` (pressure) but plant `reaction_wheel` \
             reads it in rad/s (angular speed)"
        )),
        "{err}"
    );
    let meta = dir.join("odd.meta.toml");
    std::fs::write(
        &meta,
        format!("{}[units]\n\"y:speed\" = \"furlong/fortnight\"\n", d.meta),
    )
    .unwrap();
    let v = gap_with_meta(&write(&dir, &d), &meta, &dir.join("out-odd"));
    assert_eq!(v["verdict"], si["verdict"]);
    assert!(
        v["warnings"]
            .to_string()
            .contains("unit `furlong/fortnight` of `y:speed` is not one the diagnoser converts"),
        "{}",
        v["warnings"]
    );
}

#[test]
fn an_output_column_without_a_reading_is_left_out_with_a_warning() {
    // A preparer's table has every channel's column, an absent sensor's left empty.
    let dir = scratch("empty-column");
    let mut d = one("dc_motor", "coulomb_friction", 4.0);
    let original = d.csv.clone();
    let mut lines = original.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let current = header.iter().position(|h| *h == "y:current").unwrap();
    let mut csv = header.join(",") + "\n";
    for line in lines {
        let mut cells: Vec<&str> = line.split(',').collect();
        cells[current] = "";
        csv.push_str(&(cells.join(",") + "\n"));
    }
    d.csv = csv;
    let (out, v) = diagnose(&dir, &d);
    let noise = v["noise"].as_array().unwrap();
    assert_eq!(noise.len(), 1, "{noise:?}");
    assert_eq!(noise[0]["channel"], "y:speed");
    let column = 1 + header[..current].iter().map(|h| h.len() + 1).sum::<usize>();
    let data = out.parent().unwrap().join("data.csv");
    assert!(
        v["warnings"].to_string().contains(&format!(
            "{}:1:{column}: column `y:current` holds no reading and is left out",
            s(&data)
        )),
        "{}",
        v["warnings"]
    );
}

#[test]
fn an_effect_in_a_record_of_another_timing_is_diagnosed_under_both() {
    // A wheel whose current shows its row's command (`at`) and whose viscous coefficient
    // falls with temperature: `at` fits the user's model better, but by far less than half
    // its gap, as any shift of a model far off might (progpy's leaking valve). Diagnosed under
    // both timings, `at`'s best explanation leaves the smaller held-out gap.
    let opts = BenchOptions {
        plants: vec!["reaction_wheel".into()],
        seeds: 1,
        ratios: vec![4.0],
        seed: 2026,
        only: vec!["viscous_temperature".into()],
        extra_sets: 0,
        input_timing: Some(InputTiming::At),
        ..BenchOptions::default()
    };
    let d = generate("reaction_wheel", &opts).unwrap().remove(0);
    let (_, v) = diagnose(&scratch("contested"), &d);
    assert_eq!(v["verdict"], "viscous_temperature", "{:#}", v["ranking"][0]);
    let timing = &v["input_timing"];
    assert_eq!(timing["timing"], "at", "{timing:#}");
    let left = timing["gap_left"].as_array().unwrap();
    assert_eq!((&left[0][0], &left[1][0]), (&"before".into(), &"at".into()));
    // Under `before` no effect explains the gap with white Gaussian noise, and the repeat
    // with the noise reshaped by that misfit (session 30) leaves 0.077 of a gap against the
    // inflated noise, less than `at`'s 0.146: a reshaped diagnosis loses the contest to
    // one with white Gaussian noise (`settle_contest`), which picked `before` without
    // that rule. `at` left under half of `before`'s gap before the repeat existed.
    assert!(left[1][1].as_f64().unwrap() < 0.2, "{timing:#}");
    let sources = v["noise"].to_string();
    assert!(
        !sources.contains("correlated") && !sources.contains("heavy"),
        "{sources}"
    );
}

#[test]
fn ramped_inputs_keep_attribution_and_reject_nothing_spurious() {
    // A third input family the diagnoser was not developed on: continuous commands with
    // kinks and no jumps (`--excitation ramps`). Two wheel effects and a valve leak at
    // ratio 4, and one no-effect set each.
    for (plant, only) in [
        (
            "reaction_wheel",
            vec!["viscous_temperature", "lubricant_torque_noise"],
        ),
        ("valve", vec!["internal_leak"]),
    ] {
        let opts = BenchOptions {
            plants: vec![plant.into()],
            seeds: 1,
            ratios: vec![4.0],
            seed: 5,
            only: only.iter().map(|e| e.to_string()).collect(),
            extra_sets: 1,
            excitation: Excitation::Ramps,
            ..BenchOptions::default()
        };
        let sets: Vec<Dataset> = generate(plant, &opts)
            .unwrap()
            .into_iter()
            .filter(|d| matches!(d.label.kind, CaseKind::Single | CaseKind::None))
            .collect();
        assert_eq!(sets.len(), only.len() + 1);
        let outcomes: Vec<_> = sets.iter().map(|d| run_one(d).unwrap()).collect();
        let sc = score(&outcomes, |r| r >= 2.0);
        assert_eq!(sc.top1, 1.0, "{plant}: {outcomes:#?}");
        assert_eq!(sc.false_attribution, 0.0, "{plant}: {outcomes:#?}");
        assert!(sc.median_shrink > 0.8, "{plant}: {}", sc.median_shrink);
    }
}

/// `csv` with column `name` read through `reading` (every other cell unchanged).
fn with_column_read(csv: &str, name: &str, mut reading: impl FnMut(f64) -> f64) -> String {
    let header = csv.lines().next().unwrap();
    let column = header.split(',').position(|c| c == name).unwrap();
    let mut out = format!("{header}\n");
    for l in csv.lines().skip(1) {
        let cells: Vec<String> = l
            .split(',')
            .enumerate()
            .map(|(i, c)| match c.parse::<f64>() {
                Ok(v) if i == column && v.is_finite() => format!("{}", reading(v)),
                _ => c.to_string(),
            })
            .collect();
        out.push_str(&cells.join(","));
        out.push('\n');
    }
    out
}

/// The values of column `name` of `csv`.
fn column_values(csv: &str, name: &str) -> Vec<f64> {
    let header = csv.lines().next().unwrap();
    let column = header.split(',').position(|c| c == name).unwrap();
    csv.lines()
        .skip(1)
        .filter_map(|l| l.split(',').nth(column)?.parse().ok())
        .collect()
}

#[test]
fn a_truncating_converter_is_a_quantiser_not_a_bias() {
    // `step * floor(y / step)`, as an integer conversion writes, lowers every reading by
    // half a step on average. With the thresholds fixed at round-to-nearest the quantiser
    // lost to a sensor bias; its threshold is now fitted. Steps of about 6 noise std.
    let dir = scratch("floor-quantiser");
    let mut d = named(
        generated("scooter", &["sensor_bias"], &[2.0], 7, 1),
        "scooter-none-s0",
    );
    let step = 0.015;
    d.csv = with_column_read(&d.csv, "y:rear_speed", |v| step * (v / step).floor());
    let (_, v) = diagnose(&dir, &d);
    assert_eq!(
        v["verdict"], "quantisation:rear_speed",
        "{}",
        v["ranking"][0]
    );
    let params = &v["ranking"][0]["params"];
    let value = |i: usize| params[i][1].as_f64().unwrap();
    assert!((value(0) / step - 1.0).abs() < 1e-6, "{params}");
    assert!((value(2) - 0.5).abs() < 0.05, "threshold {params}");
}

#[test]
fn jittered_stamps_around_uniform_sampling_are_replayed_on_the_grid() {
    // A logger's stamps off by up to 2 % of a sample around uniform sampling. Replayed at
    // the stamped times, the wheel's precise speed sensor (noise 3e-3 rad/s while the
    // wheel accelerates at rad/s^2) saw the timing error as a gap no current bias
    // explains: `unknown` (shrink 0.83, one held-out block at p 2e-17).
    let dir = scratch("jitter");
    let mut d = named(
        generated("reaction_wheel", &["sensor_bias"], &[4.0], 606, 0),
        "reaction_wheel-sensor_bias-r4-s0",
    );
    assert_eq!(d.label.channel.as_deref(), Some("y:current"));
    let mut state = 12345u64;
    let mut lines = d.csv.lines();
    let mut csv = format!("{}\n", lines.next().unwrap());
    for (k, line) in lines.enumerate() {
        let (t, rest) = line.split_once(',').unwrap();
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        let u = (state >> 11) as f64 / (1u64 << 53) as f64;
        let t: f64 = t.parse().unwrap();
        let jitter = if k == 0 { 0.0 } else { 0.001 * (2.0 * u - 1.0) };
        csv.push_str(&format!("{},{rest}\n", t + jitter));
    }
    d.csv = csv;
    let (_, v) = diagnose(&dir, &d);
    assert_eq!(v["verdict"], "sensor_bias:current", "{}", v["ranking"][0]);
    assert!(v["ranking"][0]["shrink"].as_f64().unwrap() > 0.9);
    let warnings = v["warnings"].to_string();
    assert!(
        warnings.contains("replayed on a uniform grid"),
        "{warnings}"
    );
}

#[test]
fn a_sensor_range_not_symmetric_about_zero_is_a_saturation() {
    // Motor speed clipped at 0.7 of its highest and 0.9 of its lowest reading. One limit,
    // +-L, cannot fit both ends: this record was `unknown` with the symmetric clip.
    let dir = scratch("asymmetric-clip");
    let mut d = named(
        generated("dc_motor", &["sensor_bias"], &[2.0], 7, 1),
        "dc_motor-none-s0",
    );
    let speeds = column_values(&d.csv, "y:speed");
    let hi = 0.7 * speeds.iter().copied().fold(f64::MIN, f64::max);
    let lo = 0.9 * speeds.iter().copied().fold(f64::MAX, f64::min);
    assert!(
        lo < 0.0 && hi > 0.0 && (hi + lo).abs() > 0.1 * hi,
        "{lo} {hi}"
    );
    d.csv = with_column_read(&d.csv, "y:speed", |v| v.max(lo).min(hi));
    let (_, v) = diagnose(&dir, &d);
    assert_eq!(
        v["verdict"], "output_saturation:speed",
        "{}",
        v["ranking"][0]
    );
    let params = &v["ranking"][0]["params"];
    let value = |i: usize| params[i][1].as_f64().unwrap();
    assert!((value(0) / hi - 1.0).abs() < 0.01, "{params}");
    assert!((value(1) / lo - 1.0).abs() < 0.01, "{params}");
}

#[test]
fn a_deadband_that_zeroes_small_readings_is_a_dead_zone_with_no_shift() {
    // A low-speed cutoff: the sensor reads 0 while |speed| < d and the speed itself
    // above (no shift by d), with the noise after it. Read from the truth column, so the
    // record's own noise stays. The shifted dead zone alone could not fit it (`unknown`).
    let dir = scratch("zeroing-deadband");
    let opts = BenchOptions {
        plants: vec!["dc_motor".into()],
        seeds: 1,
        ratios: vec![2.0],
        seed: 11,
        only: vec!["sensor_bias".into()],
        extra_sets: 1,
        truth_columns: true,
        ..BenchOptions::default()
    };
    let mut d = named(generate("dc_motor", &opts).unwrap(), "dc_motor-none-s0");
    let header: Vec<&str> = d.csv.lines().next().unwrap().split(',').collect();
    let y = header.iter().position(|c| *c == "y:speed").unwrap();
    let x = header.iter().position(|c| *c == "x:speed").unwrap();
    let rows: Vec<Vec<f64>> = d
        .csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(|c| c.parse().unwrap()).collect())
        .collect();
    let top = rows.iter().map(|r| r[x].abs()).fold(0.0, f64::max);
    let width = 0.15 * top;
    let zeroed = rows.iter().filter(|r| r[x].abs() < width).count();
    assert!(zeroed > 50, "{zeroed}");
    let mut csv = format!("{}\n", header.join(","));
    for r in &rows {
        let mut r = r.clone();
        let cut = if r[x].abs() < width { 0.0 } else { r[x] };
        r[y] += cut - r[x];
        let cells: Vec<String> = r.iter().map(|v| v.to_string()).collect();
        csv.push_str(&cells.join(","));
        csv.push('\n');
    }
    d.csv = csv;
    let (_, v) = diagnose(&dir, &d);
    assert_eq!(v["verdict"], "dead_zone:speed", "{}", v["ranking"][0]);
    let params = &v["ranking"][0]["params"];
    let value = |i: usize| params[i][1].as_f64().unwrap();
    assert!((value(0) / width - 1.0).abs() < 0.02, "{params}");
    assert!(value(1) < 0.05, "{params}");
}

#[test]
fn a_deadband_on_the_noisy_readings_is_a_dead_zone_with_the_noise_measured_off_its_zeros() {
    // The same cutoff applied to the noisy reading: inside the zone the sensor reads exactly
    // 0, so a third of the record has zero differences and the noise estimate fell to a
    // fraction of the noise; the dead zone was then `unknown`.
    let dir = scratch("deadband-after-noise");
    let mut d = named(
        generated("dc_motor", &["sensor_bias"], &[2.0], 11, 1),
        "dc_motor-none-s0",
    );
    let speed = column_values(&d.csv, "y:speed");
    let width = 0.15 * speed.iter().map(|v| v.abs()).fold(0.0, f64::max);
    let zeroed = speed.iter().filter(|v| v.abs() < width).count();
    assert!(zeroed > 50, "{zeroed}");
    d.csv = with_column_read(&d.csv, "y:speed", |v| if v.abs() < width { 0.0 } else { v });
    let (_, v) = diagnose(&dir, &d);
    assert_eq!(v["verdict"], "dead_zone:speed", "{}", v["ranking"][0]);
    let params = &v["ranking"][0]["params"];
    let value = |i: usize| params[i][1].as_f64().unwrap();
    assert!((value(0) / width - 1.0).abs() < 0.02, "{params}");
    assert!(value(1) < 0.05, "{params}");
    assert!(v["ranking"][0]["shrink"].as_f64().unwrap() > 0.9);
}

/// A seed-31 record of `plant` (`--seeds 2 --ratios 1,2,4,8`, cell `cell` such as `r2-s1`)
/// with its `channel` read through a deadband after the noise: readings of magnitude below
/// `width` set to 0. The noisy readings are the cell's sensor-bias set's (the same run and
/// noise as its dead-zone set) less the bias. Returns the record and how many it zeroed.
fn zeroed_after_the_noise(plant: &str, cell: &str, channel: &str, width: f64) -> (Dataset, usize) {
    let opts = BenchOptions {
        plants: vec![plant.into()],
        seeds: 2,
        ratios: vec![1.0, 2.0, 4.0, 8.0],
        seed: 31,
        only: vec!["sensor_bias".into()],
        extra_sets: 0,
        ..BenchOptions::default()
    };
    let mut d = named(
        generate(plant, &opts).unwrap(),
        &format!("{plant}-sensor_bias-{cell}"),
    );
    let column = format!("y:{channel}");
    assert_eq!(d.label.channel.as_deref(), Some(column.as_str()));
    let bias = d.label.truth[&format!("sensor_bias:{channel}")];
    let zeroed = column_values(&d.csv, &column)
        .iter()
        .filter(|v| (*v - bias).abs() < width)
        .count();
    d.csv = with_column_read(&d.csv, &column, |v| {
        if (v - bias).abs() < width {
            0.0
        } else {
            v - bias
        }
    });
    (d, zeroed)
}

/// Diagnoses `d` and checks that the verdict is `effect`, its width within `tolerance` of
/// `width`, its shift (0: zeroing) below 0.05 and its shrink above 0.8.
fn assert_zeroing_dead_zone(name: &str, d: &Dataset, effect: &str, width: f64, tolerance: f64) {
    let dir = scratch(name);
    let (_, v) = diagnose(&dir, d);
    assert_eq!(v["verdict"], effect, "{}", v["ranking"][0]);
    let params = &v["ranking"][0]["params"];
    let value = |i: usize| params[i][1].as_f64().unwrap();
    assert!((value(0) / width - 1.0).abs() < tolerance, "{params}");
    assert!(value(1) < 0.05, "{params}");
    assert!(v["ranking"][0]["shrink"].as_f64().unwrap() > 0.8);
}

#[test]
fn a_deadband_after_the_noise_beside_a_level_the_channel_dwells_at_is_a_dead_zone() {
    // A cutoff on the noisy current at 1.4 % of its range, where the motor's running
    // current dwells at one to two widths: the noise zeroes some readings at that level
    // as well. The fit held the shift and the noise at their neutral values one at a time
    // and never reached `shift = 0` with the noise on: `unknown`, a bias of 0.06 of the gap.
    let width = 0.122;
    let (d, zeroed) = zeroed_after_the_noise("dc_motor", "r2-s1", "current", width);
    assert!(zeroed > 300, "{zeroed}");
    assert_zeroing_dead_zone(
        "deadband-after-noise-dwelling",
        &d,
        "dead_zone:current",
        width,
        0.1,
    );
}

#[test]
fn a_deadband_after_the_noise_that_zeroes_few_readings_takes_the_channels_noise() {
    // The top chamber pressure zeroed below 570 kPa after the noise: ten readings of 1800.
    // With the noise before the zone fitted, the training blocks (which cross the edge only
    // where a hard edge agrees) put it at 0.75 of the channel's and the width 2.4 % low,
    // and the held-out blocks rejected the fit (p 1e-169): `unknown`. Exact zeros leave no
    // noise after the zone, so the noise before it is the channel's.
    let width = 569_857.0;
    let (d, zeroed) = zeroed_after_the_noise("valve", "r8-s0", "pt", width);
    assert!((10..18).contains(&zeroed), "{zeroed}");
    assert_zeroing_dead_zone(
        "deadband-after-noise-few-zeros",
        &d,
        "dead_zone:pt",
        width,
        0.05,
    );
}

#[test]
fn a_clip_after_the_noise_is_found_with_the_noise_measured_off_its_limit() {
    // The top chamber pressure clipped at 0.7 of its highest reading after the noise: about
    // two thirds of the readings sit on the limit. Their zero differences put the noise at
    // 0.4 of its level, and the clip, though fitted to 1e-8 of the limit, failed the
    // block test (`unknown`).
    let dir = scratch("clip-after-noise");
    let mut d = named(
        generated("valve", &["sensor_bias"], &[2.0], 77, 1),
        "valve-none-s0",
    );
    let unclipped = column_values(&d.csv, "y:pt");
    let limit = 0.7 * unclipped.iter().copied().fold(f64::MIN, f64::max);
    d.csv = with_column_read(&d.csv, "y:pt", |v| v.min(limit));
    let at_limit = column_values(&d.csv, "y:pt")
        .iter()
        .filter(|v| **v == limit)
        .count();
    assert!(at_limit > unclipped.len() / 3, "{at_limit}");
    let (_, v) = diagnose(&dir, &d);
    assert_eq!(v["verdict"], "output_saturation:pt", "{}", v["ranking"][0]);
    let fitted = v["ranking"][0]["params"][0][1].as_f64().unwrap();
    assert!((fitted / limit - 1.0).abs() < 1e-6, "{fitted} {limit}");
    let noise = v["noise"]
        .as_array()
        .unwrap()
        .iter()
        .find(|n| n["channel"] == "y:pt")
        .unwrap()["std"]
        .as_f64()
        .unwrap();
    assert!(noise > 3000.0, "{noise}");
}

/// The `none` set of `plant` (bench seed 77) with its `channel` read as `sensor` maps the
/// truth column `x:<channel>` (the noise kept as it was), the truth columns then dropped.
fn truth_read_through(plant: &str, channel: &str, sensor: impl Fn(&[f64]) -> Vec<f64>) -> Dataset {
    let mut d = none_set_with_truth(plant);
    let reading = format!("y:{channel}");
    let truth = column_values(&d.csv, &format!("x:{channel}"));
    let measured = column_values(&d.csv, &reading);
    let read = sensor(&truth);
    let mut k = 0;
    d.csv = with_column_read(&d.csv, &reading, |v| {
        let noise = v - truth[k];
        assert_eq!(v, measured[k]);
        k += 1;
        read[k - 1] + noise
    });
    drop_truth(&mut d);
    d
}

/// The seed-77 bench's no-effect set of `plant` with its truth columns.
fn none_set_with_truth(plant: &str) -> Dataset {
    let opts = BenchOptions {
        plants: vec![plant.into()],
        ratios: vec![],
        seed: 77,
        only: vec!["no-such-effect".into()],
        extra_sets: 1,
        truth_columns: true,
        ..BenchOptions::default()
    };
    named(generate(plant, &opts).unwrap(), &format!("{plant}-none-s0"))
}

fn drop_truth(d: &mut Dataset) {
    let truths: Vec<String> = (d.csv.lines().next().unwrap().split(','))
        .filter(|c| c.starts_with("x:"))
        .map(String::from)
        .collect();
    for column in &truths {
        d.csv = without_column(&d.csv, column);
    }
}

#[test]
fn a_filter_on_the_noisy_reading_is_a_first_order_lag() {
    // `y = lag(x + e)`: the noise is low-passed too, so the lag's residual keeps its sign
    // from sample to sample and exceeds the noise read off the differences; every such
    // record (dc motor, ratio 8) came out `unknown` though the lag fitted its time
    // constant to 0.2 %. Its one-step predictions leave the white noise itself.
    let dir = scratch("lag-after-noise");
    let (dt, tau): (f64, f64) = (0.01, 0.03);
    let alpha = 1.0 - (-dt / tau).exp();
    let mut d = none_set_with_truth("dc_motor");
    let mut state = f64::NAN;
    d.csv = with_column_read(&d.csv, "y:speed", |v| {
        state = if state.is_nan() {
            v
        } else {
            state + alpha * (v - state)
        };
        state
    });
    let (_, v) = diagnose(&dir, &d);
    let top = &v["ranking"][0];
    assert_eq!(v["verdict"], "first_order_lag:speed", "{top}");
    let fitted = top["params"][0][1].as_f64().unwrap();
    assert!((fitted / tau - 1.0).abs() < 0.05, "{fitted}");
    assert!(top["shrink"].as_f64().unwrap() > 0.8);
    // The estimator reads the speed with the lag undone (0.044 -> 0.00076 measured).
    let before = top["estimation_error_before"].as_f64().unwrap();
    let after = top["estimation_error_after"].as_f64().unwrap();
    assert!(after < 0.1 * before, "{before} -> {after}");
}

#[test]
fn a_current_read_seconds_late_is_a_measurement_delay() {
    // A wheel current that changes with the command steps alone differs from itself a few
    // samples late only at the steps: reaching ratio 8 takes a delay of tens of samples.
    // The delay was searched to 25 samples only, and the record came out `unknown`.
    let dir = scratch("long-delay");
    let late = 65;
    let d = truth_read_through("reaction_wheel", "current", |x| {
        (0..x.len()).map(|k| x[k.saturating_sub(late)]).collect()
    });
    let (_, v) = diagnose(&dir, &d);
    assert_eq!(
        v["verdict"], "measurement_delay:current",
        "{}",
        v["ranking"][0]
    );
    let delay = v["ranking"][0]["params"][0][1].as_f64().unwrap();
    assert!((delay / (late as f64 * 0.05) - 1.0).abs() < 0.01, "{delay}");
    assert!(v["ranking"][0]["shrink"].as_f64().unwrap() > 0.8);
}

#[test]
fn a_sensor_reading_under_half_the_truth_is_a_sensor_scale() {
    // The scale error was searched within +-0.5 only: a gain of 0.45 left a gap of
    // several noise stds and the record came out `unknown`.
    let dir = scratch("low-gain");
    let d = truth_read_through("dc_motor", "speed", |x| {
        x.iter().map(|v| 0.45 * v).collect()
    });
    let (_, v) = diagnose(&dir, &d);
    assert_eq!(v["verdict"], "sensor_scale:speed", "{}", v["ranking"][0]);
    let scale = v["ranking"][0]["params"][0][1].as_f64().unwrap();
    assert!((scale + 0.55).abs() < 0.005, "{scale}");
    assert!(v["ranking"][0]["shrink"].as_f64().unwrap() > 0.8);
}

#[test]
fn a_quantiser_before_the_noise_is_found_from_readings_off_its_lattice() {
    // `q round(y / q) + e`: the readings scatter about the lattice, so no exact step shows
    // in them. The quantiser was only a candidate on a lattice, and such records came out
    // `unknown` or as a sensor mimic.
    let dir = scratch("staircase");
    let step = 0.15;
    let d = truth_read_through("dc_motor", "current", |x| {
        x.iter().map(|v| step * (v / step).round()).collect()
    });
    let (_, v) = diagnose(&dir, &d);
    assert_eq!(v["verdict"], "quantisation:current", "{}", v["ranking"][0]);
    let fitted = v["ranking"][0]["params"][0][1].as_f64().unwrap();
    assert!((fitted / step - 1.0).abs() < 1e-3, "{fitted}");
    assert!(v["ranking"][0]["shrink"].as_f64().unwrap() > 0.8);
}
