"""Why ``calibrated`` weighed worse on the 5° slope: the slope, or the motions?

Usage::

    PYTHONPATH=src python benchmarks/bench_machine_slope.py --n 40 --seeds 11 13 --calibration-seed 7

The README's slope test (:func:`~excavator_payload.evaluation.demo_machine.test_sets`) replays
NMPC swings as trajectory files on a 5° slope; the flat test runs the NMPC controller itself.
This compares, after calibration (``--calibration-seed``, ten swings) and the zero check:

* ``nmpc``: NMPC swings (closed loop, piecewise-constant valve commands);
* ``slope``: the slope set as in ``test_sets``;
* ``level replay``: the *same* replayed motions and payloads on level ground;

each with the identified IMU dynamics and with them ignored, and prints mean MAX / RMS, the
share within 1 % of rated and the mean bias per experiment (kg), and the identified IMU
parameters with their posterior std against the prior's.
"""

from __future__ import annotations

import argparse
import copy

import numpy as np

from excavator_payload.estimators.classical import calibrated_machine as cm
from excavator_payload.estimators.classical.calibrated import CalibratedEstimator
from excavator_payload.evaluation import demo_machine as dm
from excavator_payload.simulation.generate import simulate_dataset


def test_motions(n: int, seed: int) -> dict:
    """``nmpc`` and ``slope`` exactly as ``dm.test_sets(n, seed)``, plus the level replay."""
    common = dict(session=dm.SESSION_WORK, with_truth=True, workers=1, progress=False)
    sets = {"nmpc": simulate_dataset(n, seed=seed + 3, motion="nmpc", machine="cat345c-hydraulic", **common)}
    payloads = np.random.default_rng(seed + 2).uniform(0, dm.RATED_PAYLOAD, n)
    for name, slope in (("slope", 5.0), ("level replay", None)):
        table = dm.motion_trajectory(n, seed + 2, payloads, motion="nmpc", slope_deg=slope)
        sets[name] = dm.simulate_trajectory(table, seed + 2, dm.SESSION_WORK)
    return sets


def summary(est, ds) -> str:
    pe = dm.judge(est, ds, est.name, None).per_experiment
    m = pe["max_error"].to_numpy(float)
    return (f"{m.mean():6.1f} {pe['rms_error'].mean():5.1f} {np.mean(m <= 0.01 * dm.RATED_PAYLOAD):5.0%} "
            f"{pe['mean_error'].mean():+6.1f}")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=40)
    ap.add_argument("--seeds", type=int, nargs="+", default=[11, 13])
    ap.add_argument("--calibration-seed", type=int, default=7)
    a = ap.parse_args()
    est = CalibratedEstimator("cat345c-hydraulic-3pct", balance="differentiated").fit(dm.calibration_data(10, a.calibration_seed))
    est.zero(dm.zero_data(a.calibration_seed + 1))
    for name, (value, posterior, ratio) in est.calibration.imu_identification().items():
        print(f"{name:38s} {value:+.4f}  posterior std {posterior:.4f} ({ratio:.2f} of the prior's)")
    ignored = copy.deepcopy(est)
    ignored.calibration.z[len(cm.CALIBRATED_PARAMETERS) + len(cm.OFFSET_SIGNALS):] = 0.0
    ignored.use_calibration()
    print(f"{'seed':>4s} {'test':13s} {'IMU dynamics':14s} {'MAX':>6s} {'RMS':>5s} {'≤1 %':>5s} {'bias':>6s}")
    for seed in a.seeds:
        for set_name, ds in test_motions(a.n, seed).items():
            for label, e in (("identified", est), ("ignored", ignored)):
                print(f"{seed:4d} {set_name:13s} {label:14s} {summary(e, ds)}", flush=True)


if __name__ == "__main__":
    main()
