"""The Cramér–Rao bound: closed form on a known case, and attained by the ML estimator."""

import numpy as np
import pandas as pd

from excavator_payload.data.dataset import Dataset
from excavator_payload.evaluation.crb import cramer_rao_bound, sample_information
from excavator_payload.model.dynamics import ArmModel
from excavator_payload.simulation.sensors import get_noise_preset


def test_window_and_history_bounds_are_consistent(mj_dataset):
    info = sample_information(mj_dataset)
    whole = cramer_rao_bound(mj_dataset)
    window = cramer_rao_bound(mj_dataset, window=6)
    first = mj_dataset.frame["experiment"].to_numpy() == mj_dataset.experiment_ids[0]
    np.testing.assert_allclose(whole[first], 1 / np.sqrt(np.cumsum(info[first])))
    assert np.isnan(window[first][:5]).all()
    np.testing.assert_allclose(window[first][5], 1 / np.sqrt(info[first][:6].sum()))
    # more samples never carry less information
    assert np.all(window[first][5:] >= whole[first][5:] - 1e-9)
    assert np.all(np.diff(whole[first]) <= 1e-12)


def test_bound_is_attained_by_weighted_least_squares(mj_dataset):
    """Monte Carlo: the ML estimate of m from noisy torques has the std the bound predicts."""
    one = mj_dataset.subset([mj_dataset.experiment_ids[0]])
    f = one.frame
    arm = ArmModel(one.machine())
    q = f[["true_boom_angle", "true_dipper_angle"]].to_numpy()
    qd = f[["true_boom_rate", "true_dipper_rate"]].to_numpy()
    qdd = f[["true_boom_accel", "true_dipper_accel"]].to_numpy()
    phi, tau0 = arm.payload_regressor(q, qd, qdd), arm.torque_empty(q, qd, qdd)
    tau_true = f[["true_boom_torque", "true_dipper_torque"]].to_numpy()
    sigma = np.sqrt(np.diag(get_noise_preset("thesis").torque_covariance))
    rng = np.random.default_rng(0)
    estimates = []
    for _ in range(400):
        tau = tau_true + rng.standard_normal(tau_true.shape) * sigma
        w = phi / sigma**2
        estimates.append(np.sum(w * (tau - tau0)) / np.sum(w * phi))
    bound = cramer_rao_bound(one)[-1]
    assert abs(np.mean(estimates) - f["payload"].iloc[0]) < 4 * bound / np.sqrt(400) + 1e-6
    assert 0.85 < np.std(estimates) / bound < 1.15


def test_noise_free_torques_give_a_zero_bound(mj_dataset_clean):
    assert np.all(cramer_rao_bound(mj_dataset_clean) == 0.0)
