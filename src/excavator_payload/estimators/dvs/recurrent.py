r"""Recurrent dynamic virtual sensors: the NARX network Net₂ (``net2``) and a layer-recurrent
network (``lrn``), thesis §4.2.2, §6.2 and appendix A.3.

Both are one family of discrete-time recurrent networks. At sample :math:`k` the first hidden
layer sees the input tapped delay line and, for NARX, the network's own past outputs;
every hidden layer of a layer-recurrent network also sees its own past outputs:

.. math::

    x_k &= \big[u_{k-d}\big]_{d \in D_u} \;\oplus\; \big[\hat y_{k-f}\big]_{f \in D_y}

    a^{(1)}_k &= \tanh\!\Big(W^{(1)} \big[x_k \oplus [a^{(1)}_{k-r}]_{r\in D_a}\big] + b^{(1)}\Big)

    a^{(l)}_k &= \tanh\!\Big(W^{(l)} \big[a^{(l-1)}_k \oplus [a^{(l)}_{k-r}]_{r\in D_a}\big] + b^{(l)}\Big),
        \quad l = 2 \dots L

    \hat y_k &= W^{(L+1)} a^{(L)}_k + b^{(L+1)}

with :math:`u` the scaled input signals (``mapminmax``/``mapstd``), :math:`\hat y` the scaled
payload estimate, :math:`D_u` the input delays, :math:`D_y` the output-feedback delays (NARX,
empty for LRN) and :math:`D_a` the layer delays (LRN, empty for NARX). ``⊕`` concatenates.

* ``net2`` = MATLAB ``narxnet(0:5, 1, [10 10 10])`` **in closed loop** (appendix A.3 calls
  ``closeloop(net)`` before ``train``): the fed-back :math:`\hat y_{k-1}` is the network's own
  estimate, during training as at run time, so the training residuals are those of the
  closed-loop rollout and their Jacobian flows back through the feedback: exact
  back-propagation through time, computed by the real-time-recurrent-learning recursion of
  :func:`narx_jacobian` (NARX) or the batched BPTT of :func:`bptt_jacobian` (LRN), both
  checked against ``torch.func`` forward-mode AD of :func:`rollout` in the tests.
* ``lrn`` = MATLAB ``layrecnet(1:2, [10 10 10])``: no input delay line (:math:`D_u=\{0\}`),
  every hidden layer fed back with delays 1 and 2 ("a feedback loop around each layer of the
  network except for the last layer", MATLAB documentation); ``--recurrent-layers first``
  restricts the recurrence to the first hidden layer.

Warm-up (MATLAB ``preparets``): the first :math:`K=\max(D_u\cup D_y\cup D_a)` samples of each
experiment fill the delay lines and get no estimate (NaN, status ``warming_up``); windows
never reach from one experiment into the next. Initial delay states: hidden-layer states are
zero, as ``preparets`` sets ``Ai`` for layer delays. For the closed-loop output feedback
``preparets(net, X, {}, T)`` takes the initial state from the *target* series (the true
payload), which is unknown when the sensor runs; we use a fixed value instead, the mean payload
of the training experiments (option ``--initial-payload`` overrides it), in training and
running alike, so the network learns to converge from it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
import torch

from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.base import Option, Status, StepResult, register
from excavator_payload.estimators.dvs.mlp import nguyen_widrow_init
from excavator_payload.estimators.dvs.neural import NeuralEstimator
from excavator_payload.estimators.dvs.options import neural_options, parse_int_list
from excavator_payload.estimators.dvs.trainbr import GRAM_BLOCK_ROWS, BlockJacobian


# -- structure ---------------------------------------------------------------------------------
def parse_delay_option(raw, name: str, minimum: int = 0) -> tuple[int, ...]:
    """Delays from ``"0:5"``, ``"1"``, ``"1,2"``, ``"none"`` (empty) or a list; sorted, distinct.

    Parameters
    ----------
    raw : Any
        The option's value.
    name : str
        Option name, for error messages.
    minimum : int
        Smallest delay allowed, samples.

    Returns
    -------
    tuple of int
        The delays, samples.
    """
    if isinstance(raw, str) and raw.strip().lower() in ("none", ""):
        return ()
    delays = parse_int_list(raw, f"--{name.replace('_', '-')}")
    if any(d < minimum for d in delays) or len(set(delays)) != len(delays):
        raise EstimatorError(f"--{name.replace('_', '-')}: delays must be distinct and >= {minimum}, "
                             f"got {raw!r}")
    return tuple(sorted(delays))


@dataclass(frozen=True)
class RecurrentStructure:
    """Sizes and delays of a recurrent network (see the module docstring for the equations).

    Parameters
    ----------
    n_signals : int
        Input signals per sample.
    hidden : tuple of int
        Neurons of each hidden layer.
    input_delays, feedback_delays, layer_delays : tuple of int
        Delays in samples, as under Attributes.
    recurrent_layers : tuple of int
        Hidden layers (0-based) with layer feedback.

    Attributes
    ----------
    n_signals : int
        Input signals per sample (before the tapped delay line).
    hidden : tuple of int
        Neurons of each hidden (tanh) layer.
    input_delays : tuple of int
        :math:`D_u`, e.g. ``(0, 1, 2, 3, 4, 5)``.
    feedback_delays : tuple of int
        :math:`D_y`, output fed back to the first hidden layer (NARX); all ``>= 1``.
    layer_delays : tuple of int
        :math:`D_a`, hidden-layer outputs fed back to their own layer (LRN); all ``>= 1``.
    recurrent_layers : tuple of int
        Which hidden layers (0-based) have the layer feedback.
    """

    n_signals: int
    hidden: tuple[int, ...]
    input_delays: tuple[int, ...] = (0,)
    feedback_delays: tuple[int, ...] = ()
    layer_delays: tuple[int, ...] = ()
    recurrent_layers: tuple[int, ...] = field(default=())

    def __post_init__(self) -> None:
        if not self.hidden or any(h < 1 for h in self.hidden):
            raise EstimatorError(f"hidden layer sizes must be positive, got {list(self.hidden)}")
        if not self.input_delays:
            raise EstimatorError("at least one input delay is needed")
        if any(d < 1 for d in self.feedback_delays) or any(d < 1 for d in self.layer_delays):
            raise EstimatorError("feedback and layer delays must be >= 1 (a loop without delay has no "
                                 "solution)")
        if any(not 0 <= i < len(self.hidden) for i in self.recurrent_layers):
            raise EstimatorError(f"recurrent layers {list(self.recurrent_layers)} outside the "
                                 f"{len(self.hidden)} hidden layers")
        if not self.layer_delays:  # no layer delays: no layer recurrence, whatever the layers
            object.__setattr__(self, "recurrent_layers", ())

    @property
    def warmup(self) -> int:
        """Samples per experiment that only fill delay lines (``preparets`` shift)."""
        return max(self.input_delays + self.feedback_delays + self.layer_delays + (0,))

    @property
    def n_tdl(self) -> int:
        """Length of the input tapped-delay-line vector."""
        return self.n_signals * len(self.input_delays)

    def layer_shapes(self) -> list[tuple[int, int]]:
        """``(n_out, n_in)`` of every weight matrix, hidden layers then the linear output layer.

        The input of layer :math:`l` is the concatenation of its feed-forward input, then (first
        layer only) the fed-back outputs, then its own delayed outputs in ``layer_delays`` order.
        """
        shapes = []
        n_in = self.n_tdl + len(self.feedback_delays)
        for i, h in enumerate(self.hidden):
            n_rec = h * len(self.layer_delays) if i in self.recurrent_layers else 0
            shapes.append((h, n_in + n_rec))
            n_in = h
        shapes.append((1, n_in))
        return shapes

    @property
    def n_weights(self) -> int:
        return sum(o * i + o for o, i in self.layer_shapes())

    def to_dict(self) -> dict:
        """The structure as a JSON-ready dict (tuples as lists); :meth:`from_dict` reads it."""
        return {"n_signals": self.n_signals, "hidden": list(self.hidden),
                "input_delays": list(self.input_delays), "feedback_delays": list(self.feedback_delays),
                "layer_delays": list(self.layer_delays), "recurrent_layers": list(self.recurrent_layers)}

    @classmethod
    def from_dict(cls, d: dict) -> "RecurrentStructure":
        """The structure saved by :meth:`to_dict`.

        Parameters
        ----------
        d : dict
            What :meth:`to_dict` returned.
        """
        return cls(int(d["n_signals"]), tuple(d["hidden"]), tuple(d["input_delays"]),
                   tuple(d["feedback_delays"]), tuple(d["layer_delays"]), tuple(d["recurrent_layers"]))


def unpack_weights(w, structure: RecurrentStructure) -> list[tuple]:
    """Split the flat weight vector into ``[(W, b), ...]`` (works for torch and numpy).

    Layout: for each layer in order, ``W`` row-major then ``b``.

    Parameters
    ----------
    w : torch.Tensor or numpy.ndarray
        Flat weight vector, ``structure.n_weights`` entries.
    structure : RecurrentStructure
        The network's sizes and delays.
    """
    layers, start = [], 0
    for n_out, n_in in structure.layer_shapes():
        W = w[start:start + n_out * n_in].reshape(n_out, n_in)
        start += n_out * n_in
        b = w[start:start + n_out]
        start += n_out
        layers.append((W, b))
    if start != w.shape[0]:
        raise EstimatorError(f"weight vector has {w.shape[0]} entries, the network needs {start}")
    return layers


def init_weights(structure: RecurrentStructure, generator: torch.Generator) -> torch.Tensor:
    r"""Nguyen–Widrow initial weights (MATLAB ``initnw``, :func:`nguyen_widrow_init`), float64.

    Each layer is initialised as a layer whose inputs are all its (scaled, :math:`[-1, 1]`)
    inputs: feed-forward, fed-back output and delayed own outputs alike, as ``initnw`` treats
    every weight into a layer.

    Parameters
    ----------
    structure : RecurrentStructure
        The network's sizes and delays.
    generator : torch.Generator
        Random number generator (seeded by the caller).
    """
    return torch.cat([nguyen_widrow_init([n_in, n_out], generator)
                      for n_out, n_in in structure.layer_shapes()])


# -- batch rollout (training, torch) -------------------------------------------------------------
def tapped_delay_inputs(u, input_delays: Sequence[int], warmup: int):
    """Input delay line of every estimated sample: ``(..., T - warmup, n_signals·len(delays))``.

    Row :math:`j` (sample :math:`k = \\text{warmup}+j`) is
    :math:`[u_{k-d_0}, u_{k-d_1}, \\dots]`; works on torch tensors and numpy arrays of shape
    ``(..., T, n_signals)``.

    Parameters
    ----------
    u : torch.Tensor or numpy.ndarray
        Scaled inputs, ``(..., T, n_signals)``.
    input_delays : Sequence[int]
        Input delays, samples.
    warmup : int
        Samples that only fill delay lines (``structure.warmup``).
    """
    T = u.shape[-2]
    parts = [u[..., warmup - d:T - d, :] for d in input_delays]
    if isinstance(u, torch.Tensor):
        return torch.cat(parts, dim=-1)
    return np.concatenate(parts, axis=-1)


def rollout(w: torch.Tensor, u: torch.Tensor, structure: RecurrentStructure,
            initial_output: float) -> torch.Tensor:
    """Closed-loop run of the network over whole experiments at once.

    Parameters
    ----------
    w : Tensor (n_weights,)
        Flat weights (layout of :func:`unpack_weights`).
    u : Tensor (n_experiments, T, n_signals)
        Scaled inputs; every experiment runs from its own first sample (no crossing).
    structure : RecurrentStructure
        Layer sizes, delays and recurrent layers of the network.
    initial_output : float
        Scaled value of the fed-back output before the first estimate (:math:`\\hat y_k` for
        :math:`k < K`).

    Returns
    -------
    Tensor (n_experiments, T - K)
        Scaled estimates of samples :math:`K \\dots T-1`, :math:`K` = ``structure.warmup``.

    Pure function of ``w`` (no in-place updates), so ``torch.func.jacfwd``/``jacrev`` give the
    exact back-propagation-through-time Jacobian of the closed loop.
    """
    K = structure.warmup
    n_exp, T = u.shape[0], u.shape[1]
    n_steps = T - K
    if n_steps <= 0:
        raise EstimatorError(f"experiments of {T} samples are too short for a delay line of {K}")
    layers = unpack_weights(w, structure)
    x_tdl = tapped_delay_inputs(u, structure.input_delays, K)  # (E, n_steps, n_tdl)
    n_tdl = structure.n_tdl
    W1, b1 = layers[0]
    # The delay-line part of the first layer needs no recursion: one matmul for all steps.
    z1_ff = x_tdl @ W1[:, :n_tdl].T + b1  # (E, n_steps, H1)
    n_fb = len(structure.feedback_delays)
    W1_fb = W1[:, n_tdl:n_tdl + n_fb]
    rec = set(structure.recurrent_layers)
    n_hidden = len(structure.hidden)
    zero_states = [u.new_zeros(n_exp, h) for h in structure.hidden]
    y_init = u.new_full((n_exp, 1), float(initial_output))
    y_hist: list[torch.Tensor] = []          # y_hist[j] = estimate of sample K + j, (E, 1)
    a_hist: list[list[torch.Tensor]] = [[] for _ in range(n_hidden)]
    for j in range(n_steps):
        z = z1_ff[:, j]
        if n_fb:
            fb = torch.cat([y_hist[j - f] if j - f >= 0 else y_init for f in structure.feedback_delays],
                           dim=1)
            z = z + fb @ W1_fb.T
        for i in range(n_hidden):
            W, b = layers[i]
            if i > 0:  # layer i - 1's output at this step
                z = a_hist[i - 1][j] @ W[:, :structure.hidden[i - 1]].T + b
            if i in rec:
                n_ff = W.shape[1] - structure.hidden[i] * len(structure.layer_delays)
                past = torch.cat([a_hist[i][j - r] if j - r >= 0 else zero_states[i]
                                  for r in structure.layer_delays], dim=1)
                z = z + past @ W[:, n_ff:].T
            a = torch.tanh(z)
            a_hist[i].append(a)
        W_out, b_out = layers[-1]
        y = a @ W_out.T + b_out
        y_hist.append(y)
    return torch.cat(y_hist, dim=1)


# -- streaming (numpy) ---------------------------------------------------------------------------
class RecurrentStepper:
    """One-sample-at-a-time run of the network in numpy, equal to :func:`rollout`.

    Keeps the input delay line, the fed-back outputs and the delayed hidden-layer outputs.
    ``step(u)`` takes one *scaled* input sample and returns the scaled estimate, or NaN while
    the delay lines fill.

    Parameters
    ----------
    w : numpy.ndarray
        Flat weight vector.
    structure : RecurrentStructure
        The network's sizes and delays.
    initial_output : float
        Fed-back output before the first estimate (scaled units).
    """

    def __init__(self, w: np.ndarray, structure: RecurrentStructure, initial_output: float) -> None:
        self.structure = structure
        self.initial_output = float(initial_output)
        layers = unpack_weights(np.asarray(w, dtype=float), structure)
        self._layers = [(np.ascontiguousarray(W), np.ascontiguousarray(b)) for W, b in layers]
        self._max_in = max(structure.input_delays)
        self._fb = structure.feedback_delays
        self._rec = [i in structure.recurrent_layers for i in range(len(structure.hidden))]
        self.reset()

    def reset(self) -> None:
        """Start a new experiment: empty delay lines, fed-back outputs at ``initial_output``,
        delayed hidden-layer outputs zero."""
        s = self.structure
        self._n = 0
        self._inputs: list[np.ndarray] = []   # newest last, at most max input delay + 1
        n_fb = max(self._fb, default=0)
        self._y_past = [self.initial_output] * n_fb      # newest last
        n_ld = max(s.layer_delays, default=0)
        self._a_past = [[np.zeros(h)] * n_ld for h in s.hidden]  # per layer, newest last

    def step(self, u: np.ndarray) -> float:
        """Feed one scaled input sample ``u`` (``n_signals``,); return the scaled estimate, or NaN
        during the first ``structure.warmup`` samples.

        Parameters
        ----------
        u : numpy.ndarray
            One scaled input sample, ``(n_signals,)``.
        """
        s = self.structure
        self._inputs.append(u)
        if len(self._inputs) > self._max_in + 1:
            del self._inputs[0]
        self._n += 1
        if self._n <= s.warmup:
            return math.nan
        ins = self._inputs
        parts = [ins[-1 - d] for d in s.input_delays]
        if self._fb:
            parts.append(np.array([self._y_past[-f] for f in self._fb]))
        x = np.concatenate(parts)
        for i, (W, b) in enumerate(self._layers[:-1]):
            if self._rec[i]:
                past = self._a_past[i]
                x = np.concatenate([x] + [past[-r] for r in s.layer_delays])
            a = np.tanh(W @ x + b)
            if self._rec[i]:
                past.append(a)
                del past[0]
            x = a
        W, b = self._layers[-1]
        y = float(W[0] @ x + b[0])
        if self._fb:
            self._y_past.append(y)
            del self._y_past[0]
        return y


# -- Jacobians of the closed loop ------------------------------------------------------------------
def open_loop_gradients(w: torch.Tensor, x: torch.Tensor,
                        structure: RecurrentStructure) -> tuple[torch.Tensor, torch.Tensor]:
    r"""Per-sample gradients of a feed-forward pass :math:`\hat y = g(w, x)` (no recurrence).

    Back-propagation for a batch of independent samples :math:`x` (N × n_in), with
    :math:`a^{(0)} = x`, :math:`a^{(l)} = \tanh(W^{(l)} a^{(l-1)} + b^{(l)})` and the linear
    output :math:`\hat y = W^{(L+1)} a^{(L)} + b^{(L+1)}`:

    .. math::

        \delta^{(L+1)} = 1, \qquad
        \delta^{(l)} = \big(W^{(l+1)\top} \delta^{(l+1)}\big) \odot \big(1 - a^{(l)2}\big),

        \frac{\partial \hat y}{\partial W^{(l)}} = \delta^{(l)} a^{(l-1)\top}, \qquad
        \frac{\partial \hat y}{\partial b^{(l)}} = \delta^{(l)}, \qquad
        \frac{\partial \hat y}{\partial x} = W^{(1)\top} \delta^{(1)} .

    Written out rather than ``vmap(grad)`` because it is ~25× faster for these tiny layers;
    the result is checked against ``torch.func`` in the tests.

    Parameters
    ----------
    w : torch.Tensor
        Flat weight vector.
    x : torch.Tensor
        Inputs of the first layer, (N × n_in).
    structure : RecurrentStructure
        The network's sizes and delays.

    Returns
    -------
    dy_dw : Tensor (N, n_weights), in the layout of :func:`unpack_weights`
    dy_dx : Tensor (N, n_in)
    """
    layers = unpack_weights(w, structure)
    acts = [x]
    for W, b in layers[:-1]:
        acts.append(torch.tanh(acts[-1] @ W.T + b))
    n = x.shape[0]
    delta = x.new_ones(n, 1)
    parts: list[torch.Tensor] = []
    for i in range(len(layers) - 1, -1, -1):
        W, _ = layers[i]
        parts.append(delta)                                                    # ∂ŷ/∂b
        parts.append((delta[:, :, None] * acts[i][:, None, :]).reshape(n, -1))  # ∂ŷ/∂W
        delta_in = delta @ W
        if i > 0:
            delta = delta_in * (1.0 - acts[i] ** 2)
    return torch.cat(parts[::-1], dim=1), delta_in


def narx_jacobian(w: torch.Tensor, u: torch.Tensor, structure: RecurrentStructure,
                  initial_output: float) -> tuple[torch.Tensor, torch.Tensor]:
    r"""Closed-loop outputs and their exact Jacobian for output-feedback (NARX) networks.

    With :math:`\hat y_k = g(w, x_k, [\hat y_{k-f}]_{f\in D_y})` the total derivative obeys the
    real-time recurrent learning recursion (forward-mode back-propagation through time)

    .. math:: S_k = \frac{d\hat y_k}{dw} = \frac{\partial g}{\partial w}\Big|_k
              + \sum_{f \in D_y} \frac{\partial g}{\partial \hat y_{k-f}}\Big|_k\, S_{k-f},
              \qquad S_k = 0 \text{ for } k < K

    (the initial feedback value is a constant). The per-sample partial derivatives of the
    open-loop step :math:`g` are independent given the rolled-out :math:`\hat y`, so they come
    from one vectorised pass over all experiments and samples (:func:`open_loop_gradients`);
    only the cheap linear recursion runs step by step. Equals ``jacfwd`` of :func:`rollout` (tested) at a
    fraction of its cost, because the only recurrent state is the scalar output.

    Parameters
    ----------
    w : torch.Tensor
        Flat weight vector.
    u : torch.Tensor
        Scaled inputs, ``(n_experiments, T, n_signals)``.
    structure : RecurrentStructure
        A structure with output feedback only.
    initial_output : float
        Fed-back output before the first estimate (scaled units).

    Returns
    -------
    y : Tensor (n_experiments, n_steps)
    S : Tensor (n_experiments, n_steps, n_weights), :math:`d\hat y/dw`
    """
    if structure.layer_delays and structure.recurrent_layers:
        raise ValueError("narx_jacobian handles output feedback only (no layer recurrence)")
    with torch.no_grad():
        y = rollout(w, u, structure, initial_output)
    K = structure.warmup
    n_exp, n_steps = y.shape
    x_tdl = tapped_delay_inputs(u, structure.input_delays, K)
    fb_delays = structure.feedback_delays
    # Feedback seen at each step: y_{k-f}, or the initial value before the first estimate.
    padded = torch.cat([y.new_full((n_exp, max(fb_delays, default=0)), float(initial_output)), y], dim=1)
    n_pad = max(fb_delays, default=0)
    fb = torch.stack([padded[:, n_pad - f:n_pad - f + n_steps] for f in fb_delays], dim=-1) \
        if fb_delays else y.new_zeros(n_exp, n_steps, 0)
    x = torch.cat([x_tdl, fb], dim=-1).reshape(n_exp * n_steps, -1)
    dg_dw, dg_dx = open_loop_gradients(w, x, structure)
    dg_dw = dg_dw.reshape(n_exp, n_steps, -1)
    dg_dfb = dg_dx[:, structure.n_tdl:].reshape(n_exp, n_steps, len(fb_delays))
    S: list[torch.Tensor] = []
    for j in range(n_steps):
        s = dg_dw[:, j]
        for i, f in enumerate(fb_delays):
            if j - f >= 0:
                s = s + dg_dfb[:, j, i:i + 1] * S[j - f]
        S.append(s)
    return y, torch.stack(S, dim=1)


def experiment_jacobian(w: torch.Tensor, u: torch.Tensor, structure: RecurrentStructure,
                        initial_output: float) -> torch.Tensor:
    r""":math:`d\hat y/dw` of :func:`rollout` for any structure, reverse mode per experiment.

    Experiments are independent, so ``vmap`` over experiments of ``jacrev`` of a
    one-experiment rollout gives the block-diagonal structure for free: ``n_steps`` backward
    passes per experiment instead of ``n_weights`` forward passes over all of them
    (``jacfwd``). Returns ``(n_experiments, n_steps, n_weights)``.

    Parameters
    ----------
    w : torch.Tensor
        Flat weight vector.
    u : torch.Tensor
        Scaled inputs, ``(n_experiments, T, n_signals)``.
    structure : RecurrentStructure
        The network's sizes and delays.
    initial_output : float
        Fed-back output before the first estimate (scaled units).
    """
    def one(w_, u_):
        return rollout(w_, u_[None], structure, initial_output)[0]

    return torch.func.vmap(torch.func.jacrev(one), in_dims=(None, 0))(w, u)


def bptt_jacobian(w: torch.Tensor, u: torch.Tensor, structure: RecurrentStructure,
                  initial_output: float, chunk: int = 16) -> torch.Tensor:
    r""":math:`d\hat y/dw` of :func:`rollout` for any structure by back-propagation through time.

    For every output :math:`\hat y_m` the adjoints run backwards from step :math:`m`; all
    :math:`m` of all experiments are carried at once (an extra batch axis), so the sequential
    loop has ``n_steps`` iterations of small tensor operations. With :math:`\lambda` the
    adjoint of a layer's output and :math:`\delta = \lambda \odot (1 - a^2)`:

    .. math::

        \lambda^{(L)}_k &= W^{(L+1)\top} \bar y_k
                          + \textstyle\sum_{r\in D_a} [W^{(L)\top}_{rec,r}\,\delta^{(L)}_{k+r}],
        \qquad \bar y_k = [k = m] + \textstyle\sum_{f\in D_y} W^{(1)\top}_{fb,f}\,\delta^{(1)}_{k+f}

        \lambda^{(l-1)}_k &= W^{(l)\top}_{ff}\,\delta^{(l)}_k
                            + \textstyle\sum_{r\in D_a} W^{(l-1)\top}_{rec,r}\,\delta^{(l-1)}_{k+r}

        \frac{\partial \hat y_m}{\partial W^{(l)}} &= \textstyle\sum_k \delta^{(l)}_k\,
            \mathrm{in}^{(l)\top}_k, \qquad
        \frac{\partial \hat y_m}{\partial b^{(l)}} = \textstyle\sum_k \delta^{(l)}_k

    (recurrent terms only for the recurrent layers, feedback only into the first layer).
    Experiments are processed ``chunk`` at a time to bound memory. Equals ``jacfwd`` of
    :func:`rollout` (tested) at a small fraction of its cost for layer-recurrent nets.

    Returns ``(n_experiments, n_steps, n_weights)``.

    Parameters
    ----------
    w : torch.Tensor
        Flat weight vector.
    u : torch.Tensor
        Scaled inputs, ``(n_experiments, T, n_signals)``.
    structure : RecurrentStructure
        The network's sizes and delays.
    initial_output : float
        Fed-back output before the first estimate (scaled units).
    chunk : int
        Outputs carried at once (bounds memory).
    """
    if u.shape[0] > chunk:
        return torch.cat([bptt_jacobian(w, u[i:i + chunk], structure, initial_output, chunk)
                          for i in range(0, u.shape[0], chunk)])
    w = w.detach()
    K = structure.warmup
    E, T = u.shape[0], u.shape[1]
    n = T - K
    layers = unpack_weights(w, structure)
    L = len(structure.hidden)
    rec = [i in structure.recurrent_layers for i in range(L)]
    ld, fbd = structure.layer_delays, structure.feedback_delays
    n_fb = len(fbd)
    # -- forward, keeping every layer's full input vector and output
    x_tdl = tapped_delay_inputs(u, structure.input_delays, K)
    ins: list[list[torch.Tensor]] = [[] for _ in range(L + 1)]
    acts: list[list[torch.Tensor]] = [[] for _ in range(L)]
    ys: list[torch.Tensor] = []
    with torch.no_grad():
        for k in range(n):
            parts = [x_tdl[:, k]]
            if n_fb:
                parts += [ys[k - f] if k - f >= 0 else u.new_full((E, 1), float(initial_output)) for f in fbd]
            a = torch.cat(parts, dim=1)
            for i in range(L):
                if rec[i]:
                    a = torch.cat([a] + [acts[i][k - r] if k - r >= 0 else u.new_zeros(E, structure.hidden[i])
                                         for r in ld], dim=1)
                ins[i].append(a)
                W, b = layers[i]
                a = torch.tanh(a @ W.T + b)
                acts[i].append(a)
            ins[L].append(a)
            W, b = layers[L]
            ys.append(a @ W.T + b)
        # -- backward, batched over the output index m; only m >= k is non-zero at step k
        Yb = torch.zeros(E, n, n, dtype=u.dtype)                  # ȳ[e, m, k]
        Yb[:, torch.arange(n), torch.arange(n)] = 1.0
        lam = [torch.zeros(n, E, n, h, dtype=u.dtype) for h in structure.hidden]  # λ[k, e, m, :]
        D = [torch.zeros(E, n, h, n, dtype=u.dtype) for h in structure.hidden]    # δ[e, m, :, k]
        W_out = layers[L][0]
        for k in range(n - 1, -1, -1):
            g = Yb[:, k:, k, None] * W_out[0] + lam[L - 1][k, :, k:]
            for i in range(L - 1, -1, -1):
                delta = g * (1.0 - acts[i][k] ** 2)[:, None, :]
                D[i][:, k:, :, k] = delta
                g_in = delta @ layers[i][0]                                  # (E, M', n_in_i)
                n_ff = structure.n_tdl + n_fb if i == 0 else structure.hidden[i - 1]
                if rec[i]:
                    h = structure.hidden[i]
                    for j, r in enumerate(ld):
                        if k - r >= 0:
                            lam[i][k - r, :, k:] += g_in[:, :, n_ff + j * h:n_ff + (j + 1) * h]
                if i == 0:
                    for j, f in enumerate(fbd):
                        if k - f >= 0:
                            Yb[:, k:, k - f] += g_in[:, :, structure.n_tdl + j]
                else:
                    g = g_in[:, :, :n_ff] + lam[i - 1][k, :, k:]
        # -- weight gradients: sums over time of adjoint ⊗ layer input (one batched matmul each)
        blocks = []
        for i in range(L):
            X = torch.stack(ins[i], dim=1)                                     # (E, n, n_in)
            h = structure.hidden[i]
            dW = torch.bmm(D[i].reshape(E, n * h, n), X)                       # (E, M·H, n_in)
            blocks += [dW.reshape(E, n, -1), D[i].sum(dim=3)]
        X = torch.stack(ins[L], dim=1)
        blocks += [torch.bmm(Yb, X), Yb.sum(dim=2, keepdim=True)]
    return torch.cat(blocks, dim=2)


# -- estimators ----------------------------------------------------------------------------------
_WARMING = StepResult(math.nan, Status.WARMING_UP)


def _initial_payload_option() -> dict:
    return {"initial_payload": Option(str, "mean", "fed-back payload (kg) before the first estimate: "
                                                   "'mean' = mean payload of the training experiments")}


class RecurrentNetwork(NeuralEstimator):
    """Base of ``net2`` and ``lrn``: a :class:`RecurrentStructure` trained in closed loop.

    After :meth:`fit`, ``initial_payload`` (kg) is the fed-back value before the first estimate
    and ``structure`` describes the network.

    Parameters
    ----------
    machine : Machine, str or None
        Optional: a network needs none (its plausibility limits then come from the data's machine).
    **options
        Estimator options, see the class attribute ``OPTIONS``.
    """

    def __init__(self, machine=None, **options: Any) -> None:
        super().__init__(machine=machine, **options)
        o = self.options
        raw = str(o["initial_payload"]).strip().lower()
        if raw == "mean":
            self._initial_option: float | None = None
        else:
            try:
                self._initial_option = float(raw)
            except ValueError:
                raise EstimatorError(f"{self.name}: --initial-payload must be 'mean' or a mass in kg, "
                                     f"got {o['initial_payload']!r}") from None
            if not math.isfinite(self._initial_option):
                raise EstimatorError(f"{self.name}: --initial-payload must be finite")
        self.initial_payload: float = self._initial_option if self._initial_option is not None else 0.0
        self.structure = self._structure()
        self._stepper: RecurrentStepper | None = None

    # -- structure -------------------------------------------------------------------------
    def _structure(self) -> RecurrentStructure:
        raise NotImplementedError

    def _inputs_changed(self) -> None:
        self.structure = self._structure()

    def _n_weights(self) -> int:
        return self.structure.n_weights

    def _init_weights(self, generator: torch.Generator) -> torch.Tensor:
        return init_weights(self.structure, generator)

    @property
    def _initial_scaled(self) -> float:
        return float(self.output_scaler.transform(np.array([[self.initial_payload]]))[0, 0])

    # -- training --------------------------------------------------------------------------
    def _fit(self, dataset) -> None:
        train, _ = self.split_experiments(dataset)
        self.initial_payload = (self._initial_option if self._initial_option is not None
                                else float(np.mean(train.payloads)))
        super()._fit(dataset)

    def _groups(self, inputs, targets):
        """Experiments grouped by length (so each group is one tensor); too-short ones dropped."""
        K = self.structure.warmup
        by_length: dict[int, list[int]] = {}
        for i, x in enumerate(inputs):
            if len(x) > K:
                by_length.setdefault(len(x), []).append(i)
        if not by_length:
            raise EstimatorError(f"{self.name}: every experiment is shorter than the delay lines "
                                 f"({K + 1} samples); nothing to train on")
        groups = []
        for length, idx in by_length.items():
            u = torch.as_tensor(np.stack([inputs[i] for i in idx]), dtype=torch.float64)
            t = torch.as_tensor(np.stack([targets[i][K:] for i in idx]), dtype=torch.float64)
            groups.append((u, t))
        return groups

    def _training_problem(self, inputs, targets):
        structure = self.structure
        y0 = self._initial_scaled
        groups = self._groups(inputs, targets)

        def residuals(w):
            return torch.cat([(t - rollout(w, u, structure, y0)).reshape(-1) for u, t in groups])

        def experiments_jacobian(u):
            def block(w, out=None):
                if structure.recurrent_layers and structure.layer_delays:
                    S = bptt_jacobian(w, u, structure, y0)
                else:
                    S = narx_jacobian(w, u, structure, y0)[1]
                return torch.neg(S.reshape(-1, S.shape[-1]), out=out)  # e = t − ŷ
            return block

        # experiments are independent: trainbr computes their Jacobian in blocks on its threads
        blocks, rows, start = [], [], 0
        for u, t in groups:
            n_steps = t.shape[1]
            for part in torch.tensor_split(u, min(len(u), max(1, round(len(u) * n_steps / GRAM_BLOCK_ROWS)))):
                blocks.append(experiments_jacobian(part))
                rows.append(slice(start, start + len(part) * n_steps))
                start += len(part) * n_steps
        return residuals, BlockJacobian(blocks, rows)

    # -- streaming -------------------------------------------------------------------------
    def _use_weights(self, w: np.ndarray) -> None:
        self._stepper = RecurrentStepper(w, self.structure, self._initial_scaled)

    def _reset_network(self) -> None:
        if self._stepper is not None:
            self._stepper.reset()

    def _network_step(self, time: float, values: np.ndarray) -> StepResult:
        y = self._stepper.step(self._scale_input(values))
        if y != y:  # NaN: delay lines still filling
            return _WARMING
        return StepResult(y / self.output_scaler.gain[0] + self.output_scaler.center[0], Status.OK)

    def predict_experiments(self, inputs: Sequence[np.ndarray]) -> list[np.ndarray]:
        """Vectorised closed-loop estimates (kg) of unscaled per-experiment ``(T_i, k)`` input
        arrays (``input_names`` columns); NaN for the warm-up samples. Equals streaming.

        Parameters
        ----------
        inputs : Sequence[numpy.ndarray]
            Per experiment, the raw ``(T_i, k)`` inputs (SI units).
        """
        if self.decimation != 1:
            raise EstimatorError(f"{self.name}: predict_experiments runs at the data's rate only "
                                 "(--decimation 1); use estimate()")
        K = self.structure.warmup
        w = torch.as_tensor(self.weights)
        out = []
        for x in inputs:
            est = np.full(len(x), np.nan)
            if len(x) > K:
                u = torch.as_tensor(self.input_scaler.transform(np.asarray(x, float)))[None]
                with torch.no_grad():
                    y = rollout(w, u, self.structure, self._initial_scaled)[0].numpy()
                est[K:] = self.output_scaler.inverse(y[:, None])[:, 0]
            out.append(est)
        return out

    # -- persistence -----------------------------------------------------------------------
    def _config(self) -> dict:
        return {**super()._config(), "initial_payload": self.initial_payload,
                "structure": self.structure.to_dict()}

    def _restore(self, config: dict, arrays) -> None:
        self.initial_payload = float(config["initial_payload"])
        super()._restore(config, arrays)


@register
class Net2(RecurrentNetwork):
    """Thesis Net₂: closed-loop NARX ``narxnet(0:5, 1, [10 10 10])`` on the six thesis signals."""

    name = "net2"
    OPTIONS = neural_options(
        hidden="10,10,10", delays="0:5",
        feedback_delays=Option(
            str, "1", "delays of the fed-back estimate, e.g. '1' or '1:2'"),
        **_initial_payload_option())

    def _structure(self) -> RecurrentStructure:
        return RecurrentStructure(
            n_signals=self.n_inputs, hidden=tuple(self.hidden_sizes), input_delays=tuple(self.delay_list),
            feedback_delays=parse_delay_option(self.options["feedback_delays"], "feedback_delays", 1))


@register
class LayerRecurrentNetwork(RecurrentNetwork):
    """``layrecnet(1:2, [10 10 10])``: every hidden layer fed back with delays 1 and 2."""

    name = "lrn"
    OPTIONS = neural_options(
        hidden="10,10,10", delays="0",
        layer_delays=Option(
            str, "1:2", "delays of the hidden layers' own outputs fed back to them"),
        recurrent_layers=Option(
            str, "all", "hidden layers with feedback: 'all' (MATLAB layrecnet) or 'first'",
            ("all", "first")),
        **_initial_payload_option())

    def _structure(self) -> RecurrentStructure:
        layers = tuple(range(len(self.hidden_sizes))) if self.options["recurrent_layers"] == "all" else (0,)
        return RecurrentStructure(
            n_signals=self.n_inputs, hidden=tuple(self.hidden_sizes), input_delays=tuple(self.delay_list),
            layer_delays=parse_delay_option(self.options["layer_delays"], "layer_delays", 1),
            recurrent_layers=layers)


__all__ = ["RecurrentStructure", "RecurrentStepper", "RecurrentNetwork", "Net2", "LayerRecurrentNetwork",
           "parse_delay_option", "unpack_weights", "init_weights", "tapped_delay_inputs", "rollout",
           "open_loop_gradients", "narx_jacobian", "bptt_jacobian", "experiment_jacobian"]
