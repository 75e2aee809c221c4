r"""NMPC swings of the hydraulic machine: boom, dipper, bucket and slew to a target pose.

The thesis' controller (:mod:`.nmpc`) generalised to the hydraulic machine: the state is
:math:`x = [q, \dot q, F]` (boom, dipper, bucket, slew: 4 angles, 4 rates, and the 4 applied
forces and slew torque behind their lag, below: 12), the inputs are the commanded cylinder
forces and slew-drive torque, the prediction model is the symbolic model's forward dynamics
with joint torques :math:`\tau_j = \text{count}_j\,\partial l_j/\partial q_j\,F_j`, and the
bounds are what the hydraulics can do:

* **forces** from the relief valves: :math:`-(p_\text{relief} A_r - p_\text{back} A_h) \le F
  \le p_\text{relief} A_h - p_\text{back} A_r` (one side at relief, the other at back pressure),
  slew torque within ``house.max_slew_torque``;
* **speeds** from the pumps: each joint's rate within the pump flow over the piston area
  through the joint's largest moment arm (a conservative box), slew rate within
  ``house.max_slew_rate``;
* **strokes**: angles inside the angle ranges (which fit the strokes).

Cost over the horizon :math:`T_p` (:math:`N` intervals of :math:`T_c`):

.. math:: \sum_{k=1}^{N} T_c\,(w_q\|q_k - r\|^2 + w_v\|\dot q_k\|^2)
          + w_u \sum_k \|\Delta U_k\|^2 + w_T\|q_N - r\|^2 + w_{Tv}\|\dot q_N\|^2

with inputs :math:`U \in [-1, 1]` scaled to the bounds. Multiple shooting over the :math:`N`
intervals with the shooting state :math:`[q, \dot q, \tilde F]`, the applied forces in the units
of U (:math:`F = F_c + F_h \tilde F` with the bounds' centre and half-range): in newtons beside
radians they left the QP's KKT matrix so ill-conditioned that ``qrqp`` stalled on zero steps
for most of its iterations. The forces stay shooting states (140 QP variables, 108
equalities) although their lag is linear and they could be computed from U: eliminated, every
interval would depend on all earlier inputs, and the fuller QP (104 variables) took twice as
long per iteration. CasADi ``sqpmethod`` with ``qrqp`` and the objective's constant
Gauss–Newton Hessian, warm-started
(three SQP iterations per step, the first step to convergence; a failed step is retried once
from a cold start; if that fails too, the previous plan is followed for that period, up to
three periods in a row; after that, or if the very first solve fails, the simulator redraws
the swing and counts it in ``controller_failures``), interval model compiled to C with its
Jacobian by the chain rule through the RK4 stages (:func:`_rk4_jacobian`), the SQP solvers
generated as C with it (:mod:`excavator_payload.model.compiled_sqp`).
Control period 0.25 s, horizon 2 s. The speed bounds hold at the nodes with a margin (85 %
of the limit); between nodes the realised rates overshoot the plan, mostly by < 15 % but in
about 5 % of the swings by more (a poorly converged step): the simulator redraws a swing
whose realised speed exceeds the pumps' by more than 5 %, or whose pressures exceed relief
(``draws`` in the experiment's metadata; its ``speed_share`` is the share used).
The plant integrates the same rigid-body model (RK4, 100 Hz) with the controller's forces
reaching the joints through a first-order lag, :math:`\dot F = (u - F)/T_v` (``force_lag``,
60 ms: valve spool and pressure build-up). Without it the forces, and so the accelerations
and pressures, would jump at every control instant, which no hydraulic machine does, and an
estimator's quadrature would be tuned to the jumps (a left rectangle rule is exact for held
inputs; the trapezoid is right for a real machine). The prediction has the same lag, from the
applied forces of the plant's state. Seal friction is not
in the loop: the pressures are then computed for the realised motion by
:func:`~excavator_payload.simulation.machine_sim.motion_physics`, friction included, so that
every sample is consistent with the model.
"""

from __future__ import annotations

import time as _time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from excavator_payload.model.codegen import BufferedCall, native
from excavator_payload.model.compiled_sqp import compiled_sqp
from excavator_payload.model.hydraulic import HydraulicArmModel
from excavator_payload.simulation.plant import rk4_sensitivity


#: Control periods in a row the controller may follow its previous plan after failed solves.
MAX_PLAN_FOLLOWING = 3


class ControlFailure(RuntimeError):
    """The hydraulic NMPC found no usable input."""


@dataclass(frozen=True)
class HydraulicNMPCSettings:
    """Tunable settings of the hydraulic NMPC: timing (s), cost weights, solver iterations and the
    force lag (defaults and meaning: see the module docstring).

    Parameters
    ----------
    control_period : float
        Control period :math:`T_c`, s.
    horizon : float
        Prediction horizon :math:`T_p`, s (a whole number of control periods).
    angle_weight : float
        Stage weight :math:`w_q` on the angle error, per rad² per s.
    rate_weight : float
        Stage weight :math:`w_v` on the joint rates, per (rad/s)² per s.
    input_rate_weight : float
        Weight :math:`w_u` on the input change, per (ΔU)² with U in units of the bounds.
    terminal_weight : float
        Weight :math:`w_T` on the angle error at the end of the horizon, per rad².
    terminal_rate_weight : float
        Weight :math:`w_{Tv}` on the joint rates at the end of the horizon, per (rad/s)².
    substeps : int
        RK4 steps per control interval in the prediction.
    speed_margin : float
        Share of the speed limits the plan may use at its nodes.
    sqp_iterations : int
        Warm-started SQP iterations per control period.
    cold_iterations : int
        SQP iterations of the first step of a swing (and of a retry).
    force_lag : float
        Time constant of the lag from commanded to applied forces, s.
    qp_solver : str
        CasADi QP solver of the SQP (``qrqp``; ``qpoases``, ``daqp`` or ``osqp`` if installed).
    generate_solver : bool
        With ``qrqp`` and a C compiler: the SQP solvers as generated C compiled with the model
        (:mod:`excavator_payload.model.compiled_sqp`; the same numbers, faster).
    """

    control_period: float = 0.25  # s (0.2 s: ~1.8× the time per experiment, same swings)
    horizon: float = 2.0  # s
    angle_weight: float = 10.0  # per rad² per s
    rate_weight: float = 2.0
    input_rate_weight: float = 0.2  # per (ΔU)², U in units of the bounds
    terminal_weight: float = 200.0
    terminal_rate_weight: float = 50.0
    substeps: int = 2  # RK4 steps per control interval in the prediction
    #: Share of the speed limits the plan may use at its nodes (every control period): the
    #: rates between the nodes overshoot them.
    speed_margin: float = 0.85
    sqp_iterations: int = 3  # warm-started SQP iterations per control period
    cold_iterations: int = 30
    #: Time constant (s) of the first-order lag from commanded to applied forces (valve spool
    #: and pressure build-up), in the plant and in the prediction.
    force_lag: float = 0.06
    qp_solver: str = "qrqp"
    generate_solver: bool = True


def _dynamics(arm: HydraulicArmModel) -> ca.Function:
    """ẋ = f(x, u, tilt, payload) with u = [F_boom, F_dipper, F_bucket, τ_slew] (N, N·m)."""
    f = arm.sym.functions
    p = ca.DM(arm.p)
    x, u, tilt, m = ca.SX.sym("x", 8), ca.SX.sym("u", 4), ca.SX.sym("tilt", 2), ca.SX.sym("payload")
    q, qd = x[:4], x[4:]
    counts = ca.DM([c.count for c in arm.machine.cylinders])
    tau = ca.vertcat(counts * f["moment_arms"](q, p) * u[:3], u[3])
    qdd = f["forward_dynamics"](q, qd, tau, tilt, m, p)
    return ca.Function("hyd_xdot", [x, u, tilt, m], [ca.vertcat(qd, qdd)], ["x", "u", "tilt", "payload"], ["xdot"])


def _lagged_dynamics(arm: HydraulicArmModel, lag: float) -> ca.Function:
    """ż = f(z, u, tilt, payload) of the plant, z = [q, q̇, F]: the applied forces F follow the
    commanded u through a first-order lag of ``lag`` seconds."""
    xdot = _dynamics(arm)
    z, u, tilt, m = ca.SX.sym("z", 12), ca.SX.sym("u", 4), ca.SX.sym("tilt", 2), ca.SX.sym("payload")
    applied = z[8:]
    return ca.Function("hyd_plant_zdot", [z, u, tilt, m],
                       [ca.vertcat(xdot(z[:8], applied, tilt, m), (u - applied) / lag)],
                       ["x", "u", "tilt", "payload"], ["xdot"])


def _rk4(f: ca.Function, duration: float, substeps: int, name: str, inner: bool = False) -> ca.Function:
    """RK4 over ``duration`` with the input held; with ``inner`` also the joint rates at the
    end of each substep but the last (to bound the speed inside a control interval)."""
    n = f.size1_in(0)
    x, u, tilt, m = ca.SX.sym("x", n), ca.SX.sym("u", 4), ca.SX.sym("tilt", 2), ca.SX.sym("payload")
    h = duration / substeps
    xn = x
    rates = []
    for _ in range(substeps):
        k1 = f(xn, u, tilt, m)
        k2 = f(xn + h / 2 * k1, u, tilt, m)
        k3 = f(xn + h / 2 * k2, u, tilt, m)
        k4 = f(xn + h * k3, u, tilt, m)
        xn = xn + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        rates.append(xn[4:8])
    if inner:
        return ca.Function(name, [x, u, tilt, m], [xn, ca.vertcat(*rates[:-1])],
                           ["x", "u", "tilt", "payload"], ["xf", "inner_rates"])
    return ca.Function(name, [x, u, tilt, m], [xn], ["x", "u", "tilt", "payload"], ["xf"])


def _rk4_jacobian(f: ca.Function, duration: float, substeps: int, name: str,
                  parameter_blocks: bool = True) -> ca.Function:
    """The Jacobian of :func:`_rk4` (``jac_<name>``, CasADi's layout: the blocks by x, u, tilt
    and payload) by the chain rule through the stages: one ẋ and ∂ẋ/∂(x, u, tilt, payload)
    per stage, S ← S + h/6 (dk1 + 2dk2 + 2dk3 + dk4). The same derivative as differentiating
    the unrolled RK4 (equal to rounding, a test checks), in about a third of the operations:
    the SQP spends most of its time in it. Without ``parameter_blocks`` the tilt and payload
    blocks are structural zeros (the NMPC never differentiates by its parameters): the same
    x and u blocks to the bit, in 3/19 fewer sensitivity columns."""
    n = f.size1_in(0)
    x, u, tilt, m = ca.SX.sym("x", n), ca.SX.sym("u", 4), ca.SX.sym("tilt", 2), ca.SX.sym("payload")
    xs, us, ts, ms = ca.SX.sym("xs", n), ca.SX.sym("us", 4), ca.SX.sym("ts", 2), ca.SX.sym("ms")
    rate = f(xs, us, ts, ms)
    with_jacobian = ca.Function("xdot_jac", [xs, us, ts, ms],
                                [rate, ca.jacobian(rate, ca.vertcat(xs, us, ts, ms))])
    n_held = 7  # u, tilt, payload: held over the interval, d/dz = [0 I]
    # Structural zeros (ca.DM(n, m), not DM.zeros) so that the Jacobian keeps the pattern of the
    # dynamics (the applied forces depend on nothing but forces and inputs): fewer operations
    # here, a sparser QP in the NMPC.
    held = ca.horzcat(ca.DM(n_held, n), ca.DM.eye(n_held))
    n_sens = n_held if parameter_blocks else 4  # sensitivity columns beyond x: u (tilt, payload)
    held = held[:, :n + n_sens]

    def stage(state, sensitivity):
        k, F = with_jacobian(state, u, tilt, m)
        return k, ca.mtimes(F, ca.vertcat(sensitivity, held))

    _, S = rk4_sensitivity(stage, x, ca.horzcat(ca.DM.eye(n), ca.DM(n, n_sens)), duration, substeps)
    by_parameters = ([S[:, n + 4:n + 6], S[:, n + 6]] if parameter_blocks
                     else [ca.SX(ca.Sparsity(n, 2)), ca.SX(ca.Sparsity(n, 1))])
    return ca.Function(f"jac_{name}", [x, u, tilt, m, ca.SX.sym("out_xf", n)],
                       [S[:, :n], S[:, n:n + 4], *by_parameters],
                       ["x", "u", "tilt", "payload", "out_xf"],
                       ["jac_xf_x", "jac_xf_u", "jac_xf_tilt", "jac_xf_payload"])


def hydraulic_bounds(arm: HydraulicArmModel):
    """(u_low, u_high, rate_limit (4,), angle ranges (3, 2)) of the machine's hydraulics.

    Parameters
    ----------
    arm : HydraulicArmModel
        The machine's model (cylinders, relief and back pressure, slew drive).

    Returns
    -------
    u_low, u_high : numpy.ndarray
        Bounds of the boom, dipper and bucket cylinder forces (N) and the slew torque (N·m).
    rate_limit : numpy.ndarray
        Largest rate of each joint, rad/s, shape (4,).
    angle_ranges : numpy.ndarray
        Boom, dipper and bucket angle ranges, rad, shape (3, 2).
    """
    m = arm.machine
    h = m.hydraulics
    low, high, rate = [], [], []
    rod_speed = arm.rod_speed_limits().min(axis=1)  # the slower direction
    largest_arm = arm.moment_arm_range(200)[:, 1]
    for j, c in enumerate(m.cylinders):
        high.append(h.relief_pressure * c.head_area - h.back_pressure * c.rod_area)
        low.append(-(h.relief_pressure * c.rod_area - h.back_pressure * c.head_area))
        rate.append(rod_speed[j] / largest_arm[j])
    low.append(-m.house.max_slew_torque)
    high.append(m.house.max_slew_torque)
    rate.append(m.house.max_slew_rate)
    return np.array(low), np.array(high), np.array(rate), m.angle_ranges


class HydraulicNMPC:
    """The NMPC of the module docstring for one machine.

    Parameters
    ----------
    arm : HydraulicArmModel
        The controlled machine's model.
    settings : HydraulicNMPCSettings, optional
        Tuning; default :class:`HydraulicNMPCSettings`.
    """

    def __init__(self, arm: HydraulicArmModel, settings: HydraulicNMPCSettings | None = None):
        self.arm = arm
        self.settings = s = settings or HydraulicNMPCSettings()
        self.N = N = int(round(s.horizon / s.control_period))
        u_low, u_high, rate, ranges = hydraulic_bounds(arm)
        self.u_centre, self.u_half = (u_high + u_low) / 2, (u_high - u_low) / 2
        xdot = _lagged_dynamics(arm, s.force_lag)
        self.nx = nx = 12  # q, q̇, applied forces (scaled, below)
        model = _rk4(xdot, s.control_period, s.substeps, "hyd_nmpc_model")
        symbolic_model = [model, _rk4_jacobian(xdot, s.control_period, s.substeps, "hyd_nmpc_model",
                                               parameter_blocks=False)]
        # compiled with its chain-rule Jacobian, which CasADi finds in the library by name
        self.model = native(*symbolic_model)
        rate = rate * s.speed_margin

        X = ca.MX.sym("X", nx, N + 1)
        U = ca.MX.sym("U", 4, N)
        x0, ref, u_prev = ca.MX.sym("x0", nx), ca.MX.sym("ref", 4), ca.MX.sym("u_prev", 4)
        tilt, payload = ca.MX.sym("tilt", 2), ca.MX.sym("payload")
        centre, half = ca.repmat(ca.DM(self.u_centre), 1, N), ca.repmat(ca.DM(self.u_half), 1, N)
        forces = centre + U * half
        # The applied forces as shooting states in units of the bounds, like U (module docstring:
        # in newtons the QP was ill-conditioned; eliminated, it was fuller and slower).
        applied = centre + X[8:, :N] * half
        X_next = self.model.map(N)(ca.vertcat(X[:8, :N], applied), forces, ca.repmat(tilt, 1, N),
                                   ca.repmat(payload, 1, N))
        X_next = ca.vertcat(X_next[:8, :], (X_next[8:, :] - centre) / half)
        x0_scaled = ca.vertcat(x0[:8], (x0[8:] - centre[:, 0]) / half[:, 0])
        g = ca.vertcat(X[:, 0] - x0_scaled, ca.vec(X[:, 1:] - X_next))
        du = U - ca.horzcat(u_prev, U[:, :N - 1])
        err = X[:4, 1:] - ca.repmat(ref, 1, N)
        cost = (s.control_period * (s.angle_weight * ca.sumsqr(err) + s.rate_weight * ca.sumsqr(X[4:8, 1:]))
                + s.input_rate_weight * ca.sumsqr(du)
                + s.terminal_weight * ca.sumsqr(X[:4, N] - ref) + s.terminal_rate_weight * ca.sumsqr(X[4:8, N]))
        w = ca.vertcat(ca.vec(X), ca.vec(U))
        params = ca.vertcat(x0, ref, u_prev, tilt, payload)
        hess = ca.Function("h", [w, params], [ca.hessian(cost, w)[0]])(np.zeros(w.shape[0]),
                                                                        np.zeros(params.shape[0]))
        hess = ca.DM(ca.triu(hess) + ca.triu(hess, False).T)
        w_sx, p_sx = ca.SX.sym("w", w.shape[0]), ca.SX.sym("p", params.shape[0])
        lam_f, lam_g = ca.SX.sym("lam_f"), ca.SX.sym("lam_g", g.shape[0])
        hess_lag = ca.Function("hyd_gauss_newton", [w_sx, p_sx, lam_f, lam_g], [lam_f * ca.SX(hess)],
                               ["x", "p", "lam_f", "lam_g"], ["hess_gamma_x_x"])
        qp_options = {"qrqp": {"print_iter": False, "print_header": False, "print_info": False,
                               "error_on_fail": False},
                      "qpoases": {"printLevel": "none", "error_on_fail": False, "sparse": True},
                      "daqp": {"error_on_fail": False},
                      "osqp": {"error_on_fail": False, "osqp": {"verbose": False}}}
        opts = {"qpsol": s.qp_solver, "hess_lag": hess_lag, "hessian_approximation": "exact",
                "qpsol_options": qp_options.get(s.qp_solver, {"error_on_fail": False}),
                "print_header": False, "print_iteration": False, "print_status": False,
                "print_time": False, "error_on_fail": False,
                # a line-search trial pose outside the cylinders' geometry evaluates to NaN: the
                # SQP rejects that step itself (results count fallbacks); no console warning
                "show_eval_warnings": False}
        nlp = {"x": w, "p": params, "f": cost, "g": g}
        self._sqp = ca.nlpsol("hyd_nmpc", "sqpmethod", nlp, {**opts, "max_iter": s.sqp_iterations})
        self._sqp_cold = ca.nlpsol("hyd_nmpc_cold", "sqpmethod", nlp, {**opts, "max_iter": s.cold_iterations})
        # The solvers as generated C compiled with the model where a compiler exists (the same
        # numbers, no virtual machine), else CasADi's; called through numpy buffers either way.
        generated = None
        if s.generate_solver and s.qp_solver == "qrqp" and self.model.class_name() == "External":
            generated = compiled_sqp([self._sqp, self._sqp_cold], symbolic_model, "hyd_nmpc_sqp")
        self.generated_solver = generated is not None
        if generated:
            self._warm_call, self._cold_call = generated["hyd_nmpc"], generated["hyd_nmpc_cold"]
        else:
            self._warm_call, self._cold_call = BufferedCall(self._sqp), BufferedCall(self._sqp_cold)
        self._n_x, self._n_g = nx * (N + 1), g.shape[0]
        self._n_eq = nx * (N + 1)
        self._lbg = self._ubg = np.zeros(self._n_eq)
        lbx = np.full(w.shape[0], -np.inf)
        ubx = np.full(w.shape[0], np.inf)
        margin = np.radians(0.5)
        # no bounds on node 0: it is the measured state (an equality), and a state already past a
        # bound there made the QP infeasible (every retry and controller failure traced on 20
        # swings; 18 retries on 40 swings before, 0 after)
        for k in range(1, N + 1):
            lbx[nx * k:nx * k + 3] = ranges[:, 0] + margin
            ubx[nx * k:nx * k + 3] = ranges[:, 1] - margin
            lbx[nx * k + 4:nx * k + 8] = -rate
            ubx[nx * k + 4:nx * k + 8] = rate
        lbx[self._n_x:], ubx[self._n_x:] = -1.0, 1.0
        self._lbx, self._ubx = lbx, ubx
        self.solve_times: list[float] = []

    def reset(self, state, target, tilt, payload) -> None:
        """Start a new swing from rest at ``state`` ([q, q̇], 8): the forces applied and the first
        guess hold the arm still against gravity (the full state is then ``initial_state``).

        Parameters
        ----------
        state : numpy.ndarray
            Start angles (rad) and rates (rad/s) of boom, dipper, bucket and slew; the first 8
            entries are used.
        target : numpy.ndarray
            Target angles of boom, dipper, bucket and slew, rad, shape (4,).
        tilt : numpy.ndarray
            Ground tilt (pitch, roll), rad.
        payload : float
            Payload mass, kg.
        """
        N = self.N
        state = np.asarray(state, float)[:8]
        tau = self.arm.inverse_dynamics(state[:4], np.zeros(4), np.zeros(4), tilt, payload)
        force = np.concatenate([self.arm.load_force(state[:4], tau[:3]), [tau[3]]])
        self._u = np.clip((force - self.u_centre) / self.u_half, -1, 1)
        self.initial_state = np.concatenate([state, self.u_centre + self.u_half * self._u])
        self._w = np.concatenate([np.tile(self._scaled(self.initial_state), N + 1), np.tile(self._u, N)])
        self._lam_x, self._lam_g = np.zeros_like(self._w), np.zeros(self._n_g)
        self._fixed = np.concatenate([np.asarray(target, float), self._u * 0, np.asarray(tilt, float), [payload]])
        self._target, self._tilt, self._payload = np.asarray(target, float), np.asarray(tilt, float), payload
        self._cold = True
        self.solve_times = []
        self.retries = 0
        self.plan_followed = 0
        self._failures_in_a_row = 0

    def _scaled(self, state) -> np.ndarray:
        """The plant state [q, q̇, F] as the NLP's shooting state (F in units of the bounds)."""
        state = np.asarray(state, float)
        return np.concatenate([state[:8], (state[8:] - self.u_centre) / self.u_half])

    def control(self, state) -> np.ndarray:
        """Forces and slew torque to apply for the next control period.

        Parameters
        ----------
        state : numpy.ndarray
            Plant state ``[q, q̇, F]`` (rad, rad/s, applied forces N and slew torque N·m),
            shape (12,).

        Returns
        -------
        numpy.ndarray
            Commanded boom, dipper, bucket cylinder forces (N) and slew torque (N·m).

        Raises
        ------
        ControlFailure
            If the first solve of a swing fails, or the solves fail more than
            ``MAX_PLAN_FOLLOWING`` periods in a row.
        """
        start = _time.perf_counter()
        w0 = self._w.copy()
        w0[:self.nx] = self._scaled(state)
        params = np.concatenate([state, self._target, self._u, self._tilt, [self._payload]])
        solver = self._cold_call if self._cold else self._warm_call
        for retry in (False, True):
            sol = solver(x0=w0, p=params, lbx=self._lbx, ubx=self._ubx, lbg=self._lbg, ubg=self._ubg,
                         lam_x0=self._lam_x, lam_g0=self._lam_g)
            stats = solver.stats()
            status = str(stats.get("return_status", ""))
            w = sol["x"]
            ok = stats.get("success", False) or status == "Maximum_Iterations_Exceeded"
            if ok and np.all(np.isfinite(w)):
                break
            # Retry once from the previous plan with the cold solver (iterates to convergence)
            # and no multipliers; a second failure skips the experiment.
            solver, self._lam_x, self._lam_g = self._cold_call, np.zeros_like(self._lam_x), np.zeros(self._n_g)
            self.retries += 1
        else:
            # As a real-time controller does: follow the previous plan (already shifted by one
            # interval) for this period; fail only after several periods in a row.
            self._failures_in_a_row += 1
            if self._cold or self._failures_in_a_row > MAX_PLAN_FOLLOWING:
                raise ControlFailure(f"hydraulic NMPC failed ({status})")
            self.plan_followed += 1
            N = self.N
            X = self._w[:self._n_x].reshape(N + 1, self.nx)
            U = self._w[self._n_x:].reshape(N, 4)
            self._u = U[0].copy()
            self._w = np.concatenate([np.vstack([X[1:], X[-1:]]).ravel(), np.vstack([U[1:], U[-1:]]).ravel()])
            self._lam_x, self._lam_g = np.zeros_like(self._lam_x), np.zeros(self._n_g)
            self.solve_times.append(_time.perf_counter() - start)
            return self.u_centre + self.u_half * self._u
        self._failures_in_a_row = 0
        N = self.N
        X = w[:self._n_x].reshape(N + 1, self.nx)
        U = w[self._n_x:].reshape(N, 4)
        self._u = U[0].copy()
        self._w = np.concatenate([np.vstack([X[1:], X[-1:]]).ravel(), np.vstack([U[1:], U[-1:]]).ravel()])
        lam_g = np.asarray(sol["lam_g"]).ravel().reshape(N + 1, self.nx)
        self._lam_g = np.vstack([lam_g[1:], lam_g[-1:]]).ravel()
        lam_u = np.asarray(sol["lam_x"]).ravel()[self._n_x:].reshape(N, 4)
        self._lam_x = np.concatenate([np.zeros(self._n_x), np.vstack([lam_u[1:], lam_u[-1:]]).ravel()])
        self._cold = False
        self.solve_times.append(_time.perf_counter() - start)
        return self.u_centre + self.u_half * self._u


class HydraulicNMPCSimulator:
    """Runs NMPC swings: controller every ``control_period``, plant and sensors at 100 Hz.

    Parameters
    ----------
    arm : HydraulicArmModel
        The machine's model (controller and plant).
    settings : HydraulicNMPCSettings, optional
        Tuning of the controller; default :class:`HydraulicNMPCSettings`.
    sample_period : float
        Plant and sensor sample period, s.
    """

    def __init__(self, arm: HydraulicArmModel, settings: HydraulicNMPCSettings | None = None,
                 sample_period: float = 0.01):
        self.arm = arm
        self.controller = HydraulicNMPC(arm, settings)
        self.sample_period = float(sample_period)
        xdot = _lagged_dynamics(arm, self.controller.settings.force_lag)
        ratio = self.controller.settings.control_period / self.sample_period
        self.samples_per_control = k = int(round(ratio))
        # One call per control period: k plant steps (RK4, 2 substeps each) with the input held,
        # and ẋ at each sample (mapaccum over the compiled step).
        step = native(_rk4(xdot, self.sample_period, 2, "hyd_plant_step"))
        self._xdot = native(xdot)
        self._interval = step.mapaccum("hyd_plant_interval", k)
        self._xdot_map = self._xdot.map(k)
        # both called through numpy buffers (no DM conversions: the same numbers)
        self._interval_call, self._xdot_map_call = BufferedCall(self._interval), BufferedCall(self._xdot_map)

    def run(self, start, target, tilt, payload, duration: float):
        """(time, q, q̇, q̈, applied forces, info) of one swing from rest at ``start`` towards
        ``target``.

        Parameters
        ----------
        start : numpy.ndarray
            Start angles of boom, dipper, bucket and slew, rad, shape (4,); the arm starts at rest.
        target : numpy.ndarray
            Target angles, rad, shape (4,).
        tilt : numpy.ndarray
            Ground tilt (pitch, roll), rad.
        payload : float
            Payload mass, kg.
        duration : float
            Length of the swing, s.

        Returns
        -------
        time : numpy.ndarray
            Sample times, s, shape (n,).
        q, qd, qdd : numpy.ndarray
            Angles (rad), rates (rad/s) and accelerations (rad/s²), shape (n, 4).
        forces : numpy.ndarray
            Applied cylinder forces (N) and slew torque (N·m), shape (n, 4).
        info : dict
            Final error, reached, solver counts and solve times.

        Raises
        ------
        ControlFailure
            If the controller fails or the plant state stops being finite.
        """
        n = int(round(duration / self.sample_period)) + 1
        time = np.arange(n) * self.sample_period
        x = np.concatenate([np.asarray(start, float), np.zeros(4)])
        ctl = self.controller
        ctl.reset(x, target, tilt, payload)
        z = ctl.initial_state
        k = self.samples_per_control
        n_intervals = -(-n // k)
        states, accels = np.empty((n_intervals * k, 12)), np.empty((n_intervals * k, 4))
        for i in range(n_intervals):
            u = ctl.control(z)
            # column-major k columns: each the held input, the tilt and the payload
            held = (np.tile(u, k), np.tile(tilt, k), np.full(k, float(payload)))
            after = self._interval_call(x=z, u=held[0], tilt=held[1], payload=held[2])["xf"].reshape(k, 12).T
            block = np.column_stack([z, after[:, :-1]])  # states at the k sample instants
            if not np.all(np.isfinite(after)):
                raise ControlFailure(f"plant state became non-finite near t = {time[min(i * k, n - 1)]:.2f} s")
            rows = slice(i * k, (i + 1) * k)
            states[rows] = block.T
            rates = self._xdot_map_call(x=block.T.ravel(), u=held[0], tilt=held[1], payload=held[2])["xdot"]
            accels[rows] = rates.reshape(k, 12)[:, 4:8]
            z = after[:, -1]
        states, accels = states[:n], accels[:n]
        q, qd, forces = states[:, :4], states[:, 4:8], states[:, 8:]
        error = np.degrees(q[-1] - np.asarray(target))
        solve = np.array(ctl.solve_times)
        info = {"final_error_deg": [float(v) for v in error],
                "reached": bool(np.all(np.abs(error) < 1.0) and np.all(np.abs(np.degrees(qd[-1])) < 1.0)),
                "n_solves": len(solve), "n_retries": ctl.retries, "n_plan_followed": ctl.plan_followed, "solve_time_median_ms": float(np.median(solve) * 1e3),
                "solve_time_max_ms": float(np.max(solve) * 1e3)}
        return time, q, qd, accels, forces, info
