//! Per-step cost of the core estimators (criterion). Each benchmark times single filter steps
//! over a fixed window of recorded samples and restarts the filter from the same saved state
//! at the start of every window (the restart is not timed), so every benchmark sees the same
//! mix of valve motion and rest, bit for bit.
//!
//! Run (short measurement times: the machine is shared):
//! `cargo bench -p prognos-tests --bench filters -- --warm-up-time 1 --measurement-time 2`
//! then `cargo run --release -p prognos-sim -- bench-report` for the table and the plots.
//!
//! Groups: `pf_valve/N` and `model_valve/N` (the same N particles through the model only:
//! the denominator of the overhead ratio), `pf_wheel/N` and `model_wheel/N`, `pipeline`
//! (the reaction-wheel and scooter pipelines per sample), `ukf`, `aukf`, `imm/K`,
//! `gp_predict/M`, `oriv/N`.

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use nalgebra::{DMatrix, DVector, Matrix1, SVector, Vector1, Vector2};
use prognos_core::filter::adaptive_ukf::{Adaptation, AdaptiveUkf};
use prognos_core::filter::imm::Imm;
use prognos_core::filter::ukf::{SigmaParams, Ukf};
use prognos_core::learn::ar::{Oriv, OrivConfig};
use prognos_core::learn::gp::{GaussianProcess, GpTransition, GpUkf};
use prognos_core::model::{Model, Stochastic};
use prognos_core::pipeline::reaction_wheel::ReactionWheelConfig;
use prognos_core::pipeline::scooter::ScooterConfig;
use prognos_core::pipeline::{ReactionWheel, Scooter};
use prognos_core::plants::scooter::ScooterModel;
use prognos_core::random::standard_normal;
use prognos_sim::plants::scooter::{Profile, ScooterPlant, SensorNoise as ScooterNoise};
use prognos_sim::valve::SAMPLE_DT;
use prognos_tests::drag_radar::DragRadar;
use rand_core::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;
use std::hint::black_box;
use std::time::{Duration, Instant};

use prognos_tests::workloads::{
    ValveCase, WHEEL_DT, WINDOW, WheelCase, valve_case, valve_filter, wheel_case, wheel_filter,
};

/// Steps a workload through a fixed window of samples, restarting it from the saved state
/// at the end of every window. The position in the window persists between criterion's
/// calls, so every sample of the window is timed equally often; restarts are not timed.
struct Cycler<S> {
    fresh: S,
    current: S,
    position: usize,
}

impl<S: Clone> Cycler<S> {
    fn new(fresh: &S) -> Self {
        Self {
            current: fresh.clone(),
            fresh: fresh.clone(),
            position: 0,
        }
    }

    /// Times `iters` steps of `step(state, k)`, `k` the sample index within the window.
    fn run(&mut self, iters: u64, mut step: impl FnMut(&mut S, usize)) -> Duration {
        let mut total = Duration::ZERO;
        let mut done = 0u64;
        while done < iters {
            if self.position == WINDOW {
                self.current = self.fresh.clone();
                self.position = 0;
            }
            let n = (iters - done).min((WINDOW - self.position) as u64) as usize;
            let start = Instant::now();
            for k in self.position..self.position + n {
                step(&mut self.current, k);
            }
            total += start.elapsed();
            black_box(&self.current);
            self.position += n;
            done += n as u64;
        }
        total
    }
}

fn bench_pf_valve_at<const N: usize>(c: &mut Criterion, case: &ValveCase) {
    let fresh = (
        valve_filter::<N>(&case.model),
        Xoshiro256PlusPlus::seed_from_u64(1),
    );
    let mut cycler = Cycler::new(&fresh);
    c.benchmark_group("pf_valve")
        .bench_function(BenchmarkId::from_parameter(N), |b| {
            b.iter_custom(|iters| {
                cycler.run(iters, |(pf, rng), k| {
                    let (u, y, n) = &case.samples[k];
                    let _ = black_box(pf.step(&case.model, u, Some(&y[..*n]), SAMPLE_DT, rng));
                })
            })
        });
}

/// The model alone over the same particles and samples: `sample_step` of every particle (the
/// strict denominator) and, separately, `sample_step` plus `log_likelihood`.
fn bench_model_valve_at<const N: usize>(c: &mut Criterion, case: &ValveCase) {
    let pf = valve_filter::<N>(&case.model);
    let fresh = (
        Box::new(*pf.particles()),
        Xoshiro256PlusPlus::seed_from_u64(1),
    );
    let mut group = c.benchmark_group("model_valve");
    let mut cycler = Cycler::new(&fresh);
    group.bench_function(BenchmarkId::from_parameter(N), |b| {
        b.iter_custom(|iters| {
            cycler.run(iters, |(particles, rng), k| {
                let (u, _, _) = &case.samples[k];
                for p in particles.iter_mut() {
                    *p = case.model.sample_step(p, u, SAMPLE_DT, rng);
                }
            })
        })
    });
    drop(group);
    let mut cycler = Cycler::new(&fresh);
    c.benchmark_group("model_ll_valve")
        .bench_function(BenchmarkId::from_parameter(N), |b| {
            b.iter_custom(|iters| {
                cycler.run(iters, |(particles, rng), k| {
                    let (u, y, n) = &case.samples[k];
                    let mut sum = 0.0;
                    for p in particles.iter_mut() {
                        *p = case.model.sample_step(p, u, SAMPLE_DT, rng);
                        sum += case.model.log_likelihood(p, u, &y[..*n]);
                    }
                    black_box(sum);
                })
            })
        });
}

fn bench_valve(c: &mut Criterion) {
    let case = valve_case();
    bench_pf_valve_at::<64>(c, &case);
    bench_pf_valve_at::<128>(c, &case);
    bench_pf_valve_at::<256>(c, &case);
    bench_pf_valve_at::<512>(c, &case);
    bench_pf_valve_at::<1024>(c, &case);
    bench_pf_valve_at::<2048>(c, &case);
    bench_pf_valve_at::<4096>(c, &case);
    bench_model_valve_at::<64>(c, &case);
    bench_model_valve_at::<512>(c, &case);
    bench_model_valve_at::<4096>(c, &case);
}

fn bench_wheel_at<const N: usize>(c: &mut Criterion, case: &WheelCase) {
    let fresh = (
        wheel_filter::<N>(&case.model),
        Xoshiro256PlusPlus::seed_from_u64(1),
    );
    let mut cycler = Cycler::new(&fresh);
    c.benchmark_group("pf_wheel")
        .bench_function(BenchmarkId::from_parameter(N), |b| {
            b.iter_custom(|iters| {
                cycler.run(iters, |(pf, rng), k| {
                    let (u, y) = &case.samples[k];
                    let _ = black_box(pf.step(&case.model, u, Some(&y[..]), WHEEL_DT, rng));
                })
            })
        });
    let fresh = (
        Box::new(*wheel_filter::<N>(&case.model).particles()),
        Xoshiro256PlusPlus::seed_from_u64(1),
    );
    let mut cycler = Cycler::new(&fresh);
    c.benchmark_group("model_wheel")
        .bench_function(BenchmarkId::from_parameter(N), |b| {
            b.iter_custom(|iters| {
                cycler.run(iters, |(particles, rng), k| {
                    let (u, _) = &case.samples[k];
                    for p in particles.iter_mut() {
                        *p = case.model.sample_step(p, u, WHEEL_DT, rng);
                    }
                })
            })
        });
    let mut cycler = Cycler::new(&fresh);
    c.benchmark_group("model_ll_wheel")
        .bench_function(BenchmarkId::from_parameter(N), |b| {
            b.iter_custom(|iters| {
                cycler.run(iters, |(particles, rng), k| {
                    let (u, y) = &case.samples[k];
                    let mut sum = 0.0;
                    for p in particles.iter_mut() {
                        *p = case.model.sample_step(p, u, WHEEL_DT, rng);
                        sum += case.model.log_likelihood(p, u, &y[..]);
                    }
                    black_box(sum);
                })
            })
        });
}

fn bench_wheel(c: &mut Criterion) {
    let case = wheel_case();
    bench_wheel_at::<128>(c, &case);
    bench_wheel_at::<512>(c, &case);
}

/// Scooter truth samples (experiment 1 profile) at the pipeline's 50 Hz.
fn scooter_samples() -> Vec<(f64, [f64; 3])> {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(4);
    let mut plant = ScooterPlant::new(Profile::EXPERIMENT1, ScooterNoise::default(), &mut rng);
    // Past the start-up transient, so that the window is a driving segment.
    for _ in 0..500 {
        plant.sample(prognos_sim::scooter::DT, &mut rng);
    }
    (0..WINDOW)
        .map(|_| {
            let (u, y) = plant.sample(prognos_sim::scooter::DT, &mut rng);
            (u, [y.x, y.y, y.z])
        })
        .collect()
}

fn bench_pipelines(c: &mut Criterion) {
    let mut group = c.benchmark_group("pipeline");
    let wheel = wheel_case();
    let config = ReactionWheelConfig::<f64>::new(0.03, 0.3).expect("valid noise");
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(2);
    let fresh = (
        Box::new(ReactionWheel::<f64, 128, 64>::new(config, &mut rng).expect("valid config")),
        Xoshiro256PlusPlus::seed_from_u64(1),
    );
    let mut cycler = Cycler::new(&fresh);
    group.bench_function("reaction_wheel_n128", |b| {
        b.iter_custom(|iters| {
            cycler.run(iters, |(pipe, rng), k| {
                let (u, y) = &wheel.samples[k];
                let _ = black_box(pipe.step(u.y, u.x, Some(&y[..]), rng));
            })
        })
    });
    let samples = scooter_samples();
    let t0 = 500.0 * prognos_sim::scooter::DT;
    let fresh = Box::new(
        Scooter::<f64>::new(t0, ScooterConfig::new(Adaptation::Enhanced)).expect("valid config"),
    );
    let mut cycler = Cycler::new(&fresh);
    group.bench_function("scooter", |b| {
        b.iter_custom(|iters| {
            cycler.run(iters, |pipe, k| {
                let (u, y) = &samples[k];
                let t = t0 + (k + 1) as f64 * prognos_sim::scooter::DT;
                let _ = black_box(pipe.step(t, *u, y));
            })
        })
    });
}

/// filterpy's drag-radar scenario (`tests/reference`) and the scooter's 9-state UKF, plain
/// and adaptive.
fn bench_ukf(c: &mut Criterion) {
    let radar = DragRadar { drag: 0.02 };
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(8);
    let mut truth = nalgebra::Vector4::new(100.0, 50.0, -2.0, 1.0);
    let u = Vector2::new(0.1, -0.05);
    let radar_samples: Vec<[f64; 2]> = (0..WINDOW)
        .map(|_| {
            truth = radar.step(&truth, &u, 0.5);
            let range = (truth[0] * truth[0] + truth[1] * truth[1]).sqrt();
            let bearing = truth[1].atan2(truth[0]);
            [
                range + 0.5 * standard_normal::<f64, _>(&mut rng),
                bearing + 0.01 * standard_normal::<f64, _>(&mut rng),
            ]
        })
        .collect();
    let fresh = Ukf::<f64, 4, 9>::new(
        nalgebra::Vector4::new(100.0, 50.0, -2.0, 1.0),
        nalgebra::Matrix4::from_diagonal(&nalgebra::Vector4::new(4.0, 4.0, 1.0, 1.0)),
        nalgebra::Matrix4::from_diagonal(&nalgebra::Vector4::new(0.01, 0.01, 0.01, 0.01)),
        SigmaParams {
            alpha: 0.5,
            beta: 2.0,
            kappa: 1.0,
        },
    )
    .expect("valid filter");
    let r = nalgebra::Matrix2::new(0.25, 0.0, 0.0, 1e-4);
    let mut group = c.benchmark_group("ukf");
    let mut cycler = Cycler::new(&fresh);
    group.bench_function("drag_radar_nx4", |b| {
        b.iter_custom(|iters| {
            cycler.run(iters, |ukf, k| {
                let _ = ukf.predict(&radar, &u, 0.5);
                let _ = black_box(ukf.update(&radar, &u, &radar_samples[k], &r));
            })
        })
    });
    drop(group);

    let samples = scooter_samples();
    let model = ScooterModel::<f64>::nominal();
    let mut group = c.benchmark_group("aukf");
    for (name, mode) in [
        ("ukf_scooter_nx9", Adaptation::None),
        ("aukf_scooter_nx9", Adaptation::CovarianceMatching),
        ("aeukf_scooter_nx9", Adaptation::Enhanced),
    ] {
        let config = ScooterConfig::<f64>::new(mode);
        let ukf = Ukf::new(
            model.nominal_state(),
            nalgebra::SMatrix::from_diagonal(&config.p0),
            nalgebra::SMatrix::from_diagonal(&config.q0),
            SigmaParams::default(),
        )
        .expect("valid filter");
        let mut adaptive = config.adaptive;
        adaptive.mode = mode;
        let fresh = AdaptiveUkf::<f64, 9, 19, 3, 25>::new(
            ukf,
            nalgebra::SMatrix::from_diagonal(&config.r0),
            adaptive,
        )
        .expect("valid filter");
        let mut cycler = Cycler::new(&fresh);
        group.bench_function(name, |b| {
            b.iter_custom(|iters| {
                cycler.run(iters, |f, k| {
                    let (u, y) = &samples[k];
                    // The detector fires on one sample in ten.
                    let enhance = k % 10 == 0;
                    let _ = black_box(f.step(
                        &model,
                        &Vector1::new(*u),
                        y,
                        prognos_sim::scooter::DT,
                        enhance,
                    ));
                })
            })
        });
    }
}

/// A GP trained on a smooth degradation increment `f(x, u)` over `M` grid inputs in
/// `[0, 1]^2`: weights computed with nalgebra's dense Cholesky, as the host trainer does.
fn trained_gp<const M: usize>() -> Box<GaussianProcess<f64, 2, M>> {
    let side = (M as f64).sqrt().ceil() as usize;
    let inputs: Vec<[f64; 2]> = (0..M)
        .map(|i| {
            let (a, b) = (i % side, i / side);
            [a as f64 / side as f64, b as f64 / side as f64]
        })
        .collect();
    let target = |p: &[f64; 2]| 0.01 + 0.02 * p[0] * p[0] + 0.005 * p[1];
    let (lengths, sf2, sn2) = ([0.4, 0.6], 1e-4, 1e-8);
    let kernel = |a: &[f64; 2], b: &[f64; 2]| {
        let q: f64 = (0..2).map(|d| ((a[d] - b[d]) / lengths[d]).powi(2)).sum();
        sf2 * (-0.5 * q).exp()
    };
    let mean = inputs.iter().map(target).sum::<f64>() / M as f64;
    let k = DMatrix::from_fn(M, M, |i, j| {
        kernel(&inputs[i], &inputs[j]) + if i == j { sn2 + 1e-10 } else { 0.0 }
    });
    let chol = k.cholesky().expect("positive definite Gram matrix");
    let y = DVector::from_iterator(M, inputs.iter().map(|p| target(p) - mean));
    let alpha = chol.solve(&y);
    let l = chol.l();
    let mut chol_rows: Box<[[f64; M]; M]> = vec![[0.0; M]; M]
        .into_boxed_slice()
        .try_into()
        .expect("M rows");
    for (i, row) in chol_rows.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = l[(i, j)];
        }
    }
    let inputs: [[f64; 2]; M] = inputs.try_into().expect("M inputs");
    let alpha: [f64; M] = alpha.as_slice().try_into().expect("M weights");
    Box::new(
        GaussianProcess::from_f64(&lengths, sf2, sn2, &inputs, &alpha, &chol_rows, mean)
            .expect("valid GP"),
    )
}

fn bench_gp_at<const M: usize>(c: &mut Criterion) {
    let gp = trained_gp::<M>();
    let queries: Vec<SVector<f64, 2>> = (0..WINDOW)
        .map(|k| SVector::from([0.3 + 0.01 * k as f64, 0.5]))
        .collect();
    let mut cycler = Cycler::new(&());
    c.benchmark_group("gp_predict")
        .bench_function(BenchmarkId::from_parameter(M), |b| {
            b.iter_custom(|iters| {
                cycler.run(iters, |_, k| {
                    let _ = black_box(gp.predict(&queries[k]));
                })
            })
        });
}

fn bench_gp(c: &mut Criterion) {
    bench_gp_at::<16>(c);
    bench_gp_at::<32>(c);
    bench_gp_at::<64>(c);
    bench_gp_at::<128>(c);
    bench_gp_at::<256>(c);
}

/// IMM of `K` GP-UKFs as in the bearing prognosis (1 state, 1 input, 64-point GPs).
fn bench_imm_at<const K: usize>(c: &mut Criterion, gp: &GaussianProcess<f64, 2, 64>) {
    type Filter<'a> = GpUkf<'a, f64, 1, 1, 2, 64, 3>;
    let filters: [Filter<'_>; K] = core::array::from_fn(|_| {
        GpUkf::new(
            GpTransition {
                gps: [gp],
                measurement_std: Vector1::new(0.01),
            },
            Vector1::new(0.3),
            Matrix1::new(1e-4),
            Matrix1::new(1e-4),
            SigmaParams::default(),
        )
        .expect("valid filter")
    });
    let fresh = Imm::<f64, Filter<'_>, 1, K>::new(
        filters,
        SVector::from([1.0 / K as f64; K]),
        Imm::<f64, Filter<'_>, 1, K>::uniform_switching(0.98),
    )
    .expect("valid IMM");
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(6);
    let samples: Vec<f64> = (0..WINDOW)
        .map(|k| 0.3 + 0.012 * k as f64 + 0.01 * standard_normal::<f64, _>(&mut rng))
        .collect();
    let u = Vector1::new(0.5);
    let mut cycler = Cycler::new(&fresh);
    c.benchmark_group("imm")
        .bench_function(BenchmarkId::from_parameter(K), |b| {
            b.iter_custom(|iters| {
                cycler.run(iters, |imm, k| {
                    let _ = black_box(imm.step(&u, &samples[k..=k]));
                })
            })
        });
}

fn bench_imm(c: &mut Criterion) {
    let gp = trained_gp::<64>();
    bench_imm_at::<2>(c, &gp);
    bench_imm_at::<3>(c, &gp);
    bench_imm_at::<4>(c, &gp);
    bench_imm_at::<6>(c, &gp);
    bench_imm_at::<8>(c, &gp);
}

/// ORIV of an AR(`N`) with `N` extra instruments on a stable AR(2) signal with noise.
fn bench_oriv_at<const N: usize, const Q: usize>(c: &mut Criterion) {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(10);
    let (mut y1, mut y2) = (0.0, 0.0);
    let signal: Vec<f64> = (0..4 * (N + Q) + WINDOW)
        .map(|_| {
            let y = 1.2 * y1 - 0.5 * y2 + standard_normal::<f64, _>(&mut rng);
            y2 = y1;
            y1 = y;
            y + 0.1 * standard_normal::<f64, _>(&mut rng)
        })
        .collect();
    let warm = signal.len() - WINDOW;
    let mut fresh = Oriv::<f64, N, Q>::new(&OrivConfig::default()).expect("valid config");
    for &y in &signal[..warm] {
        let _ = fresh.update(y);
    }
    let tail = &signal[warm..];
    let mut cycler = Cycler::new(&fresh);
    c.benchmark_group("oriv")
        .bench_function(BenchmarkId::from_parameter(N), |b| {
            b.iter_custom(|iters| {
                cycler.run(iters, |oriv, k| {
                    let _ = black_box(oriv.update(tail[k]));
                })
            })
        });
}

fn bench_oriv(c: &mut Criterion) {
    bench_oriv_at::<2, 2>(c);
    bench_oriv_at::<4, 4>(c);
    bench_oriv_at::<8, 8>(c);
    bench_oriv_at::<16, 16>(c);
}

criterion_group!(
    benches,
    bench_valve,
    bench_wheel,
    bench_pipelines,
    bench_ukf,
    bench_gp,
    bench_imm,
    bench_oriv
);
criterion_main!(benches);
