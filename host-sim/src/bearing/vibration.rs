//! Structure-borne noise of a bearing with an inner-race pit (Anger et al. 2012, Eq. 24,
//! after Antoni 2007): `x(t) = sum_i h(t - iT - tau_i) q(iT) A_i + n(t)` plus an interfering
//! impulse train of another mechanism.

use prognos_core::random::{standard_normal, uniform01};
use rand_core::Rng;
use std::f64::consts::PI;

/// Vibration model parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VibrationModel {
    /// Sample rate (Hz).
    pub sample_rate: f64,
    /// Record length in samples (one record per load cycle).
    pub samples: usize,
    /// Inner-race fault frequency (Hz).
    pub fault_frequency: f64,
    /// Arrival jitter: standard deviation of `tau_i` as a fraction of the fault period.
    pub jitter: f64,
    /// Relative amplitude scatter of `A_i` (standard deviation).
    pub amplitude_scatter: f64,
    /// Fault impulse amplitude per um^2 of pitting.
    pub gain_per_pitting: f64,
    /// Cage frequency of the amplitude modulation `q(t)` (Hz) and its depth.
    pub cage_frequency: f64,
    pub cage_depth: f64,
    /// Eigenfrequency (Hz) and damping ratio of the second-order transmission path.
    pub path_frequency: f64,
    pub path_damping: f64,
    /// Frequency (Hz) and amplitude of the interfering impulse train.
    pub other_frequency: f64,
    pub other_amplitude: f64,
    /// Standard deviation of the white background noise.
    pub noise_std: f64,
}

impl Default for VibrationModel {
    fn default() -> Self {
        Self {
            sample_rate: 16_384.0,
            samples: 16_384,
            fault_frequency: 127.0,
            jitter: 0.01,
            amplitude_scatter: 0.2,
            gain_per_pitting: 0.04,
            cage_frequency: 20.0,
            cage_depth: 0.5,
            path_frequency: 1600.0,
            path_damping: 0.05,
            other_frequency: 20.0,
            other_amplitude: 6.0,
            noise_std: 0.3,
        }
    }
}

impl VibrationModel {
    /// Adds the path's impulse response to one impulse of amplitude `amp` arriving at `t0` s.
    fn add_impulse(&self, x: &mut [f64], t0: f64, amp: f64) {
        let wn = 2.0 * PI * self.path_frequency;
        let zeta = self.path_damping;
        let wd = wn * (1.0 - zeta * zeta).sqrt();
        let decay = zeta * wn;
        // Ten time constants: the tail below e^-10 is negligible.
        let span = 10.0 / decay;
        let first = (t0 * self.sample_rate).ceil().max(0.0) as usize;
        let last = (((t0 + span) * self.sample_rate).ceil() as usize).min(x.len());
        for (k, v) in x.iter_mut().enumerate().take(last).skip(first) {
            let t = k as f64 / self.sample_rate - t0;
            *v += amp * (-decay * t).exp() * (wd * t).sin();
        }
    }

    /// One vibration record for pitting surface `pitting` (um^2).
    pub fn record<R: Rng + ?Sized>(&self, pitting: f64, rng: &mut R) -> Vec<f64> {
        let mut x: Vec<f64> = (0..self.samples)
            .map(|_| self.noise_std * standard_normal::<f64, R>(rng))
            .collect();
        let duration = self.samples as f64 / self.sample_rate;
        let period = 1.0 / self.fault_frequency;
        // A random phase so that records are not aligned to the fault period.
        let phase = uniform01::<f64, R>(rng) * period;
        let amp0 = self.gain_per_pitting * pitting;
        let mut i = 0usize;
        loop {
            let nominal = phase + i as f64 * period;
            if nominal >= duration {
                break;
            }
            let tau = self.jitter * period * standard_normal::<f64, R>(rng);
            let q = 1.0 + self.cage_depth * (2.0 * PI * self.cage_frequency * nominal).cos();
            let a_i = amp0 * (1.0 + self.amplitude_scatter * standard_normal::<f64, R>(rng));
            self.add_impulse(&mut x, nominal + tau, q * a_i);
            i += 1;
        }
        let other_period = 1.0 / self.other_frequency;
        let other_phase = uniform01::<f64, R>(rng) * other_period;
        let mut j = 0usize;
        loop {
            let t = other_phase + j as f64 * other_period;
            if t >= duration {
                break;
            }
            let a = self.other_amplitude * (1.0 + 0.05 * standard_normal::<f64, R>(rng));
            self.add_impulse(&mut x, t, a);
            j += 1;
        }
        x
    }
}
