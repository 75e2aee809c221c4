"""Glitch test and false-rejection rate of the outlier rejection (issue 9).

1. **False rejections on clean data.** Every estimator streams ``N_TEST`` clean NMPC test
   experiments (thesis noise); count the samples its statistical gate rejected
   (``rejected_outlier``) or restarted on (``reinitialised``).
2. **One glitch.** In every test experiment one sample (the 51st, mid-swing) gets a boom-torque
   glitch of 10×, 100× and 1000× the torque noise (1000 N·m); the table gives the mean and the
   largest change of the final estimate (t = 5 s) against the clean run, with the gate and,
   for comparison, without it (``Estimator.gating = False``).

Usage::

    PYTHONPATH=src python benchmarks/glitch.py [--test 200] [--train 40] [--seed 7]

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
TORQUE_COLUMN = 1 + 6  # boom_torque in (time, thesis signals)
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


def run(est, experiments, glitch: float | None, gating: bool):
    """Final estimates and status counts over the experiments (one glitch per experiment)."""
    est.gating = gating
    finals, statuses = [], []
    for rows in experiments:
        rows = rows.copy()
        if glitch is not None:
            rows[GLITCH_SAMPLE, TORQUE_COLUMN] += glitch
        est.reset()
        for r in rows:
            result = est.step_values(r[0], r[1:])
            statuses.append(result.status.value)
        finals.append(result.estimate)
    est.gating = True
    return np.array(finals), pd.Series(statuses).value_counts()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--test", type=int, default=200)
    parser.add_argument("--train", type=int, default=40)
    parser.add_argument("--seed", type=int, default=7)
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
    noise = get_noise_preset("thesis").std["boom_torque"]
    n_samples = sum(len(e) for e in experiments)

    false_rows, glitch_rows = [], []
    for label, est in roster(train, lifts):
        clean, counts = run(est, experiments, None, True)
        rejected = int(counts.get("rejected_outlier", 0)) + int(counts.get("reinitialised", 0))
        false_rows.append({"estimator": label, "samples": n_samples, "rejected": rejected,
                           "rate": rejected / n_samples,
                           "mean |final error| (kg)": float(np.nanmean(np.abs(clean - payloads)))})
        for m in MULTIPLES:
            row = {"estimator": label, "glitch": f"{m:g}× noise ({m * noise:g} N·m)"}
            for gating in (True, False):
                finals, counts = run(est, experiments, m * noise, gating)
                change = np.abs(finals - clean)
                tag = "gate" if gating else "no gate"
                row[f"mean change, {tag} (kg)"] = float(np.nanmean(change))
                row[f"largest change, {tag} (kg)"] = float(np.nanmax(change))
                if gating:
                    row["glitch rejected"] = f"{int(counts.get('rejected_outlier', 0))}/{len(experiments)}"
            glitch_rows.append(row)
        print(f"  {label} done ({time.perf_counter() - t0:.0f} s)")

    pd.set_option("display.width", 200)
    pd.set_option("display.max_columns", 20)
    print("\nfalse rejections on clean data (rejected_outlier + reinitialised samples):")
    print(markdown(pd.DataFrame(false_rows)))
    print("\nchange of the final estimate (t = 5 s) after one boom-torque glitch at sample 51:")
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
