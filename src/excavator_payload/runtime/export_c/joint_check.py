"""The calibrated kernel's joint consistency check (``--joint-check``) in C.

:func:`joint_check_c` renders :class:`~excavator_payload.estimators.classical.machine_calibration
.joint_check.JointCheck` and the kernel's per-joint sums it reads
(:meth:`CalibratedKernel._accumulate`, ``_settle``, ``_without``) for the builder in
:mod:`~excavator_payload.runtime.export_c.pressure_regression`, which calls the hooks where the
Python kernel does; :mod:`~excavator_payload.runtime.export_c.health` reports the pressures named
as ``EP_FAULT_BALANCE`` (FMI 13) through ``ep_faults``. Exported when the model's option
``joint_check`` is ``on`` (momentum form); it runs with the health monitor, as in Python
(``Estimator._step``: the check runs only with ``health``), so ``-DEP_HEALTH=0`` compiles it out.
"""

from __future__ import annotations

from dataclasses import dataclass

from excavator_payload.runtime.export_c.c_text import c_number


@dataclass
class CJointCheck:
    """The check's parts for the kernel's builder.

    Parameters
    ----------
    fields : list of str
        ``ep_state`` fields.
    definitions : str
        Constants and static functions (after the kernel's constants).
    reset : str
        Lines of ``ep_model_reset``.
    accumulate : str
        After the window's sums (each joint's share, before the new-load test).
    restart : str
        Where the new-load test restarts the weighing.
    settle : str
        Where a settled change sets the whole memory to the short one.
    update : str
        After the new-load test and the steady tracking: the check of this window.
    prologue : str
        The step's first lines (after its declarations).
    status : str
        The step's last status rule (the kernel's status with the check's: ``load_changing``
        while it pauses, a joint weighed alone held back once it moves, ``sensor_fault`` with the
        weighing without the joint named).
    on_gap : str
        In the gap handling (a gap's sample reports no fault).
    sigma : str
        Body of ``ep_model_sigma`` (the information the step reported).
    """

    fields: list
    definitions: str
    reset: str
    accumulate: str
    restart: str
    settle: str
    update: str
    prologue: str
    status: str
    on_gap: str
    sigma: str


def exports_joint_check(est, kernel) -> bool:
    """Whether ``est``'s export carries the joint check: option ``joint_check`` on and a kernel that
    checks joints (``calibrated``, momentum form).

    Parameters
    ----------
    est : Estimator
        The fitted estimator (its options).
    kernel : PressureRegression
        Its weighing kernel.
    """
    return est.options.get("joint_check", "off") == "on" and bool(getattr(kernel, "checks_joints", False))


def joint_check_c(est, kernel, signals, model_var: float) -> CJointCheck:
    """The C of the joint check of ``est``'s calibrated kernel.

    Parameters
    ----------
    est : Estimator
        The fitted ``calibrated`` estimator.
    kernel : CalibratedKernel
        Its kernel (the check's constants: rated payload, model std).
    signals : sequence of str
        The export's signals, in order (the pressures' bits).
    model_var : float
        The calibration's model variance, kg² (the sigma).
    """
    from excavator_payload.estimators.classical.machine_calibration.settings import (
        CHANGING_SIGMAS, JOINT_CHI2, JOINT_INFO_INFLATION, JOINT_MOVING_WINDOWS,
        JOINT_PAUSE_WINDOWS, JOINT_PRESSURES, JOINT_SAMPLES, LONE_YOUNG_SHARE, PAUSE_RESTARTS, SIDE_JOINTS)

    check = kernel._joints
    # --imu-nuisance on: the weighing reported is the filter's, with its marginal information
    # (PressureKernel.step reads weighed_info); the check's sums and the degraded weighing are the kernel's
    nuisance = getattr(kernel, "_imu_nuisance", None) is not None
    weighed_info = "EP_NZ_INFO(s)" if nuisance else "((s)->info)"
    # a restart of the weighing (a named joint cleared) reaches the IMU dynamics as a new load's
    nz_restart = "\n        s->nz_restarts += 1;" if nuisance else ""
    # the moving rule follows the weighing reported: with --imu-nuisance the filter's payload as
    # the last window left it (JointCheck._track_moving, CalibratedKernel.payload_before)
    moving_now = "s->nz_payload" if nuisance else "s->num / s->info"
    moving_what = "the IMU filter's payload after the last window" if nuisance else "N / I"
    # ... and the zero's share in sigma (offset_share.py), as Python's OffsetShare.restart
    if getattr(kernel, "_offset_share", None) is not None:
        nz_restart += "\n        s->os_restarts += 1;"
    masks = []
    for pair in JOINT_PRESSURES:
        bits = 0
        for name in pair:
            bits |= 1 << list(signals).index(name)
        masks.append(f"{bits:#x}UL")
    fields = [
        "ep_real jc_num_joint[3], jc_info_joint[3];  /* each joint's share of num and info */",
        "ep_real jc_num_short[3], jc_info_short[3];  /* ... of the new-load test's short memory */",
        "ep_real jc_num[3], jc_info[3];  /* the joint check's own sums (restart with loads and pauses) */",
        "ep_real jc_after_num[3], jc_after_info[3];  /* ... their share since the last dump ended */",
        "ep_real jc_neg_num[3], jc_neg_info[3];  /* ... their share of windows whose phi_j < 0 (ep_jc_side_agrees) */",
        "ep_real jc_degraded, jc_degraded_info;  /* the weighing without the joint named */",
        "ep_real jc_out_info;  /* the information of the estimate the last step reported */",
        f"ep_real jc_history[{JOINT_MOVING_WINDOWS + 1}];  /* the whole weighing N / I of the last windows, a ring */",
        f"ep_real jc_history_info[{JOINT_MOVING_WINDOWS + 1}];  /* ... and its information I */",
        "int jc_slot;      /* the ring's slot the next window writes */",
        "int jc_named;     /* bit j: joint j named (boom, dipper, bucket) */",
        "int jc_run;       /* windows in a row beyond (or, while failing, within) the limit */",
        "int jc_paused;    /* windows of the current pause (0: not paused) */",
        "unsigned char jc_armed, jc_checked, jc_new_load, jc_reported, jc_gap, jc_dumping, jc_moving, jc_restart;",
        "unsigned char jc_dumped;  /* a dump since the check's sums started */",
        "unsigned char jc_lone_moved;  /* a joint weighed alone has moved: it waits for a second (PressureKernel._joint_rules) */",
        "unsigned char jc_moved_settled;  /* it moved while its last windows held at most EP_JC_LONE_YOUNG of I */",
        "unsigned char jc_named_before_load;  /* a pair named before this load: its sums may clear it */",
    ]
    definitions = f"""/* The joint consistency check (machine_calibration/joint_check.py, JointCheck): each joint's
 * estimate N_j / I_j against the others', chi2 about their 1/v_j-weighted mean with
 * v_j = EP_JC_INFLATION / I_j + EP_JC_EXTRA; beyond EP_JC_CHI2 on EP_JC_SAMPLES windows in a row a
 * cylinder's pressures are named (EP_FAULT_BALANCE, FMI 13). Paused while the short memory has left
 * the whole weighing (a load change), at most EP_JC_PAUSE windows at a time; while the bucket dumps
 * (opens faster than EP_DUMP_RATE within the last EP_DUMP_HOLD samples: the kernel's dump_left) it names nothing new
 * and sums nothing; before the weighing is ready it names nothing new. No estimate is ok while
 * N / I moved by more than EP_JC_MOVING_LIMIT over EP_JC_MOVING windows (load_changing); a new fault
 * of one joint whose sums hold windows of both signs of its phi_j is held while one side alone
 * agrees with the others (ep_jc_side_agrees); a named
 * joint that clears restarts the weighing, and so does a joint that weighs less after a dump than
 * before it (ep_jc_dumped_load: a load too small for the new-load test left), and a pause that ends
 * with the memories agreeing again (the weighing's sums hold the windows the pause saw). */
#define EP_JOINT_CHECK EP_HEALTH  /* runs with the health monitor (Estimator._step) */
#define EP_JC_INFLATION {c_number(JOINT_INFO_INFLATION)}
#define EP_JC_EXTRA {c_number(check.extra)}  /* model std^2 + each joint's model error^2, kg^2 */
#define EP_JC_ENOUGH {c_number(check.enough)}  /* I_j for a joint to be compared (ok needs two) */
#define EP_JC_CHI2 {c_number(JOINT_CHI2)}
#define EP_JC_SAMPLES {JOINT_SAMPLES}
#define EP_JC_MOVING {JOINT_MOVING_WINDOWS}  /* windows over which N / I must hold still */
#define EP_JC_MOVING_LIMIT {c_number(check.moving_limit)}  /* kg */
#define EP_JC_LONE_YOUNG {c_number(LONE_YOUNG_SHARE)}  /* a joint alone waits on a move only once the ring's windows hold at most this share of I */
#define EP_JC_SLIGHT_LIMIT {c_number(check.slight_limit)}  /* kg: a joint moving the weighing less is not named */
#define EP_JC_CHANGE_MIN {c_number(check.change_min)}  /* kg: the pause's least change */
#define EP_JC_CHANGE_SIGMAS {c_number(CHANGING_SIGMAS)}
#define EP_JC_PAUSE {JOINT_PAUSE_WINDOWS}
#define EP_JC_PAUSE_RESTARTS {int(bool(PAUSE_RESTARTS))}  /* a pause's end restarts the weighing */
#define EP_JC_WEIGHED_INFO(s) {weighed_info}  /* the information of the weighing reported */
#define EP_JC_SIDE_JOINTS {sum(1 << j for j in range(3) if SIDE_JOINTS[j])}  /* bit j: ep_jc_side_agrees applies to joint j */

static void ep_jc_clear(ep_state *s)
{{
    int j;
    for (j = 0; j < 3; ++j)
        s->jc_num[j] = s->jc_info[j] = s->jc_after_num[j] = s->jc_after_info[j] = s->jc_neg_num[j] = s->jc_neg_info[j]
            = EP_C(0.0);
    s->jc_paused = 0;
    s->jc_dumped = 0;
}}

static void ep_jc_reset(ep_state *s)
{{
    int j;
    for (j = 0; j < 3; ++j)
        s->jc_num_joint[j] = s->jc_info_joint[j] = s->jc_num_short[j] = s->jc_info_short[j] = EP_C(0.0);
    ep_jc_clear(s);
    s->jc_degraded = EP_NAN;
    s->jc_degraded_info = EP_C(0.0);
    s->jc_out_info = EP_C(0.0);
    s->jc_named = 0;
    s->jc_run = 0;
    s->jc_armed = 1;
    s->jc_checked = 0;
    s->jc_new_load = 0;
    s->jc_lone_moved = 0;
    s->jc_moved_settled = 0;
    s->jc_named_before_load = 0;
    s->jc_reported = 0;
    s->jc_gap = 0;
    s->jc_dumping = 0;
    for (j = 0; j <= EP_JC_MOVING; ++j) {{
        s->jc_history[j] = EP_NAN;
        s->jc_history_info[j] = EP_C(0.0);
    }}
    s->jc_slot = 0;
    s->jc_moving = 0;
    s->jc_restart = 0;
}}

#if EP_JOINT_CHECK
static const unsigned long EP_JC_PRESSURES[3] = {{{", ".join(masks)}}};  /* each cylinder's head and rod */

/* CalibratedKernel._accumulate: each joint's share, the same forgetting (and the short memory's) */
static void ep_jc_accumulate(ep_state *s, const ep_real dn[3], const ep_real di[3])
{{
    int j;
    for (j = 0; j < 3; ++j) {{
        s->jc_num_joint[j] = EP_FORGETTING * s->jc_num_joint[j] + dn[j];
        s->jc_info_joint[j] = EP_FORGETTING * s->jc_info_joint[j] + di[j];
#if EP_NEW_LOAD
        s->jc_num_short[j] = EP_SHORT_FORGETTING * s->jc_num_short[j] + dn[j];
        s->jc_info_short[j] = EP_SHORT_FORGETTING * s->jc_info_short[j] + di[j];
#endif
    }}
}}

/* CalibratedKernel._accumulate's new load: the joints' sums restart, and so does the check */
static void ep_jc_reset_sums(ep_state *s)
{{
    int j;
    for (j = 0; j < 3; ++j)
        s->jc_num_joint[j] = s->jc_info_joint[j] = s->jc_num_short[j] = s->jc_info_short[j] = EP_C(0.0);
    s->jc_new_load = 1;
}}

/* CalibratedKernel._check_joints: a joint named has cleared, the weighing starts again
 * (CalibratedKernel._restart_load, as a new load's) */
static void ep_jc_restart(ep_state *s)
{{
    s->num = s->info = s->num_short = s->info_short = EP_C(0.0);
    ep_jc_reset_sums(s);
    s->boom_windows = 0;
    s->steady = !EP_WAIT_FOR_BOOM;
    s->steady_count = 0;
    s->changing_windows = 0;
    s->changing = 0;{nz_restart}
}}

/* JointCheck._track_moving: the weighing reported ({moving_what}) against its value EP_JC_MOVING
 * windows back (NaN: not moving) */
static void ep_jc_track_moving(ep_state *s)
{{
    ep_real now = s->info > EP_C(0.0) ? {moving_now} : EP_NAN;
    int oldest = (s->jc_slot + 1) % (EP_JC_MOVING + 1);
    ep_real then = s->jc_history[oldest], info_then = s->jc_history_info[oldest];
    s->jc_history[s->jc_slot] = now;
    s->jc_history_info[s->jc_slot] = s->info;
    s->jc_slot = (s->jc_slot + 1) % (EP_JC_MOVING + 1);
    s->jc_moving = (unsigned char)(EP_MATH(fabs)(now - then) > EP_JC_MOVING_LIMIT);
    /* a joint alone waits only on a move of a settled weighing (not a new load converging) */
    s->jc_moved_settled = (unsigned char)(s->jc_moving && s->info > EP_C(0.0)
        && info_then >= (EP_C(1.0) - EP_JC_LONE_YOUNG) * s->info);
}}

/* CalibratedKernel._settle: the joints' whole memory takes the short one's sums */
static void ep_jc_settle(ep_state *s)
{{
    int j;
    for (j = 0; j < 3; ++j) {{
        s->jc_num_joint[j] = s->jc_num_short[j];
        s->jc_info_joint[j] = s->jc_info_short[j];
    }}
}}

/* CalibratedKernel._without: the weighing without joint j's share */
static void ep_jc_without(ep_state *s, int j)
{{
    ep_real info = s->info - s->jc_info_joint[j];
    if (info <= EP_C(1e-12) * s->info || info <= EP_C(0.0)) {{
        s->jc_degraded = EP_NAN;
        s->jc_degraded_info = EP_C(0.0);
    }} else {{
        s->jc_degraded = (s->num - s->jc_num_joint[j]) / info;
        s->jc_degraded_info = info;
    }}
}}

/* JointCheck._load_moves: the short memory has left the whole weighing */
static int ep_jc_load_moves(const ep_state *s)
{{
    ep_real spread, change, limit;
    if (!(EP_C(0.0) < s->info_short && s->info_short < s->info)) return 0;
    spread = EP_C(1.0) / s->info_short - EP_C(1.0) / s->info;
    if (spread < EP_C(0.0)) spread = EP_C(0.0);
    spread = EP_JC_INFLATION * spread;
    change = EP_MATH(fabs)(s->num_short / s->info_short - s->num / s->info);
    limit = EP_JC_CHANGE_SIGMAS * EP_MATH(sqrt)(spread);
    if (limit < EP_JC_CHANGE_MIN) limit = EP_JC_CHANGE_MIN;
    return change > limit;
}}

/* JointCheck._dumped_load: a joint weighed before the last dump and after it (each part with
 * I >= EP_JC_ENOUGH) weighs less after it by more than EP_JC_CHANGE_MIN and beyond EP_JC_CHI2 with
 * both parts' variances: a load left in the dump */
static int ep_jc_dumped_load(const ep_state *s)
{{
    int j;
    for (j = 0; j < 3; ++j) {{
        ep_real after = s->jc_after_info[j], before = s->jc_info[j] - after, drop;
        if (after < EP_JC_ENOUGH || before < EP_JC_ENOUGH) continue;
        drop = (s->jc_num[j] - s->jc_after_num[j]) / before - s->jc_after_num[j] / after;
        if (drop > EP_JC_CHANGE_MIN
            && drop * drop > EP_JC_CHI2 * (EP_JC_INFLATION / after + EP_JC_INFLATION / before + EP_JC_EXTRA))
            return 1;
    }}
    return 0;
}}

/* joint_check._named: of three compared joints, the one that stands out most from the mean of
 * the other two, when those two then agree; else -1 (every compared joint is named) */
static int ep_jc_single(const ep_real m[3], const ep_real w[3])
{{
    ep_real best = EP_C(-1.0);
    int j, worst = 0, a, b;
    for (j = 0; j < 3; ++j) {{
        ep_real wr = EP_C(0.0), mr = EP_C(0.0), d, score;
        int i;
        for (i = 0; i < 3; ++i)
            if (i != j) {{
                wr += w[i];
                mr += w[i] * m[i];
            }}
        mr = mr / wr;
        d = m[j] - mr;
        score = (d * d) / (EP_C(1.0) / w[j] + EP_C(1.0) / wr);
        if (score > best) {{
            best = score;
            worst = j;
        }}
    }}
    a = worst == 0 ? 1 : 0;
    b = worst == 2 ? 1 : 2;
    if (((m[a] - m[b]) * (m[a] - m[b])) / (EP_C(1.0) / w[a] + EP_C(1.0) / w[b]) <= EP_JC_CHI2) return worst;
    return -1;
}}

/* JointCheck._slight: the weighing on the check's sums of the compared joints, with and without
 * joint `single`, within EP_JC_SLIGHT_LIMIT (kg) */
static int ep_jc_slight(const ep_state *s, int compared, int single)
{{
    ep_real n_all = EP_C(0.0), i_all = EP_C(0.0), n_rest = EP_C(0.0), i_rest = EP_C(0.0);
    int j;
    for (j = 0; j < 3; ++j)
        if (compared >> j & 1) {{
            n_all += s->jc_num[j];
            i_all += s->jc_info[j];
        }}
    for (j = 0; j < 3; ++j)
        if ((compared >> j & 1) && j != single) {{
            n_rest += s->jc_num[j];
            i_rest += s->jc_info[j];
        }}
    return EP_MATH(fabs)(n_all / i_all - n_rest / i_rest) <= EP_JC_SLIGHT_LIMIT;
}}

/* joint_check._spread: chi2 of the compared joints' weighings about their weighted mean */
static ep_real ep_jc_spread(int compared, const ep_real m[3], const ep_real w[3])
{{
    ep_real sw = EP_C(0.0), swm = EP_C(0.0), mean, chi2 = EP_C(0.0);
    int j;
    for (j = 0; j < 3; ++j)
        if (compared >> j & 1) {{
            sw += w[j];
            swm += w[j] * m[j];
        }}
    mean = swm / sw;
    for (j = 0; j < 3; ++j)
        if (compared >> j & 1) chi2 += w[j] * ((m[j] - mean) * (m[j] - mean));
    return chi2;
}}

/* JointCheck._side_agrees: joint `single`, one of EP_JC_SIDE_JOINTS, holds windows of both signs of phi (each side's information
 * > 0) and, weighed on one side's sums alone (a side with I >= EP_JC_ENOUGH), agrees with the other
 * compared joints (chi2 within EP_JC_CHI2) */
static int ep_jc_side_agrees(const ep_state *s, int compared, int single, const ep_real m[3], const ep_real w[3])
{{
    ep_real n_side[2], i_side[2];
    int k, j;
    if (!(EP_JC_SIDE_JOINTS >> single & 1)) return 0;
    n_side[0] = s->jc_num[single] - s->jc_neg_num[single];
    i_side[0] = s->jc_info[single] - s->jc_neg_info[single];
    n_side[1] = s->jc_neg_num[single];
    i_side[1] = s->jc_neg_info[single];
    if (!(i_side[0] > EP_C(0.0) && i_side[1] > EP_C(0.0))) return 0;
    for (k = 0; k < 2; ++k) {{
        ep_real ms[3], ws[3];
        if (i_side[k] < EP_JC_ENOUGH) continue;
        for (j = 0; j < 3; ++j) {{
            ms[j] = m[j];
            ws[j] = w[j];
        }}
        ms[single] = n_side[k] / i_side[k];
        ws[single] = EP_C(1.0) / (EP_JC_INFLATION / i_side[k] + EP_JC_EXTRA);
        if (ep_jc_spread(compared, ms, ws) <= EP_JC_CHI2) return 1;
    }}
    return 0;
}}

/* JointCheck._judge */
static void ep_jc_judge(ep_state *s)
{{
    ep_real m[3], w[3], chi2 = EP_C(0.0), total = EP_C(0.0);
    int j, compared = 0, n = 0, failing, held, single = -1;
    for (j = 0; j < 3; ++j) {{
        if (s->jc_info[j] >= EP_JC_ENOUGH) {{
            compared |= 1 << j;
            n += 1;
            m[j] = s->jc_num[j] / s->jc_info[j];
            w[j] = EP_C(1.0) / (EP_JC_INFLATION / s->jc_info[j] + EP_JC_EXTRA);
            total += s->jc_info[j];
        }}
    }}
    if (n >= 2) chi2 = ep_jc_spread(compared, m, w);
    s->jc_checked = (unsigned char)(n >= 2);
    failing = chi2 > EP_JC_CHI2;
    if (failing && n == 3) single = ep_jc_single(m, w);
    /* the load is changing: a new fault waits (named at once if still there when the pause ends),
     * unless its joint holds most of the information (JointCheck._leads); and while the one joint
     * it would name moves the weighing by at most EP_JC_SLIGHT_LIMIT (JointCheck._slight), or crossed
     * and agrees on one side (JointCheck._side_agrees) */
    held = failing && !s->jc_named
           && (s->jc_dumping || !(!EP_WAIT_FOR_BOOM || s->boom_windows >= EP_BOOM_READY)  /* dump, not ready */
               || ((s->changing || s->jc_paused > 0) && !(single >= 0 && EP_C(2.0) * s->jc_info[single] > total))
               || (single >= 0 && ep_jc_slight(s, compared, single))
               || (single >= 0 && ep_jc_side_agrees(s, compared, single, m, w)));
    /* a named joint is cleared only by agreeing with another compared joint (a pair: its own two
     * agreeing again); a pair named before this load also by the joints compared on this load's
     * sums agreeing */
    if (s->jc_named && !failing
        && !(n >= 2 && ((s->jc_named & ~compared) == 0 || s->jc_named_before_load))) failing = 1;
    if (failing != (s->jc_named != 0)) s->jc_run += 1;
    else s->jc_run = 0;
    if (s->jc_run < EP_JC_SAMPLES || held) {{
        for (j = 0; j < 3; ++j)
            if (s->jc_named == 1 << j) ep_jc_without(s, j);
        return;
    }}
    s->jc_run = 0;
    if (!failing) {{
        s->jc_restart = (unsigned char)(s->jc_named != 0);  /* its biased windows: start again */
        s->jc_named = 0;
        s->jc_named_before_load = 0;
        s->jc_degraded = EP_NAN;
        s->jc_degraded_info = EP_C(0.0);
        return;
    }}
    s->jc_named = single >= 0 ? 1 << single : compared;
    s->jc_named_before_load = 0;
    if (single >= 0) ep_jc_without(s, single);
    else {{
        s->jc_degraded = EP_NAN;
        s->jc_degraded_info = EP_C(0.0);
    }}
}}

/* JointCheck.update: one balance window, after the kernel has summed it */
static void ep_jc_update(ep_state *s, const ep_real dn[3], const ep_real di[3], const unsigned char neg[3])
{{
    int j, ended = 0;
    if (s->jc_new_load) {{  /* the weighing restarted: so do the check's sums (not a fault named) */
        s->jc_new_load = 0;
        ep_jc_clear(s);
        /* a pair named (nothing weighed) is judged again on the new load's sums */
        s->jc_named_before_load = (unsigned char)((s->jc_named & (s->jc_named - 1)) != 0);
    }}
    ep_jc_track_moving(s);
    s->jc_dumping = (unsigned char)(s->dump_left > 0);  /* CalibratedKernel.dumping */
    if (s->jc_dumping) {{  /* the load leaves: what the joints weigh now is no one load (not summed) */
        s->jc_dumped = 1;
        for (j = 0; j < 3; ++j) s->jc_after_num[j] = s->jc_after_info[j] = EP_C(0.0);
        ep_jc_judge(s);
        return;
    }}
    for (j = 0; j < 3; ++j) {{
        s->jc_num[j] = EP_FORGETTING * s->jc_num[j] + dn[j];
        s->jc_info[j] = EP_FORGETTING * s->jc_info[j] + di[j];
        s->jc_after_num[j] = EP_FORGETTING * s->jc_after_num[j] + dn[j];
        s->jc_after_info[j] = EP_FORGETTING * s->jc_after_info[j] + di[j];
        s->jc_neg_num[j] = EP_FORGETTING * s->jc_neg_num[j] + (neg[j] ? dn[j] : EP_C(0.0));
        s->jc_neg_info[j] = EP_FORGETTING * s->jc_neg_info[j] + (neg[j] ? di[j] : EP_C(0.0));
    }}
    if (s->jc_dumped && ep_jc_dumped_load(s)) {{  /* a load left in the dump: the weighing starts again */
        s->jc_restart = 1;
        ep_jc_clear(s);
        return;
    }}
    if (ep_jc_load_moves(s)) {{
        if (s->jc_armed && (!s->jc_paused || di[0] + di[1] + di[2] > EP_C(0.0))) {{
            s->jc_paused += 1;  /* windows with information, not of standstill */
            if (s->jc_paused > EP_JC_PAUSE) {{  /* a lasting difference: judged on the sums */
                s->jc_paused = 0;
                s->jc_armed = 0;
            }}
        }}
    }} else {{
        s->jc_armed = 1;
        if (s->jc_paused) {{
            ep_jc_clear(s);
            ended = 1;
        }}
    }}
    ep_jc_judge(s);
    /* a pause ended: the weighing's sums hold the windows it saw, it starts again as the check's did;
     * not while it weighs the monitor's substitutes (it would start again on them alone) */
    if (ended && EP_JC_PAUSE_RESTARTS && !s->hm_substituting) s->jc_restart = 1;
}}

/* PressureKernel._joint_rules and step's last rule: load_changing while the check pauses, a
 * joint weighed alone ok until its weighing moves (then warming_up until a second joint is
 * weighed, across restarts), sensor_fault (never ok) while a cylinder is named,
 * with the weighing without it when one joint stands out (else NaN) */
static int ep_jc_status(ep_state *s, int status, ep_real *estimate, int gap)
{{
    if (status == EP_STATUS_OK) {{
        if (s->jc_moved_settled) s->jc_lone_moved = 1;  /* compared or not: after the pause, fresh sums */
        else if (s->jc_checked && !s->jc_paused) s->jc_lone_moved = 0;
    }}
    /* paused, or (JointCheck.suspect) the weighing moves before a fault is named */
    if (status == EP_STATUS_OK && (s->jc_paused || s->jc_moving))
        status = EP_STATUS_LOAD_CHANGING;
    if (status == EP_STATUS_OK && !s->jc_checked && s->jc_lone_moved && !s->jc_named) status = EP_STATUS_WARMING_UP;
    if (s->jc_named && (status == EP_STATUS_OK || status == EP_STATUS_LOAD_CHANGING)) {{
        *estimate = s->jc_degraded;
        s->jc_out_info = s->jc_degraded_info;
        s->jc_reported = (unsigned char)!gap;  /* a gap's sample says gap, with no fault */
        return EP_STATUS_SENSOR_FAULT;
    }}
    return status;
}}

/* the pressures named by the last ep_step (EP_FAULT_BALANCE) */
static unsigned long ep_jc_faults(const ep_state *s)
{{
    unsigned long mask = 0;
    int j;
    if (!s->jc_reported) return 0;
    for (j = 0; j < 3; ++j)
        if (s->jc_named >> j & 1) mask |= EP_JC_PRESSURES[j];
    return mask;
}}
#endif"""
    return CJointCheck(
        fields=fields,
        definitions=definitions,
        reset="\n    ep_jc_reset(s);",
        accumulate="#if EP_JOINT_CHECK\nep_jc_accumulate(s, jd_num, jd_info);\n#endif",
        restart="\n#if EP_JOINT_CHECK\n            ep_jc_reset_sums(s);\n#endif",
        settle="\n#if EP_JOINT_CHECK\n                ep_jc_settle(s);\n#endif",
        update="#if EP_JOINT_CHECK\nep_jc_update(s, jd_num, jd_info, jd_neg);\nif (s->jc_restart) {\n    s->jc_restart = 0;\n    ep_jc_restart(s);\n}\n#else\n(void)jd_num;\n(void)jd_info;\n(void)jd_neg;\n#endif",
        prologue="""#if EP_JOINT_CHECK
    unsigned char jc_gap = s->jc_gap;  /* this sample came after a gap (its status: gap) */
    s->jc_gap = 0;
    s->jc_reported = 0;
#endif
""",
        status="""#if EP_JOINT_CHECK
    s->jc_out_info = EP_JC_WEIGHED_INFO(s);
    if (rejected) return EP_STATUS_REJECTED;
    return ep_jc_status(s, EP_JC_WEIGHED_INFO(s) < EP_WARM_INFO ? EP_STATUS_WARMING_UP : @KERNEL_STATUS@, estimate,
                        jc_gap);
#endif""",
        on_gap="\n#if EP_JOINT_CHECK\n    s->jc_gap = 1;\n#endif",
        sigma=("    /* _estimate_sigma: sqrt(1/I + s_model^2), I of the estimate reported (the joint check's\n"
               "     * weighing without a named joint) */\n"
               "#if EP_JOINT_CHECK\n"
               "    ep_real info = s->jc_out_info;\n"
               "#else\n"
               "    ep_real info = EP_JC_WEIGHED_INFO(s);\n"
               "#endif\n"
               f"    return info > EP_C(0.0) ? EP_MATH(sqrt)(EP_C(1.0) / info + {c_number(model_var)}) : EP_NAN;"),
    )


def _once(text: str, anchor: str, new: str, where: str) -> str:
    """``text`` with ``new`` put after (or, ``where="before"``, before) its one ``anchor``."""
    if text.count(anchor) != 1:
        raise RuntimeError(f"joint check export: the kernel's C has {text.count(anchor)} of {anchor!r}")
    return text.replace(anchor, anchor + new if where == "after" else new + anchor)


def add_joint_check(model, est, kernel, signals, model_var: float):
    """``model`` (the calibrated kernel's :class:`CModel`, momentum form) with the joint check's
    hooks put where the Python kernel calls them.

    Parameters
    ----------
    model : CModel
        The kernel's parts from its builder.
    est : Estimator
        The fitted ``calibrated`` estimator.
    kernel : CalibratedKernel
        Its kernel.
    signals : sequence of str
        The export's signals, in order.
    model_var : float
        The calibration's model variance, kg².
    """
    jc = joint_check_c(est, kernel, signals, model_var)
    step = model.step
    step = _once(step, "ep_real integral[6], momentum[6], bal[15], bal_rate[3];",
                 "\n            ep_real jd_num[3], jd_info[3];  /* each joint's share (the joint check) */"
                 "\n            unsigned char jd_neg[3];  /* ... its phi_j < 0 in a weighed window */", "after")
    step = _once(step, "d_info += wt * (bal[3 + j] * bal[3 + j]);",
                 "\n            jd_num[j] = wt * (bal[3 + j] * bal[j]);"
                 "\n            jd_info[j] = wt * (bal[3 + j] * bal[3 + j]);"
                 "\n            jd_neg[j] = (unsigned char)(wt > EP_C(0.0) && bal[3 + j] < EP_C(0.0));", "after")
    step = _once(step, "s->info = EP_FORGETTING * s->info + d_info;\n", jc.accumulate + "\n", "after")
    step = _once(step, "restarted = 1;", jc.restart, "after")
    step = _once(step, "s->info = s->info_short;", jc.settle, "after")
    step = _once(step, "s->steady_count = k + 1;\n        }\n", jc.update + "\n", "after")
    step = _once(step, "    for (i = 0; i < EP_N_SIGNALS; ++i) s->ring[newest * EP_N_SIGNALS + i] = v[i];",
                 jc.prologue, "before")
    last = "    return (s->changing || EP_DUMP_PENDING(s)) ? EP_STATUS_LOAD_CHANGING : EP_STATUS_OK;"
    step = _once(step, "    if (rejected) return EP_STATUS_REJECTED;",
                 jc.status.replace("@KERNEL_STATUS@", "((s->changing || EP_DUMP_PENDING(s)) ? EP_STATUS_LOAD_CHANGING : EP_STATUS_OK)") + "\n",
                 "before")
    if step.count(last) != 1:
        raise RuntimeError("joint check export: the kernel's C has no single changing status")
    model.step = step
    model.on_gap = model.on_gap + jc.on_gap
    model.reset = model.reset + jc.reset
    model.state_fields = list(model.state_fields) + jc.fields
    model.definitions = model.definitions + "\n" + jc.definitions
    model.sigma = jc.sigma
    return model
