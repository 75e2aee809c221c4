"""C builder of ``inverse-dynamics`` and ``calibrated`` fitted on the machine sensor set.

The kernel :class:`~excavator_payload.estimators.classical.pressure_regression.PressureRegression`
(``calibrated``: ``calibrated_machine.CalibratedKernel``). One sample of the weighing regression
is CasADi's code of ``HydraulicSymbolic.functions["pressure_regression"]`` with the fitted
parameter vector as constants, behind the kernel's sensor correction (``calibrated``:
``calibrated_machine._corrected_signals`` with the identified offsets and IMU dynamics as
constants; ``inverse-dynamics``: the ground tilt from the house IMU). The ring buffer of
``2·half_window + 1`` samples, the centred least-squares slope of the rates, the weights and
``--low-speed`` rule, the recursive sums, status, sigma and gap rule (a short gap restarts the
window) are ported here (``calibrated --balance momentum``: one sample's momentum-balance terms
from ``HydraulicSymbolic.functions["momentum_regression"]``, and a second ring holding the
balance's window), and so is the kernels' one-frame outlier test in place of the chi-square
gate (the sample before the newest judged between its neighbours against per-signal
thresholds from the fit data, its slot repaired and never regressed, ``rejected_outlier``;
``-DEP_GATING=0`` turns it off).
"""

from __future__ import annotations

import textwrap

import casadi as ca
import numpy as np

from excavator_payload.errors import EstimatorError
from excavator_payload.runtime.export_c.c_text import c_array, c_number, one_frame_glitch_c
from excavator_payload.runtime.export_c.casadi_code import (
    casadi_c_code,
    casadi_call,
    ground_tilt_symbolic,
)
from excavator_payload.runtime.export_c.joint_check import add_joint_check, exports_joint_check
from excavator_payload.runtime.export_c.registry import c_builder
from excavator_payload.runtime.export_c.cmodel import CModel
from excavator_payload.runtime.export_c.imu_nuisance import imu_nuisance_c, imu_nuisance_functions
from excavator_payload.runtime.export_c.offset_share import offset_share_c, offset_share_functions, with_offset_share


@c_builder("inverse-dynamics", "calibrated", sensor_set="machine")
def pressure_regression_model(est) -> CModel:
    """``inverse-dynamics`` and ``calibrated`` fitted on machine-sensor-set data: the kernel
    :class:`~excavator_payload.estimators.classical.pressure_regression.PressureRegression`
    (for ``calibrated`` its subclass ``calibrated_machine.CalibratedKernel``), ported to C.

    The physics is CasADi's code of ``HydraulicSymbolic.functions["pressure_regression"]``
    with the fitted parameter vector baked in as constants, behind the ground tilt each
    kernel computes from the house IMU; the rest (ring buffer, centred slope, weights,
    low-speed rule, recursive sums, status, sigma, gap rule) is written here, line by line
    after the Python.

    Parameters
    ----------
    est : Estimator
        The fitted estimator.
    """
    from excavator_payload.estimators.classical.calibrated_machine import (
        CHANGING_SIGMAS, NEW_LOAD_SIGMAS, CalibratedKernel)
    from excavator_payload.estimators.classical.machine_calibration.settings import (
        BOOM_READY_WINDOWS, DUMP_OPENING_RATE, DUMP_RESTARTS, DUMP_TURN, SETTLE_WINDOWS, STEADY_WINDOWS)
    from excavator_payload.estimators.classical.inverse_dynamics import MAX_BRIDGED_GAP
    from excavator_payload.estimators.classical.pressure_regression import (
        ANGLES, PITCH, PRESSURES, RATES, ROLL, PressureKernel)
    from excavator_payload.model.hydraulic import hydraulic_symbolic

    if not isinstance(est.kernel, PressureKernel):
        raise EstimatorError(f"{est.name}: fitted on machine-sensor-set data but has no kernel")
    kernel = est.kernel.regression
    nuisance = getattr(kernel, "_imu_nuisance", None) is not None  # --imu-nuisance on: imu_nuisance.py
    model_var = float(kernel.model_std) ** 2
    calibrated = isinstance(kernel, CalibratedKernel)
    momentum = calibrated and kernel.balance == "momentum"
    # a named cylinder pressure drops its joint (degraded_pressures; health.py's ep_hm_substitute)
    drops = momentum and bool(est.degraded_pressures())
    dropped_at_centre = "\n                                                            && !(s->ring_drop[centre_slot] >> j & 1)" \
        if drops else ""
    sensors = est.sensor_set
    n = len(sensors.signals)
    h = int(kernel.half_window)
    width = 2 * h + 1
    p = np.asarray(kernel._p, dtype=float)
    # One sample of the kernel with the fitted machine as constants: corrected signals (15) and
    # the differentiated rates (4) -> residual, phi, lever, rod speed, stiction (3 each).
    x = ca.SX.sym("x", n)
    qdd = ca.SX.sym("qdd", len(RATES))
    q = ca.vertcat(*[x[i] for i in ANGLES], 0)  # the slew angle does not enter the dynamics
    qd = ca.vertcat(*[x[i] for i in RATES])
    if calibrated:  # calibrated_machine.kernel_function: the sensor correction of calibration
        from excavator_payload.estimators.classical.calibrated_machine import _corrected_signals

        q, qd, tilt, pressures = _corrected_signals(x, qdd, ca.DM(np.asarray(kernel._offset, float)),
                                                    ca.DM(np.asarray(kernel._imu, float)))
    else:  # pressure_regression.ground_tilt
        tilt = ground_tilt_symbolic(x[PITCH], x[ROLL])
        pressures = ca.vertcat(*[x[i] for i in PRESSURES])
    if momentum:  # calibrated_machine.kernel_function("momentum"): the balance terms of one sample
        from excavator_payload.estimators.classical.calibrated_machine import _momentum_terms

        A, lever_s, speed_s, stiction_s, gain_s = _momentum_terms(
            x, qdd, ca.DM(p), ca.DM(np.asarray(kernel._offset, float)), ca.DM(np.asarray(kernel._imu, float)))
        outputs = [A, lever_s, speed_s, stiction_s, gain_s]
    else:
        outputs = hydraulic_symbolic().functions["pressure_regression"](q, qd, qdd, tilt, pressures, ca.DM(p))
    kernel_fn = ca.Function("ep_pressure_regression", [x, qdd], [ca.vertcat(*outputs)], ["x", "qdd"], ["out"])
    extra = imu_nuisance_functions(kernel) if nuisance else {}
    zero_share = getattr(kernel, "_offset_share", None) is not None  # after a zero: offset_share.py
    if zero_share:
        extra.update(offset_share_functions(kernel))
    code = casadi_c_code({"ep_pressure_regression": kernel_fn, **extra})

    head, rod = np.asarray(kernel._head, float), np.asarray(kernel._rod, float)
    still_speed = 3 * np.asarray(kernel._v_stribeck, float)
    rates_c = ", ".join(str(i) for i in RATES)
    defs = [
        "/* One sample of the machine's weighing regression, generated by CasADi from the symbolic",
        " * model (HydraulicSymbolic.functions[\"pressure_regression\"]) with the fitted parameter",
        " * vector as constants; input: the sample at the window's centre (as measured) and",
        " * the centred slope of the rates; output: [residual tau_p - tau0 (3), phi (3), lever (3),",
        " * rod speed (3), stiction torque (3)] for boom, dipper, bucket. */",
        code,
        "",
        f"static const int EP_RATES[{len(RATES)}] = {{{rates_c}}};  /* boom, dipper, bucket, slew rate */",
        f"#define EP_FORGETTING {c_number(kernel.forgetting)}",
        f"#define EP_WARM_INFO {c_number(est.kernel.warm_info)}      /* 1 / warmup_std^2 */",
        f"#define EP_MAX_BRIDGED_GAP {c_number(MAX_BRIDGED_GAP)}  /* s: a longer gap restarts */",
        "/* pressure_regression's one-frame outlier test: the sample before the newest is rejected",
        " * when some signal moves away from both neighbours, in the same direction, by more than",
        " * z sigma_delta (z: GATE_PROBABILITY two-sided; sigma_delta: the fit data's sample-to-sample",
        " * change); its slot gets the neighbours' mean and is never regressed. Off with",
        " * -DEP_GATING=0 (Estimator.gating = False). */",
        *one_frame_glitch_c(est.gating, kernel.spike_threshold),
    ]
    if not (calibrated and kernel.low_speed == "model"):
        defs.append(c_array("EP_STILL_SPEED", still_speed).rstrip() + "  /* 3 Stribeck velocities, m/s */")
    if calibrated:
        k = np.arange(-h, h + 1) / sensors.sample_rate
        defs += [
            "/* CalibratedKernel: the least-squares slope over the window as fixed weights (uniform",
            " * sampling), the per-joint pressure variance through the areas, (A_h^2 + A_r^2)",
            " * (sigma_p^2 + 1 Pa^2). The identified sensor offsets and IMU dynamics (lag,",
            " * acceleration leak) are constants inside ep_pressure_regression, as in calibration",
            " * (calibrated_machine._corrected_signals):",
            f" *   offsets {', '.join(f'{v:.6g}' for v in kernel._offset)}",
            f" *   IMU {', '.join(f'{v:.6g}' for v in kernel._imu)} */",
            c_array("EP_SLOPE", k / float(k @ k)).rstrip(),
            c_array("EP_LEVER_VAR", kernel._lever_var).rstrip(),
            "/* CalibratedKernel._inside (--outside-calibration "
            f"{kernel.outside_calibration}): a joint is weighed only while its measured angle lies",
            " * in the range the calibration motions covered (calibrated_machine.COVERAGE_JOINTS: the",
            " * bucket), in raw units (1e30: no limit) */",
            f"static const int EP_ANGLES[3] = {{{', '.join(str(i) for i in ANGLES)}}};",
            c_array("EP_COVERAGE_LOW", kernel._raw_low).rstrip(),
            c_array("EP_COVERAGE_HIGH", kernel._raw_high).rstrip(),
            *([] if not kernel.whole_arm else [
                "/* --outside-calibration arm: any arm joint outside its range, and no joint is weighed */",
                "static int ep_arm_outside(const ep_real *x)",
                "{",
                "    int j;",
                "    for (j = 0; j < 3; ++j)",
                "        if (x[EP_ANGLES[j]] < EP_COVERAGE_LOW[j] || x[EP_ANGLES[j]] > EP_COVERAGE_HIGH[j]) return 1;",
                "    return 0;",
                "}"]),
            "/* CalibratedKernel.ready (--wait-for-boom): no estimate until the boom joint has been",
            " * weighed in EP_BOOM_READY windows */",
            f"#define EP_WAIT_FOR_BOOM {1 if kernel.wait_for_boom else 0}",
            f"#define EP_BOOM_READY {BOOM_READY_WINDOWS}",
            "/* CalibratedKernel.steady: then reported once the estimate has moved by at most",
            " * EP_STEADY_LIMIT kg over the last EP_STEADY windows, until the weighing restarts */",
            f"#define EP_STEADY_LIMIT {c_number(kernel._steady_limit)}",
            "/* CalibratedKernel._accumulate (--new-load): a short memory's estimate leaving the",
            " * whole one by more than EP_NEW_LOAD_MIN kg and EP_NEW_LOAD_SIGMAS of the difference's",
            " * sigma is a new load: the weighing restarts */",
            f"#define EP_NEW_LOAD {1 if kernel.new_load else 0}",
            f"#define EP_SHORT_FORGETTING {c_number(kernel._short_forgetting)}",
            f"#define EP_NEW_LOAD_MIN {c_number(kernel._new_load_min)}",
            f"#define EP_NEW_LOAD_SIGMAS {c_number(NEW_LOAD_SIGMAS)}",
            f"#define EP_CHANGING_MIN {c_number(kernel._changing_min)}  /* ... load_changing before it */",
            f"#define EP_CHANGING_SIGMAS {c_number(CHANGING_SIGMAS)}",
            "/* CalibratedKernel._settle: a load_changing episode of EP_SETTLE_WINDOWS windows or more",
            " * that ends without a new load sets the whole memory to the short one */",
            f"#define EP_SETTLE_WINDOWS {SETTLE_WINDOWS}",
            "/* CalibratedKernel.update / dump_pending (--new-load, settings.DUMP_RESTARTS): the bucket",
            " * opening faster than EP_DUMP_RATE (rad/s), held EP_DUMP_HOLD samples, is a dump once it has",
            " * opened by EP_DUMP_TURN (rad) with more than EP_DUMP_LOAD_MIN kg weighed as it began (or the",
            " * weighing not ready): load_changing until it ends, then the weighing restarts */",
            f"#define EP_DUMP_RESTARTS {1 if DUMP_RESTARTS else 0}",
            f"#define EP_DUMP_RATE {c_number(DUMP_OPENING_RATE)}",
            f"#define EP_DUMP_HOLD {kernel._dump_hold}",
            f"#define EP_DUMP_TURN {c_number(DUMP_TURN)}",
            f"#define EP_DUMP_LOAD_MIN {c_number(kernel._dump_load_min)}",
            "#define EP_DUMP_PENDING(s) (EP_NEW_LOAD && EP_DUMP_RESTARTS && (s)->dump_left > 0 && (s)->dump_load \\",
            "                            && (s)->dump_turned)",
        ]
        derivative = """    /* qdd = slope . window (CalibratedKernel: fixed weights k dt / sum (k dt)^2) */
    for (j = 0; j < 4; ++j) {
        ep_real acc = EP_C(0.0);
        for (k = 0; k < EP_WINDOW; ++k)
            acc += EP_SLOPE[k] * s->ring[((s->ring_next + k) % EP_RING) * EP_N_SIGNALS + EP_RATES[j]];
        qdd[j] = acc;
    }"""
        low_speed = {
            "downweight": """        {
            ep_real z = out[9 + j] / EP_STILL_SPEED[j], stiction = out[12 + j];
            var = var + EP_MATH(exp)(-(z * z)) * (stiction * stiction) / EP_C(3.0);
        }
        wt = EP_C(1.0) / var;""",
            "skip": """        wt = EP_C(1.0) / var;
        if (EP_MATH(fabs)(out[9 + j]) < EP_STILL_SPEED[j]) wt = EP_C(0.0);""",
            "model": """        wt = EP_C(1.0) / var;""",
        }[kernel.low_speed]
        weights = f"""    /* CalibratedKernel.update: var = lever^2 (A_h^2 + A_r^2) sigma_p^2; --low-speed
     * {kernel.low_speed} (downweight: + stiction^2/3 fading with the rod speed; skip: joints
     * slower than 3 Stribeck velocities get no weight; model: nothing more); a joint outside
     * its calibrated angle range gets no weight */
    for (j = 0; j < 3; ++j) {{
        ep_real lever = out[6 + j], var, wt;
        var = lever * lever * EP_LEVER_VAR[j];
{low_speed}
        if (x[EP_ANGLES[j]] < EP_COVERAGE_LOW[j] || x[EP_ANGLES[j]] > EP_COVERAGE_HIGH[j]) wt = EP_C(0.0);
        if (j == 0 && wt > EP_C(0.0) && s->boom_windows < EP_BOOM_READY) s->boom_windows += 1;
        d_num += wt * (out[3 + j] * out[j]);
        d_info += wt * (out[3 + j] * out[3 + j]);
    }}"""
        if kernel.whole_arm:
            weights = weights.replace(
                "if (x[EP_ANGLES[j]] < EP_COVERAGE_LOW[j] || x[EP_ANGLES[j]] > EP_COVERAGE_HIGH[j]) wt",
                "if (ep_arm_outside(x)) wt")
        description = (f"calibrated on the machine sensor set: weighing regression from cylinder pressures "
                       f"and IMUs with the identified machine (from {est.machine.name}), sensor offsets and "
                       f"pressure noise {kernel.pressure_var ** 0.5:.4g} Pa, --low-speed {kernel.low_speed}, "
                       f"half window {h}")
    else:
        defs += [
            "/* PressureRegression weights: pressure noise (+1 Pa^2 floor) and pump ripple (RMS share)",
            " * through the areas, stiction near standstill */",
            c_array("EP_HEAD_AREA_SQ", head**2).rstrip(),
            c_array("EP_ROD_AREA_SQ", rod**2).rstrip(),
            f"#define EP_PRESSURE_VAR {c_number(kernel.pressure_var)}",
            f"#define EP_RIPPLE_VAR_SHARE {c_number(kernel.ripple_var_share)}",
            f"static const int EP_HEAD_PRESSURES[3] = {{{', '.join(str(i) for i in PRESSURES[0::2])}}};",
            f"static const int EP_ROD_PRESSURES[3] = {{{', '.join(str(i) for i in PRESSURES[1::2])}}};",
        ]
        derivative = """    /* PressureRegression._derivative: least-squares slope of the rates against the window's
     * times (t - mean t); times are taken relative to the centre sample first (the same
     * slope; in single precision it keeps the 10 ms steps exact) */
    {
        ep_real t_rel[EP_WINDOW], t_centre, t_mean = EP_C(0.0), tt = EP_C(0.0);
        t_centre = s->ring_time[(s->ring_next + EP_HALF_WINDOW) % EP_RING];
        for (k = 0; k < EP_WINDOW; ++k) {
            t_rel[k] = s->ring_time[(s->ring_next + k) % EP_RING] - t_centre;
            t_mean += t_rel[k];
        }
        t_mean /= (ep_real)EP_WINDOW;
        for (k = 0; k < EP_WINDOW; ++k) {
            t_rel[k] -= t_mean;
            tt += t_rel[k] * t_rel[k];
        }
        for (j = 0; j < 4; ++j) {
            ep_real mean = EP_C(0.0), acc = EP_C(0.0);
            for (k = 0; k < EP_WINDOW; ++k)
                mean += s->ring[((s->ring_next + k) % EP_RING) * EP_N_SIGNALS + EP_RATES[j]];
            mean /= (ep_real)EP_WINDOW;
            for (k = 0; k < EP_WINDOW; ++k)
                acc += t_rel[k] * (s->ring[((s->ring_next + k) % EP_RING) * EP_N_SIGNALS + EP_RATES[j]] - mean);
            qdd[j] = acc / tt;
        }
    }"""
        weights = """    /* PressureRegression.update: per joint, var = lever^2 (A_h^2 var_h + A_r^2 var_r) with
     * var_side = sigma_p^2 + share p_side^2, plus stiction^2/3 fading with the rod speed */
    for (j = 0; j < 3; ++j) {
        ep_real lever = out[6 + j], speed = out[9 + j], stiction = out[12 + j], var, z, w;
        ep_real p_head = x[EP_HEAD_PRESSURES[j]], p_rod = x[EP_ROD_PRESSURES[j]];
        var = lever * lever * (EP_HEAD_AREA_SQ[j] * (EP_PRESSURE_VAR + EP_RIPPLE_VAR_SHARE * (p_head * p_head))
                               + EP_ROD_AREA_SQ[j] * (EP_PRESSURE_VAR + EP_RIPPLE_VAR_SHARE * (p_rod * p_rod)));
        z = speed / EP_STILL_SPEED[j];
        var = var + EP_MATH(exp)(-(z * z)) * (stiction * stiction) / EP_C(3.0);
        w = EP_C(1.0) / var;
        d_num += (w * out[3 + j]) * out[j];
        d_info += (w * out[3 + j]) * out[3 + j];
    }"""
        description = (f"inverse-dynamics on the machine sensor set: weighing regression from cylinder "
                       f"pressures and IMUs (machine {est.machine.name}, noise {est.noise_name}), "
                       f"half window {h}")
    new_load = ""
    if calibrated:
        new_load = """#if EP_NEW_LOAD
if (1) {
    ep_real change, spread, limit;
    unsigned char was_changing = s->changing, restarted = 0;
    unsigned char dumped = (unsigned char)(EP_DUMP_RESTARTS && s->dump_ended);  /* a dump has ended */
    s->num_short = EP_SHORT_FORGETTING * s->num_short + d_num;
    s->info_short = EP_SHORT_FORGETTING * s->info_short + d_info;
    s->changing = 0;
    s->dump_ended = 0;
    if (dumped || ((!EP_WAIT_FOR_BOOM || s->boom_windows >= EP_BOOM_READY) && s->info_short > EP_C(0.0)
                   && s->info_short < s->info)) {
        change = spread = limit = EP_C(0.0);
        if (!dumped) {
            change = s->num_short / s->info_short - s->num / s->info;
            spread = EP_C(1.0) / s->info_short - EP_C(1.0) / s->info;
            if (spread < EP_C(0.0)) spread = EP_C(0.0);
            limit = EP_NEW_LOAD_SIGMAS * EP_MATH(sqrt)(spread);
            if (limit < EP_NEW_LOAD_MIN) limit = EP_NEW_LOAD_MIN;
        }
        if (dumped || EP_MATH(fabs)(change) > limit) {  /* a new load (or a dump's end): restart the weighing */
            s->num = s->info = s->num_short = s->info_short = EP_C(0.0);
            s->boom_windows = 0;
            s->changing_windows = 0;
            s->steady = !EP_WAIT_FOR_BOOM;
            s->steady_count = 0;
            restarted = 1;
        } else {  /* CalibratedKernel.changing: the load is changing (status load_changing) */
            limit = EP_CHANGING_SIGMAS * EP_MATH(sqrt)(spread);
            if (limit < EP_CHANGING_MIN) limit = EP_CHANGING_MIN;
            s->changing = EP_MATH(fabs)(change) > limit;
        }
    }
    if (!restarted) {
        if (s->changing) {
            if (s->changing_windows < EP_SETTLE_WINDOWS) ++s->changing_windows;
        } else if (was_changing) {  /* CalibratedKernel._settle: the change has settled */
            if (s->changing_windows >= EP_SETTLE_WINDOWS) {
                s->num = s->num_short;
                s->info = s->info_short;
            }
            s->changing_windows = 0;
        }
    }
}
#endif
if (!s->steady && s->boom_windows >= EP_BOOM_READY && s->info > EP_C(0.0)) {
    /* CalibratedKernel._track_steady: this estimate against the one EP_STEADY windows back */
    ep_real now = s->num / s->info;
    unsigned int k = s->steady_count;
    if (k >= EP_STEADY && EP_MATH(fabs)(now - s->steady_history[(k - EP_STEADY) % (EP_STEADY + 1)]) <= EP_STEADY_LIMIT)
        s->steady = 1;
    s->steady_history[k % (EP_STEADY + 1)] = now;
    s->steady_count = k + 1;
}"""
    call = casadi_call("ep_pressure_regression", kernel_fn, ["x", "qdd"], ["out"], code)
    if not momentum:
        regress = f"""    if (s->ring_filled == EP_RING && s->ring_used[(s->ring_next + EP_HALF_WINDOW) % EP_RING]) {{
        /* the window, oldest first, starts at ring_next and ends on the sample before the newest */
        const ep_real *centre = s->ring + ((s->ring_next + EP_HALF_WINDOW) % EP_RING) * EP_N_SIGNALS;
        for (i = 0; i < EP_N_SIGNALS; ++i) x[i] = centre[i];
{textwrap.indent(derivative, "    ")}
{textwrap.indent(call, "    ")}
{textwrap.indent(weights, "    ")}
        s->num = EP_FORGETTING * s->num + d_num;
        s->info = EP_FORGETTING * s->info + d_info;
{textwrap.indent(new_load, "    ")}
    }}"""
    else:
        from excavator_payload.estimators.classical.calibrated_machine import (
            BALANCE_HALF_WINDOW, BALANCE_RAMP, balance_weights)

        bw, bu = balance_weights(BALANCE_HALF_WINDOW, BALANCE_RAMP)
        dt = 1.0 / sensors.sample_rate
        defs += [
            "/* CalibratedKernel, --balance momentum: the window's weights of the integrand (w dt) and",
            " * of the momentum (u), calibrated_machine.balance_weights */",
            c_array("EP_BALANCE_W", bw * dt).rstrip(),
            c_array("EP_BALANCE_U", bu).rstrip(),
            f"#define EP_BALANCE_SPAN {c_number(kernel._balance_span)}  /* sum w dt, s */",
            f"#define EP_RATE_VAR_SPAN {c_number(kernel._rate_var_span)}  /* rate variance / span^2 */",
        ]
        weights_m = weights.replace("out[", "bal[").replace(
            "wt = EP_C(1.0) / var;", "var = var + bal_rate[j];\n        wt = EP_C(1.0) / var;").replace(
            "if (x[EP_ANGLES[j]] < EP_COVERAGE_LOW[j] || x[EP_ANGLES[j]] > EP_COVERAGE_HIGH[j]) wt",
            "if (!bal_inside[j]) wt").replace("if (ep_arm_outside(x)) wt", "if (!bal_inside[j]) wt")
        inside_terms = (
            """        for (j = 0; j < 3; ++j)
            s->terms_inside[slot * 3 + j] = (unsigned char)(x[EP_ANGLES[j]] >= EP_COVERAGE_LOW[j]
                                                            && x[EP_ANGLES[j]] <= EP_COVERAGE_HIGH[j]"""
            + dropped_at_centre + ");"
            if not kernel.whole_arm else
            """        for (j = 0; j < 3; ++j)
            s->terms_inside[slot * 3 + j] = (unsigned char)"""
            + ("(!ep_arm_outside(x)" + dropped_at_centre + ");" if dropped_at_centre else "!ep_arm_outside(x);"))
        regress = f"""    if (s->ring_filled == EP_RING) {{
        /* the differentiator window's centre: its balance terms (its qdd serves the IMU
         * correction only) go into the balance's ring, a rejected slot too (its interval
         * belongs to the integral), marked never to be a window's centre */
        int centre_slot = (s->ring_next + EP_HALF_WINDOW) % EP_RING, slot;
        const ep_real *centre = s->ring + centre_slot * EP_N_SIGNALS;
        for (i = 0; i < EP_N_SIGNALS; ++i) x[i] = centre[i];
{textwrap.indent(derivative, "    ")}
{textwrap.indent(call, "    ")}
        slot = s->terms_next;
        for (i = 0; i < 24; ++i) s->terms[slot * 24 + i] = out[i];
        s->terms_used[slot] = s->ring_used[centre_slot];
{inside_terms}
        s->terms_next = (slot + 1) % EP_BALANCE;
        if (s->terms_filled < EP_BALANCE) s->terms_filled += 1;
        if (s->terms_filled == EP_BALANCE && s->terms_used[(s->terms_next + EP_BALANCE_CENTRE) % EP_BALANCE]) {{
            /* the momentum balance over the window, oldest first from terms_next
             * (calibrated_machine.window_residuals) */
            ep_real integral[6], momentum[6], bal[15], bal_rate[3];
            unsigned char bal_inside[3];  /* each joint inside its calibrated range all window long */
            for (j = 0; j < 6; ++j) integral[j] = momentum[j] = EP_C(0.0);
            for (j = 0; j < 3; ++j) {{
                bal_rate[j] = EP_C(0.0);
                bal_inside[j] = 1;
                bal[9 + j] = EP_MATH(fabs)(s->terms[s->terms_next * 24 + 15 + j]);
                bal[12 + j] = s->terms[s->terms_next * 24 + 18 + j];
            }}
            for (k = 0; k < EP_BALANCE; ++k) {{
                const ep_real *t = s->terms + ((s->terms_next + k) % EP_BALANCE) * 24;
                for (j = 0; j < 6; ++j) {{
                    integral[j] += EP_BALANCE_W[k] * t[6 + j];
                    momentum[j] += EP_BALANCE_U[k] * t[j];
                }}
                for (j = 0; j < 3; ++j) {{
                    ep_real speed = EP_MATH(fabs)(t[15 + j]);
                    bal_rate[j] += (EP_BALANCE_U[k] * EP_BALANCE_U[k]) * t[21 + j];
                    if (speed < bal[9 + j]) bal[9 + j] = speed;  /* the slowest sample */
                    if (t[18 + j] > bal[12 + j]) bal[12 + j] = t[18 + j];  /* the largest stiction */
                    bal_inside[j] = (unsigned char)(bal_inside[j] && s->terms_inside[((s->terms_next + k) % EP_BALANCE) * 3 + j]);
                }}
            }}
            for (j = 0; j < 3; ++j) {{
                bal[j] = (integral[j] - momentum[j]) / EP_BALANCE_SPAN;
                bal[3 + j] = (momentum[3 + j] - integral[3 + j]) / EP_BALANCE_SPAN;
                bal[6 + j] = s->terms[((s->terms_next + EP_BALANCE_CENTRE) % EP_BALANCE) * 24 + 12 + j];
                bal_rate[j] = bal_rate[j] * EP_RATE_VAR_SPAN;
            }}
{textwrap.indent(weights_m, "        ")}
            s->num = EP_FORGETTING * s->num + d_num;
            s->info = EP_FORGETTING * s->info + d_info;
{textwrap.indent(new_load, "        ")}
        }}
    }}"""
    not_ready = " || (EP_WAIT_FOR_BOOM && (s->boom_windows < EP_BOOM_READY || !s->steady))" if calibrated else ""
    changing_status = "(s->changing || EP_DUMP_PENDING(s)) ? EP_STATUS_LOAD_CHANGING : EP_STATUS_OK" \
        if calibrated else "EP_STATUS_OK"
    time_push = "    (void)time;  /* uniform sampling: fixed slope weights */\n" if calibrated else \
        "    s->ring_time[newest] = time;\n"
    step = f"""    /* InverseDynamicsEstimator._step with the machine set's kernel. The ring holds the
     * differentiator's window (2 half_window + 1 samples) and the two newest, not yet judged:
     * the outlier test judges the sample two before the newest between its neighbours; once the
     * ring is full, the window's centre is regressed unless it was rejected. */
    ep_real x[EP_N_SIGNALS], qdd[4], out[{24 if momentum else 15}];
    ep_real d_num = EP_C(0.0), d_info = EP_C(0.0);
    int i, j, k, newest = s->ring_next, rejected = 0;
    for (i = 0; i < EP_N_SIGNALS; ++i) s->ring[newest * EP_N_SIGNALS + i] = v[i];
{time_push}    s->ring_used[newest] = 1;
    s->ring_next = (newest + 1) % EP_RING;
    if (s->ring_filled < EP_RING) s->ring_filled += 1;
@DUMP@#if EP_GATING
    if (s->ring_filled >= 4) {{  /* the sample two before the newest, two neighbours each side */
        ep_real *m = s->ring + ((newest + EP_RING - 2) % EP_RING) * EP_N_SIGNALS;
        const ep_real *b = s->ring + ((newest + EP_RING - 3) % EP_RING) * EP_N_SIGNALS;
        const ep_real *a = s->ring + ((newest + EP_RING - 1) % EP_RING) * EP_N_SIGNALS;
        const ep_real *b2 = s->ring_filled >= 5 ? s->ring + ((newest + EP_RING - 4) % EP_RING) * EP_N_SIGNALS : 0;
        int mid = (newest + EP_RING - 2) % EP_RING, judged = ep_spike(b2, b, m, a, v);
        if (judged) {{  /* stands out: never regressed; reported only as a glitch */
            for (i = 0; i < EP_N_SIGNALS; ++i) m[i] = EP_C(0.5) * (b[i] + a[i]);
            s->ring_used[mid] = 0;
            rejected = judged == 2;
        }}
    }}
#else
    (void)ep_spike;
#endif
{regress}
    if (s->info <= EP_C(0.0){not_ready}) {{
        *estimate = EP_NAN;
        return EP_STATUS_WARMING_UP;
    }}
    *estimate = s->num / s->info;
    if (rejected) return EP_STATUS_REJECTED;  /* the sample two before this one was an outlier */
    if (s->info < EP_WARM_INFO) return EP_STATUS_WARMING_UP;
    return {changing_status};"""
    # always tracked, as in Python: the joint check reads dump_left too (CalibratedKernel.dumping)
    dump = """    if (v[EP_RATES[2]] > EP_DUMP_RATE) {  /* the bucket opens fast: a dump (CalibratedKernel.update) */
        if (!s->dump_left) {  /* it starts: can it leave a load? */
            s->dump_load = (unsigned char)(!(!EP_WAIT_FOR_BOOM || s->boom_windows >= EP_BOOM_READY)
                                           || !(s->info > EP_C(0.0)) || s->num / s->info > EP_DUMP_LOAD_MIN);
            s->dump_from = v[EP_ANGLES[2]];
            s->dump_turned = 0;
        }
        s->dump_left = EP_DUMP_HOLD;
    } else if (s->dump_left) {
        s->dump_left -= 1;
        if (!s->dump_left && s->dump_load && s->dump_turned) s->dump_ended = 1;  /* over: a new load */
    }
    if (s->dump_left && v[EP_ANGLES[2]] - s->dump_from > EP_DUMP_TURN) s->dump_turned = 1;  /* turned over */
""" if calibrated else ""
    step = step.replace("@DUMP@", dump)
    on_gap = """    /* InverseDynamicsEstimator._on_gap: a short gap keeps the sums and restarts the window
     * (the differentiator needs evenly spaced samples), a long one (or time going back)
     * restarts */
    ep_real dt = time - s->last_time;
    (void)v;
    if (!s->has_last_time || !(EP_C(0.0) < dt && dt <= EP_MAX_BRIDGED_GAP)) ep_model_reset(s);
    else s->ring_filled = 0;"""
    if momentum:  # CalibratedKernel.restart_window: both rings restart
        on_gap = on_gap[:-len("s->ring_filled = 0;")] + "{ s->ring_filled = 0; s->terms_filled = 0; s->terms_next = 0; }"
    if drops:  # CalibratedKernel.drop: each sample's joints dropped, read at the window's centre
        step = step.replace("    s->ring_used[newest] = 1;\n",
                            "    s->ring_used[newest] = 1;\n"
                            "    s->ring_drop[newest] = (unsigned char)EP_HM_DROPPED(s);  /* CalibratedKernel.drop */\n")
    fields = ["ep_real num;   /* sum of w phi r */",
              "ep_real info;  /* sum of w phi^2: information, 1/variance of the estimate */",
              "ep_real ring[EP_RING * EP_N_SIGNALS];  /* the last samples, as measured (outliers repaired) */"]
    if not calibrated:
        fields.append("ep_real ring_time[EP_RING];  /* their times */")
    if drops:
        fields.append("unsigned char ring_drop[EP_RING];  /* joints (bit j) a named pressure dropped from each sample */")
    fields += ["unsigned char ring_used[EP_RING];  /* 0: a rejected sample's slot */",
               "int ring_next;    /* slot the next sample goes to (the oldest once full) */",
               "int ring_filled;  /* samples in the ring (saturates at EP_RING) */"]
    reset = "    s->num = EP_C(0.0);\n    s->info = EP_C(0.0);\n    s->ring_next = 0;\n    s->ring_filled = 0;"
    if calibrated:
        fields.append("unsigned int boom_windows;  /* windows with weight on the boom (up to EP_BOOM_READY) */")
        fields += ["ep_real num_short;   /* the new-load test's short memory: sum of w phi r */",
                   "ep_real info_short;  /* ... and of w phi^2 */"]
        fields.append("unsigned char changing;  /* the short memory has left the whole one */")
        fields.append("unsigned int changing_windows;  /* windows of the load_changing episode (up to EP_SETTLE_WINDOWS) */")
        fields += ["int dump_left;  /* samples the bucket's fast opening still counts (EP_DUMP_HOLD) */",
                   "ep_real dump_from;  /* the bucket's angle as it began to open fast, rad */",
                   "unsigned char dump_load, dump_turned, dump_ended;  /* a load to leave; opened EP_DUMP_TURN; "
                   "over since the last window */"]
        fields += ["ep_real steady_history[EP_STEADY + 1];  /* the last estimates (CalibratedKernel.steady) */",
                   "unsigned int steady_count;  /* estimates since the boom was ready */",
                   "unsigned char steady;  /* the estimate has held still: reported */"]
        reset += ("\n    s->boom_windows = 0;\n    s->num_short = EP_C(0.0);\n    s->info_short = EP_C(0.0);"
                  "\n    s->changing = 0;\n    s->changing_windows = 0;"
                  "\n    s->dump_left = 0;\n    s->dump_from = EP_C(0.0);"
                  "\n    s->dump_load = s->dump_turned = s->dump_ended = 0;"
                  "\n    s->steady = !EP_WAIT_FOR_BOOM;\n    s->steady_count = 0;")
    defines = [f"#define EP_HALF_WINDOW {h}  /* samples each side of the centred differentiator */",
               f"#define EP_WINDOW {width}  /* 2 EP_HALF_WINDOW + 1 */",
               "#define EP_RING (EP_WINDOW + 2)  /* the window and the two newest, unjudged samples */"]
    if calibrated:
        defines.append(f"#define EP_STEADY {STEADY_WINDOWS}  /* windows an estimate holds still before it is reported */")
    if momentum:
        from excavator_payload.estimators.classical.calibrated_machine import BALANCE_HALF_WINDOW

        fields += ["ep_real terms[EP_BALANCE * 24];  /* balance terms of the last samples: P0, Pm, I0, Fm, "
                   "lever, speed, stiction, rate gain */",
                   "unsigned char terms_used[EP_BALANCE];  /* 0: a rejected sample's repaired slot */",
                   "unsigned char terms_inside[EP_BALANCE * 3];  /* joints inside their calibrated range */",
                   "int terms_next;    /* slot the next terms go to (the oldest once full) */",
                   "int terms_filled;  /* terms in the ring (saturates at EP_BALANCE) */"]
        reset += "\n    s->terms_next = 0;\n    s->terms_filled = 0;"
        defines += [f"#define EP_BALANCE {2 * BALANCE_HALF_WINDOW + 1}  /* samples of the momentum balance's window */",
                    f"#define EP_BALANCE_CENTRE {BALANCE_HALF_WINDOW}"]
        description += f", momentum balance over ±{BALANCE_HALF_WINDOW} samples"
    sigma = ("    /* _estimate_sigma: sqrt(1/I + s_model^2), the calibration's cross-checked model error */\n"
             f"    return s->info > EP_C(0.0) ? EP_MATH(sqrt)(EP_C(1.0) / s->info + {c_number(model_var)}) : EP_NAN;")
    if nuisance:
        nz = imu_nuisance_c(kernel, casadi_call("ep_imu_jacobian", extra["ep_imu_jacobian"], ["x", "qdd"], ["jac"],
                                                code), step, fields, reset, c_number(model_var))
        defs.append(nz["defs"])
        defines += nz["header"]
        step, fields, reset, sigma = nz["step"], nz["fields"], nz["reset"], nz["sigma"]
        description += ", the IMU lag and house IMU sensitivity re-estimated per load (--imu-nuisance on)"
    if zero_share:
        os_ = offset_share_c(kernel, casadi_call("ep_offset_jacobian", extra["ep_offset_jacobian"], ["x", "qdd"],
                                                 ["jac"], code), step, fields, reset, defs, nuisance)
        defines += os_["header"]
        step, fields, reset, defs = os_["step"], os_["fields"], os_["reset"], os_["defs"]
        sigma = with_offset_share(sigma, model_var)
        description += ", the zero's share of sigma per estimate"
    model = CModel(
        description=description,
        state_fields=fields,
        definitions="\n".join(defs),
        reset=reset,
        step=step, on_gap=on_gap,
        header_defines=defines,
        sigma=sigma,
        # InverseDynamicsEstimator._state_finite: on this set its N stays 0 (the kernel keeps
        # the sum), so only I is watched
        state_finite="    return isfinite(s->info);")
    if momentum and exports_joint_check(est, kernel):  # --joint-check on: runtime/export_c/joint_check.py
        model = add_joint_check(model, est, kernel, sensors.signals, model_var)
        if zero_share:
            model.sigma = with_offset_share(model.sigma, model_var)
    return model
