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
The per-experiment simulator is chosen from ``spec.motion`` in :data:`MOTIONS`: a
:class:`Motion` names a function ``f(spec, experiment) -> (rows, metadata)`` by its import path
(``"package.module:function"``, imported lazily in the worker, so the entry must be in this
table, not registered at run time in the client: remote workers would not see it), a chunk
size rule and the exceptions that mean "this one experiment failed, skip it". A new machine
type with its own simulator adds one table: the hydraulic machine's motions
(:data:`MACHINE_MOTIONS`, simulated by :mod:`~excavator_payload.simulation.machine_sim`) go
through the same chunks, checkpoints, clusters and studies; :func:`motions_for` picks the table
by the machine's kind. Per-process state that is expensive to build
(the NMPC's compiled solver: ~2 s) is cached at module level in the worker, keyed by machine,
so it is built once per worker process, not once per chunk.

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
import math
import shutil
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.io import atomic_write_table, write_dataset
from excavator_payload.data.schema import (
    DURATION,
    MACHINE_SENSORS,
    METADATA_KEY,
    SAMPLE_PERIOD,
    THESIS_SENSORS,
)
from excavator_payload.errors import DatasetError, ExcavatorPayloadError
from excavator_payload.execution import Execution
from excavator_payload.model.machine import Machine, load_machine
from excavator_payload.simulation.experiment import RunSpec, experiment_frame, noise_rng
from excavator_payload.simulation.scenario import experiment_rngs, sample_scenario
from excavator_payload.simulation.sensors import NoisePreset, get_noise_preset

log = logging.getLogger(__name__)

PARTIAL_SUFFIX = ".partial"


# -- the motion families ----------------------------------------------------------------------
def nmpc_chunk_size(n_experiments: int) -> int:
    """Experiments per checkpointed chunk: small enough for a smooth progress bar and little
    lost work on interruption, large enough to keep the per-chunk overhead small."""
    return int(min(25, max(1, math.ceil(n_experiments / 40))))


def cheap_chunk_size(n_experiments: int) -> int:
    """Motions with computed torques take ~1 ms per experiment: big chunks (small jobs: one)."""
    return int(min(5000, max(1, n_experiments)))


@dataclass(frozen=True)
class Motion:
    """A motion family: how one experiment is simulated and how a run is cut into chunks.

    Attributes
    ----------
    experiment : str
        ``"module:function"`` of ``f(spec, experiment) -> (rows DataFrame, metadata dict)``.
    chunk_size : callable
        Experiments per chunk for a run of ``n`` experiments.
    skip_on : tuple of str
        ``"module:ExceptionClass"`` names: such an error skips the experiment (recorded with its
        reason) instead of stopping the run.
    needs_first_zero : bool
        The run's experiments depend on each other's numbering from 0 (the lifts).
    description : str
        For ``--help``.
    """

    experiment: str
    chunk_size: Callable[[int], int]
    skip_on: tuple[str, ...] = ()
    needs_first_zero: bool = False
    description: str = ""


#: The motion families, by name (see "Adding a simulator" above).
MOTIONS: dict[str, Motion] = {
    "nmpc": Motion("excavator_payload.simulation.generate:nmpc_experiment", nmpc_chunk_size,
                   skip_on=("builtins:RuntimeError", "builtins:ValueError", "builtins:FloatingPointError"),
                   description="the thesis' NMPC-driven swings"),
    "minimum-jerk": Motion("excavator_payload.simulation.minimum_jerk:minimum_jerk_experiment",
                           cheap_chunk_size, description="minimum-jerk swings with computed torques"),
    "lifts": Motion("excavator_payload.simulation.lifts:lift_experiment", cheap_chunk_size,
                    needs_first_zero=True, description="slow constant-speed calibration lifts"),
}


def _machine_chunk_size(n_experiments: int) -> int:
    """Hydraulic motions take ~0.05 s each: ≈ 40 chunks of 1–50 experiments."""
    return int(min(50, max(1, math.ceil(n_experiments / 40))))


_MACHINE_EXPERIMENT = "excavator_payload.simulation.machine_sim:machine_experiment"
_MACHINE_SKIP = ("builtins:RuntimeError", "builtins:ValueError", "builtins:FloatingPointError")

#: The hydraulic machine's motion families (issue "The machine as it is").
MACHINE_MOTIONS: dict[str, Motion] = {
    "swing": Motion(_MACHINE_EXPERIMENT, _machine_chunk_size, _MACHINE_SKIP,
                    description="swings with slewing, within pump flow and relief pressure"),
    "nmpc": Motion(_MACHINE_EXPERIMENT, nmpc_chunk_size, _MACHINE_SKIP,
                   description="NMPC swings with slewing, bounded by relief valves, pump flow and strokes"),
    "work-cycle": Motion(_MACHINE_EXPERIMENT, _machine_chunk_size, _MACHINE_SKIP,
                         description="operator-like cycles: dig, lift while slewing, pause, dump, return"),
    "slopes": Motion(_MACHINE_EXPERIMENT, _machine_chunk_size, _MACHINE_SKIP,
                     description="work cycles of a machine standing on a slope"),
    "lifts": Motion(_MACHINE_EXPERIMENT, _machine_chunk_size, _MACHINE_SKIP,
                    description="slow calibration lifts"),
    "operator": Motion(_MACHINE_EXPERIMENT, _machine_chunk_size, _MACHINE_SKIP,
                       description="operator-like lift and slew: a pause, an overshoot, trims all along"),
    "trajectory": Motion(_MACHINE_EXPERIMENT, _machine_chunk_size, _MACHINE_SKIP,
                         description="prescribed motions replayed from a trajectory file"),
    "shift": Motion(_MACHINE_EXPERIMENT, _machine_chunk_size, _MACHINE_SKIP,
                    description="a day of loading: one truck of 2-6 work cycles per experiment"),
}


def is_hydraulic(machine) -> bool:
    """Whether ``machine`` (an object) is a hydraulic machine."""
    return getattr(machine, "kind", None) == "hydraulic"


def motions_for(machine) -> dict[str, Motion]:
    """The motion families a machine can be simulated with."""
    return MACHINE_MOTIONS if is_hydraulic(machine) else MOTIONS


def sensor_set_of(machine):
    """The sensor set a simulated machine carries."""
    return MACHINE_SENSORS if is_hydraulic(machine) else THESIS_SENSORS


def _import(path: str):
    module, _, name = path.partition(":")
    return getattr(importlib.import_module(module), name)


def chunk_size_for(n_experiments: int, motion: str = "nmpc", machine=None) -> int:
    """Experiments per chunk of a run of ``n_experiments`` ``motion`` experiments."""
    return motions_for(machine)[motion].chunk_size(n_experiments)


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

    Raises
    ------
    excavator_payload.simulation.nmpc.ControlFailure
        If the controller fails even after its IPOPT fallback.
    """
    sim = _simulator(machine)
    scenario = sample_scenario(seed, experiment, machine.max_payload)
    _, independent = experiment_rngs(seed, experiment)
    preset = get_noise_preset(noise)
    rng = independent if frozen_noise_seed is None else np.random.default_rng(int(frozen_noise_seed))
    result = sim.run(scenario.start_pose, scenario.target_pose, scenario.payload)
    frame = experiment_frame(experiment, result.time, result.q, result.qd, result.qdd, result.tau,
                             scenario.payload, preset, rng, with_truth)
    return frame, {**scenario.to_dict(), "status": "ok", **result.info}


def nmpc_experiment(spec: RunSpec, experiment: int) -> tuple[pd.DataFrame, dict]:
    """NMPC experiment ``experiment`` of the run ``spec`` (the :data:`MOTIONS` entry)."""
    return simulate_nmpc_experiment(experiment, spec.seed, spec.machine, spec.noise, spec.with_truth,
                                    spec.frozen_noise_seed)


# -- one chunk: the unit of work ----------------------------------------------------------------
def simulate_chunk(spec: RunSpec, first: int, count: int) -> tuple[pd.DataFrame, list[dict], list[dict]]:
    """Experiments ``first … first+count-1`` of the run ``spec``: (rows, metadata of the written
    experiments, skipped experiments with their reason)."""
    motion = motions_for(spec.machine)[spec.motion]
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
    sensors = sensor_set_of(spec.machine)
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
    motions = motions_for(machine)
    if motion not in motions:
        kind = "a hydraulic machine" if is_hydraulic(machine) else "this machine"
        raise ExcavatorPayloadError(f"unknown motion '{motion}' for {kind}: choose one of {', '.join(motions)}")
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
    """
    machine = load_machine(machine)
    options = dict(options or {})
    if is_hydraulic(machine):
        from excavator_payload.simulation.machine_sensors import get_machine_noise
        from excavator_payload.simulation.trajectory import (
            check_trajectory_motion,
            read_trajectory,
            smooth_trajectory,
        )

        if motion is None:
            motion = "trajectory" if trajectory is not None else "swing"
        if (motion == "trajectory") != (trajectory is not None):
            raise ExcavatorPayloadError("a trajectory file goes with --motion trajectory (and only with it)")
        if frozen_noise_seed is not None:
            raise ExcavatorPayloadError("frozen noise is a thesis-setting study; the hydraulic machine's "
                                        "sensors always draw their own noise")
        if isinstance(session, bool) or not isinstance(session, (int, np.integer)) or session < 0:
            raise ExcavatorPayloadError(f"the session must be a whole number ≥ 0, got {session!r}")
        preset = get_machine_noise("field" if noise is None else noise)
        options["session"] = int(session)
        if payload is not None:
            if trajectory is not None:
                raise ExcavatorPayloadError("--payload does not go with a trajectory file: its payload "
                                            "column sets the mass")
            if (isinstance(payload, bool) or not isinstance(payload, (int, float, np.number))
                    or not 0.0 <= float(payload) <= machine.max_payload):
                raise ExcavatorPayloadError(f"--payload must be between 0 and the machine's maximum "
                                            f"payload, {machine.max_payload:g} kg; got {payload!r}")
            options["payload"] = float(payload)
        if trajectory is None and (smooth is not None or allow_overspeed):
            raise ExcavatorPayloadError("--smooth and --allow-overspeed go with a trajectory file (--trajectory)")
        if truck_target is not None or motion == "shift":
            if motion != "shift":
                raise ExcavatorPayloadError("--truck-target goes with --motion shift (and only with it)")
            if payload is not None:
                raise ExcavatorPayloadError("--payload does not go with --motion shift: each pass draws "
                                            "its fill towards --truck-target")
            if truck_target is not None:
                most = machine.max_payload * 6
                if (isinstance(truck_target, bool) or not isinstance(truck_target, (int, float, np.number))
                        or not 0.0 < float(truck_target) <= most):
                    raise ExcavatorPayloadError(f"--truck-target must be above 0 and at most 6 passes of the "
                                                f"machine's maximum payload, {most:g} kg; got {truck_target!r}")
                options["truck_target"] = float(truck_target)
        if trajectory is not None:
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
    else:
        if smooth is not None or allow_overspeed:
            raise ExcavatorPayloadError("--smooth and --allow-overspeed go with a trajectory file (--trajectory)")
        if session or trajectory is not None or payload is not None or truck_target is not None:
            raise ExcavatorPayloadError("--session, --trajectory, --payload and --truck-target apply to a "
                                        "hydraulic machine only")
        motion = "nmpc" if motion is None else motion
        preset = get_noise_preset("thesis" if noise is None else noise)
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
    result)`` is called in this process as each chunk finishes."""
    def done(index, result):
        first, count = chunks[index]
        on_done(first, count, result)

    execution.map(simulate_chunk, [(spec, first, count) for first, count in chunks], on_done=done,
                  weights=[count for _, count in chunks], description=description, progress=progress)


def assemble(parts: dict[int, tuple], spec: RunSpec) -> Dataset:
    """The dataset of the finished chunks ``{first: (rows, metas, skipped)}`` of the run ``spec``."""
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
    sensors = sensor_set_of(spec.machine)
    meta = {"sensor_set": sensors.name, "machine": spec.machine.to_dict(), "noise": spec.noise.name,
            "motion": spec.motion, "base_seed": int(spec.seed), "sample_rate": sensors.sample_rate,
            "experiments": metas, "skipped": skipped}
    if is_hydraulic(spec.machine):
        from excavator_payload.simulation.machine_sim import dataset_meta

        meta.update(dataset_meta(spec))
    if spec.frozen_noise_seed is not None:
        meta["frozen_noise_seed"] = int(spec.frozen_noise_seed)
    if spec.motion == "nmpc":
        from excavator_payload.simulation.nmpc import NMPCSettings

        meta["nmpc"] = asdict(NMPCSettings())
    return Dataset(frame, meta)


def simulate_many(specs: dict, execution: Execution, progress: bool = True,
                  description: str = "simulating") -> dict:
    """Every experiment of several runs ``{key: spec}`` in one job (their chunks interleave on
    the workers); returns ``{key: Dataset}``. Experiments are numbered 0 … ``spec.n_experiments − 1``."""
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
    """Experiments ``first_experiment …`` of the run ``spec``, in memory, through ``execution``."""
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
                     machine: Machine | str = "cat345c", noise: str | NoisePreset | None = None,
                     with_truth: bool = False, workers: int | None = None, motion: str | None = None,
                     progress: bool = True, scheduler: str | None = None,
                     frozen_noise_seed: int | None = None, execution: Execution | None = None,
                     session: int = 0, trajectory=None, payload: float | None = None,
                     allow_overspeed: bool = False, truck_target: float | None = None) -> Dataset:
    """Simulate and write the dataset to ``out`` (Parquet, atomic); resume an interrupted run.

    Finished chunks of experiments are kept in ``<out>.partial/`` until the file is written;
    run the same command again after an interruption to continue where it stopped.
    Parameters as :func:`simulate_dataset`. Returns the written dataset.

    Raises
    ------
    ExcavatorPayloadError
        Bad arguments, an unwritable output, or a checkpoint folder from a run with other
        settings.
    """
    out = Path(out)
    if out.is_dir():
        raise DatasetError(f"output '{out}' is a folder; give a file name such as data.parquet")
    spec = make_spec(n_experiments, seed, machine, noise, with_truth, motion, 0, frozen_noise_seed,
                     session=session, trajectory=trajectory, payload=payload,
                     allow_overspeed=allow_overspeed, truck_target=truck_target)
    _check_arguments(n_experiments, seed, workers, spec.motion, 0, spec.machine)
    source = dict(spec.options).get("trajectory")
    if source is not None and Path(source.source).resolve() == out.resolve():
        raise DatasetError("the output would overwrite the trajectory file")
    n_experiments = spec.n_experiments  # a trajectory may hold fewer than asked for
    folder = partial_folder(out)
    settings = {**spec.to_dict(), "chunk_size": chunk_size_for(n_experiments, spec.motion, spec.machine)}
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
    """Counts for the CLI: written, skipped (with reasons), share that reached the target."""
    metas = dataset.meta.get("experiments", [])
    reached = [m.get("reached") for m in metas if "reached" in m]
    return {
        "written": dataset.n_experiments,
        "skipped": list(dataset.meta.get("skipped", [])),
        "reached_share": (float(np.mean(reached)) if reached else None),
        "wall_time": wall_time,
    }
