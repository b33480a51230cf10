//! Instruction-count form of the filter overhead ratio, for a machine too loaded for clean
//! wall-clock numbers: `bench/overhead_instructions.sh` runs this under
//! `valgrind --tool=callgrind --toggle-collect=*counted_window*`, so only the steps inside
//! [`counted_window`] are counted (not the set-up).
//!
//! `pf_overhead <valve|wheel> <pf|model|model_ll>`: one window of the criterion workload
//! (`prognos_tests::workloads`), three times over from the same start, with the particle
//! filter step, the model's `sample_step` alone, or `sample_step` plus `log_likelihood`.

use prognos_core::model::Stochastic;
use prognos_sim::valve::SAMPLE_DT;
use prognos_tests::workloads::{
    WHEEL_DT, WINDOW, valve_case, valve_filter, wheel_case, wheel_filter,
};
use rand_core::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;
use std::hint::black_box;

/// Particle counts of the check (those of the criterion overhead rows).
const VALVE_N: usize = 512;
const WHEEL_N: usize = 128;
const REPEATS: usize = 3;

/// The counted region: one window of steps (the restart between windows is outside).
#[inline(never)]
fn counted_window(mut body: impl FnMut(usize)) {
    for k in 0..WINDOW {
        body(k);
    }
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (system, what) = match args.as_slice() {
        [s, w] => (s.as_str(), w.as_str()),
        _ => panic!("usage: pf_overhead <valve|wheel> <pf|model|model_ll>"),
    };
    match system {
        "valve" => {
            let case = valve_case();
            let fresh = valve_filter::<VALVE_N>(&case.model);
            for _ in 0..REPEATS {
                let mut pf = fresh.clone();
                let mut particles = Box::new(*fresh.particles());
                let mut rng = Xoshiro256PlusPlus::seed_from_u64(1);
                counted_window(|k| {
                    let (u, y, n) = &case.samples[k];
                    match what {
                        "pf" => {
                            let _ = black_box(pf.step(
                                &case.model,
                                u,
                                Some(&y[..*n]),
                                SAMPLE_DT,
                                &mut rng,
                            ));
                        }
                        _ => {
                            let mut sum = 0.0;
                            for p in particles.iter_mut() {
                                *p = case.model.sample_step(p, u, SAMPLE_DT, &mut rng);
                                if what == "model_ll" {
                                    sum += case.model.log_likelihood(p, u, &y[..*n]);
                                }
                            }
                            black_box(sum);
                        }
                    }
                });
                black_box((&pf, &particles));
            }
        }
        "wheel" => {
            let case = wheel_case();
            let fresh = wheel_filter::<WHEEL_N>(&case.model);
            for _ in 0..REPEATS {
                let mut pf = fresh.clone();
                let mut particles = Box::new(*fresh.particles());
                let mut rng = Xoshiro256PlusPlus::seed_from_u64(1);
                counted_window(|k| {
                    let (u, y) = &case.samples[k];
                    match what {
                        "pf" => {
                            let _ = black_box(pf.step(
                                &case.model,
                                u,
                                Some(&y[..]),
                                WHEEL_DT,
                                &mut rng,
                            ));
                        }
                        _ => {
                            let mut sum = 0.0;
                            for p in particles.iter_mut() {
                                *p = case.model.sample_step(p, u, WHEEL_DT, &mut rng);
                                if what == "model_ll" {
                                    sum += case.model.log_likelihood(p, u, &y[..]);
                                }
                            }
                            black_box(sum);
                        }
                    }
                });
                black_box((&pf, &particles));
            }
        }
        other => panic!("unknown system {other}"),
    }
}
