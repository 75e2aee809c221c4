"""zero command and the machine demo at a tiny scale."""

from excavator_payload.cli import main
from excavator_payload.data.io import write_dataset
from excavator_payload.estimators.base import load_estimator
from excavator_payload.evaluation import demo_machine as dm


def test_train_zero_evaluate_from_the_cli(tmp_path, capsys):
    cal, zero, test = tmp_path / "cal.parquet", tmp_path / "zero.parquet", tmp_path / "test.parquet"
    write_dataset(dm.calibration_data(2, seed=31), cal)
    write_dataset(dm.zero_data(seed=32), zero)
    write_dataset(dm.test_sets(1, seed=33)["swing"], test)
    model, zeroed = tmp_path / "model", tmp_path / "zeroed"
    assert main(["train", "calibrated", "--data", str(cal), "--machine", "cat345c-hydraulic-3pct",
                 "--out", str(model)]) == 0
    assert main(["zero", "--model", str(model), "--data", str(zero), "--out", str(model)]) == 2
    assert "--out must differ" in capsys.readouterr().err
    assert main(["zero", "--model", str(model), "--data", str(cal), "--out", str(zeroed)]) == 2
    assert "empty bucket" in capsys.readouterr().err
    assert main(["zero", "--model", str(model), "--data", str(zero), "--out", str(zeroed)]) == 0
    assert "boom_head_pressure" in capsys.readouterr().out
    before, after = load_estimator(model).calibration, load_estimator(zeroed).calibration
    assert (before.offsets != after.offsets).any()
    assert main(["evaluate", "--data", str(test), "--model", str(zeroed)]) == 0
    out = capsys.readouterr()
    assert "Traceback" not in out.err


def test_machine_demo_tiny(tmp_path):
    assert main(["demo", "--machine", "cat345c-hydraulic", "--scale", "tiny", "--out", str(tmp_path)]) == 0
    report = (tmp_path / "report.md").read_text()
    assert "| swing | calibrated |" in report and "slope-5deg" in report
    assert main(["demo", "--machine", "cat345c", "--scale", "tiny", "--out", str(tmp_path / "x")]) == 2


def test_attainable_reads_twice_the_bound_over_the_judged_window():
    import numpy as np
    import pandas as pd

    from excavator_payload.data.dataset import Dataset

    n = 150
    frame = pd.DataFrame({"experiment": np.repeat([0, 1], n), "time": np.tile(np.arange(n) * 0.01, 2)})
    bound = np.r_[np.full(n, 20.0), np.full(n, 20.0)]
    bound[n + 120] = 30.0  # experiment 1: once, 2σ = 60 kg > 50 kg inside the judged window
    bound[5] = 500.0  # experiment 0: before the judged window, not counted
    ds = Dataset.__new__(Dataset)
    ds.frame = frame
    reach = dm.attainable(ds, bound, 50.0, discard=100)
    assert reach.to_dict() == {0: True, 1: False}
