//! Residual-based FDI of the electric scooter (Yu et al. 2020, Eqs. 1-4, Table 2 and the
//! auxiliary detector `Psi` of Eq. 6).
//!
//! The ARRs are evaluated from the three measured velocities with nominal efficiency factors
//! (1): positions by trapezoidal integration, accelerations by backward differences. The
//! input in `r1` is the one held over the sampling interval (zero-order hold), which aligns
//! it with the backward-difference acceleration. `r2` is expressed as a torque at the wheel
//! (the paper's `r2` times `N4`) so that `Psi` adds like units.

use crate::error::Error;
use crate::plants::scooter::{ScooterParams, rebase_angles};
use crate::real::{Real, all_finite, cast};

/// Multiplicative uncertainties `delta` of Table 3 used by the adaptive thresholds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ArrUncertainty<T> {
    pub r_mv: T,
    pub r_mc: T,
    pub j_m: T,
    pub m: T,
    pub j_r: T,
    pub j_f: T,
    pub r_rv: T,
    pub r_rc: T,
    pub r_fv: T,
    pub r_fc: T,
    pub k1: T,
    pub k2: T,
}

impl<T: Real> ArrUncertainty<T> {
    /// Table 3.
    pub fn table3() -> Self {
        Self {
            r_mv: cast(0.0298),
            r_mc: cast(0.0586),
            j_m: cast(0.0812),
            m: cast(0.0206),
            j_r: cast(0.0284),
            j_f: cast(0.0276),
            r_rv: cast(0.0512),
            r_rc: cast(0.0189),
            r_fv: cast(0.0279),
            r_fc: cast(0.0291),
            k1: cast(0.0229),
            k2: cast(0.0113),
        }
    }
}

/// Fault candidates of Table 2 as bits of a [`FaultSet`].
pub mod fault {
    /// Rear-wheel viscous friction `R_rv`.
    pub const R_RV: u8 = 1;
    /// Rear-encoder efficiency `beta_theta_r`.
    pub const BETA_THETA_R: u8 = 1 << 1;
    /// Rear shaft stiffness `K1`.
    pub const K1: u8 = 1 << 2;
    /// Wheel radius `N4`.
    pub const N4: u8 = 1 << 3;
    /// Body-speed sensor efficiency `beta_s_m`.
    pub const BETA_S_M: u8 = 1 << 4;
    /// Front-encoder efficiency `beta_theta_f`.
    pub const BETA_THETA_F: u8 = 1 << 5;
    /// Front-wheel friction (Table 2's last row, printed garbled as `beta_f_v`).
    pub const R_FV: u8 = 1 << 6;
    /// Number of faults in the matrix.
    pub const COUNT: usize = 7;
}

/// A set of faults (bits of [`fault`]).
pub type FaultSet = u8;

/// Table 2: signature `[ARR1 ARR2 ARR3]` (bit 0 = ARR1) of each fault, in [`fault`] order.
pub const SIGNATURES: [(FaultSet, u8); fault::COUNT] = [
    (fault::R_RV, 0b001),
    (fault::BETA_THETA_R, 0b011),
    (fault::K1, 0b011),
    (fault::N4, 0b111),
    (fault::BETA_S_M, 0b111),
    (fault::BETA_THETA_F, 0b110),
    (fault::R_FV, 0b100),
];

/// Union of the signatures of the faults in `set` (a coherence vector, bit i = ARR i+1).
pub fn signature(set: FaultSet) -> u8 {
    SIGNATURES
        .iter()
        .filter(|(f, _)| set & f != 0)
        .fold(0, |acc, (_, s)| acc | s)
}

/// The set of fault candidates (SFC) for coherence vector `cv`: every non-empty combination
/// of faults whose joint signature equals `cv` exactly (none for a zero `cv`).
pub fn fault_candidates(cv: u8) -> impl Iterator<Item = FaultSet> {
    let all: u16 = 1 << fault::COUNT;
    (1..all).filter_map(move |s| {
        let set = s as FaultSet;
        (cv != 0 && signature(set) == cv).then_some(set)
    })
}

/// Faults that appear in at least one candidate set for `cv` (the parameters to estimate).
pub fn suspected_faults(cv: u8) -> FaultSet {
    fault_candidates(cv).fold(0, |acc, s| acc | s)
}

/// What one ARR evaluation found.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ArrReport<T> {
    /// Nominal residuals `[r1n, r2n * N4, r3n]` (Nm).
    pub residuals: [T; 3],
    /// Adaptive thresholds `[a1, a2 * N4, a3]` plus the noise margins (Nm).
    pub thresholds: [T; 3],
    /// Coherence vector, bit i set when ARR i+1 is inconsistent.
    pub cv: u8,
    /// Auxiliary detector `Psi = sum eta_i |d^2 r_i / dt^2|` (0 until three residuals exist).
    pub psi: T,
}

/// Online ARR evaluation for the scooter.
#[derive(Clone, Debug)]
pub struct ScooterArr<T: Real> {
    params: ScooterParams<T>,
    delta: ArrUncertainty<T>,
    /// Added to each threshold to cover sensor noise and integration drift (Nm).
    pub noise_margin: [T; 3],
    positions: [T; 3],
    previous_y: Option<[T; 3]>,
    /// Last two residuals (most recent first), for the second difference in `Psi`.
    history: [[T; 3]; 2],
    /// Interval between the last two residuals (for `Psi` over a gap).
    last_dt: T,
    samples: u32,
}

impl<T: Real> ScooterArr<T> {
    /// Nominal parameters, Table 3 uncertainties and the given noise margins.
    pub fn new(params: ScooterParams<T>, delta: ArrUncertainty<T>, noise_margin: [T; 3]) -> Self {
        Self {
            params,
            delta,
            noise_margin,
            positions: [T::zero(); 3],
            previous_y: None,
            history: [[T::zero(); 3]; 2],
            last_dt: T::zero(),
            samples: 0,
        }
    }

    /// Default margins for the default sensor noise (encoders 1e-3 rad/s, body 1e-4 m/s).
    pub fn nominal() -> Self {
        Self::new(
            ScooterParams::nominal(),
            ArrUncertainty::table3(),
            [cast(0.12), cast(0.2), cast(0.06)],
        )
    }

    /// Evaluates the ARRs at a new sample: `u` is the input held over the last interval, `y`
    /// the measured `[omega_r, v_m, omega_f]`. Rejects non-finite data and `dt <= 0` (state
    /// unchanged). The first sample only initialises the differentiators (zero residuals).
    pub fn step(&mut self, u: T, y: &[T; 3], dt: T) -> Result<ArrReport<T>, Error> {
        crate::error::check_dt(dt)?;
        if !u.finite() {
            return Err(Error::NonFiniteInput);
        }
        if !all_finite(y) {
            return Err(Error::NonFiniteMeasurement);
        }
        let [wr, vm, wf] = *y;
        let Some([pwr, pvm, pwf]) = self.previous_y else {
            self.previous_y = Some(*y);
            return Ok(ArrReport {
                residuals: [T::zero(); 3],
                thresholds: self.noise_margin,
                cv: 0,
                psi: T::zero(),
            });
        };
        let p = &self.params;
        let d = &self.delta;
        let half: T = cast(0.5);
        let [mut th_r, mut s_m, mut th_f] = self.positions;
        th_r += (wr + pwr) * half * dt;
        s_m += (vm + pvm) * half * dt;
        th_f += (wf + pwf) * half * dt;
        let (ar, am, af) = ((wr - pwr) / dt, (vm - pvm) / dt, (wf - pwf) / dt);
        let n3sq = p.n3 * p.n3;
        let tw1 = th_r - s_m / p.n4;
        let tw2 = s_m / p.n4 - th_f;
        let (sr, sf) = (p.sign(wr), p.sign(wf));
        let r1 = p.drive_torque(u)
            - (p.j_r + p.j_m / n3sq) * ar
            - (p.r_rc + p.r_mc / p.n3) * sr
            - (p.r_rv + p.r_mv / n3sq) * wr
            - p.k1 * tw1;
        let r2 = p.k1 * tw1 - p.m * p.n4 * am - p.k2 * tw2;
        let r3 = p.k2 * tw2 - p.r_fc * sf - p.r_fv * wf - p.j_f * af;
        let a1 = d.j_r * p.j_r * ar.abs()
            + d.r_rc * p.r_rc * sr.abs()
            + d.r_rv * p.r_rv * wr.abs()
            + d.r_mc * p.r_mc / p.n3 * sr.abs()
            + d.r_mv * p.r_mv / n3sq * wr.abs()
            + d.j_m * p.j_m / n3sq * ar.abs()
            + d.k1 * p.k1 * tw1.abs();
        let a2 = d.k1 * p.k1 * tw1.abs() + d.m * p.m * p.n4 * am.abs() + d.k2 * p.k2 * tw2.abs();
        let a3 = d.k2 * p.k2 * tw2.abs()
            + d.r_fc * p.r_fc * sf.abs()
            + d.r_fv * p.r_fv * wf.abs()
            + d.j_f * p.j_f * af.abs();
        let residuals = [r1, r2, r3];
        let [m1, m2, m3] = self.noise_margin;
        let thresholds = [a1 + m1, a2 + m2, a3 + m3];
        if !all_finite(&residuals) || !all_finite(&thresholds) {
            return Err(Error::NonFiniteState);
        }
        let mut cv = 0u8;
        for (i, (r, a)) in residuals.iter().zip(thresholds.iter()).enumerate() {
            if r.abs() > *a {
                cv |= 1 << i;
            }
        }
        let dt2 = dt * dt;
        let two: T = cast(2.0);
        let [h1, h2] = self.history;
        let mut psi = T::zero();
        if self.samples >= 2 {
            for (i, ((r, a), b)) in residuals.iter().zip(h1.iter()).zip(h2.iter()).enumerate() {
                if cv & (1 << i) != 0 {
                    psi += if (dt - self.last_dt).abs() <= self.last_dt * cast::<T>(1e-3) {
                        ((*r - two * *a + *b) / dt2).abs()
                    } else {
                        // Unequal intervals (a missing sample): the three-point second
                        // derivative on a non-uniform grid, or a linear drift would fire.
                        ((*r - *a) / dt - (*a - *b) / self.last_dt).abs() * two
                            / (dt + self.last_dt)
                    };
                }
            }
        }
        // The integrals enter only through the twists: keep them bounded (see rebase_angles).
        rebase_angles(&mut th_r, &mut s_m, &mut th_f, p.n4);
        self.positions = [th_r, s_m, th_f];
        self.previous_y = Some(*y);
        self.history = [residuals, h1];
        self.last_dt = dt;
        self.samples = self.samples.saturating_add(1);
        Ok(ArrReport {
            residuals,
            thresholds,
            cv,
            psi,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_fault_candidates_for_cv_110() {
        // CV = [1 1 0]: the paper's SFC {b, K1, b&Rrv, b&K1, b&Rrv&K1, Rrv&K1}.
        let cv = 0b011;
        let mut got = [0u8; 8];
        let mut n = 0;
        for s in fault_candidates(cv) {
            got[n] = s;
            n += 1;
        }
        use fault::*;
        let mut expected = [
            BETA_THETA_R,
            K1,
            BETA_THETA_R | R_RV,
            BETA_THETA_R | K1,
            BETA_THETA_R | R_RV | K1,
            R_RV | K1,
        ];
        expected.sort_unstable();
        let got = &mut got[..n];
        got.sort_unstable();
        assert_eq!(got, &expected[..]);
        assert_eq!(suspected_faults(cv), BETA_THETA_R | R_RV | K1);
        assert_eq!(fault_candidates(0).count(), 0);
        assert_eq!(suspected_faults(0b001), R_RV);
    }

    #[test]
    fn rejects_bad_samples_without_changing_state() {
        let mut arr = ScooterArr::<f64>::nominal();
        arr.step(1.0, &[0.0, 0.0, 0.0], 0.02).unwrap();
        arr.step(1.0, &[0.4, 0.04, 0.3], 0.02).unwrap();
        let before = arr.clone();
        assert_eq!(
            arr.step(1.0, &[f64::NAN, 0.0, 0.0], 0.02),
            Err(Error::NonFiniteMeasurement)
        );
        assert_eq!(
            arr.step(f64::INFINITY, &[0.4, 0.0, 0.0], 0.02),
            Err(Error::NonFiniteInput)
        );
        assert_eq!(
            arr.step(1.0, &[0.4, 0.0, 0.0], 0.0),
            Err(Error::InvalidTimeStep)
        );
        assert_eq!(arr.positions, before.positions);
        assert_eq!(arr.previous_y, before.previous_y);
    }
}
