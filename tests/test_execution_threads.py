"""Threads per job: a job uses the cores it is given, a local worker its share of them."""

import os

import pytest

from excavator_payload.errors import ExcavatorPayloadError
from excavator_payload.execution import (
    THREADS_ENV,
    Execution,
    default_workers,
    job_threads,
    numeric_threads,
    worker_threads,
)


def worker_thread_settings():
    """What a worker's numerics run with (a task: module level, the workers import it by name)."""
    import torch
    from threadpoolctl import threadpool_info

    return (os.getpid(), job_threads(), torch.get_num_threads(),
            sorted({i["num_threads"] for i in threadpool_info()}))


def test_job_threads_from_the_environment_capped_at_the_cores(monkeypatch):
    cores = len(os.sched_getaffinity(0))
    assert default_workers() == cores
    monkeypatch.setenv(THREADS_ENV, "1")
    assert job_threads() == 1
    monkeypatch.setenv(THREADS_ENV, str(cores + 5))
    assert job_threads() == cores
    for bad in ("0", "-2", "two", "1.5"):
        monkeypatch.setenv(THREADS_ENV, bad)
        with pytest.raises(ExcavatorPayloadError, match=f"^\\${THREADS_ENV} must be a whole number ≥ 1, got"):
            job_threads()
    monkeypatch.delenv(THREADS_ENV)
    assert 1 <= job_threads() <= cores


def test_a_workers_share(monkeypatch):
    monkeypatch.setenv(THREADS_ENV, "1")
    assert worker_threads(1) == 1 and worker_threads(3) == 1  # at least one each
    monkeypatch.delenv(THREADS_ENV)
    assert worker_threads(1) == job_threads()
    assert worker_threads(2) == max(1, job_threads() // 2)


def test_numeric_threads_sets_every_pool_and_restores_it():
    import torch
    from threadpoolctl import threadpool_info

    before_torch = torch.get_num_threads()
    before = {i["filepath"]: i["num_threads"] for i in threadpool_info()}
    with numeric_threads(1):
        assert torch.get_num_threads() == 1
        assert {i["num_threads"] for i in threadpool_info()} == {1}
    assert torch.get_num_threads() == before_torch
    assert {i["filepath"]: i["num_threads"] for i in threadpool_info()} == before


def test_local_workers_run_their_numerics_with_their_share():
    with Execution(workers=2) as execution:
        results = execution.map(worker_thread_settings, [()] * 4, progress=False)
    share = worker_threads(2)
    assert {pid for pid, *_ in results} and os.getpid() not in {pid for pid, *_ in results}
    for _, threads, torch_threads, pools in results:
        assert threads == share and torch_threads == share and pools == [share]
