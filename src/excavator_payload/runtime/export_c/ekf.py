"""C builder of ``ekf`` fitted on the thesis sensor set.

The whole filter step (update + prediction) is CasADi's code of
:func:`~excavator_payload.estimators.classical._kalman.ekf_step_symbolic`, built from the
symbolic arm model, and so is its gate
(:func:`~excavator_payload.estimators.classical._kalman.gate_symbolic`); initialisation,
clamping, status and gap bridging are written here, mirroring
:mod:`~excavator_payload.estimators.classical.ekf`. The float build computes the whole step in
float with an equivalent step (:func:`_ekf_single_functions`: the measurement updates as
sequential scalar Joseph updates of whitened measurements, no ill-conditioned matrix solve).
The thesis tuning has no usable noise model: it carries the borrowed gate.
"""

from __future__ import annotations

import casadi as ca

from excavator_payload.runtime.export_c.c_text import c_array, c_number
from excavator_payload.runtime.export_c.casadi_code import casadi_c_code, casadi_call, scalar_updates
from excavator_payload.runtime.export_c.registry import c_builder
from excavator_payload.runtime.export_c.cmodel import CModel, borrowed_gate


def _ekf_single_functions(est, torque_channel: bool) -> tuple[ca.Function, ca.Function]:
    """The EKF step and gate of a single-precision build: those of ``_kalman.ekf_step_symbolic``
    and ``_kalman.gate_symbolic`` (same inputs and outputs, same model functions, prediction
    line by line), with every measurement update done by :func:`scalar_updates`."""
    from excavator_payload.estimators.classical import _kalman as kf

    model = kf.kalman_model(est.machine, est.options["tuning"] == "thesis")
    n = kf.N_STATE
    n_y = 6 if torque_channel else 4
    x, P = ca.SX.sym("x", n), ca.SX.sym("P", n, n)
    y, u, a = ca.SX.sym("y", n_y), ca.SX.sym("u", 2), ca.SX.sym("a", 2)
    Q0, R_qqd = ca.SX.sym("Q", n, n), ca.SX.sym("R", 4, 4)
    torque_cov, accel_cov = ca.SX.sym("torque_cov", 2, 2), ca.SX.sym("accel_cov", 2, 2)
    mass = kf.kalman_mass_matrix(model)

    def torque_terms(at):
        h = model.measurement(at, a)[4:6]
        M = ca.reshape(mass(at), 2, 2)
        return h, ca.jacobian(h, at), torque_cov + M @ accel_cov @ M.T

    # update 1: angles and rates (linear); update 2: torques linearised at the result
    H1 = ca.horzcat(ca.SX.eye(4), ca.SX.zeros(4, 1))
    x_post, P_post = scalar_updates(x, P, y[0:4] - x[0:4], H1, R_qqd)
    if torque_channel:
        xs = ca.SX.sym("xs", n)
        torque_at = torque_terms(xs)
        h_1, H_1, R_1 = (ca.substitute(e, xs, x_post) for e in torque_at)
        x_post, P_post = scalar_updates(x_post, P_post, y[4:6] - h_1, H_1, R_1)
    # prediction at the posterior (as _kalman.ekf_step_symbolic)
    f = model.transition(x_post, u)
    F = ca.substitute(ca.jacobian(model.transition(x, u), x), x, x_post)
    if torque_channel:
        h_post, H_post, R_post = (ca.substitute(e, xs, x_post) for e in torque_at)
        G = ca.substitute(ca.jacobian(model.transition(x, u), u), x, x_post)
        G_sigma = G @ torque_cov
        D = -kf.scaled_solve(R_post, G_sigma.T, R_post).T
        x_next = f + D @ (y[4:6] - h_post)
        F_tilde = F - D @ H_post
        P_next = F_tilde @ P_post @ F_tilde.T + G_sigma @ G.T + Q0 + D @ G_sigma.T
    else:
        x_next = f
        P_next = F @ P_post @ F.T + Q0
    P_next = 0.5 * (P_next + P_next.T)
    packed = ca.cse(ca.densify(ca.vertcat(x_post, ca.vec(P_post), x_next, ca.vec(P_next))))
    step = ca.Function("ep_ekf_step", [x, P, y, u, a, Q0, R_qqd, torque_cov, accel_cov], [packed])
    # the gate: NIS of all measurements at the prior
    h_all = model.measurement(x, a)[:n_y]
    R_all = ca.SX.zeros(n_y, n_y)
    R_all[:4, :4] = R_qqd
    if torque_channel:
        R_all[4:, 4:] = torque_terms(x)[2]
    nis = scalar_updates(x, P, y - h_all, ca.jacobian(h_all, x), R_all, nis=True)
    gate = ca.Function("ep_ekf_gate", [x, P, y, a, R_qqd, torque_cov, accel_cov], [ca.cse(nis)])
    return step, gate


@c_builder("ekf", sensor_set="thesis")
def ekf_model(est) -> CModel:
    """The C of ``ekf`` on the thesis sensor set (``ExtendedKalmanFilter``).

    Parameters
    ----------
    est : Estimator
        The fitted estimator.
    """
    from excavator_payload.estimators.classical import _kalman as kf

    tuning = est.tuning
    thesis = est.options["tuning"] == "thesis"
    step_fn = kf.ekf_step_symbolic(est.machine, thesis, tuning.torque_channel)
    gate_fn = kf.gate_symbolic(est.machine, thesis, tuning.torque_channel)
    sensors = est.sensor_set
    measured = [sensors.index(s) for s in ("boom_angle", "dipper_angle", "boom_rate", "dipper_rate")]
    torques = [sensors.index(s) for s in ("boom_torque", "dipper_torque")]
    accels = [sensors.index(s) for s in ("boom_accel", "dipper_accel")]
    y_index = measured + torques if tuning.torque_channel else measured
    low, high = kf.payload_bounds(est.machine)
    o = est.options
    gate = borrowed_gate(est)
    functions = {"ep_ekf_step": step_fn}
    if gate is None:
        functions["ep_ekf_gate"] = gate_fn
    else:  # the thesis tuning has no usable noise model: it borrows the gate
        functions.update(gate.functions)
    code_double = casadi_c_code(functions)
    step_single, gate_single = _ekf_single_functions(est, tuning.torque_channel)
    functions_single = dict(functions, ep_ekf_step=step_single)
    if gate is None:
        functions_single["ep_ekf_gate"] = gate_single
    code_single = casadi_c_code(functions_single)
    code = code_double + code_single  # what the calls' work arrays are sized from

    def either(name, double_fn, single_fn, inputs, outputs):
        """The call of generated ``name``: its double or its single-precision variant."""
        return "\n".join(["#if EP_SINGLE", casadi_call(name, single_fn, inputs, outputs, code),
                          "#else", casadi_call(name, double_fn, inputs, outputs, code), "#endif"])

    definitions = "\n".join([
        "/* One EKF step generated by CasADi from the symbolic arm model (_kalman.ekf_step_symbolic):",
        " * sequential Joseph-form update with y, then the (decorrelated) Euler prediction with u.",
        " * Output: [x_post (5), vec P_post (25), x_next (5), vec P_next (25)].",
        " * The gate (_kalman.gate_symbolic): nu' S^-1 nu of all measurements at the prior.",
        " * The filter computes in ep_real. In a single-precision build (EP_SINGLE) the same step",
        " * does its measurement updates as sequential scalar Joseph-form updates of whitened",
        " * measurements (and the gate sums the scalar NIS): the same filter in exact arithmetic,",
        " * without solving the joint innovation covariance, whose condition number (up to 1e9",
        " * with the consistent tuning, 1e20 with the thesis' P0 = 5e15, R = 1e-5) is beyond",
        " * float's 7 digits; P is symmetrised after every update. */",
        "#if EP_SINGLE",
        code_single,
        "#else",
        code_double,
        "#endif",
        "",
        c_array("EP_Q", tuning.Q.ravel(order="F"), kind="static const ep_real"),
        c_array("EP_R", tuning.R.ravel(order="F"), kind="static const ep_real"),
        c_array("EP_TORQUE_COV", tuning.torque_cov.ravel(order="F"), kind="static const ep_real"),
        c_array("EP_ACCEL_COV", tuning.accel_cov.ravel(order="F"), kind="static const ep_real"),
        c_array("EP_X0", tuning.x0, kind="static const ep_real"),
        c_array("EP_P0", tuning.P0.ravel(order="F"), kind="static const ep_real"),
        f"static const int EP_Y_INDEX[{len(y_index)}] = {{{', '.join(map(str, y_index))}}};",
        (f"static const int EP_MEASURED[4] = {{{', '.join(map(str, measured))}}};"
         if tuning.init_from_sample else "/* angles and rates do not start from the sample */"),
        f"#define EP_N_Y {len(y_index)}",
        f"#define EP_INIT_FROM_SAMPLE {int(tuning.init_from_sample)}",
        f"#define EP_TORQUE_CHANNEL {int(tuning.torque_channel)}",
        f"#define EP_WARMUP_SAMPLES {int(o['warmup_samples'])}",
        f"#define EP_CONVERGED_STD {c_number(o['converged_std'], cast=True)}",
        f"#define EP_MAX_GAP {c_number(o['max_gap'], cast=True)}",
        f"#define EP_TS {c_number(kf.TS, cast=True)}",
        f"#define EP_PAYLOAD_LOW {c_number(low, cast=True)}",
        f"#define EP_PAYLOAD_HIGH {c_number(high, cast=True)}",
        "",
        "/* _kalman.initial_state: x0 (angles and rates from the sample), P0 */",
        "static void ep_initial_state(ep_state *s, const ep_real v[EP_N_SIGNALS])",
        "{",
        "    int i;",
        "    for (i = 0; i < 5; ++i) s->x[i] = EP_X0[i];",
        "#if EP_INIT_FROM_SAMPLE",
        "    for (i = 0; i < 4; ++i) s->x[i] = v[EP_MEASURED[i]];",
        "#else",
        "    (void)v;",
        "#endif",
        "    for (i = 0; i < 25; ++i) s->P[i] = EP_P0[i];",
        "}",
        "",
        "static ep_real ep_clamp_payload(ep_real m)",
        "{",
        "    return m < EP_PAYLOAD_LOW ? EP_PAYLOAD_LOW : (m > EP_PAYLOAD_HIGH ? EP_PAYLOAD_HIGH : m);",
        "}",
    ])
    step = f"""    /* ExtendedKalmanFilter._step */
    ep_real packed[60], y[EP_N_Y], u[2], a[2];
    int i, status;
    (void)time;
    if (!s->started) {{
        ep_initial_state(s, v);
        s->started = 1;
    }}
    for (i = 0; i < EP_N_Y; ++i) y[i] = v[EP_Y_INDEX[i]];
    u[0] = v[{torques[0]}]; u[1] = v[{torques[1]}];
    a[0] = v[{accels[0]}]; a[1] = v[{accels[1]}];
{either("ep_ekf_step", step_fn, step_single, ["s->x", "s->P", "y", "u", "a", "EP_Q", "EP_R", "EP_TORQUE_COV", "EP_ACCEL_COV"], ["packed"])}
    /* a bad posterior discards the sample; a bad prediction keeps the posterior as prior */
    for (i = 0; i < 60; ++i) {{
        if (!isfinite(packed[i])) {{
            *estimate = s->last_estimate;
            return EP_STATUS_INVALID;
        }}
    }}
    for (i = 0; i < 5; ++i) {{
        if (packed[5 + 6 * i] < EP_C(0.0)) {{
            *estimate = s->last_estimate;
            return EP_STATUS_INVALID;
        }}
    }}
    packed[4] = ep_clamp_payload(packed[4]);
    for (i = 0; i < 5; ++i) s->x[i] = packed[i];
    for (i = 0; i < 25; ++i) s->P[i] = packed[5 + i];
    /* KalmanEstimatorBase._result */
    s->n_filtered += 1;
    s->posterior_std = EP_MATH(sqrt)(s->P[24] > EP_C(0.0) ? s->P[24] : EP_C(0.0));
    *estimate = s->x[4];
    if (s->n_filtered <= EP_WARMUP_SAMPLES) status = EP_STATUS_WARMING_UP;
    else if (EP_TORQUE_CHANNEL && s->posterior_std > EP_CONVERGED_STD) status = EP_STATUS_WARMING_UP;
    else status = EP_STATUS_OK;
    for (i = 0; i < 5; ++i) {{
        if (packed[35 + 6 * i] < EP_C(0.0)) return status;
    }}
    packed[34] = ep_clamp_payload(packed[34]);
    for (i = 0; i < 5; ++i) s->x[i] = packed[30 + i];
    for (i = 0; i < 25; ++i) s->P[i] = packed[35 + i];
    return status;"""
    on_gap = """    /* KalmanEstimatorBase._on_gap: bridge a short gap, keeping the payload and growing its
     * variance by the random walk, P_mm += q_m dt / Ts; restart after a long one */
    ep_real dt = time - s->last_time, payload, payload_var;
    if (!s->started || !s->has_last_time || !(EP_C(0.0) < dt && dt <= EP_MAX_GAP)) {
        ep_model_reset(s);
        return;
    }
    payload = s->x[4];
    payload_var = s->P[24];
    ep_initial_state(s, v);
    s->x[4] = payload;
    s->P[24] = payload_var + EP_Q[24] * dt / EP_TS;"""
    gate_call = "" if gate is not None else either("ep_ekf_gate", gate_fn, gate_single,
                                                   ["s->x", "s->P", "y", "a", "EP_R", "EP_TORQUE_COV",
                                                    "EP_ACCEL_COV"], ["&value"])
    innovation = f"""    /* KalmanEstimatorBase._innovation: NIS of the filter's measurements at the prior */
    ep_real y[EP_N_Y], a[2], value;
    int i;
    (void)time;
    if (!s->started) return 0;
    for (i = 0; i < EP_N_Y; ++i) y[i] = v[EP_Y_INDEX[i]];
    a[0] = v[{accels[0]}]; a[1] = v[{accels[1]}];
{gate_call}
    *nis = value;
    return 1;"""
    state_finite = """    /* KalmanEstimatorBase._state_finite */
    int i;
    if (!s->started) return 1;
    for (i = 0; i < 5; ++i) if (!isfinite(s->x[i])) return 0;
    for (i = 0; i < 25; ++i) if (!isfinite(s->P[i])) return 0;
    return 1;"""
    model = CModel(
        description=f"ekf: extended Kalman filter, tuning {o['tuning']} (machine {est.machine.name})",
        state_fields=["ep_real x[5];        /* [q1, q2, qd1, qd2, payload] */",
                      "ep_real P[25];       /* covariance, column-major */",
                      "int started;         /* x, P initialised */",
                      "int n_filtered;      /* samples since the filter (re)started */",
                      "ep_real posterior_std;"],
        definitions=definitions,
        reset="    int i;\n    s->started = 0;\n    s->n_filtered = 0;\n    s->posterior_std = EP_NAN;\n"
              "    for (i = 0; i < 5; ++i) s->x[i] = EP_C(0.0);\n"
              "    for (i = 0; i < 25; ++i) s->P[i] = EP_C(0.0);",
        step=step, on_gap=on_gap, innovation=innovation, gate_dof=len(y_index),
        sigma="    /* _estimate_sigma: the payload's posterior standard deviation */\n"
              "    return s->posterior_std;",
        state_finite=state_finite)
    if gate is not None:
        gate.apply(model, code)
    return model
