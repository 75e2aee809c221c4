"""The execution layer: where tasks run, shared arguments, retries, lost workers, clean shutdown,
and the same simulated bits in this process, on a local cluster and on a cluster started with
``dask scheduler`` / ``dask worker``."""

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pandas as pd
import pytest

import excavator_payload
from excavator_payload.errors import ExcavatorPayloadError
from excavator_payload.execution import (
    SCHEDULER_ENV,
    WORKER_TIMEOUT_ENV,
    Execution,
    SchedulerError,
    Shared,
    scheduler_address,
    worker_timeout,
)
from excavator_payload.simulation.generate import simulate_dataset

SRC = str(Path(excavator_payload.__file__).resolve().parents[1])


# -- task functions (module level: the workers import them by name) -----------------------------
def pid_and_square(x):
    return os.getpid(), x * x


def length_of(shared, extra):
    return len(shared) + extra


def fail_first_time(marker):
    """Raises on the first call (leaving a marker file), succeeds afterwards."""
    marker = Path(marker)
    if not marker.exists():
        marker.write_text("failed once")
        raise RuntimeError("transient failure")
    return "ok"


class BadInput(ExcavatorPayloadError):
    """A user error raised inside a task."""


def bad_input_counted(log, bad):
    """Appends a line to ``log`` at every call; raises a user error if ``bad``."""
    with open(log, "a") as fh:
        fh.write("call\n")
    if bad:
        raise BadInput("experiment 7: the payload column is missing")
    time.sleep(0.5)
    return "ok"


def die_first_time(marker):
    """Kills its own worker process on the first call: the task must be rerun elsewhere."""
    marker = Path(marker)
    if not marker.exists():
        marker.write_text(str(os.getpid()))
        os.kill(os.getpid(), signal.SIGKILL)
    return os.getpid()


@pytest.fixture(scope="module")
def cluster():
    """One local cluster of two worker processes for this module."""
    with Execution(workers=2) as execution:
        execution.client.wait_for_workers(2, timeout=60)
        yield execution


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # A zombie (exited, not yet reaped) is not alive either.
    try:
        return Path(f"/proc/{pid}/stat").read_text().split()[2] != "Z"
    except OSError:
        return False


def _wait_dead(pids, timeout=20.0) -> list[int]:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        alive = [p for p in pids if _alive(p)]
        if not alive:
            return []
        time.sleep(0.2)
    return [p for p in pids if _alive(p)]


# -- addresses --------------------------------------------------------------------------------
def test_scheduler_address_from_argument_or_environment(monkeypatch):
    monkeypatch.delenv(SCHEDULER_ENV, raising=False)
    assert scheduler_address(None) is None
    assert scheduler_address("10.0.0.5:8786") == "tcp://10.0.0.5:8786"
    monkeypatch.setenv(SCHEDULER_ENV, "tcp://head:8786")
    assert scheduler_address(None) == "tcp://head:8786"
    assert scheduler_address("other:1") == "tcp://other:1"  # the option wins
    with pytest.raises(SchedulerError, match="HOST:PORT"):
        scheduler_address("no-port")


def test_unreachable_scheduler_is_a_clear_error(monkeypatch):
    monkeypatch.setattr("excavator_payload.execution.CONNECT_TIMEOUT", 1.0)
    with Execution("tcp://127.0.0.1:9") as execution, pytest.raises(SchedulerError, match="cannot reach"):
        execution.map(pid_and_square, [(1,), (2,)], progress=False)


def test_a_port_where_no_dask_scheduler_answers_is_a_clear_error_not_a_hang(monkeypatch):
    """`--scheduler` at an HTTP server (e.g. Dask's dashboard port) hung for ever in the handshake."""
    import http.server
    import threading

    monkeypatch.setattr("excavator_payload.execution.CONNECT_TIMEOUT", 2.0)
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), http.server.SimpleHTTPRequestHandler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    address = f"tcp://127.0.0.1:{server.server_address[1]}"
    outcome = []

    def run():
        try:
            with Execution(address) as execution:
                execution.map(pid_and_square, [(1,), (2,)], progress=False)
        except BaseException as exc:  # noqa: BLE001 - the test looks at it
            outcome.append(exc)

    try:
        thread = threading.Thread(target=run, daemon=True)
        start = time.monotonic()
        thread.start()
        thread.join(timeout=30)
        assert not thread.is_alive(), "still waiting for the handshake after 30 s"
    finally:
        server.shutdown()
        server.server_close()
    assert time.monotonic() - start < 15
    assert len(outcome) == 1 and isinstance(outcome[0], SchedulerError), outcome
    message = str(outcome[0])
    assert "\n" not in message
    assert f"cannot reach the Dask scheduler at {address}: no Dask answer within 2 s" in message


def test_bad_worker_count():
    with pytest.raises(excavator_payload.errors.ExcavatorPayloadError, match="workers"):
        Execution(workers=0)


def test_a_script_without_main_guard_runs_in_this_process_with_one_warning(tmp_path):
    """`python api.py` calling the API at top level, no `if __name__ == "__main__":`: each new
    worker process re-runs the script and fails to start (~520 lines of traceback); the job runs
    in this process instead, with one warning naming the line to guard."""
    script = tmp_path / "api.py"
    script.write_text(textwrap.dedent("""\
        from excavator_payload.execution import Execution
        with Execution(workers=2) as execution:
            print(execution.map(abs, [(-1,), (-2,), (-3,)], progress=False), execution._cluster is None)
        from excavator_payload.execution import unguarded_main_line
        def called():
            return unguarded_main_line()
        print("unguarded", called())
        print("cell", eval(compile("unguarded_main_line()", "<cell>", "eval")))  # a notebook's
        if __name__ == "__main__":
            print("guarded", unguarded_main_line(), called())
        """))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([SRC, os.environ.get("PYTHONPATH", "")])}
    env.pop(SCHEDULER_ENV, None)
    done = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == ["[1, 2, 3] True", f"unguarded ('{script}', 7)", "cell None",
                                        "guarded None None"]
    assert "Traceback" not in done.stderr and "Nanny" not in done.stderr
    warning = [line for line in done.stderr.splitlines() if "InProcessWarning" in line]
    assert len(warning) == 1 and 'if __name__ == "__main__":' in warning[0] and "api.py line 3" in warning[0]


# -- in this process ----------------------------------------------------------------------------
def test_one_worker_or_one_task_runs_in_this_process():
    with Execution(workers=1) as execution:
        results = execution.map(pid_and_square, [(2,), (3,)], progress=False)
        assert execution._cluster is None
    assert results == [(os.getpid(), 4), (os.getpid(), 9)]
    with Execution(workers=2) as execution:
        assert execution.map(length_of, [(Shared([1, 2]), 1)], progress=False) == [3]
        assert execution._cluster is None


# -- on a local cluster ------------------------------------------------------------------------
def test_results_in_task_order_and_callbacks_as_they_finish(cluster):
    seen = []
    results = cluster.map(pid_and_square, [(k,) for k in range(6)], progress=False,
                          on_done=lambda i, r: seen.append(i))
    assert [r[1] for r in results] == [k * k for k in range(6)]
    assert sorted(seen) == list(range(6))
    assert os.getpid() not in {r[0] for r in results}


def test_shared_arguments_reach_every_task(cluster):
    big = list(range(1000))
    assert cluster.map(length_of, [(Shared(big), k) for k in range(3)], progress=False) == [1000, 1001, 1002]


def test_a_failing_task_is_retried(cluster, tmp_path):
    assert cluster.map(fail_first_time, [(str(tmp_path / "m1"),), (str(tmp_path / "m2"),)],
                       progress=False) == ["ok", "ok"]


def test_a_user_error_fails_at_once_without_retries(cluster, tmp_path):
    log = tmp_path / "calls"
    with pytest.raises(BadInput, match="^experiment 7: the payload column is missing$"):
        cluster.map(bad_input_counted, [(str(log), True), (str(tmp_path / "other"), False)], progress=False)
    assert log.read_text().count("call") == 1  # run once, not 1 + retries times


def test_a_task_whose_worker_dies_is_rerun(cluster, tmp_path):
    marker = tmp_path / "died"
    pids = cluster.map(die_first_time, [(str(marker),), (str(tmp_path / "other"),)], progress=False)
    assert int(marker.read_text()) not in pids  # the first attempt's worker is gone
    cluster.client.wait_for_workers(2, timeout=60)  # the nanny started a new one


def test_same_bits_on_a_local_cluster(cluster):
    here = simulate_dataset(3, seed=31, workers=1, noise="thesis", with_truth=True, progress=False)
    there = simulate_dataset(3, seed=31, noise="thesis", with_truth=True, progress=False, execution=cluster)
    pd.testing.assert_frame_equal(here.frame, there.frame, check_exact=True)


def test_workers_do_not_outlive_the_execution():
    with Execution(workers=2) as execution:
        execution.map(pid_and_square, [(1,), (2,)], progress=False)
        pids = list(execution.client.run(os.getpid).values())
    assert pids and _wait_dead(pids) == []


def test_workers_die_with_a_killed_parent(tmp_path):
    """kill -9 of the command leaves no worker process behind."""
    script = textwrap.dedent(f"""
        import json, os, sys, time
        sys.path.insert(0, {SRC!r})
        from excavator_payload.execution import Execution
        if __name__ == "__main__":
            with Execution(workers=2) as ex:
                ex.client.wait_for_workers(2, timeout=60)
                print(json.dumps(list(ex.client.run(os.getpid).values())), flush=True)
                time.sleep(120)
    """)
    path = tmp_path / "parent.py"
    path.write_text(script)
    parent = subprocess.Popen([sys.executable, str(path)], stdout=subprocess.PIPE, text=True)
    try:
        pids = json.loads(parent.stdout.readline())
    finally:
        parent.kill()
        parent.wait(timeout=30)
    assert len(pids) == 2 and _wait_dead(pids) == []


# -- a cluster started from the command line -----------------------------------------------------
def _start_scheduler(tmp_path, env) -> tuple[subprocess.Popen, str]:
    """``dask scheduler`` in a subprocess; returns it and its address."""
    address_file = tmp_path / "scheduler.json"
    proc = subprocess.Popen([sys.executable, "-m", "dask", "scheduler", "--host", "127.0.0.1", "--port", "0",
                             "--no-dashboard", "--scheduler-file", str(address_file)],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 30
    while not address_file.exists() and time.monotonic() < deadline:
        time.sleep(0.1)
    return proc, json.loads(address_file.read_text())["address"]


def _stop(procs) -> None:
    for p in reversed(procs):
        p.terminate()
    for p in procs:
        try:
            p.wait(timeout=20)
        except subprocess.TimeoutExpired:
            p.kill()


def test_worker_timeout_from_argument_or_environment(monkeypatch):
    monkeypatch.delenv(WORKER_TIMEOUT_ENV, raising=False)
    assert worker_timeout() == 60.0
    monkeypatch.setenv(WORKER_TIMEOUT_ENV, "2.5")
    assert worker_timeout() == 2.5 and Execution(workers=1).worker_timeout == 2.5
    assert worker_timeout(7) == 7.0
    monkeypatch.setenv(WORKER_TIMEOUT_ENV, "soon")
    with pytest.raises(SchedulerError, match=WORKER_TIMEOUT_ENV):
        worker_timeout()
    with pytest.raises(SchedulerError, match="positive"):
        worker_timeout(0)


def test_a_scheduler_without_workers_times_out_with_one_line(tmp_path):
    proc, address = _start_scheduler(tmp_path, dict(os.environ))
    try:
        start = time.monotonic()
        with Execution(address, worker_timeout=2.0) as execution, \
                pytest.raises(SchedulerError) as caught:
            execution.map(pid_and_square, [(1,), (2,)], progress=False)
        assert time.monotonic() - start < 20
    finally:
        _stop([proc])
    message = str(caught.value)
    assert "\n" not in message
    assert f"no worker joined {address} within 2 s" in message
    assert f"dask worker {address} --nthreads 1" in message


def test_same_bits_on_a_scheduler_and_worker_started_with_the_dask_command(tmp_path):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([SRC, os.environ.get("PYTHONPATH", "")])}
    proc, address = _start_scheduler(tmp_path, env)
    procs = [proc]
    try:
        procs.append(subprocess.Popen([sys.executable, "-m", "dask", "worker", address, "--nworkers", "2",
                                       "--nthreads", "1", "--no-dashboard"],
                                      env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        with Execution(address) as execution:
            execution.client.wait_for_workers(2, timeout=60)
            there = simulate_dataset(3, seed=31, noise="thesis", with_truth=True, progress=False,
                                     execution=execution)
            assert os.getpid() not in execution.client.run(os.getpid).values()
    finally:
        _stop(procs)
    here = simulate_dataset(3, seed=31, workers=1, noise="thesis", with_truth=True, progress=False)
    pd.testing.assert_frame_equal(here.frame, there.frame, check_exact=True)
    assert here.meta["experiments"][0]["payload"] == there.meta["experiments"][0]["payload"]


def test_absurd_worker_count_is_one_clear_error(tmp_path, capsys):
    """`--workers 100000` must not try to start 100000 processes."""
    from excavator_payload.cli import main

    out = tmp_path / "never-written.parquet"
    assert main(["simulate", "-n", "2", "--workers", "100000", "--out", str(out), "--quiet"]) == 2
    assert "at most" in capsys.readouterr().err and not out.exists()


def test_progress_is_plain_lines_where_the_output_is_no_terminal():
    """Output to a file or CI: rich draws nothing until the end, so a plain line comes at every
    tenth of the work (and at least once a minute) with what is left (one line in 39 min before)."""
    import io

    from rich.console import Console

    from excavator_payload.execution import PlainProgress

    out = io.StringIO()
    plain = PlainProgress("simulating", 100, Console(file=out, force_terminal=False, width=200))
    for _ in range(100):
        plain.advance(1)
    lines = out.getvalue().splitlines()
    assert len(lines) == 10
    assert lines[0].startswith("simulating: 10/100 (10%),") and "left" in lines[0]
    assert [line.split(":")[1].split()[0] for line in lines] == [f"{k}/100" for k in range(10, 101, 10)]
