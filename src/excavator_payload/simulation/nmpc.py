r"""Nonlinear model-predictive control of the arm (thesis §5.3, eq. 5.7, appendix A.2).

Every control period :math:`T_s = 0.1` s the controller solves, over the horizon
:math:`T_p = 2` s (:math:`N = 20` intervals, inputs held over each interval),

.. math::

    \min_{u_0 \dots u_{N-1}} \;
        \sum_{k=1}^{N} T_s \left(\|q_k - r\|^2_{Q} + \|\dot q_k\|^2_{Q_v}\right)
        + \sum_{k=0}^{N-1} \|\Delta \bar u_k\|^2_{R_\Delta}
        + \|x_N - x_r\|^2_P
    \quad\text{s.t.}\quad
    x_0 = \hat x,\;\; x_{k+1} = F(x_k, u_k, m),\;\; |u_{k,j}| \le \bar\tau_j

with the thesis' terminal weight :math:`P = \mathrm{diag}(2\cdot10^{11}, 2\cdot10^{11}, 10^3,
10^3)`, the reference :math:`x_r = [r_1, r_2, 0, 0]`, the machine's torque limits
:math:`\bar\tau` (``Machine.torque_limits``), the input rate in units of the limits
:math:`\Delta\bar u_k = (u_k - u_{k-1}) / \bar\tau` (:math:`u_{-1}` = the torque applied now) and
:math:`F` two RK4 steps of ``ArmModel.casadi_function("state_derivative")``.

Why the additions to the thesis' problem
----------------------------------------
The thesis sets :math:`Q = 0`, :math:`R = 0` and no bounds. That problem is ill-posed: only
the state at :math:`t + T_p` is priced, so any torque history that lands there is optimal (the
plan can be postponed forever as the horizon recedes) and nothing limits the torque. We add

* a stage cost on the angle error, :math:`Q = 2\cdot10^{9}\,\mathrm{s^{-1}}` per joint (1 % of
  the terminal weight per second of horizon): reach the target early and *stay* there, which
  also brings the arm to rest since moving away is priced;
* a stage cost on the joint rates, :math:`Q_v = 10^{9}\,\mathrm{s^{-1}}` per joint: without it
  the swings peak at 90–150 °/s and overshoot the target by ~5°; with it they peak at
  40–85 °/s (median ~55 °/s boom, closer to a real excavator's boom and stick speeds), do not
  overshoot, and still settle within 1° after 3.2 s (median; 3.45 s at most in 500 runs);
* an input-rate cost :math:`R_\Delta = 2\cdot10^{8}` on the torque change in units of the limit:
  smooth torques, as hydraulic cylinders give, instead of bang-bang chattering; it does not
  bias the final pose (an input cost :math:`\|u\|_R^2` would, since holding the arm needs the
  gravity torque);
* box bounds :math:`|u_j| \le \bar\tau_j` from the machine file (4 MN·m boom, 2 MN·m dipper for
  the CAT 345C: 3–4 × (boom) and 7 × (dipper) the largest torque that holds a full bucket
  still; with the weights above the boom bound is reached in ~1 % of the swings, heavy
  payloads starting low, and the dipper uses at most ~45 % of its bound).

The objective is divided by the terminal weight :math:`2\cdot10^{11}` inside the solver, and the
inputs are optimised in units of :math:`\bar\tau`: this leaves the minimiser unchanged and keeps
the SQP's quadratic programs well conditioned.

Solver
------
Multiple shooting, CasADi ``sqpmethod`` with the active-set QP solver ``qrqp`` and a
Gauss–Newton Hessian (the objective's own, constant Hessian), warm-started from the previous
solution shifted by one interval, two SQP iterations per control step (real-time-iteration
style; the first step of an experiment iterates to convergence). The interval model and its
Jacobian are compiled to C and cached on disk when a C compiler is available, and the SQP
solvers are generated as C with them
(:mod:`excavator_payload.model.compiled_sqp`; see ``docs/speed-simulation.md``). If a solve fails
(QP failure, non-finite plan, or a shooting defect above ``max_defect``), the step is retried
from a cold start with IPOPT; if that fails too, the controller raises :class:`ControlFailure`
and the caller skips the experiment with the reason.
"""

from __future__ import annotations

import logging
import time as _time
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from excavator_payload.model.codegen import BufferedCall, native
from excavator_payload.model.compiled_sqp import compiled_sqp
from excavator_payload.model.dynamics import ArmModel
from excavator_payload.simulation.plant import rk4_interval, rk4_sensitivity

log = logging.getLogger(__name__)

#: Thesis NMPC settings (§5.3, appendix A.2).
CONTROL_PERIOD = 0.1  # s, T_s
HORIZON = 2.0  # s, T_p
TERMINAL_WEIGHT = (2e11, 2e11, 1e3, 1e3)  # P


def _interval_model(arm: ArmModel, duration: float, substeps: int, jit: bool, chain_rule: bool = False):
    """The prediction model ``(x, u, payload) -> x(t + duration)``, compiled to C when possible,
    and the SX functions behind it (the model and its Jacobian).

    The model and its Jacobian (``jac_nmpc_model``, which CasADi's ``external`` picks up for
    the derivatives) are compiled once per machine and cached (:mod:`excavator_payload.model.codegen`):
    ~15× faster Jacobians than CasADi's virtual machine. Without a compiler, or if compiling
    fails, the same function runs in the virtual machine (same results, slower).
    """
    model = rk4_interval(arm, duration, substeps, "nmpc_model")
    jacobian = (_chain_rule_jacobian(arm, duration, substeps, model.name()) if chain_rule
                else _state_input_jacobian(model))
    symbolic = [model, jacobian]
    return (native(*symbolic) if jit else model), symbolic


def _chain_rule_jacobian(arm: ArmModel, duration: float, substeps: int, name: str) -> ca.Function:
    """``jac_<name>`` (as :func:`_state_input_jacobian`) by the chain rule through the RK4 stages:
    one ẋ and ∂ẋ/∂(x, u) per stage, S ← S + h/6 (dk1 + 2dk2 + 2dk3 + dk4). The same derivative,
    equal to rounding, in 13.9k operations instead of 28.2k."""
    f = arm.casadi_function("state_derivative")
    x, u, m = ca.SX.sym("x", 4), ca.SX.sym("u", 2), ca.SX.sym("payload")
    xs, us = ca.SX.sym("xs", 4), ca.SX.sym("us", 2)
    rate = f(xs, us, m)
    with_jacobian = ca.Function("xdot_jac", [xs, us, m], [rate, ca.jacobian(rate, ca.vertcat(xs, us))])
    held = ca.horzcat(ca.DM(2, 4), ca.DM.eye(2))  # the input is held: d u / d(x0, u) = [0 I]

    def stage(state, sensitivity):
        k, F = with_jacobian(state, u, m)
        return k, ca.mtimes(F, ca.vertcat(sensitivity, held))

    _, S = rk4_sensitivity(stage, x, ca.horzcat(ca.DM.eye(4), ca.DM(4, 2)), duration, substeps)
    return ca.Function(f"jac_{name}", [x, u, m, ca.SX(ca.Sparsity(4, 1))],
                       [S[:, :4], S[:, 4:], ca.SX(ca.Sparsity(4, 1))],
                       ["x", "u", "payload", "out_xf"], ["jac_xf_x", "jac_xf_u", "jac_xf_payload"])


def _state_input_jacobian(model: ca.Function) -> ca.Function:
    """``jac_nmpc_model`` as CasADi's ``model.jacobian()`` names and lays it out, with the blocks
    by state and input and none by payload (a structural zero): the payload is a parameter of the
    NLP, never differentiated, and its column cost 1/8 of the Jacobian's operations. The two
    blocks are CasADi's own, to the bit (a test compares them)."""
    x, u, payload = model.sx_in()
    xf = model(x, u, payload)
    both = ca.jacobian(xf, ca.vertcat(x, u))
    n_x = x.numel()
    return ca.Function(f"jac_{model.name()}", [x, u, payload, ca.SX(ca.Sparsity(xf.numel(), 1))],
                       [both[:, :n_x], both[:, n_x:], ca.SX(xf.numel(), 1)],
                       ["x", "u", "payload", "out_xf"], ["jac_xf_x", "jac_xf_u", "jac_xf_payload"])


class ControlFailure(RuntimeError):
    """The NMPC found no usable input, even after the IPOPT fallback."""


@dataclass
class NMPCSettings:
    """Tunable settings of :class:`NMPCController` (defaults: see the module docstring).

    Parameters
    ----------
    control_period : float
        Control period :math:`T_s`, s; the inputs are held over it.
    horizon : float
        Prediction horizon :math:`T_p`, s (a whole number of control periods).
    terminal_weight : tuple of float
        Diagonal of the terminal weight :math:`P` on the error of (boom, dipper angle, rad;
        boom, dipper rate, rad/s).
    angle_weight : float
        Stage weight :math:`Q` on each angle error, per second of horizon (1/(rad²·s)).
    input_rate_weight : float
        Weight R_Δ on each torque change, in units of the torque limit.
    rate_weight : float
        Stage weight :math:`Q_v` on each joint rate, per second of horizon.
    model_substeps : int
        RK4 steps per control interval in the prediction model.
    sqp_iterations : int
        SQP iterations per (warm-started) control step.
    cold_iterations : int
        SQP iterations of the first control step of an experiment.
    max_defect : float
        Largest shooting defect (rad or rad/s) accepted before falling back to IPOPT.
    jit : bool
        Compile the interval model and its Jacobian to C when a C compiler exists.
    generate_solver : bool
        With ``jit``: also generate the SQP solvers as C, compiled with the model
        (:mod:`excavator_payload.model.compiled_sqp`; the same numbers, faster).
    chain_rule_jacobian : bool
        The interval model's Jacobian by the chain rule through the RK4 stages: half the
        operations, the same derivative to rounding, so the data differ in their last bits
        (< 1e-15 relative) and so do estimators fitted on them; off by default, which keeps
        every dataset and exported C file as it was.
    extra : dict
        Further options of CasADi's ``sqpmethod``, passed as they are.
    """

    control_period: float = CONTROL_PERIOD
    horizon: float = HORIZON
    terminal_weight: tuple[float, float, float, float] = TERMINAL_WEIGHT
    angle_weight: float = 2e9  # Q on each angle error, per second
    input_rate_weight: float = 2e8  # R_Δ on the torque change in units of the limit
    rate_weight: float = 1e9  # Q_v on each joint rate, per second
    model_substeps: int = 2  # RK4 steps per control interval in the prediction model
    sqp_iterations: int = 2  # SQP iterations per control step (warm-started)
    cold_iterations: int = 50  # SQP iterations of the first step of an experiment
    max_defect: float = 1e-2  # largest shooting defect accepted before falling back to IPOPT
    jit: bool = True  # compile the interval model and its Jacobian to C (if a C compiler exists)
    generate_solver: bool = True  # with jit: the SQP solvers as generated C too
    chain_rule_jacobian: bool = False  # the interval Jacobian by the chain rule (equal to rounding)
    extra: dict = field(default_factory=dict)


@dataclass
class SolveRecord:
    """Outcome of one control step.

    Parameters
    ----------
    seconds : float
        Wall time of the step, s.
    status : str
        Solver return status (``ipopt:``-prefixed after a fallback).
    fallback : bool
        Whether the IPOPT fallback was used.
    """

    seconds: float
    status: str
    fallback: bool


class NMPCController:
    """The thesis' NMPC with input-rate cost, stage angle cost and torque bounds.

    Parameters
    ----------
    arm : ArmModel
        Model of the controlled machine (the controller knows the payload, as the thesis).
    settings : NMPCSettings, optional
        Tuning of the controller; default :class:`NMPCSettings`.
    """

    def __init__(self, arm: ArmModel, settings: NMPCSettings | None = None):
        self.arm = arm
        self.settings = s = settings or NMPCSettings()
        self.n_intervals = N = int(round(s.horizon / s.control_period))
        self.limits = np.asarray(arm.machine.torque_limits, dtype=float)
        F, symbolic_model = _interval_model(arm, s.control_period, s.model_substeps, s.jit,
                                            s.chain_rule_jacobian)
        self.compiled = F.class_name() == "External"

        # Multiple shooting in MX: the interval model F (and the Jacobian CasADi derives from
        # it) is called once per interval through ``map``, compiled to C when ``jit``.
        x0 = ca.MX.sym("x0", 4)
        ref = ca.MX.sym("ref", 2)
        u_prev = ca.MX.sym("u_prev", 2)  # in units of the limits
        payload = ca.MX.sym("payload")
        X = ca.MX.sym("X", 4, N + 1)
        U = ca.MX.sym("U", 2, N)  # in units of the limits

        scale = 1.0 / s.terminal_weight[0]
        P = ca.diag(ca.DM(s.terminal_weight))
        torques = U * ca.repmat(ca.DM(self.limits), 1, N)
        X_next = F.map(N)(X[:, :N], torques, payload)
        constraints = ca.vertcat(X[:, 0] - x0, ca.vec(X[:, 1:] - X_next))
        du = U - ca.horzcat(u_prev, U[:, :N - 1])
        angle_error = X[:2, 1:] - ca.repmat(ref, 1, N)
        rates = X[2:, 1:]
        terminal_error = X[:, N] - ca.vertcat(ref, 0, 0)
        cost = (s.input_rate_weight * ca.sumsqr(du)
                + s.control_period * s.angle_weight * ca.sumsqr(angle_error)
                + s.control_period * s.rate_weight * ca.sumsqr(rates)
                + ca.bilin(P, terminal_error, terminal_error))

        w = ca.vertcat(ca.vec(X), ca.vec(U))
        self._n_x = 4 * (N + 1)
        params = ca.vertcat(x0, ref, u_prev, payload)
        nlp = {"x": w, "p": params, "f": scale * cost, "g": constraints}
        # Gauss–Newton Hessian: the objective is a sum of squares, so its own Hessian is
        # constant and PSD; the constraint curvature Σλ∇²F is dropped. This saves the costly
        # second derivatives of the RK4 model and needs no convexification.
        hess_objective = ca.Function("h", [w, params], [ca.hessian(scale * cost, w)[0]])(
            np.zeros(w.shape[0]), np.zeros(params.shape[0]))
        hess_objective = ca.DM(ca.triu(hess_objective) + ca.triu(hess_objective, False).T)
        w_sx, p_sx = ca.SX.sym("w", w.shape[0]), ca.SX.sym("p", params.shape[0])
        lam_f, lam_g = ca.SX.sym("lam_f"), ca.SX.sym("lam_g", constraints.shape[0])
        hess_lag = ca.Function("nmpc_gauss_newton", [w_sx, p_sx, lam_f, lam_g],
                               [lam_f * ca.SX(hess_objective)],
                               ["x", "p", "lam_f", "lam_g"], ["hess_gamma_x_x"])
        sqp_opts = {
            "qpsol": "qrqp",
            "hess_lag": hess_lag,
            "qpsol_options": {"print_iter": False, "print_header": False, "print_info": False,
                              "error_on_fail": False},
            "hessian_approximation": "exact",
            "max_iter": s.sqp_iterations,
            "print_header": False,
            "print_iteration": False,
            "print_status": False,
            "print_time": False,
            "error_on_fail": False,
            **s.extra,
        }
        self._sqp = ca.nlpsol("nmpc_sqp", "sqpmethod", nlp, sqp_opts)
        # The first step of an experiment has no previous plan: iterate to convergence.
        self._sqp_cold = ca.nlpsol("nmpc_sqp_cold", "sqpmethod", nlp,
                                   {**sqp_opts, "max_iter": s.cold_iterations})
        # The SQP solvers as one generated C library with the model (where a compiler exists:
        # the same numbers, no virtual machine), else CasADi's, called through numpy buffers
        # (no DM conversions, same numbers).
        generated = (compiled_sqp([self._sqp, self._sqp_cold], symbolic_model, "nmpc_sqp")
                     if self.compiled and s.generate_solver else None)
        self.generated_solver = generated is not None
        calls = generated or {f.name(): BufferedCall(f) for f in (self._sqp, self._sqp_cold)}
        self._warm_call, self._cold_call = calls[self._sqp.name()], calls[self._sqp_cold.name()]
        # Fallback: interior point with the same Gauss–Newton Hessian (IPOPT takes the upper
        # triangle), cold-started.
        hess_lag_triu = ca.Function("nmpc_gauss_newton_triu", [w_sx, p_sx, lam_f, lam_g],
                                    [lam_f * ca.SX(ca.triu(hess_objective))],
                                    ["x", "p", "lam_f", "lam_g"], ["hess_gamma_x_x"])
        ipopt_opts = {"ipopt.print_level": 0, "ipopt.max_iter": 500, "print_time": False,
                      "ipopt.sb": "yes", "error_on_fail": False, "hess_lag": hess_lag_triu}
        self._ipopt = ca.nlpsol("nmpc_ipopt", "ipopt", nlp, ipopt_opts)
        self._n_g = constraints.shape[0]
        n_w = w.shape[0]
        self._lbx = np.full(n_w, -np.inf)
        self._ubx = np.full(n_w, np.inf)
        self._lbx[self._n_x:] = -1.0
        self._ubx[self._n_x:] = 1.0
        self.records: list[SolveRecord] = []
        self.reset(np.zeros(4), np.zeros(2), 0.0)

    # -- state of the controller -----------------------------------------------------------
    def reset(self, state: np.ndarray, target: np.ndarray, payload: float) -> None:
        """Start a new experiment: rest at ``state``, reach ``target``; the first guess is
        the gravity-holding torque at the start, constant, with the arm standing still.

        Parameters
        ----------
        state : numpy.ndarray
            Start state ``[q1, q2, q1dot, q2dot]`` (rad, rad/s).
        target : numpy.ndarray
            Target (boom, dipper) angles, rad.
        payload : float
            Payload mass, kg (known to the controller).
        """
        N = self.n_intervals
        state = np.asarray(state, dtype=float)
        hold = self.arm.gravity_torque(state[:2], payload) / self.limits
        self._u_applied = np.clip(hold, -1, 1)
        self._w = np.concatenate([np.tile(state, N + 1), np.tile(self._u_applied, N)])
        self._lam_g = np.zeros(self._n_g)
        self._lam_x = np.zeros_like(self._w)
        self._target = np.asarray(target, dtype=float)
        self._payload = float(payload)
        self._cold = True
        self.records = []

    def _params(self, state: np.ndarray) -> np.ndarray:
        return np.concatenate([state, self._target, self._u_applied, [self._payload]])

    def _solve(self, solver: ca.Function, state: np.ndarray, w0, lam_x0, lam_g0):
        args = dict(x0=w0, p=self._params(state), lbx=self._lbx, ubx=self._ubx,
                    lbg=0.0, ubg=0.0, lam_x0=lam_x0, lam_g0=lam_g0)
        if solver is self._ipopt:  # the IPOPT fallback, rare: called as it is
            return solver(**args), solver.stats()
        call = self._cold_call if solver is self._sqp_cold else self._warm_call
        return call(**args), call.stats()

    def control(self, state: np.ndarray) -> np.ndarray:
        """The torques (N·m) to apply for the next control period from ``state``.

        Parameters
        ----------
        state : numpy.ndarray
            Measured state ``[q1, q2, q1dot, q2dot]`` (rad, rad/s).

        Returns
        -------
        numpy.ndarray
            Boom and dipper torques, N·m, shape (2,).

        Raises
        ------
        ControlFailure
            If neither the warm-started SQP nor the IPOPT fallback gives a finite input.
        """
        state = np.asarray(state, dtype=float)
        start = _time.perf_counter()
        # Warm start: the previous plan, with the measured state as the first node.
        w0 = self._w.copy()
        w0[:4] = state
        solver = self._sqp_cold if self._cold else self._sqp
        sol, stats = self._solve(solver, state, w0, self._lam_x, self._lam_g)
        status = str(stats.get("return_status", ""))
        # Few iterations by design (real-time iteration): hitting max_iter is not a failure,
        # a failed QP, a non-finite plan or a large shooting defect (diverged) is.
        ok = stats.get("success", False) or status == "Maximum_Iterations_Exceeded"
        w = np.asarray(sol["x"]).ravel()
        fallback = False
        if not ok or not np.all(np.isfinite(w)) or self._defect(sol) > self.settings.max_defect:
            fallback = True
            sol, stats = self._solve(self._ipopt, state, w0, np.zeros_like(w0),
                                     np.zeros(self._n_g))
            status = "ipopt:" + str(stats.get("return_status", ""))
            w = np.asarray(sol["x"]).ravel()
            if not stats.get("success", False) or not np.all(np.isfinite(w)):
                self.records.append(SolveRecord(_time.perf_counter() - start, status, True))
                raise ControlFailure(f"NMPC failed: sqpmethod and IPOPT fallback ({status})")
        self._store(w, sol)
        self._cold = False
        self.records.append(SolveRecord(_time.perf_counter() - start, status, fallback))
        return self._u_applied * self.limits

    def _defect(self, sol) -> float:
        g = np.asarray(sol["g"]).ravel()
        return float(np.max(np.abs(g))) if g.size else 0.0

    def _store(self, w: np.ndarray, sol) -> None:
        n_x = self._n_x
        self._u_applied = w[n_x:n_x + 2].copy()
        # Shift the plan by one interval for the next warm start (last node/input repeated).
        self._w = _shifted(w, n_x, 4, 2)
        self._lam_g = _shifted(np.asarray(sol["lam_g"]).ravel(), self._n_g, 4, 2)
        lam_x = _shifted(np.asarray(sol["lam_x"]).ravel(), n_x, 4, 2)
        lam_x[:n_x] = 0.0
        self._lam_x = lam_x


def _shifted(values: np.ndarray, n_states: int, state_size: int, input_size: int) -> np.ndarray:
    """A plan ``[x_0 … x_N, u_0 … u_{N-1}]`` (the first ``n_states`` entries the nodes) shifted by
    one interval, the last node and input repeated; a copy."""
    out = np.empty_like(values)
    out[:n_states - state_size] = values[state_size:n_states]
    out[n_states - state_size:n_states] = values[n_states - state_size:n_states]
    if values.size > n_states:
        out[n_states:-input_size] = values[n_states + input_size:]
        out[-input_size:] = values[-input_size:]
    return out


# -- one experiment ---------------------------------------------------------------------------
#: An experiment has reached its target when both angles are within this of it ...
REACH_ANGLE = np.pi / 180.0  # 1°
#: ... and both joints move slower than this (at rest).
REST_RATE = np.pi / 180.0  # 1°/s


@dataclass
class ExperimentResult:
    """True signals of one simulated experiment at the sample instants, and how it went.

    Parameters
    ----------
    time : numpy.ndarray
        Sample times, s, shape (n,).
    q, qd : numpy.ndarray
        Boom and dipper angles (rad) and rates (rad/s), shape (n, 2).
    qdd : numpy.ndarray
        Accelerations from the dynamics under the applied torque, rad/s², shape (n, 2).
    tau : numpy.ndarray
        Torque applied from each instant on (zero-order hold), N·m, shape (n, 2).
    info : dict
        Final error, reached, settle time, solver status, fallbacks, solve times.
    """

    time: np.ndarray  # (n,) s
    q: np.ndarray  # (n, 2) rad
    qd: np.ndarray  # (n, 2) rad/s
    qdd: np.ndarray  # (n, 2) rad/s², from the dynamics under the applied torque
    tau: np.ndarray  # (n, 2) N·m, the torque applied from that instant on (zero-order hold)
    info: dict  # final error, reached, settle time, solver status, fallbacks, solve times


class NMPCSimulator:
    """Runs experiments: the NMPC drives the plant from the start pose to the target pose.

    The controller acts every ``control_period`` (0.1 s); the sensors sample every
    ``sample_period`` (0.05 s, 20 Hz), so each control input is held over two samples. The
    torque recorded at a sample instant is the one applied from that instant on, and the
    acceleration is the dynamics' q̈ under that torque, so every sample satisfies the inverse
    dynamics exactly.

    Parameters
    ----------
    arm : ArmModel
        Model of the machine (controller and plant).
    settings : NMPCSettings, optional
        Tuning of the controller; default :class:`NMPCSettings`.
    sample_period : float
        Sensor sample period, s; the control period must be a whole multiple of it.
    duration : float
        Length of an experiment, s.
    """

    def __init__(self, arm: ArmModel, settings: NMPCSettings | None = None,
                 sample_period: float = 0.05, duration: float = 5.0):
        from excavator_payload.simulation.plant import Plant

        self.arm = arm
        self.controller = NMPCController(arm, settings)
        self.plant = Plant(arm, sample_period)
        self.sample_period = float(sample_period)
        self.duration = float(duration)
        ratio = self.controller.settings.control_period / self.sample_period
        if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
            raise ValueError("the control period must be a whole number of sample periods")
        self.samples_per_control = int(round(ratio))

    def run(self, start_pose, target_pose, payload: float) -> ExperimentResult:
        """Simulate one experiment from rest at ``start_pose`` (rad) towards ``target_pose``.

        Parameters
        ----------
        start_pose : sequence of float
            Start (boom, dipper) angles, rad; the arm starts at rest.
        target_pose : sequence of float
            Target (boom, dipper) angles, rad.
        payload : float
            Payload mass, kg.

        Returns
        -------
        ExperimentResult
            The true signals at the sample times and a summary of the run.

        Raises
        ------
        ControlFailure
            If the NMPC fails (after its IPOPT fallback) or the plant state stops being finite.
        """
        wall_start = _time.perf_counter()
        n_samples = int(round(self.duration / self.sample_period)) + 1
        time = np.arange(n_samples) * self.sample_period
        state = np.array([start_pose[0], start_pose[1], 0.0, 0.0], dtype=float)
        target = np.asarray(target_pose, dtype=float)
        ctl = self.controller
        ctl.reset(state, target, payload)
        states = np.empty((n_samples, 4))
        torques = np.empty((n_samples, 2))
        accels = np.empty((n_samples, 2))
        k = self.samples_per_control
        for i in range(0, n_samples, k):
            torque = ctl.control(state)
            # the plant over one control period, torque held: the states at its sample instants
            block, accel, after = self.plant.hold(state, torque, payload, k)
            rows = slice(i, min(i + k, n_samples))
            m = rows.stop - rows.start
            states[rows], accels[rows], torques[rows] = block[:m], accel[:m], torque
            reached = np.vstack([block[1:], after]) if i + k < n_samples else block[1:m]
            bad = ~np.isfinite(reached).all(axis=1)
            if np.any(bad):
                raise ControlFailure(f"plant state became non-finite at t = "
                                     f"{time[i + 1 + int(np.argmax(bad))]:.2f} s")
            state = after
        q, qd = states[:, :2], states[:, 2:]
        info = self._summary(time, q, qd, target)
        solve = np.array([r.seconds for r in ctl.records])
        statuses = sorted({r.status for r in ctl.records})
        info.update({
            "solver_status": ",".join(statuses),
            "n_fallbacks": int(sum(r.fallback for r in ctl.records)),
            "n_solves": len(ctl.records),
            "solve_time_median_ms": float(np.median(solve) * 1e3),
            "solve_time_max_ms": float(np.max(solve) * 1e3),
            "wall_time": float(_time.perf_counter() - wall_start),
        })
        return ExperimentResult(time, q, qd, accels, torques, info)

    @staticmethod
    def _summary(time, q, qd, target) -> dict:
        angle_error = np.abs(q - target)
        settled = (angle_error.max(axis=1) < REACH_ANGLE) & (np.abs(qd).max(axis=1) < REST_RATE)
        unsettled = np.flatnonzero(~settled)
        if not settled[-1]:
            settle_time = None
        else:
            settle_time = float(time[unsettled[-1] + 1]) if unsettled.size else 0.0
        return {
            "final_error_deg": [float(v) for v in np.degrees(q[-1] - target)],
            "final_rate_deg_s": [float(v) for v in np.degrees(qd[-1])],
            "reached": bool(settled[-1]),
            "settle_time": settle_time,
        }
