"""The parts of the C health monitor (:mod:`.health`) for a model that weighs on through more
faults (``calibrated``, momentum form): a named house tilt replaced by its value from before the
fault (:meth:`HealthMonitor._tilt_reference`, ``degraded_tilts``), and the kernel's windows over
the samples before a signal's name forgotten (:meth:`HealthMonitor.newly_named_joints`,
:meth:`CalibratedKernel.forget`). Rendered into :func:`.health.health_c`'s text."""

from __future__ import annotations

from excavator_payload.runtime.export_c.c_text import c_number
# HealthMonitor._tilt_reference and the tilts' substitute (degraded_tilts): a named house tilt is
# its mean over EP_HM_N_SUB samples EP_HM_TILT_BACK back, while young and the house has not
# slewed far since
TILT_FIELDS = ("    ep_real hm_house[EP_HM_SUMS][3];  /* pitch, roll, slew rate: the tilt substitute's history */\n"
                "    ep_real hm_tilt_ref[2], hm_tilt_turn;  /* its reference, the slew rates summed since */\n"
                "    int hm_tilt_state, hm_tilt_age, hm_tilt_clean;  /* state as hm_angle_state */\n")


def tilt_defines(m) -> str:
    """The tilt substitute's constants.

    Parameters
    ----------
    m : HealthMonitor
        The monitor built for the export (its windows in samples, the slew rate's column).
    """
    return (f"#define EP_HM_SLEW {m.slew}\n"
            f"#define EP_HM_PERIOD {c_number(m.period)}\n"
            f"#define EP_HM_TILT_BACK {m.n_tilt_back}  /* its reference ends this many samples back */\n"
            f"#define EP_HM_TILT_LIMIT {m.n_tilt_limit}  /* samples a named tilt is substituted for */\n")


def tilt_functions(text: str) -> str:
    """The monitor with HealthMonitor._tilt_reference after every step (and its history ring,
    restart and reset).

    Parameters
    ----------
    text : str
        The monitor's C functions with the lost angles' references (``ep_hm_angle_refs``).
    """
    text = text.replace("    s->hm_tilt_tracked = 0;\n    s->hm_tilt_run = 0;\n",
                        "    if (s->hm_tilt_state) s->hm_tilt_state = 2;  /* its samples are gone */\n"
                        "    s->hm_tilt_clean = 0;\n"
                        "    s->hm_tilt_tracked = 0;\n    s->hm_tilt_run = 0;\n", 1)
    text = text.replace("    s->hm_last_time = EP_C(0.0);\n",
                        "    s->hm_last_time = EP_C(0.0);\n"
                        "    s->hm_tilt_state = s->hm_tilt_age = s->hm_tilt_clean = 0;\n"
                        "    s->hm_tilt_turn = EP_C(0.0);\n", 1)
    text = text.replace("    s->hm_tilt[row] = EP_MATH(hypot)(v[EP_HM_PITCH], v[EP_HM_ROLL]);\n",
                        "    s->hm_tilt[row] = EP_MATH(hypot)(v[EP_HM_PITCH], v[EP_HM_ROLL]);\n"
                        "    s->hm_house[row][0] = v[EP_HM_PITCH];\n"
                        "    s->hm_house[row][1] = v[EP_HM_ROLL];\n"
                        "    s->hm_house[row][2] = v[EP_HM_SLEW];\n", 1)
    text = text.replace("/* HealthMonitor.step: judge one finite", _C_TILT_REF + "\n/* HealthMonitor.step: judge one finite", 1)
    return text.replace("ep_hm_angle_refs(s);\n", "ep_hm_angle_refs(s);\n        ep_hm_tilt_ref(s);\n", 1) \
        .replace("    ep_hm_angle_refs(s);\n    return any;\n", "    ep_hm_angle_refs(s);\n    ep_hm_tilt_ref(s);\n    return any;\n", 1)


_C_TILT_REF = r"""
/* HealthMonitor._tilt_reference: when a tilt is first named, pitch and roll averaged over the
 * EP_HM_N_SUB samples ending EP_HM_TILT_BACK back (none of them named) and the slew rates summed
 * from that window's centre on; then each sample's slew rate added and its age counted */
static void ep_hm_tilt_ref(ep_state *s)
{
    int k, back, named = 0;
    for (k = 0; k < EP_N_FAULT_KINDS; ++k) named |= s->hm_age[EP_HM_PITCH][k] >= 0 || s->hm_age[EP_HM_ROLL][k] >= 0;
    if (!named) {
        s->hm_tilt_state = 0;
        if (s->hm_tilt_clean < EP_HM_CAP) s->hm_tilt_clean += 1;
        return;
    }
    if (s->hm_tilt_state == 0) {
        if (s->hm_count > EP_HM_TILT_BACK + EP_HM_N_SUB && s->hm_tilt_clean >= EP_HM_TILT_BACK + EP_HM_N_SUB) {
            ep_real pitch = EP_C(0.0), roll = EP_C(0.0), turn = EP_C(0.0);
            for (back = EP_HM_TILT_BACK + EP_HM_N_SUB - 1; back >= EP_HM_TILT_BACK; --back) {
                pitch += s->hm_house[EP_HM_SUM_AT(s, back)][0];
                roll += s->hm_house[EP_HM_SUM_AT(s, back)][1];
            }
            for (back = EP_HM_TILT_BACK + EP_HM_N_SUB - 1 - EP_HM_N_SUB / 2; back >= 0; --back)
                turn += s->hm_house[EP_HM_SUM_AT(s, back)][2];
            s->hm_tilt_ref[0] = pitch / (ep_real)EP_HM_N_SUB;
            s->hm_tilt_ref[1] = roll / (ep_real)EP_HM_N_SUB;
            s->hm_tilt_turn = turn;
            s->hm_tilt_state = 1;
        } else {
            s->hm_tilt_state = 2;
        }
        s->hm_tilt_age = 0;
    } else {
        s->hm_tilt_turn += s->hm_house[EP_HM_SUM_AT(s, 0)][2];
    }
    if (s->hm_tilt_age <= EP_HM_TILT_LIMIT) s->hm_tilt_age += 1;
    s->hm_tilt_clean = 0;
}
"""


def tilt_substitute(text: str) -> str:
    """The extended substitute with the named tilts (HealthMonitor._tilt_value): any kind.

    Parameters
    ----------
    text : str
        The extended ``ep_hm_substitute`` (pressures' joints, lost angles).
    """
    text = text.replace("            if (s->hm_age[i][k] < 0) continue;\n",
                        "            if (s->hm_age[i][k] < 0 || i == EP_HM_PITCH || i == EP_HM_ROLL) continue;  /* a tilt: any kind */\n", 1)
    return text.replace("        if (!named) continue;\n",
                        "        if (!named) continue;\n"
                        "        if (i == EP_HM_PITCH || i == EP_HM_ROLL) {  /* its value from before the fault */\n"
                        "            if (s->hm_tilt_state != 1 || s->hm_tilt_age > EP_HM_TILT_LIMIT\n"
                        "                || EP_MATH(hypot)(s->hm_tilt_ref[0], s->hm_tilt_ref[1])\n"
                        "                   * EP_MATH(fabs)(s->hm_tilt_turn * EP_HM_PERIOD) > EP_HM_TILT_OFFSET_LIMIT)\n"
                        "                return 0;\n"
                        "            out[i] = s->hm_tilt_ref[i == EP_HM_ROLL];\n"
                        "            continue;\n"
                        "        }\n", 1)


# HealthMonitor.newly_named_joints and CalibratedKernel.forget (a model that drops a pressure's joint)
C_FORGET = r"""
/* HealthMonitor.newly_named_joints: per joint (bit j) whether a signal named now and not after the
 * sample before concerns it: a pressure of EP_HM_DROP_JOINT its joint, any other signal every joint */
static unsigned int ep_hm_newly_named_joints(const ep_state *s)
{
    unsigned int joints = 0;
    int i, k;
    for (i = 0; i < EP_N_SIGNALS; ++i) {
        int named = 0;
        for (k = 0; k < EP_N_FAULT_KINDS; ++k) named |= s->hm_age[i][k] >= 0;
        if (!named || (s->hm_prev_named & EP_HM_BIT(i))) continue;
        joints |= EP_HM_DROP_JOINT[i] >= 0 ? 1u << EP_HM_DROP_JOINT[i] : 7u;
    }
    return joints;
}

/* HealthMonitor.cleared_joints: every joint when a signal named after the sample before is not
 * now and is not a pressure of EP_HM_DROP_JOINT (its substitute ends), else none */
static unsigned int ep_hm_cleared_joints(const ep_state *s)
{
    int i, k;
    for (i = 0; i < EP_N_SIGNALS; ++i) {
        int named = 0;
        for (k = 0; k < EP_N_FAULT_KINDS; ++k) named |= s->hm_age[i][k] >= 0;
        if (!named && (s->hm_prev_named & EP_HM_BIT(i)) && EP_HM_DROP_JOINT[i] < 0) return 7u;
    }
    return 0u;
}

/* CalibratedKernel.forget: these joints weigh no window over the samples the rings hold now */
static void ep_hm_forget(ep_state *s, unsigned int joints)
{
    int i, j;
    for (i = 0; i < EP_RING; ++i) s->ring_drop[i] = (unsigned char)(s->ring_drop[i] | joints);
    for (i = 0; i < EP_BALANCE; ++i)
        for (j = 0; j < 3; ++j)
            if (joints >> j & 1) s->terms_inside[i * 3 + j] = 0;
}

/* HealthMonitor.step, then Estimator.step_values' forget of the windows over a substitute's end */
static int ep_hm_step_forget(ep_state *s, ep_real time, const ep_real v[EP_N_SIGNALS])
{
    int any = ep_hm_step(s, time, v);
    unsigned int gone = ep_hm_cleared_joints(s);
    if (gone) ep_hm_forget(s, gone);
    return any;
}
"""
