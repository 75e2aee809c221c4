r"""The zero's share of each estimate's σ, exact per estimate: :class:`OffsetShare`.

``zero`` re-estimates the session's sensor offsets :math:`o` from one empty motion; their
posterior :math:`\Sigma_o` (11 × 11) stays in every later weighing, one error shared by all of
them. How much of it a weighing takes depends on the poses and motions it weighed on: the
estimate's own sensitivity :math:`g = \partial\hat m/\partial o` carries it,
:math:`s_0^2 = g\,\Sigma_o\,g^\top`. Beside the momentum-form
:class:`~.kernel.CalibratedKernel` this class keeps running sums from which :math:`g` follows
exactly (to first order, the kernel's weights held):

Per sample the Jacobian of the balance terms by the offsets, whitened by :math:`\Sigma_o`
(:math:`o = \hat o + L v`, :math:`LL^\top = \Sigma_o`), goes into a ring beside the terms; per
window and joint the balance gives :math:`\partial r_0/\partial v` and
:math:`\partial\varphi/\partial v` (rows of 11). With :math:`a` the weighing's regressor of the
joint (:math:`[\varphi]`, or with ``--imu-nuisance`` the filter's :math:`[\varphi, \partial r_0,
\partial\varphi]`) the sums are

.. math:: G_r \leftarrow \lambda G_r + \sum_j w_j a_j \partial r_{0,j}, \quad
          G_\varphi \leftarrow \lambda G_\varphi + \sum_j w_j a_j \partial\varphi_j, \quad
          c \leftarrow \lambda c + \sum_j w_j r_{0,j}\,\partial\varphi_j

(the kernel's λ, new loads and settles), and the estimating equation
:math:`T^\top\sum_j w_j a_j(r_{0,j} - a_j^\top T\theta) - P\theta = 0` differentiated gives

.. math:: \partial\theta/\partial v = H^{-1} T^\top \big(G_r - m\,G_\varphi
          + e_0\,(c - G_\varphi^\top T\theta)^\top\big), \qquad s_0^2 = \lVert(\partial\theta/\partial v)_0\rVert^2

(the plain weighing: :math:`T = 1`, :math:`H = I`, :math:`\hat m = N/I`:
:math:`\partial\hat m = (G_r + c - 2\hat m G_\varphi)/I`). The weights' own dependence on the
offsets (through the levers) and the discrete decisions (coverage, new loads) are held.
"""

from __future__ import annotations

import math
from functools import lru_cache

import casadi as ca
import numpy as np

from excavator_payload.estimators.classical.machine_calibration.settings import (
    _OFFSET_COLUMNS, CALIBRATED_PARAMETERS, IMU_PARAMETERS, OFFSET_SIGNALS, SIGNALS)
from excavator_payload.estimators.classical.machine_calibration.imu_nuisance import (
    KernelJacobianRing, posterior_whitening)
from excavator_payload.estimators.classical.machine_calibration.symbolic import _momentum_terms
from excavator_payload.model.codegen import native
from excavator_payload.model.hydraulic import HYDRAULIC_PARAMETER_NAMES


@lru_cache(maxsize=1)
def offset_jacobian_function() -> ca.Function:
    """One streaming sample's momentum-balance terms' Jacobian (12 × 11) by the offsets
    :data:`OFFSET_SIGNALS`, compiled; the inputs of :func:`~.symbolic.kernel_function`
    (momentum form)."""
    x = ca.SX.sym("x", len(SIGNALS))
    qdd = ca.SX.sym("qdd", 4)
    p = ca.SX.sym("p", len(HYDRAULIC_PARAMETER_NAMES))
    offsets = ca.SX.sym("offsets", len(SIGNALS))
    imu = ca.SX.sym("imu", len(IMU_PARAMETERS))
    A = _momentum_terms(x, qdd, p, offsets, imu)[0]
    free = ca.vertcat(*[offsets[int(i)] for i in _OFFSET_COLUMNS])
    jac = ca.densify(ca.jacobian(A, free))
    return native(ca.Function("cal_machine_offset_jacobian", [x, qdd, p, offsets, imu], [jac]))


def offset_whitening(cal) -> np.ndarray:
    """L with L Lᵀ = the calibration's posterior covariance of the offsets (after ``zero``:
    the zero's).

    Parameters
    ----------
    cal : MachineCalibration
        The calibration (its ``covariance`` over z = (δ, offsets, IMU dynamics)).
    """
    start = len(CALIBRATED_PARAMETERS)
    return posterior_whitening(cal, np.arange(start, start + len(OFFSET_SIGNALS)))


class OffsetShare(KernelJacobianRing):
    """The zero's share of the current estimate's σ (kg), beside a momentum-form
    :class:`~.kernel.CalibratedKernel` (see the module doc).

    Parameters
    ----------
    cal : MachineCalibration
        The zeroed calibration (its offsets' posterior).
    balance_len : int
        Samples of the kernel's momentum window (its ring of per-sample terms is twice this).
    regressors : int
        Entries of the weighing's regressor a per joint: 1 (N/I), or 1 + 2n with the IMU
        nuisance filter of n nuisances.
    """

    def __init__(self, cal, balance_len: int, regressors: int = 1):
        self.L = offset_whitening(cal)
        self.k = self.L.shape[1]
        self.d = int(regressors)
        self._balance_len = balance_len
        self._jac = self._jacobian_function()
        self._trigger = None
        self.reset()

    def reset(self) -> None:
        """Forget every load: empty sums."""
        d, k = self.d, self.k
        self._terms = np.zeros((2 * self._balance_len, 12, k))
        self.Gr, self.Gphi, self.c = np.zeros((d, k)), np.zeros((d, k)), np.zeros(k)
        self.Gr_short, self.Gphi_short, self.c_short = np.zeros((d, k)), np.zeros((d, k)), np.zeros(k)
        self._loads = self._settles = 0
        self.std = 0.0

    def restart(self, kernel) -> None:
        """The kernel restarted after this window was added (its joint check cleared a named
        joint): the sums start again now, this window's too, and :attr:`std` follows (as the C
        export does in the same window; the IMU filter's restart comes first).

        Parameters
        ----------
        kernel : CalibratedKernel
            The kernel (its new-load count, its estimate).
        """
        self._loads = kernel.new_loads
        for sums in (self.Gr, self.Gphi, self.c, self.Gr_short, self.Gphi_short, self.c_short):
            sums[...] = 0.0
        self.std = self._solve(kernel)

    columns = len(OFFSET_SIGNALS)  # the Jacobian's: every offset

    def _jacobian_function(self):
        return offset_jacobian_function()

    def window(self, kernel, start: int, w: np.ndarray, a: np.ndarray, residual: np.ndarray) -> None:
        """Add one momentum window (after the kernel's sums and the IMU nuisance filter, whose
        new load or settle it follows) and update :attr:`std`.

        Parameters
        ----------
        kernel : CalibratedKernel
            The kernel (forgetting, short memory, new-load and settle counts, balance weights,
            its estimate).
        start : int
            The window's first slot in the term ring.
        w : numpy.ndarray
            The window's weights per joint (3).
        a : numpy.ndarray
            The weighing's regressor per joint (3, d).
        residual : numpy.ndarray
            The kernel's r₀ per joint (3).
        """
        b, k = self._balance_len, self.k
        dT = self._terms[start:start + b]
        integral = (kernel._balance_w @ dT[:, 6:12].reshape(b, 6 * k)).reshape(6, k)
        momentum = (kernel._balance_u @ dT[:, 0:6].reshape(b, 6 * k)).reshape(6, k)
        dr = (integral[0:3] - momentum[0:3]) / kernel._balance_span
        dphi = (momentum[3:6] - integral[3:6]) / kernel._balance_span
        ok = w > 0.0
        aw = a[ok].T * w[ok]  # (d, used joints)
        dGr, dGphi, dc = aw @ dr[ok], aw @ dphi[ok], (w[ok] * residual[ok]) @ dphi[ok]
        if not (np.all(np.isfinite(dGr)) and np.all(np.isfinite(dGphi)) and np.all(np.isfinite(dc))):
            dGr, dGphi, dc = 0.0 * self.Gr, 0.0 * self.Gphi, 0.0 * self.c  # a hostile sample's Jacobian
        lam = kernel.forgetting
        self.Gr, self.Gphi, self.c = lam * self.Gr + dGr, lam * self.Gphi + dGphi, lam * self.c + dc
        if kernel.new_load:
            mu = kernel._short_forgetting
            self.Gr_short = mu * self.Gr_short + dGr
            self.Gphi_short = mu * self.Gphi_short + dGphi
            self.c_short = mu * self.c_short + dc
        if kernel.new_loads != self._loads:  # the kernel restarted: a new load
            self._loads = kernel.new_loads
            for s in (self.Gr, self.Gphi, self.c, self.Gr_short, self.Gphi_short, self.c_short):
                s[...] = 0.0
        elif kernel.settles != self._settles:  # the settle: the short memory's sums
            self._settles = kernel.settles
            self.Gr, self.Gphi, self.c = self.Gr_short.copy(), self.Gphi_short.copy(), self.c_short.copy()
        self.std = self._solve(kernel)

    def _solve(self, kernel) -> float:
        g = self._gradient(kernel)
        if g is None:
            return 0.0
        s = float(math.sqrt(float(g @ g)))
        return s if math.isfinite(s) else 0.0

    def _gradient(self, kernel):
        """∂m̂/∂v of the current estimate (the module's equations), None before there is one."""
        nz = kernel._imu_nuisance
        if nz is None:
            if not kernel.info > 0.0:
                return None
            m = kernel.num / kernel.info
            return (self.Gr[0] + self.c - 2.0 * m * self.Gphi[0]) / kernel.info
        if not (nz.variance > 0.0 and math.isfinite(nz.variance)):
            return None
        T, theta, Hinv = nz.solved
        m = theta[0]
        V = self.Gr - m * self.Gphi
        V[0] += self.c - self.Gphi.T @ (T @ theta)
        return (Hinv[0] @ T.T) @ V
