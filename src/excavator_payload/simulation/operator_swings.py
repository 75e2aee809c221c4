"""Operator-like swings of the thesis' arm: a pause mid-way, an overshoot corrected back, and
small corrections at the end, with computed torques.

A third motion generator for the thesis setting, for estimators trained on other families to be
judged on motions they have not seen. From the start pose of the thesis' scenario
(:func:`~excavator_payload.simulation.scenario.sample_scenario`) the arm

1. moves part of the way (each joint its own share of its travel) and pauses;
2. moves on past the target (each joint overshoots by a drawn angle) and is corrected back
   to the target;
3. makes one to three small corrections around the target, each followed by a short rest
   (some of them inside the last second, where estimates are judged).

Every move is a rest-to-rest minimum-jerk segment
(:func:`~excavator_payload.simulation.minimum_jerk.minimum_jerk`) whose duration grows with its
longest joint travel, at a drawn operator tempo; after the last one the arm rests. A plan whose
torques would exceed :data:`TORQUE_SHARE` of a joint's limit is slowed down, and end
corrections that no longer fit into the 5 s record are dropped. The torques are the exact inverse
dynamics (``ArmModel.inverse_dynamics``) of the motion, and the sensors add noise through
:func:`~excavator_payload.simulation.experiment.experiment_frame`, as for the other families.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.schema import DURATION, SAMPLES_PER_EXPERIMENT
from excavator_payload.model.machine import Machine, load_machine
from excavator_payload.simulation.experiment import RunSpec, experiment_frame, noise_rng, run_in_process
from excavator_payload.simulation.minimum_jerk import _arm, minimum_jerk
from excavator_payload.simulation.scenario import experiment_rngs, sample_scenario
from excavator_payload.simulation.sensors import NoisePreset, get_noise_preset

DEG = math.pi / 180.0
#: The operator runs draw from the streams of ``seed + SEED_OFFSET``: they differ from the other
#: families' runs of the same seed (the scenario itself is the thesis' draw of ``seed``).
SEED_OFFSET = 15_401
#: Share of each joint's travel done before the pause (drawn per joint: the joints need not
#: keep in step).
FIRST_SHARE = (0.3, 0.75)
#: Pause mid-way, s.
PAUSE = (0.2, 0.6)
#: Overshoot beyond the target, rad (drawn per joint, in the direction of travel).
OVERSHOOT = (2 * DEG, 8 * DEG)
#: Size of each small end correction, rad (drawn per joint, either sign).
CORRECTION = (0.3 * DEG, 2.0 * DEG)
#: Rest after each end correction, s.
CORRECTION_REST = (0.05, 0.3)
#: A segment lasts ``BASE_TIME + travel / SPEED`` (travel: its largest joint move, rad), scaled
#: by a drawn operator tempo ``TEMPO``.
BASE_TIME, SPEED, TEMPO = 0.35, 0.9, (0.85, 1.2)
#: Share of each joint's torque limit the motion may ask for; a plan that asks more is slowed
#: down by SLOW_STEP at a time (at most MAX_SLOW in all).
TORQUE_SHARE, SLOW_STEP, MAX_SLOW = 0.9, 1.1, 2.5
#: Margin kept from the ends of each joint's angle range, rad.
RANGE_MARGIN = 1 * DEG


def operator_plan(start: np.ndarray, target: np.ndarray, rng: np.random.Generator,
                  angle_ranges: tuple[tuple[float, float], tuple[float, float]]
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Waypoints, rests and natural durations of the minimum-jerk segments of one operator swing.

    Parameters
    ----------
    start, target : numpy.ndarray
        Start and target (boom, dipper) angles, rad, shape (2,).
    rng : numpy.random.Generator
        Source of the operator's choices (shares, pauses, overshoots, corrections, tempo).
    angle_ranges : tuple of two (low, high) pairs
        Each joint's angle range, rad; the waypoints keep :data:`RANGE_MARGIN` from its ends.

    Returns
    -------
    points : numpy.ndarray
        Waypoints, rad, shape (n_segments + 1, 2): start, the pause, the overshoot, the target
        and one to three end corrections.
    rests : numpy.ndarray
        Rest before each segment, s, shape (n_segments,): none before the first move and the
        correction back, the pause before the move on, a short rest before each end correction.
    lengths : numpy.ndarray
        Duration of each segment at the operator's tempo, s, shape (n_segments,).
    """
    start, target = np.asarray(start, float), np.asarray(target, float)
    lo = np.array([r[0] for r in angle_ranges]) + RANGE_MARGIN
    hi = np.array([r[1] for r in angle_ranges]) - RANGE_MARGIN
    travel = target - start
    direction = np.where(travel >= 0, 1.0, -1.0)
    mid = start + rng.uniform(*FIRST_SHARE, size=2) * travel
    over = np.clip(target + direction * rng.uniform(*OVERSHOOT, size=2), lo, hi)
    n_corrections = int(rng.integers(1, 4))
    corrections = [np.clip(target + rng.choice([-1.0, 1.0], size=2) * rng.uniform(*CORRECTION, size=2),
                           lo, hi) for _ in range(n_corrections)]
    points = np.vstack([start, mid, over, target, *corrections])
    rests = np.concatenate([[0.0, rng.uniform(*PAUSE), 0.0],
                            rng.uniform(*CORRECTION_REST, size=n_corrections)])
    tempo = rng.uniform(*TEMPO)
    lengths = tempo * (BASE_TIME + np.abs(np.diff(points, axis=0)).max(axis=1) / SPEED)
    return points, rests, lengths


def schedule(points: np.ndarray, rests: np.ndarray, lengths: np.ndarray,
             duration: float = DURATION) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Start times of a plan's segments; end corrections that do not fit into ``duration`` are dropped.

    The first end correction is always kept: a slow operator's swing may then still move when
    the record ends.

    Parameters
    ----------
    points : numpy.ndarray
        Waypoints, rad, shape (n_segments + 1, 2), as :func:`operator_plan` gives them.
    rests, lengths : numpy.ndarray
        Rest before and duration of each segment, s, shape (n_segments,).
    duration : float
        Length of the record, s.

    Returns
    -------
    points : numpy.ndarray
        The waypoints kept, rad.
    starts, lengths : numpy.ndarray
        Start time and duration of each kept segment, s.
    """
    n = len(lengths)
    while n > 4 and rests[:n].sum() + lengths[:n].sum() > duration:
        n -= 1
    rests, lengths = rests[:n], lengths[:n]
    starts = np.cumsum(rests + np.concatenate([[0.0], lengths[:-1]]))
    return points[:n + 1], starts, lengths


def operator_motion(points: np.ndarray, starts: np.ndarray, lengths: np.ndarray,
                    t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Angles, rates and accelerations of the minimum-jerk segments between ``points``.

    Parameters
    ----------
    points : numpy.ndarray
        Waypoints, rad, shape (n_segments + 1, 2).
    starts, lengths : numpy.ndarray
        Start time and duration of each segment, s, shape (n_segments,); segments must not
        overlap (the arm rests between them).
    t : numpy.ndarray
        Sample times, s, shape (n_samples,).

    Returns
    -------
    q, qd, qdd : numpy.ndarray
        Angles (rad), rates (rad/s) and accelerations (rad/s²), shape (n_samples, 2).
    """
    q = np.tile(points[0], (len(t), 1)).astype(float)
    qd = np.zeros_like(q)
    qdd = np.zeros_like(q)
    for k, (t0, length) in enumerate(zip(starts, lengths)):
        # Each segment adds its own displacement once it has started (rest to rest: no overlap).
        after = t >= t0
        pos, vel, acc = minimum_jerk(np.zeros(2), points[k + 1] - points[k], t[after] - t0, length)
        q[after] += pos
        qd[after] += vel
        qdd[after] += acc
    return q, qd, qdd


def operator_experiment(spec: RunSpec, experiment: int) -> tuple[pd.DataFrame, dict]:
    """Rows and metadata of operator swing ``experiment`` of the run ``spec``.

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
        Its scenario, the waypoints (rad), the segments' start times and durations (s), the
        factor the operator's tempo was slowed down by to keep the torques within
        :data:`TORQUE_SHARE` of their limits, and ``status``.
    """
    machine = spec.machine
    t = np.linspace(0.0, DURATION, SAMPLES_PER_EXPERIMENT)
    sc = sample_scenario(spec.seed, experiment, machine.max_payload)
    rng_sc, rng_noise = experiment_rngs(spec.seed + SEED_OFFSET, experiment)  # own stream
    plan = operator_plan(np.array(sc.start_pose), np.array(sc.target_pose), rng_sc,
                         (machine.boom_angle_range, machine.dipper_angle_range))
    limit = TORQUE_SHARE * np.array([machine.boom_torque_limit, machine.dipper_torque_limit])
    slow = 1.0
    while True:  # the operator slows down until the cylinders can follow
        points, starts, lengths = schedule(plan[0], plan[1], slow * plan[2])
        q, qd, qdd = operator_motion(points, starts, lengths, t)
        tau = _arm(machine).inverse_dynamics(q, qd, qdd, sc.payload)
        if np.all(np.abs(tau).max(axis=0) <= limit) or slow * SLOW_STEP > MAX_SLOW:
            break
        slow *= SLOW_STEP
    frame = experiment_frame(experiment, t, q, qd, qdd, tau, sc.payload, spec.noise,
                             noise_rng(spec, rng_noise), spec.with_truth)
    return frame, {**sc.to_dict(), "waypoints": points.tolist(), "segment_starts": starts.tolist(),
                   "segment_lengths": lengths.tolist(), "slow_down": slow, "status": "ok"}


def simulate_operator_swings(n_experiments: int, seed: int = 0, machine: Machine | str = "cat345c",
                             noise: str | NoisePreset = "thesis", with_truth: bool = False,
                             first_experiment: int = 0) -> Dataset:
    """Dataset of operator-like swings between the thesis' random start and target poses.

    Parameters
    ----------
    n_experiments : int
        Number of experiments.
    seed : int
        Base seed (same seed, same data).
    machine : Machine or str
        Machine, or a preset name or TOML file for :func:`load_machine`.
    noise : str or NoisePreset
        Sensor noise preset or its name.
    with_truth : bool
        Also store the noise-free ``true_*`` columns.
    first_experiment : int
        Number of the first experiment (experiments ``first_experiment`` …
        ``first_experiment + n_experiments - 1`` are simulated).

    Returns
    -------
    Dataset
        The rows of all experiments and their metadata.
    """
    machine = load_machine(machine)
    preset = get_noise_preset(noise)
    spec = RunSpec("operator", int(seed), machine, preset, bool(with_truth), first_experiment + n_experiments)
    return run_in_process(spec, operator_experiment, first_experiment, n_experiments)
