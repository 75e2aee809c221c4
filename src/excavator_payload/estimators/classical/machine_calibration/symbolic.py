r"""The symbolic residuals of the machine-set calibration and the streaming kernels' functions.

Everything here is built from the hydraulic model's symbolic source
(``HydraulicSymbolic.functions``, :func:`~excavator_payload.model.hydraulic.hydraulic_symbolic`)
called on CasADi symbols; no physics is derived by hand. A raw sample :math:`\tilde x` is first
corrected (:func:`_corrected_signals`): offsets :math:`o` removed, then the IMUs' dynamic error
(output lag :math:`\tau`, the inclination fusion's acceleration leak :math:`k`),

.. math:: q_j = \tilde q_j - o_j + \tau\dot q_j - k_j a_j + k_{j-1} a_{j-1}, \qquad
          \dot q = \tilde{\dot q} - o + \tau\ddot q,

with :math:`a_j` the link's absolute angular acceleration. The residual of one sample, per arm
joint :math:`j` (boom, dipper, bucket), is that of
:class:`~excavator_payload.estimators.classical.pressure_regression.PressureRegression`,

.. math:: r_j(z) = \text{count}_j\,\partial l_j/\partial q_j\,\big((\tilde p_h - o_h)A_h
          - (\tilde p_r - o_r)A_r - F_{f,j}\big) - \tau_{0,j}(q, \dot q, \ddot q,
          \text{tilt}) - m\,\varphi_j(\dots),

at the parameters :math:`p = p_\text{file}\odot(1 + \delta)` (:func:`_unpack`). Its Jacobian
:math:`\partial r/\partial z` is CasADi's (:func:`residual_function`). The momentum form
(:func:`momentum_function`) takes ``momentum_regression`` instead: per sample the momentum
:math:`P_0 + m P_m` and the integrand :math:`I_0 + m F_m` of Lagrange's equation read as a
momentum balance (windowed in :mod:`.data`). :func:`kernel_function` compiles one streaming
sample of either form.
"""

from __future__ import annotations

from functools import lru_cache

import casadi as ca

from excavator_payload.estimators.classical.machine_calibration.settings import (
    _OFFSET_COLUMNS, _PARAM_INDEX, CALIBRATED_PARAMETERS, IMU_PARAMETERS, OFFSET_SIGNALS, SIGNALS)
from excavator_payload.estimators.classical.pressure_regression import ANGLES, PITCH, PRESSURES, RATES, ROLL
from excavator_payload.model.codegen import native
from excavator_payload.model.hydraulic import HYDRAULIC_PARAMETER_NAMES, hydraulic_symbolic


def house_imu_leak(slew_rate, slew_accel):
    r"""The slew accelerations the house IMU's sensitivity k multiplies: the measured pitch
    carries :math:`+k\,\dot\psi^2` (centripetal, the IMU ahead of the slew axis), the measured
    roll :math:`-k\,\ddot\psi` (tangential). One definition for the kernel
    (:func:`_corrected_signals`) and the calibration's read-off
    (:func:`~.data.house_imu_sensitivity`); numbers or CasADi symbols.

    Parameters
    ----------
    slew_rate : float, numpy.ndarray or casadi.SX
        Slew rate, rad/s.
    slew_accel : float, numpy.ndarray or casadi.SX
        Slew acceleration, rad/s².

    Returns
    -------
    centripetal, tangential
        :math:`\dot\psi^2` ((rad/s)², into pitch, +k) and :math:`\ddot\psi` (rad/s², into
        roll, −k).
    """
    return slew_rate**2, slew_accel


def _corrected_signals(x, qdd, offsets, imu):
    """Symbolic sensor correction of one raw sample: offsets, then the IMUs' dynamic error.

    Returns the joint angles ``q`` (4, slew 0), rates ``qd`` (4), ground tilt (2) and pressures
    (6) the arm model takes. ``offsets`` has one entry per signal (zeros where none is
    estimated); ``imu`` = (lag τ, the boom, dipper and bucket IMUs' and the house IMU's
    acceleration sensitivity k, s²) — see the module doc.
    """
    corr = [x[i] - offsets[i] for i in range(len(SIGNALS))]
    lag, k_links, k_house = imu[0], [imu[1], imu[2], imu[3]], imu[4]
    rates = [corr[i] for i in RATES]
    # a first-order lag τ delays a signal by τ at the frequencies of arm motion: the true value
    # is the measured one plus τ times its derivative (the rate for an angle, the derived
    # acceleration for a rate)
    angles = [corr[i] + lag * rates[j] for j, i in enumerate(ANGLES)]
    qd = ca.vertcat(*[rates[j] + lag * qdd[j] for j in range(4)])
    # an inclination IMU's fusion reads part of its link's tangential acceleration as tilt:
    # k_j times the link's absolute angular acceleration; a relative angle is the difference
    # of two IMUs (the boom's reference, the house, does not pitch with the arm)
    absolute = [qdd[0], qdd[0] + qdd[1], qdd[0] + qdd[1] + qdd[2]]
    for j in range(3):
        angles[j] = angles[j] - k_links[j] * absolute[j] + (k_links[j - 1] * absolute[j - 1] if j else 0)
    q = ca.vertcat(*angles, 0)
    # the house IMU ahead of the slew axis: centripetal acceleration into pitch, tangential
    # into roll
    centripetal, tangential = house_imu_leak(rates[3] + lag * qdd[3], qdd[3])
    pitch = corr[PITCH] - k_house * centripetal
    roll = corr[ROLL] + k_house * tangential
    # ground tilt from the house IMU at slew angle 0 (inverse of house_inclination at ψ = 0,
    # as pressure_regression.ground_tilt)
    tilt = ca.vertcat(ca.asin(ca.sin(pitch) / ca.cos(roll)), roll)
    pressures = ca.vertcat(*[corr[i] for i in PRESSURES])
    return q, qd, tilt, pressures


def _unpack(p_file, z):
    """Symbolic z = (δ, o, imu) as the model's parameter vector p = p_file ⊙ (1 + δ), the
    offsets over all signals (zeros where none is estimated) and the IMU dynamics."""
    n_delta, n_off = len(CALIBRATED_PARAMETERS), len(OFFSET_SIGNALS)
    scale = ca.SX.ones(len(HYDRAULIC_PARAMETER_NAMES))
    for k, i in enumerate(_PARAM_INDEX):
        scale[int(i)] = 1 + z[k]
    offsets = ca.SX.zeros(len(SIGNALS))
    for k, i in enumerate(_OFFSET_COLUMNS):
        offsets[int(i)] = z[n_delta + k]
    return p_file * scale, offsets, z[n_delta + n_off:]


@lru_cache(maxsize=1)
def residual_function() -> ca.Function:
    """CasADi function of one sample: residual (3), its Jacobian by z (3×nz) and the kernel's
    lever, rod speed and stiction torque (3 each).

    Inputs: signals (15, raw measured), qdd (4), payload, p (file), z = (δ, o, imu).
    """
    sym = hydraulic_symbolic()
    f = sym.functions["pressure_regression"]
    n_delta, n_off, n_imu = len(CALIBRATED_PARAMETERS), len(OFFSET_SIGNALS), len(IMU_PARAMETERS)
    x = ca.SX.sym("x", len(SIGNALS))
    qdd = ca.SX.sym("qdd", 4)
    payload = ca.SX.sym("payload")
    p_file = ca.SX.sym("p", len(HYDRAULIC_PARAMETER_NAMES))
    z = ca.SX.sym("z", n_delta + n_off + n_imu)
    p, offsets, imu = _unpack(p_file, z)
    q, qd, tilt, pressures = _corrected_signals(x, qdd, offsets, imu)
    residual, phi, lever, speed, stiction = f(q, qd, qdd, tilt, pressures, p)
    r = residual - payload * phi
    # ∂r/∂q̈ carries the differentiator's noise into the residual (weights)
    inertia = ca.sum2(ca.jacobian(r, qdd) ** 2)
    return ca.Function("cal_machine_residual", [x, qdd, payload, p_file, z],
                       [r, ca.jacobian(r, z), lever, speed, stiction, inertia, ca.jacobian(r, payload)])


def _momentum_terms(x, qdd, p, offsets, imu, sign=None):
    """Symbolic momentum-balance terms of one raw sample (``HydraulicSymbolic``'s
    ``momentum_regression`` behind the sensor correction): (P0, Pm, I0, Fm) (12), lever,
    rod speed, stiction and the rates' gain into the momentum (3 each). With ``sign`` the seal
    friction's presliding state is given (``momentum_regression_held``), else a smooth sign of
    the rod speed."""
    q, qd, tilt, pressures = _corrected_signals(x, qdd, offsets, imu)
    functions = hydraulic_symbolic().functions
    if sign is None:
        terms = functions["momentum_regression"](q, qd, tilt, pressures, p)
    else:
        terms = functions["momentum_regression_held"](q, qd, tilt, pressures, sign, p)
    P0, Pm, I0, Fm, lever, speed, stiction, gain = terms
    return ca.vertcat(P0, Pm, I0, Fm), lever, speed, stiction, gain


@lru_cache(maxsize=4)
def compiled(name: str) -> ca.Function:
    """``residual`` or ``momentum``: the batch functions of calibration and zero, compiled to C
    (:func:`~excavator_payload.model.codegen.native`; CasADi's virtual machine where no compiler
    is). Calibration evaluates them on every sample once per iteration: on three swings the
    virtual machine took 10 of the 15 s. (The streaming kernels, :func:`kernel_function`, are
    compiled already.)"""
    return native({"residual": residual_function, "momentum": momentum_function}[name]())


@lru_cache(maxsize=1)
def momentum_function() -> ca.Function:
    """CasADi function of one sample for calibration and zero: the momentum-balance terms A
    (12), ∂A/∂z (12×nz), lever, rod speed and stiction (3 each). Inputs as
    :func:`residual_function` but no payload (A is split by it) and with the seals' presliding
    state last (3, :func:`held_direction`): a stopped seal holds the friction of its last
    sliding direction, which the smooth sign of the streaming kernel cannot know. The windows
    keep their standstill variance (the state is not known to the millimetre of presliding,
    nor before a cylinder's first sliding)."""
    n_delta, n_off, n_imu = len(CALIBRATED_PARAMETERS), len(OFFSET_SIGNALS), len(IMU_PARAMETERS)
    x = ca.SX.sym("x", len(SIGNALS))
    qdd = ca.SX.sym("qdd", 4)
    p_file = ca.SX.sym("p", len(HYDRAULIC_PARAMETER_NAMES))
    z = ca.SX.sym("z", n_delta + n_off + n_imu)
    sign = ca.SX.sym("sign", 3)
    A, lever, speed, stiction, _ = _momentum_terms(x, qdd, *_unpack(p_file, z), sign=sign)
    # how the rates' white noise enters (the windows' noise model): through the momentum at the
    # window's ends, at the sample's payload (∂(P0 + m Pm)/∂rates, 3×4 each), and through each
    # sample's integrand, by the seal friction and the centrifugal and Coriolis forces (for the
    # dipper and bucket more than the pressures' noise near standstill)
    dA = ca.jacobian(A, x)[:, RATES]
    return ca.Function("cal_machine_momentum", [x, qdd, p_file, z, sign],
                       [A, ca.jacobian(A, z), lever, speed, stiction, dA[0:3, :], dA[3:6, :],
                        ca.sum2(dA[6:9, :] ** 2)])


@lru_cache(maxsize=2)
def kernel_function(balance: str = "differentiated") -> ca.Function:
    """One streaming sample, compiled, from raw signals (15), q̈ (4), p, the offsets (one per
    signal) and the IMU dynamics (:data:`IMU_PARAMETERS`), corrected as in calibration.

    ``differentiated``: residual τ_p − τ0 (3), φ (3), lever, rod speed and stiction torque (3
    each). ``momentum``: the momentum-balance terms (P0, Pm, I0, Fm) (12), lever, rod speed,
    stiction and the rates' gain into the momentum (3 each); q̈ serves the IMU correction only.
    """
    x = ca.SX.sym("x", len(SIGNALS))
    qdd = ca.SX.sym("qdd", 4)
    p = ca.SX.sym("p", len(HYDRAULIC_PARAMETER_NAMES))
    offsets = ca.SX.sym("offsets", len(SIGNALS))
    imu = ca.SX.sym("imu", len(IMU_PARAMETERS))
    if balance == "momentum":
        A, lever, speed, stiction, gain = _momentum_terms(x, qdd, p, offsets, imu)
        out = ca.vertcat(A, lever, speed, stiction, gain)
        name = "cal_machine_momentum_kernel"
    else:
        q, qd, tilt, pressures = _corrected_signals(x, qdd, offsets, imu)
        residual, phi, lever, speed, stiction = hydraulic_symbolic().functions["pressure_regression"](
            q, qd, qdd, tilt, pressures, p)
        out = ca.vertcat(residual, phi, lever, speed, stiction)
        name = "cal_machine_kernel"
    function = ca.Function(name, [x, qdd, p, offsets, imu], [out])
    return native(function)
