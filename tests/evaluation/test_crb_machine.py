"""Cramér–Rao bound of the machine sensor set."""

import numpy as np
import pytest

from excavator_payload.estimators.base import create_estimator
from excavator_payload.evaluation import demo_machine as dm
from excavator_payload.evaluation.crb_machine import dataset_machine_bound, machine_bound


@pytest.fixture(scope="module")
def model_and_test():
    cal = dm.calibration_data(2, seed=21)
    est = create_estimator("calibrated", "cat345c-hydraulic-3pct").fit(cal)
    return est, dm.test_sets(2, seed=22)["swing"]


def test_bound_is_positive_falls_with_time_and_nuisances_cost(model_and_test):
    est, test = model_and_test
    with_nuisances = dataset_machine_bound(test, est)
    alone = machine_bound(test, est.calibration, nuisances=False)
    exp = test.frame["experiment"].to_numpy()
    for k in np.unique(exp):
        b = with_nuisances[exp == k]
        b = b[np.isfinite(b)]
        assert np.all(b > 0) and np.all(np.diff(b) <= 1e-9 * b[:-1])  # information only grows
    ok = np.isfinite(with_nuisances) & np.isfinite(alone)
    assert np.all(with_nuisances[ok] >= alone[ok] * (1 - 1e-9))
    assert np.nanmean(with_nuisances[ok]) > 1.5 * np.nanmean(alone[ok])  # friction and offsets cost


def test_bound_scales_with_the_pressure_noise(model_and_test):
    est, test = model_and_test
    a = machine_bound(test, est.calibration, pressure_std=3e4, nuisances=False)
    b = machine_bound(test, est.calibration, pressure_std=6e4, nuisances=False)
    last = np.flatnonzero(np.isfinite(a))[-1]
    assert 1.2 < b[last] / a[last] <= 2.0 + 1e-9  # stiction variance does not scale with it


def test_no_bound_without_a_machine_calibration(model_and_test):
    _, test = model_and_test
    other = create_estimator("inverse-dynamics", "cat345c-hydraulic").fit(test)
    assert dataset_machine_bound(test, other) is None
