"""Sensor faults outside the gap catalogue, for `prognos gap-bench --datasets`.

From every `*-none-*.csv` dataset in SRC (with its `.csv.meta.toml`), writes to DST one
dataset per fault and measured channel, labelled `kind = "unknown"`: a linear drift, a gain
step midway, a 0.37 Hz sinusoidal interference, and spikes on 1 % of the samples. Each is
scaled to an RMS of RATIO times the channel's noise (the MAD of its second differences).

    python3 docs/gap/sensor_faults.py SRC DST [RATIO]

Standard library only; the spikes' positions are seeded, so DST is the same on every run.
"""
import csv
import math
import os
import random
import shutil
import sys


def noise_std(v):
    d = sorted(
        abs(v[i + 2] - 2 * v[i + 1] + v[i])
        for i in range(len(v) - 2)
        if all(math.isfinite(x) for x in v[i:i + 3])
    )
    return d[len(d) // 2] / 0.6745 / math.sqrt(6)


def cell(x):
    return float(x) if x not in ("", "NaN", "nan") else float("nan")


def main(src, dst, ratio):
    os.makedirs(dst, exist_ok=True)
    rng = random.Random(5)
    for f in sorted(f for f in os.listdir(src) if "-none-" in f and f.endswith(".csv")):
        rows = list(csv.reader(open(os.path.join(src, f))))
        header, data = rows[0], [[cell(x) for x in r] for r in rows[1:]]
        t = [r[0] for r in data]
        span, n = t[-1] - t[0], len(t)
        for kind in ["drift", "gain_step", "interference", "spikes"]:
            for c, name in enumerate(header):
                if not name.startswith("y:"):
                    continue
                y = [r[c] for r in data]
                if kind == "drift":
                    add = [(s - t[0]) / span - 0.5 for s in t]
                elif kind == "interference":
                    add = [math.sin(2 * math.pi * 0.37 * s) for s in t]
                elif kind == "gain_step":
                    add = [v if s > t[0] + span / 2 else 0.0 for v, s in zip(y, t)]
                else:
                    add = [1.0 if rng.random() < 0.01 else 0.0 for _ in t]
                rms = math.sqrt(sum(a * a for a in add if math.isfinite(a)) / n)
                if rms == 0:
                    continue
                k = ratio * noise_std(y) / rms
                out = f[: -len(".csv")] + f"-{kind}-{name[2:]}"
                with open(os.path.join(dst, out + ".csv"), "w") as o:
                    o.write(",".join(header) + "\n")
                    for r, a in zip(data, add):
                        r = list(r)
                        r[c] += k * a
                        o.write(",".join(repr(x) for x in r) + "\n")
                shutil.copy(
                    os.path.join(src, f + ".meta.toml"),
                    os.path.join(dst, out + ".csv.meta.toml"),
                )
                with open(os.path.join(dst, out + ".csv.label.toml"), "w") as o:
                    o.write(
                        f'kind = "unknown"\neffects = ["{kind}"]\n'
                        f'channel = "{name}"\nratio = {ratio}\n'
                    )


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], float(sys.argv[3]) if len(sys.argv) > 3 else 4.0)
