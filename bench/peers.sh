#!/usr/bin/env bash
# Our estimators against NASA's progpy 1.9.0 and filterpy 1.4.5, on this machine, in one
# invocation: progpy's ParticleFilter on its PneumaticValveBase against our PF on our valve
# (N = 500, dt = 0.01 s, the same samples), progpy's MonteCarlo prediction to EOL of 100
# samples against ours, filterpy's UnscentedKalmanFilter against ours on the drag-radar
# reference, and the valve's opening/closing times of each model at dt = 0.01 s against a
# fine-dt reference. Prints the table and the ratios; writes bench/out/peers.json.
#
# Slow (about two minutes, most of it progpy): not part of CI.
# Usage: bench/peers.sh [--steps N] [--reps R]     (defaults: 200 PF steps, 20 repetitions)
# Environment: PEERS_VENV (default bench/.venv), PEERS_OUT (default bench/out).
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
root="$(dirname "$here")"
venv="${PEERS_VENV:-$here/.venv}"
out="${PEERS_OUT:-$here/out}"

if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv"
fi
"$venv/bin/python" -m pip install --quiet --disable-pip-version-check -r "$here/requirements.txt"

cd "$root"
cargo build --quiet --release -p prognos-tests --example peers
"${CARGO_TARGET_DIR:-$root/target}/release/examples/peers" --out "$out" "$@"
"$venv/bin/python" "$here/peers.py" \
    --rust "$out/rust.json" \
    --measurements "$out/valve_measurements.csv" \
    --reference "$root/tests/reference" \
    --out "$out/peers.json"
