"""Smoke test of ``benchmarks/bench_soak.py``: the streaming sensor replayed with the time going
on (Python ``step_values``, the CAN sensor, the C export) equals batch ``estimate`` sample by
sample, and its comparison catches an estimate that does not."""

import importlib.util
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from excavator_payload.estimators.base import create_estimator
from excavator_payload.runtime.c_harness import c_compiler
from excavator_payload.runtime.codec import SignalCodec
from excavator_payload.simulation.minimum_jerk import simulate_minimum_jerk

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("bench_soak", ROOT / "benchmarks" / "bench_soak.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["bench_soak"] = module  # its dataclasses look their module up
    spec.loader.exec_module(module)
    yield module
    del sys.modules["bench_soak"]


@pytest.fixture(scope="module")
def fitted():
    dataset = simulate_minimum_jerk(2, seed=5, noise="thesis")
    return dataset, create_estimator("inverse-dynamics").fit(dataset)


def test_log_stream_has_gaps_between_experiments(bench, fitted):
    dataset, est = fitted
    log = bench.make_log(est, dataset, gap=3.0)
    steps = np.diff(log.times)
    assert np.allclose(steps[~log.starts[1:]], 0.05)
    assert np.allclose(steps[log.starts[1:]], 3.0) and log.starts.sum() == 2
    assert log.span == pytest.approx(log.times[-1] - log.times[0] + 3.0)


def test_python_paths_equal_batch_over_copies(bench, fitted):
    dataset, est = fitted
    log = bench.make_log(est, dataset, gap=3.0)
    blocks = bench.soak_step(est, log, 2000, 500)   # ten copies of the log
    assert [b.samples for b in blocks] == [500, 1000, 1500, 2000]
    assert sum(b.differing for b in blocks) == 0 and all(b.rss_kb > 0 for b in blocks)
    codec = SignalCodec.for_sensor_set(dataset.sensor_set)
    blocks = bench.soak_can(est, bench.make_log(est, dataset, 3.0, codec), codec, 1000, 500)
    assert sum(b.differing for b in blocks) == 0 and blocks[-1].samples == 1000
    # the comparison can fail: batch's answer off by 0.01 kg at one sample of the log
    wrong = replace(log, estimate=log.estimate + np.where(np.arange(len(log.times)) == 150, 0.01, 0.0))
    blocks = bench.soak_step(est, wrong, 1000, 500)
    assert sum(b.differing for b in blocks) == (np.arange(1000) % len(log.times) == 150).sum() == 5


@pytest.mark.skipif(c_compiler() is None, reason="no C compiler")
def test_c_export_equals_batch_over_copies(bench, fitted, tmp_path):
    dataset, est = fitted
    log = bench.make_log(est, dataset, gap=3.0)
    blocks = bench.soak_c(est, log, 10_000, 2500, tmp_path)
    assert [b.samples for b in blocks] == [2500, 5000, 7500, 10_000]
    assert sum(b.differing for b in blocks) == 0 and all(b.rss_kb > 0 for b in blocks)
    # the comparison can fail: a status, or an estimate 0.01 kg off at one sample of the log
    wrong = replace(log, status=["ok" if s == "warming_up" else "warming_up" for s in log.status])
    assert bench.soak_c(est, wrong, 1000, 1000, tmp_path / "status")[0].differing > 0
    wrong = replace(log, estimate=log.estimate + np.where(np.arange(len(log.times)) == 150, 0.01, 0.0))
    block, = bench.soak_c(est, wrong, 1000, 1000, tmp_path / "estimate")
    assert block.differing == 5 and block.max_diff == pytest.approx(0.01, rel=1e-6)
