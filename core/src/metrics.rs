//! Prognostics performance metrics (Daigle & Goebel 2011 Appendix; Saxena et al. 2010; Anger
//! et al. 2012 Eqs. 25-31; Barbieri et al. 2021 Eqs. 34-35). All allocation-free: functions
//! that need a median reorder the caller's slice.

use crate::real::{Real, cast};
use crate::stats::median_in_place;

/// Root mean square percentage error `100 sqrt(mean(((est - truth) / truth)^2))`, the valve
/// paper's PRMSE and the reaction-wheel paper's RMSPE. Pairs with a zero or non-finite truth
/// or estimate are skipped; `None` when none remain.
pub fn rmspe<T: Real>(estimates: &[T], truth: &[T]) -> Option<T> {
    let (mut acc, mut n) = (T::zero(), 0usize);
    for (&e, &t) in estimates.iter().zip(truth) {
        if e.finite() && t.finite() && t != T::zero() {
            let r = (e - t) / t;
            acc += r * r;
            n = n.saturating_add(1);
        }
    }
    (n > 0).then(|| cast::<T>(100.0) * (acc / cast(n as f64)).sqrt())
}

/// Relative median absolute deviation of a sample in percent of its median (reorders `values`).
pub fn rmad<T: Real>(values: &mut [T]) -> Option<T> {
    let (median, mad) = crate::stats::mad_in_place(values)?;
    (median != T::zero()).then(|| cast::<T>(100.0) * mad / median.abs())
}

/// Relative accuracy `100 (1 - |RUL* - RUL| / RUL*)` of one prediction (the valve paper uses
/// the median of the RUL distribution as `predicted`). `None` for a non-positive true RUL.
pub fn relative_accuracy<T: Real>(true_rul: T, predicted: T) -> Option<T> {
    (true_rul > T::zero() && predicted.finite())
        .then(|| cast::<T>(100.0) * (T::one() - (true_rul - predicted).abs() / true_rul))
}

/// Relative standard deviation of a sample in percent of its mean.
pub fn relative_std<T: Real>(values: &[T]) -> Option<T> {
    let n = values.len();
    if n < 2 {
        return None;
    }
    let nf: T = cast(n as f64);
    let mean = values.iter().fold(T::zero(), |a, &v| a + v) / nf;
    let var = values
        .iter()
        .fold(T::zero(), |a, &v| a + (v - mean) * (v - mean))
        / (nf - T::one());
    (mean != T::zero()).then(|| cast::<T>(100.0) * var.sqrt() / mean.abs())
}

/// Convergence of a metric curve (Saxena et al. 2010): the distance from `(times[0], 0)` to
/// the centroid of the area under the piecewise-constant curve `values` over `times`. Smaller
/// is better (faster convergence). Needs at least two points and a positive area.
pub fn convergence<T: Real>(times: &[T], values: &[T]) -> Option<T> {
    let t0 = *times.first()?;
    let half: T = cast(0.5);
    let (mut area, mut mx, mut my) = (T::zero(), T::zero(), T::zero());
    for (w, &m) in times.windows(2).zip(values) {
        let (a, b) = match w {
            [a, b] => (*a, *b),
            _ => continue,
        };
        let m = m.abs();
        area += (b - a) * m;
        mx += half * (b * b - a * a) * m;
        my += half * (b - a) * m * m;
    }
    if !(area > T::zero()) {
        return None;
    }
    let (xc, yc) = (mx / area, my / area);
    Some(((xc - t0) * (xc - t0) + yc * yc).sqrt())
}

/// Whether a prediction lies within the alpha band `[(1 - alpha) RUL*, (1 + alpha) RUL*]`
/// (Anger et al. Eqs. 30-31; alpha-lambda accuracy evaluates it at the lambda points).
pub fn within_alpha<T: Real>(true_rul: T, predicted: T, alpha: T) -> bool {
    predicted.finite()
        && predicted >= (T::one() - alpha) * true_rul
        && predicted <= (T::one() + alpha) * true_rul
}

/// Fraction of predictions inside the relative alpha band (alpha-lambda accuracy over all
/// prediction points).
pub fn alpha_lambda_accuracy<T: Real>(true_rul: &[T], predicted: &[T], alpha: T) -> Option<T> {
    let n = true_rul.len().min(predicted.len());
    if n == 0 {
        return None;
    }
    let hits = true_rul
        .iter()
        .zip(predicted)
        .filter(|&(&t, &p)| within_alpha(t, p, alpha))
        .count();
    Some(cast::<T>(hits as f64) / cast(n as f64))
}

/// How the prognostic-horizon error band is measured.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HorizonBand {
    /// `|RUL* - RUL| <= alpha * t_EOL` (Saxena et al.; Barbieri et al. Eq. 35).
    FractionOfEol,
    /// `(1 - alpha) RUL* <= RUL <= (1 + alpha) RUL*` (Anger et al. Eq. 30).
    FractionOfRul,
}

/// Prognostic horizon `t_EOL - t_k_alpha`: `t_k_alpha` is the first prediction time from which
/// every later prediction stays inside the band. `None` when the last prediction is outside.
pub fn prognostic_horizon<T: Real>(
    times: &[T],
    true_rul: &[T],
    predicted: &[T],
    eol: T,
    alpha: T,
    band: HorizonBand,
) -> Option<T> {
    let inside = |t: T, p: T| match band {
        HorizonBand::FractionOfEol => p.finite() && (t - p).abs() <= alpha * eol,
        HorizonBand::FractionOfRul => within_alpha(t, p, alpha),
    };
    let mut first_of_final_run = None;
    for ((&tk, &t), &p) in times.iter().zip(true_rul).zip(predicted) {
        if inside(t, p) {
            if first_of_final_run.is_none() {
                first_of_final_run = Some(tk);
            }
        } else {
            first_of_final_run = None;
        }
    }
    first_of_final_run.map(|tk| eol - tk)
}

/// Average bias `mean(RUL* - RUL)` (Anger et al. Eq. 26; negative is late, positive early).
pub fn average_bias<T: Real>(true_rul: &[T], predicted: &[T]) -> Option<T> {
    mean_of(true_rul, predicted, |d, _| d)
}

/// Mean squared error of the RUL predictions (Anger et al. Eq. 28).
pub fn mean_squared_error<T: Real>(true_rul: &[T], predicted: &[T]) -> Option<T> {
    mean_of(true_rul, predicted, |d, _| d * d)
}

/// Mean absolute percentage error of the RUL predictions (Anger et al. Eq. 27); points with a
/// zero true RUL are skipped.
pub fn mean_absolute_percentage_error<T: Real>(true_rul: &[T], predicted: &[T]) -> Option<T> {
    let (mut acc, mut n) = (T::zero(), 0usize);
    for (&t, &p) in true_rul.iter().zip(predicted) {
        if t != T::zero() && t.finite() && p.finite() {
            acc += cast::<T>(100.0) * ((t - p) / t).abs();
            n = n.saturating_add(1);
        }
    }
    (n > 0).then(|| acc / cast(n as f64))
}

fn mean_of<T: Real>(a: &[T], b: &[T], f: impl Fn(T, T) -> T) -> Option<T> {
    let (mut acc, mut n) = (T::zero(), 0usize);
    for (&t, &p) in a.iter().zip(b) {
        if t.finite() && p.finite() {
            acc += f(t - p, t);
            n = n.saturating_add(1);
        }
    }
    (n > 0).then(|| acc / cast(n as f64))
}

/// Median of a sample (reorders it), re-exported for metric tables.
pub fn median<T: Real>(values: &mut [T]) -> Option<T> {
    median_in_place(values)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rmspe_and_ra() {
        assert!((rmspe::<f64>(&[1.1, 0.9], &[1.0, 1.0]).unwrap() - 10.0).abs() < 1e-9);
        assert_eq!(rmspe::<f64>(&[1.0], &[0.0]), None);
        assert!((relative_accuracy::<f64>(20.0, 18.0).unwrap() - 90.0).abs() < 1e-12);
        assert_eq!(relative_accuracy(0.0, 1.0), None);
    }

    #[test]
    fn rmad_of_known_sample() {
        let mut v: [f64; 5] = [9.0, 10.0, 11.0, 10.0, 30.0];
        // median 10, |dev| = 1,0,1,0,20 -> MAD 1 -> 10 %.
        assert!((rmad(&mut v).unwrap() - 10.0).abs() < 1e-12);
    }

    #[test]
    fn convergence_of_step_curve() {
        // Constant error 1 on [0, 10]: centroid (5, 0.5) -> distance sqrt(25.25).
        let t = [0.0, 5.0, 10.0];
        let v = [1.0, 1.0, 1.0];
        assert!((convergence(&t, &v).unwrap() - 25.25f64.sqrt()).abs() < 1e-12);
        // A curve that decays converges closer to the origin.
        let fast = convergence(&t, &[1.0, 0.1, 0.0]).unwrap();
        assert!(fast < convergence(&t, &v).unwrap());
    }

    #[test]
    fn horizon_requires_staying_in_band() {
        let times = [0.0, 10.0, 20.0, 30.0];
        let truth = [40.0, 30.0, 20.0, 10.0];
        let pred = [60.0, 29.0, 30.0, 11.0];
        // alpha 0.2 of EOL 40 = 8: in, in(1), out(10), in(1) -> horizon from t=30 -> 10.
        let ph = prognostic_horizon(&times, &truth, &pred, 40.0, 0.2, HorizonBand::FractionOfEol);
        assert_eq!(ph, Some(10.0));
        let pred = [60.0, 29.0, 21.0, 11.0];
        let ph = prognostic_horizon(&times, &truth, &pred, 40.0, 0.2, HorizonBand::FractionOfEol);
        assert_eq!(ph, Some(30.0));
        let pred_bad_end = [40.0, 30.0, 20.0, 30.0];
        let ph = prognostic_horizon(
            &times,
            &truth,
            &pred_bad_end,
            40.0,
            0.2,
            HorizonBand::FractionOfRul,
        );
        assert_eq!(ph, None);
    }

    #[test]
    fn bias_mse_mape() {
        let t: [f64; 2] = [10.0, 20.0];
        let p = [8.0, 22.0];
        assert_eq!(average_bias(&t, &p), Some(0.0));
        assert_eq!(mean_squared_error(&t, &p), Some(4.0));
        assert!((mean_absolute_percentage_error(&t, &p).unwrap() - 15.0).abs() < 1e-12);
        assert_eq!(alpha_lambda_accuracy(&t, &p, 0.2), Some(1.0));
        assert_eq!(alpha_lambda_accuracy(&t, &p, 0.15), Some(0.5));
        assert!((relative_std(&[9.0, 11.0]).unwrap() - 100.0 * 2f64.sqrt() / 10.0).abs() < 1e-12);
    }
}
