//! Sequential prognosis of an intermittent fault under changing usage (Yu et al. 2020,
//! section 3.2): usage-dependent degradation (Eq. 8), degradation coefficients (Eqs. 10 and
//! 13), EOL (Eqs. 11 and 14), reactivation events EV1-EV4 (Eq. 9) and the Monte-Carlo RUL
//! distribution (Eqs. 16-18).
//!
//! Between its appearing and disappearing moments the fault holds a value; the values at the
//! disappearing moments `t_d` follow `F(t) = F_bar exp(lambda (t - t_bar)^2)`. Eq. 13 as
//! printed multiplies by the squared interval; we divide, as Eq. 10 does (the designed
//! coefficients of experiment 1, -0.002 and -0.01, are reproduced only this way).

use crate::error::Error;
use crate::random::normal;
use crate::real::{Real, cast};
use rand_core::Rng;

/// Maximum number of disappearing moments and usage changes remembered.
pub const CAPACITY: usize = 16;

/// A fault event fed to the prognoser.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FaultEvent<T> {
    /// The intermittent fault appeared.
    Appeared { time: T },
    /// The fault disappeared; `value` is its estimate over the interval that just ended and
    /// `variance` the estimator's variance of it.
    Disappeared { time: T, value: T, variance: T },
    /// The usage condition changed.
    UsageChanged { time: T },
}

/// The reactivation events of Eq. 9.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Reactivation {
    /// EV1: the degradation keeps its direction after the usage change (monotonic).
    pub monotonic: bool,
    /// EV2: the newest value has not crossed the failure threshold.
    pub before_threshold: bool,
    /// EV3: at least two disappearing moments since the usage change.
    pub enough_estimates: bool,
    /// EV4: a usage change was observed.
    pub usage_changed: bool,
}

impl Reactivation {
    /// `Omega_p`: all four events hold.
    pub fn reactivate(&self) -> bool {
        self.monotonic && self.before_threshold && self.enough_estimates && self.usage_changed
    }
}

/// One identified degradation segment (`Upsilon_f` for usage 1, `Upsilon_r` after a change).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Segment<T> {
    /// Usage index `j` (1 before any change).
    pub usage: u8,
    /// Reference time `t_bar` (`t_a1`, or the first disappearance after the change).
    pub t_ref: T,
    /// Value at the reference time and its variance (zero variance for `F_nom`).
    pub f_ref: T,
    pub f_ref_variance: T,
    /// The disappearing moment at which the segment was identified, its value and variance.
    pub t_id: T,
    pub f_id: T,
    pub f_id_variance: T,
    /// Degradation coefficient `lambda` (Eq. 10 or 13).
    pub lambda: T,
    /// End of life (Eq. 11 or 14), `MAX_FINITE` when the threshold is never reached.
    pub eol: T,
}

impl<T: Real> Segment<T> {
    /// RUL at the identification moment (Eqs. 12 and 15).
    pub fn rul(&self) -> T {
        self.eol - self.t_id
    }
}

/// What an event did to the prognoser.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Outcome<T> {
    /// Nothing to predict yet (or the event was recorded only).
    Recorded,
    /// The prognoser was enabled (`t_d1`) or reactivated with a new segment.
    Predicted(Segment<T>),
    /// The reactivation point was reached but Eq. 9 refused it.
    NotReactivated(Reactivation),
}

/// Coefficient `lambda = ln(F_id / F_ref) / (t_id - t_ref)^2` (Eqs. 10 and 13).
pub fn degradation_coefficient<T: Real>(f_ref: T, t_ref: T, f_id: T, t_id: T) -> Option<T> {
    let dt = t_id - t_ref;
    if !(dt > T::zero()) || !(f_ref > T::zero()) || !(f_id > T::zero()) {
        return None;
    }
    let lambda = (f_id / f_ref).ln() / (dt * dt);
    lambda.finite().then_some(lambda)
}

/// End of life `t_ref + sqrt(ln(F_end / F_ref) / lambda)` (Eqs. 11 and 14); `None` when the
/// trajectory never reaches `F_end` (wrong direction or `lambda = 0`).
pub fn end_of_life<T: Real>(f_ref: T, t_ref: T, lambda: T, f_end: T) -> Option<T> {
    if !(f_ref > T::zero()) || !(f_end > T::zero()) || lambda == T::zero() {
        return None;
    }
    let ratio = (f_end / f_ref).ln() / lambda;
    (ratio >= T::zero() && ratio.finite()).then(|| t_ref + ratio.sqrt())
}

/// The sequential prognoser of one intermittent fault parameter.
#[derive(Clone, Debug)]
pub struct SequentialPrognoser<T: Real> {
    f_nom: T,
    f_end: T,
    first_appearance: Option<T>,
    disappearances: heapless::Vec<(T, T, T), CAPACITY>,
    usage_changes: heapless::Vec<T, CAPACITY>,
    segment: Option<Segment<T>>,
    /// Usage changes already handled (reactivated or refused).
    handled_changes: usize,
}

impl<T: Real> SequentialPrognoser<T> {
    /// Prognoser for a parameter with nominal value `f_nom` and failure threshold `f_end`.
    pub fn new(f_nom: T, f_end: T) -> Result<Self, Error> {
        if !(f_nom > T::zero()) || !(f_end > T::zero()) || !f_nom.finite() || !f_end.finite() {
            return Err(Error::InvalidParameter("f_nom and f_end must be positive"));
        }
        if f_nom == f_end {
            return Err(Error::InvalidParameter("f_end equals f_nom"));
        }
        Ok(Self {
            f_nom,
            f_end,
            first_appearance: None,
            disappearances: heapless::Vec::new(),
            usage_changes: heapless::Vec::new(),
            segment: None,
            handled_changes: 0,
        })
    }

    /// The current degradation segment, if any.
    pub fn segment(&self) -> Option<&Segment<T>> {
        self.segment.as_ref()
    }

    /// Feeds one event (times must not decrease). Non-finite data is rejected unchanged.
    pub fn on_event(&mut self, event: FaultEvent<T>) -> Result<Outcome<T>, Error> {
        match event {
            FaultEvent::Appeared { time } => {
                if !time.finite() {
                    return Err(Error::NonFiniteMeasurement);
                }
                if self.first_appearance.is_none() {
                    self.first_appearance = Some(time);
                }
                Ok(Outcome::Recorded)
            }
            FaultEvent::UsageChanged { time } => {
                if !time.finite() {
                    return Err(Error::NonFiniteInput);
                }
                self.usage_changes
                    .push(time)
                    .map_err(|_| Error::InsufficientData)?;
                Ok(Outcome::Recorded)
            }
            FaultEvent::Disappeared {
                time,
                value,
                variance,
            } => {
                if !time.finite() || !value.finite() || !variance.finite() {
                    return Err(Error::NonFiniteMeasurement);
                }
                if !(value > T::zero()) || variance < T::zero() {
                    return Err(Error::OutOfRange("fault value"));
                }
                let Some(t_a1) = self.first_appearance else {
                    // A disappearance without an appearance cannot start a trajectory.
                    return Ok(Outcome::Recorded);
                };
                self.disappearances
                    .push((time, value, variance))
                    .map_err(|_| Error::InsufficientData)?;
                if self.disappearances.len() == 1 {
                    return Ok(self.enable(t_a1, time, value, variance));
                }
                Ok(self.consider_reactivation())
            }
        }
    }

    /// Eq. 10-12 at `t_d1`.
    fn enable(&mut self, t_a1: T, t_d1: T, value: T, variance: T) -> Outcome<T> {
        let Some(lambda) = degradation_coefficient(self.f_nom, t_a1, value, t_d1) else {
            return Outcome::Recorded;
        };
        let eol = end_of_life(self.f_nom, t_a1, lambda, self.f_end).unwrap_or(T::MAX_FINITE);
        let segment = Segment {
            usage: 1,
            t_ref: t_a1,
            f_ref: self.f_nom,
            f_ref_variance: T::zero(),
            t_id: t_d1,
            f_id: value,
            f_id_variance: variance,
            lambda,
            eol,
        };
        self.segment = Some(segment);
        Outcome::Predicted(segment)
    }

    /// Eq. 9 and Eqs. 13-15 at the second disappearance after the latest unhandled change.
    fn consider_reactivation(&mut self) -> Outcome<T> {
        let Some(&t_s) = self.usage_changes.get(self.handled_changes) else {
            return Outcome::Recorded;
        };
        let t_next = self
            .usage_changes
            .get(self.handled_changes.saturating_add(1))
            .copied()
            .unwrap_or(T::MAX_FINITE);
        let mut after = self
            .disappearances
            .iter()
            .filter(|(t, _, _)| *t > t_s && *t < t_next);
        let (Some(&first), Some(&second)) = (after.next(), after.next()) else {
            return Outcome::Recorded;
        };
        self.handled_changes = self.handled_changes.saturating_add(1);
        let Some(&(_, f_d1, _)) = self.disappearances.first() else {
            return Outcome::Recorded;
        };
        let direction = |d: T| {
            if d > T::zero() {
                1i8
            } else if d < T::zero() {
                -1
            } else {
                0
            }
        };
        let events = Reactivation {
            monotonic: direction(second.1 - first.1) == direction(f_d1 - self.f_nom),
            before_threshold: direction(second.1 - self.f_end)
                == direction(self.f_nom - self.f_end),
            enough_estimates: true,
            usage_changed: true,
        };
        if !events.reactivate() {
            return Outcome::NotReactivated(events);
        }
        let Some(lambda) = degradation_coefficient(first.1, first.0, second.1, second.0) else {
            return Outcome::NotReactivated(events);
        };
        let eol = end_of_life(first.1, first.0, lambda, self.f_end).unwrap_or(T::MAX_FINITE);
        let usage = u8::try_from(self.handled_changes.saturating_add(1)).unwrap_or(u8::MAX);
        let segment = Segment {
            usage,
            t_ref: first.0,
            f_ref: first.1,
            f_ref_variance: first.2,
            t_id: second.0,
            f_id: second.1,
            f_id_variance: second.2,
            lambda,
            eol,
        };
        self.segment = Some(segment);
        Outcome::Predicted(segment)
    }

    /// Monte-Carlo RUL distribution of the current segment (Eqs. 16-17): `out.len()` samples
    /// of the fault values from `N(F_hat, P_F)`, each giving a coefficient and an EOL. Samples
    /// that never reach the threshold get `MAX_FINITE`. Returns the mean RUL of the samples
    /// that reach it (Eq. 18) and their count.
    pub fn rul_samples<R: Rng + ?Sized>(
        &self,
        rng: &mut R,
        out: &mut [T],
    ) -> Result<(T, usize), Error> {
        let seg = self.segment.as_ref().ok_or(Error::InsufficientData)?;
        if out.is_empty() {
            return Err(Error::InsufficientData);
        }
        let mut sum = T::zero();
        let mut count = 0usize;
        for slot in out.iter_mut() {
            let f_ref = if seg.f_ref_variance > T::zero() {
                normal(rng, seg.f_ref, seg.f_ref_variance.sqrt())
            } else {
                seg.f_ref
            };
            let f_id = normal(rng, seg.f_id, seg.f_id_variance.sqrt());
            let eol = degradation_coefficient(f_ref, seg.t_ref, f_id, seg.t_id)
                .and_then(|lambda| end_of_life(f_ref, seg.t_ref, lambda, self.f_end));
            *slot = match eol {
                Some(e) => {
                    let rul = e - seg.t_id;
                    sum += rul;
                    count = count.saturating_add(1);
                    rul
                }
                None => T::MAX_FINITE,
            };
        }
        if count == 0 {
            return Err(Error::HorizonExceeded);
        }
        Ok((sum / cast(count as f64), count))
    }
}

/// Turns the auxiliary detector's change moments into appearing/disappearing events: a
/// change while the estimate is near nominal is an appearance, otherwise a disappearance.
#[derive(Clone, Copy, Debug)]
pub struct IntermittentTracker<T> {
    /// Nominal value of the parameter.
    pub nominal: T,
    /// Distance from nominal beyond which the fault counts as present.
    pub margin: T,
    /// Changes closer than this to the previous one are the same change.
    pub refractory: T,
    last_change: Option<T>,
}

impl<T: Real> IntermittentTracker<T> {
    /// Tracker with the given nominal value, margin and refractory time.
    pub fn new(nominal: T, margin: T, refractory: T) -> Self {
        Self {
            nominal,
            margin,
            refractory,
            last_change: None,
        }
    }

    /// A change detected at `time`, with the estimate and variance held just before it.
    pub fn on_change(&mut self, time: T, estimate: T, variance: T) -> Option<FaultEvent<T>> {
        if !time.finite() || !estimate.finite() {
            return None;
        }
        if let Some(last) = self.last_change
            && time - last < self.refractory
        {
            return None;
        }
        self.last_change = Some(time);
        if (estimate - self.nominal).abs() > self.margin {
            Some(FaultEvent::Disappeared {
                time,
                value: estimate,
                variance: variance.max(T::zero()),
            })
        } else {
            Some(FaultEvent::Appeared { time })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics::relative_accuracy;
    use rand_core::SeedableRng;
    use rand_xoshiro::Xoshiro256PlusPlus;

    fn feed(
        p: &mut SequentialPrognoser<f64>,
        events: &[FaultEvent<f64>],
    ) -> [Option<Outcome<f64>>; 12] {
        let mut out = [None; 12];
        for (slot, e) in out.iter_mut().zip(events) {
            *slot = Some(p.on_event(*e).unwrap());
        }
        out
    }

    fn experiment1_events() -> [FaultEvent<f64>; 9] {
        use FaultEvent::*;
        [
            Appeared { time: 10.0 },
            Disappeared {
                time: 15.56,
                value: 0.94,
                variance: 0.0,
            },
            Appeared { time: 18.0 },
            UsageChanged { time: 19.8 },
            Disappeared {
                time: 21.16,
                value: 0.78,
                variance: 0.0,
            },
            Appeared { time: 24.0 },
            Disappeared {
                time: 27.08,
                value: 0.55,
                variance: 0.0,
            },
            Appeared { time: 28.5 },
            Disappeared {
                time: 30.94,
                value: 0.3,
                variance: 0.0,
            },
        ]
    }

    #[test]
    fn designed_ruls_of_experiment_1() {
        let mut p = SequentialPrognoser::new(1.0, 0.3).unwrap();
        let out = feed(&mut p, &experiment1_events());
        let Some(Outcome::Predicted(s1)) = out[1] else {
            panic!("{:?}", out[1])
        };
        assert!((s1.lambda + 0.002).abs() < 1e-5, "{}", s1.lambda);
        assert!((s1.rul() - 18.98).abs() < 0.02, "{}", s1.rul());
        assert_eq!(out[4], Some(Outcome::Recorded));
        let Some(Outcome::Predicted(s2)) = out[6] else {
            panic!("{:?}", out[6])
        };
        assert_eq!(s2.usage, 2);
        assert!((s2.lambda + 0.01).abs() < 1e-4, "{}", s2.lambda);
        assert!((s2.rul() - 3.86).abs() < 0.02, "{}", s2.rul());
        // The designed EOL is the last disappearing moment, where F reaches F_end.
        assert!((s2.eol - 30.94).abs() < 0.02);
    }

    #[test]
    fn experiment_2_is_not_reactivated_after_the_non_monotonic_change() {
        use FaultEvent::*;
        let mut p = SequentialPrognoser::new(1.0, 0.3).unwrap();
        let events = [
            Appeared { time: 10.0 },
            Disappeared {
                time: 15.3,
                value: 0.92,
                variance: 0.0,
            },
            Appeared { time: 19.2 },
            UsageChanged { time: 19.7 },
            Disappeared {
                time: 21.0,
                value: 0.7,
                variance: 0.0,
            },
            Appeared { time: 24.0 },
            Disappeared {
                time: 27.0,
                value: 0.82,
                variance: 0.0,
            },
        ];
        let out = feed(&mut p, &events);
        let Some(Outcome::Predicted(s1)) = out[1] else {
            panic!()
        };
        assert!((s1.lambda + 0.003).abs() < 5e-5);
        assert!((s1.rul() - 14.8).abs() < 0.1, "{}", s1.rul());
        let Some(Outcome::NotReactivated(ev)) = out[6] else {
            panic!("{:?}", out[6])
        };
        assert!(!ev.monotonic && ev.before_threshold && ev.enough_estimates && ev.usage_changed);
        assert_eq!(p.segment().map(|s| s.usage), Some(1));
    }

    #[test]
    fn monte_carlo_rul_is_centred_on_the_deterministic_one() {
        let mut p = SequentialPrognoser::new(1.0, 0.3).unwrap();
        p.on_event(FaultEvent::Appeared { time: 10.0 }).unwrap();
        p.on_event(FaultEvent::Disappeared {
            time: 15.56,
            value: 0.94,
            variance: 1e-6,
        })
        .unwrap();
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(3);
        let mut samples = [0.0f64; 80];
        let (mean, n) = p.rul_samples(&mut rng, &mut samples).unwrap();
        assert_eq!(n, 80);
        // dRUL/dF ~ 160 s per unit: std(F) = 1e-3 gives a spread of about 0.16 s.
        assert!((mean - 18.98).abs() < 0.1, "{mean}");
        let ra = relative_accuracy(18.98, mean).unwrap();
        assert!(ra > 99.0);
        let spread = crate::metrics::relative_std(&samples).unwrap();
        assert!(spread > 0.3 && spread < 2.0, "{spread}");
    }

    #[test]
    fn bad_events_are_rejected() {
        let mut p = SequentialPrognoser::new(1.0, 0.3).unwrap();
        assert!(SequentialPrognoser::<f64>::new(1.0, 1.0).is_err());
        assert!(p.on_event(FaultEvent::Appeared { time: f64::NAN }).is_err());
        p.on_event(FaultEvent::Appeared { time: 10.0 }).unwrap();
        assert!(
            p.on_event(FaultEvent::Disappeared {
                time: 12.0,
                value: -0.5,
                variance: 0.0
            })
            .is_err()
        );
        assert!(
            p.on_event(FaultEvent::Disappeared {
                time: 12.0,
                value: f64::NAN,
                variance: 0.0
            })
            .is_err()
        );
        assert!(p.segment().is_none());
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(3);
        assert_eq!(
            p.rul_samples(&mut rng, &mut [0.0; 4]),
            Err(Error::InsufficientData)
        );
    }

    #[test]
    fn tracker_classifies_changes_and_ignores_repeats() {
        let mut t = IntermittentTracker::new(1.0, 0.02, 0.2);
        assert_eq!(
            t.on_change(10.02, 1.0, 1e-6),
            Some(FaultEvent::Appeared { time: 10.02 })
        );
        assert_eq!(t.on_change(10.06, 0.95, 1e-6), None);
        assert_eq!(
            t.on_change(15.58, 0.94, 1e-6),
            Some(FaultEvent::Disappeared {
                time: 15.58,
                value: 0.94,
                variance: 1e-6
            })
        );
    }
}
