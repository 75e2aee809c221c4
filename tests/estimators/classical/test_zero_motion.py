"""The zero check says how good it is: a predicted weighing error from the posteriors, and a
refusal (CLI exit 2 unless --force) when the motion cannot determine the offsets or the zero
would weigh worse than 1 % of rated."""

import copy

import numpy as np
import pytest

from excavator_payload.estimators.base import create_estimator
from excavator_payload.estimators.classical import calibrated_machine as cm
from excavator_payload.estimators.classical import zero_quality as zq
from excavator_payload.evaluation import demo_machine as dm
from excavator_payload.simulation.machine_sensors import get_machine_noise, session_offsets

PRIOR = "cat345c-hydraulic-3pct"


@pytest.fixture(scope="module")
def setup():
    """4 calibration swings (session 1), the calibrated estimator, an empty swing and the same
    swing with the dipper and bucket held still (session 2)."""
    # model_std none: the quality statement does not use the cross-check, which fits twice more
    cal = create_estimator("calibrated", PRIOR, model_std="none").fit(dm.calibration_data(4, seed=5))
    table = dm.motion_trajectory(1, 6, (0.0,))
    swing = dm.simulate_trajectory(table, 6, dm.SESSION_WORK)
    for column in ("dipper_angle", "bucket_angle"):
        table[column] = table[column].iloc[0]
    boom_only = dm.simulate_trajectory(table, 6, dm.SESSION_WORK)
    return dict(calibrated=cal, swing=swing, boom_only=boom_only)


def test_a_zero_motion_that_leaves_cylinders_still_is_refused_by_name(setup):
    """Dipper and bucket held still: their force offsets keep the prior (posterior / prior std
    1), the refusal names both and says how to move them, and the predicted error is beyond 1 %
    of rated; the empty swing determines every cylinder (posterior / prior std below 0.2)."""
    est = copy.deepcopy(setup["calibrated"])
    est.zero(setup["boom_only"])
    determined = est.zero_quality.determined
    assert determined[0] < 0.2 and np.all(determined[1:] > 0.9)
    reasons = " ".join(est.zero_refusals)
    assert "dipper and bucket" in reasons and "up and down" in reasons
    assert est.zero_quality.predicted_error > 50.0
    good = copy.deepcopy(setup["calibrated"])
    good.zero(setup["swing"])
    assert np.all(good.zero_quality.determined < 0.2)
    assert "predicted weighing error" in good.zero_report[0]


def test_the_predicted_error_covers_what_the_offsets_do_to_the_weighing(setup):
    """The true offsets of the zero's session are known to the simulator: the weighing error
    the zeroed offsets leave against them (the calibration's offsets plus the true drift), at
    the calibrated poses, lies within the predicted 95 % error; and the prediction's own part
    (the zero's noise) is smaller than its total."""
    est = copy.deepcopy(setup["calibrated"])
    before = est.calibration.offsets.copy()
    est.zero(setup["swing"])
    noise = get_machine_noise("field")
    drift = np.array([session_offsets(dm.SESSION_WORK, noise)[s] - session_offsets(dm.SESSION_CALIBRATION, noise)[s]
                      for s in cm.OFFSET_SIGNALS])
    g = zq.weighing_sensitivity(est.calibration)
    bias = g @ (est.calibration.offsets - (before + drift))
    q = est.zero_quality
    assert 2 * np.sqrt(np.mean(bias**2)) <= q.predicted_error
    assert q.offset_part < q.predicted_error / 2


def test_weighing_sensitivity_is_the_estimates_change(setup):
    """g·δo is the change of the static estimate Σwφr/Σwφ² when an offset moves by δo
    (finite difference on the symbolic model's residuals; the angle enters non-linearly)."""
    cal = copy.deepcopy(setup["calibrated"].calibration)
    poses = zq.grid_poses(cal, 3)
    g = zq.weighing_sensitivity(cal, poses, payloads=(2500.0,))
    values = zq._static_samples(cal, poses, 2500.0)
    n = len(cm.CALIBRATED_PARAMETERS)

    def estimate(z):
        r, _, lever, _, _ = cal.evaluate(values, np.zeros((len(poses), 4)), np.full(len(poses), 2500.0), z)
        phi = -cal._payload_sensitivity
        w = 1.0 / (lever**2 * (cal._head**2 + cal._rod**2))
        return np.sum(w * phi * r, axis=1) / np.sum(w * phi**2, axis=1)

    for k, step in ((0, 1.0e5), (6, np.radians(0.1)), (9, np.radians(0.1))):  # boom head, boom angle, pitch
        z = cal.z.copy()
        z[n + k] += step
        np.testing.assert_allclose(estimate(z) - estimate(cal.z), g[:, k] * step, rtol=0.05, atol=0.2)


def test_cli_refuses_with_exit_2_and_saves_with_force(setup, tmp_path, capsys):
    """excavator-payload zero: a refused zero is one error line, exit 2, nothing saved; --force
    saves it and repeats the reasons as warnings; the accepted zero prints its predicted error."""
    from excavator_payload.cli import main
    from excavator_payload.data.io import write_dataset

    setup["calibrated"].save(tmp_path / "model")
    write_dataset(setup["boom_only"], tmp_path / "boom.parquet")
    write_dataset(setup["swing"], tmp_path / "swing.parquet")
    args = ["zero", "--model", str(tmp_path / "model"), "--data"]
    assert main([*args, str(tmp_path / "boom.parquet"), "--out", str(tmp_path / "z1")]) == 2
    err = capsys.readouterr().err
    assert err.count("error:") == 1 and "zero refused" in err and "--force" in err
    assert not (tmp_path / "z1").exists()
    assert main([*args, str(tmp_path / "boom.parquet"), "--out", str(tmp_path / "z2"), "--force"]) == 0
    out = capsys.readouterr()
    assert "(saved: --force)" in out.err and (tmp_path / "z2" / "estimator.json").exists()
    assert main([*args, str(tmp_path / "swing.parquet"), "--out", str(tmp_path / "z3")]) == 0
    assert "predicted weighing error" in capsys.readouterr().out


def test_sigma_carries_the_zeros_offsets_and_keeps_them_through_save(setup, tmp_path):
    """After a zero every estimate's σ² holds the zero's offsets posterior as that estimate
    weighs (its own sensitivity, machine_calibration/offset_share.py; below the RMS over the
    calibrated poses, ``zero_quality.offset_part``) beside 1/I and the cross-checked s; before a
    zero it does not; a saved and loaded model weighs with the same σ to the bit."""
    from excavator_payload.estimators import load_estimator

    est = copy.deepcopy(setup["calibrated"])
    test = dm.simulate_trajectory(dm.motion_trajectory(1, 7, (2500.0,)), 7, dm.SESSION_WORK)
    assert est.kernel.model_std == est.calibration.model_std == 0.0  # model_std none: noise only
    assert est.kernel.regression._offset_share is None
    est.zero(setup["swing"])
    part = est.zero_quality.offset_part
    assert part > 0 and est.kernel.model_std == 0.0  # the zero's part is per estimate, not a constant
    after = est.estimate(test)
    ok = (after["status"] == "ok").to_numpy()
    assert ok.sum() > 100
    # the same estimates without the zero's part: σ² - σ_noise² is the share, positive everywhere
    noise_only = copy.deepcopy(est)
    noise_only.calibration.zero_std = 0.0
    noise_only.use_calibration()
    plain = noise_only.estimate(test)
    np.testing.assert_array_equal(plain["payload_estimate"].to_numpy(), after["payload_estimate"].to_numpy())
    sigma, noise = after["sigma"].to_numpy(float)[ok], plain["sigma"].to_numpy(float)[ok]
    share = np.sqrt(sigma**2 - noise**2)
    assert np.all(share > 0) and np.median(share) < part
    est.save(tmp_path / "zeroed")
    again = load_estimator(tmp_path / "zeroed")
    assert again.calibration.zero_std == est.calibration.zero_std
    np.testing.assert_array_equal(again.estimate(test)["sigma"].to_numpy(float), after["sigma"].to_numpy(float))
