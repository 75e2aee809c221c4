r"""How well calibration motions identify the house IMU's acceleration sensitivity, read off its
own pitch and roll (issue 28; docs/findings/false-alarms.md, "The house IMU's sensitivity read off
its signals").

The link IMUs' sensitivities are read off their signals at calibration
(``machine_calibration.data.imu_sensitivities``); the house IMU's can be too
(``house_imu_sensitivity``: the kernel's own leak terms, ``symbolic.house_imu_leak``, and the
model's ``house_inclination`` for a ground tilt). The calibration does not use it: as the
momentum form's prior mean it helped with empty-swing zeros and hurt with slow ones on nine
fresh draws. This measures it on ``simulate --motion calibration`` data of the given seeds (cached),
from the first 5 and all 10 motions and per motion, against the simulator's
k = leak · radius / g.

    PYTHONPATH=src python benchmarks/house_imu_readoff.py --seeds 97010,97110,97210
"""

from __future__ import annotations

import argparse
import pickle
from pathlib import Path

import numpy as np

from excavator_payload.data.dataset import Dataset
from excavator_payload.estimators.classical.machine_calibration.data import house_imu_sensitivity
from excavator_payload.evaluation import demo_machine as dm
from excavator_payload.platforms.hydraulic import PRESETS
from excavator_payload.simulation.generate import simulate_dataset


def calibration_motions(seed: int, cache: Path) -> Dataset:
    """Ten recommended calibration motions (``--motion calibration``, session A) at ``seed``,
    kept under ``cache``.

    Parameters
    ----------
    seed : int
        Seed of the motions and of the simulation.
    cache : pathlib.Path
        Folder of the pickled datasets.
    """
    path = cache / f"cal_{seed}.pkl"
    if path.exists():
        return pickle.loads(path.read_bytes())
    ds = simulate_dataset(10, seed=seed, motion="calibration", machine="cat345c-hydraulic",
                          session=dm.SESSION_CALIBRATION, with_truth=True, workers=1, progress=False)
    cache.mkdir(parents=True, exist_ok=True)
    path.write_bytes(pickle.dumps(ds))
    return ds


def main() -> None:
    """Per seed and motion count (5, 10), the read-off with and without the tilt nuisance, and
    per motion."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", default="97010,97110,97210")
    ap.add_argument("--cache", type=Path, default=Path("/work/scratch/houseimu28"))
    a = ap.parse_args()
    field = PRESETS["field"]
    truth = field.acceleration_leak * field.house_imu_radius / 9.81
    print(f"true k = {truth:.5f} s² (field preset)")
    for seed in (int(s) for s in a.seeds.split(",")):
        ds = calibration_motions(seed, a.cache)
        for n in (5, 10):
            sub = ds.subset(list(ds.experiment_ids)[:n])
            for tilt in (False, True):
                k, sd = house_imu_sensitivity(sub, tilt=tilt)
                print(f"{seed} {n:2d} motions {'tilt' if tilt else 'flat'}: k = {k:.5f} ± {sd:.5f} s², "
                      f"{100 * (k / truth - 1):+.1f} %")
        each = [house_imu_sensitivity(ds.subset([e]))[0] for e in ds.experiment_ids]
        print(f"{seed} per motion: {np.round(np.asarray(each) / truth - 1, 3).tolist()}")


if __name__ == "__main__":
    main()
