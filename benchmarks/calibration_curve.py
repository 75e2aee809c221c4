"""Accuracy of the ``calibrated`` estimator against the number of calibration experiments.

Starts from the wrong machine file (default ``cat345c-3pct``), calibrates on the first N of the
calibration experiments (known payloads) and tests on the test experiments; count 0 is the
uncalibrated ``inverse-dynamics`` baseline.

Usage::

    python benchmarks/calibration_curve.py [--train CAL.parquet --test TEST.parquet | --data ALL.parquet]
                                           [--n-test 200] [--motion minimum-jerk|nmpc]
                                           [--machine cat345c-3pct] [--csv OUT.csv]

Targets (200 test experiments, thesis noise, judged samples index >= 81): with <= 10 calibration
experiments, mean RMS error <= 5 kg and every test experiment's max error < 50 kg.
"""

from __future__ import annotations

import argparse
import time

from excavator_payload.data.io import read_dataset
from excavator_payload.estimators.classical.calibrated import calibration_curve
from excavator_payload.simulation.minimum_jerk import simulate_minimum_jerk


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--train", help="calibration dataset (Parquet); default: simulate 20")
    parser.add_argument("--test", help="test dataset (Parquet); default: simulate --n-test")
    parser.add_argument("--data", help="one dataset (Parquet): its first max(counts) experiments "
                        "calibrate, the rest test")
    parser.add_argument("--n-test", type=int, default=200)
    parser.add_argument("--motion", default="minimum-jerk", choices=("minimum-jerk", "nmpc"))
    parser.add_argument("--noise", default="thesis")
    parser.add_argument("--machine", default="cat345c-3pct")
    parser.add_argument("--counts", default="0,1,2,5,10,20")
    parser.add_argument("--csv", help="also write the table as CSV")
    args = parser.parse_args()
    counts = [int(c) for c in args.counts.split(",")]

    if args.motion == "nmpc" and not (args.train and args.test):
        from excavator_payload.simulation.generate import simulate_dataset

        def simulate(n, seed):
            return simulate_dataset(n, seed=seed, noise=args.noise, workers=1)
    else:
        def simulate(n, seed):
            return simulate_minimum_jerk(n, seed=seed, noise=args.noise)

    if args.data:
        whole = read_dataset(args.data)
        n_cal = max(counts)
        train, test = whole.split(n_cal, whole.n_experiments - n_cal)
    else:
        train = read_dataset(args.train) if args.train else simulate(max(counts), 100)
        test = read_dataset(args.test) if args.test else simulate(args.n_test, 5)
    print(f"calibration: {train}\ntest:        {test}\nstarting machine: {args.machine}")
    start = time.perf_counter()
    table = calibration_curve(train, test, counts=counts, machine=args.machine, progress=True)
    print(table.to_string(index=False, float_format=lambda v: f"{v:.2f}"))
    print(f"({time.perf_counter() - start:.1f} s)")
    if args.csv:
        table.to_csv(args.csv, index=False)


if __name__ == "__main__":
    main()
