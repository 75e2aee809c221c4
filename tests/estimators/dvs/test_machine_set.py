"""The networks on the machine sensor set: inputs from the data's sensor set, thesis set unchanged."""

from __future__ import annotations

import numpy as np
import pytest

from excavator_payload.data.schema import MACHINE_SENSORS
from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.base import create_estimator, load_estimator
from excavator_payload.estimators.dvs.common import THESIS_INPUTS, experiment_arrays, parse_inputs
from excavator_payload.simulation.machine_sim import simulate_machine_dataset

TINY = dict(hidden="4", delays="0,3", epochs=3, train_experiments=2, validation_experiments=1,
            progress=False)


@pytest.fixture(scope="module")
def swings():
    return simulate_machine_dataset(3, seed=21, noise="field", motion="swing", session=1)


def test_thesis_defaults_are_unchanged():
    est = create_estimator("net1")
    assert est.input_names == list(THESIS_INPUTS)
    assert est.n_inputs * 6 == est._layer_sizes()[0]


def test_inputs_are_validated_against_the_set():
    assert parse_inputs("all", MACHINE_SENSORS) == list(MACHINE_SENSORS.signals)
    assert parse_inputs("default", MACHINE_SENSORS) == list(MACHINE_SENSORS.signals)
    assert parse_inputs("1,10", MACHINE_SENSORS) == ["boom_angle", "boom_head_pressure"]
    with pytest.raises(EstimatorError, match="machine sensor set"):
        parse_inputs("boom_torque", MACHINE_SENSORS)
    with pytest.raises(EstimatorError, match="inputs"):
        create_estimator("net1", inputs="boom_speed")   # in no sensor set: refused at once


@pytest.mark.parametrize("name", ["net1", "net2"])
def test_networks_train_and_stream_on_the_machine_set(name, swings, tmp_path):
    est = create_estimator(name, **TINY).fit(swings)
    assert est.input_names == list(MACHINE_SENSORS.signals)
    assert list(est.input_index) == list(range(len(MACHINE_SENSORS.signals)))
    out = est.estimate(swings)["payload_estimate"].to_numpy()
    assert np.isfinite(out).sum() > 0.9 * len(out)
    # streaming (step, folded scaling, ring buffer) equals the batch forward pass
    inputs, _ = experiment_arrays(swings, est.input_names)
    batch = (np.concatenate(est.predict_windows(inputs)) if name == "net1"
             else np.concatenate(est.predict_experiments(inputs)))
    np.testing.assert_allclose(out, batch, rtol=1e-9, atol=1e-6)
    est.save(tmp_path / name)
    again = load_estimator(tmp_path / name)
    assert again.sensor_set.name == "machine" and again.input_names == est.input_names
    np.testing.assert_array_equal(again.estimate(swings)["payload_estimate"].to_numpy(), out)


def test_chosen_machine_inputs(swings, mj_dataset):
    chosen = "boom_angle,boom_rate,boom_head_pressure,boom_rod_pressure"
    est = create_estimator("net1", inputs=chosen, **TINY).fit(swings)
    assert est.input_names == chosen.split(",")
    assert est._layer_sizes()[0] == 4 * 2
    with pytest.raises(EstimatorError, match="thesis sensor set"):
        create_estimator("net1", inputs=chosen, **TINY).fit(mj_dataset)
