"""The sensor health monitor (:class:`~excavator_payload.estimators.health.HealthMonitor`) in C,
for every export of the ``machine`` sensor set.

:func:`health_c` renders the monitor's constants, state fields, reset and step for the
template (:func:`~excavator_payload.runtime.export_c.template.render`), which calls it where
:meth:`Estimator.step_values` calls the monitor: after the finite and plausibility checks,
before the gap rule; while it reports a fault the sample is not used, ``ep_step`` returns
``EP_STATUS_SENSOR_FAULT`` with the last estimate and sigma (or, where only link rates the
estimator weighs without are named, ``ep_hm_substitute`` puts their angles' slopes in their
place and the sample is weighed, ``EP_STATUS_DEGRADED``, sigma widened: as
:meth:`HealthMonitor.substitute`), and ``ep_faults`` says which
signals and kinds (one bit mask over the signals per kind). The thresholds, windows and rules
are read from :mod:`excavator_payload.estimators.health` and from a monitor built for the
estimator's sensor set at export time (so a retuned constant is exported as it is), the noise
limits from the fitted estimator's ``health_reference``.

The C follows ``HealthMonitor.step`` rule by rule and in the same order (the same 5-sample
stagger), with two differences in how, not what: the windows' sums (offset, gain, tilt) are
summed over a ring of per-sample terms instead of Python's differences of running totals
(bounded state; a float build loses no precision over a long shift, where a running total
of 10⁶ samples would), so they agree to rounding, not bit for bit; and the sample counters
saturate (C ints do not grow for ever). ``-DEP_HEALTH=0`` compiles the monitor out
(``Estimator.health = False``); the default is the estimator's ``health``.
"""

from __future__ import annotations

from dataclasses import dataclass

from excavator_payload.estimators import health as H
from excavator_payload.runtime import dbc
from excavator_payload.runtime.export_c.c_text import c_array, c_number
from excavator_payload.runtime.export_c.health_degraded import (
    C_FORGET, TILT_FIELDS, tilt_defines, tilt_functions, tilt_substitute)
from excavator_payload.runtime.export_c.health_slew import SLEW_FIELDS, slew_defines, slew_functions
from excavator_payload.runtime.export_c.joint_check import exports_joint_check


@dataclass
class CHealth:
    """The monitor's parts for the template.

    Parameters
    ----------
    header : str
        Defines and declarations for the header (after the model's defines).
    fields : str
        ``ep_state`` fields (under ``#if EP_HEALTH``).
    definitions : str
        Constants and static functions of the source (before the model's definitions).
    declaration : str
        ``ep_faults``' declaration (header, after ``ep_sigma``'s).
    api : str
        ``ep_faults`` and its tables (source, after ``ep_sigma``).
    """

    header: str
    fields: str
    definitions: str
    declaration: str
    api: str

    #: ep_step: before anything (the fault report is the last sample's only)
    clear = "#if EP_HEALTH\n    s->hm_reported = 0;\n    s->hm_substituting = 0;\n#endif\n"
    #: ep_step: its locals for degraded weighing (HealthMonitor.substitute)
    locals = "#if EP_HEALTH\n    ep_real hm_used[EP_N_SIGNALS];\n    int degraded = 0;\n#endif\n"
    #: ep_step: where Estimator.step_values calls the monitor
    check = ("#if EP_HEALTH\n"
             "    /* the sensor health monitor (estimators/health.py): while it names a fault the sample\n"
             "     * is not used (the next healthy one sees a hole in time), the estimate is kept;\n"
             "     * unless only link rates are named (stuck, dropout, noise): then the model weighs\n"
             "     * on with their angles' slopes (HealthMonitor.substitute), degraded */\n"
             "    if (ep_hm_step(s, time, v)) {\n"
             "        s->hm_reported = 1;\n"
             "        if (!ep_hm_substitute(s, v, hm_used)) {\n"
             "            *estimate = s->last_estimate;\n"
             "            return EP_STATUS_SENSOR_FAULT;\n"
             "        }\n"
             "        v = hm_used;\n"
             "        degraded = 1;\n"
             "        s->hm_substituting = 1;  /* Estimator._substituting: the model weighs substitutes */\n"
             "    }\n"
             "#endif\n")
    #: ep_step: after the model's sigma (Estimator._use: widened while degraded)
    inflate = ("#if EP_HEALTH\n"
               "    if (degraded) {  /* and the move since the degraded samples began (Estimator._use) */\n"
               "        sigma *= EP_DEGRADED_SIGMA_FACTOR;\n"
               "        if (!isfinite(s->hm_degraded_from)) s->hm_degraded_from = result;\n"
               "        else if (isfinite(result)) sigma += EP_MATH(fabs)(result - s->hm_degraded_from);\n"
               "    } else {\n"
               "        s->hm_degraded_from = EP_NAN;\n"
               "    }\n"
               "#endif\n")
    #: ep_step: the last rule (Estimator.step_values: an ok of a degraded sample is degraded)
    final = "#if EP_HEALTH\n    if (degraded && status == EP_STATUS_OK) return EP_STATUS_DEGRADED;\n#endif\n"
    #: ep_reset
    reset = "\n#if EP_HEALTH\n    ep_hm_reset(s);\n#endif"


# J1939-73's failure mode identifiers the kinds map to (health.FMI; runtime/dm1.py)
_FMI_MEANING = {2: "data erratic", 5: "current below normal or open circuit",
                7: "mechanical system not responding", 13: "out of calibration"}


def _ints(name: str, values) -> str:
    values = [int(v) for v in values]
    return f"static const int {name}[{len(values)}] = {{{', '.join(map(str, values))}}};\n"


def _mask(indices) -> str:
    bits = 0
    for i in indices:
        bits |= 1 << i
    return f"{bits:#x}UL"


def health_c(est) -> CHealth | None:
    """The C monitor of ``est``'s export, or None where Python runs none (not the machine set).

    Parameters
    ----------
    est : Estimator
        The fitted estimator (sensor set, ``health``, ``health_reference``).
    """
    m = H.for_sensor_set(est.sensor_set, getattr(est, "health_reference", None))
    if m is None:
        return None
    n = len(m.signals)
    if n > 32:
        raise ValueError("the fault masks hold 32 signals")  # unsigned long has at least 32 bits
    kinds = list(H.KINDS) + ["balance"]  # the last: the calibrated kernel's joint check (joint_check.py)
    kind_of = {k: i for i, k in enumerate(kinds)}
    L = len(m.link_angle)
    # the raw samples' ring needs the stuck, disagree and noise windows; the per-sample terms'
    # ring the offset and gain windows (Python keeps one ring of m.size for both)
    raw = max(m.n_stuck, m.n_dis, m.n_sub, m.every + 2)
    sums = max(m.n_smooth, m.n_gain)
    cap = max(raw, sums, m.every + 3) + 1  # the counter saturates above every window
    group = [0] * n  # dropout groups: 1 angles, 2 pressures
    for i in m.angles:
        group[i] = 1
    for i in m.pressures:
        group[i] = 2
    partner = [-1] * n
    for p, r in m.pressure_rate:
        partner[p] = r
    is_rate = [1 if i in m.rates else 0 for i in range(n)]
    lone = [1 if i in m.lone else 0 for i in range(n)]
    pitch, roll = (m.tilts if m.tilts else (-1, -1))
    restart = _mask(kind_of[k] for k in H._RESTART_KINDS)
    flagged = _mask(kind_of[k] for k in H._TRACK_FLAGGED)
    kind_defines = "\n".join(f"#define EP_FAULT_{k.upper()} {i}  /* J1939 FMI {H.FMI[k]}: "
                             f"{_FMI_MEANING.get(H.FMI[k], 'see J1939-73')} */"
                             for i, k in enumerate(kinds))
    header = f"""

/* Sensor health (estimators/health.py, HealthMonitor): while a signal is named faulty, ep_step
 * returns EP_STATUS_SENSOR_FAULT, does not use the sample and keeps the last estimate and sigma;
 * or, where only link rates the model weighs without are named, weighs on with their angles'
 * slopes (EP_STATUS_DEGRADED unless another status applies, sigma widened).
 * ep_faults(s, kind) is then a bit mask over the signals (bit i = EP_SIGNAL_NAMES[i]) of those
 * named with that kind; 0 when nothing is named. For J1939 DM1: one DTC per set bit,
 * SPN = EP_SPN_BASE + i (the generated DBC's), FMI = EP_FAULT_FMI[kind]. Kinds: */
#ifndef EP_HEALTH
#define EP_HEALTH {1 if est.health else 0}  /* -DEP_HEALTH=0: no monitor (Estimator.health = False) */
#endif
#define EP_N_FAULT_KINDS {len(kinds)}
{kind_defines}
#define EP_SPN_BASE {dbc.FIRST_PROPRIETARY_SPN}
#define EP_HM_N_LINKS {L}
#define EP_HM_RAW {raw}  /* rows of the raw samples' ring */
#define EP_HM_SUMS {sums}  /* rows of the per-sample terms' ring */
#define EP_HM_N_BLOCKS {m.n_blocks}  /* noise blocks of EP_HM_EVERY samples */
#define EP_HM_EVERY {m.every}

extern const char *const EP_FAULT_KIND_NAMES[EP_N_FAULT_KINDS];
extern const int EP_FAULT_FMI[EP_N_FAULT_KINDS];"""
    api_decl = """
/* Bit mask over the signals named with fault `kind` (EP_FAULT_*) by the last ep_step (0 unless it
 * returned EP_STATUS_SENSOR_FAULT, or when built with EP_HEALTH=0). */
unsigned long ep_faults(const ep_state *s, int kind);
"""
    fields = """#if EP_HEALTH
    /* sensor health monitor (estimators/health.py) */
    int hm_reported;           /* the last ep_step returned sensor_fault or weighed degraded */
    int hm_age[EP_N_SIGNALS][EP_N_FAULT_KINDS];  /* samples since the fault was last seen, -1: none */
    int hm_any_active;         /* any hm_age >= 0 */
    ep_real hm_last_time;
    int hm_has_last_time;
    ep_real hm_degraded_from;  /* the estimate when the degraded samples began (NaN: not degraded) */
    int hm_substituting;       /* this ep_step weighs the monitor's substitutes (degraded) */
    int hm_count;              /* samples since the windows started (saturates) */
    int hm_phase;              /* count modulo EP_HM_EVERY: the stagger */
    int hm_raw_next, hm_sum_next;
    ep_real hm_raw[EP_HM_RAW][EP_N_SIGNALS];
    ep_real hm_y[EP_HM_SUMS][EP_HM_N_LINKS];  /* angle - integrated rate */
    ep_real hm_x[EP_HM_SUMS][EP_HM_N_LINKS];  /* angle - its first value */
    ep_real hm_tilt[EP_HM_SUMS];              /* hypot(pitch, roll) */
    ep_real hm_integral[EP_HM_N_LINKS], hm_origin[EP_HM_N_LINKS];
    int hm_zeros[EP_N_SIGNALS], hm_since[EP_N_SIGNALS], hm_disagreeing[EP_HM_N_LINKS];
    int hm_tracked[EP_HM_N_LINKS], hm_off_run[EP_HM_N_LINKS], hm_gain_run[EP_HM_N_LINKS];
    int hm_gain_wait[EP_HM_N_LINKS];
    ep_real hm_track[EP_HM_N_LINKS][2];       /* level, slope */
    int hm_tilt_tracked, hm_tilt_run;
    ep_real hm_tilt_track[2];
    int hm_blocks[EP_HM_N_BLOCKS][EP_N_SIGNALS], hm_n_blocks, hm_block_next;
    int hm_noise_count[EP_N_SIGNALS];
#endif"""
    alpha, beta = zip(*m.track_gains)
    sub_angle = [-1] * n  # per signal: a link rate's angle (its substitute's source), else -1
    allowed = m.substitutable(est.degraded_rates())
    for a, r in zip(m.link_angle, m.link_rate):
        if r in allowed:
            sub_angle[r] = a
    drop_joint = [-1] * n  # per signal: the joint a named pressure drops (degraded_pressures), else -1
    for i in m.droppable(est.degraded_pressures()):
        drop_joint[i] = m.pressure_joint[i]
    drops = any(j >= 0 for j in drop_joint)  # else not a byte of it (the other models' C as before)
    # per signal: the link whose lost angle (degraded_angles) it is, or whose rate, else -1
    int_link = [-1] * n
    for j, a in enumerate(m.link_angle):
        if a in m.integrable(est.degraded_angles()):
            int_link[a] = int_link[m.link_rate[j]] = j
    angles = any(j >= 0 for j in int_link)
    # the house tilts weighed on with their value from before the fault (degraded_tilts)
    tilts = angles and bool(m.tilts) and m.slew is not None and \
        any(m.signals[i] in est.degraded_tilts() for i in m.tilts)
    if tilts and not all(m.signals[i] in est.degraded_tilts() for i in m.tilts):
        raise ValueError("health: the C export substitutes both house tilts or neither")
    more = drops or angles  # the extended substitute (pressures' joints, lost angles)
    jump = est.jump_limit()  # Estimator._use: an ok estimate that jumps says load_changing
    if angles:
        fields = fields.replace("    int hm_reported;",
                                "    ep_real hm_angle_ref[EP_HM_N_LINKS];  /* a lost angle's reference (angle - integral) */\n"
                                "    int hm_angle_state[EP_HM_N_LINKS];    /* 0 not named, 1 reference taken, 2 none to be had */\n"
                                "    int hm_angle_age[EP_HM_N_LINKS], hm_angle_clean[EP_HM_N_LINKS];\n"
                                "    int hm_reported;")
    slew = bool(m.slew_watched)  # the slew rate against the tilt's direction (health_slew)
    if tilts and not slew:
        raise ValueError("health: the C tilt substitute reads the slew check's ring")
    if slew:
        fields = fields.replace("    int hm_reported;", SLEW_FIELDS + "    int hm_reported;")
    if tilts:
        fields = fields.replace("    int hm_reported;", TILT_FIELDS + "    int hm_reported;")
    if drops:
        header += """
#if EP_HEALTH  /* the joints (bit j: boom, dipper, bucket) a named pressure drops from this sample */
#define EP_HM_DROPPED(s) ((s)->hm_drop)
#else
#define EP_HM_DROPPED(s) 0u
#endif"""
        fields = fields.replace("    int hm_reported;", "    unsigned int hm_drop;      /* joints dropped from this sample's weighing (bit j) */\n"
                                "    unsigned long hm_prev_named;  /* the signals named after the sample before */\n"
                                "    int hm_reported;")
    definitions = f"""#if EP_HEALTH
/* estimators/health.py at export time: windows in samples, thresholds in SI units */
#define EP_HM_CAP {cap}
#define EP_HM_N_STUCK {m.n_stuck}
#define EP_HM_N_DIS {m.n_dis}
#define EP_HM_N_SMOOTH {m.n_smooth}
#define EP_HM_N_GAIN {m.n_gain}
#define EP_HM_HOLD {m.hold}
#define EP_HM_PITCH {pitch}
#define EP_HM_ROLL {roll}
#define EP_HM_DROPOUT_SAMPLES {H.DROPOUT_SAMPLES}
#define EP_HM_DISAGREE_SAMPLES {H.DISAGREE_SAMPLES}
#define EP_HM_OFFSET_EVALUATIONS {m.offset_evaluations}
#define EP_HM_GAIN_EVALUATIONS {m.gain_evaluations}
#define EP_HM_NOISE_CHECKED {1 if m.noise_checked else 0}
#define EP_HM_RESTART_KINDS {restart}  /* after these a link's track starts again */
#define EP_HM_FLAGGED_KINDS {flagged}  /* under these a link's track follows slowly */
#define EP_HM_MOVING_RATE {c_number(H.MOVING_RATE)}
#define EP_HM_MOVED {c_number(H.MOVING_RATE * m.duration)}
#define EP_HM_HALF_PERIOD {c_number(0.5 * m.period)}
#define EP_HM_DISAGREE_LIMIT {c_number(H.DISAGREE_LIMIT)}
#define EP_HM_DISAGREE_PER_RATE_CHANGE {c_number(H.DISAGREE_PER_RATE_CHANGE)}
#define EP_HM_TILT_OFFSET_LIMIT {c_number(H.TILT_OFFSET_LIMIT)}
#define EP_HM_OFFSET_SLOPE_LIMIT {c_number(H.OFFSET_SLOPE_LIMIT)}
#define EP_HM_GAIN_LIMIT {c_number(H.GAIN_LIMIT)}
#define EP_HM_GAIN_MIN_VAR {c_number(H.GAIN_MIN_STD ** 2)}
#define EP_HM_NOISE_COUNT_LIMIT {c_number(m.noise_count_limit)}
#define EP_HM_N_SUB {m.n_sub}  /* samples of a rate's substitute (the angle's least-squares slope) */
#define EP_HM_SUB_KINDS {_mask(kind_of[k] for k in H.SUBSTITUTE_KINDS)}  /* kinds a rate is replaced under */
#define EP_DEGRADED_SIGMA_FACTOR {c_number(H.DEGRADED_SIGMA_FACTOR)}
{_ints("EP_HM_SUB_ANGLE", sub_angle)}{c_array("EP_HM_SUB_WEIGHTS", m.sub_weights)}\
{_ints("EP_HM_LINK_ANGLE", m.link_angle)}{_ints("EP_HM_LINK_RATE", m.link_rate)}\
{_ints("EP_HM_GROUP", group)}{_ints("EP_HM_PARTNER", partner)}{_ints("EP_HM_IS_RATE", is_rate)}\
{_ints("EP_HM_LONE", lone)}{c_array("EP_HM_QUANTUM", m.quantum)}{c_array("EP_HM_NOISE_LIMIT", m.noise_limit)}\
{c_array("EP_HM_NOISE_RELATIVE", m.noise_relative)}{c_array("EP_HM_ALPHA", alpha)}{c_array("EP_HM_BETA", beta)}\
{c_array("EP_HM_OFFSET_LIMIT", m.offset_limit)}
{_more_defines(m, drop_joint, int_link, kind_of) if more else ""}\
{slew_defines(m) if slew else ""}{tilt_defines(m) if tilts else ""}\
{_functions(slew, angles, tilts)}\
{tilt_substitute(_C_SUBSTITUTE_MORE) if tilts else _C_SUBSTITUTE_MORE if more else _C_SUBSTITUTE}
{C_FORGET if drops else ""}\
#endif
"""
    fmis = ", ".join(str(H.FMI[k]) for k in kinds)
    names = ", ".join(f'"{k}"' for k in kinds)
    balance = ""
    if exports_joint_check(est, getattr(getattr(est, "kernel", None), "regression", None)):
        balance = "    if (kind == EP_FAULT_BALANCE) return ep_jc_faults(s);  /* the kernel's joint check */\n"
    api = f"""
const char *const EP_FAULT_KIND_NAMES[EP_N_FAULT_KINDS] = {{{names}}};
const int EP_FAULT_FMI[EP_N_FAULT_KINDS] = {{{fmis}}};

unsigned long ep_faults(const ep_state *s, int kind)
{{
#if EP_HEALTH
    unsigned long mask = 0;
    int i;
{balance}    if (!s->hm_reported || kind < 0 || kind >= EP_N_FAULT_KINDS) return 0;
    for (i = 0; i < EP_N_SIGNALS; ++i)
        if (s->hm_age[i][kind] >= 0) mask |= 1UL << i;
    return mask;
#else
    (void)s;
    (void)kind;
    return 0;
#endif
}}
"""
    parts = CHealth(header, fields, definitions, api_decl, api)
    if more:
        parts.check = CHealth.check.replace("ep_hm_substitute(s, v, hm_used)", "ep_hm_substitute(s, v, hm_used, &s->hm_drop)")
    if drops:
        parts.clear = CHealth.clear.replace("#endif\n", "    s->hm_drop = 0;\n#endif\n")
    if balance:  # a sample the monitor keeps from the kernel reports no balance fault (as in Python)
        parts.clear = parts.clear.replace("#endif\n", "    s->jc_reported = 0;\n#endif\n")
    if angles and not drops:  # no pressure's joint to drop (before: also a model that drops one
        # but has no joint check, whose named pressures' joints C then weighed on, unlike Python)
        parts.check = CHealth.check.replace("ep_hm_substitute(s, v, hm_used)", "ep_hm_substitute(s, v, hm_used, 0)")
    if jump is not None:
        parts.inflate = parts.inflate.replace(
            "#if EP_HEALTH\n",
            "#if EP_HEALTH\n"
            f"    if (status == EP_STATUS_OK && isfinite(s->last_estimate) && isfinite(result)\n"
            f"        && EP_MATH(fabs)(result - s->last_estimate) > {c_number(jump)})  /* Estimator.jump_limit */\n"
            "        status = EP_STATUS_LOAD_CHANGING;\n", 1)
    if drops:  # the samples before a signal's name carry its fault too (HealthMonitor.newly_named_joints)
        # and a substitute's end mixes it with the signal (HealthMonitor.cleared_joints)
        parts.check = parts.check.replace("    if (ep_hm_step(s, time, v)) {\n",
                                          "    if (ep_hm_step_forget(s, time, v)) {\n", 1)
        if "ep_hm_step_forget" not in parts.check:
            raise AssertionError("health C: the check's call of ep_hm_step has changed")
        parts.check = parts.check.replace(
            "        degraded = 1;\n",
            "        degraded = 1;\n"
            "        {\n"
            "            unsigned int hm_new = ep_hm_newly_named_joints(s);  /* their samples before the name */\n"
            "            if (hm_new) ep_hm_forget(s, hm_new);\n"
            "        }\n")
        parts.definitions = parts.definitions.replace(
            "    unsigned long found[EP_N_FAULT_KINDS] = {0};\n    int i, j, k, c, row, any = 0;\n",
            "    unsigned long found[EP_N_FAULT_KINDS] = {0};\n    int i, j, k, c, row, any = 0;\n"
            "    s->hm_prev_named = 0;  /* HealthMonitor.previous: named after the last sample */\n"
            "    if (s->hm_any_active)\n"
            "        for (i = 0; i < EP_N_SIGNALS; ++i)\n"
            "            for (k = 0; k < EP_N_FAULT_KINDS; ++k)\n"
            "                if (s->hm_age[i][k] >= 0) s->hm_prev_named |= EP_HM_BIT(i);\n", 1)
        if "s->hm_prev_named = 0;" not in parts.definitions:
            raise AssertionError("health C: ep_hm_step's opening has changed")
    return parts


# HealthMonitor.step, _faults, _stuck, _noise, _offset_and_gain, _tilt_offset and _gain (_slew_gain:
# health_slew.py)
_C_FUNCTIONS = r"""
#define EP_HM_BIT(i) (1UL << (i))
/* ring rows `back` samples before the newest */
#define EP_HM_RAW_AT(s, back) ((s)->hm_raw_next + 2 * EP_HM_RAW - 1 - (back)) % EP_HM_RAW
#define EP_HM_SUM_AT(s, back) ((s)->hm_sum_next + 2 * EP_HM_SUMS - 1 - (back)) % EP_HM_SUMS

/* HealthMonitor._restart: the windows start again; active faults keep their hold */
static void ep_hm_restart(ep_state *s)
{
    int i, j;
    s->hm_count = 0;
    s->hm_phase = 0;
    s->hm_raw_next = 0;
    s->hm_sum_next = 0;
    for (i = 0; i < EP_N_SIGNALS; ++i) {
        s->hm_zeros[i] = 0;
        s->hm_since[i] = EP_HM_CAP;
        s->hm_noise_count[i] = 0;
    }
    for (j = 0; j < EP_HM_N_LINKS; ++j) {
        s->hm_integral[j] = EP_C(0.0);
        s->hm_origin[j] = EP_C(0.0);
        s->hm_disagreeing[j] = 0;
        s->hm_tracked[j] = 0;
        s->hm_off_run[j] = 0;
        s->hm_gain_run[j] = 0;
        s->hm_gain_wait[j] = 0;
    }
    s->hm_tilt_tracked = 0;
    s->hm_tilt_run = 0;
    s->hm_n_blocks = 0;
    s->hm_block_next = 0;
}

/* HealthMonitor.reset */
static void ep_hm_reset(ep_state *s)
{
    int i, k;
    for (i = 0; i < EP_N_SIGNALS; ++i)
        for (k = 0; k < EP_N_FAULT_KINDS; ++k) s->hm_age[i][k] = -1;
    s->hm_reported = 0;
    s->hm_any_active = 0;
    s->hm_has_last_time = 0;
    s->hm_last_time = EP_C(0.0);
    s->hm_degraded_from = EP_NAN;
    s->hm_substituting = 0;
    ep_hm_restart(s);
}

/* HealthMonitor._is_active: signal i named with any kind in `kinds` (a bit mask of kinds) */
static int ep_hm_active(const ep_state *s, int i, unsigned long kinds)
{
    int k;
    for (k = 0; k < EP_N_FAULT_KINDS; ++k)
        if ((kinds & EP_HM_BIT(k)) && s->hm_age[i][k] >= 0) return 1;
    return 0;
}

/* signal i among this sample's findings with any kind in `kinds` */
static int ep_hm_found(const unsigned long found[EP_N_FAULT_KINDS], int i, unsigned long kinds)
{
    int k;
    for (k = 0; k < EP_N_FAULT_KINDS; ++k)
        if ((kinds & EP_HM_BIT(k)) && (found[k] & EP_HM_BIT(i))) return 1;
    return 0;
}

/* HealthMonitor._stuck */
static void ep_hm_stuck(const ep_state *s, const ep_real *v, unsigned long found[EP_N_FAULT_KINDS])
{
    unsigned long still = 0, dropped = found[EP_FAULT_DROPOUT];
    int first_row = EP_HM_RAW_AT(s, EP_HM_N_STUCK - 1), row = first_row;
    const ep_real *first = s->hm_raw[first_row];
    ep_real hi[EP_N_SIGNALS], lo[EP_N_SIGNALS];
    int i, j, back, turning_any = 0;
    for (i = 0; i < EP_N_SIGNALS; ++i) hi[i] = lo[i] = v[i];
    for (back = EP_HM_N_STUCK - 1; back >= 1; --back) {  /* the window's older rows, oldest first */
        const ep_real *x = s->hm_raw[row];
        for (i = 0; i < EP_N_SIGNALS; ++i) {
            if (x[i] > hi[i]) hi[i] = x[i];
            if (x[i] < lo[i]) lo[i] = x[i];
        }
        if (++row == EP_HM_RAW) row = 0;
    }
    for (i = 0; i < EP_N_SIGNALS; ++i)
        if (hi[i] - lo[i] <= EP_HM_QUANTUM[i]) still |= EP_HM_BIT(i);
    if (!still) return;
    for (j = 0; j < EP_HM_N_LINKS; ++j) {
        int a = EP_HM_LINK_ANGLE[j], r = EP_HM_LINK_RATE[j];
        int turning = s->hm_since[r] < EP_HM_N_STUCK;
        turning_any |= turning;
        if ((still & EP_HM_BIT(a)) && turning && !(dropped & EP_HM_BIT(a))) found[EP_FAULT_STUCK] |= EP_HM_BIT(a);
        if (EP_MATH(fabs)(v[a] - first[a]) > EP_HM_MOVED) {
            if (still & EP_HM_BIT(r)) found[EP_FAULT_STUCK] |= EP_HM_BIT(r);
            else if (s->hm_zeros[r] >= EP_HM_DROPOUT_SAMPLES) found[EP_FAULT_DROPOUT] |= EP_HM_BIT(r);
        }
    }
    for (i = 0; i < EP_N_SIGNALS; ++i) {
        int r = EP_HM_PARTNER[i];
        if (r >= 0 && (still & EP_HM_BIT(i)) && s->hm_since[r] < EP_HM_N_STUCK && !(dropped & EP_HM_BIT(i)))
            found[EP_FAULT_STUCK] |= EP_HM_BIT(i);
        if (turning_any && EP_HM_LONE[i] && (still & EP_HM_BIT(i))) found[EP_FAULT_STUCK] |= EP_HM_BIT(i);
        /* a frozen value stays named while it stays frozen, moving or not */
        if ((still & EP_HM_BIT(i)) && s->hm_age[i][EP_FAULT_STUCK] >= 0) found[EP_FAULT_STUCK] |= EP_HM_BIT(i);
    }
}

/* HealthMonitor._noise: the last EP_HM_EVERY second differences; a share of the window's beyond
 * the limit */
static void ep_hm_noise(ep_state *s, unsigned long found[EP_N_FAULT_KINDS])
{
    int i, t, count[EP_N_SIGNALS], *block = s->hm_blocks[s->hm_block_next];
    for (i = 0; i < EP_N_SIGNALS; ++i) count[i] = 0;
    for (t = 0; t < EP_HM_EVERY; ++t) {
        const ep_real *w0 = s->hm_raw[EP_HM_RAW_AT(s, EP_HM_EVERY + 1 - t)];
        const ep_real *w1 = s->hm_raw[EP_HM_RAW_AT(s, EP_HM_EVERY - t)];
        const ep_real *w2 = s->hm_raw[EP_HM_RAW_AT(s, EP_HM_EVERY - 1 - t)];
        for (i = 0; i < EP_N_SIGNALS; ++i) {
            ep_real d2 = EP_MATH(fabs)(w2[i] - EP_C(2.0) * w1[i] + w0[i]);
            if (d2 > EP_HM_NOISE_LIMIT[i] + EP_MATH(fabs)(w2[i]) * EP_HM_NOISE_RELATIVE[i]) ++count[i];
        }
    }
    for (i = 0; i < EP_N_SIGNALS; ++i) {
        if (s->hm_n_blocks == EP_HM_N_BLOCKS) s->hm_noise_count[i] -= block[i];  /* the oldest leaves */
        block[i] = count[i];
        s->hm_noise_count[i] += count[i];
    }
    s->hm_block_next = (s->hm_block_next + 1) % EP_HM_N_BLOCKS;
    if (s->hm_n_blocks < EP_HM_N_BLOCKS) s->hm_n_blocks += 1;
    if (s->hm_n_blocks == EP_HM_N_BLOCKS)
        for (i = 0; i < EP_N_SIGNALS; ++i)
            if ((ep_real)s->hm_noise_count[i] >= EP_HM_NOISE_COUNT_LIMIT) found[EP_FAULT_NOISE] |= EP_HM_BIT(i);
}

/* HealthMonitor._offset_and_gain: each link's angle - integrated rate against its slow track
 * (offset), and its least-squares slope against the angle (gain) */
static void ep_hm_offset_and_gain(ep_state *s, unsigned long found[EP_N_FAULT_KINDS])
{
    int j, back, row, c = s->hm_count;
    int ns = c < EP_HM_N_SMOOTH ? c : EP_HM_N_SMOOTH;
    ep_real sy[EP_HM_N_LINKS], g[EP_HM_N_LINKS][4];  /* the gain window's sums of y, x, x^2, x y */
    /* the windows' sums, oldest sample first, the links side by side */
    for (j = 0; j < EP_HM_N_LINKS; ++j) sy[j] = g[j][0] = g[j][1] = g[j][2] = g[j][3] = EP_C(0.0);
    for (back = ns - 1, row = EP_HM_SUM_AT(s, back); back >= 0; --back) {
        for (j = 0; j < EP_HM_N_LINKS; ++j) sy[j] += s->hm_y[row][j];
        if (++row == EP_HM_SUMS) row = 0;
    }
    if (c >= EP_HM_N_GAIN) {
        for (back = EP_HM_N_GAIN - 1, row = EP_HM_SUM_AT(s, back); back >= 0; --back) {
            for (j = 0; j < EP_HM_N_LINKS; ++j) {
                ep_real x = s->hm_x[row][j], y = s->hm_y[row][j];
                g[j][0] += y;
                g[j][1] += x;
                g[j][2] += x * x;
                g[j][3] += x * y;
            }
            if (++row == EP_HM_SUMS) row = 0;
        }
    }
    for (j = 0; j < EP_HM_N_LINKS; ++j) {
        int a = EP_HM_LINK_ANGLE[j], r = EP_HM_LINK_RATE[j], slow;
        ep_real smooth = sy[j] / (ep_real)ns, predicted, error, slope = EP_C(0.0);
        /* a link whose angle or rate was stuck, dropped out or noisy has a meaningless integral:
         * its track starts again once that has cleared */
        if (!s->hm_tracked[j] || ep_hm_active(s, a, EP_HM_RESTART_KINDS) || ep_hm_active(s, r, EP_HM_RESTART_KINDS)
            || ep_hm_found(found, a, EP_HM_RESTART_KINDS) || ep_hm_found(found, r, EP_HM_RESTART_KINDS)) {
            s->hm_tracked[j] = 1;
            s->hm_track[j][0] = smooth;
            s->hm_track[j][1] = EP_C(0.0);
            s->hm_off_run[j] = 0;
            s->hm_gain_run[j] = 0;
            s->hm_gain_wait[j] = EP_HM_N_GAIN;
            continue;
        }
        predicted = s->hm_track[j][0] + s->hm_track[j][1] * (ep_real)EP_HM_EVERY * EP_SAMPLE_PERIOD;
        error = smooth - predicted;
        slow = ep_hm_active(s, a, EP_HM_FLAGGED_KINDS);
        s->hm_track[j][0] = predicted + EP_HM_ALPHA[slow] * error;
        s->hm_track[j][1] += EP_HM_BETA[slow] * error;
        s->hm_off_run[j] = (EP_MATH(fabs)(error) > EP_HM_OFFSET_LIMIT[j]
                            || EP_MATH(fabs)(s->hm_track[j][1]) > EP_HM_OFFSET_SLOPE_LIMIT)
                           ? (s->hm_off_run[j] < EP_HM_CAP ? s->hm_off_run[j] + 1 : EP_HM_CAP) : 0;
        if (s->hm_off_run[j] >= EP_HM_OFFSET_EVALUATIONS) {
            found[EP_FAULT_OFFSET] |= EP_HM_BIT(a) | EP_HM_BIT(r);
        }
        if (c >= EP_HM_N_GAIN && s->hm_gain_wait[j] <= 0) {  /* HealthMonitor._gain */
            ep_real m = (ep_real)EP_HM_N_GAIN, var = g[j][2] / m - (g[j][1] / m) * (g[j][1] / m);
            if (var >= EP_HM_GAIN_MIN_VAR) slope = (g[j][3] / m - g[j][1] * g[j][0] / m / m) / var;
        }
        s->hm_gain_run[j] = EP_MATH(fabs)(slope) > EP_HM_GAIN_LIMIT
                            ? (s->hm_gain_run[j] < EP_HM_CAP ? s->hm_gain_run[j] + 1 : EP_HM_CAP) : 0;
        if (s->hm_gain_run[j] >= EP_HM_GAIN_EVALUATIONS) {
            found[EP_FAULT_GAIN] |= EP_HM_BIT(a) | EP_HM_BIT(r);
        }
    }
}

/* HealthMonitor._tilt_offset: the size of the house's tilt against its own slow track */
static void ep_hm_tilt_offset(ep_state *s, unsigned long found[EP_N_FAULT_KINDS])
{
#if EP_HM_PITCH >= 0
    int back, row, c = s->hm_count, ns = c < EP_HM_N_SMOOTH ? c : EP_HM_N_SMOOTH, slow;
    ep_real sum = EP_C(0.0), smooth, predicted, error;
    for (back = ns - 1, row = EP_HM_SUM_AT(s, back); back >= 0; --back) {
        sum += s->hm_tilt[row];
        if (++row == EP_HM_SUMS) row = 0;
    }
    smooth = sum / (ep_real)ns;
    if (!s->hm_tilt_tracked || ep_hm_active(s, EP_HM_PITCH, EP_HM_RESTART_KINDS)
        || ep_hm_active(s, EP_HM_ROLL, EP_HM_RESTART_KINDS) || ep_hm_found(found, EP_HM_PITCH, EP_HM_RESTART_KINDS)
        || ep_hm_found(found, EP_HM_ROLL, EP_HM_RESTART_KINDS)) {
        s->hm_tilt_tracked = 1;
        s->hm_tilt_track[0] = smooth;
        s->hm_tilt_track[1] = EP_C(0.0);
        s->hm_tilt_run = 0;
        return;
    }
    predicted = s->hm_tilt_track[0] + s->hm_tilt_track[1] * (ep_real)EP_HM_EVERY * EP_SAMPLE_PERIOD;
    error = smooth - predicted;
    slow = s->hm_age[EP_HM_PITCH][EP_FAULT_OFFSET] >= 0;
    s->hm_tilt_track[0] = predicted + EP_HM_ALPHA[slow] * error;
    s->hm_tilt_track[1] += EP_HM_BETA[slow] * error;
    s->hm_tilt_run = EP_MATH(fabs)(error) > EP_HM_TILT_OFFSET_LIMIT
                     ? (s->hm_tilt_run < EP_HM_CAP ? s->hm_tilt_run + 1 : EP_HM_CAP) : 0;
    if (s->hm_tilt_run >= EP_HM_OFFSET_EVALUATIONS)
        found[EP_FAULT_OFFSET] |= EP_HM_BIT(EP_HM_PITCH) | EP_HM_BIT(EP_HM_ROLL);
#else
    (void)s;
    (void)found;
#endif
}

/* HealthMonitor.step: judge one finite, plausible sample; 1 while any fault is active */
static int ep_hm_step(ep_state *s, ep_real time, const ep_real v[EP_N_SIGNALS])
{
    unsigned long found[EP_N_FAULT_KINDS] = {0};
    int i, j, k, c, row, any = 0;
    if (s->hm_has_last_time) {
        ep_real dt = time - s->hm_last_time;
        if (!(dt > EP_C(0.0) && dt <= EP_MAX_STEP)) ep_hm_restart(s);  /* a hole in time */
    }
    s->hm_last_time = time;
    s->hm_has_last_time = 1;
    /* per link: angle - integrated rate (trapezoid), and the angle from its first value */
    row = s->hm_sum_next;
    for (j = 0; j < EP_HM_N_LINKS; ++j) {
        int a = EP_HM_LINK_ANGLE[j], r = EP_HM_LINK_RATE[j];
        if (s->hm_count == 0) s->hm_origin[j] = v[a];
        else s->hm_integral[j] += EP_HM_HALF_PERIOD * (s->hm_raw[EP_HM_RAW_AT(s, 0)][r] + v[r]);
        s->hm_y[row][j] = v[a] - s->hm_integral[j];
        s->hm_x[row][j] = v[a] - s->hm_origin[j];
    }
#if EP_HM_PITCH >= 0
    s->hm_tilt[row] = EP_MATH(hypot)(v[EP_HM_PITCH], v[EP_HM_ROLL]);
#endif
    s->hm_sum_next = (row + 1) % EP_HM_SUMS;
    for (i = 0; i < EP_N_SIGNALS; ++i) s->hm_raw[s->hm_raw_next][i] = v[i];
    s->hm_raw_next = (s->hm_raw_next + 1) % EP_HM_RAW;
    if (s->hm_count < EP_HM_CAP) s->hm_count += 1;
    s->hm_phase = (s->hm_phase + 1) % EP_HM_EVERY;
    c = s->hm_count;
    for (j = 0; j < EP_HM_N_LINKS; ++j)
        if (s->hm_gain_wait[j] > 0) s->hm_gain_wait[j] -= 1;
    /* every sample: moving joints, dropouts, angle against rate */
    for (i = 0; i < EP_N_SIGNALS; ++i) {
        if (EP_HM_IS_RATE[i])
            s->hm_since[i] = (v[i] < -EP_HM_MOVING_RATE || v[i] > EP_HM_MOVING_RATE) ? 0
                             : (s->hm_since[i] < EP_HM_CAP ? s->hm_since[i] + 1 : EP_HM_CAP);
        s->hm_zeros[i] = v[i] == EP_C(0.0) ? (s->hm_zeros[i] < EP_HM_CAP ? s->hm_zeros[i] + 1 : EP_HM_CAP) : 0;
    }
    for (k = 1; k <= 2; ++k) {  /* the angles, the pressures: a group not all at 0 */
        int live = 0;
        for (i = 0; i < EP_N_SIGNALS; ++i) live |= (EP_HM_GROUP[i] == k && v[i] != EP_C(0.0));
        if (live)
            for (i = 0; i < EP_N_SIGNALS; ++i)
                if (EP_HM_GROUP[i] == k && s->hm_zeros[i] >= EP_HM_DROPOUT_SAMPLES)
                    found[EP_FAULT_DROPOUT] |= EP_HM_BIT(i);
    }
    if (c >= EP_HM_N_DIS) {
        int old = EP_HM_SUM_AT(s, EP_HM_N_DIS - 1);
        for (j = 0; j < EP_HM_N_LINKS; ++j) {
            int a = EP_HM_LINK_ANGLE[j], r = EP_HM_LINK_RATE[j], back, raw_row = EP_HM_RAW_AT(s, EP_HM_N_DIS - 1);
            ep_real hi = v[r], lo = v[r], limit;
            for (back = EP_HM_N_DIS - 1; back >= 1; --back) {
                ep_real x = s->hm_raw[raw_row][r];
                if (x > hi) hi = x;
                if (x < lo) lo = x;
                if (++raw_row == EP_HM_RAW) raw_row = 0;
            }
            limit = EP_HM_DISAGREE_LIMIT + EP_HM_DISAGREE_PER_RATE_CHANGE * (hi - lo);
            if (EP_MATH(fabs)(s->hm_y[row][j] - s->hm_y[old][j]) > limit) {
                /* one frame is the outlier gate's; two in a row are the sensor's */
                if (s->hm_disagreeing[j] < EP_HM_CAP) s->hm_disagreeing[j] += 1;
                if (s->hm_disagreeing[j] >= EP_HM_DISAGREE_SAMPLES)
                    found[EP_FAULT_DISAGREE] |= EP_HM_BIT(a) | EP_HM_BIT(r);
            } else {
                s->hm_disagreeing[j] = 0;
            }
        }
    }
    /* every EP_HM_EVERY samples, staggered: stuck, noise, offset and gain, the tilt */
    if (s->hm_phase == 0 && c >= EP_HM_N_STUCK) ep_hm_stuck(s, v, found);
    else if (s->hm_phase == 1 && EP_HM_NOISE_CHECKED && c > EP_HM_EVERY + 2) ep_hm_noise(s, found);
    else if (s->hm_phase == 2 && c >= EP_HM_N_SMOOTH) ep_hm_offset_and_gain(s, found);
    else if (s->hm_phase == 3 && c >= EP_HM_N_SMOOTH && EP_HM_PITCH >= 0) ep_hm_tilt_offset(s, found);
    /* the hold: a fault stays active until its condition has been clear EP_HM_HOLD samples */
    for (k = 0; k < EP_N_FAULT_KINDS; ++k) any |= found[k] != 0;
    if (!any && !s->hm_any_active) return 0;
    any = 0;
    for (i = 0; i < EP_N_SIGNALS; ++i) {
        for (k = 0; k < EP_N_FAULT_KINDS; ++k) {
            if (s->hm_age[i][k] >= 0 && ++s->hm_age[i][k] > EP_HM_HOLD) s->hm_age[i][k] = -1;
            if (found[k] & EP_HM_BIT(i)) s->hm_age[i][k] = 0;
            any |= s->hm_age[i][k] >= 0;
        }
    }
    s->hm_any_active = any;
    return any;
}
"""

# HealthMonitor.substitute
_C_SUBSTITUTE = r"""
/* HealthMonitor.substitute: 1 with `out` the sample whose named link rates are replaced by
 * their angles' least-squares slope over the last EP_HM_N_SUB raw samples (summed oldest
 * first), when every active fault is a link rate's of a kind in EP_HM_SUB_KINDS and the
 * windows hold EP_HM_N_SUB samples; else 0 (the sample is not used) */
static int ep_hm_substitute(const ep_state *s, const ep_real v[EP_N_SIGNALS], ep_real out[EP_N_SIGNALS])
{
    int i, k, back;
    if (s->hm_count < EP_HM_N_SUB) return 0;
    for (i = 0; i < EP_N_SIGNALS; ++i)
        for (k = 0; k < EP_N_FAULT_KINDS; ++k)
            if (s->hm_age[i][k] >= 0 && (EP_HM_SUB_ANGLE[i] < 0 || !(EP_HM_SUB_KINDS & EP_HM_BIT(k))))
                return 0;
    for (i = 0; i < EP_N_SIGNALS; ++i) {
        int named = 0;
        out[i] = v[i];
        for (k = 0; k < EP_N_FAULT_KINDS; ++k) named |= s->hm_age[i][k] >= 0;
        if (named) {
            ep_real slope = EP_C(0.0);
            for (back = EP_HM_N_SUB - 1; back >= 0; --back)
                slope += EP_HM_SUB_WEIGHTS[EP_HM_N_SUB - 1 - back]
                         * s->hm_raw[EP_HM_RAW_AT(s, back)][EP_HM_SUB_ANGLE[i]];
            out[i] = slope;
        }
    }
    return 1;
}
"""

def _functions(slew: bool, angles: bool, tilts: bool) -> str:
    """The monitor's C functions: with the slew check, the lost angles' references, the tilt
    substitute's reference, as the export has them."""
    text = slew_functions(_C_FUNCTIONS) if slew else _C_FUNCTIONS
    text = _angle_functions(text) if angles else text
    return tilt_functions(text) if tilts else text


def _more_defines(m, drop_joint, int_link, kind_of) -> str:
    """The extended substitute's tables: each pressure's joint, each lost angle's link."""
    if any(j >= 0 for j in int_link):
        value = ("#define EP_HM_ANGLE_REF_OK(s, j) ((s)->hm_angle_state[j] == 1 && (s)->hm_angle_age[j] <= EP_HM_ANGLE_LIMIT)\n"
                 "#define EP_HM_ANGLE_VALUE(s, j) ((s)->hm_angle_ref[j] + (s)->hm_integral[j])  /* reference + integral */\n")
    else:
        value = "#define EP_HM_ANGLE_REF_OK(s, j) 0\n#define EP_HM_ANGLE_VALUE(s, j) EP_C(0.0)\n"
    return value + (f"#define EP_HM_ANGLE_KINDS {_mask(kind_of[k] for k in H.ANGLE_SUBSTITUTE_KINDS)}"
            "  /* kinds a lost angle is integrated under */\n"
            f"#define EP_HM_ANGLE_BACK {m.n_stuck + m.n_sub}  /* its reference: y of the samples EP_HM_N_STUCK"
            " ... this - 1 back */\n"
            f"#define EP_HM_ANGLE_LIMIT {m.n_angle_limit}  /* samples a lost angle is integrated for */\n"
            + _ints("EP_HM_DROP_JOINT", drop_joint) + _ints("EP_HM_INT_LINK", int_link))


def _angle_functions(text: str) -> str:
    """:data:`_C_FUNCTIONS` with HealthMonitor._angle_references (a lost angle's reference and
    age, after every step) and its restart and reset."""
    text = text.replace("    s->hm_tilt_tracked = 0;\n    s->hm_tilt_run = 0;\n",
                        "    for (j = 0; j < EP_HM_N_LINKS; ++j) {  /* the integral restarts: a reference is lost */\n"
                        "        if (s->hm_angle_state[j]) s->hm_angle_state[j] = 2;\n"
                        "        s->hm_angle_clean[j] = 0;\n"
                        "    }\n"
                        "    s->hm_tilt_tracked = 0;\n    s->hm_tilt_run = 0;\n", 1)
    text = text.replace("    s->hm_last_time = EP_C(0.0);\n    ep_hm_restart(s);\n",
                        "    s->hm_last_time = EP_C(0.0);\n"
                        "    for (i = 0; i < EP_HM_N_LINKS; ++i) s->hm_angle_state[i] = s->hm_angle_age[i] = 0;\n"
                        "    ep_hm_restart(s);\n", 1)
    text = text.replace("/* HealthMonitor.step: judge one finite", _C_ANGLE_REFS + "\n/* HealthMonitor.step: judge one finite", 1)
    text = text.replace("    if (!any && !s->hm_any_active) return 0;\n",
                        "    if (!any && !s->hm_any_active) {\n        ep_hm_angle_refs(s);\n        return 0;\n    }\n", 1)
    text = text.replace("    s->hm_any_active = any;\n    return any;\n",
                        "    s->hm_any_active = any;\n    ep_hm_angle_refs(s);\n    return any;\n", 1)
    return text


_C_ANGLE_REFS = r"""
/* HealthMonitor._angle_references: a link's lost-angle reference is taken when its angle is first
 * named (y = angle - integrated rate, the mean of the EP_HM_N_SUB samples EP_HM_N_STUCK back, none
 * of them named), its age counted, and forgotten once the angle is no longer named */
static void ep_hm_angle_refs(ep_state *s)
{
    int j, k, back;
    for (j = 0; j < EP_HM_N_LINKS; ++j) {
        int a = EP_HM_LINK_ANGLE[j], named = 0;
        for (k = 0; k < EP_N_FAULT_KINDS; ++k) named |= s->hm_age[a][k] >= 0;
        if (!named) {
            s->hm_angle_state[j] = 0;
            if (s->hm_angle_clean[j] < EP_HM_CAP) s->hm_angle_clean[j] += 1;
            continue;
        }
        if (s->hm_angle_state[j] == 0) {
            if (s->hm_count > EP_HM_ANGLE_BACK && s->hm_angle_clean[j] >= EP_HM_ANGLE_BACK) {
                ep_real total = EP_C(0.0);
                for (back = EP_HM_N_STUCK; back < EP_HM_ANGLE_BACK; ++back) total += s->hm_y[EP_HM_SUM_AT(s, back)][j];
                s->hm_angle_ref[j] = total / (ep_real)EP_HM_N_SUB;
                s->hm_angle_state[j] = 1;
            } else {
                s->hm_angle_state[j] = 2;
            }
            s->hm_angle_age[j] = 0;
        }
        if (s->hm_angle_age[j] <= EP_HM_ANGLE_LIMIT) s->hm_angle_age[j] += 1;
        s->hm_angle_clean[j] = 0;
    }
}
"""

# HealthMonitor.substitute for a model that weighs without a pressure's joint or a lost angle
# (degraded_pressures, degraded_angles): a named pressure is set to 0 and its joint's bit set in
# *drop (CalibratedKernel.drop: the kernel's ring_drop); a lost angle is its reference plus the
# integrated rate, its rate weighed as measured
_C_SUBSTITUTE_MORE = r"""
/* HealthMonitor.substitute: 1 with `out` the sample whose named link rates are replaced by their
 * angles' least-squares slope over the last EP_HM_N_SUB raw samples (summed oldest first), each
 * named pressure of EP_HM_DROP_JOINT by 0 with its joint's bit set in *drop, and each lost angle
 * (EP_HM_INT_LINK: named stuck or dropped out, its rate named at most `disagree`) by its reference
 * plus the integrated rate for EP_HM_ANGLE_LIMIT samples; when every active fault is one of these
 * and the windows hold EP_HM_N_SUB samples; else 0 (the sample is not used) */
static int ep_hm_substitute(const ep_state *s, const ep_real v[EP_N_SIGNALS], ep_real out[EP_N_SIGNALS],
                            unsigned int *drop)
{
    int i, k, back, lost[EP_HM_N_LINKS];
    unsigned int dropped = 0;
    if (s->hm_count < EP_HM_N_SUB) return 0;
    for (k = 0; k < EP_HM_N_LINKS; ++k) {
        int a = EP_HM_LINK_ANGLE[k];
        lost[k] = EP_HM_INT_LINK[a] == k && (s->hm_age[a][EP_FAULT_STUCK] >= 0 || s->hm_age[a][EP_FAULT_DROPOUT] >= 0);
    }
    for (i = 0; i < EP_N_SIGNALS; ++i)
        for (k = 0; k < EP_N_FAULT_KINDS; ++k) {
            int j = EP_HM_INT_LINK[i];
            if (s->hm_age[i][k] < 0) continue;
            if (j >= 0 && lost[j] && i == EP_HM_LINK_ANGLE[j]) {
                if (!(EP_HM_ANGLE_KINDS & EP_HM_BIT(k)) && k != EP_FAULT_DISAGREE) return 0;
            } else if (j >= 0 && lost[j]) {
                if (k != EP_FAULT_DISAGREE) return 0;  /* the pair's disagreement is the lost angle's doing */
            } else if ((EP_HM_SUB_ANGLE[i] < 0 && EP_HM_DROP_JOINT[i] < 0) || !(EP_HM_SUB_KINDS & EP_HM_BIT(k))) {
                return 0;
            }
        }
    for (i = 0; i < EP_N_SIGNALS; ++i) {
        int named = 0, j = EP_HM_INT_LINK[i];
        out[i] = v[i];
        for (k = 0; k < EP_N_FAULT_KINDS; ++k) named |= s->hm_age[i][k] >= 0;
        if (!named) continue;
        if (EP_HM_DROP_JOINT[i] >= 0) {
            out[i] = EP_C(0.0);
            dropped |= 1u << EP_HM_DROP_JOINT[i];
        } else if (j >= 0 && lost[j]) {
            if (i != EP_HM_LINK_ANGLE[j]) continue;  /* the rate: weighed as measured */
            if (!EP_HM_ANGLE_REF_OK(s, j)) return 0;
            out[i] = EP_HM_ANGLE_VALUE(s, j);
        } else {
            ep_real slope = EP_C(0.0);
            for (back = EP_HM_N_SUB - 1; back >= 0; --back)
                slope += EP_HM_SUB_WEIGHTS[EP_HM_N_SUB - 1 - back]
                         * s->hm_raw[EP_HM_RAW_AT(s, back)][EP_HM_SUB_ANGLE[i]];
            out[i] = slope;
        }
    }
    if (drop) *drop |= dropped;
    return 1;
}
"""

