//! The edge half of the edge-cloud prognoser (Barbieri et al. 2021, "Edge-computing on PLCs"):
//! a FIFO circular buffer of `S` snapshots of `L` samples (12 x 256 at 2560 Hz in the paper),
//! an ORIV AR(`N`) model with `Q` extra instruments identified on the whole buffer at every
//! new snapshot (every 10 s), the reference model as the mean of the first models after a
//! warm-up, and the local backup indicator `HI_NRMSE` (Eq. 17) with its alarm threshold.
//!
//! Size (f32, N = Q = 8, S = 12, L = 256): the buffer is 12 KB, the rest under 200 B; the
//! identification runs a fresh [`Oriv`](crate::learn::ar::Oriv) on the stack (about 0.8 KB).

use crate::error::Error;
use crate::health::nrmse;
use crate::learn::ar::{ArModel, OrivConfig, WindowCheck, check_window, identify};
use crate::real::{Real, cast};
use nalgebra::SVector;

/// Settings of the edge monitor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EdgeConfig<T: Real> {
    /// ORIV settings (`psi = 10`, no instrument delay in the paper).
    pub oriv: OrivConfig<T>,
    /// Screening of each incoming snapshot (flat, saturated, non-finite).
    pub check: WindowCheck<T>,
    /// Models made before transmission and the reference start (the paper waits about
    /// 1500 s for the grease to reach its working temperature).
    pub warmup_models: usize,
    /// Number of transmitted models averaged into the reference (10 in the paper).
    pub reference_models: usize,
    /// Backup alarm threshold on `HI_NRMSE` (the paper uses 1, range [1, 1.1]).
    pub nrmse_alarm: T,
}

impl<T: Real> Default for EdgeConfig<T> {
    fn default() -> Self {
        Self {
            oriv: OrivConfig::default(),
            check: WindowCheck::default(),
            warmup_models: 0,
            reference_models: 10,
            nrmse_alarm: cast(1.0),
        }
    }
}

/// What one snapshot produced once the buffer is full.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EdgeReport<T: Real, const N: usize> {
    /// The model identified on the buffer ending with this snapshot.
    pub model: ArModel<T, N>,
    /// 1-based count of models made so far.
    pub model_index: usize,
    /// True once past the warm-up: this model is sent to the cloud.
    pub transmit: bool,
    /// `HI_NRMSE` against the reference, once the reference exists.
    pub hi_nrmse: Option<T>,
    /// `HI_NRMSE` is above the backup alarm threshold.
    pub alarm: bool,
}

/// The edge monitor: buffer, identification, reference and local indicator.
#[derive(Clone, Debug)]
pub struct EdgeMonitor<T: Real, const N: usize, const Q: usize, const S: usize, const L: usize> {
    config: EdgeConfig<T>,
    buffer: [[T; L]; S],
    /// Slot of the oldest snapshot once the buffer is full.
    head: usize,
    filled: usize,
    model: Option<ArModel<T, N>>,
    models_made: usize,
    reference_sum: SVector<T, N>,
    reference_count: usize,
    reference: Option<SVector<T, N>>,
}

impl<T: Real, const N: usize, const Q: usize, const S: usize, const L: usize>
    EdgeMonitor<T, N, Q, S, L>
{
    /// New, empty monitor.
    pub fn new(config: EdgeConfig<T>) -> Result<Self, Error> {
        if S == 0 || L == 0 {
            return Err(Error::InvalidParameter("buffer size"));
        }
        if config.reference_models == 0 {
            return Err(Error::InvalidParameter("reference_models"));
        }
        if !(config.nrmse_alarm.finite() && config.nrmse_alarm > T::zero()) {
            return Err(Error::InvalidParameter("nrmse_alarm"));
        }
        // Validates psi and the instrument delay once, up front.
        crate::learn::ar::Oriv::<T, N, Q>::new(&config.oriv)?;
        Ok(Self {
            config,
            buffer: [[T::zero(); L]; S],
            head: 0,
            filled: 0,
            model: None,
            models_made: 0,
            reference_sum: SVector::zeros(),
            reference_count: 0,
            reference: None,
        })
    }

    /// The last good model (held when a window fails).
    pub fn model(&self) -> Option<&ArModel<T, N>> {
        self.model.as_ref()
    }

    /// The reference parameters, once `reference_models` transmitted models were averaged.
    pub fn reference(&self) -> Option<&SVector<T, N>> {
        self.reference.as_ref()
    }

    /// Number of snapshots in the buffer.
    pub fn filled(&self) -> usize {
        self.filled
    }

    /// Adds one snapshot (FIFO). Returns `Ok(None)` while the buffer is filling, otherwise the
    /// model of the window ending with this snapshot. A non-finite, flat or saturated
    /// snapshot, or a window on which ORIV fails, returns `Err`: the snapshot is dropped, the
    /// buffer and the last good model are kept.
    pub fn push_snapshot(&mut self, snapshot: &[T; L]) -> Result<Option<EdgeReport<T, N>>, Error> {
        check_window(snapshot.iter().copied(), &self.config.check)?;
        let full = self.filled >= S;
        let (start, kept) = if full {
            (self.head.saturating_add(1), S.saturating_sub(1))
        } else {
            (0, self.filled)
        };
        let slot = if full { self.head } else { self.filled };
        if !full && self.filled.saturating_add(1) < S {
            self.store(slot, snapshot);
            self.filled = self.filled.saturating_add(1);
            return Ok(None);
        }
        let buffer = &self.buffer;
        let window = (0..kept)
            .filter_map(move |k| buffer.get(start.saturating_add(k).checked_rem(S)?))
            .flat_map(|s| s.iter().copied())
            .chain(snapshot.iter().copied());
        let model = identify::<T, N, Q, _>(window, &self.config.oriv, &self.config.check)?;
        self.store(slot, snapshot);
        if full {
            self.head = self.head.saturating_add(1).checked_rem(S).unwrap_or(0);
        } else {
            self.filled = self.filled.saturating_add(1);
            self.head = 0;
        }
        Ok(Some(self.accept(model)))
    }

    fn store(&mut self, slot: usize, snapshot: &[T; L]) {
        if let Some(dst) = self.buffer.get_mut(slot) {
            *dst = *snapshot;
        }
    }

    fn accept(&mut self, model: ArModel<T, N>) -> EdgeReport<T, N> {
        self.model = Some(model);
        self.models_made = self.models_made.saturating_add(1);
        let transmit = self.models_made > self.config.warmup_models;
        if transmit && self.reference.is_none() {
            self.reference_sum += model.theta;
            self.reference_count = self.reference_count.saturating_add(1);
            if self.reference_count >= self.config.reference_models {
                self.reference = Some(self.reference_sum / cast::<T>(self.reference_count as f64));
            }
        }
        let hi_nrmse = self
            .reference
            .as_ref()
            .and_then(|r| nrmse(&model.theta, r).ok());
        EdgeReport {
            model,
            model_index: self.models_made,
            transmit,
            hi_nrmse,
            alarm: hi_nrmse.is_some_and(|h| h > self.config.nrmse_alarm),
        }
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use crate::random::standard_normal;
    use rand_core::SeedableRng;
    use rand_xoshiro::Xoshiro256PlusPlus;
    use std::vec::Vec;

    type Monitor = EdgeMonitor<f64, 2, 2, 12, 256>;

    /// Snapshots of a continuous AR(2) process whose coefficients switch after `switch_at`.
    fn snapshots(count: usize, switch_at: usize, seed: u64) -> Vec<[f64; 256]> {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        let (mut y1, mut y2) = (0.0, 0.0);
        (0..count)
            .map(|k| {
                let (a1, a2) = if k < switch_at {
                    (-1.5, 0.8)
                } else {
                    (0.3, 0.4)
                };
                core::array::from_fn(|_| {
                    let e: f64 = standard_normal(&mut rng);
                    let y = e - a1 * y1 - a2 * y2;
                    y2 = y1;
                    y1 = y;
                    y
                })
            })
            .collect()
    }

    #[test]
    fn buffer_is_fifo_and_models_every_snapshot_once_full() {
        let snaps = snapshots(20, 100, 1);
        let mut mon = Monitor::new(EdgeConfig::default()).unwrap();
        for (k, s) in snaps.iter().enumerate() {
            let out = mon.push_snapshot(s).unwrap();
            if k < 11 {
                assert!(out.is_none());
                continue;
            }
            let report = out.unwrap();
            assert_eq!(report.model_index, k - 10);
            // Same as identifying the last 12 snapshots in chronological order.
            let window = snaps[k - 11..=k].iter().flat_map(|s| s.iter().copied());
            let direct =
                identify::<f64, 2, 2, _>(window, &OrivConfig::default(), &WindowCheck::default())
                    .unwrap();
            assert_eq!(report.model, direct);
            assert!((report.model.theta[0] + 1.5).abs() < 0.1);
            assert!((report.model.theta[1] - 0.8).abs() < 0.1);
        }
    }

    #[test]
    fn reference_after_warmup_and_nrmse_alarm_on_change() {
        let config = EdgeConfig {
            warmup_models: 3,
            reference_models: 10,
            ..EdgeConfig::default()
        };
        let snaps = snapshots(60, 30, 2);
        let mut mon = Monitor::new(config).unwrap();
        let mut reports = Vec::new();
        for s in &snaps {
            if let Some(r) = mon.push_snapshot(s).unwrap() {
                reports.push(r);
            }
        }
        // Models 1-3 are warm-up, 4-13 form the reference; HI exists from model 13 on.
        assert!(!reports[2].transmit && reports[3].transmit);
        assert!(reports[11].hi_nrmse.is_none());
        let hi_healthy = reports[12].hi_nrmse.unwrap();
        assert!(hi_healthy < 0.4, "{hi_healthy}");
        assert!(!reports[12].alarm);
        // Once the buffer holds only the new process, HI_NRMSE is far above 1.
        let last = reports.last().unwrap();
        let hi_faulty = last.hi_nrmse.unwrap();
        let expected = (nalgebra::Vector2::<f64>::new(0.3 + 1.5, 0.4 - 0.8).norm()
            / nalgebra::Vector2::<f64>::new(-1.5, 0.8).norm())
        .sqrt();
        assert!(
            (hi_faulty - expected).abs() < 0.1,
            "{hi_faulty} vs {expected}"
        );
        assert!(last.alarm);
    }

    #[test]
    fn flat_or_saturated_snapshot_is_rejected_and_last_model_held() {
        let snaps = snapshots(16, 100, 3);
        let mut mon = Monitor::new(EdgeConfig::default()).unwrap();
        let mut twin = Monitor::new(EdgeConfig::default()).unwrap();
        for s in &snaps[..13] {
            mon.push_snapshot(s).unwrap();
            twin.push_snapshot(s).unwrap();
        }
        let held = *mon.model().unwrap();
        let flat = [0.7f64; 256];
        assert_eq!(
            mon.push_snapshot(&flat),
            Err(Error::OutOfRange("signal window (flat)"))
        );
        let saturated: [f64; 256] =
            core::array::from_fn(|i| (0.5 * i as f64).sin().clamp(-0.3, 0.3));
        assert_eq!(
            mon.push_snapshot(&saturated),
            Err(Error::OutOfRange("signal window (saturated)"))
        );
        let mut nan = snaps[13];
        nan[5] = f64::NAN;
        assert_eq!(mon.push_snapshot(&nan), Err(Error::NonFiniteMeasurement));
        assert_eq!(*mon.model().unwrap(), held);
        assert!(mon.model().unwrap().theta.iter().all(|v| v.is_finite()));
        // The rejected snapshots left no trace: the next good one gives the twin's model.
        let a = mon.push_snapshot(&snaps[13]).unwrap().unwrap();
        let b = twin.push_snapshot(&snaps[13]).unwrap().unwrap();
        assert_eq!(a, b);
    }

    #[test]
    fn runs_in_f32() {
        let snaps = snapshots(13, 100, 4);
        let mut mon = EdgeMonitor::<f32, 2, 2, 12, 256>::new(EdgeConfig::default()).unwrap();
        let mut last = None;
        for s in &snaps {
            let s32: [f32; 256] = core::array::from_fn(|i| s[i] as f32);
            last = mon.push_snapshot(&s32).unwrap();
        }
        let m = last.unwrap().model;
        assert!((m.theta[0] + 1.5).abs() < 0.1 && (m.theta[1] - 0.8).abs() < 0.1);
    }

    #[test]
    fn rejects_bad_config() {
        let bad = EdgeConfig {
            reference_models: 0,
            ..EdgeConfig::default()
        };
        assert!(Monitor::new(bad).is_err());
    }
}
