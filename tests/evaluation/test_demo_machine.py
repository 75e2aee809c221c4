"""zero command and the machine demo at a tiny scale."""

from excavator_payload.cli import main
from excavator_payload.data.io import write_dataset
from excavator_payload.estimators.base import load_estimator
from excavator_payload.evaluation import demo_machine as dm
from .._machine_data import swing_test_set


def test_train_zero_evaluate_from_the_cli(tmp_path, capsys):
    cal, zero, test = tmp_path / "cal.parquet", tmp_path / "zero.parquet", tmp_path / "test.parquet"
    write_dataset(dm.calibration_data(2, seed=31), cal)
    write_dataset(dm.zero_data(seed=32), zero)
    write_dataset(swing_test_set(1, seed=33), test)
    model, zeroed = tmp_path / "model", tmp_path / "zeroed"
    assert main(["train", "calibrated", "--data", str(cal), "--machine", "cat345c-hydraulic-3pct",
                 "--out", str(model)]) == 0
    assert main(["zero", "--model", str(model), "--data", str(zero), "--out", str(model)]) == 2
    assert "--out must differ" in capsys.readouterr().err
    # Inside the calibrated model's folder (was accepted), or an existing file (was "Not a directory").
    assert main(["zero", "--model", str(model), "--data", str(zero), "--out", str(model / "zeroed")]) == 2
    assert "refusing to overwrite" in capsys.readouterr().err and not (model / "zeroed").exists()
    (tmp_path / "file").write_text("precious")
    assert main(["zero", "--model", str(model), "--data", str(zero), "--out", str(tmp_path / "file")]) == 2
    assert "is a file; give a folder" in capsys.readouterr().err
    assert (tmp_path / "file").read_text() == "precious"
    assert main(["zero", "--model", str(model), "--data", str(cal), "--out", str(zeroed)]) == 2
    assert "empty bucket" in capsys.readouterr().err
    # two calibration swings weigh worse than 1 % of rated after any zero: refused, saved with --force
    assert main(["zero", "--model", str(model), "--data", str(zero), "--out", str(zeroed)]) == 2
    assert "zero refused" in capsys.readouterr().err and not zeroed.exists()
    assert main(["zero", "--model", str(model), "--data", str(zero), "--out", str(zeroed), "--force"]) == 0
    assert "boom_head_pressure" in capsys.readouterr().out
    before, after = load_estimator(model).calibration, load_estimator(zeroed).calibration
    assert (before.offsets != after.offsets).any()
    assert main(["evaluate", "--data", str(test), "--model", str(zeroed)]) == 0
    out = capsys.readouterr()
    assert "Traceback" not in out.err


def test_machine_demo_tiny_on_a_machine_of_ones_own(tmp_path):
    """The demo on a user's machine file: its rated payload sets the known weights and the 1 %,
    and calibration starts from that machine 3 % off (not from the preset's file)."""
    import dataclasses

    import pandas as pd

    from excavator_payload.model.machine import load_machine

    preset = load_machine("cat345c-hydraulic")
    mine = dataclasses.replace(preset, name="my-35t",
                               bucket=dataclasses.replace(preset.bucket, mass=0.7 * preset.bucket.mass),
                               payload=dataclasses.replace(preset.payload, rated=3500.0, max=3500.0))
    path = tmp_path / "my-35t.toml"
    path.write_text(mine.to_toml())
    out = tmp_path / "demo"
    assert main(["demo", "--machine", str(path), "--scale", "tiny", "--out", str(out)]) == 0
    report = (out / "report.md").read_text()
    assert "| swing | calibrated |" in report and "slope-5deg" in report
    assert "rated payload 3500 kg (1 % = 35 kg)" in report and "`my-35t-3pct`" in report
    assert "(weighing.png)" in report and (out / "weighing.png").stat().st_size > 10_000
    # the networks are said once to be left out (they were announced as fitting, then "not fitted"
    # six times), and a tiny run says its figures mean nothing
    assert report.count("not fitted") == 0 and report.count("Not fitted: net1, net2") == 1
    assert "**Scale `tiny`**" in report and "1 experiment per set" in report
    assert "Failed:" not in report, report  # a refusal is listed as not judged, with its reason
    known = pd.read_parquet(out / "trajectories" / "calibration.parquet")["payload"]
    assert sorted(known.unique()) == [0.0, 1750.0]  # two motions: empty, then half rated
    assert dm.calibration_payloads(path) == (0.0, 1750.0, 3500.0)
    slope = pd.read_parquet(out / "data" / "slope-5deg.parquet")["payload"]
    assert slope.max() <= 3500.0
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


def test_the_reports_table_reads_as_a_table_for_people():
    """report.md: readable headings, shares in per cent, an em dash where there is no value
    (it showed raw column names, shares as 0/1 and `nan`)."""
    import math

    import pandas as pd

    table = pd.DataFrame([{"test": "nmpc", "estimator": "calibrated", "mean_max_kg": 9.614,
                           "within_1pct": 1.0, "within_0.25pct": 0.785, "efficiency": math.nan}])
    text = dm.markdown_table(table)
    assert text.splitlines()[0] == "| test motions | estimator | mean MAX (kg) | MAX ≤ 1 % rated | ≤ 0.25 % | efficiency |"
    assert text.splitlines()[2] == "| nmpc | calibrated | 9.61 | 100% | 78% | — |"


def test_the_recommended_calibration_mix_holds_swings_then_reach_motions():
    """calibration_mix: as many reach motions as `simulate --motion calibration` makes (3 in
    10), after the swings; its trajectory file has the same motions, experiments numbered on."""
    assert [dm.reach_count(n) for n in (1, 2, 3, 5, 9, 10, 13)] == [0, 0, 1, 1, 3, 3, 4]
    mix = dm.calibration_mix(3, 17)
    swings = dm.calibration_data(2, 17)
    assert list(mix.experiment_ids) == [0, 1, 2]
    f = mix.frame
    for k in (0, 1):  # the swings are the study's, unchanged
        a = f[f["experiment"] == k]["boom_angle"].to_numpy()
        b = swings.frame[swings.frame["experiment"] == k]["boom_angle"].to_numpy()
        assert a.shape == b.shape and (a == b).all()
    # the reach motion takes every arm joint through far more of its range than a swing
    spans = f.groupby("experiment")[["boom_angle", "dipper_angle", "bucket_angle"]].agg(lambda x: x.max() - x.min())
    assert (spans.loc[2] > spans.loc[[0, 1]].max()).sum() >= 2
    table = dm.calibration_trajectory(3, 17)
    assert sorted(table["experiment"].unique()) == [0, 1, 2]
    assert set(table["payload"]) <= set(dm.calibration_payloads())
