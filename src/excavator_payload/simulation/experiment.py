"""Turning a simulated motion into the rows of a dataset (sensor sampling + noise), and the
description of a simulated run (:class:`RunSpec`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from excavator_payload.data.schema import SAMPLE_RATE, SIGNALS, TRUTH_COLUMNS
from excavator_payload.model.machine import Machine
from excavator_payload.simulation.sensors import NoisePreset, add_noise


def experiment_frame(experiment: int, time: np.ndarray, q: np.ndarray, qd: np.ndarray,
                     qdd: np.ndarray, tau: np.ndarray, payload: float, noise: NoisePreset,
                     rng: np.random.Generator, with_truth: bool = False) -> pd.DataFrame:
    """Rows of one experiment: measured signals (truth + noise), optionally the truth.

    Parameters
    ----------
    experiment : int
        Experiment number written into the ``experiment`` column.
    time : numpy.ndarray
        Sample times, s, shape (n_samples,).
    q, qd, qdd : numpy.ndarray
        True joint angles (rad), rates (rad/s) and accelerations (rad/s²) of boom and dipper
        at the sample times, shape (n_samples, 2).
    tau : numpy.ndarray
        True joint torques, N·m, shape (n_samples, 2).
    payload : float
        Payload mass, kg, written into the ``payload`` column.
    noise : NoisePreset
        Sensor noise added to the true signals.
    rng : numpy.random.Generator
        Source of the sensor noise.
    with_truth : bool
        Also add the noise-free ``true_*`` columns.

    Returns
    -------
    pandas.DataFrame
        One row per sample: ``experiment``, ``time``, the measured signals, ``payload`` and,
        with ``with_truth``, the true signals.
    """
    truth = np.column_stack([q[:, 0], qd[:, 0], qdd[:, 0], q[:, 1], qd[:, 1], qdd[:, 1],
                             tau[:, 0], tau[:, 1]])
    measured = add_noise(truth, noise, rng)
    data = {"experiment": np.full(len(time), int(experiment), dtype=np.int64), "time": time}
    for i, name in enumerate(SIGNALS):
        data[name] = measured[:, i]
    data["payload"] = np.full(len(time), float(payload))
    if with_truth:
        for i, name in enumerate(TRUTH_COLUMNS):
            data[name] = truth[:, i]
    return pd.DataFrame(data)


@dataclass(frozen=True)
class RunSpec:
    """Everything the experiments of one simulated run depend on: small and picklable.

    A worker process (local or on a cluster) simulates experiment ``k`` of the run from this
    and ``k`` alone, so the data do not depend on where or in which order experiments run.

    Parameters
    ----------
    motion : str
        Motion family, a key of :data:`excavator_payload.simulation.generate.MOTIONS`.
    seed : int
        Base seed; experiment ``k`` draws from the streams of ``(seed, k)``.
    machine : Machine
        The simulated machine.
    noise : NoisePreset
        Sensor noise.
    with_truth : bool
        Add the noise-free ``true_*`` columns.
    n_experiments : int
        Size of the whole run (the lifts spread their dipper angles over it).
    frozen_noise_seed : int or None
        ``None``: independent noise in every experiment. An integer: the *same* noise sequence,
        drawn from this seed, in every experiment (Simulink's noise block with its seed reused).
    options : tuple of (name, value) pairs
        Motion-specific settings (e.g. ``move_time`` of the minimum-jerk moves).
    """

    motion: str
    seed: int
    machine: Machine
    noise: NoisePreset
    with_truth: bool = False
    n_experiments: int = 0
    frozen_noise_seed: int | None = None
    options: tuple = ()

    def option(self, name: str, default: Any = None) -> Any:
        """The value of motion setting ``name`` in :attr:`options`, else ``default``.

        Parameters
        ----------
        name : str
            Name of the motion setting.
        default : object
            Returned when :attr:`options` has no setting ``name``.
        """
        return dict(self.options).get(name, default)

    def to_dict(self) -> dict:
        """JSON-able description (checkpoint settings, cache keys)."""
        return {"motion": self.motion, "seed": int(self.seed), "machine": self.machine.to_dict(),
                "noise": (self.noise.to_dict() if hasattr(self.noise, "to_dict")
                          else {"name": self.noise.name, "std": dict(self.noise.std)}),
                "with_truth": bool(self.with_truth), "n_experiments": int(self.n_experiments),
                "frozen_noise_seed": self.frozen_noise_seed,
                "options": {str(k): _jsonable_option(v) for k, v in self.options}}


def _jsonable_option(value):
    """An option as JSON: tuples as lists, a replayed trajectory by its content digest."""
    if isinstance(value, tuple):
        return list(value)
    if hasattr(value, "digest"):
        return {"trajectory": value.source, "digest": value.digest}
    return value


def noise_rng(spec: RunSpec, independent: np.random.Generator) -> np.random.Generator:
    """The generator of an experiment's sensor noise: its own stream, or the frozen sequence's.

    Parameters
    ----------
    spec : RunSpec
        The run; its ``frozen_noise_seed`` decides which generator is returned.
    independent : numpy.random.Generator
        The experiment's own noise stream, returned when the noise is not frozen.

    Returns
    -------
    numpy.random.Generator
        ``independent``, or a fresh generator seeded with ``spec.frozen_noise_seed``.
    """
    if spec.frozen_noise_seed is None:
        return independent
    return np.random.default_rng(int(spec.frozen_noise_seed))


def run_in_process(spec: RunSpec, experiment, first_experiment: int, n_experiments: int):
    """The dataset of experiments ``first_experiment …`` of the run ``spec``, simulated one
    after another in this process by ``experiment(spec, k) -> (frame, meta)``.

    Parameters
    ----------
    spec : RunSpec
        The run.
    experiment : callable
        One experiment's rows and metadata.
    first_experiment : int
        Number of the first experiment.
    n_experiments : int
        Number of experiments.

    Returns
    -------
    Dataset
        The rows of all experiments and their metadata.
    """
    from excavator_payload.data.dataset import Dataset

    frames, metas = [], []
    for k in range(first_experiment, first_experiment + n_experiments):
        frame, meta = experiment(spec, k)
        frames.append(frame)
        metas.append(meta)
    meta = {"machine": spec.machine.to_dict(), "noise": spec.noise.name, "motion": spec.motion,
            "base_seed": int(spec.seed), "sample_rate": SAMPLE_RATE, "experiments": metas}
    return Dataset(pd.concat(frames, ignore_index=True), meta)
