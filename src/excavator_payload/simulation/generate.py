"""Dataset generation: many experiments in parallel, reproducible, resumable.

Every experiment draws its scenario and its sensor noise from its own random streams
(:func:`~excavator_payload.simulation.scenario.experiment_rngs` of ``(seed, experiment)``), so
the data are the same whatever the number of workers or the order in which they finish.

:func:`simulate_to_file` checkpoints finished chunks of experiments in ``<out>.partial/``; an
interrupted run started again with the same settings simulates only the missing chunks. The
folder is removed once the dataset file has been written (atomically).
"""

from __future__ import annotations

import json
import logging
import math
import multiprocessing
import shutil
import signal
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.io import atomic_write_table, write_dataset
from excavator_payload.data.schema import COLUMNS, DURATION, METADATA_KEY, SAMPLE_PERIOD, SAMPLE_RATE, TRUTH_COLUMNS
from excavator_payload.errors import DatasetError, ExcavatorPayloadError
from excavator_payload.model.machine import Machine, load_machine
from excavator_payload.simulation.experiment import experiment_frame
from excavator_payload.simulation.scenario import experiment_rngs, sample_scenario
from excavator_payload.simulation.sensors import get_noise_preset

log = logging.getLogger(__name__)

MOTIONS = ("nmpc", "minimum-jerk", "lifts")
PARTIAL_SUFFIX = ".partial"


# -- one chunk of NMPC experiments (runs in a worker process) -------------------------------------
_SIMULATORS: dict[str, object] = {}


def _simulator(machine: Machine):
    """The process's NMPC simulator for ``machine`` (built once per process: ~2 s)."""
    from excavator_payload.model.dynamics import ArmModel
    from excavator_payload.simulation.nmpc import NMPCSimulator

    key = json.dumps(machine.to_dict(), sort_keys=True)
    if key not in _SIMULATORS:
        _SIMULATORS[key] = NMPCSimulator(ArmModel(machine), sample_period=SAMPLE_PERIOD,
                                         duration=DURATION)
    return _SIMULATORS[key]


def simulate_nmpc_experiment(experiment: int, seed: int, machine: Machine, noise: str,
                             with_truth: bool) -> tuple[pd.DataFrame, dict]:
    """Rows and metadata of NMPC experiment number ``experiment`` of the run ``seed``.

    Raises
    ------
    excavator_payload.simulation.nmpc.ControlFailure
        If the controller fails even after its IPOPT fallback.
    """
    sim = _simulator(machine)
    scenario = sample_scenario(seed, experiment, machine.max_payload)
    _, noise_rng = experiment_rngs(seed, experiment)
    result = sim.run(scenario.start_pose, scenario.target_pose, scenario.payload)
    frame = experiment_frame(experiment, result.time, result.q, result.qd, result.qdd, result.tau,
                             scenario.payload, get_noise_preset(noise), noise_rng, with_truth)
    return frame, {**scenario.to_dict(), "status": "ok", **result.info}


def _simulate_chunk(first: int, count: int, seed: int, machine_dict: dict, noise: str,
                    with_truth: bool) -> tuple[pd.DataFrame, list[dict], list[dict]]:
    """Experiments ``first … first+count-1``: (rows, metadata of the written, skipped ones)."""
    from excavator_payload.simulation.nmpc import ControlFailure

    machine = Machine.from_dict(machine_dict)
    frames, metas, skipped = [], [], []
    for k in range(first, first + count):
        try:
            frame, meta = simulate_nmpc_experiment(k, seed, machine, noise, with_truth)
        except (ControlFailure, RuntimeError, ValueError, FloatingPointError) as exc:
            if "KeyboardInterrupt" in str(exc):  # CasADi turns Ctrl-C into a RuntimeError
                raise KeyboardInterrupt from None
            # One bad experiment must not kill a long run: skip it and say why.
            reason = f"{type(exc).__name__}: {exc}".splitlines()[0][:300]
            log.warning("experiment %d skipped: %s", k, reason)
            skipped.append({"experiment": k, "reason": reason})
            continue
        frames.append(frame)
        metas.append(meta)
    columns = list(COLUMNS) + (list(TRUTH_COLUMNS) if with_truth else [])
    frame = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(columns=columns)
    return frame, metas, skipped


# -- the public entry points ------------------------------------------------------------------
def _check_arguments(n_experiments, seed, workers, motion, first_experiment=0):
    if isinstance(n_experiments, bool) or not isinstance(n_experiments, (int, np.integer)) or n_experiments < 1:
        raise ExcavatorPayloadError(f"the number of experiments must be a whole number ≥ 1, got {n_experiments!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ExcavatorPayloadError(f"the seed must be a whole number ≥ 0, got {seed!r}")
    if workers is not None and (not isinstance(workers, (int, np.integer)) or workers < 1):
        raise ExcavatorPayloadError(f"workers must be a whole number ≥ 1, got {workers!r}")
    if motion not in MOTIONS:
        raise ExcavatorPayloadError(f"unknown motion '{motion}': choose one of {', '.join(MOTIONS)}")
    if not isinstance(first_experiment, (int, np.integer)) or first_experiment < 0:
        raise ExcavatorPayloadError(f"first_experiment must be a whole number ≥ 0, got {first_experiment!r}")


def chunk_size_for(n_experiments: int) -> int:
    """Experiments per checkpointed chunk: small enough for a smooth progress bar and little
    lost work on interruption, large enough to keep the per-chunk overhead small."""
    return int(min(25, max(1, math.ceil(n_experiments / 40))))


def _chunks(first_experiment: int, n_experiments: int, size: int) -> list[tuple[int, int]]:
    end = first_experiment + n_experiments
    return [(k, min(size, end - k)) for k in range(first_experiment, end, size)]


def _ignore_interrupts() -> None:
    """Workers leave Ctrl-C to the parent, which keeps the finished chunks and stops."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _default_workers() -> int:
    return max(1, multiprocessing.cpu_count())


def _run_chunks(chunks, seed, machine, noise, with_truth, workers, progress, on_done,
                description="simulating"):
    """Simulate ``chunks`` (in a process pool when workers > 1) and call ``on_done`` for each."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    total = sum(c for _, c in chunks)
    machine_dict = machine.to_dict()
    columns = [TextColumn("[progress.description]{task.description}"), BarColumn(),
               MofNCompleteColumn(), TimeElapsedColumn(), TimeRemainingColumn()]
    with Progress(*columns, disable=not progress, transient=False) as bar:
        task = bar.add_task(description, total=total)
        if workers == 1 or len(chunks) == 1:
            for first, count in chunks:
                on_done(first, count, _simulate_chunk(first, count, seed, machine_dict, noise, with_truth))
                bar.advance(task, count)
            return
        # Build (and JIT-compile) the simulator once here: the forked workers inherit it.
        _simulator(machine)
        # fork shares the built simulator; where fork does not exist, workers load the cached one.
        context = multiprocessing.get_context(
            "fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn")
        pool = ProcessPoolExecutor(max_workers=min(workers, len(chunks)), mp_context=context,
                                   initializer=_ignore_interrupts)
        try:
            pending = {pool.submit(_simulate_chunk, first, count, seed, machine_dict, noise, with_truth):
                       (first, count) for first, count in chunks}
            while pending:
                done, _ = wait(pending, return_when=FIRST_COMPLETED)
                for future in done:
                    first, count = pending.pop(future)
                    on_done(first, count, future.result())
                    bar.advance(task, count)
        except BaseException:
            pool.shutdown(wait=False, cancel_futures=True)
            raise
        pool.shutdown(wait=True)


def _assemble(parts: dict[int, tuple], machine: Machine, noise: str, seed: int, motion: str,
              with_truth: bool) -> Dataset:
    frames, metas, skipped = [], [], []
    for first in sorted(parts):
        frame, m, s = parts[first]
        if len(frame):
            frames.append(frame)
        metas.extend(m)
        skipped.extend(s)
    if not frames:
        reasons = "; ".join(f"#{s['experiment']}: {s['reason']}" for s in skipped[:3])
        raise ExcavatorPayloadError(f"every experiment failed, nothing to write ({reasons})")
    frame = pd.concat(frames, ignore_index=True)
    frame["experiment"] = frame["experiment"].astype("int64")
    from excavator_payload.simulation.nmpc import NMPCSettings

    meta = {"machine": machine.to_dict(), "noise": get_noise_preset(noise).name, "motion": motion,
            "base_seed": int(seed), "sample_rate": SAMPLE_RATE, "experiments": metas,
            "skipped": skipped, "nmpc": asdict(NMPCSettings())}
    return Dataset(frame, meta)


def simulate_dataset(n_experiments: int, seed: int = 0, machine: Machine | str = "cat345c",
                     noise: str = "thesis", with_truth: bool = False, workers: int | None = None,
                     motion: str = "nmpc", first_experiment: int = 0, progress: bool = True,
                     **hydraulic) -> Dataset:
    """Simulate ``n_experiments`` experiments in memory.

    Parameters
    ----------
    n_experiments : int
        Number of experiments (numbered ``first_experiment …``).
    seed : int
        Base seed; experiment ``k`` uses the streams of ``(seed, k)``.
    machine : Machine or str
        Machine, preset name or TOML machine file.
    noise : str
        Noise preset: ``thesis``, ``none`` or ``field``.
    with_truth : bool
        Add the noise-free ``true_*`` columns.
    workers : int, optional
        Worker processes (default: all cores). The data do not depend on it.
    motion : str
        ``nmpc`` (the thesis' simulator), ``minimum-jerk`` or ``lifts``.
    first_experiment : int
        Number of the first experiment.
    progress : bool
        Show a progress bar.
    **hydraulic
        For a hydraulic machine only: ``session`` and ``trajectory`` (see
        :func:`excavator_payload.simulation.machine_sim.simulate_machine_dataset`).

    Returns
    -------
    Dataset
        ``meta["experiments"]`` describes each written experiment, ``meta["skipped"]`` lists
        the experiments whose simulation failed, with the reason.
    """
    # -- issue 11 hook: a hydraulic machine has its own simulator (simulation/machine_sim.py) --
    if _hydraulic(machine):
        return _simulate_hydraulic(None, n_experiments, seed, machine, noise, motion, with_truth,
                                   workers, progress, first_experiment=first_experiment, **hydraulic)
    if hydraulic:
        raise ExcavatorPayloadError(f"{', '.join(hydraulic)}: only for a hydraulic machine")
    _check_arguments(n_experiments, seed, workers, motion, first_experiment)
    machine = load_machine(machine)
    get_noise_preset(noise)
    n_experiments, seed = int(n_experiments), int(seed)
    if motion != "nmpc":
        return _delegate(motion, n_experiments, seed, machine, noise, with_truth, first_experiment)
    workers = _default_workers() if workers is None else int(workers)
    chunks = _chunks(int(first_experiment), n_experiments, chunk_size_for(n_experiments))
    parts: dict[int, tuple] = {}

    def keep(first, count, result):
        parts[first] = result

    _run_chunks(chunks, seed, machine, noise, with_truth, workers, progress, keep)
    return _assemble(parts, machine, noise, seed, motion, with_truth)


def _delegate(motion, n_experiments, seed, machine, noise, with_truth, first_experiment) -> Dataset:
    if motion == "minimum-jerk":
        from excavator_payload.simulation.minimum_jerk import simulate_minimum_jerk

        return simulate_minimum_jerk(n_experiments, seed=seed, machine=machine, noise=noise,
                                     with_truth=with_truth, first_experiment=first_experiment)
    from excavator_payload.simulation.lifts import simulate_lifts

    if first_experiment:
        raise ExcavatorPayloadError("motion 'lifts' always starts at experiment 0")
    return simulate_lifts(n_experiments, seed, machine, noise, with_truth)


# -- to a file, with checkpoints ---------------------------------------------------------------
def partial_folder(out: str | Path) -> Path:
    """Folder holding the finished chunks of an unfinished :func:`simulate_to_file` run."""
    out = Path(out)
    return out.with_name(out.name + PARTIAL_SUFFIX)


def _write_chunk(path: Path, result: tuple) -> None:
    frame, metas, skipped = result
    table = pa.Table.from_pandas(frame.reset_index(drop=True), preserve_index=False)
    meta = json.dumps({"experiments": metas, "skipped": skipped}).encode()
    table = table.replace_schema_metadata({**(table.schema.metadata or {}), METADATA_KEY: meta})
    atomic_write_table(table, path)


def _read_chunk(path: Path) -> tuple | None:
    try:
        table = pq.read_table(path)
        meta = json.loads(table.schema.metadata[METADATA_KEY])
    except Exception:  # a damaged checkpoint is simply simulated again
        log.warning("ignoring unreadable checkpoint %s", path)
        return None
    frame = table.to_pandas()
    return frame, meta["experiments"], meta["skipped"]


def simulate_to_file(out: str | Path, n_experiments: int, seed: int = 0,
                     machine: Machine | str = "cat345c", noise: str = "thesis",
                     with_truth: bool = False, workers: int | None = None, motion: str = "nmpc",
                     progress: bool = True, **hydraulic) -> Dataset:
    """Simulate and write the dataset to ``out`` (Parquet, atomic); resume an interrupted run.

    Finished chunks of NMPC experiments are kept in ``<out>.partial/`` until the file is
    written; run the same command again after an interruption to continue where it stopped.
    Parameters as :func:`simulate_dataset`. Returns the written dataset.

    Raises
    ------
    ExcavatorPayloadError
        Bad arguments, an unwritable output, or a checkpoint folder from a run with other
        settings.
    """
    # -- issue 11 hook: a hydraulic machine has its own simulator (simulation/machine_sim.py) --
    if _hydraulic(machine):
        return _simulate_hydraulic(out, n_experiments, seed, machine, noise, motion, with_truth,
                                   workers, progress, **hydraulic)
    if hydraulic:
        raise ExcavatorPayloadError(f"{', '.join(hydraulic)}: only for a hydraulic machine")
    _check_arguments(n_experiments, seed, workers, motion)
    out = Path(out)
    if out.is_dir():
        raise DatasetError(f"output '{out}' is a folder; give a file name such as data.parquet")
    machine = load_machine(machine)
    get_noise_preset(noise)
    n_experiments, seed = int(n_experiments), int(seed)
    if motion != "nmpc":
        dataset = _delegate(motion, n_experiments, seed, machine, noise, with_truth, 0)
        write_dataset(dataset, out)
        return dataset

    workers = _default_workers() if workers is None else int(workers)
    folder = partial_folder(out)
    settings = {"n_experiments": n_experiments, "seed": seed, "machine": machine.to_dict(),
                "noise": noise, "with_truth": bool(with_truth), "motion": motion,
                "chunk_size": chunk_size_for(n_experiments)}
    run_file = folder / "run.json"
    parts: dict[int, tuple] = {}
    if run_file.exists():
        try:
            previous = json.loads(run_file.read_text())
        except (OSError, json.JSONDecodeError):
            previous = None
        if previous != json.loads(json.dumps(settings)):
            raise ExcavatorPayloadError(
                f"'{folder}' holds an unfinished run with other settings; rerun it with the same "
                "settings to resume, or delete the folder to start afresh")
        for path in sorted(folder.glob("chunk_*.parquet")):
            chunk = _read_chunk(path)
            if chunk is not None:
                parts[int(path.stem.split("_")[1])] = chunk
        if parts:
            log.info("resuming: %d chunk(s) already simulated", len(parts))
    else:
        try:
            folder.mkdir(parents=True, exist_ok=True)
            run_file.write_text(json.dumps(settings))
        except OSError as exc:
            raise DatasetError(f"cannot write next to '{out}': {exc}") from None

    chunks = [c for c in _chunks(0, n_experiments, settings["chunk_size"]) if c[0] not in parts]

    def checkpoint(first, count, result):
        _write_chunk(folder / f"chunk_{first:08d}.parquet", result)
        parts[first] = result

    _run_chunks(chunks, seed, machine, noise, with_truth, workers, progress, checkpoint,
                description="simulating" if len(chunks) == len(_chunks(0, n_experiments, settings["chunk_size"]))
                else "resuming")
    dataset = _assemble(parts, machine, noise, seed, motion, with_truth)
    write_dataset(dataset, out)
    shutil.rmtree(folder, ignore_errors=True)
    return dataset


def _hydraulic(machine) -> bool:
    """Whether ``machine`` (object, preset or file) is a hydraulic machine (issue 11 hook)."""
    return getattr(load_machine(machine), "kind", None) == "hydraulic"


def _simulate_hydraulic(out, n_experiments, seed, machine, noise, motion, with_truth, workers,
                        progress, first_experiment=0, session=0, trajectory=None):
    """Issue 11 hook: the hydraulic machine's simulator. The thesis' default noise preset
    translates to the machine sensor set's ``field``."""
    from excavator_payload.simulation import machine_sim

    noise = "field" if noise == "thesis" else noise
    if trajectory is not None and motion == "nmpc":
        motion = "trajectory"
    if out is None:
        return machine_sim.simulate_machine_dataset(
            n_experiments, seed=seed, session=session, machine=machine, noise=noise, motion=motion,
            with_truth=with_truth, workers=workers, first_experiment=first_experiment,
            trajectory=trajectory, progress=progress)
    return machine_sim.simulate_machine_to_file(
        out, n_experiments, seed=seed, session=session, machine=machine, noise=noise, motion=motion,
        with_truth=with_truth, workers=workers, trajectory=trajectory, progress=progress)


def summary(dataset: Dataset, wall_time: float | None = None) -> dict:
    """Counts for the CLI: written, skipped (with reasons), share that reached the target."""
    metas = dataset.meta.get("experiments", [])
    reached = [m.get("reached") for m in metas if "reached" in m]
    return {
        "written": dataset.n_experiments,
        "skipped": list(dataset.meta.get("skipped", [])),
        "reached_share": (float(np.mean(reached)) if reached else None),
        "wall_time": wall_time,
    }
