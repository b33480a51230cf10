//! `pipeline::ReactionWheel` (f32, N = 128 temperature particles, M = 128 loss particles) at
//! 20 Hz over the wheel scenario, on QEMU mps2-an386. Prints per-sample instruction counts of
//! the whole pipeline (driver read + conversion + step), the stack high-water mark and the
//! final RUL; exits with a semihosting status.
#![no_std]
#![no_main]

use cortex_m_rt::{ExceptionFrame, entry, exception};
use prognos_core::pipeline::ReactionWheel;
use prognos_firmware::devices::{WheelDriver, WheelFrontEnd};
use prognos_firmware::measure::{self, InstructionCounter, StepStats};
use prognos_firmware::scenario::wheel::{self, M, N, RulBuffers, WheelPlant};
use prognos_firmware::{fail, say};
use static_cell::{ConstStaticCell, StaticCell};

type Pipeline = ReactionWheel<f32, N, M>;

// An all-zero constant: the pipeline sits in .bss and is configured in place by `reset`, so
// its ~8 KiB of filters never pass through the stack.
static PIPELINE: ConstStaticCell<Pipeline> = ConstStaticCell::new(Pipeline::UNSET);
static PLANT: StaticCell<WheelPlant<f32>> = StaticCell::new();
static RUL_BUFFERS: StaticCell<RulBuffers<f32>> = StaticCell::new();

#[entry]
fn main() -> ! {
    let Some(peripherals) = cortex_m::Peripherals::take() else {
        fail("peripherals", 0)
    };
    let counter = InstructionCounter::new(peripherals.SYST);
    let mut rng = wheel::filter_rng();
    let (pipeline, plant, buffers) = init(&mut rng);
    let mut driver = WheelDriver::new(WheelFrontEnd::wheel());
    let init_stack = measure::stack_high_water();
    measure::repaint_stack();
    say!(
        "firmware=reaction_wheel particles={} loss_particles={} samples={}",
        N as u32,
        M as u32,
        wheel::STEPS + 1
    );

    let (mut steps, mut closing, mut plant_cost) = (
        StepStats::default(),
        StepStats::default(),
        StepStats::default(),
    );
    for k in 0..=wheel::STEPS {
        let start = counter.now();
        if k > 0 {
            plant.advance();
        }
        let counts = plant.sample();
        driver.bus_mut().latch_counts(&counts);
        plant_cost.record(k, counter.since(start));

        // The measured part: what the controller does per sample.
        let start = counter.now();
        let closes_interval = controller_step(&mut driver, pipeline, k, plant.command(), &mut rng);
        let cost = counter.since(start);
        steps.record(k, cost);
        if closes_interval {
            closing.record(k, cost);
        }
    }
    let step_stack = measure::stack_high_water();
    measure::repaint_stack();
    let start = counter.now();
    let Ok(rul) = wheel::predict_rul(pipeline, buffers, &mut rng) else {
        fail("rul prediction", wheel::STEPS)
    };
    let rul_cost = counter.since(start);
    let (b, beta) = pipeline.loss_parameters();
    let rul_stack = measure::stack_high_water();

    say!(
        "step_worst_instructions={} worst_step={} step_mean_instructions={}",
        steps.worst,
        steps.worst_step,
        steps.mean()
    );
    say!(
        "interval_close_worst_instructions={} intervals={}",
        closing.worst,
        closing.count
    );
    say!("plant_mean_instructions={}", plant_cost.mean());
    say!("rul_prediction_instructions={}", rul_cost);
    say!(
        "stack_high_water_bytes={} init_stack_high_water_bytes={} rul_stack_high_water_bytes={}",
        step_stack,
        init_stack,
        rul_stack
    );
    say!("b_degc={} beta_ul_per_s={}", b, beta * 1.0e3);
    say!(
        "rul_s={} rul_p05_s={} rul_p95_s={} true_rul_s={}",
        rul.median,
        rul.p05,
        rul.p95,
        plant.true_rul() as f32
    );
    let pass = rul.median.is_finite() && rul.median > 0.0;
    say!("result={}", if pass { "pass" } else { "fail" });
    measure::exit(pass)
}

/// What the controller does per sample: read the front-end over I2C, convert, step; returns
/// whether a gauge reading closed an interval. Not inlined, so that `main`'s frame (live
/// during start-up) does not hold the step's temporaries.
#[inline(never)]
fn controller_step(
    driver: &mut WheelDriver<WheelFrontEnd>,
    pipeline: &mut Pipeline,
    k: u32,
    command: f32,
    rng: &mut rand_xoshiro::Xoshiro256PlusPlus,
) -> bool {
    let Ok(raw) = driver.read() else {
        fail("sensor read", k)
    };
    let y = wheel::convert::<f32>(&raw);
    if wheel::step(pipeline, k, command, &y, rng).is_err() {
        fail("pipeline step", k);
    }
    y.consumption.is_some()
}

/// Builds the statics. Not inlined: its frame (the constructors' temporaries) is released
/// before the loop.
#[inline(never)]
fn init(
    rng: &mut rand_xoshiro::Xoshiro256PlusPlus,
) -> (
    &'static mut Pipeline,
    &'static mut WheelPlant<f32>,
    &'static mut RulBuffers<f32>,
) {
    let Ok(config) = wheel::config::<f32>() else {
        fail("config", 0)
    };
    let pipeline = PIPELINE.take();
    if pipeline.reset(config, rng).is_err() {
        fail("pipeline init", 0)
    }
    (
        pipeline,
        PLANT.init_with(WheelPlant::new),
        RUL_BUFFERS.init_with(RulBuffers::new),
    )
}

#[exception]
unsafe fn HardFault(_frame: &ExceptionFrame) -> ! {
    say!("FAIL hard fault");
    measure::exit(false)
}
