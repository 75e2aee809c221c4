"""Benchmark of the Dask execution layer (issue 10) for ``simulate``.

Measures

1. **same bits**: NMPC experiments simulated in this process, on a Dask cluster of 1 worker, of
   2 workers, and on a scheduler + 2 workers started from the command line with
   ``dask scheduler`` / ``dask worker`` are identical, bit for bit (rows and the deterministic
   metadata);
2. **scaling**: throughput of 2 workers against 1 (target ≥ 1.8×);
3. **overhead**: the Dask layer against the process pool ``simulate`` used before (a fork-based
   ``ProcessPoolExecutor``, copied below for this comparison only) at equal workers (target ≤ 5 %);
4. **a killed worker**: one worker is killed (SIGKILL) mid-run; the run completes with every
   experiment and the same bits;
5. **memory**: peak resident memory of a worker process while simulating.

Usage::

    python benchmarks/bench_dask.py [--bits 40] [--throughput 400] [--repeats 2] [--json out.json]
    python benchmarks/bench_dask.py --overhead-only [--throughput 400] [--repeats 3] [--first-release-settings]

``--overhead-only`` measures 3. alone, interleaving the old pool and the Dask layer (ABAB…) so
that a shared machine's changing load hits both alike, each run a fresh process as a user's
command (interpreter, imports, start-up included), and reports medians and load averages.

Every cluster's start-up is included in its wall time (a user pays it), except in the
"steady" figures, measured on a cluster that has already simulated once.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path

import pandas as pd

from excavator_payload.execution import Execution
from excavator_payload.simulation import generate
from excavator_payload.simulation.generate import assemble, make_spec, simulate_dataset

DETERMINISTIC = ("experiment", "seed", "payload", "start_pose", "target_pose", "final_error_deg",
                 "reached", "settle_time", "n_fallbacks")
SEED = 10


# -- the pool simulate used before issue 10 (kept here only for the comparison) ------------------
def _ignore_interrupts() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def old_pool_simulate(n: int, workers: int):
    """``simulate_dataset`` as it ran before: fork-based ProcessPoolExecutor over the same chunks."""
    spec = make_spec(n, SEED, "cat345c", "thesis", True, "nmpc")
    chunks = generate._chunks(0, n, generate.chunk_size_for(n))
    generate._simulator(spec.machine)  # built in the parent, inherited by the forked workers
    pool = ProcessPoolExecutor(max_workers=min(workers, len(chunks)),
                               mp_context=multiprocessing.get_context("fork"), initializer=_ignore_interrupts)
    parts = {}
    try:
        pending = {pool.submit(generate.simulate_chunk, spec, first, count): first for first, count in chunks}
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                parts[pending.pop(future)] = future.result()
    finally:
        pool.shutdown(wait=True)
    return assemble(parts, spec)


# -- helpers -----------------------------------------------------------------------------------
def same(a, b) -> bool:
    try:
        pd.testing.assert_frame_equal(a.frame, b.frame, check_exact=True)
    except AssertionError:
        return False
    return all({k: ma[k] for k in DETERMINISTIC} == {k: mb[k] for k in DETERMINISTIC}
               for ma, mb in zip(a.meta["experiments"], b.meta["experiments"], strict=True))


def simulate_on(execution: Execution, n: int):
    return simulate_dataset(n, seed=SEED, with_truth=True, progress=False, execution=execution)


def timed(fn):
    start = time.perf_counter()
    result = fn()
    return result, time.perf_counter() - start


class CommandLineCluster:
    """``dask scheduler`` + ``dask worker ADDRESS --nworkers N`` as separate processes."""

    def __init__(self, workers: int) -> None:
        self.workers = workers
        self.procs: list[subprocess.Popen] = []

    def __enter__(self) -> str:
        src = str(Path(generate.__file__).resolve().parents[2])
        env = {**os.environ, "PYTHONPATH": os.pathsep.join([src, os.environ.get("PYTHONPATH", "")])}
        self.tmp = tempfile.TemporaryDirectory()
        address_file = Path(self.tmp.name) / "scheduler.json"
        self.procs.append(subprocess.Popen(
            [sys.executable, "-m", "dask", "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
             "--scheduler-file", str(address_file)], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        deadline = time.monotonic() + 60
        while not address_file.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        address = json.loads(address_file.read_text())["address"]
        self.procs.append(subprocess.Popen(
            [sys.executable, "-m", "dask", "worker", address, "--nworkers", str(self.workers), "--nthreads", "1",
             "--no-dashboard"], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        return address

    def __exit__(self, *exc) -> None:
        for p in reversed(self.procs):
            p.terminate()
        for p in self.procs:
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()
        self.tmp.cleanup()


def one_worker_cluster():
    """A Dask LocalCluster of exactly one worker process, started as the layer starts its own
    (``Execution(workers=1)`` would run in this process instead)."""
    from excavator_payload.execution import start_local_cluster

    return start_local_cluster(1)


class _null:
    def __enter__(self):
        return None

    def __exit__(self, *exc):
        return False


def cpu_seconds() -> float:
    """User + system CPU time of this process and of its finished child processes."""
    import resource

    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def own_cpu_seconds() -> float:
    """User + system CPU time of this process only."""
    import resource

    me = resource.getrusage(resource.RUSAGE_SELF)
    return me.ru_utime + me.ru_stime


def peak_rss_mb() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def median(values):
    ordered = sorted(values)
    middle = len(ordered) // 2
    return ordered[middle] if len(ordered) % 2 else (ordered[middle - 1] + ordered[middle]) / 2


def run_arm(arm: str, n: int, workers: int = 2) -> float:
    """One arm of the overhead comparison in this (fresh) process; returns the steady time of a
    second run for ``dask-steady``, else 0."""
    if arm == "old":
        old_pool_simulate(n, workers)
        return 0.0
    with Execution(workers=workers) as ex:
        simulate_on(ex, n)
        return timed(lambda: simulate_on(ex, n))[1] if arm == "dask-steady" else 0.0


def _arm_in_subprocess(arm: str, n: int, extra: list[str]) -> tuple[float, float]:
    """Wall time of ``arm`` run as its own command, as a user runs ``simulate`` (interpreter
    start, imports and cluster start-up included), and the steady time it printed.

    No CPU seconds here: workers forked by a fork server are not this process's descendants
    once the server outlives the command, so their CPU time would go uncounted.
    """
    start = time.perf_counter()
    done = subprocess.run([sys.executable, __file__, "--arm", arm, "--throughput", str(n), *extra],
                          capture_output=True, text=True, check=True)
    return time.perf_counter() - start, float(done.stdout.strip().splitlines()[-1])


def overhead_only(n: int, repeats: int, workers: int = 2, extra: list[str] | None = None,
                  compare_first_release: bool = False) -> dict:
    """The old pool and the Dask layer at ``workers`` workers, interleaved ABAB…; medians.

    Each arm is a fresh process, as a user's ``simulate`` command: "old pool" and "dask" are
    its whole wall time (interpreter, imports, pool or cluster start-up, simulation);
    "dask steady" is a second simulation on the same, already warm cluster (a process of its own).
    """
    extra = list(extra or [])
    arms = [("old", "old pool", []), ("dask", "dask", extra)]
    if compare_first_release:
        arms.append(("dask", "dask first release", ["--first-release-settings"]))
    times: dict[str, list[float]] = {name: [] for _, name, _ in arms}
    times["dask steady"] = []
    loads = []
    for repeat in range(repeats):
        for arm, name, flags in arms:
            loads.append(os.getloadavg()[0])
            times[name].append(_arm_in_subprocess(arm, n, flags)[0])
        times["dask steady"].append(_arm_in_subprocess("dask-steady", n, extra)[1])
        print(f"   repeat {repeat + 1}: " + ", ".join(f"{k} {v[-1]:.1f} s" for k, v in times.items())
              + f", load {loads[-1]:.1f}", flush=True)
    med = {k: median(v) for k, v in times.items()}
    result = {"experiments": n, "workers": workers, "repeats": repeats, "times_s": times, "median_s": med,
              "load_averages": loads, "overhead": med["dask"] / med["old pool"] - 1}
    if compare_first_release:
        result["overhead_first_release"] = med["dask first release"] / med["old pool"] - 1
        print(f"   first release's settings: {med['dask first release']:.1f} s, "
              f"overhead {100 * result['overhead_first_release']:+.1f} %")
    print(f"   medians: old pool {med['old pool']:.1f} s, dask {med['dask']:.1f} s (second run on a warm "
          f"cluster: {med['dask steady']:.1f} s); overhead {100 * result['overhead']:+.1f} %; load average "
          f"{min(loads):.1f}–{max(loads):.1f}")
    return result


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--bits", type=int, default=40, help="experiments of the same-bits runs")
    p.add_argument("--throughput", type=int, default=400, help="experiments of the timing runs")
    p.add_argument("--repeats", type=int, default=2, help="timing runs of each setup (best is kept)")
    p.add_argument("--json", type=Path, help="write the results here")
    p.add_argument("--overhead-only", action="store_true",
                   help="only the overhead against the old pool, interleaved, medians of --repeats")
    p.add_argument("--first-release-settings", action="store_true",
                   help="local clusters as the first Dask release started them (spawned workers, Dask's "
                        "event-loop intervals), to measure what the fork server and quieter loops gain")
    p.add_argument("--compare-first-release", action="store_true",
                   help="with --overhead-only: a third arm, the first release's cluster settings, interleaved too")
    p.add_argument("--arm", choices=("old", "dask", "dask-steady"), help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.first_release_settings:
        from excavator_payload import execution

        execution.LOCAL_START_METHOD = "spawn"
        execution.LOCAL_WORKER_CONFIG = {"distributed.worker.profile.enabled": False}
    if args.arm:
        print(run_arm(args.arm, args.throughput))
        return 0
    out: dict = {"load_average_before": os.getloadavg(), "cores": os.cpu_count()}
    if args.overhead_only:
        print(f"3. overhead, {args.throughput} NMPC experiments, old pool and Dask interleaved"
              + (" (first release's cluster settings)" if args.first_release_settings else ""), flush=True)
        out["overhead_only"] = overhead_only(args.throughput, args.repeats,
                                             extra=["--first-release-settings"] if args.first_release_settings else [],
                                             compare_first_release=args.compare_first_release)
        if args.json:
            args.json.write_text(json.dumps(out, indent=2, default=str))
        return 0

    # 1. same bits
    print(f"1. same bits, {args.bits} NMPC experiments (seed {SEED})", flush=True)
    reference = simulate_dataset(args.bits, seed=SEED, with_truth=True, workers=1, progress=False)
    bits = {}
    with one_worker_cluster() as cluster, Execution(cluster.scheduler_address) as ex:
        bits["dask, 1 worker"] = same(reference, simulate_on(ex, args.bits))
    with Execution(workers=2) as ex:
        bits["dask, 2 local workers"] = same(reference, simulate_on(ex, args.bits))
    with CommandLineCluster(2) as address, Execution(address) as ex:
        ex.client.wait_for_workers(2, timeout=120)
        bits["dask scheduler + dask worker (2) from the command line"] = same(reference, simulate_on(ex, args.bits))
    for k, v in bits.items():
        print(f"   {k}: {'identical' if v else 'DIFFERENT'} to the in-process run")
    out["same_bits"] = bits

    # 2./3. throughput (best of --repeats), start-up included; CPU seconds of this process and
    # its (reaped) worker processes, which other jobs on the machine do not inflate
    n = args.throughput
    print(f"2./3. throughput, {n} NMPC experiments (load average {os.getloadavg()[0]:.2f})", flush=True)
    times: dict[str, list[float]] = {}
    cpu: dict[str, list[float]] = {}

    def record(name, wall, seconds):
        times.setdefault(name, []).append(wall)
        cpu.setdefault(name, []).append(seconds)

    rss = {}
    for _ in range(args.repeats):
        c0, (_, wall) = cpu_seconds(), timed(lambda: simulate_dataset(n, seed=SEED, with_truth=True, workers=1,
                                                                      progress=False))
        record("in-process (no cluster)", wall, cpu_seconds() - c0)
        for workers in (1, 2):
            name = f"dask {workers} worker{'s' if workers > 1 else ''}"
            # The workers' CPU is read from them: forked by a fork server, they are not this
            # process's children, whose CPU time the operating system would add up.
            c0, start = own_cpu_seconds(), time.perf_counter()
            with (one_worker_cluster() if workers == 1 else _null()) as cluster, \
                    Execution(cluster.scheduler_address if workers == 1 else None, workers=workers) as ex:
                simulate_on(ex, n)
                first = time.perf_counter() - start
                steady = timed(lambda: simulate_on(ex, n))[1]
                if workers == 2:
                    rss = ex.client.run(peak_rss_mb)
                worker_cpu = sum(ex.client.run(time.process_time).values())
            c1 = own_cpu_seconds()
            record(name, first, (c1 - c0 + worker_cpu) / 2)  # CPU per run of n (start-up shared by the two runs)
            times.setdefault(name + " steady", []).append(steady)
        c0, (_, wall) = cpu_seconds(), timed(lambda: old_pool_simulate(n, 2))
        record("old pool 2 workers", wall, cpu_seconds() - c0)
    best = {k: min(v) for k, v in times.items()}
    best_cpu = {k: min(v) for k, v in cpu.items()}
    for k, v in best.items():
        extra = f", CPU {best_cpu[k]:6.1f} s" if k in best_cpu else ""
        print(f"   {k:28s} {v:6.1f} s wall ({n / v:5.1f} experiments/s{extra})")
    scaling = best["dask 1 worker"] / best["dask 2 workers"]
    scaling_steady = best["dask 1 worker steady"] / best["dask 2 workers steady"]
    overhead = best["dask 2 workers"] / best["old pool 2 workers"] - 1
    overhead_cpu = best_cpu["dask 2 workers"] / best_cpu["old pool 2 workers"] - 1
    print(f"   scaling 2 vs 1 worker: {scaling:.2f}× (steady {scaling_steady:.2f}×; target ≥ 1.8×)")
    print(f"   Dask overhead vs the old pool at 2 workers: wall {100 * overhead:+.1f} %, "
          f"CPU {100 * overhead_cpu:+.1f} % (target ≤ 5 %)")
    out.update(throughput_s=best, cpu_s=best_cpu, all_times_s=times, all_cpu_s=cpu, scaling=scaling,
               scaling_steady=scaling_steady, overhead=overhead, overhead_cpu=overhead_cpu)
    print(f"5. peak RSS of a worker process after simulating {2 * n} experiments: "
          f"{', '.join(f'{v:.0f} MB' for v in rss.values())}")
    out["worker_peak_rss_mb"] = list(rss.values())

    # 4. kill a worker mid-run
    print("4. one worker killed mid-run", flush=True)
    with Execution(workers=2) as ex:
        ex.client.wait_for_workers(2)
        victims: list[int] = []

        def kill_one():
            time.sleep(3.0)
            pid = next(iter(ex.client.run(os.getpid).values()))
            os.kill(pid, signal.SIGKILL)
            victims.append(pid)

        killer = threading.Thread(target=kill_one)
        killer.start()
        survived, seconds = timed(lambda: simulate_dataset(n // 2, seed=SEED, with_truth=True, progress=False,
                                                           execution=ex))
        killer.join()
    complete = survived.n_experiments == n // 2 and not survived.meta["skipped"]
    reference = simulate_dataset(n // 2, seed=SEED, with_truth=True, workers=1, progress=False)
    identical = same(reference, survived)
    print(f"   killed worker pid {victims}; run finished in {seconds:.1f} s with "
          f"{survived.n_experiments}/{n // 2} experiments; identical to the in-process run: {identical}")
    out.update(kill={"killed": victims, "complete": complete, "identical": identical, "seconds": seconds},
               load_average_after=os.getloadavg())
    if args.json:
        args.json.write_text(json.dumps(out, indent=2, default=str))
    ok = all(bits.values()) and complete and identical
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
