"""Simulator of the hydraulic machine: motions through the model and the machine's sensors.

Every experiment is a motion (an NMPC swing, :mod:`.hydraulic_nmpc`; planned in
:mod:`.machine_motions` within the hydraulics' limits; or replayed from a trajectory file,
:mod:`.trajectory`) pushed through the symbolic model of
:mod:`excavator_payload.model.hydraulic`:

1. inverse dynamics gives the joint torques (and the slew torque) of the motion, with the
   house slewing on tilted ground and the payload in the bucket;
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
import json
import logging
import math
from pathlib import Path

import numpy as np
import pandas as pd

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.schema import MACHINE_SENSORS
from excavator_payload.errors import DatasetError, ExcavatorPayloadError, MachineError
from excavator_payload.model.hydraulic import HydraulicArmModel
from excavator_payload.model.hydraulic_machine import HydraulicMachine
from excavator_payload.simulation import machine_motions as mm
from excavator_payload.simulation.machine_sensors import (
    MachineNoise,
    get_machine_noise,
    measure,
    session_offsets,
)

log = logging.getLogger(__name__)

SAMPLE_RATE = MACHINE_SENSORS.sample_rate
MOTIONS = ("nmpc", *mm.MACHINE_MOTIONS, "trajectory")
#: Length of an NMPC swing, s.
NMPC_DURATION = 10.0
#: Largest share of the pumps' speed an NMPC swing may use (between its nodes).
NMPC_SPEED_TOLERANCE = 1.05
MAX_ATTEMPTS = 30


def machine_rngs(seed: int, experiment: int) -> tuple[np.random.Generator, np.random.Generator]:
    """Independent (motion, noise) generators of experiment ``experiment`` of run ``seed``."""
    ss = np.random.SeedSequence([int(seed), int(experiment), 11])
    a, b = ss.spawn(2)
    return np.random.default_rng(a), np.random.default_rng(b)


def closing_rng(seed: int, experiment: int) -> np.random.Generator:
    """A third independent stream of the experiment: how its valves close (:func:`rest_friction`).
    Its own stream, so that the motions and the noise drawn stay those of the same seed before
    friction at rest was drawn (SeedSequence children do not depend on how many are spawned)."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), int(experiment), 11]).spawn(3)[2])


_ARMS: dict[str, HydraulicArmModel] = {}


def _arm(machine: HydraulicMachine) -> HydraulicArmModel:
    key = json.dumps(machine.to_dict(), sort_keys=True)
    if key not in _ARMS:
        _ARMS[key] = HydraulicArmModel(machine)
    return _ARMS[key]


# -- physics of one motion ------------------------------------------------------------------
def friction_states(lengths: np.ndarray, presliding: np.ndarray, initial: np.ndarray,
                    forced: np.ndarray | None = None) -> np.ndarray:
    """Presliding (Dahl) state s ∈ [-1, 1] of each cylinder along its length history.

    ds/dx = (1 − s·sign(dx)) / x_p, integrated exactly between samples: s follows the sign of
    the motion over the presliding displacement x_p and keeps its value while the cylinder
    stands still. ``forced`` (n, 3, NaN elsewhere) sets s where a standstill holds the friction
    its valve left (:func:`rest_friction`), so that the motion after it starts from there.
    """
    dx = np.diff(lengths, axis=0)
    decay = np.exp(-np.abs(dx) / presliding)
    direction = np.sign(dx)
    out = np.empty_like(lengths)
    s = np.asarray(initial, dtype=float).copy()
    if forced is not None:
        s = np.where(np.isnan(forced[0]), s, forced[0])
    out[0] = s
    for i in range(len(dx)):
        s = direction[i] + (s - direction[i]) * decay[i]
        if forced is not None:
            s = np.where(np.isnan(forced[i + 1]), s, forced[i + 1])
        out[i + 1] = s
    return out


#: A rod slower than this share of its Stribeck velocity stands still (its valve is closed).
REST_SPEED_SHARE = 0.1
#: ... for at least this many samples (0.1 s): a reversal passes zero speed in a sample or two
#: and its friction turns over through the presliding state, no valve closing in between.
REST_MIN_SAMPLES = 10


def rest_friction(speed: np.ndarray, breakaway: np.ndarray, rest_speed: np.ndarray,
                  friction: np.ndarray, closing: np.ndarray) -> np.ndarray:
    r"""Seal friction (N) where a rod stands still: held at what it was when the valve closed.

    For each cylinder ``j`` and each standstill (``|speed| <`` ``rest_speed``) starting at
    sample ``a`` and lasting ``REST_MIN_SAMPLES`` or more, the friction is :math:`F_f = u\,F_b(a)` with :math:`u` the standstill's
    ``closing`` draw in [−1, 1] (how the valve closed), kept while the rod stands: the oil's
    stiffness (βA²/V ≈ 3·10⁷ N/m on a boom cylinder) is several times the seal's presliding
    stiffness (F_C/x_p ≈ 5·10⁶ N/m), so a change of the load goes to the pressures. Where the
    breakaway :math:`F_b(t)` shrinks below it the seal gives at the band's edge. Moving samples
    keep ``friction``. ``breakaway`` (n, 3), N; ``closing`` (k, 3), used in order per cylinder.
    """
    out = friction.copy()
    for j in range(speed.shape[1]):
        still = np.abs(speed[:, j]) < rest_speed[j]
        edges = np.flatnonzero(np.diff(np.r_[0, still.astype(np.int8), 0]))
        runs = [(a, b) for a, b in zip(edges[::2], edges[1::2]) if b - a >= REST_MIN_SAMPLES]
        for k, (a, b) in enumerate(runs):
            held = closing[k % len(closing), j] * breakaway[a, j]
            out[a:b, j] = np.clip(held, -breakaway[a:b, j], breakaway[a:b, j])
    return out


def motion_physics(arm: HydraulicArmModel, time: np.ndarray, q: np.ndarray, qd: np.ndarray,
                   qdd: np.ndarray, tilt: np.ndarray, payload: np.ndarray,
                   friction_initial: np.ndarray, rng: np.random.Generator | None = None) -> dict[str, np.ndarray]:
    """True signals of a motion: torques, cylinder forces, friction, pressures, house inclination.

    ``rng`` draws how each valve closed where a rod stops (:func:`rest_friction`); without it the
    draws come from ``friction_initial`` (reproducible, for callers without a generator).
    """
    tilt = np.broadcast_to(np.asarray(tilt, float), (len(time), 2))
    sig = arm.motion_signals(q, qd, qdd, tilt, payload)
    cylinders = arm.machine.cylinders
    presliding = np.array([c.presliding for c in cylinders])
    # breakaway of the load force (Stribeck peak at rest), per sample and cylinder
    coulomb = np.array([c.coulomb for c in cylinders])
    load_coefficient = np.array([c.load_coefficient for c in cylinders])
    static_ratio = np.array([c.static_ratio for c in cylinders])
    band = (coulomb + load_coefficient * np.abs(sig["load"])) * static_ratio
    rest_speed = REST_SPEED_SHARE * np.array([c.stribeck_velocity for c in cylinders])
    if rng is None:
        rng = np.random.default_rng(np.frombuffer(np.asarray(friction_initial, float).tobytes(), np.uint32))
    closing = rng.uniform(-1.0, 1.0, (64, 3))
    closing[0] = friction_initial  # a motion that starts at rest: the state it was drawn with
    held = rest_friction(sig["speed"], band, rest_speed, np.full_like(band, np.nan), closing)
    # the presliding state through a standstill is the held friction's share of the band, so
    # the motion after it turns the friction over from there (not from the last sliding one:
    # that left a one-sample pressure dip where a rod started again)
    share = np.divide(held, band, out=np.full_like(band, np.nan), where=band > 0)
    states = friction_states(sig["length"], presliding, friction_initial, share)
    friction, _, _ = arm.cylinder_pressures(sig["speed"], states, sig["load"])
    friction = np.where(np.isnan(held), friction, held)
    head, rod = arm.pressures(sig["load"] + friction)
    return {"tau": sig["tau"], "load": sig["load"], "friction": friction, "head": head, "rod": rod,
            "lengths": sig["length"], "speeds": sig["speed"], "inclination": sig["inclination"]}


def _truth_columns(q, qd, qdd, physics) -> dict[str, np.ndarray]:
    truth = {"boom_angle": q[:, 0], "dipper_angle": q[:, 1], "bucket_angle": q[:, 2],
             "boom_rate": qd[:, 0], "dipper_rate": qd[:, 1], "bucket_rate": qd[:, 2],
             "slew_rate": qd[:, 3], "house_pitch": physics["inclination"][:, 0],
             "house_roll": physics["inclination"][:, 1]}
    for j, name in enumerate(("boom", "dipper", "bucket")):
        truth[f"{name}_head_pressure"] = physics["head"][:, j]
        truth[f"{name}_rod_pressure"] = physics["rod"][:, j]
    return truth


def experiment_rows(experiment: int, time: np.ndarray, q, qd, qdd, physics, payload: float,
                    noise: MachineNoise, offsets: dict, rng: np.random.Generator,
                    with_truth: bool) -> pd.DataFrame:
    """Rows of one experiment in the machine sensor set's columns (+ truth columns)."""
    truth = _truth_columns(q, qd, qdd, physics)
    measured = measure(truth, time, qdd, noise, offsets, rng)
    data = {"experiment": np.full(len(time), int(experiment), dtype=np.int64), "time": time}
    for name in MACHINE_SENSORS.signals:
        data[name] = measured[name]
    data["payload"] = np.full(len(time), float(payload))
    if with_truth:
        for name in MACHINE_SENSORS.signals:
            data[f"true_{name}"] = truth[name]
        for j, name in enumerate(("boom", "dipper", "bucket")):
            data[f"true_{name}_torque"] = physics["tau"][:, j]
        for j, name in enumerate(("boom", "dipper", "bucket", "slew")):
            data[f"true_{name}_accel"] = qdd[:, j]
        data["true_slew_angle"] = q[:, 3]
    frame = pd.DataFrame(data)
    return frame[list(MACHINE_SENSORS.columns) + (list(MACHINE_SENSORS.truth_columns) if with_truth else [])]


def sample_times(duration: float) -> np.ndarray:
    """Sample times (s) from 0 to ``duration`` s inclusive at the machine sensor set's
    :data:`SAMPLE_RATE` (Hz)."""
    n = int(math.floor(duration * SAMPLE_RATE + 1e-9)) + 1
    return np.arange(n) / SAMPLE_RATE


def _draw_motion(motion: str, k: int, rng, arm: HydraulicArmModel) -> mm.Motion:
    if motion == "swing":
        return mm.swing_motion(rng, arm)
    if motion == "work-cycle":
        return mm.work_cycle_motion(rng, arm)
    if motion == "slopes":
        return mm.work_cycle_motion(rng, arm, tilt=mm.slope_tilt(rng))
    if motion == "lifts":
        return mm.lift_motion(k, arm.machine)
    if motion == "operator":
        return mm.operator_motion(rng, arm)
    raise ExcavatorPayloadError(f"unknown motion '{motion}' for a hydraulic machine: choose one of "
                                f"{', '.join(MOTIONS)}")


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
    ``payload_override`` (kg): this mass instead of the drawn one (``simulate --payload``)."""
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
        physics = motion_physics(arm, time, q, qd, qdd, plan.tilt, plan.payload_at(time), friction0, valves)
        peak = float(max(physics["head"].max(), physics["rod"].max()))
        if peak <= relief or any_peak:
            return plan, time, (q, qd, qdd), physics, peak, attempt
    raise ValueError(f"no {what} within the relief pressure in {MAX_ATTEMPTS} draws")


def simulate_motion_experiment(k: int, seed: int, arm: HydraulicArmModel, noise: MachineNoise,
                               offsets: dict, motion: str, with_truth: bool,
                               payload_override: float | None = None) -> tuple[pd.DataFrame, dict]:
    """Rows and metadata of generated experiment ``k`` (redrawn until within the relief pressure).
    ``payload_override`` (kg): this mass instead of the drawn one (``simulate --payload``)."""
    machine = arm.machine
    motion_rng, noise_rng = machine_rngs(seed, k)
    relief = machine.hydraulics.relief_pressure

    def draw():
        drawn = _draw_motion(motion, k, motion_rng, arm)
        if payload_override is not None:  # before the fit: the mass shapes the pressures it checks
            drawn = dataclasses.replace(drawn, payload=float(payload_override))
        return drawn

    plan, time, (q, qd, qdd), physics, peak, attempt = _within_relief(
        arm, draw, motion_rng, closing_rng(seed, k), "motion", any_peak=motion == "lifts")
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
    """Truck target (kg) of ``--motion shift`` without ``--truck-target``: 4 passes at 90 % of rated."""
    return 4 * 0.9 * float(machine.rated_payload)


def simulate_shift_experiment(k: int, seed: int, arm: HydraulicArmModel, noise: MachineNoise,
                              offsets: dict, truck_target: float, with_truth: bool) -> tuple[pd.DataFrame, dict]:
    """Truck ``k`` of a shift (:func:`~.machine_motions.shift_motion`): its passes chained in
    one experiment, redrawn until within the relief pressure.

    The dataset schema keeps ``payload`` constant within an experiment, so the ``payload``
    column (and the metadata's ``payload``) is the truck's true load; the mass in the bucket
    over time is in the metadata's ``passes``: each pass's true fill (kg) and times (s),
    ``fill`` (the load enters, linearly) and ``release`` (it leaves, linearly).
    """
    motion_rng, noise_rng = machine_rngs(seed, k)
    plan, time, (q, qd, qdd), physics, peak, attempt = _within_relief(
        arm, lambda: mm.shift_motion(motion_rng, arm, truck_target), motion_rng, closing_rng(seed, k), "truck")
    frame = experiment_rows(k, time, q, qd, qdd, physics, plan.payload, noise, offsets, noise_rng,
                            with_truth)
    stretch = float(plan.info["time_stretch"])
    passes = [{"pass": p["pass"], "payload": float(p["payload"]),
               **{key: [stretch * v for v in p[key]] for key in ("fill", "release")},
               "start": stretch * p["start"], "end": stretch * p["end"]} for p in plan.info["passes"]]
    meta = {"experiment": int(k), "seed": int(seed), "payload": float(plan.payload), "motion": "shift",
            "truck": int(k), "truck_target": float(truck_target), "passes": passes,
            "tilt": [float(v) for v in plan.tilt], "duration": float(time[-1]),
            "peak_pressure": peak, "within_relief": True, "draws": attempt, "status": "ok",
            "time_stretch": stretch, "speed_share": float(plan.info["speed_share"])}
    return frame, meta


def machine_experiment(spec, experiment: int) -> tuple[pd.DataFrame, dict]:
    """Experiment ``experiment`` of the run ``spec`` (the entry of
    :data:`excavator_payload.simulation.generate.MACHINE_MOTIONS`): a generated motion, or the
    trajectory file's experiment at that position."""
    arm = _arm(spec.machine)
    offsets = session_offsets(spec.option("session", 0), spec.noise)
    if spec.motion == "trajectory":
        from excavator_payload.simulation.trajectory import simulate_trajectory_experiment

        return simulate_trajectory_experiment(experiment, spec.seed, arm, spec.noise, offsets,
                                              spec.option("trajectory"), spec.with_truth)
    if spec.motion == "shift":
        target = spec.option("truck_target")
        return simulate_shift_experiment(experiment, spec.seed, arm, spec.noise, offsets,
                                         default_truck_target(spec.machine) if target is None else target,
                                         spec.with_truth)
    payload = spec.option("payload")
    if spec.motion == "nmpc":
        return simulate_nmpc_experiment(experiment, spec.seed, arm, spec.noise, offsets, spec.with_truth,
                                        payload)
    return simulate_motion_experiment(experiment, spec.seed, arm, spec.noise, offsets, spec.motion,
                                      spec.with_truth, payload)


def dataset_meta(spec) -> dict:
    """File metadata a hydraulic run adds (session, its true offsets, the trajectory's source)."""
    session = int(spec.option("session", 0))
    meta = {"session": session,
            # The true offsets of this session: for checking offset estimation, not for estimators.
            "true_sensor_offsets": session_offsets(session, spec.noise)}
    trajectory = spec.option("trajectory")
    if trajectory is not None:
        meta["trajectory"] = trajectory.source
    return meta


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

    A convenience wrapper of :func:`excavator_payload.simulation.generate.simulate_to_file`;
    parameters as :func:`simulate_machine_dataset`.
    """
    from excavator_payload.model.machine import load_machine
    from excavator_payload.simulation.generate import simulate_to_file

    machine = load_machine(machine)
    if not isinstance(machine, HydraulicMachine):
        raise MachineError(f"machine '{getattr(machine, 'name', machine)}' is not a hydraulic machine")
    return simulate_to_file(out, n_experiments, seed=seed, machine=machine, noise=noise,
                            with_truth=with_truth, workers=workers, motion=motion, progress=progress,
                            session=session, trajectory=trajectory, **execution)
