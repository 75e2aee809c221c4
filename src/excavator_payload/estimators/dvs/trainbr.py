r"""Levenberg–Marquardt training with Bayesian regularisation (MATLAB ``trainbr``), and Adam.

The thesis trains its networks with MATLAB's ``trainbr`` (appendix A.3), which implements
MacKay's Bayesian regularisation in the Gauss–Newton approximation of Foresee & Hagan (1997).
With residuals :math:`e = t - y(w)` (targets minus outputs, in scaled units) over :math:`N`
targets and :math:`P` weights, the cost is

.. math:: F(w) = \beta E_D + \alpha E_W, \qquad E_D = e^\top e, \qquad E_W = w^\top w .

With :math:`J = \partial e / \partial w` (an :math:`N\times P` matrix) one epoch is

1. the Levenberg–Marquardt step, tried with increasing damping :math:`\mu` until :math:`F`
   decreases,

   .. math:: \Delta w = -\big(\beta J^\top J + (\mu + \alpha) I\big)^{-1}
             \big(\beta J^\top e + \alpha w\big),

   :math:`\mu \leftarrow \mu\,\mu_{dec}` on success, :math:`\mu \leftarrow \mu\,\mu_{inc}`
   on failure (up to :math:`\mu_{max}`);
2. the re-estimation of the hyper-parameters with the effective number of parameters
   :math:`\gamma`,

   .. math:: \gamma = P - \alpha\,\mathrm{tr}\big((\beta J^\top J + \alpha I)^{-1}\big),\qquad
             \alpha = \frac{\gamma}{2 E_W}, \qquad \beta = \frac{N - \gamma}{2 E_D}.

Training starts as MATLAB does, with :math:`\alpha = 0, \beta = 1` (plain Levenberg–Marquardt
for the first step), and stops after ``epochs`` epochs, when the gradient norm
:math:`\|\nabla F\| = 2\|\beta J^\top e + \alpha w\|` falls below ``min_grad``, or when
:math:`\mu` exceeds :math:`\mu_{max}`.

One eigen-decomposition :math:`J^\top J = V\,\mathrm{diag}(s)\,V^\top` per epoch makes every
trial step and the trace cheap: :math:`(\beta J^\top J + cI)^{-1} = V\,\mathrm{diag}
(1/(\beta s + c))\,V^\top`.

References
----------
D. J. C. MacKay, "Bayesian interpolation", Neural Computation 4(3), 1992.
F. D. Foresee, M. T. Hagan, "Gauss–Newton approximation to Bayesian learning", ICNN 1997.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd
import torch
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
        """Add one epoch's row (the per-epoch fields in :data:`LOG_COLUMNS` order)."""
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
        run's summary fields."""
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
        """Save a figure like thesis Fig. 6.3: SSE (training and validation), E_W, γ and μ."""
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
    """
    n_params = w.numel()
    eye = torch.eye(n_params, dtype=w.dtype)

    def push(tangent):
        return torch.func.jvp(residuals, (w,), (tangent,))[1]

    columns = [torch.func.vmap(push)(eye[i:i + chunk_size]) for i in range(0, n_params, chunk_size)]
    return torch.cat(columns, dim=0).T.contiguous()


# -- linear algebra of an epoch ------------------------------------------------------------
def _numpy_blas_single_threaded() -> bool:
    return any(os.environ.get(v) == "1" for v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS",
                                                   "MKL_NUM_THREADS"))


def _gram(J: torch.Tensor) -> torch.Tensor:
    """JᵀJ, most of an epoch's cost.

    numpy evaluates ``A.T @ A`` as a symmetric rank-k update (BLAS syrk), half the work of the
    general product torch does, but its BLAS threads ignore ``torch.set_num_threads`` and
    thrash on a busy machine; so numpy is used only when its BLAS is pinned to one thread
    (``OPENBLAS_NUM_THREADS=1`` or ``OMP_NUM_THREADS=1``), torch otherwise.
    """
    if _numpy_blas_single_threaded():
        J_np = J.numpy()
        return torch.from_numpy(J_np.T @ J_np)
    return J.T @ J


def _eigh(A: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Eigen-decomposition of the (P × P) JᵀJ.

    On a busy machine train with ``OMP_NUM_THREADS=1`` (or ``OPENBLAS_NUM_THREADS=1``): the
    threaded LAPACK eigensolver synchronises its threads many times per call and waits for a
    core each time another process holds one. Measured on this 2-core machine at load ~4:
    P = 601 (thesis net1) 8.8 s with 2 threads against 0.056 s with one, P = 1141 (net1 on the
    machine set) 10–15 s against 0.22 s: most of an epoch (the 26 epochs in 30 minutes of the
    first machine-set training). The default is left threaded because a single-threaded
    eigensolver changes the trained thesis networks in the last bits (≈1e-13 relative after 15
    epochs), and their published figures are kept bit-identical.
    """
    if _numpy_blas_single_threaded():
        s, V = np.linalg.eigh(A.numpy())
        return torch.from_numpy(s), torch.from_numpy(V)
    return torch.linalg.eigh(A)


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
             jacobian: JacobianFn | None = None,
             max_seconds: float | None = None, best_validation: bool = False,
             validation_patience: int = 0) -> tuple[torch.Tensor, TrainingLog]:
    r"""Train by Levenberg–Marquardt with Bayesian regularisation (MATLAB ``trainbr``).

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
    jacobian : callable, optional
        ``jacobian(w) -> J`` (N × P, :math:`\partial e/\partial w`), e.g. an efficient per-sample
        ``torch.func`` Jacobian; default :func:`jacobian_forward` of ``residuals``.
    max_seconds : float, optional
        Stop (reason ``"time limit"``) when training has run this long (MATLAB's
        ``trainParam.time``).

    Returns
    -------
    w : torch.Tensor
        The trained weights (float64).
    log : TrainingLog
    """
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

    alpha, beta = 0.0, 1.0  # MATLAB: plain LM for the first step, then Bayesian updates
    e_d = float(e @ e)
    e_w = float(w @ w)
    gamma = float(n_params)
    watch = _ValidationWatch(best_validation, validation_patience)
    v = _validation_value(validation, w)
    watch.update(0, v, w)
    log.append(0, e_d, e_w, gamma, alpha, beta, mu, v, math.nan)
    stop_reason = f"maximum epochs ({epochs}) reached"
    with _progress(progress) as bar:
        task = bar.add_task(description, total=epochs, sse=e_d, gamma=gamma, mu=mu)
        for epoch in range(1, epochs + 1):
            J = jac(w).detach()
            if J.shape != (n_errors, n_params):
                raise ValueError(f"train_br: Jacobian has shape {tuple(J.shape)}, "
                                 f"expected {(n_errors, n_params)}")
            jtj = _gram(J)
            jte = J.T @ e
            # gradient of F/2 = β Jᵀe + α w
            half_grad = beta * jte + alpha * w
            grad_norm = 2.0 * float(torch.linalg.vector_norm(half_grad))
            if grad_norm < min_grad:
                stop_reason = f"minimum gradient reached ({grad_norm:.2e} < {min_grad:g})"
                log.grad_norm[-1] = grad_norm
                break
            s, V = _eigh(jtj)
            s = s.clamp_min(0.0)
            g_rot = V.T @ half_grad  # the gradient in the eigenbasis of JᵀJ
            cost = beta * e_d + alpha * e_w
            accepted = False
            while mu <= mu_max:
                # Δw = −(βJᵀJ + (μ+α)I)⁻¹ (βJᵀe + αw)
                step = -(V @ (g_rot / (beta * s + mu + alpha)))
                w_new = w + step
                with torch.no_grad():
                    e_new = residuals(w_new).detach()
                e_d_new = float(e_new @ e_new)
                e_w_new = float(w_new @ w_new)
                cost_new = beta * e_d_new + alpha * e_w_new
                if math.isfinite(cost_new) and cost_new < cost:
                    accepted = True
                    break
                mu *= mu_inc
            if not accepted:
                stop_reason = f"maximum mu reached (mu > {mu_max:g})"
                log.grad_norm[-1] = grad_norm
                break
            mu_used = mu
            w, e, e_d, e_w = w_new, e_new, e_d_new, e_w_new
            mu *= mu_dec
            # Bayesian re-estimation with the Gauss–Newton Hessian of this epoch:
            # γ = P − α tr((βJᵀJ + αI)⁻¹) = Σ βs/(βs + α)   (α = 0 gives γ = P)
            gamma = float(n_params - alpha * torch.sum(1.0 / (beta * s + alpha)).item()) \
                if alpha > 0 else float(n_params)
            alpha = gamma / (2.0 * e_w) if e_w > 0 else 1.0
            beta = (n_errors - gamma) / (2.0 * e_d) if e_d > 0 else 1.0
            if beta <= 0:  # more effective parameters than errors: fall back to LM weighting
                beta = 1.0
            log.grad_norm[-1] = grad_norm
            v = _validation_value(validation, w)
            log.append(epoch, e_d, e_w, gamma, alpha, beta, mu_used, v, math.nan)
            bar.update(task, advance=1, sse=e_d, gamma=gamma, mu=mu)
            if watch.update(epoch, v, w):
                stop_reason = (f"validation SSE not improved for {validation_patience} epochs "
                               f"(best at epoch {watch.best_epoch})")
                break
            if max_seconds is not None and time.perf_counter() - start > max_seconds:
                stop_reason = f"time limit ({max_seconds:g} s) reached"
                break
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
    The log has the same columns; γ, α, β, μ are NaN.
    """
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


__all__ = ["TrainingLog", "LOG_COLUMNS", "train_br", "train_adam", "jacobian_forward"]
