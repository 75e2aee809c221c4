"""The new-load test of the default calibrated form (``--new-load detect``), measured.

1. It must never fire under one load: the estimates on the study's constant-load test sets
   (NMPC swings, planned swings, work cycles up to the dump, the 5° slope, hand-made
   trajectories) are compared with ``--new-load off``, sample by sample.
2. Full work cycles (with the dump and the return): the error before the dump, and with the
   bucket empty (> 3 s after the dump), with and without the test.

Usage::

    PYTHONPATH=src python benchmarks/bench_machine_new_load.py --n-test 40
"""
import argparse
import copy
import time

import numpy as np
import pandas as pd
from excavator_payload.estimators.classical.calibrated import CalibratedEstimator
from excavator_payload.evaluation import demo_machine as dm
from excavator_payload.simulation.generate import simulate_dataset

ap = argparse.ArgumentParser()
ap.add_argument("--n-test", type=int, default=40)
ap.add_argument("--seed", type=int, default=7, help="the study's seed (its calibration)")
a = ap.parse_args()
n, seed = a.n_test, a.seed
t0 = time.time()
cal, zero = dm.calibration_data(10, seed), dm.zero_data(seed + 1)
est = CalibratedEstimator("cat345c-hydraulic-3pct", balance="momentum").fit(cal)
est.zero(zero)
off = copy.deepcopy(est); off.options["new_load"] = "off"; off.use_calibration()
print("fitted", time.time() - t0, "s", flush=True)
tests = dm.test_sets(n, seed + 2)
hand = dm.hand_made_trajectory(n, seed + 3)
tests["hand-made trajectory"] = dm.simulate_trajectory(hand, seed + 3, dm.SESSION_WORK)
for name, ds in tests.items():
    a = est.estimate(ds); b = off.estimate(ds)
    same = np.array_equal(a["payload_estimate"].to_numpy(), b["payload_estimate"].to_numpy(), equal_nan=True)
    print(f"{name}: identical {same}; differing samples {(~np.isclose(a.payload_estimate, b.payload_estimate, equal_nan=True)).sum()}", flush=True)
# full work cycles: truth = load until release[0], then falls to 0 by release[1]
common = dict(machine="cat345c-hydraulic", session=dm.SESSION_WORK, with_truth=False, workers=1, progress=False)
full = simulate_dataset(n, seed=seed + 3, motion="work-cycle", **common)
f = full.frame
rel = {int(m["experiment"]): m["release"] for m in full.meta["experiments"]}
ra = f["experiment"].map({k: v[0] for k, v in rel.items()}).to_numpy(); rb = f["experiment"].map({k: v[1] for k, v in rel.items()}).to_numpy()
t = f["time"].to_numpy(); load = f["payload"].to_numpy()
truth = load * np.clip((rb - t) / (rb - ra), 0, 1)
for label, e in (("detect", est), ("off", off)):
    r = e.estimate(full)
    err = r["payload_estimate"].to_numpy() - truth
    before = (t < ra) & (t > 1.0)
    empty = t > rb + 3.0
    ok = np.isfinite(err)
    per = pd.DataFrame({"exp": f["experiment"], "err": np.abs(err), "before": before & ok, "mt": empty & ok})
    mb = per[per.before].groupby("exp").err.max(); me = per[per.mt].groupby("exp").err.max()
    print(f"full work cycles {label}: before the dump mean MAX {mb.mean():.1f} kg; empty bucket (> 3 s after the dump) mean MAX {me.mean():.1f} kg, median {me.median():.1f}, estimated share there {(per.mt.sum() / empty.sum()):.2f}, new loads seen {int(e.kernel.regression.new_loads)}", flush=True)
print("total", time.time() - t0)
