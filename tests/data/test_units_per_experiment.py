"""Units judged per experiment and per signal (issue 31, plausible but wrong input).

A file-wide unit check let one experiment in another unit through among others in SI (one
experiment's pressures in bar weighed -8960 kg 'ok'; one calibration experiment in bar
calibrated without a word). Every case runs the command line in-process and asserts exit
status 2 and one line naming the experiment, the column and the unit; clean data pass.
"""

from __future__ import annotations

import json

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from excavator_payload.cli import main
from excavator_payload.data.io import read_dataset, write_dataset
from excavator_payload.data.dataset import Dataset
from excavator_payload.estimators import create_estimator

PRESSURES = ("boom_head_pressure", "boom_rod_pressure", "dipper_head_pressure", "dipper_rod_pressure",
             "bucket_head_pressure", "bucket_rod_pressure")


@pytest.fixture(scope="module")
def machine_data():
    from excavator_payload.simulation.machine_sim import simulate_machine_dataset

    return simulate_machine_dataset(3, seed=4, workers=1)


@pytest.fixture(scope="module")
def thesis_data():
    from excavator_payload.simulation.minimum_jerk import simulate_minimum_jerk

    return simulate_minimum_jerk(4, seed=41, noise="thesis")


def _edited(dataset: Dataset, path, edit) -> str:
    """The dataset with ``edit(frame)`` applied, written without validation (what reading it
    says is the point)."""
    frame = dataset.frame.copy()
    edit(frame)
    table = pa.Table.from_pandas(frame, preserve_index=False).replace_schema_metadata(
        {b"excavator_payload": json.dumps(dataset.meta).encode()})
    pq.write_table(table, path)
    return str(path)


def _one_line_error(capsys, code: int, *fragments: str) -> str:
    captured = capsys.readouterr()
    assert code == 2, captured.err
    lines = [line for line in captured.err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:"), captured.err
    for fragment in fragments:
        assert fragment in lines[0], lines[0]
    return lines[0]


def _experiment(frame, k):
    return frame["experiment"] == frame["experiment"].unique()[k]


def test_one_experiments_pressures_in_bar_are_refused(tmp_path, machine_data, capsys):
    def bar(frame):
        frame.loc[_experiment(frame, 1), list(PRESSURES)] /= 1e5
    bad = _edited(machine_data, tmp_path / "bar.parquet", bar)
    code = main(["can-record", "--data", bad, "--out", str(tmp_path / "x.blf")])
    _one_line_error(capsys, code, "experiment 1", "in bar instead of Pa")
    assert not (tmp_path / "x.blf").exists()


def test_one_signal_of_one_experiment_in_kpa_is_refused(tmp_path, machine_data, capsys):
    def kpa(frame):
        frame.loc[_experiment(frame, 2), "dipper_head_pressure"] /= 1e3
    bad = _edited(machine_data, tmp_path / "kpa.parquet", kpa)
    code = main(["export-mat", "--data", bad, "--out", str(tmp_path / "x.mat")])
    _one_line_error(capsys, code, "experiment 2", "'dipper_head_pressure'", "in kPa instead of Pa")


def test_one_calibration_experiment_in_bar_is_refused_by_train(tmp_path, machine_data, capsys):
    def bar(frame):
        frame.loc[_experiment(frame, 0), list(PRESSURES)] /= 1e5
    bad = _edited(machine_data, tmp_path / "calibration.parquet", bar)
    code = main(["train", "calibrated", "--machine", "cat345c-hydraulic-3pct", "--data", bad,
                 "--out", str(tmp_path / "model")])
    _one_line_error(capsys, code, "experiment 0", "bar")
    assert not (tmp_path / "model" / "estimator.json").exists()


def test_one_experiments_torques_in_knm_are_refused(tmp_path, thesis_data, capsys):
    def knm(frame):
        rows = _experiment(frame, 3)
        frame.loc[rows, ["boom_torque", "dipper_torque"]] /= 1e3
    bad = _edited(thesis_data, tmp_path / "knm.parquet", knm)
    code = main(["export-mat", "--data", bad, "--out", str(tmp_path / "x.mat")])
    _one_line_error(capsys, code, "experiment 3", "kN·m")


def test_a_degree_angle_names_its_experiment(tmp_path, thesis_data, capsys):
    def degrees(frame):
        rows = _experiment(frame, 2)
        frame.loc[rows, "dipper_angle"] = np.degrees(frame.loc[rows, "dipper_angle"])
    bad = _edited(thesis_data, tmp_path / "deg.parquet", degrees)
    code = main(["export-mat", "--data", bad, "--out", str(tmp_path / "x.mat")])
    _one_line_error(capsys, code, "(experiment 2)", "degrees")


def test_clean_data_pass(tmp_path, machine_data, thesis_data):
    for name, data in (("m.parquet", machine_data), ("t.parquet", thesis_data)):
        write_dataset(data, tmp_path / name)
        read_dataset(tmp_path / name)  # no refusal on clean data of either sensor set


def _machine_map(path, pressure_factor: float):
    """The generated machine DBC's signal map, with ``pressure_factor`` on every pressure (a DBC
    whose pressures are in bar, mapped with factor 1, decodes 1e-5 times the Pa)."""
    from excavator_payload.data.schema import get_sensor_set
    from excavator_payload.runtime.dbc import sensor_layout

    text = ""
    for message in sensor_layout(get_sensor_set("machine")):
        for s in message.signals:
            text += f'[signals.{s.signal}]\nmessage = "{s.message}"\nsignal = "{s.name}"\n'
            if s.signal.endswith("_pressure"):
                text += f"factor = {pressure_factor!r}\n"
            text += "\n"
    path.write_text(text)
    return path


def test_can_replay_judges_units_after_the_signal_map(tmp_path, machine_data, capsys):
    from excavator_payload.runtime.dbc import generate_dbc

    data, model, log = tmp_path / "d.parquet", tmp_path / "model", tmp_path / "d.blf"
    # one swing is recorded and replayed (each replay streams every sample through the model)
    write_dataset(machine_data.subset(machine_data.experiment_ids[:1]), data)
    create_estimator("inverse-dynamics", machine="cat345c-hydraulic").fit(machine_data).save(model)
    dbc = tmp_path / "machine.dbc"
    dbc.write_text(generate_dbc("machine"))
    assert main(["can-record", "--data", str(data), "--out", str(log)]) == 0
    capsys.readouterr()
    good = _machine_map(tmp_path / "good.toml", 1.0)
    assert main(["can-replay", "--log", str(log), "--model", str(model), "--out", str(tmp_path / "ok.parquet"),
                 "--dbc", str(dbc), "--signal-map", str(good)]) == 0
    capsys.readouterr()
    in_bar = _machine_map(tmp_path / "bar.toml", 1e-5)
    code = main(["can-replay", "--log", str(log), "--model", str(model), "--out", str(tmp_path / "e.parquet"),
                 "--dbc", str(dbc), "--signal-map", str(in_bar)])
    _one_line_error(capsys, code, "decoded through the signal map", "bar")
    assert not (tmp_path / "e.parquet").exists()
def test_known_loads_in_tonnes_or_pounds_are_refused_at_fit():
    """A calibration file whose payload column is in tonnes (0.4–3.1 for a 5 t machine) was
    refused for its model error ("add calibration motions"), not its unit; one in grams would
    have calibrated 1000 times off. Now fit names the unit; kg pass."""
    from excavator_payload.data.units import check_payload_unit
    from excavator_payload.errors import DatasetError
    from excavator_payload.model.machine import load_machine

    machine = load_machine("cat345c-hydraulic")
    kg = np.array([0.0, 400.6, 3056.4])
    check_payload_unit(kg, machine, "data")
    check_payload_unit(np.zeros(3), machine, "data")  # empty buckets: nothing to judge
    check_payload_unit(kg / 1000, None, "data")  # no machine: nothing to judge
    with pytest.raises(DatasetError, match=r"reach only 3\.056 kg.*in tonnes\?"):
        check_payload_unit(kg / 1000, machine, "data")
    with pytest.raises(DatasetError, match="in pounds or grams"):
        check_payload_unit(kg * 1000, machine, "data")
