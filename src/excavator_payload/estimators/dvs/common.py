r"""What every data-driven virtual sensor (DVS) shares: scaling, MLP algebra, delay lines, and
the :class:`NeuralEstimator` base that trains, saves and streams a network.

Conventions (MATLAB's, as the thesis used them, appendix A.3)
-------------------------------------------------------------
* Hidden layers use :math:`\tanh` (``tansig``), the output layer is linear (``purelin``).
* Inputs and the output are scaled by ``mapminmax`` (to :math:`[-1, 1]`) or ``mapstd``
  (zero mean, unit standard deviation), fitted on the training experiments.
* ``preparets``: the first ``max(delays)`` samples of each experiment only fill the delay
  lines and get no estimate; a window never reaches back into the previous experiment.
* The first ``train_experiments`` experiments of the dataset train, the next
  ``validation_experiments`` validate (appendix A.3: 100 and 51).

Weights travel as ONE flat float64 vector; an MLP with layer sizes
:math:`[n_0, n_1, \dots, n_L]` stores, layer after layer, :math:`W_l` (:math:`n_l\times
n_{l-1}`, row-major) then :math:`b_l`.
"""

from __future__ import annotations

import math

import re
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import torch

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.schema import MACHINE_SENSORS, SENSOR_SETS, THESIS_SENSORS, SensorSet
from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.base import Estimator, Option, Status, StepResult
from excavator_payload.estimators.dvs.trainbr import LOG_COLUMNS, TrainingLog, train_adam, train_br

#: The thesis' network inputs (appendix A.3 ``Input='[1 2 4 5 7 8]'``): angles, rates, torques.
THESIS_INPUTS: tuple[str, ...] = ("boom_angle", "boom_rate", "dipper_angle", "dipper_rate",
                                  "boom_torque", "dipper_torque")
#: Default inputs per sensor set: the thesis' six signals; on a machine every signal it has
#: (angles, rates, slew rate, inclinations and all six pressures).
DEFAULT_INPUTS: dict[str, tuple[str, ...]] = {THESIS_SENSORS.name: THESIS_INPUTS,
                                               MACHINE_SENSORS.name: MACHINE_SENSORS.signals}
SCALINGS = ("mapminmax", "mapstd")
TRAINERS = ("trainbr", "adam")


# -- option parsing -------------------------------------------------------------------------
def parse_int_list(raw: Any, what: str) -> list[int]:
    """``"10,10,10"``, ``"[10 10 10]"``, ``"0:5"`` (MATLAB range), ``"0:2:6"``, ``[0, 1]`` or an int.

    Parameters
    ----------
    raw : Any
        The option's value (text, int or sequence of them).
    what : str
        What the list is, for error messages.

    Returns
    -------
    list of int
        The integers, in the order given.
    """
    if isinstance(raw, (int, np.integer)):
        return [int(raw)]
    if isinstance(raw, (list, tuple, np.ndarray)):
        out = []
        for v in raw:
            out.extend(parse_int_list(v, what))
        return out
    text = str(raw).strip().strip("[]()").strip()
    if not text:
        return []
    out: list[int] = []
    try:
        for part in re.split(r"[,\s;]+", text):
            if not part:
                continue
            if ":" in part:
                bits = [int(b) for b in part.split(":")]
                if len(bits) == 2:
                    lo, step, hi = bits[0], 1, bits[1]
                elif len(bits) == 3:
                    lo, step, hi = bits
                else:
                    raise ValueError
                if step <= 0:
                    raise ValueError
                if (hi - lo) // step > MAX_LIST:
                    raise EstimatorError(f"{what}: {raw!r} has more than {MAX_LIST} entries")
                out.extend(range(lo, hi + 1, step))
            else:
                out.append(int(part))
    except ValueError:
        raise EstimatorError(f"{what}: cannot read {raw!r} (use e.g. '10,10,10' or '0:5')") from None
    return out


#: Largest ``--decimation``: 10 s between network samples at 100 Hz, beyond any use.
MAX_DECIMATION = 1000


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


#: Longest list an option may expand to (delays, layers).
MAX_LIST = 1000
#: Largest layer and largest delay accepted: far beyond any payload network, small enough that
#: a typo cannot ask for terabytes.
MAX_LAYER_SIZE = 1000
MAX_DELAY = 1000
#: Most weights a network may have: trainbr solves an (n × n) system per epoch (8·n² bytes).
MAX_WEIGHTS = {"trainbr": 5000, "adam": 1_000_000}


def parse_hidden(raw: Any) -> list[int]:
    """Hidden-layer sizes from the ``--hidden`` option (any form :func:`parse_int_list` reads):
    at most 20 layers of 1 to ``MAX_LAYER_SIZE`` neurons each, else :class:`EstimatorError`.

    Parameters
    ----------
    raw : Any
        The ``--hidden`` value.
    """
    sizes = parse_int_list(raw, "--hidden")
    if any(s <= 0 for s in sizes):
        raise EstimatorError(f"--hidden: layer sizes must be positive, got {raw!r}")
    if any(s > MAX_LAYER_SIZE for s in sizes) or len(sizes) > 20:
        raise EstimatorError(f"--hidden: at most 20 layers of at most {MAX_LAYER_SIZE} neurons, got {raw!r}")
    return sizes


def parse_delays(raw: Any) -> list[int]:
    """Tapped-delay-line delays in samples from the ``--delays`` option (e.g. ``'0:5'``), sorted:
    at least one, distinct, between 0 and ``MAX_DELAY``, else :class:`EstimatorError`.

    Parameters
    ----------
    raw : Any
        The ``--delays`` value.
    """
    delays = parse_int_list(raw, "--delays")
    if not delays:
        raise EstimatorError("--delays: give at least one delay (e.g. '0:5')")
    if any(d < 0 for d in delays) or len(set(delays)) != len(delays):
        raise EstimatorError(f"--delays: delays must be distinct and non-negative, got {raw!r}")
    if max(delays) > MAX_DELAY:
        raise EstimatorError(f"--delays: at most {MAX_DELAY} samples, got {raw!r}")
    return sorted(delays)


def parse_inputs(raw: Any, sensor_set: SensorSet = THESIS_SENSORS) -> list[str]:
    """Signal names (comma separated), ``all``, ``default`` or MATLAB's 1-based column numbers
    (``'1,2,4'``), of the signals of ``sensor_set``.

    Parameters
    ----------
    raw : Any
        The ``--inputs`` value (text or sequence).
    sensor_set : SensorSet
        Sensor set whose signals are chosen from.

    Returns
    -------
    list of str
        Signal names.
    """
    signals = sensor_set.signals
    items = list(raw) if isinstance(raw, (list, tuple)) else \
        [p for p in re.split(r"[,\s;]+", str(raw).strip().strip("[]")) if p]
    if items == ["all"]:
        return list(signals)
    if items == ["default"]:
        return list(DEFAULT_INPUTS.get(sensor_set.name, signals))
    names: list[str] = []
    for item in items:
        item = str(item).strip()
        if item.isdigit():
            k = int(item)
            if not 1 <= k <= len(signals):
                raise EstimatorError(f"--inputs: column number {k} is not in 1…{len(signals)} "
                                     f"(the {sensor_set.name} sensor set)")
            item = signals[k - 1]
        if item not in signals:
            raise EstimatorError(f"--inputs: unknown signal {item!r} of the {sensor_set.name} sensor "
                                 f"set; choose from {', '.join(signals)}")
        names.append(item)
    if not names or len(set(names)) != len(names):
        raise EstimatorError(f"--inputs: give distinct signal names, got {raw!r}")
    return names


# -- scaling --------------------------------------------------------------------------------
class Scaler:
    r"""Column-wise affine scaling :math:`y = (x - c)\,g`, as MATLAB's process functions.

    ``mapminmax``: :math:`c = (x_{max} + x_{min})/2`, :math:`g = 2/(x_{max} - x_{min})`, so the
    training range maps onto :math:`[-1, 1]`. ``mapstd``: :math:`c = \bar x`, :math:`g = 1/s_x`.
    A constant column passes unscaled (:math:`g = 1`), as in MATLAB.

    Parameters
    ----------
    method : str
        ``"mapminmax"`` or ``"mapstd"``.
    """

    def __init__(self, method: str = "mapminmax") -> None:
        if method not in SCALINGS:
            raise EstimatorError(f"unknown scaling {method!r}: choose one of {', '.join(SCALINGS)}")
        self.method = method
        self.center: np.ndarray | None = None
        self.gain: np.ndarray | None = None

    def fit(self, x: np.ndarray) -> "Scaler":
        """Fit centre and gain per column of ``x`` (rows are samples); returns ``self``.

        Parameters
        ----------
        x : numpy.ndarray
            Training values, samples in rows (finite).
        """
        x = np.asarray(x, dtype=float)
        x = x.reshape(len(x), -1)
        if len(x) == 0 or not np.all(np.isfinite(x)):
            raise EstimatorError("cannot fit scaling: no data or non-finite values")
        if self.method == "mapminmax":
            lo, hi = x.min(axis=0), x.max(axis=0)
            center, spread = (hi + lo) / 2.0, (hi - lo) / 2.0
        else:
            center, spread = x.mean(axis=0), x.std(axis=0, ddof=1) if len(x) > 1 else np.zeros(x.shape[1])
        self.center = center
        # A (numerically) constant column keeps gain 1, as MATLAB does for xmax == xmin; a
        # subnormal spread would otherwise overflow the gain to inf and the transform to NaN.
        usable = spread > np.finfo(float).tiny * 1e6
        self.gain = np.where(usable, 1.0 / np.where(usable, spread, 1.0), 1.0)
        return self

    def _check(self) -> None:
        if self.center is None:
            raise EstimatorError("scaler is not fitted")

    def transform(self, x):
        """Scale ``x``: ``(x - center) * gain``.

        Parameters
        ----------
        x : numpy.ndarray or torch.Tensor
            Values in their own units, columns as fitted.
        """
        self._check()
        return (x - self.center) * self.gain

    def inverse(self, y):
        """Undo :meth:`transform`: ``y / gain + center``.

        Parameters
        ----------
        y : numpy.ndarray or torch.Tensor
            Scaled values.
        """
        self._check()
        return y / self.gain + self.center

    def to_arrays(self, prefix: str = "scaler") -> dict[str, np.ndarray]:
        """``{prefix}_center``, ``{prefix}_gain``, ``{prefix}_method`` (for an ``.npz``).

        Parameters
        ----------
        prefix : str
            Prefix of the array names.
        """
        self._check()
        return {f"{prefix}_center": self.center, f"{prefix}_gain": self.gain,
                f"{prefix}_method": np.array(self.method)}

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray], prefix: str = "scaler",
                    method: str | None = None) -> "Scaler":
        """Inverse of :meth:`to_arrays` (``method`` defaults to the stored one).

        Parameters
        ----------
        arrays : Mapping[str, numpy.ndarray]
            Saved arrays (e.g. an ``.npz``).
        prefix : str
            Prefix of the array names.
        method : str or None
            Scaling method (None: the stored one, else ``mapminmax``).
        """
        if method is None:
            method = str(arrays[f"{prefix}_method"]) if f"{prefix}_method" in arrays else "mapminmax"
        s = cls(method)
        s.center = np.asarray(arrays[f"{prefix}_center"], dtype=float)
        s.gain = np.asarray(arrays[f"{prefix}_gain"], dtype=float)
        return s


# -- multilayer perceptron --------------------------------------------------------------------
def mlp_sizes(n_in: int, hidden: Sequence[int], n_out: int = 1) -> list[int]:
    """Layer sizes ``[n_in, *hidden, n_out]``.

    Parameters
    ----------
    n_in : int
        Number of inputs.
    hidden : Sequence[int]
        Hidden-layer sizes.
    n_out : int
        Number of outputs.
    """
    return [int(n_in), *[int(h) for h in hidden], int(n_out)]


def n_weights(sizes: Sequence[int]) -> int:
    """Number of weights and biases of an MLP with these layer sizes.

    Parameters
    ----------
    sizes : Sequence[int]
        Layer sizes, inputs first (:func:`mlp_sizes`).
    """
    return sum(sizes[i + 1] * (sizes[i] + 1) for i in range(len(sizes) - 1))


def mlp_layers(w, sizes: Sequence[int]) -> list[tuple[Any, Any]]:
    """Split a flat weight vector (torch or numpy) into ``[(W_1, b_1), …]``.

    Parameters
    ----------
    w : torch.Tensor or numpy.ndarray
        Flat weight vector (last axis), :func:`n_weights` entries.
    sizes : Sequence[int]
        Layer sizes, inputs first.
    """
    if w.shape[-1] != n_weights(sizes):
        raise EstimatorError(f"weight vector has {w.shape[-1]} entries, layers {list(sizes)} "
                             f"need {n_weights(sizes)}")
    layers, k = [], 0
    for n_prev, n_next in zip(sizes[:-1], sizes[1:]):
        W = w[k:k + n_next * n_prev].reshape(n_next, n_prev)
        k += n_next * n_prev
        b = w[k:k + n_next]
        k += n_next
        layers.append((W, b))
    return layers


def nguyen_widrow_init(sizes: Sequence[int], generator: torch.Generator) -> torch.Tensor:
    r"""Nguyen–Widrow initial weights (MATLAB ``initnw``) as one flat float64 vector.

    For a layer of :math:`S` neurons with :math:`R` inputs in :math:`[-1, 1]`: rows of
    :math:`W` uniform in :math:`[-1, 1]` then scaled to norm :math:`\beta = 0.7\,S^{1/R}`, and
    biases spread evenly over :math:`[-\beta, \beta]` with the sign of the first weight, so the
    neurons' active regions tile the input space. A single-neuron layer gets bias 0.

    Parameters
    ----------
    sizes : Sequence[int]
        Layer sizes, inputs first.
    generator : torch.Generator
        Random number generator (seeded by the caller).
    """
    parts = []
    for n_prev, n_next in zip(sizes[:-1], sizes[1:]):
        beta = 0.7 * n_next ** (1.0 / n_prev)
        W = 2.0 * torch.rand(n_next, n_prev, generator=generator, dtype=torch.float64) - 1.0
        W = beta * W / torch.linalg.vector_norm(W, dim=1, keepdim=True).clamp_min(1e-12)
        if n_next == 1:
            b = torch.zeros(1, dtype=torch.float64)
        else:
            b = beta * torch.linspace(-1.0, 1.0, n_next, dtype=torch.float64) * torch.sign(W[:, 0])
        parts += [W.reshape(-1), b]
    return torch.cat(parts)


def mlp_forward(w: torch.Tensor, x: torch.Tensor, sizes: Sequence[int]) -> torch.Tensor:
    r"""Outputs of the MLP: :math:`a_0 = x`, :math:`a_l = \tanh(W_l a_{l-1} + b_l)` for hidden
    layers, :math:`y = W_L a_{L-1} + b_L`. ``x`` is ``(..., n_in)``, the result ``(..., n_out)``.

    Parameters
    ----------
    w : torch.Tensor
        Flat weight vector.
    x : torch.Tensor
        Scaled inputs, ``(..., n_in)``.
    sizes : Sequence[int]
        Layer sizes, inputs first.
    """
    layers = mlp_layers(w, sizes)
    a = x
    for W, b in layers[:-1]:
        a = torch.tanh(a @ W.T + b)
    W, b = layers[-1]
    return a @ W.T + b


def mlp_output_jacobian(w: torch.Tensor, x: torch.Tensor, sizes: Sequence[int],
                        negate: bool = False, out: torch.Tensor | None = None) -> torch.Tensor:
    r"""Per-sample gradients :math:`\partial y_i/\partial w` of a single-output MLP, ``(N, P)``.

    Backpropagation written out: with :math:`\delta_L = 1` and
    :math:`\delta_{l-1} = (W_l^\top \delta_l) \odot (1 - a_{l-1}^2)`, the gradient of sample
    :math:`i` w.r.t. :math:`W_l` is :math:`\delta_{l,i}\, a_{l-1,i}^\top` and w.r.t.
    :math:`b_l` is :math:`\delta_{l,i}`. Equal to ``torch.func.vmap(torch.func.grad(...))``
    (tested) but several times faster, which keeps an LM epoch cheap.

    Parameters
    ----------
    w : torch.Tensor
        Flat weights.
    x : torch.Tensor
        ``(N, n_in)`` scaled inputs.
    sizes : sequence of int
        Layer sizes (last one 1).
    negate : bool
        Return :math:`-\partial y/\partial w` (the Jacobian of the residuals target − output)
        by starting from :math:`\delta_L = -1`. Exactly the negated matrix (IEEE negation
        commutes with every product and sum here), without the extra pass and the extra copy
        of an ``(N, P)`` array a separate negation costs: on the machine set ``N·P`` is about
        10⁸ and that copy was a quarter of an epoch.
    out : torch.Tensor, optional
        ``(N, P)`` float64 array to write into (and return), e.g. rows of a buffer trainbr keeps
        for the whole training; its last dimension must be contiguous. Default: a new array.

    Notes
    -----
    The blocks are written straight into one preallocated ``(N, P)`` array (no concatenation,
    which would hold every block twice).
    """
    if sizes[-1] != 1:
        raise ValueError("mlp_output_jacobian: single-output networks only")
    layers = mlp_layers(w, sizes)
    acts = [x]
    for W, b in layers[:-1]:
        acts.append(torch.tanh(acts[-1] @ W.T + b))
    n = x.shape[0]
    if out is None:
        out = torch.empty(n, w.shape[-1], dtype=x.dtype)
    elif out.shape != (n, w.shape[-1]) or out.dtype != x.dtype or out.stride(-1) != 1:
        raise ValueError(f"mlp_output_jacobian: out must be a ({n}, {w.shape[-1]}) {x.dtype} array "
                         f"with contiguous rows, got {tuple(out.shape)} {out.dtype}")
    # column offset of each layer's (W, b) block in the flat weight vector
    offsets, k = [], 0
    for n_prev, n_next in zip(sizes[:-1], sizes[1:]):
        offsets.append(k)
        k += n_next * (n_prev + 1)
    delta = torch.full((n, 1), -1.0 if negate else 1.0, dtype=x.dtype)
    for l in range(len(layers) - 1, -1, -1):
        a_prev = acts[l]
        n_next, n_prev = delta.shape[1], a_prev.shape[1]
        k = offsets[l]
        torch.mul(delta[:, :, None], a_prev[:, None, :],
                  out=out[:, k:k + n_next * n_prev].view(n, n_next, n_prev))  # W block
        out[:, k + n_next * n_prev:k + n_next * (n_prev + 1)] = delta  # bias block
        if l > 0:
            delta = (delta @ layers[l][0]) * (1.0 - a_prev ** 2)
    return out


def mlp_forward_numpy(layers: Sequence[tuple[np.ndarray, np.ndarray]], x: np.ndarray) -> np.ndarray:
    """:func:`mlp_forward` with pre-extracted numpy matrices (fast, for streaming).

    Parameters
    ----------
    layers : Sequence[tuple[numpy.ndarray, numpy.ndarray]]
        ``[(W_1, b_1), …]`` from :func:`mlp_layers`.
    x : numpy.ndarray
        Scaled inputs, one sample ``(n_in,)`` or rows ``(N, n_in)``.
    """
    a = x
    for W, b in layers[:-1]:
        a = np.tanh(W @ a + b) if a.ndim == 1 else np.tanh(a @ W.T + b)
    W, b = layers[-1]
    return W @ a + b if a.ndim == 1 else a @ W.T + b


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


def neural_options(hidden: str = "10,10,10", delays: str = "0:5", **extra: Option) -> dict[str, Option]:
    """The options every network has (with per-network defaults) plus ``extra``.

    Parameters
    ----------
    hidden : str
        Default of ``--hidden``.
    delays : str
        Default of ``--delays``.
    **extra : Option
        The network's own options.
    """
    options = {
        "hidden": Option(str, hidden, "hidden layer sizes, e.g. '10,10,10'"),
        "delays": Option(str, delays, "input delays in samples, MATLAB style, e.g. '0:5' or '0,1,2'"),
        "inputs": Option(str, "default",
                         "input signals of the data's sensor set (comma separated names, 'all', "
                         "1-based column numbers, or 'default': the thesis' six signals on the "
                         "thesis set, every signal on the machine set)"),
        "scaling": Option(str, "mapminmax", "input/output scaling", SCALINGS),
        "trainer": Option(str, "trainbr", "training algorithm", TRAINERS),
        "decimation": Option(int, 1, "the network runs on every K-th sample of the data (samples), "
                             "each input the mean of the last K samples; --delays then count the "
                             "network's samples and the estimate is held in between (1: every "
                             "sample; 5 on the machine set's 100 Hz gives the thesis nets' 20 Hz)"),
        "smoothing": Option(float, 0.0, "time constant of a first-order low-pass on the "
                            "network's estimate, seconds (a payload is constant while carried; "
                            "0: none, the thesis nets)"),
        "epochs": Option(int, 700, "maximum training epochs (MATLAB: 1000; capped so that net1 on "
                                   "100 experiments trains in about 2 minutes)"),
        "max_time": Option(float, 0.0, "stop training after this many seconds (0: no limit)"),
        "learning_rate": Option(float, 1e-3, "Adam learning rate (trainer adam only)"),
        "seed": Option(int, 0, "seed of the initial weights"),
        "train_experiments": Option(int, 100, "the first N experiments of the data train"),
        "validation_experiments": Option(int, 51, "the next N experiments validate"),
        "best_validation": Option(bool, True, "return the weights of the epoch with the lowest "
                                  "validation error, as MATLAB's train does with a validation set "
                                  "(false: the last epoch's, trainbr alone)"),
        "validation_patience": Option(int, 0, "stop when the validation error has not improved "
                                      "for this many epochs (MATLAB max_fail; 0: never, as trainbr)"),
        "progress": Option(bool, True, "show a progress bar while training"),
    }
    options.update(extra)
    return options


TrainingProblem = tuple[Callable[[torch.Tensor], torch.Tensor], Callable[[torch.Tensor], torch.Tensor] | None]


class NeuralEstimator(Estimator):
    """Base of all DVS networks: options, scaling, training, persistence.

    Subclasses implement

    * ``_n_weights() -> int`` and optionally ``_init_weights(generator)`` (default Nguyen–Widrow
      of :meth:`_layer_sizes`);
    * ``_training_problem(inputs, targets) -> (residuals, jacobian or None)``: ``inputs`` are
      per-experiment scaled ``(T_i, k)`` arrays, ``targets`` scaled ``(T_i,)``;
      ``residuals(w)`` returns the flat target − output errors of all samples that get an
      estimate (``preparets``), ``jacobian(w)`` their ``∂e/∂w`` (None: generic forward AD);
    * ``_use_weights(w)``: pre-extract numpy matrices for streaming;
    * ``_reset_network`` and ``_network_step`` (streaming at the network's rate, see
      :class:`~excavator_payload.estimators.base.Estimator`'s ``_reset``/``_step``; the base
      feeds them every sample, or block means with ``--decimation``).

    After :meth:`fit`: ``weights`` (numpy float64), ``input_scaler``, ``output_scaler``,
    ``training_log``; ``input_names`` / ``input_index`` say which signals feed the network.

    Parameters
    ----------
    machine : Machine, str or None
        Optional: a network needs none (its plausibility limits then come from the data's machine).
    **options
        Estimator options, see the class attribute ``OPTIONS``.
    """

    NEEDS_MACHINE = False
    OPTIONS = neural_options()
    #: The inputs are resolved against the sensor set of the data (:meth:`_use_sensor_set`).
    # SENSOR_SETS: from its traits (estimators/traits.py)
    #: A network has no noise model: it borrows the gate of its training data's physics.
    BORROWS_GATE = True

    def __init__(self, machine=None, **options: Any) -> None:
        super().__init__(machine=machine, **options)
        o = self.options
        self.hidden_sizes = parse_hidden(o["hidden"])
        self.delay_list = parse_delays(o["delays"])
        # Until fit() names the sensor set, the inputs are those of the thesis set, or of the
        # first set that has them all (unknown everywhere: one clear error now, not at fit).
        error = None
        for sensors in (THESIS_SENSORS, *(s for s in SENSOR_SETS.values() if s is not THESIS_SENSORS)):
            try:
                self.input_names = parse_inputs(o["inputs"], sensors)
                self.input_index = np.array(sensors.indices(self.input_names))
                break
            except EstimatorError as exc:
                error = error or exc
        else:
            raise error
        self.decimation = int(o["decimation"])
        if not 1 <= self.decimation <= MAX_DECIMATION:
            raise EstimatorError(f"{self.name}: --decimation must be in 1 … {MAX_DECIMATION} samples, "
                                 f"got {o['decimation']}")
        self.smoothing = float(o["smoothing"])
        if not (math.isfinite(self.smoothing) and 0.0 <= self.smoothing <= 3600.0):
            raise EstimatorError(f"{self.name}: --smoothing must be 0 … 3600 s, got {o['smoothing']}")
        self._smoothed = math.nan
        self._block_sum: np.ndarray | None = None
        self._block_count = 0
        self._held: StepResult | None = None
        for key in ("epochs", "train_experiments"):
            if int(o[key]) < 1:
                raise EstimatorError(f"{self.name}: --{key.replace('_', '-')} must be at least 1")
        if int(o["validation_experiments"]) < 0 or not float(o["max_time"]) >= 0:
            raise EstimatorError(f"{self.name}: --validation-experiments and --max-time must be ≥ 0")
        if not 0 <= int(o["seed"]) < 2**63:
            raise EstimatorError(f"{self.name}: --seed must be in 0 … 2⁶³−1, got {o['seed']}")
        if not (math.isfinite(float(o["learning_rate"])) and float(o["learning_rate"]) > 0):
            raise EstimatorError(f"{self.name}: --learning-rate must be a positive number, got "
                                 f"{o['learning_rate']}")
        if int(o["epochs"]) > 10**7 or int(o["validation_patience"]) < 0:
            raise EstimatorError(f"{self.name}: --epochs must be at most 10⁷ and "
                                 "--validation-patience ≥ 0")
        self.weights: np.ndarray | None = None
        self.input_scaler: Scaler | None = None
        self.output_scaler: Scaler | None = None
        self.training_log: TrainingLog | None = None
        #: RMS error (kg) on the validation (else training) experiments: the ``sigma`` of a step.
        self.residual_std = math.nan
        self.residual_source = ""

    def _check_size(self) -> None:
        """One clear line instead of an attempt to allocate gigabytes."""
        n, limit = self._n_weights(), MAX_WEIGHTS[self.options["trainer"]]
        if n > limit:
            raise EstimatorError(f"{self.name}: {n} weights is more than the {limit} that "
                                 f"--trainer {self.options['trainer']} can train here; use smaller "
                                 "--hidden / --delays (the thesis' nets have a few hundred)")

    def _use_sensor_set(self, sensors: SensorSet) -> None:
        """Resolve ``--inputs`` against the signals of ``sensors`` (the data's sensor set)."""
        names = parse_inputs(self.options["inputs"], sensors)
        changed = names != self.input_names
        self.input_names = names
        self.input_index = np.array(sensors.indices(names))
        if changed:
            self._inputs_changed()

    def _inputs_changed(self) -> None:
        """Hook: the number of inputs changed (subclasses rebuild what depends on it)."""


    # -- hooks -----------------------------------------------------------------------------
    @property
    def n_inputs(self) -> int:
        return len(self.input_names)

    def _layer_sizes(self) -> list[int]:
        raise NotImplementedError

    def _n_weights(self) -> int:
        return n_weights(self._layer_sizes())

    def _init_weights(self, generator: torch.Generator) -> torch.Tensor:
        return nguyen_widrow_init(self._layer_sizes(), generator)

    def _training_problem(self, inputs: list[np.ndarray], targets: list[np.ndarray]) -> TrainingProblem:
        raise NotImplementedError

    def _use_weights(self, w: np.ndarray) -> None:
        raise NotImplementedError

    # -- training --------------------------------------------------------------------------
    def split_experiments(self, dataset: Dataset) -> tuple[Dataset, Dataset | None]:
        """Training and validation parts (thesis A.3: the first 100, the next 51).

        Parameters
        ----------
        dataset : Dataset
            The training data.

        Returns
        -------
        tuple of (Dataset, Dataset or None)
            Training part and validation part (None when there is none).
        """
        n_train = int(self.options["train_experiments"])
        n_val = int(self.options["validation_experiments"])
        n = dataset.n_experiments
        if n < n_train:
            raise EstimatorError(f"{self.name}: the dataset has {n} experiments but "
                                 f"--train-experiments is {n_train}; pass --train-experiments {n} "
                                 f"(or fewer) or use a bigger dataset")
        n_val = min(n_val, n - n_train)
        ids = list(dataset.experiment_ids)
        train = dataset.subset(ids[:n_train])
        val = dataset.subset(ids[n_train:n_train + n_val]) if n_val > 0 else None
        return train, val

    def _scaled(self, dataset: Dataset) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """Scaled per-experiment inputs and targets at the network's rate.

        With ``--decimation K`` the inputs are the means of blocks of K samples and the target
        of a block is the payload at its last sample, exactly what :meth:`_step` feeds the
        network while streaming (the mean is taken of the raw values, then scaled, as there).
        """
        xs, ys = experiment_arrays(dataset, self.input_names)
        bad = [i for i, x in enumerate(xs) if not np.all(np.isfinite(x))]
        if bad or not all(np.all(np.isfinite(y)) for y in ys):
            raise EstimatorError(f"{self.name}: training data contain NaN or infinite values "
                                 f"(e.g. experiment row block {bad[:3]}); clean them first")
        K = self.decimation
        if K > 1:
            xs = [block_means(x, K) for x in xs]
            ys = [y[K - 1::K][:len(x)] for x, y in zip(xs, ys)]
        return ([self.input_scaler.transform(x) for x in xs],
                [self.output_scaler.transform(y[:, None])[:, 0] for y in ys])

    def _fit(self, dataset: Dataset) -> None:
        self._use_sensor_set(self.sensor_set)
        self._check_size()  # after the inputs are known: their number sizes the first layer
        train, val = self.split_experiments(dataset)
        o = self.options
        scaling = o["scaling"]
        x_train = train.signals(self.input_names)
        self.input_scaler = Scaler(scaling).fit(x_train)
        self.output_scaler = Scaler(scaling).fit(train.frame["payload"].to_numpy(float)[:, None])
        inputs, targets = self._scaled(train)
        residuals, jacobian = self._training_problem(inputs, targets)
        validation = None
        if val is not None:
            v_inputs, v_targets = self._scaled(val)
            v_residuals, _ = self._training_problem(v_inputs, v_targets)

            def validation(w):
                e = v_residuals(w)
                return float(e @ e)

        generator = torch.Generator().manual_seed(int(o["seed"]))
        w0 = self._init_weights(generator)
        max_time = float(o["max_time"]) or None
        desc = f"{self.name} {o['trainer']}"
        if o["trainer"] == "trainbr":
            w, log = train_br(residuals, w0, epochs=int(o["epochs"]), validation=validation,
                              progress=bool(o["progress"]), description=desc, jacobian=jacobian,
                              max_seconds=max_time, best_validation=bool(o["best_validation"]),
                              validation_patience=int(o["validation_patience"]))
        else:
            w, log = train_adam(residuals, w0, epochs=int(o["epochs"]), lr=float(o["learning_rate"]),
                                validation=validation, progress=bool(o["progress"]),
                                description=desc, max_seconds=max_time,
                                best_validation=bool(o["best_validation"]),
                                validation_patience=int(o["validation_patience"]))
        weights = w.detach().numpy().astype(np.float64)
        if not np.all(np.isfinite(weights)):
            raise EstimatorError(f"{self.name}: training diverged ({log.stop_reason}); try "
                                 f"--trainer trainbr or a smaller --learning-rate")
        self.training_log = log
        self.weights = weights
        self._use_weights(weights)
        if o["progress"]:
            from rich.console import Console

            Console(stderr=True).print(
                f"{self.name}: {log.trainer} stopped after {log.epoch[-1]} epochs ({log.stop_reason}) "
                f"in {log.seconds:.1f} s; training SSE {log.sse[-1]:.4g} over {log.n_errors} targets "
                f"(scaled), effective parameters γ {log.gamma[-1]:.1f} of {log.n_parameters}, "
                + (f"validation SSE {log.returned_validation_sse:.4g}"
                   if math.isfinite(log.returned_validation_sse) else
                   "no validation experiments (every experiment was used for training, so "
                   "nothing guards against overfitting: give more experiments than "
                   "--train-experiments)")
                + (f" (weights of epoch {log.best_epoch}, the lowest validation error)"
                   if log.best_epoch >= 0 else ""))

    def fit(self, dataset: Dataset) -> "NeuralEstimator":
        """Train (see :meth:`_fit`), then measure the spread of the net's errors for ``sigma``.

        Parameters
        ----------
        dataset : Dataset
            Training data with the true ``payload``, kg.

        Returns
        -------
        NeuralEstimator
            ``self``, trained.
        """
        super().fit(dataset)
        train, val = self.split_experiments(dataset)
        judged = val if val is not None else train
        frame = self.estimate(judged)
        truth = judged.frame["payload"].to_numpy(float)
        ok = (frame["status"] == "ok").to_numpy()
        errors = frame["payload_estimate"].to_numpy(float)[ok] - truth[ok]
        self.residual_std = float(np.sqrt(np.mean(errors**2))) if errors.size else math.nan
        self.residual_source = "validation" if val is not None else "training"
        self.reset()
        return self

    # -- streaming at the network's rate ----------------------------------------------------
    def _reset(self) -> None:
        self._smoothed = math.nan
        self._block_sum = None
        self._block_count = 0
        self._held = None
        self._reset_network()

    def _step(self, time: float, values: np.ndarray) -> StepResult:
        """Feed the network every sample, or with ``--decimation K`` the mean of each block of
        K samples (counted from the start of the experiment, as in training) and hold its
        last estimate in between."""
        K = self.decimation
        if K == 1:
            result = self._network_step(time, values)
            return result if self.smoothing == 0.0 else self._smooth(result)
        if self._block_sum is None:
            self._block_sum = np.array(values, dtype=float)
        else:
            self._block_sum += values
        self._block_count += 1
        if self._block_count == K:
            mean = self._block_sum / K
            self._block_sum, self._block_count = None, 0
            result = self._network_step(time, mean)
            self._held = result if self.smoothing == 0.0 else self._smooth(result)
        return self._held if self._held is not None else StepResult(math.nan, Status.WARMING_UP)

    def _smooth(self, result: StepResult) -> StepResult:
        r"""First-order low-pass of the estimate at the network's rate,
        :math:`\hat m_k = \hat m_{k-1} + (1 - e^{-\Delta t/\tau})(y_k - \hat m_{k-1})`, started
        at the first estimate of the experiment (``--smoothing`` :math:`\tau`)."""
        y = result.estimate
        if result.status is not Status.OK or not math.isfinite(y):
            return result
        if math.isnan(self._smoothed):
            self._smoothed = y
        else:
            period = self.decimation * self.sensor_set.sample_period
            self._smoothed += -math.expm1(-period / self.smoothing) * (y - self._smoothed)
        return StepResult(self._smoothed, result.status, result.sigma)

    def _reset_network(self) -> None:
        """Forget the network's delay lines and states (subclasses)."""
        raise NotImplementedError

    def _network_step(self, time: float, values: np.ndarray) -> StepResult:
        """One sample at the network's rate (``values`` in sensor-set order, raw)."""
        raise NotImplementedError

    def _on_skip(self, time: float, values: np.ndarray) -> None:
        """Nothing before the next sample is judged; see :meth:`_fill_rejected`."""

    def _fill_rejected(self, time: float, values: np.ndarray) -> None:
        """Samples the gate rejected: the delay lines get values interpolated between their
        neighbours in their place (a net's window must stay evenly spaced), not a restart."""
        self._interpolate_rejected(time, values)

    def _estimate_sigma(self) -> float:
        """RMS error of the net on its validation experiments (training experiments when it had
        none: then optimistic), kg; a net has no uncertainty of its own, this is its typical
        error on data like its training data."""
        return self.residual_std

    # -- persistence -----------------------------------------------------------------------
    def _config(self) -> dict:
        log = self.training_log
        return {"input_names": list(self.input_names), "n_weights": int(self.weights.size),
                "training": log.summary() if log is not None else None,
                "residual_std": self.residual_std if math.isfinite(self.residual_std) else None,
                "residual_source": self.residual_source}

    def _arrays(self) -> dict[str, np.ndarray]:
        arrays = {"weights": self.weights, **self.input_scaler.to_arrays("input"),
                  **self.output_scaler.to_arrays("output")}
        if self.training_log is not None:
            frame = self.training_log.to_frame()
            for c in LOG_COLUMNS:
                arrays[f"log_{c}"] = frame[c].to_numpy(dtype=float)
        return arrays

    def _restore(self, config: dict, arrays: Mapping[str, np.ndarray]) -> None:
        self._use_sensor_set(self.sensor_set)
        scaling = self.options["scaling"]
        weights = np.asarray(arrays["weights"], dtype=np.float64)
        if weights.shape != (self._n_weights(),):
            raise EstimatorError(f"{self.name}: saved weights have shape {weights.shape}, the options "
                                 f"need ({self._n_weights()},)")
        self.input_scaler = Scaler.from_arrays(arrays, "input", scaling)
        self.output_scaler = Scaler.from_arrays(arrays, "output", scaling)
        if self.input_scaler.center.shape != (self.n_inputs,):
            raise EstimatorError(f"{self.name}: saved input scaling does not match the inputs")
        if not (np.all(np.isfinite(self.input_scaler.center)) and np.all(np.isfinite(self.input_scaler.gain))
                and np.all(np.isfinite(self.output_scaler.center))
                and np.all(np.isfinite(self.output_scaler.gain))):
            raise EstimatorError(f"{self.name}: saved scaling is not finite")
        self.weights = weights
        spread = config.get("residual_std")
        self.residual_std = float(spread) if isinstance(spread, (int, float)) and spread >= 0 else math.nan
        self.residual_source = str(config.get("residual_source", ""))
        summary = config.get("training") or {}
        if "log_epoch" in arrays:
            import pandas as pd

            frame = pd.DataFrame({c: arrays[f"log_{c}"] for c in LOG_COLUMNS if f"log_{c}" in arrays})
            self.training_log = TrainingLog.from_frame(
                frame, summary.get("stop_reason", ""), summary.get("seconds", 0.0),
                summary.get("n_errors", 0), summary.get("n_parameters", 0), summary.get("trainer", ""),
                summary.get("best_epoch", -1))
        self._use_weights(weights)

    def save(self, directory: str | Path) -> Path:
        """Save (see :meth:`Estimator.save`) plus ``training_log.csv`` and ``training.png``.

        Parameters
        ----------
        directory : str or Path
            Model folder (created if missing).

        Returns
        -------
        Path
            ``directory``.
        """
        directory = super().save(directory)
        if self.training_log is not None:
            tmp = directory / "training_log.csv.tmp"
            self.training_log.to_frame().to_csv(tmp, index=False)
            tmp.replace(directory / "training_log.csv")
            self.training_log.plot(directory / "training.png")
        return directory

    # -- helpers for subclasses --------------------------------------------------------------
    def _scale_input(self, values: np.ndarray) -> np.ndarray:
        """The network's input vector from a sample in sensor-set order (scaled)."""
        return (values[self.input_index] - self.input_scaler.center) * self.input_scaler.gain

    def _unscale_output(self, y: float) -> float:
        return float(y / self.output_scaler.gain[0] + self.output_scaler.center[0])


__all__ = ["THESIS_INPUTS", "DEFAULT_INPUTS", "SCALINGS", "TRAINERS", "Scaler", "mlp_sizes", "n_weights", "mlp_layers",
           "nguyen_widrow_init", "mlp_forward", "mlp_output_jacobian", "mlp_forward_numpy", "delay_windows", "DelayLine",
           "experiment_bounds", "experiment_arrays", "neural_options", "NeuralEstimator",
           "parse_int_list", "parse_hidden", "parse_delays", "parse_inputs", "block_means"]
