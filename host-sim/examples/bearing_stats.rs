use prognos_sim::bearing::trial::TrialGenerator;
fn main() {
    let g = TrialGenerator::new();
    println!("cal {:?}", g.extractor.calibration);
    for seed in 0..12 {
        let t = g.trial(seed);
        let n = t.eol;
        let res: Vec<f64> = t
            .feature
            .iter()
            .zip(&t.pitting)
            .map(|(f, a)| f - ((a * a - 25.0) / (4900.0 - 25.0) * 0.999 + 0.001))
            .collect();
        let sd = (res.iter().take(n).map(|r| r * r).sum::<f64>() / n as f64).sqrt();
        println!(
            "seed {seed} eol {n} q {:.2} rate {:.4} feat_rms_err {:.3} f[0..5] {:?}",
            t.params.progressivity,
            t.params.rate,
            sd,
            &t.feature[..5]
                .iter()
                .map(|v| (v * 1000.0).round() / 1000.0)
                .collect::<Vec<_>>()
        );
    }
}
