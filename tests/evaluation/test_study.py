"""Studies: the grid of a study file, per-experiment results, reuse of computed cells, the report."""

import os
import shutil
import subprocess
import sys
import tomllib
import zipfile
from importlib import resources
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from excavator_payload.cli import main
from excavator_payload.evaluation import study as study_module
from excavator_payload.evaluation.metrics import evaluate_estimates
from excavator_payload.evaluation.study import (
    StudyError,
    data_specs,
    load_study,
    find_study,
    parse_study,
    run_study,
    shipped_studies,
)
from excavator_payload.execution import Execution

TINY = """
name = "tiny"
[grid]
noise = ["thesis", "field"]
motion = ["minimum-jerk"]
test_experiments = [3]
fit_experiments = [4]
[[estimators]]
name = "inverse-dynamics"
[[estimators]]
name = "calibrated"
label = "cal"
machine = "cat345c-3pct"
fit_experiments = [2, 4]
"""


def _write(tmp_path, text, name="s.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_the_grid_is_the_product_of_the_axes_per_estimator():
    s = parse_study(tomllib.loads(TINY))
    assert len(s.cells) == 2 + 2 * 2  # ID: 2 noises; calibrated: 2 noises × 2 fit sizes
    cal = [c for c in s.cells if c.label == "cal"]
    assert {(c.noise, c.fit_experiments) for c in cal} == {("thesis", 2), ("thesis", 4), ("field", 2), ("field", 4)}
    assert all(c.machine == "cat345c-3pct" for c in cal)
    assert s.rows == "estimator" and s.columns == "noise"  # the first axis that varies
    assert s.axes["fit_experiments"] == [4, 2]


def test_fit_and_test_data_never_share_experiments_and_frozen_modes():
    s = parse_study(tomllib.loads(TINY.replace('[grid]', '[grid]\nnoise_mode = ["frozen-mismatch"]')))
    fit, test = data_specs(s.cells[0])
    assert fit.seed != test.seed and fit.with_truth and test.with_truth
    assert fit.frozen_noise_seed == study_module.FROZEN_SEED != test.frozen_noise_seed


@pytest.mark.parametrize("change, message", [
    (('name = "inverse-dynamics"', 'name = "oracle"'), "unknown estimator"),
    (('noise = ["thesis", "field"]', 'noise = ["loud"]'), "unknown noise 'loud'"),
    (('motion = ["minimum-jerk"]', 'motion = ["teleport"]'), "unknown motion"),
    (('test_experiments = [3]', 'test_experiments = [0]'), "test_experiments must be"),
    (('[grid]', '[grid]\ncolour = ["red"]'), "unknown key"),
    (('machine = "cat345c-3pct"', 'machine = "nope.toml"'), "nope.toml"),
    (('label = "cal"', 'label = "cal"\noptions = { speed = 3 }'), "unknown option"),
])
def test_bad_study_files_are_one_clear_error(change, message):
    with pytest.raises(StudyError, match=message):
        parse_study(tomllib.loads(TINY.replace(*change)))


def test_missing_and_malformed_files(tmp_path):
    with pytest.raises(StudyError, match="does not exist"):
        load_study(tmp_path / "none.toml")
    with pytest.raises(StudyError, match="TOML"):
        load_study(_write(tmp_path, "name = [unclosed"))


SHIPPED = {"full_grid", "network_robustness", "calibration_curve", "frozen_noise"}


def test_shipped_studies_parse():
    shipped = shipped_studies()
    assert SHIPPED <= set(shipped)
    # They are package resources, not files found next to the sources.
    package = resources.files("excavator_payload")
    assert all(Path(str(f)).parent == Path(str(package / "studies")) for f in shipped.values())
    assert find_study("full_grid.toml").read_text() == find_study("full_grid").read_text()
    full = load_study("full_grid")  # found by name
    assert len(full.axes["estimator"]) == 10 and len(full.axes["noise"]) == 3 and len(full.axes["motion"]) == 3
    assert {c.test_experiments for c in full.cells} == {200}


def test_shipped_studies_are_in_the_wheel(tmp_path):
    """A wheel built from the sources carries the study files, and an installed copy of it
    resolves them by name (``study --config full_grid`` after ``pip install .``)."""
    pytest.importorskip("setuptools")
    root = Path(__file__).resolve().parents[2]
    source = tmp_path / "source"  # a copy: building writes build/ and *.egg-info next to the sources
    shutil.copytree(root / "src", source / "src", ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
    shutil.copy(root / "pyproject.toml", source)
    shutil.copy(root / "README.md", source)
    built = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
                            "-w", str(tmp_path / "wheel"), str(source)], capture_output=True, text=True)
    assert built.returncode == 0, built.stderr[-2000:]
    wheel = next((tmp_path / "wheel").glob("*.whl"))
    names = set(zipfile.ZipFile(wheel).namelist())
    assert {f"excavator_payload/studies/{name}.toml" for name in SHIPPED} <= names
    installed = tmp_path / "installed"
    zipfile.ZipFile(wheel).extractall(installed)  # a pure-Python wheel installs by unpacking
    check = ("import excavator_payload, sys; from excavator_payload.evaluation.study import find_study; "
             "assert excavator_payload.__file__.startswith(sys.argv[1]), excavator_payload.__file__; "
             "print(find_study('full_grid').read_text(), end='')")
    env = {**os.environ, "PYTHONPATH": str(installed)}
    ran = subprocess.run([sys.executable, "-c", check, str(installed)], capture_output=True, text=True,
                         cwd=tmp_path, env=env)
    assert ran.returncode == 0, ran.stderr[-2000:]
    assert ran.stdout == (root / "src/excavator_payload/studies/full_grid.toml").read_text()


def test_study_results_reuse_and_report(tmp_path):
    out = tmp_path / "out"
    s = load_study(_write(tmp_path, TINY))
    with Execution(workers=1) as execution:
        first = run_study(s, out, execution, progress=False)
    assert first["computed"] == 6 and first["reused"] == 0 and not first["failures"]
    results = pd.read_parquet(out / "results.parquet")
    assert len(results) == 6 * 3  # one row per test experiment per cell
    assert {"estimator", "noise", "motion", "fit_experiments", "seed", "max_error", "rms_error",
            "efficiency", "within_1pct"} <= set(results.columns)

    # The per-experiment figures are evaluation/metrics.py's on the cell's own data.
    from excavator_payload.data.io import read_dataset
    from excavator_payload.estimators import create_estimator

    cell = next(c for c in s.cells if c.label == "inverse-dynamics" and c.noise == "field")
    fit_spec, test_spec = data_specs(cell)
    fit = read_dataset(out / "data" / f"{study_module.spec_key(fit_spec)}.parquet")
    test = read_dataset(out / "data" / f"{study_module.spec_key(test_spec)}.parquet")
    assert test.meta["noise"] == "field" and test.n_experiments == 3
    expected = evaluate_estimates(test, create_estimator("inverse-dynamics").fit(fit).estimate(test))
    got = results[(results.estimator == "inverse-dynamics") & (results.noise == "field")]
    np.testing.assert_allclose(got["rms_error"].to_numpy(), expected.per_experiment["rms_error"].to_numpy())

    html = (out / "report" / "report.html").read_text()
    figures = ("heatmap_efficiency", "heatmap_within_1pct", "error_vs_noise", "error_vs_fit_experiments",
               "error_vs_machine")  # every axis that varies
    for figure in figures:
        assert (out / "report" / "figures" / f"{figure}.png").stat().st_size > 1000
        assert f"figures/{figure}.png" in html
    assert html.count("<img src='data:image/png;base64,") == len(figures)

    # A grown grid computes only the new cells.
    grown = load_study(_write(tmp_path, TINY.replace('noise = ["thesis", "field"]',
                                                     'noise = ["thesis", "field", "none"]')))
    with Execution(workers=1) as execution:
        second = run_study(grown, out, execution, progress=False)
    assert second["reused"] == 6 and second["computed"] == 3
    assert len(pd.read_parquet(out / "results.parquet")) == 9 * 3


def test_a_failing_fit_is_reported_not_fatal(tmp_path, monkeypatch):
    real = study_module.fit_task

    def broken(estimator, *args):
        if estimator == "calibrated":
            return {"error": "fit: EstimatorError: broken on purpose"}
        return real(estimator, *args)

    monkeypatch.setattr(study_module, "fit_task", broken)
    with Execution(workers=1) as execution:
        result = run_study(load_study(_write(tmp_path, TINY)), tmp_path / "out", execution, progress=False)
    assert result["computed"] == 2 and len(result["failures"]) == 4
    assert all("broken on purpose" in r for r in result["failures"].values())
    assert "broken on purpose" in (tmp_path / "out" / "report" / "report.html").read_text()


def test_study_command(tmp_path, capsys):
    config = _write(tmp_path, TINY.replace('fit_experiments = [2, 4]', 'fit_experiments = [2]'))
    out = tmp_path / "out"
    assert main(["study", "--config", str(config), "--out", str(out), "--workers", "1", "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "4 cells: 4 computed, 0 reused, 0 failed" in text and "report.html" in text
    assert main(["study", "--config", str(tmp_path / "missing.toml"), "--out", str(out)]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_ctrl_c_keeps_finished_cells_and_says_so(tmp_path, capsys, monkeypatch):
    config = _write(tmp_path, TINY)
    real = study_module.score_task
    calls = []

    def interrupted(cell, *args):
        if calls:
            raise KeyboardInterrupt
        calls.append(cell)
        return real(cell, *args)

    monkeypatch.setattr(study_module, "score_task", interrupted)
    out = tmp_path / "out"
    assert main(["study", "--config", str(config), "--out", str(out), "--workers", "1", "--quiet"]) == 130
    assert "rerun the same command to resume" in capsys.readouterr().err
    assert len(list((out / "cells").glob("*.parquet"))) == 1
    monkeypatch.setattr(study_module, "score_task", real)
    assert main(["study", "--config", str(config), "--out", str(out), "--workers", "1", "--quiet"]) == 0
    assert "5 computed, 1 reused" in capsys.readouterr().out
