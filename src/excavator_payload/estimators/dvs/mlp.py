r"""The multilayer perceptron's algebra: layer sizes, the flat weight vector, Nguyen–Widrow
initial weights, the forward pass (torch and numpy) and the closed-form output Jacobian.

Conventions (MATLAB's, as the thesis used them, appendix A.3): hidden layers use
:math:`\tanh` (``tansig``), the output layer is linear (``purelin``). Weights travel as ONE
flat float64 vector; an MLP with layer sizes :math:`[n_0, n_1, \dots, n_L]` stores, layer
after layer, :math:`W_l` (:math:`n_l\times n_{l-1}`, row-major) then :math:`b_l`.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np
import torch

from excavator_payload.errors import EstimatorError


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


__all__ = ["mlp_sizes", "n_weights", "mlp_layers", "nguyen_widrow_init", "mlp_forward",
           "mlp_output_jacobian", "mlp_forward_numpy"]
