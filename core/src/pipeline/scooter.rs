//! The electric-scooter pipeline (Yu et al. 2020): ARR-based FDI, the AEUKF (or AUKF/UKF for
//! comparison) for joint estimation of the states and `[beta_theta_r, R_rv, K1]`, and the
//! sequential prognoser of the intermittent `beta_theta_r` fault, behind one
//! [`Scooter::step`] call at 50 Hz.
//!
//! Size: 4192 bytes in f32 (8312 in f64), dominated by the UKF (9 states, 19 sigma points)
//! and the 25-sample matching window. A step keeps one copy of the UKF on the stack (so that an
//! error leaves the pipeline unchanged); keep the pipeline in a `static`.

use crate::diagnose::scooter::{ArrReport, FaultSet, ScooterArr, suspected_faults};
use crate::error::Error;
use crate::filter::adaptive_ukf::{Adaptation, AdaptiveConfig, AdaptiveUkf};
use crate::filter::ukf::{SigmaParams, Ukf};
use crate::plants::scooter::{
    BETA_THETA_R, NS, NX, NY, S_M, ScooterModel, THETA_F, THETA_R, rebase_angles,
};
use crate::prognose::sequential::{FaultEvent, IntermittentTracker, Outcome, SequentialPrognoser};
use crate::real::{Real, all_finite, cast};
use crate::safeguard::Flags;
use nalgebra::{SMatrix, SVector, Vector1};

/// Covariance-matching window (samples).
pub const WINDOW: usize = 25;

/// Pipeline configuration (defaults: see [`ScooterConfig::new`]).
#[derive(Clone, Copy, Debug)]
pub struct ScooterConfig<T: Real> {
    /// Filter variant (the pipeline's own is [`Adaptation::Enhanced`]).
    pub mode: Adaptation,
    /// Initial covariance, process noise and measurement noise (diagonals).
    pub p0: SVector<T, NX>,
    pub q0: SVector<T, NX>,
    pub r0: SVector<T, NY>,
    /// Adaptive-layer settings (tau, floors, ceilings, enhancement mask, bounds).
    pub adaptive: AdaptiveConfig<T, NX, NY>,
    /// Auxiliary-detector threshold `Psi_0`.
    pub psi_threshold: T,
    /// Consecutive inconsistent samples that activate fault estimation.
    pub activation_samples: u32,
    /// `|beta - 1|` above which the fault counts as present when a change is detected.
    pub beta_margin: T,
    /// Changes closer than this (s) are one change.
    pub refractory: T,
    /// Failure threshold of `beta_theta_r`.
    pub beta_end: T,
    /// Plausible measurement ranges `[omega_r, v_m, omega_f]` and largest plausible jump
    /// between two samples; outside them a sample is an encoder glitch and is rejected.
    pub max_abs: [T; 3],
    pub max_jump: [T; 3],
    /// Largest plausible deviation of a sample from the straight-line trend of the last two
    /// processed samples. A sample beyond it is held for one sample: when the next sample
    /// returns to the trend, the held one was an isolated spike and is dropped (the next
    /// sample predicts over the gap); otherwise it was a real change and both are processed
    /// in order, with their own times (the estimate is then one sample late, never changed).
    pub spike_limit: [T; 3],
}

impl<T: Real> ScooterConfig<T> {
    /// The tuning used for the reproduced tables (see docs/deviations.md).
    pub fn new(mode: Adaptation) -> Self {
        let v = |a: [f64; NX]| SVector::<T, NX>::from_iterator(a.iter().map(|x| cast::<T>(*x)));
        let w = |a: [f64; NY]| SVector::<T, NY>::from_iterator(a.iter().map(|x| cast::<T>(*x)));
        let mut adaptive = AdaptiveConfig::new(
            mode,
            cast(5.0),
            v([
                1e-12, 1e-10, 1e-14, 1e-12, 1e-12, 1e-10, 1e-10, 1e-10, 1e-12,
            ]),
            v([1e-6, 1e-6, 1e-8, 1e-6, 1e-6, 1e-6, 1e-6, 1e-6, 1e-9]),
            w([1e-8, 1e-10, 1e-8]),
        );
        adaptive.enhance_floor = v([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.01, 0.0, 0.0]);
        adaptive.enhance_mask = v([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0]);
        adaptive.lower = v([-1e9, -1e9, -1e9, -1e9, -1e9, -1e9, 0.05, 0.0, 5.0]);
        adaptive.upper = v([1e9, 1e9, 1e9, 1e9, 1e9, 1e9, 1.5, 5.0, 20.0]);
        Self {
            mode,
            p0: v([1e-4, 1e-4, 1e-6, 1e-4, 1e-4, 1e-4, 0.05, 0.3, 0.01]),
            q0: v([1e-8, 1e-6, 1e-10, 1e-8, 1e-8, 1e-6, 1e-10, 1e-10, 1e-10]),
            r0: w([1e-6, 1e-8, 1e-6]),
            adaptive,
            psi_threshold: cast(760.0),
            activation_samples: 10,
            beta_margin: cast(0.02),
            refractory: cast(0.2),
            beta_end: cast(0.3),
            max_abs: [cast(100.0), cast(10.0), cast(100.0)],
            max_jump: [cast(5.0), cast(0.5), cast(5.0)],
            // Twice the largest second difference of clean runs of both experiments outside
            // sensor-efficiency steps (omega_f 0.031, v_m 0.0025; measured with 20 seeds).
            spike_limit: [cast(0.06), cast(0.005), cast(0.06)],
        }
    }
}

/// What one pipeline step found.
#[derive(Clone, Copy, Debug)]
pub struct ScooterReport<T: Real> {
    /// Residuals, thresholds, coherence vector and `Psi`.
    pub arr: ArrReport<T>,
    /// Faults that appear in some candidate set of the current coherence vector.
    pub suspected: FaultSet,
    /// Whether fault estimation has been activated (persistent inconsistency seen).
    pub active: bool,
    /// Augmented state estimate and the variance of `beta_theta_r`.
    pub state: SVector<T, NX>,
    pub beta_variance: T,
    /// Whether the covariance was enhanced on this sample.
    pub enhanced: bool,
    /// A fault event recognised on this sample and what the prognoser did with it.
    pub event: Option<FaultEvent<T>>,
    pub outcome: Option<Outcome<T>>,
    /// Safeguards that acted (`MEASUREMENT_REJECTED` when a held spike was dropped).
    pub flags: Flags,
    /// The sample was held (it deviates from the trend): nothing was processed yet and the
    /// report repeats the current estimate; the next sample decides.
    pub held: bool,
    /// A held sample was dropped as an isolated spike on this call.
    pub spike_dropped: bool,
}

/// A sample kept back by the spike check: time, input, measurement.
type HeldSample<T> = (T, T, [T; 3], [bool; 3]);

/// The scooter's on-board diagnoser and prognoser.
#[derive(Clone, Debug)]
pub struct Scooter<T: Real> {
    model: ScooterModel<T>,
    config: ScooterConfig<T>,
    arr: ScooterArr<T>,
    filter: AdaptiveUkf<T, NX, NS, NY, WINDOW>,
    tracker: IntermittentTracker<T>,
    prognoser: SequentialPrognoser<T>,
    time: T,
    last_y: Option<[T; 3]>,
    /// The processed sample before `last_y` and its time (the spike check's trend).
    previous: Option<(T, [T; 3])>,
    held: Option<HeldSample<T>>,
    last_arr: ArrReport<T>,
    /// The last sample rejected as a jump: a second sample agreeing with it is a real level
    /// change (e.g. after a dropout), not a glitch, and is accepted.
    jump_candidate: Option<[T; 3]>,
    last_u: Option<T>,
    inconsistent_run: u32,
    /// Time of the first sample of the current run of inconsistent samples.
    run_start: T,
    active: bool,
    psi_above: bool,
}

impl<T: Real> Scooter<T> {
    /// A pipeline at rest at time `t0` with the nominal model.
    pub fn new(t0: T, config: ScooterConfig<T>) -> Result<Self, Error> {
        if !t0.finite() {
            return Err(Error::InvalidParameter("t0"));
        }
        let model = ScooterModel::<T>::nominal();
        let ukf = Ukf::new(
            model.nominal_state(),
            SMatrix::from_diagonal(&config.p0),
            SMatrix::from_diagonal(&config.q0),
            SigmaParams::default(),
        )?;
        let mut adaptive = config.adaptive;
        adaptive.mode = config.mode;
        let filter = AdaptiveUkf::new(ukf, SMatrix::from_diagonal(&config.r0), adaptive)?;
        Ok(Self {
            model,
            arr: ScooterArr::nominal(),
            filter,
            tracker: IntermittentTracker::new(T::one(), config.beta_margin, config.refractory),
            prognoser: SequentialPrognoser::new(T::one(), config.beta_end)?,
            config,
            time: t0,
            last_y: None,
            previous: None,
            held: None,
            last_arr: ArrReport {
                residuals: [T::zero(); 3],
                thresholds: [T::zero(); 3],
                cv: 0,
                psi: T::zero(),
            },
            jump_candidate: None,
            last_u: None,
            inconsistent_run: 0,
            run_start: t0,
            active: false,
            psi_above: false,
        })
    }

    /// The filter (state, covariance, noise estimates).
    pub fn filter(&self) -> &AdaptiveUkf<T, NX, NS, NY, WINDOW> {
        &self.filter
    }
    /// The sequential prognoser (current degradation segment, Monte-Carlo RUL).
    pub fn prognoser(&self) -> &SequentialPrognoser<T> {
        &self.prognoser
    }

    /// Processes the sample `y = [omega_r, v_m, omega_f]` taken at time `t`, with `u` the
    /// motor-driver input held since the previous sample. On `Err` the estimator is unchanged:
    /// a non-finite sample, a time that does not advance, or an encoder glitch (a value
    /// outside `max_abs`, or a jump larger than `max_jump` from the last accepted sample,
    /// reported as `OutOfRange`). The glitch check remembers a rejected jump: when the next
    /// sample agrees with it, the level change is real and the sample is accepted.
    pub fn step(&mut self, t: T, u: T, y: &[T]) -> Result<ScooterReport<T>, Error> {
        let dt = t - self.time;
        crate::error::check_dt(dt)?;
        if !u.finite() {
            return Err(Error::NonFiniteInput);
        }
        let y3: [T; 3] = match y {
            [a, b, c] => [*a, *b, *c],
            _ => {
                return Err(Error::MeasurementLength {
                    expected: 3,
                    got: y.len(),
                });
            }
        };
        if !all_finite(&y3) {
            return Err(Error::NonFiniteMeasurement);
        }
        for (i, v) in y3.iter().enumerate() {
            let limit = self.config.max_abs.get(i).copied().unwrap_or(T::MAX_FINITE);
            if v.abs() > limit {
                return Err(Error::OutOfRange("measurement magnitude (encoder glitch)"));
            }
        }
        let within = |a: &[T; 3], b: &[T; 3]| {
            a.iter()
                .zip(b.iter())
                .zip(self.config.max_jump.iter())
                .all(|((x, y), jump)| (*x - *y).abs() <= *jump)
        };
        if let Some(prev) = self.last_y
            && !within(&y3, &prev)
        {
            let confirmed = self.jump_candidate.is_some_and(|c| within(&y3, &c));
            if !confirmed {
                self.jump_candidate = Some(y3);
                return Err(Error::OutOfRange("measurement jump (encoder glitch)"));
            }
        }
        if self.held.is_some_and(|(ht, _, _, _)| !(t > ht)) {
            return Err(Error::InvalidTimeStep);
        }
        let channels_on_trend = self.on_trend(t, &y3);
        let on_trend = channels_on_trend.iter().all(|c| *c);
        // A real change stays: this sample lies near the held one (within five spike limits,
        // room for the slope change of an abrupt fault). Otherwise two outliers in a row.
        let near_held = self.held.is_some_and(|(_, _, hy, _)| {
            y3.iter()
                .zip(hy.iter())
                .zip(self.config.spike_limit.iter())
                .all(|((a, b), limit)| (*a - *b).abs() <= *limit * cast::<T>(5.0))
        });
        match self.held.take() {
            Some(held) if !on_trend && !near_held => {
                // Both off: drop the held one, hold this one in its place.
                self.held = Some((t, u, y3, channels_on_trend));
                let mut report = self.current_report(true);
                report.spike_dropped = true;
                report.flags.insert(Flags::MEASUREMENT_REJECTED);
                let _ = held;
                Ok(report)
            }
            Some(held) if on_trend => {
                // The held sample was an isolated spike: drop it, process this one over the gap.
                let mut report = self.process(t, u, &y3, false).inspect_err(|_| {
                    self.held = Some(held);
                })?;
                report.spike_dropped = true;
                report.flags.insert(Flags::MEASUREMENT_REJECTED);
                Ok(report)
            }
            Some(held) => {
                // A real change: the held sample first, then this one.
                let (ht, hu, hy, held_on_trend) = held;
                // Over a missing sample the detector's second difference spans the gap and
                // loses most of its sensitivity to a step; a confirmed step of the rear
                // encoder alone (a sensor-efficiency change) is then taken as the change.
                let after_gap = self
                    .previous
                    .is_some_and(|(t0, _)| ht - self.time > cast::<T>(1.5) * (self.time - t0));
                let rear_encoder_step = held_on_trend == [false, true, true];
                let first = self
                    .process(ht, hu, &hy, after_gap && rear_encoder_step)
                    .inspect_err(|_| {
                        self.held = Some(held);
                    })?;
                match self.process(t, u, &y3, false) {
                    Ok(mut second) => {
                        if second.event.is_none() {
                            second.event = first.event;
                            second.outcome = first.outcome;
                        }
                        second.flags.insert(first.flags);
                        second.enhanced |= first.enhanced;
                        Ok(second)
                    }
                    // The held sample is in; this one is lost (reported, not an error: the
                    // pipeline has changed).
                    Err(_) => {
                        let mut first = first;
                        first.flags.insert(Flags::MEASUREMENT_REJECTED);
                        Ok(first)
                    }
                }
            }
            None if on_trend => self.process(t, u, &y3, false),
            None => {
                self.held = Some((t, u, y3, channels_on_trend));
                Ok(self.current_report(true))
            }
        }
    }

    /// Which channels of `y` at time `t` lie within `spike_limit` of the line through the
    /// last two processed samples (all until two samples exist).
    fn on_trend(&self, t: T, y: &[T; 3]) -> [bool; 3] {
        let (Some((t0, y0)), Some(y1)) = (self.previous, self.last_y) else {
            return [true; 3];
        };
        let span = self.time - t0;
        if !(span > T::zero()) {
            return [true; 3];
        }
        let ahead = (t - self.time) / span;
        let mut within = [true; 3];
        for (((w, y), (a, b)), limit) in within
            .iter_mut()
            .zip(y.iter())
            .zip(y0.iter().zip(y1.iter()))
            .zip(self.config.spike_limit.iter())
        {
            *w = (*y - (*b + (*b - *a) * ahead)).abs() <= *limit;
        }
        within
    }

    /// A report of the current estimate without processing anything.
    fn current_report(&self, held: bool) -> ScooterReport<T> {
        ScooterReport {
            arr: self.last_arr,
            suspected: suspected_faults(self.last_arr.cv),
            active: self.active,
            state: *self.filter.ukf().state(),
            beta_variance: beta_variance(&self.filter),
            enhanced: false,
            event: None,
            outcome: None,
            flags: Flags::NONE,
            held,
            spike_dropped: false,
        }
    }

    /// ARRs, activation, filter and prognoser for one accepted sample (`step_seen`: a sudden
    /// change is known without the detector); on `Err` nothing has changed.
    fn process(
        &mut self,
        t: T,
        u: T,
        y3: &[T; 3],
        step_seen: bool,
    ) -> Result<ScooterReport<T>, Error> {
        let dt = t - self.time;
        crate::error::check_dt(dt)?;
        let y3 = *y3;
        let mut arr = self.arr.clone();
        let arr_report = arr.step(u, &y3, dt)?;
        let run = if arr_report.cv != 0 {
            self.inconsistent_run.saturating_add(1)
        } else {
            0
        };
        let run_start = if run == 1 { t } else { self.run_start };
        // The filter steps in place (no copy of it on the stack: it is most of the pipeline's
        // size); `AdaptiveUkf::step` leaves it unchanged on error, and the covariance reset of
        // an activation is undone here if the step then fails.
        let mut flags = Flags::NONE;
        let mut active = self.active;
        let mut activated_now = false;
        let mut covariance_before_activation = None;
        if !active && run >= self.config.activation_samples {
            // Fault estimation starts: the fault parameters get their initial uncertainty.
            let before = *self.filter.ukf().covariance();
            let mut p = before;
            for i in BETA_THETA_R..NX {
                for j in 0..NX {
                    if let Some(v) = p.get_mut((i, j)) {
                        *v = T::zero();
                    }
                    if let Some(v) = p.get_mut((j, i)) {
                        *v = T::zero();
                    }
                }
                if let (Some(v), Some(p0)) = (p.get_mut((i, i)), self.config.p0.get(i)) {
                    *v = *p0;
                }
            }
            self.filter.ukf_mut().set_covariance(p)?;
            covariance_before_activation = Some(before);
            active = true;
            activated_now = true;
        }
        let fire = step_seen || arr_report.psi >= self.config.psi_threshold;
        let rising = fire && !self.psi_above;
        let beta_before = self
            .filter
            .ukf()
            .state()
            .get(BETA_THETA_R)
            .copied()
            .unwrap_or(T::one());
        let var_before = beta_variance(&self.filter);
        let adaptive =
            match self
                .filter
                .step(&self.model, &Vector1::new(u), &y3, dt, fire && active)
            {
                Ok(r) => r,
                Err(e) => {
                    if let Some(before) = covariance_before_activation {
                        // It was accepted before the reset, so it is accepted again.
                        let _ = self.filter.ukf_mut().set_covariance(before);
                    }
                    return Err(e);
                }
            };
        flags.insert(adaptive.flags);
        // Keep the angle states bounded (only the twists matter): a shifted state is finite
        // whenever the state was, so set_state cannot fail here.
        let mut x = *self.filter.ukf().state();
        if let (Some(a), Some(b), Some(c)) = (x.get(THETA_R), x.get(S_M), x.get(THETA_F)) {
            let mut angles = [*a, *b, *c];
            let [a, b, c] = &mut angles;
            if rebase_angles(a, b, c, self.model.params.n4) {
                for (i, v) in [THETA_R, S_M, THETA_F].into_iter().zip(angles) {
                    if let Some(slot) = x.get_mut(i) {
                        *slot = v;
                    }
                }
                let _ = self.filter.ukf_mut().set_state(x);
            }
        }

        // Commit.
        self.arr = arr;
        self.inconsistent_run = run;
        self.run_start = run_start;
        self.active = active;
        self.psi_above = fire;
        self.previous = self.last_y.map(|y| (self.time, y));
        self.time = t;
        self.last_y = Some(y3);
        self.last_arr = arr_report;
        self.jump_candidate = None;
        let mut event = None;
        let mut outcome = None;
        if let Some(prev_u) = self.last_u
            && prev_u != u
        {
            let e = FaultEvent::UsageChanged { time: t };
            outcome = self.prognoser.on_event(e).ok();
            event = Some(e);
        }
        self.last_u = Some(u);
        if activated_now {
            // The detector's first inconsistent sample is the first appearing moment t_a1.
            if let Some(e) = self.tracker.on_change(run_start, T::one(), T::zero()) {
                outcome = self.prognoser.on_event(e).ok();
                event = Some(e);
            }
        } else if rising
            && active
            && let Some(e) = self.tracker.on_change(t, beta_before, var_before)
        {
            outcome = self.prognoser.on_event(e).ok();
            event = Some(e);
        }
        let state = *self.filter.ukf().state();
        Ok(ScooterReport {
            arr: arr_report,
            suspected: suspected_faults(arr_report.cv),
            active,
            state,
            beta_variance: beta_variance(&self.filter),
            enhanced: adaptive.enhanced,
            event,
            outcome,
            flags,
            held: false,
            spike_dropped: false,
        })
    }
}

/// Variance of `beta_theta_r` in the filter's covariance.
fn beta_variance<T: Real>(filter: &AdaptiveUkf<T, NX, NS, NY, WINDOW>) -> T {
    filter
        .ukf()
        .covariance()
        .get((BETA_THETA_R, BETA_THETA_R))
        .copied()
        .unwrap_or(T::zero())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{Model, Observe};
    use crate::plants::scooter::{OMEGA_R, R_RV};

    /// Noise-free nominal run with an `R_rv` fault from 2 s, as a deterministic truth.
    fn samples(n: usize) -> [[f64; 3]; 400] {
        let model = ScooterModel::<f64>::nominal();
        let mut x = model.nominal_state();
        let mut out = [[0.0; 3]; 400];
        let u = Vector1::new(1.0);
        for (k, slot) in out.iter_mut().enumerate().take(n) {
            if k == 100 {
                x[R_RV] = 0.469;
            }
            x = model.step(&x, &u, 0.02);
            let y = model.observe(&x, &u);
            *slot = [y[0], y[1], y[2]];
        }
        out
    }

    fn warmed_up() -> (Scooter<f64>, [[f64; 3]; 400]) {
        let ys = samples(400);
        let mut pipe = Scooter::new(0.0, ScooterConfig::new(Adaptation::Enhanced)).unwrap();
        for (k, y) in ys.iter().enumerate().take(200) {
            pipe.step((k + 1) as f64 * 0.02, 1.0, y).unwrap();
        }
        (pipe, ys)
    }

    #[test]
    fn friction_fault_is_detected_isolated_and_estimated() {
        let (mut pipe, ys) = warmed_up();
        let mut last = None;
        for (k, y) in ys.iter().enumerate().skip(200) {
            last = Some(pipe.step((k + 1) as f64 * 0.02, 1.0, y).unwrap());
        }
        let report = last.unwrap();
        // An R_rv fault alone violates only ARR1: CV = [1 0 0], candidate R_rv only.
        assert_eq!(report.arr.cv, 0b001);
        assert_eq!(report.suspected, crate::diagnose::scooter::fault::R_RV);
        assert!(report.active);
        assert!(
            (report.state[R_RV] - 0.469).abs() < 0.01 * 0.469,
            "{}",
            report.state[R_RV]
        );
        assert!((report.state[BETA_THETA_R] - 1.0).abs() < 0.005);
    }

    #[test]
    fn bad_samples_return_errors_and_change_nothing() {
        let (mut pipe, ys) = warmed_up();
        let t = 201.0 * 0.02;
        let y = ys[200];
        let before = (
            *pipe.filter().ukf().state(),
            *pipe.filter().ukf().covariance(),
        );
        let glitch = [y[0] + 40.0, y[1], y[2]];
        assert_eq!(
            pipe.step(t, 1.0, &glitch).unwrap_err(),
            Error::OutOfRange("measurement jump (encoder glitch)")
        );
        assert!(matches!(
            pipe.step(t, 1.0, &[1e6, y[1], y[2]]),
            Err(Error::OutOfRange(_))
        ));
        assert_eq!(
            pipe.step(t, 1.0, &[f64::NAN, y[1], y[2]]).unwrap_err(),
            Error::NonFiniteMeasurement
        );
        assert_eq!(
            pipe.step(t, f64::NAN, &y).unwrap_err(),
            Error::NonFiniteInput
        );
        assert_eq!(
            pipe.step(t - 1.0, 1.0, &y).unwrap_err(),
            Error::InvalidTimeStep
        );
        assert!(matches!(
            pipe.step(t, 1.0, &y[..2]),
            Err(Error::MeasurementLength {
                expected: 3,
                got: 2
            })
        ));
        assert_eq!(before.0, *pipe.filter().ukf().state());
        assert_eq!(before.1, *pipe.filter().ukf().covariance());
        // The clean sample is then accepted and the estimate is still sensible.
        let report = pipe.step(t, 1.0, &y).unwrap();
        assert!(report.state.iter().all(|v| v.is_finite()));
        assert!((report.state[OMEGA_R] - y[0]).abs() < 0.05);
    }

    #[test]
    fn an_isolated_spike_is_dropped_and_a_real_step_is_processed_late() {
        let (mut pipe, ys) = warmed_up();
        let (clean, _) = warmed_up();
        let t = |k: usize| (k + 1) as f64 * 0.02;
        let mut spiked = ys[200];
        spiked[1] += 0.05;
        let held = pipe.step(t(200), 1.0, &spiked).unwrap();
        assert!(held.held && !held.spike_dropped);
        assert_eq!(held.state, *clean.filter().ukf().state());
        let after = pipe.step(t(201), 1.0, &ys[201]).unwrap();
        assert!(after.spike_dropped && after.flags.contains(Flags::MEASUREMENT_REJECTED));
        // Equivalent to a dropout of sample 200.
        let mut gap = clean.clone();
        let reference = gap.step(t(201), 1.0, &ys[201]).unwrap();
        assert_eq!(after.state, reference.state);
        // A lasting step (sensor efficiency 0.9 from sample 200) is held once, then both
        // samples are processed: the same estimate as without the check, one sample late.
        let scaled = |y: [f64; 3]| [0.9 * y[0], y[1], y[2]];
        let mut checked = clean.clone();
        let mut unchecked = clean.clone();
        unchecked.config.spike_limit = [f64::MAX; 3];
        assert!(checked.step(t(200), 1.0, &scaled(ys[200])).unwrap().held);
        unchecked.step(t(200), 1.0, &scaled(ys[200])).unwrap();
        let a = checked.step(t(201), 1.0, &scaled(ys[201])).unwrap();
        let b = unchecked.step(t(201), 1.0, &scaled(ys[201])).unwrap();
        assert!(!a.held && !a.spike_dropped);
        assert_eq!(a.state, b.state);
        assert_eq!(a.arr, b.arr);
    }

    #[test]
    fn documented_size_holds() {
        let size = core::mem::size_of::<Scooter<f32>>();
        assert!(size <= 4200, "{size}");
        assert!(core::mem::size_of::<Scooter<f64>>() <= 8400);
    }

    #[test]
    fn hostile_input_never_panics_or_produces_nan_in_f32() {
        use crate::random::uniform01;
        use rand_core::SeedableRng;
        use rand_xoshiro::Xoshiro256PlusPlus;
        let ys = samples(400);
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(21);
        let mut pipe = Scooter::<f32>::new(0.0, ScooterConfig::new(Adaptation::Enhanced)).unwrap();
        let mut t = 0.0f32;
        let (mut accepted, mut rejected) = (0, 0);
        for k in 0..3000 {
            let clean = ys[k % 400];
            let mut y = [clean[0] as f32, clean[1] as f32, clean[2] as f32];
            let mut u = 1.0f32;
            let mut dt = 0.02f32;
            let pick: f32 = uniform01(&mut rng);
            let channel = (uniform01::<f32, _>(&mut rng) * 3.0) as usize % 3;
            match (pick * 10.0) as u32 {
                0 => y[channel] = f32::NAN,
                1 => y[channel] = f32::INFINITY,
                2 => y[channel] += 3.0 * (uniform01::<f32, _>(&mut rng) - 0.5),
                3 => u = 50.0 * (uniform01::<f32, _>(&mut rng) - 0.5),
                4 => dt = if pick < 0.45 { 0.0 } else { -0.02 },
                5 => y[channel] = 1e20,
                _ => {}
            }
            let before = *pipe.filter().ukf().state();
            match pipe.step(t + dt, u, &y) {
                Ok(report) => {
                    accepted += 1;
                    t += dt;
                    assert!(report.state.iter().all(|v| v.is_finite()), "{report:?}");
                    assert!(report.beta_variance.is_finite() && report.beta_variance >= 0.0);
                    assert!(report.arr.psi.is_finite());
                }
                Err(_) => {
                    rejected += 1;
                    assert_eq!(before, *pipe.filter().ukf().state());
                }
            }
        }
        assert!(accepted > 1500 && rejected > 300, "{accepted} {rejected}");
    }
}
