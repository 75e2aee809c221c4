r"""Inverse-dynamics payload estimator: recursive weighted least squares on the payload mass.

The arm's torques are affine in the payload (:mod:`excavator_payload.model.dynamics`),

.. math:: \tau_k = \tau_0(x_k) + m\,\varphi(x_k) + \varepsilon_k,
          \qquad x_k = (q_k, \dot q_k, \ddot q_k),

so with measured kinematics and torques the payload is a linear regression (the approach of the
thesis' ref. [40], "A Method for Payload Estimation in Excavators"), here made noise-aware.

Base-parameter (closed-form) model
----------------------------------
Working the Lagrangian of appendix A.1 out by hand (boom and dipper uniform bars, bucket plus
payload a point mass :math:`m_3 = m_b + m` at the dipper tip) gives the torques as a linear
combination of seven *base parameters* :math:`\theta = (A, B, C, D, E, \beta_1, \beta_2)`,

.. math::

    \tau_1 &= A\ddot q_1 + B(\ddot q_1 + \ddot q_2)
              + C\,[c_2(2\ddot q_1 + \ddot q_2) - s_2(2\dot q_1\dot q_2 + \dot q_2^2)]
              + D c_1 + E c_{12} + \beta_1 \dot q_1 \\
    \tau_2 &= B(\ddot q_1 + \ddot q_2) + C\,[c_2\ddot q_1 + s_2\dot q_1^2] + E c_{12}
              + \beta_2 \dot q_2

i.e. :math:`\tau = Y(x)\,\theta` with

.. math::

    A &= \tfrac13 m_1 l_1^2 + (m_2 + m_3) l_1^2, &
    B &= \tfrac13 m_2 l_2^2 + m_3 l_2^2, &
    C &= (\tfrac12 m_2 + m_3) l_1 l_2, \\
    D &= g(\tfrac12 m_1 + m_2 + m_3) l_1, &
    E &= g(\tfrac12 m_2 + m_3) l_2 .

Every one of :math:`A \dots E` is affine in :math:`m_3`, so
:math:`\theta = \theta_0 + m\,[\theta_1; 0, 0]` with the *payload parameters*
:math:`\theta_1 = (l_1^2, l_2^2, l_1 l_2, g l_1, g l_2)`; hence

.. math:: \tau_0 = Y(x)\,\theta_0, \qquad \varphi = Y_{1:5}(x)\,\theta_1 .

:func:`base_parameters` gives :math:`(\theta_0, \theta_1)` of a machine, :func:`base_regressor`
evaluates :math:`Y` on arrays; the test suite proves that :math:`Y\theta_0` and
:math:`Y_{1:5}\theta_1` equal the symbolic ``ArmModel.torque_empty`` and ``payload_regressor``
(the symbolic model stays the source; this closed form is what makes ``step`` fast).

Noise: total residual covariance and errors in variables
--------------------------------------------------------
The residual :math:`r_k = \tilde\tau_k - \tau_0(\tilde x_k)` uses *measured* kinematics
:math:`\tilde x = x + \delta x` (white, :math:`\Sigma_x = \mathrm{diag}(\sigma^2_{q}, \sigma^2_{\dot
q}, \sigma^2_{\ddot q})`), so to first order

.. math:: r_k - m\varphi(\tilde x_k) = \varepsilon_k - J_k\,\delta x_k, \qquad
          J_k = \frac{\partial \tau}{\partial x}\Big|_{\tilde x_k, \hat m},

with total covariance :math:`R_k = \Sigma_\tau + J_k\Sigma_x J_k^\top` (2×2: the same angle
error moves both joint torques, hence the off-diagonal term). The Jacobian is closed-form, linear
in the base parameters: :math:`J = J_0 + \hat m J_\varphi`. The weight is
:math:`W_k = R_k^{-1}` (``--weighting full``; ``diagonal`` keeps each joint's own total
variance only; ``torque`` ignores the kinematic noise, :math:`W = \Sigma_\tau^{-1}`).

Because the regressor :math:`\varphi(\tilde x)` is itself noisy, plain least squares is biased
(*errors in variables*: regression dilution, and correlation between the noise of
:math:`\varphi(\tilde x)` and of :math:`\tau_0(\tilde x)`). Its first-order expectation is

.. math:: \mathbb E\big[\tilde\varphi^\top W (r - m\tilde\varphi)\big]
          = -\operatorname{tr}(J_\varphi^\top W J_0 \Sigma_x)
            - m\,\operatorname{tr}(J_\varphi^\top W J_\varphi \Sigma_x),

so the bias-corrected estimating equation accumulates (``--eiv-correction true``)

.. math::

    N_k &= \lambda N_{k-1} + \tilde\varphi_k^\top W_k r_k
           + \operatorname{tr}(J_{\varphi,k}^\top W_k J_{0,k}\Sigma_x) \\
    I_k &= \lambda I_{k-1} + \tilde\varphi_k^\top W_k \tilde\varphi_k
           - \operatorname{tr}(J_{\varphi,k}^\top W_k J_{\varphi,k}\Sigma_x) \\
    \hat m_k &= N_k / I_k, \qquad \sigma_{\hat m,k} \approx I_k^{-1/2} .

This information form is exactly the scalar recursive least-squares update
:math:`P_k^{-1} = \lambda P_{k-1}^{-1} + \varphi_k^\top W_k\varphi_k`,
:math:`\hat m_k = \hat m_{k-1} + P_k\varphi_k^\top W_k(r_k - \hat m_{k-1}\varphi_k)`, with
forgetting factor :math:`\lambda` (``--forgetting``, 1 = keep the whole history; e.g. 0.98 to
follow a payload that changes, memory ≈ 1/(1-λ) samples). At the thesis' noise both corrections
are negligible (the kinematic noise adds ≈ 1.6 % to the boom torque's variance, the
errors-in-variables bias is ≈ 0.001 kg); at the ``field`` noise they matter: the kinematic noise
doubles the boom torque's variance (joint correlation ≈ 0.3) and the uncorrected bias is ≈ -4 kg
at 2.5 t (measured on minimum-jerk swings).

Warm-up
-------
The status is ``warming_up`` until the estimate's standard deviation :math:`I_k^{-1/2}` is at
most ``--warmup-std`` kg (default 50 kg = 1 % of a 5 t rated payload); the estimate itself is
returned from the first sample.
"""

from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.schema import SIGNALS
from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.base import Estimator, Option, Status, StepResult, register
from excavator_payload.model.machine import Machine
from excavator_payload.simulation.sensors import get_noise_preset

#: Names of the seven base parameters θ (the columns of the regressor Y).
BASE_PARAMETER_NAMES = ("A", "B", "C", "D", "E", "boom_friction", "dipper_friction")
#: Names of the five payload parameters θ1 (multiplying the first five columns of Y).
PAYLOAD_PARAMETER_NAMES = ("l1^2", "l2^2", "l1*l2", "g*l1", "g*l2")
#: Kinematic signals, in :data:`SIGNALS` order (the order of the Jacobian's columns).
KINEMATIC_SIGNALS = SIGNALS[:6]
#: A time gap up to this long (s) keeps the least-squares sums; a longer one restarts.
MAX_BRIDGED_GAP = 1.0
#: Torque standard deviation used when a noise preset has none (noise-free data), N·m: keeps
#: the weights finite; it only scales the reported uncertainty, not the estimate.
TORQUE_STD_FLOOR = 1.0


def base_parameters(machine: Machine) -> tuple[np.ndarray, np.ndarray]:
    r"""The base parameters :math:`\theta_0` (7, empty bucket) and :math:`\theta_1` (5) of a machine.

    .. math::

        \theta_0 &= \big(\tfrac13 m_1 l_1^2 + (m_2 + m_b) l_1^2,\;
                   \tfrac13 m_2 l_2^2 + m_b l_2^2,\; (\tfrac12 m_2 + m_b) l_1 l_2,\;
                   g(\tfrac12 m_1 + m_2 + m_b) l_1,\; g(\tfrac12 m_2 + m_b) l_2,\;
                   \beta_1,\; \beta_2\big) \\
        \theta_1 &= (l_1^2,\; l_2^2,\; l_1 l_2,\; g l_1,\; g l_2)
    """
    l1, l2 = machine.boom_length, machine.dipper_length
    m1, m2, mb, g = machine.boom_mass, machine.dipper_mass, machine.bucket_mass, machine.gravity
    theta_empty = np.array([
        m1 * l1**2 / 3 + (m2 + mb) * l1**2,
        m2 * l2**2 / 3 + mb * l2**2,
        (m2 / 2 + mb) * l1 * l2,
        g * (m1 / 2 + m2 + mb) * l1,
        g * (m2 / 2 + mb) * l2,
        machine.boom_friction,
        machine.dipper_friction,
    ])
    theta_payload = np.array([l1**2, l2**2, l1 * l2, g * l1, g * l2])
    return theta_empty, theta_payload


# -- closed-form kernels: written once, evaluated on Python floats (streaming) or numpy arrays --

def _columns(s2, c2, c1, c12, qd1, qd2, qdd1, qdd2):
    """Regressor columns Y (see module docstring) as (boom, dipper) pairs; floats or arrays."""
    yb = qdd1 + qdd2
    return (
        (qdd1, 0.0 * qdd1),                                                     # A
        (yb, yb),                                                               # B
        (c2 * (2.0 * qdd1 + qdd2) - s2 * (2.0 * qd1 * qd2 + qd2 * qd2),
         c2 * qdd1 + s2 * qd1 * qd1),                                           # C
        (c1, 0.0 * c1),                                                         # D
        (c12, c12),                                                             # E
        (qd1, 0.0 * qd1),                                                       # β1
        (0.0 * qd2, qd2),                                                       # β2
    )


def _jacobian(A, B, C, D, E, F1, F2, s1, s2, c2, s12, qd1, qd2, qdd1, qdd2):
    r"""∂τ/∂x of :math:`\tau = Y(x)\theta`, columns in :data:`KINEMATIC_SIGNALS` order.

    Returns six (∂τ_boom, ∂τ_dipper) pairs for q1, q̇1, q̈1, q2, q̇2, q̈2.
    """
    return (
        (-D * s1 - E * s12, -E * s12),                                          # q1
        (-2.0 * C * s2 * qd2 + F1, 2.0 * C * s2 * qd1),                         # q̇1
        (A + B + 2.0 * C * c2, B + C * c2),                                     # q̈1
        (C * (-s2 * (2.0 * qdd1 + qdd2) - c2 * (2.0 * qd1 * qd2 + qd2 * qd2)) - E * s12,
         C * (-s2 * qdd1 + c2 * qd1 * qd1) - E * s12),                         # q2
        (-2.0 * C * s2 * (qd1 + qd2), F2),                                      # q̇2
        (B + C * c2, B),                                                        # q̈2
    )


def base_regressor(q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
    """The regressor Y(q, q̇, q̈), shape (..., 2, 7), so that τ = Y θ (joint on axis -2)."""
    q, qd, qdd = (np.asarray(a, dtype=float) for a in (q, qd, qdd))
    q1, q2 = q[..., 0], q[..., 1]
    cols = _columns(np.sin(q2), np.cos(q2), np.cos(q1), np.cos(q1 + q2),
                    qd[..., 0], qd[..., 1], qdd[..., 0], qdd[..., 1])
    return np.stack([np.stack(c, axis=-1) for c in cols], axis=-1)


def torque_jacobian(q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """∂τ/∂(q1, q̇1, q̈1, q2, q̇2, q̈2) of τ = Y θ (θ of length 7), shape (..., 2, 6)."""
    q, qd, qdd = (np.asarray(a, dtype=float) for a in (q, qd, qdd))
    q1, q2 = q[..., 0], q[..., 1]
    theta = np.asarray(theta, dtype=float)
    cols = _jacobian(*(theta[..., i] for i in range(7)), np.sin(q1), np.sin(q2), np.cos(q2),
                     np.sin(q1 + q2), qd[..., 0], qd[..., 1], qdd[..., 0], qdd[..., 1])
    shape = np.broadcast_shapes(q1.shape, theta.shape[:-1])
    return np.stack([np.stack([np.broadcast_to(c[0], shape), np.broadcast_to(c[1], shape)], -1)
                     for c in cols], axis=-1)


def split_torque(q, qd, qdd, theta_empty, theta_payload) -> tuple[np.ndarray, np.ndarray]:
    """(τ0, φ) on arrays: τ0 = Y θ0 and φ = Y[:, :5] θ1, each shape (..., 2)."""
    Y = base_regressor(q, qd, qdd)
    return Y @ np.asarray(theta_empty, float), Y[..., :5] @ np.asarray(theta_payload, float)


def residual_covariance(jac: np.ndarray, kinematic_var: np.ndarray, torque_var: np.ndarray,
                        weighting: str = "full") -> np.ndarray:
    r"""Total residual covariance :math:`R = \Sigma_\tau + J\Sigma_x J^\top`, shape (..., 2, 2).

    ``weighting="diagonal"`` zeroes the cross term, ``"torque"`` returns :math:`\Sigma_\tau`.
    """
    R = np.zeros(jac.shape[:-2] + (2, 2))
    if weighting != "torque":
        R = np.einsum("...ik,k,...jk->...ij", jac, kinematic_var, jac)
        if weighting == "diagonal":
            R[..., 0, 1] = R[..., 1, 0] = 0.0
    R[..., 0, 0] += torque_var[0]
    R[..., 1, 1] += torque_var[1]
    return R


def sensor_variances(noise, torque_floor: float = TORQUE_STD_FLOOR) -> np.ndarray:
    """Variances of the eight :data:`SIGNALS` of a noise preset (torque std floored)."""
    std = get_noise_preset(noise).std_vector(SIGNALS).copy()
    std[6:] = np.maximum(std[6:], torque_floor)
    return std**2


def information_terms(values, theta_empty, theta_payload, variances, weight_payload: float,
                      weighting: str = "full", eiv_correction: bool = True,
                      trig=math) -> tuple[float, float]:
    r"""One sample's contribution :math:`(\Delta N, \Delta I)` to the estimating equation.

    ``values`` is the sample in :data:`SIGNALS` order as Python floats; the arithmetic is plain
    float math (no numpy, no CasADi) so that a streaming step stays in the tens of microseconds.

    Returns
    -------
    (float, float)
        :math:`\tilde\varphi^\top W r + \operatorname{tr}(J_\varphi^\top W J_0\Sigma_x)` and
        :math:`\tilde\varphi^\top W\tilde\varphi - \operatorname{tr}(J_\varphi^\top W J_\varphi
        \Sigma_x)` (the traces only with ``eiv_correction``).
    """
    q1, qd1, qdd1, q2, qd2, qdd2, t1, t2 = values
    s1 = trig.sin(q1)
    c1 = trig.cos(q1)
    s2 = trig.sin(q2)
    c2 = trig.cos(q2)
    s12 = trig.sin(q1 + q2)
    c12 = trig.cos(q1 + q2)
    A0, B0, C0, D0, E0, F1, F2 = theta_empty
    a, b, c, d, e = theta_payload
    (ya1, _), (yb, _), (yc1, yc2), _, _, _, _ = _columns(s2, c2, c1, c12, qd1, qd2, qdd1, qdd2)
    r1 = t1 - (A0 * ya1 + B0 * yb + C0 * yc1 + D0 * c1 + E0 * c12 + F1 * qd1)
    r2 = t2 - (B0 * yb + C0 * yc2 + E0 * c12 + F2 * qd2)
    p1 = a * ya1 + b * yb + c * yc1 + d * c1 + e * c12
    p2 = b * yb + c * yc2 + e * c12

    R11, R22, R12 = variances[6], variances[7], 0.0
    if weighting != "torque" or eiv_correction:
        j0 = _jacobian(A0, B0, C0, D0, E0, F1, F2, s1, s2, c2, s12, qd1, qd2, qdd1, qdd2)
        jp = _jacobian(a, b, c, d, e, 0.0, 0.0, s1, s2, c2, s12, qd1, qd2, qdd1, qdd2)
    if weighting != "torque":
        m = weight_payload
        for k in range(6):
            v = variances[k]
            g1 = j0[k][0] + m * jp[k][0]
            g2 = j0[k][1] + m * jp[k][1]
            R11 += v * g1 * g1
            R22 += v * g2 * g2
            R12 += v * g1 * g2
        if weighting == "diagonal":
            R12 = 0.0
    det = R11 * R22 - R12 * R12
    W11, W22, W12 = R22 / det, R11 / det, -R12 / det
    wp1 = W11 * p1 + W12 * p2
    wp2 = W12 * p1 + W22 * p2
    d_num = wp1 * r1 + wp2 * r2
    d_info = wp1 * p1 + wp2 * p2
    if eiv_correction:
        for k in range(6):
            v = variances[k]
            f1, f2 = jp[k]
            w1 = W11 * f1 + W12 * f2
            w2 = W12 * f1 + W22 * f2
            d_num += v * (w1 * j0[k][0] + w2 * j0[k][1])
            d_info -= v * (w1 * f1 + w2 * f2)
    return d_num, d_info


def residual_nis(values, theta_empty, theta_payload, variances, payload: float,
                 payload_var: float, trig=math) -> float:
    r"""Normalised squared torque residual of one sample at the current payload estimate.

    :math:`r^\top (R + \varphi\varphi^\top \sigma_m^2)^{-1} r` with
    :math:`r = \tau - \tau_0 - m\varphi` and :math:`R = \Sigma_\tau + J\Sigma_x J^\top` the
    sensors' full residual covariance (whatever the ``weighting`` option): chi-square with 2
    degrees of freedom for a sample the noise model describes. Plain float math, as
    :func:`information_terms` (``trig=casadi`` builds the C export's copy of it).
    """
    q1, qd1, qdd1, q2, qd2, qdd2, t1, t2 = values
    s1, c1, s2, c2 = trig.sin(q1), trig.cos(q1), trig.sin(q2), trig.cos(q2)
    s12, c12 = trig.sin(q1 + q2), trig.cos(q1 + q2)
    A0, B0, C0, D0, E0, F1, F2 = theta_empty
    a, b, c, d, e = theta_payload
    (ya1, _), (yb, _), (yc1, yc2), _, _, _, _ = _columns(s2, c2, c1, c12, qd1, qd2, qdd1, qdd2)
    p1 = a * ya1 + b * yb + c * yc1 + d * c1 + e * c12
    p2 = b * yb + c * yc2 + e * c12
    r1 = t1 - (A0 * ya1 + B0 * yb + C0 * yc1 + D0 * c1 + E0 * c12 + F1 * qd1) - payload * p1
    r2 = t2 - (B0 * yb + C0 * yc2 + E0 * c12 + F2 * qd2) - payload * p2
    j0 = _jacobian(A0, B0, C0, D0, E0, F1, F2, s1, s2, c2, s12, qd1, qd2, qdd1, qdd2)
    jp = _jacobian(a, b, c, d, e, 0.0, 0.0, s1, s2, c2, s12, qd1, qd2, qdd1, qdd2)
    R11 = variances[6] + payload_var * p1 * p1
    R22 = variances[7] + payload_var * p2 * p2
    R12 = payload_var * p1 * p2
    for k in range(6):
        v = variances[k]
        g1 = j0[k][0] + payload * jp[k][0]
        g2 = j0[k][1] + payload * jp[k][1]
        R11 += v * g1 * g1
        R22 += v * g2 * g2
        R12 += v * g1 * g2
    det = R11 * R22 - R12 * R12
    return (R22 * r1 * r1 - 2.0 * R12 * r1 * r2 + R11 * r2 * r2) / det


def restore_difference_scale(arrays: Mapping[str, np.ndarray]) -> np.ndarray:
    """The machine set's per-signal outlier-test scale from a saved model (checked)."""
    if "difference_scale" not in arrays:
        raise EstimatorError("saved model predates the machine set's outlier test: fit it again")
    scale = np.asarray(arrays["difference_scale"], float)
    if scale.shape != (15,) or np.any(np.isnan(scale)) or np.any(scale <= 0):
        raise EstimatorError("saved outlier-test scale is corrupt")
    return scale


@register
class InverseDynamicsEstimator(Estimator):
    """Recursive weighted least squares on the payload through the arm's inverse dynamics.

    See the module docstring for the equations. ``fit`` only reads the noise preset of the
    training dataset (``--noise auto``) to set the weights; the physics comes from the machine.
    """

    name = "inverse-dynamics"
    #: On the machine sensor set (a hydraulic machine) the kernel is
    #: :class:`~excavator_payload.estimators.classical.pressure_regression.PressureRegression`.
    SENSOR_SETS = ("thesis", "machine")
    OPTIONS = {
        "forgetting": Option(float, 1.0, "forgetting factor λ in (0, 1]; 1 keeps the whole history"),
        "warmup_std": Option(float, 50.0, "status warming_up until the estimate's std (kg) is at most this"),
        "weighting": Option(str, "full", "residual weights: full total covariance, its diagonal, or "
                            "torque noise only", ("full", "diagonal", "torque")),
        "eiv_correction": Option(bool, True, "correct the errors-in-variables bias of noisy kinematics"),
        "noise": Option(str, "auto", "sensor noise preset for the weights (auto: the training data's)",
                        ("auto", "thesis", "none", "field")),
        "half_window": Option(int, 5, "machine sensor set: samples each side of the centred "
                              "differentiator that gives the accelerations"),
    }

    def __init__(self, machine=None, **options) -> None:
        super().__init__(machine, **options)
        lam = self.options["forgetting"]
        if not (0.0 < lam <= 1.0):
            raise EstimatorError(f"{self.name}: option --forgetting must be in (0, 1], got {lam}")
        if not self.options["warmup_std"] > 0:
            raise EstimatorError(f"{self.name}: option --warmup-std must be > 0 kg")
        if not 1 <= self.options["half_window"] <= 100:
            raise EstimatorError(f"{self.name}: option --half-window must be in 1…100 samples")
        self._pressure = None  # the machine sensor set's kernel, once fitted on such data
        if self._hydraulic:
            self.noise_name = "field"
            self._pressure_noise = (0.0, 0.0)
            self.difference_scale = np.full(15, np.inf)  # the outlier test's scale, from fit data
            self._reset()
            return
        self.theta_empty, self.theta_payload = base_parameters(self.machine)
        self.variances = sensor_variances("thesis")
        self.noise_name = "thesis"
        self._prepare()
        self._reset()


    def _build_pressure_kernel(self) -> None:
        from excavator_payload.estimators.classical.pressure_regression import PressureRegression
        from excavator_payload.model.hydraulic import HydraulicArmModel

        std, ripple = self._pressure_noise
        from excavator_payload.estimators.classical.pressure_regression import spike_threshold

        self._pressure = PressureRegression(HydraulicArmModel(self.machine, compiled=False),
                                            pressure_std=std, ripple_fraction=ripple,
                                            half_window=self.options["half_window"],
                                            forgetting=self.options["forgetting"])
        self._pressure.spike_threshold = spike_threshold(self.difference_scale)
        self._warm_info = 1.0 / float(self.options["warmup_std"]) ** 2

    def _fit_machine_set(self, dataset: Dataset) -> None:
        from excavator_payload.simulation.machine_sensors import get_machine_noise

        from excavator_payload.estimators.classical.pressure_regression import difference_scale

        if not self._hydraulic:
            raise EstimatorError(f"{self.name}: data of the machine sensor set need a hydraulic machine "
                                 f"file, not '{self.machine.name}' (e.g. --machine cat345c-hydraulic)")
        self.difference_scale = difference_scale(dataset)
        name = self.options["noise"]
        if name == "auto":
            name = dataset.meta.get("noise")
        if name is None:  # issue 12: no preset named, the pressure noise is estimated from the data
            from excavator_payload.estimators.classical.calibrated_machine import pressure_noise_from_data

            self.noise_name = "estimated"
            self._pressure_noise = (pressure_noise_from_data(dataset), 0.0)
            self._build_pressure_kernel()
            return
        preset = get_machine_noise(name)
        self.noise_name = preset.name
        self._pressure_noise = (preset.pressure_noise, preset.ripple_fraction)
        self._build_pressure_kernel()

    # -- fitting ---------------------------------------------------------------------------
    def _noise_from(self, dataset: Dataset):
        name = self.options["noise"]
        if name == "auto":
            name = dataset.meta.get("noise")
            if name is None:
                raise EstimatorError(f"{self.name}: the training data names no noise preset; "
                                     "pass --noise thesis|field|none")
        preset = get_noise_preset(name)
        return preset

    def _set_noise(self, preset) -> None:
        self.variances = sensor_variances(preset)
        self.noise_name = get_noise_preset(preset).name
        self._prepare()

    def _fit(self, dataset: Dataset) -> None:
        if dataset.sensor_set.name == "machine":
            self._fit_machine_set(dataset)
            return
        if self._hydraulic:
            raise EstimatorError(f"{self.name}: the hydraulic machine '{self.machine.name}' goes "
                                 "with machine-sensor-set data")
        self._set_noise(self._noise_from(dataset))
        self.theta_empty, self.theta_payload = base_parameters(self.machine)
        self._prepare()

    def _prepare(self) -> None:
        """Cache plain-float copies of the parameters for the streaming kernel."""
        self._th0 = tuple(float(v) for v in self.theta_empty)
        self._th1 = tuple(float(v) for v in self.theta_payload)
        self._var = tuple(float(v) for v in self.variances)
        self._lam = float(self.options["forgetting"])
        self._warm_info = 1.0 / float(self.options["warmup_std"]) ** 2
        self._weighting = self.options["weighting"]
        self._eiv = bool(self.options["eiv_correction"])
        self._default_weight_payload = 0.5 * float(self.machine.max_payload)
        self._max_payload = float(self.machine.max_payload)

    # -- streaming -------------------------------------------------------------------------
    def _reset(self) -> None:
        self._num = 0.0
        self._info = 0.0
        if self._pressure is not None:
            self._pressure.reset()


    def _step(self, time: float, values: np.ndarray) -> StepResult:
        if self._pressure is not None:
            self._pressure.judge = self.gating
            self._pressure.update(time, values)
            self._info = self._pressure.info
            if self._info <= 0.0:
                return StepResult(math.nan, Status.WARMING_UP)
            status = Status.OK if self._info >= self._warm_info else Status.WARMING_UP
            if self._pressure.rejected:  # the sample before this one was a one-frame outlier
                status = Status.REJECTED
            return StepResult(self._pressure.estimate, status)
        if self._info > 0.0:  # weights use the current estimate, kept physical
            m_w = min(max(self._num / self._info, 0.0), self._max_payload)
        else:
            m_w = self._default_weight_payload
        d_num, d_info = information_terms(values.tolist(), self._th0, self._th1, self._var, m_w,
                                          self._weighting, self._eiv)
        self._num = self._lam * self._num + d_num
        self._info = self._lam * self._info + d_info
        if self._info <= 0.0:
            return StepResult(math.nan, Status.WARMING_UP)
        estimate = self._num / self._info
        status = Status.OK if self._info >= self._warm_info else Status.WARMING_UP
        return StepResult(estimate, status)

    # -- gate, uncertainty, state watch (see estimators.base) --------------------------------
    def _innovation(self, time: float, values: np.ndarray) -> tuple[float, int] | None:
        """The sample's torque residual at the current estimate (:func:`residual_nis`), 2 dof.

        On the machine sensor set the kernel judges each sample itself, one sample after it
        arrived (a one-frame outlier test, see
        :mod:`~excavator_payload.estimators.classical.pressure_regression`): None here.
        """
        if self._info <= 0.0 or self._pressure is not None:
            return None
        payload = min(max(self._num / self._info, 0.0), self._max_payload)
        return residual_nis(values.tolist(), self._th0, self._th1, self._var, payload, 1.0 / self._info), 2

    def _estimate_sigma(self) -> float:
        """Standard deviation of the estimate from the accumulated information, kg (I^{-1/2})."""
        return 1.0 / math.sqrt(self._info) if self._info > 0 else math.nan

    def _state_finite(self) -> bool:
        return math.isfinite(self._num) and math.isfinite(self._info)

    def _on_gap(self, time: float, values: np.ndarray) -> None:
        """Samples are independent equations: a gap of up to 1 s keeps the sums, a longer one
        (or time going back: a new lift) restarts. The machine set's differentiator needs evenly
        spaced samples: its window starts again after any gap."""
        if self._last_time is None or not 0.0 < time - self._last_time <= MAX_BRIDGED_GAP:
            self._reset()
        elif self._pressure is not None:
            self._pressure.restart_window()

    @property
    def uncertainty(self) -> float:
        """Current standard deviation of the estimate, kg (I^{-1/2}); inf before any sample."""
        return 1.0 / math.sqrt(self._info) if self._info > 0 else math.inf

    # -- persistence -----------------------------------------------------------------------
    def _config(self) -> dict:
        if self._pressure is not None:
            return {"noise": self.noise_name, "kernel": "pressure_regression"}
        return {"noise": self.noise_name,
                "base_parameter_names": list(BASE_PARAMETER_NAMES),
                "payload_parameter_names": list(PAYLOAD_PARAMETER_NAMES)}

    def _arrays(self) -> dict[str, np.ndarray]:
        if self._pressure is not None:
            return {"pressure_noise": np.asarray(self._pressure_noise, float),
                    "difference_scale": np.asarray(self.difference_scale, float)}
        return {"theta_empty": np.asarray(self.theta_empty, float),
                "theta_payload": np.asarray(self.theta_payload, float),
                "sensor_variances": np.asarray(self.variances, float)}

    def _restore(self, config: dict, arrays: Mapping[str, np.ndarray]) -> None:
        if config.get("kernel") == "pressure_regression":
            noise = np.asarray(arrays["pressure_noise"], float)
            if noise.shape != (2,) or not np.all(np.isfinite(noise)) or not self._hydraulic:
                raise EstimatorError("saved pressure-regression state is corrupt")
            self._pressure_noise = (float(noise[0]), float(noise[1]))
            self.noise_name = str(config.get("noise", "unknown"))
            self.difference_scale = restore_difference_scale(arrays)
            self._build_pressure_kernel()
            return
        theta_empty = np.asarray(arrays["theta_empty"], float)
        theta_payload = np.asarray(arrays["theta_payload"], float)
        variances = np.asarray(arrays["sensor_variances"], float)
        if theta_empty.shape != (7,) or theta_payload.shape != (5,) or variances.shape != (8,):
            raise EstimatorError("saved parameters have the wrong shape (corrupt model folder)")
        if not (np.all(np.isfinite(theta_empty)) and np.all(np.isfinite(theta_payload))
                and np.all(variances > 0)):
            raise EstimatorError("saved parameters are not finite (corrupt model folder)")
        self.theta_empty, self.theta_payload, self.variances = theta_empty, theta_payload, variances
        self.noise_name = str(config.get("noise", "unknown"))
        self._prepare()
