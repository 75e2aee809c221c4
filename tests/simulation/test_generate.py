"""Dataset generation: same data whatever the worker count; interrupted runs resume."""

import json

import numpy as np
import pandas as pd
import pytest

from excavator_payload.data.io import read_dataset
from excavator_payload.errors import ExcavatorPayloadError
from excavator_payload.simulation import generate
from excavator_payload.simulation.generate import partial_folder, simulate_dataset, simulate_to_file
from excavator_payload.simulation.nmpc import ControlFailure

DETERMINISTIC = ("experiment", "seed", "payload", "start_pose", "target_pose", "final_error_deg",
                 "reached", "settle_time", "n_fallbacks")


def _same(a, b):
    pd.testing.assert_frame_equal(a.frame, b.frame)
    for ma, mb in zip(a.meta["experiments"], b.meta["experiments"], strict=True):
        assert {k: ma[k] for k in DETERMINISTIC} == {k: mb[k] for k in DETERMINISTIC}


@pytest.fixture(scope="module")
def reference():
    """Four NMPC experiments of seed 21 in this process (one worker)."""
    return simulate_dataset(4, seed=21, workers=1, noise="thesis", with_truth=True, progress=False)


def test_dataset_shape_and_noise(reference):
    assert reference.n_experiments == 4
    assert list(reference.experiment_ids) == [0, 1, 2, 3]
    assert reference.meta["motion"] == "nmpc" and reference.meta["skipped"] == []
    assert reference.has_truth
    noise = reference.signals(["boom_torque"]) - reference.signals(["true_boom_torque"])
    assert 500 < noise.std() < 1500  # thesis preset: σ = 1000 N·m
    assert all(m["reached"] for m in reference.meta["experiments"])


def test_same_data_whatever_the_worker_count(reference):
    parallel = simulate_dataset(4, seed=21, workers=2, noise="thesis", with_truth=True, progress=False)
    _same(reference, parallel)


def test_first_experiment_offset_gives_the_same_experiments(reference):
    tail = simulate_dataset(1, seed=21, workers=1, noise="thesis", with_truth=True,
                            first_experiment=3, progress=False)
    pd.testing.assert_frame_equal(tail.frame, reference.subset([3]).frame)


def test_other_seed_other_data(reference):
    other = simulate_dataset(1, seed=22, workers=1, progress=False)
    assert other.payloads[0] != reference.payloads[0]


def test_interrupted_run_resumes(reference, tmp_path, monkeypatch):
    out = tmp_path / "d.parquet"
    real_chunk = generate.simulate_chunk
    calls = []

    def interrupted(spec, first, count):
        if calls:
            raise KeyboardInterrupt  # the user presses Ctrl-C during the second chunk
        calls.append(first)
        return real_chunk(spec, first, count)

    monkeypatch.setattr(generate, "simulate_chunk", interrupted)
    with pytest.raises(KeyboardInterrupt):
        simulate_to_file(out, 4, seed=21, noise="thesis", with_truth=True, workers=1, progress=False)
    assert not out.exists()
    folder = partial_folder(out)
    assert len(list(folder.glob("chunk_*.parquet"))) == 1
    assert json.loads((folder / "run.json").read_text())["seed"] == 21

    # Resuming with other settings is refused (the checkpoints would not fit).
    with pytest.raises(ExcavatorPayloadError, match="other settings"):
        simulate_to_file(out, 4, seed=99, noise="thesis", with_truth=True, workers=1, progress=False)

    resumed = []

    def counting(spec, first, count):
        resumed.append(first)
        return real_chunk(spec, first, count)

    monkeypatch.setattr(generate, "simulate_chunk", counting)
    simulate_to_file(out, 4, seed=21, noise="thesis", with_truth=True, workers=1, progress=False)
    assert calls[0] not in resumed and sorted(resumed + calls) == [0, 1, 2, 3]
    assert not folder.exists()
    _same(read_dataset(out), reference)


def test_a_failing_experiment_is_skipped_with_its_reason(monkeypatch):
    real = generate.simulate_nmpc_experiment

    def flaky(experiment, *args):
        if experiment == 1:
            raise ControlFailure("NMPC failed: sqpmethod and IPOPT fallback (test)")
        return real(experiment, *args)

    monkeypatch.setattr(generate, "simulate_nmpc_experiment", flaky)
    ds = simulate_dataset(3, seed=21, workers=1, progress=False)
    assert list(ds.experiment_ids) == [0, 2]
    assert ds.meta["skipped"] == [{"experiment": 1,
                                   "reason": "ControlFailure: NMPC failed: sqpmethod and IPOPT fallback (test)"}]
    assert generate.summary(ds)["written"] == 2


def test_delegated_motions(tmp_path):
    from excavator_payload.simulation.minimum_jerk import simulate_minimum_jerk

    ds = simulate_dataset(3, seed=4, motion="minimum-jerk", progress=False)
    pd.testing.assert_frame_equal(ds.frame, simulate_minimum_jerk(3, seed=4).frame)
    out = tmp_path / "mj.parquet"
    simulate_to_file(out, 3, seed=4, motion="minimum-jerk", progress=False)
    assert read_dataset(out).meta["motion"] == "minimum-jerk"


@pytest.mark.parametrize("kwargs, message", [
    ({"n_experiments": 0}, "number of experiments"),
    ({"n_experiments": 2, "seed": -1}, "seed"),
    ({"n_experiments": 2, "workers": 0}, "workers"),
    ({"n_experiments": 2, "motion": "teleport"}, "unknown motion"),
    ({"n_experiments": 2, "noise": "loud"}, "unknown noise preset"),
    ({"n_experiments": 2, "machine": "cat999"}, "unknown machine"),
])
def test_bad_arguments(kwargs, message):
    with pytest.raises(ExcavatorPayloadError, match=message):
        simulate_dataset(progress=False, **kwargs)


def test_output_folder_is_refused(tmp_path):
    with pytest.raises(ExcavatorPayloadError, match="folder"):
        simulate_to_file(tmp_path, 2, progress=False)


def test_chunk_sizes():
    assert generate.chunk_size_for(4) == 1
    assert generate.chunk_size_for(200) == 5
    assert generate.chunk_size_for(100_000) == 25
    assert generate.chunk_size_for(200, "minimum-jerk") == 200  # cheap: one chunk, in this process
    chunks = generate._chunks(0, 11, 5)
    assert chunks == [(0, 5), (5, 5), (10, 1)]
    assert np.sum([c for _, c in chunks]) == 11


def test_unwritable_output_is_a_clear_error(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(ExcavatorPayloadError, match="cannot write"):
        simulate_to_file(blocker / "sub" / "d.parquet", 2, workers=1, progress=False)
