"""calibrated on the machine sensor set, momentum form: its windows and balance, where it weighs
and waits, the IMUs' leaks read off their own signals, and the joint check naming a pressure offset."""

import copy

import numpy as np
import pytest

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.schema import MACHINE_SENSORS
from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.base import create_estimator, load_estimator
from excavator_payload.estimators.status import Status
from excavator_payload.estimators.classical import calibrated_machine as cm
from excavator_payload.estimators.classical.pressure_regression import LOOK_AHEAD
from excavator_payload.evaluation import demo_machine as dm
from excavator_payload.model.hydraulic import HydraulicArmModel
from excavator_payload.model.machine import load_machine
from ..._machine_data import mean_abs_error

PRIOR = "cat345c-hydraulic-3pct"


def test_momentum_calibration_holds_where_the_arm_stands_on_the_house(momentum):
    """The boom foot's position relative to the slew axis stays at the file's (moving it with
    the boom cylinder's base is invisible in the arm's balance but for slewing's centrifugal
    terms, and the fit used it to absorb what it cannot model); the cylinder base, which sets
    the boom's moment arm, is still calibrated."""
    cal = momentum.calibration
    k = len(cm.CALIBRATED_PARAMETERS)
    sd = np.sqrt(np.diag(cal.covariance))[:k]
    for name in cm.HELD_IN_MOMENTUM:
        i = cm.CALIBRATED_PARAMETERS.index(name)
        assert cal.z[i] == 0.0 and sd[i] == pytest.approx(0.05), name
    base = cm.CALIBRATED_PARAMETERS.index("boom_cylinder_parent_x")
    assert cal.z[base] != 0.0 and sd[base] < 0.05


def test_momentum_balance_weighs_and_streams_as_it_estimates(momentum, setup, tmp_path):
    """--balance momentum: calibrated and zeroed in that form, it weighs the test swings better
    than the uncalibrated file, streams what it estimates in batch, and survives save/load."""
    est = momentum
    assert est.calibration.balance == "momentum"
    test = setup["test"]
    batch = est.estimate(test)["payload_estimate"].to_numpy()
    uncalibrated = copy.deepcopy(est)
    uncalibrated.calibration.z[:len(cm.CALIBRATED_PARAMETERS)] = 0.0
    # the file's joints disagree with one another: the joint check names their cylinders and
    # weighs nothing (NaN) once a joint weighed alone is ok; the weighing itself is compared here
    uncalibrated.options["joint_check"] = "off"
    uncalibrated.use_calibration()
    assert mean_abs_error(est, test) < mean_abs_error(uncalibrated, test)
    f = test.frame
    first = f["experiment"].to_numpy() == f["experiment"].iloc[0]
    values = test.signals(est.sensor_set.signals)[first]
    est.reset()
    streamed = np.array([est.step_values(t, v).estimate for t, v in zip(f["time"].to_numpy()[first], values)])
    ok = np.isfinite(batch[first])
    assert ok.sum() > 100
    np.testing.assert_allclose(streamed[ok], batch[first][ok], rtol=1e-9, atol=1e-6)
    est.save(tmp_path / "m")
    again = load_estimator(tmp_path / "m")
    assert again.options["balance"] == "momentum" and again.calibration.balance == "momentum"
    np.testing.assert_allclose(again.estimate(test)["payload_estimate"].to_numpy(), batch, rtol=1e-12,
                               equal_nan=True)


def test_momentum_calibration_weighs_its_windows_by_what_the_model_leaves(momentum, setup, tmp_path):
    """The calibration measures, at the identified machine, how much larger each joint's
    window residual is than the noise model says (a variance component, ≥ 1), fits again with
    the windows weighted by it, keeps it through save/load, and refuses a saved one below 1."""
    cal = momentum.calibration
    f = cal.window_inflation
    assert f.shape == (3,) and np.all(f >= 1.0)
    values, qdd, payload, runs = cm.calibration_arrays(setup["cal"], cm.CALIBRATION_HALF_WINDOW,
                                                       cal.arm.machine)
    # a machine the data do not fit leaves more than the noise model: the component grows
    wrong = copy.deepcopy(cal)
    wrong.z = cal.z.copy()
    wrong.z[cm.CALIBRATED_PARAMETERS.index("boom_mass")] += 0.1
    assert wrong.measure_window_inflation(values, qdd, payload, runs)[0] > 1.5
    first = copy.deepcopy(cal)
    first.window_inflation = np.ones(3)
    # the first fit as calibrate makes it: from the prior, the links' IMU leak held at what
    # their own signals say, the boom foot held (HELD_IN_MOMENTUM)
    n = len(cm.CALIBRATED_PARAMETERS) + len(cm.OFFSET_SIGNALS) + 1
    prior_mean = np.zeros(len(first.z))
    prior_mean[n:n + 3] = cal.z[n:n + 3]
    first.z = prior_mean.copy()
    free = np.setdiff1d(np.arange(n), [cm.CALIBRATED_PARAMETERS.index(p) for p in cm.HELD_IN_MOMENTUM])
    std = first.prior_std(0.05)
    first.solve(values, qdd, payload, free, prior_mean, std, "downweight",
                estimate_noise=False, runs=runs)
    # the measured inflation is that of the unweighted fit's residuals, not a constant
    np.testing.assert_allclose(first.measure_window_inflation(values, qdd, payload, runs), f, rtol=1e-6)
    momentum.save(tmp_path / "m")
    np.testing.assert_array_equal(load_estimator(tmp_path / "m").calibration.window_inflation, f)
    arrays = dict(np.load(tmp_path / "m" / "arrays.npz"))
    arrays["window_inflation"] = np.array([0.5, 1.0, 1.0])
    np.savez(tmp_path / "m" / "arrays.npz", **arrays)
    with pytest.raises(EstimatorError, match="corrupt"):
        load_estimator(tmp_path / "m")


def test_momentum_windows_jacobian_is_that_of_their_residual_at_the_known_payload(setup):
    """The momentum calibration's Jacobian equals finite differences of its window residuals
    on a loaded motion: r = r0(z) - m·φ(z), so the payload's lever enters through m·∂φ/∂z.
    (Taken at payload 0 it left the load's position in the bucket without any information and
    the boom length's sensitivity 44 % short on a 4.1-t swing: the fit stopped where that
    wrong gradient vanished, not at the optimum.)"""
    cal = cm.MachineCalibration(HydraulicArmModel(load_machine(PRIOR)))
    ds = setup["cal"]
    loaded = ds.subset([e for e, g in ds.frame.groupby("experiment") if g["payload"].iloc[0] > 0][:1])
    values, qdd, payload, runs = cm.calibration_arrays(loaded, cm.CALIBRATION_HALF_WINDOW, cal.arm.machine)
    assert payload.min() > 0
    z = cal.z.copy()
    r, J, *_ = cal.evaluate_windows(values, qdd, payload, z, runs)
    for name in ("payload_u", "payload_w", "boom_length", "bucket_mass", "bucket_cylinder_parent_u"):
        k = cm.CALIBRATED_PARAMETERS.index(name)
        h = 1e-6
        dz = np.zeros_like(z)
        dz[k] = h
        r2 = cal.evaluate_windows(values, qdd, payload, z + dz, runs)[0]
        fd = (r2 - r) / h
        ok = np.isfinite(fd) & np.isfinite(J[:, :, k])
        scale = np.abs(fd[ok]).max()
        assert scale > 0, name
        np.testing.assert_allclose(J[:, :, k][ok], fd[ok], rtol=1e-3, atol=1e-4 * scale, err_msg=name)


def test_momentum_windows_noise_model_explains_the_true_machine(setup):
    """At the true machine, offsets and IMU dynamics, the windows' noise model accounts for
    what is left of the field-noise calibration data: actual / modelled variance near 1 per
    joint. (Counting a standstill's friction once per overlapping window and leaving out the
    rates' noise through the integrand, it was 13-90 on these three swings.)"""
    from excavator_payload.simulation.machine_sensors import get_machine_noise, session_offsets

    ds = setup["cal"]
    cal = cm.MachineCalibration(HydraulicArmModel(load_machine("cat345c-hydraulic")))
    cal.rate_var = cm.rate_variance(ds)
    cal.pressure_std = cm.pressure_noise_from_data(ds)
    noise = get_machine_noise("field")
    offsets = session_offsets(dm.SESSION_CALIBRATION, noise)
    n_delta, n_off = len(cm.CALIBRATED_PARAMETERS), len(cm.OFFSET_SIGNALS)
    cal.z[n_delta:n_delta + n_off] = [offsets[s] for s in cm.OFFSET_SIGNALS]
    leak = noise.acceleration_leak / 9.81
    cal.z[n_delta + n_off:] = [noise.imu_lag, *[leak * noise.link_imu_distance] * 3, leak * noise.house_imu_radius]
    values, qdd, payload, runs = cm.calibration_arrays(ds, cm.CALIBRATION_HALF_WINDOW, cal.arm.machine)
    f = cal.measure_window_inflation(values, qdd, payload, runs)
    assert np.all(f < 3.0), f


def test_momentum_balance_windows_are_exact_on_a_quadratic_momentum():
    """The window residual is the weighted momentum balance, trapezoid rule: with the integrand
    I0 changing linearly in time and P0 its exact integral the residual vanishes, whatever the
    ramp (a left rectangle rule would leave half a sample's change of I0)."""
    n, dt = 80, 0.01
    A = np.zeros((n, 12))
    t = np.arange(n)[:, None] * dt
    rate, change = np.array([3.0, -2.0, 0.5]), np.array([40.0, 15.0, -8.0])
    A[:, 6:9] = rate + change * t
    A[:, 0:3] = rate * t + change * t**2 / 2
    centres = cm.momentum_windows(np.zeros(n, int), 10)
    for ramp in (1, 4):
        r, minus_phi = cm.window_residuals(A, np.zeros(n), centres, 10, dt, ramp)
        np.testing.assert_allclose(r, 0.0, atol=1e-12)
    # no window across a break between runs (a dropped sample, another experiment)
    np.testing.assert_array_equal(cm.momentum_windows(np.r_[np.zeros(30, int), np.ones(50, int)], 10),
                                  np.r_[10:20, 40:70])


def test_nmpc_swings_are_continuous_so_the_trapezoid_closes_the_balance():
    """The NMPC simulator's forces reach the joints through a lag, so the momentum balance per
    sample interval closes by the trapezoid rule (noise-free, true machine). With forces held
    over each control period (the simulator before the lag) the trapezoid was 10× worse than a
    left rectangle rule on the boom; now it is several times better on every joint."""
    from excavator_payload.simulation.generate import simulate_dataset

    ds = simulate_dataset(2, seed=607, machine="cat345c-hydraulic", motion="nmpc", noise="none",
                          with_truth=True, workers=1, progress=False)
    cal = cm.MachineCalibration(HydraulicArmModel(load_machine("cat345c-hydraulic")))
    v, qdd, payload, runs = cm.calibration_arrays(ds, cm.CALIBRATION_HALF_WINDOW, cal.arm.machine)
    n = len(v)
    sign = cm.held_direction(cal.rod_speeds(v), runs, np.full(3, 0.01))
    out = cm.momentum_function().map(n, "serial")(v.T, qdd.T, np.repeat(cal.p_file[:, None], n, 1),
                                                  np.repeat(cal.z[:, None], n, 1), sign.T)
    A, speed = np.asarray(out[0]).T, np.abs(np.asarray(out[3]).T)
    momentum = A[:, 0:3] + payload[:, None] * A[:, 3:6]
    integrand = A[:, 6:9] + payload[:, None] * A[:, 9:12]
    still = 3 * np.array([c.stribeck_velocity for c in cal.arm.machine.cylinders])
    moving = (runs[1:] == runs[:-1])[:, None] & (speed[1:] > still) & (speed[:-1] > still)
    change = np.diff(momentum, axis=0) / 0.01
    for rule, estimate in (("left", integrand[:-1]), ("trapezoid", 0.5 * (integrand[:-1] + integrand[1:]))):
        error = change - estimate
        rms = [np.sqrt(np.mean(error[moving[:, j], j] ** 2)) for j in range(3)]
        if rule == "left":
            left = np.array(rms)
        else:
            assert np.all(np.array(rms) < left / 3), (rms, left)


def test_held_direction_keeps_the_last_sliding_sign_per_run():
    """A still cylinder's friction sign is that of its last sliding; unknown (0) until a run's
    first sliding; every run starts afresh."""
    speed = np.array([[0.0, 0.05, 0.0], [0.02, 0.001, -0.02], [0.001, -0.001, 0.0], [-0.03, 0.0, 0.0],
                      [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    runs = np.array([0, 0, 0, 0, 0, 1])
    np.testing.assert_array_equal(cm.held_direction(speed, runs, np.full(3, 0.01)),
                                  [[0, 1, 0], [1, 1, -1], [1, 1, -1], [-1, 1, -1], [-1, 1, -1], [0, 0, 0]])


def test_a_long_standstill_is_balanced_by_unknown_friction_not_the_last_direction():
    """Noise-free calibration motions at the true machine, whose seals at rest hold whatever
    friction the closing valve left (anywhere within ± breakaway): windows centred on a long
    standstill (beyond HELD_SAMPLES) balance better with the friction unknown (mean 0, the
    windows' standstill variance) than with ± breakaway of the last sliding direction held for
    good (the rule the simulator and the calibration shared before)."""
    from excavator_payload.simulation.generate import simulate_dataset
    from excavator_payload.simulation.trajectory import trajectory_from_frame

    traj = trajectory_from_frame(dm.motion_trajectory(3, 7, dm.calibration_payloads()))
    ds = simulate_dataset(3, seed=7, motion="trajectory", trajectory=traj, session=1, noise="none",
                          with_truth=True, workers=1, progress=False, machine="cat345c-hydraulic")
    cal = cm.MachineCalibration(HydraulicArmModel(load_machine("cat345c-hydraulic")))
    v, qdd, payload, runs = cm.calibration_arrays(ds, cm.CALIBRATION_HALF_WINDOW, cal.arm.machine)
    speed = cal.rod_speeds(v)
    unknown, *_, centres = cal.evaluate_windows(v, qdd, payload, cal.z, runs)
    forever = cm.held_direction(speed, runs, cal._stribeck, held=10**9)
    old = cm.momentum_function().map(len(v), "serial")(
        v.T, qdd.T, np.repeat(cal.p_file[:, None], len(v), 1), np.repeat(cal.z[:, None], len(v), 1), forever.T)
    old_residual, _ = cm.window_residuals(np.asarray(old[0]).T, payload, centres,
                                          cm.BALANCE_HALF_WINDOW, 0.01, cm.BALANCE_RAMP)
    sign = cm.held_direction(speed, runs, cal._stribeck)
    long_still = ((sign == 0) & (forever != 0))[centres]
    for j in range(3):
        assert long_still[:, j].sum() > 50
        rms_unknown = np.sqrt(np.mean(unknown[long_still[:, j], j] ** 2))
        rms_held = np.sqrt(np.mean(old_residual[long_still[:, j], j] ** 2))
        assert rms_unknown < rms_held, (j, rms_unknown, rms_held)


def test_momentum_balance_rejects_a_glitch_and_keeps_its_interval(momentum, setup):
    """In the momentum form a rejected frame's repaired slot stays in the balance (its interval
    belongs to the integral) but is never regressed: the estimate hardly moves."""
    test = setup["test"]
    clean = momentum.estimate(test)
    frame = test.frame.copy()
    # a frame 3 s or more into each experiment where the estimate is already reported (the
    # momentum form waits for the boom: before, every status is warming_up)
    ok = (frame.groupby("experiment").cumcount() >= 300).to_numpy() & (clean["status"].astype(str) == "ok").to_numpy()
    hit = frame.index[ok].to_series().groupby(frame["experiment"].to_numpy()[ok]).first().to_numpy()
    assert len(hit) == frame["experiment"].nunique()
    frame.loc[hit, "boom_head_pressure"] += 3e6
    glitched = momentum.estimate(Dataset(frame, test.meta))
    status = glitched["status"].astype(str).to_numpy()
    assert np.all(status[hit + LOOK_AHEAD] == "rejected_outlier")
    last = frame.groupby("experiment").tail(1).index
    change = np.abs(glitched["payload_estimate"].to_numpy()[last] - clean["payload_estimate"].to_numpy()[last])
    assert np.all(change < 1.0)


def test_outside_calibration_arm_weighs_no_joint_while_any_is_outside(momentum, setup):
    """--outside-calibration arm: with the dipper's covered range narrowed, a sample whose dipper
    lies outside it gives no joint weight (skip would weigh all three there), the estimate
    differs from skip's, and the note names the arm and the angle reached."""
    from excavator_payload.estimators.classical.pressure_regression import ANGLES

    test = setup["test"]
    dipper = test.frame["dipper_angle"].to_numpy(float)
    offset = momentum.calibration.offset_vector()[ANGLES[1]]
    ests = {}
    for mode in ("skip", "arm"):
        est = copy.deepcopy(momentum)
        est.options["outside_calibration"] = mode
        est.calibration.angle_coverage[1] = (np.median(dipper) - offset, np.radians(60))
        est.use_calibration()
        ests[mode] = est
    sample = test.frame.iloc[int(np.argmin(dipper))][list(cm.SIGNALS)].to_numpy(float)
    assert not ests["arm"].kernel.regression._inside(sample).any()
    assert ests["skip"].kernel.regression._inside(sample).tolist() == [True, True, True]
    a, b = (ests[m].estimate(test)["payload_estimate"].to_numpy() for m in ("skip", "arm"))
    assert not np.array_equal(a, b, equal_nan=True)
    notes = ests["arm"].estimate_notes(test)
    assert any("dipper angle lay outside" in n and "the arm is not weighed" in n and "it reached" in n
               for n in notes), notes
    # skip weighs the dipper there all the same: the note says it extrapolated, not that it skipped
    skip_notes = [n for n in ests["skip"].estimate_notes(test) if "dipper" in n]
    assert len(skip_notes) == 1 and "weighed there by extrapolation" in skip_notes[0], skip_notes
    assert "not weighed" not in skip_notes[0]


def test_calibration_records_the_angles_it_covered_and_weighing_keeps_inside(momentum, setup, tmp_path, capsys):
    """fit records the boom, dipper and bucket angle range of the calibration motions (offsets
    removed, 0.5-99.5 percentiles ± 5°); the momentum form does not weigh a joint outside it
    (auto = skip), the per-sample form does (auto = use); the range survives save/load, and a
    model saved without it weighs with no limit."""
    cov = momentum.calibration.angle_coverage
    angles = setup["cal"].frame[["boom_angle", "dipper_angle", "bucket_angle"]].to_numpy(float)
    assert np.all(cov[:, 0] < angles.min(axis=0)) and np.all(cov[:, 1] > angles.max(axis=0))
    assert np.all(cov[:, 0] > angles.min(axis=0) - np.radians(6))  # 5° margin, not more
    assert momentum.kernel.regression.outside_calibration == "skip"
    assert setup["zeroed"].kernel.regression.outside_calibration == "use"
    test = setup["test"]
    # a test experiment's bucket leaves a narrowed range: its windows are not weighed then
    narrow = copy.deepcopy(momentum)
    bucket = test.frame["bucket_angle"].to_numpy(float)
    narrow.calibration.angle_coverage[2] = (np.median(bucket), cov[2, 1])
    narrow.use_calibration()
    a = momentum.estimate(test)["payload_estimate"].to_numpy()
    b = narrow.estimate(test)["payload_estimate"].to_numpy()
    ok = np.isfinite(a) & np.isfinite(b)
    assert np.abs(a[ok] - b[ok]).max() > 0.5
    def unlimited(est):  # --outside-calibration use: every angle weighed
        est = copy.deepcopy(est)
        est.options["outside_calibration"] = "use"
        est.use_calibration()
        return est.estimate(test)["payload_estimate"].to_numpy()

    everywhere = unlimited(momentum)
    np.testing.assert_allclose(unlimited(narrow), everywhere, rtol=1e-12, equal_nan=True)
    notes = narrow.estimate_notes(test)
    bucket_notes = [n for n in notes if "bucket angle" in n]
    assert len(bucket_notes) == 1 and "lay outside" in bucket_notes[0] and "--outside-calibration use" in bucket_notes[0]
    # the boom and dipper are weighed outside the (small) test calibration's range: said, not skipped
    assert all("weighed there by extrapolation" in n for n in notes if n not in bucket_notes), notes
    narrow.save(tmp_path / "n")
    from excavator_payload.cli import main
    from excavator_payload.data.io import write_dataset

    write_dataset(test, tmp_path / "test.parquet")
    capsys.readouterr()
    assert main(["estimate", "--model", str(tmp_path / "n"), "--data", str(tmp_path / "test.parquet"),
                 "--out", str(tmp_path / "e.parquet"), "--quiet"]) == 0
    assert "note: calibrated: the bucket angle lay outside" in " ".join(capsys.readouterr().out.split())
    again = load_estimator(tmp_path / "n")
    np.testing.assert_array_equal(again.calibration.angle_coverage, narrow.calibration.angle_coverage)
    np.testing.assert_allclose(again.estimate(test)["payload_estimate"].to_numpy(), b, rtol=1e-12, equal_nan=True)
    # a model saved before the coverage existed: no limit
    saved = narrow.kernel.arrays()
    del saved["angle_coverage"]
    old = copy.deepcopy(narrow)
    old._restore(narrow.kernel.config(), saved)
    assert np.all(np.abs(old.calibration.angle_coverage) == cm.NO_LIMIT) and old.estimate_notes(test) == []
    np.testing.assert_allclose(old.estimate(test)["payload_estimate"].to_numpy(), everywhere, rtol=1e-12,
                               equal_nan=True)
    saved["angle_coverage"] = np.array([[0.0, -1.0]] * 3)  # low above high: corrupt
    with pytest.raises(EstimatorError, match="corrupt"):
        old._restore(narrow.kernel.config(), saved)


def test_momentum_form_waits_for_the_boom_before_it_reports(momentum, setup):
    """--wait-for-boom (auto = yes in the momentum form): no estimate (NaN, warming_up) until a
    window has weighed the boom; the information gathered meanwhile is kept, so from then on the
    estimate is the one that reporting at once (no) gives."""
    test = setup["test"]
    assert momentum.kernel.regression.wait_for_boom and not setup["zeroed"].kernel.regression.wait_for_boom
    waiting = momentum.estimate(test)
    at_once = copy.deepcopy(momentum)
    at_once.options["wait_for_boom"] = "no"
    at_once.use_calibration()
    eager = at_once.estimate(test)
    w, e = waiting["payload_estimate"].to_numpy(), eager["payload_estimate"].to_numpy()
    assert np.isfinite(e).sum() > np.isfinite(w).sum()  # it waited somewhere
    both = np.isfinite(w)
    np.testing.assert_allclose(w[both], e[both], rtol=1e-12)
    assert set(waiting["status"].astype(str)[np.isfinite(e) & ~both]) == {"warming_up"}
    # it waited for the boom: the boom's rate was small before its first estimate
    f = test.frame
    for _, rows in f.groupby("experiment").groups.items():
        first = rows[np.isfinite(w[rows])][0]
        assert np.abs(f.loc[rows[0]:first, "boom_rate"]).max() > np.radians(1.0)
    with pytest.raises(EstimatorError, match="wait-for-boom"):
        type(momentum)(PRIOR, wait_for_boom="maybe")


def test_momentum_form_reports_a_weight_once_it_holds_still(momentum, setup):
    """After the boom's windows, the first estimate reported is one that moved by at most
    STEADY_SHARE of rated over the last STEADY_WINDOWS windows; before, warming_up. A new load
    (the weighing restarts) waits for it again."""
    from excavator_payload.estimators.classical.machine_calibration.settings import STEADY_SHARE, STEADY_WINDOWS

    test = setup["test"]
    est = copy.deepcopy(momentum)
    est.reset()
    regression = est.kernel.regression
    limit = STEADY_SHARE * est.rated_payload
    f = test.frame[test.frame["experiment"] == test.experiment_ids[0]]
    signals = f[list(test.sensor_set.signals)].to_numpy(float)
    history, first_ok = [], None
    for k, (t, values) in enumerate(zip(f["time"].to_numpy(float), signals)):
        result = est.step_values(t, values)
        if regression.ready and regression.info > 0.0:
            history.append(regression.num / regression.info)
        if result.status is Status.OK and first_ok is None:
            first_ok = k
            assert len(history) > STEADY_WINDOWS  # it waited beyond the boom's windows
            assert abs(history[-1] - history[-1 - STEADY_WINDOWS]) <= limit
            # and no earlier estimate of the ready weighing held still that long
            assert all(abs(history[i] - history[i - STEADY_WINDOWS]) > limit
                       for i in range(STEADY_WINDOWS, len(history) - 1))
        if first_ok is None:
            assert result.status is not Status.OK
    assert first_ok is not None and regression.steady
    # a restart (a new load) clears it: no ok until the boom is weighed and the estimate holds again
    regression.num = regression.info = 0.0
    regression.boom_windows = 0
    regression._restart_steady()
    assert not regression.steady
    assert est.step_values(f["time"].to_numpy(float)[-1] + 0.01, signals[-1]).status is not Status.OK


def test_estimate_says_why_a_motion_without_boom_motion_got_no_estimate(momentum, setup, tmp_path, capsys):
    """A motion whose boom stands still is never weighed by the momentum form (--wait-for-boom):
    `estimate` says so in a note naming the experiments and the way out, instead of leaving a
    column of NaN that looks like a broken sensor; motions that move the boom get no such note."""
    table = dm.motion_trajectory(1, 6, (2500.0,))
    table["boom_angle"] = table["boom_angle"].iloc[0]
    still_boom = dm.simulate_trajectory(table, 6, dm.SESSION_WORK)
    frame = momentum.estimate(still_boom)
    assert not np.isfinite(frame["payload_estimate"]).any()
    def waiting(est, ds):
        return [n for n in est.estimate_notes(ds, est.estimate(ds)) if "no estimate in" in n]

    notes = waiting(momentum, still_boom)
    assert len(notes) == 1 and "no estimate in 1 of 1 experiments" in notes[0]
    assert "--wait-for-boom no" in notes[0] and "stiction band (boom rod" in notes[0]
    assert waiting(momentum, setup["test"]) == []
    # the per-sample form reports at once: nothing to say
    assert waiting(setup["zeroed"], still_boom) == []
    from excavator_payload.cli import main
    from excavator_payload.data.io import write_dataset

    momentum.save(tmp_path / "m")
    write_dataset(still_boom, tmp_path / "still.parquet")
    capsys.readouterr()
    assert main(["estimate", "--model", str(tmp_path / "m"), "--data", str(tmp_path / "still.parquet"),
                 "--out", str(tmp_path / "e.parquet"), "--quiet"]) == 0
    assert "note: calibrated: no estimate in 1 of 1 experiments" in " ".join(capsys.readouterr().out.split())


def test_imu_leak_is_read_off_the_imus_own_signals(setup):
    """Angle minus integrated rate shows a link IMU's acceleration leak alone: the simulator's
    k = leak · distance / g is found on three calibration swings, and neither a further output
    lag on both signals nor new offsets and a gyro bias change it."""
    from excavator_payload.simulation.machine_sensors import get_machine_noise
    from scipy.signal import lfilter

    field = get_machine_noise("field")
    truth = field.acceleration_leak * field.link_imu_distance / 9.81
    k, std = cm.imu_sensitivities(setup["cal"])
    assert np.all(std > 0) and np.all(std < 0.1 * truth)
    assert np.allclose(k, truth, rtol=0.2)
    assert np.allclose(k[1:], truth, rtol=0.05)
    frame = setup["cal"].frame.copy()
    columns = [cm.SIGNALS[i] for i in (*cm.ANGLES, *cm.RATES[:3])]
    a = np.exp(-0.01 / 0.02)  # a 20 ms first-order lag more, on angles and rates alike
    for _, rows in frame.groupby("experiment").groups.items():
        x = frame.loc[rows, columns].to_numpy(float)
        frame.loc[rows, columns] = lfilter([1 - a], [1, -a], x, axis=0, zi=x[:1] * a)[0]
    frame[columns[:3]] += [0.003, -0.002, 0.004]
    frame[columns[3:]] += [0.002, -0.001, 0.0015]
    moved, _ = cm.imu_sensitivities(Dataset(frame, setup["cal"].meta))
    assert np.allclose(moved, k, rtol=0.05)
    # one-frame glitches (a rate's would step its integral for the rest of the run) change nothing
    glitched = setup["cal"].frame.copy()
    glitched.loc[500, "boom_rate"] += 5.0
    glitched.loc[900, "dipper_angle"] = 3.0  # outside the machine's range too
    glitched.loc[1500, "bucket_rate"] -= 0.5
    machine = load_machine(PRIOR)
    assert not cm._glitches(setup["cal"].frame[columns].to_numpy(float),
                            setup["cal"].frame["experiment"].to_numpy(), 15).any()
    robust, _ = cm.imu_sensitivities(Dataset(glitched, setup["cal"].meta), machine=machine)
    # (the runs split at the glitches lose some of the boom's slow acceleration to their trends)
    assert np.all(np.abs(robust - k) < np.maximum(0.05 * k, 3 * std)), (robust, k, std)
    unguarded = glitched.copy()
    unguarded.loc[1500, "bucket_rate"] -= 4.5  # a glitch the plausibility limits let through
    assert np.all(np.isfinite(cm.imu_sensitivities(Dataset(unguarded, setup["cal"].meta))[0]))
    # no leak to find in signals that have none: the same motions' true angles and rates
    if all("true_" + c in frame for c in columns):
        clean = setup["cal"].frame.copy()
        for c in columns:
            clean[c] = clean["true_" + c]
        none, _ = cm.imu_sensitivities(Dataset(clean, setup["cal"].meta))
        assert np.all(np.abs(none) < 0.05 * truth)


def test_house_imu_leak_is_read_off_its_pitch_and_roll(setup, momentum):
    """On fixed ground the house's pitch and roll move only with the slew's accelerations: the
    simulator's k = leak · radius / g is found from the kernel's own leak terms; true signals
    give about 0; a 3° ground slope (the house's tilt turning with the slew, the model's
    house_inclination) does not move it with the tilt term and does without; the momentum form
    does not use it (a measurement: benchmarks/house_imu_readoff.py)."""
    from excavator_payload.model.hydraulic import hydraulic_symbolic
    from excavator_payload.simulation.machine_sensors import get_machine_noise

    field = get_machine_noise("field")
    truth = field.acceleration_leak * field.house_imu_radius / 9.81
    k, std = cm.house_imu_sensitivity(setup["cal"])
    assert k == pytest.approx(truth, rel=0.1) and 0 < std < 0.1 * truth
    frame = setup["cal"].frame
    if "true_house_pitch" in frame:
        clean = frame.copy()
        clean[["house_pitch", "house_roll"]] = clean[["true_house_pitch", "true_house_roll"]].to_numpy()
        assert abs(cm.house_imu_sensitivity(Dataset(clean, setup["cal"].meta))[0]) < 0.05 * truth
    sloped = frame.copy()
    f = hydraulic_symbolic().functions["house_inclination"]
    for _, rows in sloped.groupby("experiment").groups.items():
        rate = sloped.loc[rows, "true_slew_rate" if "true_slew_rate" in sloped else "slew_rate"].to_numpy()
        q = np.zeros((4, len(rows)))
        q[3] = 0.7 + np.r_[0.0, np.cumsum(0.5 * (rate[1:] + rate[:-1]) / MACHINE_SENSORS.sample_rate)]
        tilt = np.asarray(f.map(len(rows))(q, np.outer([0.05, 0.02], np.ones(len(rows)))))
        sloped.loc[rows, ["house_pitch", "house_roll"]] += tilt.T
    on_slope, _ = cm.house_imu_sensitivity(Dataset(sloped, setup["cal"].meta))
    assert on_slope == pytest.approx(k, rel=0.05)
    assert cm.house_imu_sensitivity(Dataset(sloped, setup["cal"].meta), tilt=False)[0] != pytest.approx(k, rel=0.05)
    # the momentum form does not take it (its prior mean stays 0: on fresh draws it helped with
    # empty-swing zeros and hurt with slow ones, docs/findings/false-alarms.md)
    cal = momentum.calibration
    house = len(cm.CALIBRATED_PARAMETERS) + len(cm.OFFSET_SIGNALS) + 4
    assert cal.z[house] == 0.0
    assert np.sqrt(cal.covariance[house, house]) == pytest.approx(cm.IMU_PRIOR_STD[4])


def test_imu_leak_signals_is_held_in_calibration(setup):
    """``imu_leak="signals"``: the three link sensitivities are the ones read off the signals
    (held, with their standard errors as posterior), the house's is still fitted; a bad choice
    is refused in one line."""
    est = create_estimator("calibrated", PRIOR, balance="differentiated", imu_leak="signals").fit(setup["cal"])
    k, std = cm.imu_sensitivities(setup["cal"])
    cal = est.calibration
    links = slice(len(cm.CALIBRATED_PARAMETERS) + len(cm.OFFSET_SIGNALS) + 1,
                  len(cm.CALIBRATED_PARAMETERS) + len(cm.OFFSET_SIGNALS) + 4)
    assert np.array_equal(cal.z[links], k)
    assert np.allclose(np.sqrt(np.diag(cal.covariance)[links]), std)
    default = setup["calibrated"].calibration
    assert not np.allclose(default.z[links], k)
    with pytest.raises(EstimatorError, match="imu_leak|imu-leak"):
        create_estimator("calibrated", PRIOR, imu_leak="datasheet")


def test_imu_leak_of_a_joint_that_never_moved_stays_at_its_prior(setup):
    """A boom that stood still through the calibration motions says nothing of its IMU's leak:
    it keeps 0 and the prior's std (no ratio of noises, no error), the others are still found."""
    frame = setup["cal"].frame.copy()
    frame["boom_angle"] = 0.3
    frame["boom_rate"] = 0.0
    k, std = cm.imu_sensitivities(Dataset(frame, setup["cal"].meta))
    assert np.all(np.isfinite(k)) and np.all(np.isfinite(std))
    assert abs(k[0]) < 1e-6 and std[0] == pytest.approx(cm.IMU_PRIOR_STD[1], rel=1e-6)
    assert std[2] < 0.05 * cm.IMU_PRIOR_STD[3]
    empty = setup["cal"].frame.iloc[:10]
    k, std = cm.imu_sensitivities(Dataset(empty.reset_index(drop=True), setup["cal"].meta))
    assert np.array_equal(k, np.zeros(3)) and np.array_equal(std, cm.IMU_PRIOR_STD[1:4])


def _boom_offset(test, bar: float, onset_share: float = 0.4):
    """The first test swing with its boom head pressure ``bar`` off from ``onset_share`` of it on."""
    f = test.frame
    one = f[f["experiment"] == f["experiment"].iloc[0]].reset_index(drop=True)
    a = int(onset_share * len(one))
    v = one["boom_head_pressure"].to_numpy(float).copy()
    v[a:] += bar * 1e5
    one["boom_head_pressure"] = v
    return Dataset(one, test.meta), a


def test_joint_check_names_a_boom_pressure_offset_and_never_calls_it_ok(momentum, setup):
    """A boom head pressure 15 bar off biases the boom joint's balance only: the joints' estimates
    part, the boom cylinder's pressures are named ``balance`` (FMI 13), no ``ok`` after that, the
    estimate then weighs without the boom; the clean swing raises nothing; streaming gives the
    same statuses and faults; with ``health`` off (the C export's path) or ``joint_check`` off the
    check is silent."""
    from excavator_payload.estimators.health import FMI

    est = copy.deepcopy(momentum)
    est.options["joint_check"] = "on"  # the default (a model saved before it may say off)
    clean = est.estimate(setup["test"])
    assert not clean["fault"].str.contains("balance").any()
    bad, a = _boom_offset(setup["test"], 15.0)
    out = est.estimate(bad)
    named = out["fault"].str.contains("boom_head_pressure:balance", regex=False).to_numpy()
    assert named.any() and not named[:a].any()
    first = int(np.flatnonzero(named)[0])
    assert out["fault"].iloc[first] == "boom_head_pressure:balance,boom_rod_pressure:balance"
    status = out["status"].to_numpy()
    assert not (status[first:] == "ok").any()
    degraded = out["payload_estimate"].to_numpy()[named]
    truth = bad.frame["payload"].to_numpy()[named]
    finite = np.isfinite(degraded)
    assert np.abs(degraded[finite] - truth[finite]).max() < 0.02 * est.rated_payload if finite.any() else True
    assert FMI["balance"] == 13
    # streaming: the same statuses and faults
    f = bad.frame
    est.reset()
    streamed = [est.step_values(t, v) for t, v in zip(f["time"].to_numpy(), bad.signals(est.sensor_set.signals))]
    assert [r.status.value for r in streamed] == list(status)
    assert [r.fault for r in streamed] == list(out["fault"])
    est.health = False
    try:
        off = est.estimate(bad)
    finally:
        est.health = True
    assert not off["fault"].astype(str).str.contains("balance").any()
    assert (off["status"].to_numpy()[first:] == "ok").any()  # what the weighing said before the check
    est.options["joint_check"] = "off"
    try:
        unchecked = est.estimate(bad)
    finally:
        est.options["joint_check"] = "on"
    np.testing.assert_array_equal(unchecked["status"].to_numpy(), off["status"].to_numpy())
