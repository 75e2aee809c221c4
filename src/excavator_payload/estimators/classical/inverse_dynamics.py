r"""Inverse-dynamics payload estimator: recursive weighted least squares on the payload mass.

The arm's torques are affine in the payload (:mod:`excavator_payload.model.dynamics`),

.. math:: \tau_k = \tau_0(x_k) + m\,\varphi(x_k) + \varepsilon_k,
          \qquad x_k = (q_k, \dot q_k, \ddot q_k),

so with measured kinematics and torques the payload is a linear regression (the approach of the
thesis' ref. [40], "A Method for Payload Estimation in Excavators"), here made noise-aware.

Base-parameter model, generated from the symbolic one
-----------------------------------------------------
The torques are a linear combination of seven *base parameters*
:math:`\theta = (A, B, C, D, E, \beta_1, \beta_2)`, :math:`\tau = Y(x)\,\theta`, with a regressor
:math:`Y` that holds no machine parameter. Nothing of it is written out here: the symbolic model
(:mod:`excavator_payload.model.dynamics`) generates :math:`Y` (the payload column
:math:`\varphi = \partial\tau/\partial m` is a quadratic form in the lengths and gravity whose
coefficients are the first five columns; the friction columns are :math:`\partial\tau/\partial
\beta_i`) and solves for :math:`\theta_0` of a machine. For the thesis' arm they work out to

.. math::

    \tau_1 &= A\ddot q_1 + B(\ddot q_1 + \ddot q_2)
              + C\,[c_2(2\ddot q_1 + \ddot q_2) - s_2(2\dot q_1\dot q_2 + \dot q_2^2)]
              + D c_1 + E c_{12} + \beta_1 \dot q_1 \\
    \tau_2 &= B(\ddot q_1 + \ddot q_2) + C\,[c_2\ddot q_1 + s_2\dot q_1^2] + E c_{12}
              + \beta_2 \dot q_2, \\
    A &= \tfrac13 m_1 l_1^2 + (m_2 + m_3) l_1^2, \quad
    B = \tfrac13 m_2 l_2^2 + m_3 l_2^2, \quad
    C = (\tfrac12 m_2 + m_3) l_1 l_2, \\
    D &= g(\tfrac12 m_1 + m_2 + m_3) l_1, \quad
    E = g(\tfrac12 m_2 + m_3) l_2

(a test checks the solved :math:`\theta_0` against this hand calculation). Every one of
:math:`A \dots E` is affine in :math:`m_3 = m_b + m`, so
:math:`\theta = \theta_0 + m\,[\theta_1; 0, 0]` with the *payload parameters*
:math:`\theta_1 = (l_1^2, l_2^2, l_1 l_2, g l_1, g l_2)`; hence

.. math:: \tau_0 = Y(x)\,\theta_0, \qquad \varphi = Y_{1:5}(x)\,\theta_1 .

The estimator's kernels (:func:`information_function`, :func:`nis_function`: the sample's
information terms and gate statistic, with the Jacobians :math:`\partial\tau/\partial x` by
CasADi's automatic differentiation) are CasADi functions of :math:`(x, \theta_0, \theta_1)` built
on :math:`Y`, compiled to C once per user (:mod:`excavator_payload.model.codegen`) and called
through CasADi's buffer interface, so that ``step`` stays in the tens of microseconds; the
calibrated estimator identifies :math:`(\theta_0, \theta_1)` with the same regressor, and the C
export generates its code from the same functions.

Noise: total residual covariance and errors in variables
--------------------------------------------------------
The residual :math:`r_k = \tilde\tau_k - \tau_0(\tilde x_k)` uses *measured* kinematics
:math:`\tilde x = x + \delta x` (white, :math:`\Sigma_x = \mathrm{diag}(\sigma^2_{q}, \sigma^2_{\dot
q}, \sigma^2_{\ddot q})`), so to first order

.. math:: r_k - m\varphi(\tilde x_k) = \varepsilon_k - J_k\,\delta x_k, \qquad
          J_k = \frac{\partial \tau}{\partial x}\Big|_{\tilde x_k, \hat m},

with total covariance :math:`R_k = \Sigma_\tau + J_k\Sigma_x J_k^\top` (2×2: the same angle
error moves both joint torques, hence the off-diagonal term). The Jacobian (automatic differentiation of
:math:`Y\theta`) is linear in the base parameters: :math:`J = J_0 + \hat m J_\varphi`. The weight is
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
from functools import lru_cache
from typing import Mapping

import casadi as ca
import numpy as np

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.schema import SIGNALS
from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.base import Estimator, Option, Status, StepResult, register
from excavator_payload.estimators.classical.kernels import PayloadKernel, UnfittedKernel, saved_kernel
from excavator_payload.estimators.classical.pressure_regression import (  # noqa: F401 (re-exported)
    PressureKernel, restore_difference_scale)
from excavator_payload.model.codegen import native
from excavator_payload.model.dynamics import (
    BASE_PARAMETER_NAMES,
    PAYLOAD_PARAMETER_NAMES,
    ArmModel,
    base_regressor,  # noqa: F401 (re-exported: calibrated.py and the tests import it from here)
    symbolic,
)
from excavator_payload.model.machine import Machine
from excavator_payload.platforms import HYDRAULIC, THESIS, platform_for

#: Kinematic signals, in :data:`SIGNALS` order (the order of the Jacobian's columns).
KINEMATIC_SIGNALS = SIGNALS[:6]
#: A time gap up to this long (s) keeps the least-squares sums; a longer one restarts.
MAX_BRIDGED_GAP = 1.0
#: Torque standard deviation used when a noise preset has none (noise-free data), N·m: keeps
#: the weights finite; it only scales the reported uncertainty, not the estimate.
TORQUE_STD_FLOOR = 1.0


def base_parameters(machine: Machine) -> tuple[np.ndarray, np.ndarray]:
    r"""The base parameters :math:`\theta_0` (7, empty bucket) and :math:`\theta_1` (5) of a machine.

    From the symbolic model (:meth:`~excavator_payload.model.dynamics.ArmModel.base_parameters`);
    for the thesis' uniform bars they are

    .. math::

        \theta_0 &= \big(\tfrac13 m_1 l_1^2 + (m_2 + m_b) l_1^2,\;
                   \tfrac13 m_2 l_2^2 + m_b l_2^2,\; (\tfrac12 m_2 + m_b) l_1 l_2,\;
                   g(\tfrac12 m_1 + m_2 + m_b) l_1,\; g(\tfrac12 m_2 + m_b) l_2,\;
                   \beta_1,\; \beta_2\big) \\
        \theta_1 &= (l_1^2,\; l_2^2,\; l_1 l_2,\; g l_1,\; g l_2)

    Parameters
    ----------
    machine : Machine
        The 2-link machine model.

    Returns
    -------
    tuple of numpy.ndarray
        ``(theta_0, theta_1)``, lengths 7 and 5, SI units (as in the formulas above).
    """
    return ArmModel(machine).base_parameters()


# -- the kernel: CasADi functions generated from the symbolic model, compiled ------------------

def _kinematics(values: ca.SX) -> tuple[ca.SX, ca.SX, ca.SX]:
    """(q, q̇, q̈) of a sample in :data:`SIGNALS` order."""
    return (ca.vertcat(values[0], values[3]), ca.vertcat(values[1], values[4]),
            ca.vertcat(values[2], values[5]))


def _split_symbolic(values: ca.SX, theta_empty: ca.SX, theta_payload: ca.SX):
    r"""τ0 = Yθ0, φ = Y_{1:5}θ1 and their Jacobians J0, Jφ (2×6, :data:`KINEMATIC_SIGNALS`)."""
    Y = symbolic().functions["base_regressor"](*_kinematics(values))
    tau0 = ca.mtimes(Y, theta_empty)
    phi = ca.mtimes(Y[:, :len(PAYLOAD_PARAMETER_NAMES)], theta_payload)
    kinematics = values[:len(KINEMATIC_SIGNALS)]
    return tau0, phi, ca.jacobian(tau0, kinematics), ca.jacobian(phi, kinematics)


def _symbols():
    n_signals, n_empty, n_payload = len(SIGNALS), len(BASE_PARAMETER_NAMES), len(PAYLOAD_PARAMETER_NAMES)
    return (ca.SX.sym("values", n_signals), ca.SX.sym("theta_empty", n_empty),
            ca.SX.sym("theta_payload", n_payload), ca.SX.sym("variances", n_signals))


def _add_kinematic_covariance(R11, R22, R12, j0, jp, payload, variances):
    r"""(R11, R22, R12) plus :math:`J\Sigma_x J^\top` at ``payload`` (J = J0 + m Jφ)."""
    for k in range(len(KINEMATIC_SIGNALS)):
        g1 = j0[0, k] + payload * jp[0, k]
        g2 = j0[1, k] + payload * jp[1, k]
        R11 += variances[k] * g1 * g1
        R22 += variances[k] * g2 * g2
        R12 += variances[k] * g1 * g2
    return R11, R22, R12


@lru_cache(maxsize=None)
def information_function(weighting: str = "full", eiv_correction: bool = True) -> ca.Function:
    r"""CasADi function ``(values, theta_empty, theta_payload, variances, m_w) -> (dN, dI)``.

    The sample's contribution to the estimating equation (module docstring), built on the
    symbolic model's base regressor; ``m_w`` is the payload the weights are evaluated at.
    """
    values, th0, th1, variances = _symbols()
    m_w = ca.SX.sym("m_w")
    tau0, phi, j0, jp = _split_symbolic(values, th0, th1)
    n = len(KINEMATIC_SIGNALS)
    r1, r2 = values[n] - tau0[0], values[n + 1] - tau0[1]
    p1, p2 = phi[0], phi[1]
    R11, R22, R12 = variances[n], variances[n + 1], 0.0
    if weighting != "torque":
        R11, R22, R12 = _add_kinematic_covariance(R11, R22, R12, j0, jp, m_w, variances)
        if weighting == "diagonal":
            R12 = 0.0
    det = R11 * R22 - R12 * R12
    W11, W22, W12 = R22 / det, R11 / det, -R12 / det
    wp1 = W11 * p1 + W12 * p2
    wp2 = W12 * p1 + W22 * p2
    d_num = wp1 * r1 + wp2 * r2
    d_info = wp1 * p1 + wp2 * p2
    if eiv_correction:
        for k in range(n):
            f1, f2 = jp[0, k], jp[1, k]
            w1 = W11 * f1 + W12 * f2
            w2 = W12 * f1 + W22 * f2
            d_num += variances[k] * (w1 * j0[0, k] + w2 * j0[1, k])
            d_info -= variances[k] * (w1 * f1 + w2 * f2)
    eiv = "eiv" if eiv_correction else "plain"
    return ca.Function(f"inverse_dynamics_information_{weighting}_{eiv}",
                       [values, th0, th1, variances, m_w], [ca.cse(ca.vertcat(d_num, d_info))],
                       ["values", "theta_empty", "theta_payload", "variances", "m_w"], ["terms"])


@lru_cache(maxsize=1)
def nis_function() -> ca.Function:
    r"""CasADi function ``(values, theta_empty, theta_payload, variances, payload, payload_var) -> nis``.

    :math:`r^\top (R + \varphi\varphi^\top \sigma_m^2)^{-1} r`, see :func:`residual_nis`.
    """
    values, th0, th1, variances = _symbols()
    payload, payload_var = ca.SX.sym("payload"), ca.SX.sym("payload_var")
    tau0, phi, j0, jp = _split_symbolic(values, th0, th1)
    n = len(KINEMATIC_SIGNALS)
    p1, p2 = phi[0], phi[1]
    r1 = values[n] - tau0[0] - payload * p1
    r2 = values[n + 1] - tau0[1] - payload * p2
    R11, R22, R12 = _add_kinematic_covariance(
        variances[n] + payload_var * p1 * p1, variances[n + 1] + payload_var * p2 * p2,
        payload_var * p1 * p2, j0, jp, payload, variances)
    det = R11 * R22 - R12 * R12
    nis = (R22 * r1 * r1 - 2.0 * R12 * r1 * r2 + R11 * r2 * r2) / det
    return ca.Function("inverse_dynamics_residual_nis",
                       [values, th0, th1, variances, payload, payload_var], [ca.cse(nis)],
                       ["values", "theta_empty", "theta_payload", "variances", "payload",
                        "payload_var"], ["nis"])


@lru_cache(maxsize=1)
def _batch_functions() -> tuple[ca.Function, ca.Function]:
    """(τ0, φ) and ∂τ/∂x of τ = Yθ for one sample, for the array helpers below."""
    values, th0, th1, _ = _symbols()
    theta = ca.SX.sym("theta", len(BASE_PARAMETER_NAMES))
    tau0, phi, _, _ = _split_symbolic(values, th0, th1)
    _, _, jac, _ = _split_symbolic(values, theta, th1)
    return (ca.Function("inverse_dynamics_split", [values, th0, th1], [ca.vertcat(tau0, phi)]),
            ca.Function("inverse_dynamics_jacobian", [values, theta], [ca.vec(jac)]))


@lru_cache(maxsize=None)
def _compiled(name: str, weighting: str = "full", eiv_correction: bool = True) -> ca.Function:
    """The kernel ``name`` compiled to C (:func:`~excavator_payload.model.codegen.native`)."""
    function = nis_function() if name == "nis" else information_function(weighting, eiv_correction)
    return native(function)


def _values_columns(q, qd, qdd, tau=None) -> tuple[np.ndarray, tuple[int, ...]]:
    """Samples in :data:`SIGNALS` order as a (8, N) column matrix, and the leading shape."""
    q, qd, qdd = (np.asarray(a, dtype=float) for a in (q, qd, qdd))
    lead = np.broadcast_shapes(q.shape[:-1], qd.shape[:-1], qdd.shape[:-1])
    q, qd, qdd = (np.broadcast_to(a, lead + (2,)).reshape(-1, 2) for a in (q, qd, qdd))
    tau = np.zeros_like(q) if tau is None else tau
    columns = np.stack([q[:, 0], qd[:, 0], qdd[:, 0], q[:, 1], qd[:, 1], qdd[:, 1],
                        tau[:, 0], tau[:, 1]])
    return np.ascontiguousarray(columns), lead


def torque_jacobian(q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """∂τ/∂(q1, q̇1, q̈1, q2, q̇2, q̈2) of τ = Y θ (θ of length 7), shape (..., 2, 6).

    Parameters
    ----------
    q, qd, qdd : numpy.ndarray
        Joint angles (rad), rates (rad/s) and accelerations (rad/s²), shape (..., 2).
    theta : numpy.ndarray
        Base parameters, shape (..., 7).

    Returns
    -------
    numpy.ndarray
        Shape (..., 2, 6), N·m per unit of each kinematic signal.
    """
    theta = np.asarray(theta, dtype=float)
    q, qd, qdd = (np.asarray(a, dtype=float) for a in (q, qd, qdd))
    lead = np.broadcast_shapes(q.shape[:-1], qd.shape[:-1], qdd.shape[:-1], theta.shape[:-1])
    values, _ = _values_columns(*(np.broadcast_to(a, lead + (2,)) for a in (q, qd, qdd)))
    thetas = np.ascontiguousarray(np.broadcast_to(theta, lead + theta.shape[-1:]).reshape(-1, theta.shape[-1]).T)
    out = np.asarray(_batch_functions()[1](values, thetas)).T  # (N, 12), column-major 2×6
    return out.reshape(lead + (len(KINEMATIC_SIGNALS), 2)).swapaxes(-1, -2)


def split_torque(q, qd, qdd, theta_empty, theta_payload) -> tuple[np.ndarray, np.ndarray]:
    """(τ0, φ) on arrays: τ0 = Y θ0 and φ = Y[:, :5] θ1, each shape (..., 2).

    Parameters
    ----------
    q, qd, qdd : numpy.ndarray
        Joint angles (rad), rates (rad/s) and accelerations (rad/s²), shape (..., 2).
    theta_empty : numpy.ndarray
        Empty-bucket base parameters θ0 (7).
    theta_payload : numpy.ndarray
        Payload base parameters θ1 (5).

    Returns
    -------
    tuple of numpy.ndarray
        ``(tau0, phi)``: N·m and N·m per kg, each shape (..., 2).
    """
    values, lead = _values_columns(q, qd, qdd)
    out = np.asarray(_batch_functions()[0](values, np.asarray(theta_empty, float),
                                           np.asarray(theta_payload, float))).T
    return out[:, :2].reshape(lead + (2,)), out[:, 2:].reshape(lead + (2,))


def residual_covariance(jac: np.ndarray, kinematic_var: np.ndarray, torque_var: np.ndarray,
                        weighting: str = "full") -> np.ndarray:
    r"""Total residual covariance :math:`R = \Sigma_\tau + J\Sigma_x J^\top`, shape (..., 2, 2).

    ``weighting="diagonal"`` zeroes the cross term, ``"torque"`` returns :math:`\Sigma_\tau`.

    Parameters
    ----------
    jac : numpy.ndarray
        Torque Jacobian from :func:`torque_jacobian`, shape (..., 2, 6).
    kinematic_var : numpy.ndarray
        Variances of the six kinematic signals (rad², (rad/s)², (rad/s²)²).
    torque_var : numpy.ndarray
        Variances of the two torques, (N·m)².
    weighting : str
        ``"full"``, ``"diagonal"`` or ``"torque"``.
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
    """Variances of the eight :data:`SIGNALS` of a noise preset (torque std floored).

    Parameters
    ----------
    noise : str or NoisePreset
        The noise preset (name or object).
    torque_floor : float
        Smallest torque standard deviation, N·m.

    Returns
    -------
    numpy.ndarray
        The eight variances, :data:`SIGNALS` order (SI units squared).
    """
    std = THESIS.noise(noise).std_vector(SIGNALS).copy()
    std[6:] = np.maximum(std[6:], torque_floor)
    return std**2


def _evaluate(function: ca.Function, symbolic_out: bool, *args):
    """``function`` on lists/arrays of numbers (floats back) or CasADi symbols (SX back)."""
    out = function(*(ca.vertcat(*a) if isinstance(a, (list, tuple)) else a for a in args))
    if symbolic_out:
        return out
    return np.asarray(out, dtype=float).reshape(-1)


def information_terms(values, theta_empty, theta_payload, variances, weight_payload,
                      weighting: str = "full", eiv_correction: bool = True,
                      trig=math) -> tuple[float, float]:
    r"""One sample's contribution :math:`(\Delta N, \Delta I)` to the estimating equation.

    Evaluates :func:`information_function` (generated from the symbolic model). ``values`` is
    the sample in :data:`SIGNALS` order. With numbers it returns two floats (through CasADi's
    interpreter: the estimator's ``step`` calls the compiled copy instead); with
    ``trig=casadi`` and CasADi symbols it returns the two SX expressions (for the C export).

    Parameters
    ----------
    values : sequence of float or casadi.SX
        The sample, :data:`SIGNALS` order (rad, rad/s, rad/s², N·m).
    theta_empty : sequence of float or casadi.SX
        Empty-bucket base parameters θ0 (7).
    theta_payload : sequence of float or casadi.SX
        Payload base parameters θ1 (5).
    variances : sequence of float or casadi.SX
        Sensor variances, :data:`SIGNALS` order.
    weight_payload : float or casadi.SX
        Payload (kg) at which the weights are evaluated.
    weighting : str
        ``"full"``, ``"diagonal"`` or ``"torque"`` (see :func:`residual_covariance`).
    eiv_correction : bool
        Add the errors-in-variables trace corrections.
    trig : module
        ``math`` (numbers) or ``casadi`` (symbols).

    Returns
    -------
    (float, float)
        :math:`\tilde\varphi^\top W r + \operatorname{tr}(J_\varphi^\top W J_0\Sigma_x)` and
        :math:`\tilde\varphi^\top W\tilde\varphi - \operatorname{tr}(J_\varphi^\top W J_\varphi
        \Sigma_x)` (the traces only with ``eiv_correction``).
    """
    out = _evaluate(information_function(weighting, bool(eiv_correction)), trig is ca, values,
                    theta_empty, theta_payload, variances, weight_payload)
    return (out[0], out[1]) if trig is ca else (float(out[0]), float(out[1]))


def residual_nis(values, theta_empty, theta_payload, variances, payload,
                 payload_var, trig=math) -> float:
    r"""Normalised squared torque residual of one sample at the current payload estimate.

    :math:`r^\top (R + \varphi\varphi^\top \sigma_m^2)^{-1} r` with
    :math:`r = \tau - \tau_0 - m\varphi` and :math:`R = \Sigma_\tau + J\Sigma_x J^\top` the
    sensors' full residual covariance (whatever the ``weighting`` option): chi-square with 2
    degrees of freedom for a sample the noise model describes. Evaluates :func:`nis_function`
    as :func:`information_terms` does (``trig=casadi``: the SX expression for the C export).

    Parameters
    ----------
    values : sequence of float or casadi.SX
        The sample, :data:`SIGNALS` order (rad, rad/s, rad/s², N·m).
    theta_empty : sequence of float or casadi.SX
        Empty-bucket base parameters θ0 (7).
    theta_payload : sequence of float or casadi.SX
        Payload base parameters θ1 (5).
    variances : sequence of float or casadi.SX
        Sensor variances, :data:`SIGNALS` order.
    payload : float or casadi.SX
        Current payload estimate m, kg.
    payload_var : float or casadi.SX
        Its variance σ_m², kg².
    trig : module
        ``math`` (numbers) or ``casadi`` (symbols).

    Returns
    -------
    float or casadi.SX
        The normalised innovation squared.
    """
    out = _evaluate(nis_function(), trig is ca, values, theta_empty, theta_payload, variances,
                    payload, payload_var)
    return out if trig is ca else float(out[0])


class _Kernel:
    """The compiled information terms and gate of one estimator, on preallocated buffers.

    CasADi's buffer interface evaluates in place into numpy memory: a few microseconds per
    call, against ≈ 100 µs through ``Function.__call__`` and its conversions. The parameters
    are written once; per sample only the values and the weighting payload are.
    """

    def __init__(self, theta_empty, theta_payload, variances, weighting: str, eiv_correction: bool):
        self._values = np.zeros(len(SIGNALS))
        self._scalars = np.zeros(2)  # m_w for the terms; payload, payload_var for the gate
        self._parameters = [np.array(theta_empty, float), np.array(theta_payload, float),
                            np.array(variances, float)]
        self._terms_out = np.zeros(2)
        self._nis_out = np.zeros(1)
        self._terms = self._bind(_compiled("terms", weighting, eiv_correction),
                                 [self._scalars[:1]], self._terms_out)
        self._nis = self._bind(_compiled("nis"), [self._scalars[:1], self._scalars[1:]], self._nis_out)

    def _bind(self, function: ca.Function, scalars, out):
        buffer, trigger = function.buffer()
        for i, array in enumerate([self._values, *self._parameters, *scalars]):
            buffer.set_arg(i, memoryview(array))
        buffer.set_res(0, memoryview(out))
        return function, buffer, trigger  # the buffer points into the function: keep both

    def terms(self, values: np.ndarray, weight_payload: float) -> tuple[float, float]:
        self._values[:] = values
        self._scalars[0] = weight_payload
        self._terms[2]()
        out = self._terms_out
        return float(out[0]), float(out[1])

    def nis(self, values: np.ndarray, payload: float, payload_var: float) -> float:
        self._values[:] = values
        self._scalars[0] = payload
        self._scalars[1] = payload_var
        self._nis[2]()
        return float(self._nis_out[0])


class TorqueKernel(PayloadKernel):
    """The thesis' sensor set: the torque residuals' recursive weighted least squares (module doc).

    Parameters
    ----------
    machine : Machine
        The 2-link machine the estimator believes in (its payload range bounds the weights).
    options : dict
        The estimator's options (``weighting``, ``eiv_correction``, ``forgetting``, ``warmup_std``).
    theta_empty, theta_payload : numpy.ndarray
        Base parameters θ0 (7) and θ1 (5).
    variances : numpy.ndarray
        Sensor variances, :data:`SIGNALS` order.
    noise_name : str
        The noise preset the variances come from.
    """

    def __init__(self, machine: Machine, options: dict, theta_empty, theta_payload, variances,
                 noise_name: str) -> None:
        self.theta_empty, self.theta_payload, self.variances = theta_empty, theta_payload, variances
        self.noise_name = noise_name
        self._weighting = options["weighting"]
        self._eiv = bool(options["eiv_correction"])
        self._lam = float(options["forgetting"])
        self._warm_info = 1.0 / float(options["warmup_std"]) ** 2
        self._default_weight_payload = 0.5 * float(machine.max_payload)
        self._max_payload = float(machine.max_payload)
        self._bind()
        self.reset()

    def _bind(self) -> None:
        """Bind the compiled functions to the parameters."""
        self._compiled = _Kernel(self.theta_empty, self.theta_payload, self.variances, self._weighting,
                                 self._eiv)

    # -- picking ---------------------------------------------------------------------------
    @classmethod
    def of_noise(cls, estimator, noise) -> "TorqueKernel":
        """The kernel of ``estimator``'s machine (its file's base parameters) at a noise preset.

        Parameters
        ----------
        estimator : InverseDynamicsEstimator
            The estimator (machine and options).
        noise : str or NoisePreset
            The thesis-set noise preset of the weights.
        """
        theta_empty, theta_payload = base_parameters(estimator.machine)
        return cls(estimator.machine, estimator.options, theta_empty, theta_payload,
                   sensor_variances(noise), THESIS.noise(noise).name)

    @staticmethod
    def fitting_noise(estimator, dataset: Dataset):
        """The noise preset of the weights: ``--noise``, or (``auto``) the one the data name.

        Parameters
        ----------
        estimator : InverseDynamicsEstimator
            The estimator (its name and options).
        dataset : Dataset
            The fitting data.
        """
        if HYDRAULIC.owns(estimator.machine):
            raise EstimatorError(f"{estimator.name}: the hydraulic machine '{estimator.machine.name}' goes "
                                 "with machine-sensor-set data")
        name = estimator.options["noise"]
        if name == "auto":
            name = dataset.meta.get("noise")
            if name is None:
                raise EstimatorError(f"{estimator.name}: the training data name no noise preset; "
                                     "pass --noise thesis|field|none")
        return THESIS.noise(name)

    @classmethod
    def fit(cls, estimator, dataset: Dataset) -> "TorqueKernel":
        """The kernel of the machine file's parameters at the fitting data's noise.

        Parameters
        ----------
        estimator : InverseDynamicsEstimator
            The estimator (machine and options).
        dataset : Dataset
            Thesis-set fitting data (only their noise preset is read).
        """
        return cls.of_noise(estimator, cls.fitting_noise(estimator, dataset))

    # -- streaming -------------------------------------------------------------------------
    def reset(self) -> None:
        """Zero the least-squares sums."""
        self.num = 0.0
        self.info = 0.0

    def step(self, time: float, values: np.ndarray, judge: bool = True,
             joint_check: bool = False) -> StepResult:
        """One sample's information terms, accumulated (``judge``, ``joint_check``: unused, the
        estimator's χ² gate judges the samples through :meth:`innovation`).

        Parameters
        ----------
        time : float
            Sample time, s.
        values : numpy.ndarray
            The sample, :data:`SIGNALS` order (SI units).
        judge : bool
            Unused.
        joint_check : bool
            Unused.
        """
        if self.info > 0.0:  # weights use the current estimate, kept physical
            m_w = min(max(self.num / self.info, 0.0), self._max_payload)
        else:
            m_w = self._default_weight_payload
        d_num, d_info = self._compiled.terms(values, m_w)
        self.num = self._lam * self.num + d_num
        self.info = self._lam * self.info + d_info
        if self.info <= 0.0:
            return StepResult(math.nan, Status.WARMING_UP)
        estimate = self.num / self.info
        status = Status.OK if self.info >= self._warm_info else Status.WARMING_UP
        return StepResult(estimate, status)

    def innovation(self, values: np.ndarray) -> tuple[float, int] | None:
        """The sample's torque residual at the current estimate (:func:`residual_nis`), 2 dof.

        Parameters
        ----------
        values : numpy.ndarray
            The sample, :data:`SIGNALS` order (SI units).
        """
        if self.info <= 0.0:
            return None
        payload = min(max(self.num / self.info, 0.0), self._max_payload)
        return self._compiled.nis(values, payload, 1.0 / self.info), 2

    def terms(self, values: np.ndarray, weight_payload: float) -> tuple[float, float]:
        """The compiled :func:`information_terms` of one sample.

        Parameters
        ----------
        values : numpy.ndarray
            The sample, :data:`SIGNALS` order (SI units).
        weight_payload : float
            Payload at which the weights are evaluated, kg.
        """
        return self._compiled.terms(values, weight_payload)

    def nis(self, values: np.ndarray, payload: float, payload_var: float) -> float:
        """The compiled :func:`residual_nis` of one sample.

        Parameters
        ----------
        values : numpy.ndarray
            The sample, :data:`SIGNALS` order (SI units).
        payload : float
            Payload estimate, kg.
        payload_var : float
            Its variance, kg².
        """
        return self._compiled.nis(values, payload, payload_var)

    def state_finite(self) -> bool:
        """Whether both sums are finite."""
        return math.isfinite(self.num) and math.isfinite(self.info)

    # -- persistence -----------------------------------------------------------------------
    def __getstate__(self) -> dict:
        """The compiled functions' buffers are rebuilt, not pickled (multiprocessing, deepcopy)."""
        state = dict(self.__dict__)
        state.pop("_compiled", None)
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._bind()

    def config(self) -> dict:
        """The noise preset and the base parameters' names."""
        return {"noise": self.noise_name,
                "base_parameter_names": list(BASE_PARAMETER_NAMES),
                "payload_parameter_names": list(PAYLOAD_PARAMETER_NAMES)}

    def arrays(self) -> dict[str, np.ndarray]:
        """θ0, θ1 and the sensor variances."""
        return {"theta_empty": np.asarray(self.theta_empty, float),
                "theta_payload": np.asarray(self.theta_payload, float),
                "sensor_variances": np.asarray(self.variances, float)}

    @classmethod
    def restore(cls, estimator, config: dict, arrays: Mapping[str, np.ndarray]) -> "TorqueKernel":
        """The kernel :meth:`config` and :meth:`arrays` saved (checked).

        Parameters
        ----------
        estimator : InverseDynamicsEstimator
            The estimator being loaded (machine and options).
        config : dict
            The saved state.
        arrays : Mapping[str, numpy.ndarray]
            The saved arrays.
        """
        theta_empty = np.asarray(arrays["theta_empty"], float)
        theta_payload = np.asarray(arrays["theta_payload"], float)
        variances = np.asarray(arrays["sensor_variances"], float)
        if theta_empty.shape != (7,) or theta_payload.shape != (5,) or variances.shape != (8,):
            raise EstimatorError("saved parameters have the wrong shape (corrupt model folder)")
        if not (np.all(np.isfinite(theta_empty)) and np.all(np.isfinite(theta_payload))
                and np.all(variances > 0)):
            raise EstimatorError("saved parameters are not finite (corrupt model folder)")
        return cls(estimator.machine, estimator.options, theta_empty, theta_payload, variances,
                   str(config.get("noise", "unknown")))


@register
class InverseDynamicsEstimator(Estimator):
    """Recursive weighted least squares on the payload through the arm's inverse dynamics.

    See the module docstring for the equations. ``fit`` only reads the noise preset of the
    training dataset (``--noise auto``) to set the weights; the physics comes from the machine.
    The weighing itself is the estimator's :attr:`kernel`, one per platform (:data:`KERNELS`,
    :mod:`~excavator_payload.estimators.classical.kernels`).

    Parameters
    ----------
    machine : Machine, str or None
        The machine model the estimator believes in (preset name or file; None: ``cat345c``).
    **options
        Estimator options, see the class attribute ``OPTIONS``.
    """

    name = "inverse-dynamics"
    # SENSOR_SETS: from its traits (estimators/traits.py)
    OPTIONS = {
        "forgetting": Option(float, 1.0, "forgetting factor λ in (0, 1]; 1 keeps the whole history"),
        "warmup_std": Option(float, 50.0, "status warming_up until the estimate's std (kg) is at most this"),
        "weighting": Option(str, "full", "residual weights: full total covariance, its diagonal, or "
                            "torque noise only", ("full", "diagonal", "torque")),
        "eiv_correction": Option(bool, True, "correct the errors-in-variables bias of noisy kinematics"),
        "noise": Option(str, "auto", "sensor noise preset for the weights (auto: the training data's)",
                        ("auto", "thesis", "none", "field")),
        "half_window": Option(int, 3, "machine sensor set: samples each side of the centred "
                              "differentiator that gives the accelerations (3: measured best on "
                              "NMPC swings and work cycles, 5 on slowly starting swings)"),
    }
    #: The kernel of each platform, by platform name: picked at fit for the data's platform.
    KERNELS: dict[str, type[PayloadKernel]] = {THESIS.name: TorqueKernel, HYDRAULIC.name: PressureKernel}

    def __init__(self, machine=None, **options) -> None:
        super().__init__(machine, **options)
        lam = self.options["forgetting"]
        if not (0.0 < lam <= 1.0):
            raise EstimatorError(f"{self.name}: option --forgetting must be in (0, 1], got {lam}")
        if not self.options["warmup_std"] > 0:
            raise EstimatorError(f"{self.name}: option --warmup-std must be > 0 kg")
        if not 1 <= self.options["half_window"] <= 100:
            raise EstimatorError(f"{self.name}: option --half-window must be in 1…100 samples")
        #: The weighing: until fit, the thesis kernel of the machine file at the default noise;
        #: a hydraulic machine's kernel needs the fitting data (noise, outlier-test scale).
        self.kernel: PayloadKernel = (UnfittedKernel(HYDRAULIC.default_noise) if HYDRAULIC.owns(self.machine)
                                      else self.KERNELS[THESIS.name].of_noise(self, THESIS.default_noise))

    # -- the kernel's parameters, read by the C export and the reports -----------------------
    @property
    def noise_name(self) -> str:
        """The noise preset the weights come from (``estimated``: from the data)."""
        return self.kernel.noise_name

    @property
    def theta_empty(self) -> np.ndarray:
        """Empty-bucket base parameters θ0 (thesis sensor set)."""
        return self.kernel.theta_empty

    @property
    def theta_payload(self) -> np.ndarray:
        """Payload base parameters θ1 (thesis sensor set)."""
        return self.kernel.theta_payload

    @property
    def variances(self) -> np.ndarray:
        """Sensor variances of the weights, :data:`SIGNALS` order (thesis sensor set)."""
        return self.kernel.variances

    # -- fitting ---------------------------------------------------------------------------
    def _set_noise(self, preset) -> None:
        """Weigh with the machine file's parameters at noise ``preset`` (the borrowed gate's
        sentinel, :meth:`Estimator._build_sentinel`)."""
        self.kernel = TorqueKernel.of_noise(self, preset)

    def _fit(self, dataset: Dataset) -> None:
        self.kernel = self.KERNELS[platform_for(dataset).name].fit(self, dataset)

    # -- streaming -------------------------------------------------------------------------
    def _reset(self) -> None:
        self.kernel.reset()

    def _step(self, time: float, values: np.ndarray) -> StepResult:
        # the joint check (calibrated's --joint-check) runs with the health monitor
        joint_check = self.health and self.options.get("joint_check", "off") == "on"
        return self.kernel.step(time, values, judge=self.gating, joint_check=joint_check)

    # -- gate, uncertainty, state watch (see estimators.base) --------------------------------
    def _innovation(self, time: float, values: np.ndarray) -> tuple[float, int] | None:
        """The kernel's χ² statistic of the sample (the thesis set's torque residual, 2 dof); on
        the machine sensor set the kernel judges each sample itself, one sample after it
        arrived (:mod:`~excavator_payload.estimators.classical.pressure_regression`): None."""
        return self.kernel.innovation(values)

    def _estimate_sigma(self) -> float:
        """Standard deviation of the estimate from the accumulated information, kg (I^{-1/2});
        a calibrated machine kernel adds its model error: √(1/I + s_model²)."""
        return self.kernel.sigma()

    def _state_finite(self) -> bool:
        return self.kernel.state_finite()

    def _on_gap(self, time: float, values: np.ndarray) -> None:
        """Samples are independent equations: a gap of up to 1 s keeps the sums, a longer one
        (or time going back: a new lift) restarts. The machine set's differentiator needs evenly
        spaced samples: its window starts again after any gap."""
        if self._last_time is None or not 0.0 < time - self._last_time <= MAX_BRIDGED_GAP:
            self._reset()
        else:
            self.kernel.bridge_gap()

    @property
    def uncertainty(self) -> float:
        """Current standard deviation of the estimate, kg (I^{-1/2}); inf before any sample."""
        info = self.kernel.info
        return 1.0 / math.sqrt(info) if info > 0 else math.inf

    # -- persistence -----------------------------------------------------------------------
    def _config(self) -> dict:
        return self.kernel.config()

    def _arrays(self) -> dict[str, np.ndarray]:
        return self.kernel.arrays()

    def _restore(self, config: dict, arrays: Mapping[str, np.ndarray]) -> None:
        self.kernel = saved_kernel(self.KERNELS, config).restore(self, config, arrays)
