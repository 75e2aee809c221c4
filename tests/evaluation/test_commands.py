"""``excavator-payload evaluate`` and ``report`` on estimates files (from any tool) and models."""

import json

import numpy as np
import pandas as pd
import pytest

from excavator_payload.cli import main
from excavator_payload.data.io import write_dataset, write_estimates


@pytest.fixture(scope="module")
def files(mj_dataset, tmp_path_factory):
    d = tmp_path_factory.mktemp("cli")
    data = d / "test.parquet"
    write_dataset(mj_dataset, data)
    f = mj_dataset.frame
    plus10 = d / "plus10.parquet"
    write_estimates(pd.DataFrame({"experiment": f["experiment"], "time": f["time"],
                                  "payload_estimate": f["payload"] + 10.0}), plus10)
    # "another tool": no status column, no metadata, rows in another order, early NaNs
    est = f["payload"].to_numpy() - 20.0
    est[f["time"].to_numpy() < 0.2] = np.nan
    other = d / "other.parquet"
    write_estimates(pd.DataFrame({"experiment": f["experiment"], "time": f["time"],
                                  "payload_estimate": est}).iloc[::-1], other)
    return d, data, plus10, other


def test_evaluate_estimates_files(files):
    d, data, plus10, other = files
    out = d / "eval.json"
    assert main(["evaluate", "--data", str(data), "--estimates", str(plus10), "--estimates", str(other),
                 "--discard", "81", "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    assert res["discard"] == 81
    first, second = res["evaluations"]
    assert first["summary"]["mean_max"] == pytest.approx(10.0)
    assert first["summary"]["mean_rms"] == pytest.approx(10.0)
    assert first["summary"]["meets_requirement_share"] == 1.0
    assert len(first["per_experiment"]) == 20
    assert second["summary"]["mean_max"] == pytest.approx(20.0)
    assert second["label"] == "other"
    # with nothing discarded the early NaNs are counted as not estimated
    assert main(["evaluate", "--data", str(data), "--estimates", str(other), "--discard", "0",
                 "--json", str(out)]) == 0
    s = json.loads(out.read_text())["evaluations"][0]["summary"]
    assert s["estimated_share"] == pytest.approx(97 / 101)


def test_default_discard_depends_on_the_sensor_set(files, tmp_path, capsys):
    """--discard defaults to 81 samples on thesis data (20 Hz) and to 1 s = 100 samples on the
    machine set (100 Hz: 81 were 0.81 s), and --help says so; an explicit --discard is kept."""
    from excavator_payload.simulation.machine_sim import simulate_machine_dataset

    d, data, plus10, _ = files
    out = tmp_path / "eval.json"
    assert main(["evaluate", "--data", str(data), "--estimates", str(plus10), "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    assert res["discard"] == 81 and res["evaluations"][0]["per_experiment"][0]["n_judged"] == 101 - 81
    swing = simulate_machine_dataset(1, seed=5, session=2, motion="swing")
    machine_data, machine_est = tmp_path / "swing.parquet", tmp_path / "swing-est.parquet"
    write_dataset(swing, machine_data)
    f = swing.frame
    write_estimates(pd.DataFrame({"experiment": f["experiment"], "time": f["time"],
                                  "payload_estimate": f["payload"] + 10.0}), machine_est)
    for option, discard in (([], 100), (["--discard", "81"], 81)):
        assert main(["evaluate", "--data", str(machine_data), "--estimates", str(machine_est), "--json", str(out),
                     *option]) == 0
        res = json.loads(out.read_text())
        assert res["discard"] == discard
        assert res["evaluations"][0]["per_experiment"][0]["n_judged"] == len(f) - discard
    assert main(["report", "--data", str(machine_data), "--estimates", str(machine_est),
                 "--out", str(tmp_path / "r")]) == 0
    assert json.loads((tmp_path / "r" / "evaluation.json").read_text())["settings"]["discard"] == 100
    capsys.readouterr()
    for command in ("evaluate", "report"):
        assert main([command, "--help"]) == 0
        text = " ".join(capsys.readouterr().out.replace("│", " ").split())
        assert "81 on the thesis sensor set" in text and "100 samples at 100 Hz, on the machine set" in text


def test_evaluate_errors_are_one_line(files, capsys):
    d, data, plus10, _ = files
    assert main(["evaluate", "--data", str(d / "nope.parquet"), "--estimates", str(plus10)]) == 2
    assert main(["evaluate", "--data", str(data)]) == 2
    assert "nothing to evaluate" in capsys.readouterr().err
    assert main(["evaluate", "--data", str(plus10), "--estimates", str(plus10)]) == 2  # estimates as data
    assert main(["evaluate", "--data", str(data), "--estimates", str(data)]) == 2  # data as estimates
    assert main(["evaluate", "--data", str(data), "--model", str(d / "no-model")]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "error:" in err


def test_evaluate_a_saved_model(files, mj_dataset):
    """--model runs the saved estimator on the data (inverse dynamics: quick to fit)."""
    from excavator_payload.errors import EstimatorError
    from excavator_payload.estimators.base import create_estimator

    d, data, _, _ = files
    try:
        est = create_estimator("inverse-dynamics", "cat345c")
    except EstimatorError as exc:
        pytest.skip(f"inverse-dynamics not available: {exc}")
    est.fit(mj_dataset.subset(mj_dataset.experiment_ids[:2])).save(d / "idyn")
    out = d / "model.json"
    assert main(["evaluate", "--data", str(data), "--model", str(d / "idyn"), "--json", str(out)]) == 0
    s = json.loads(out.read_text())["evaluations"][0]
    assert s["info"]["estimator"] == "inverse-dynamics"
    assert s["summary"]["bound_window"] is None
    # exact model, thesis noise: a few kilograms after 4 s of data
    assert s["summary"]["mean_rms"] < 50


def test_report_command(files):
    d, data, plus10, other = files
    out = d / "report"
    assert main(["report", "--data", str(data), "--estimates", str(plus10), "--estimates", str(other),
                 "--out", str(out), "--experiments", "3"]) == 0
    html = (out / "report.html").read_text()
    assert html.count("<img ") == 2 + 3  # fig 7.0, CRB, one experiment × (joints, estimates, zoom)
    assert (out / "report.md").is_file()
    assert main(["report", "--data", str(data), "--estimates", str(plus10), "--out", str(out),
                 "--experiments", "0,999"]) == 2


# -- big datasets on the execution layer ----------------------------------------------------------
def _fitted(name, machine, data, **options):
    from excavator_payload.errors import EstimatorError
    from excavator_payload.estimators.base import create_estimator

    try:
        est = create_estimator(name, machine, **options)
    except EstimatorError as exc:
        pytest.skip(f"{name} not available: {exc}")
    return est.fit(data)


def test_a_big_dataset_is_estimated_on_the_workers_with_the_same_estimates(mj_dataset, monkeypatch):
    from excavator_payload.estimators import running as commands  # estimating in chunks lives there
    from excavator_payload.execution import Execution

    train = mj_dataset.subset(mj_dataset.experiment_ids[:4])
    estimators = [_fitted("inverse-dynamics", "cat345c", train), _fitted("ekf", "cat345c", train, tuning="thesis"),
                  _fitted("net1", None, train, epochs=2, hidden="4", train_experiments=3, validation_experiments=1)]
    with Execution(workers=2) as execution:
        # 20 experiments of a fast estimator: estimated here (no cluster started)
        small = commands.estimate_in_chunks(estimators[0], mj_dataset, chunk=3, execution=execution)
        assert execution._client is None
        pd.testing.assert_frame_equal(small, estimators[0].estimate(mj_dataset), check_exact=True)
        monkeypatch.setattr(commands, "PARALLEL_MIN_SECONDS", 0.0)
        for est in estimators:
            here = est.estimate(mj_dataset)
            there = commands.estimate_in_chunks(est, mj_dataset, chunk=3, execution=execution)
            pd.testing.assert_frame_equal(there, here, check_exact=True, obj=est.name)
        assert execution._cluster is not None  # it did run on worker processes
        pids = execution.client.run(lambda: __import__("os").getpid())
        assert len(pids) == 2


def test_estimate_command_on_workers(files, mj_dataset, monkeypatch, capsys):
    from excavator_payload.data.io import read_estimates
    from excavator_payload.estimators import running as commands  # estimating in chunks lives there

    d, data, _, _ = files
    _fitted("inverse-dynamics", "cat345c", mj_dataset.subset(mj_dataset.experiment_ids[:2])).save(d / "idyn2")
    assert main(["estimate", "--model", str(d / "idyn2"), "--data", str(data), "--out", str(d / "e1.parquet"),
                 "--workers", "1"]) == 0
    monkeypatch.setattr(commands, "PARALLEL_MIN_SECONDS", 0.0)
    real, calls = commands._estimate_on_layer, []

    def spy(*args):
        calls.append(args[3])  # the execution layer the command opened
        return real(*args)

    monkeypatch.setattr(commands, "_estimate_on_layer", spy)
    assert main(["estimate", "--model", str(d / "idyn2"), "--data", str(data), "--out", str(d / "e2.parquet"),
                 "--workers", "2", "--quiet"]) == 0
    pd.testing.assert_frame_equal(read_estimates(d / "e1.parquet"), read_estimates(d / "e2.parquet"),
                                  check_exact=True)
    assert len(calls) == 1 and calls[0].workers == 2
    assert "estimating" in capsys.readouterr().out  # the progress bar of the first run
    assert main(["estimate", "--model", str(d / "idyn2"), "--data", str(data), "--out", str(d / "e3.parquet"),
                 "--workers", "-1"]) == 2


def test_an_experiment_without_any_estimate_is_named_not_averaged_silently(files, mj_dataset, tmp_path, capsys):
    """An experiment whose every estimate is NaN was left out of the MAX and RMS means while the
    title counted it among the experiments: the note names it."""
    d, data, plus10, _ = files
    f = mj_dataset.frame
    est = f["payload"].to_numpy() + 10.0
    lost = int(mj_dataset.experiment_ids[1])
    est[f["experiment"].to_numpy() == lost] = np.nan
    path = tmp_path / "est.parquet"
    write_estimates(pd.DataFrame({"experiment": f["experiment"], "time": f["time"], "payload_estimate": est}), path)
    capsys.readouterr()
    assert main(["evaluate", "--data", str(data), "--estimates", str(path)]) == 0
    out = " ".join(capsys.readouterr().out.split())
    n = mj_dataset.n_experiments
    assert f"1 of {n} experiments have no estimate to judge" in out and f"(experiment {lost}:" in out
    assert main(["evaluate", "--data", str(data), "--estimates", str(plus10)]) == 0
    assert "no estimate to judge" not in capsys.readouterr().out
