"""The dataset loader rejects bad files with a message that says what is wrong; round trips."""

import json

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.io import read_dataset, read_metadata, write_dataset
from excavator_payload.data.schema import COLUMNS, METADATA_KEY, TRUTH_COLUMNS
from excavator_payload.errors import DatasetError


@pytest.fixture()
def small(mj_dataset_clean):
    return mj_dataset_clean.subset(mj_dataset_clean.experiment_ids[:3])


def _write_frame(frame, path):
    pq.write_table(pa.Table.from_pandas(frame, preserve_index=False), path)
    return path


def test_round_trip_keeps_data_and_metadata(small, tmp_path):
    path = tmp_path / "d.parquet"
    write_dataset(small, path)
    back = read_dataset(path)
    assert back.meta["experiments"] == json.loads(json.dumps(small.meta["experiments"]))
    assert back.meta["noise"] == small.meta["noise"]
    assert back.meta["motion"] == small.meta["motion"]
    assert back.machine() == small.machine()
    assert back.has_truth
    for column in COLUMNS + TRUTH_COLUMNS:
        np.testing.assert_array_equal(back.frame[column].to_numpy(), small.frame[column].to_numpy())
    assert read_metadata(path)["units"]["boom_angle"] == "rad"


def test_truncated_file(small, tmp_path):
    path = tmp_path / "d.parquet"
    write_dataset(small, path)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(DatasetError, match="truncated|corrupt|not a readable Parquet"):
        read_dataset(path)


def test_not_parquet(tmp_path):
    path = tmp_path / "d.parquet"
    path.write_text("experiment,time,boom_angle\n0,0.0,0.1\n")
    with pytest.raises(DatasetError, match="not a readable Parquet"):
        read_dataset(path)


def test_missing_file_and_folder(tmp_path):
    with pytest.raises(DatasetError, match="does not exist"):
        read_dataset(tmp_path / "nope.parquet")
    with pytest.raises(DatasetError, match="folder"):
        read_dataset(tmp_path)


def test_missing_column(small, tmp_path):
    path = _write_frame(small.frame.drop(columns=["dipper_torque"]), tmp_path / "d.parquet")
    with pytest.raises(DatasetError, match="missing column.*dipper_torque"):
        read_dataset(path)


@pytest.mark.parametrize("column", ["boom_angle", "dipper_angle"])
def test_degrees_instead_of_radians(small, tmp_path, column):
    frame = small.frame.copy()
    frame[column] = np.degrees(frame[column])
    path = _write_frame(frame, tmp_path / "d.parquet")
    with pytest.raises(DatasetError, match=f"{column}.*(radians|degrees)"):
        read_dataset(path)


def test_nan_payload(small, tmp_path):
    frame = small.frame.copy()
    frame.loc[5, "payload"] = np.nan
    path = _write_frame(frame, tmp_path / "d.parquet")
    with pytest.raises(DatasetError, match="payload.*NaN"):
        read_dataset(path)


def test_negative_payload_and_changing_payload(small, tmp_path):
    frame = small.frame.copy()
    frame.loc[:, "payload"] = -frame["payload"] - 1
    with pytest.raises(DatasetError, match="negative"):
        read_dataset(_write_frame(frame, tmp_path / "neg.parquet"))
    frame = small.frame.copy()
    frame.loc[3, "payload"] = frame.loc[3, "payload"] + 10
    with pytest.raises(DatasetError, match="constant within an experiment"):
        read_dataset(_write_frame(frame, tmp_path / "change.parquet"))


def test_time_must_increase(small, tmp_path):
    frame = small.frame.copy()
    frame.loc[4, "time"] = frame.loc[2, "time"]
    with pytest.raises(DatasetError, match="time.*increase"):
        read_dataset(_write_frame(frame, tmp_path / "d.parquet"))


def test_text_column_and_empty_file(small, tmp_path):
    frame = small.frame.copy()
    frame["boom_torque"] = frame["boom_torque"].astype(str)
    with pytest.raises(DatasetError, match="boom_torque.*numeric"):
        read_dataset(_write_frame(frame, tmp_path / "text.parquet"))
    with pytest.raises(DatasetError, match="no rows"):
        read_dataset(_write_frame(small.frame.iloc[:0], tmp_path / "empty.parquet"))


def test_estimates_file_is_not_a_dataset(tmp_path):
    import pandas as pd

    frame = pd.DataFrame({"experiment": [0], "time": [0.0], "payload_estimate": [1.0]})
    with pytest.raises(DatasetError, match="estimates file"):
        read_dataset(_write_frame(frame, tmp_path / "e.parquet"))


def test_bad_metadata_json(small, tmp_path):
    table = pa.Table.from_pandas(small.frame, preserve_index=False)
    table = table.replace_schema_metadata({METADATA_KEY: b"{not json"})
    path = tmp_path / "d.parquet"
    pq.write_table(table, path)
    with pytest.raises(DatasetError, match="not valid JSON"):
        read_dataset(path)


def test_write_is_atomic_and_validates(small, tmp_path):
    path = tmp_path / "d.parquet"
    write_dataset(small, path)
    before = path.read_bytes()
    bad = Dataset(small.frame.assign(payload=np.nan), small.meta)
    with pytest.raises(DatasetError):
        write_dataset(bad, path)
    assert path.read_bytes() == before  # the good file is untouched, no data lost
    assert [p.name for p in tmp_path.iterdir()] == ["d.parquet"]  # no temporary file left


@pytest.mark.parametrize("unit,scale", [("bar", 1e-5), ("kPa", 1e-3), ("MPa", 1e-6), ("psi", 1 / 6894.76),
                                        ("unplugged", 0.0)])
def test_machine_pressures_not_in_pascal_are_refused(unit, scale):
    """Pressures in bar (or kPa, MPa, psi) passed every check and were weighed as Pa: -6200 kg
    'ok' for a 1900 kg payload."""
    from excavator_payload.data.io import validate_frame
    from excavator_payload.errors import DatasetError
    from excavator_payload.simulation.machine_sim import simulate_machine_dataset

    data = simulate_machine_dataset(1, seed=4)
    validate_frame(data.frame, sensor_set="machine")  # in Pa: fine
    frame = data.frame.copy()
    for c in frame.columns:
        if c.endswith("_pressure") and not c.startswith("true_"):
            frame[c] = frame[c] * scale
    with pytest.raises(DatasetError, match="instead of Pa"):
        validate_frame(frame, sensor_set="machine")


@pytest.fixture(scope="module")
def machine_frame():
    from excavator_payload.simulation.machine_sim import simulate_machine_dataset

    return simulate_machine_dataset(3, seed=4).frame


@pytest.mark.parametrize("rate", ["boom_rate", "dipper_rate", "bucket_rate"])
def test_machine_rates_in_degrees_are_refused(machine_frame, rate):
    """Rates in °/s passed every check (< 50 rad/s) and were weighed as rad/s: -3700 kg 'ok' for a
    1890 kg payload. The rate's integral over moving windows is 57.3× its angle's change."""
    from excavator_payload.data.io import validate_frame

    validate_frame(machine_frame, sensor_set="machine")  # rad/s: fine
    frame = machine_frame.copy()
    frame[rate] = np.degrees(frame[rate])
    # (a fast bucket in °/s may already pass 50 "rad/s" and be refused for its magnitude)
    with pytest.raises(DatasetError, match=rf"'{rate}' (is 5\d\.\d times .*°/s instead of rad/s|reaches)"):
        validate_frame(frame, sensor_set="machine")


@pytest.mark.parametrize("rate", ["boom_rate", "dipper_rate", "boom_accel", "dipper_accel"])
def test_thesis_rates_in_degrees_are_refused(small, rate):
    from excavator_payload.data.io import validate_frame

    frame = small.frame.copy()
    validate_frame(frame, sensor_set="thesis")
    frame[rate] = np.degrees(frame[rate])
    with pytest.raises(DatasetError, match=rf"'{rate}' is 5\d\.?\d* times .*instead of rad/s"):
        validate_frame(frame, sensor_set="thesis")


def test_rate_check_survives_nan_gaps_short_and_still_experiments(machine_frame):
    """NaN gaps, a time gap, a 0.3 s experiment and a still one: judged where it can be, never a crash."""
    from excavator_payload.data.io import validate_frame

    frame = machine_frame.copy()
    frame.loc[frame.index[::7], "boom_rate"] = np.nan  # sparse NaNs
    frame.loc[frame.index[100:160], "dipper_angle"] = np.nan  # a hole
    validate_frame(frame, sensor_set="machine")
    frame["bucket_rate"] = np.degrees(frame["bucket_rate"])
    with pytest.raises(DatasetError, match="bucket_rate"):
        validate_frame(frame, sensor_set="machine")
    # A still experiment cannot be judged: degrees or not, it is accepted.
    still = machine_frame[machine_frame["experiment"] == machine_frame["experiment"].iloc[0]].copy()
    for angle, rate in (("boom_angle", "boom_rate"), ("dipper_angle", "dipper_rate"),
                        ("bucket_angle", "bucket_rate")):
        still[angle] = still[angle].iloc[0]
        still[rate] = np.degrees(np.random.default_rng(0).normal(0.0, 0.002, len(still)))
    validate_frame(still, sensor_set="machine")
    # Short experiments (0.3 s each: one window) are judged together.
    short = machine_frame.copy()
    short["experiment"] = short["experiment"] * 1000 + short.groupby("experiment").cumcount() // 30
    short["time"] = short.groupby("experiment").cumcount() * 0.01
    validate_frame(short, sensor_set="machine")
    short["boom_rate"] = np.degrees(short["boom_rate"])
    with pytest.raises(DatasetError, match="boom_rate"):
        validate_frame(short, sensor_set="machine")


@pytest.mark.parametrize("tilt_deg", [0.8, 5.0, 10.0])
def test_house_tilt_in_degrees_is_refused(machine_frame, tilt_deg):
    """A house tilt in degrees reads as that many radians: 5 (a 5° slope) was already refused
    (> 1 rad), 0.8 (46° 'in rad') weighed ~200 kg off, 'ok'. No excavator works on more than 35°.
    A tilt under 0.61° in degrees (< 35° read as rad) cannot be told from a slope."""
    from excavator_payload.data.io import validate_frame

    for column in ("house_pitch", "house_roll"):
        frame = machine_frame.copy()
        frame[column] = frame[column] + np.radians(tilt_deg)
        validate_frame(frame, sensor_set="machine")  # in radians: a slope
        frame[column] = np.degrees(frame[column])
        with pytest.raises(DatasetError, match=rf"'{column}' reaches .* implausible in rad .*degrees"):
            validate_frame(frame, sensor_set="machine")


@pytest.mark.parametrize("sensor_set", ["thesis", "machine"])
def test_a_boom_angle_without_a_finite_value_is_data_not_a_unit(small, machine_frame, sensor_set):
    """A boom angle of NaN everywhere (a logger that lost the IMU) leaked numpy's 'All-NaN slice'
    warning onto stderr; one inf read as "exceeds 2π; angles must be in radians". Both are bad
    samples (invalid_input when estimating), degrees are still refused."""
    import warnings

    from excavator_payload.data.io import validate_frame

    frame = (small.frame if sensor_set == "thesis" else machine_frame).copy()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        validate_frame(frame.assign(boom_angle=np.nan), sensor_set=sensor_set)
        one_inf = frame.copy()
        one_inf.loc[one_inf.index[7], "boom_angle"] = np.inf
        validate_frame(one_inf, sensor_set=sensor_set)
    with pytest.raises(DatasetError, match="boom_angle"):
        validate_frame(frame.assign(boom_angle=np.degrees(frame["boom_angle"])), sensor_set=sensor_set)


def test_an_implausible_pressure_is_not_asked_about_degrees(machine_frame):
    """One pressure sample of 5e8 Pa was refused with "are the units degrees instead of SI?"."""
    from excavator_payload.data.io import validate_frame

    frame = machine_frame.copy()
    frame.loc[frame.index[100], "boom_head_pressure"] = 5e8
    with pytest.raises(DatasetError, match="boom_head_pressure") as info:
        validate_frame(frame, sensor_set="machine")
    assert "degrees" not in str(info.value) and "Pa" in str(info.value)


def test_an_angle_beyond_any_degrees_is_a_glitch_not_a_unit(machine_frame):
    """Six samples of a bucket angle at 1e300 were asked whether the file was in degrees; no angle
    in degrees reaches that. A whole column in degrees is still asked about degrees; both say how
    many samples are beyond."""
    from excavator_payload.data.io import validate_frame

    frame = machine_frame.copy()
    frame.loc[frame.index[100:106], "bucket_angle"] = 1e300
    with pytest.raises(DatasetError, match="bucket_angle") as info:
        validate_frame(frame, sensor_set="machine")
    assert "degrees" not in str(info.value) and "glitch" in str(info.value)
    assert f"6 of {len(frame)} samples beyond" in str(info.value) and "(experiment 0)" in str(info.value)
    degrees = machine_frame.assign(bucket_angle=np.degrees(machine_frame["bucket_angle"]))
    with pytest.raises(DatasetError, match="degrees instead of SI"):
        validate_frame(degrees, sensor_set="machine")


def test_a_true_false_column_is_not_a_measurement(small, tmp_path):
    """A boolean angle column (a flag written where the angle belongs) was read as 0 and 1 rad."""
    frame = small.frame.copy()
    frame["dipper_angle"] = frame["dipper_angle"] > -1.0
    with pytest.raises(DatasetError, match=r"column 'dipper_angle' must be numeric, found bool \(true/false"):
        read_dataset(_write_frame(frame, tmp_path / "d.parquet"))
