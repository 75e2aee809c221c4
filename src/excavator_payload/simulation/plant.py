r"""The simulated plant: the arm's dynamics integrated accurately under zero-order-hold torques.

The state is :math:`x = [q_1, q_2, \dot q_1, \dot q_2]` (boom angle, dipper angle, their rates)
and the input the two joint torques :math:`u = \tau`, held constant over each interval
(zero-order hold). The right-hand side :math:`\dot x = f(x, u, m)` is
``ArmModel.casadi_function("state_derivative")`` (the single symbolic source), integrated with
the classical fourth-order Runge–Kutta scheme

.. math::

    k_1 &= f(x_n, u),\quad k_2 = f(x_n + \tfrac h2 k_1, u),\quad
    k_3 = f(x_n + \tfrac h2 k_2, u),\quad k_4 = f(x_n + h k_3, u) \\
    x_{n+1} &= x_n + \tfrac h6 (k_1 + 2k_2 + 2k_3 + k_4)

with small substeps :math:`h` (default 2.5 ms: the fastest mode of the arm, about
:math:`-30\,\mathrm{s^{-1}}` with an empty bucket, gives :math:`|h\lambda| < 0.1`; over one
20 Hz sample the state differs from CVODES at 1e-10 tolerance by < 1e-7 rad or rad/s, hundreds of
times below the thesis' smallest sensor noise). :func:`cvodes_integrator` gives the same step with CasADi's adaptive
CVODES integrator; the tests check that both agree.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from excavator_payload.model.codegen import BufferedCall, native
from excavator_payload.model.dynamics import ArmModel

#: Default RK4 substep of the plant, s.
PLANT_SUBSTEP = 0.0025


def rk4_step(f: ca.Function, x, u, payload, h: float):
    """One classical RK4 step of ``xdot = f(x, u, payload)`` of length ``h`` (symbolic or numeric).

    Parameters
    ----------
    f : casadi.Function
        Right-hand side ``(x, u, payload) -> xdot``.
    x : casadi.SX or numpy.ndarray
        State at the start of the step, ``[q1, q2, q1dot, q2dot]`` (rad, rad/s).
    u : casadi.SX or numpy.ndarray
        Joint torques held over the step, N·m.
    payload : casadi.SX or float
        Payload mass, kg.
    h : float
        Step length, s.

    Returns
    -------
    casadi.SX or casadi.DM
        State at the end of the step.
    """
    k1 = f(x, u, payload)
    k2 = f(x + h / 2 * k1, u, payload)
    k3 = f(x + h / 2 * k2, u, payload)
    k4 = f(x + h * k3, u, payload)
    return x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def rk4_sensitivity(stage, x, sensitivity, duration: float, substeps: int):
    """``substeps`` RK4 steps over ``duration`` of a state and its sensitivity by the chain rule
    through the stages: ``stage(x, S)`` gives ẋ and ∂ẋ/∂x · S (plus the held inputs' part),
    and S ← S + h/6 (dk1 + 2dk2 + 2dk3 + dk4), the derivative of the RK4 step.

    Parameters
    ----------
    stage : callable
        ``stage(x, S) -> (xdot, dxdot)`` at one RK4 stage (symbolic).
    x : casadi.SX
        State at the start.
    sensitivity : casadi.SX
        Its sensitivity at the start (identity for the state, zeros for the held inputs).
    duration : float
        Length of the interval, s.
    substeps : int
        Number of equal RK4 steps.

    Returns
    -------
    tuple of casadi.SX
        The state and its sensitivity at the end.
    """
    h = duration / substeps
    S = sensitivity
    for _ in range(substeps):
        k1, d1 = stage(x, S)
        k2, d2 = stage(x + h / 2 * k1, S + h / 2 * d1)
        k3, d3 = stage(x + h / 2 * k2, S + h / 2 * d2)
        k4, d4 = stage(x + h * k3, S + h * d3)
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        S = S + h / 6 * (d1 + 2 * d2 + 2 * d3 + d4)
    return x, S


def rk4_interval(arm: ArmModel, duration: float, substeps: int, name: str = "rk4_interval") -> ca.Function:
    """CasADi function ``(x, u, payload) -> x(t + duration)`` by ``substeps`` RK4 steps, u held.

    Parameters
    ----------
    arm : ArmModel
        The arm whose ``state_derivative`` is integrated.
    duration : float
        Length of the interval, s.
    substeps : int
        Number of equal RK4 steps over the interval.
    name : str
        Name of the CasADi function.

    Returns
    -------
    casadi.Function
        ``(x, u, payload) -> xf``.
    """
    f = arm.casadi_function("state_derivative")
    x = ca.SX.sym("x", 4)
    u = ca.SX.sym("u", 2)
    m = ca.SX.sym("payload")
    h = duration / substeps
    xn = x
    for _ in range(substeps):
        xn = rk4_step(f, xn, u, m, h)
    return ca.Function(name, [x, u, m], [xn], ["x", "u", "payload"], ["xf"])


def cvodes_integrator(arm: ArmModel, duration: float, reltol: float = 1e-10,
                      abstol: float = 1e-10) -> ca.Function:
    """CasADi CVODES integrator over ``duration`` with ``p = [u1, u2, payload]`` held constant.

    Parameters
    ----------
    arm : ArmModel
        The arm whose ``state_derivative`` is integrated.
    duration : float
        Length of the interval, s.
    reltol, abstol : float
        Relative and absolute tolerances of CVODES.

    Returns
    -------
    casadi.Function
        The integrator (inputs ``x0`` and ``p``, output ``xf`` among others).
    """
    f = arm.casadi_function("state_derivative")
    x = ca.SX.sym("x", 4)
    p = ca.SX.sym("p", 3)
    dae = {"x": x, "p": p, "ode": f(x, p[:2], p[2])}
    return ca.integrator("plant_cvodes", "cvodes", dae, 0.0, duration,
                         {"reltol": reltol, "abstol": abstol})


class Plant:
    """The arm of one machine, stepped with zero-order-hold torques.

    Parameters
    ----------
    arm : ArmModel
        The machine's arm model.
    sample_period : float
        Length of one :meth:`step`, s (the 20 Hz sensor period).
    substep : float
        RK4 substep, s.
    """

    def __init__(self, arm: ArmModel, sample_period: float = 0.05, substep: float = PLANT_SUBSTEP):
        self.arm = arm
        self.sample_period = float(sample_period)
        n = max(1, int(round(sample_period / substep)))
        self.substeps = n
        # compiled to C where a compiler exists: the same operations, the same bits, 10× faster
        self._step = native(rk4_interval(arm, self.sample_period, n, "plant_step"))
        self._xdot = native(arm.casadi_function("state_derivative"))
        # numpy in and out through buffers (no DM conversions: most of a step's cost)
        self._step_call = BufferedCall(self._step)
        self._xdot_call = BufferedCall(self._xdot)
        self._hold_calls: dict[int, BufferedCall] = {}

    def _hold_call(self, k: int) -> BufferedCall:
        """One call for :meth:`hold`: the same compiled step and ẋ, ``k`` times, in one graph."""
        if k not in self._hold_calls:
            x, u, m = ca.MX.sym("x", 4), ca.MX.sym("u", 2), ca.MX.sym("payload")
            states, accelerations = [], []
            for _ in range(k):
                states.append(x)
                accelerations.append(self._xdot(x, u, m)[2:])
                x = self._step(x, u, m)
            hold = ca.Function("plant_hold", [states[0], u, m],
                               [ca.horzcat(*states), ca.horzcat(*accelerations), x],
                               ["x", "u", "payload"], ["states", "accelerations", "after"])
            self._hold_calls[k] = BufferedCall(hold)
        return self._hold_calls[k]

    def hold(self, state: np.ndarray, torque: np.ndarray, payload: float, k: int):
        """``k`` sample periods with ``torque`` held: the states at the ``k`` sample instants
        (the first is ``state``), their accelerations, and the state after them.

        Parameters
        ----------
        state : numpy.ndarray
            State ``[q1, q2, q1dot, q2dot]`` (rad, rad/s) at the first instant.
        torque : numpy.ndarray
            Boom and dipper torques, N·m, held over the ``k`` periods.
        payload : float
            Payload mass, kg.
        k : int
            Number of sample periods.

        Returns
        -------
        states : numpy.ndarray
            States at the ``k`` instants, shape (k, 4).
        accelerations : numpy.ndarray
            Accelerations q̈ there under ``torque``, rad/s², shape (k, 2).
        after : numpy.ndarray
            State after the ``k`` periods, shape (4,).
        """
        out = self._hold_call(int(k))(x=state, u=torque, payload=payload)
        return out["states"].reshape(k, 4), out["accelerations"].reshape(k, 2), out["after"]

    def step(self, state: np.ndarray, torque: np.ndarray, payload: float) -> np.ndarray:
        """State after one sample period with ``torque`` held constant.

        Parameters
        ----------
        state : numpy.ndarray
            State ``[q1, q2, q1dot, q2dot]`` (rad, rad/s) at the start of the period.
        torque : numpy.ndarray
            Boom and dipper torques, N·m, held over the period.
        payload : float
            Payload mass, kg.

        Returns
        -------
        numpy.ndarray
            State after :attr:`sample_period`, shape (4,).
        """
        return np.asarray(self._step(state, torque, payload)).ravel()

    def acceleration(self, state: np.ndarray, torque: np.ndarray, payload: float) -> np.ndarray:
        """True joint accelerations q̈ = M⁻¹(τ − h) at ``state`` under ``torque``, rad/s².

        Parameters
        ----------
        state : numpy.ndarray
            State ``[q1, q2, q1dot, q2dot]`` (rad, rad/s).
        torque : numpy.ndarray
            Boom and dipper torques, N·m.
        payload : float
            Payload mass, kg.

        Returns
        -------
        numpy.ndarray
            Boom and dipper accelerations, rad/s², shape (2,).
        """
        return np.asarray(self._xdot(state, torque, payload)).ravel()[2:]
