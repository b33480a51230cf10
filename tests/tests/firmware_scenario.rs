//! Host reference runs of the firmware scenarios (`firmware-example/src/scenario/`, included
//! here by path so that plant, sensors, schedule and seeds are the firmware's own). The f64
//! runs are what `firmware-example/run-qemu.sh` compares the QEMU f32 results against; it
//! reads the `firmware-reference` lines these tests print.

// The firmware uses parts of these modules that the host runs do not.
#[allow(dead_code)]
#[path = "../../firmware-example/src/scenario/scooter.rs"]
mod scooter;
#[allow(dead_code)]
#[path = "../../firmware-example/src/scenario/wheel.rs"]
mod wheel;

use prognos_core::Real;
use prognos_core::pipeline::ReactionWheel;
use prognos_core::prognose::sequential::Outcome;

/// Final RUL median (s), the true RUL (s) and the two-step estimates `(b, beta)`.
fn run_wheel<T: Real>() -> (f64, f64, (f64, f64)) {
    let mut rng = wheel::filter_rng();
    let mut pipeline =
        ReactionWheel::<T, { wheel::N }, { wheel::M }>::new(wheel::config().unwrap(), &mut rng)
            .unwrap();
    let mut plant = wheel::WheelPlant::<T>::new();
    for k in 0..=wheel::STEPS {
        if k > 0 {
            plant.advance();
        }
        let y = wheel::convert::<T>(&plant.sample());
        wheel::step(&mut pipeline, k, plant.command(), &y, &mut rng).unwrap();
    }
    let mut buffers = wheel::RulBuffers::<T>::new();
    let summary = wheel::predict_rul(&pipeline, &mut buffers, &mut rng).unwrap();
    let (b, beta) = pipeline.loss_parameters();
    (
        summary.median.as_f64(),
        plant.true_rul(),
        (b.as_f64(), beta.as_f64()),
    )
}

/// RUL (s) predicted for usage 1 and for the last prediction of the run.
fn run_scooter<T: Real>() -> (f64, f64) {
    let mut pipeline = scooter::pipeline::<T>().unwrap();
    let mut plant = scooter::ScooterPlant::<T>::new();
    let mut ruls = Vec::new();
    for _ in 0..scooter::STEPS {
        plant.advance();
        let y = scooter::convert::<T>(&plant.sample());
        let report = scooter::step(&mut pipeline, plant.index(), plant.input(), &y).unwrap();
        if let Some(Outcome::Predicted(segment)) = report.outcome {
            ruls.push(segment.rul().as_f64());
        }
    }
    assert!(ruls.len() >= 2, "predictions {ruls:?}");
    (ruls[0], ruls[ruls.len() - 1])
}

#[test]
fn wheel_scenario_predicts_the_true_rul_in_f64_and_f32() {
    let (rul, truth, (b, beta)) = run_wheel::<f64>();
    println!(
        "firmware-reference wheel rul_s={rul:.3} true_rul_s={truth:.3} b={b:.3} beta={beta:.4e}"
    );
    let (rul32, _, _) = run_wheel::<f32>();
    println!("firmware-reference wheel host_f32_rul_s={rul32:.3}");
    assert!(truth > 1000.0 && truth < 2000.0, "true RUL {truth}");
    assert!((rul - truth).abs() / truth < 0.05, "RUL {rul} vs {truth}");
    assert!((rul32 - rul).abs() / rul < 0.02, "f32 {rul32} vs f64 {rul}");
}

#[test]
fn scooter_scenario_predicts_both_usages_in_f64_and_f32() {
    let (first, last) = run_scooter::<f64>();
    println!("firmware-reference scooter rul_usage1_s={first:.4} rul_s={last:.4}");
    let (first32, last32) = run_scooter::<f32>();
    println!(
        "firmware-reference scooter host_f32_rul_usage1_s={first32:.4} host_f32_rul_s={last32:.4}"
    );
    assert!(first > 0.0 && last > 0.0);
    assert!((first32 - first).abs() / first < 0.02);
    assert!((last32 - last).abs() / last < 0.02);
}
