"""Dataset generation: many experiments in parallel, reproducible, resumable.

Every experiment draws its scenario and its sensor noise from its own random streams
(:func:`~excavator_payload.simulation.scenario.experiment_rngs` of ``(seed, experiment)``), so
the data are the same whatever the number of workers, where they run, or the order in which
they finish.

The unit of work
----------------
A run is described by a small picklable :class:`~excavator_payload.simulation.experiment.RunSpec`
(motion family, seed, machine and noise preset *objects*, options). The unit of work is
:func:`simulate_chunk` ``(spec, first, count)``: experiments ``first … first+count−1`` of that
run. Chunks go through the one execution layer (:mod:`excavator_payload.execution`): a local
Dask cluster by default, an existing one with ``scheduler=``, or this process for small jobs.

Adding a simulator (extension point)
------------------------------------
The per-experiment simulator is chosen from ``spec.motion`` in the machine's platform's motion
table (:attr:`excavator_payload.platforms.Platform.motions`; named here :data:`MOTIONS` for the
thesis' arm and :data:`MACHINE_MOTIONS` for the hydraulic machine): a
:class:`~excavator_payload.platforms.base.Motion` names a function
``f(spec, experiment) -> (rows, metadata)`` by its import path (``"package.module:function"``,
imported lazily in the worker, so the entry must be in a platform's table, not registered at run
time in the client: remote workers would not see it), a chunk size rule and the exceptions that
mean "this one experiment failed, skip it". A new motion is one entry of its platform's table; a
new machine family is a new platform. Per-process state that is expensive to build (the NMPC's
compiled solver: ~2 s) is cached at module level in the worker, keyed by machine, so it is built
once per worker process, not once per chunk.

Checkpoints
-----------
:func:`simulate_to_file` checkpoints finished chunks of experiments in ``<out>.partial/``; an
interrupted run started again with the same settings simulates only the missing chunks. The
folder is removed once the dataset file has been written (atomically).
"""

from __future__ import annotations

import dataclasses
import importlib
import json
import logging
import shutil
from dataclasses import asdict
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.io import atomic_write_table, write_dataset
from excavator_payload.data.schema import DURATION, METADATA_KEY, SAMPLE_PERIOD
from excavator_payload.errors import DatasetError, ExcavatorPayloadError
from excavator_payload.execution import Execution
from excavator_payload.model.machine import Machine, load_machine
from excavator_payload.platforms import HYDRAULIC, THESIS, platform_for
from excavator_payload.platforms.base import Motion, cheap_chunk_size, nmpc_chunk_size  # noqa: F401
from excavator_payload.simulation.experiment import RunSpec, experiment_frame
from excavator_payload.simulation.scenario import experiment_rngs, sample_scenario
from excavator_payload.simulation.sensors import NoisePreset

log = logging.getLogger(__name__)

PARTIAL_SUFFIX = ".partial"


# -- the motion families: each platform's one table --------------------------------------------
# Named here too (the tables themselves are the platforms').
MOTIONS: dict[str, Motion] = THESIS.motions
MACHINE_MOTIONS: dict[str, Motion] = HYDRAULIC.motions


def motions_for(machine) -> dict[str, Motion]:
    """The motion families a machine can be simulated with (its platform's table).

    Parameters
    ----------
    machine : Machine or HydraulicMachine
        The simulated machine.

    Returns
    -------
    dict of str to Motion
        Its platform's motion table.
    """
    return platform_for(machine).motions


def sensor_set_of(machine):
    """The sensor set a simulated machine carries (its platform's).

    Parameters
    ----------
    machine : Machine or HydraulicMachine
        The simulated machine.
    """
    return platform_for(machine).sensors


def _import(path: str):
    module, _, name = path.partition(":")
    return getattr(importlib.import_module(module), name)


def chunk_size_for(n_experiments: int, motion: str = "nmpc", machine=None) -> int:
    """Experiments per chunk of a run of ``n_experiments`` ``motion`` experiments (of the thesis'
    arm unless ``machine`` is given).

    Parameters
    ----------
    n_experiments : int
        Size of the run.
    motion : str
        Motion family, a key of the platform's motion table.
    machine : Machine or HydraulicMachine, optional
        The simulated machine, which chooses the platform; default the thesis' arm.

    Returns
    -------
    int
        Experiments per chunk (the motion's chunk size rule).
    """
    platform = THESIS if machine is None else platform_for(machine)
    return platform.motions[motion].chunk_size(n_experiments)


# -- NMPC experiments (run in a worker process) -------------------------------------------------
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


def simulate_nmpc_experiment(experiment: int, seed: int, machine: Machine, noise: str | NoisePreset,
                             with_truth: bool, frozen_noise_seed: int | None = None) -> tuple[pd.DataFrame, dict]:
    """Rows and metadata of NMPC experiment number ``experiment`` of the run ``seed``.

    Parameters
    ----------
    experiment : int
        Experiment number.
    seed : int
        Base seed of the run; scenario and noise come from the streams of ``(seed, experiment)``.
    machine : Machine
        The simulated (thesis) arm.
    noise : str or NoisePreset
        Sensor noise preset or its name.
    with_truth : bool
        Also add the noise-free ``true_*`` columns.
    frozen_noise_seed : int, optional
        Draw the noise from this seed instead of the experiment's own stream (the same noise
        in every experiment).

    Returns
    -------
    frame : pandas.DataFrame
        The experiment's rows.
    meta : dict
        Its scenario, ``status`` and the controller's information.

    Raises
    ------
    excavator_payload.simulation.nmpc.ControlFailure
        If the controller fails even after its IPOPT fallback.
    """
    sim = _simulator(machine)
    scenario = sample_scenario(seed, experiment, machine.max_payload)
    _, independent = experiment_rngs(seed, experiment)
    preset = THESIS.noise(noise)
    rng = independent if frozen_noise_seed is None else np.random.default_rng(int(frozen_noise_seed))
    result = sim.run(scenario.start_pose, scenario.target_pose, scenario.payload)
    frame = experiment_frame(experiment, result.time, result.q, result.qd, result.qdd, result.tau,
                             scenario.payload, preset, rng, with_truth)
    return frame, {**scenario.to_dict(), "status": "ok", **result.info}


def nmpc_experiment(spec: RunSpec, experiment: int) -> tuple[pd.DataFrame, dict]:
    """NMPC experiment ``experiment`` of the run ``spec`` (the :data:`MOTIONS` entry).

    Parameters
    ----------
    spec : RunSpec
        The run.
    experiment : int
        Experiment number.

    Returns
    -------
    frame : pandas.DataFrame
        The experiment's rows.
    meta : dict
        Its metadata (see :func:`simulate_nmpc_experiment`).
    """
    return simulate_nmpc_experiment(experiment, spec.seed, spec.machine, spec.noise, spec.with_truth,
                                    spec.frozen_noise_seed)


# -- one chunk: the unit of work ----------------------------------------------------------------
def simulate_chunk(spec: RunSpec, first: int, count: int) -> tuple[pd.DataFrame, list[dict], list[dict]]:
    """Experiments ``first … first+count-1`` of the run ``spec``: (rows, metadata of the written
    experiments, skipped experiments with their reason).

    Parameters
    ----------
    spec : RunSpec
        The run.
    first : int
        Number of the chunk's first experiment.
    count : int
        Number of experiments in the chunk.

    Returns
    -------
    frame : pandas.DataFrame
        Rows of the written experiments (empty, with the sensor set's columns, if none).
    metas : list of dict
        Metadata of each written experiment.
    skipped : list of dict
        ``{"experiment", "reason"}`` of each experiment whose simulation failed.
    """
    platform = platform_for(spec.machine)
    motion = platform.motions[spec.motion]
    simulate = _import(motion.experiment)
    skip_on = tuple(_import(name) for name in motion.skip_on)
    frames, metas, skipped = [], [], []
    for k in range(first, first + count):
        try:
            frame, meta = simulate(spec, k)
        except skip_on as exc:
            if "KeyboardInterrupt" in str(exc):  # CasADi turns Ctrl-C into a RuntimeError
                raise KeyboardInterrupt from None
            # One bad experiment must not kill a long run: skip it and say why.
            reason = f"{type(exc).__name__}: {exc}".splitlines()[0][:300]
            log.warning("experiment %d skipped: %s", k, reason)
            skipped.append({"experiment": k, "reason": reason})
            continue
        frames.append(frame)
        metas.append(meta)
    sensors = platform.sensors
    columns = list(sensors.columns) + (list(sensors.truth_columns) if spec.with_truth else [])
    frame = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(columns=columns)
    return frame, metas, skipped


# -- the public entry points ------------------------------------------------------------------
def _check_arguments(n_experiments, seed, workers, motion, first_experiment=0, machine=None):
    if isinstance(n_experiments, bool) or not isinstance(n_experiments, (int, np.integer)) or n_experiments < 1:
        raise ExcavatorPayloadError(f"the number of experiments must be a whole number ≥ 1, got {n_experiments!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ExcavatorPayloadError(f"the seed must be a whole number ≥ 0, got {seed!r}")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, (int, np.integer))
                                or workers < 1):
        raise ExcavatorPayloadError(f"workers must be a whole number ≥ 1, got {workers!r}")
    motions = THESIS.motions if machine is None else platform_for(machine).motions
    if motion not in motions:
        (THESIS if machine is None else platform_for(machine)).motion(motion)  # one line naming them
    if not isinstance(first_experiment, (int, np.integer)) or first_experiment < 0:
        raise ExcavatorPayloadError(f"first_experiment must be a whole number ≥ 0, got {first_experiment!r}")
    if first_experiment and motions[motion].needs_first_zero:
        raise ExcavatorPayloadError(f"motion '{motion}' always starts at experiment 0")


def _chunks(first_experiment: int, n_experiments: int, size: int) -> list[tuple[int, int]]:
    end = first_experiment + n_experiments
    return [(k, min(size, end - k)) for k in range(first_experiment, end, size)]


def make_spec(n_experiments: int, seed: int = 0, machine: Machine | str = "cat345c",
              noise: str | NoisePreset | None = None, with_truth: bool = False, motion: str | None = None,
              first_experiment: int = 0, frozen_noise_seed: int | None = None,
              options: dict | None = None, session: int = 0, trajectory=None,
              payload: float | None = None, smooth: float | None = None,
              allow_overspeed: bool = False, truck_target: float | None = None) -> RunSpec:
    """Check the arguments and resolve the names into a :class:`RunSpec` (at the edge, once).

    ``noise`` and ``motion`` default to the machine kind's own (thesis: ``thesis`` noise and
    ``nmpc`` swings; hydraulic: ``field`` noise and ``swing``, or ``trajectory`` when a
    trajectory is given). ``session`` and ``trajectory`` (a file or a
    :class:`~excavator_payload.simulation.trajectory.Trajectory`) are for a hydraulic machine,
    and so is ``payload`` (kg: every generated experiment carries this mass instead of a drawn
    one, e.g. 0 for a zero-check motion; a trajectory file's payload column sets its own).
    ``smooth`` (s) filters a trajectory's angles first
    (:func:`~excavator_payload.simulation.trajectory.smooth_trajectory`); ``allow_overspeed``
    simulates a trajectory faster than the pumps instead of refusing it (the trajectory's
    ``warnings`` say where).
    ``truck_target`` (kg) is the load each truck of ``motion="shift"`` aims at.

    Parameters
    ----------
    n_experiments : int
        Number of experiments (a trajectory may hold fewer: then as many as it holds).
    seed : int
        Base seed; experiment ``k`` uses the streams of ``(seed, k)``.
    machine : Machine, HydraulicMachine or str
        Machine, preset name or TOML machine file.
    noise : NoisePreset, MachineNoise or str, optional
        Noise preset or its name; default the machine kind's own.
    with_truth : bool
        Add the noise-free ``true_*`` columns.
    motion : str, optional
        Motion family; default the machine kind's own.
    first_experiment : int
        Number of the first experiment; the spec covers experiments 0 …
        ``first_experiment + n_experiments − 1``.
    frozen_noise_seed : int, optional
        Put the same noise sequence (drawn from this seed) in every experiment.
    options : dict, optional
        Extra motion settings (e.g. ``move_time``); the platform's settings are added.
    session : int
        Hydraulic machine: working session, draws the sensor offsets.
    trajectory : str, Path or Trajectory, optional
        Hydraulic machine: prescribed motions to replay.
    payload : float, optional
        Hydraulic machine: mass every generated experiment carries, kg.
    smooth : float, optional
        Filter a trajectory's angles over this many seconds first, s.
    allow_overspeed : bool
        Simulate a trajectory faster than the pumps instead of refusing it.
    truck_target : float, optional
        Load each truck of ``motion="shift"`` aims at, kg.

    Returns
    -------
    RunSpec
        The checked description of the run.

    Raises
    ------
    ExcavatorPayloadError
        Bad arguments, or a trajectory that cannot be read or simulated.
    """
    machine = load_machine(machine)
    platform = platform_for(machine)
    motion, preset, platform_options = platform.simulation_settings(
        machine, motion, noise, session=session, trajectory=trajectory, payload=payload, smooth=smooth,
        allow_overspeed=allow_overspeed, truck_target=truck_target, frozen_noise_seed=frozen_noise_seed)
    options = {**dict(options or {}), **platform_options}
    if trajectory is not None:  # the platform took it: read and check it here, once
        from excavator_payload.simulation.trajectory import (
            check_trajectory_motion,
            read_trajectory,
            smooth_trajectory,
        )

        if not hasattr(trajectory, "experiments"):
            trajectory = read_trajectory(trajectory)
        if smooth is not None:
            trajectory = smooth_trajectory(trajectory, smooth)
        warned = check_trajectory_motion(trajectory, machine, allow_overspeed=allow_overspeed)
        if warned:
            trajectory = dataclasses.replace(trajectory, warnings=tuple(warned))
        available = len(trajectory.experiments) - int(first_experiment)
        if available < 1:
            raise ExcavatorPayloadError(f"the trajectory file holds {len(trajectory.experiments)} experiment(s)")
        n_experiments = min(int(n_experiments), available) if not isinstance(n_experiments, bool) \
            and isinstance(n_experiments, (int, np.integer)) else n_experiments
        options["trajectory"] = trajectory
    _check_arguments(n_experiments, seed, None, motion, first_experiment, machine)
    if frozen_noise_seed is not None and (isinstance(frozen_noise_seed, bool) or frozen_noise_seed < 0):
        raise ExcavatorPayloadError(f"frozen_noise_seed must be a whole number ≥ 0, got {frozen_noise_seed!r}")
    opts = tuple(sorted((str(k), tuple(v) if isinstance(v, list) else v) for k, v in options.items()))
    return RunSpec(motion, int(seed), machine, preset, bool(with_truth),
                   int(first_experiment) + int(n_experiments),
                   None if frozen_noise_seed is None else int(frozen_noise_seed), opts)


def run_chunks(spec: RunSpec, chunks: list[tuple[int, int]], execution: Execution, progress: bool,
               on_done: Callable[[int, int, tuple], None], description: str = "simulating") -> None:
    """Simulate ``chunks`` of the run ``spec`` through ``execution``; ``on_done(first, count,
    result)`` is called in this process as each chunk finishes.

    Parameters
    ----------
    spec : RunSpec
        The run.
    chunks : list of (int, int)
        ``(first, count)`` of each chunk to simulate.
    execution : Execution
        The open execution layer the chunks run on.
    progress : bool
        Show a progress bar.
    on_done : callable
        ``on_done(first, count, result)`` with the :func:`simulate_chunk` result, called in
        the order chunks finish.
    description : str
        Label of the progress bar.
    """
    def done(index, result):
        first, count = chunks[index]
        on_done(first, count, result)

    execution.map(simulate_chunk, [(spec, first, count) for first, count in chunks], on_done=done,
                  weights=[count for _, count in chunks], description=description, progress=progress)


def assemble(parts: dict[int, tuple], spec: RunSpec) -> Dataset:
    """The dataset of the finished chunks ``{first: (rows, metas, skipped)}`` of the run ``spec``.

    Parameters
    ----------
    parts : dict of int to tuple
        :func:`simulate_chunk` result of each finished chunk, keyed by its first experiment.
    spec : RunSpec
        The run (its description goes into the metadata).

    Returns
    -------
    Dataset
        Rows in experiment order; ``meta`` describes the run, the written experiments and the
        skipped ones.

    Raises
    ------
    ExcavatorPayloadError
        If every experiment failed.
    """
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
    platform = platform_for(spec.machine)
    sensors = platform.sensors
    meta = {"sensor_set": sensors.name, "machine": spec.machine.to_dict(), "noise": spec.noise.name,
            "motion": spec.motion, "base_seed": int(spec.seed), "sample_rate": sensors.sample_rate,
            "experiments": metas, "skipped": skipped}
    meta.update(platform.run_meta(spec))
    if spec.frozen_noise_seed is not None:
        meta["frozen_noise_seed"] = int(spec.frozen_noise_seed)
    if spec.motion == "nmpc":
        from excavator_payload.simulation.nmpc import NMPCSettings

        meta["nmpc"] = asdict(NMPCSettings())
    return Dataset(frame, meta)


def simulate_many(specs: dict, execution: Execution, progress: bool = True,
                  description: str = "simulating") -> dict:
    """Every experiment of several runs ``{key: spec}`` in one job (their chunks interleave on
    the workers); returns ``{key: Dataset}``. Experiments are numbered 0 … ``spec.n_experiments − 1``.

    Parameters
    ----------
    specs : dict
        The runs, by any hashable key.
    execution : Execution
        The open execution layer the chunks run on.
    progress : bool
        Show a progress bar.
    description : str
        Label of the progress bar.

    Returns
    -------
    dict
        The dataset of each run, by the same keys.
    """
    keys = list(specs)
    tasks = [(specs[key], first, count) for key in keys
             for first, count in _chunks(0, specs[key].n_experiments,
                                         chunk_size_for(specs[key].n_experiments, specs[key].motion,
                                                        specs[key].machine))]
    parts: dict = {key: {} for key in keys}
    owner = {id(specs[key]): key for key in keys}

    def keep(index, result):
        spec, first, _ = tasks[index]
        parts[owner[id(spec)]][first] = result

    execution.map(simulate_chunk, tasks, on_done=keep, weights=[t[2] for t in tasks],
                  description=description, progress=progress)
    return {key: assemble(parts[key], specs[key]) for key in keys}


def simulate_spec(spec: RunSpec, first_experiment: int, n_experiments: int, execution: Execution,
                  progress: bool = True, description: str = "simulating") -> Dataset:
    """Experiments ``first_experiment …`` of the run ``spec``, in memory, through ``execution``.

    Parameters
    ----------
    spec : RunSpec
        The run.
    first_experiment : int
        Number of the first experiment.
    n_experiments : int
        Number of experiments (fewer if the run holds fewer, e.g. a short trajectory).
    execution : Execution
        The open execution layer the chunks run on.
    progress : bool
        Show a progress bar.
    description : str
        Label of the progress bar.

    Returns
    -------
    Dataset
        The simulated experiments.
    """
    # A trajectory run may hold fewer experiments than asked for: the spec knows how many.
    n_experiments = min(int(n_experiments), spec.n_experiments - int(first_experiment))
    chunks = _chunks(int(first_experiment), n_experiments,
                     chunk_size_for(n_experiments, spec.motion, spec.machine))
    parts: dict[int, tuple] = {}

    def keep(first, count, result):
        parts[first] = result

    run_chunks(spec, chunks, execution, progress, keep, description)
    return assemble(parts, spec)


def simulate_dataset(n_experiments: int, seed: int = 0, machine: Machine | str = "cat345c",
                     noise: str | NoisePreset | None = None, with_truth: bool = False,
                     workers: int | None = None, motion: str | None = None, first_experiment: int = 0,
                     progress: bool = True, scheduler: str | None = None,
                     frozen_noise_seed: int | None = None, execution: Execution | None = None,
                     session: int = 0, trajectory=None, payload: float | None = None,
                     allow_overspeed: bool = False, truck_target: float | None = None) -> Dataset:
    """Simulate ``n_experiments`` experiments in memory.

    Parameters
    ----------
    n_experiments : int
        Number of experiments (numbered ``first_experiment …``).
    seed : int
        Base seed; experiment ``k`` uses the streams of ``(seed, k)``.
    machine : Machine, HydraulicMachine or str
        Machine, preset name or TOML machine file (thesis arm or hydraulic machine).
    noise : NoisePreset, MachineNoise or str, optional
        Noise preset: ``thesis`` (default), ``none`` or ``field``; for a hydraulic machine
        ``field`` (default) or ``none``.
    with_truth : bool
        Add the noise-free ``true_*`` columns.
    workers : int, optional
        Local worker processes (default: all cores). The data do not depend on it.
    motion : str, optional
        A key of :data:`MOTIONS`: ``nmpc`` (default, the thesis' simulator), ``minimum-jerk`` or
        ``lifts``; for a hydraulic machine a key of :data:`MACHINE_MOTIONS` (default ``swing``).
    first_experiment : int
        Number of the first experiment.
    progress : bool
        Show a progress bar.
    scheduler : str, optional
        Address of a Dask scheduler to run on (default ``$EXCAVATOR_PAYLOAD_SCHEDULER``, else
        local worker processes).
    frozen_noise_seed : int, optional
        Put the same noise sequence (drawn from this seed) in every experiment.
    execution : Execution, optional
        An open execution layer to use instead of ``workers`` / ``scheduler`` (kept open).
    session : int
        Hydraulic machine: the working session, which draws the sensor offsets (independently
        of ``seed``).
    trajectory : str, Path or Trajectory, optional
        Hydraulic machine: prescribed motions to replay (``motion="trajectory"``).
    payload : float, optional
        Hydraulic machine: the mass (kg) every generated experiment carries instead of a drawn
        one (0: an empty bucket, as a zero check needs).
    allow_overspeed : bool
        Hydraulic machine: simulate a trajectory faster than the pumps give instead of refusing it.
    truck_target : float, optional
        Hydraulic machine, ``motion="shift"``: the load (kg) each truck (experiment) aims at.

    Returns
    -------
    Dataset
        ``meta["experiments"]`` describes each written experiment, ``meta["skipped"]`` lists
        the experiments whose simulation failed, with the reason.
    """
    spec = make_spec(n_experiments, seed, machine, noise, with_truth, motion, first_experiment,
                     frozen_noise_seed, session=session, trajectory=trajectory, payload=payload,
                     allow_overspeed=allow_overspeed, truck_target=truck_target)
    _check_arguments(n_experiments, seed, workers, spec.motion, first_experiment, spec.machine)
    if execution is not None:
        return simulate_spec(spec, first_experiment, n_experiments, execution, progress)
    with Execution(scheduler, None if workers is None else int(workers)) as own:
        return simulate_spec(spec, first_experiment, n_experiments, own, progress)


# -- to a file, with checkpoints ---------------------------------------------------------------
def partial_folder(out: str | Path) -> Path:
    """Folder holding the finished chunks of an unfinished :func:`simulate_to_file` run.

    Parameters
    ----------
    out : str or Path
        The run's dataset file.

    Returns
    -------
    Path
        ``<out>.partial`` next to it.
    """
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
                     machine: Machine | str = "cat345c", noise: str | NoisePreset | None = None,
                     with_truth: bool = False, workers: int | None = None, motion: str | None = None,
                     progress: bool = True, scheduler: str | None = None,
                     frozen_noise_seed: int | None = None, execution: Execution | None = None,
                     session: int = 0, trajectory=None, payload: float | None = None,
                     allow_overspeed: bool = False, truck_target: float | None = None) -> Dataset:
    """Simulate and write the dataset to ``out`` (Parquet, atomic); resume an interrupted run.

    Finished chunks of experiments are kept in ``<out>.partial/`` until the file is written;
    run the same command again after an interruption to continue where it stopped.

    Parameters
    ----------
    out : str or Path
        The dataset file to write.
    n_experiments : int
        Number of experiments (numbered from 0).
    seed : int
        Base seed; experiment ``k`` uses the streams of ``(seed, k)``.
    machine : Machine, HydraulicMachine or str
        Machine, preset name or TOML machine file.
    noise : NoisePreset, MachineNoise or str, optional
        Noise preset or its name; default the machine kind's own.
    with_truth : bool
        Add the noise-free ``true_*`` columns.
    workers : int, optional
        Local worker processes (default: all cores). The data do not depend on it.
    motion : str, optional
        Motion family; default the machine kind's own.
    progress : bool
        Show a progress bar.
    scheduler : str, optional
        Address of a Dask scheduler to run on.
    frozen_noise_seed : int, optional
        Put the same noise sequence (drawn from this seed) in every experiment.
    execution : Execution, optional
        An open execution layer to use instead of ``workers`` / ``scheduler`` (kept open).
    session : int
        Hydraulic machine: working session, draws the sensor offsets.
    trajectory : str, Path or Trajectory, optional
        Hydraulic machine: prescribed motions to replay.
    payload : float, optional
        Hydraulic machine: mass every generated experiment carries, kg.
    allow_overspeed : bool
        Simulate a trajectory faster than the pumps instead of refusing it.
    truck_target : float, optional
        Load each truck of ``motion="shift"`` aims at, kg.

    Returns
    -------
    Dataset
        The written dataset.

    Raises
    ------
    ExcavatorPayloadError
        Bad arguments, an unwritable output, or a checkpoint folder from a run with other
        settings.
    """
    if Path(out).is_dir():
        raise DatasetError(f"output '{out}' is a folder; give a file name such as data.parquet")
    spec = make_spec(n_experiments, seed, machine, noise, with_truth, motion, 0, frozen_noise_seed,
                     session=session, trajectory=trajectory, payload=payload,
                     allow_overspeed=allow_overspeed, truck_target=truck_target)
    _check_arguments(n_experiments, seed, workers, spec.motion, 0, spec.machine)
    return simulate_spec_to_file(out, spec, workers=workers, progress=progress, scheduler=scheduler,
                                 execution=execution)


def simulate_spec_to_file(out: str | Path, spec: RunSpec, workers: int | None = None, progress: bool = True,
                          scheduler: str | None = None, execution: Execution | None = None) -> Dataset:
    """Simulate the run ``spec`` (from :func:`make_spec`, built once at the edge) and write it to
    ``out`` (Parquet, atomic); resume an interrupted run.

    Parameters
    ----------
    out : str or Path
        The dataset file; finished chunks are kept in ``<out>.partial/`` until it is written.
    spec : RunSpec
        The whole run (machine, noise, motion, options), already checked.
    workers : int, optional
        Local worker processes (default: all cores). The data do not depend on it.
    progress : bool
        Show a progress bar.
    scheduler : str, optional
        Address of a Dask scheduler to run on.
    execution : Execution, optional
        An open execution layer to use instead of ``workers`` / ``scheduler`` (kept open).

    Returns
    -------
    Dataset
        The written dataset.

    Raises
    ------
    ExcavatorPayloadError
        An unwritable output, or a checkpoint folder from a run with other settings.
    """
    out = Path(out)
    if out.is_dir():
        raise DatasetError(f"output '{out}' is a folder; give a file name such as data.parquet")
    source = dict(spec.options).get("trajectory")
    if source is not None and Path(source.source).resolve() == out.resolve():
        raise DatasetError("the output would overwrite the trajectory file")
    n_experiments = spec.n_experiments  # a trajectory may hold fewer than asked for (first is 0)
    folder = partial_folder(out)
    settings = {**spec.to_dict(), "chunk_size": chunk_size_for(n_experiments, spec.motion, spec.machine)}
    run_file = folder / "run.json"
    parts: dict[int, tuple] = {}
    if run_file.exists():
        try:
            previous = json.loads(run_file.read_text(encoding="utf-8"))
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
            run_file.write_text(json.dumps(settings), encoding="utf-8")
        except OSError as exc:
            raise DatasetError(f"cannot write next to '{out}': {exc}") from None

    all_chunks = _chunks(0, n_experiments, settings["chunk_size"])
    chunks = [c for c in all_chunks if c[0] not in parts]

    def checkpoint(first, count, result):
        _write_chunk(folder / f"chunk_{first:08d}.parquet", result)
        parts[first] = result

    description = "simulating" if len(chunks) == len(all_chunks) else "resuming"
    if execution is not None:
        run_chunks(spec, chunks, execution, progress, checkpoint, description)
    else:
        with Execution(scheduler, None if workers is None else int(workers)) as own:
            run_chunks(spec, chunks, own, progress, checkpoint, description)
    dataset = assemble(parts, spec)
    write_dataset(dataset, out)
    shutil.rmtree(folder, ignore_errors=True)
    return dataset


def summary(dataset: Dataset, wall_time: float | None = None) -> dict:
    """Counts for the CLI: written, skipped (with reasons), share that reached the target.

    Parameters
    ----------
    dataset : Dataset
        A simulated dataset.
    wall_time : float, optional
        Duration of the run, s, passed through.

    Returns
    -------
    dict
        ``written`` (int), ``skipped`` (list of dict), ``reached_share`` (float in [0, 1], or
        ``None`` when the motion does not record it) and ``wall_time``.
    """
    metas = dataset.meta.get("experiments", [])
    reached = [m.get("reached") for m in metas if "reached" in m]
    return {
        "written": dataset.n_experiments,
        "skipped": list(dataset.meta.get("skipped", [])),
        "reached_share": (float(np.mean(reached)) if reached else None),
        "wall_time": wall_time,
    }
