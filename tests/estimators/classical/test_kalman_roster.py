"""ekf and ukf run on the thesis sensor set only (issue 28): asked for on the machine sensor set
they refuse in one line that says why and names ``calibrated``; a model folder saved there
before is refused the same way."""

from __future__ import annotations

import json

import pytest

from excavator_payload.cli import main
from excavator_payload.data.io import write_dataset
from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.base import create_estimator, load_estimator
from excavator_payload.estimators.traits import ESTIMATOR_TRAITS, estimators_on, exportable
from excavator_payload.simulation.machine_sim import simulate_machine_dataset
from excavator_payload.simulation.minimum_jerk import simulate_minimum_jerk


@pytest.fixture(scope="module")
def machine_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("machine") / "swing.parquet"
    write_dataset(simulate_machine_dataset(1, seed=5), path)
    return path


def test_the_traits_keep_them_off_the_machine_set():
    for name in ("ekf", "ukf"):
        assert ESTIMATOR_TRAITS[name].sensor_sets == ("thesis",)
        assert name not in estimators_on("machine") and name in estimators_on("thesis")
        assert "'calibrated'" in ESTIMATOR_TRAITS[name].refusal("machine")
        assert ESTIMATOR_TRAITS[name].refusal("thesis") == ""
    assert "ekf" in exportable("c", "thesis") and "ekf" not in exportable("c", "machine")
    assert "calibrated" in estimators_on("machine")


@pytest.mark.parametrize("name", ["ekf", "ukf"])
@pytest.mark.parametrize("machine", [None, "cat345c-hydraulic-3pct", "cat345c"])
def test_train_on_the_machine_set_fails_in_one_line(name, machine, machine_file, tmp_path, capsys):
    argv = ["train", name, "--data", str(machine_file), "--out", str(tmp_path / "m")]
    assert main(argv + (["--machine", machine] if machine else [])) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert "does not run on" in err and "use 'calibrated'" in err and "machine-filters.md" in err
    assert not (tmp_path / "m" / "estimator.json").exists()


def test_the_api_says_the_same(machine_file):
    from excavator_payload.data.io import read_dataset

    with pytest.raises(EstimatorError, match="use 'calibrated'"):
        create_estimator("ekf", "cat345c").fit(read_dataset(machine_file))
    with pytest.raises(EstimatorError, match="use 'calibrated'"):
        create_estimator("ukf", "cat345c-hydraulic")


def test_a_model_saved_on_the_machine_set_is_refused_clearly(tmp_path):
    """A folder saved by an older version (ekf fitted on the machine set): its sensor set is
    what the refusal reads, before anything is rebuilt."""
    folder = tmp_path / "ekf"
    create_estimator("ekf", "cat345c").fit(simulate_minimum_jerk(2, seed=3, noise="thesis")).save(folder)
    assert load_estimator(folder).name == "ekf"  # the thesis model loads
    config = json.loads((folder / "estimator.json").read_text())
    config["sensor_set"] = "machine"
    (folder / "estimator.json").write_text(json.dumps(config))
    with pytest.raises(EstimatorError, match=r"fitted on the machine sensor set, which it no longer runs on.*"
                                             r"use 'calibrated'"):
        load_estimator(folder)
