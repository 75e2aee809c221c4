"""How often does `train` wrongly refuse a calibration, and does a K-fold second check fix it?
(issue 28; docs/findings/machine-calibration.md, "The refusal's second check").

For each seed S of ``--seeds``: the calibration of ``bench_machine_draws``' draw 0 of S
(``--motions``, ``--reach``), fitted in the momentum form as `train` fits it, zeroed on its empty
swing, weighed on the same test sets (``--n-test`` motions per family of ``--test-seed``, made
as ``bench_machine_draws`` makes them). Per draw it prints the halves' s, the folds' s (computed
only when the halves would refuse, as `train` does), whether today's rule (halves only) and the
estimator's rule refuse, and each family's share of test motions within 1 % of rated: a refusal
is false when every family is ≥ 95 % within 1 %, an acceptance is false when one is below.

Usage::

    PYTHONPATH=src python benchmarks/measure_refusal_folds.py --seeds 120000 121000 \\
        --motions 5 --reach 2 --test-seed 120500 --n-test 3 --out r.jsonl
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_machine_draws as bmd  # noqa: E402
from held_out_motions import lever_trajectory, multisine_trajectory  # noqa: E402

from excavator_payload.estimators.classical.calibrated import CalibratedEstimator
from excavator_payload.estimators.classical.machine_calibration import weighing
from excavator_payload.evaluation import demo_machine as dm

FAMILIES = ("nmpc", "work-cycle", "slope-5deg", "lever", "multisine")


def test_sets(n: int, seed: int) -> dict:
    """The families as ``bench_machine_draws --seed seed`` makes them (first ``n`` of each)."""
    tests = {k: v for k, v in dm.test_sets(n, seed + 2).items() if k in FAMILIES}
    tests["lever"] = dm.simulate_trajectory(lever_trajectory(n, seed + 4), seed + 4, dm.SESSION_WORK)
    tests["multisine"] = dm.simulate_trajectory(multisine_trajectory(n, seed + 6), seed + 6, dm.SESSION_WORK)
    return tests


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="+", required=True)
    ap.add_argument("--motions", type=int, default=5)
    ap.add_argument("--reach", type=int, default=2)
    ap.add_argument("--test-seed", type=int, required=True, help="bench_machine_draws' --seed of the test sets")
    ap.add_argument("--n-test", type=int, default=3)
    ap.add_argument("--balance", default="momentum", help="the calibrated form (differentiated: a control "
                    "whose fast `reach` motions spoil it)")
    ap.add_argument("--out", type=Path, default=Path("refusals.jsonl"))
    a = ap.parse_args()
    rated = dm.RATED_PAYLOAD
    t0 = time.time()
    tests = test_sets(a.n_test, a.test_seed)
    print(f"test sets simulated in {time.time() - t0:.0f} s", flush=True)
    original = weighing.cross_validated_model_std
    for seed in a.seeds:
        fits = {}

        def recorded(dataset, calibrate_fold, weigh_with, folds=2):
            t = time.time()
            s = original(dataset, calibrate_fold, weigh_with, folds=folds)
            fits[folds] = (s, time.time() - t)
            return s

        weighing.cross_validated_model_std = recorded
        cal = bmd.calibration(a.motions, seed, a.reach)
        t = time.time()
        est = CalibratedEstimator("cat345c-hydraulic-3pct", balance=a.balance).fit(cal)
        fit_seconds = time.time() - t
        est.zero(bmd.zero_motion("empty-swing", seed))
        within = {name: bmd.judge(est, ds, a.balance, None)["within_1pct"] for name, ds in tests.items()}
        halves = fits[2][0]
        row = {"seed": seed, "motions": a.motions, "balance": a.balance, "s_halves": halves,
               "s_folds": next((v[0] for k, v in fits.items() if k != 2), None),
               "seconds": {str(k): v[1] for k, v in fits.items()}, "fit_seconds": fit_seconds,
               "refused_today": bool(2 * halves > 0.01 * rated),
               "refused_new": any("weighs the other only" in r for r in est.fit_refusals),
               "other_refusals": [r for r in est.fit_refusals if "weighs the other only" not in r],
               "within_1pct": within, "good": all(w >= 0.95 for w in within.values())}
        with a.out.open("a") as f:
            f.write(json.dumps(row) + "\n")
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
