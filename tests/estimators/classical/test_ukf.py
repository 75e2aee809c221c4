"""Unscented Kalman filter: sigma points, known answers, statuses, persistence."""

import copy
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from excavator_payload.errors import EstimatorError
from excavator_payload.estimators import Status, load_estimator
from excavator_payload.estimators.classical.ekf import ExtendedKalmanFilter
from excavator_payload.estimators.classical.ukf import (
    UnscentedKalmanFilter,
    merwe_weights,
    repair_covariance,
)

JUDGED = 81


def errors(out, dataset):
    err = out["payload_estimate"].to_numpy() - dataset.frame["payload"].to_numpy()
    return err.reshape(dataset.n_experiments, -1)


@pytest.fixture(scope="module")
def small(mj_dataset):
    return mj_dataset.subset(mj_dataset.experiment_ids[:6])


@pytest.fixture(scope="module")
def ukf(small):
    return UnscentedKalmanFilter("cat345c", tuning="consistent").fit(small)


@pytest.fixture(scope="module")
def ukf_out(ukf, small):
    return ukf.estimate(small)


@settings(max_examples=25, deadline=None)
@given(alpha=st.floats(0.05, 1.0), seed=st.integers(0, 10_000))
def test_sigma_points_reproduce_mean_and_covariance_of_a_linear_map(alpha, seed):
    """Unscented transform of a linear map is exact: A x̄, A P Aᵀ."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=5) * [0.5, 1, 0.3, 0.3, 2000]
    L = rng.normal(size=(5, 5)) * np.array([0.01, 0.01, 0.02, 0.02, 300])[:, None]
    P = L @ L.T + np.diag([1e-6, 1e-6, 1e-6, 1e-6, 1.0])
    f = UnscentedKalmanFilter.__new__(UnscentedKalmanFilter)
    f.Wm, f.Wc, f.spread = merwe_weights(5, alpha, 2.0, 0.0)
    assert math.isclose(f.Wm.sum(), 1.0, rel_tol=1e-9, abs_tol=1e-9)
    X = f.sigma_points(x, P)
    A = rng.normal(size=(3, 5))
    Y = A @ X
    mean = Y @ f.Wm
    cov = ((Y - mean[:, None]) * f.Wc) @ (Y - mean[:, None]).T
    assert np.allclose(mean, A @ x, rtol=1e-6, atol=1e-6 * np.abs(A @ x).max())
    assert np.allclose(cov, A @ P @ A.T, rtol=1e-6, atol=1e-6 * np.abs(A @ P @ A.T).max())


def test_repair_makes_indefinite_covariance_usable():
    P = np.diag([1e-8, 1e-8, 1e-6, 1e-6, 1e6])
    P[0, 1] = P[1, 0] = 2e-8  # correlation 2: indefinite
    fixed = repair_covariance(P)
    np.linalg.cholesky(fixed)
    assert np.allclose(np.diag(fixed)[2:], np.diag(P)[2:])


def test_noise_free_data_converges_to_true_payload(mj_dataset_clean):
    ukf = UnscentedKalmanFilter("cat345c").fit(mj_dataset_clean)
    sub = mj_dataset_clean.subset(mj_dataset_clean.experiment_ids[:4])
    assert np.abs(errors(ukf.estimate(sub), sub)[:, JUDGED:]).max() < 0.05


def test_agrees_with_ekf_and_meets_the_bound(small, ukf_out):
    """The torque channel is linear in the payload, so UKF and EKF nearly coincide."""
    ekf_out = ExtendedKalmanFilter("cat345c").fit(small).estimate(small)
    e_ukf = errors(ukf_out, small)[:, JUDGED:]
    e_ekf = errors(ekf_out, small)[:, JUDGED:]
    assert np.abs(e_ukf - e_ekf).max() < 0.5
    assert np.sqrt(np.mean(e_ukf**2)) < 5.0  # CRB here ≈ 1.2 kg


def test_wrong_model_is_biased(small, ukf_out):
    wrong = UnscentedKalmanFilter("cat345c-3pct").fit(small).estimate(small)
    assert np.abs(errors(wrong, small)[:, JUDGED:]).mean() > 10 * np.abs(errors(ukf_out, small)[:, JUDGED:]).mean()


def test_thesis_tuning_stays_finite(small):
    """Thesis Q = 10⁶ puts sigma points at ±10³ rad/s: useless, but it must not produce NaN."""
    out = UnscentedKalmanFilter("cat345c", tuning="thesis").fit(small).estimate(
        small.subset(small.experiment_ids[:2]))
    assert np.isfinite(out["payload_estimate"]).all()


def test_streaming_equals_batch(small, ukf, ukf_out):
    exp_id = small.experiment_ids[1]
    rows = small.frame[small.frame["experiment"] == exp_id]
    ukf.reset()
    stream = [ukf.step(s) for s in rows.to_dict("records")]
    batch = ukf_out[ukf_out["experiment"] == exp_id]
    assert np.array_equal([r.estimate for r in stream], batch["payload_estimate"].to_numpy())
    assert [r.status.value for r in stream] == list(batch["status"])


def test_nan_sample_and_gap(small, ukf):
    rows = small.frame[small.frame["experiment"] == small.experiment_ids[0]].to_dict("records")
    ukf.reset()
    for s in rows[:30]:
        ukf.step(s)
    assert ukf.step(dict(rows[30], dipper_rate=math.nan)).status is Status.INVALID
    kept = ukf.step(rows[31])  # a short gap: payload kept, kinematics restart
    assert kept.status is Status.GAP and abs(kept.estimate - rows[0]["payload"]) < 20.0
    assert [ukf.step(s).status for s in rows[32:40]] == [Status.OK] * 8
    assert ukf.step(dict(rows[40], time=99.0)).status is Status.GAP  # long gap: restart
    assert ukf.step(dict(rows[41], time=99.05)).status is Status.WARMING_UP
    assert np.all(np.isfinite(ukf._x)) and np.all(np.isfinite(ukf._P))


def test_save_load_round_trip(tmp_path, small, ukf, ukf_out):
    ukf.save(tmp_path / "ukf")
    loaded = load_estimator(tmp_path / "ukf")
    assert isinstance(loaded, UnscentedKalmanFilter) and loaded.options == ukf.options
    sub = small.subset(small.experiment_ids[:1])
    assert np.array_equal(loaded.estimate(sub)["payload_estimate"],
                          ukf_out["payload_estimate"][: len(sub.frame)])
    clone = copy.deepcopy(loaded)
    assert np.array_equal(clone.estimate(sub)["payload_estimate"], ukf_out["payload_estimate"][: len(sub.frame)])


def test_bad_options():
    with pytest.raises(EstimatorError):
        UnscentedKalmanFilter("cat345c", alpha=0.0)
    with pytest.raises(EstimatorError):
        UnscentedKalmanFilter("cat345c", alpha="x")
