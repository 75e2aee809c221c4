r"""Levenberg–Marquardt training with Bayesian regularisation (MATLAB ``trainbr``), and Adam.

The thesis trains its networks with MATLAB's ``trainbr`` (appendix A.3), which implements
MacKay's Bayesian regularisation in the Gauss–Newton approximation of Foresee & Hagan (1997).

Model
-----
With residuals :math:`e = t - y(w)` (targets minus outputs, in scaled units) over :math:`N`
targets and :math:`P` weights, the cost is

.. math:: F(w) = \beta E_D + \alpha E_W, \qquad E_D = e^\top e, \qquad E_W = w^\top w ,

:math:`\beta` the precision of the data, :math:`\alpha` that of the Gaussian prior on the
weights. With :math:`J = \partial e / \partial w` (:math:`N\times P`) the Gauss–Newton Hessian
of :math:`F/2` is :math:`\beta H + \alpha I`, :math:`H = J^\top J`, and its gradient
:math:`g = \beta J^\top e + \alpha w`.

One epoch
---------
1. **Normal equations** (most of the work, :math:`N P^2` flops): one Gram matrix

   .. math:: [J\;e]^\top [J\;e] = \begin{bmatrix} H & J^\top e \\ e^\top J & e^\top e
             \end{bmatrix}, \qquad H = J^\top J ,

   from :data:`GRAM_TILES` × :data:`GRAM_TILES` column tiles (symmetric rank-k updates, BLAS
   ``syrk``, on the diagonal, general products beside them), each a task for the job's
   threads. A :class:`BlockJacobian` fills :math:`J` in row blocks (:func:`row_blocks`), also
   as tasks, into one array kept for the whole training. Neither split depends on the thread
   count: the same bits for any number of threads.
2. **Levenberg–Marquardt step**, tried with growing damping :math:`\mu` until :math:`F`
   decreases (:func:`lm_step`):

   .. math:: (\beta H + (\mu + \alpha) I)\,\Delta w = -g, \qquad
             \beta H + (\mu + \alpha) I = R^\top R \;(\text{Cholesky}),\qquad
             \Delta w = -R^{-1} R^{-\top} g ,

   :math:`\mu \leftarrow \mu\,\mu_{dec}` on success, :math:`\mu \leftarrow \mu\,\mu_{inc}` on
   failure (a matrix that is not numerically positive definite is a failed trial too), up
   to :math:`\mu_{max}`. One Cholesky factorisation, :math:`P^3/3` flops, per trial. Nearly
   every epoch takes two trials (:math:`\mu\,\mu_{dec}` fails, :math:`\mu` succeeds), so
   with more than one thread the next trials of the sequence run side by side, one per
   thread, and the first that lowers :math:`F` wins, as one after the other.
3. **Re-estimation** of the hyper-parameters with the effective number of parameters
   :math:`\gamma`, at the epoch's :math:`H` and the :math:`\alpha, \beta` the step used
   (:func:`effective_parameters`), once per accepted step:

   .. math:: \gamma = P - \alpha\,\mathrm{tr}\big((\beta H + \alpha I)^{-1}\big),\qquad
             \alpha \leftarrow \frac{\gamma}{2 E_W}, \qquad
             \beta \leftarrow \frac{N - \gamma}{2 E_D} ,

   the trace from one more Cholesky factor: with :math:`\beta H + \alpha I = R^\top R`,
   :math:`(\beta H + \alpha I)^{-1} = R^{-1}R^{-\top}` and
   :math:`\mathrm{tr}(R^{-1}R^{-\top}) = \|R^{-1}\|_F^2`, the sum of the squares of the
   triangular inverse (LAPACK ``potrf`` then ``trtri``, :math:`2P^3/3` flops). This is
   MATLAB's own formula (``gamk = numParameters - alph*trace(inv(beta*jj + ii*alph))``), and
   equals :math:`\sum_i \beta s_i/(\beta s_i + \alpha)` over the eigenvalues :math:`s_i` of
   :math:`H`. With more than one thread it runs beside the next epoch's Jacobian blocks,
   which do not need it (its log row is written when it is known).

Training starts as MATLAB does, with :math:`\alpha = 0, \beta = 1` (plain Levenberg–Marquardt
for the first step, :math:`\gamma = P`), and stops after ``epochs`` epochs, when the gradient
norm :math:`\|\nabla F\| = 2\|g\|` falls below ``min_grad``, or when :math:`\mu` exceeds
:math:`\mu_{max}`.

Threads
-------
A run uses the cores its job is given (:func:`excavator_payload.execution.job_threads`, or
``threads``), as its own pool of workers over the blocks of step 1, the trials of step 2 and
the trace of step 3; inside, torch and every BLAS run single-threaded
(:func:`~excavator_payload.execution.numeric_threads`). Coarse blocks, taken by whichever worker is free, degrade gracefully when
another job holds a core; the libraries' own threads did not: a threaded eigensolver waits for
every thread many times per call, and took 35× longer on a loaded 2-core machine. Until this
release an epoch took an eigen-decomposition of :math:`H` (:math:`\approx 9P^3` flops), which made
every trial and the trace cheap but cost as much as the normal equations.

References
----------
D. J. C. MacKay, "Bayesian interpolation", Neural Computation 4(3), 1992.
F. D. Foresee, M. T. Hagan, "Gauss–Newton approximation to Bayesian learning", ICNN 1997.
M. T. Hagan, M. B. Menhaj, "Training feedforward networks with the Marquardt algorithm",
IEEE Trans. Neural Networks 5(6), 1994.
"""

from __future__ import annotations

import math
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd
import torch
from scipy.linalg import lapack as _lapack
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

Residuals = Callable[[torch.Tensor], torch.Tensor]
JacobianFn = Callable[[torch.Tensor], torch.Tensor]

#: Columns of :meth:`TrainingLog.to_frame`, in order.
LOG_COLUMNS = ("epoch", "sse", "sum_sq_weights", "gamma", "alpha", "beta", "mu",
               "validation_sse", "grad_norm")


@dataclass
class TrainingLog:
    """What happened during training, one row per epoch.

    ``epoch`` 0 is the initial state (before any step). ``sse`` is :math:`E_D` (sum of squared
    errors in scaled units), ``sum_sq_weights`` :math:`E_W`, ``gamma`` the effective number of
    parameters, ``alpha``/``beta`` the regularisation hyper-parameters, ``mu`` the damping used
    for the step, ``validation_sse`` the validation :math:`E_D` (NaN without a validation set),
    ``grad_norm`` :math:`\\|\\nabla F\\|`. ``gamma``, ``alpha``, ``beta``, ``mu`` are NaN for Adam.

    Parameters
    ----------
    epoch, sse, sum_sq_weights, gamma, alpha, beta, mu, validation_sse, grad_norm : list
        Per-epoch columns, as above (empty for a new log).
    stop_reason : str
        Why training stopped.
    seconds : float
        Training time, s.
    n_errors : int
        Number of residuals.
    n_parameters : int
        Number of weights.
    trainer : str
        ``"trainbr"`` or ``"adam"``.
    best_epoch : int
        Epoch whose weights were returned (-1: the last).
    """

    epoch: list[int] = field(default_factory=list)
    sse: list[float] = field(default_factory=list)
    sum_sq_weights: list[float] = field(default_factory=list)
    gamma: list[float] = field(default_factory=list)
    alpha: list[float] = field(default_factory=list)
    beta: list[float] = field(default_factory=list)
    mu: list[float] = field(default_factory=list)
    validation_sse: list[float] = field(default_factory=list)
    stop_reason: str = ""
    seconds: float = 0.0
    grad_norm: list[float] = field(default_factory=list)
    n_errors: int = 0
    n_parameters: int = 0
    trainer: str = ""
    #: epoch whose weights were returned (the lowest validation SSE with ``best_validation``);
    #: -1: the last epoch's
    best_epoch: int = -1

    def append(self, epoch, sse, sum_sq_weights, gamma, alpha, beta, mu, validation_sse,
               grad_norm) -> None:
        """Add one epoch's row (the per-epoch fields in :data:`LOG_COLUMNS` order).

        Parameters
        ----------
        epoch : int
            Epoch number.
        sse, sum_sq_weights, gamma, alpha, beta, mu, validation_sse, grad_norm : float
            That epoch's values (see the class docstring).
        """
        for name, value in zip(LOG_COLUMNS, (epoch, sse, sum_sq_weights, gamma, alpha, beta, mu,
                                             validation_sse, grad_norm)):
            getattr(self, name).append(int(value) if name == "epoch" else float(value))

    def to_frame(self) -> pd.DataFrame:
        """The per-epoch log as a table (columns :data:`LOG_COLUMNS`)."""
        return pd.DataFrame({c: getattr(self, c) for c in LOG_COLUMNS})

    @classmethod
    def from_frame(cls, frame: pd.DataFrame, stop_reason: str = "", seconds: float = 0.0,
                   n_errors: int = 0, n_parameters: int = 0, trainer: str = "",
                   best_epoch: int = -1) -> "TrainingLog":
        """A log from the per-epoch table of :meth:`to_frame` (absent columns become NaN) and the
        run's summary fields.

        Parameters
        ----------
        frame : pandas.DataFrame
            Per-epoch table (:meth:`to_frame`).
        stop_reason, seconds, n_errors, n_parameters, trainer, best_epoch
            The run's summary fields (see the class docstring).
        """
        log = cls(stop_reason=stop_reason, seconds=float(seconds), n_errors=int(n_errors),
                  n_parameters=int(n_parameters), trainer=trainer, best_epoch=int(best_epoch))
        for c in LOG_COLUMNS:
            values = frame[c].tolist() if c in frame else [math.nan] * len(frame)
            setattr(log, c, [int(v) for v in values] if c == "epoch" else [float(v) for v in values])
        return log

    def summary(self) -> dict:
        """Scalars describing the run (JSON-able)."""
        return {"trainer": self.trainer, "stop_reason": self.stop_reason, "seconds": self.seconds,
                "epochs": (self.epoch[-1] if self.epoch else 0), "n_errors": self.n_errors,
                "n_parameters": self.n_parameters,
                "final_sse": (self.sse[-1] if self.sse else math.nan),
                "final_gamma": (self.gamma[-1] if self.gamma else math.nan),
                "final_validation_sse": (self.validation_sse[-1] if self.validation_sse else math.nan),
                "best_epoch": self.best_epoch,
                "returned_validation_sse": self.returned_validation_sse}

    @property
    def returned_validation_sse(self) -> float:
        """Validation SSE of the weights that were returned."""
        if not self.validation_sse:
            return math.nan
        if self.best_epoch < 0:
            return self.validation_sse[-1]
        return self.validation_sse[self.epoch.index(self.best_epoch)]

    def plot(self, path) -> None:
        """Save a figure like thesis Fig. 6.3: SSE (training and validation), E_W, γ and μ.

        Parameters
        ----------
        path : str or Path
            Image file to write (parent folders created).
        """
        import matplotlib

        matplotlib.use("Agg", force=False)
        import matplotlib.pyplot as plt

        frame = self.to_frame()
        fig, axes = plt.subplots(4, 1, figsize=(7, 9), sharex=True)
        ep = frame["epoch"]
        axes[0].semilogy(ep, frame["sse"], label="training")
        if frame["validation_sse"].notna().any():
            axes[0].semilogy(ep, frame["validation_sse"], label="validation")
        if self.best_epoch >= 0:
            for ax in axes:
                ax.axvline(self.best_epoch, ls=":", lw=1, color="black")
            axes[0].plot([], [], ls=":", color="black", label=f"returned (epoch {self.best_epoch})")
        axes[0].set_ylabel("SSE (scaled)")
        axes[0].legend()
        title = f"{self.trainer or 'training'}: {self.stop_reason} after {len(ep) - 1} epochs"
        axes[0].set_title(title)
        axes[1].semilogy(ep, frame["sum_sq_weights"])
        axes[1].set_ylabel("sum sq. weights")
        axes[2].plot(ep, frame["gamma"])
        axes[2].set_ylabel("effective params γ")
        if self.n_parameters:
            axes[2].axhline(self.n_parameters, ls="--", lw=0.8, color="gray")
        mu = frame["mu"].where(frame["mu"] > 0)
        if mu.notna().any():
            axes[3].semilogy(ep, mu)
        axes[3].set_ylabel("μ")
        axes[3].set_xlabel("epoch")
        for ax in axes:
            ax.grid(True, which="both", alpha=0.3)
        fig.tight_layout()
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=100)
        plt.close(fig)


# -- Jacobian -------------------------------------------------------------------------------
def jacobian_forward(residuals: Residuals, w: torch.Tensor, chunk_size: int = 64) -> torch.Tensor:
    r""":math:`J = \partial e/\partial w` by forward-mode AD (``torch.func.jvp`` under ``vmap``).

    Forward mode costs one forward pass per weight, which beats reverse mode when there are
    fewer weights than residuals (always, for these networks); ``chunk_size`` tangents are
    pushed at once to bound memory.

    Parameters
    ----------
    residuals : callable
        ``residuals(w) -> e``, the flattened errors.
    w : torch.Tensor
        Flat weight vector.
    chunk_size : int
        Tangents pushed at once.

    Returns
    -------
    torch.Tensor
        J, (N × P).
    """
    n_params = w.numel()
    eye = torch.eye(n_params, dtype=w.dtype)

    def push(tangent):
        return torch.func.jvp(residuals, (w,), (tangent,))[1]

    columns = [torch.func.vmap(push)(eye[i:i + chunk_size]) for i in range(0, n_params, chunk_size)]
    return torch.cat(columns, dim=0).T.contiguous()


# -- linear algebra of an epoch ------------------------------------------------------------
#: Rows of one block of a :class:`BlockJacobian` (as :func:`row_blocks` cuts them): about 5 MB
#: of J for the thesis nets' 601 weights, work enough for a thread, and blocks enough to
#: balance over the threads.
GRAM_BLOCK_ROWS = 1024
#: The Gram matrix :math:`[J\,e]^\top [J\,e]` is computed as 2 × 2 column tiles: two
#: symmetric products (``syrk``) on the diagonal, one general product beside them, half the
#: work each way for two threads. Narrower tiles repack J once per tile column and cost
#: more (×1.2–1.5 for 4–6 tiles, measured); the tiles do not depend on the thread count, so
#: neither do the bits.
GRAM_TILES = 2


def row_blocks(n_rows: int, size: int = GRAM_BLOCK_ROWS) -> list[slice]:
    """``n_rows`` rows cut into ``ceil(n_rows / size)`` contiguous blocks of (nearly) equal size.

    Parameters
    ----------
    n_rows : int
        Number of rows.
    size : int
        Largest block size, rows.
    """
    n_rows = int(n_rows)
    k = max(1, -(-n_rows // int(size)))
    edges = [(i * n_rows) // k for i in range(k + 1)]
    return [slice(lo, hi) for lo, hi in zip(edges[:-1], edges[1:])]


class BlockJacobian:
    r"""A Jacobian :math:`J = \partial e/\partial w` computed in independent row blocks.

    ``blocks[k](w, out)`` fills ``out`` (an ``(n_k, P)`` float64 tensor with contiguous rows,
    or ``None``: a new one) with rows ``rows[k]`` of :math:`J` and returns it. :func:`train_br`
    computes the blocks on its threads, straight into one array it keeps for the whole
    training (a new :math:`N\times P` array every epoch costs its fresh pages, as much as
    filling it).

    Parameters
    ----------
    blocks : sequence of callable
        ``block(w, out=None) -> J_k``.
    rows : sequence of slice
        The rows of :math:`e` each block covers (``slice(start, stop)``): together every row,
        in order, as :func:`row_blocks` gives them.
    """

    def __init__(self, blocks, rows):
        self.blocks, self.rows = tuple(blocks), tuple(rows)
        if not self.blocks or len(self.blocks) != len(self.rows):
            raise ValueError("BlockJacobian: one row slice per block, at least one block")
        stops = [0] + [r.stop for r in self.rows[:-1]]
        if any(r.start != stop or r.stop < r.start for r, stop in zip(self.rows, stops)):
            raise ValueError("BlockJacobian: the row slices must follow each other from row 0")

    @property
    def n_rows(self) -> int:
        """Rows of the whole Jacobian."""
        return self.rows[-1].stop

    def __call__(self, w: torch.Tensor) -> torch.Tensor:
        """The whole Jacobian (the blocks stacked)."""
        return torch.cat([block(w, None) for block in self.blocks])


def _run(pool: ThreadPoolExecutor | None, tasks) -> list:
    """Results of the ``tasks`` (callables without arguments), in their order: on ``pool``'s
    threads, which take them as they come free, or here without a pool."""
    if pool is None:
        return [task() for task in tasks]
    return [future.result() for future in [pool.submit(task) for task in tasks]]


class _NormalEquations:
    r""":math:`H = J^\top J` and :math:`J^\top e` of every epoch (step 1 of an epoch)."""

    def __init__(self, jac, n_errors: int, n_params: int, pool: ThreadPoolExecutor | None):
        self.jac, self.n_errors, self.n_params, self.pool = jac, n_errors, n_params, pool
        self.buffer = None
        if isinstance(jac, BlockJacobian) and jac.n_rows != n_errors:
            raise ValueError(f"train_br: the Jacobian's blocks cover {jac.n_rows} rows, "
                             f"expected {n_errors}")

    def __call__(self, w: torch.Tensor, e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(H, Jᵀe)`` at ``w`` with residuals ``e``; ``H`` in Fortran order, upper triangle
        (and the diagonal tiles) filled."""
        P = self.n_params
        if isinstance(self.jac, BlockJacobian):
            if self.buffer is None:  # [J e], kept: the Gram of it holds Jᵀe in its last column
                self.buffer = np.empty((self.n_errors, P + 1))
            Je = self.buffer
            _run(self.pool, [self._block_task(k, w) for k in range(len(self.jac.blocks))])
            Je[:, P] = e
            G = self._gram(Je)
            return G[:P, :P], G[:P, P].copy()
        J = self.jac(w).detach()
        if J.shape != (self.n_errors, P):
            raise ValueError(f"train_br: Jacobian has shape {tuple(J.shape)}, "
                             f"expected {(self.n_errors, P)}")
        J = np.ascontiguousarray(J.numpy())
        jte = []
        return self._gram(J, extra=lambda: jte.append(J.T @ e)), jte[0]

    def _block_task(self, k: int, w: torch.Tensor):
        def task():
            rows = self.jac.rows[k]
            out = torch.from_numpy(self.buffer[rows, :self.n_params])
            J_k = self.jac.blocks[k](w, out).detach()
            if J_k.shape != out.shape:
                raise ValueError(f"train_br: Jacobian block {k} has shape {tuple(J_k.shape)}, "
                                 f"expected {tuple(out.shape)}")
            if J_k.data_ptr() != out.data_ptr():  # a block that made its own array
                out.copy_(J_k)
        return task

    def _gram(self, A: np.ndarray, extra=None) -> np.ndarray:
        r""":math:`A^\top A` (Fortran order) from :data:`GRAM_TILES` × :data:`GRAM_TILES` column
        tiles, upper ones only; ``extra`` runs as one more task beside them."""
        n = A.shape[1]
        edges = [(i * n) // GRAM_TILES for i in range(GRAM_TILES + 1)]
        cols = [slice(lo, hi) for lo, hi in zip(edges[:-1], edges[1:])]
        G = np.zeros((n, n), order="F")

        def tile(a, b):
            def task():
                A_a = A[:, cols[a]]
                # the same operand on both sides: numpy takes the symmetric product (syrk)
                G[cols[a], cols[b]] = A_a.T @ A_a if a == b else A_a.T @ A[:, cols[b]]
            return task

        pairs = sorted(((a, b) for a in range(GRAM_TILES) for b in range(a, GRAM_TILES)),
                       key=lambda ab: ab[0] == ab[1])  # the general products (twice the work) first
        _run(self.pool, [tile(a, b) for a, b in pairs] + ([extra] if extra is not None else []))
        return G


def _factor(H: np.ndarray, beta: float, shift: float) -> np.ndarray | None:
    r"""Upper Cholesky factor :math:`R` of :math:`\beta H + \text{shift}\,I` (from ``H``'s upper
    triangle), or ``None`` when that matrix is not numerically positive definite."""
    A = np.multiply(H, beta, order="F")
    diagonal = np.arange(A.shape[0])
    A[diagonal, diagonal] += shift
    R, info = _lapack.dpotrf(A, lower=0, clean=1, overwrite_a=1)
    if info < 0:
        raise ValueError(f"dpotrf: illegal argument {-info}")
    return R if info == 0 else None


def lm_step(H: np.ndarray, gradient: np.ndarray, alpha: float, beta: float,
            mu: float) -> np.ndarray | None:
    r"""The Levenberg–Marquardt step :math:`\Delta w = -(\beta H + (\mu + \alpha) I)^{-1} g` by
    a Cholesky factorisation.

    Parameters
    ----------
    H : numpy.ndarray
        :math:`J^\top J` (``P × P``; its upper triangle is read).
    gradient : numpy.ndarray
        :math:`g = \beta J^\top e + \alpha w`, half the gradient of :math:`F`.
    alpha, beta, mu : float
        Prior and data precisions and the damping.

    Returns
    -------
    numpy.ndarray or None
        :math:`\Delta w`; ``None`` when the damped matrix is not numerically positive definite
        (a failed trial: the caller raises :math:`\mu`).
    """
    R = _factor(H, beta, mu + alpha)
    if R is None:
        return None
    x, info = _lapack.dpotrs(R, gradient, lower=0)
    if info != 0:
        raise ValueError(f"dpotrs: illegal argument {-info}")
    return -x


def effective_parameters(H: np.ndarray, alpha: float, beta: float) -> float:
    r"""The effective number of parameters :math:`\gamma = P - \alpha\,\mathrm{tr}((\beta H +
    \alpha I)^{-1})` (MacKay; MATLAB ``trainbr``), :math:`P` when :math:`\alpha = 0`.

    The trace is :math:`\|R^{-1}\|_F^2` for the Cholesky factor :math:`R^\top R = \beta H +
    \alpha I`; should that matrix not be numerically positive definite, it comes from the
    eigenvalues :math:`s_i \ge 0` of :math:`H` instead (:math:`\gamma = \sum_i \beta s_i/(\beta
    s_i + \alpha)`).

    Parameters
    ----------
    H : numpy.ndarray
        :math:`J^\top J` (``P × P``; its upper triangle is read).
    alpha, beta : float
        Prior and data precisions.
    """
    n_params = H.shape[0]
    if not alpha > 0:
        return float(n_params)
    R = _factor(H, beta, alpha)
    if R is not None:
        R_inv, info = _lapack.dtrtri(R, lower=0, overwrite_c=1)
        if info == 0:
            flat = R_inv.ravel(order="K")  # the strict lower triangle is zero
            return float(n_params - alpha * float(flat @ flat))
    s = np.linalg.eigvalsh(np.triu(H) + np.triu(H, 1).T).clip(min=0.0)
    return float(n_params - alpha * np.sum(1.0 / (beta * s + alpha)))


# -- trainers -------------------------------------------------------------------------------
def _progress(enabled: bool) -> Progress:
    return Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                    TextColumn("SSE {task.fields[sse]:.4g}  γ {task.fields[gamma]:.1f}  "
                               "μ {task.fields[mu]:.0e}"),
                    TimeElapsedColumn(), disable=not enabled, transient=False)


def _validation_value(validation, w) -> float:
    if validation is None:
        return math.nan
    with torch.no_grad():
        return float(validation(w))


class _ValidationWatch:
    """Keeps the weights of the epoch with the lowest validation SSE and counts the epochs since.

    MATLAB's ``train`` returns the network of the best validation epoch whenever it has a
    validation set (``tr.best_epoch``) and stops after ``max_fail`` epochs without improvement;
    ``trainbr`` on its own keeps the last epoch. ``keep_best`` and ``patience`` choose.
    """

    def __init__(self, keep_best: bool, patience: int):
        self.keep_best, self.patience = keep_best, int(patience)
        self.best_value, self.best_epoch, self.best_w, self.since = math.inf, -1, None, 0

    def update(self, epoch: int, value: float, w: torch.Tensor) -> bool:
        """Record an epoch's validation SSE; True when patience has run out."""
        if not math.isfinite(value):
            return False
        if value < self.best_value:
            self.best_value, self.best_epoch, self.since = value, epoch, 0
            if self.keep_best:
                self.best_w = w.detach().clone()
        else:
            self.since += 1
        return self.patience > 0 and self.since >= self.patience

    def finish(self, w: torch.Tensor, log: "TrainingLog") -> torch.Tensor:
        if self.keep_best and self.best_w is not None:
            log.best_epoch = self.best_epoch
            return self.best_w
        return w


def train_br(residuals: Residuals, w0: torch.Tensor, *, epochs: int = 1000, mu: float = 0.005,
             mu_dec: float = 0.1, mu_inc: float = 10.0, mu_max: float = 1e10,
             min_grad: float = 1e-7, validation: Callable[[torch.Tensor], float] | None = None,
             progress: bool = True, description: str = "trainbr",
             jacobian: JacobianFn | BlockJacobian | None = None,
             max_seconds: float | None = None, best_validation: bool = False,
             validation_patience: int = 0, threads: int | None = None) -> tuple[torch.Tensor, TrainingLog]:
    r"""Train by Levenberg–Marquardt with Bayesian regularisation (MATLAB ``trainbr``; the
    equations are in the module's docstring).

    Parameters
    ----------
    residuals : callable
        ``residuals(w) -> e``: the flattened errors (target − output, scaled units) for the flat
        float64 weight vector ``w``.
    w0 : torch.Tensor
        Initial weights (1-D); converted to float64.
    epochs, mu, mu_dec, mu_inc, mu_max, min_grad
        As MATLAB's ``net.trainParam`` (same defaults).
    validation : callable, optional
        ``validation(w) -> float``: the validation SSE, logged every epoch.
    best_validation : bool
        Return the weights of the epoch with the lowest validation SSE (as MATLAB's ``train``
        does when it has a validation set) instead of the last epoch's.
    validation_patience : int
        Stop when the validation SSE has not improved for this many epochs (MATLAB's
        ``max_fail``); 0 never stops on validation (``trainbr``'s default).
    progress : bool
        Show a rich progress bar with SSE, γ and μ.
    description : str
        Label of the progress bar.
    jacobian : callable or BlockJacobian, optional
        ``jacobian(w) -> J`` (N × P, :math:`\partial e/\partial w`), e.g. an efficient per-sample
        ``torch.func`` Jacobian, or a :class:`BlockJacobian` (cheaper: computed block by block
        on the threads); default :func:`jacobian_forward` of ``residuals``.
    max_seconds : float, optional
        Stop (reason ``"time limit"``) when training has run this long (MATLAB's
        ``trainParam.time``).
    threads : int, optional
        Threads to use (default: the cores the job is given,
        :func:`excavator_payload.execution.job_threads`). The result does not depend on it.

    Returns
    -------
    w : torch.Tensor
        The trained weights (float64).
    log : TrainingLog
    """
    from excavator_payload.execution import job_threads, numeric_threads

    threads = job_threads() if threads is None else int(threads)
    if threads < 1:
        raise ValueError(f"train_br: threads must be ≥ 1, got {threads}")
    # torch and BLAS single-threaded inside; the job's cores work through this pool instead
    with numeric_threads(1), (ThreadPoolExecutor(threads, thread_name_prefix="trainbr")
                              if threads > 1 else _no_pool()) as pool:
        return _train_br(residuals, w0, epochs=epochs, mu=mu, mu_dec=mu_dec, mu_inc=mu_inc,
                         mu_max=mu_max, min_grad=min_grad, validation=validation,
                         progress=progress, description=description, jacobian=jacobian,
                         max_seconds=max_seconds, best_validation=best_validation,
                         validation_patience=validation_patience, pool=pool, width=threads)


class _no_pool:
    """Stands in for a thread pool when there is one thread: everything runs in this one."""

    def __enter__(self):
        return None

    def __exit__(self, *exc):
        return False


class _Done:
    """A finished result with the interface of a future (no pool: computed here, at once)."""

    def __init__(self, value):
        self.value = value

    def result(self):
        return self.value


def _submit(pool, fn, *args):
    return pool.submit(fn, *args) if pool is not None else _Done(fn(*args))


def _trial(residuals, w, H, half_grad, alpha, beta, mu):
    r"""One Levenberg–Marquardt trial at damping ``mu``: ``None`` when the damped matrix is not
    positive definite, else ``(w_new, e_new, E_D, E_W)``. A pure function of its arguments
    (single-threaded BLAS), so trials may run side by side."""
    step = lm_step(H, half_grad, alpha, beta, mu)
    if step is None:
        return None
    w_new = w + torch.from_numpy(step)
    with torch.no_grad():
        e_new = residuals(w_new).detach()
    return w_new, e_new, float(e_new @ e_new), float(w_new @ w_new)


def _train_br(residuals, w0, *, epochs, mu, mu_dec, mu_inc, mu_max, min_grad, validation,
              progress, description, jacobian, max_seconds, best_validation, validation_patience,
              pool, width):
    start = time.perf_counter()
    jac = jacobian if jacobian is not None else (lambda v: jacobian_forward(residuals, v))
    w = w0.detach().to(torch.float64).clone()
    n_params = w.numel()
    with torch.no_grad():
        e = residuals(w).detach()
    n_errors = e.numel()
    if n_errors == 0:
        raise ValueError("train_br: no residuals (no training targets)")
    log = TrainingLog(n_errors=n_errors, n_parameters=n_params, trainer="trainbr")
    normal_equations = _NormalEquations(jac, n_errors, n_params, pool)
    width = int(width) if pool is not None else 1  # LM trials side by side: one per thread

    alpha, beta = 0.0, 1.0  # MATLAB: plain LM for the first step, then Bayesian updates
    e_d = float(e @ e)
    e_w = float(w @ w)
    gamma = float(n_params)
    watch = _ValidationWatch(best_validation, validation_patience)
    v = _validation_value(validation, w)
    watch.update(0, v, w)
    log.append(0, e_d, e_w, gamma, alpha, beta, mu, v, math.nan)
    stop_reason = f"maximum epochs ({epochs}) reached"
    # An accepted epoch whose γ is still being computed (on the pool, beside the next epoch's
    # Jacobian blocks): its log row is written, and α, β re-estimated, once γ is known.
    pending = None

    def settle():
        nonlocal pending, gamma, alpha, beta
        if pending is None:
            return
        done_epoch, gamma_job, v_done, mu_done = pending
        pending = None
        # Bayesian re-estimation with the Gauss–Newton Hessian of that epoch (α = 0: γ = P)
        gamma = gamma_job.result()
        alpha = gamma / (2.0 * e_w) if e_w > 0 else 1.0
        beta = (n_errors - gamma) / (2.0 * e_d) if e_d > 0 else 1.0
        if beta <= 0:  # more effective parameters than errors: fall back to LM weighting
            beta = 1.0
        log.append(done_epoch, e_d, e_w, gamma, alpha, beta, mu_done, v_done, math.nan)
        bar.update(task, advance=1, sse=e_d, gamma=gamma, mu=mu)

    with _progress(progress) as bar:
        task = bar.add_task(description, total=epochs, sse=e_d, gamma=gamma, mu=mu)
        for epoch in range(1, epochs + 1):
            H, jte = normal_equations(w, e.numpy())
            settle()  # the previous epoch's γ ran beside these blocks: α, β of this epoch
            # half the gradient of F: g = β Jᵀe + α w
            half_grad = beta * jte + alpha * w.numpy()
            grad_norm = 2.0 * float(np.linalg.norm(half_grad))
            if grad_norm < min_grad:
                stop_reason = f"minimum gradient reached ({grad_norm:.2e} < {min_grad:g})"
                log.grad_norm[-1] = grad_norm
                break
            cost = beta * e_d + alpha * e_w
            accepted = None
            while mu <= mu_max and accepted is None:
                # the next `width` dampings of the sequence μ, μ·μ_inc, … tried at once; the
                # first that lowers F wins, as if they were tried one after the other (nearly
                # every epoch takes two trials: μ·μ_dec fails, μ succeeds)
                mus = [mu]
                while len(mus) < width and mus[-1] * mu_inc <= mu_max:
                    mus.append(mus[-1] * mu_inc)
                jobs = [_submit(pool, _trial, residuals, w, H, half_grad, alpha, beta, m) for m in mus]
                for m, job in zip(mus, jobs):
                    mu = m
                    result = job.result()
                    if result is not None:  # else not positive definite: a failed trial
                        cost_new = beta * result[2] + alpha * result[3]
                        if math.isfinite(cost_new) and cost_new < cost:
                            accepted = result
                            break
                    mu = m * mu_inc
                for job in jobs:  # the trials after the accepted one are not needed
                    if hasattr(job, "cancel"):
                        job.cancel()
            if accepted is None:
                stop_reason = f"maximum mu reached (mu > {mu_max:g})"
                log.grad_norm[-1] = grad_norm
                break
            mu_used = mu
            w, e, e_d, e_w = accepted
            mu *= mu_dec
            log.grad_norm[-1] = grad_norm
            # γ of this epoch (its H, the α and β of its step), on the pool beside the next
            # epoch's Jacobian blocks, which do not need it
            gamma_job = _submit(pool, effective_parameters, H, alpha, beta)
            v = _validation_value(validation, w)
            pending = (epoch, gamma_job, v, mu_used)
            if watch.update(epoch, v, w):
                stop_reason = (f"validation SSE not improved for {validation_patience} epochs "
                               f"(best at epoch {watch.best_epoch})")
                break
            if max_seconds is not None and time.perf_counter() - start > max_seconds:
                stop_reason = f"time limit ({max_seconds:g} s) reached"
                break
        settle()
    log.stop_reason = stop_reason
    log.seconds = time.perf_counter() - start
    return watch.finish(w, log), log


def train_adam(residuals: Residuals, w0: torch.Tensor, *, epochs: int = 1000, lr: float = 1e-3,
               validation: Callable[[torch.Tensor], float] | None = None, progress: bool = True,
               description: str = "adam",
               max_seconds: float | None = None, best_validation: bool = False,
               validation_patience: int = 0) -> tuple[torch.Tensor, TrainingLog]:
    r"""Train by full-batch Adam on the mean squared error :math:`E_D/N`.

    One epoch is one Adam step on all residuals (no regularisation term, no mini-batches), so
    it is comparable epoch-for-epoch with :func:`train_br`, though it needs many more epochs.
    The log has the same columns; γ, α, β, μ are NaN. Torch runs single-threaded here: a step's
    operations are too small to gain from threads, and on a busy machine threads waiting for
    each other at every operation made them many times slower.

    Parameters
    ----------
    residuals : callable
        ``residuals(w) -> e``: the flattened errors (scaled units).
    w0 : torch.Tensor
        Initial weights (1-D).
    epochs : int
        Most Adam steps.
    lr : float
        Learning rate.
    validation : callable, optional
        ``validation(w) -> float``: the validation SSE, logged every epoch.
    progress : bool
        Show a progress bar.
    description : str
        Label of the progress bar.
    max_seconds : float, optional
        Stop after training this long, s.
    best_validation : bool
        Return the weights of the lowest validation SSE instead of the last.
    validation_patience : int
        Stop after this many epochs without validation improvement (0: never).

    Returns
    -------
    tuple of (torch.Tensor, TrainingLog)
        The weights and the log.
    """
    from excavator_payload.execution import numeric_threads

    with numeric_threads(1):
        return _train_adam(residuals, w0, epochs=epochs, lr=lr, validation=validation,
                           progress=progress, description=description, max_seconds=max_seconds,
                           best_validation=best_validation, validation_patience=validation_patience)


def _train_adam(residuals, w0, *, epochs, lr, validation, progress, description, max_seconds,
                best_validation, validation_patience):
    start = time.perf_counter()
    w = w0.detach().to(torch.float64).clone().requires_grad_(True)
    opt = torch.optim.Adam([w], lr=lr)
    log = TrainingLog(n_parameters=w.numel(), trainer="adam")
    watch = _ValidationWatch(best_validation, validation_patience)
    stop_reason = f"maximum epochs ({epochs}) reached"
    with _progress(progress) as bar:
        task = bar.add_task(description, total=epochs, sse=math.nan, gamma=math.nan, mu=math.nan)
        for epoch in range(0, epochs + 1):
            opt.zero_grad()
            e = residuals(w)
            sse = e @ e
            loss = sse / e.numel()
            loss.backward()
            grad_norm = float(torch.linalg.vector_norm(w.grad)) * e.numel()  # ‖∇E_D‖
            log.n_errors = e.numel()
            with torch.no_grad():
                v = _validation_value(validation, w.detach())
                log.append(epoch, float(sse.detach()), float(w @ w), math.nan, math.nan, math.nan, math.nan,
                           v, grad_norm)
            if not math.isfinite(float(sse.detach())):
                stop_reason = "diverged (non-finite error)"
                break
            if watch.update(epoch, v, w):
                stop_reason = (f"validation SSE not improved for {validation_patience} epochs "
                               f"(best at epoch {watch.best_epoch})")
                break
            if epoch == epochs:
                break
            if max_seconds is not None and time.perf_counter() - start > max_seconds:
                stop_reason = f"time limit ({max_seconds:g} s) reached"
                break  # before stepping: the returned weights are the last logged ones
            opt.step()
            bar.update(task, advance=1, sse=float(sse.detach()))
    log.stop_reason = stop_reason
    log.seconds = time.perf_counter() - start
    return watch.finish(w.detach(), log), log


__all__ = ["TrainingLog", "LOG_COLUMNS", "train_br", "train_adam", "jacobian_forward", "BlockJacobian",
           "row_blocks", "lm_step", "effective_parameters", "GRAM_BLOCK_ROWS", "GRAM_TILES"]
