//! A generated trial: a degradation course and the vibration feature measured each cycle.

use super::degradation::{CourseParams, simulate_course};
use super::feature::FeatureExtractor;
use super::vibration::VibrationModel;
use rand_core::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;

/// One bearing run to failure.
#[derive(Clone, Debug)]
pub struct Trial {
    pub seed: u64,
    pub params: CourseParams,
    /// Load difference during each cycle, known for the whole schedule (also past the EOL):
    /// the prognoser is given the planned future load.
    pub load_diff: Vec<f64>,
    /// True pitting (um^2) after each cycle.
    pub pitting: Vec<f64>,
    /// Measured feature `r_feat` at each cycle.
    pub feature: Vec<f64>,
    /// True end of life (first cycle with pitting >= 70 um^2).
    pub eol: usize,
}

/// Trial generator: the course population and the feature extractor.
pub struct TrialGenerator {
    pub extractor: FeatureExtractor,
    pub max_cycles: usize,
}

impl TrialGenerator {
    /// The default generator (vibration model of [`VibrationModel::default`], calibrated on 16
    /// records per end of the range).
    pub fn new() -> Self {
        Self::with_model(VibrationModel::default(), 16)
    }

    pub fn with_model(model: VibrationModel, calibration_records: usize) -> Self {
        Self {
            extractor: FeatureExtractor::calibrated(model, calibration_records),
            max_cycles: 600,
        }
    }

    /// Trial `seed`: a bearing drawn from the population. Courses that do not fail within
    /// `max_cycles` are redrawn with the next sub-seed.
    pub fn trial(&self, seed: u64) -> Trial {
        let mut sub = 0u64;
        loop {
            let s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15).wrapping_add(sub);
            let mut rng = Xoshiro256PlusPlus::seed_from_u64(s);
            let params = CourseParams::sample(&mut rng);
            let course = simulate_course(params, self.max_cycles, 5, s);
            if let Some(eol) = course.eol {
                let mut meas_rng = Xoshiro256PlusPlus::seed_from_u64(s ^ 0xFEA7);
                let feature = course
                    .pitting
                    .iter()
                    .map(|&a| self.extractor.measure(a, &mut meas_rng))
                    .collect();
                return Trial {
                    seed,
                    params,
                    load_diff: course.load_diff,
                    pitting: course.pitting,
                    feature,
                    eol,
                };
            }
            sub += 1;
        }
    }
}

impl Default for TrialGenerator {
    fn default() -> Self {
        Self::new()
    }
}

/// Zero-phase low-pass (first-order exponential smoothing forward then backward), used on the
/// training features as the paper does before GP training.
pub fn zero_phase_lowpass(x: &[f64], smoothing: f64) -> Vec<f64> {
    let a = smoothing.clamp(0.0, 0.999);
    let mut y = x.to_vec();
    let mut s = match y.first() {
        Some(&v) => v,
        None => return y,
    };
    for v in y.iter_mut() {
        s = a * s + (1.0 - a) * *v;
        *v = s;
    }
    s = *y.last().unwrap_or(&0.0);
    for v in y.iter_mut().rev() {
        s = a * s + (1.0 - a) * *v;
        *v = s;
    }
    y
}
