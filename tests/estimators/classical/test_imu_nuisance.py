"""calibrated --imu-nuisance on: the IMU lag and the house IMU's sensitivity re-estimated per
load while weighing (machine_calibration/imu_nuisance.py)."""

import copy
import pickle

import numpy as np
import pytest

from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.base import create_estimator, load_estimator
from excavator_payload.estimators.classical import calibrated_machine as cm
from excavator_payload.estimators.classical.machine_calibration.imu_nuisance import ImuNuisanceFilter
from excavator_payload.evaluation import demo_machine as dm
from excavator_payload.model.hydraulic import HydraulicArmModel
from excavator_payload.model.machine import load_machine
from ..._machine_data import swing_test_set

PRIOR = "cat345c-hydraulic-3pct"
LAG = len(cm.CALIBRATED_PARAMETERS) + len(cm.OFFSET_SIGNALS) + cm.IMU_PARAMETERS.index("imu_lag")


@pytest.fixture(scope="module")
def fitted(machine_calibration):
    """The momentum form calibrated on conftest's three swings (no cross-check, for time),
    zeroed, with --imu-nuisance off and on, and two test swings."""
    off = create_estimator("calibrated", PRIOR, balance="momentum", model_std="none",
                           imu_nuisance="off").fit(machine_calibration["cal"])
    off.zero(machine_calibration["zero"])
    on = copy.deepcopy(off)
    on.options["imu_nuisance"] = "on"
    on.use_calibration()
    return dict(off=off, on=on, test=swing_test_set(2, seed=7))


def _errors(est, ds):
    frame = est.estimate(ds)
    ok = (frame["status"].astype(str) == "ok").to_numpy()
    err = frame["payload_estimate"].to_numpy(float) - ds.frame["payload"].to_numpy(float)
    return err[ok], frame["sigma"].to_numpy(float)[ok]


def test_streams_what_it_estimates_and_survives_save_load_and_pickle(fitted, tmp_path):
    est, test = fitted["on"], fitted["test"]
    assert isinstance(est.kernel.regression._imu_nuisance, ImuNuisanceFilter)
    frame = est.estimate(test)
    batch = frame["payload_estimate"].to_numpy(float)
    f = test.frame
    first = f["experiment"].to_numpy() == f["experiment"].iloc[0]
    values = test.signals(est.sensor_set.signals)[first]
    est.reset()
    streamed = [est.step_values(t, v) for t, v in zip(f["time"].to_numpy()[first], values)]
    ok = np.isfinite(batch[first])
    assert ok.sum() > 100
    np.testing.assert_allclose(np.array([r.estimate for r in streamed])[ok], batch[first][ok], rtol=1e-9, atol=1e-6)
    np.testing.assert_allclose(np.array([r.sigma for r in streamed])[ok], frame["sigma"].to_numpy()[first][ok],
                               rtol=1e-9)
    again = load_estimator(est.save(tmp_path / "m"))
    assert again.options["imu_nuisance"] == "on"
    assert again.kernel.regression._imu_nuisance is not None
    np.testing.assert_array_equal(again.estimate(test)["payload_estimate"].to_numpy(), batch)
    copied = pickle.loads(pickle.dumps(est))
    np.testing.assert_array_equal(copied.estimate(test)["payload_estimate"].to_numpy(), batch)


def test_off_is_the_kernel_as_before_and_on_differs(fitted):
    off, on, test = fitted["off"], fitted["on"], fitted["test"]
    assert off.kernel.regression._imu_nuisance is None
    e_off = off.estimate(test)["payload_estimate"].to_numpy(float)
    e_on = on.estimate(test)["payload_estimate"].to_numpy(float)
    both = np.isfinite(e_off) & np.isfinite(e_on)
    assert both.sum() > 100
    assert np.max(np.abs(e_off[both] - e_on[both])) > 0.1  # the nuisances moved the payload
    # σ reads the payload's marginal variance: never below the held nuisances' one (the zero's
    # share beside it is each weighing's own sensitivity, which the nuisances change: compared
    # without it)
    def sensor_part(est):
        est.reset()
        f = test.frame
        part = []
        for t, v in zip(f["time"].to_numpy(float), test.signals(est.sensor_set.signals)):
            r = est.step_values(t, v)
            part.append(r.sigma**2 - est.kernel.extra_std**2)
        return np.array(part)

    s_off, s_on = sensor_part(copy.deepcopy(off)), sensor_part(copy.deepcopy(on))
    assert np.all(s_on[both] >= s_off[both] * (1 - 1e-9))


def test_a_mis_identified_lag_is_taken_back_while_weighing(fitted):
    """The lag set 25 ms off the calibration's, its prior spread widened to 10 ms: held, the
    weighing is off; re-estimated per load it comes back towards the truth."""
    est = {}
    for mode in ("off", "on"):
        e = copy.deepcopy(fitted["off"])
        e.options["imu_nuisance"] = mode
        e.calibration.z[LAG] += 0.025
        e.calibration.covariance[LAG, :] = e.calibration.covariance[:, LAG] = 0.0
        e.calibration.covariance[LAG, LAG] = 0.010**2
        e.use_calibration()
        est[mode] = e
    err_off, _ = _errors(est["off"], fitted["test"])
    err_on, _ = _errors(est["on"], fitted["test"])
    assert np.mean(np.abs(err_on)) < 0.7 * np.mean(np.abs(err_off))
    lag = est["on"].kernel.regression._imu_nuisance.nuisances(est["on"].calibration)[0]
    assert abs(lag - fitted["off"].calibration.z[LAG]) < 0.015  # pulled back from +25 ms


def _true_machine(est):
    """``est`` weighing with the simulator's own machine file, session offsets and IMU
    dynamics as its calibration (the fitted one's covariance kept as their spread)."""
    from excavator_payload.platforms import HYDRAULIC
    from excavator_payload.platforms.hydraulic import session_offsets

    est = copy.deepcopy(est)
    cal = est.calibration
    cal.arm = HydraulicArmModel(load_machine("cat345c-hydraulic"), compiled=False)
    cal.p_file = np.asarray(cal.arm.p, float)
    noise = HYDRAULIC.noise("field")
    offsets = session_offsets(dm.SESSION_WORK, noise)
    z = np.zeros_like(cal.z)
    n_delta = len(cm.CALIBRATED_PARAMETERS)
    z[n_delta:n_delta + len(cm.OFFSET_SIGNALS)] = [offsets[s] for s in cm.OFFSET_SIGNALS]
    k_link = noise.acceleration_leak * noise.link_imu_distance / 9.81
    z[LAG:] = [noise.imu_lag, k_link, k_link, k_link, noise.acceleration_leak * noise.house_imu_radius / 9.81]
    cal.z = z
    cal.zero_std = 0.0  # the true offsets, not a zero's: σ from the sensor noise only
    est.use_calibration(cal)
    return est


def test_with_the_true_machine_the_estimate_stays_within_sigma(fitted):
    """With the true machine the held form is biased by the momentum form's first-order lag
    correction (it prefers 6-7 ms on exact data to the true 10 ms: findings, nuisance-oracle):
    σ (sensor noise only here, no cross-check) covers few of its errors. Re-estimated, the lag
    settles near 7 ms, every final estimate is within 2σ and σ covers most samples."""
    test = fitted["test"]
    on, off = _true_machine(fitted["on"]), _true_machine(fitted["off"])
    err_off, sigma_off = _errors(off, test)
    err, sigma = _errors(on, test)
    assert len(err) > 100
    cover, cover_off = np.mean(np.abs(err) <= 2 * sigma), np.mean(np.abs(err_off) <= 2 * sigma_off)
    assert cover >= 0.7 and cover > cover_off + 0.3
    assert np.max(np.abs(err)) <= 0.01 * float(on.machine.rated_payload)
    frame, f = on.estimate(test), test.frame
    for e in f["experiment"].unique():
        rows = ((f["experiment"] == e) & (frame["status"].astype(str) == "ok")).to_numpy()
        final = frame["payload_estimate"].to_numpy()[rows][-1] - f["payload"].to_numpy()[rows][-1]
        assert abs(final) <= 2 * frame["sigma"].to_numpy()[rows][-1], e


def test_needs_the_momentum_form_and_refuses_a_bad_choice():
    with pytest.raises(EstimatorError, match="imu-nuisance"):
        create_estimator("calibrated", PRIOR, balance="differentiated", imu_nuisance="on")
    with pytest.raises(EstimatorError):
        create_estimator("calibrated", PRIOR, imu_nuisance="maybe")


def test_the_cli_refuses_a_bad_choice_in_one_line_and_exports_c(fitted, tmp_path, capsys):
    from excavator_payload.cli import main
    from excavator_payload.data.io import write_dataset

    data = tmp_path / "zero.parquet"
    write_dataset(dm.zero_data(seed=6), data)
    for extra in (["--imu-nuisance", "maybe"], ["--imu-nuisance", "on", "--balance", "differentiated"]):
        assert main(["train", "calibrated", "--data", str(data), "--out", str(tmp_path / "m"), *extra]) == 2
        err = capsys.readouterr().err.strip()
        assert "imu-nuisance" in err and len(err.splitlines()) == 1 and "Traceback" not in err
    model = fitted["on"].save(tmp_path / "on")
    assert main(["export", "--model", str(model), "--format", "c", "--out", str(tmp_path / "c")]) == 0
    assert "EP_NZ" in (tmp_path / "c" / "ep_calibrated.h").read_text()  # parity: tests/runtime


def test_auto_is_on_in_the_momentum_form_with_or_without_the_joint_check():
    """``--imu-nuisance auto`` (the default) re-estimates the IMU dynamics in the momentum form,
    with the joint check too (it judges the kernel's own sums; C for the two together:
    tests/runtime/test_export_c_imu_nuisance.py), not in the per-sample form; ``on``/``off`` say
    so explicitly."""
    from excavator_payload.estimators.classical.machine_calibration.weighing import imu_nuisance_on

    assert create_estimator("calibrated", PRIOR).options["imu_nuisance"] == "auto"
    assert imu_nuisance_on({"imu_nuisance": "auto", "joint_check": "off"}, "momentum")
    assert imu_nuisance_on({"imu_nuisance": "auto", "joint_check": "on"}, "momentum")
    assert imu_nuisance_on({"imu_nuisance": "on", "joint_check": "on"}, "momentum")
    assert not imu_nuisance_on({"imu_nuisance": "off", "joint_check": "on"}, "momentum")
    assert not imu_nuisance_on({"imu_nuisance": "auto"}, "differentiated")


def test_the_default_estimator_weighs_with_the_nuisances(fitted, machine_calibration):
    """A model fitted with the defaults carries the IMU-dynamics filter; told off, it does not."""
    default = create_estimator("calibrated", PRIOR, model_std="none").fit(machine_calibration["cal"])
    assert default.kernel.regression._imu_nuisance is not None
    assert fitted["off"].kernel.regression._imu_nuisance is None
