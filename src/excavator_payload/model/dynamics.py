r"""Arm dynamics of the planar boom + dipper excavator arm (thesis §5.2, appendix A.1).

This module is the *single symbolic source* of the physics: the simulator, the NMPC, the EKF
and UKF, the inverse-dynamics and calibrated estimators, the Cramér–Rao bound and the C export
all use the CasADi expressions built here.

Geometry and conventions
------------------------
* ``boom_angle`` :math:`q_1`: boom from the horizontal; ``dipper_angle`` :math:`q_2`: dipper
  relative to the boom; :math:`q_{12} = q_1 + q_2`.
* Boom and dipper are uniform bars (centre of mass at mid-length, inertia
  :math:`J_i = m_i l_i^2/12`); bucket plus payload is a point mass :math:`m_3 = m_b + m` at the
  dipper tip.

Lagrangian (appendix A.1)
-------------------------
.. math::

    K &= \tfrac12 (m_1 \|\dot p_1\|^2 + J_1 \dot q_1^2) + \tfrac12 (m_2 \|\dot p_2\|^2
         + J_2 \dot q_{12}^2) + \tfrac12 m_3 \|\dot p_3\|^2 \\
    P &= g\,(m_1 y_1 + m_2 y_2 + m_3 y_3) \\
    D &= \tfrac12 (\beta_1 \dot q_1^2 + \beta_2 \dot q_2^2) \\
    \tau &= \frac{d}{dt}\frac{\partial K}{\partial \dot q} - \frac{\partial K}{\partial q}
            + \frac{\partial P}{\partial q} + \frac{\partial D}{\partial \dot q}
          = M(q)\ddot q + C(q,\dot q)\dot q + G(q) + B\dot q

The torques are affine in the payload: :math:`\tau = \tau_0(q,\dot q,\ddot q) + m\,\varphi(q,\dot
q,\ddot q)` with the *payload regressor* :math:`\varphi = \partial\tau/\partial m`.

Both are linear in seven lumped *base parameters*: :math:`\tau = Y(q,\dot q,\ddot q)\,(\theta_0
+ m\,[\theta_1; 0; 0])`, with the base regressor :math:`Y` generated here from the torque
(:func:`_base_form`) and :math:`\theta_0` solved for a machine (:meth:`ArmModel.base_parameters`):
the inverse-dynamics and calibrated estimators work on this form.

Numeric evaluation
------------------
:class:`ArmModel` binds a :class:`~excavator_payload.model.machine.Machine` to the symbolic
functions and evaluates them on whole datasets at once: every method takes arrays whose last
axis is the joint (``(..., 2)``) and broadcasts over the leading axes.
"""

from __future__ import annotations

from functools import lru_cache

import casadi as ca
import numpy as np

from excavator_payload.model.machine import Machine, load_machine

#: Order of the machine parameter vector ``p`` fed to every symbolic function.
PARAMETER_NAMES = (
    "boom_length",
    "dipper_length",
    "boom_mass",
    "dipper_mass",
    "bucket_mass",
    "boom_friction",
    "dipper_friction",
    "gravity",
)


#: Names of the seven base parameters θ0 (the columns of the base regressor Y).
BASE_PARAMETER_NAMES = ("A", "B", "C", "D", "E", "boom_friction", "dipper_friction")
#: Names of the five payload parameters θ1 (multiplying the first five columns of Y).
PAYLOAD_PARAMETER_NAMES = ("l1^2", "l2^2", "l1*l2", "g*l1", "g*l2")
#: Fixed motion samples (q1, q2, q̇1, q̇2, q̈1, q̈2) on which the base parameters are solved for:
#: with these the stacked regressor has full column rank and a condition number near 10.
BASE_POINTS = np.array([
    [0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    [0.3, -0.7, 0.5, -0.2, 1.0, 0.4],
    [-0.4, 1.2, -0.8, 0.6, -0.3, 1.1],
    [1.0, -1.5, 0.2, 0.9, 0.7, -0.9],
    [0.7, 0.4, -0.6, -1.0, -1.2, 0.3],
    [-1.1, -0.3, 1.1, 0.3, 0.2, -0.6],
    [0.5, 2.0, 0.9, -0.7, -0.5, 0.8],
])


class Symbolic:
    """The CasADi symbols and expressions of the arm (built once, see :func:`symbolic`).

    Attributes hold SX expressions in the symbols ``q`` (2), ``qd`` (2), ``qdd`` (2),
    ``tau`` (2), ``payload`` (1) and ``p`` (8, :data:`PARAMETER_NAMES`); ``functions`` holds
    the CasADi :class:`casadi.Function` objects built from them.
    """

    def __init__(self) -> None:
        q = ca.SX.sym("q", 2)
        qd = ca.SX.sym("qd", 2)
        qdd = ca.SX.sym("qdd", 2)
        tau = ca.SX.sym("tau", 2)
        payload = ca.SX.sym("payload")
        p = ca.SX.sym("p", len(PARAMETER_NAMES))
        l1, l2, m1, m2, mb, beta1, beta2, g = (p[i] for i in range(len(PARAMETER_NAMES)))
        m3 = mb + payload
        J1 = m1 * l1**2 / 12
        J2 = m2 * l2**2 / 12
        q1, q2 = q[0], q[1]
        q12 = q1 + q2

        # Centres of mass (appendix A.1 poses T1, T2, T3).
        p1 = ca.vertcat(l1 / 2 * ca.cos(q1), l1 / 2 * ca.sin(q1))
        p2 = ca.vertcat(l1 * ca.cos(q1) + l2 / 2 * ca.cos(q12), l1 * ca.sin(q1) + l2 / 2 * ca.sin(q12))
        p3 = ca.vertcat(l1 * ca.cos(q1) + l2 * ca.cos(q12), l1 * ca.sin(q1) + l2 * ca.sin(q12))
        # Velocities by the chain rule: v = (dp/dq) qd.
        v1, v2, v3 = (ca.mtimes(ca.jacobian(pi, q), qd) for pi in (p1, p2, p3))
        qd12 = qd[0] + qd[1]

        kinetic = 0.5 * (m1 * ca.dot(v1, v1) + J1 * qd[0] ** 2) + 0.5 * (
            m2 * ca.dot(v2, v2) + J2 * qd12**2
        ) + 0.5 * m3 * ca.dot(v3, v3)
        potential = g * (m1 * p1[1] + m2 * p2[1] + m3 * p3[1])
        rayleigh = 0.5 * (beta1 * qd[0] ** 2 + beta2 * qd[1] ** 2)

        dK_dqd = ca.gradient(kinetic, qd)
        # d/dt (dK/dqd) = (d/dq dK/dqd) qd + (d/dqd dK/dqd) qdd
        ddt_dK_dqd = ca.mtimes(ca.jacobian(dK_dqd, q), qd) + ca.mtimes(ca.jacobian(dK_dqd, qd), qdd)
        torque = ddt_dK_dqd - ca.gradient(kinetic, q) + ca.gradient(potential, q) + ca.gradient(rayleigh, qd)
        torque = ca.simplify(torque)

        mass_matrix = ca.simplify(ca.hessian(kinetic, qd)[0])
        bias = ca.simplify(ca.substitute(torque, qdd, ca.DM.zeros(2)))  # C qd + G + B qd
        gravity_torque = ca.simplify(ca.gradient(potential, q))
        qdd_forward = ca.solve(mass_matrix, tau - bias)
        regressor = ca.simplify(ca.jacobian(torque, payload))  # ∂τ/∂m, independent of m
        torque_empty = ca.substitute(torque, payload, 0)  # τ0: torque with no payload

        base_regressor, payload_parameters = _base_form(torque, regressor, p, payload)

        state = ca.vertcat(q, qd)
        state_derivative = ca.vertcat(qd, qdd_forward)

        self.q, self.qd, self.qdd, self.tau, self.payload, self.p = q, qd, qdd, tau, payload, p
        self.state = state
        self.kinetic, self.potential, self.rayleigh = kinetic, potential, rayleigh
        self.torque, self.mass_matrix, self.bias = torque, mass_matrix, bias
        self.gravity_torque = gravity_torque
        self.qdd_forward, self.regressor, self.torque_empty = qdd_forward, regressor, torque_empty
        self.state_derivative = state_derivative
        self.tip_position = p3
        self.base_regressor, self.payload_parameters = base_regressor, payload_parameters

        F = ca.Function
        self.functions = {
            "inverse_dynamics": F("inverse_dynamics", [q, qd, qdd, payload, p], [torque],
                                  ["q", "qd", "qdd", "payload", "p"], ["tau"]),
            "forward_dynamics": F("forward_dynamics", [q, qd, tau, payload, p], [qdd_forward],
                                  ["q", "qd", "tau", "payload", "p"], ["qdd"]),
            "mass_matrix": F("mass_matrix", [q, payload, p], [mass_matrix], ["q", "payload", "p"], ["M"]),
            "bias": F("bias", [q, qd, payload, p], [bias], ["q", "qd", "payload", "p"], ["h"]),
            "gravity_torque": F("gravity_torque", [q, payload, p], [gravity_torque],
                                ["q", "payload", "p"], ["G"]),
            "payload_regressor": F("payload_regressor", [q, qd, qdd, p], [regressor],
                                   ["q", "qd", "qdd", "p"], ["phi"]),
            "torque_empty": F("torque_empty", [q, qd, qdd, p], [torque_empty],
                              ["q", "qd", "qdd", "p"], ["tau0"]),
            "energy": F("energy", [q, qd, payload, p], [kinetic, potential],
                        ["q", "qd", "payload", "p"], ["kinetic", "potential"]),
            "state_derivative": F("state_derivative", [state, tau, payload, p], [state_derivative],
                                  ["x", "u", "payload", "p"], ["xdot"]),
            "tip_position": F("tip_position", [q, p], [p3], ["q", "p"], ["tip"]),
            "base_regressor": F("base_regressor", [q, qd, qdd], [base_regressor],
                                ["q", "qd", "qdd"], ["Y"]),
            "payload_parameters": F("payload_parameters", [p], [payload_parameters],
                                    ["p"], ["theta_payload"]),
        }


def _base_form(torque: ca.SX, regressor: ca.SX, p: ca.SX, payload: ca.SX) -> tuple[ca.SX, ca.SX]:
    r"""The base regressor :math:`Y(x)` (2×7) and payload parameters :math:`\theta_1(p)` (5).

    Generated from the torque, not written out: the payload is a point mass at the dipper tip,
    so its column :math:`\varphi = \partial\tau/\partial m` is a quadratic form in the
    lengths and gravity, :math:`\varphi = Y_{1:5}(x)\,(l_1^2, l_2^2, l_1l_2, gl_1, gl_2)`, and
    the columns :math:`Y_{1:5}` are its coefficients (second derivatives with respect to those
    parameters); the friction columns are :math:`\partial\tau/\partial\beta_i`. None of the
    columns depends on a machine parameter (checked here), so :math:`Y` is the same for every
    machine and the whole arm is :math:`\tau = Y(x)\,(\theta_0 + m\,[\theta_1; 0; 0])` with
    :math:`\theta_0` from :meth:`ArmModel.base_parameters` (tests prove both identities).
    """
    index = {name: i for i, name in enumerate(PARAMETER_NAMES)}
    l1, l2, g = (p[index[n]] for n in ("boom_length", "dipper_length", "gravity"))
    columns = []
    for first, second, scale in ((l1, l1, 0.5), (l2, l2, 0.5), (l1, l2, 1.0), (g, l1, 1.0), (g, l2, 1.0)):
        columns.append(scale * ca.jacobian(ca.jacobian(regressor, first), second))
    for name in ("boom_friction", "dipper_friction"):
        columns.append(ca.jacobian(torque, p[index[name]]))
    Y = ca.simplify(ca.horzcat(*columns))
    if ca.depends_on(Y, ca.vertcat(p, payload)):
        raise RuntimeError("the base regressor depends on machine parameters: the payload is no "
                           "longer a point mass at the dipper tip, derive another base form")
    return Y, ca.vertcat(l1 * l1, l2 * l2, l1 * l2, g * l1, g * l2)


@lru_cache(maxsize=1)
def symbolic() -> Symbolic:
    """The arm's symbolic model (built on first use, then cached)."""
    return Symbolic()


def _cols(a: np.ndarray) -> np.ndarray:
    """(..., k) array -> (k, N) column matrix for CasADi's automatic map."""
    a = np.asarray(a, dtype=float)
    return np.ascontiguousarray(a.reshape(-1, a.shape[-1]).T)


def base_regressor(q, qd, qdd) -> np.ndarray:
    """The base regressor Y(q, q̇, q̈) on arrays, shape (..., 2, 7): τ = Y θ, joint on axis -2.

    Parameters
    ----------
    q : array_like, shape (..., 2)
        Joint angles (boom, dipper), rad.
    qd : array_like, shape (..., 2)
        Joint rates, rad/s.
    qdd : array_like, shape (..., 2)
        Joint accelerations, rad/s².
    """
    arrays = [np.asarray(a, dtype=float) for a in (q, qd, qdd)]
    lead = np.broadcast_shapes(*(a.shape[:-1] for a in arrays))
    cols = [_cols(np.broadcast_to(a, lead + a.shape[-1:])) for a in arrays]
    out = np.asarray(symbolic().functions["base_regressor"](*cols)).T  # CasADi stacks the 2×7 blocks
    return out.reshape(lead + (len(BASE_PARAMETER_NAMES), 2)).swapaxes(-1, -2)


class ArmModel:
    """Numeric arm dynamics of one machine, evaluated in batches.

    Parameters
    ----------
    machine : Machine or str
        A :class:`Machine` or a preset name / machine file path.

    Notes
    -----
    Every method takes joint arrays with the joint on the last axis, shape ``(..., 2)``, and a
    payload that is a scalar or broadcasts against the leading axes. Evaluation is one CasADi
    call for the whole batch (CasADi maps a function over horizontally stacked columns).
    """

    def __init__(self, machine: Machine | str):
        self.machine = load_machine(machine)
        self.p = self.machine.parameter_vector
        self.sym = symbolic()
        self._f = self.sym.functions

    # -- helpers ---------------------------------------------------------------------------
    def _call(self, name: str, joint_args: list[np.ndarray], payload=None, out_dim: int = 2):
        arrays = [np.asarray(a, dtype=float) for a in joint_args]
        lead = np.broadcast_shapes(*(a.shape[:-1] for a in arrays),
                                   *(() if payload is None else np.shape(payload),))
        n = int(np.prod(lead)) if lead else 1
        cols = [_cols(np.broadcast_to(a, lead + a.shape[-1:])) for a in arrays]
        args = list(cols)
        if payload is not None:
            args.append(np.broadcast_to(np.asarray(payload, dtype=float), lead).reshape(1, n))
        args.append(np.repeat(self.p[:, None], n, axis=1))
        out = self._f[name](*args)
        outs = out if isinstance(out, (tuple, list)) else (out,)
        result = [np.asarray(o).T.reshape(lead + ((out_dim,) if out_dim > 1 else ())) for o in outs]
        return result if len(result) > 1 else result[0]

    # -- public API ------------------------------------------------------------------------
    def inverse_dynamics(self, q, qd, qdd, payload):
        """Joint torques τ = M(q)q̈ + C(q,q̇)q̇ + G(q) + Bq̇, N·m, shape (..., 2).

        Parameters
        ----------
        q : array_like, shape (..., 2)
            Joint angles (boom, dipper), rad.
        qd : array_like, shape (..., 2)
            Joint rates, rad/s.
        qdd : array_like, shape (..., 2)
            Joint accelerations, rad/s².
        payload : float or array_like
            Payload mass, kg; broadcasts against the leading axes.
        """
        return self._call("inverse_dynamics", [q, qd, qdd], payload)

    def forward_dynamics(self, q, qd, tau, payload):
        """Joint accelerations q̈ = M⁻¹(τ − Cq̇ − G − Bq̇), rad/s², shape (..., 2).

        Parameters
        ----------
        q : array_like, shape (..., 2)
            Joint angles (boom, dipper), rad.
        qd : array_like, shape (..., 2)
            Joint rates, rad/s.
        tau : array_like, shape (..., 2)
            Joint torques, N·m.
        payload : float or array_like
            Payload mass, kg; broadcasts against the leading axes.
        """
        return self._call("forward_dynamics", [q, qd, tau], payload)

    def payload_regressor(self, q, qd, qdd):
        """φ = ∂τ/∂m (N·m/kg), so that τ = τ₀ + m·φ, shape (..., 2).

        Parameters
        ----------
        q : array_like, shape (..., 2)
            Joint angles (boom, dipper), rad.
        qd : array_like, shape (..., 2)
            Joint rates, rad/s.
        qdd : array_like, shape (..., 2)
            Joint accelerations, rad/s².
        """
        return self._call("payload_regressor", [q, qd, qdd])

    def torque_empty(self, q, qd, qdd):
        """τ₀, the torques with an empty bucket (payload 0), shape (..., 2).

        Parameters
        ----------
        q : array_like, shape (..., 2)
            Joint angles (boom, dipper), rad.
        qd : array_like, shape (..., 2)
            Joint rates, rad/s.
        qdd : array_like, shape (..., 2)
            Joint accelerations, rad/s².
        """
        return self._call("torque_empty", [q, qd, qdd])

    def mass_matrix(self, q, payload):
        """M(q), shape (..., 2, 2).

        Parameters
        ----------
        q : array_like, shape (..., 2)
            Joint angles (boom, dipper), rad.
        payload : float or array_like
            Payload mass, kg; broadcasts against the leading axes.
        """
        out = self._call("mass_matrix", [q], payload, out_dim=4)
        return out.reshape(out.shape[:-1] + (2, 2))

    def gravity_torque(self, q, payload):
        """G(q), the torques that hold the arm still, shape (..., 2).

        Parameters
        ----------
        q : array_like, shape (..., 2)
            Joint angles (boom, dipper), rad.
        payload : float or array_like
            Payload mass, kg; broadcasts against the leading axes.
        """
        return self._call("gravity_torque", [q], payload)

    def energy(self, q, qd, payload):
        """(kinetic, potential) energy in J, each of the leading shape.

        Parameters
        ----------
        q : array_like, shape (..., 2)
            Joint angles (boom, dipper), rad.
        qd : array_like, shape (..., 2)
            Joint rates, rad/s.
        payload : float or array_like
            Payload mass, kg; broadcasts against the leading axes.
        """
        k, p = self._call("energy", [q, qd], payload, out_dim=1)
        return k, p

    def state_derivative(self, state, tau, payload):
        """ẋ for x = [q1, q2, q̇1, q̇2], shape (..., 4).

        Parameters
        ----------
        state : array_like, shape (..., 4)
            The state [q1, q2, q̇1, q̇2], rad and rad/s.
        tau : array_like, shape (..., 2)
            Joint torques, N·m.
        payload : float or array_like
            Payload mass, kg; broadcasts against the leading axes.
        """
        return self._call("state_derivative", [state, tau], payload, out_dim=4)

    def tip_position(self, q):
        """Position of the dipper tip (bucket) in m, shape (..., 2).

        Parameters
        ----------
        q : array_like, shape (..., 2)
            Joint angles (boom, dipper), rad.
        """
        return self._call("tip_position", [q])

    def base_parameters(self) -> tuple[np.ndarray, np.ndarray]:
        r"""The base parameters :math:`\theta_0` (7, empty bucket) and :math:`\theta_1` (5).

        :math:`\theta_1` is the symbolic ``payload_parameters``; :math:`\theta_0` is the least
        squares solution of :math:`\tau_0(x_k) = Y(x_k)\,\theta_0` on :data:`BASE_POINTS`
        (exact: the empty-arm torques lie in the span of the base regressor, which is checked).
        """
        q, qd, qdd = (BASE_POINTS[:, i:i + 2] for i in (0, 2, 4))
        Y = base_regressor(q, qd, qdd).reshape(-1, len(BASE_PARAMETER_NAMES))
        tau0 = self.torque_empty(q, qd, qdd).reshape(-1)
        theta_empty = np.linalg.lstsq(Y, tau0, rcond=None)[0]
        misfit = np.abs(Y @ theta_empty - tau0).max()
        if not misfit <= 1e-9 * max(1.0, np.abs(tau0).max()):
            raise RuntimeError(f"the empty arm's torques are not linear in the base parameters "
                               f"(misfit {misfit:.3g} N·m)")
        theta_payload = np.asarray(self._f["payload_parameters"](self.p), dtype=float).reshape(-1)
        return theta_empty, theta_payload

    def casadi_function(self, name: str) -> ca.Function:
        """The symbolic function ``name`` with this machine's parameters substituted.

        The returned function has the same inputs minus ``p``; use it inside CasADi graphs
        (NMPC, EKF Jacobians) and for C code generation.

        Parameters
        ----------
        name : str
            A function of the symbolic model (e.g. ``inverse_dynamics``, ``energy``).
        """
        f = self._f[name]
        names = [f.name_in(i) for i in range(f.n_in()) if f.name_in(i) != "p"]
        ins = [ca.SX.sym(f.name_in(i), f.sparsity_in(i)) for i in range(f.n_in()) if f.name_in(i) != "p"]
        full = list(ins)
        full.insert([f.name_in(i) for i in range(f.n_in())].index("p"), ca.DM(self.p))
        outs = f(*full)
        outs = list(outs) if isinstance(outs, (tuple, list)) else [outs]
        return ca.Function(f"{name}_{self.machine.name.replace('-', '_')}", ins, outs,
                           names, [f.name_out(i) for i in range(f.n_out())])
