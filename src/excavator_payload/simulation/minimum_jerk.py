"""A second motion generator: minimum-jerk moves with computed torques.

Estimators trained on the NMPC's motions are tested on these to see how they generalise to
motions they have not seen. Joint angles follow the minimum-jerk profile
q(s) = q₀ + (q_T − q₀)(10s³ − 15s⁴ + 6s⁵), s = t/T_move, followed by rest at the target; the
torques are the exact inverse dynamics (``ArmModel.inverse_dynamics``) of that motion.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.schema import DURATION, SAMPLES_PER_EXPERIMENT
from excavator_payload.model.dynamics import ArmModel
from excavator_payload.model.machine import Machine, load_machine
from excavator_payload.simulation.experiment import RunSpec, experiment_frame, noise_rng, run_in_process
from excavator_payload.simulation.scenario import experiment_rngs, sample_scenario
from excavator_payload.simulation.sensors import NoisePreset, get_noise_preset


def minimum_jerk(q0: np.ndarray, q1: np.ndarray, t: np.ndarray, move_time: float):
    """Angle, rate and acceleration of a minimum-jerk move from q0 to q1 (rest to rest).

    Parameters
    ----------
    q0, q1 : numpy.ndarray
        Start and end joint angles, rad, shape (n_joints,).
    t : numpy.ndarray
        Sample times, s, shape (n_samples,); after ``move_time`` the joints rest at ``q1``.
    move_time : float
        Duration of the move, s.

    Returns
    -------
    pos, vel, acc : numpy.ndarray
        Angles (rad), rates (rad/s) and accelerations (rad/s²), shape (n_samples, n_joints).
    """
    s = np.clip(t / move_time, 0.0, 1.0)[:, None]
    d = (np.asarray(q1) - np.asarray(q0))[None, :]
    pos = np.asarray(q0)[None, :] + d * (10 * s**3 - 15 * s**4 + 6 * s**5)
    moving = (t < move_time)[:, None]
    vel = d * (30 * s**2 - 60 * s**3 + 30 * s**4) / move_time * moving
    acc = d * (60 * s - 180 * s**2 + 120 * s**3) / move_time**2 * moving
    return pos, vel, acc


#: Range of the move durations, s (drawn per experiment).
MOVE_TIME = (2.5, 4.5)
#: The minimum-jerk runs draw from the streams of ``seed + SEED_OFFSET``: they differ from NMPC runs.
SEED_OFFSET = 7_919

_ARMS: dict[str, ArmModel] = {}


def _arm(machine: Machine) -> ArmModel:
    """This process's numeric model of ``machine`` (built once per process)."""
    key = repr(machine)
    if key not in _ARMS:
        _ARMS[key] = ArmModel(machine)
    return _ARMS[key]


def minimum_jerk_experiment(spec: RunSpec, experiment: int) -> tuple[pd.DataFrame, dict]:
    """Rows and metadata of minimum-jerk experiment ``experiment`` of the run ``spec``.

    Parameters
    ----------
    spec : RunSpec
        The run; ``spec.options`` may set ``move_time`` (range of the move durations, s).
    experiment : int
        Experiment number.

    Returns
    -------
    frame : pandas.DataFrame
        The experiment's rows.
    meta : dict
        Its scenario, the drawn ``move_time`` (s) and ``status``.
    """
    machine = spec.machine
    move_time = tuple(spec.option("move_time", MOVE_TIME))
    t = np.linspace(0.0, DURATION, SAMPLES_PER_EXPERIMENT)
    sc = sample_scenario(spec.seed, experiment, machine.max_payload)
    rng_sc, rng_noise = experiment_rngs(spec.seed + SEED_OFFSET, experiment)  # own stream
    T = float(rng_sc.uniform(*move_time))
    q, qd, qdd = minimum_jerk(np.array(sc.start_pose), np.array(sc.target_pose), t, T)
    tau = _arm(machine).inverse_dynamics(q, qd, qdd, sc.payload)
    frame = experiment_frame(experiment, t, q, qd, qdd, tau, sc.payload, spec.noise,
                             noise_rng(spec, rng_noise), spec.with_truth)
    return frame, {**sc.to_dict(), "move_time": T, "status": "ok"}


def simulate_minimum_jerk(n_experiments: int, seed: int = 0, machine: Machine | str = "cat345c",
                          noise: str | NoisePreset = "thesis", with_truth: bool = False,
                          move_time: tuple[float, float] = MOVE_TIME,
                          first_experiment: int = 0) -> Dataset:
    """Dataset of minimum-jerk swings between the thesis' random start and target poses.

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
    move_time : tuple of float
        Range (low, high) the move duration of each experiment is drawn from, s.
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
    spec = RunSpec("minimum-jerk", int(seed), machine, preset, bool(with_truth),
                   first_experiment + n_experiments, options=(("move_time", tuple(move_time)),))
    return run_in_process(spec, minimum_jerk_experiment, first_experiment, n_experiments)
