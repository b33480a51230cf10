//! `pipeline::Scooter` (f32, AEUKF) at 50 Hz over experiment 1, on QEMU mps2-an386. Prints
//! per-sample instruction counts of the whole pipeline (driver read + conversion + step), the
//! stack high-water mark and the RUL predictions; exits with a semihosting status.
#![no_std]
#![no_main]

use cortex_m_rt::{ExceptionFrame, entry, exception};
use prognos_core::pipeline::Scooter;
use prognos_core::pipeline::scooter::ScooterReport;
use prognos_core::prognose::sequential::Outcome;
use prognos_firmware::devices::{ScooterDriver, ScooterFrontEnd};
use prognos_firmware::measure::{self, InstructionCounter, StepStats};
use prognos_firmware::scenario::scooter::{self, ScooterPlant};
use prognos_firmware::{fail, say};
use static_cell::StaticCell;

static PIPELINE: StaticCell<Scooter<f32>> = StaticCell::new();
static PLANT: StaticCell<ScooterPlant<f32>> = StaticCell::new();

#[entry]
fn main() -> ! {
    let Some(peripherals) = cortex_m::Peripherals::take() else {
        fail("peripherals", 0)
    };
    let counter = InstructionCounter::new(peripherals.SYST);
    let (pipeline, plant) = init();
    let mut driver = ScooterDriver::new(ScooterFrontEnd::scooter());
    let init_stack = measure::stack_high_water();
    measure::repaint_stack();
    say!("firmware=scooter samples={}", scooter::STEPS);

    let (mut steps, mut plant_cost) = (StepStats::default(), StepStats::default());
    let (mut first_rul, mut last_rul, mut predictions) = (f32::NAN, f32::NAN, 0u32);
    for _ in 0..scooter::STEPS {
        let start = counter.now();
        plant.advance();
        let counts = plant.sample();
        driver.bus_mut().latch_counts(&counts);
        let k = plant.index();
        plant_cost.record(k, counter.since(start));

        let start = counter.now();
        let report = controller_step(&mut driver, pipeline, k, plant.input());
        steps.record(k, counter.since(start));
        if let Some(Outcome::Predicted(segment)) = report.outcome {
            let rul = segment.rul();
            say!(
                "prediction usage={} t_s={} rul_s={}",
                segment.usage,
                segment.t_id,
                rul
            );
            if predictions == 0 {
                first_rul = rul;
            }
            last_rul = rul;
            predictions += 1;
        }
    }
    let stack = measure::stack_high_water();
    say!(
        "step_worst_instructions={} worst_step={} step_mean_instructions={}",
        steps.worst,
        steps.worst_step,
        steps.mean()
    );
    say!("plant_mean_instructions={}", plant_cost.mean());
    say!(
        "stack_high_water_bytes={} init_stack_high_water_bytes={}",
        stack,
        init_stack
    );
    say!(
        "predictions={} rul_usage1_s={} rul_s={}",
        predictions,
        first_rul,
        last_rul
    );
    let pass = predictions >= 2 && last_rul.is_finite() && last_rul > 0.0;
    say!("result={}", if pass { "pass" } else { "fail" });
    measure::exit(pass)
}

/// What the controller does per sample: read the front-end over I2C, convert, step. Not
/// inlined, so that `main`'s frame (live during start-up) does not hold the step's
/// temporaries.
#[inline(never)]
fn controller_step(
    driver: &mut ScooterDriver<ScooterFrontEnd>,
    pipeline: &mut Scooter<f32>,
    k: u32,
    u: f32,
) -> ScooterReport<f32> {
    let Ok(raw) = driver.read() else {
        fail("sensor read", k)
    };
    let y = scooter::convert::<f32>(&raw);
    match scooter::step(pipeline, k, u, &y) {
        Ok(report) => report,
        Err(_) => fail("pipeline step", k),
    }
}

/// Builds the statics. Not inlined: its frame (the constructors' temporaries) is released
/// before the loop.
#[inline(never)]
fn init() -> (&'static mut Scooter<f32>, &'static mut ScooterPlant<f32>) {
    // `init_with` lets the constructor write straight into the static.
    let pipeline = PIPELINE.init_with(|| match scooter::pipeline::<f32>() {
        Ok(p) => p,
        Err(_) => fail("pipeline init", 0),
    });
    (pipeline, PLANT.init_with(ScooterPlant::new))
}

#[exception]
unsafe fn HardFault(_frame: &ExceptionFrame) -> ! {
    say!("FAIL hard fault");
    measure::exit(false)
}
