"""Simulator of the hydraulic machine: motions through the model and the machine's sensors.

Every experiment is a motion (an NMPC swing, :mod:`.hydraulic_nmpc`; planned in
:mod:`.machine_motions` within the hydraulics' limits; or replayed from a trajectory file,
:mod:`.trajectory`) pushed through the symbolic model of
:mod:`excavator_payload.model.hydraulic`:

1. inverse dynamics gives the joint torques (and the slew torque) of the motion, with the
   house slewing on tilted ground and the payload in the bucket (on a shift's cuts, plus the
   torques Jᵀf of the soil's force on the teeth, :meth:`~.machine_motions.Motion.soil_force`);
2. each cylinder's load force is its joint torque over its moment arm (÷ count);
3. seal friction (Coulomb + load-dependent + Stribeck + viscous, with a presliding state
   while the rod slides) is added: the pressures must overcome it. Where a rod stands still
   (:func:`rest_friction`) its valve has closed: the seal holds the friction it had when the
   valve closed — anywhere within ± the breakaway force, set by how the valve closed — and the
   trapped oil, far stiffer than the seal's presliding, takes up whatever the load does
   meanwhile;
4. the head and rod pressures that give that force (the other side at the back pressure);
5. the sensors (:mod:`.machine_sensors`) add white noise, the session's offsets, pump ripple
   and the IMUs' dynamic error, at 100 Hz.

Generated motions whose pressures would exceed the relief pressure are redrawn (the operator
cannot make them), so that every sample is one the machine can produce.

Reproducibility: experiment ``k`` of run ``seed`` draws its motion and its noise from streams
of ``(seed, k)`` alone, and the sensor offsets from ``session`` alone, so the data do not depend
on chunking or worker count. :func:`machine_experiment` is the entry of the hydraulic motions in
:mod:`excavator_payload.simulation.generate`, which runs them in chunks through the execution
layer like every other simulation (parallel, resumable, atomic);
:func:`simulate_machine_dataset` and :func:`simulate_machine_to_file` are wrappers of it.
"""

from __future__ import annotations

import dataclasses
import importlib
import json
import logging

import numpy as np
import pandas as pd

from excavator_payload.data.dataset import Dataset
from excavator_payload.errors import MachineError
from excavator_payload.model.hydraulic import HydraulicArmModel
from excavator_payload.model.hydraulic_machine import HydraulicMachine
from excavator_payload.platforms import HYDRAULIC
from excavator_payload.simulation import machine_motions as mm

# The physics of one motion, named here too (tests and benchmarks use these names).
from excavator_payload.simulation.machine_physics import (  # noqa: F401
    REST_MIN_SAMPLES,
    REST_SPEED_SHARE,
    SAMPLE_RATE,
    arm_model,
    closing_rng,
    experiment_rows,
    friction_states,
    machine_rngs,
    motion_physics,
    rest_friction,
    sample_times,
)
from excavator_payload.simulation.machine_sensors import MachineNoise, session_offsets

log = logging.getLogger(__name__)

_arm = arm_model
#: Length of an NMPC swing, s.
NMPC_DURATION = 10.0
#: Largest share of the pumps' speed an NMPC swing may use (between its nodes).
NMPC_SPEED_TOLERANCE = 1.05
MAX_ATTEMPTS = 30


_NMPC: dict[str, object] = {}


def _nmpc_simulator(arm: HydraulicArmModel):
    """The process's NMPC simulator for this machine (built once; compiled model cached on disk)."""
    from excavator_payload.simulation.hydraulic_nmpc import HydraulicNMPCSimulator

    key = json.dumps(arm.machine.to_dict(), sort_keys=True)
    if key not in _NMPC:
        _NMPC[key] = HydraulicNMPCSimulator(arm)
    return _NMPC[key]


def simulate_nmpc_experiment(k: int, seed: int, arm: HydraulicArmModel, noise: MachineNoise,
                             offsets: dict, with_truth: bool,
                             payload_override: float | None = None) -> tuple[pd.DataFrame, dict]:
    """NMPC swing ``k``: from a digging pose to a dumping pose while slewing 30-120°, 10 s.
    ``payload_override`` (kg): this mass instead of the drawn one (``simulate --payload``).

    Parameters
    ----------
    k : int
        Experiment number; motion and noise come from the streams of ``(seed, k)``.
    seed : int
        Base seed of the run.
    arm : HydraulicArmModel
        The machine's model.
    noise : MachineNoise
        Sensor noise preset.
    offsets : dict
        The session's sensor offsets, SI units (:func:`session_offsets`).
    with_truth : bool
        Also add the noise-free ``true_*`` columns.
    payload_override : float, optional
        Mass in the bucket, kg, instead of the drawn one.

    Returns
    -------
    frame : pandas.DataFrame
        The experiment's rows.
    meta : dict
        Its description (payload in kg, poses in rad, peak pressure in Pa, draws, …).

    Raises
    ------
    ValueError
        If no swing within the relief pressure and the pumps' speed was found in
        ``MAX_ATTEMPTS`` draws.
    """
    machine = arm.machine
    motion_rng, noise_rng = machine_rngs(seed, k)
    valves = closing_rng(seed, k)
    relief = machine.hydraulics.relief_pressure
    from excavator_payload.simulation.hydraulic_nmpc import ControlFailure

    sim = _nmpc_simulator(arm)
    failures: list[str] = []
    for attempt in range(1, MAX_ATTEMPTS + 1):
        start = mm.dig_pose(motion_rng, machine)
        target = mm.carry_pose(motion_rng, machine)
        target[3] = float(motion_rng.uniform(np.radians(30), np.radians(120)) * motion_rng.choice([-1, 1]))
        payload = float(motion_rng.uniform(0.0, machine.max_payload))
        if payload_override is not None:  # drawn all the same: the other draws stay the same
            payload = float(payload_override)
        friction0 = motion_rng.uniform(-1, 1, 3)
        try:
            time, q, qd, qdd, _, info = sim.run(start, target, np.zeros(2), payload, NMPC_DURATION)
        except ControlFailure as exc:  # a swing the controller cannot plan is redrawn too
            failures.append(str(exc))
            continue
        physics = motion_physics(arm, time, q, qd, qdd, np.zeros(2), np.full(len(time), payload), friction0,
                                 valves)
        peak = float(max(physics["head"].max(), physics["rod"].max()))
        share = mm.speed_share(arm, q, qd)
        # The controller bounds speeds at its nodes only and friction is not in its model: a
        # swing the machine cannot make (over relief, or over the pumps' speed by > 5 %) is
        # redrawn, as the other motions are.
        if peak <= relief and share <= NMPC_SPEED_TOLERANCE:
            break
    else:
        last = f" (last controller failure: {failures[-1]})" if failures else ""
        raise ValueError(f"no NMPC swing within the relief pressure and pump speed in {MAX_ATTEMPTS} "
                         f"draws{last}")
    frame = experiment_rows(k, time, q, qd, qdd, physics, payload, noise, offsets, noise_rng, with_truth)
    meta = {"experiment": int(k), "seed": int(seed), "payload": payload, "motion": "nmpc",
            "tilt": [0.0, 0.0], "duration": float(time[-1]), "start_pose": start.tolist(),
            "target_pose": target.tolist(), "peak_pressure": peak, "within_relief": True,
            "speed_share": share, "controller_failures": len(failures),
            "draws": attempt, "status": "ok", **info}
    return frame, meta


def _within_relief(arm: HydraulicArmModel, draw, motion_rng: np.random.Generator,
                   valves: np.random.Generator, what: str, any_peak: bool = False):
    """A planned motion (``draw()``, slowed to the pumps) pushed through the physics, drawn again
    until its pressures stay within the relief pressure (``any_peak``: the first one, as the
    calibration lifts). Returns (plan, time, (q, q̇, q̈), physics, peak pressure, attempts)."""
    relief = arm.machine.hydraulics.relief_pressure
    for attempt in range(1, MAX_ATTEMPTS + 1):
        plan = mm.fit_to_hydraulics(arm, draw())
        time = sample_times(plan.duration)
        q, qd, qdd = plan.sample(time)
        friction0 = motion_rng.uniform(-1, 1, 3)
        soil = plan.soil_force(time, arm.tip_velocity(q, qd)) if plan.soil else None
        physics = motion_physics(arm, time, q, qd, qdd, plan.tilt, plan.payload_at(time), friction0, valves,
                                 tip_force=soil)
        peak = float(max(physics["head"].max(), physics["rod"].max()))
        if peak <= relief or any_peak:
            return plan, time, (q, qd, qdd), physics, peak, attempt
    raise ValueError(f"no {what} within the relief pressure in {MAX_ATTEMPTS} draws")


def simulate_motion_experiment(k: int, seed: int, arm: HydraulicArmModel, noise: MachineNoise,
                               offsets: dict, motion: str, with_truth: bool,
                               payload_override: float | None = None, *, draw_motion,
                               any_peak: bool = False) -> tuple[pd.DataFrame, dict]:
    """Rows and metadata of generated experiment ``k`` (redrawn until within the relief pressure).
    ``draw_motion(k, rng, arm)`` plans the motion called ``motion``; ``any_peak``: keep the first
    draw whatever its peak (the calibration lifts). ``payload_override`` (kg): this mass instead
    of the drawn one (``simulate --payload``).

    Parameters
    ----------
    k : int
        Experiment number; motion and noise come from the streams of ``(seed, k)``.
    seed : int
        Base seed of the run.
    arm : HydraulicArmModel
        The machine's model.
    noise : MachineNoise
        Sensor noise preset.
    offsets : dict
        The session's sensor offsets, SI units (:func:`session_offsets`).
    motion : str
        Name of the motion family, written into the metadata.
    with_truth : bool
        Also add the noise-free ``true_*`` columns.
    payload_override : float, optional
        Mass in the bucket, kg, instead of the drawn one.
    draw_motion : callable
        ``draw_motion(k, rng, arm) -> Motion`` plans one candidate motion.
    any_peak : bool
        Keep the first draw whatever its peak pressure.

    Returns
    -------
    frame : pandas.DataFrame
        The experiment's rows.
    meta : dict
        Its description (payload in kg, poses in rad, peak pressure in Pa, draws, …).

    Raises
    ------
    ValueError
        If no draw stayed within the relief pressure in ``MAX_ATTEMPTS`` draws.
    """
    machine = arm.machine
    motion_rng, noise_rng = machine_rngs(seed, k)
    relief = machine.hydraulics.relief_pressure

    def draw():
        drawn = draw_motion(k, motion_rng, arm)
        if payload_override is not None:  # before the fit: the mass shapes the pressures it checks
            drawn = dataclasses.replace(drawn, payload=float(payload_override))
        return drawn

    plan, time, (q, qd, qdd), physics, peak, attempt = _within_relief(
        arm, draw, motion_rng, closing_rng(seed, k), "motion", any_peak=any_peak)
    frame = experiment_rows(k, time, q, qd, qdd, physics, plan.payload, noise, offsets, noise_rng,
                            with_truth)
    meta = {"experiment": int(k), "seed": int(seed), "payload": float(plan.payload),
            "motion": motion, "tilt": [float(v) for v in plan.tilt], "duration": float(time[-1]),
            "peak_pressure": peak, "within_relief": bool(peak <= relief), "draws": attempt,
            "status": "ok", **{key: (v.tolist() if isinstance(v, np.ndarray) else v)
                               for key, v in plan.info.items()}}
    if plan.release is not None:
        meta["release"] = [float(plan.release[0]), float(plan.release[1])]
    return frame, meta


def default_truck_target(machine) -> float:
    """Truck target (kg) of ``--motion shift`` without ``--truck-target``: 4 passes at 90 % of rated.

    Parameters
    ----------
    machine : HydraulicMachine
        The machine (its rated payload, kg).
    """
    return 4 * 0.9 * float(machine.rated_payload)


def simulate_shift_experiment(k: int, seed: int, arm: HydraulicArmModel, noise: MachineNoise,
                              offsets: dict, truck_target: float, with_truth: bool) -> tuple[pd.DataFrame, dict]:
    """Truck ``k`` of a shift (:func:`~.machine_motions.shift_motion`): its passes chained in
    one experiment, redrawn until within the relief pressure.

    The dataset schema keeps ``payload`` constant within an experiment, so the ``payload``
    column (and the metadata's ``payload``) is the truck's true load; the mass in the bucket
    over time is in the metadata's ``passes``: each pass's true fill (kg) and times (s),
    ``fill`` (the load enters, linearly, while the teeth cut against the soil's
    ``soil_resistance``, N) and ``release`` (it leaves, linearly).

    Parameters
    ----------
    k : int
        Experiment number; motion and noise come from the streams of ``(seed, k)``.
    seed : int
        Base seed of the run.
    arm : HydraulicArmModel
        The machine's model.
    noise : MachineNoise
        Sensor noise preset.
    offsets : dict
        The session's sensor offsets, SI units (:func:`session_offsets`).
    truck_target : float
        Load the truck aims at, kg.
    with_truth : bool
        Also add the noise-free ``true_*`` columns.

    Returns
    -------
    frame : pandas.DataFrame
        The experiment's rows.
    meta : dict
        Its description (payload in kg, poses in rad, peak pressure in Pa, draws, …).

    Raises
    ------
    ValueError
        If no truck within the relief pressure was found in ``MAX_ATTEMPTS`` draws.
    """
    motion_rng, noise_rng = machine_rngs(seed, k)
    plan, time, (q, qd, qdd), physics, peak, attempt = _within_relief(
        arm, lambda: mm.shift_motion(motion_rng, arm, truck_target), motion_rng, closing_rng(seed, k), "truck")
    frame = experiment_rows(k, time, q, qd, qdd, physics, plan.payload, noise, offsets, noise_rng,
                            with_truth)
    stretch = float(plan.info["time_stretch"])
    passes = [{"pass": p["pass"], "payload": float(p["payload"]),
               **{key: [stretch * v for v in p[key]] for key in ("fill", "release")},
               "start": stretch * p["start"], "end": stretch * p["end"],
               "soil_resistance": float(p["soil_resistance"])} for p in plan.info["passes"]]
    meta = {"experiment": int(k), "seed": int(seed), "payload": float(plan.payload), "motion": "shift",
            "truck": int(k), "truck_target": float(truck_target), "passes": passes,
            "tilt": [float(v) for v in plan.tilt], "duration": float(time[-1]),
            "peak_pressure": peak, "within_relief": True, "draws": attempt, "status": "ok",
            "time_stretch": stretch, "speed_share": float(plan.info["speed_share"])}
    return frame, meta


# -- the entries of the hydraulic platform's motion table (excavator_payload.platforms.hydraulic) --
def _generated(spec, k: int, draw_motion, any_peak: bool = False) -> tuple[pd.DataFrame, dict]:
    return simulate_motion_experiment(k, spec.seed, arm_model(spec.machine), spec.noise,
                                      session_offsets(spec.option("session", 0), spec.noise), spec.motion,
                                      spec.with_truth, spec.option("payload"), draw_motion=draw_motion,
                                      any_peak=any_peak)


def swing_experiment(spec, experiment: int) -> tuple[pd.DataFrame, dict]:
    """Swing ``experiment`` of the run ``spec`` (:func:`~.machine_motions.swing_motion`).

    Parameters
    ----------
    spec : RunSpec
        The run (hydraulic machine, noise, options ``session``, ``payload``).
    experiment : int
        Experiment number; its motion and noise come from the streams of ``(spec.seed, experiment)``.

    Returns
    -------
    frame : pandas.DataFrame
        The experiment's rows.
    meta : dict
        Its description (payload in kg, poses in rad, peak pressure in Pa, draws, …).
    """
    return _generated(spec, experiment, lambda k, rng, arm: mm.swing_motion(rng, arm))


def work_cycle_experiment(spec, experiment: int) -> tuple[pd.DataFrame, dict]:
    """Work cycle ``experiment`` of the run ``spec`` (:func:`~.machine_motions.work_cycle_motion`).

    Parameters
    ----------
    spec : RunSpec
        The run (hydraulic machine, noise, options ``session``, ``payload``).
    experiment : int
        Experiment number; its motion and noise come from the streams of ``(spec.seed, experiment)``.

    Returns
    -------
    frame : pandas.DataFrame
        The experiment's rows.
    meta : dict
        Its description (payload in kg, poses in rad, peak pressure in Pa, draws, …).
    """
    return _generated(spec, experiment, lambda k, rng, arm: mm.work_cycle_motion(rng, arm))


def slopes_experiment(spec, experiment: int) -> tuple[pd.DataFrame, dict]:
    """Work cycle ``experiment`` of the run ``spec`` on a drawn slope.

    Parameters
    ----------
    spec : RunSpec
        The run (hydraulic machine, noise, options ``session``, ``payload``).
    experiment : int
        Experiment number; its motion and noise come from the streams of ``(spec.seed, experiment)``.

    Returns
    -------
    frame : pandas.DataFrame
        The experiment's rows.
    meta : dict
        Its description (payload in kg, poses in rad, peak pressure in Pa, draws, …).
    """
    return _generated(spec, experiment,
                      lambda k, rng, arm: mm.work_cycle_motion(rng, arm, tilt=mm.slope_tilt(rng)))


def lifts_experiment(spec, experiment: int) -> tuple[pd.DataFrame, dict]:
    """Calibration lift ``experiment`` of the run ``spec`` (:func:`~.machine_motions.lift_motion`).

    Parameters
    ----------
    spec : RunSpec
        The run (hydraulic machine, noise, options ``session``, ``payload``).
    experiment : int
        Experiment number; its motion and noise come from the streams of ``(spec.seed, experiment)``.

    Returns
    -------
    frame : pandas.DataFrame
        The experiment's rows.
    meta : dict
        Its description (payload in kg, poses in rad, peak pressure in Pa, draws, …).
    """
    return _generated(spec, experiment, lambda k, rng, arm: mm.lift_motion(k, arm.machine), any_peak=True)


def operator_experiment(spec, experiment: int) -> tuple[pd.DataFrame, dict]:
    """Operator-like lift and slew ``experiment`` of the run ``spec``.

    Parameters
    ----------
    spec : RunSpec
        The run (hydraulic machine, noise, options ``session``, ``payload``).
    experiment : int
        Experiment number; its motion and noise come from the streams of ``(spec.seed, experiment)``.

    Returns
    -------
    frame : pandas.DataFrame
        The experiment's rows.
    meta : dict
        Its description (payload in kg, poses in rad, peak pressure in Pa, draws, …).
    """
    return _generated(spec, experiment, lambda k, rng, arm: mm.operator_motion(rng, arm))


def reach_experiment(spec, experiment: int) -> tuple[pd.DataFrame, dict]:
    """Calibration motion ``experiment`` of the run ``spec`` that takes every joint through its
    range at once (:func:`~.machine_motions.reach_motion`).

    Parameters
    ----------
    spec : RunSpec
        The run (hydraulic machine, noise, options ``session``, ``payload``).
    experiment : int
        Experiment number; its motion and noise come from the streams of ``(spec.seed, experiment)``.

    Returns
    -------
    frame : pandas.DataFrame
        The experiment's rows.
    meta : dict
        Its description (payload in kg, start pose in rad, peak pressure in Pa, draws, …).
    """
    return _generated(spec, experiment, lambda k, rng, arm: mm.reach_motion(rng, arm))


#: ``--motion calibration``: of every ten experiments these are `reach` motions, the rest swings
#: (three in ten: findings, "Every joint at once").
CALIBRATION_REACH = (2, 5, 8)


def calibration_experiment(spec, experiment: int) -> tuple[pd.DataFrame, dict]:
    """The recommended calibration mix, experiment ``experiment`` of the run ``spec``: a swing
    (:func:`swing_experiment`), or every ten experiments three `reach` motions
    (:func:`reach_experiment`, :data:`CALIBRATION_REACH`).

    Parameters
    ----------
    spec : RunSpec
        The run (hydraulic machine, noise, options ``session``, ``payload``).
    experiment : int
        Experiment number; its motion and noise come from the streams of ``(spec.seed, experiment)``.

    Returns
    -------
    frame : pandas.DataFrame
        The experiment's rows.
    meta : dict
        Its description, with ``calibration_motion`` (``swing`` or ``reach``).
    """
    reach = experiment % 10 in CALIBRATION_REACH
    frame, meta = (reach_experiment if reach else swing_experiment)(spec, experiment)
    return frame, {**meta, "calibration_motion": "reach" if reach else "swing"}


def nmpc_experiment(spec, experiment: int) -> tuple[pd.DataFrame, dict]:
    """NMPC swing ``experiment`` of the run ``spec`` (:func:`simulate_nmpc_experiment`).

    Parameters
    ----------
    spec : RunSpec
        The run (hydraulic machine, noise, options ``session``, ``payload``).
    experiment : int
        Experiment number; its motion and noise come from the streams of ``(spec.seed, experiment)``.

    Returns
    -------
    frame : pandas.DataFrame
        The experiment's rows.
    meta : dict
        Its description (payload in kg, poses in rad, peak pressure in Pa, draws, …).
    """
    return simulate_nmpc_experiment(experiment, spec.seed, arm_model(spec.machine), spec.noise,
                                    session_offsets(spec.option("session", 0), spec.noise), spec.with_truth,
                                    spec.option("payload"))


def shift_experiment(spec, experiment: int) -> tuple[pd.DataFrame, dict]:
    """Truck ``experiment`` of the run ``spec`` (:func:`simulate_shift_experiment`).

    Parameters
    ----------
    spec : RunSpec
        The run (hydraulic machine, noise, options ``session``, ``payload``, ``truck_target``).
    experiment : int
        Experiment number; its motion and noise come from the streams of ``(spec.seed, experiment)``.

    Returns
    -------
    frame : pandas.DataFrame
        The experiment's rows.
    meta : dict
        Its description (payload in kg, poses in rad, peak pressure in Pa, draws, …).
    """
    target = spec.option("truck_target")
    return simulate_shift_experiment(experiment, spec.seed, arm_model(spec.machine), spec.noise,
                                     session_offsets(spec.option("session", 0), spec.noise),
                                     default_truck_target(spec.machine) if target is None else target,
                                     spec.with_truth)


def machine_experiment(spec, experiment: int) -> tuple[pd.DataFrame, dict]:
    """Experiment ``experiment`` of the run ``spec``, by the hydraulic platform's motion table.

    Parameters
    ----------
    spec : RunSpec
        The run (hydraulic machine, noise, options ``session``, ``payload``, and the motion's own).
    experiment : int
        Experiment number; its motion and noise come from the streams of ``(spec.seed, experiment)``.

    Returns
    -------
    frame : pandas.DataFrame
        The experiment's rows.
    meta : dict
        Its description (payload in kg, poses in rad, peak pressure in Pa, draws, …).
    """
    module, _, name = HYDRAULIC.motion(spec.motion).experiment.partition(":")
    return getattr(importlib.import_module(module), name)(spec, experiment)


def dataset_meta(spec) -> dict:
    """File metadata a hydraulic run adds (:meth:`HydraulicPlatform.run_meta
    <excavator_payload.platforms.hydraulic.HydraulicPlatform.run_meta>`).

    Parameters
    ----------
    spec : RunSpec
        The hydraulic run.
    """
    return HYDRAULIC.run_meta(spec)


# -- whole datasets: the one simulation pipeline (simulation/generate.py) -----------------------
def simulate_machine_dataset(n_experiments: int, seed: int = 0, session: int = 0,
                             machine="cat345c-hydraulic", noise="field", motion: str | None = None,
                             with_truth: bool = False, workers: int | None = 1,
                             first_experiment: int = 0, trajectory=None,
                             progress: bool = False, payload: float | None = None,
                             truck_target: float | None = None, **execution) -> Dataset:
    """Simulate experiments of a hydraulic machine in memory.

    A convenience wrapper of :func:`excavator_payload.simulation.generate.simulate_dataset`
    (the same chunks, execution layer and reproducibility as every other simulation).

    Parameters
    ----------
    n_experiments : int
        Number of experiments (with a trajectory: at most that many of its experiments).
    seed, session : int
        Motions and noise from ``seed``; sensor offsets from ``session``.
    machine : HydraulicMachine or str
        A hydraulic machine, preset name or TOML file.
    noise : str
        ``field`` or ``none``.
    motion : str, optional
        ``swing`` (default), ``nmpc`` (NMPC swings with slewing, :mod:`.hydraulic_nmpc`),
        ``work-cycle``, ``slopes``, ``lifts`` or ``trajectory``.
    with_truth : bool
        Add the ``true_*`` columns.
    workers : int, optional
        Worker processes (None: all cores); the data do not depend on it.
    first_experiment : int
        Number of the first experiment.
    trajectory : str, Path or Trajectory, optional
        Prescribed motions for ``motion="trajectory"`` (see :mod:`.trajectory`).
    progress : bool
        Show a progress bar.
    payload : float, optional
        Every generated experiment carries this mass (kg) instead of a drawn one (0: an empty
        bucket, as ``zero`` needs); the motions are those drawn without it.
    truck_target : float, optional
        ``motion="shift"``: the load (kg) each truck aims at.
    """
    from excavator_payload.model.machine import load_machine
    from excavator_payload.simulation.generate import simulate_dataset

    machine = load_machine(machine)
    if not isinstance(machine, HydraulicMachine):
        raise MachineError(f"machine '{getattr(machine, 'name', machine)}' is not a hydraulic machine")
    return simulate_dataset(n_experiments, seed=seed, machine=machine, noise=noise,
                            with_truth=with_truth, workers=workers, motion=motion,
                            first_experiment=first_experiment, progress=progress, session=session,
                            trajectory=trajectory, payload=payload, truck_target=truck_target,
                            **execution)


def simulate_machine_to_file(out, n_experiments: int, seed: int = 0, session: int = 0,
                             machine="cat345c-hydraulic", noise="field", motion: str | None = None,
                             with_truth: bool = False, workers: int | None = None, trajectory=None,
                             progress: bool = True, **execution) -> Dataset:
    """Simulate and write a dataset (Parquet, atomic); an interrupted run resumes.

    A convenience wrapper of :func:`excavator_payload.simulation.generate.simulate_to_file`.

    Parameters
    ----------
    out : str or Path
        The dataset file to write; finished chunks wait in ``<out>.partial/``.
    n_experiments : int
        Number of experiments (with a trajectory: at most that many of its experiments).
    seed, session : int
        Motions and noise from ``seed``; sensor offsets from ``session``.
    machine : HydraulicMachine or str
        A hydraulic machine, preset name or TOML file.
    noise : str
        ``field`` or ``none``.
    motion : str, optional
        Motion family (default ``swing``), as for :func:`simulate_machine_dataset`.
    with_truth : bool
        Add the ``true_*`` columns.
    workers : int, optional
        Worker processes (None: all cores); the data do not depend on it.
    trajectory : str, Path or Trajectory, optional
        Prescribed motions for ``motion="trajectory"`` (see :mod:`.trajectory`).
    progress : bool
        Show a progress bar.
    **execution
        Passed on to :func:`~excavator_payload.simulation.generate.simulate_to_file`
        (e.g. ``scheduler``, ``execution``, ``payload``).

    Returns
    -------
    Dataset
        The written dataset.

    Raises
    ------
    MachineError
        If ``machine`` is not a hydraulic machine.
    """
    from excavator_payload.model.machine import load_machine
    from excavator_payload.simulation.generate import simulate_to_file

    machine = load_machine(machine)
    if not isinstance(machine, HydraulicMachine):
        raise MachineError(f"machine '{getattr(machine, 'name', machine)}' is not a hydraulic machine")
    return simulate_to_file(out, n_experiments, seed=seed, machine=machine, noise=noise,
                            with_truth=with_truth, workers=workers, motion=motion, progress=progress,
                            session=session, trajectory=trajectory, **execution)
