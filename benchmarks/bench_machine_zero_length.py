"""Does a longer zero check close the efficiency gap? Five draws x 40 NMPC swings: the momentum
form zeroed on one empty swing (the procedure) or on two; each variant's bound from the
per-sample reference zeroed the same way.

Usage::

    PYTHONPATH=src python benchmarks/bench_machine_zero_length.py   # writes zero_length.csv
"""
import copy
import time

import pandas as pd
from excavator_payload.data.dataset import Dataset
from excavator_payload.estimators.classical.calibrated import CalibratedEstimator
from excavator_payload.evaluation import demo_machine as dm
from excavator_payload.evaluation.crb_machine import dataset_machine_bound
t0 = time.time()
tests = dm.test_sets(40, 9)
nmpc = tests["nmpc"]
rows = []
for draw in range(5):
    seed = 7 + 1000 * draw
    cal = dm.calibration_data(10, seed)
    z1 = dm.zero_data(seed + 1)
    extra = dm.zero_data(seed + 5)
    f2 = extra.frame.assign(experiment=extra.frame["experiment"] + 1)
    meta = dict(z1.meta); meta["experiments"] = list(z1.meta.get("experiments", [])) + [
        {**e, "experiment": int(e["experiment"]) + 1} for e in extra.meta.get("experiments", [])]
    z2 = Dataset(pd.concat([z1.frame, f2], ignore_index=True), meta)
    mom = CalibratedEstimator("cat345c-hydraulic-3pct", balance="momentum").fit(cal)
    ref = CalibratedEstimator("cat345c-hydraulic-3pct", balance="differentiated").fit(cal)
    for label, z in (("one swing", z1), ("two swings", z2)):
        m, r = copy.deepcopy(mom), copy.deepcopy(ref)
        m.zero(z); r.zero(z)
        bound = dataset_machine_bound(nmpc, r)
        row = dm.summary_row(dm.judge(m, nmpc, m.name, bound), dm.RATED_PAYLOAD, None)
        rows.append({"draw": draw, "zero": label, **row})
        print(f"draw {draw} zero on {label}: MAX {row['mean_max_kg']:.1f} RMS {row['mean_rms_kg']:.1f} within 1 % {row['within_1pct']:.1%} efficiency {row['efficiency']:.2f} ({time.time()-t0:.0f} s)", flush=True)
    pd.DataFrame(rows).to_csv("zero_length.csv", index=False)
fr = pd.DataFrame(rows)
print(fr.groupby("zero")[["mean_max_kg", "mean_rms_kg", "within_1pct", "efficiency"]].mean())
