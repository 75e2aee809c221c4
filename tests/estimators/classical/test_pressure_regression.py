"""inverse-dynamics on the machine sensor set: weighing from cylinder pressures and IMUs."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.base import create_estimator, load_estimator
from excavator_payload.estimators.classical.pressure_regression import ground_tilt, judge_frame, one_frame_glitch
from excavator_payload.model.hydraulic import HydraulicArmModel
from excavator_payload.model.machine import load_machine
from excavator_payload.simulation.machine_sim import simulate_machine_dataset

MACHINE = load_machine("cat345c-hydraulic")


def _final_errors(estimator, data):
    est = estimator.estimate(data)
    return est.groupby("experiment", sort=False)["payload_estimate"].last().to_numpy() - data.payloads


def test_exact_without_friction_and_noise():
    """With friction-free cylinders and perfect sensors the regression is exact: the centred
    differentiator, the tilt from the house IMU and the pressure-to-torque path are right."""
    frictionless = dataclasses.replace(MACHINE, **{
        name: dataclasses.replace(getattr(MACHINE, name), coulomb=0.0, load_coefficient=0.0, viscous=0.0)
        for name in ("boom_cylinder", "dipper_cylinder", "bucket_cylinder")})
    frictionless = dataclasses.replace(frictionless, name="frictionless")
    data = simulate_machine_dataset(2, seed=3, noise="none", motion="swing", machine=frictionless)
    est = create_estimator("inverse-dynamics", frictionless).fit(data)
    assert np.all(np.abs(_final_errors(est, data)) < 0.1)


def test_within_half_a_percent_with_seal_friction(tmp_path):
    """Noise-free sensors, real seal friction (presliding state unknown to the estimator)."""
    data = simulate_machine_dataset(2, seed=4, noise="none", motion="lifts")
    est = create_estimator("inverse-dynamics", MACHINE).fit(data)
    errors = _final_errors(est, data)
    assert np.all(np.abs(errors) < 0.005 * MACHINE.rated_payload)
    est.save(tmp_path / "m")
    again = load_estimator(tmp_path / "m")
    np.testing.assert_array_equal(_final_errors(again, data), errors)
    assert again.sensor_set.name == "machine"


def test_ground_tilt_inverts_the_house_inclination():
    arm = HydraulicArmModel(MACHINE)
    for tilt in ([0.1, 0.0], [0.05, -0.08], [-0.12, 0.1]):
        pitch, roll = arm.house_inclination(np.zeros(4), np.array(tilt))
        np.testing.assert_allclose(ground_tilt(pitch, roll), tilt, atol=1e-12)


def test_wrong_pairs_are_refused_in_one_line():
    data = simulate_machine_dataset(1, seed=4, noise="none", motion="lifts")
    with pytest.raises(EstimatorError, match="need a hydraulic machine"):
        create_estimator("inverse-dynamics", "cat345c").fit(data)
    # calibrated runs on the hydraulic machine since issue 12 (calibrated_machine)
    assert "machine" in create_estimator("calibrated", MACHINE).SENSOR_SETS


def test_cli_trains_estimates_and_evaluates_on_the_machine_set(tmp_path):
    from excavator_payload.cli import main
    from excavator_payload.simulation.machine_sim import simulate_machine_to_file

    data = tmp_path / "swings.parquet"
    simulate_machine_to_file(data, 2, seed=1, motion="swing", workers=1, progress=False)
    assert main(["train", "inverse-dynamics", "--data", str(data), "--out", str(tmp_path / "m")]) == 0
    assert main(["estimate", "--model", str(tmp_path / "m"), "--data", str(data),
                 "--out", str(tmp_path / "e.parquet")]) == 0
    assert main(["evaluate", "--model", str(tmp_path / "m"), "--data", str(data), "--discard", "100"]) == 0


@pytest.mark.parametrize("shape", ["corner", "rounded tip", "step"])
def test_a_sharp_turn_of_a_signal_is_not_a_glitch(shape):
    """A pressure's corner (a rod stopping, a force turning) lies on the line through one
    side's two samples; a rounded tip bends away from both lines the other way; a step moves
    from one neighbour only: none is a one-frame glitch, however large."""
    t = np.arange(-2, 3, dtype=float)
    values = {"corner": 5.0 * np.abs(t), "rounded tip": -3.0 * t**2, "step": np.where(t > 0, 40.0, 0.0)}[shape]
    x = values[:, None] * np.ones((1, 3))
    assert not one_frame_glitch(x[1], x[2], x[3], np.ones(3), x[0], x[4])
    # a corner or a tip still stands out from its neighbours: not regressed, not reported
    assert judge_frame(x[1], x[2], x[3], np.ones(3), x[0], x[4]) == (shape != "step", False)


@pytest.mark.parametrize("base", ["flat", "ramp", "corner"])
def test_a_frame_off_both_sides_lines_is_a_glitch(base):
    """One frame off a flat, sloped or cornered signal (its neighbours' lines agree with each
    other) is a glitch, with or without the second neighbours known."""
    t = np.arange(-2, 3, dtype=float)
    values = {"flat": np.zeros(5), "ramp": 2.0 * t, "corner": 0.5 * np.abs(t)}[base]
    x = values[:, None] * np.ones((1, 2))
    x[2, 1] += 10.0  # the second signal glitches
    assert one_frame_glitch(x[1], x[2], x[3], np.ones(2), x[0], x[4])
    assert one_frame_glitch(x[1], x[2], x[3], np.ones(2))
    assert one_frame_glitch(x[1], x[2], x[3], np.ones(2), x[0], None)
    assert not one_frame_glitch(x[1], x[2], x[3], np.full(2, 20.0), x[0], x[4])  # below the threshold
