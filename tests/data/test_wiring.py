"""Wiring mistakes from the arm's balance (issue 31): a cylinder's head and rod pressure columns
swapped passed every check and weighed -13 t 'ok'. The machine's symbolic model says which way
each cylinder must push; a swapped pair's net force has the wrong sign. Through the command line:
exit status 2 and one line naming the cylinder and its two columns.
"""

from __future__ import annotations

import json

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from excavator_payload.cli import main
from excavator_payload.data.wiring import AGREEMENT_LIMIT, balance_agreement
from excavator_payload.estimators import create_estimator


@pytest.fixture(scope="module")
def data():
    from excavator_payload.simulation.machine_sim import simulate_machine_dataset

    return simulate_machine_dataset(3, seed=5, motion="work-cycle", workers=1)


def _swapped(frame, cylinder: str, rows=None):
    frame = frame.copy()
    head, rod = f"{cylinder}_head_pressure", f"{cylinder}_rod_pressure"
    rows = slice(None) if rows is None else rows
    frame.loc[rows, [head, rod]] = frame.loc[rows, [rod, head]].to_numpy().copy()  # no view: both would read rod
    return frame


def _write(path, frame, meta):
    table = pa.Table.from_pandas(frame, preserve_index=False).replace_schema_metadata(
        {b"excavator_payload": json.dumps(meta).encode()})
    pq.write_table(table, path)
    return str(path)


def _one_line(capsys, code):
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error:"), err
    return lines[0]


def test_the_balance_tells_a_swap_from_a_correct_wiring(data):
    """Measured on this data: every cylinder judged, a correct wiring agrees with the model on
    (nearly) all judged samples, a swapped one on (nearly) none."""
    clean = balance_agreement(data.frame, data.sensor_set, data.machine())
    assert set(clean["cylinder"]) == {"boom", "dipper", "bucket"}
    assert clean["agreement"].min() >= 0.95
    for cylinder in ("boom", "dipper", "bucket"):
        table = balance_agreement(_swapped(data.frame, cylinder), data.sensor_set, data.machine())
        mine = table[table["cylinder"] == cylinder]
        assert len(mine) and mine["agreement"].max() <= 0.05
        others = table[table["cylinder"] != cylinder]
        assert others["agreement"].min() >= 0.95  # the other cylinders are not blamed


@pytest.mark.parametrize("cylinder", ["boom", "dipper", "bucket"])
def test_swapped_columns_are_named_by_the_data_machine(tmp_path, data, capsys, cylinder):
    bad = _write(tmp_path / "bad.parquet", _swapped(data.frame, cylinder), data.meta)
    code = main(["can-record", "--data", bad, "--out", str(tmp_path / "x.blf")])
    line = _one_line(capsys, code)
    assert f"'{cylinder}_head_pressure' and '{cylinder}_rod_pressure' swapped" in line
    assert "experiment 0" in line and "3 of 3 experiments alike" in line


def test_one_swapped_experiment_of_a_field_log_is_named_with_the_models_machine(tmp_path, data, capsys):
    """A field log has no machine in its metadata: the model's machine judges it."""
    model = tmp_path / "model"
    create_estimator("inverse-dynamics", machine="cat345c-hydraulic").fit(data).save(model)
    frame = data.frame.drop(columns=["payload"])
    meta = {k: v for k, v in data.meta.items() if k not in ("machine", "experiments")}
    bad = _write(tmp_path / "field.parquet", _swapped(frame, "boom", frame["experiment"] == 2), meta)
    code = main(["estimate", "--model", str(model), "--data", bad, "--out", str(tmp_path / "e.parquet")])
    line = _one_line(capsys, code)
    assert "experiment 2" in line and "'boom_head_pressure' and 'boom_rod_pressure'" in line
    assert not (tmp_path / "e.parquet").exists()
    good = _write(tmp_path / "good.parquet", frame, meta)
    assert main(["estimate", "--model", str(model), "--data", good, "--out", str(tmp_path / "e.parquet"),
                 "--quiet"]) == 0


def test_the_limit_sits_between_what_was_measured():
    assert 0.05 < AGREEMENT_LIMIT < 0.95
