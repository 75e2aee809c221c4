"""Benchmark of the model-based estimators: accuracy, efficiency against the Cramér–Rao bound,
and streaming speed of ``inverse-dynamics``; how ``quasi-static`` fails in dynamic motion.

Usage::

    python benchmarks/bench_inverse_dynamics.py [--data TEST.parquet] [--n 200] [--seed 5]
                                                 [--motion minimum-jerk|nmpc] [--noise thesis]

Without ``--data`` the test experiments are simulated (``--motion minimum-jerk`` is fast; ``nmpc``
runs the NMPC simulator, minutes). Prints, per estimator: mean per-experiment RMS error, worst
max error and mean bias (kg) on the judged samples (index >= 81), the efficiency ratio
RMS(error / whole-history CRB) for ``inverse-dynamics``, and microseconds per ``step()``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from excavator_payload.data.io import read_dataset
from excavator_payload.estimators import create_estimator
from excavator_payload.estimators.classical.calibrated import FIRST_JUDGED_SAMPLE, judged_errors
from excavator_payload.evaluation.crb import cramer_rao_bound
from excavator_payload.simulation.lifts import simulate_lifts
from excavator_payload.simulation.minimum_jerk import simulate_minimum_jerk


def test_data(args):
    if args.data:
        ds = read_dataset(args.data)
        return ds.subset(ds.experiment_ids[args.skip:]) if args.skip else ds
    if args.motion == "nmpc":
        from excavator_payload.simulation.generate import simulate_dataset

        return simulate_dataset(args.n, seed=args.seed, noise=args.noise, with_truth=True, workers=1)
    return simulate_minimum_jerk(args.n, seed=args.seed, noise=args.noise, with_truth=True)


def step_speed(est, dataset, repeats: int = 3) -> float:
    """Best-of-``repeats`` microseconds per ``step_values`` call over the whole dataset."""
    times = dataset.frame["time"].to_numpy(float)
    values = dataset.signals()
    exp = dataset.frame["experiment"].to_numpy()
    best = np.inf
    for _ in range(repeats):
        est.reset()
        start = time.perf_counter()
        previous = exp[0]
        for i in range(len(times)):
            if exp[i] != previous:
                est.reset()
                previous = exp[i]
            est.step_values(times[i], values[i])
        best = min(best, (time.perf_counter() - start) / len(times))
    return best * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", help="test dataset (Parquet); default: simulate")
    parser.add_argument("--skip", type=int, default=0,
                        help="ignore the first SKIP experiments of --data (e.g. used for calibration)")
    parser.add_argument("--n", type=int, default=200)
    parser.add_argument("--seed", type=int, default=5)
    parser.add_argument("--motion", default="minimum-jerk", choices=("minimum-jerk", "nmpc"))
    parser.add_argument("--noise", default="thesis")
    args = parser.parse_args()

    test = test_data(args)
    print(f"test data: {test} motion={test.meta.get('motion')}")
    judged = test.frame.groupby("experiment", sort=False).cumcount().to_numpy() >= FIRST_JUDGED_SAMPLE
    crb = cramer_rao_bound(test)
    print(f"whole-history CRB at the judged samples: median {np.median(crb[judged]):.2f} kg")
    lifts = simulate_lifts(24, seed=1, noise=test.meta.get("noise", "thesis"))
    if args.data and args.skip:  # calibrate on (up to 10 of) the experiments set aside
        whole = read_dataset(args.data)
        calibration = whole.subset(whole.experiment_ids[:min(args.skip, 10)])
    else:
        calibration = simulate_minimum_jerk(10, seed=100, noise=test.meta.get("noise", "thesis"))
    machine = test.machine() or "cat345c"

    candidates = [
        ("inverse-dynamics (true model)", create_estimator("inverse-dynamics", machine).fit(test)),
        ("inverse-dynamics, torque-only weights, no EIV",
         create_estimator("inverse-dynamics", machine, weighting="torque", eiv_correction=False).fit(test)),
        ("inverse-dynamics (cat345c-3pct)", create_estimator("inverse-dynamics", "cat345c-3pct").fit(test)),
        (f"calibrated (cat345c-3pct, {calibration.n_experiments} {calibration.meta.get('motion')} exps)",
         create_estimator("calibrated", "cat345c-3pct").fit(calibration)),
        ("quasi-static (24 lifts at 5 deg/s)", create_estimator("quasi-static", machine).fit(lifts)),
    ]
    header = f"{'estimator':48s} {'meanRMS':>9s} {'maxErr':>9s} {'bias':>8s} {'CRBratio':>9s} {'us/step':>8s}"
    print(header)
    print("-" * len(header))
    for label, est in candidates:
        out = est.estimate(test)
        per_exp = judged_errors(test, out)
        err = out["payload_estimate"].to_numpy() - test.frame["payload"].to_numpy()
        ratio = float(np.sqrt(np.mean((err[judged] / crb[judged]) ** 2)))
        speed = step_speed(est, test.subset(test.experiment_ids[:20]))
        print(f"{label:48s} {per_exp['rms_kg'].mean():9.2f} {per_exp['max_kg'].max():9.2f} "
              f"{per_exp['bias_kg'].mean():8.2f} {ratio:9.3f} {speed:8.1f}")


if __name__ == "__main__":
    main()
