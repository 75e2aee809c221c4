"""The solver's full prior covariance (``MachineCalibration.solve(prior_covariance=…)``) and the
zero that frees parameters under the calibration's posterior (``zero_offsets(parameters=…)``,
measured in docs/findings/any-motion.md, "A zero that moves the parameters")."""

import copy

import numpy as np
import pytest

from excavator_payload.estimators.base import create_estimator
from excavator_payload.estimators.classical.machine_calibration import solver
from excavator_payload.estimators.classical.machine_calibration.data import calibration_arrays
from excavator_payload.estimators.classical.machine_calibration.settings import (
    CALIBRATED_PARAMETERS, CALIBRATION_HALF_WINDOW, OFFSET_PRIOR_STD, OFFSET_SIGNALS)
from excavator_payload.evaluation import demo_machine as dm

N_DELTA, N_OFF = len(CALIBRATED_PARAMETERS), len(OFFSET_SIGNALS)
OFFSETS = np.arange(N_DELTA, N_DELTA + N_OFF)


@pytest.fixture(scope="module")
def setup():
    """A momentum calibration on 4 swings (session 1) and two empty swings of session 2."""
    est = create_estimator("calibrated", "cat345c-hydraulic-3pct", model_std="none").fit(
        dm.calibration_data(4, seed=5))
    swings = [dm.simulate_trajectory(dm.motion_trajectory(1, seed, (0.0,)), seed, dm.SESSION_WORK)
              for seed in (6, 7)]
    return dict(cal=est.calibration, swings=swings)


def _arrays(cal, dataset):
    return calibration_arrays(dataset, CALIBRATION_HALF_WINDOW, cal.arm.machine)


def _solve(cal, arrays, mean, std=None, covariance=None):
    values, qdd, payload, runs = arrays
    cal.solve(values, qdd, payload, OFFSETS, mean, std if std is not None else np.ones(len(mean)), "skip",
              iterations=8, estimate_noise=False, runs=runs, prior_covariance=covariance)
    return cal.z.copy(), cal.covariance[np.ix_(OFFSETS, OFFSETS)].copy()


def test_a_diagonal_prior_covariance_is_the_diagonal_prior(setup):
    """The full-prior path with Σ = diag(σ²) finds the same offsets and posterior as σ alone."""
    arrays = _arrays(setup["cal"], setup["swings"][0])
    std = np.r_[np.ones(N_DELTA), OFFSET_PRIOR_STD, np.ones(len(setup["cal"].z) - N_DELTA - N_OFF)]
    a, b = copy.deepcopy(setup["cal"]), copy.deepcopy(setup["cal"])
    mean = a.z.copy()
    z_diag, cov_diag = _solve(a, arrays, mean, std=std)
    z_full, cov_full = _solve(b, arrays, mean, covariance=np.diag(OFFSET_PRIOR_STD ** 2))
    sd = np.sqrt(np.diag(cov_diag))
    assert np.max(np.abs(z_full - z_diag)[OFFSETS] / sd) < 1e-6
    np.testing.assert_allclose(cov_full, cov_diag, rtol=1e-8, atol=1e-12 * np.max(cov_diag))


def test_two_motions_one_after_the_other_are_both_at_once(setup):
    """Bayes in sequence: the second swing's fit with the first's full posterior as prior finds
    what both swings fitted at once find (within 0.1 posterior σ); dropping the posterior's
    correlations (its diagonal alone) does not."""
    cal = setup["cal"]
    first, second = (_arrays(cal, s) for s in setup["swings"])
    both = tuple(np.concatenate([x, y + (first[3].max() if k == 3 else 0)])
                 for k, (x, y) in enumerate(zip(first, second)))
    prior = np.diag(OFFSET_PRIOR_STD ** 2)
    mean = cal.z.copy()
    z_both, cov_both = _solve(copy.deepcopy(cal), both, mean, covariance=prior)
    step = copy.deepcopy(cal)
    z_one, cov_one = _solve(step, first, mean, covariance=prior)
    z_seq, _ = _solve(step, second, z_one.copy(), covariance=cov_one)
    sd = np.sqrt(np.diag(cov_both))
    assert np.max(np.abs(z_seq - z_both)[OFFSETS] / sd) < 0.1
    diagonal = copy.deepcopy(cal)
    _solve(diagonal, first, mean, covariance=prior)
    z_diag, _ = _solve(diagonal, second, z_one.copy(), covariance=np.diag(np.diag(cov_one)))
    assert np.max(np.abs(z_diag - z_both)[OFFSETS] / sd) > 0.3


def test_the_zero_moves_the_parameters_it_frees_and_no_others(setup):
    """``zero_offsets(parameters=…)`` moves those parameters within their inflated prior, keeps
    the rest, and with ``parameters=None`` is the offsets-only zero."""
    cal = setup["cal"]
    areas = np.array([i for i, n in enumerate(CALIBRATED_PARAMETERS) if n.endswith("_area")])
    plain, freed = copy.deepcopy(cal), copy.deepcopy(cal)
    solver.zero_offsets(plain, setup["swings"][0])
    solver.zero_offsets(freed, setup["swings"][0], parameters=areas, inflation=4.0)
    others = np.setdiff1d(np.arange(N_DELTA), areas)
    assert np.array_equal(plain.z[:N_DELTA], cal.z[:N_DELTA])
    assert np.array_equal(freed.z[others], cal.z[others])
    moved = np.abs(freed.z[areas] - cal.z[areas]) / np.sqrt(4.0 * np.diag(cal.covariance)[areas])
    assert moved.max() > 1e-3 and moved.max() < 5.0
    assert np.all(np.diag(freed.covariance)[areas] <= 4.0 * np.diag(cal.covariance)[areas] * (1 + 1e-9))
