"""The one execution layer: every embarrassingly parallel job of the package runs through here.

Simulation chunks (:mod:`excavator_payload.simulation.generate`), study cells
(:mod:`excavator_payload.evaluation.study`) and whatever else splits into independent tasks are
handed to :meth:`Execution.map`, which runs them on a `Dask <https://distributed.dask.org>`_
cluster and calls back, in the calling process, as each task finishes (so that the caller can
checkpoint it), with a progress bar.

Where the tasks run
-------------------
* ``scheduler`` given (``--scheduler tcp://HOST:PORT`` on the command line) or the environment
  variable :data:`SCHEDULER_ENV` set: on that existing cluster, started with Dask's own
  ``dask scheduler`` and ``dask worker tcp://HOST:PORT`` commands (the workers need this package
  importable, e.g. installed in the same environment).
* otherwise: a local cluster of worker processes, one single-threaded worker per core (or
  ``workers``), started on first use and shut down when the :class:`Execution` closes. Dask's
  worker processes watch their parent: they exit with it, even after ``kill -9``. On Linux they
  are forked from a fork server that has imported Dask and the simulators once
  (:data:`LOCAL_START_METHOD`), and their event loops wake seldom (:data:`LOCAL_WORKER_CONFIG`):
  see ``benchmarks/bench_dask.py`` for what that gains against the pool used before.
* a job of one task, or ``workers=1`` without a scheduler, runs in this process: starting a
  cluster costs 1–3 s, more than small jobs take.

Threads
-------
A job uses the cores it is given and no more (:func:`job_threads`): the cores this process may
run on (its CPU affinity, e.g. ``taskset``), or fewer when ``$EXCAVATOR_PAYLOAD_THREADS`` (or
``OMP_NUM_THREADS`` as the job started) says so. Each local worker process gets its share,
``job_threads() // workers`` (at least 1), through its environment and
:func:`numeric_threads` at start. Numeric code sets its libraries' pools explicitly with
:func:`numeric_threads` (torch's intra-op pool, and every BLAS / OpenMP pool that
``threadpoolctl`` finds): a library left to its default starts one thread per core in every
process, and on a machine with other work those threads fight over the cores (``trainbr``
ran 35× slower so). On a Dask cluster of your own, set ``EXCAVATOR_PAYLOAD_THREADS`` in the
workers' environment to their share of the machine.

A task lost with a dead worker is run again on another one (Dask does that); a task that raises
is retried ``retries`` times before its error reaches the caller, except for a user error (an
:class:`~excavator_payload.errors.ExcavatorPayloadError`: bad input fails the same way every
time), which stops the job at once with its one line. Results never depend on where or in which
order tasks run: the tasks themselves must be deterministic functions of their arguments (every
simulated experiment draws from its own random streams).

An existing scheduler with no worker would hold the tasks forever: the job waits
:data:`DEFAULT_WORKER_TIMEOUT` seconds (``worker_timeout``, or ``$EXCAVATOR_PAYLOAD_WORKER_TIMEOUT``)
for a first worker to join, then stops with one line saying how to start one; an address where
something else answers (an HTTP server, Dask's dashboard, a worker) is one line too, after at
most :data:`CONNECT_TIMEOUT` seconds.

A script run as ``python script.py`` that calls the API from its top-level code without an
``if __name__ == "__main__":`` guard cannot start local worker processes: each new process
re-runs the script's top-level code (``spawn`` and ``forkserver`` do that), which would start a
cluster of its own. There the job runs in this process instead, with one warning saying where
the guard belongs (:func:`unguarded_main_line`).
"""

from __future__ import annotations

import ast
import logging
import os
import signal
import sys
import threading
import uuid
import warnings
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

from excavator_payload.errors import ExcavatorPayloadError

log = logging.getLogger(__name__)

#: Environment variable naming the Dask scheduler to use when ``--scheduler`` is not given.
SCHEDULER_ENV = "EXCAVATOR_PAYLOAD_SCHEDULER"
#: How often a task that raised is run again before its error reaches the caller.
DEFAULT_RETRIES = 2
#: Dask settings of the local cluster. Its event loops wake less often: no statistical profiler
#: (it samples the task's stack every 10 ms, for a dashboard nobody looks at), the blocked-loop
#: check every 1 s instead of 20 ms, the system and memory monitors every 1 s instead of 0.5 and
#: 0.1 s; measured, this cuts a worker's CPU outside its task from 3–5 % to ~1 %, and these
#: CPU-bound tasks lose every wake-up (the worker's threads share one interpreter lock).
LOCAL_WORKER_CONFIG = {"distributed.worker.profile.enabled": False,
                       "distributed.admin.tick.interval": "1s",
                       "distributed.admin.system-monitor.interval": "1s",
                       "distributed.worker.memory.monitor-interval": "1s"}
#: How local worker processes start. ``forkserver`` (Linux): forked from one clean server process
#: that has imported :data:`FORKSERVER_PRELOAD` once, instead of each worker starting a new
#: interpreter and importing them itself (``spawn``, Dask's default). Forked from a server
#: with no threads, not from this process (whose threads could hold locks at the fork).
LOCAL_START_METHOD = "forkserver" if sys.platform.startswith("linux") else "spawn"
#: Modules the fork server imports for every local worker: Dask and what a simulation chunk
#: needs (the estimators' torch is left out: simulations do not need it and it takes ~1–2 s).
FORKSERVER_PRELOAD = ("distributed", "numpy", "pandas", "pyarrow", "pyarrow.parquet", "scipy", "casadi",
                      "excavator_payload.execution", "excavator_payload.simulation.generate",
                      "excavator_payload.simulation.nmpc", "excavator_payload.simulation.minimum_jerk",
                      "excavator_payload.simulation.machine_sim")
#: Seconds to wait for an existing scheduler to answer.
CONNECT_TIMEOUT = 20.0
#: Environment variable: seconds to wait for a first worker on an existing scheduler.
WORKER_TIMEOUT_ENV = "EXCAVATOR_PAYLOAD_WORKER_TIMEOUT"
#: Seconds to wait for a first worker to join an existing scheduler that has none.
DEFAULT_WORKER_TIMEOUT = 60.0



class PlainProgress:
    """Progress as plain lines, for output that is no terminal: one line at every tenth of the
    work and at least once a minute, with the time elapsed and an estimate of what is left.

    Parameters
    ----------
    description : str
        What is being done (the progress bar's label).
    total : int
        Units of work in all.
    console : rich.console.Console
        Where the lines go.
    every : float
        Seconds between lines at the least.
    """

    def __init__(self, description: str, total: int, console, every: float = 60.0):
        import time

        self._clock = time.monotonic
        self.description, self.total, self.console, self.every = description, max(int(total), 1), console, every
        self.done = 0
        self._start = self._last = self._clock()
        self._next_tenth = 1  # the next tenth of the work that gets a line

    def advance(self, units: int) -> None:
        """Count ``units`` more of the work done; print a line when a tenth or a minute passed.

        Parameters
        ----------
        units : int
            Units of work just finished.
        """
        self.done += int(units)
        now = self._clock()
        share = self.done / self.total
        tenth = self.done * 10 // self.total  # whole tenths done (integers: no rounding drift)
        if tenth < self._next_tenth and now - self._last < self.every and self.done < self.total:
            return
        self._next_tenth = max(self._next_tenth, tenth + 1)
        self._last = now
        elapsed = now - self._start
        left = elapsed * (1 - share) / share if share > 0 else float("nan")
        self.console.print(f"{self.description}: {self.done}/{self.total} ({share:.0%}), "
                           f"{_minutes(elapsed)} elapsed, about {_minutes(left)} left",
                           highlight=False, markup=False)


def _minutes(seconds: float) -> str:
    """``seconds`` as ``"42 s"`` or ``"3.5 min"``."""
    if seconds != seconds:
        return "?"
    return f"{seconds:.0f} s" if seconds < 120 else f"{seconds / 60:.1f} min"

class SchedulerError(ExcavatorPayloadError):
    """A scheduler address is malformed, the scheduler cannot be reached or no worker joins it."""


class InProcessWarning(RuntimeWarning):
    """A job that would have run on local worker processes runs in this process instead."""


#: Where :class:`InProcessWarning` was shown already (once per line of the user's script).
_WARNED: dict = {}


def worker_timeout(seconds: float | None = None) -> float:
    """Seconds to wait for a first worker: ``seconds``, else ``$EXCAVATOR_PAYLOAD_WORKER_TIMEOUT``,
    else :data:`DEFAULT_WORKER_TIMEOUT`.

    Parameters
    ----------
    seconds : float, optional
        The wait, s; None: from the environment or the default.

    Raises
    ------
    SchedulerError
        If the value is not a positive number.
    """
    if seconds is None:
        text = os.environ.get(WORKER_TIMEOUT_ENV, "").strip()
        if not text:
            return DEFAULT_WORKER_TIMEOUT
        try:
            seconds = float(text)
        except ValueError:
            raise SchedulerError(f"${WORKER_TIMEOUT_ENV} must be a number of seconds, got {text!r}") from None
    if isinstance(seconds, bool) or not isinstance(seconds, (int, float)) or not seconds > 0 \
            or seconds == float("inf"):
        raise SchedulerError(f"the worker timeout must be a positive number of seconds, got {seconds!r}")
    return float(seconds)


@dataclass(frozen=True)
class _UserError:
    """What a task returns instead of raising a user error, so that Dask does not retry it."""

    error: BaseException


def _run_task(function: Callable, *args):
    """Run one task on a worker; a user error comes back as a result (see :class:`_UserError`)."""
    try:
        return function(*args)
    except ExcavatorPayloadError as exc:
        return _UserError(exc)


@dataclass(frozen=True)
class Shared:
    """An argument several tasks receive: sent to the cluster once, not once per task.

    Parameters
    ----------
    value : object
        The argument itself.
    """

    value: Any


def scheduler_address(scheduler: str | None = None) -> str | None:
    """The scheduler to use: ``scheduler``, else ``$EXCAVATOR_PAYLOAD_SCHEDULER``, else ``None``.

    ``HOST:PORT`` gets the ``tcp://`` prefix.

    Parameters
    ----------
    scheduler : str, optional
        A scheduler address (``tcp://HOST:PORT`` or ``HOST:PORT``); None: from the environment.

    Raises
    ------
    SchedulerError
        If the address has no port.
    """
    address = (scheduler if scheduler is not None else os.environ.get(SCHEDULER_ENV, "")).strip()
    if not address:
        return None
    if "://" not in address:
        address = "tcp://" + address
    host_port = address.split("://", 1)[1]
    host, _, port = host_port.rpartition(":")
    if not host or not port.isdigit():
        raise SchedulerError(f"scheduler address '{address}' must look like tcp://HOST:PORT")
    return address


#: Local worker processes per core at most: more only cost memory and start-up time (each
#: builds its own compiled solvers), never speed, for these CPU-bound tasks.
MAX_LOCAL_WORKERS_PER_CORE = 4


def default_workers() -> int:
    """Local worker processes by default: one per core this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


#: Environment variable: threads one job (a command, or one local worker process) may use for its
#: numerics; default: the cores it may run on. Never more than those.
THREADS_ENV = "EXCAVATOR_PAYLOAD_THREADS"
#: ``OMP_NUM_THREADS`` as this process started: Dask's nanny sets ``OMP_NUM_THREADS=1`` in the
#: process that starts local workers (``distributed.nanny.pre-spawn-environ``), which is no
#: request of the user's and must not make the commands that follow single-threaded.
_OMP_AT_START = os.environ.get("OMP_NUM_THREADS")


def job_threads() -> int:
    """Threads this job may use: ``$EXCAVATOR_PAYLOAD_THREADS``, else ``OMP_NUM_THREADS`` as the
    process started, else the cores this process may run on; capped at those cores.

    Raises
    ------
    ExcavatorPayloadError
        If ``$EXCAVATOR_PAYLOAD_THREADS`` is set but is not a whole number ≥ 1.
    """
    cores = default_workers()
    text = os.environ.get(THREADS_ENV, "").strip()
    if text:
        try:
            n = int(text)
        except ValueError:
            n = 0
        if n < 1:
            raise ExcavatorPayloadError(f"${THREADS_ENV} must be a whole number ≥ 1, got {text!r}")
        return min(n, cores)
    try:  # OMP_NUM_THREADS may be a list ("4,2": nested levels); its first level counts
        n = int((_OMP_AT_START or "").split(",")[0])
    except ValueError:
        n = 0
    return min(n, cores) if n >= 1 else cores


def worker_threads(workers: int) -> int:
    """Threads of each of ``workers`` local worker processes: their share of :func:`job_threads`.

    Parameters
    ----------
    workers : int
        Number of local worker processes (values below 1 count as 1).
    """
    return max(1, job_threads() // max(1, int(workers)))


@contextmanager
def numeric_threads(threads: int):
    """Inside the block torch's intra-op pool (when torch is loaded) and every BLAS / OpenMP pool
    ``threadpoolctl`` finds (numpy's and scipy's OpenBLAS, torch's OpenMP) use ``threads``
    threads; the previous settings come back after.

    Parameters
    ----------
    threads : int
        Threads for the numeric pools inside the block (at least 1).
    """
    from threadpoolctl import threadpool_limits

    threads = max(1, int(threads))
    torch = sys.modules.get("torch")  # never imported here: simulations do not need it
    before = torch.get_num_threads() if torch is not None else None
    with threadpool_limits(limits=threads):
        if torch is not None:
            torch.set_num_threads(threads)
        try:
            yield
        finally:
            if torch is not None:
                torch.set_num_threads(before)


def _guard_test(test: ast.expr) -> bool:
    """Whether an ``if`` test reads ``__name__`` (``if __name__ == "__main__":`` and its variants)."""
    return any(isinstance(node, ast.Name) and node.id == "__name__" for node in ast.walk(test))


def unguarded_main_line() -> tuple[str, int] | None:
    """The file and line of the ``__main__`` script's top-level code that is running this call
    without an ``if __name__ == "__main__":`` guard, else ``None``.

    A new local worker process (started with ``spawn`` or ``forkserver``) re-runs the main
    script's top-level code; if that code is what starts the cluster, every worker would start
    one of its own while it bootstraps, and fail (``RuntimeError: An attempt has been made to
    start a new process before the current process has finished its bootstrapping phase``,
    ``Nanny failed to start``). ``None`` when the main module is not re-run (an interactive
    session, ``python -c``, a package's ``__main__``), when the call comes from guarded code, or
    when the script's source cannot be read (then nothing is known, and nothing is changed).
    """
    main = sys.modules.get("__main__")
    if main is None:
        return None
    name = getattr(getattr(main, "__spec__", None), "name", None)
    if name is not None and (name == "__main__" or name.endswith(".__main__")):
        return None  # multiprocessing does not re-run these
    path = getattr(main, "__file__", None)
    if not path:
        return None
    frame = sys._getframe(1)
    while frame is not None and not (frame.f_globals is vars(main) and frame.f_code.co_name == "<module>"):
        frame = frame.f_back
    if frame is None:
        return None  # not called while the main script's top-level code runs
    if os.path.abspath(frame.f_code.co_filename) != os.path.abspath(path):
        return None  # code run in the main namespace but not from its file (a notebook's cell)
    line = frame.f_lineno
    try:
        with open(path, "rb") as fh:
            tree = ast.parse(fh.read(), filename=path)
    except (OSError, SyntaxError, ValueError):
        return None
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and _guard_test(node.test) and node.test.end_lineno < line <= node.end_lineno:
            return None
    return path, line


def _prepare_forkserver() -> None:
    """Tell the fork server (started with the first local worker) what to import."""
    import dask
    from distributed.utils import get_mp_context

    with dask.config.set({"distributed.worker.multiprocessing-method": "forkserver"}):
        context = get_mp_context()  # Dask sets its own preload list once; ours replaces it
    context.set_forkserver_preload(list(FORKSERVER_PRELOAD))


def start_local_cluster(workers: int):
    """A Dask ``LocalCluster`` of ``workers`` worker processes running one task at a time, each
    with its share of the cores for its numerics (:func:`worker_threads`), started the way this
    layer starts them (:data:`LOCAL_START_METHOD`, :data:`LOCAL_WORKER_CONFIG`, workers that
    ignore Ctrl-C); close it when done.

    Parameters
    ----------
    workers : int
        Number of worker processes.

    Returns
    -------
    distributed.LocalCluster
        The started cluster.
    """
    import dask
    from distributed import LocalCluster

    _quiet_dask()
    config = dict(LOCAL_WORKER_CONFIG)
    if LOCAL_START_METHOD == "forkserver":
        config["distributed.worker.multiprocessing-method"] = "forkserver"
        _prepare_forkserver()
    with warnings.catch_warnings(), dask.config.set(config), _interrupts_ignored():
        # Without a dashboard the scheduler still serves health checks, on another port if
        # 8787 is taken (a second cluster): nothing the user needs to hear about.
        warnings.filterwarnings("ignore", message="Port .* is already in use")
        # Each worker's share of the cores, in its environment (read by libraries it imports
        # later and by job_threads(); the nanny's own default is 1 thread).
        share = str(worker_threads(workers))
        env = {THREADS_ENV: share, "OMP_NUM_THREADS": share, "MKL_NUM_THREADS": share,
               "OPENBLAS_NUM_THREADS": share}
        # Workers' own logs stay quiet up to CRITICAL: a task's error reaches the client as its
        # exception, and what a worker logs when Ctrl-C tears the cluster down under it (a lost
        # heartbeat, with its traceback) is noise to the user (seen once in CI).
        return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                            silence_logs=logging.CRITICAL, preload=[__name__], env=env)


@contextmanager
def _interrupts_ignored():
    """Ctrl-C is ignored while the local workers start: they inherit that (a terminal's Ctrl-C
    reaches every process of the group; the command, not its workers, handles it)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def dask_setup(worker) -> None:
    """Dask preload hook, run by every local worker as it starts (also one its nanny restarts
    after a crash): the workers ignore Ctrl-C; the command stops them itself, without a
    traceback from each worker. The libraries the worker has loaded already (from the fork
    server) take its share of the cores (:func:`job_threads` reads the share from its
    environment), since they read their thread counts when they were loaded.

    Parameters
    ----------
    worker : distributed.Worker
        The starting worker (passed by Dask; not used otherwise).
    """
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    from threadpoolctl import threadpool_limits

    threads = job_threads()
    threadpool_limits(limits=threads)  # kept for the worker's life
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(threads)


def _quiet_dask() -> None:
    """Dask logs every started worker, lost connection and retry on the console: keep errors only."""
    for name in ("distributed", "dask"):
        logging.getLogger(name).setLevel(logging.ERROR)
    # A slow disk under load is no news for the user of a command-line tool.
    warnings.filterwarnings("ignore", message="Creating scratch directories is taking")


def _first_line(exc: BaseException) -> str:
    return str(exc).splitlines()[0] if str(exc).strip() else type(exc).__name__


def _probe_scheduler(address: str, timeout: float) -> None:
    """Check within ``timeout`` seconds that a Dask scheduler answers at ``address``.

    ``distributed.Client`` waits for the handshake without a time limit: at a port where
    something else listens (an HTTP server, Dask's own dashboard) it hung for ever. This asks
    the server who it is, on an event loop of its own (so also when the caller's thread runs
    one), and gives up after ``timeout`` seconds.

    Raises
    ------
    SchedulerError
        If nothing listens there, nothing answers like Dask within ``timeout`` seconds, or a
        Dask server that is not a scheduler (a worker) answers.
    """
    import asyncio
    from concurrent.futures import ThreadPoolExecutor

    from distributed.comm import connect

    async def identity():
        comm = await connect(address, timeout=timeout)
        try:
            await comm.write({"op": "identity", "reply": True})
            return await comm.read()
        finally:
            comm.abort()

    def ask():
        return asyncio.run(asyncio.wait_for(identity(), timeout))

    with ThreadPoolExecutor(1, thread_name_prefix="scheduler-probe") as pool:
        try:
            info = pool.submit(ask).result()
        except (asyncio.TimeoutError, TimeoutError):
            raise SchedulerError(f"cannot reach the Dask scheduler at {address}: no Dask answer within "
                                 f"{timeout:g} s (is that the scheduler's port? not its dashboard's)") from None
        except Exception as exc:  # noqa: BLE001 - refused, reset, garbage: one line whatever it is
            raise SchedulerError(f"cannot reach the Dask scheduler at {address}: {_first_line(exc)}") from None
    kind = info.get("type") if isinstance(info, dict) else None
    if kind != "Scheduler":
        raise SchedulerError(f"{address} is not a Dask scheduler (a Dask {kind or 'server'} answers there): "
                             "give the scheduler's address, as `dask scheduler` prints it")


@dataclass
class Execution:
    """Where and how parallel jobs run; use as a context manager so that a cluster it starts
    is shut down.

    Parameters
    ----------
    scheduler : str, optional
        Address of an existing Dask scheduler (``tcp://HOST:PORT``); default
        ``$EXCAVATOR_PAYLOAD_SCHEDULER``, else a local cluster.
    workers : int, optional
        Worker processes of the local cluster (default: one per core). Ignored with a scheduler.
    retries : int
        Times a task that raised is run again (never for an ``ExcavatorPayloadError``).
    worker_timeout : float, optional
        Seconds to wait for a first worker on an existing scheduler that has none (default
        ``$EXCAVATOR_PAYLOAD_WORKER_TIMEOUT``, else :data:`DEFAULT_WORKER_TIMEOUT`).
    """

    scheduler: str | None = None
    workers: int | None = None
    retries: int = DEFAULT_RETRIES
    worker_timeout: float | None = None
    _client: Any = field(default=None, init=False, repr=False)
    _cluster: Any = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        self.scheduler = scheduler_address(self.scheduler)
        self.worker_timeout = worker_timeout(self.worker_timeout)
        if self.workers is not None and (isinstance(self.workers, bool) or not isinstance(self.workers, int)
                                         or self.workers < 1):
            raise ExcavatorPayloadError(f"workers must be a whole number ≥ 1, got {self.workers!r}")
        if self.workers is None:
            self.workers = default_workers()
        limit = MAX_LOCAL_WORKERS_PER_CORE * default_workers()
        if self.scheduler is None and self.workers > limit:
            raise ExcavatorPayloadError(
                f"--workers {self.workers}: at most {limit} local worker processes here "
                f"({MAX_LOCAL_WORKERS_PER_CORE} per core of {default_workers()}); more cost memory, "
                "not speed. For more, run on a cluster with --scheduler")

    # -- lifetime -----------------------------------------------------------------------------
    def __enter__(self) -> "Execution":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Disconnect, and stop the local cluster if this object started one."""
        client, cluster = self._client, self._cluster
        self._client = self._cluster = None
        for thing in (client, cluster):
            if thing is not None:
                try:
                    thing.close()
                except Exception:  # noqa: BLE001 - shutting down: nothing left to save
                    log.debug("error while closing %r", thing, exc_info=True)

    @property
    def where(self) -> str:
        """Where the tasks run, for messages."""
        if self.scheduler:
            return f"Dask scheduler {self.scheduler}"
        return f"{self.workers} local worker process(es)"

    def runs_in_process(self, n_tasks: int) -> bool:
        """Whether a job of ``n_tasks`` tasks runs in this process (no cluster).

        Parameters
        ----------
        n_tasks : int
            Number of tasks in the job.
        """
        return self.scheduler is None and (self.workers == 1 or n_tasks <= 1)

    @property
    def client(self):
        """The ``distributed.Client`` (connecting or starting the local cluster on first use)."""
        if self._client is None:
            self._client = self._connect()
        return self._client

    def _connect(self):
        _quiet_dask()
        from distributed import Client

        if self.scheduler:
            _probe_scheduler(self.scheduler, CONNECT_TIMEOUT)
            try:
                client = Client(self.scheduler, set_as_default=False, timeout=CONNECT_TIMEOUT)
            except (OSError, TimeoutError) as exc:
                raise SchedulerError(f"cannot reach the Dask scheduler at {self.scheduler}: "
                                     f"{_first_line(exc)}") from None
            try:
                # Tasks sent to a scheduler without workers would wait forever.
                client.wait_for_workers(1, timeout=self.worker_timeout)
            except (OSError, TimeoutError):
                client.close()
                raise SchedulerError(
                    f"no worker joined {self.scheduler} within {self.worker_timeout:g} s; start one with "
                    f"`dask worker {self.scheduler} --nthreads 1` (or wait longer: ${WORKER_TIMEOUT_ENV})"
                ) from None
            return client
        self._cluster = start_local_cluster(self.workers)
        return Client(self._cluster, set_as_default=False)

    # -- running ------------------------------------------------------------------------------
    def map(self, function: Callable, tasks: Sequence[tuple], *, on_done: Callable[[int, Any], None] | None = None,
            weights: Sequence[int] | None = None, description: str = "working", progress: bool = True,
            console=None) -> list:
        """Run ``function(*task)`` for every task; call ``on_done(index, result)`` as each finishes.

        Parameters
        ----------
        function : callable
            Importable, module-level function (it is pickled by reference for the workers).
        tasks : sequence of tuple
            Arguments of each call. A :class:`Shared` argument is sent to the cluster once and
            every task that names the same object receives it.
        on_done : callable, optional
            Called in this process, in the order tasks finish, with the task's index and result
            (checkpoint there: a later interruption keeps it).
        weights : sequence of int, optional
            Progress units of each task (e.g. its experiment count); default 1 each.
        description : str
            Label of the progress bar.
        progress : bool
            Show the progress bar.
        console : rich.console.Console, optional
            Console the progress bar is drawn on (default: rich's own).

        Returns
        -------
        list
            The results, in the order of ``tasks``.

        Raises
        ------
        KeyboardInterrupt
            On Ctrl-C: the unfinished tasks are cancelled; the finished ones went to ``on_done``.
        """
        from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn,
                                   TimeRemainingColumn)

        tasks = [tuple(t) for t in tasks]
        weights = [1] * len(tasks) if weights is None else [int(w) for w in weights]
        results: list = [None] * len(tasks)
        columns = [TextColumn("[progress.description]{task.description}"), BarColumn(),
                   MofNCompleteColumn(), TimeElapsedColumn(), TimeRemainingColumn()]
        from rich import get_console

        console = console if console is not None else get_console()
        # rich draws nothing until the end where the output is no terminal (a log file, CI):
        # there a plain line every tenth of the work or every minute says how far it is, and
        # the bar is left out (it would only repeat the last line)
        bar_drawn = progress and console.is_terminal
        with Progress(*columns, disable=not bar_drawn, transient=False, console=console) as bar:
            bar_task = bar.add_task(description, total=sum(weights))
            plain = PlainProgress(description, sum(weights), console) if progress and not bar_drawn else None

            def finished(index, result):
                results[index] = result
                if on_done is not None:
                    on_done(index, result)
                bar.advance(bar_task, weights[index])
                if plain is not None:
                    plain.advance(weights[index])

            if not tasks:
                return results
            if self.runs_in_process(len(tasks)) or self._main_script_unguarded(len(tasks)):
                for index, task in enumerate(tasks):
                    finished(index, function(*(a.value if isinstance(a, Shared) else a for a in task)))
                return results
            self._map_on_cluster(function, tasks, finished)
        return results

    def _main_script_unguarded(self, n_tasks: int) -> bool:
        """Whether local worker processes cannot start because the main script would re-run
        this call in each (:func:`unguarded_main_line`); warns once per line of the script."""
        if self.scheduler is not None or self._client is not None:
            return False
        where = unguarded_main_line()
        if where is None:
            return False
        path, line = where
        warnings.warn_explicit(
            f"{n_tasks} tasks run in this process, not on {self.workers} worker processes: new worker "
            f"processes re-run this script's top-level code ({os.path.basename(path)} line {line}); put "
            "it under `if __name__ == \"__main__\":` to use them (or pass workers=1 to run here quietly)",
            InProcessWarning, path, line, registry=_WARNED)
        return True

    def _map_on_cluster(self, function, tasks, finished) -> None:
        from distributed import as_completed

        client = self.client
        scattered: dict[int, Any] = {}

        def resolve(arg):
            if not isinstance(arg, Shared):
                return arg
            if id(arg.value) not in scattered:
                # A list is scattered element by element: wrap the value so that it travels whole.
                scattered[id(arg.value)] = client.scatter([arg.value], hash=False)[0]
            return scattered[id(arg.value)]

        futures = {}
        name = getattr(function, "__name__", "task")
        try:
            for index, task in enumerate(tasks):
                future = client.submit(_run_task, function, *(resolve(a) for a in task), pure=False,
                                       retries=self.retries, key=f"{name}-{index}-{uuid.uuid4().hex}")
                futures[future] = index
            for future in as_completed(list(futures), loop=client.loop):
                index = futures[future]
                result = future.result()
                if isinstance(result, _UserError):
                    raise result.error
                finished(index, result)
        except BaseException:
            # Ctrl-C or a task that failed for good: stop the rest; the finished ones are kept.
            try:
                client.cancel(list(futures), force=True)
            except Exception:  # noqa: BLE001 - the cluster may be gone already
                pass
            raise
        finally:
            futures.clear()
            scattered.clear()


def interrupted_message(what: str = "finished work is kept; rerun the same command to resume") -> str:
    """The one line the commands print on Ctrl-C.

    Parameters
    ----------
    what : str, optional
        What happens to the work, shown in parentheses after "interrupted".
    """
    return f"[red]interrupted[/red] ({what})"
