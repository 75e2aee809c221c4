"""C builder of ``ekf`` fitted on the machine sensor set (pressures + IMUs).

One step of :class:`~excavator_payload.estimators.classical._kalman_machine.MachineKalman`
(update with angles and rates, update with the piston forces of ``force_measurement_symbolic``
with the machine's parameters as constants, low-speed rule, payload clamp, white-jerk
prediction) is one CasADi-generated function (:func:`_machine_ekf_functions`), in a double and
a single-precision variant; initialisation, status, the one-frame glitch test with its undo and
gap bridging are written here. No chi-square gate (none in Python on this set).
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from excavator_payload.errors import EstimatorError
from excavator_payload.runtime.export_c.c_text import c_array, c_number, one_frame_glitch_c
from excavator_payload.runtime.export_c.casadi_code import (
    casadi_c_code,
    casadi_call,
    ground_tilt_symbolic,
    scalar_updates,
)
from excavator_payload.runtime.export_c.registry import c_builder
from excavator_payload.runtime.export_c.cmodel import CModel


def _machine_ekf_functions(est, single: bool) -> ca.Function:
    """One step of ``_kalman_machine.MachineKalman`` (EKF) as a CasADi function of the prior
    ``x`` (12), ``P`` (12×12) and the sample (15), everything else constant:
    ``[x_post (12), vec P_post (144), x_next (12), vec P_next (144)]``, the posterior's payload
    clamped (the prediction starts from it). The force model is
    ``force_measurement_symbolic`` (the symbolic hydraulic model) with the machine's parameter
    vector as constants. ``single``: the measurement updates as :func:`scalar_updates`
    (float builds), else line by line as the Python (update 1 in the plain form, update 2 in
    Joseph form, linear solves)."""
    from excavator_payload.estimators.classical import _kalman_machine as km

    mk = est._machine_filter
    n, payload = km.N_STATE, km.PAYLOAD
    x = ca.SX.sym("x", n)
    P = ca.SX.sym("P", n, n)
    v = ca.SX.sym("v", len(est.sensor_set.signals))
    R_kin = ca.DM(mk.R_kin)
    # update 1: angles and rates, h = x[:7]
    measured = ca.vertcat(*[v[i] for i in km.KINEMATIC])
    H1 = ca.horzcat(ca.SX.eye(km.N_KIN), ca.SX.zeros(km.N_KIN, n - km.N_KIN))
    if single:
        x1, P1 = scalar_updates(x, P, measured - x[:km.N_KIN], H1, ca.SX(R_kin))
    else:
        S = P[:km.N_KIN, :km.N_KIN] + R_kin
        K = ca.solve(S, P[:km.N_KIN, :]).T
        x1 = x + K @ (measured - x[:km.N_KIN])
        P1 = P - K @ P[:km.N_KIN, :]
        P1 = 0.5 * (P1 + P1.T)
    # update 2: the piston forces through the symbolic model, at the state after update 1
    pressures = [v[i] for i in km.PRESSURES]
    head, rod = np.sqrt(mk._head2), np.sqrt(mk._rod2)  # as MachineKalman keeps them
    force = ca.vertcat(*[pressures[2 * j] * head[j] - pressures[2 * j + 1] * rod[j] for j in range(3)])
    tilt = ground_tilt_symbolic(v[km.PITCH], v[km.ROLL])
    packed = km.force_measurement_symbolic()(x1, tilt, force, ca.DM(np.asarray(mk._p, float)))
    h, H = packed[0:3], ca.reshape(packed[3:39], 3, n)
    breakaway, speed = packed[39:42], packed[42:45]
    noise = [mk._head2[j] * (mk._pvar + mk._ripple * pressures[2 * j] ** 2)
             + mk._rod2[j] * (mk._pvar + mk._ripple * pressures[2 * j + 1] ** 2) for j in range(3)]
    variances = []
    for j in range(3):
        var = noise[j] + ca.exp(-(speed[j] / mk._v_still[j]) ** 2) * breakaway[j] ** 2 / 3
        if mk.skip_low_speed:  # a slow cylinder gives no force once the payload is known
            skip = ca.logic_and(P1[payload, payload] < mk.skip_std ** 2, ca.fabs(speed[j]) < mk._v_skip[j])
            var = var + ca.if_else(skip, 1e30, 0.0)
        variances.append(var)
    R = ca.diag(ca.vertcat(*variances))
    if single:
        x2, P2 = scalar_updates(x1, P1, force - h, H, R)
    else:
        PHt = P1 @ H.T
        S = H @ PHt + R
        K = ca.solve(S, PHt.T).T
        x2 = x1 + K @ (force - h)
        I_KH = ca.SX.eye(n) - K @ H
        P2 = I_KH @ P1 @ I_KH.T + K @ R @ K.T
    low, high = mk._bounds
    x2 = ca.vertcat(x2[:payload], ca.fmin(ca.fmax(x2[payload], low), high))
    # prediction (linear)
    F = ca.DM(mk.F)
    x_next = F @ x2
    P_next = F @ P2 @ F.T + ca.DM(mk.Q)
    P_next = 0.5 * (P_next + P_next.T)
    out = ca.cse(ca.densify(ca.vertcat(x2, ca.vec(P2), x_next, ca.vec(P_next))))
    return ca.Function("ep_machine_ekf_step", [x, P, v], [out])


@c_builder("ekf", sensor_set="machine")
def machine_ekf_model(est) -> CModel:
    """``ekf`` fitted on the machine sensor set: ``_kalman_machine.MachineKalman`` with the
    status rules of ``KalmanEstimatorBase._machine_step`` (no statistical gate on this set; the
    one-frame glitch test with its undo, as the Python).

    Parameters
    ----------
    est : Estimator
        The fitted estimator.
    """
    from excavator_payload.estimators.classical import _kalman_machine as km
    from excavator_payload.estimators.classical.calibrated_machine import NO_LIMIT

    mk = est._machine_filter
    if mk is None or mk.unscented:
        raise EstimatorError(f"{est.name}: fitted on machine-sensor-set data but has no EKF kernel")
    n = km.N_STATE
    step_double = _machine_ekf_functions(est, single=False)
    step_single = _machine_ekf_functions(est, single=True)
    code_double = casadi_c_code({"ep_machine_ekf_step": step_double})
    code_single = casadi_c_code({"ep_machine_ekf_step": step_single})
    code = code_double + code_single
    calls = "\n".join(["#if EP_SINGLE",
                       casadi_call("ep_machine_ekf_step", step_single, ["s->x", "s->P", "v"], ["packed"], code),
                       "#else",
                       casadi_call("ep_machine_ekf_step", step_double, ["s->x", "s->P", "v"], ["packed"], code),
                       "#endif"])
    o = est.options
    x0_p0 = np.r_[100.0 * mk.tuning.R_kinematic, np.ones(4), (mk._max_payload / 2) ** 2]
    definitions = "\n".join([
        "/* One step of the machine-set EKF (_kalman_machine.MachineKalman), generated by CasADi:",
        " * update with the angles and rates, then with the piston forces predicted by the symbolic",
        " * hydraulic model (force_measurement_symbolic, the machine's parameters as constants),",
        " * then the white-jerk prediction. Output: [x_post (12), vec P_post (144), x_next (12),",
        " * vec P_next (144)], the posterior's payload clamped. A single-precision build does the",
        " * measurement updates as sequential scalar Joseph updates (the same filter without an",
        " * ill-conditioned solve; the skipped forces' 1e30 variance squared overflows float). */",
        "#if EP_SINGLE",
        code_single,
        "#else",
        code_double,
        "#endif",
        "",
        f"static const int EP_KINEMATIC[{km.N_KIN}] = {{{', '.join(map(str, km.KINEMATIC))}}};",
        c_array("EP_P0_DIAG", x0_p0).rstrip() + "  /* initial_state: 100 R_kin, 1 (rad/s^2)^2, (m_max/2)^2 */",
        f"#define EP_INITIAL_PAYLOAD {c_number(mk._max_payload / 2)}",
        f"#define EP_WARMUP_SAMPLES {int(o['warmup_samples'])}",
        f"#define EP_CONVERGED_STD {c_number(o['converged_std'])}",
        f"#define EP_MAX_GAP {c_number(o['max_gap'])}",
        f"#define EP_PAYLOAD_WALK_VAR {c_number(mk.tuning.payload_walk ** 2)}  /* kg^2/s */",
        "",
        "/* KalmanEstimatorBase._judge_previous: a sample is a one-frame glitch when a signal stands",
        " * out from both neighbours in the same direction by more than z sigma_delta and more than",
        " * they differ; the filter then goes back to its state before it and predicts over its slot.",
        " * Off with -DEP_GATING=0 (Estimator.gating = False). */",
        *one_frame_glitch_c(est.gating, np.minimum(mk.tuning.spike_threshold, NO_LIMIT)),
        c_array("EP_F", mk.F).rstrip() + "  /* white-jerk transition, row-major */",
        c_array("EP_Q", mk.Q).rstrip() + "  /* its process noise, row-major */",
        "",
        "/* MachineKalman.predict: x = F x, P = F P F' + Q, symmetrised (P column-major) */",
        "static void ep_predict(ep_state *s)",
        "{",
        f"    ep_real x[{n}], T[{n * n}], Pn[{n * n}];",
        "    int i, j, k;",
        f"    for (i = 0; i < {n}; ++i) {{",
        "        x[i] = EP_C(0.0);",
        f"        for (k = 0; k < {n}; ++k) x[i] += EP_F[i * {n} + k] * s->x[k];",
        "    }",
        f"    for (i = 0; i < {n}; ++i)",
        f"        for (j = 0; j < {n}; ++j) {{",
        f"            T[i + j * {n}] = EP_C(0.0);",
        f"            for (k = 0; k < {n}; ++k) T[i + j * {n}] += EP_F[i * {n} + k] * s->P[k + j * {n}];",
        "        }",
        f"    for (i = 0; i < {n}; ++i)",
        f"        for (j = 0; j < {n}; ++j) {{",
        f"            Pn[i + j * {n}] = EP_Q[i * {n} + j];",
        f"            for (k = 0; k < {n}; ++k) Pn[i + j * {n}] += T[i + k * {n}] * EP_F[j * {n} + k];",
        "        }",
        f"    for (i = 0; i < {n}; ++i) {{",
        "        s->x[i] = x[i];",
        f"        for (j = 0; j < {n}; ++j) s->P[i + j * {n}] = EP_C(0.5) * (Pn[i + j * {n}] + Pn[j + i * {n}]);",
        "    }",
        "}",
        "",
        "/* MachineKalman.initial_state: angles and rates from the sample (broad prior), accelerations",
        " * 0 +- 1 rad/s^2, payload m_max/2 +- m_max/2 */",
        "static void ep_initial_state(ep_state *s, const ep_real v[EP_N_SIGNALS])",
        "{",
        "    int i;",
        f"    for (i = 0; i < {n}; ++i) s->x[i] = EP_C(0.0);",
        f"    for (i = 0; i < {n * n}; ++i) s->P[i] = EP_C(0.0);",
        f"    for (i = 0; i < {km.N_KIN}; ++i) s->x[i] = v[EP_KINEMATIC[i]];",
        f"    s->x[{km.PAYLOAD}] = EP_INITIAL_PAYLOAD;",
        f"    for (i = 0; i < {n}; ++i) s->P[i * {n + 1}] = EP_P0_DIAG[i];",
        "}",
    ])
    np_ = n * n
    step = f"""    /* KalmanEstimatorBase._machine_step around MachineKalman.step */
    ep_real packed[{2 * (n + np_)}];
    int i, undone = 0, hold = 0;
    ep_real held_std = s->posterior_std;
    (void)time;
#if EP_GATING
    /* _judge_previous: the sample before this one a glitch? back to the state before it */
    int judged = s->n_recent >= 2 && s->has_undo
        ? ep_spike(s->n_recent == 3 ? s->recent : 0, s->recent + (s->n_recent - 2) * EP_N_SIGNALS,
                   s->recent + (s->n_recent - 1) * EP_N_SIGNALS, v, 0) : 0;
    if (judged) {{  /* stands out: undone; reported only as a glitch */
        for (i = 0; i < {n}; ++i) s->x[i] = s->undo_x[i];
        for (i = 0; i < {np_}; ++i) s->P[i] = s->undo_P[i];
        s->n_filtered = s->undo_n_filtered;
        ep_predict(s);
        for (i = 0; i < EP_N_SIGNALS; ++i)
            s->recent[(s->n_recent - 1) * EP_N_SIGNALS + i] =
                EP_C(0.5) * (s->recent[(s->n_recent - 2) * EP_N_SIGNALS + i] + v[i]);
        undone = judged == 2;
    }}
#else
    (void)ep_spike;
#endif
    /* the state before this sample (to undo it), and the last three samples */
    s->has_undo = s->started;
    if (s->started) {{
        for (i = 0; i < {n}; ++i) s->undo_x[i] = s->x[i];
        for (i = 0; i < {np_}; ++i) s->undo_P[i] = s->P[i];
        s->undo_n_filtered = s->n_filtered;
    }}
#if EP_GATING
    /* a sample that jumps from the one before it: its own estimate (and sigma) is the last one
     * held, so a glitch the next sample reveals is never reported */
    if (s->started && s->n_recent >= 1 && isfinite(s->last_estimate))
        for (i = 0; i < EP_N_SIGNALS; ++i)
            if (EP_MATH(fabs)(v[i] - s->recent[(s->n_recent - 1) * EP_N_SIGNALS + i]) > EP_SPIKE_THRESHOLD[i])
                hold = 1;
#endif
    if (s->n_recent == 3)
        for (i = 0; i < 2 * EP_N_SIGNALS; ++i) s->recent[i] = s->recent[EP_N_SIGNALS + i];
    else
        s->n_recent += 1;
    for (i = 0; i < EP_N_SIGNALS; ++i) s->recent[(s->n_recent - 1) * EP_N_SIGNALS + i] = v[i];
    if (!s->started) {{
        ep_initial_state(s, v);
        s->started = 1;
    }}
{calls}
    /* a posterior that is not finite or has a negative variance: the sample is not used */
    for (i = 0; i < {n + np_}; ++i) {{
        if (!isfinite(packed[i])) {{
            *estimate = s->last_estimate;
            return EP_STATUS_INVALID;
        }}
    }}
    for (i = 0; i < {n}; ++i) {{
        if (packed[{n} + {n + 1} * i] < EP_C(0.0)) {{
            *estimate = s->last_estimate;
            return EP_STATUS_INVALID;
        }}
    }}
    s->n_filtered += 1;
    {{
        ep_real var = packed[{n} + {n + 1} * {km.PAYLOAD}];
        s->posterior_std = hold ? held_std : EP_MATH(sqrt)(var > EP_C(0.0) ? var : EP_C(0.0));
    }}
    *estimate = hold ? s->last_estimate : packed[{km.PAYLOAD}];
    for (i = 0; i < {n}; ++i) s->x[i] = packed[{n + np_} + i];
    for (i = 0; i < {np_}; ++i) s->P[i] = packed[{2 * n + np_} + i];
    if (s->n_filtered <= EP_WARMUP_SAMPLES || s->posterior_std > EP_CONVERGED_STD)
        return EP_STATUS_WARMING_UP;
    return undone ? EP_STATUS_REJECTED : EP_STATUS_OK;"""
    on_gap = f"""    /* KalmanEstimatorBase._on_gap / MachineKalman.restart_kinematics: a short gap restarts the
     * kinematic states from the sample and keeps the payload (its variance grown by the random
     * walk); a long one (or time going back) restarts the filter */
    ep_real dt = time - s->last_time, payload, payload_var;
    if (!s->started || !s->has_last_time || !(EP_C(0.0) < dt && dt <= EP_MAX_GAP)) {{
        ep_model_reset(s);
        return;
    }}
    payload = s->x[{km.PAYLOAD}];
    payload_var = s->P[{km.PAYLOAD * (n + 1)}];
    ep_initial_state(s, v);
    s->x[{km.PAYLOAD}] = payload;
    s->P[{km.PAYLOAD * (n + 1)}] = payload_var + EP_PAYLOAD_WALK_VAR * dt;
    s->n_recent = 0;  /* no neighbours across a gap */
    s->has_undo = 0;"""
    return CModel(
        description=f"ekf on the machine sensor set: extended Kalman filter on IMU angles and rates and "
                    f"cylinder pressures (machine {est.machine.name}, noise {mk.tuning.noise}, "
                    f"--low-speed {o['low_speed']})",
        state_fields=[f"ep_real x[{n}];    /* angles (3), rates (4), accelerations (4), payload */",
                      f"ep_real P[{np_}];  /* covariance, column-major */",
                      "int started;      /* x, P initialised */",
                      "int n_filtered;   /* samples since the filter (re)started */",
                      "ep_real posterior_std;",
                      f"ep_real undo_x[{n}];  /* the state before the last sample (glitch undo) */",
                      f"ep_real undo_P[{np_}];",
                      "int undo_n_filtered;",
                      "int has_undo;",
                      "ep_real recent[3 * EP_N_SIGNALS];  /* the last three samples used */",
                      "int n_recent;"],
        definitions=definitions,
        reset="    s->started = 0;\n    s->n_filtered = 0;\n    s->posterior_std = EP_NAN;\n"
              "    s->has_undo = 0;\n    s->n_recent = 0;",
        step=step, on_gap=on_gap,
        sigma="    /* _estimate_sigma: the payload's posterior standard deviation */\n"
              "    return s->posterior_std;",
        # KalmanEstimatorBase._state_finite watches the thesis set's state only
        state_finite="    (void)s;\n    return 1;")
