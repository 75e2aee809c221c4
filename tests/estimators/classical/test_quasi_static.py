"""Quasi-static (patent EP0736752A1) estimator and the slow-lift simulator."""

import math

import numpy as np
import pandas as pd
import pytest

from excavator_payload.cli import main
from excavator_payload.data.io import read_dataset, write_dataset
from excavator_payload.data.schema import COLUMNS, SAMPLE_PERIOD
from excavator_payload.errors import EstimatorError
from excavator_payload.estimators import Status, create_estimator, load_estimator
from excavator_payload.estimators.classical.calibrated import judged_errors
from excavator_payload.estimators.classical.quasi_static import QuasiStaticEstimator
from excavator_payload.model.dynamics import ArmModel
from excavator_payload.simulation.lifts import simulate_lifts

DEG = math.pi / 180


@pytest.fixture(scope="module")
def clean_lifts():
    return simulate_lifts(24, seed=1, noise="none", with_truth=True)


@pytest.fixture(scope="module")
def noisy_lifts():
    return simulate_lifts(24, seed=1, noise="thesis")


# -- simulator -----------------------------------------------------------------------------

def test_lifts_are_slow_constant_speed_with_exact_torques(clean_lifts):
    ds = clean_lifts
    assert list(ds.frame.columns[:len(COLUMNS)]) == list(COLUMNS)
    assert ds.meta["motion"] == "lifts" and ds.n_experiments == 24
    np.testing.assert_array_equal(ds.payloads, np.tile([0.0, 5000.0], 12))
    rows = next(ds.experiments())[1]
    assert len(rows) > 101 and np.allclose(np.diff(rows["time"]), SAMPLE_PERIOD)
    middle = rows.iloc[len(rows) // 4: 3 * len(rows) // 4]
    np.testing.assert_allclose(middle["boom_rate"], 5 * DEG, rtol=1e-12)
    assert np.abs(middle["boom_accel"]).max() < 1e-12
    assert rows["dipper_rate"].abs().max() == 0 and rows["dipper_angle"].nunique() == 1
    # position is the integral of the rate (trapezoid) and the motion starts and ends at rest
    q1 = rows["boom_angle"].to_numpy()
    integral = q1[0] + np.r_[0, np.cumsum((rows["boom_rate"].to_numpy()[1:]
                                           + rows["boom_rate"].to_numpy()[:-1]) / 2 * SAMPLE_PERIOD)]
    np.testing.assert_allclose(q1, integral, atol=2e-4)
    assert rows["boom_rate"].iloc[0] == 0 and abs(rows["boom_rate"].iloc[-1]) < 1e-3
    # pairs of lifts share a dipper angle, spread over the range
    dippers = ds.frame.groupby("experiment")["dipper_angle"].first().to_numpy()
    np.testing.assert_array_equal(dippers[0::2], dippers[1::2])
    assert np.ptp(dippers) > 100 * DEG
    f = ds.frame
    tau = ArmModel("cat345c").inverse_dynamics(f[["boom_angle", "dipper_angle"]].to_numpy(),
                                               f[["boom_rate", "dipper_rate"]].to_numpy(),
                                               f[["boom_accel", "dipper_accel"]].to_numpy(),
                                               f["payload"].to_numpy())
    np.testing.assert_allclose(f[["boom_torque", "dipper_torque"]].to_numpy(), tau)


def test_lifts_round_trip_through_parquet(tmp_path):
    ds = simulate_lifts(3, seed=5, payloads=[100.0, 200.0, 300.0])
    write_dataset(ds, tmp_path / "lifts.parquet")
    back = read_dataset(tmp_path / "lifts.parquet")
    np.testing.assert_array_equal(back.payloads, [100.0, 200.0, 300.0])
    pd.testing.assert_frame_equal(back.frame, ds.frame, check_dtype=False)


# -- estimator -----------------------------------------------------------------------------

def test_exact_on_slow_lifts(clean_lifts):
    est = create_estimator("quasi-static", "cat345c", averaging="none").fit(clean_lifts)
    same_lines = simulate_lifts(24, seed=2, noise="none", payloads=[1500.0, 3500.0])
    other_lines = simulate_lifts(9, seed=2, noise="none", payloads=[1500.0, 3500.0, 2500.0])
    for ds, tolerance in ((same_lines, 10.0), (other_lines, 30.0)):
        out = est.estimate(ds)
        ok = (out["status"] == Status.OK.value).to_numpy()
        err = out["payload_estimate"].to_numpy()[ok] - ds.frame["payload"].to_numpy()[ok]
        assert ok.mean() > 0.25
        assert np.abs(err).max() < tolerance  # kg, on a 5000 kg rated payload


def test_ramps_are_outside_the_map(clean_lifts):
    est = create_estimator("quasi-static", "cat345c").fit(clean_lifts)
    rows = next(clean_lifts.experiments())[1]
    out = est.estimate(clean_lifts.subset([0]))
    ramp = (rows["boom_rate"] < 4.5 * DEG).to_numpy()
    assert (out["status"].to_numpy()[ramp] == Status.OUT_OF_RANGE.value).all()
    assert est.calibration_speed == pytest.approx(5 * DEG, rel=1e-6)


def test_noisy_calibration_still_weighs_slow_lifts(noisy_lifts):
    est = create_estimator("quasi-static", "cat345c").fit(noisy_lifts)
    test = simulate_lifts(6, seed=3, noise="thesis", payloads=[1000.0, 2000.0, 4000.0])
    final = est.estimate(test).groupby("experiment")["payload_estimate"].last().to_numpy()
    assert np.abs(final - test.payloads).max() < 25.0


def test_biased_in_dynamic_motion(noisy_lifts, mj_dataset):
    quasi = create_estimator("quasi-static", "cat345c").fit(noisy_lifts)
    dynamic = create_estimator("inverse-dynamics", "cat345c").fit(mj_dataset)
    err_quasi = judged_errors(mj_dataset, quasi.estimate(mj_dataset))
    err_dynamic = judged_errors(mj_dataset, dynamic.estimate(mj_dataset))
    assert err_quasi["rms_kg"].mean() > 100.0
    assert err_dynamic["rms_kg"].mean() < 10.0


def test_fit_needs_lifts_at_two_reference_payloads(clean_lifts, mj_dataset):
    with pytest.raises(EstimatorError, match="lift"):
        create_estimator("quasi-static", "cat345c").fit(mj_dataset)
    one_level = clean_lifts.subset(clean_lifts.experiment_ids[0::2])
    with pytest.raises(EstimatorError, match="two reference payloads"):
        create_estimator("quasi-static", "cat345c").fit(one_level)
    three = simulate_lifts(6, payloads=[0.0, 2500.0, 5000.0], noise="none")
    with pytest.raises(EstimatorError, match="3 payload level"):
        create_estimator("quasi-static", "cat345c").fit(three)
    with pytest.raises(EstimatorError, match="grid-step"):
        create_estimator("quasi-static", "cat345c", grid_step=-1.0)


def test_save_load_round_trip_and_streaming(noisy_lifts, mj_dataset, tmp_path):
    est = create_estimator("quasi-static", "cat345c", grid_step=3.0).fit(noisy_lifts)
    est.save(tmp_path / "qs")
    loaded = load_estimator(tmp_path / "qs")
    assert isinstance(loaded, QuasiStaticEstimator)
    ds = mj_dataset.subset(mj_dataset.experiment_ids[:2])
    batch = est.estimate(ds)
    pd.testing.assert_frame_equal(loaded.estimate(ds), batch)
    rows = next(ds.experiments())[1]
    loaded.reset()
    streamed = [loaded.step(r).estimate for r in rows.to_dict("records")]
    np.testing.assert_array_equal(streamed, batch["payload_estimate"].to_numpy()[:len(rows)])


def test_cli_train_and_estimate(noisy_lifts, tmp_path):
    data = tmp_path / "lifts.parquet"
    write_dataset(noisy_lifts, data)
    assert main(["train", "quasi-static", "--data", str(data), "--out", str(tmp_path / "m"),
                 "--averaging", "none"]) == 0
    assert load_estimator(tmp_path / "m").options["averaging"] == "none"
    assert main(["estimate", "--model", str(tmp_path / "m"), "--data", str(data),
                 "--out", str(tmp_path / "e.parquet")]) == 0
    assert main(["train", "quasi-static", "--data", str(data), "--out", str(tmp_path / "x"),
                 "--averaging", "median"]) == 2


def test_speed_gate_uses_only_calibration_speed_samples(noisy_lifts, mj_dataset):
    est = create_estimator("quasi-static", "cat345c", speed_gate=True).fit(noisy_lifts)
    lifts = simulate_lifts(2, seed=7, noise="thesis", payloads=[3000.0])
    out = est.estimate(lifts)
    assert abs(out["payload_estimate"].iloc[-1] - 3000.0) < 25.0
    ramp_start = (lifts.frame["boom_rate"] < 4 * DEG).to_numpy() & (lifts.frame["time"] < 1).to_numpy()
    assert set(out["status"].to_numpy()[ramp_start]) <= {Status.NO_DATA.value, Status.OUT_OF_RANGE.value}
    dynamic = est.estimate(mj_dataset)
    assert (dynamic["status"] == Status.NO_DATA.value).mean() > 0.9  # min-jerk swings: hardly ever


def test_repeated_lifts_at_one_dipper_angle_are_averaged():
    cal = simulate_lifts(12, seed=8, noise="thesis", payloads=[0.0, 0.0, 5000.0, 5000.0])
    est = create_estimator("quasi-static", "cat345c").fit(cal)
    assert [len(d) for d in est.dipper_nodes] == [3, 3]
    test = simulate_lifts(3, seed=9, noise="thesis", payloads=[2000.0])
    final = est.estimate(test).groupby("experiment")["payload_estimate"].last().to_numpy()
    assert np.abs(final - 2000.0).max() < 60.0  # three dipper lines only: coarse map
