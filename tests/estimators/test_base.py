"""The estimator protocol itself: input checks, gaps, streaming == batch, save/load errors.

Uses a small concrete estimator (running mean of the inverse-dynamics payload solve) so the
protocol is exercised without depending on any particular production estimator.
"""

import json
import math

import numpy as np
import pytest

from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.base import (
    Estimator,
    Option,
    Status,
    StepResult,
    create_estimator,
    load_estimator,
    register,
)
from excavator_payload.model.dynamics import ArmModel


@register
class _RunningMean(Estimator):
    """Per-sample least squares on τ − τ0 = m·φ, averaged over the experiment."""

    name = "test-running-mean"
    OPTIONS = {"min_samples": Option(int, 3, "samples before the estimate is OK")}

    def _fit(self, dataset):
        self.arm = ArmModel(self.machine)

    def _reset(self):
        self.sum, self.n = 0.0, 0

    def _step(self, time, v):
        q, qd, qdd, tau = v[[0, 3]], v[[1, 4]], v[[2, 5]], v[[6, 7]]
        phi = self.arm.payload_regressor(q, qd, qdd)
        tau0 = self.arm.torque_empty(q, qd, qdd)
        self.sum += float(phi @ (tau - tau0) / (phi @ phi))
        self.n += 1
        status = Status.OK if self.n >= self.options["min_samples"] else Status.WARMING_UP
        return StepResult(self.sum / self.n, status)

    def _config(self):
        return {"fitted_on": "test"}

    def _restore(self, config, arrays):
        assert config["fitted_on"] == "test"
        self.arm = ArmModel(self.machine)


def _sample(ds, row):
    r = ds.frame.iloc[row]
    return {k: float(r[k]) for k in ds.frame.columns}


def test_noise_free_converges_and_statuses(mj_dataset_clean):
    est = create_estimator("test-running-mean").fit(mj_dataset_clean)
    out = est.estimate(mj_dataset_clean)
    assert list(out.columns) == ["experiment", "time", "payload_estimate", "status", "sigma"]
    first = out.groupby("experiment").head(2)
    assert set(first["status"]) == {"warming_up"}
    err = out["payload_estimate"] - mj_dataset_clean.frame["payload"]
    assert np.nanmax(np.abs(err)) < 1e-3


def test_streaming_equals_batch(mj_dataset):
    est = create_estimator("test-running-mean").fit(mj_dataset)
    batch = est.estimate(mj_dataset.subset([0, 1]))
    est.reset()
    streamed = []
    for i in range(len(batch)):
        if i == 101:
            est.reset()
        streamed.append(est.step(_sample(mj_dataset, i)).estimate)
    np.testing.assert_allclose(streamed, batch["payload_estimate"].to_numpy())


def test_bad_samples_are_reported_not_raised(mj_dataset):
    est = create_estimator("test-running-mean").fit(mj_dataset)
    assert math.isnan(est.step({"time": 0.0}).estimate)  # missing signals
    assert est.step({"time": 0.0}).status is Status.INVALID
    s = _sample(mj_dataset, 0)
    r = est.step(s)
    assert r.status is Status.WARMING_UP
    bad = dict(s, time=0.05, boom_torque=float("nan"))
    assert est.step(bad) == StepResult(r.estimate, Status.INVALID)
    out_of_range = dict(s, time=0.05, boom_angle=3.0)
    assert est.step(out_of_range).status is Status.OUT_OF_RANGE
    ok = _sample(mj_dataset, 1)
    assert est.step(ok).status is Status.WARMING_UP  # the skipped samples did not count
    gap = dict(_sample(mj_dataset, 10))
    assert est.step(gap).status is Status.GAP  # 0.45 s jump restarts the estimator
    assert est.n == 1


def test_save_load_round_trip(tmp_path, mj_dataset):
    est = create_estimator("test-running-mean", min_samples=5).fit(mj_dataset)
    est.save(tmp_path / "m")
    config = json.loads((tmp_path / "m" / "estimator.json").read_text())
    assert config["estimator"] == "test-running-mean" and config["options"] == {"min_samples": 5}
    again = load_estimator(tmp_path / "m")
    np.testing.assert_allclose(again.estimate(mj_dataset)["payload_estimate"],
                               est.estimate(mj_dataset)["payload_estimate"])


def test_protocol_errors(tmp_path):
    with pytest.raises(EstimatorError, match="unknown option"):
        create_estimator("test-running-mean", nonsense=1)
    with pytest.raises(EstimatorError, match="not a valid int"):
        create_estimator("test-running-mean", min_samples="many")
    with pytest.raises(EstimatorError, match="unknown estimator"):
        create_estimator("no-such-estimator")
    with pytest.raises(EstimatorError, match="does not exist"):
        load_estimator(tmp_path / "missing")
    (tmp_path / "foreign").mkdir()
    with pytest.raises(EstimatorError, match="not a saved estimator"):
        load_estimator(tmp_path / "foreign")
    (tmp_path / "foreign" / "estimator.json").write_text("{not json")
    with pytest.raises(EstimatorError, match="corrupt"):
        load_estimator(tmp_path / "foreign")
    (tmp_path / "foreign" / "estimator.json").write_text('{"format": "something-else"}')
    with pytest.raises(EstimatorError, match="not saved by excavator-payload"):
        load_estimator(tmp_path / "foreign")
    est = create_estimator("test-running-mean")
    with pytest.raises(EstimatorError, match="fit"):
        est.step({"time": 0.0})
    with pytest.raises(EstimatorError, match="not fitted"):
        est.save(tmp_path / "unfitted")
