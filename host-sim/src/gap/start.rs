//! The replay's initial condition, refitted by least squares.
//!
//! A replay starts from the first measurements, which carry noise and, under a sensor
//! effect (bias, scale, saturation, ...), the effect itself; a slow plant carries that
//! start through the whole record. The diagnoser and `gap-bench` (which measures how much
//! of an effect a free start leaves visible) both refit it with these helpers.

use super::plant::PlantData;

/// How a replay moves with the measured initial value of one output channel.
#[derive(Clone, Debug, PartialEq)]
pub struct StartSensitivity {
    /// Output channel (index into the replayed outputs) whose start is moved.
    pub channel: usize,
    /// d output / d initial value, per replayed channel and sample.
    pub gain: Vec<Vec<f64>>,
    /// A step (in the channel's units) small enough for a finite difference through the
    /// sensor components applied after the replay.
    pub step: f64,
}

/// The sensitivity of `replay` to the start of each channel in `starts` (`(name, noise
/// std)`, in replayed output order), by moving it 10 noise stds; channels the plant does
/// not initialise from the data (zero gain) or whose moved replay fails are left out.
pub fn start_sensitivities(
    data: &PlantData,
    starts: &[(String, f64)],
    reference: &[Vec<f64>],
    replay: impl Fn(&PlantData) -> Option<Vec<Vec<f64>>>,
) -> Vec<StartSensitivity> {
    let mut out = Vec::new();
    for (channel, (name, sigma)) in starts.iter().enumerate() {
        let step = 10.0 * sigma;
        let mut moved = data.clone();
        moved.initial_offsets.insert(name.clone(), step);
        let Some(shifted) = replay(&moved) else {
            continue;
        };
        let gain: Vec<Vec<f64>> = shifted
            .iter()
            .zip(reference)
            .map(|(a, b)| a.iter().zip(b).map(|(x, y)| (x - y) / step).collect())
            .collect();
        let flat = || gain.iter().flatten();
        if flat().any(|g| g.abs() > 1e-6) && flat().all(|g| g.is_finite()) {
            out.push(StartSensitivity {
                channel,
                gain,
                step: *sigma,
            });
        }
    }
    out
}

/// `raw` with its start moved by the weighted least-squares fit of `observe(raw moved)` to
/// `measured` on the samples `use_sample` keeps: Gauss-Newton, each step halved up to 6
/// times until it lowers the misfit, relinearised at the moved start up to
/// [`START_ITERATIONS`] times. One step is exact when `observe` is linear; through a clip
/// it is not (a start read from clipped samples is fitted first as if they moved with it,
/// and the next step sees them clipped). `observe` applies what acts after the replay
/// (sensor components; the identity for none). Returns `observe(raw)` when there is
/// nothing to fit, the system is singular or no step helps.
pub fn refit_start(
    raw: &[Vec<f64>],
    sens: &[StartSensitivity],
    measured: &[Vec<f64>],
    sigma: &[f64],
    use_sample: impl Fn(usize) -> bool,
    observe: impl Fn(Vec<Vec<f64>>) -> Vec<Vec<f64>>,
) -> Vec<Vec<f64>> {
    let base = observe(raw.to_vec());
    if sens.is_empty() {
        return base;
    }
    let shifted = |deltas: &[f64]| -> Vec<Vec<f64>> {
        let mut s = raw.to_vec();
        for (si, d) in sens.iter().zip(deltas) {
            for (out, g) in s.iter_mut().zip(&si.gain) {
                for (v, gk) in out.iter_mut().zip(g) {
                    *v += d * gk;
                }
            }
        }
        observe(s)
    };
    let misfit = |out: &[Vec<f64>]| -> f64 {
        let mut sum = 0.0;
        for (j, y) in measured.iter().enumerate() {
            let w = 1.0 / (sigma[j] * sigma[j]);
            for (k, &yk) in y.iter().enumerate() {
                let r = yk - out[j][k];
                if use_sample(k) && r.is_finite() {
                    sum += w * r * r;
                }
            }
        }
        sum
    };
    let m = sens.len();
    let mut deltas = vec![0.0; m];
    let mut best = base;
    let mut best_misfit = misfit(&best);
    for _ in 0..START_ITERATIONS {
        let jac: Vec<Vec<Vec<f64>>> = (0..m)
            .map(|i| {
                let mut d = deltas.clone();
                d[i] += sens[i].step;
                shifted(&d)
            })
            .collect();
        let mut a = vec![vec![0.0; m]; m];
        let mut b = vec![0.0; m];
        for (j, y) in measured.iter().enumerate() {
            let w = 1.0 / (sigma[j] * sigma[j]);
            for (k, &yk) in y.iter().enumerate() {
                let r = yk - best[j][k];
                if !(use_sample(k) && r.is_finite()) {
                    continue;
                }
                let g: Vec<f64> = (0..m)
                    .map(|i| (jac[i][j][k] - best[j][k]) / sens[i].step)
                    .collect();
                for p in 0..m {
                    b[p] += w * g[p] * r;
                    for q in 0..m {
                        a[p][q] += w * g[p] * g[q];
                    }
                }
            }
        }
        let Some(delta) = solve_small(a, b) else {
            break;
        };
        let mut step = 1.0;
        let mut moved_to = None;
        for _ in 0..7 {
            let trial: Vec<f64> = deltas
                .iter()
                .zip(&delta)
                .map(|(d, dd)| d + dd * step)
                .collect();
            let moved = shifted(&trial);
            let cost = misfit(&moved);
            if cost <= best_misfit {
                moved_to = Some((trial, moved, cost));
                break;
            }
            step *= 0.5;
        }
        let Some((trial, moved, cost)) = moved_to else {
            break;
        };
        // Where the moved start lands where the linearisation said, `observe` is linear
        // there and the step is exact: no second Jacobian (this runs in every candidate
        // replay). Likewise a step that no longer lowers the misfit by a noise-level amount.
        let exact = step == 1.0
            && moved.iter().enumerate().all(|(j, out)| {
                out.iter().enumerate().all(|(k, v)| {
                    let linear = best[j][k]
                        + (0..m)
                            .map(|i| delta[i] * (jac[i][j][k] - best[j][k]) / sens[i].step)
                            .sum::<f64>();
                    !v.is_finite() || (v - linear).abs() <= 1e-9 * (1.0 + v.abs())
                })
            });
        let gain = best_misfit - cost;
        deltas = trial;
        best = moved;
        best_misfit = cost;
        if exact || gain < 1e-3 {
            break;
        }
    }
    best
}

/// Gauss-Newton steps [`refit_start`] takes at most.
pub const START_ITERATIONS: usize = 4;

/// Solves the small symmetric system `a x = b` by Gaussian elimination with partial
/// pivoting; `None` when singular.
pub(crate) fn solve_small(mut a: Vec<Vec<f64>>, mut b: Vec<f64>) -> Option<Vec<f64>> {
    let n = b.len();
    for col in 0..n {
        let piv = (col..n).max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))?;
        if a[piv][col].abs() < 1e-300 {
            return None;
        }
        a.swap(col, piv);
        b.swap(col, piv);
        for row in col + 1..n {
            let f = a[row][col] / a[col][col];
            let pivot_row = a[col].clone();
            for (v, p) in a[row].iter_mut().zip(&pivot_row).skip(col) {
                *v -= f * p;
            }
            b[row] -= f * b[col];
        }
    }
    let mut x = vec![0.0; n];
    for row in (0..n).rev() {
        let s: f64 = (row + 1..n).map(|k| a[row][k] * x[k]).sum();
        x[row] = (b[row] - s) / a[row][row];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_linear_start_is_recovered_exactly() {
        // Replay: y = x0 * exp(-t) from a start 0.3 too high; the data start at 1.0.
        let t: Vec<f64> = (0..50).map(|k| 0.1 * k as f64).collect();
        let truth: Vec<f64> = t.iter().map(|t| (-t).exp()).collect();
        let raw = vec![t.iter().map(|t| 1.3 * (-t).exp()).collect::<Vec<_>>()];
        let sens = vec![StartSensitivity {
            channel: 0,
            gain: vec![t.iter().map(|t| (-t).exp()).collect()],
            step: 0.01,
        }];
        let fitted = refit_start(
            &raw,
            &sens,
            std::slice::from_ref(&truth),
            &[0.01],
            |_| true,
            |s| s,
        );
        for (f, y) in fitted[0].iter().zip(&truth) {
            assert!((f - y).abs() < 1e-12, "{f} vs {y}");
        }
    }

    #[test]
    fn a_step_that_a_clip_turns_worse_is_shortened_and_then_relinearised() {
        // The replay sits just under a clip at 1, the data at 0.6: the finite-difference
        // gain through the clip is 0.4, so the full first step (-0.99) lands at 0.006,
        // further off than the start; half of it lands at 0.501, below the clip, where
        // the next step is exact.
        let clip = |v: Vec<Vec<f64>>| -> Vec<Vec<f64>> {
            v.into_iter()
                .map(|c| c.into_iter().map(|x| x.min(1.0)).collect())
                .collect()
        };
        let raw = vec![vec![0.996; 5]];
        let sens = vec![StartSensitivity {
            channel: 0,
            gain: vec![vec![1.0; 5]],
            step: 0.01,
        }];
        let fitted = refit_start(&raw, &sens, &[vec![0.6; 5]], &[0.01], |_| true, clip);
        assert!((fitted[0][0] - 0.6).abs() < 1e-9, "{}", fitted[0][0]);
    }

    #[test]
    fn a_start_read_from_clipped_samples_is_found() {
        // A decay from 1.3 read through a clip at 1.1: the first samples read 1.1, the
        // replay starts there. The first step treats the clipped samples as moving with
        // the start and falls short; relinearised, the start comes out at 1.3.
        let t: Vec<f64> = (0..60).map(|k| 0.05 * k as f64).collect();
        let clip = |v: Vec<Vec<f64>>| -> Vec<Vec<f64>> {
            v.into_iter()
                .map(|c| c.into_iter().map(|x| x.min(1.1)).collect())
                .collect()
        };
        let truth = clip(vec![t.iter().map(|t| 1.3 * (-t).exp()).collect()]);
        let raw = vec![t.iter().map(|t| 1.1 * (-t).exp()).collect::<Vec<_>>()];
        let sens = vec![StartSensitivity {
            channel: 0,
            gain: vec![t.iter().map(|t| (-t).exp()).collect()],
            step: 0.01,
        }];
        let fitted = refit_start(&raw, &sens, &truth, &[0.01], |_| true, clip);
        for (f, y) in fitted[0].iter().zip(&truth[0]) {
            assert!((f - y).abs() < 1e-9, "{f} vs {y}");
        }
    }

    #[test]
    fn a_singular_system_is_none() {
        assert_eq!(solve_small(vec![vec![0.0]], vec![1.0]), None);
        let x = solve_small(vec![vec![2.0, 1.0], vec![1.0, 3.0]], vec![3.0, 5.0]).unwrap();
        assert!((x[0] - 0.8).abs() < 1e-12 && (x[1] - 1.4).abs() < 1e-12);
    }
}
