"""The classical estimators' kernels: one per platform, picked at construction, fit and load.

``saved_before_kernels/`` holds model folders written by the code before the kernels (the
estimators then held both platforms' state and branched on it): they must load, weigh and save
back byte for byte, so that models saved in the field keep working.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.base import create_estimator, load_estimator
from excavator_payload.estimators.persistence import DIGEST_KEY, arrays_digest
from excavator_payload.estimators.classical.calibrated import IdentifiedTorqueKernel
from excavator_payload.estimators.classical.inverse_dynamics import TorqueKernel
from excavator_payload.estimators.classical.kernels import UnfittedKernel
from excavator_payload.estimators.classical.pressure_regression import PressureKernel
from excavator_payload.simulation.minimum_jerk import simulate_minimum_jerk

SAVED = Path(__file__).parent / "saved_before_kernels"


@pytest.mark.parametrize("name", ["inverse-dynamics", "calibrated", "inverse-dynamics-machine"])
def test_a_model_saved_before_the_kernels_saves_back_byte_for_byte(name, tmp_path):
    est = load_estimator(SAVED / name)
    est.save(tmp_path / "again")
    # saved again, the folder gains the digest of its arrays (session 22), nothing else
    config = json.loads((tmp_path / "again" / "estimator.json").read_text())
    digest = config.pop(DIGEST_KEY)
    assert json.dumps(config, indent=2) == (SAVED / name / "estimator.json").read_text()
    before, after = np.load(SAVED / name / "arrays.npz"), np.load(tmp_path / "again" / "arrays.npz")
    assert digest == arrays_digest(dict(before))
    assert list(after.keys()) == list(before.keys())
    for key in before:
        assert after[key].dtype == before[key].dtype
        np.testing.assert_array_equal(after[key], before[key])


def test_a_thesis_model_saved_before_weighs_as_a_fresh_fit():
    """inverse-dynamics reads only the noise preset of its data: a fresh fit on any thesis-noise
    data is the saved model, and both give the same statuses exactly and the same estimates and
    sigmas to rounding (the saved parameters were computed on another CPU, whose BLAS kernels sum
    in another order: 2e-14 relative on an AMD EPYC)."""
    saved = load_estimator(SAVED / "inverse-dynamics")
    fresh = create_estimator("inverse-dynamics", "cat345c", weighting="diagonal").fit(
        simulate_minimum_jerk(2, seed=21, noise="thesis"))
    test = simulate_minimum_jerk(2, seed=22, noise="field")
    got, want = saved.estimate(test), fresh.estimate(test)
    assert set(got["status"]) >= {"ok", "rejected_outlier"}
    pd.testing.assert_frame_equal(got, want, check_exact=False, rtol=1e-12, atol=0.0)
    assert (got["status"] == want["status"]).all()


def test_the_kernel_is_picked_per_platform():
    thesis = create_estimator("inverse-dynamics", "cat345c")
    assert type(thesis.kernel) is TorqueKernel and thesis.noise_name == "thesis"
    hydraulic = create_estimator("inverse-dynamics", "cat345c-hydraulic")
    # before fit a hydraulic machine's kernel waits for the data (noise, outlier scale)
    assert isinstance(hydraulic.kernel, UnfittedKernel) and hydraulic.noise_name == "field"
    hydraulic.reset()
    assert math.isinf(hydraulic.uncertainty)
    with pytest.raises(EstimatorError, match="fit"):
        hydraulic.step({"time": 0.0})
    assert type(load_estimator(SAVED / "inverse-dynamics-machine").kernel) is PressureKernel
    calibrated = load_estimator(SAVED / "calibrated")
    assert type(calibrated.kernel) is IdentifiedTorqueKernel
    assert calibrated.parameter_covariance.shape == (12, 12) and calibrated.calibration_experiments
    assert calibrated.weighing is None and calibrated.calibration is None
    assert type(create_estimator("calibrated", "cat345c").kernel) is IdentifiedTorqueKernel


def test_a_saved_state_naming_another_kernel_is_refused(tmp_path):
    """The kernel tag picks the kernel at load: a machine kernel's state on a 2-link machine, or
    a tag no kernel of the estimator wrote, is one clear line."""
    est = load_estimator(SAVED / "inverse-dynamics")
    arrays = dict(np.load(SAVED / "inverse-dynamics-machine" / "arrays.npz"))
    with pytest.raises(EstimatorError, match="corrupt"):
        est._restore({"kernel": "pressure_regression", "noise": "field"}, arrays)
    with pytest.raises(EstimatorError, match="unknown kernel"):
        est._restore({"kernel": "calibrated_machine"}, arrays)
