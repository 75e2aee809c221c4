"""Where balance-net's error over the Cramér–Rao bound comes from, on the machine set: each test
motion weighed again with one source of error removed at a time (simulation only: it uses the
sessions' true sensor offsets and the true signals).

* **as is**: zeroed on one empty swing of the weighing session (``bench_balance_net``'s flow);
* **true offsets (the zero's)**: the ten offsets the zero estimates (angles, house pitch,
  pressures) set to the sessions' true difference (``session_offsets``);
* **true offsets (all)**: every signal moved back to the training session's offsets (the rates,
  slew rate and house roll too, which the zero does not estimate);
* **noise-free**: the true signals through the IMUs' lag and leak, no noise or pump ripple, the
  training session's offsets: what is left is the learned balance's own bias;
* **true signals**: as noise-free, without the IMU dynamics;
* **noise part**: RMS over the rows both weigh of (true offsets (all) − noise-free) / bound: the
  error the sensors' noise makes through the estimator's weighting (weights by the true
  information could lower only this part);
* **zero part**: RMS of (as is − true offsets (the zero's)) / bound.

Efficiency = RMS over the judged ``ok`` rows of error / bound (the calibrated model's bound from
the true machine file, as ``bench_balance_net --efficiency``). ``--ready`` also judges the
zeroed sensor at other ``ready`` shares (the late start's part).

Usage::

    OMP_NUM_THREADS=1 PYTHONPATH=src python benchmarks/bench_balance_net_decomposition.py \\
        --train-seed 1700 --seed 10300 --n-test 8
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_balance_net import MACHINE, mixture, training_motions  # noqa: E402
from held_out_motions import joystick_trajectory, lever_trajectory, multisine_trajectory  # noqa: E402

from excavator_payload.data.dataset import Dataset  # noqa: E402
from excavator_payload.data.schema import MACHINE_SENSORS  # noqa: E402
from excavator_payload.estimators.base import create_estimator  # noqa: E402
from excavator_payload.estimators.classical.calibrated import CalibratedEstimator  # noqa: E402
from excavator_payload.evaluation import demo_machine as dm  # noqa: E402
from excavator_payload.evaluation.crb_machine import dataset_machine_bound  # noqa: E402
from excavator_payload.simulation.generate import simulate_dataset  # noqa: E402
from excavator_payload.simulation.machine_sensors import PRESETS, measure, session_offsets  # noqa: E402

SIGNALS = list(MACHINE_SENSORS.signals)
FIELD = PRESETS["field"]
MIX = {"swing": 25, "work-cycle": 25, "lifts": 20, "reach": 30}


def test_families(n: int, seed: int) -> dict[str, Dataset]:
    """The judged families of the weighing session (``bench_balance_net``'s seeds)."""
    common = dict(machine=MACHINE, session=dm.SESSION_WORK, with_truth=True, workers=1, progress=False)
    return {
        "nmpc": simulate_dataset(n, seed=seed, motion="nmpc", **common),
        "work-cycle": dm.before_release(simulate_dataset(n, seed=seed + 1, motion="work-cycle", **common)),
        "lever": dm.simulate_trajectory(lever_trajectory(n, seed + 3), seed + 3, dm.SESSION_WORK),
        "slopes": dm.before_release(simulate_dataset(n, seed=seed + 5, motion="slopes", **common)),
        "joystick": dm.simulate_trajectory(joystick_trajectory(n, seed + 6), seed + 6, dm.SESSION_WORK),
        "multisine": dm.simulate_trajectory(multisine_trajectory(n, seed + 7), seed + 7, dm.SESSION_WORK),
    }


def shifted(ds: Dataset, to: dict, away: dict) -> Dataset:
    """Every signal moved from the offsets ``away`` to ``to``."""
    f = ds.frame.copy()
    for s in SIGNALS:
        f[s] = f[s] - away[s] + to[s]
    return Dataset(f, ds.meta)


def noise_free(ds: Dataset, offsets: dict, imu: bool) -> Dataset:
    """The true signals plus ``offsets``, through the IMUs' lag and leak when ``imu``."""
    f = ds.frame.copy()
    if not imu:
        for s in SIGNALS:
            f[s] = f["true_" + s] + offsets[s]
        return Dataset(f, ds.meta)
    quiet = dataclasses.replace(FIELD, angle_noise=0.0, rate_noise=0.0, inclination_noise=0.0,
                                pressure_noise=0.0, ripple_fraction=0.0)
    exp = f["experiment"].to_numpy()
    for x in np.unique(exp):
        rows = np.flatnonzero(exp == x)
        g = f.iloc[rows]
        truth = {s: g["true_" + s].to_numpy(float) for s in SIGNALS}
        acc = g[["true_boom_accel", "true_dipper_accel", "true_bucket_accel", "true_slew_accel"]].to_numpy(float)
        out = measure(truth, g["time"].to_numpy(float), acc, quiet, offsets, np.random.default_rng(0))
        for s in SIGNALS:
            f.loc[f.index[rows], s] = out[s]
    return Dataset(f, ds.meta)


def errors(est, ds: Dataset, bound: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(error, error / bound) per row; NaN where not judged (the first second) or not weighed."""
    f = ds.frame
    err = est.estimate(ds)["payload_estimate"].to_numpy(float) - f["payload"].to_numpy(float)
    exp = f["experiment"].to_numpy()
    judged = np.ones(len(f), bool)
    for a in np.flatnonzero(np.r_[True, exp[1:] != exp[:-1]]):
        judged[a:a + dm.DISCARD] = False
    use = judged & np.isfinite(err) & np.isfinite(bound) & (bound > 0)
    ratio = np.full(len(f), np.nan)
    ratio[use] = err[use] / bound[use]
    return err, ratio


def rms(x: np.ndarray) -> float:
    """RMS of the finite values."""
    return float(np.sqrt(np.nanmean(np.square(x))))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--train-seed", type=int, default=1700)
    ap.add_argument("--seed", type=int, default=10300)
    ap.add_argument("--n-test", type=int, default=8)
    ap.add_argument("--ready", type=float, nargs="*", default=[], help="also judge at these ready shares")
    ap.add_argument("--out", type=Path, default=None, help="a JSON file of the table")
    a = ap.parse_args()
    t0 = time.time()
    train = mixture(training_motions(MIX, a.train_seed), MIX)
    tests = test_families(a.n_test, a.seed)
    zero = dm.zero_data(a.seed + 50)
    first, second = session_offsets(dm.SESSION_CALIBRATION, FIELD), session_offsets(dm.SESSION_WORK, FIELD)
    est = create_estimator("balance-net", None).fit(train)
    reference = CalibratedEstimator(MACHINE).fit(train.subset(train.experiment_ids[:10]))
    reference.zero(zero)
    zeroed = copy.deepcopy(est)
    zeroed.zero(zero)
    true_zero = copy.deepcopy(est)  # the offsets the zero estimates, at their true values
    true_zero.model.offsets = np.array([second[s] - first[s] for s in est.offset_names()])
    trained = copy.deepcopy(est)  # the training session's offsets (the data moved back to them)
    trained.model.offsets = np.zeros(est.model.offset_count())
    trained.health = False  # noise-free signals hold constants the health monitor calls stuck
    print(f"balance-net κ {est.kappa:.2f}; the zero's offsets / true: "
          f"{np.round(zeroed.model.offsets / true_zero.model.offsets, 2).tolist()} ({time.time() - t0:.0f} s)")
    table = {}
    for family, ds in tests.items():
        bound = dataset_machine_bound(ds, reference)
        runs = {"as is": (zeroed, ds), "true offsets (the zero's)": (true_zero, ds),
                "true offsets (all)": (trained, shifted(ds, first, second)),
                "noise-free": (trained, noise_free(ds, first, imu=True)),
                "true signals": (trained, noise_free(ds, first, imu=False))}
        res = {name: errors(e, d, bound) for name, (e, d) in runs.items()}
        row = {name: rms(ratio) for name, (_, ratio) in res.items()}
        noisy, clean = res["true offsets (all)"], res["noise-free"]
        both = np.isfinite(noisy[1]) & np.isfinite(clean[1])
        row["noise part"] = rms((noisy[0] - clean[0])[both] / bound[both])
        as_is, true = res["as is"], res["true offsets (the zero's)"]
        both = np.isfinite(as_is[1]) & np.isfinite(true[1])
        row["zero part"] = rms((as_is[0] - true[0])[both] / bound[both])
        for share in a.ready:
            e = copy.deepcopy(zeroed)
            e.options["ready"] = share
            row[f"as is, ready {share:g}"] = rms(errors(e, ds, bound)[1])
        table[family] = row
        print(family, json.dumps({k: round(v, 2) for k, v in row.items()}), f"({time.time() - t0:.0f} s)", flush=True)
    if a.out is not None:
        a.out.write_text(json.dumps(table, indent=1))


if __name__ == "__main__":
    main()
