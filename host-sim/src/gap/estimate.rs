//! The downstream estimation error: the project's estimator for a plant (prognos-core's
//! [`Ukf`]) run over a record with the user's model, then with the fitted effect added, and
//! its state estimates compared with the record's truth columns.
//!
//! A plant opts in through [`crate::gap::plant::GapPlant::estimate`], usually by handing
//! its one-step model to [`run_ukf`]. The sensors the filter sees are those of the
//! candidate: its generic sensor effects enter the measurement function when they are a
//! static map of the model's output (bias, scale, clipping, dead zone), a quantiser as the
//! rounding noise it adds, and effects that act over time are undone on the readings (a
//! delay is shifted back, a first-order lag inverted, its noise amplified by the inversion
//! and declared so).

use crate::gap::effects::GenericKind;
use nalgebra::{SMatrix, SVector};
use prognos_core::filter::ukf::{SigmaParams, Ukf};
use prognos_core::model::{Model, Observe};
use std::collections::BTreeMap;

/// What the estimator is told about one output channel of the plant.
#[derive(Clone, Debug, PartialEq)]
pub struct ChannelSensor {
    /// Readings as the model's output would show them (a delay or lag undone; NaN: no
    /// reading, as for a channel the record does not have).
    pub readings: Vec<f64>,
    /// Noise std of a reading (after any inversion).
    pub sigma: f64,
    /// Static sensor effects applied to the model's output, in order.
    pub maps: Vec<(GenericKind, Vec<f64>)>,
}

impl ChannelSensor {
    /// A channel the record does not have.
    pub fn absent(n: usize) -> Self {
        Self {
            readings: vec![f64::NAN; n],
            sigma: 1.0,
            maps: Vec::new(),
        }
    }

    /// The channel as a sensor with `effects` (generic kind and its fitted values) reads
    /// `measured`, sampled every `dt`, with noise std `sigma` (a quantiser's values: step,
    /// noise before it, threshold, lattice offset; a lag's: time constant and, where the
    /// noise went through it, the noise std before it). `on_lattice`: the readings lie on a
    /// quantiser's lattice ([`crate::gap::effects::Problem::lattices`]), so no noise came
    /// after it.
    pub fn new(
        measured: &[f64],
        sigma: f64,
        dt: f64,
        effects: &[(GenericKind, Vec<f64>)],
        on_lattice: bool,
    ) -> Self {
        let mut readings = measured.to_vec();
        let mut sigma = sigma;
        let mut maps = Vec::new();
        for (kind, values) in effects {
            let p = values.first().copied().unwrap_or(0.0);
            match kind {
                GenericKind::MeasurementDelay => readings = advanced(&readings, p / dt),
                GenericKind::FirstOrderLag => {
                    let alpha = 1.0 - (-dt / p.max(1e-12)).exp();
                    readings = unlagged(&readings, alpha);
                    // Undone, noise that went through the lag is the noise before it
                    // (the values' second, where given); noise after it is amplified.
                    sigma = match values.get(1) {
                        Some(&before) => before,
                        None => sigma * (1.0 + (1.0 - alpha).powi(2)).sqrt() / alpha.max(1e-12),
                    };
                }
                GenericKind::Quantisation => {
                    // Read as the model's output plus rounding noise of variance
                    // step^2 / 12 on the noise fitted before the quantiser: through the
                    // staircase of its mean the sigma points would see steps, not a slope.
                    // Readings off its lattice carry the channel's noise after it too.
                    let before = values.get(1).copied().unwrap_or(sigma);
                    let after = if on_lattice { 0.0 } else { sigma };
                    sigma = (before * before + p * p / 12.0 + after * after).sqrt();
                    // Thresholds above round-to-nearest lower the mean reading.
                    let threshold = values.get(2).copied().unwrap_or(0.0);
                    maps.push((GenericKind::SensorBias, vec![-threshold * p]));
                }
                _ => maps.push((*kind, values.clone())),
            }
        }
        Self {
            readings,
            sigma,
            maps,
        }
    }

    /// The reading of model output `v` (noise-free).
    pub fn read(&self, v: f64) -> f64 {
        self.maps.iter().fold(v, |y, (kind, values)| {
            kind.static_reading(values, y).unwrap_or(y)
        })
    }
}

/// `y` read `shift` samples later (`y(t + shift dt)`, linear between samples; NaN beyond
/// the end): a delayed sensor's reading of the model's output at `t`.
fn advanced(y: &[f64], shift: f64) -> Vec<f64> {
    let shift = shift.max(0.0);
    let whole = shift.floor() as usize;
    let frac = shift - shift.floor();
    (0..y.len())
        .map(|k| match (y.get(k + whole), y.get(k + whole + 1)) {
            (Some(a), Some(b)) => (1.0 - frac) * a + frac * b,
            (Some(a), None) if frac == 0.0 => *a,
            _ => f64::NAN,
        })
        .collect()
}

/// The input of the first-order lag `s_k = s_{k-1} + alpha (v_k - s_{k-1})` that read `y`.
fn unlagged(y: &[f64], alpha: f64) -> Vec<f64> {
    let alpha = alpha.max(1e-12);
    (0..y.len())
        .map(|k| match k.checked_sub(1).map(|j| y[j]) {
            Some(prev) => prev + (y[k] - prev) / alpha,
            None => y[k],
        })
        .collect()
}

/// Every output channel of a plant as the estimator sees it, in the plant's output order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Sensors {
    /// One per output of [`crate::gap::plant::GapPlant::outputs`].
    pub channels: Vec<ChannelSensor>,
}

/// What a plant's estimator made of a record.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Estimates {
    /// State estimates after each sample, by state name (as truth columns `x:<name>`).
    pub states: BTreeMap<String, Vec<f64>>,
    /// Per output channel (the plant's order), each sample's innovation over its predicted
    /// standard deviation, `nu / sqrt(S)`: standard normal and white when the model and its
    /// noise are right; NaN where there was no reading or it could not be fused.
    pub innovations: Vec<Vec<f64>>,
}

/// A plant's one-step model for [`run_ukf`]: `step(x, u, dt)` from one sample to the next,
/// `outputs(x, k)` the model's outputs at sample `k` in the plant's order (a plant whose
/// outputs read an input takes it from the record's row `k`).
pub struct StepModel<F, H> {
    /// One step of the model.
    pub step: F,
    /// The model's outputs.
    pub outputs: H,
}

impl<F, H, const NX: usize, const NU: usize> Model<f64, NX, NU> for StepModel<F, H>
where
    F: Fn(&SVector<f64, NX>, &SVector<f64, NU>, f64) -> SVector<f64, NX>,
{
    fn step(&self, x: &SVector<f64, NX>, u: &SVector<f64, NU>, dt: f64) -> SVector<f64, NX> {
        (self.step)(x, u, dt)
    }
}

/// One channel of a [`StepModel`] as its sensor reads it (the filter fuses channels one at
/// a time, so a record may miss any of them at any sample).
struct ChannelModel<'a, F, H> {
    model: &'a StepModel<F, H>,
    sensor: &'a ChannelSensor,
    channel: usize,
    sample: usize,
}

impl<F, H, const NX: usize, const NU: usize, const NY: usize> Observe<f64, NX, NU, 1>
    for ChannelModel<'_, F, H>
where
    H: Fn(&SVector<f64, NX>, usize) -> SVector<f64, NY>,
{
    fn observe(&self, x: &SVector<f64, NX>, _u: &SVector<f64, NU>) -> SVector<f64, 1> {
        let output = (self.model.outputs)(x, self.sample)[self.channel];
        SVector::<f64, 1>::new(self.sensor.read(output))
    }
}

/// How the filter of [`run_ukf`] starts and how much it trusts the model.
pub struct FilterSetup<const NX: usize> {
    /// Initial state.
    pub x0: SVector<f64, NX>,
    /// Initial covariance (diagonal).
    pub p0: SVector<f64, NX>,
    /// Process noise per second (diagonal; the filter uses `q dt` per step).
    pub q_rate: SVector<f64, NX>,
    /// Bounds the estimate is clamped to after each sample's updates (as the core's
    /// adaptive UKF projects its fault parameters), if any.
    pub bounds: Option<(SVector<f64, NX>, SVector<f64, NX>)>,
}

/// Runs the core's UKF over a record of `n` samples at times `t`: predict with `inputs(k)`
/// (the input over the step from sample `k` to `k + 1`), then fuse each channel's reading
/// at the new sample. Returns the estimate after each sample, as `names` (state name,
/// index) select, and every reading's standardised innovation. A failed prediction ends
/// the run with its time; a failed update skips that reading (the filter stays as it was).
pub fn run_ukf<F, H, const NX: usize, const NS: usize, const NU: usize, const NY: usize>(
    model: &StepModel<F, H>,
    setup: &FilterSetup<NX>,
    t: &[f64],
    inputs: impl Fn(usize) -> SVector<f64, NU>,
    sensors: &Sensors,
    names: &[(&str, usize)],
) -> Result<Estimates, String>
where
    F: Fn(&SVector<f64, NX>, &SVector<f64, NU>, f64) -> SVector<f64, NX>,
    H: Fn(&SVector<f64, NX>, usize) -> SVector<f64, NY>,
{
    if sensors.channels.len() != NY {
        return Err(format!(
            "{} sensors for {NY} outputs",
            sensors.channels.len()
        ));
    }
    let mut ukf = Ukf::<f64, NX, NS>::new(
        setup.x0,
        SMatrix::from_diagonal(&setup.p0),
        SMatrix::zeros(),
        SigmaParams::default(),
    )
    .map_err(|e| format!("the estimator cannot start: {e}"))?;
    let mut out: Vec<Vec<f64>> = names.iter().map(|_| Vec::with_capacity(t.len())).collect();
    let mut innovations = vec![vec![f64::NAN; t.len()]; NY];
    for k in 0..t.len() {
        if k > 0 {
            let dt = t[k] - t[k - 1];
            ukf.set_process_noise(SMatrix::from_diagonal(&(setup.q_rate * dt)))
                .map_err(|e| format!("process noise: {e}"))?;
            ukf.predict(model, &inputs(k - 1), dt)
                .map_err(|e| format!("the estimator failed at t = {}: {e}", t[k]))?;
        }
        let u = SVector::<f64, NU>::zeros();
        for (channel, sensor) in sensors.channels.iter().enumerate() {
            let y = sensor.readings.get(k).copied().unwrap_or(f64::NAN);
            if !y.is_finite() {
                continue;
            }
            let r = SMatrix::<f64, 1, 1>::new(sensor.sigma * sensor.sigma);
            let observe = ChannelModel {
                model,
                sensor,
                channel,
                sample: k,
            };
            // A reading the filter cannot fuse (a covariance that lost definiteness) is
            // skipped; the estimate stays where it was.
            if let Ok(report) = ukf.update(&observe, &u, &[y], &r) {
                let s = report.innovation_cov[(0, 0)];
                if s > 0.0 {
                    innovations[channel][k] = report.innovation[0] / s.sqrt();
                }
            }
        }
        if let Some((lo, hi)) = &setup.bounds {
            let clamped = ukf
                .state()
                .zip_zip_map(lo, hi, |x, lo, hi| x.max(lo).min(hi));
            // A clamped state is always finite and the covariance is kept: cannot fail.
            let _ = ukf.set_state(clamped);
        }
        for (o, (_, i)) in out.iter_mut().zip(names) {
            o.push(ukf.state()[*i]);
        }
    }
    Ok(Estimates {
        states: names
            .iter()
            .zip(out)
            .map(|((name, _), v)| (name.to_string(), v))
            .collect(),
        innovations,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Vector1, Vector2};

    /// A constant-velocity track measured in position: the UKF on a linear model is the
    /// Kalman filter, so its steady-state gain must match the Riccati solution.
    #[test]
    fn on_a_linear_model_the_estimate_is_the_kalman_filters() {
        let model = StepModel {
            step: |x: &Vector2<f64>, _u: &Vector1<f64>, dt: f64| {
                Vector2::new(x[0] + dt * x[1], x[1])
            },
            outputs: |x: &Vector2<f64>, _: usize| Vector1::new(x[0]),
        };
        let n = 400;
        let t: Vec<f64> = (0..n).map(|k| k as f64 * 0.1).collect();
        let truth: Vec<f64> = t.iter().map(|t| 1.0 + 0.5 * t).collect();
        // Deterministic "noise" with zero mean.
        let measured: Vec<f64> = truth
            .iter()
            .enumerate()
            .map(|(k, v)| v + 0.05 * ((k * 7919 % 13) as f64 / 6.0 - 1.0))
            .collect();
        let sensors = Sensors {
            channels: vec![ChannelSensor::new(&measured, 0.05, 0.1, &[], false)],
        };
        let setup = FilterSetup {
            x0: Vector2::new(measured[0], 0.0),
            p0: Vector2::new(0.05f64.powi(2), 1.0),
            q_rate: Vector2::new(0.0, 1e-6),
            bounds: None,
        };
        let est = run_ukf::<_, _, 2, 5, 1, 1>(
            &model,
            &setup,
            &t,
            |_| Vector1::new(0.0),
            &sensors,
            &[("position", 0), ("velocity", 1)],
        )
        .unwrap();
        // The same filter written out as a Kalman filter.
        let (mut x, mut p) = (
            Vector2::new(measured[0], 0.0),
            nalgebra::Matrix2::new(0.0025, 0.0, 0.0, 1.0),
        );
        let f = nalgebra::Matrix2::new(1.0, 0.1, 0.0, 1.0);
        let q = nalgebra::Matrix2::new(0.0, 0.0, 0.0, 1e-7);
        for (k, reading) in measured.iter().enumerate() {
            if k > 0 {
                x = f * x;
                p = f * p * f.transpose() + q;
            }
            let s = p[(0, 0)] + 0.0025;
            let innovation = (reading - x[0]) / s.sqrt();
            assert!((est.innovations[0][k] - innovation).abs() < 1e-9, "{k}");
            let gain = Vector2::new(p[(0, 0)], p[(1, 0)]) / s;
            x += gain * (reading - x[0]);
            p -= gain * Vector2::new(p[(0, 0)], p[(0, 1)]).transpose();
            assert!((est.states["position"][k] - x[0]).abs() < 1e-9, "{k}");
            assert!((est.states["velocity"][k] - x[1]).abs() < 1e-9, "{k}");
        }
        assert!((est.states["velocity"][n - 1] - 0.5).abs() < 0.01);
    }

    #[test]
    #[allow(clippy::needless_range_loop)]
    fn sensor_effects_are_read_or_undone() {
        let dt = 0.1;
        let model_out: Vec<f64> = (0..50).map(|k| (k as f64 * 0.3).sin()).collect();
        // A bias and a clip are read through the measurement function.
        let static_sensor = ChannelSensor::new(
            &model_out,
            0.01,
            dt,
            &[
                (GenericKind::SensorBias, vec![0.2]),
                (GenericKind::OutputSaturation, vec![0.9]),
            ],
            false,
        );
        assert_eq!(static_sensor.read(1.0), 0.9);
        assert!((static_sensor.read(0.1) - 0.3).abs() < 1e-12);
        // A delay of 2.5 samples is shifted back, a lag inverted.
        let delayed = GenericKind::MeasurementDelay.apply(&[0.25], &model_out, dt);
        let s = ChannelSensor::new(
            &delayed,
            0.01,
            dt,
            &[(GenericKind::MeasurementDelay, vec![0.25])],
            false,
        );
        for k in 3..45 {
            // Linear interpolation twice (the delay's, then its undoing) is off by the
            // curvature only.
            assert!((s.readings[k] - model_out[k]).abs() < 0.05, "{k}");
        }
        assert!(s.readings[49].is_nan());
        let lagged = GenericKind::FirstOrderLag.apply(&[0.3], &model_out, dt);
        let s = ChannelSensor::new(
            &lagged,
            0.01,
            dt,
            &[(GenericKind::FirstOrderLag, vec![0.3])],
            false,
        );
        for k in 1..50 {
            assert!((s.readings[k] - model_out[k]).abs() < 1e-9, "{k}");
        }
        assert!(s.sigma > 0.03);
        // Noise that went through the lag is, undone, the noise before it.
        let s = ChannelSensor::new(
            &lagged,
            0.01,
            dt,
            &[(GenericKind::FirstOrderLag, vec![0.3, 0.02])],
            false,
        );
        assert_eq!(s.sigma, 0.02);
    }

    #[test]
    fn a_quantisers_reading_noise_adds_the_channels_noise_only_off_its_lattice() {
        let step = 0.5;
        let model_out: Vec<f64> = (0..50).map(|k| 3.0 * (k as f64 * 0.3).sin()).collect();
        let on: Vec<f64> = model_out
            .iter()
            .map(|v| step * (v / step).round())
            .collect();
        let off: Vec<f64> = on
            .iter()
            .enumerate()
            .map(|(k, v)| v + 0.1 * (k as f64 * 1.7).sin())
            .collect();
        // Step, noise before the quantiser, threshold, lattice offset.
        let quantiser = [(GenericKind::Quantisation, vec![step, 0.03, 0.0, 0.0])];
        let rounding = step * step / 12.0;
        let s = ChannelSensor::new(&on, 0.1, 0.1, &quantiser, true);
        assert!((s.sigma - (0.03f64.powi(2) + rounding).sqrt()).abs() < 1e-12);
        let s = ChannelSensor::new(&off, 0.1, 0.1, &quantiser, false);
        assert!((s.sigma - (0.03f64.powi(2) + rounding + 0.01).sqrt()).abs() < 1e-12);
    }
}
