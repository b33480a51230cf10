//! Truth plant of the electric scooter (Yu et al. 2020): the uncertain parameters of Table 3
//! are drawn uniformly within their multiplicative bounds once per run, faults follow the
//! experiment's profile, and the two encoders and the body-speed sensor add Gaussian noise.

use nalgebra::{Vector3, Vector6};
use prognos_core::plants::scooter::{OMEGA_F, OMEGA_R, ScooterParams, V_M};
use prognos_core::random::{normal, uniform01};
use rand_core::Rng;

/// Multiplicative uncertainty bounds of Table 3 (`delta`, as fractions).
#[derive(Clone, Copy, Debug)]
pub struct Uncertainty {
    pub r_mv: f64,
    pub r_mc: f64,
    pub j_m: f64,
    pub m: f64,
    pub j_r: f64,
    pub j_f: f64,
    pub r_rv: f64,
    pub r_rc: f64,
    pub r_fv: f64,
    pub r_fc: f64,
    pub k1: f64,
    pub k2: f64,
}

impl Uncertainty {
    /// Table 3 values.
    pub const TABLE3: Uncertainty = Uncertainty {
        r_mv: 0.0298,
        r_mc: 0.0586,
        j_m: 0.0812,
        m: 0.0206,
        j_r: 0.0284,
        j_f: 0.0276,
        r_rv: 0.0512,
        r_rc: 0.0189,
        r_fv: 0.0279,
        r_fc: 0.0291,
        k1: 0.0229,
        k2: 0.0113,
    };

    /// Draws parameters uniformly in `nominal * [1 - delta, 1 + delta]`.
    pub fn draw<R: Rng + ?Sized>(
        &self,
        nominal: &ScooterParams<f64>,
        rng: &mut R,
    ) -> ScooterParams<f64> {
        let mut d = |delta: f64| 1.0 + delta * (2.0 * uniform01::<f64, R>(rng) - 1.0);
        let mut p = *nominal;
        p.r_mv *= d(self.r_mv);
        p.r_mc *= d(self.r_mc);
        p.j_m *= d(self.j_m);
        p.m *= d(self.m);
        p.j_r *= d(self.j_r);
        p.j_f *= d(self.j_f);
        p.r_rv *= d(self.r_rv);
        p.r_rc *= d(self.r_rc);
        p.r_fv *= d(self.r_fv);
        p.r_fc *= d(self.r_fc);
        p.k1 *= d(self.k1);
        p.k2 *= d(self.k2);
        p
    }
}

/// Gaussian sensor noise standard deviations.
#[derive(Clone, Copy, Debug)]
pub struct SensorNoise {
    /// Rear encoder speed (rad/s).
    pub rear: f64,
    /// Body speed (m/s).
    pub body: f64,
    /// Front encoder speed (rad/s).
    pub front: f64,
}

impl Default for SensorNoise {
    fn default() -> Self {
        Self {
            rear: 1e-3,
            body: 1e-4,
            front: 1e-3,
        }
    }
}

/// Piecewise-constant fault and usage profile of one experiment.
#[derive(Clone, Copy, Debug)]
pub struct Profile {
    /// Intermittent `beta_theta_r` intervals `(t_a, t_d, value)`; 1 outside them.
    pub beta_intervals: [(f64, f64, f64); 4],
    /// Abrupt `R_rv` fault `(onset, value)`.
    pub friction_fault: (f64, f64),
    /// Usage: input `u_before` volts until `usage_change`, then `u_after`.
    pub u_before: f64,
    pub u_after: f64,
    pub usage_change: f64,
    /// Run length (s).
    pub duration: f64,
}

impl Profile {
    /// Experiment 1 (section 4.2, Figure 7): monotonic intermittent fault, usage 1 V -> 1.2 V.
    pub const EXPERIMENT1: Profile = Profile {
        beta_intervals: [
            (10.0, 15.56, 0.94),
            (18.0, 21.16, 0.78),
            (24.0, 27.08, 0.55),
            (28.5, 30.94, 0.3),
        ],
        friction_fault: (10.0, 0.469),
        u_before: 1.0,
        u_after: 1.2,
        usage_change: 19.8,
        duration: 32.0,
    };
    /// Experiment 2 (Figure 13): non-monotonic intermittent fault, usage 1 V -> 1.3 V.
    pub const EXPERIMENT2: Profile = Profile {
        beta_intervals: [
            (10.0, 15.3, 0.92),
            (19.2, 21.0, 0.7),
            (24.0, 27.0, 0.82),
            (30.0, 34.0, 0.76),
        ],
        friction_fault: (10.0, 0.469),
        u_before: 1.0,
        u_after: 1.3,
        usage_change: 19.7,
        duration: 35.0,
    };

    /// True `beta_theta_r` at time `t`.
    pub fn beta(&self, t: f64) -> f64 {
        self.beta_intervals
            .iter()
            .find(|(a, d, _)| t >= *a && t < *d)
            .map_or(1.0, |i| i.2)
    }
    /// True `R_rv` at time `t` given the run's healthy value.
    pub fn r_rv(&self, t: f64, healthy: f64) -> f64 {
        if t >= self.friction_fault.0 {
            self.friction_fault.1
        } else {
            healthy
        }
    }
    /// Input at time `t`.
    pub fn input(&self, t: f64) -> f64 {
        if t >= self.usage_change {
            self.u_after
        } else {
            self.u_before
        }
    }
}

/// The simulated scooter of one run.
#[derive(Clone, Debug)]
pub struct ScooterPlant {
    /// This run's drawn parameters.
    pub params: ScooterParams<f64>,
    /// Fault and usage profile.
    pub profile: Profile,
    /// Sensor noise.
    pub noise: SensorNoise,
    /// True dynamic state.
    pub state: Vector6<f64>,
    /// Simulation time (s).
    pub time: f64,
    /// RK4 sub-steps per sample.
    pub substeps: u32,
}

impl ScooterPlant {
    /// A plant at rest with parameters drawn from Table 3's bounds.
    pub fn new<R: Rng + ?Sized>(profile: Profile, noise: SensorNoise, rng: &mut R) -> Self {
        let params = Uncertainty::TABLE3.draw(&ScooterParams::nominal(), rng);
        Self {
            params,
            profile,
            noise,
            state: Vector6::zeros(),
            time: 0.0,
            substeps: 8,
        }
    }

    /// Advances by `dt` under the profile's input and returns `(u, y)`: `u` is the input held
    /// over the step (zero-order hold) and `y` is sampled at the new time,
    /// `y = [beta_theta_r omega_r, v_m, omega_f] + noise` (the body and front sensors are
    /// healthy, efficiency 1).
    pub fn sample<R: Rng + ?Sized>(&mut self, dt: f64, rng: &mut R) -> (f64, Vector3<f64>) {
        let u = self.profile.input(self.time);
        let r_rv = self.profile.r_rv(self.time, self.params.r_rv);
        self.state = self
            .params
            .advance(&self.state, u, r_rv, self.params.k1, dt, self.substeps);
        self.time += dt;
        let beta = self.profile.beta(self.time);
        let y = Vector3::new(
            normal(rng, beta * self.state[OMEGA_R], self.noise.rear),
            normal(rng, self.state[V_M], self.noise.body),
            normal(rng, self.state[OMEGA_F], self.noise.front),
        );
        (u, y)
    }
}
