r"""Feed-forward data-driven virtual sensors: ``net1``, ``ffnn`` and ``dtdnn``.

``net1`` (thesis Net₁, MATLAB ``timedelaynet(0:5, [10 10 10])``)
    A focused time-delay network: the input vector at time :math:`t` is the tapped delay line
    :math:`u(t) = [x(t); x(t-1); \dots; x(t-5)]` of the six thesis signals (boom and dipper
    angle, rate and torque), fed to an MLP with three tanh layers of 10 neurons and a linear
    output,

    .. math:: \hat m(t) = W_4 \tanh(W_3 \tanh(W_2 \tanh(W_1 u(t) + b_1) + b_2) + b_3) + b_4 .

``ffnn`` (MATLAB ``feedforwardnet``)
    The same MLP on the current sample only (delays ``0``).

``dtdnn`` (MATLAB ``distdelaynet``)
    A distributed time-delay network: EVERY layer sees the last four values (delays ``0:3``)
    of its input,

    .. math:: a_l(t) = f_l\big(\textstyle\sum_{d} W_{l,d}\, a_{l-1}(t-d) + b_l\big),
              \qquad a_0 = x .

    As MATLAB's ``preparets``, the input delay line is filled with the first ``max(delays)``
    samples (no estimate there) and the hidden layers' delay states start at zero.

All three output the payload in kg after undoing the output scaling; the streaming
:meth:`step` runs the network in numpy with pre-extracted matrices.

Training budget: ``--epochs`` defaults to 700, not MATLAB's 1000 (the thesis even set 10¹⁰ and
let μ saturate). A trainbr epoch of net1 on 100 experiments (9600 targets, 601 weights) is
dominated by the normal equations :math:`J^\top J`; what an epoch and the 700 cost, part by
part, is measured in ``docs/findings/networks.md`` ("Training time"). 700 epochs reach RMS
errors within 1.2× of the 6-sample Cramér–Rao bound on NMPC data (``benchmarks/bench_dvs.py``).
Pass ``--epochs 1000`` for MATLAB's default.

On the machine sensor set (15 signals at 100 Hz) one epoch is far dearer: 150 experiments give
~2·10⁵ targets and the 15 signals × 6 delays make ~1100 weights, so :math:`J^\top J` alone is
~2·10¹¹ flops. ``--decimation 5`` runs the network at the thesis nets' 20 Hz on block means of 5
samples: five times fewer targets (and less noise per input) for the same span of motion
(``benchmarks/bench_machine_nets.py``).
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np
import torch

from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.base import Status, StepResult, register
from excavator_payload.estimators.dvs.mlp import (
    mlp_forward,
    mlp_forward_numpy,
    mlp_layers,
    mlp_output_jacobian,
    mlp_sizes,
    nguyen_widrow_init,
)
from excavator_payload.estimators.dvs.neural import NeuralEstimator
from excavator_payload.estimators.dvs.options import neural_options
from excavator_payload.estimators.dvs.trainbr import BlockJacobian, row_blocks
from excavator_payload.estimators.dvs.windows import DelayLine, delay_windows

_WARMING = StepResult(math.nan, Status.WARMING_UP)


class TimeDelayNetwork(NeuralEstimator):
    """Focused time-delay network (delays on the inputs only); base of ``net1`` and ``ffnn``."""

    def _layer_sizes(self) -> list[int]:
        return mlp_sizes(self.n_inputs * len(self.delay_list), self.hidden_sizes)

    def windows(self, inputs: Sequence[np.ndarray]) -> np.ndarray:
        """Stacked delay-line rows of all experiments that get an estimate (``preparets``).

        Parameters
        ----------
        inputs : Sequence[numpy.ndarray]
            Per experiment, the ``(T_i, n_inputs)`` inputs.

        Returns
        -------
        numpy.ndarray
            One delay-line row per estimated sample.
        """
        d = max(self.delay_list)
        rows = [delay_windows(x, self.delay_list)[d:] for x in inputs]
        out = np.concatenate(rows) if rows else np.empty((0, self._layer_sizes()[0]))
        if len(out) == 0:
            raise EstimatorError(f"{self.name}: experiments are shorter than the delay line "
                                 f"({d + 1} samples); nothing to train on")
        return out

    def _training_problem(self, inputs, targets):
        d = max(self.delay_list)
        sizes = self._layer_sizes()
        X = torch.as_tensor(self.windows(inputs), dtype=torch.float64)
        t = torch.as_tensor(np.concatenate([y[d:] for y in targets]), dtype=torch.float64)

        def residuals(w):
            return t - mlp_forward(w, X, sizes)[:, 0]

        def rows_jacobian(rows):
            # ∂e_i/∂w = −∂y(x_i)/∂w (backpropagation per sample, equal to torch.func's per-sample
            # gradients, tested; several times faster), negated inside: no second (N, P) array;
            # rows are independent, so trainbr computes them block by block on its threads
            return lambda w, out=None: mlp_output_jacobian(w, X[rows], sizes, negate=True, out=out)

        blocks = row_blocks(len(X))
        return residuals, BlockJacobian([rows_jacobian(rows) for rows in blocks], blocks)

    def _use_weights(self, w: np.ndarray) -> None:
        self._layers = [(np.ascontiguousarray(W), np.ascontiguousarray(b))
                        for W, b in mlp_layers(np.asarray(w, dtype=np.float64), self._layer_sizes())]
        # Streaming form, same function: the input scaling is folded into the first layer
        # (W₁·((x − c)∘g) + b₁ = (W₁ diag g) x + (b₁ − W₁ (c∘g))) and the output scaling into
        # the last; the first layer reads ALL signals of the sensor set over the last L = max(delay)+1
        # samples, oldest first, straight from a doubled ring buffer (zero columns for unused
        # signals and delays). That leaves two slice copies and the matrix products per sample.
        n_sig = len(self.sensor_set.signals)
        L = max(self.delay_list) + 1
        W1, b1 = self._layers[0]
        gain, center = self.input_scaler.gain, self.input_scaler.center
        W1_stream = np.zeros((W1.shape[0], L * n_sig))
        b1_stream = b1.copy()
        for j, d in enumerate(self.delay_list):
            for c, signal in enumerate(self.input_index):
                column = W1[:, j * self.n_inputs + c]
                W1_stream[:, (L - 1 - d) * n_sig + signal] = column * gain[c]
                b1_stream -= column * gain[c] * center[c]
        WL, bL = self._layers[-1]
        g_out, c_out = self.output_scaler.gain[0], self.output_scaler.center[0]
        self._stream_layers = [(W1_stream, b1_stream), *self._layers[1:-1], (WL[0] / g_out, bL[0] / g_out + c_out)]
        self._stream_length = L
        self._n_signals = n_sig
        self._buffer = np.zeros(2 * L * n_sig)
        self._reset()

    def _reset_network(self) -> None:
        if self.weights is not None:
            self._newest = -1  # ring position of the newest sample
            self._count = 0

    def _network_step(self, time: float, values: np.ndarray) -> StepResult:
        L, n_sig = self._stream_length, self._n_signals
        p = self._newest = (self._newest + 1) % L
        # each sample is written twice, L blocks apart, so the last L samples are always the
        # contiguous slice [p+1, p+L] (oldest first)
        self._buffer[p * n_sig:(p + 1) * n_sig] = values
        self._buffer[(p + L) * n_sig:(p + L + 1) * n_sig] = values
        self._count += 1
        if self._count < L:
            return _WARMING
        a = self._buffer[(p + 1) * n_sig:(p + 1 + L) * n_sig]
        layers = self._stream_layers
        for W, b in layers[:-1]:
            a = np.tanh(W @ a + b)
        w_out, b_out = layers[-1]
        return StepResult(float(w_out @ a + b_out), Status.OK)

    def predict_windows(self, inputs: Sequence[np.ndarray]) -> list[np.ndarray]:
        """Batch outputs (kg) per experiment from RAW ``(T_i, n_inputs)`` arrays; NaN where no
        estimate (used to check that streaming equals batch).

        Parameters
        ----------
        inputs : Sequence[numpy.ndarray]
            Per experiment, the raw ``(T_i, n_inputs)`` inputs (``input_names`` columns, SI units).
        """
        if self.decimation != 1:
            raise EstimatorError(f"{self.name}: predict_windows runs at the data's rate only "
                                 "(--decimation 1); use estimate()")
        out = []
        for x in inputs:
            win = delay_windows(self.input_scaler.transform(np.asarray(x, float)), self.delay_list)
            y = np.full(len(x), np.nan)
            ok = ~np.isnan(win).any(axis=1)
            if ok.any():
                y[ok] = mlp_forward_numpy(self._layers, win[ok])[:, 0]
            out.append(self.output_scaler.inverse(y[:, None])[:, 0])
        return out


@register
class Net1(TimeDelayNetwork):
    """Thesis Net₁: ``timedelaynet(0:5, [10 10 10])`` on angles, rates and torques, trainbr."""

    name = "net1"
    OPTIONS = neural_options(hidden="10,10,10", delays="0:5")


@register
class FeedForwardNetwork(TimeDelayNetwork):
    """MATLAB ``feedforwardnet``: the MLP on the current sample only."""

    name = "ffnn"
    OPTIONS = neural_options(hidden="10,10,10", delays="0")


@register
class DistributedDelayNetwork(NeuralEstimator):
    """MATLAB ``distdelaynet``: the same delays on every layer's input."""

    name = "dtdnn"
    OPTIONS = neural_options(hidden="10,10,10", delays="0:3")

    def _layer_shapes(self) -> list[tuple[int, int]]:
        n_delays = len(self.delay_list)
        sizes = [self.n_inputs, *self.hidden_sizes, 1]
        return [(n_next, n_prev * n_delays) for n_prev, n_next in zip(sizes[:-1], sizes[1:])]

    def _n_weights(self) -> int:
        return sum(r * (c + 1) for r, c in self._layer_shapes())

    def _split(self, w):
        layers, k = [], 0
        for rows, cols in self._layer_shapes():
            W = w[k:k + rows * cols].reshape(rows, cols)
            k += rows * cols
            layers.append((W, w[k:k + rows]))
            k += rows
        return layers

    def _init_weights(self, generator: torch.Generator) -> torch.Tensor:
        # Nguyen–Widrow per layer on its tapped-delay input (every tap is a separate input)
        return torch.cat([nguyen_widrow_init([cols, rows], generator) for rows, cols in self._layer_shapes()])

    def _forward(self, w: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        r"""Outputs ``(n_exp, T - max(d))`` for scaled inputs ``x`` ``(n_exp, T, k)``.

        Layer 1 sees true input windows (times :math:`t \ge d_{max}`); deeper layers see their
        input's past padded with zeros before :math:`d_{max}` (zero layer delay states).
        """
        delays = self.delay_list
        dmax = max(delays)
        T = x.shape[1]
        n_out = T - dmax
        layers = self._split(w)
        a = torch.cat([x[:, dmax - d:T - d, :] for d in delays], dim=-1)
        for i, (W, b) in enumerate(layers):
            if i > 0:
                padded = torch.cat([torch.zeros(a.shape[0], dmax, a.shape[2], dtype=a.dtype), a], dim=1)
                a = torch.cat([padded[:, dmax - d:dmax - d + n_out, :] for d in delays], dim=-1)
            z = a @ W.T + b
            a = torch.tanh(z) if i < len(layers) - 1 else z
        return a[..., 0]

    def _groups(self, inputs, targets=None):
        """Experiments grouped by length (so each group stacks into one tensor)."""
        dmax = max(self.delay_list)
        by_len: dict[int, list[int]] = {}
        for i, x in enumerate(inputs):
            if len(x) > dmax:
                by_len.setdefault(len(x), []).append(i)
        if not by_len:
            raise EstimatorError(f"{self.name}: experiments are shorter than the delay line "
                                 f"({dmax + 1} samples); nothing to train on")
        groups = []
        for _, idx in sorted(by_len.items()):
            X = torch.as_tensor(np.stack([inputs[i] for i in idx]), dtype=torch.float64)
            t = None if targets is None else torch.as_tensor(
                np.stack([targets[i][dmax:] for i in idx]), dtype=torch.float64)
            groups.append((X, t))
        return groups

    def _training_problem(self, inputs, targets):
        groups = self._groups(inputs, targets)

        def residuals(w):
            return torch.cat([(t - self._forward(w, X)).reshape(-1) for X, t in groups])

        def jacobian(w):
            # ∂e/∂w = −∂y/∂w, backpropagated through the delay structure (equal to torch.func's
            # forward-mode Jacobian, tested)
            return -torch.cat([self._output_jacobian(w, X) for X, _ in groups])

        return residuals, jacobian

    def _output_jacobian(self, w: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        r"""``∂y/∂w`` for every output of a group ``x`` ``(E, T, k)``: ``(E·(T − d_max), P)``.

        The output at :math:`t` depends on layer :math:`l`'s net input at the lags
        :math:`r = 0 … R_l` (:math:`R_L = 0`, :math:`R_{l-1} = R_l + d_{max}`). With
        :math:`\delta_l[t, r] = \partial y(t)/\partial z_l(t-r)`, starting from
        :math:`\delta_L[t, 0] = 1`,

        .. math:: \delta_{l-1}[t, r + d] \mathrel{+}= W_{l,d}^\top \delta_l[t, r]
                  \odot (1 - a_{l-1}(t-r-d)^2),

        zero where :math:`t - r < 0` (the zero initial layer states), and
        :math:`\partial y(t)/\partial W_l = \sum_r \delta_l[t,r]\, u_l(t-r)^\top`,
        :math:`\partial y(t)/\partial b_l = \sum_r \delta_l[t,r]` with :math:`u_l` the
        layer's tapped-delay input.
        """
        delays = self.delay_list
        dmax = max(delays)
        E, T, _ = x.shape
        n = T - dmax
        layers = self._split(w)
        n_layers = len(layers)
        # forward pass, keeping every layer's tapped input u_l (E, n, ·) and output a_l
        u = [torch.cat([x[:, dmax - d:T - d, :] for d in delays], dim=-1)]
        acts = []
        for i, (W, b) in enumerate(layers):
            if i > 0:
                padded = torch.cat([torch.zeros(E, dmax, acts[-1].shape[2], dtype=x.dtype), acts[-1]], dim=1)
                u.append(torch.cat([padded[:, dmax - d:dmax - d + n, :] for d in delays], dim=-1))
            z = u[i] @ W.T + b
            acts.append(torch.tanh(z) if i < n_layers - 1 else z)

        def lagged(values, R):  # values (E, n, m) -> (E, n, R+1, m) with values[t - r], 0 before t=0
            padded = torch.cat([torch.zeros(E, R, values.shape[2], dtype=x.dtype), values], dim=1)
            return torch.stack([padded[:, R - r:R - r + n, :] for r in range(R + 1)], dim=2)

        time_index = torch.arange(n)[:, None]
        blocks = []
        delta = torch.ones(E, n, 1, 1, dtype=x.dtype)  # δ_L[t, r=0], output size 1
        R = 0
        for i in range(n_layers - 1, -1, -1):
            W, _ = layers[i]
            u_lag = lagged(u[i], R)  # (E, n, R+1, width)
            blocks.append(delta.sum(dim=2).reshape(E * n, -1))  # ∂y/∂b_i
            blocks.append(torch.einsum("enrh,enrk->enhk", delta, u_lag).reshape(E * n, -1))  # ∂y/∂W_i
            if i == 0:
                break
            h_prev = acts[i - 1].shape[2]
            R_new = R + dmax
            back = torch.zeros(E, n, R_new + 1, h_prev, dtype=x.dtype)
            for j, d in enumerate(delays):
                back[:, :, d:d + R + 1, :] += delta @ W[:, j * h_prev:(j + 1) * h_prev]
            valid = (time_index - torch.arange(R_new + 1)[None, :] >= 0).to(x.dtype)  # (n, R_new+1)
            delta = back * (1.0 - lagged(acts[i - 1], R_new) ** 2) * valid[None, :, :, None]
            R = R_new
        # blocks were collected last layer first as (b, W); weights are stored (W, b) per layer
        ordered = []
        for k in range(n_layers - 1, -1, -1):
            ordered += [blocks[2 * k + 1], blocks[2 * k]]
        return torch.cat(ordered, dim=1)

    def _use_weights(self, w: np.ndarray) -> None:
        self._layers = [(np.ascontiguousarray(W), np.ascontiguousarray(b))
                        for W, b in self._split(np.asarray(w, dtype=np.float64))]
        sizes = [self.n_inputs, *self.hidden_sizes]
        self._lines = [DelayLine(n, self.delay_list, zero_history=(i > 0)) for i, n in enumerate(sizes)]

    def _reset_network(self) -> None:
        if self.weights is not None:
            for line in self._lines:
                line.reset()

    def _network_step(self, time: float, values: np.ndarray) -> StepResult:
        window = self._lines[0].push(self._scale_input(values))
        if window is None:
            return _WARMING
        *hidden, (W_out, b_out) = self._layers
        for i, (W, b) in enumerate(hidden):
            window = self._lines[i + 1].push(np.tanh(W @ window + b))  # the next layer's delay line
        return StepResult(self._unscale_output((W_out @ window + b_out)[0]), Status.OK)

    def predict_windows(self, inputs: Sequence[np.ndarray]) -> list[np.ndarray]:
        """Batch outputs (kg) per experiment from RAW inputs, NaN where no estimate.

        Parameters
        ----------
        inputs : Sequence[numpy.ndarray]
            Per experiment, the raw ``(T_i, n_inputs)`` inputs (``input_names`` columns, SI units).
        """
        dmax = max(self.delay_list)
        w = torch.as_tensor(self.weights)
        out = []
        for x in inputs:
            y = np.full(len(x), np.nan)
            if len(x) > dmax:
                xs = torch.as_tensor(self.input_scaler.transform(np.asarray(x, float))[None])
                with torch.no_grad():
                    y[dmax:] = self._forward(w, xs)[0].numpy()
            out.append(self.output_scaler.inverse(y[:, None])[:, 0])
        return out


__all__ = ["TimeDelayNetwork", "Net1", "FeedForwardNetwork", "DistributedDelayNetwork"]
