//! End-to-end checks of the edge-cloud method on the real PRONOSTIA files in `data/`.

use nalgebra::{Vector1, Vector2, Vector4};
use prognos_core::filter::particle::{ParticleFilter, PfConfig};
use prognos_core::health::{DegradationStage, PiecewiseHiModel, StageInput};
use prognos_core::random::{normal, uniform01};
use prognos_sim::edge_cloud::bearing::{load_bearing, parse_bearing};
use prognos_sim::edge_cloud::{
    EdgeCloudConfig, EdgeCloudError, PAPER_TABLE1_PH_MIN, analyse_bearing, run_bearing,
};
use rand_core::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;
use std::path::{Path, PathBuf};

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../data/pronostia")
        .join(name)
}

fn scratch_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("prognos-ec-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn bearing3_1_end_to_end_meets_the_paper_horizon_and_writes_outputs_atomically() {
    let out = scratch_dir("b31");
    let config = EdgeCloudConfig {
        output_dir: out.clone(),
        ..EdgeCloudConfig::default()
    };
    let (run, dir) = run_bearing(&data("Bearing3_1.csv"), &config).unwrap();
    let s = &run.summary;
    assert_eq!(s.snapshots, 515);
    assert_eq!(s.end_of_life_s, 5140.0);
    assert_eq!(s.edge_rejections, 0);
    // Table 1 of the paper: PH = 1.17 min on Bearing3_1 (condition 3, bearing 1).
    let ph = s.prognostic_horizon_s.expect("a prognostic horizon");
    assert!(ph >= 1.17 * 60.0, "PH {ph} s");
    let trigger = s.trigger_s.unwrap();
    assert!(trigger < s.end_of_life_s - ph + 1e-9);
    // The HI is finite wherever it exists and its last smoothed value is past T_EoL.
    assert!(
        run.series
            .iter()
            .filter_map(|r| r.hi_smoothed)
            .all(f64::is_finite)
    );
    // Healthy before the trigger, far above it at the end.
    let last_hi = run.series.iter().rev().find_map(|r| r.hi_smoothed).unwrap();
    assert!(last_hi > 10.0 * config.prog_threshold, "{last_hi}");
    // Every prediction from t_EoL - PH on lies in the alpha band (Eq. 35).
    let band = config.alpha * s.end_of_life_s;
    for r in run.series.iter().filter(|r| r.t_s >= s.end_of_life_s - ph) {
        let p = r.rul.expect("a prediction").mean_s;
        assert!(
            (p - r.true_rul_s).abs() <= band,
            "{} s: {p} vs {}",
            r.t_s,
            r.true_rul_s
        );
    }
    // Nine REALs every 10 s against 2560 samples/s of four bytes.
    assert_eq!(s.data_rate.raw_bytes_per_s, 10240.0);
    assert!((s.data_rate.model_bytes_per_s - 3.6).abs() < 1e-12);
    for f in ["hi.csv", "rul.csv", "summary.json", "hi.svg", "rul.svg"] {
        let text = std::fs::read_to_string(dir.join(f)).unwrap();
        assert!(text.len() > 100, "{f}");
    }
    let leftovers: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().ends_with(".tmp"))
        .collect();
    assert!(leftovers.is_empty());
    let hi_rows = std::fs::read_to_string(dir.join("hi.csv"))
        .unwrap()
        .lines()
        .count();
    assert_eq!(hi_rows, 516);
    let _ = std::fs::remove_dir_all(out);
}

#[test]
fn excerpt_parses_to_the_file_values() {
    let path = data("excerpt_Bearing1_2_first40.csv");
    let record = load_bearing(&path).unwrap();
    assert_eq!(record.snapshots.len(), 40);
    assert_eq!(record.snapshots[39].t_s, 390.0);
    let text = std::fs::read_to_string(&path).unwrap();
    let row3: Vec<f64> = text
        .lines()
        .nth(3)
        .unwrap()
        .split(',')
        .map(|f| f.parse().unwrap())
        .collect();
    assert_eq!(record.snapshots[2].horizontal[17], row3[2 + 17]);
    assert_eq!(record.snapshots[2].vertical[255], row3[2 + 256 + 255]);
}

fn parse_error_position(err: EdgeCloudError) -> (usize, usize, String) {
    assert_eq!(err.exit_code(), 2, "{err}");
    match err {
        EdgeCloudError::Parse {
            line,
            column,
            message,
            ..
        } => (line, column, message),
        other => panic!("expected a parse error, got {other}"),
    }
}

#[test]
fn truncated_and_malformed_files_report_line_and_column() {
    let text = std::fs::read_to_string(data("excerpt_Bearing1_2_first40.csv")).unwrap();
    let path = Path::new("bad.csv");
    // Truncated in the middle of the last row.
    let cut = text.trim_end()[..text.trim_end().len() - 500]
        .rfind(',')
        .unwrap();
    let truncated = &text[..cut];
    let last_line = truncated.lines().last().unwrap();
    let (line, column, _) = parse_error_position(parse_bearing(path, truncated).unwrap_err());
    assert_eq!(line, 41);
    assert_eq!(column, last_line.chars().count() + 1);
    // A field that is not a number, on line 5: column of that field's first character.
    let lines: Vec<&str> = text.lines().collect();
    let mut fields: Vec<String> = lines[4].split(',').map(String::from).collect();
    fields[7] = "0.1x".into();
    let expected_column = fields[..7].iter().map(|f| f.len() + 1).sum::<usize>() + 1;
    let mut bad: Vec<String> = lines.iter().map(|l| l.to_string()).collect();
    bad[4] = fields.join(",");
    let (line, column, message) =
        parse_error_position(parse_bearing(path, &bad.join("\n")).unwrap_err());
    assert_eq!((line, column), (5, expected_column));
    assert!(message.contains("0.1x"));
    // A wrong header names the field.
    let renamed = text.replacen("h3,", "hx,", 1);
    let (line, column, _) = parse_error_position(parse_bearing(path, &renamed).unwrap_err());
    assert_eq!((line, column), (1, "idx,t_s,h0,h1,h2,".len() + 1));
    // Header only.
    let header_only = lines[0];
    let (line, _, _) = parse_error_position(parse_bearing(path, header_only).unwrap_err());
    assert_eq!(line, 2);
    // The message carries the path too.
    let err = parse_bearing(path, truncated).unwrap_err().to_string();
    assert!(err.starts_with("bad.csv:41:"), "{err}");
}

#[test]
fn config_errors_have_line_and_column() {
    let dir = scratch_dir("cfg");
    let file = dir.join("bad.toml");
    std::fs::write(&file, "seed = 3\npsi = \"ten\"\n").unwrap();
    let err = EdgeCloudConfig::from_toml_file(&file).unwrap_err();
    assert_eq!(err.exit_code(), 2);
    match err {
        EdgeCloudError::Parse { line, column, .. } => assert_eq!((line, column), (2, 7)),
        other => panic!("{other}"),
    }
    std::fs::write(&file, "alpha = -1.0\n").unwrap();
    assert_eq!(
        EdgeCloudConfig::from_toml_file(&file)
            .unwrap_err()
            .exit_code(),
        2
    );
    std::fs::write(&file, "prog_threshold = 0.05\nchannel = \"vertical\"\n").unwrap();
    let ok = EdgeCloudConfig::from_toml_file(&file).unwrap();
    assert_eq!(ok.prog_threshold, 0.05);
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn flat_and_saturated_snapshots_are_held_without_nan() {
    let text = std::fs::read_to_string(data("excerpt_Bearing1_2_first40.csv")).unwrap();
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    let replace_h = |line: &str, f: &dyn Fn(usize, f64) -> f64| -> String {
        let mut fields: Vec<String> = line.split(',').map(String::from).collect();
        for i in 0..256 {
            let v: f64 = fields[2 + i].parse().unwrap();
            fields[2 + i] = format!("{}", f(i, v));
        }
        fields.join(",")
    };
    lines[25] = replace_h(&lines[25], &|_, _| 0.0);
    lines[30] = replace_h(&lines[30], &|_, v| v.clamp(-0.01, 0.01));
    let record = parse_bearing(Path::new("held.csv"), &lines.join("\n")).unwrap();
    let config = EdgeCloudConfig {
        warmup_models: 0,
        reference_models: 5,
        ..EdgeCloudConfig::default()
    };
    let run = analyse_bearing(&record, &config).unwrap();
    assert_eq!(run.summary.edge_rejections, 2);
    assert!(run.series[24].edge_rejected && run.series[29].edge_rejected);
    for r in &run.series {
        for v in [r.hi_nrmse, r.hi_raw, r.hi_smoothed].into_iter().flatten() {
            assert!(v.is_finite());
        }
    }
    // The held model is sent again: the raw HI at the rejected snapshot repeats the last one.
    assert_eq!(run.series[24].hi_raw, run.series[23].hi_raw);
}

#[test]
fn particle_filter_learns_the_exponential_then_polynomial_degradation() {
    // Smoothed HI from Eq. (30) with b = 0.05 /min, change after 60 min, c = 0.02 /min^2,
    // 5 % noise; steps of 10 s. The core SIR filter with the piecewise model must learn b and c
    // and predict the time to T_EoL = 10 in closed form.
    let (b, c, t_change): (f64, f64, f64) = (0.05, 0.02, 60.0);
    let model = PiecewiseHiModel {
        trigger_level: 0.1,
        b_walk_std: 1e-5f64.sqrt(),
        c_walk_std: 1e-5f64.sqrt(),
        relative_noise: 0.1,
        absolute_noise: 0.01,
    };
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(42);
    let config = PfConfig {
        resample_threshold: 0.5,
        lower: Vector2::new(1e-4, 1e-4),
        ..PfConfig::default()
    };
    let mut pf = ParticleFilter::<f64, 2, 1000>::new(Vector2::new(0.0, 0.0), config).unwrap();
    pf.init_with(&mut rng, |_, r| {
        let u1: f64 = uniform01(r);
        let u2: f64 = uniform01(r);
        Vector2::new(
            (1e-3f64.ln() + u1 * (1e3f64).ln()).exp(),
            (1e-3f64.ln() + u2 * (1e4f64).ln()).exp(),
        )
    })
    .unwrap();
    let d = 0.1 * (b * t_change).exp();
    let dt = 10.0 / 60.0;
    let t_eol = t_change + ((10.0 - d) / c).sqrt();
    let mut k = 0;
    let mut last_rul = f64::NAN;
    loop {
        let t = k as f64 * dt;
        if t > t_eol - 1.0 {
            break;
        }
        let input = if t < t_change {
            StageInput {
                stage: DegradationStage::Exponential,
                since_trigger: t,
                since_change: 0.0,
                change_level: 0.0,
            }
        } else {
            StageInput {
                stage: DegradationStage::Polynomial,
                since_trigger: t,
                since_change: t - t_change,
                change_level: d,
            }
        };
        let truth = model.predict(&Vector2::new(b, c), &input);
        let y = normal(&mut rng, truth, 0.05 * truth);
        let u: Vector4<f64> = input.to_input();
        pf.step(&model, &u, Some(Vector1::new(y).as_slice()), dt, &mut rng)
            .unwrap();
        if (t - (t_change - dt)).abs() < 1e-9 {
            let b_hat = pf.mean().x;
            assert!((b_hat - b).abs() < 0.1 * b, "b {b_hat}");
            let rul: f64 = (0..1000)
                .map(|i| model.time_to_threshold(&pf.particles()[i], &input, 1e9) * pf.weight(i))
                .sum();
            assert!(rul.is_finite());
        }
        last_rul = (0..1000)
            .map(|i| model.time_to_threshold(&pf.particles()[i], &input, 10.0) * pf.weight(i))
            .sum::<f64>();
        k += 1;
    }
    let c_hat = pf.mean().y;
    assert!((c_hat - c).abs() < 0.15 * c, "c {c_hat}");
    let t_last = (k - 1) as f64 * dt;
    let true_rul = t_eol - t_last;
    // Within 0.6 min one minute before EoL (the alpha = 0.2 band of a 100-min life is 20 min).
    assert!(
        (last_rul - true_rul).abs() < 0.6,
        "RUL {last_rul} vs {true_rul} min"
    );
}

#[test]
fn edge_in_f32_matches_f64_on_real_vibration() {
    // The firmware runs the edge in f32: its models on real data must match the host's f64
    // models closely enough that the spectra (and so the HI) agree.
    use prognos_core::health::symmetric_itakura_saito;
    use prognos_core::pipeline::edge::{EdgeConfig, EdgeMonitor};
    let record = load_bearing(&data("excerpt_Bearing1_2_first40.csv")).unwrap();
    let mut m64 = EdgeMonitor::<f64, 8, 8, 12, 256>::new(EdgeConfig::default()).unwrap();
    let mut m32 = EdgeMonitor::<f32, 8, 8, 12, 256>::new(EdgeConfig::default()).unwrap();
    let mut compared = 0;
    let mut worst = 0.0f64;
    for snap in &record.snapshots {
        let s32: [f32; 256] = std::array::from_fn(|i| snap.horizontal[i] as f32);
        let a = m64.push_snapshot(&snap.horizontal).unwrap();
        let b = m32.push_snapshot(&s32).unwrap();
        if let (Some(a), Some(b)) = (a, b) {
            let b64 = prognos_core::learn::ar::ArModel::<f64, 8> {
                theta: b.model.theta.map(f64::from),
                noise_variance: f64::from(b.model.noise_variance),
                residual_count: b.model.residual_count,
            };
            let d = symmetric_itakura_saito(&a.model, &b64, 256).unwrap();
            worst = worst.max(d);
            compared += 1;
        }
    }
    assert_eq!(compared, 29);
    // Measured about 4e-12; far below the trigger threshold 0.5 of the HI.
    assert!(worst < 1e-6, "f32 vs f64 spectral distance {worst}");
}

#[test]
fn cli_entry_returns_2_on_a_truncated_file() {
    let dir = scratch_dir("cli");
    let text = std::fs::read_to_string(data("excerpt_Bearing1_2_first40.csv")).unwrap();
    let bad = dir.join("Bearing_truncated.csv");
    std::fs::write(&bad, &text[..text.len() / 2]).unwrap();
    assert_eq!(prognos_sim::edge_cloud::cli_edge_cloud(&bad, None), 2);
    let bad_config = dir.join("c.toml");
    std::fs::write(&bad_config, "nonsense_key = 1\n").unwrap();
    assert_eq!(
        prognos_sim::edge_cloud::cli_edge_cloud(&data("Bearing3_1.csv"), Some(&bad_config)),
        2
    );
    let _ = std::fs::remove_dir_all(dir);
}

/// All six learning bearings against Table 1 (about a minute in the test profile):
/// `cargo test -p prognos-tests --test edge_cloud -- --ignored`.
#[test]
#[ignore]
fn six_bearings_prognostic_horizon_against_table_1() {
    let config = EdgeCloudConfig::default();
    let mut meets = Vec::new();
    for (name, paper_min) in PAPER_TABLE1_PH_MIN {
        let record = load_bearing(&data(&format!("{name}.csv"))).unwrap();
        let run = analyse_bearing(&record, &config).unwrap();
        let ph_min = run.summary.prognostic_horizon_s.unwrap_or(0.0) / 60.0;
        eprintln!("{name}: PH {ph_min:.2} min (paper {paper_min})");
        meets.push((name, ph_min >= paper_min));
    }
    // Measured: every bearing but Bearing3_2 (4.33 min against 20: the change is detected
    // 4.33 min before the end and nothing earlier rises) reaches the paper's PH.
    let failing: Vec<_> = meets
        .iter()
        .filter(|(_, ok)| !ok)
        .map(|(n, _)| *n)
        .collect();
    assert_eq!(failing, ["Bearing3_2"]);
}

/// A model whose spectrum is the reference's times `gain` (a pure level change), so the
/// symmetric Itakura-Saito HI is exactly `(gain + 1/gain)/2 - 1`.
fn gain_model(gain: f64) -> prognos_core::learn::ar::ArModel<f64, 8> {
    prognos_core::learn::ar::ArModel {
        theta: nalgebra::SVector::from([-0.5, 0.2, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]),
        noise_variance: gain,
        residual_count: 3000,
    }
}

/// The gain whose HI is `hi` (the root above 1 of `(g + 1/g)/2 - 1 = hi`).
fn gain_for_hi(hi: f64) -> f64 {
    let s = 1.0 + hi;
    s + (s * s - 1.0).sqrt()
}

/// RUL spread (p95 / p05) right after the change to the polynomial stage on a synthetic HI:
/// 100 min of noisy exponential growth from the trigger (10 % log-normal noise, seeded),
/// then a jump.
fn rul_spread_after_change(redraw: bool) -> f64 {
    use prognos_sim::edge_cloud::cloud::CloudPrognoser;
    let config = EdgeCloudConfig {
        redraw_c_at_change: redraw,
        ..EdgeCloudConfig::default()
    };
    let mut cloud = CloudPrognoser::new(&config).unwrap();
    let mut t = 0.0;
    for _ in 0..config.reference_models {
        cloud.on_model(t, &gain_model(1.0)).unwrap();
        t += 10.0;
    }
    let b = 0.015; // 1/min
    let start = t;
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(7);
    for _ in 0..600 {
        let noise = normal(&mut rng, 0.0f64, 0.1).exp();
        let hi = config.prog_threshold * (b * (t - start) / 60.0).exp() * noise;
        let step = cloud.on_model(t, &gain_model(gain_for_hi(hi))).unwrap();
        assert!(cloud.change_s().is_none(), "{t}: {step:?}");
        t += 10.0;
    }
    let last = config.prog_threshold * (b * (t - start) / 60.0).exp();
    let step = cloud
        .on_model(
            t,
            &gain_model(gain_for_hi(
                last + 3.0 * config.smoothing_window as f64 * config.diff_threshold,
            )),
        )
        .unwrap();
    assert_eq!(cloud.change_s(), Some(t));
    let rul = step.rul.unwrap();
    rul.p95_s / rul.p05_s.max(1e-9)
}

#[test]
fn c_is_drawn_afresh_from_its_prior_at_the_change() {
    // Over four decades of the c prior the time to T_EoL (sqrt of 1/c) spans two; without the
    // redraw the resampling on b in the exponential stage has left a few c values.
    let fresh = rul_spread_after_change(true);
    let thinned = rul_spread_after_change(false);
    eprintln!("p95/p05 of the RUL after the change: redrawn {fresh:.2}, thinned {thinned:.2}");
    assert!(fresh > 10.0, "{fresh}");
    assert!(fresh > 2.0 * thinned, "{fresh} vs {thinned}");
}
