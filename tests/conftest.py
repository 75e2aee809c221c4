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
