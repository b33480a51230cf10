#!/usr/bin/env python3
"""Reference run of filterpy's UnscentedKalmanFilter on a nonlinear tracking scenario.

A point target with quadratic drag and a commanded acceleration (4 states: px, py, vx, vy;
2 inputs: ax, ay) is observed by a radar at the origin in range and bearing (2 measurements).
Both fx (RK4 step of the drag dynamics) and hx (range, bearing) are nonlinear.

Writes, next to this script:
  filterpy_ukf_setup.csv      name,value rows: sigma-point parameters, drag, x0, P0, Q, R
  filterpy_ukf_reference.csv  one row per step: k, dt, inputs, measurement, filterpy's prior
                              (x, P after predict) and posterior (x, P after update)

Every float is written with repr(), which round-trips f64 exactly. The Rust test
tests/tests/ukf_filterpy.rs rebuilds the same model and checks our Ukf against these rows.
Run: python3 make_filterpy_reference.py   (see README.md for pinned versions)
"""
import csv
import math
import os

import numpy as np
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

SEED = 20261122
STEPS = 100
DT = 0.5
DRAG = 0.01
ALPHA, BETA, KAPPA = 0.5, 2.0, 1.0
X_TRUE0 = np.array([100.0, 50.0, 8.0, 4.0])
X0 = np.array([105.0, 45.0, 7.0, 5.0])
P0 = np.diag([25.0, 25.0, 4.0, 4.0])
Q = np.diag([0.01, 0.01, 0.05, 0.05])
R = np.diag([1.0, 0.01**2])


def accel(s, u):
    """Time derivative of the state under drag -c |v| v and commanded acceleration u."""
    px, py, vx, vy = s
    speed = math.sqrt(vx * vx + vy * vy)
    return np.array([vx, vy, -DRAG * speed * vx + u[0], -DRAG * speed * vy + u[1]])


def fx(x, dt, u):
    """One classical RK4 step, written in the same operation order as prognos_core::model::rk4."""
    half_h = dt * 0.5
    sixth_h = dt / 6.0
    k1 = accel(x, u)
    k2 = accel(x + k1 * half_h, u)
    k3 = accel(x + k2 * half_h, u)
    k4 = accel(x + k3 * dt, u)
    return x + (k1 + k2 * 2.0 + k3 * 2.0 + k4) * sixth_h


def hx(x):
    """Range and bearing from a radar at the origin."""
    return np.array([math.sqrt(x[0] * x[0] + x[1] * x[1]), math.atan2(x[1], x[0])])


def command(k):
    return np.array([0.5 * math.sin(0.1 * k), 0.3 * math.cos(0.07 * k)])


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    rng = np.random.default_rng(SEED)
    points = MerweScaledSigmaPoints(n=4, alpha=ALPHA, beta=BETA, kappa=KAPPA)
    ukf = UnscentedKalmanFilter(dim_x=4, dim_z=2, dt=DT, hx=hx, fx=fx, points=points)
    ukf.x = X0.copy()
    ukf.P = P0.copy()
    ukf.Q = Q.copy()
    ukf.R = R.copy()

    with open(os.path.join(here, "filterpy_ukf_setup.csv"), "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["name", "value"])
        for name, value in [("alpha", ALPHA), ("beta", BETA), ("kappa", KAPPA), ("drag", DRAG)]:
            w.writerow([name, repr(float(value))])
        for i in range(4):
            w.writerow([f"x0_{i}", repr(float(X0[i]))])
        for name, m in [("p0", P0), ("q", Q), ("r", R)]:
            for i in range(m.shape[0]):
                for j in range(m.shape[1]):
                    w.writerow([f"{name}_{i}{j}", repr(float(m[i, j]))])

    header = ["k", "dt", "u0", "u1", "z0", "z1"]
    header += [f"prior_x{i}" for i in range(4)]
    header += [f"prior_p{i}{j}" for i in range(4) for j in range(4)]
    header += [f"x{i}" for i in range(4)]
    header += [f"p{i}{j}" for i in range(4) for j in range(4)]
    truth = X_TRUE0.copy()
    q_std = np.sqrt(np.diag(Q))
    r_std = np.sqrt(np.diag(R))
    with open(os.path.join(here, "filterpy_ukf_reference.csv"), "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        for k in range(STEPS):
            u = command(k)
            truth = fx(truth, DT, u) + q_std * rng.standard_normal(4)
            z = hx(truth) + r_std * rng.standard_normal(2)
            ukf.predict(u=u)
            prior_x, prior_p = ukf.x.copy(), ukf.P.copy()
            ukf.update(z)
            row = [k, DT, u[0], u[1], z[0], z[1]]
            row += list(prior_x) + list(prior_p.ravel())
            row += list(ukf.x) + list(ukf.P.ravel())
            w.writerow([str(v) if isinstance(v, int) else repr(float(v)) for v in row])


if __name__ == "__main__":
    main()
