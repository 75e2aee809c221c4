"""Measure the sensor health monitor for docs/sensor-health.md (not a test: run by hand).

    python benchmarks/measure_sensor_health.py MODEL clean-nmpc.parquet clean-operator.parquet ...

False alarms: the share of ``sensor_fault`` samples after each experiment's first second on
clean data. Detection: per experiment, each fault kind injected once on a signal drawn from
its list at a random onset (1.5 s … end − 1.5 s) and length (0.3 … 1.5 s); time to flag is
from the onset to the first ``sensor_fault`` naming that signal; the error is the largest
|ok estimate − payload| from the onset to the experiment's end, with the monitor on and off.
"""

from __future__ import annotations

import sys
import time as _time

import numpy as np

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.io import read_dataset
from excavator_payload.estimators.base import load_estimator

KINDS = {
    # a transmitter frozen at its last value
    "stuck": ["boom_angle", "dipper_angle", "bucket_angle", "boom_rate", "dipper_rate",
              "boom_head_pressure", "boom_rod_pressure", "dipper_head_pressure", "bucket_rod_pressure",
              "slew_rate", "house_pitch"],
    # a pulled connector: 0
    "dropout": ["boom_angle", "dipper_angle", "boom_head_pressure", "boom_rod_pressure",
                "dipper_head_pressure", "bucket_head_pressure", "dipper_rate"],
    # an angle jumping by 3-10° (a slipped mounting, runs of agreeing bad frames)
    "offset": ["boom_angle", "dipper_angle", "bucket_angle"],
}


def inject(frame, kind, signal, a, b, rng):
    v = frame[signal].to_numpy(dtype=float).copy()
    if kind == "stuck":
        v[a:b] = v[a - 1]
    elif kind == "dropout":
        v[a:b] = 0.0
    else:
        v[a:b] += rng.choice([-1, 1]) * np.radians(rng.uniform(3, 10))
    frame[signal] = v


def run(est, data: Dataset, health: bool):
    est.health = health
    try:
        return est.estimate(data)
    finally:
        est.health = True


def main(model, paths, seed=0):
    est = load_estimator(model)
    rng = np.random.default_rng(seed)
    false_rows, det_rows = [], []
    for path in paths:
        data = read_dataset(path)
        family = data.meta.get("motion", path)
        t0 = _time.perf_counter()
        out = run(est, data, True)
        late = out["time"].to_numpy() >= out.groupby("experiment")["time"].transform("min").to_numpy() + 1.0
        flagged = (out["status"] == "sensor_fault").to_numpy() & late
        names = out.loc[flagged, "fault"].value_counts().head(3).to_dict()
        false_rows.append((family, int(late.sum()), int(flagged.sum()), names, _time.perf_counter() - t0))
        for e in data.frame["experiment"].unique():
            one = data.frame[data.frame["experiment"] == e].reset_index(drop=True)
            n = len(one)
            for kind, signals in KINDS.items():
                signal = signals[rng.integers(len(signals))]
                a = int(rng.integers(150, max(151, n - 150)))
                b = min(n, a + int(rng.integers(30, 151)))
                bad = one.copy()
                inject(bad, kind, signal, a, b, rng)
                ds = Dataset(bad, data.meta)
                truth = bad["payload"].to_numpy()
                row = [family, kind, signal, (b - a) / 100]
                for health in (True, False):
                    r = run(est, ds, health)
                    ok = (r["status"] == "ok").to_numpy()
                    err = np.abs(r["payload_estimate"].to_numpy() - truth)
                    window = ok & (np.arange(n) >= a)
                    row.append(float(err[window].max()) if window.any() else float("nan"))
                    if health:
                        hit = np.flatnonzero((np.arange(n) >= a) & r["fault"].str.contains(signal, regex=False).to_numpy())
                        row.append((hit[0] - a) / 100 if len(hit) else float("nan"))
                det_rows.append(row)
    print("| family | samples after 1 s | flagged | share | most named |")
    print("|---|---|---|---|---|")
    for family, n, k, names, _ in false_rows:
        print(f"| {family} | {n} | {k} | {100 * k / n:.3f} % | {', '.join(f'{a} ({b})' for a, b in names.items()) or '–'} |")
    print()
    print("| family | fault | signal | length s | time to flag s | worst ok error after onset, kg (monitor on) | (monitor off) |")
    print("|---|---|---|---|---|---|---|")
    for family, kind, signal, length, err_on, flag, err_off in det_rows:
        print(f"| {family} | {kind} | {signal} | {length:.2f} | {flag:.2f} | {err_on:.0f} | {err_off:.0f} |")
    return false_rows, det_rows


if __name__ == "__main__":
    if len(sys.argv) < 3:
        sys.exit(__doc__)  # the usage: too few arguments
    main(sys.argv[1], sys.argv[2:])
