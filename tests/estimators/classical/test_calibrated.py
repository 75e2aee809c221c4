"""Calibrated estimator: base-parameter identification removes the wrong model's bias."""

import numpy as np
import pandas as pd
import pytest

from excavator_payload.cli import main
from excavator_payload.data.io import write_dataset
from excavator_payload.errors import EstimatorError
from excavator_payload.estimators import create_estimator, load_estimator
from excavator_payload.estimators.classical.calibrated import (
    CalibratedEstimator,
    calibration_curve,
    identify_base_parameters,
    judged_errors,
)
from excavator_payload.estimators.classical.inverse_dynamics import base_parameters, sensor_variances
from excavator_payload.model.machine import load_machine
from excavator_payload.simulation.minimum_jerk import simulate_minimum_jerk


@pytest.fixture(scope="module")
def calibration_and_test(mj_dataset):
    return mj_dataset.split(10, 10)


def test_noise_free_identification_recovers_the_true_parameters(mj_dataset_clean):
    theta0, theta1, _ = identify_base_parameters(mj_dataset_clean, load_machine("cat345c-3pct"),
                                                 sensor_variances("none"), prior_std=0.1)
    true0, true1 = base_parameters(load_machine("cat345c"))
    np.testing.assert_allclose(theta0, true0, rtol=1e-5)
    np.testing.assert_allclose(theta1, true1, rtol=1e-5)


def test_calibration_removes_the_wrong_model_bias(calibration_and_test):
    train, test = calibration_and_test
    wrong = create_estimator("inverse-dynamics", "cat345c-3pct").fit(train)
    calibrated = create_estimator("calibrated", "cat345c-3pct", experiments=5).fit(train)
    err_wrong = judged_errors(test, wrong.estimate(test))
    err_cal = judged_errors(test, calibrated.estimate(test))
    assert err_wrong["rms_kg"].mean() > 30.0
    assert err_cal["rms_kg"].mean() < 5.0
    assert err_cal["max_kg"].max() < 50.0
    assert calibrated.calibration_experiments == list(train.experiment_ids[:5])
    table = calibrated.identified_parameters()
    true = np.concatenate(base_parameters(load_machine("cat345c")))
    rel = np.abs(table["identified"] - true) / true
    assert rel.max() < 0.01  # within 1 % of the truth (the prior was 3 % off)


def test_single_experiment_falls_back_on_the_prior(calibration_and_test):
    """One payload cannot separate θ0 from θ1; the prior keeps the result sane."""
    train, test = calibration_and_test
    est = create_estimator("calibrated", "cat345c-3pct", experiments=1).fit(train)
    err = judged_errors(test, est.estimate(test))
    assert np.isfinite(err["rms_kg"]).all() and err["rms_kg"].mean() < 300.0


def test_calibration_curve_improves_with_data(mj_dataset):
    train, test = mj_dataset.split(10, 6)
    curve = calibration_curve(train, test, counts=(0, 2, 10))
    assert list(curve.columns) == ["calibration_experiments", "mean_rms_kg", "rms_kg", "max_error_kg",
                                   "worst_rms_kg", "bias_kg", "n_test"]
    assert curve["calibration_experiments"].tolist() == [0, 2, 10]
    assert (curve["n_test"] == 6).all()
    assert curve["mean_rms_kg"].iloc[0] > 30.0 > 5.0 > curve["mean_rms_kg"].iloc[2]
    with pytest.raises(EstimatorError, match="counts"):
        calibration_curve(train, test, counts=(50,))


def test_bad_calibration_requests_are_clear_errors(calibration_and_test):
    train, _ = calibration_and_test
    with pytest.raises(EstimatorError, match="--experiments 99"):
        create_estimator("calibrated", "cat345c-3pct", experiments=99).fit(train)
    nameless = simulate_minimum_jerk(2, seed=1)
    nameless.meta = {k: v for k, v in nameless.meta.items() if k != "noise"}
    with pytest.raises(EstimatorError, match="noise"):
        create_estimator("calibrated", "cat345c-3pct").fit(nameless)
    with pytest.raises(EstimatorError, match="prior-std"):
        create_estimator("calibrated", "cat345c-3pct", prior_std=0.0)


def test_save_load_round_trip_and_streaming(calibration_and_test, tmp_path):
    train, test = calibration_and_test
    test = test.subset(test.experiment_ids[:2])
    est = create_estimator("calibrated", "cat345c-3pct", experiments=3).fit(train)
    est.save(tmp_path / "cal")
    loaded = load_estimator(tmp_path / "cal")
    assert isinstance(loaded, CalibratedEstimator)
    np.testing.assert_array_equal(loaded.theta_empty, est.theta_empty)
    np.testing.assert_array_equal(loaded.parameter_covariance, est.parameter_covariance)
    batch = est.estimate(test)
    pd.testing.assert_frame_equal(loaded.estimate(test), batch)
    rows = next(test.experiments())[1]
    loaded.reset()
    streamed = [loaded.step(r).estimate for r in rows.to_dict("records")]
    np.testing.assert_array_equal(streamed, batch["payload_estimate"].to_numpy()[:len(rows)])


def test_cli_calibrates_from_a_wrong_machine(calibration_and_test, tmp_path):
    train, _ = calibration_and_test
    data = tmp_path / "cal.parquet"
    write_dataset(train, data)
    assert main(["train", "calibrated", "--data", str(data), "--out", str(tmp_path / "m"),
                 "--machine", "cat345c-3pct", "--experiments", "4"]) == 0
    est = load_estimator(tmp_path / "m")
    assert est.machine.name == "cat345c-3pct" and est.options["experiments"] == 4
    assert len(est.calibration_experiments) == 4
    assert main(["train", "calibrated", "--data", str(data), "--out", str(tmp_path / "x"),
                 "--machine", "cat345c-3pct", "--experiments", "400"]) == 2
