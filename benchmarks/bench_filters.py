"""Benchmark of the Kalman filters ``ekf`` and ``ukf``: streaming speed and accuracy.

Speed: µs per streaming ``step()`` (a dict sample, as a live machine would feed it) and per
``step_values()`` (an array), median of 5 passes over the test samples, one core.

Accuracy (thesis Table 7.1 protocol): on the test experiments, discard the first 81 samples of
each, take MAX and RMS of |error| per experiment, then the mean over experiments. Plus the
efficiency ratio: RMS over the judged samples of error ÷ Cramér–Rao bound (whole history).

Usage::

    python benchmarks/bench_filters.py [N_TEST=200] [--data TEST.parquet] [--train TRAIN.parquet]
                                       [--no-ukf] [--speed-only]

Without ``--data`` the test set is ``N_TEST`` minimum-jerk experiments (thesis noise); with it,
any dataset (e.g. NMPC experiments from ``excavator-payload simulate``). The training set only
fixes the noise preset and the Euler truncation size of the ``consistent`` tuning (default:
20 minimum-jerk experiments with another seed, or the test file itself when given).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import pandas as pd

from excavator_payload.data.io import read_dataset
from excavator_payload.data.schema import SIGNALS
from excavator_payload.estimators import create_estimator
from excavator_payload.evaluation.crb import cramer_rao_bound
from excavator_payload.simulation.minimum_jerk import simulate_minimum_jerk

JUDGED = 81
THESIS = {  # Table 7.1: mean MAX, mean RMS (kg)
    ("ekf", "thesis", "cat345c"): (22.978, 15.845),
    ("ekf", "thesis", "cat345c-1pct"): (86.954, 72.141),
    ("ekf", "thesis", "cat345c-3pct"): (100.485, 89.880),
}


def speed(estimator, dataset, passes: int = 5, max_samples: int = 2020) -> tuple[float, float]:
    """Median µs per ``step`` (dict) and per ``step_values`` (array) over the first samples."""
    frame = dataset.frame.iloc[:max_samples]
    records = frame[["time", *SIGNALS]].to_dict("records")
    times = frame["time"].to_numpy()
    values = frame[list(SIGNALS)].to_numpy()
    exp = frame["experiment"].to_numpy()
    starts = set(np.flatnonzero(np.r_[True, exp[1:] != exp[:-1]]))
    per_dict, per_array = [], []
    for _ in range(passes):
        t0 = time.perf_counter()
        for i, rec in enumerate(records):
            if i in starts:
                estimator.reset()
            estimator.step(rec)
        per_dict.append((time.perf_counter() - t0) / len(records) * 1e6)
        t0 = time.perf_counter()
        for i in range(len(times)):
            if i in starts:
                estimator.reset()
            estimator.step_values(times[i], values[i])
        per_array.append((time.perf_counter() - t0) / len(records) * 1e6)
    return float(np.median(per_dict)), float(np.median(per_array))


def accuracy(estimator, dataset, crb: np.ndarray) -> dict:
    out = estimator.estimate(dataset)
    n = dataset.n_experiments
    err = (out["payload_estimate"].to_numpy() - dataset.frame["payload"].to_numpy()).reshape(n, -1)
    bound = crb.reshape(n, -1)
    judged = np.abs(err[:, JUDGED:])
    return {
        "mean_max_kg": judged.max(axis=1).mean(),
        "mean_rms_kg": np.sqrt((judged**2).mean(axis=1)).mean(),
        "std_max_kg": judged.max(axis=1).std(),
        "efficiency_ratio": float(np.sqrt(np.mean((err[:, JUDGED:] / bound[:, JUDGED:]) ** 2))),
        "final_bias_kg": float(err[:, -1].mean()),
        "nonfinite": int((~np.isfinite(out["payload_estimate"])).sum()),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("n_test", nargs="?", type=int, default=200)
    parser.add_argument("--data", help="test dataset (Parquet)")
    parser.add_argument("--train", help="training dataset for the consistent tuning (Parquet)")
    parser.add_argument("--no-ukf", action="store_true", help="skip the (slower) UKF")
    parser.add_argument("--speed-only", action="store_true")
    args = parser.parse_args()

    if args.data:
        test = read_dataset(args.data)
    else:
        test = simulate_minimum_jerk(args.n_test, seed=2, noise="thesis", with_truth=True)
    if args.train:
        train = read_dataset(args.train)
    elif args.data:
        train = test
    else:
        train = simulate_minimum_jerk(20, seed=1, noise="thesis", with_truth=True)
    print(f"test: {test}  (motion {test.meta.get('motion')})   train: {train}")

    names = ["ekf"] if args.no_ukf else ["ekf", "ukf"]
    rows = []
    for name in names:
        for tuning in ("consistent", "thesis"):
            est = create_estimator(name, machine="cat345c", tuning=tuning).fit(train)
            us_dict, us_array = speed(est, test)
            rows.append({"estimator": name, "tuning": tuning, "machine": "cat345c",
                         "step_us": us_dict, "step_values_us": us_array})
    print("\nstreaming speed (µs per sample, median of 5 passes; target ekf step <= 200 µs)")
    print(pd.DataFrame(rows).to_string(index=False, float_format=lambda v: f"{v:.0f}"))
    if args.speed_only:
        return

    crb = cramer_rao_bound(test)
    rows = []
    for name in names:
        for tuning in ("thesis", "consistent"):
            for machine in ("cat345c", "cat345c-1pct", "cat345c-3pct"):
                est = create_estimator(name, machine=machine, tuning=tuning).fit(train)
                t0 = time.perf_counter()
                scores = accuracy(est, test, crb)
                thesis = THESIS.get((name, tuning, machine), (np.nan, np.nan))
                rows.append({"estimator": name, "tuning": tuning, "machine": machine, **scores,
                             "thesis_max": thesis[0], "thesis_rms": thesis[1],
                             "batch_s": time.perf_counter() - t0})
    print(f"\naccuracy on {test.n_experiments} test experiments (samples >= {JUDGED}); "
          f"median CRB at the judged samples {np.nanmedian(crb.reshape(test.n_experiments, -1)[:, JUDGED:]):.2f} kg")
    print(pd.DataFrame(rows).to_string(index=False, float_format=lambda v: f"{v:.2f}"))


if __name__ == "__main__":
    main()
