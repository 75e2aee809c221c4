"""Shared fixtures: small datasets that are cheap to make (minimum-jerk moves, exact torques)."""

import pytest

from excavator_payload.simulation.minimum_jerk import simulate_minimum_jerk


@pytest.fixture(scope="session")
def mj_dataset():
    """20 minimum-jerk experiments, thesis noise, with the noise-free truth columns."""
    return simulate_minimum_jerk(20, seed=11, noise="thesis", with_truth=True)


@pytest.fixture(scope="session")
def mj_dataset_clean():
    """10 minimum-jerk experiments without noise."""
    return simulate_minimum_jerk(10, seed=12, noise="none", with_truth=True)


@pytest.fixture(scope="session")
def machine_calibration():
    """3 calibration swings (0, 2500, 5000 kg, session 1, seed 5), an empty swing in session 2
    (seed 6) and ``calibrated`` (differentiated balance) fitted on the swings, not zeroed;
    simulated and fitted once for every file that uses them (deep-copy the estimator before
    changing it)."""
    from excavator_payload.estimators.base import create_estimator
    from excavator_payload.evaluation import demo_machine as dm

    cal = dm.calibration_data(3, seed=5)
    fitted = create_estimator("calibrated", "cat345c-hydraulic-3pct", balance="differentiated").fit(cal)
    return dict(cal=cal, zero=dm.zero_data(seed=6), fitted=fitted)


#: The longest test files, started first: with two workers (pytest-xdist, one file per worker at
#: a time) a long file begun last would leave one worker running it alone at the end.
LONG_FILES = ("estimators/test_conformance.py", "test_hostile_cli.py",
              "estimators/classical/test_calibrated_machine.py", "evaluation/test_demo_machine.py",
              "estimators/classical/test_calibrated_machine_momentum.py")


def pytest_collection_modifyitems(config, items):
    def rank(item):
        path = item.nodeid.split("::")[0].removeprefix("tests/")
        return LONG_FILES.index(path) if path in LONG_FILES else len(LONG_FILES)

    items.sort(key=rank)  # stable: the order within a file and among the others is kept
