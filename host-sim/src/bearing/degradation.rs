//! Stochastic pitting degradation of a rolling-element bearing (Anger et al. 2012, Eqs. 1-2)
//! and the load spectrum that drives it (like their Figure 1b).
//!
//! `A_i = A_{i-1} + k_A A_{i-1} + k_u du_{i-1}` with `k_A ~ Weibull(scale(A), shape(A))` and
//! `k_u ~ Exp(mean(A))`, both parameters depending on the current damage `A_{i-1}`.

use prognos_core::random::{uniform_open01, uniform01};
use rand_core::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

/// Pitting surface at the start of the prognostic range (r_feat = 0.001), in um^2.
pub const PITTING_START: f64 = 5.0;
/// Pitting surface at failure (r_feat = 1), in um^2.
pub const PITTING_FAILURE: f64 = 70.0;

/// Parameters of one bearing's degradation law. The per-bearing values (`rate`, `progressivity`,
/// `load_sensitivity`) are drawn by [`CourseParams::sample`]: material and fit vary from bearing
/// to bearing, which is what makes the courses of the paper's Figure 4a differ so strongly.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CourseParams {
    /// Weibull scale of `k_A` at `A = REFERENCE` (per cycle).
    pub rate: f64,
    /// Exponent of the scale's dependence on damage: `scale(A) = rate (A / REFERENCE)^q`.
    /// Negative: fast early growth that flattens (the paper's trial 2); positive: progressive.
    pub progressivity: f64,
    /// Weibull shape of `k_A` at `A = 0`; it falls linearly to `shape_at_failure` at `A = 70`
    /// (more scatter and sudden steps once the pit is large).
    pub shape_at_start: f64,
    pub shape_at_failure: f64,
    /// Mean of `k_u` (um^2 per unit load difference) at `A = 0`; it grows linearly with `A`
    /// to `(1 + load_growth)` times that at failure.
    pub load_sensitivity: f64,
    pub load_growth: f64,
}

impl CourseParams {
    /// Reference pitting for the scale law.
    pub const REFERENCE: f64 = 20.0;

    /// The nominal bearing.
    pub fn nominal() -> Self {
        Self {
            rate: 0.011,
            progressivity: 0.0,
            shape_at_start: 2.0,
            shape_at_failure: 0.9,
            load_sensitivity: 0.9,
            load_growth: 1.0,
        }
    }

    /// A bearing drawn from the population: lognormal rate and load sensitivity scatter and a
    /// uniform progressivity in [-0.6, 0.4].
    pub fn sample<R: Rng + ?Sized>(rng: &mut R) -> Self {
        let nominal = Self::nominal();
        let z1 = prognos_core::random::standard_normal::<f64, R>(rng);
        let z2 = prognos_core::random::standard_normal::<f64, R>(rng);
        let q = -0.6 + uniform01::<f64, R>(rng);
        Self {
            rate: nominal.rate * (0.3 * z1).exp(),
            progressivity: q,
            load_sensitivity: nominal.load_sensitivity * (0.3 * z2).exp(),
            ..nominal
        }
    }

    /// Weibull (scale, shape) of `k_A` at damage `a`.
    pub fn weibull(&self, a: f64) -> (f64, f64) {
        let scale = self.rate * (a.max(1e-3) / Self::REFERENCE).powf(self.progressivity);
        let frac = (a / PITTING_FAILURE).clamp(0.0, 1.0);
        let shape = self.shape_at_start + (self.shape_at_failure - self.shape_at_start) * frac;
        (scale, shape)
    }

    /// Mean of the exponential `k_u` at damage `a`.
    pub fn load_mean(&self, a: f64) -> f64 {
        self.load_sensitivity * (1.0 + self.load_growth * (a / PITTING_FAILURE).clamp(0.0, 2.0))
    }

    /// One step of Eqs. 1-2: the pitting after a cycle with load difference `du`.
    pub fn step<R: Rng + ?Sized>(&self, a: f64, du: f64, rng: &mut R) -> f64 {
        let (scale, shape) = self.weibull(a);
        let k_a = scale * (-uniform_open01::<f64, R>(rng).ln()).powf(1.0 / shape);
        let k_u = -self.load_mean(a) * uniform_open01::<f64, R>(rng).ln();
        a + k_a * a + k_u * du.abs()
    }
}

/// A normalised load spectrum `u_i` in [0, 1] per cycle, like the paper's Figure 1b: blocks of
/// constant load (no load difference, hence slow degradation), blocks of fluctuating load and
/// ramps. Returns `(u, du)` with `du_i = |u_{i+1} - u_i|`, the load difference during cycle
/// `i` that drives the step from `A_i` to `A_{i+1}`.
pub fn load_spectrum(cycles: usize, seed: u64) -> (Vec<f64>, Vec<f64>) {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed ^ 0x10AD_5BEC);
    let mut u = Vec::with_capacity(cycles + 1);
    let mut level = 0.5;
    while u.len() < cycles + 1 {
        let len = 8 + (uniform01::<f64, _>(&mut rng) * 25.0) as usize;
        let kind = uniform01::<f64, _>(&mut rng);
        let target = 0.15 + 0.8 * uniform01::<f64, _>(&mut rng);
        for k in 0..len {
            let v = if kind < 0.3 {
                // Constant block.
                target
            } else if kind < 0.75 {
                // Fluctuating block around the target.
                let amp = 0.1 + 0.25 * uniform01::<f64, _>(&mut rng);
                target + amp * (2.0 * uniform01::<f64, _>(&mut rng) - 1.0)
            } else {
                // Ramp from the previous level to the target.
                level + (target - level) * (k + 1) as f64 / len as f64
            };
            u.push(v.clamp(0.0, 1.0));
        }
        level = *u.last().unwrap_or(&target);
    }
    u.truncate(cycles + 1);
    let du = u.windows(2).map(|w| (w[1] - w[0]).abs()).collect();
    u.truncate(cycles);
    (u, du)
}

/// One simulated degradation course.
#[derive(Clone, Debug)]
pub struct Course {
    pub params: CourseParams,
    /// Load per cycle (schedule, longer than the life).
    pub load: Vec<f64>,
    /// Load difference during each cycle (`load_diff[i]` drives `pitting[i] -> pitting[i+1]`).
    pub load_diff: Vec<f64>,
    /// Pitting surface after each cycle, from `PITTING_START` until just past failure.
    pub pitting: Vec<f64>,
    /// First cycle at which the pitting reaches `PITTING_FAILURE` (the true EOL), if reached.
    pub eol: Option<usize>,
}

/// Simulates a course of at most `max_cycles` cycles, `extra` cycles past failure.
pub fn simulate_course(params: CourseParams, max_cycles: usize, extra: usize, seed: u64) -> Course {
    let (load, load_diff) = load_spectrum(max_cycles + extra + 1, seed);
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut pitting = vec![PITTING_START];
    let mut eol = None;
    let mut a = PITTING_START;
    for (i, &du) in load_diff.iter().enumerate().take(max_cycles + extra) {
        if let Some(e) = eol
            && i >= e + extra
        {
            break;
        }
        a = params.step(a, du, &mut rng);
        pitting.push(a);
        if eol.is_none() && a >= PITTING_FAILURE {
            eol = Some(i + 1);
        }
    }
    Course {
        params,
        load,
        load_diff,
        pitting,
        eol,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weibull_and_exponential_draws_have_their_means() {
        // Mean of Weibull(scale, shape 2) = scale * Gamma(1.5) = scale * sqrt(pi)/2.
        let p = CourseParams {
            shape_at_start: 2.0,
            shape_at_failure: 2.0,
            ..CourseParams::nominal()
        };
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(3);
        let a = CourseParams::REFERENCE;
        let n = 200_000;
        let (mut sa, mut su) = (0.0, 0.0);
        for _ in 0..n {
            sa += (p.step(a, 0.0, &mut rng) - a) / a;
            su += p.step(0.0, 1.0, &mut rng);
        }
        let (scale, _) = p.weibull(a);
        let want = scale * std::f64::consts::PI.sqrt() / 2.0;
        assert!(
            (sa / n as f64 / want - 1.0).abs() < 0.01,
            "{}",
            sa / n as f64
        );
        assert!((su / n as f64 / p.load_mean(0.0) - 1.0).abs() < 0.01);
    }

    #[test]
    fn courses_are_monotone_and_fail_in_a_plausible_range() {
        let mut lives = Vec::new();
        for seed in 0..40 {
            let mut rng = Xoshiro256PlusPlus::seed_from_u64(1000 + seed);
            let c = simulate_course(CourseParams::sample(&mut rng), 600, 3, seed);
            assert!(c.pitting.windows(2).all(|w| w[1] >= w[0]));
            lives.push(c.eol.expect("every course fails within 600 cycles") as f64);
        }
        lives.sort_by(f64::total_cmp);
        let (lo, hi) = (lives[0], lives[lives.len() - 1]);
        assert!(lo > 40.0 && hi < 500.0, "{lo} {hi}");
        // Strongly different courses: the longest life is well over the shortest.
        assert!(hi / lo > 1.8, "{lo} {hi}");
    }

    #[test]
    fn constant_load_blocks_have_no_load_difference() {
        let (u, du) = load_spectrum(300, 5);
        assert_eq!(u.len(), 300);
        assert!(u.iter().all(|&v| (0.0..=1.0).contains(&v)));
        let zeros = du.iter().filter(|&&d| d == 0.0).count();
        assert!(zeros > 20, "{zeros}");
    }
}
