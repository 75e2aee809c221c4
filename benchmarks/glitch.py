"""Glitch test and false-rejection rate of the outlier rejection (issue 9).

1. **False rejections on clean data.** Every estimator streams ``N_TEST`` clean NMPC test
   experiments (thesis noise); count the samples its statistical gate rejected
   (``rejected_outlier``) or restarted on (``reinitialised``).
2. **One glitch.** In every test experiment one sample (the 51st, mid-swing) of one signal
   (``--signal``, default the boom torque) gets a glitch of 10×, 100× and 1000× its noise
   (thesis preset; 1000 N·m for a torque); the table gives the change of the estimate against
   the clean run at the end (t = 5 s: mean and largest over experiments) and at its worst after
   the glitch (mean over experiments), with the gate and, for comparison, without it
   (``Estimator.gating = False``).

Usage::

    PYTHONPATH=src python benchmarks/glitch.py [--test 200] [--train 40] [--seed 7] [--signal boom_torque]

Takes a few minutes on 2 cores (simulation, two small network trainings, the UKF).
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np
import pandas as pd

from excavator_payload.estimators import create_estimator
from excavator_payload.simulation.generate import simulate_dataset
from excavator_payload.simulation.lifts import simulate_lifts
from excavator_payload.simulation.sensors import get_noise_preset

MULTIPLES = (10.0, 100.0, 1000.0)
GLITCH_SAMPLE = 50
NET = {"epochs": 60, "train_experiments": 30, "validation_experiments": 10, "progress": False}


def roster(train, lifts):
    """(label, fitted estimator) of every estimator family."""
    out = [
        ("ekf", create_estimator("ekf", "cat345c").fit(train)),
        ("ekf --tuning thesis", create_estimator("ekf", "cat345c", tuning="thesis").fit(train)),
        ("ukf", create_estimator("ukf", "cat345c").fit(train)),
        ("inverse-dynamics", create_estimator("inverse-dynamics", "cat345c").fit(train)),
        ("calibrated (3 % model, 10 exps)", create_estimator("calibrated", "cat345c-3pct",
                                                             experiments=10).fit(train)),
        ("quasi-static", create_estimator("quasi-static", "cat345c").fit(lifts)),
        ("net1", create_estimator("net1", **NET).fit(train)),
        ("net2", create_estimator("net2", **NET).fit(train)),
    ]
    return out


def run(est, experiments, glitch: float | None, gating: bool, column: int):
    """Estimates (experiments × samples) and status counts (one glitch per experiment)."""
    est.gating = gating
    estimates, statuses = [], []
    for rows in experiments:
        rows = rows.copy()
        if glitch is not None:
            rows[GLITCH_SAMPLE, column] += glitch
        est.reset()
        trace = []
        for r in rows:
            result = est.step_values(r[0], r[1:])
            statuses.append(result.status.value)
            trace.append(result.estimate)
        estimates.append(trace)
    est.gating = True
    return np.array(estimates, dtype=float), pd.Series(statuses).value_counts()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--test", type=int, default=200)
    parser.add_argument("--train", type=int, default=40)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--signal", default="boom_torque", help="signal to glitch (thesis set)")
    args = parser.parse_args()
    t0 = time.perf_counter()
    data = simulate_dataset(args.train + args.test, seed=args.seed, noise="thesis", progress=False)
    ids = list(data.experiment_ids)
    train, test = data.subset(ids[:args.train]), data.subset(ids[args.train:])
    lifts = simulate_lifts(10, seed=args.seed, noise="thesis")
    print(f"data: {args.train} training + {args.test} test NMPC experiments, thesis noise "
          f"({time.perf_counter() - t0:.0f} s)")
    experiments = [rows[["time", *test.sensor_set.signals]].to_numpy(float) for _, rows in test.experiments()]
    payloads = test.payloads
    preset = get_noise_preset("thesis")
    noise = preset.std[args.signal]
    unit = test.sensor_set.units[args.signal]
    column = 1 + test.sensor_set.index(args.signal)
    n_samples = sum(len(e) for e in experiments)

    false_rows, glitch_rows = [], []
    for label, est in roster(train, lifts):
        clean, counts = run(est, experiments, None, True, column)
        rejected = int(counts.get("rejected_outlier", 0)) + int(counts.get("reinitialised", 0))
        false_rows.append({"estimator": label, "samples": n_samples, "rejected": rejected,
                           "rate": rejected / n_samples,
                           "mean |final error| (kg)": float(np.nanmean(np.abs(clean[:, -1] - payloads)))})
        for m in MULTIPLES:
            row = {"estimator": label, "glitch": f"{m:g}× ({m * noise:.3g} {unit})"}
            for gating in (True, False):
                traces, counts = run(est, experiments, m * noise, gating, column)
                change = np.abs(traces - clean)
                final = change[:, -1]
                peak = np.nanmax(change[:, GLITCH_SAMPLE:], axis=1)
                tag = "" if gating else ", no gate"
                if gating:
                    row["rejected"] = f"{int(counts.get('rejected_outlier', 0))}/{len(experiments)}"
                row[f"final change{tag}: mean / max (kg)"] = f"{np.nanmean(final):.3g} / {np.nanmax(final):.3g}"
                row[f"peak change after it{tag}: mean (kg)"] = float(np.nanmean(peak))
            glitch_rows.append(row)
        print(f"  {label} done ({time.perf_counter() - t0:.0f} s)")

    pd.set_option("display.width", 200)
    pd.set_option("display.max_columns", 20)
    print("\nfalse rejections on clean data (rejected_outlier + reinitialised samples):")
    print(markdown(pd.DataFrame(false_rows)))
    print(f"\none {args.signal} glitch at sample {GLITCH_SAMPLE + 1} of every test experiment, in multiples "
          f"of its noise ({noise:.3g} {unit}): change of the estimate against the clean run at the end "
          "(t = 5 s) and at its worst after the glitch:")
    print(markdown(pd.DataFrame(glitch_rows)))
    print(f"\ntotal {time.perf_counter() - t0:.0f} s")


def markdown(frame: pd.DataFrame) -> str:
    """A Markdown table (3 significant digits) without extra dependencies."""
    def cell(v):
        if isinstance(v, float):
            return "–" if not math.isfinite(v) else (f"{v:.2e}" if v and abs(v) < 1e-3 else f"{v:.3g}")
        return str(v)
    lines = ["| " + " | ".join(frame.columns) + " |", "|" + "---|" * len(frame.columns)]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in frame.itertuples(index=False)]
    return "\n".join(lines)


if __name__ == "__main__":
    main()
