"""Sensor sets: the schema every dataset, estimator and runtime path takes its signals from."""

import numpy as np
import pandas as pd
import pytest

from excavator_payload.data import MACHINE_SENSORS, THESIS_SENSORS, Dataset, read_dataset, write_dataset
from excavator_payload.data.schema import SIGNALS, detect_sensor_set, get_sensor_set
from excavator_payload.errors import DatasetError


def _machine_frame(n_exp=2, n=5, payload=True):
    rows = []
    for e in range(n_exp):
        for k in range(n):
            row = {"experiment": e, "time": k * MACHINE_SENSORS.sample_period}
            row.update({s: 0.1 for s in MACHINE_SENSORS.signals})
            row.update({s: 2.0e6 for s in MACHINE_SENSORS.signals if s.endswith("pressure")})
            if payload:
                row["payload"] = 1000.0 * e
            rows.append(row)
    return pd.DataFrame(rows)


def test_thesis_set_is_the_legacy_schema():
    assert THESIS_SENSORS.signals == SIGNALS
    assert THESIS_SENSORS.sample_period == pytest.approx(0.05)
    assert get_sensor_set("thesis") is THESIS_SENSORS


def test_machine_set_columns_and_units():
    assert MACHINE_SENSORS.sample_rate == 100.0
    assert "boom_head_pressure" in MACHINE_SENSORS.signals
    assert MACHINE_SENSORS.unit("boom_rod_pressure") == "Pa"
    assert MACHINE_SENSORS.unit("true_boom_torque") == "N*m"
    assert MACHINE_SENSORS.unit("true_slew_rate") == "rad/s"
    assert set(MACHINE_SENSORS.plausible_abs) == set(MACHINE_SENSORS.signals)


def test_detect_and_unknown():
    frame = _machine_frame()
    assert detect_sensor_set(frame.columns) is MACHINE_SENSORS
    assert detect_sensor_set(["experiment", "time"]) is None
    with pytest.raises(DatasetError, match="unknown sensor set"):
        get_sensor_set("lidar")


def test_machine_dataset_round_trip_without_payload(tmp_path):
    """A field log has no payload column: it is still a valid dataset."""
    ds = Dataset(_machine_frame(payload=False), {"sensor_set": "machine"})
    assert ds.sensor_set is MACHINE_SENSORS and not ds.has_payload
    write_dataset(ds, tmp_path / "log.parquet")
    back = read_dataset(tmp_path / "log.parquet")
    assert back.sensor_set is MACHINE_SENSORS
    assert back.meta["units"]["bucket_head_pressure"] == "Pa"
    np.testing.assert_array_equal(back.signals(), ds.signals())
    with pytest.raises(DatasetError, match="no 'payload'"):
        back.payloads


def test_machine_dataset_missing_column_named():
    frame = _machine_frame().drop(columns=["bucket_rod_pressure"])
    with pytest.raises(DatasetError, match="bucket_rod_pressure"):
        Dataset(frame, {"sensor_set": "machine"})


def test_implausible_pressure_rejected(tmp_path):
    frame = _machine_frame()
    frame.loc[3, "boom_head_pressure"] = 5e9
    with pytest.raises(DatasetError, match="boom_head_pressure"):
        write_dataset(Dataset(frame, {"sensor_set": "machine"}), tmp_path / "x.parquet")


def test_thesis_estimator_refuses_machine_data():
    from excavator_payload.errors import EstimatorError
    from excavator_payload.estimators.base import create_estimator

    est = create_estimator("inverse-dynamics")
    with pytest.raises(EstimatorError, match="machine sensor set"):
        est.fit(Dataset(_machine_frame(), {"sensor_set": "machine"}))
