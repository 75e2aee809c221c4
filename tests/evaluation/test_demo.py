"""A tiny end-to-end demo run: every estimator evaluated or reported failed, reruns reuse the cache."""

import json

import pytest

from excavator_payload.cli import main
from excavator_payload.evaluation import demo as demo_module
from excavator_payload.evaluation.demo import ROSTER, Entry, run_demo


@pytest.fixture(autouse=True)
def one_thread():
    try:
        import torch
    except ImportError:
        return
    torch.set_num_threads(1)


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    code = main(["demo", "--out", str(out), "--scale", "tiny", "--motion", "minimum-jerk", "--seed", "3"])
    return out, code


def test_tiny_demo_end_to_end(tiny_run):
    out, code = tiny_run
    assert code == 0
    html = (out / "report" / "report.html").read_text()
    result = json.loads((out / "report" / "evaluation.json").read_text())
    judged = {ev["label"] for ev in result["evaluations"]}
    failed = set(result["failures"])
    # every estimator of the roster is either judged or reported failed with a reason
    for entry in ROSTER:
        assert entry.label in judged or entry.label in failed, entry.label
        assert entry.label in html
    assert all(reason for reason in result["failures"].values())
    # the exact-model classical estimators are in every installation of this role's siblings
    assert judged, "no estimator could be evaluated"
    s = result["settings"]
    assert s["scale"] == "tiny" and s["base_seed"] == 3 and s["sizes"]["test"] == 6
    assert "versions" in s and "timings_s" in s


def test_rerun_reuses_datasets_models_and_estimates(tiny_run, monkeypatch):
    out, _ = tiny_run
    before = json.loads((out / "report" / "evaluation.json").read_text())

    def no_simulation(*args, **kwargs):
        raise AssertionError("the rerun simulated again")

    def no_fitting(*args, **kwargs):
        raise AssertionError("the rerun fitted again")

    monkeypatch.setattr(demo_module, "simulate", no_simulation)
    monkeypatch.setattr("excavator_payload.estimators.base.create_estimator", no_fitting)
    res = run_demo(out, scale="tiny", motion="minimum-jerk", seed=3)
    assert [ev.label for ev in res["evaluations"]] == [ev["label"] for ev in before["evaluations"]]
    for ev, old in zip(res["evaluations"], before["evaluations"]):
        assert ev.summary["mean_rms"] == pytest.approx(old["summary"]["mean_rms"] or float("nan"), nan_ok=True)


def test_a_failing_estimator_does_not_stop_the_demo(tmp_path, monkeypatch):
    roster = (Entry("inverse-dynamics", "inverse-dynamics"),
              Entry("broken", "ekf", options={"tuning": "no-such-tuning"}),
              Entry("missing", "no-such-estimator"))
    monkeypatch.setattr(demo_module, "ROSTER", roster)
    res = run_demo(tmp_path, scale="tiny", motion="minimum-jerk", seed=4)
    assert set(res["failures"]) == {"broken", "missing"}
    assert "no-such-estimator" in res["failures"]["missing"]
    assert res["report"].is_file()
    assert (tmp_path / "failures.log").is_file()


def test_bad_demo_options_are_clear(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path), "--scale", "huge"]) == 2
    assert main(["demo", "--out", str(tmp_path), "--scale", "tiny", "--motion", "teleport"]) == 2
    assert main(["demo", "--out", str(tmp_path), "--scale", "tiny", "--only", "Net9"]) == 2
    assert "Traceback" not in capsys.readouterr().err


def test_one_execution_layer_for_every_simulated_chunk(tmp_path, monkeypatch):
    """The demo's datasets are cut into cached chunks: they share one execution layer (one local
    cluster), not one each."""
    import dataclasses

    real = demo_module.simulate_dataset
    used = []

    def recording(*args, **kwargs):
        used.append(kwargs.get("execution"))
        return real(*args, **kwargs)

    made = []

    class Counted(demo_module.Execution):
        def __post_init__(self):
            made.append(self)
            super().__post_init__()

    monkeypatch.setattr(demo_module, "simulate_dataset", recording)
    monkeypatch.setattr(demo_module, "Execution", Counted)
    monkeypatch.setattr(demo_module, "ROSTER", (Entry("inverse-dynamics", "inverse-dynamics"),))
    monkeypatch.setitem(demo_module.SCALES, "tiny", dataclasses.replace(demo_module.SCALES["tiny"], chunk=4))
    run_demo(tmp_path, scale="tiny", motion="minimum-jerk", seed=5)
    assert len(used) == 5  # 8 train, 4 validation, 6 test experiments in chunks of at most 4
    assert len(made) == 1 and all(execution is made[0] for execution in used)
    assert made[0]._client is None and made[0]._cluster is None  # closed
