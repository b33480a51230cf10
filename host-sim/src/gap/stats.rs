//! Statistics the gap diagnoser needs: tail probabilities of the normal and chi-square
//! distributions, Holm's step-down correction, Ljung-Box whiteness, a robust noise estimate
//! and the periodogram.

use rustfft::FftPlanner;
use rustfft::num_complex::Complex;

/// Upper tail `P(Z > z)` of the standard normal (erfc via libm).
pub fn normal_sf(z: f64) -> f64 {
    0.5 * libm::erfc(z / std::f64::consts::SQRT_2)
}

/// Regularised upper incomplete gamma `Q(a, x)` (Numerical Recipes: series below `a + 1`,
/// Lentz continued fraction above).
pub fn gamma_q(a: f64, x: f64) -> f64 {
    if a.is_nan() || a <= 0.0 || !x.is_finite() {
        return if x.is_infinite() && x > 0.0 { 0.0 } else { 1.0 };
    }
    if x <= 0.0 {
        return 1.0;
    }
    let ln_front = -x + a * x.ln() - libm::lgamma(a);
    if x < a + 1.0 {
        let (mut sum, mut term, mut ap) = (1.0 / a, 1.0 / a, a);
        for _ in 0..10_000 {
            ap += 1.0;
            term *= x / ap;
            sum += term;
            if term.abs() < sum.abs() * 1e-15 {
                break;
            }
        }
        (1.0 - sum * ln_front.exp()).clamp(0.0, 1.0)
    } else {
        let tiny = 1e-300;
        let mut b = x + 1.0 - a;
        let mut c = 1.0 / tiny;
        let mut d = 1.0 / b;
        let mut h = d;
        for i in 1..10_000 {
            let an = -(i as f64) * (i as f64 - a);
            b += 2.0;
            d = an * d + b;
            if d.abs() < tiny {
                d = tiny;
            }
            c = b + an / c;
            if c.abs() < tiny {
                c = tiny;
            }
            d = 1.0 / d;
            let delta = d * c;
            h *= delta;
            if (delta - 1.0).abs() < 1e-15 {
                break;
            }
        }
        (ln_front.exp() * h).clamp(0.0, 1.0)
    }
}

/// Upper tail of the chi-square distribution with `dof` degrees of freedom.
pub fn chi2_sf(x: f64, dof: f64) -> f64 {
    gamma_q(0.5 * dof, 0.5 * x)
}

/// Upper-tail p-value that a mean of squared standardised residuals `ratio` (expected 1)
/// is larger than noise explains, when it is the mean of `n` terms and the noise variance
/// itself was estimated with `reference_dof` effective degrees of freedom (infinite when
/// declared). Normal approximation of the log of an F ratio: `var ln F = 2/n + 2/m`.
pub fn variance_ratio_p(ratio: f64, n: f64, reference_dof: f64) -> f64 {
    if ratio.is_nan() || ratio <= 0.0 || n < 1.0 {
        return 1.0;
    }
    let var = 2.0 / n
        + if reference_dof.is_finite() {
            2.0 / reference_dof
        } else {
            0.0
        };
    normal_sf(ratio.ln() / var.sqrt())
}

/// Holm's step-down adjusted p-values (same order as `p`): controls the family-wise error
/// rate over all tests without assuming independence.
pub fn holm(p: &[f64]) -> Vec<f64> {
    let m = p.len();
    let mut order: Vec<usize> = (0..m).collect();
    order.sort_by(|&a, &b| p[a].total_cmp(&p[b]));
    let mut adjusted = vec![1.0; m];
    let mut running: f64 = 0.0;
    for (rank, &i) in order.iter().enumerate() {
        let v = ((m - rank) as f64 * p[i]).min(1.0);
        running = running.max(v);
        adjusted[i] = running;
    }
    adjusted
}

/// Sample autocorrelation of `x` (finite entries, mean removed) at lags `1..=max_lag`.
pub fn autocorrelation(x: &[f64], max_lag: usize) -> Vec<f64> {
    let n = x.len();
    let mean = x.iter().sum::<f64>() / n.max(1) as f64;
    let c0: f64 = x.iter().map(|v| (v - mean) * (v - mean)).sum();
    (1..=max_lag)
        .map(|k| {
            if k >= n || c0 <= 0.0 {
                return 0.0;
            }
            let ck: f64 = (0..n - k).map(|i| (x[i] - mean) * (x[i + k] - mean)).sum();
            ck / c0
        })
        .collect()
}

/// Ljung-Box statistic over lags `1..=h` and its chi-square(h) p-value.
pub fn ljung_box(x: &[f64], h: usize) -> (f64, f64) {
    let n = x.len() as f64;
    let rho = autocorrelation(x, h);
    let q = n
        * (n + 2.0)
        * rho
            .iter()
            .enumerate()
            .map(|(k, r)| r * r / (n - (k + 1) as f64))
            .sum::<f64>();
    (q, chi2_sf(q, h as f64))
}

/// One-sided test that `x` lingers: the sum of its autocorrelations at lags `1..=h`
/// (its low-frequency power against white noise's), standardised by its white-noise mean
/// and spread (Bartlett: `E rho_k = -(n - k) / (n (n - 1))`, `var rho_k = (n - k) / (n (n +
/// 2))`, nearly uncorrelated), and its upper-tail normal p-value. A filter whose model
/// misses slow dynamics lags behind them and its innovations keep their sign (positive
/// sum); one that trusts its model less than the data warrant over-corrects, and its
/// innovations alternate (negative sum), which is no gap.
pub fn persistence(x: &[f64], h: usize) -> (f64, f64) {
    let n = x.len() as f64;
    let rho = autocorrelation(x, h);
    let (mut mean, mut var) = (0.0, 0.0);
    for k in 1..=rho.len() {
        let kept = (n - k as f64).max(0.0);
        mean -= kept / (n * (n - 1.0)).max(1.0);
        var += kept / (n * (n + 2.0)).max(1.0);
    }
    if var <= 0.0 {
        return (0.0, 1.0);
    }
    let z = (rho.iter().sum::<f64>() - mean) / var.sqrt();
    (z, normal_sf(z))
}

/// Median of a copy of `values` (finite ones); `None` when there are none.
pub fn median(values: &[f64]) -> Option<f64> {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let m = v.len() / 2;
    Some(if v.len() % 2 == 1 {
        v[m]
    } else {
        0.5 * (v[m - 1] + v[m])
    })
}

/// Second differences `y[k+1] - 2 y[k] + y[k-1]` over finite triples, those below the float
/// rounding of the signal (1e-9 of its largest magnitude) set to exactly 0: a staircase
/// computed in floating point (quantised readings `n q + offset` near 600 rad/s) has second
/// differences of 1e-14 where exact arithmetic has 0.
pub fn second_differences(y: &[f64]) -> Vec<f64> {
    let scale = y
        .iter()
        .filter(|v| v.is_finite())
        .fold(0.0f64, |m, v| m.max(v.abs()));
    y.windows(3)
        .filter(|w| w.iter().all(|v| v.is_finite()))
        .map(|w| w[2] - 2.0 * w[1] + w[0])
        .map(|d| if d.abs() <= 1e-9 * scale { 0.0 } else { d })
        .collect()
}

/// `y` with its readings that sit exactly on a repeated level set to NaN: one that at least
/// 10 and 1 % of the finite readings equal, as a clip's limit or the zero of a deadband
/// that zeroes small readings. A noisy sensor off a lattice never repeats a reading, so
/// such readings carry no noise, and the zero differences between them would pull a noise
/// estimate down (to 0.4 of the noise on a record clipped two thirds of the time, to 0.15
/// on a speed read as zero for half of it). For a channel off a lattice: on a lattice
/// every level repeats.
pub fn without_repeated_levels(y: &[f64]) -> Vec<f64> {
    let mut finite: Vec<f64> = y.iter().copied().filter(|v| v.is_finite()).collect();
    let least = (finite.len() / 100).max(10);
    finite.sort_by(f64::total_cmp);
    let mut repeated = Vec::new();
    for run in finite.chunk_by(|a, b| a == b) {
        if run.len() >= least {
            repeated.push(run[0]);
        }
    }
    y.iter()
        .map(|&v| if repeated.contains(&v) { f64::NAN } else { v })
        .collect()
}

/// Sensor-noise std estimated from the data alone, from second differences
/// (`var(y[k+1] - 2 y[k] + y[k-1]) = 6 sigma^2` for white noise; the signal's own curvature
/// is negligible at the sample rate). Their MAD gives a scale that ignores transients; the
/// variance of the differences within 3 of that scale, corrected for the truncation and
/// iterated, then keeps that robustness at ~95 % of the plain variance's efficiency (the
/// MAD alone has 37 %, which put the estimate 5 % off on 1800 samples). Falls back to the
/// plain std of the differences when more than half are zero (quantised data). Returns the
/// estimate and its effective degrees of freedom (second differences of white noise are
/// correlated, -2/3 at lag 1 and 1/6 at lag 2: about half as many as there are).
pub fn noise_std_from_differences(y: &[f64]) -> Option<(f64, f64)> {
    let d2 = second_differences(y);
    if d2.len() < 10 {
        return None;
    }
    let abs: Vec<f64> = d2.iter().map(|v| v.abs()).collect();
    let mad = median(&abs)?;
    let n = d2.len() as f64;
    let dof = n / (1.0 + 2.0 * (4.0 / 9.0 + 1.0 / 36.0));
    if mad <= 0.0 {
        let sigma = (d2.iter().map(|v| v * v).sum::<f64>() / n / 6.0).sqrt();
        return (sigma > 0.0).then_some((sigma, dof));
    }
    let (scale, kept) = trimmed_std(&d2)?;
    let sigma = scale / 6f64.sqrt();
    (sigma > 0.0).then_some((sigma, 0.95 * dof * kept / n))
}

/// The std of `d` (zero-mean differences) from its values within 3 of its scale, corrected
/// for the truncation of a Gaussian and iterated from the MAD's scale, and how many values
/// it kept; `None` when fewer than 10 or the MAD is 0.
fn trimmed_std(d: &[f64]) -> Option<(f64, f64)> {
    if d.len() < 10 {
        return None;
    }
    let abs: Vec<f64> = d.iter().map(|v| v.abs()).collect();
    let mad = median(&abs)?;
    if mad <= 0.0 {
        return None;
    }
    // Variance of a unit normal truncated to [-3, 3].
    const TRUNCATED_VARIANCE: f64 = 0.973_336_924;
    let mut scale = 1.4826 * mad;
    let mut kept = d.len() as f64;
    for _ in 0..4 {
        let limit = 3.0 * scale;
        let (sum, m) = d
            .iter()
            .filter(|v| v.abs() <= limit)
            .fold((0.0, 0usize), |(a, m), v| (a + v * v, m + 1));
        if m < 10 {
            break;
        }
        scale = (sum / m as f64 / TRUNCATED_VARIANCE).sqrt();
        kept = m as f64;
    }
    Some((scale, kept))
}

/// Noise whose tails are heavier than a Gaussian's, as read off a residual by
/// [`heavy_tailed_noise`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HeavyTailedNoise {
    /// Std.
    pub std: f64,
    /// Effective degrees of freedom of its variance (as in [`variance_ratio_p`]).
    pub dof: f64,
    /// Kurtosis `E e^4 / (E e^2)^2` (3 for a Gaussian).
    pub kurtosis: f64,
}

/// How many Gaussian samples a mean of `n` squared standardised residuals of noise with
/// `kurtosis` is worth: its relative variance is `(kurtosis - 1) / n` where a Gaussian's is
/// `2 / n` (the `n` to give [`variance_ratio_p`]).
pub fn gaussian_equivalent_samples(n: f64, kurtosis: f64) -> f64 {
    n * 2.0 / (kurtosis - 1.0).max(2.0)
}

/// Largest kurtosis [`heavy_tailed_noise`] reports: beyond it a record's few extremes decide.
pub const MAX_KURTOSIS: f64 = 30.0;

/// The noise of `residual` (finite entries; the readings less a model's replay) when its
/// tails are heavier than a Gaussian's, `None` when they are not told apart from one.
///
/// For white noise of variance `s^2` and kurtosis `k`, the lag product
/// `P_k = -(r_k - r_{k-1}) (r_{k+1} - r_k)` has mean `s^2` and mean square `(k + 3) s^4`,
/// so `mean P^2 / (mean P)^2 - 3` estimates `k`. What is left of a slow signal takes off its
/// slope's square, and a jump `J` adds `J` times the noise, not `J^4` as it would to a
/// kurtosis of the differences; an isolated wild reading `A` adds `A^4`. On Gaussian noise
/// the estimate spreads `16.5 / sqrt(n)` (simulated, 300 to 10 000 samples, skewed to the
/// right); tails count as heavy beyond 4 of those. The variance is then the mean lag product
/// (unbiased whatever the tails, where [`noise_std_from_differences`], trimmed and corrected
/// for a Gaussian's truncation, gives 0.93 of the std on Laplace or Student-t5 noise), its
/// degrees of freedom from the products' own spread (they correlate up to lag 2). Flags 95 %
/// of Laplace and 92 % of Student-t5 records of 1800 samples, and no Gaussian one of 1000.
pub fn heavy_tailed_noise(residual: &[f64]) -> Option<HeavyTailedNoise> {
    let products: Vec<f64> = residual
        .windows(3)
        .filter(|w| w.iter().all(|v| v.is_finite()))
        .map(|w| -(w[1] - w[0]) * (w[2] - w[1]))
        .collect();
    let n = products.len() as f64;
    if products.len() < 30 {
        return None;
    }
    let mean = products.iter().sum::<f64>() / n;
    let mean_square = products.iter().map(|p| p * p).sum::<f64>() / n;
    if mean <= 0.0 {
        return None;
    }
    let kurtosis = mean_square / (mean * mean) - 3.0;
    if kurtosis <= 3.0 + 4.0 * 16.5 / n.sqrt() {
        return None;
    }
    let covariance = |lag: usize| {
        products
            .iter()
            .zip(&products[lag..])
            .map(|(a, b)| (a - mean) * (b - mean))
            .sum::<f64>()
            / n
    };
    let variance_of_mean = (covariance(0) + 2.0 * covariance(1) + 2.0 * covariance(2)) / n;
    let dof = if variance_of_mean > 0.0 {
        2.0 * mean * mean / variance_of_mean
    } else {
        n
    };
    Some(HeavyTailedNoise {
        std: mean.sqrt(),
        dof,
        kurtosis: kurtosis.min(MAX_KURTOSIS),
    })
}

/// The variance of second differences of unit-variance AR(1) noise with coefficient `phi`
/// (6 when white).
pub fn second_difference_variance(phi: f64) -> f64 {
    6.0 - 8.0 * phi + 2.0 * phi * phi
}

/// The ratio of the variances of third and second differences of AR(1) noise with
/// coefficient `phi`: `(20 - 30 phi + 12 phi^2 - 2 phi^3) / (6 - 8 phi + 2 phi^2)` (10/3 when
/// white, falling with `phi`).
fn third_to_second_difference_ratio(phi: f64) -> f64 {
    (20.0 - 30.0 * phi + 12.0 * phi * phi - 2.0 * phi.powi(3)) / second_difference_variance(phi)
}

/// The coefficient of AR(1) noise in `residual` (readings less a model's replay; NaN where
/// none) when its samples are positively correlated, `None` when they are not told apart
/// from white or are not AR(1). For AR(1) noise of coefficient `phi` the variances of the
/// second and first differences are `(6 - 8 phi + 2 phi^2) s^2` and `2 (1 - phi) s^2`, a
/// ratio of `3 - phi`, whatever slow signal the residual also carries; each is the trimmed
/// variance of [`noise_std_from_differences`], so a few jumps are left out, and those left
/// in pull the estimate down, away from correlated. On white noise the estimate spreads
/// `2.07 / sqrt(n)` (simulated, 1800 samples); correlated beyond 5 of those (0.24 at 1800
/// samples, where AR(1) noise of coefficient 0.5 reads 0.29 to 0.68). A smooth gap left in
/// the residual (a ripple) also raises it, but far less the ratio of the third and second
/// differences' variances ([`third_to_second_difference_ratio`]): the coefficient read from
/// that must agree within 3 of their difference's spread, `(3.4 + 4.4 phi) / sqrt(n)` at
/// the latter's `phi` (simulated; a ripple of twice the noise at 0.44 rad per sample reads
/// 0.79 and 0.14).
pub fn ar1_from_differences(residual: &[f64]) -> Option<f64> {
    let d1: Vec<f64> = residual
        .windows(2)
        .filter(|w| w.iter().all(|v| v.is_finite()))
        .map(|w| w[1] - w[0])
        .collect();
    let d2 = second_differences(residual);
    let d3: Vec<f64> = residual
        .windows(4)
        .filter(|w| w.iter().all(|v| v.is_finite()))
        .map(|w| w[3] - 3.0 * w[2] + 3.0 * w[1] - w[0])
        .collect();
    let (s1, _) = trimmed_std(&d1)?;
    let (s2, _) = trimmed_std(&d2)?;
    let (s3, _) = trimmed_std(&d3)?;
    let root_n = (d2.len() as f64).sqrt();
    let phi = 3.0 - (s2 / s1).powi(2);
    if phi <= 5.0 * 2.07 / root_n || phi >= 0.95 {
        return None;
    }
    // Bisection: the ratio falls as the coefficient rises on [-0.9, 0.95].
    let ratio = (s3 / s2).powi(2);
    let (mut lo, mut hi) = (-0.9f64, 0.95f64);
    for _ in 0..50 {
        let mid = 0.5 * (lo + hi);
        if third_to_second_difference_ratio(mid) > ratio {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let from_third = 0.5 * (lo + hi);
    let spread = (3.4 + 4.4 * from_third.max(0.0)) / root_n;
    ((phi - from_third).abs() <= 3.0 * spread).then_some(phi)
}

/// How many independent samples `n` consecutive samples of AR(1) noise with coefficient
/// `phi` are worth to a mean of their squares: `n (1 - phi^2) / (1 + phi^2)`.
pub fn ar1_equivalent_samples(n: f64, phi: f64) -> f64 {
    n * (1.0 - phi * phi) / (1.0 + phi * phi)
}

/// `x` (unit-variance AR(1) noise of coefficient `phi` plus whatever else) whitened:
/// `(x_k - phi x_{k-1}) / sqrt(1 - phi^2)`, the first sample as it is.
pub fn ar1_whitened(x: &[f64], phi: f64) -> Vec<f64> {
    let scale = 1.0 / (1.0 - phi * phi).sqrt();
    x.iter()
        .enumerate()
        .map(|(k, v)| {
            if k == 0 {
                *v
            } else {
                (v - phi * x[k - 1]) * scale
            }
        })
        .collect()
}

/// Periodogram of `x` (mean removed) normalised so that white noise of unit variance has
/// expected value 1 in every bin: `|X_k|^2 / n` for `k = 1..n/2`, with frequencies
/// `k / (n dt)` (Hz).
pub fn periodogram(x: &[f64], dt: f64) -> (Vec<f64>, Vec<f64>) {
    let n = x.len();
    if n < 4 {
        return (Vec::new(), Vec::new());
    }
    let mean = x.iter().sum::<f64>() / n as f64;
    let mut buf: Vec<Complex<f64>> = x.iter().map(|v| Complex::new(v - mean, 0.0)).collect();
    FftPlanner::new().plan_fft_forward(n).process(&mut buf);
    let half = n / 2;
    let freqs = (1..=half).map(|k| k as f64 / (n as f64 * dt)).collect();
    let power = buf[1..=half]
        .iter()
        .map(|c| c.norm_sqr() / n as f64)
        .collect();
    (freqs, power)
}

#[cfg(test)]
mod tests {
    use super::*;
    use prognos_core::random::standard_normal;
    use rand_core::SeedableRng;

    #[test]
    fn chi_square_tail_matches_tables() {
        // chi2(10) 95th percentile 18.307; chi2(1) at 3.841 -> 0.05; chi2(100) at 124.342.
        assert!((chi2_sf(18.307, 10.0) - 0.05).abs() < 1e-4);
        assert!((chi2_sf(3.841, 1.0) - 0.05).abs() < 1e-4);
        assert!((chi2_sf(124.342, 100.0) - 0.05).abs() < 1e-4);
        assert!((normal_sf(1.959_964) - 0.025).abs() < 1e-6);
    }

    #[test]
    fn holm_adjusts_step_down() {
        let adj = holm(&[0.01, 0.04, 0.03, 0.5]);
        assert_eq!(adj, vec![0.04, 0.09, 0.09, 0.5]);
    }

    #[test]
    fn white_noise_passes_and_noise_std_is_recovered() {
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(3);
        let x: Vec<f64> = (0..5000)
            .map(|k| 0.2 * standard_normal::<f64, _>(&mut rng) + (k as f64 * 1e-3).sin())
            .collect();
        let (sigma, dof) = noise_std_from_differences(&x).unwrap();
        assert!((sigma - 0.2).abs() < 0.01, "{sigma}");
        assert!(dof > 1000.0);
        let white: Vec<f64> = (0..5000).map(|_| standard_normal(&mut rng)).collect();
        let (_, p) = ljung_box(&white, 20);
        assert!(p > 0.01, "{p}");
        let mut ar = vec![0.0f64; 5000];
        for k in 1..5000 {
            ar[k] = 0.3 * ar[k - 1] + white[k];
        }
        assert!(ljung_box(&ar, 20).1 < 1e-10);
    }

    #[test]
    fn readings_on_a_repeated_level_are_left_out_of_the_noise_estimate() {
        // Noise 0.2 on a sine of amplitude 3 read through a clip at [-1, 2]: about two
        // thirds of the readings sit on a limit with zero differences, and the plain
        // estimate falls to about half the noise.
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(5);
        let y: Vec<f64> = (0..5000)
            .map(|k| {
                let v = 3.0 * (k as f64 * 2e-3).sin() + 0.2 * standard_normal::<f64, _>(&mut rng);
                v.clamp(-1.0, 2.0)
            })
            .collect();
        let (plain, _) = noise_std_from_differences(&y).unwrap();
        assert!(plain < 0.15, "{plain}");
        let kept = without_repeated_levels(&y);
        assert_eq!(
            kept.iter().filter(|v| v.is_nan()).count(),
            y.iter().filter(|v| **v == -1.0 || **v == 2.0).count()
        );
        let (sigma, _) = noise_std_from_differences(&kept).unwrap();
        assert!((sigma - 0.2).abs() < 0.01, "{sigma}");
        // A deadband zeroing the readings within 1.5 of zero (about a third of them).
        let zeroed: Vec<f64> = (0..5000)
            .map(|k| {
                let v = 3.0 * (k as f64 * 2e-3).sin() + 0.2 * standard_normal::<f64, _>(&mut rng);
                if v.abs() < 1.5 { 0.0 } else { v }
            })
            .collect();
        assert!(noise_std_from_differences(&zeroed).unwrap().0 < 0.17);
        let kept = without_repeated_levels(&zeroed);
        assert!(kept.iter().filter(|v| v.is_nan()).count() > 1000);
        let (sigma, _) = noise_std_from_differences(&kept).unwrap();
        assert!((sigma - 0.2).abs() < 0.01, "{sigma}");
        // A noisy record without a clip keeps every reading.
        let free: Vec<f64> = y
            .iter()
            .map(|v| v + 1e-3 * standard_normal::<f64, _>(&mut rng))
            .collect();
        assert!(without_repeated_levels(&free).iter().all(|v| v.is_finite()));
    }

    #[test]
    fn persistence_flags_a_lingering_signal_not_an_alternating_one() {
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(8);
        // Under white noise the statistic is standard normal: 400 records of 2000 samples.
        let z: Vec<f64> = (0..400)
            .map(|_| {
                let w: Vec<f64> = (0..2000).map(|_| standard_normal(&mut rng)).collect();
                persistence(&w, 20).0
            })
            .collect();
        let mean = z.iter().sum::<f64>() / z.len() as f64;
        let var = z.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / (z.len() - 1) as f64;
        assert!(mean.abs() < 0.15 && (var - 1.0).abs() < 0.2, "{mean} {var}");
        let white: Vec<f64> = (0..5000).map(|_| standard_normal(&mut rng)).collect();
        // A slowly decaying AR(1) lingers. A filter's over-correction alternates: a scalar
        // one as an MA(1) with a negative coefficient, a two-state one with a positive
        // echo at lag 2 (the scooter's front wheel: -0.57, +0.13, +0.09). Ljung-Box
        // rejects all three.
        let mut ar = vec![0.0f64; 5000];
        let mut alternating = vec![0.0f64; 5000];
        let mut echo = vec![0.0f64; 5000];
        for k in 2..5000 {
            ar[k] = 0.5 * ar[k - 1] + white[k];
            alternating[k] = white[k] - 0.3 * white[k - 1];
            echo[k] = white[k] - 0.8 * white[k - 1] + 0.3 * white[k - 2];
        }
        assert!(persistence(&ar, 20).1 < 1e-10);
        assert!(persistence(&alternating, 20).1 > 0.99);
        assert!(persistence(&echo, 20).1 > 0.99);
        assert!(ljung_box(&alternating, 20).1 < 1e-10);
        assert!(ljung_box(&echo, 20).1 < 1e-10);
        assert!(ljung_box(&alternating, 20).1 < 1e-10);
    }

    #[test]
    fn noise_std_spreads_as_its_degrees_of_freedom_say_and_shrugs_off_steps() {
        // 200 records of 1800 samples (a 90 s valve record). Pure noise: the relative spread
        // of the estimates is the chi-square one of the stated dof (1 / sqrt(2 dof), 2.4 %;
        // the MAD alone spreads 3.4 %). A staircase of 10-sigma steps every 50 samples (4 %
        // of the differences hit): the mean is off by 2 % (the MAD alone: 5 %).
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(5);
        for (step, bias) in [(0.0, 0.01), (10.0, 0.03)] {
            let (mut sum, mut sum2, mut dof_sum) = (0.0, 0.0, 0.0);
            let records = 200;
            for _ in 0..records {
                let x: Vec<f64> = (0..1800)
                    .map(|k| standard_normal::<f64, _>(&mut rng) + step * (k / 50) as f64)
                    .collect();
                let (sigma, dof) = noise_std_from_differences(&x).unwrap();
                sum += sigma;
                sum2 += sigma * sigma;
                dof_sum += dof;
            }
            let mean = sum / records as f64;
            let spread = (sum2 / records as f64 - mean * mean).sqrt() / mean;
            let stated = 1.0 / (2.0 * dof_sum / records as f64).sqrt();
            assert!((mean - 1.0).abs() < bias, "step {step}: {mean}");
            assert!(
                spread < 1.25 * stated && spread > 0.75 * stated,
                "{spread} vs {stated}"
            );
        }
    }

    #[test]
    fn heavy_tails_are_told_from_gaussian_noise_and_their_variance_is_not_trimmed_away() {
        // 1000 records of 1800 samples on a slow sine, per shape: the share flagged heavy,
        // the mean std reported when flagged, and the trimmed estimate's mean beside it.
        use crate::gap::bench::NoiseShape;
        let records = 1000;
        for shape in [
            NoiseShape::Gaussian,
            NoiseShape::Laplace,
            NoiseShape::StudentT5,
        ] {
            let mut rng = crate::lockstep::stream_rng(9, 1);
            let (mut flagged, mut std_sum, mut trimmed_sum) = (0, 0.0, 0.0);
            for _ in 0..records {
                let x: Vec<f64> = (0..1800)
                    .map(|k| shape.sample(&mut rng, 0.0) + 5.0 * (k as f64 * 3e-3).sin())
                    .collect();
                if let Some(tails) = heavy_tailed_noise(&x) {
                    flagged += 1;
                    std_sum += tails.std;
                    trimmed_sum += noise_std_from_differences(&x).unwrap().0;
                    assert!(tails.kurtosis > 3.0 && tails.dof > 20.0, "{tails:?}");
                }
            }
            let share = flagged as f64 / records as f64;
            let mean_std = std_sum / flagged.max(1) as f64;
            let trimmed = trimmed_sum / flagged.max(1) as f64;
            println!("{shape:?}: flagged {share}, std {mean_std:.4}, trimmed {trimmed:.4}");
            if shape == NoiseShape::Gaussian {
                assert!(share < 0.01, "{shape:?}: {share}");
            } else {
                assert!(share > 0.85, "{shape:?}: {share}");
                assert!((mean_std - 1.0).abs() < 0.02, "{shape:?}: {mean_std}");
                assert!(trimmed < 0.95, "{shape:?}: trimmed {trimmed}");
            }
        }
    }

    #[test]
    fn correlated_noise_is_told_from_white_and_its_coefficient_recovered() {
        // 500 records of 1800 samples on a slow sine: white noise (alone, with 10-std jumps
        // every 50 samples) is never flagged, nor with a ripple of twice its std at 0.44 rad
        // per sample but once in 100; AR(1) noise of coefficient 0.5 nearly always, its
        // coefficient within 0.02 on average.
        use crate::gap::bench::NoiseShape;
        for (shape, jump, ripple) in [
            (NoiseShape::Gaussian, 0.0, 0.0),
            (NoiseShape::Gaussian, 10.0, 0.0),
            (NoiseShape::Gaussian, 0.0, 2.0),
            (NoiseShape::Ar1, 0.0, 0.0),
        ] {
            let mut rng = crate::lockstep::stream_rng(11, 1);
            let (mut flagged, mut sum) = (0, 0.0);
            for _ in 0..500 {
                let mut previous = 0.0;
                let x: Vec<f64> = (0..1800)
                    .map(|k| {
                        previous = shape.sample(&mut rng, previous);
                        previous
                            + 5.0 * (k as f64 * 3e-3).sin()
                            + jump * (k / 50) as f64
                            + ripple * 2f64.sqrt() * (0.44 * k as f64).sin()
                    })
                    .collect();
                if let Some(phi) = ar1_from_differences(&x) {
                    flagged += 1;
                    sum += phi;
                }
            }
            if shape == NoiseShape::Ar1 {
                assert!(flagged >= 490, "{flagged}");
                assert!((sum / flagged as f64 - 0.5).abs() < 0.02, "{}", sum / 500.0);
            } else {
                // The ripple: 2 of 500 at this seed.
                let allowed = if ripple > 0.0 { 5 } else { 0 };
                assert!(flagged <= allowed, "jump {jump} ripple {ripple}: {flagged}");
            }
        }
        assert!((second_difference_variance(0.5) - 2.5).abs() < 1e-12);
        assert!((third_to_second_difference_ratio(0.0) - 10.0 / 3.0).abs() < 1e-12);
    }

    #[test]
    fn periodogram_of_unit_white_noise_averages_one() {
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(4);
        let x: Vec<f64> = (0..4096).map(|_| standard_normal(&mut rng)).collect();
        let (f, p) = periodogram(&x, 0.05);
        assert_eq!(f.len(), 2048);
        assert!((f[2047] - 10.0).abs() < 1e-9);
        let mean = p.iter().sum::<f64>() / p.len() as f64;
        assert!((mean - 1.0).abs() < 0.06, "{mean}");
    }
}
