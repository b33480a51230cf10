//! Adaptive UKFs of Yu et al. (2020), built on [`Ukf`]: covariance matching of `Q` and `R`
//! over a window of innovations (AUKF, Eq. 7) and, in addition, enhancement of the posterior
//! covariance `P <- tau P` when an auxiliary detector fires (AEUKF, Eq. 6).
//!
//! Eq. 7 as printed adds a matrix to a vector; we use the standard reading of covariance
//! matching (Mohamed & Schwarz 1999): with `C = (1/L) sum e e^T` over the last `L`
//! innovations, `R = C - sum W_c (y_i - y^-)(y_i - y^-)^T = C - (S - R_used)`, and
//! `Q = K C K^T`, estimated as the window mean of the state corrections
//! `dx dx^T = K e e^T K^T` (equal when the gain is constant over the window).

use crate::error::Error;
use crate::filter::ukf::{Ukf, UkfReport};
use crate::model::{Model, Observe};
use crate::real::{Real, all_finite, cast};
use crate::safeguard::{Flags, floor_variances, symmetrise};
use nalgebra::{Cholesky, SMatrix, SVector};

/// Which filter variant runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Adaptation {
    /// Plain UKF with fixed `Q` and `R`.
    None,
    /// AUKF: `Q` and `R` by covariance matching.
    CovarianceMatching,
    /// AEUKF: covariance matching plus covariance enhancement.
    Enhanced,
}

/// Configuration of the adaptive layer.
#[derive(Clone, Copy, Debug)]
pub struct AdaptiveConfig<T: Real, const NX: usize, const NY: usize> {
    pub mode: Adaptation,
    /// Enhancement factor `tau` (the paper's 5).
    pub tau: T,
    /// Diagonal floor of the matched `Q` (keeps parameter random walks alive).
    pub q_floor: SVector<T, NX>,
    /// Diagonal ceiling of the matched `Q`: matching `Q` from the filter's own corrections is
    /// a positive feedback (large `Q`, large gain, large corrections) for weakly observable
    /// parameters, so each variance is capped.
    pub q_ceiling: SVector<T, NX>,
    /// Diagonal floor of the matched `R`.
    pub r_floor: SVector<T, NY>,
    /// Diagonal ceiling of the matched `R`: one sudden change in the window otherwise
    /// inflates `R` by orders of magnitude and the filter stops listening to its sensors.
    pub r_ceiling: SVector<T, NY>,
    /// Floor for repairing a state covariance that lost positive definiteness.
    pub p_floor: T,
    /// Which states the enhancement scales (1 = enhance, 0 = keep): their variances are
    /// multiplied by `tau` and their cross-covariances with the other states cleared. All
    /// ones is the paper's `P <- tau P` up to the cleared cross terms.
    pub enhance_mask: SVector<T, NX>,
    /// Smallest variance of an enhanced state after enhancement (`max(tau P_ii, floor_i)`):
    /// when the filter has grown very confident, `tau P` alone is too small to follow a
    /// large step. Zero gives the paper's rule.
    pub enhance_floor: SVector<T, NX>,
    /// Physical bounds of the state (e.g. a stiffness cannot be negative); an estimate
    /// outside is clamped and flagged [`Flags::BOUNDS_CLAMPED`].
    pub lower: SVector<T, NX>,
    pub upper: SVector<T, NX>,
}

impl<T: Real, const NX: usize, const NY: usize> AdaptiveConfig<T, NX, NY> {
    /// A configuration with the paper's whole-covariance enhancement and no bounds.
    pub fn new(
        mode: Adaptation,
        tau: T,
        q_floor: SVector<T, NX>,
        q_ceiling: SVector<T, NX>,
        r_floor: SVector<T, NY>,
    ) -> Self {
        Self {
            mode,
            tau,
            q_floor,
            q_ceiling,
            r_floor,
            r_ceiling: SVector::repeat(T::MAX_FINITE),
            p_floor: cast(1e-12),
            enhance_mask: SVector::repeat(T::one()),
            enhance_floor: SVector::zeros(),
            lower: SVector::repeat(-T::MAX_FINITE),
            upper: SVector::repeat(T::MAX_FINITE),
        }
    }
}

/// What one adaptive step did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdaptiveReport<T: Real, const NY: usize> {
    /// The underlying UKF update (innovation, S, NIS).
    pub update: UkfReport<T, NY>,
    /// Whether `P` was enhanced this step.
    pub enhanced: bool,
    /// Safeguards that acted (union of the UKF's and the adaptive layer's).
    pub flags: Flags,
}

/// UKF with covariance matching and enhancement; `L` is the matching window.
#[derive(Clone, Debug)]
pub struct AdaptiveUkf<T: Real, const NX: usize, const NS: usize, const NY: usize, const L: usize> {
    ukf: Ukf<T, NX, NS>,
    r: SMatrix<T, NY, NY>,
    config: AdaptiveConfig<T, NX, NY>,
    innovations: [SVector<T, NY>; L],
    corrections: [SVector<T, NX>; L],
    head: usize,
    filled: usize,
}

impl<T: Real, const NX: usize, const NS: usize, const NY: usize, const L: usize>
    AdaptiveUkf<T, NX, NS, NY, L>
{
    /// Wraps `ukf` with initial measurement noise `r0` (positive definite).
    pub fn new(
        ukf: Ukf<T, NX, NS>,
        r0: SMatrix<T, NY, NY>,
        config: AdaptiveConfig<T, NX, NY>,
    ) -> Result<Self, Error> {
        if L == 0 {
            return Err(Error::InvalidParameter("window L must be positive"));
        }
        if !all_finite(r0.as_slice()) || Cholesky::new(r0).is_none() {
            return Err(Error::NotPositiveDefinite);
        }
        if !(config.tau >= T::one())
            || !config.tau.finite()
            || !all_finite(config.q_floor.as_slice())
            || !all_finite(config.q_ceiling.as_slice())
            || !all_finite(config.r_floor.as_slice())
            || config.r_ceiling.iter().any(|c| c.nan())
            || !(config.p_floor > T::zero())
            || !all_finite(config.enhance_mask.as_slice())
            || config
                .enhance_floor
                .iter()
                .any(|f| !(*f >= T::zero()) || !f.finite())
            || config
                .lower
                .iter()
                .zip(config.upper.iter())
                .any(|(lo, hi)| !(lo <= hi))
        {
            return Err(Error::InvalidParameter("tau, q_floor, r_floor or p_floor"));
        }
        Ok(Self {
            ukf,
            r: r0,
            config,
            innovations: [SVector::zeros(); L],
            corrections: [SVector::zeros(); L],
            head: 0,
            filled: 0,
        })
    }

    /// The wrapped UKF (state, covariance, Q).
    pub fn ukf(&self) -> &Ukf<T, NX, NS> {
        &self.ukf
    }
    /// Mutable access to the wrapped UKF (e.g. to re-initialise parameter covariances).
    pub fn ukf_mut(&mut self) -> &mut Ukf<T, NX, NS> {
        &mut self.ukf
    }
    /// Current measurement noise covariance.
    pub fn measurement_noise(&self) -> &SMatrix<T, NY, NY> {
        &self.r
    }
    /// Configuration.
    pub fn config(&self) -> &AdaptiveConfig<T, NX, NY> {
        &self.config
    }

    /// Repairs a state covariance that is no longer positive definite: symmetrise, then
    /// replace by its diagonal raised to `p_floor` (a conservative, flagged repair).
    fn repair_covariance(&mut self) -> Result<(), Error> {
        let mut p = *self.ukf.covariance();
        symmetrise(&mut p);
        let floor = self.config.p_floor;
        let diagonal = p
            .diagonal()
            .map(|v| if v.finite() && v > floor { v } else { floor });
        self.ukf
            .set_covariance(SMatrix::<T, NX, NX>::from_diagonal(&diagonal))
    }

    /// One predict-update cycle over `dt` with input `u` and measurement `y`; when `enhance`
    /// (the auxiliary detector fired on `y`) and the mode is [`Adaptation::Enhanced`], the
    /// previous posterior covariance is multiplied by `tau` before the cycle. Errors leave the filter unchanged, except that a
    /// covariance found not positive definite is repaired (flagged
    /// [`Flags::CHOLESKY_REPAIRED`]): before the prediction by flooring the posterior's
    /// diagonal and loading `Q` for that prediction; in the update by keeping the prior
    /// (a predict-only step, also flagged [`Flags::MEASUREMENT_REJECTED`]).
    pub fn step<M, const NU: usize>(
        &mut self,
        model: &M,
        u: &SVector<T, NU>,
        y: &[T],
        dt: T,
        enhance: bool,
    ) -> Result<AdaptiveReport<T, NY>, Error>
    where
        M: Model<T, NX, NU> + Observe<T, NX, NU, NY>,
    {
        if y.len() != NY {
            return Err(Error::MeasurementLength {
                expected: NY,
                got: y.len(),
            });
        }
        if !all_finite(y) {
            return Err(Error::NonFiniteMeasurement);
        }
        // The estimate to roll back to on error (x and P only: the rest is restored by the
        // code that changes it, and a full copy of the UKF would double its stack use).
        let saved = (*self.ukf.state(), *self.ukf.covariance());
        let mut flags = Flags::NONE;
        // Eq. 6: the detector fired on this sample, so the posterior of the previous step is
        // enhanced before it meets the measurement that carries the sudden change.
        let mut enhanced = false;
        if enhance && self.config.mode == Adaptation::Enhanced {
            let root = self.config.tau.sqrt();
            let scale = self
                .config
                .enhance_mask
                .map(|m| if m > T::zero() { root } else { T::one() });
            let d = SMatrix::<T, NX, NX>::from_diagonal(&scale);
            let mut p = d * self.ukf.covariance() * d;
            // The enhanced states lose their cross-covariances: correlations learnt while the
            // parameter was constant would otherwise steer the sudden change into the
            // correlated states. A PD matrix stays PD when a row/column pair is decoupled.
            for (i, (m, floor)) in self
                .config
                .enhance_mask
                .iter()
                .zip(self.config.enhance_floor.iter())
                .enumerate()
            {
                if *m > T::zero() {
                    if let Some(v) = p.get_mut((i, i))
                        && *v < *floor
                    {
                        *v = *floor;
                    }
                    for j in 0..NX {
                        if j != i {
                            if let Some(v) = p.get_mut((i, j)) {
                                *v = T::zero();
                            }
                            if let Some(v) = p.get_mut((j, i)) {
                                *v = T::zero();
                            }
                        }
                    }
                }
            }
            if self.ukf.set_covariance(p).is_ok() {
                enhanced = true;
                flags.insert(Flags::COVARIANCE_ENHANCED);
            }
        }
        let predicted = match self.ukf.predict(model, u, dt) {
            Err(Error::NotPositiveDefinite) => {
                // Repair the posterior and load Q's diagonal for this one prediction, so that
                // a prior that collapsed (e.g. Q = 0 and a contracting model) is PD again.
                self.repair_covariance()?;
                flags.insert(Flags::CHOLESKY_REPAIRED);
                let q = *self.ukf.process_noise();
                let loading = SMatrix::<T, NX, NX>::identity() * self.config.p_floor;
                let retried = self
                    .ukf
                    .set_process_noise(q + loading)
                    .and_then(|()| self.ukf.predict(model, u, dt));
                // Restoring a Q that was accepted before cannot fail.
                let _ = self.ukf.set_process_noise(q);
                retried
            }
            other => other,
        };
        let predict_flags = match predicted {
            Ok(f) => f,
            Err(e) => {
                self.ukf.restore_estimate(saved.0, saved.1);
                return Err(e);
            }
        };
        flags.insert(predict_flags);
        let prior = *self.ukf.state();
        let update = match self.ukf.update(model, u, y, &self.r) {
            Ok(rep) => rep,
            // S or the posterior is not positive definite: the UKF kept the prior. Repair:
            // this step is predict-only (flagged), rather than an error that loses the
            // prediction.
            Err(Error::NotPositiveDefinite) => {
                flags.insert(Flags::CHOLESKY_REPAIRED);
                flags.insert(Flags::MEASUREMENT_REJECTED);
                UkfReport {
                    innovation: SVector::zeros(),
                    innovation_cov: self.r,
                    nis: T::zero(),
                    fused: false,
                    flags: Flags::MEASUREMENT_REJECTED,
                }
            }
            Err(e) => {
                self.ukf.restore_estimate(saved.0, saved.1);
                return Err(e);
            }
        };
        flags.insert(update.flags);
        let state = *self.ukf.state();
        let clamped = state.zip_zip_map(&self.config.lower, &self.config.upper, |x, lo, hi| {
            x.max(lo).min(hi)
        });
        if clamped != state && self.ukf.set_state(clamped).is_ok() {
            flags.insert(Flags::BOUNDS_CLAMPED);
        }
        // Innovations of a sample flagged as a sudden change are not noise: they stay out of
        // the matching window.
        if update.fused && !enhanced {
            let correction = self.ukf.state() - prior;
            if let (Some(e), Some(c)) = (
                self.innovations.get_mut(self.head),
                self.corrections.get_mut(self.head),
            ) {
                *e = update.innovation;
                *c = correction;
            }
            self.head = self.head.saturating_add(1).checked_rem(L).unwrap_or(0);
            self.filled = self.filled.saturating_add(1).min(L);
        }
        if self.config.mode != Adaptation::None && self.filled == L {
            flags.insert(self.match_covariances(&update.innovation_cov));
        }
        Ok(AdaptiveReport {
            update,
            enhanced,
            flags,
        })
    }

    /// Eq. 7 (see the module note): new `Q` and `R` from the window.
    fn match_covariances(&mut self, s: &SMatrix<T, NY, NY>) -> Flags {
        let mut flags = Flags::NONE;
        let n: T = cast(L as f64);
        let mut c = SMatrix::<T, NY, NY>::zeros();
        for e in self.innovations.iter() {
            c += e * e.transpose();
        }
        c /= n;
        // Only the diagonal of K C K^T is kept: the window is shorter than needed to estimate
        // cross-covariances of nine states reliably.
        let mut q_diagonal = SVector::<T, NX>::zeros();
        for dx in self.corrections.iter() {
            q_diagonal += dx.component_mul(dx);
        }
        q_diagonal /= n;
        let q_diagonal = q_diagonal.zip_map(&self.config.q_ceiling, |v, c| v.min(c));
        let mut q = SMatrix::<T, NX, NX>::from_diagonal(&q_diagonal);
        if floor_diagonal(&mut q, &self.config.q_floor) {
            flags.insert(Flags::VARIANCE_FLOOR);
        }
        if self.ukf.set_process_noise(q).is_err() {
            flags.insert(Flags::MEASUREMENT_REJECTED);
        }
        // R = C - (S - R_used), kept positive definite.
        let mut r = c - (s - self.r);
        symmetrise(&mut r);
        let capped = r
            .diagonal()
            .zip_map(&self.config.r_ceiling, |v, cap| v.min(cap));
        for (i, v) in capped.iter().enumerate() {
            if let Some(entry) = r.get_mut((i, i)) {
                *entry = *v;
            }
        }
        if floor_diagonal(&mut r, &self.config.r_floor) {
            flags.insert(Flags::VARIANCE_FLOOR);
        }
        if !all_finite(r.as_slice()) || Cholesky::new(r).is_none() {
            // Keep only the (floored) diagonal.
            let mut d = SMatrix::<T, NY, NY>::from_diagonal(&r.diagonal());
            floor_variances(&mut d, T::MIN_POSITIVE.sqrt());
            r = d;
            flags.insert(Flags::CHOLESKY_REPAIRED);
        }
        if all_finite(r.as_slice()) {
            self.r = r;
        }
        flags
    }
}

/// Raises each diagonal entry of `m` to at least the matching entry of `floor` (NaN entries
/// too). Returns true when any entry was raised.
fn floor_diagonal<T: Real, const N: usize>(
    m: &mut SMatrix<T, N, N>,
    floor: &SVector<T, N>,
) -> bool {
    let diagonal = m.diagonal();
    let mut raised = false;
    let new = diagonal.zip_map(floor, |v, f| {
        if v >= f {
            v
        } else {
            raised = true;
            f
        }
    });
    for (i, v) in new.iter().enumerate() {
        if let Some(entry) = m.get_mut((i, i)) {
            *entry = *v;
        }
    }
    raised
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filter::ukf::SigmaParams;
    use crate::random::normal;
    use nalgebra::{Matrix1, Matrix2, Vector1, Vector2};
    use rand_core::SeedableRng;
    use rand_xoshiro::Xoshiro256PlusPlus;

    /// State `[level, gain]`, measurement `gain * level`; the level is held at 1 by the
    /// model, so the measurement reveals the gain (like `beta_theta_r * omega_r`).
    struct Gain;
    impl Model<f64, 2, 1> for Gain {
        fn step(&self, x: &Vector2<f64>, _u: &Vector1<f64>, _dt: f64) -> Vector2<f64> {
            Vector2::new(x[0] + 0.5 * (1.0 - x[0]), x[1])
        }
    }
    impl Observe<f64, 2, 1, 1> for Gain {
        fn observe(&self, x: &Vector2<f64>, _u: &Vector1<f64>) -> Vector1<f64> {
            Vector1::new(x[0] * x[1])
        }
    }

    fn filter(mode: Adaptation, r0: f64) -> AdaptiveUkf<f64, 2, 5, 1, 20> {
        let ukf = Ukf::new(
            Vector2::new(1.0, 1.0),
            Matrix2::from_diagonal(&Vector2::new(1e-4, 1e-2)),
            Matrix2::from_diagonal(&Vector2::new(1e-8, 1e-8)),
            SigmaParams::default(),
        )
        .unwrap();
        let config = AdaptiveConfig::new(
            mode,
            5.0,
            Vector2::new(1e-10, 1e-10),
            Vector2::new(1e-4, 1e-4),
            Vector1::new(1e-8),
        );
        AdaptiveUkf::new(ukf, Matrix1::new(r0), config).unwrap()
    }

    /// Runs a gain step 1 -> 0.7 at k = 200 and returns the gain estimate 25 samples later.
    fn gain_after_step(mode: Adaptation) -> f64 {
        let mut f = filter(mode, 1e-4);
        f.config.enhance_mask = Vector2::new(0.0, 1.0);
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(7);
        let u = Vector1::new(0.0);
        let mut estimate = 0.0;
        for k in 0..225 {
            let gain = if k >= 200 { 0.7 } else { 1.0 };
            let y = normal(&mut rng, gain, 0.01);
            let fire = (200..203).contains(&k);
            let report = f.step(&Gain, &u, &[y], 0.02, fire).unwrap();
            assert_eq!(report.enhanced, fire && mode == Adaptation::Enhanced);
            estimate = f.ukf().state()[1];
        }
        estimate
    }

    #[test]
    fn enhancement_tracks_a_step_that_the_plain_ukf_lags() {
        let plain = gain_after_step(Adaptation::None);
        let enhanced = gain_after_step(Adaptation::Enhanced);
        assert!(
            (enhanced - 0.7).abs() < 0.01,
            "AEUKF {enhanced}, UKF {plain}"
        );
        assert!((plain - 0.7).abs() > 0.05, "UKF should lag: {plain}");
    }

    #[test]
    fn covariance_matching_recovers_the_measurement_noise() {
        // True noise variance 4e-4, initial guess 100 times too small.
        let mut f = filter(Adaptation::CovarianceMatching, 4e-6);
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(11);
        let u = Vector1::new(0.0);
        let mut sum = 0.0;
        for k in 0..2000 {
            let y = normal(&mut rng, 1.0, 0.02);
            f.step(&Gain, &u, &[y], 0.02, false).unwrap();
            if k >= 1000 {
                sum += f.measurement_noise()[(0, 0)];
            }
        }
        let r = sum / 1000.0;
        assert!((r / 4e-4 - 1.0).abs() < 0.25, "matched R {r}");
    }

    #[test]
    fn bad_samples_are_rejected_and_leave_the_filter_unchanged() {
        let mut f = filter(Adaptation::Enhanced, 1e-4);
        let u = Vector1::new(0.0);
        f.step(&Gain, &u, &[1.0], 0.02, false).unwrap();
        let (x, p) = (*f.ukf().state(), *f.ukf().covariance());
        assert_eq!(
            f.step(&Gain, &u, &[f64::NAN], 0.02, true).unwrap_err(),
            Error::NonFiniteMeasurement
        );
        assert_eq!(
            f.step(&Gain, &u, &[1.0, 2.0], 0.02, false).unwrap_err(),
            Error::MeasurementLength {
                expected: 1,
                got: 2
            }
        );
        assert_eq!(
            f.step(&Gain, &u, &[1.0], -0.02, false).unwrap_err(),
            Error::InvalidTimeStep
        );
        assert_eq!(
            f.step(&Gain, &Vector1::new(f64::INFINITY), &[1.0], 0.02, false)
                .unwrap_err(),
            Error::NonFiniteInput
        );
        assert_eq!(*f.ukf().state(), x);
        assert_eq!(*f.ukf().covariance(), p);
    }

    /// Collapses every state to a constant: with `Q = 0` the covariance becomes singular.
    struct Collapse;
    impl Model<f64, 2, 1> for Collapse {
        fn step(&self, _x: &Vector2<f64>, _u: &Vector1<f64>, _dt: f64) -> Vector2<f64> {
            Vector2::new(1.0, 1.0)
        }
    }
    impl Observe<f64, 2, 1, 1> for Collapse {
        fn observe(&self, x: &Vector2<f64>, _u: &Vector1<f64>) -> Vector1<f64> {
            Vector1::new(x[0])
        }
    }

    #[test]
    fn a_covariance_that_loses_definiteness_is_repaired_and_flagged() {
        let ukf = Ukf::new(
            Vector2::new(1.0, 1.0),
            Matrix2::identity(),
            Matrix2::zeros(),
            SigmaParams::default(),
        )
        .unwrap();
        let config = AdaptiveConfig::new(
            Adaptation::None,
            5.0,
            Vector2::zeros(),
            Vector2::zeros(),
            Vector1::new(1e-8),
        );
        let mut f: AdaptiveUkf<f64, 2, 5, 1, 4> =
            AdaptiveUkf::new(ukf, Matrix1::new(1e-2), config).unwrap();
        let u = Vector1::new(0.0);
        // The model collapses every sigma point and Q = 0: the prior is singular at once.
        for _ in 0..3 {
            let report = f.step(&Collapse, &u, &[1.0], 0.02, false).unwrap();
            assert!(report.flags.contains(Flags::CHOLESKY_REPAIRED));
            assert!(f.ukf().covariance().diagonal().iter().all(|v| *v > 0.0));
        }
        assert!(f.ukf().state().iter().all(|v| v.is_finite()));
        assert!(f.ukf().covariance().iter().all(|v| v.is_finite()));
    }

    #[test]
    fn enhancement_floor_and_window_exclusion() {
        let mut f = filter(Adaptation::Enhanced, 1e-4);
        f.config.enhance_mask = Vector2::new(0.0, 1.0);
        f.config.enhance_floor = Vector2::new(0.0, 0.04);
        let u = Vector1::new(0.0);
        for _ in 0..30 {
            f.step(&Gain, &u, &[1.0], 0.02, false).unwrap();
        }
        let filled = f.filled;
        let report = f.step(&Gain, &u, &[0.7], 0.02, true).unwrap();
        assert!(report.enhanced && report.flags.contains(Flags::COVARIANCE_ENHANCED));
        // The floor (std 0.2) lets one sample carry most of the 0.3 step.
        assert!(f.ukf().state()[1] < 0.75, "{}", f.ukf().state()[1]);
        // The flagged sample stayed out of the matching window.
        assert_eq!(f.filled, filled);
    }

    #[test]
    fn bounds_clamp_the_estimate_and_flag_it() {
        let mut f = filter(Adaptation::None, 1e-4);
        f.config.upper = Vector2::new(10.0, 0.95);
        let u = Vector1::new(0.0);
        let report = f.step(&Gain, &u, &[1.2], 0.02, false).unwrap();
        assert!(report.flags.contains(Flags::BOUNDS_CLAMPED));
        assert_eq!(f.ukf().state()[1], 0.95);
    }
}
