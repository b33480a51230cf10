//! Our UKF against filterpy's `UnscentedKalmanFilter` + `MerweScaledSigmaPoints` on a
//! nonlinear model (reference rows written by tests/reference/make_filterpy_reference.py).

use nalgebra::{Matrix2, Matrix4, Vector2, Vector4};
use prognos_core::filter::ukf::{SigmaParams, Ukf};
use prognos_tests::drag_radar::DragRadar;
use prognos_tests::reference::{Table, read_settings, reference_path};
use std::collections::HashMap;

fn setting(s: &HashMap<String, f64>, name: &str) -> f64 {
    *s.get(name)
        .unwrap_or_else(|| panic!("setup file lacks {name}"))
}

fn matrix<const N: usize>(s: &HashMap<String, f64>, name: &str) -> nalgebra::SMatrix<f64, N, N> {
    nalgebra::SMatrix::from_fn(|i, j| setting(s, &format!("{name}_{i}{j}")))
}

/// Largest |ours - theirs| / max(1, |theirs|) over a row's named columns.
fn worst(table: &Table, row: &[f64], prefix: &str, ours: &[f64], labels: &[String]) -> f64 {
    ours.iter()
        .zip(labels)
        .map(|(v, label)| {
            let r = row[table.column(&format!("{prefix}{label}"))];
            (v - r).abs() / r.abs().max(1.0)
        })
        .fold(0.0, f64::max)
}

#[test]
fn ukf_matches_filterpy_on_nonlinear_drag_radar_model() {
    let setup = read_settings(&reference_path("filterpy_ukf_setup.csv"));
    let table = Table::read(&reference_path("filterpy_ukf_reference.csv"));
    assert_eq!(table.rows.len(), 100);
    let model = DragRadar {
        drag: setting(&setup, "drag"),
    };
    let params = SigmaParams {
        alpha: setting(&setup, "alpha"),
        beta: setting(&setup, "beta"),
        kappa: setting(&setup, "kappa"),
    };
    let x0 = Vector4::from_fn(|i, _| setting(&setup, &format!("x0_{i}")));
    let p0: Matrix4<f64> = matrix(&setup, "p0");
    let q: Matrix4<f64> = matrix(&setup, "q");
    let r: Matrix2<f64> = matrix(&setup, "r");
    let mut ukf = Ukf::<f64, 4, 9>::new(x0, p0, q, params).unwrap();

    // Column suffixes in nalgebra's column-major order, so they pair with `as_slice()`.
    let x_labels: Vec<String> = (0..4).map(|i| format!("x{i}")).collect();
    let p_labels: Vec<String> = (0..4)
        .flat_map(|j| (0..4).map(move |i| format!("p{i}{j}")))
        .collect();
    let (mut worst_prior, mut worst_post) = (0.0f64, 0.0f64);
    for row in &table.rows {
        let col = |name: &str| row[table.column(name)];
        let u = Vector2::new(col("u0"), col("u1"));
        let z = [col("z0"), col("z1")];
        ukf.predict(&model, &u, col("dt")).unwrap();
        let prior = worst(&table, row, "prior_", ukf.state().as_slice(), &x_labels).max(worst(
            &table,
            row,
            "prior_",
            ukf.covariance().as_slice(),
            &p_labels,
        ));
        let report = ukf.update(&model, &u, &z, &r).unwrap();
        assert!(report.fused);
        let post = worst(&table, row, "", ukf.state().as_slice(), &x_labels).max(worst(
            &table,
            row,
            "",
            ukf.covariance().as_slice(),
            &p_labels,
        ));
        assert!(
            prior < 1e-9 && post < 1e-9,
            "step {}: prior differs by {prior:e}, posterior by {post:e}",
            col("k")
        );
        worst_prior = worst_prior.max(prior);
        worst_post = worst_post.max(post);
    }
    println!(
        "filterpy agreement over 100 steps: prior {worst_prior:.3e}, posterior {worst_post:.3e}"
    );
}
