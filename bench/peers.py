#!/usr/bin/env python3
"""Peers of bench/peers.sh: progpy 1.9.0 and filterpy 1.4.5 on the work the Rust side
(tests/examples/peers.rs) just timed, then the side-by-side table and the ratios.

- PF: progpy's ParticleFilter (N = 500, residual resampling every step) on progpy's
  PneumaticValveBase, over the same noisy samples (valve_measurements.csv), dt = 0.01 s,
  one model step per filter step. Process noise as ours (velocity only, 1e-3 m/s per step); measurement noise as ours (position 1 mm,
  flow 0.03 m^3/s, pressures 30 kPa, indicators 0.3).
- Prediction: progpy's MonteCarlo, 100 samples (progpy's default state with the spring
  constant of sample j as in peers.rs), spring wear wk, no process noise, dt = 0.01 s,
  30 s open/close cycles, until the 'Spring Failure' event.
- UKF: filterpy's UnscentedKalmanFilter with MerweScaledSigmaPoints over the 100 rows of
  tests/reference/filterpy_ukf_reference.csv (the model of make_filterpy_reference.py).
- Accuracy: opening and closing times of progpy's model at dt = 0.01 s, from progpy itself.
"""
import argparse
import csv
import json
import math
import os
import statistics
import sys
import time

import numpy as np
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter
from progpy.models import PneumaticValveBase
from progpy.predictors import MonteCarlo
from progpy.state_estimators import ParticleFilter
from progpy.uncertain_data import UnweightedSamples

DT = 0.01
PERIOD = 30.0
FLUID = (3.5e5, 2.0e5)
LS = 0.0381


def load(t, x=None, model=None):
    """Open command (bottom port at supply) for the first half of each 30 s cycle."""
    opening = (t % PERIOD) < PERIOD / 2
    return model.InputContainer(
        {"pL": FLUID[0], "pR": FLUID[1], "uTop": not opening, "uBot": opening}
    )


def run_pf(rows, noise, particles, seed):
    np.random.seed(seed)
    m = PneumaticValveBase(
        process_noise={
            "Aeb": 0, "Aet": 0, "Ai": 0, "k": 0, "r": 0, "x": 0, "pDiff": 0,
            # progpy adds dt * N(0, pn): 0.1 m/s gives 1e-3 m/s per step, as ours.
            "v": 0.1,
            "mTop": 0,
            "mBot": 0,
        },
    )
    u0 = load(0.0, model=m)
    x0 = m.initialize(u0)
    filt = ParticleFilter(
        m,
        x0,
        num_particles=particles,
        measurement_noise={
            "Q": noise["f"],
            "iB": noise["discrete"],
            "iT": noise["discrete"],
            "pB": noise["p"] * 1e-6,  # progpy's pressures are in MPa
            "pT": noise["p"] * 1e-6,
            "x": noise["x"],
        },
    )
    per_step, sq = [], 0.0
    for r in rows:
        u = m.InputContainer(
            {"pL": r["pL"], "pR": r["pR"], "uTop": r["uTop"] > 0.5, "uBot": r["uBot"] > 0.5}
        )
        z = m.OutputContainer(
            {
                "Q": r["Q"],
                "iB": r["iB"],
                "iT": r["iT"],
                "pB": r["pB"] * 1e-6,
                "pT": r["pT"] * 1e-6,
                "x": r["x"],
            }
        )
        start = time.perf_counter()
        filt.estimate(r["t"], u, z, dt=DT)
        per_step.append(time.perf_counter() - start)
        mean_x = float(np.mean(filt.particles["x"]))
        sq += (mean_x - r["truth_x"]) ** 2
    return {
        "step_seconds": statistics.median(per_step),
        "mean_step_seconds": statistics.fmean(per_step),
        "position_rmse_m": math.sqrt(sq / len(rows)),
        "final_mean_x_m": mean_x,
    }


def run_prediction(rust):
    pred = rust["prediction"]
    n = pred["samples"]
    m = PneumaticValveBase(process_noise=0, wk=pred["wear_spring"])
    x0 = m.initialize(load(0.0, model=m))
    samples = []
    for j in range(n):
        s = {k: float(x0[k]) for k in x0.keys()}
        k_min = rust["limits"]["k_min"]
        fraction = pred["margin_low"] + (1.0 - pred["margin_low"]) * (j + 0.5) / n
        s["k"] = k_min + (pred["k_nominal"] - k_min) * fraction
        samples.append(m.StateContainer(s))
    mc = MonteCarlo(m)
    start = time.perf_counter()
    result = mc.predict(
        UnweightedSamples(samples, _type=m.StateContainer),
        lambda t, x=None: load(t, x, m),
        dt=DT,
        events=["Spring Failure"],
        horizon=400.0,
        save_freq=1e9,
    )
    seconds = time.perf_counter() - start
    toe = [float(t["Spring Failure"]) if t["Spring Failure"] is not None else math.inf
           for t in result.time_of_event]
    return {"seconds": seconds, "eol_s": toe}


def read_settings(path):
    with open(path, newline="") as fh:
        return {r["name"]: float(r["value"]) for r in csv.DictReader(fh)}


def run_ukf(reference_dir, reps):
    sys.path.insert(0, reference_dir)
    import make_filterpy_reference as ref  # fx, hx and the constants of the reference run

    setup = read_settings(os.path.join(reference_dir, "filterpy_ukf_setup.csv"))
    with open(os.path.join(reference_dir, "filterpy_ukf_reference.csv"), newline="") as fh:
        rows = [{k: float(v) for k, v in r.items()} for r in csv.DictReader(fh)]
    mat = lambda name, n: np.array([[setup[f"{name}_{i}{j}"] for j in range(n)] for i in range(n)])
    per_step, final = [], None
    for _ in range(reps):
        points = MerweScaledSigmaPoints(
            n=4, alpha=setup["alpha"], beta=setup["beta"], kappa=setup["kappa"]
        )
        ukf = UnscentedKalmanFilter(dim_x=4, dim_z=2, dt=ref.DT, hx=ref.hx, fx=ref.fx, points=points)
        ukf.x = np.array([setup[f"x0_{i}"] for i in range(4)])
        ukf.P, ukf.Q, ukf.R = mat("p0", 4), mat("q", 4), mat("r", 2)
        start = time.perf_counter()
        for r in rows:
            ukf.predict(dt=r["dt"], u=np.array([r["u0"], r["u1"]]))
            ukf.update(np.array([r["z0"], r["z1"]]))
        per_step.append((time.perf_counter() - start) / len(rows))
        final = ukf.x.copy()
    return {"step_seconds": statistics.median(per_step), "final_state": final.tolist()}


def progpy_timing(leak):
    """Opening and closing times of progpy's own model at dt = 0.01 s over one cycle."""
    m = PneumaticValveBase(process_noise=0)
    x0 = m.initialize(load(0.0, model=m))
    x0["Aeb"] = leak
    x0["Aet"] = leak
    res = m.simulate_to(PERIOD, lambda t, x=None: load(t, x, m), x=x0, dt=DT, save_freq=DT)
    times = list(res.times)
    xs = [float(s["x"]) for s in res.states]
    opened = next(t for t, x in zip(times, xs) if t > 0 and x >= LS)
    closed = next(t for t, x in zip(times, xs) if t > PERIOD / 2 and x <= 0.0)
    return {"open_s": opened, "close_s": closed - PERIOD / 2}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--rust", required=True)
    ap.add_argument("--measurements", required=True)
    ap.add_argument("--reference", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--ukf-reps", type=int, default=20)
    args = ap.parse_args()
    with open(args.rust) as fh:
        rust = json.load(fh)
    with open(args.measurements, newline="") as fh:
        rows = [{k: float(v) for k, v in r.items()} for r in csv.DictReader(fh)]

    print(f"progpy PF: {len(rows)} steps at N = {rust['particles']} ...", flush=True)
    pf = run_pf(rows, rust["sensor_noise"], rust["particles"], seed=1)
    print(f"progpy MonteCarlo: {rust['prediction']['samples']} samples to EOL ...", flush=True)
    pred = run_prediction(rust)
    print("filterpy UKF ...", flush=True)
    ukf = run_ukf(args.reference, args.ukf_reps)
    timing = {"progpy default state": progpy_timing(1e-5), "leak-free": progpy_timing(0.0)}

    ours_eol = rust["prediction"]["eol_s"]
    both = [(a, b) for a, b in zip(pred["eol_s"], ours_eol) if math.isfinite(a) and b < 1e300]
    eol_diff = [abs(a - b) for a, b in both]
    ukf_diff = max(abs(a - b) for a, b in zip(ukf["final_state"], rust["ukf"]["final_state"]))

    ratios = {
        "pf_step": pf["step_seconds"] / rust["pf"]["step_seconds"],
        "prediction": pred["seconds"] / rust["prediction"]["seconds"],
        "ukf_step": ukf["step_seconds"] / rust["ukf"]["step_seconds"],
    }
    lines = []
    lines.append("")
    lines.append(f"{'work':48} {'peer':>12} {'ours':>12} {'peer/ours':>10}  target")
    lines.append(
        f"{'PF step, valve, N = 500, dt = 0.01 s':48} {pf['step_seconds'] * 1e3:9.2f} ms "
        f"{rust['pf']['step_seconds'] * 1e6:9.1f} us {ratios['pf_step']:10.0f}  >= 300"
    )
    lines.append(
        f"{'prediction to EOL, 100 samples, dt = 0.01 s':48} {pred['seconds']:10.2f} s "
        f"{rust['prediction']['seconds'] * 1e3:9.1f} ms {ratios['prediction']:10.0f}  >= 300"
    )
    lines.append(
        f"{'UKF step, drag radar (4 states, filterpy)':48} {ukf['step_seconds'] * 1e6:9.1f} us "
        f"{rust['ukf']['step_seconds'] * 1e6:9.2f} us {ratios['ukf_step']:10.0f}"
    )
    lines.append("")
    lines.append("Estimates: PF position RMSE over the run (truth at a 2 ms step)")
    lines.append(f"  progpy {pf['position_rmse_m'] * 1e3:.3f} mm, ours {rust['pf']['position_rmse_m'] * 1e3:.3f} mm")
    lines.append(
        f"EOL per sample, progpy vs ours: {len(both)} of {len(ours_eol)} both reached, "
        f"mean |diff| {statistics.fmean(eol_diff) if eol_diff else float('nan'):.3f} s, "
        f"max {max(eol_diff) if eol_diff else float('nan'):.3f} s; "
        f"EOL range ours {min(b for _, b in both):.2f}..{max(b for _, b in both):.2f} s"
    )
    ref_eol = rust["prediction"]["eol_reference_s"]
    err_peer = [abs(pred["eol_s"][j] - t) for j, t in ref_eol]
    err_ours = [abs(ours_eol[j] - t) for j, t in ref_eol]
    lines.append(
        f"EOL against the dt = {rust['prediction']['reference_dt']} s reference ({len(ref_eol)} samples): "
        f"mean |err| progpy {statistics.fmean(err_peer):.3f} s (max {max(err_peer):.3f}), "
        f"ours {statistics.fmean(err_ours):.3f} s (max {max(err_ours):.3f})"
    )
    lines.append(f"UKF final state, filterpy vs ours: max |diff| {ukf_diff:.3e}")
    lines.append("")
    lines.append("Opening / closing time [s] (dt each model uses, against the dt = 1e-5 s reference)")
    refs = {}
    for t in rust["timings"]:
        if t["model"].startswith("reference: semi"):
            refs[t["case"]] = t
    for case, peer in timing.items():
        ref = refs[case]
        ours = next(t for t in rust["timings"] if t["case"] == case and t["model"].startswith("ours"))
        lines.append(f"  {case}: reference open {ref['open_s']:.4f}, close {ref['close_s']:.4f}")
        for name, t in [("progpy, dt 0.01", peer), ("ours, dt 0.01", ours)]:
            lines.append(
                f"    {name:16} open {t['open_s']:.4f} (err {t['open_s'] - ref['open_s']:+.4f}), "
                f"close {t['close_s']:.4f} (err {t['close_s'] - ref['close_s']:+.4f})"
            )
    text = "\n".join(lines)
    print(text)
    result = {
        "progpy_pf": pf,
        "progpy_prediction": {"seconds": pred["seconds"], "eol_s": pred["eol_s"]},
        "filterpy_ukf": ukf,
        "progpy_timing": timing,
        "ours": rust,
        "ratios": ratios,
        "eol_mean_abs_diff_s": statistics.fmean(eol_diff) if eol_diff else None,
        "eol_reference_mean_abs_err_s": {
            "progpy": statistics.fmean(err_peer),
            "ours": statistics.fmean(err_ours),
        },
        "ukf_final_state_max_abs_diff": ukf_diff,
        "table": text,
    }
    with open(args.out, "w") as fh:
        json.dump(result, fh, indent=2)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
