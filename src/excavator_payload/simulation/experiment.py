"""Turning a simulated motion into the rows of a dataset (sensor sampling + noise)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from excavator_payload.data.schema import SIGNALS, TRUTH_COLUMNS
from excavator_payload.simulation.sensors import NoisePreset, add_noise


def experiment_frame(experiment: int, time: np.ndarray, q: np.ndarray, qd: np.ndarray,
                     qdd: np.ndarray, tau: np.ndarray, payload: float, noise: NoisePreset,
                     rng: np.random.Generator, with_truth: bool = False) -> pd.DataFrame:
    """Rows of one experiment: measured signals (truth + noise), optionally the truth.

    ``q, qd, qdd, tau`` are (n_samples, 2) arrays of the true joint signals at the sample times.
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
