r"""The IMU dynamics re-estimated while weighing (``--imu-nuisance on``): :class:`ImuNuisanceFilter`.

The calibration identifies the IMUs' output lag and acceleration sensitivities once; a
calibration that saw few motions can get the lag wrong by milliseconds, and the momentum form
does not identify the house IMU's sensitivity at all (its prior is what weighing starts from).
Beside :class:`~.kernel.CalibratedKernel`'s sums this filter carries the payload :math:`m`
and the nuisances :data:`~.settings.IMU_NUISANCES`, whitened by the calibration's posterior
(:math:`\nu = \mu + Lu`, :math:`LL^\top = C`, prior :math:`u \sim N(0, I)`). Per momentum
window and joint the kernel's residual is linear in :math:`m` and linearised in :math:`u`,

.. math:: r(m, u) \approx r_0 + \partial r_0\,u - m(\varphi + \partial\varphi\,u),

so the filter keeps the weighted sums of :math:`a = [\varphi, \partial r_0, \partial\varphi]`
(:math:`S \leftarrow \lambda S + \sum_j w_j a_j a_j^\top`, :math:`t \leftarrow \lambda t +
\sum_j w_j a_j r_{0,j}`; the kernel's weights, windows and forgetting λ, the prior not
forgotten) and solves at the payload of its previous solve, :math:`m_\ell`:

.. math:: (T^\top S T + \operatorname{diag}(0, I))\,\theta = T^\top t, \qquad
          T = \begin{bmatrix}1 & 0\\ 0 & -I\\ 0 & m_\ell I\end{bmatrix}, \qquad
          \theta = (m, u).

The payload's marginal variance :math:`(H^{-1})_{00}` replaces :math:`1/I` in σ (which keeps
the calibrated model error). With the nuisances held (:math:`u = 0`) the sums reduce to the
kernel's :math:`N = t_0`, :math:`I = S_{00}`. Per load: the kernel's new load restarts the
sums (the nuisances go back to the calibration's posterior), its settle takes the short
memory's. The prototype and its batch check: ``benchmarks/nuisance_filter.py``.
"""

from __future__ import annotations

import math
from functools import lru_cache

import casadi as ca
import numpy as np

from excavator_payload.estimators.classical.machine_calibration.settings import (
    CALIBRATED_PARAMETERS, IMU_NUISANCES, IMU_PARAMETERS, OFFSET_SIGNALS, SIGNALS)
from excavator_payload.estimators.classical.machine_calibration.symbolic import _momentum_terms
from excavator_payload.model.codegen import native
from excavator_payload.model.hydraulic import HYDRAULIC_PARAMETER_NAMES

#: Below this information on the payload (kg⁻²) the filter linearises at half the rated payload.
KNOWN_INFO = 1.0 / 50.0**2


@lru_cache(maxsize=2)
def imu_jacobian_function(names: tuple = IMU_NUISANCES) -> ca.Function:
    """One streaming sample's momentum-balance terms' Jacobian (12 × n) with respect to the
    IMU dynamics ``names``, compiled; the inputs of :func:`~.symbolic.kernel_function`
    (momentum form).

    Parameters
    ----------
    names : tuple of str
        The IMU dynamics (:data:`IMU_PARAMETERS`) re-estimated.
    """
    x = ca.SX.sym("x", len(SIGNALS))
    qdd = ca.SX.sym("qdd", 4)
    p = ca.SX.sym("p", len(HYDRAULIC_PARAMETER_NAMES))
    offsets = ca.SX.sym("offsets", len(SIGNALS))
    imu = ca.SX.sym("imu", len(IMU_PARAMETERS))
    A = _momentum_terms(x, qdd, p, offsets, imu)[0]
    free = ca.vertcat(*[imu[IMU_PARAMETERS.index(name)] for name in names])
    jac = ca.densify(ca.jacobian(A, free))
    return native(ca.Function(f"cal_machine_imu_jacobian_{len(names)}", [x, qdd, p, offsets, imu], [jac]))


def _indices(names) -> list[int]:
    start = len(CALIBRATED_PARAMETERS) + len(OFFSET_SIGNALS)
    return [start + IMU_PARAMETERS.index(name) for name in names]


def imu_whitening(cal, names: tuple = IMU_NUISANCES) -> np.ndarray:
    """L with L Lᵀ = the calibration's posterior covariance of the IMU dynamics ``names``.

    Parameters
    ----------
    cal : MachineCalibration
        The calibration (its ``covariance`` over z = (δ, offsets, IMU dynamics)).
    names : tuple of str
        The IMU dynamics re-estimated.
    """
    return posterior_whitening(cal, _indices(names))


def posterior_whitening(cal, idx) -> np.ndarray:
    """L with L Lᵀ = the calibration's posterior covariance of the entries ``idx`` of z (its
    eigenvectors scaled by the square roots of its eigenvalues, negative ones taken as 0).

    Parameters
    ----------
    cal : MachineCalibration
        The calibration (its ``covariance`` over z = (δ, offsets, IMU dynamics)).
    idx : sequence of int
        The entries of z.
    """
    idx = np.asarray(idx, int)
    C = np.asarray(cal.covariance, float)[np.ix_(idx, idx)]
    lam, V = np.linalg.eigh(0.5 * (C + C.T))
    return V * np.sqrt(np.maximum(lam, 0.0))


class KernelJacobianRing:
    """Per sample, the Jacobian of the kernel's 12 momentum terms with respect to some entries of
    z (:meth:`_jacobian_function`, :attr:`columns` of them), whitened by :attr:`L`, into a ring of
    twice the momentum window (each sample at ``slot`` and ``slot + balance_len``). The compiled
    call reads the kernel's own input buffers; copies and pickles bind them again on first use."""

    columns: int
    L: np.ndarray
    _balance_len: int

    def _jacobian_function(self):
        raise NotImplementedError

    def __getstate__(self):  # the compiled call's buffers are rebuilt on first use
        state = dict(self.__dict__)
        for key in ("_jac", "_call", "_trigger", "_out"):
            state.pop(key, None)
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._jac = self._jacobian_function()
        self._trigger = None

    def sample(self, kernel, slot: int) -> None:
        """The whitened Jacobian of the sample the kernel has just evaluated (its call's input
        buffers) into ring slot ``slot``.

        Parameters
        ----------
        kernel : CalibratedKernel
            The kernel (its ``_x``, ``_qdd``, ``_pvec``, ``_ovec``, ``_ivec`` buffers).
        slot : int
            The slot of the kernel's term ring.
        """
        if self._trigger is None:
            self._out = np.zeros(12 * self.columns)
            self._call, self._trigger = self._jac.buffer()
            for i, a in enumerate((kernel._x, kernel._qdd, kernel._pvec, kernel._ovec, kernel._ivec)):
                self._call.set_arg(i, memoryview(a))
            self._call.set_res(0, memoryview(self._out))
        self._trigger()
        # CasADi's dense output is column-major
        jac = self._out.reshape(self.columns, 12).T @ self.L
        b = self._balance_len
        self._terms[slot] = self._terms[slot + b] = jac


class ImuNuisanceFilter(KernelJacobianRing):
    """The payload and the IMU dynamics, per load, beside a momentum-form
    :class:`~.kernel.CalibratedKernel` (see the module doc).

    Parameters
    ----------
    cal : MachineCalibration
        The calibration weighed with (prior mean and covariance of the IMU dynamics).
    balance_len : int
        Samples of the kernel's momentum window (its ring of per-sample terms is twice this).
    names : tuple of str
        The IMU dynamics re-estimated (:data:`IMU_NUISANCES`; all five were measured too).
    """

    def __init__(self, cal, balance_len: int, names: tuple = IMU_NUISANCES):
        self.names = tuple(names)
        self.n = len(self.names)
        self.L = imu_whitening(cal, self.names)
        self.rated = float(cal.arm.machine.rated_payload)
        self._balance_len = balance_len
        self._jac = self._jacobian_function()
        self._trigger = None
        # (m, u) from a = [φ, ∂r0, ∂φ]: θ's design is a·T (the payload block of T set per solve)
        self._eye = np.eye(self.n)
        self._T = np.zeros((1 + 2 * self.n, 1 + self.n))
        self._T[0, 0] = 1.0
        self._T[1:1 + self.n, 1:] = -self._eye
        self._prior = np.zeros((1 + self.n, 1 + self.n))
        self._prior[1:, 1:] = self._eye
        self.reset()

    def reset(self) -> None:
        """Forget every load: empty sums, the nuisances at the calibration's posterior."""
        d = 1 + 2 * self.n
        self._terms = np.zeros((2 * self._balance_len, 12, self.n))  # whitened ∂A/∂u, doubled ring
        self.S, self.t = np.zeros((d, d)), np.zeros(d)
        self.S_short, self.t_short = np.zeros((d, d)), np.zeros(d)
        self.m_lin = 0.5 * self.rated
        self.payload, self.variance = math.nan, math.inf
        self.u = np.zeros(self.n)
        self._loads = self._settles = 0

    @property
    def columns(self) -> int:
        """The IMU dynamics re-estimated: the Jacobian's columns."""
        return self.n

    def _jacobian_function(self):
        return imu_jacobian_function(self.names)

    def window(self, kernel, start: int, w: np.ndarray, phi: np.ndarray, residual: np.ndarray) -> None:
        """Add one momentum window (after the kernel's own :meth:`~.kernel.CalibratedKernel._accumulate`,
        whose new load or settle it follows) and solve.

        Parameters
        ----------
        kernel : CalibratedKernel
            The kernel (forgetting, short memory, its new-load and settle counts, balance weights).
        start : int
            The window's first slot in the term ring.
        w : numpy.ndarray
            The window's weights per joint (3).
        phi, residual : numpy.ndarray
            The kernel's φ and r₀ per joint (3 each).
        """
        b = self._balance_len
        dT = self._terms[start:start + b]
        n = self.n
        integral = (kernel._balance_w @ dT[:, 6:12].reshape(b, 6 * n)).reshape(6, n)
        momentum = (kernel._balance_u @ dT[:, 0:6].reshape(b, 6 * n)).reshape(6, n)
        dr0 = (integral[0:3] - momentum[0:3]) / kernel._balance_span
        dphi = (momentum[3:6] - integral[3:6]) / kernel._balance_span
        a = np.concatenate([phi[:, None], dr0, dphi], axis=1)  # (3, 1 + 2n)
        self.last_a = a  # the window's regressors (the zero's share, OffsetShare, reads them)
        ok = w > 0.0
        a, w, r = a[ok], w[ok], residual[ok]
        dS, dt = (a.T * w) @ a, (a.T * w) @ r
        if not (np.all(np.isfinite(dS)) and np.all(np.isfinite(dt))):  # a hostile sample's Jacobian
            dS, dt = 0.0 * self.S, 0.0 * self.t
        lam = kernel.forgetting
        self.S, self.t = lam * self.S + dS, lam * self.t + dt
        if kernel.new_load:
            mu = kernel._short_forgetting
            self.S_short, self.t_short = mu * self.S_short + dS, mu * self.t_short + dt
        if kernel.new_loads != self._loads:  # the kernel restarted: a new load, per load
            self._empty(kernel)
        elif kernel.settles != self._settles:
            self._settles = kernel.settles
            self.S, self.t = self.S_short.copy(), self.t_short.copy()
        self.solve()

    def _empty(self, kernel) -> None:
        self._loads = kernel.new_loads
        self.S[:], self.t[:], self.S_short[:], self.t_short[:] = 0.0, 0.0, 0.0, 0.0
        self.m_lin = 0.5 * self.rated

    def restart(self, kernel) -> None:
        """The kernel restarted after this window was added (its joint check cleared a named
        joint): the sums start again now, this window's too, and the filter solves (the C export
        follows the restart in the same window).

        Parameters
        ----------
        kernel : CalibratedKernel
            The kernel (its new-load count).
        """
        self._empty(kernel)
        self.solve()

    def solve(self) -> None:
        """θ = (m, u) and the payload's marginal variance from the sums, linearised at the
        previous solve's payload (half the rated payload until it is known to 50 kg)."""
        if self.S[0, 0] <= 0.0:
            self.payload, self.variance = math.nan, math.inf
            return
        n, T = self.n, self._T
        T[1 + n:, 1:] = self.m_lin * self._eye
        H = T.T @ self.S @ T + self._prior
        try:
            Hinv = np.linalg.inv(H)
        except np.linalg.LinAlgError:
            self.payload, self.variance = math.nan, math.inf
            return
        theta = Hinv @ (T.T @ self.t)
        variance = float(Hinv[0, 0])
        if not (variance > 0.0 and np.all(np.isfinite(theta))):
            self.payload, self.variance = math.nan, math.inf
            return
        self.payload, self.variance, self.u = float(theta[0]), variance, theta[1:]
        self.solved = (T.copy(), theta, Hinv)  # what the zero's share differentiates (OffsetShare)
        if 1.0 / self.variance > KNOWN_INFO:
            self.m_lin = self.payload

    @property
    def info(self) -> float:
        """1 / the payload's marginal variance (0 before any window)."""
        return 1.0 / self.variance if self.variance > 0.0 and math.isfinite(self.variance) else 0.0

    def nuisances(self, cal) -> np.ndarray:
        """The current estimate of the IMU dynamics re-estimated (s, s²).

        Parameters
        ----------
        cal : MachineCalibration
            The calibration (prior mean).
        """
        return np.asarray(cal.z, float)[_indices(self.names)] + self.L @ self.u
