//! Envelope analysis and the degradation feature `r_feat`: the envelope spectrum's power at
//! the fault frequency, normalised to [0.001, 1] over the pitting range 5-70 um^2.

use super::degradation::{PITTING_FAILURE, PITTING_START};
use super::vibration::VibrationModel;
use rand_core::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;
use rustfft::{Fft, FftPlanner, num_complex::Complex};
use std::sync::Arc;

/// Envelope spectrum analyser for records of a fixed length (FFT plans kept).
pub struct EnvelopeAnalyser {
    len: usize,
    sample_rate: f64,
    forward: Arc<dyn Fft<f64>>,
    inverse: Arc<dyn Fft<f64>>,
}

impl EnvelopeAnalyser {
    pub fn new(len: usize, sample_rate: f64) -> Self {
        let mut planner = FftPlanner::new();
        Self {
            len,
            sample_rate,
            forward: planner.plan_fft_forward(len),
            inverse: planner.plan_fft_inverse(len),
        }
    }

    /// The envelope `|x + i H{x}|` via the analytic signal (FFT, zero the negative
    /// frequencies, double the positive ones, inverse FFT).
    pub fn envelope(&self, x: &[f64]) -> Vec<f64> {
        let n = self.len;
        let mut buf: Vec<Complex<f64>> = x.iter().take(n).map(|&v| Complex::new(v, 0.0)).collect();
        buf.resize(n, Complex::new(0.0, 0.0));
        self.forward.process(&mut buf);
        for (k, c) in buf.iter_mut().enumerate() {
            if k == 0 || (n.is_multiple_of(2) && k == n / 2) {
                continue;
            } else if k < n.div_ceil(2) {
                *c *= 2.0;
            } else {
                *c = Complex::new(0.0, 0.0);
            }
        }
        self.inverse.process(&mut buf);
        buf.iter().map(|c| c.norm() / n as f64).collect()
    }

    /// One-sided power spectral density of the mean-removed envelope (periodogram), per bin
    /// of width `sample_rate / len`.
    pub fn envelope_psd(&self, x: &[f64]) -> Vec<f64> {
        let env = self.envelope(x);
        let mean = env.iter().sum::<f64>() / env.len().max(1) as f64;
        let mut buf: Vec<Complex<f64>> = env.iter().map(|&v| Complex::new(v - mean, 0.0)).collect();
        self.forward.process(&mut buf);
        let n = self.len as f64;
        buf.iter()
            .take(self.len / 2 + 1)
            .map(|c| 2.0 * c.norm_sqr() / (n * self.sample_rate))
            .collect()
    }

    /// Frequency of bin `k`.
    pub fn bin_frequency(&self, k: usize) -> f64 {
        k as f64 * self.sample_rate / self.len as f64
    }

    /// Amplitude of the envelope spectrum's line at `frequency`: the square root of the power
    /// in a band of `+-half_width` Hz around it.
    pub fn line_amplitude(&self, x: &[f64], frequency: f64, half_width: f64) -> f64 {
        self.line_power(x, frequency, half_width).sqrt()
    }

    /// Power of the envelope spectrum in a band of `+-half_width` Hz around `frequency`.
    pub fn line_power(&self, x: &[f64], frequency: f64, half_width: f64) -> f64 {
        let psd = self.envelope_psd(x);
        let df = self.sample_rate / self.len as f64;
        psd.iter()
            .enumerate()
            .filter(|(k, _)| (*k as f64 * df - frequency).abs() <= half_width)
            .map(|(_, p)| p * df)
            .sum()
    }
}

/// Maps the line amplitude to `r_feat`: linear, 0.001 at the expected amplitude of a 5 um^2
/// pit and 1 at that of a 70 um^2 pit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FeatureCalibration {
    pub amplitude_at_start: f64,
    pub amplitude_at_failure: f64,
}

/// Feature extraction: vibration model, analyser and calibration together.
pub struct FeatureExtractor {
    pub model: VibrationModel,
    pub analyser: EnvelopeAnalyser,
    pub calibration: FeatureCalibration,
    /// Half width (Hz) of the band summed around the fault line (the arrival jitter widens it).
    pub half_width: f64,
}

pub const FEATURE_AT_START: f64 = 0.001;
pub const FEATURE_AT_FAILURE: f64 = 1.0;

impl FeatureExtractor {
    /// Builds the extractor and calibrates it by averaging `records` records at 5 and 70 um^2.
    pub fn calibrated(model: VibrationModel, records: usize) -> Self {
        let analyser = EnvelopeAnalyser::new(model.samples, model.sample_rate);
        let half_width = 1.5;
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(0xCA11B);
        let mut mean_amplitude = |pitting: f64| {
            (0..records)
                .map(|_| {
                    let x = model.record(pitting, &mut rng);
                    analyser.line_amplitude(&x, model.fault_frequency, half_width)
                })
                .sum::<f64>()
                / records as f64
        };
        let calibration = FeatureCalibration {
            amplitude_at_start: mean_amplitude(PITTING_START),
            amplitude_at_failure: mean_amplitude(PITTING_FAILURE),
        };
        Self {
            model,
            analyser,
            calibration,
            half_width,
        }
    }

    /// Normalises a line power to `r_feat`.
    pub fn normalise(&self, amplitude: f64) -> f64 {
        let c = self.calibration;
        FEATURE_AT_START
            + (FEATURE_AT_FAILURE - FEATURE_AT_START) * (amplitude - c.amplitude_at_start)
                / (c.amplitude_at_failure - c.amplitude_at_start)
    }

    /// Measures `r_feat` from one vibration record.
    pub fn feature_of_record(&self, x: &[f64]) -> f64 {
        self.normalise(
            self.analyser
                .line_amplitude(x, self.model.fault_frequency, self.half_width),
        )
    }

    /// Simulates a record for `pitting` and measures its feature.
    pub fn measure<R: rand_core::Rng + ?Sized>(&self, pitting: f64, rng: &mut R) -> f64 {
        let x = self.model.record(pitting, rng);
        self.feature_of_record(&x)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn envelope_of_modulated_carrier_is_its_amplitude() {
        let fs = 4096.0;
        let n = 4096;
        let a = EnvelopeAnalyser::new(n, fs);
        // Carrier at 1000 Hz modulated by 1 + 0.5 cos(2 pi 10 t): envelope is the modulation.
        let x: Vec<f64> = (0..n)
            .map(|k| {
                let t = k as f64 / fs;
                (1.0 + 0.5 * (2.0 * std::f64::consts::PI * 10.0 * t).cos())
                    * (2.0 * std::f64::consts::PI * 1000.0 * t).cos()
            })
            .collect();
        let env = a.envelope(&x);
        for (k, e) in env.iter().enumerate().skip(100).take(3000) {
            let t = k as f64 / fs;
            let want = 1.0 + 0.5 * (2.0 * std::f64::consts::PI * 10.0 * t).cos();
            assert!((e - want).abs() < 1e-6, "{k} {e} {want}");
        }
    }

    #[test]
    fn envelope_spectrum_finds_the_fault_line_in_synthetic_vibration() {
        let model = VibrationModel::default();
        let a = EnvelopeAnalyser::new(model.samples, model.sample_rate);
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(11);
        let x = model.record(60.0, &mut rng);
        let psd = a.envelope_psd(&x);
        // Strongest line between 100 and 200 Hz (away from the 20 Hz interference harmonics
        // at 100/120/140/...): must be the 127 Hz fault line.
        let (k_max, _) = psd
            .iter()
            .enumerate()
            .filter(|(k, _)| {
                let f = a.bin_frequency(*k);
                (100.0..200.0).contains(&f) && (f / 20.0 - (f / 20.0).round()).abs() > 0.1
            })
            .max_by(|a, b| a.1.total_cmp(b.1))
            .unwrap();
        assert!((a.bin_frequency(k_max) - 127.0).abs() <= 1.0);
        // Cage sidebands at 127 +- 20 Hz stand above the local floor.
        let floor = psd[160..200].iter().sum::<f64>() / 40.0;
        assert!(psd[107] > 2.0 * floor && psd[147] > 2.0 * floor);
        assert!(psd[127] > 10.0 * floor);
        // Without a pit there is no line.
        let x0 = model.record(0.0, &mut rng);
        let p0 = a.line_power(&x0, 127.0, 1.5);
        let p60 = a.line_power(&x, 127.0, 1.5);
        assert!(p60 > 5.0 * p0, "{p60} {p0}");
    }

    #[test]
    fn feature_is_normalised_over_the_pitting_range_and_rises() {
        let model = VibrationModel {
            samples: 8192,
            sample_rate: 8192.0,
            ..VibrationModel::default()
        };
        let fx = FeatureExtractor::calibrated(model, 6);
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(12);
        let mean = |a: f64, rng: &mut Xoshiro256PlusPlus| {
            (0..8).map(|_| fx.measure(a, rng)).sum::<f64>() / 8.0
        };
        let (r5, r35, r70) = (
            mean(5.0, &mut rng),
            mean(35.0, &mut rng),
            mean(70.0, &mut rng),
        );
        assert!(r5.abs() < 0.05, "{r5}");
        assert!((r70 - 1.0).abs() < 0.15, "{r70}");
        assert!(r5 < r35 && r35 < r70, "{r5} {r35} {r70}");
    }
}
