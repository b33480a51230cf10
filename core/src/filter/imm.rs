//! Interacting multiple model estimator over `K` filters (Anger et al. 2012, Table 3; Li &
//! Jilkov 2003): Markov mode transitions, mixing (re-initialisation) of every filter from all
//! of them, mode probabilities from the filters' measurement likelihoods, and the fused
//! estimate (Eq. 23).

use crate::error::Error;
use crate::real::{Real, all_finite, cast};
use crate::safeguard::{Flags, log_sum_exp, symmetrise};
use nalgebra::{SMatrix, SVector};

/// What the IMM needs from one mode's filter.
pub trait ModeFilter<T: Real, const NX: usize>: Clone {
    /// What one step consumes besides the measurement (e.g. the input vector).
    type Input;
    fn mode_state(&self) -> SVector<T, NX>;
    fn mode_covariance(&self) -> SMatrix<T, NX, NX>;
    /// Replaces the estimate by the mixed one (Table 3, lines 4-5).
    fn reinitialise(&mut self, x: &SVector<T, NX>, p: &SMatrix<T, NX, NX>) -> Result<(), Error>;
    /// One predict-update step (Table 3, lines 6-7). Errors leave the filter unchanged.
    fn filter_step(&mut self, input: &Self::Input, z: &[T]) -> Result<ModeUpdate<T>, Error>;
    /// The prediction alone, for a cycle whose measurement is missing or rejected.
    fn predict_step(&mut self, input: &Self::Input) -> Result<(), Error>;
}

/// What one mode's update reports to the IMM.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ModeUpdate<T> {
    /// `ln N(e; 0, S)` of the innovation (Table 3, line 7).
    pub log_likelihood: T,
    /// Normalised innovation squared `e' S^-1 e`.
    pub nis: T,
}

/// What one IMM step did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImmReport<T: Real, const K: usize> {
    /// `ln N(e_j; 0, S_j)` of each mode's innovation (the per-mode test statistic).
    pub log_likelihoods: SVector<T, K>,
    /// Posterior mode probabilities.
    pub probabilities: SVector<T, K>,
    /// Each mode's normalised innovation squared (zero for a mode with no predicted
    /// probability and for a predict-only cycle).
    pub nis: SVector<T, K>,
    /// `ln sum_j c_j N(e_j; 0, S_j)`: the log evidence of the measurement under the mixture
    /// (zero for a predict-only cycle).
    pub log_evidence: T,
    /// Whether the measurement was fused; `false` for a predict-only cycle (missing, or
    /// rejected by the gate of [`Imm::step_gated`]).
    pub fused: bool,
    /// Safeguards that acted in the mixing and fusion (covariance symmetrised).
    pub flags: Flags,
}

/// IMM over `K` filters of type `F` with an `NX`-dimensional common state.
#[derive(Clone, Debug)]
pub struct Imm<T: Real, F, const NX: usize, const K: usize> {
    filters: [F; K],
    probabilities: SVector<T, K>,
    /// `h[(i, j)] = P(m_k = j | m_{k-1} = i)`; rows sum to one.
    transition: SMatrix<T, K, K>,
    x: SVector<T, NX>,
    p: SMatrix<T, NX, NX>,
}

impl<T: Real, F: ModeFilter<T, NX>, const NX: usize, const K: usize> Imm<T, F, NX, K> {
    /// An IMM with initial mode probabilities and a Markov transition matrix (rows sum to one).
    pub fn new(
        filters: [F; K],
        probabilities: SVector<T, K>,
        transition: SMatrix<T, K, K>,
    ) -> Result<Self, Error> {
        let tol: T = cast(1e-6);
        if K == 0 {
            return Err(Error::InsufficientData);
        }
        if !all_finite(transition.as_slice())
            || transition.iter().any(|&h| h < T::zero())
            || transition
                .row_iter()
                .any(|r| (r.sum() - T::one()).abs() > tol)
        {
            return Err(Error::InvalidParameter("IMM transition matrix"));
        }
        if !all_finite(probabilities.as_slice())
            || probabilities.iter().any(|&m| m < T::zero())
            || (probabilities.sum() - T::one()).abs() > tol
        {
            return Err(Error::InvalidParameter("IMM mode probabilities"));
        }
        let (x, p, _) = fuse(&filters, &probabilities);
        Ok(Self {
            filters,
            probabilities,
            transition,
            x,
            p,
        })
    }

    /// A transition matrix that stays in a mode with probability `stay` and moves to each
    /// other mode with `(1 - stay) / (K - 1)`.
    pub fn uniform_switching(stay: T) -> SMatrix<T, K, K> {
        if K <= 1 {
            return SMatrix::repeat(T::one());
        }
        let off = (T::one() - stay) / cast(K.saturating_sub(1) as f64);
        SMatrix::from_fn(|i, j| if i == j { stay } else { off })
    }

    pub fn filters(&self) -> &[F; K] {
        &self.filters
    }
    pub fn probabilities(&self) -> &SVector<T, K> {
        &self.probabilities
    }
    /// Fused state estimate (Eq. 23).
    pub fn state(&self) -> &SVector<T, NX> {
        &self.x
    }
    /// Fused covariance (Eq. 23).
    pub fn covariance(&self) -> &SMatrix<T, NX, NX> {
        &self.p
    }

    /// One IMM cycle (Table 3). Any filter error leaves the whole IMM unchanged.
    pub fn step(&mut self, input: &F::Input, z: &[T]) -> Result<ImmReport<T, K>, Error> {
        self.update(input, z, None)
    }

    /// [`Self::step`] with an outlier gate: when no mode with a predicted probability explains
    /// the measurement (every mode's NIS above `gate`, e.g. the chi-square 99.9 % point), the
    /// cycle is predict-only and the report says it was not fused.
    pub fn step_gated(
        &mut self,
        input: &F::Input,
        z: &[T],
        gate: T,
    ) -> Result<ImmReport<T, K>, Error> {
        if !(gate.finite() && gate > T::zero()) {
            return Err(Error::InvalidParameter("gate"));
        }
        self.update(input, z, Some(gate))
    }

    /// A predict-only cycle (missing measurement): mixing and every mode's prediction; the
    /// mode probabilities become the predicted ones (Table 3, line 2).
    pub fn predict(&mut self, input: &F::Input) -> Result<ImmReport<T, K>, Error> {
        let predicted = self.transition.transpose() * self.probabilities;
        let (mut filters, mut flags) = self.mixed(&predicted)?;
        for filter in filters.iter_mut() {
            filter.predict_step(input)?;
        }
        let total = predicted.sum();
        if !(total.finite() && total > T::zero()) {
            return Err(Error::NonFiniteState);
        }
        let probabilities = predicted / total;
        self.commit(filters, probabilities, &mut flags)?;
        Ok(ImmReport {
            log_likelihoods: SVector::zeros(),
            probabilities,
            nis: SVector::zeros(),
            log_evidence: T::zero(),
            fused: false,
            flags,
        })
    }

    /// Lines 3-5: every filter with a predicted probability re-initialised from the mixture.
    fn mixed(&self, predicted: &SVector<T, K>) -> Result<([F; K], Flags), Error> {
        let tiny = T::MIN_POSITIVE;
        let mut filters = self.filters.clone();
        let mut flags = Flags::NONE;
        for ((filter, column), &c_j) in filters
            .iter_mut()
            .zip(self.transition.column_iter())
            .zip(predicted.iter())
        {
            if c_j <= tiny {
                continue;
            }
            // Mixing weights mu^{i|j} = h_ij mu_i / c_j, mixed mean and covariance.
            let mut x0 = SVector::<T, NX>::zeros();
            for (src, (&h, &mu)) in self
                .filters
                .iter()
                .zip(column.iter().zip(self.probabilities.iter()))
            {
                x0 += src.mode_state() * (h * mu / c_j);
            }
            let mut p0 = SMatrix::<T, NX, NX>::zeros();
            for (src, (&h, &mu)) in self
                .filters
                .iter()
                .zip(column.iter().zip(self.probabilities.iter()))
            {
                let d = src.mode_state() - x0;
                p0 += (src.mode_covariance() + d * d.transpose()) * (h * mu / c_j);
            }
            if symmetrise(&mut p0) {
                flags.insert(Flags::COVARIANCE_SYMMETRISED);
            }
            filter.reinitialise(&x0, &p0)?;
        }
        Ok((filters, flags))
    }

    /// Lines 9-10 and the state change: fuses `filters` with `probabilities` and keeps them
    /// if the result is finite.
    fn commit(
        &mut self,
        filters: [F; K],
        probabilities: SVector<T, K>,
        flags: &mut Flags,
    ) -> Result<(), Error> {
        let (x, p, symmetrised) = fuse(&filters, &probabilities);
        if symmetrised {
            flags.insert(Flags::COVARIANCE_SYMMETRISED);
        }
        if !all_finite(x.as_slice()) || !all_finite(p.as_slice()) {
            return Err(Error::NonFiniteState);
        }
        self.filters = filters;
        self.probabilities = probabilities;
        self.x = x;
        self.p = p;
        Ok(())
    }

    fn update(
        &mut self,
        input: &F::Input,
        z: &[T],
        gate: Option<T>,
    ) -> Result<ImmReport<T, K>, Error> {
        // Line 2: predicted mode probabilities c_j = sum_i h_ij mu_i.
        let predicted = self.transition.transpose() * self.probabilities;
        let tiny = T::MIN_POSITIVE;
        let (mut filters, mut flags) = self.mixed(&predicted)?;
        let mut log_weights = SVector::<T, K>::zeros();
        let mut log_likelihoods = SVector::<T, K>::zeros();
        let mut nis = SVector::<T, K>::zeros();
        let mut explained = false;
        for ((filter, &c_j), ((lw, ll), n)) in filters.iter_mut().zip(predicted.iter()).zip(
            log_weights
                .iter_mut()
                .zip(log_likelihoods.iter_mut())
                .zip(nis.iter_mut()),
        ) {
            // Lines 6-7.
            let m = filter.filter_step(input, z)?;
            (*ll, *n) = (m.log_likelihood, m.nis);
            *lw = if c_j > tiny {
                explained |= gate.is_none_or(|g| m.nis <= g);
                c_j.ln() + m.log_likelihood
            } else {
                -T::MAX_FINITE
            };
        }
        if !explained {
            return self
                .predict(input)
                .map(|report| ImmReport { nis, ..report });
        }
        // Line 8 in the log domain.
        let norm = log_sum_exp(log_weights.as_slice());
        if !norm.finite() {
            return Err(Error::NonFiniteState);
        }
        // Divided by their sum: at huge log-likelihoods `norm` loses the `ln K` term to
        // round-off and the exponentials alone would not sum to one.
        let unnormalised = log_weights.map(|lw| (lw - norm).exp());
        let total = unnormalised.sum();
        if !(total.finite() && total > T::zero()) {
            return Err(Error::NonFiniteState);
        }
        let probabilities = unnormalised / total;
        self.commit(filters, probabilities, &mut flags)?;
        Ok(ImmReport {
            log_likelihoods,
            probabilities,
            nis,
            log_evidence: norm,
            fused: true,
            flags,
        })
    }
}

/// Lines 9-10: probability-weighted mean and spread-of-means covariance.
fn fuse<T: Real, F: ModeFilter<T, NX>, const NX: usize, const K: usize>(
    filters: &[F; K],
    probabilities: &SVector<T, K>,
) -> (SVector<T, NX>, SMatrix<T, NX, NX>, bool) {
    let mut x = SVector::<T, NX>::zeros();
    for (f, &mu) in filters.iter().zip(probabilities.iter()) {
        x += f.mode_state() * mu;
    }
    let mut p = SMatrix::<T, NX, NX>::zeros();
    for (f, &mu) in filters.iter().zip(probabilities.iter()) {
        let d = f.mode_state() - x;
        p += (f.mode_covariance() + d * d.transpose()) * mu;
    }
    let symmetrised = symmetrise(&mut p);
    (x, p, symmetrised)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::random::standard_normal;
    use nalgebra::{Matrix1, Vector1, Vector2};
    use rand_core::SeedableRng;
    use rand_xoshiro::Xoshiro256PlusPlus;

    /// Scalar Kalman filter for `x' = x + drift + w`, `z = x + v`.
    #[derive(Clone, Debug)]
    struct DriftKf {
        drift: f64,
        q: f64,
        r: f64,
        x: f64,
        p: f64,
    }

    impl ModeFilter<f64, 1> for DriftKf {
        type Input = ();
        fn mode_state(&self) -> Vector1<f64> {
            Vector1::new(self.x)
        }
        fn mode_covariance(&self) -> Matrix1<f64> {
            Matrix1::new(self.p)
        }
        fn reinitialise(&mut self, x: &Vector1<f64>, p: &Matrix1<f64>) -> Result<(), Error> {
            self.x = x[0];
            self.p = p[(0, 0)];
            Ok(())
        }
        fn predict_step(&mut self, _: &()) -> Result<(), Error> {
            self.x += self.drift;
            self.p += self.q;
            Ok(())
        }
        fn filter_step(&mut self, _: &(), z: &[f64]) -> Result<ModeUpdate<f64>, Error> {
            let z = *z.first().ok_or(Error::InsufficientData)?;
            if !z.is_finite() {
                return Err(Error::NonFiniteMeasurement);
            }
            let xp = self.x + self.drift;
            let pp = self.p + self.q;
            let s = pp + self.r;
            let e = z - xp;
            let k = pp / s;
            self.x = xp + k * e;
            self.p = (1.0 - k) * pp;
            Ok(ModeUpdate {
                log_likelihood: -0.5 * (e * e / s + (2.0 * core::f64::consts::PI * s).ln()),
                nis: e * e / s,
            })
        }
    }

    fn kf(drift: f64) -> DriftKf {
        DriftKf {
            drift,
            q: 1e-4,
            r: 0.04,
            x: 0.0,
            p: 1.0,
        }
    }

    #[test]
    fn mode_probabilities_follow_a_switching_system() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(21);
        let mut imm: Imm<f64, DriftKf, 1, 3> = Imm::new(
            [kf(0.0), kf(0.1), kf(-0.1)],
            SVector::from([1.0 / 3.0; 3]),
            Imm::<f64, DriftKf, 1, 3>::uniform_switching(0.98),
        )
        .unwrap();
        let mut x = 0.0;
        let mut right = [0usize; 3];
        let mut counted = [0usize; 3];
        for k in 0..300 {
            let mode = k / 100; // drift 0, then +0.1, then -0.1
            x += [0.0, 0.1, -0.1][mode] + 0.01 * standard_normal::<f64, _>(&mut rng);
            let z = x + 0.2 * standard_normal::<f64, _>(&mut rng);
            let rep = imm.step(&(), &[z]).unwrap();
            assert!((rep.probabilities.sum() - 1.0).abs() < 1e-12);
            if k % 100 >= 25 {
                counted[mode] += 1;
                if rep.probabilities.imax() == mode && rep.probabilities[mode] > 0.8 {
                    right[mode] += 1;
                }
            }
            if k % 100 == 99 {
                assert!((imm.state()[0] - x).abs() < 0.3, "{} {x}", imm.state()[0]);
            }
        }
        for m in 0..3 {
            assert!(
                right[m] as f64 >= 0.9 * counted[m] as f64,
                "mode {m}: {} of {}",
                right[m],
                counted[m]
            );
        }
    }

    #[test]
    fn fused_estimate_is_the_weighted_mixture_and_errors_leave_it_unchanged() {
        let mut imm: Imm<f64, DriftKf, 1, 2> = Imm::new(
            [kf(0.0), kf(1.0)],
            SVector::from([0.5, 0.5]),
            Imm::<f64, DriftKf, 1, 2>::uniform_switching(0.9),
        )
        .unwrap();
        imm.step(&(), &[0.6]).unwrap();
        let mu = *imm.probabilities();
        let (a, b) = (&imm.filters()[0], &imm.filters()[1]);
        let x = mu[0] * a.x + mu[1] * b.x;
        let p = mu[0] * (a.p + (a.x - x).powi(2)) + mu[1] * (b.p + (b.x - x).powi(2));
        assert!((imm.state()[0] - x).abs() < 1e-12);
        assert!((imm.covariance()[(0, 0)] - p).abs() < 1e-12);
        let before = (*imm.probabilities(), *imm.state());
        assert_eq!(
            imm.step(&(), &[f64::NAN]).map(|_| ()),
            Err(Error::NonFiniteMeasurement)
        );
        assert_eq!((*imm.probabilities(), *imm.state()), before);
        // Bad configurations.
        let bad = SMatrix::<f64, 2, 2>::new(0.9, 0.2, 0.1, 0.9);
        assert!(Imm::new([kf(0.0), kf(1.0)], Vector2::new(0.5, 0.5), bad).is_err());
    }

    #[test]
    fn missing_and_gated_cycles_predict_only() {
        let new = || {
            Imm::<f64, DriftKf, 1, 2>::new(
                [kf(0.0), kf(1.0)],
                SVector::from([0.5, 0.5]),
                Imm::<f64, DriftKf, 1, 2>::uniform_switching(0.9),
            )
            .unwrap()
        };
        // A missing cycle: probabilities become the predicted ones (uniform stays uniform),
        // and the fused state is the mixture of the two drifts.
        let mut imm = new();
        let rep = imm.predict(&()).unwrap();
        assert!(!rep.fused);
        assert!((rep.probabilities[0] - 0.5).abs() < 1e-12);
        assert!((imm.state()[0] - 0.5).abs() < 1e-12, "{}", imm.state()[0]);
        assert!((imm.covariance()[(0, 0)] - (1.0 + 1e-4 + 0.25)).abs() < 1e-12);
        // An outlier far from both modes (NIS ~ 1e4 against a 10.83 gate) is not fused: the
        // gated IMM ends where a predict-only cycle does, the ungated one jumps toward it.
        let (mut gated, mut plain, mut predicted) = (new(), new(), new());
        let rep = gated.step_gated(&(), &[100.0], 10.83).unwrap();
        assert!(!rep.fused && rep.nis.iter().all(|&n| n > 10.83), "{rep:?}");
        predicted.predict(&()).unwrap();
        assert_eq!(gated.state(), predicted.state());
        assert_eq!(gated.probabilities(), predicted.probabilities());
        assert!(plain.step(&(), &[100.0]).unwrap().fused);
        assert!(plain.state()[0] > 50.0);
        // A measurement one mode explains is fused, and the gate must be positive.
        assert!(gated.step_gated(&(), &[1.2], 10.83).unwrap().fused);
        assert!(gated.step_gated(&(), &[1.2], f64::NAN).is_err());
    }

    #[test]
    fn one_mode_imm_is_the_filter() {
        let mut imm: Imm<f64, DriftKf, 1, 1> = Imm::new(
            [kf(0.2)],
            SVector::from([1.0]),
            Imm::<f64, DriftKf, 1, 1>::uniform_switching(0.9),
        )
        .unwrap();
        let mut plain = kf(0.2);
        for z in [0.1, 0.5, 0.4, 0.9] {
            imm.step(&(), &[z]).unwrap();
            plain.filter_step(&(), &[z]).unwrap();
        }
        assert!((imm.state()[0] - plain.x).abs() < 1e-12);
        assert!((imm.covariance()[(0, 0)] - plain.p).abs() < 1e-12);
    }
}
