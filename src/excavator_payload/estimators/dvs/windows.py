"""What a DVS network sees of the data: per-experiment arrays of a dataset, tapped-delay-line
windows (``preparets``: the first ``max(delays)`` samples of each experiment only fill the delay
lines, and a window never reaches back into the previous experiment), the streaming
:class:`DelayLine`, and block means for ``--decimation``.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from excavator_payload.data.dataset import Dataset


# -- delay lines ----------------------------------------------------------------------------
def delay_windows(values: np.ndarray, delays: Sequence[int]) -> np.ndarray:
    r"""Tapped-delay-line rows of ONE experiment: row :math:`t` is
    :math:`[x(t-d_1), x(t-d_2), \dots]` (each a block of all channels).

    ``values`` is ``(T, k)``; the result ``(T, k·len(delays))`` is NaN for the first
    ``max(delays)`` rows, whose window would reach before the experiment (``preparets``).

    Parameters
    ----------
    values : numpy.ndarray
        One experiment's inputs, ``(T, k)``.
    delays : Sequence[int]
        Delays in samples.
    """
    values = np.asarray(values, dtype=float)
    T, k = values.shape
    out = np.full((T, k * len(delays)), np.nan)
    for j, d in enumerate(delays):
        if d < T:
            out[d:, j * k:(j + 1) * k] = values[:T - d]
    out[:max(delays)] = np.nan
    return out


class DelayLine:
    """Streaming counterpart of :func:`delay_windows`: a ring buffer of the last
    ``max(delays) + 1`` input vectors.

    ``push(x)`` returns the window ``[x(t-d_1), x(t-d_2), …]`` (same order as
    :func:`delay_windows`), or None while the line is still filling.

    Parameters
    ----------
    n_channels : int
        Values per input vector.
    delays : Sequence[int]
        Delays in samples.
    zero_history : bool
        Start full of zeros instead of waiting to be filled.
    """

    def __init__(self, n_channels: int, delays: Sequence[int], zero_history: bool = False) -> None:
        # zero_history: the line starts full of zeros (MATLAB's zero initial layer delay
        # states ``Ai``) instead of waiting to be filled (input delay states)
        self.zero_history = zero_history
        self.delays = np.asarray(delays, dtype=int)
        self.length = int(self.delays.max()) + 1
        self.buffer = np.zeros((self.length, n_channels))
        self.reset()

    def reset(self) -> None:
        """Empty the line (or refill it with zeros when ``zero_history``)."""
        self.position = -1  # index of the newest entry
        self.count = self.length if self.zero_history else 0
        self.buffer[:] = 0.0

    def push(self, x: np.ndarray) -> np.ndarray | None:
        """Add the newest sample; return the window (delays order), or None while filling.

        Parameters
        ----------
        x : numpy.ndarray
            The newest input vector, ``(n_channels,)``.
        """
        self.position = (self.position + 1) % self.length
        self.buffer[self.position] = x
        self.count += 1
        if self.count < self.length:
            return None
        return self.buffer[(self.position - self.delays) % self.length].ravel()


# -- datasets -> per-experiment arrays ------------------------------------------------------
def experiment_bounds(dataset: Dataset) -> np.ndarray:
    """Row index bounds ``[a_0, a_1, …, n_rows]`` of consecutive experiments (as :meth:`Estimator.estimate`).

    Parameters
    ----------
    dataset : Dataset
        Data with rows grouped by experiment.
    """
    exp = dataset.frame["experiment"].to_numpy()
    starts = np.flatnonzero(np.r_[True, exp[1:] != exp[:-1]])
    return np.r_[starts, len(exp)]


def experiment_arrays(dataset: Dataset, columns: Sequence[str]) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Per experiment: the ``(T_i, k)`` inputs of ``columns`` and the ``(T_i,)`` payload targets.

    Parameters
    ----------
    dataset : Dataset
        Data with a ``payload`` column, kg.
    columns : Sequence[str]
        Input signal names.
    """
    x = dataset.signals(columns)
    y = dataset.frame["payload"].to_numpy(dtype=float)
    bounds = experiment_bounds(dataset)
    xs = [x[a:b] for a, b in zip(bounds[:-1], bounds[1:])]
    ys = [y[a:b] for a, b in zip(bounds[:-1], bounds[1:])]
    return xs, ys


def block_means(values: np.ndarray, factor: int) -> np.ndarray:
    """Means of consecutive blocks of ``factor`` rows, ``(T // factor, …)``; an incomplete
    last block is dropped (a streaming network would not have run on it yet).

    Parameters
    ----------
    values : numpy.ndarray
        Samples in rows, ``(T, …)``.
    factor : int
        Rows per block (``--decimation``).
    """
    values = np.asarray(values, dtype=float)
    n = len(values) // factor
    return values[:n * factor].reshape(n, factor, *values.shape[1:]).mean(axis=1)


__all__ = ["delay_windows", "DelayLine", "experiment_bounds", "experiment_arrays", "block_means"]
