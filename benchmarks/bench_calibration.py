"""How long the technician's procedure takes: calibrating ``calibrated`` on ten calibration
motions with known payloads (as ``demo --machine`` makes them) and the zero check on one empty
swing, both forms, CPU and wall time. The calibrated machine is printed as a checksum (the same
code must give the same numbers, bit for bit, whatever makes it faster).

Usage::

    PYTHONPATH=src python benchmarks/bench_calibration.py [--motions 10] [--seed 7] [--repeat 2]
"""

from __future__ import annotations

import argparse
import hashlib
import time

import numpy as np

from excavator_payload.estimators.classical import calibrated_machine as cm
from excavator_payload.estimators.classical.calibrated import CalibratedEstimator
from excavator_payload.evaluation import demo_machine as dm


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--motions", type=int, default=10)
    ap.add_argument("--seed", type=int, default=7, help="the study's seed (its calibration)")
    ap.add_argument("--repeat", type=int, default=2, help="runs per form (the first compiles)")
    a = ap.parse_args()
    cal, zero = dm.calibration_data(a.motions, a.seed), dm.zero_data(a.seed + 1)
    print(f"{a.motions} calibration motions, {len(cal.frame)} samples; zero check {len(zero.frame)} samples")
    for balance in cm.BALANCE_CHOICES:
        for run in range(a.repeat):
            wall, cpu = time.perf_counter(), time.process_time()
            est = CalibratedEstimator("cat345c-hydraulic-3pct", balance=balance).fit(cal)
            fit_wall, fit_cpu = time.perf_counter() - wall, time.process_time() - cpu
            wall, cpu = time.perf_counter(), time.process_time()
            est.zero(zero)
            zero_wall, zero_cpu = time.perf_counter() - wall, time.process_time() - cpu
            z = np.ascontiguousarray(est.calibration.z)
            print(f"{balance:14s} run {run}: calibrate {fit_wall:6.1f} s wall / {fit_cpu:6.1f} s CPU, "
                  f"zero {zero_wall:5.1f} s / {zero_cpu:5.1f} s; calibrated z sha256 "
                  f"{hashlib.sha256(z.tobytes()).hexdigest()[:12]}", flush=True)


if __name__ == "__main__":
    main()
