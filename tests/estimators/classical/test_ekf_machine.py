"""ekf and ukf on the machine sensor set: kinematic state, piston forces through the symbolic model."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.base import create_estimator, load_estimator
from excavator_payload.estimators.classical import _kalman_machine as km
from excavator_payload.model.hydraulic import parameter_vector
from excavator_payload.model.machine import load_machine
from excavator_payload.simulation.machine_sim import simulate_machine_dataset

MACHINE = load_machine("cat345c-hydraulic")
FRICTIONLESS = dataclasses.replace(
    dataclasses.replace(MACHINE, **{
        name: dataclasses.replace(getattr(MACHINE, name), coulomb=0.0, load_coefficient=0.0, viscous=0.0)
        for name in ("boom_cylinder", "dipper_cylinder", "bucket_cylinder")}),
    name="frictionless")


@pytest.fixture(scope="module")
def frictionless_swings():
    return simulate_machine_dataset(2, seed=3, noise="none", motion="swing", machine=FRICTIONLESS,
                                    with_truth=True)


@pytest.fixture(scope="module")
def field_swings():
    return simulate_machine_dataset(2, seed=5, noise="field", motion="swing", session=2)


def _final_errors(estimator, data):
    est = estimator.estimate(data)
    return est.groupby("experiment", sort=False)["payload_estimate"].last().to_numpy() - data.payloads


def test_force_model_reproduces_the_simulated_pressures(frictionless_swings):
    """At the true state (angles, rates, accelerations, payload) the measurement function gives
    the piston forces the simulator's pressures hold: one physics for both."""
    data = frictionless_swings
    f = data.frame
    func = km.force_measurement_function()
    p = parameter_vector(FRICTIONLESS)
    rows = np.linspace(50, len(f) - 50, 40).astype(int)
    for i in rows:
        r = f.iloc[i]
        x = np.r_[[r[f"true_{s}"] for s in ("boom_angle", "dipper_angle", "bucket_angle", "boom_rate",
                                             "dipper_rate", "bucket_rate", "slew_rate")],
                  [r[f"true_{s}_accel"] for s in ("boom", "dipper", "bucket", "slew")], r["payload"]]
        tilt = km.ground_tilt(r["true_house_pitch"], r["true_house_roll"])
        force = np.array([r[f"true_{c}_head_pressure"] * cyl.head_area - r[f"true_{c}_rod_pressure"] * cyl.rod_area
                          for c, cyl in zip(("boom", "dipper", "bucket"), FRICTIONLESS.cylinders)])
        h = np.asarray(func(x, tilt, force, p)).ravel()[:3]
        np.testing.assert_allclose(h, force, rtol=1e-6, atol=1.0)


@pytest.mark.parametrize("name", ["ekf", "ukf"])
def test_accurate_without_friction_and_noise(name, frictionless_swings):
    """Perfect sensors, no friction: only the filter's own acceleration estimate limits it."""
    est = create_estimator(name, FRICTIONLESS, noise="none").fit(frictionless_swings)
    assert np.all(np.abs(_final_errors(est, frictionless_swings)) < 0.002 * MACHINE.rated_payload)


@pytest.mark.parametrize("name", ["ekf", "ukf"])
def test_field_noise_converges_and_round_trips(name, field_swings, tmp_path):
    """Field noise and session offsets: within 5 % (offsets are not estimated), a finite
    posterior standard deviation, and a saved filter gives the same estimates."""
    est = create_estimator(name, MACHINE).fit(field_swings)
    errors = _final_errors(est, field_swings)
    assert np.all(np.abs(errors) < 0.05 * MACHINE.rated_payload)
    assert 0 < est.payload_std < 0.01 * MACHINE.rated_payload
    out = est.estimate(field_swings)
    assert (out["status"].iloc[-1]) == "ok"
    est.save(tmp_path / "m")
    again = load_estimator(tmp_path / "m")
    assert again.sensor_set.name == "machine"
    np.testing.assert_array_equal(_final_errors(again, field_swings), errors)


def test_a_gap_keeps_the_payload(field_swings):
    est = create_estimator("ekf", MACHINE).fit(field_swings)
    data = field_swings.subset([field_swings.experiment_ids[0]])
    full = est.estimate(data)["payload_estimate"].to_numpy()
    holed = data.frame.drop(index=data.frame.index[300:320])
    from excavator_payload.data.dataset import Dataset

    out = est.estimate(Dataset(holed.reset_index(drop=True), data.meta))
    assert "gap" in set(out["status"])
    assert abs(out["payload_estimate"].iloc[-1] - full[-1]) < 0.01 * MACHINE.rated_payload


def test_jerk_density_matches_the_true_jerk(frictionless_swings):
    """On noise-free rates the smoothed double derivative finds the motion's 99 % jerk."""
    true = []
    for _, rows in frictionless_swings.experiments():
        accel = rows[[f"true_{j}_accel" for j in ("boom", "dipper", "bucket", "slew")]].to_numpy()
        true.append(np.diff(accel, axis=0) / km.T)
    j99 = np.quantile(np.abs(np.concatenate(true)), 0.99, axis=0)
    np.testing.assert_allclose(np.sqrt(km.jerk_density(frictionless_swings) / km.T), j99, rtol=0.3)


def test_wrong_pairs_are_refused_in_one_line(field_swings):
    with pytest.raises(EstimatorError, match="need a hydraulic machine"):
        create_estimator("ekf", "cat345c").fit(field_swings)
    with pytest.raises(EstimatorError, match="tuning consistent"):
        create_estimator("ukf", MACHINE, tuning="thesis").fit(field_swings)
    nameless = dataclasses.replace(field_swings, meta={k: v for k, v in field_swings.meta.items()
                                                       if k != "noise"})
    with pytest.raises(EstimatorError, match="--noise field"):
        create_estimator("ekf", MACHINE).fit(nameless)
