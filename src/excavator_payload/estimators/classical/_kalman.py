r"""What the EKF and UKF share: the discrete arm model with the payload as a state, and the tunings.

State, input, measurements
--------------------------
.. math::

    x = [q_1, q_2, \dot q_1, \dot q_2, m]^\top, \qquad u = \tau^{meas}, \qquad
    x_{k+1} = f_d(x_k, u_k) = \begin{bmatrix} x_{1:4} + T_s\, f(x_{1:4}, u_k, m) \\ m \end{bmatrix}

with :math:`f` the arm's continuous state derivative
(:func:`excavator_payload.model.dynamics.symbolic` ``state_derivative``) and :math:`T_s = 0.05`
s: the forward-Euler step of the thesis (appendix A.4).

Two tunings
-----------
``thesis`` (§6.1): :math:`y = [q_1, q_2, \dot q_1, \dot q_2]`, :math:`Q = 10^6 I_5` (1.005·10⁶
for the EKF₁% model, 1.01·10⁶ for EKF₃%), :math:`R = \mathrm{diag}(10^{-4}, 10^{-5}, 10^{-4},
10^{-5})`, :math:`P_0 = 5\cdot10^{15} I`, :math:`x_0 = [-0.17, -1.57, 0, 0, 5000]` and the payload
passed through :math:`|x_5|` (appendix A.4: ``Mload = abs(x(5)) + Mbucket``).

``consistent``: every covariance comes from the sensor noise preset of the training data.
The measured torque is the filter *input*, so its noise :math:`v_\tau\sim N(0,\Sigma_\tau)`
becomes process noise through :math:`G = \partial f_d/\partial u` (:math:`T_s M^{-1}` on the
rate states):

.. math:: Q_k = G_k \Sigma_\tau G_k^\top + Q_{disc} + \mathrm{diag}(0,0,0,0,\ \sigma_w^2 T_s)

where :math:`Q_{disc}` covers the Euler step's truncation error (:math:`\tfrac{T_s^2}{2}\ddot q`
on the angles, :math:`\tfrac{T_s^2}{2}\dddot q` on the rates, sized from the training data's
measured accelerations) and :math:`\sigma_w` is the payload random walk (kg/√s).

**Measured accelerations are used.** They are 6× more precise than the accelerations the
torque noise leaves in the model (thesis preset: 1.7·10⁻⁴ vs ≈1.1·10⁻³ rad/s² on the boom), and
the Euler step's truncation error, not the sensors, would otherwise dominate the rate
innovations (min-jerk moves ≈3·10⁻³ rad/s, NMPC moves ≈0.1 rad/s, vs 5.5·10⁻⁵ rad/s of rate
noise). They enter through a second measurement, the torque predicted by inverse dynamics at
the measured acceleration :math:`a_k`, which is *linear* in the payload
(:math:`\tau = \tau_0 + m\varphi`):

.. math::

    y^{(1)}_k = [q, \dot q]^{meas}, \quad h^{(1)}(x) = x_{1:4}, \quad
    R^{(1)} = \mathrm{diag}(\sigma_q^2, \sigma_q^2, \sigma_{\dot q}^2, \sigma_{\dot q}^2) \\
    y^{(2)}_k = \tau^{meas}_k, \quad h^{(2)}(x) = \tau(q, \dot q, a_k, m), \quad
    R^{(2)}_k = \Sigma_\tau + M \Sigma_a M^\top

The two groups have independent noise, so they are processed one after the other (a
*sequential* update): the torques are linearised at the state already corrected by the precise
angle and rate measurements. (Linearising at the prior instead, whose rates are off by the Euler
truncation error, leaves a second-order bias of ~10³ N·m in the Coriolis torques of the NMPC's
fast moves: efficiency ratio 1.6 instead of 1.2.)

The same torque noise drives the process (through :math:`u`) and the torque measurement, so
they are correlated, :math:`S_k = E[w_k e_k^{(2)\top}] = -G_k \Sigma_\tau`. The filters
decorrelate them the textbook way (Simon, *Optimal State Estimation*, §7.1): with
:math:`D_k = S_k (R^{(2)}_k)^{-1}` the prediction becomes

.. math::

    \bar x_{k+1} = f_d(\hat x_k, u_k) + D_k\,(\tau^{meas}_k - h^{(2)}(\hat x_k)), \qquad
    \tilde F_k = F_k - D_k H^{(2)}_k, \qquad \tilde Q_k = Q_k - D_k S_k^\top.

Initial state: angles and rates from the first sample (broad prior around it), payload
:math:`m_0 = m_{max}/2` with :math:`\sigma_0 = m_{max}/2`, so one σ covers the whole range.
"""

from __future__ import annotations

import re
import warnings
from dataclasses import dataclass, field
from functools import lru_cache

import casadi as ca
import numpy as np

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.schema import SAMPLE_PERIOD, SIGNALS
from excavator_payload.errors import EstimatorError, ExcavatorPayloadError
from excavator_payload.model.codegen import native
from excavator_payload.model.dynamics import ArmModel
from excavator_payload.model.machine import Machine
from excavator_payload.platforms import THESIS

TS = SAMPLE_PERIOD  # s, the thesis' Euler step (appendix A.4)
N_STATE = 5
PAYLOAD = 4  # index of the payload in the state

# Positions of the filter's inputs inside a sample (SIGNALS order).
ANGLES = [SIGNALS.index("boom_angle"), SIGNALS.index("dipper_angle")]
RATES = [SIGNALS.index("boom_rate"), SIGNALS.index("dipper_rate")]
ACCELS = [SIGNALS.index("boom_accel"), SIGNALS.index("dipper_accel")]
TORQUES = [SIGNALS.index("boom_torque"), SIGNALS.index("dipper_torque")]
MEASURED = ANGLES + RATES  # y = [q1, q2, qd1, qd2]

#: Thesis §6.1: Q = scale · I5, per machine model (EKF_ideal, EKF_1%, EKF_3%).
THESIS_Q_SCALE = {"cat345c": 1.0e6, "cat345c-1pct": 1.005e6, "cat345c-3pct": 1.01e6}
THESIS_R = np.diag([1e-4, 1e-5, 1e-4, 1e-5])
THESIS_P0 = 5e15
THESIS_X0 = np.array([-0.17, -1.57, 0.0, 0.0, 5000.0])

#: Smallest standard deviations used when a noise preset says 0 (keeps R invertible).
STD_FLOOR = {"angle": 1e-7, "rate": 1e-7, "accel": 1e-6, "torque": 1.0}


def _c_name(text: str) -> str:
    """A C identifier made from ``text`` (machine names become function names)."""
    return re.sub(r"\W", "_", text)


# -- the compiled model ----------------------------------------------------------------------
@dataclass(frozen=True)
class KalmanModel:
    """Compiled CasADi functions of the discrete model, for one machine.

    ``terms(x, u, a)`` returns one packed vector with, evaluated at ``x``:
    ``f_d`` (5), ``F = ∂f_d/∂x`` (5×5), ``G = ∂f_d/∂u`` (5×2), ``h`` (6), ``H = ∂h/∂x`` (6×5)
    and the mass matrix ``M`` (2×2); see :meth:`unpack`. ``transition(x, u)`` and
    ``measurement(x, a)`` are ``f_d`` and ``h`` as CasADi functions (for building graphs).

    Parameters
    ----------
    machine : Machine
        The 2-link machine the model is built for.
    abs_payload : bool
        Whether the model uses ``|payload|`` (thesis tuning) instead of the signed payload.
    terms, transition, measurement : casadi.Function
        The compiled functions described above.
    """

    machine: Machine
    abs_payload: bool
    terms: ca.Function = field(compare=False)
    transition: ca.Function = field(compare=False)
    measurement: ca.Function = field(compare=False)

    def evaluator(self):
        """A private, low-overhead caller of :attr:`terms`: ``(x, u, a) -> (f, F, G, h, H, M)``."""
        call = BufferedFunction(self.terms)
        return lambda x, u, a: KalmanModel.unpack(call(x, u, a))

    @staticmethod
    def unpack(packed: np.ndarray):
        """Split the packed output of :attr:`terms` into ``(f, F, G, h, H, M)`` (column-major
        matrices, shapes as in the class docstring).

        Parameters
        ----------
        packed : numpy.ndarray
            The 80 values :attr:`terms` returns.
        """
        v = np.asarray(packed).ravel()
        f = v[0:5]
        F = v[5:30].reshape(5, 5, order="F")
        G = v[30:40].reshape(5, 2, order="F")
        h = v[40:46]
        H = v[46:76].reshape(6, 5, order="F")
        M = v[76:80].reshape(2, 2, order="F")
        return f, F, G, h, H, M


class BufferedFunction:
    """Calls a CasADi function with dense inputs/outputs through its buffer interface.

    A plain ``Function.__call__`` converts numpy arrays to ``DM`` and back (≈50 µs for the
    filter's functions); the buffer interface evaluates in place into numpy memory (≈15 µs).
    One instance per filter: the buffers are private state.

    Parameters
    ----------
    function : casadi.Function
        The function to call (dense inputs, first output only).
    """

    def __init__(self, function: ca.Function):
        self._function = function  # the buffers point into it: keep it alive as long as we are
        self._inputs = [np.zeros(function.nnz_in(i)) for i in range(function.n_in())]
        self._out = np.zeros(function.nnz_out(0))
        self._buffer, self._trigger = function.buffer()
        for i, array in enumerate(self._inputs):
            self._buffer.set_arg(i, memoryview(array))
        self._buffer.set_res(0, memoryview(self._out))

    def __call__(self, *args: np.ndarray) -> np.ndarray:
        """The (first) output for ``args``, as a new 1-d array (column-major for matrices)."""
        for i, value in enumerate(args):
            self.set_input(i, value)
        self._trigger()
        return self._out.copy()

    def set_input(self, index: int, value: np.ndarray) -> None:
        """Write input ``index`` (kept until overwritten: constants need writing once).

        Parameters
        ----------
        index : int
            Input position of the function.
        value : numpy.ndarray
            The input value (flattened column-major).
        """
        self._inputs[index][:] = np.ravel(value, order="F")

    def evaluate(self, *leading: np.ndarray) -> np.ndarray:
        """Like ``__call__`` but only the first inputs are given; the rest keep their values.

        Inputs must be 1-d or symmetric (written in memory order, no transpose).
        """
        inputs = self._inputs
        for i, value in enumerate(leading):
            inputs[i][:] = value.reshape(-1)
        self._trigger()
        return self._out.copy()


@lru_cache(maxsize=16)
def kalman_model(machine: Machine, abs_payload: bool) -> KalmanModel:
    """Build (once per machine and payload convention) the compiled filter model."""
    arm = ArmModel(machine)
    state_derivative = arm.casadi_function("state_derivative")
    inverse_dynamics = arm.casadi_function("inverse_dynamics")
    mass_matrix = arm.casadi_function("mass_matrix")
    x = ca.SX.sym("x", N_STATE)
    u = ca.SX.sym("u", 2)   # measured torques (input)
    a = ca.SX.sym("a", 2)   # measured accelerations (torque-channel measurement)
    # Appendix A.4: the thesis feeds |x5| to the model and carries |x5| forward.
    payload = ca.fabs(x[PAYLOAD]) if abs_payload else x[PAYLOAD]
    xdot = state_derivative(x[0:4], u, payload)
    f_d = ca.vertcat(x[0:4] + TS * xdot, payload)
    h = ca.vertcat(x[0:4], inverse_dynamics(x[0:2], x[2:4], a, payload))
    M = mass_matrix(x[0:2], payload)
    F = ca.jacobian(f_d, x)
    G = ca.jacobian(f_d, u)
    H = ca.jacobian(h, x)
    packed = ca.densify(ca.vertcat(f_d, ca.vec(F), ca.vec(G), h, ca.vec(H), ca.vec(M)))
    tag = _c_name(machine.name) + ("_abs" if abs_payload else "")
    terms = native(ca.Function(f"kalman_terms_{tag}", [x, u, a], [ca.cse(packed)], ["x", "u", "a"],
                               ["packed"]))
    transition = ca.Function(f"kalman_f_{tag}", [x, u], [f_d], ["x", "u"], ["f_d"])
    measurement = ca.Function(f"kalman_h_{tag}", [x, a], [h], ["x", "a"], ["h"])
    return KalmanModel(machine, abs_payload, terms, transition, measurement)


@lru_cache(maxsize=16)
def ekf_step_function(machine: Machine, abs_payload: bool, torque_channel: bool) -> ca.Function:
    """:func:`ekf_step_symbolic`, compiled to C when a compiler is available."""
    return native(ekf_step_symbolic(machine, abs_payload, torque_channel))


@lru_cache(maxsize=16)
def ekf_step_symbolic(machine: Machine, abs_payload: bool, torque_channel: bool) -> ca.Function:
    r"""One whole EKF step (update with :math:`y_k`, then prediction with :math:`u_k`) as one
    CasADi function (compiled by :func:`ekf_step_function`; exported to C for an ECU by
    :mod:`excavator_payload.runtime.export_c`), so a 20 Hz step costs one call instead of dozens
    of numpy calls.

    Inputs ``x, P`` (prior), ``y`` (4 or 6), ``u``, ``a``, ``Q`` (5×5), ``R`` (4×4),
    ``torque_cov``, ``accel_cov`` (2×2). Output: one dense vector
    ``[x_post (5), vec P_post (25), x_next (5), vec P_next (25)]``. The equations are those of
    :mod:`excavator_payload.estimators.classical.ekf`, line by line: a sequential update
    (angles and rates first, then the torques linearised at the updated state), then the
    decorrelated prediction.
    """
    model = kalman_model(machine, abs_payload)
    n_y = 6 if torque_channel else 4
    x = ca.SX.sym("x", N_STATE)
    P = ca.SX.sym("P", N_STATE, N_STATE)
    y = ca.SX.sym("y", n_y)
    u = ca.SX.sym("u", 2)
    a = ca.SX.sym("a", 2)
    Q0 = ca.SX.sym("Q", N_STATE, N_STATE)
    R_qqd = ca.SX.sym("R", 4, 4)
    torque_cov = ca.SX.sym("torque_cov", 2, 2)
    accel_cov = ca.SX.sym("accel_cov", 2, 2)

    # Update 1: angles and rates, h = x[0:4] (linear).
    H1 = ca.horzcat(ca.SX.eye(4), ca.SX.zeros(4, 1))
    x_post, P_post = joseph_update(x, P, y[0:4] - x[0:4], H1, R_qqd)
    if torque_channel:
        # Update 2: torques, linearised at the angles and rates just measured.
        torque_h = model.measurement(x, a)[4:6]
        torque_H = ca.jacobian(torque_h, x)
        M = ca.reshape(kalman_mass_matrix(model)(x), 2, 2)
        torque_R = torque_cov + M @ accel_cov @ M.T
        at_post = [ca.substitute(e, x, x_post) for e in (torque_h, torque_H, torque_R)]
        x_post, P_post = joseph_update(x_post, P_post, y[4:6] - at_post[0], at_post[1], at_post[2])

    # Prediction at the posterior.
    f = model.transition(x_post, u)
    F = ca.substitute(ca.jacobian(model.transition(x, u), x), x, x_post)
    if torque_channel:
        G = ca.substitute(ca.jacobian(model.transition(x, u), u), x, x_post)
        h_post, H_post, R_post = (ca.substitute(e, x, x_post) for e in (torque_h, torque_H, torque_R))
        G_sigma = G @ torque_cov
        D = -scaled_solve(R_post, G_sigma.T, R_post).T   # D = S R⁻¹, S = E[w eᵀ] = −G Σ_τ
        x_next = f + D @ (y[4:6] - h_post)
        F_tilde = F - D @ H_post
        P_next = F_tilde @ P_post @ F_tilde.T + G_sigma @ G.T + Q0 + D @ G_sigma.T   # Q − D Sᵀ
    else:
        x_next = f
        P_next = F @ P_post @ F.T + Q0
    P_next = 0.5 * (P_next + P_next.T)
    packed = ca.cse(ca.densify(ca.vertcat(x_post, ca.vec(P_post), x_next, ca.vec(P_next))))
    tag = _c_name(machine.name) + ("_abs" if abs_payload else "") + ("_tau" if torque_channel else "")
    return ca.Function(f"ekf_step_{tag}", [x, P, y, u, a, Q0, R_qqd, torque_cov, accel_cov],
                       [packed], ["x", "P", "y", "u", "a", "Q", "R", "torque_cov", "accel_cov"],
                       ["packed"])


@lru_cache(maxsize=16)
def gate_function(machine: Machine, abs_payload: bool, torque_channel: bool) -> ca.Function:
    """:func:`gate_symbolic`, compiled to C when a compiler is available."""
    return native(gate_symbolic(machine, abs_payload, torque_channel))


@lru_cache(maxsize=16)
def gate_symbolic(machine: Machine, abs_payload: bool, torque_channel: bool) -> ca.Function:
    r"""Normalised innovation squared of a sample at the prior, as one compiled function.

    Inputs ``x, P, y`` (4 or 6), ``a``, ``R`` (4×4), ``torque_cov``, ``accel_cov``; output
    :math:`\nu^\top S^{-1}\nu` with :math:`\nu = y - h(x)` and :math:`S = HPH^\top +
    \mathrm{blockdiag}(R, \Sigma_\tau + M\Sigma_a M^\top)` (angles and rates only without the
    torque channel). The statistical gate of the filters (see :mod:`excavator_payload.estimators.base`).
    """
    model = kalman_model(machine, abs_payload)
    n_y = 6 if torque_channel else 4
    x = ca.SX.sym("x", N_STATE)
    P = ca.SX.sym("P", N_STATE, N_STATE)
    y = ca.SX.sym("y", n_y)
    a = ca.SX.sym("a", 2)
    R_qqd = ca.SX.sym("R", 4, 4)
    torque_cov = ca.SX.sym("torque_cov", 2, 2)
    accel_cov = ca.SX.sym("accel_cov", 2, 2)
    h = model.measurement(x, a)[:n_y]
    H = ca.jacobian(h, x)
    R = ca.SX.zeros(n_y, n_y)
    R[:4, :4] = R_qqd
    if torque_channel:
        M = ca.reshape(kalman_mass_matrix(model)(x), 2, 2)
        R[4:, 4:] = torque_cov + M @ accel_cov @ M.T
    S = H @ P @ H.T + R
    nu = y - h
    nis = nu.T @ scaled_solve(S, nu, S)
    tag = _c_name(machine.name) + ("_abs" if abs_payload else "") + ("_tau" if torque_channel else "")
    return ca.Function(f"kalman_gate_{tag}", [x, P, y, a, R_qqd, torque_cov, accel_cov],
                       [ca.cse(nis)], ["x", "P", "y", "a", "R", "torque_cov", "accel_cov"], ["nis"])


def joseph_update(x, P, innovation, H, R):
    r"""Kalman measurement update in Joseph form.

    .. math::

        S = H P H^\top + R,\quad K = P H^\top S^{-1},\quad x^+ = x + K\nu,\quad
        P^+ = (I - KH) P (I - KH)^\top + K R K^\top

    Parameters
    ----------
    x : casadi.SX
        Prior state (5).
    P : casadi.SX
        Prior covariance (5 × 5).
    innovation : casadi.SX
        Measurement minus prediction, ν.
    H : casadi.SX
        Measurement Jacobian.
    R : casadi.SX
        Measurement noise covariance.

    Returns
    -------
    tuple of casadi.SX
        Posterior ``(x, P)``, P symmetrised.
    """
    S = H @ P @ H.T + R
    K = scaled_solve(S, H @ P, R).T              # P Hᵀ S⁻¹ (S, P symmetric)
    x_new = x + K @ innovation
    I_KH = ca.SX.eye(N_STATE) - K @ H
    P_new = I_KH @ P @ I_KH.T + K @ R @ K.T
    return x_new, 0.5 * (P_new + P_new.T)


def scaled_solve(A: ca.SX, B: ca.SX, R: ca.SX) -> ca.SX:
    r""":math:`A^{-1}B` for a covariance-like ``A``, solved in measurement-σ units.

    The measurements span 14 orders of magnitude (10⁻⁸ rad² … 10⁶ N²m²) and CasADi's symbolic
    solve does not pivot, so the system is first scaled by :math:`W = \mathrm{diag}(R)^{-1/2}`:
    :math:`A^{-1}B = W (W A W)^{-1} W B`.

    Parameters
    ----------
    A : casadi.SX
        Square covariance-like matrix (e.g. the innovation covariance S).
    B : casadi.SX
        Right-hand side, as many rows as ``A``.
    R : casadi.SX
        Measurement noise covariance whose diagonal sets the scaling.
    """
    w = 1.0 / ca.sqrt(ca.diag(R))
    W = ca.diag(w)
    return W @ ca.solve(W @ A @ W, W @ B)


@lru_cache(maxsize=16)
def sigma_point_function(machine: Machine, abs_payload: bool, n_points: int) -> ca.Function:
    """``(X (5×N), u, a) -> [vec f_d(X) (5N), vec h(X) (6N)]``: the model at all sigma points."""
    model = kalman_model(machine, abs_payload)
    X = ca.SX.sym("X", N_STATE, n_points)
    u = ca.SX.sym("u", 2)
    a = ca.SX.sym("a", 2)
    f = ca.horzcat(*[model.transition(X[:, i], u) for i in range(n_points)])
    h = ca.horzcat(*[model.measurement(X[:, i], a) for i in range(n_points)])
    tag = _c_name(machine.name) + ("_abs" if abs_payload else "")
    return native(ca.Function(f"sigma_points_{tag}", [X, u, a],
                              [ca.cse(ca.densify(ca.vertcat(ca.vec(f), ca.vec(h))))], ["X", "u", "a"],
                              ["packed"]))


def kalman_mass_matrix(model: KalmanModel) -> ca.Function:
    """M(q, m) of the filter state x (payload convention of ``model``).

    Parameters
    ----------
    model : KalmanModel
        The compiled model (machine and payload convention).

    Returns
    -------
    casadi.Function
        ``x -> vec(M)`` (2 × 2, kg·m²).
    """
    arm = ArmModel(model.machine)
    x = ca.SX.sym("x", N_STATE)
    payload = ca.fabs(x[PAYLOAD]) if model.abs_payload else x[PAYLOAD]
    return ca.Function("mass_matrix_of_state", [x], [ca.vec(arm.casadi_function("mass_matrix")(x[0:2], payload))])


# -- tunings ---------------------------------------------------------------------------------
@dataclass
class Tuning:
    """Covariances and initial conditions of one filter (everything that is saved).

    Parameters
    ----------
    name : str
        ``"thesis"`` or ``"consistent"``.
    Q, R, torque_cov, accel_cov : numpy.ndarray
        Covariances as described under Attributes (SI units squared).
    x0 : numpy.ndarray
        Initial state (rad, rad/s, kg).
    P0 : numpy.ndarray
        Initial covariance.
    init_from_sample : bool
        Whether angles and rates start at the first sample.
    noise : str
        Noise preset the covariances come from.

    Attributes
    ----------
    name : ``"thesis"`` or ``"consistent"``.
    Q : (5, 5) constant part of the process noise covariance.
    R : (4, 4) covariance of the angle and rate measurements.
    torque_cov : (2, 2) Σ_τ of the measured torques (zeros for ``thesis``: no torque channel).
    accel_cov : (2, 2) Σ_a of the measured accelerations.
    x0 : (5,) initial state (angles/rates replaced by the first sample when ``init_from_sample``).
    P0 : (5, 5) initial covariance.
    init_from_sample : whether angles and rates start at the first sample.
    noise : name of the noise preset the covariances come from (``consistent``).
    """

    name: str
    Q: np.ndarray
    R: np.ndarray
    torque_cov: np.ndarray
    accel_cov: np.ndarray
    x0: np.ndarray
    P0: np.ndarray
    init_from_sample: bool
    noise: str = ""

    @property
    def torque_channel(self) -> bool:
        """Whether the torque (measured-acceleration) measurement is used."""
        return self.name == "consistent"

    def arrays(self) -> dict[str, np.ndarray]:
        """The covariances and initial state to save (``Q``, ``R``, ``torque_cov``, ``accel_cov``,
        ``x0``, ``P0``)."""
        return {"Q": self.Q, "R": self.R, "torque_cov": self.torque_cov, "accel_cov": self.accel_cov,
                "x0": self.x0, "P0": self.P0}

    def config(self) -> dict:
        """The JSON-able part to save: tuning name, ``init_from_sample`` and noise preset."""
        return {"tuning": self.name, "init_from_sample": self.init_from_sample, "noise": self.noise}

    @classmethod
    def restore(cls, config: dict, arrays) -> "Tuning":
        """The tuning saved by :meth:`config` and :meth:`arrays`; :class:`EstimatorError` when an
        array is missing, of the wrong shape or not finite.

        Parameters
        ----------
        config : dict
            What :meth:`config` returned.
        arrays : Mapping[str, numpy.ndarray]
            What :meth:`arrays` returned.
        """
        shapes = {"Q": (5, 5), "R": (4, 4), "torque_cov": (2, 2), "accel_cov": (2, 2), "x0": (5,),
                  "P0": (5, 5)}
        values = {}
        for key, shape in shapes.items():
            if key not in arrays:
                raise EstimatorError(f"saved filter has no array '{key}'")
            value = np.asarray(arrays[key], dtype=float)
            if value.shape != shape or not np.all(np.isfinite(value)):
                raise EstimatorError(f"saved filter array '{key}' is corrupt (shape {value.shape})")
            values[key] = value
        return cls(name=str(config["tuning"]), init_from_sample=bool(config["init_from_sample"]),
                   noise=str(config.get("noise", "")), **values)


def thesis_tuning(machine: Machine) -> Tuning:
    """Thesis §6.1: Q = 10⁶·I (1.005·10⁶ EKF₁%, 1.01·10⁶ EKF₃%), R, P0 = 5·10¹⁵·I, fixed x0.

    Parameters
    ----------
    machine : Machine
        The machine (its name picks Q's scale).
    """
    scale = THESIS_Q_SCALE.get(machine.name, THESIS_Q_SCALE["cat345c"])
    return Tuning(name="thesis", Q=scale * np.eye(N_STATE), R=THESIS_R.copy(),
                  torque_cov=np.zeros((2, 2)), accel_cov=np.zeros((2, 2)), x0=THESIS_X0.copy(),
                  P0=THESIS_P0 * np.eye(N_STATE), init_from_sample=False)


def euler_truncation_std(dataset: Dataset, quantile: float = 0.99) -> tuple[np.ndarray, np.ndarray]:
    r"""Size of the Euler step's local truncation error, from the data's measured accelerations.

    One Euler step misses :math:`\tfrac{T_s^2}{2}\ddot q` on the angles and
    :math:`\tfrac{T_s^2}{2}\dddot q` on the rates. The jerk is the difference of consecutive
    measured accelerations over :math:`T_s` (within each experiment). The error is systematic,
    not white, so the filter gets its ``quantile`` (99 %), not its RMS.

    Parameters
    ----------
    dataset : Dataset
        Training data with ``boom_accel`` and ``dipper_accel``, rad/s².
    quantile : float
        Quantile of the absolute acceleration / jerk used, in (0, 1).

    Returns
    -------
    angle_std, rate_std : (2,) arrays, rad and rad/s.
    """
    accel = dataset.signals(["boom_accel", "dipper_accel"])
    if len(accel) == 0:
        raise EstimatorError("the training dataset has no samples")
    exp = dataset.frame["experiment"].to_numpy()
    same_experiment = exp[1:] == exp[:-1]
    jerk = np.diff(accel, axis=0)[same_experiment] / TS  # never across two experiments
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns: handled below
        angle = np.nanquantile(np.abs(accel), quantile, axis=0) * TS**2 / 2
        rate = (np.nanquantile(np.abs(jerk), quantile, axis=0) * TS**2 / 2 if len(jerk)
                else np.zeros(2))
    return np.nan_to_num(angle), np.nan_to_num(rate)


def consistent_tuning(machine: Machine, noise: str, angle_trunc: np.ndarray, rate_trunc: np.ndarray,
                      payload_walk: float) -> Tuning:
    """Covariances from the sensor noise preset ``noise`` (see the module docstring).

    Parameters
    ----------
    machine : Machine
        The machine (its maximum payload sets x0 and P0, kg).
    noise : str
        Sensor noise preset name.
    angle_trunc, rate_trunc : numpy.ndarray
        Euler truncation errors (2 each), rad and rad/s (:func:`euler_truncation_std`).
    payload_walk : float
        Payload random walk, kg/√s.

    Returns
    -------
    Tuning
        The ``consistent`` tuning.
    """
    try:
        preset = THESIS.noise(noise)
    except ExcavatorPayloadError as exc:
        raise EstimatorError(str(exc)) from None
    std = preset.std

    def floor(value: float, kind: str) -> float:
        return max(float(value), STD_FLOOR[kind])

    angle_std = [floor(std["boom_angle"], "angle"), floor(std["dipper_angle"], "angle")]
    rate_std = [floor(std["boom_rate"], "rate"), floor(std["dipper_rate"], "rate")]
    accel_std = [floor(std["boom_accel"], "accel"), floor(std["dipper_accel"], "accel")]
    torque_std = [floor(std["boom_torque"], "torque"), floor(std["dipper_torque"], "torque")]
    # Euler truncation error (plus the sensors' own floor so Q stays positive definite).
    Q = np.diag(np.r_[np.square(angle_trunc) + np.square(angle_std) * 1e-2,
                      np.square(rate_trunc) + np.square(rate_std) * 1e-2,
                      payload_walk**2 * TS])
    R = np.diag(np.square(angle_std + rate_std))
    x0 = np.r_[0.0, 0.0, 0.0, 0.0, machine.max_payload / 2]
    # Broad prior around the first sample: it carries (almost) no information of its own.
    P0 = np.diag(np.r_[1e4 * np.square(angle_std), 1e4 * np.square(rate_std),
                       (machine.max_payload / 2) ** 2])
    return Tuning(name="consistent", Q=Q, R=R, torque_cov=np.diag(np.square(torque_std)),
                  accel_cov=np.diag(np.square(accel_std)), x0=x0, P0=P0, init_from_sample=True,
                  noise=preset.name)


def dataset_noise(dataset: Dataset, override: str) -> str:
    """The noise preset to tune for: the option if given, else the dataset's metadata.

    Parameters
    ----------
    dataset : Dataset
        Training data (its ``noise`` metadata).
    override : str
        The ``--noise`` option (empty: not given).

    Returns
    -------
    str
        The preset name.
    """
    if override:
        return override
    noise = dataset.meta.get("noise")
    if not noise:
        raise EstimatorError("--tuning consistent needs the sensor noise level: the dataset names no "
                             "noise preset, pass --noise thesis|none|field")
    return str(noise)


def symmetrise(P: np.ndarray) -> np.ndarray:
    """(P + Pᵀ)/2: keeps rounding from making the covariance asymmetric.

    Parameters
    ----------
    P : numpy.ndarray
        A square matrix.
    """
    return 0.5 * (P + P.T)


def sample_parts(values: np.ndarray, tuning: Tuning):
    """Split a sample (SIGNALS order) into measurement y, input u and measured acceleration a.

    Parameters
    ----------
    values : numpy.ndarray
        The sample, :data:`SIGNALS` order (SI units).
    tuning : Tuning
        The tuning (whether the torque channel is measured).

    Returns
    -------
    tuple of numpy.ndarray
        ``(y, u, a)``.
    """
    u = values[TORQUES]
    a = values[ACCELS]
    y = values[MEASURED + TORQUES] if tuning.torque_channel else values[MEASURED]
    return y, u, a


def initial_state(tuning: Tuning, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """x0, P0 for the first sample of an experiment.

    Parameters
    ----------
    tuning : Tuning
        The tuning (x0, P0, ``init_from_sample``).
    values : numpy.ndarray
        The first sample, :data:`SIGNALS` order (SI units).
    """
    x = tuning.x0.copy()
    if tuning.init_from_sample:
        x[:4] = values[MEASURED]
    return x, tuning.P0.copy()


def payload_bounds(machine: Machine) -> tuple[float, float]:
    """Box the payload state is kept in: the bucket mass must stay positive for M⁻¹ to exist.

    Parameters
    ----------
    machine : Machine
        The machine (bucket mass, maximum and rated payload, kg).

    Returns
    -------
    tuple of float
        ``(low, high)``, kg.
    """
    return -0.5 * machine.bucket_mass, 20.0 * max(machine.max_payload, machine.rated_payload)


# -- sigma-point helpers (the UKF) ------------------------------------------------------------

def covariance_sqrt(P: np.ndarray) -> np.ndarray:
    """Lower Cholesky factor of P, repairing P first if rounding left it indefinite.

    Parameters
    ----------
    P : numpy.ndarray
        Covariance matrix (n × n).
    """
    try:
        return np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        return np.linalg.cholesky(repair_covariance(P))


def repair_covariance(P: np.ndarray, floor: float = 1e-12) -> np.ndarray:
    """Nearest-ish positive definite P: clip the eigenvalues of its correlation matrix.

    Working on the correlation matrix keeps states of very different scale (rad² vs kg²) from
    being clipped by one absolute threshold.

    Parameters
    ----------
    P : numpy.ndarray
        Covariance matrix (n × n).
    floor : float
        Smallest variance and correlation eigenvalue kept.
    """
    P = symmetrise(P)
    d = np.sqrt(np.maximum(np.diag(P), floor))
    C = P / np.outer(d, d)
    eigval, eigvec = np.linalg.eigh(C)
    C = (eigvec * np.maximum(eigval, floor)) @ eigvec.T
    return symmetrise(C * np.outer(d, d))


def statistical_linearisation(P: np.ndarray, P_xy: np.ndarray) -> np.ndarray:
    """H_s = P_xyᵀ P⁻¹, solved on the correlation matrix of P (states of very different scale).

    Parameters
    ----------
    P : numpy.ndarray
        State covariance (n × n).
    P_xy : numpy.ndarray
        State-measurement cross covariance (n × m).

    Returns
    -------
    numpy.ndarray
        H_s, shape (m, n).
    """
    d = np.sqrt(np.maximum(np.diag(P), 1e-300))
    C = P / np.outer(d, d)
    try:
        return (np.linalg.solve(C, P_xy / d[:, None]) / d[:, None]).T
    except np.linalg.LinAlgError:
        return (np.linalg.lstsq(C, P_xy / d[:, None], rcond=None)[0] / d[:, None]).T
