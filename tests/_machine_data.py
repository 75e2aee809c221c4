"""Small machine-sensor-set test data shared by several test files."""

from __future__ import annotations

import numpy as np

from excavator_payload.data.dataset import Dataset
from excavator_payload.evaluation import demo_machine as dm
from excavator_payload.simulation.generate import simulate_dataset


def swing_test_set(n: int, seed: int, machine: str = "cat345c-hydraulic") -> Dataset:
    """Exactly ``dm.test_sets(n, seed)["swing"]`` (same call, same seed), without simulating the
    three other sets (NMPC, work cycle, slope) the tests never use: 0.6 s instead of 29 s for n=2."""
    return simulate_dataset(n, seed=seed, motion="swing", machine=machine, session=dm.SESSION_WORK,
                            with_truth=True, workers=1, progress=False)


def zeroed_momentum_models(swings: Dataset) -> dict:
    """The momentum form fitted on ``swings`` (no cross-check: s = 0, so σ beyond the sensor
    noise is the zero's share alone; health monitor off), unzeroed and zeroed on an empty swing,
    the IMU nuisance filter off and on: ``{"unzeroed", "off", "on"}``."""
    import copy

    from excavator_payload.estimators.base import create_estimator

    fitted = create_estimator("calibrated", machine="cat345c-hydraulic-3pct", model_std="none",
                              imu_nuisance="off").fit(swings)
    fitted.health = False  # the monitor's C is compared in test_export_c_health.py
    off = copy.deepcopy(fitted)
    off.zero(dm.zero_data(seed=6))
    on = copy.deepcopy(off)
    on.options["imu_nuisance"] = "on"
    on.use_calibration()
    return {"unzeroed": fitted, "off": off, "on": on}


def mean_abs_error(est, ds: Dataset) -> float:
    """Mean |error| (kg) of ``est`` on ``ds`` after each experiment's discarded first samples."""
    e = est.estimate(ds)["payload_estimate"].to_numpy() - ds.frame["payload"].to_numpy()
    judged = ds.frame.groupby("experiment").cumcount().to_numpy() >= dm.DISCARD
    return float(np.nanmean(np.abs(e[judged])))
