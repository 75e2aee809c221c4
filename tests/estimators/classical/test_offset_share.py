"""The zero's share of σ per estimate (machine_calibration/offset_share.py): the running sums
give the estimate's own sensitivity to the zero's offsets, checked against finite differences of
the whole weighing; σ² = 1/I + s² + share²; streamed == batch; saved and loaded alike."""

import copy
import pickle

import numpy as np
import pytest

from excavator_payload.data.schema import MACHINE_SENSORS
from excavator_payload.estimators.base import load_estimator
from excavator_payload.estimators.classical.machine_calibration.offset_share import offset_whitening
from excavator_payload.estimators.classical.machine_calibration.settings import CALIBRATED_PARAMETERS, OFFSET_SIGNALS
from excavator_payload.simulation.machine_sim import simulate_machine_dataset

from ..._machine_data import swing_test_set, zeroed_momentum_models


@pytest.fixture(scope="module")
def zeroed():
    """The momentum form on three swings (no cross-check: s = 0), zeroed on an empty swing;
    the IMU nuisance filter off and on."""
    return zeroed_momentum_models(simulate_machine_dataset(3, seed=3))


@pytest.fixture(scope="module")
def test_swing():
    return swing_test_set(1, seed=7)


def _streamed(est, ds):
    """Per sample: the status, σ, the share and 1/I, streamed."""
    est.reset()
    f = ds.frame
    rows = []
    for t, v in zip(f["time"].to_numpy(float), f[list(MACHINE_SENSORS.signals)].to_numpy(float)):
        r = est.step_values(t, v)
        rows.append((r.status.value, r.sigma, est.kernel.regression.extra_std, est.kernel.info))
    return rows


@pytest.mark.parametrize("nuisance", ["off", "on"])
def test_share_equals_finite_differences_of_the_weighing(zeroed, test_swing, nuisance):
    """Moving the zero's offsets along each whitened direction of their posterior moves the
    batch estimate by what the running sums say (the weights held: within 2 %, 4 % with the IMU
    dynamics filter, which re-weights the windows)."""
    est = copy.deepcopy(zeroed[nuisance])
    rows = _streamed(est, test_swing)
    share = np.array([r[2] for r in rows])
    ok = np.array([r[0] == "ok" for r in rows])
    assert ok.sum() > 100 and np.all(share[ok] > 0)
    cal = est.calibration
    L = offset_whitening(cal)
    start, z0, h = len(CALIBRATED_PARAMETERS), cal.z.copy(), 0.5
    columns = []
    for k in range(L.shape[1]):
        moved = []
        for sign in (1.0, -1.0):
            cal.z = z0.copy()
            cal.z[start:start + len(OFFSET_SIGNALS)] += sign * h * L[:, k]
            est.use_calibration()
            moved.append(est.estimate(test_swing)["payload_estimate"].to_numpy(float))
        columns.append((moved[0] - moved[1]) / (2 * h))
    cal.z = z0
    est.use_calibration()
    G = np.array(columns)
    finite = ok & np.all(np.isfinite(G), axis=0)
    assert finite.sum() > 0.9 * ok.sum()
    fd = np.sqrt(np.sum(G[:, finite] ** 2, axis=0))
    # the share holds the windows' weights; with the IMU dynamics filter on, moved offsets also
    # re-weight the windows a little (2.4 % at most here with two BLAS threads, 1.9 % with one)
    np.testing.assert_allclose(share[finite], fd, rtol=0.02 if nuisance == "off" else 0.04)


def test_sigma_adds_the_share_and_streams_as_the_batch(zeroed, test_swing, tmp_path):
    est = copy.deepcopy(zeroed["on"])
    rows = _streamed(est, test_swing)
    sigma = np.array([r[1] for r in rows], float)
    share = np.array([r[2] for r in rows])
    info = np.array([r[3] for r in rows])
    s = est.calibration.model_std
    has = np.isfinite(sigma)
    np.testing.assert_allclose(sigma[has] ** 2, 1.0 / info[has] + s**2 + share[has] ** 2, rtol=1e-12)
    batch = est.estimate(test_swing)["sigma"].to_numpy(float)
    np.testing.assert_array_equal(np.isnan(batch), ~has)
    np.testing.assert_allclose(batch[has], sigma[has], rtol=1e-12)
    est.save(tmp_path / "m")
    loaded = load_estimator(tmp_path / "m").estimate(test_swing)["sigma"].to_numpy(float)
    np.testing.assert_allclose(loaded[has], batch[has], rtol=1e-12)
    copied = pickle.loads(pickle.dumps(est)).estimate(test_swing)["sigma"].to_numpy(float)
    np.testing.assert_array_equal(copied, batch)
    # the grid's RMS share is no longer in σ: the per-estimate share replaces it
    assert est.kernel.regression.model_std == pytest.approx(s)
    # ... and it is the estimate's own: it moves as the swing adds poses whose sensitivities to
    # the offsets add up or cancel (1.3-6.9 kg on main f58db74, 4.4-7.7 kg with the house IMU's
    # read-off: one load, one swing), where the grid's is one number (5.9 kg both). Its size is
    # the grid's: the same posterior through the weighing's sensitivity, at the swing's poses
    # instead of the static grid's. Which side of the grid's RMS its median falls is not a
    # property (0.69 and 1.05 of it on those two calibrations); a lost term or a unit slip is
    # (docs/findings/false-alarms.md, "The house IMU's sensitivity read off its signals").
    ok_share = share[has & (share > 0)]
    assert ok_share.max() > 1.5 * ok_share.min()
    assert 0.5 < np.median(ok_share) / est.calibration.zero_std < 2.0


def test_no_share_before_a_zero(zeroed, test_swing):
    est = copy.deepcopy(zeroed["unzeroed"])
    assert est.kernel.regression._offset_share is None
    rows = _streamed(est, test_swing)
    assert all(r[2] == 0.0 for r in rows)
