"""The physics of one hydraulic-machine motion: cylinder forces, seal friction, chamber
pressures and the sensors' rows (steps 1-5 of :mod:`excavator_payload.simulation.machine_sim`),
and the random streams of an experiment. Shared by the generated motions
(:mod:`.machine_sim`) and the replayed ones (:mod:`.trajectory`).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd

from excavator_payload.data.schema import MACHINE_SENSORS
from excavator_payload.model.hydraulic import HydraulicArmModel
from excavator_payload.model.hydraulic_machine import HydraulicMachine
from excavator_payload.simulation.machine_sensors import MachineNoise, measure

SAMPLE_RATE = MACHINE_SENSORS.sample_rate


def machine_rngs(seed: int, experiment: int) -> tuple[np.random.Generator, np.random.Generator]:
    """Independent (motion, noise) generators of experiment ``experiment`` of run ``seed``.

    Parameters
    ----------
    seed : int
        Base seed of the run.
    experiment : int
        Experiment number.

    Returns
    -------
    motion_rng, noise_rng : numpy.random.Generator
        Generator of the motion draws and generator of the sensor noise.
    """
    ss = np.random.SeedSequence([int(seed), int(experiment), 11])
    a, b = ss.spawn(2)
    return np.random.default_rng(a), np.random.default_rng(b)


def closing_rng(seed: int, experiment: int) -> np.random.Generator:
    """A third independent stream of the experiment: how its valves close (:func:`rest_friction`).
    Its own stream, so that the motions and the noise drawn stay those of the same seed before
    friction at rest was drawn (SeedSequence children do not depend on how many are spawned).

    Parameters
    ----------
    seed : int
        Base seed of the run.
    experiment : int
        Experiment number.

    Returns
    -------
    numpy.random.Generator
        The experiment's valve-closing stream.
    """
    return np.random.default_rng(np.random.SeedSequence([int(seed), int(experiment), 11]).spawn(3)[2])


_ARMS: dict[str, HydraulicArmModel] = {}


def arm_model(machine: HydraulicMachine) -> HydraulicArmModel:
    """The process's :class:`HydraulicArmModel` of ``machine`` (built once per process).

    Parameters
    ----------
    machine : HydraulicMachine
        The simulated machine (its dictionary is the cache key).

    Returns
    -------
    HydraulicArmModel
        The cached model.
    """
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

    Parameters
    ----------
    lengths : numpy.ndarray
        Length of each cylinder at each sample, m, shape (n, 3).
    presliding : numpy.ndarray
        Presliding displacement ``x_p`` of each cylinder, m, shape (3,).
    initial : numpy.ndarray
        State ``s`` of each cylinder at the first sample, in [-1, 1], shape (3,).
    forced : numpy.ndarray, optional
        State imposed at some samples (NaN elsewhere), shape (n, 3).

    Returns
    -------
    numpy.ndarray
        State ``s`` of each cylinder at each sample, shape (n, 3).
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

    Parameters
    ----------
    speed : numpy.ndarray
        Rod speed of each cylinder, m/s, shape (n, 3).
    breakaway : numpy.ndarray
        Breakaway friction :math:`F_b` of each cylinder at each sample, N, shape (n, 3).
    rest_speed : numpy.ndarray
        Speed below which each rod stands still, m/s, shape (3,).
    friction : numpy.ndarray
        Friction of the moving samples, N, shape (n, 3); copied, not changed.
    closing : numpy.ndarray
        Draws :math:`u` in [−1, 1] of how the valves closed, shape (k, 3); the k-th standstill
        of a cylinder uses row ``k mod len(closing)``.

    Returns
    -------
    numpy.ndarray
        ``friction`` with the standstills' held friction, N, shape (n, 3).
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
                   friction_initial: np.ndarray, rng: np.random.Generator | None = None,
                   tip_force: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """True signals of a motion: torques, cylinder forces, friction, pressures, house inclination.

    ``rng`` draws how each valve closed where a rod stops (:func:`rest_friction`); without it the
    draws come from ``friction_initial`` (reproducible, for callers without a generator).

    Parameters
    ----------
    arm : HydraulicArmModel
        The machine's model.
    time : numpy.ndarray
        Sample times, s, shape (n,).
    q, qd, qdd : numpy.ndarray
        Angles (rad), rates (rad/s) and accelerations (rad/s²) of boom, dipper, bucket
        (relative) and slew, shape (n, 4).
    tilt : numpy.ndarray
        Ground tilt (pitch, roll), rad, shape (2,) or (n, 2).
    payload : numpy.ndarray
        Payload mass, kg, per sample (or a scalar).
    friction_initial : numpy.ndarray
        Presliding state of each cylinder at the start, in [-1, 1], shape (3,).
    rng : numpy.random.Generator, optional
        Stream of the valve-closing draws.
    tip_force : numpy.ndarray, optional
        A force on the teeth (the soil's on a dig), N, in the arm plane [x, z], shape (n, 2):
        the cylinders hold its torques too.

    Returns
    -------
    dict of str to numpy.ndarray
        ``tau`` (N·m, (n, 4)), cylinder ``load``, ``friction`` (N), ``head`` and ``rod``
        pressures (Pa), ``lengths`` (m), ``speeds`` (m/s), all (n, 3), and house
        ``inclination`` (rad, (n, 2)), and ``bucket_load`` (kg, (n,): the payload mass in the
        bucket at each sample, as the physics took it).
    """
    tilt = np.broadcast_to(np.asarray(tilt, float), (len(time), 2))
    sig = arm.motion_signals(q, qd, qdd, tilt, payload)
    if tip_force is not None and np.any(tip_force):
        # M q̈ + c + g = τ + Jᵀf: the cylinders give τ = τ_free − Jᵀf
        soil = arm.tip_torque(q, tip_force)
        sig["tau"] = sig["tau"].copy()
        sig["tau"][:, :3] -= soil
        sig["load"] = sig["load"] - arm.load_force(q, soil)
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
            "lengths": sig["length"], "speeds": sig["speed"], "inclination": sig["inclination"],
            "bucket_load": np.broadcast_to(np.asarray(payload, float), (len(time),)).copy()}


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
    """Rows of one experiment in the machine sensor set's columns (+ truth columns).

    Parameters
    ----------
    experiment : int
        Experiment number written into the ``experiment`` column.
    time : numpy.ndarray
        Sample times, s, shape (n,).
    q, qd, qdd : numpy.ndarray
        True angles (rad), rates (rad/s) and accelerations (rad/s²) of boom, dipper, bucket
        (relative) and slew, shape (n, 4).
    physics : dict
        The motion's true signals, as :func:`motion_physics` returns them.
    payload : float
        Payload mass, kg, written into the ``payload`` column.
    noise : MachineNoise
        Sensor noise preset.
    offsets : dict
        The session's sensor offsets, SI units (:func:`session_offsets`).
    rng : numpy.random.Generator
        The experiment's noise stream.
    with_truth : bool
        Also add the noise-free ``true_*`` columns.

    Returns
    -------
    pandas.DataFrame
        The rows, in the machine sensor set's column order.
    """
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
        # what is in the bucket at each sample (``payload`` is one figure per experiment: a work
        # cycle's load after its dump, a shift's truck total)
        data["true_bucket_load"] = physics["bucket_load"]
    frame = pd.DataFrame(data)
    return frame[list(MACHINE_SENSORS.columns) + (list(MACHINE_SENSORS.truth_columns) if with_truth else [])]


def sample_times(duration: float) -> np.ndarray:
    """Sample times (s) from 0 to ``duration`` s inclusive at the machine sensor set's
    :data:`SAMPLE_RATE` (Hz).

    Parameters
    ----------
    duration : float
        Duration of the experiment, s.
    """
    n = int(math.floor(duration * SAMPLE_RATE + 1e-9)) + 1
    return np.arange(n) / SAMPLE_RATE
