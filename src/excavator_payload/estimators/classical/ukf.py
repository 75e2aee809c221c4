r"""Unscented Kalman filter on the same model and tunings as the EKF.

Model, tunings and the decorrelation of the torque noise: see
:mod:`excavator_payload.estimators.classical._kalman`. Sigma points are Wan and van der Merwe's
scaled points (filterpy's ``MerweScaledSigmaPoints``), :math:`n = 5`:

.. math::

    \lambda &= \alpha^2 (n + \kappa) - n, \qquad L L^\top = (n + \lambda) P \\
    \chi_0 &= x, \quad \chi_i = x + L_{:,i}, \quad \chi_{n+i} = x - L_{:,i} \quad (i = 1..n) \\
    W^m_0 &= \frac{\lambda}{n+\lambda}, \quad W^c_0 = W^m_0 + 1 - \alpha^2 + \beta, \quad
    W^m_i = W^c_i = \frac{1}{2(n+\lambda)}

Update, sequential as in the EKF: the angles and rates (:math:`h^{(1)}(x) = x_{1:4}`, linear,
where the unscented update *is* the Kalman update, done in Joseph form), then, ``consistent``
tuning, the torques with sigma points :math:`\chi_i` of the state :math:`(\bar x, \bar P)`
after the first update, :math:`\mathcal Y_i = h^{(2)}(\chi_i)`:

.. math::

    \hat y &= \sum W^m_i \mathcal Y_i, \qquad
    P_{yy} = \sum W^c_i (\mathcal Y_i - \hat y)(\mathcal Y_i - \hat y)^\top + R^{(2)}_k, \qquad
    P_{xy} = \sum W^c_i (\chi_i - \bar x)(\mathcal Y_i - \hat y)^\top \\
    K &= P_{xy} P_{yy}^{-1}, \qquad \hat x = \bar x + K (\tau^{meas}_k - \hat y)

The covariance uses the Joseph form of the statistically linearised measurement
:math:`H_s = P_{xy}^\top \bar P^{-1}` (residual :math:`r_i = \mathcal Y_i - \hat y - H_s(\chi_i
- \bar x)`, :math:`E = \sum W^c_i r_i r_i^\top`), algebraically equal to the textbook
:math:`\bar P - K P_{yy} K^\top` but without its cancellation when :math:`\bar P` is huge:

.. math:: P = (I - K H_s)\bar P (I - K H_s)^\top + K (R^{(2)}_k + E) K^\top

Prediction with sigma points :math:`\mathcal X_i` of :math:`(\hat x, P)` through the
decorrelated transition :math:`\tilde f(x) = f_d(x, u_k) + D_k (\tau^{meas}_k - h^{(2)}(x))`:

.. math::

    \bar x_{k+1} = \sum W^m_i \tilde f(\mathcal X_i), \qquad
    \bar P_{k+1} = \sum W^c_i (\tilde f(\mathcal X_i) - \bar x_{k+1})(\cdot)^\top + \tilde Q_k

Status and guards as the EKF (a non-positive-definite covariance is repaired by clipping the
eigenvalues of its correlation matrix).

With the ``thesis`` tuning the UKF is faithful but useless: :math:`Q = 10^6 I` puts sigma points
at ±10³ rad/s and ±10³ kg per step, where the arm model is nothing like the arm (the EKF only
linearises at the mean, so the same Q merely makes it trust the measurements). It stays finite
and is kept for comparison only.

Thesis sensor set only, as the EKF (issue 28: on the machine sensor set neither filter weighed
within 1 % of rated nor had a σ that covered its error).
"""

from __future__ import annotations

import numpy as np

from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.base import Option, Status, StepResult, register
from excavator_payload.estimators.classical import _kalman as kf
from excavator_payload.estimators.classical._kalman import (  # noqa: F401  (ukf.covariance_sqrt …)
    covariance_sqrt, repair_covariance, statistical_linearisation)
from excavator_payload.estimators.classical.ekf import COMMON_OPTIONS, KalmanEstimatorBase

N = kf.N_STATE


def merwe_weights(n: int, alpha: float, beta: float, kappa: float):
    """Wan–van der Merwe weights ``(Wm, Wc, n + λ)`` for ``2n + 1`` sigma points.

    Parameters
    ----------
    n : int
        State dimension.
    alpha, beta, kappa : float
        Spread, prior-distribution and secondary scaling parameters.
    """
    lam = alpha**2 * (n + kappa) - n
    Wm = np.full(2 * n + 1, 1.0 / (2 * (n + lam)))
    Wc = Wm.copy()
    Wm[0] = lam / (n + lam)
    Wc[0] = lam / (n + lam) + 1 - alpha**2 + beta
    return Wm, Wc, n + lam


@register
class UnscentedKalmanFilter(KalmanEstimatorBase):
    """UKF on x = [q1, q2, q̇1, q̇2, payload] (same model, tunings and options as ``ekf``).

    Parameters
    ----------
    machine : Machine or str
        The model the filter believes in (preset name or file), as for ``ekf``.
    alpha, beta, kappa : float
        Sigma-point spread and weights (Wan & van der Merwe). ``alpha = 0.5`` keeps the payload
        sigma points of the broad initial prior above minus the bucket mass.
    """

    name = "ukf"
    OPTIONS = {
        **COMMON_OPTIONS,
        "alpha": Option(float, 0.5, "sigma-point spread α (0 < α ≤ 1)"),
        "beta": Option(float, 2.0, "prior-distribution weight β (2 is optimal for Gaussians)"),
        "kappa": Option(float, 0.0, "secondary scaling κ"),
    }

    def __init__(self, machine=None, **options):
        super().__init__(machine, **options)
        if not 0.0 < self.options["alpha"] <= 1.0:
            raise EstimatorError(f"ukf: --alpha must be in (0, 1], got {self.options['alpha']}")
        self.Wm, self.Wc, self.spread = merwe_weights(N, self.options["alpha"], self.options["beta"],
                                                      self.options["kappa"])
        if self.spread <= 0:
            raise EstimatorError("ukf: α²(n + κ) must be positive; increase --alpha or --kappa")
        self._build_runtime()

    def _build_runtime(self) -> None:
        abs_payload = self.options["tuning"] == "thesis"
        self._sigma = kf.BufferedFunction(kf.sigma_point_function(self.machine, abs_payload, 2 * N + 1))
        self._terms = kf.kalman_model(self.machine, abs_payload).evaluator()
        self._build_gate()

    def sigma_points(self, x: np.ndarray, P: np.ndarray) -> np.ndarray:
        """The 2n+1 sigma points as the columns of an (n, 2n+1) array.

        Parameters
        ----------
        x : numpy.ndarray
            State mean, shape (n,).
        P : numpy.ndarray
            State covariance, shape (n, n).
        """
        L = covariance_sqrt(self.spread * P)
        return np.hstack([x[:, None], x[:, None] + L, x[:, None] - L])

    def _propagate(self, X: np.ndarray, u: np.ndarray, a: np.ndarray):
        packed = self._sigma(X, u, a)
        n_points = X.shape[1]
        f = packed[:N * n_points].reshape(N, n_points, order="F")
        h = packed[N * n_points:].reshape(6, n_points, order="F")
        return f, h

    def _step(self, time: float, values: np.ndarray) -> StepResult:
        tuning = self.tuning
        y, u, a = kf.sample_parts(values, tuning)
        if self._x is None:
            self._x, self._P = kf.initial_state(tuning, values)
        x_prior, P_prior = self._x, self._P
        Wm, Wc = self.Wm, self.Wc

        # Update 1, angles and rates: h = x[0:4] is linear, so the unscented update is the
        # Kalman update itself (Joseph form).
        x_post, P_post = linear_update(x_prior, P_prior, y[:4], tuning.R)
        if tuning.torque_channel:
            # Update 2, torques: sigma points of the state after update 1.
            chi = self.sigma_points(x_post, P_post)
            _, Y = self._propagate(chi, u, a)
            Y = Y[4:6]
            *_, M = self._terms(x_post, u, a)
            R = tuning.torque_cov + M @ tuning.accel_cov @ M.T
            y_hat = Y @ Wm
            dY = Y - y_hat[:, None]
            dX = chi - x_post[:, None]
            P_yy = (dY * Wc) @ dY.T + R
            P_xy = (dX * Wc) @ dY.T
            K = np.linalg.solve(P_yy, P_xy.T).T  # P_xy P_yy⁻¹ (P_yy symmetric)
            H_s = statistical_linearisation(P_post, P_xy)
            residual = dY - H_s @ dX
            E = (residual * Wc) @ residual.T
            I_KH = np.eye(N) - K @ H_s
            x_post = x_post + K @ (y[4:6] - y_hat)
            P_post = kf.symmetrise(I_KH @ P_post @ I_KH.T + K @ (R + E) @ K.T)
        if not self._accept(x_post, P_post):
            return StepResult(self._last_estimate, Status.INVALID)
        self._x, self._P = x_post, P_post
        result = self._result()

        # Predict to k+1 through f̃(x) = f_d(x, u_k) + D_k (τ_k − h_τ(x)).
        X = self.sigma_points(x_post, P_post)
        f, h = self._propagate(X, u, a)
        if tuning.torque_channel:
            _, _, G, _, _, M = self._terms(x_post, u, a)
            R = tuning.torque_cov + M @ tuning.accel_cov @ M.T
            G_sigma = G @ tuning.torque_cov
            D = -np.linalg.solve(R, G_sigma.T).T  # S R⁻¹ with S = −G Σ_τ
            f = f + D @ (y[4:6, None] - h[4:6])
            Q = G_sigma @ G.T + tuning.Q + D @ G_sigma.T  # Q − D Sᵀ
        else:
            Q = tuning.Q
        x_next = f @ Wm
        dF = f - x_next[:, None]
        P_next = kf.symmetrise((dF * Wc) @ dF.T + Q)
        if self._accept(x_next, P_next):
            self._x, self._P = x_next, P_next
        return result


def linear_update(x: np.ndarray, P: np.ndarray, y: np.ndarray, R: np.ndarray):
    """Kalman update (Joseph form) with the angles and rates, ``h(x) = x[0:4]``.

    Parameters
    ----------
    x : numpy.ndarray
        Prior state [q1, q2, q̇1, q̇2, payload] (rad, rad/s, kg).
    P : numpy.ndarray
        Prior covariance.
    y : numpy.ndarray
        Measured angles and rates (4), rad and rad/s.
    R : numpy.ndarray
        Their noise covariance (4 × 4).

    Returns
    -------
    tuple of numpy.ndarray
        Posterior ``(x, P)``.
    """
    H = np.eye(4, N)
    S = H @ P @ H.T + R
    K = np.linalg.solve(S, H @ P).T
    I_KH = np.eye(N) - K @ H
    return x + K @ (y - x[:4]), kf.symmetrise(I_KH @ P @ I_KH.T + K @ R @ K.T)
