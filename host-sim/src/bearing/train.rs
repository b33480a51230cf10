//! Host training of the dynamic GP (Anger et al. 2012, Eqs. 8-11): inputs `(r_k, du_k)`,
//! output `r_{k+1} - r_k` of the low-pass filtered feature; SE-ARD hyperparameters by
//! maximising the log marginal likelihood (Nelder-Mead from argmin on the log-parameters);
//! weights (subset of data, [`train`], or FITC on all pairs, [`train_sparse`]) exported for the
//! core's fixed-size [`GaussianProcess`].

use super::trial::{Trial, zero_phase_lowpass};
use argmin::core::{CostFunction, Executor, State};
use argmin::solver::neldermead::NelderMead;
use nalgebra::{DMatrix, DVector};
use prognos_core::learn::gp::GaussianProcess;
use std::fmt::Write as _;

/// Number of stored GP points in the bearing predictor (const generic `M` of the core).
pub const GP_POINTS: usize = 64;
/// GP input dimension: `(r, du)`.
pub const GP_INPUTS: usize = 2;

/// Training data of the dynamic GP.
#[derive(Clone, Debug, Default)]
pub struct Dataset {
    pub inputs: Vec<[f64; GP_INPUTS]>,
    pub targets: Vec<f64>,
}

/// Smoothing of the training features (forward-backward exponential, the paper's low-pass).
pub const TRAINING_SMOOTHING: f64 = 0.8;

impl Dataset {
    /// Pairs `((r_k, du_k), r_{k+1} - r_k)` of the low-passed feature up to the true EOL.
    pub fn from_trials(trials: &[&Trial]) -> Self {
        let mut d = Self::default();
        for t in trials {
            let r = zero_phase_lowpass(&t.feature, TRAINING_SMOOTHING);
            for k in 0..t.eol.min(r.len() - 1) {
                d.inputs.push([r[k], t.load_diff[k]]);
                d.targets.push(r[k + 1] - r[k]);
            }
        }
        d
    }

    /// `m` points spread evenly over the data (subset of data for the fixed-size predictor).
    pub fn subset(&self, m: usize) -> Self {
        let n = self.targets.len();
        if n <= m {
            return self.clone();
        }
        let mut d = Self::default();
        for i in 0..m {
            let k = (i as f64 * (n - 1) as f64 / (m - 1).max(1) as f64).round() as usize;
            d.inputs.push(self.inputs[k]);
            d.targets.push(self.targets[k]);
        }
        d
    }
}

/// Variance of the measured feature around its low-passed course (the UKF's `R`).
pub fn feature_noise_variance(trials: &[&Trial]) -> f64 {
    let (mut s, mut n) = (0.0, 0usize);
    for t in trials {
        let r = zero_phase_lowpass(&t.feature, TRAINING_SMOOTHING);
        for (f, rk) in t.feature.iter().zip(&r).take(t.eol) {
            s += (f - rk).powi(2);
            n += 1;
        }
    }
    s / n.max(1) as f64
}

/// Noise law `var(r) = floor + growth r^2` of the measured feature around its low-passed
/// course on the training trials: least squares of the squared residuals on `r^2` (the
/// low-passed value), an unbiased fit of `E[e^2 | r]`. Both coefficients are kept positive
/// (a floor of 1 % of the mean variance).
pub fn feature_noise_law(trials: &[&Trial]) -> prognos_core::learn::gp_rate::FeatureNoise<f64> {
    let (mut n, mut sx, mut sy, mut sxx, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for t in trials {
        let r = zero_phase_lowpass(&t.feature, TRAINING_SMOOTHING);
        for (f, rk) in t.feature.iter().zip(&r).take(t.eol) {
            let (x, y) = (rk * rk, (f - rk).powi(2));
            n += 1.0;
            sx += x;
            sy += y;
            sxx += x * x;
            sxy += x * y;
        }
    }
    let mean_var = sy / f64::max(n, 1.0);
    let det = n * sxx - sx * sx;
    let growth = if det > 0.0 {
        ((n * sxy - sx * sy) / det).max(0.0)
    } else {
        0.0
    };
    let floor = ((sy - growth * sx) / f64::max(n, 1.0)).max(0.01 * mean_var);
    prognos_core::learn::gp_rate::FeatureNoise { floor, growth }
}

/// The training units' log-rate terms and the prior they give (see [`rate_prior`]).
#[derive(Clone, Debug, PartialEq)]
pub struct RatePriorFit {
    /// `[theta_0, ..]` of each training unit.
    pub per_trial: Vec<Vec<f64>>,
    pub mean: Vec<f64>,
    pub covariance: Vec<Vec<f64>>,
}

/// Log-rate polynomial of each training unit relative to `gp` and the prior it gives for an
/// unseen unit. A unit's course (low-passed) is cut at `pivot` into a low and a high part; in
/// each, `ln(sum dr / sum mu(r, du))` is how much faster the unit went than the GP's mean
/// increments say. `NX = 2`: `theta_0` = the whole course's ratio; `NX = 3`: `theta_0` is the
/// line through the two parts' (mean r, ratio) at `pivot`, `theta_1` its slope. Returns each
/// unit's `[theta..]` and the prior (mean, covariance over the units with the diagonal
/// floored at `min_variance`: a few training units understate the population's spread).
pub fn rate_prior<const NX: usize>(
    gp: &prognos_core::learn::gp::GaussianProcess<f64, GP_INPUTS, GP_POINTS>,
    trials: &[&Trial],
    pivot: f64,
    min_variance: f64,
) -> anyhow::Result<RatePriorFit> {
    anyhow::ensure!((2..=3).contains(&NX), "rate prior for NX = 2 or 3");
    let mut all = Vec::with_capacity(trials.len());
    for t in trials {
        let r = zero_phase_lowpass(&t.feature, TRAINING_SMOOTHING);
        // [part][progress, predicted, sum r, count]
        let mut acc = [[0.0f64; 4]; 2];
        for k in 0..t.eol.min(r.len() - 1) {
            let p = gp
                .predict(&nalgebra::Vector2::new(r[k], t.load_diff[k]))
                .map_err(|e| anyhow::anyhow!("{e}"))?;
            let part = &mut acc[usize::from(NX == 3 && r[k] >= pivot)];
            part[0] += r[k + 1] - r[k];
            part[1] += p.mean;
            part[2] += r[k];
            part[3] += 1.0;
        }
        let ratio = |a: &[f64; 4]| {
            anyhow::ensure!(
                a[0] > 0.0 && a[1] > 0.0,
                "trial {} does not degrade under the GP",
                t.seed
            );
            Ok((a[0] / a[1]).ln())
        };
        let theta = if NX == 2 {
            vec![ratio(&acc[0])?]
        } else {
            let (lo, hi) = (ratio(&acc[0])?, ratio(&acc[1])?);
            let (rlo, rhi) = (acc[0][2] / acc[0][3], acc[1][2] / acc[1][3]);
            let slope = (hi - lo) / (rhi - rlo).max(1e-3);
            vec![lo + slope * (pivot - rlo), slope]
        };
        all.push(theta);
    }
    let n = all.len() as f64;
    let dim = NX - 1;
    let mean: Vec<f64> = (0..dim)
        .map(|i| all.iter().map(|v| v[i]).sum::<f64>() / n)
        .collect();
    let mut cov = vec![vec![0.0; dim]; dim];
    for v in &all {
        for i in 0..dim {
            for j in 0..dim {
                cov[i][j] += (v[i] - mean[i]) * (v[j] - mean[j]) / (n - 1.0).max(1.0);
            }
        }
    }
    for (i, row) in cov.iter_mut().enumerate() {
        row[i] = row[i].max(min_variance);
    }
    Ok(RatePriorFit {
        per_trial: all,
        mean,
        covariance: cov,
    })
}

/// Hyperparameters of the SE-ARD GP.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hyper {
    pub length_scales: [f64; GP_INPUTS],
    pub signal_variance: f64,
    pub noise_variance: f64,
}

impl Hyper {
    fn from_log(p: &[f64]) -> Self {
        Self {
            length_scales: [p[0].exp(), p[1].exp()],
            signal_variance: (2.0 * p[2]).exp(),
            noise_variance: (2.0 * p[3]).exp(),
        }
    }

    fn kernel(&self, a: &[f64; GP_INPUTS], b: &[f64; GP_INPUTS]) -> f64 {
        let q: f64 = a
            .iter()
            .zip(b)
            .zip(&self.length_scales)
            .map(|((x, y), l)| ((x - y) / l).powi(2))
            .sum();
        self.signal_variance * (-0.5 * q).exp()
    }
}

fn gram(h: &Hyper, x: &[[f64; GP_INPUTS]]) -> DMatrix<f64> {
    let n = x.len();
    DMatrix::from_fn(n, n, |i, j| {
        h.kernel(&x[i], &x[j]) + if i == j { h.noise_variance } else { 0.0 }
    })
}

/// Negative log marginal likelihood `1/2 y^T K^-1 y + 1/2 ln|K| + n/2 ln 2 pi` of centred
/// targets (Eq. 8); `None` when `K` is not positive definite.
pub fn negative_log_marginal_likelihood(
    h: &Hyper,
    x: &[[f64; GP_INPUTS]],
    y: &[f64],
) -> Option<f64> {
    let k = gram(h, x);
    let chol = k.cholesky()?;
    let yv = DVector::from_column_slice(y);
    let alpha = chol.solve(&yv);
    let log_det: f64 = chol.l().diagonal().iter().map(|d| d.ln()).sum::<f64>() * 2.0;
    Some(
        0.5 * yv.dot(&alpha)
            + 0.5 * log_det
            + 0.5 * y.len() as f64 * (2.0 * std::f64::consts::PI).ln(),
    )
}

struct Nlml<'a> {
    x: &'a [[f64; GP_INPUTS]],
    y: &'a [f64],
    /// Bounds of the log-parameters (outside: a steep penalty).
    lo: [f64; 4],
    hi: [f64; 4],
}

impl CostFunction for Nlml<'_> {
    type Param = Vec<f64>;
    type Output = f64;
    fn cost(&self, p: &Vec<f64>) -> Result<f64, argmin::core::Error> {
        let mut clamped = p.clone();
        let mut penalty = 0.0;
        for ((v, lo), hi) in clamped.iter_mut().zip(self.lo).zip(self.hi) {
            if *v < lo || *v > hi {
                penalty += 1e3 * (1.0 + (*v - v.clamp(lo, hi)).powi(2));
                *v = v.clamp(lo, hi);
            }
        }
        let h = Hyper::from_log(&clamped);
        Ok(negative_log_marginal_likelihood(&h, self.x, self.y).unwrap_or(1e12) + penalty)
    }
}

/// A trained GP: hyperparameters, stored points and the weights the core needs.
#[derive(Clone, Debug)]
pub struct TrainedGp {
    pub hyper: Hyper,
    pub inputs: Vec<[f64; GP_INPUTS]>,
    pub targets: Vec<f64>,
    pub mean_offset: f64,
    pub alpha: Vec<f64>,
    /// Row-major lower Cholesky factor of `K + sigma_n^2 I`.
    pub chol_lower: Vec<Vec<f64>>,
    pub nlml: f64,
}

/// Trains a GP on `data` (at most `m` points kept): constant mean = mean target,
/// hyperparameters by maximising the marginal likelihood.
pub fn train(data: &Dataset, m: usize) -> anyhow::Result<TrainedGp> {
    let d = data.subset(m);
    anyhow::ensure!(d.targets.len() >= 3, "too few training points");
    let mean = d.targets.iter().sum::<f64>() / d.targets.len() as f64;
    let y: Vec<f64> = d.targets.iter().map(|v| v - mean).collect();
    let sd = (y.iter().map(|v| v * v).sum::<f64>() / y.len() as f64)
        .sqrt()
        .max(1e-6);
    let range = |i: usize| {
        let (lo, hi) = d
            .inputs
            .iter()
            .fold((f64::MAX, f64::MIN), |(a, b), x| (a.min(x[i]), b.max(x[i])));
        (hi - lo).max(1e-3)
    };
    let (r0, r1) = (range(0), range(1));
    let start = vec![(0.3 * r0).ln(), (0.5 * r1).ln(), sd.ln(), (0.5 * sd).ln()];
    let problem = Nlml {
        x: &d.inputs,
        y: &y,
        lo: [
            (0.1 * r0).ln(),
            (0.1 * r1).ln(),
            (0.01 * sd).ln(),
            (0.05 * sd).ln(),
        ],
        hi: [
            (20.0 * r0).ln(),
            (20.0 * r1).ln(),
            (100.0 * sd).ln(),
            (10.0 * sd).ln(),
        ],
    };
    let mut simplex = vec![start.clone()];
    for i in 0..start.len() {
        let mut v = start.clone();
        v[i] += 0.7;
        simplex.push(v);
    }
    let solver = NelderMead::new(simplex).with_sd_tolerance(1e-7)?;
    let res = Executor::new(problem, solver)
        .configure(|s| s.max_iters(600))
        .run()?;
    let best = res
        .state()
        .get_best_param()
        .cloned()
        .ok_or_else(|| anyhow::anyhow!("optimiser returned no parameters"))?;
    let nlml = res.state().get_best_cost();
    fit(
        Hyper::from_log(&best),
        d.inputs.clone(),
        d.targets.clone(),
        mean,
        nlml,
    )
}

/// Weights for given hyperparameters.
pub fn fit(
    hyper: Hyper,
    inputs: Vec<[f64; GP_INPUTS]>,
    targets: Vec<f64>,
    mean_offset: f64,
    nlml: f64,
) -> anyhow::Result<TrainedGp> {
    let k = gram(&hyper, &inputs);
    let chol = k
        .cholesky()
        .ok_or_else(|| anyhow::anyhow!("kernel matrix is not positive definite"))?;
    let y = DVector::from_iterator(targets.len(), targets.iter().map(|v| v - mean_offset));
    let alpha = chol.solve(&y);
    let l = chol.l();
    let n = inputs.len();
    Ok(TrainedGp {
        hyper,
        inputs,
        targets,
        mean_offset,
        alpha: alpha.iter().copied().collect(),
        chol_lower: (0..n)
            .map(|i| (0..n).map(|j| l[(i, j)]).collect())
            .collect(),
        nlml,
    })
}

/// Greedy choice of `m` inducing inputs out of `x` by the sparse-GP criterion of the
/// Nystrom / FITC approximation: each pick is the training input whose prior variance the
/// inputs picked so far explain least, `k(x, x) - q(x, x)` (incomplete pivoted Cholesky).
/// Once every input is explained to within the jitter, the remaining picks are spread evenly
/// in time. Returns the picked indices and every input's residual `k(x_i, x_i) - q(x_i, x_i)`.
pub fn greedy_inducing(h: &Hyper, x: &[[f64; GP_INPUTS]], m: usize) -> (Vec<usize>, Vec<f64>) {
    let n = x.len();
    let mut residual = vec![h.signal_variance; n];
    let mut columns: Vec<Vec<f64>> = Vec::with_capacity(m);
    let mut picked = Vec::with_capacity(m);
    for _ in 0..m.min(n) {
        let (p, &d) = residual
            .iter()
            .enumerate()
            .filter(|(i, _)| !picked.contains(i))
            .max_by(|a, b| a.1.total_cmp(b.1).then(b.0.cmp(&a.0)))
            .unwrap_or((0, &0.0));
        // The rest is explained to within the jitter: fill up evenly in time below.
        if d <= INDUCING_JITTER * h.signal_variance {
            break;
        }
        let sd = d.sqrt();
        let col: Vec<f64> = (0..n)
            .map(|i| {
                let dot: f64 = columns.iter().map(|c| c[i] * c[p]).sum();
                (h.kernel(&x[i], &x[p]) - dot) / sd
            })
            .collect();
        for (r, c) in residual.iter_mut().zip(&col) {
            *r = (*r - c * c).max(0.0);
        }
        residual[p] = 0.0;
        columns.push(col);
        picked.push(p);
    }
    let missing = m.min(n) - picked.len();
    let rest: Vec<usize> = (0..n).filter(|i| !picked.contains(i)).collect();
    for j in 0..missing {
        picked.push(rest[j * rest.len() / missing]);
    }
    (picked, residual)
}

/// Jitter on the inducing inputs' prior covariance, relative to the signal variance.
const INDUCING_JITTER: f64 = 1e-6;

/// Sparse GP on all of `data` with `m` inducing inputs (FITC, Snelson & Ghahramani 2006): the
/// hyperparameters of [`train`] (fitted on `m` points spread in time), inducing inputs by
/// [`greedy_inducing`], and weights from every training pair, each with noise variance
/// `sigma_n^2 + k(x_i, x_i) - q(x_i, x_i)`. The predictor keeps the core's form
/// `mean + k_*^T alpha`, `k_** - k_*^T C^-1 k_*`, with
/// `alpha = (K_mm + K_mn L^-1 K_nm)^-1 K_mn L^-1 (y - mean)` and
/// `C = K_mm + K_mm (K_mn L^-1 K_nm)^-1 K_mm` (`L` the per-pair noise): the FITC predictive
/// variance `k_** - q_** + k_*^T (K_mm + K_mn L^-1 K_nm)^-1 k_*` rewritten.
pub fn train_sparse(data: &Dataset, m: usize) -> anyhow::Result<TrainedGp> {
    let sod = train(data, m)?;
    let n = data.targets.len();
    if n <= m {
        return Ok(sod);
    }
    let h = sod.hyper;
    let (picked, residual) = greedy_inducing(&h, &data.inputs, m);
    anyhow::ensure!(picked.len() == m, "only {} inducing inputs", picked.len());
    let z: Vec<[f64; GP_INPUTS]> = picked.iter().map(|&i| data.inputs[i]).collect();
    let mean = data.targets.iter().sum::<f64>() / n as f64;
    let jitter = INDUCING_JITTER * h.signal_variance;
    let kmm = DMatrix::from_fn(m, m, |i, j| {
        h.kernel(&z[i], &z[j]) + if i == j { jitter } else { 0.0 }
    });
    let knm = DMatrix::from_fn(n, m, |i, j| h.kernel(&data.inputs[i], &z[j]));
    let inv_noise =
        DVector::from_iterator(n, residual.iter().map(|d| 1.0 / (h.noise_variance + d)));
    let weighted = DMatrix::from_fn(n, m, |i, j| knm[(i, j)] * inv_noise[i]);
    let mut g = knm.transpose() * &weighted;
    g = (&g + g.transpose()) * 0.5;
    let y = DVector::from_iterator(n, data.targets.iter().map(|v| v - mean));
    let a = &kmm + &g;
    let alpha = a
        .cholesky()
        .ok_or_else(|| anyhow::anyhow!("FITC system is not positive definite"))?
        .solve(&(weighted.transpose() * &y));
    let g_chol = (&g + DMatrix::identity(m, m) * (1e-12 * g.trace() / m as f64))
        .cholesky()
        .ok_or_else(|| anyhow::anyhow!("FITC data term is not positive definite"))?;
    let mut c = &kmm + &kmm * g_chol.solve(&kmm);
    c = (&c + c.transpose()) * 0.5;
    let l = c
        .cholesky()
        .ok_or_else(|| anyhow::anyhow!("FITC variance matrix is not positive definite"))?
        .l();
    Ok(TrainedGp {
        hyper: h,
        targets: picked.iter().map(|&i| data.targets[i]).collect(),
        inputs: z,
        mean_offset: mean,
        alpha: alpha.iter().copied().collect(),
        chol_lower: (0..m)
            .map(|i| (0..m).map(|j| l[(i, j)]).collect())
            .collect(),
        nlml: sod.nlml,
    })
}

impl TrainedGp {
    /// The core predictor (exactly `M` stored points required), boxed: it is large.
    pub fn to_core<const M: usize>(
        &self,
    ) -> anyhow::Result<Box<GaussianProcess<f64, GP_INPUTS, M>>> {
        anyhow::ensure!(
            self.inputs.len() == M,
            "GP has {} points, predictor wants {M}",
            self.inputs.len()
        );
        let inputs: [[f64; GP_INPUTS]; M] = self
            .inputs
            .clone()
            .try_into()
            .map_err(|_| anyhow::anyhow!("size"))?;
        let alpha: [f64; M] = self
            .alpha
            .clone()
            .try_into()
            .map_err(|_| anyhow::anyhow!("size"))?;
        let mut chol: Box<[[f64; M]; M]> = vec![[0.0; M]; M]
            .into_boxed_slice()
            .try_into()
            .map_err(|_| anyhow::anyhow!("size"))?;
        for (dst, src) in chol.iter_mut().zip(&self.chol_lower) {
            dst.copy_from_slice(src);
        }
        let gp = GaussianProcess::from_f64(
            &self.hyper.length_scales,
            self.hyper.signal_variance,
            self.hyper.noise_variance,
            &inputs,
            &alpha,
            &chol,
            self.mean_offset,
        )
        .map_err(|e| anyhow::anyhow!("{e}"))?;
        Ok(Box::new(gp))
    }

    /// Mean and latent variance by the textbook dense formulas with an explicit inverse of
    /// `K + sigma_n^2 I` (an independent check of the core predictor; for a GP of [`train`],
    /// not of [`train_sparse`]).
    pub fn predict_dense(&self, x: &[f64; GP_INPUTS]) -> (f64, f64) {
        let k = gram(&self.hyper, &self.inputs);
        let kinv = k.try_inverse().unwrap_or_else(|| DMatrix::zeros(1, 1));
        let ks = DVector::from_iterator(
            self.inputs.len(),
            self.inputs.iter().map(|xi| self.hyper.kernel(x, xi)),
        );
        let y = DVector::from_iterator(
            self.targets.len(),
            self.targets.iter().map(|v| v - self.mean_offset),
        );
        let mean = self.mean_offset + (ks.transpose() * &kinv * y)[(0, 0)];
        let var = self.hyper.signal_variance - (ks.transpose() * &kinv * &ks)[(0, 0)];
        (mean, var)
    }

    /// Rust source defining the weights as constants (`<NAME>_INPUTS`, `_ALPHA`, `_CHOL`,
    /// `_LENGTH_SCALES`, `_SIGNAL_VARIANCE`, `_NOISE_VARIANCE`, `_MEAN`) for
    /// `GaussianProcess::from_f64` in firmware.
    pub fn to_rust_source(&self, name: &str) -> String {
        let m = self.inputs.len();
        let mut s = String::new();
        let _ = writeln!(
            s,
            "// Generated by prognos-sim bearing training: do not edit."
        );
        let _ = writeln!(
            s,
            "pub const {name}_LENGTH_SCALES: [f64; {GP_INPUTS}] = {:?};",
            self.hyper.length_scales
        );
        let _ = writeln!(
            s,
            "pub const {name}_SIGNAL_VARIANCE: f64 = {:e};",
            self.hyper.signal_variance
        );
        let _ = writeln!(
            s,
            "pub const {name}_NOISE_VARIANCE: f64 = {:e};",
            self.hyper.noise_variance
        );
        let _ = writeln!(s, "pub const {name}_MEAN: f64 = {:e};", self.mean_offset);
        let _ = writeln!(
            s,
            "pub const {name}_INPUTS: [[f64; {GP_INPUTS}]; {m}] = {:?};",
            self.inputs
        );
        let _ = writeln!(s, "pub const {name}_ALPHA: [f64; {m}] = {:?};", self.alpha);
        let _ = writeln!(
            s,
            "pub const {name}_CHOL: [[f64; {m}]; {m}] = {:?};",
            self.chol_lower
        );
        s
    }
}
