"""Cramér–Rao bound of the machine sensor set."""

import numpy as np
import pytest

from excavator_payload.estimators.base import create_estimator
from excavator_payload.evaluation import demo_machine as dm
from excavator_payload.evaluation.crb_machine import dataset_machine_bound, machine_bound
from .._machine_data import swing_test_set


@pytest.fixture(scope="module")
def calibration_swings():
    return dm.calibration_data(2, seed=21)


@pytest.fixture(scope="module")
def model_and_test(calibration_swings):
    cal = calibration_swings
    est = create_estimator("calibrated", "cat345c-hydraulic-3pct").fit(cal)
    return est, swing_test_set(2, seed=22)


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


def test_a_standstill_counts_once_not_per_sample(model_and_test):
    """Stiction is one unknown per standstill episode: the information of a stopped cylinder's
    samples is capped (Schur complement of the shared stiction), below the per-sample model."""
    from excavator_payload.evaluation.crb_machine import _episode_information

    rng = np.random.default_rng(0)
    n, d = 400, 4
    G = rng.normal(size=(n, 3, d))
    w = np.full((n, 3), 2.0)
    still = np.zeros((n, 3), bool)
    still[:300, 0] = True  # joint 0 stands still for 300 samples
    stiction = np.full((n, 3), 0.5)
    removed = np.cumsum(_episode_information(G, w, still, stiction), axis=0)
    full = np.cumsum(np.einsum("nja,nj,njb->nab", G, w, G), axis=0)
    kept = full - removed
    assert np.allclose(removed[300:], removed[299])  # nothing more after the episode ends
    assert np.all(np.linalg.eigvalsh(removed[299]) >= -1e-9)  # it only removes information
    assert np.all(np.linalg.eigvalsh(kept[299]) >= -1e-9)
    # the removed information is exactly the episode's share along its mean direction
    S = (w[:300, 0, None] * G[:300, 0]).sum(0)
    assert np.allclose(removed[299], np.outer(S, S) / (w[:300, 0].sum() + 3 / 0.25))


def test_episodes_make_a_slow_start_harder_to_weigh(model_and_test):
    est, test = model_and_test
    episodes = machine_bound(test, est.calibration)
    independent = machine_bound(test, est.calibration, stiction_episodes=False)
    t = test.frame["time"].to_numpy(float)
    early = (t > 0.5) & (t < 1.0) & np.isfinite(episodes) & np.isfinite(independent)
    assert np.median(episodes[early] / independent[early]) > 1.5


def test_procedure_bound_counts_what_calibration_leaves_unknown(model_and_test, calibration_swings):
    """The whole procedure's bound (every calibrated parameter unknown, learnt from the
    calibration motions) only grows when the calibration data shrink, and falls with time."""
    from excavator_payload.data.dataset import Dataset
    from excavator_payload.evaluation.crb_machine import procedure_bound

    est, test = model_and_test
    cal = calibration_swings  # dm.calibration_data(2, seed=21), the model's own
    full = procedure_bound(test, est.calibration, cal)
    f = cal.frame
    half = Dataset(f[f["experiment"] == f["experiment"].iloc[0]].reset_index(drop=True), cal.meta)
    less = procedure_bound(test, est.calibration, half)
    ok = np.isfinite(full) & np.isfinite(less)
    assert ok.sum() > 100 and np.all(full[ok] > 0)
    assert np.all(less[ok] >= full[ok] * (1 - 1e-7))  # less calibration data: never a lower bound
    assert np.nanmedian(less[ok] / full[ok]) > 1.05
    exp = test.frame["experiment"].to_numpy()
    b = full[(exp == exp[0]) & np.isfinite(full)]
    assert np.all(np.diff(b) <= 1e-7 * b[:-1])  # information only grows within an experiment


def test_procedure_bound_refuses_thesis_data(model_and_test):
    from excavator_payload.errors import EstimatorError
    from excavator_payload.evaluation.crb_machine import procedure_bound
    from excavator_payload.simulation.generate import simulate_dataset

    est, test = model_and_test
    thesis = simulate_dataset(1, seed=3, workers=1, progress=False)
    with pytest.raises(EstimatorError, match="machine-sensor-set calibration"):
        procedure_bound(test, est.calibration, thesis)
