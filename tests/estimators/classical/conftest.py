"""The machine set's calibrated estimator, fitted and zeroed once per test module (shared by
``test_calibrated_machine.py`` and ``test_calibrated_machine_momentum.py``)."""

import copy

import pytest

from excavator_payload.estimators.base import create_estimator

from ..._machine_data import swing_test_set

PRIOR = "cat345c-hydraulic-3pct"



@pytest.fixture(scope="module")
def setup(machine_calibration):
    """3 calibration swings (0, 2500, 5000 kg) in session 1, an empty swing and 2 test swings
    in session 2, and the calibrated + zeroed estimator (conftest's machine_calibration)."""
    cal, zero = machine_calibration["cal"], machine_calibration["zero"]
    test = swing_test_set(2, seed=7)
    calibrated = copy.deepcopy(machine_calibration["fitted"])
    est = copy.deepcopy(machine_calibration["fitted"])
    est.zero(zero)
    return dict(cal=cal, zero=zero, test=test, calibrated=calibrated, zeroed=est)


@pytest.fixture(scope="module")
def momentum(setup):
    est = create_estimator("calibrated", PRIOR, balance="momentum").fit(setup["cal"])
    est.zero(setup["zero"])
    return est
