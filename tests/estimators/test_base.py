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


# -- plausibility limits of a hydraulic machine (issue 11) ------------------------------------

def test_hydraulic_angle_limits_are_the_ranges_widened_by_the_sensor_margin():
    from excavator_payload.data.schema import MACHINE_SENSORS
    from excavator_payload.estimators.base import angle_sensor_margins, plausibility_limits
    from excavator_payload.model.machine import load_machine
    from excavator_payload.simulation.machine_sensors import DEG, PRESETS

    machine = load_machine("cat345c-hydraulic")
    low, high = plausibility_limits(MACHINE_SENSORS, machine)
    margins = angle_sensor_margins()
    field = PRESETS["field"]
    # hand calculation from the field preset: leak × π/2 per IMU (the boom has one), 6σ of
    # offset and noise; the IMU lag adds nothing
    assert margins["boom_angle"] == pytest.approx(0.05 * math.pi / 2 + 6 * 0.15 * DEG)
    assert margins["bucket_angle"] == pytest.approx(0.05 * math.pi + 6 * 0.15 * DEG)
    assert field.imu_lag > 0
    for j, name in enumerate(("boom_angle", "dipper_angle", "bucket_angle")):
        i = MACHINE_SENSORS.index(name)
        lo, hi = machine.angle_ranges[j]
        assert (low[i], high[i]) == pytest.approx((lo - margins[name], hi + margins[name]))
    # signals without a machine rule keep the sensor set's limits
    i = MACHINE_SENSORS.index("house_roll")
    assert (low[i], high[i]) == (-MACHINE_SENSORS.plausible_abs["house_roll"],
                                 MACHINE_SENSORS.plausible_abs["house_roll"])


def test_hydraulic_rate_limits_are_what_the_pumps_can_turn_a_joint():
    """A joint rate is bounded by the pump's flow through the cylinder's smaller area and the
    joint's smallest moment arm (here from the cylinder lengths by finite differences, not the
    model's moment_arms), × RATE_LIMIT_FACTOR, plus 6σ of the rate sensors' offset and noise; the
    slew by max_slew_rate the same way."""
    from excavator_payload.data.schema import MACHINE_SENSORS
    from excavator_payload.estimators.base import RATE_LIMIT_FACTOR, plausibility_limits
    from excavator_payload.model.hydraulic import HydraulicArmModel
    from excavator_payload.model.machine import load_machine
    from excavator_payload.simulation.machine_sensors import PRESETS

    machine = load_machine("cat345c-hydraulic")
    low, high = plausibility_limits(MACHINE_SENSORS, machine)
    arm = HydraulicArmModel(machine)
    field = PRESETS["field"]
    margin = 6 * (field.rate_offset + field.rate_noise)
    assert margin > 0
    h = 1e-6
    for j, name in enumerate(("boom_rate", "dipper_rate", "bucket_rate")):
        q = np.zeros((2001, 4))
        q[:, :3] = (-0.3, -1.3, -0.8)
        q[:, j] = np.linspace(*machine.angle_ranges[j], 2001)
        dq = np.zeros(4)
        dq[j] = h
        arms = np.abs(arm.cylinder_lengths(q + dq)[:, j] - arm.cylinder_lengths(q - dq)[:, j]) / (2 * h)
        cyl = machine.cylinders[j]
        fastest = machine.hydraulics.pump_flow / (cyl.count * min(cyl.head_area, cyl.rod_area)) / arms.min()
        i = MACHINE_SENSORS.index(name)
        assert high[i] == pytest.approx(RATE_LIMIT_FACTOR * fastest + margin, rel=1e-3)
        assert low[i] == -high[i]
    i = MACHINE_SENSORS.index("slew_rate")
    assert high[i] == pytest.approx(RATE_LIMIT_FACTOR * machine.house.max_slew_rate + margin)
    # a 345C's boom turns at most about 0.7 rad/s; the sensor set alone allowed 50
    assert high[MACHINE_SENSORS.index("boom_rate")] < 2.0


def test_hydraulic_pressure_limits_are_a_vacuum_and_twice_the_relief_pressure():
    """Gauge pressure never lies below a full vacuum (−1 bar); twice the relief setting leaves
    room for pressure peaks; both widened by 6σ of the pressure sensors' offset and noise."""
    from excavator_payload.data.schema import MACHINE_SENSORS
    from excavator_payload.estimators.base import plausibility_limits
    from excavator_payload.model.machine import load_machine
    from excavator_payload.simulation.machine_sensors import PRESETS

    machine = load_machine("cat345c-hydraulic")
    low, high = plausibility_limits(MACHINE_SENSORS, machine)
    field = PRESETS["field"]
    margin = 6 * (field.pressure_offset + field.pressure_noise)  # 10.8 bar
    assert margin == pytest.approx(10.8e5)
    for name in MACHINE_SENSORS.signals:
        if name.endswith("_pressure"):
            i = MACHINE_SENSORS.index(name)
            assert low[i] == pytest.approx(-1e5 - margin)
            assert high[i] == pytest.approx(2 * 324e5 + margin)  # the preset's 324 bar relief


def test_two_agreeing_rate_glitches_are_out_of_range_on_the_machine_set():
    """No one-frame test sees two equal bad frames in a row (each agrees with a neighbour); the
    machine's own rate and pressure limits do."""
    from excavator_payload.simulation.machine_sim import simulate_machine_dataset

    data = simulate_machine_dataset(1, seed=3, motion="lifts")
    est = create_estimator("inverse-dynamics", "cat345c-hydraulic").fit(data)
    statuses = [est.step(_sample(data, k)).status for k in range(20)]
    assert Status.OUT_OF_RANGE not in statuses
    for k in (20, 21):
        assert est.step(dict(_sample(data, k), boom_rate=30.0)).status is Status.OUT_OF_RANGE
    assert est.step(_sample(data, 22)).status is not Status.OUT_OF_RANGE
    # the same for pressures: two frames of −300 bar, or of 700 bar on a 324-bar machine
    for k, bad in ((23, -3e7), (24, -3e7), (25, 7e7), (26, 7e7)):
        assert est.step(dict(_sample(data, k), boom_head_pressure=bad)).status is Status.OUT_OF_RANGE
    assert est.step(_sample(data, 27)).status is not Status.OUT_OF_RANGE


def test_an_impossible_bucket_angle_is_rejected_on_the_machine_set():
    from excavator_payload.estimators.base import angle_sensor_margins
    from excavator_payload.model.machine import load_machine
    from excavator_payload.simulation.machine_sim import simulate_machine_dataset

    data = simulate_machine_dataset(1, seed=3, motion="lifts")
    est = create_estimator("inverse-dynamics", "cat345c-hydraulic").fit(data)
    top = load_machine("cat345c-hydraulic").angle_ranges[2, 1]
    margin = angle_sensor_margins()["bucket_angle"]
    sample = _sample(data, 0)
    assert est.step(sample).status is not Status.OUT_OF_RANGE
    near = dict(_sample(data, 1), bucket_angle=top + 0.9 * margin)  # past the stop, but a sensor can
    assert est.step(near).status is not Status.OUT_OF_RANGE
    impossible = dict(_sample(data, 2), bucket_angle=top + 1.1 * margin)
    assert est.step(impossible).status is Status.OUT_OF_RANGE


@pytest.mark.parametrize("motion,n", [("swing", 4), ("work-cycle", 6), ("slopes", 6), ("lifts", 3),
                                      ("nmpc", 2)])
def test_simulated_machine_data_stay_inside_the_plausibility_limits(motion, n):
    """No false rejections on field-noise data of every motion family (the benchmark runs 200
    experiments of each: benchmarks/bench_hydraulic.py --plausibility)."""
    from excavator_payload.data.schema import MACHINE_SENSORS
    from excavator_payload.estimators.base import plausibility_limits
    from excavator_payload.model.machine import load_machine
    from excavator_payload.simulation.machine_sim import simulate_machine_dataset

    data = simulate_machine_dataset(n, seed=11, session=4, motion=motion)
    low, high = plausibility_limits(MACHINE_SENSORS, load_machine("cat345c-hydraulic"))
    values = data.signals()
    assert np.all((values >= low) & (values <= high))


def test_estimate_notes_name_the_non_finite_columns(mj_dataset):
    """One NaN every few samples leaves (almost) no estimate: every estimator's notes say which
    column holds how many NaN (the statuses alone left the user guessing)."""
    from excavator_payload.data.dataset import Dataset
    from excavator_payload.estimators.base import create_estimator

    data = mj_dataset.subset(mj_dataset.experiment_ids[:2])
    est = create_estimator("ekf", "cat345c").fit(data)
    assert est.all_estimate_notes(data, est.estimate(data)) == est.estimate_notes(data, est.estimate(data))
    frame = data.frame.copy()
    frame.loc[frame.index[::3], "boom_torque"] = np.nan
    frame.loc[frame.index[7], "dipper_rate"] = np.inf
    holed = Dataset(frame, data.meta)
    estimates = est.estimate(holed)
    unusable = estimates["status"].isin(["warming_up", "invalid_input", "gap", "no_data"]).mean()
    assert unusable > 0.2
    notes = est.all_estimate_notes(holed, estimates)
    assert len(notes) == 1 + len(est.estimate_notes(holed, estimates))
    assert "boom_torque 68 (1 sample in 3) of 202 samples" in notes[0]
    assert "dipper_rate 1 (1 sample in 202)" in notes[0]
    assert "dipper_accel" not in notes[0]
    # A few NaN that cost little: no note.
    frame = data.frame.copy()
    frame.loc[frame.index[50], "boom_torque"] = np.nan
    few = Dataset(frame, data.meta)
    assert est.non_finite_notes(few, est.estimate(few)) == []


def test_estimate_notes_name_the_signals_out_of_range():
    """A machine file with too low a pump flow makes most samples out_of_range: the notes say
    which signals, how often, their limits and values, and that the machine file sets them; a
    clean run has no such note."""
    import dataclasses

    from excavator_payload.model.machine import load_machine
    from excavator_payload.simulation.machine_sim import simulate_machine_dataset

    data = simulate_machine_dataset(2, seed=3)
    machine = load_machine("cat345c-hydraulic")
    est = create_estimator("inverse-dynamics", machine).fit(data)
    assert not [n for n in est.all_estimate_notes(data, est.estimate(data)) if "out_of_range" in n]
    assert not est.fit_warnings
    slow = dataclasses.replace(machine, hydraulics=dataclasses.replace(machine.hydraulics, pump_flow=1e-4))
    est = create_estimator("inverse-dynamics", slow).fit(data)
    # fit says so first: streaming would skip these samples
    assert len(est.fit_warnings) == 1 and "training samples lie outside the plausibility limits" \
        in est.fit_warnings[0] and "boom_rate on" in est.fit_warnings[0]
    out = est.estimate(data)
    share = (out["status"] == "out_of_range").mean()
    assert share > 0.5
    notes = [n for n in est.all_estimate_notes(data, out) if "out_of_range" in n]
    assert len(notes) == 1
    assert f"({100 * share:.0f} %) are out_of_range" in notes[0]
    assert "boom_rate on" in notes[0] and "rad/s" in notes[0] and "pump_flow" in notes[0]
    assert "boom_head_pressure" not in notes[0]  # only the signals that were out
