"""Can trainbr's Gram matrix be formed in float32? Measured along today's (float64) training.

    python benchmarks/bench_trainbr_precision.py --data data.parquet            # net1, 700 epochs
    python benchmarks/bench_trainbr_precision.py --data data.parquet --every 25 --csv pcg.csv

Trains ``net1`` exactly as ``excavator-payload train net1`` does (float64 normal equations, the
result unchanged) and, at every ``--every``-th epoch, looks at each Levenberg–Marquardt trial
through a float32 Gram :math:`H_{32}` of the same :math:`J` (float32 blocks of 1024 rows,
summed in float64):

* the error of the step solved with :math:`H_{32}` directly (what a float32 Gram gives);
* how many preconditioned conjugate-gradient iterations reach the exact float64 step (relative
  residual ``--tolerance``), with matrix–vector products :math:`\\beta J^\\top(Jv) + (\\mu+\\alpha)v`
  in float64 and the float64 Cholesky factor of :math:`\\beta H_{32} + (\\mu+\\alpha)I` as the
  preconditioner (shifted until positive definite when it is not);
* whether :math:`\\beta H_{32} + \\alpha I` is positive definite, i.e. whether the effective
  number of parameters :math:`\\gamma = P - \\alpha\\,\\mathrm{tr}((\\beta H + \\alpha I)^{-1})`
  can be computed from :math:`H_{32}` at all;
* how many eigenvalues of :math:`H` lie below :math:`\\|H - H_{32}\\|_2`.

The instrumentation wraps two internals of ``estimators/dvs/trainbr.py`` (the normal equations
and ``lm_step``) for the length of this process; run it with one thread
(``EXCAVATOR_PAYLOAD_THREADS=1``, set here) so the trials see the epoch's Jacobian. Findings:
``docs/speed-trainbr.md`` ("Mixed precision with exact steps").
"""

from __future__ import annotations

import os

os.environ.setdefault("EXCAVATOR_PAYLOAD_THREADS", "1")

import argparse
import csv

import numpy as np
from scipy.linalg import lapack

from excavator_payload.data.io import read_dataset
from excavator_payload.estimators.base import create_estimator
from excavator_payload.estimators.dvs import trainbr

#: rows of J summed per float32 block of the float32 Gram
BLOCK_ROWS = 1024
#: rows of J per pass of one exact product Jᵀ(Jv) (the block stays in cache between the two)
PRODUCT_ROWS = 128


def gram_float32(J: np.ndarray) -> np.ndarray:
    """:math:`J^\\top J` from float32 row blocks, summed in float64.

    Parameters
    ----------
    J : numpy.ndarray
        ``(N, P)`` float64 Jacobian.
    """
    H = np.zeros((J.shape[1], J.shape[1]))
    for lo in range(0, J.shape[0], BLOCK_ROWS):
        B = J[lo:lo + BLOCK_ROWS].astype(np.float32)
        H += B.T @ B
    return H


def cholesky(H: np.ndarray, beta: float, shift: float) -> np.ndarray | None:
    """Upper Cholesky factor of :math:`\\beta H + \\text{shift}\\,I`, ``None`` if not positive definite.

    Parameters
    ----------
    H : numpy.ndarray
        Symmetric ``P × P`` matrix.
    beta, shift : float
        Scale and diagonal shift.
    """
    A = beta * H + shift * np.eye(H.shape[0])
    R, info = lapack.dpotrf(np.asfortranarray(A), lower=0, clean=1)
    return R if info == 0 else None


def pcg_iterations(J: np.ndarray, beta: float, shift: float, b: np.ndarray, R: np.ndarray,
                   tolerance: float, max_iterations: int) -> tuple[int, np.ndarray]:
    """Preconditioned CG on :math:`(\\beta J^\\top J + \\text{shift}\\,I)x = b` with exact products.

    Parameters
    ----------
    J : numpy.ndarray
        ``(N, P)`` float64 Jacobian.
    beta, shift : float
        As in the system above.
    b : numpy.ndarray
        Right-hand side.
    R : numpy.ndarray
        Upper Cholesky factor of the preconditioner.
    tolerance : float
        Relative residual :math:`\\|b - Ax\\|/\\|b\\|` to reach.
    max_iterations : int
        Iterations before giving up.

    Returns
    -------
    tuple of (int, numpy.ndarray)
        Iterations (−1: not converged) and the last iterate.
    """
    def product(v):
        out = np.zeros_like(v)
        for lo in range(0, J.shape[0], PRODUCT_ROWS):
            B = J[lo:lo + PRODUCT_ROWS]
            out += B.T @ (B @ v)
        return beta * out + shift * v

    def precondition(r):
        return lapack.dpotrs(R, r, lower=0)[0]

    x = precondition(b)
    r = b - product(x)
    norm_b = np.linalg.norm(b)
    if np.linalg.norm(r) <= tolerance * norm_b:
        return 0, x
    z = precondition(r)
    p, rz = z.copy(), r @ z
    for iteration in range(1, max_iterations + 1):
        Ap = product(p)
        step = rz / (p @ Ap)
        x += step * p
        r -= step * Ap
        if np.linalg.norm(r) <= tolerance * norm_b:
            return iteration, x
        z = precondition(r)
        rz_next = r @ z
        p = z + (rz_next / rz) * p
        rz = rz_next
    return -1, x


def main() -> None:
    """Train net1 and print (and optionally write) one row per looked-at trial."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", required=True, help="training dataset (Parquet)")
    parser.add_argument("--epochs", type=int, default=700)
    parser.add_argument("--every", type=int, default=25, help="look at every this many epochs (and 1)")
    parser.add_argument("--tolerance", type=float, default=1e-10)
    parser.add_argument("--max-iterations", type=int, default=300)
    parser.add_argument("--csv", default=None, help="write the rows here")
    args = parser.parse_args()

    state = {"epoch": 0, "J": None, "H32": None}
    rows = []
    normal_equations, lm_step = trainbr._NormalEquations.__call__, trainbr.lm_step

    def watched_normal_equations(self, w, e):
        out = normal_equations(self, w, e)
        state.update(epoch=state["epoch"] + 1, J=self.buffer[:, :self.n_params], H32=None)
        return out

    def watched_lm_step(H, gradient, alpha, beta, mu):
        step = lm_step(H, gradient, alpha, beta, mu)
        epoch = state["epoch"]
        if step is None or not (epoch == 1 or epoch % args.every == 0):
            return step
        J = state["J"]
        first_look = state["H32"] is None
        if first_look:
            state["H32"] = gram_float32(J)
        H32 = state["H32"]
        H_full = np.triu(H) + np.triu(H, 1).T
        R, added = cholesky(H32, beta, mu + alpha), 0.0
        direct = (np.nan if R is None else
                  np.linalg.norm(-lapack.dpotrs(R, gradient, lower=0)[0] - step) / np.linalg.norm(step))
        while R is None:  # β‖H − H32‖ above μ + α: shift the preconditioner until it factors
            added = 2 * added if added else 1e-7 * beta * np.diag(H32).max()
            R = cholesky(H32, beta, mu + alpha + added)
        iterations, x = pcg_iterations(J, beta, mu + alpha, -gradient, R, args.tolerance,
                                       args.max_iterations)
        row = {"epoch": epoch, "mu": mu, "alpha": alpha, "beta": beta,
               "float32_step_error": direct, "pcg_iterations": iterations,
               "pcg_step_error": np.linalg.norm(x - step) / np.linalg.norm(step),
               "preconditioner_shift_added": added,
               "gamma_defined_from_H32": alpha == 0 or cholesky(H32, beta, alpha) is not None,
               "eigenvalues_below_float32_error": ""}
        if first_look:
            error = np.abs(np.linalg.eigvalsh(H_full - H32)).max()
            row["eigenvalues_below_float32_error"] = int(np.sum(np.linalg.eigvalsh(H_full) < error))
        rows.append(row)
        print(", ".join(f"{k} {v:.3g}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()),
              flush=True)
        return step

    trainbr._NormalEquations.__call__, trainbr.lm_step = watched_normal_equations, watched_lm_step
    dataset = read_dataset(args.data)
    estimator = create_estimator("net1", machine=dataset.machine() or "cat345c", progress=False,
                                 epochs=args.epochs)
    estimator.fit(dataset)
    print(estimator.training_log.summary())
    if args.csv and rows:
        with open(args.csv, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)


if __name__ == "__main__":
    main()
