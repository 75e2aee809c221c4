"""The C health monitor's slew-rate check (:meth:`HealthMonitor._slew_gain`,
:func:`~excavator_payload.estimators.health_slew.slew_gain_slope`): the slew rate against the slew
angle the house tilt's direction says, on a slope. Rendered into :func:`.health.health_c`'s text
for every export whose sensor set has the house's pitch, roll and slew rate.

Each sample's sines of pitch and roll, the tilt's direction and the slew rate are kept in
``hm_slew`` (a ring of ``EP_HM_SUMS`` rows beside the links' terms: the sines and the arctangent
once a sample, not once a window). The fit is summed in two passes over the window (means first,
then the centred sums), oldest sample first: equal to Python's to rounding.
"""

from __future__ import annotations

import math

from excavator_payload.estimators import health_slew as S
from excavator_payload.runtime.export_c.c_text import c_number

#: ``ep_state`` fields of the check (the house's ring, the check's run and wait)
SLEW_FIELDS = ("    ep_real hm_slew[EP_HM_SUMS][4];  /* sin pitch, sin roll, the tilt's direction, slew rate */\n"
               "    int hm_slew_run, hm_slew_wait;  /* evaluations beyond the limit; samples until judged */\n")


def slew_defines(m) -> str:
    """The check's constants.

    Parameters
    ----------
    m : HealthMonitor
        The monitor built for the export (the slew rate's column, the window, the period).
    """
    return (f"#define EP_HM_SLEW_RATE {m.slew}\n"
            f"#define EP_HM_SLEW_TILT_MIN2 {c_number(S.SLEW_TILT_MIN ** 2)}  /* least tilt size, squared */\n"
            f"#define EP_HM_SLEW_GAIN_LIMIT {c_number(S.SLEW_GAIN_LIMIT)}\n"
            f"#define EP_HM_SLEW_GAIN_EVALUATIONS {S.SLEW_GAIN_EVALUATIONS}\n"
            f"#define EP_HM_SLEW_ACCEL_HALF {S.SLEW_ACCEL_HALF}\n"
            f"#define EP_HM_SLEW_ACCEL_SPAN {c_number(2 * S.SLEW_ACCEL_HALF * m.period)}  /* s */\n"
            f"#define EP_HM_SLEW_MIN_INDEPENDENCE {c_number(S.SLEW_MIN_INDEPENDENCE)}\n"
            f"#define EP_HM_PI {c_number(math.pi)}\n")


def slew_functions(text: str) -> str:
    """The monitor's C functions with the slew check: the house's ring filled every sample, its
    wait counted down, the check on the fifth phase, and its restart.

    Parameters
    ----------
    text : str
        The monitor's C functions (``_C_FUNCTIONS`` of :mod:`.health`).
    """
    def once(old: str, new: str, where: str) -> None:
        nonlocal text
        if old not in text:
            raise AssertionError(f"health C: {where} has changed")
        text = text.replace(old, new, 1)

    once("    s->hm_tilt_tracked = 0;\n    s->hm_tilt_run = 0;\n",
         "    s->hm_tilt_tracked = 0;\n    s->hm_tilt_run = 0;\n    s->hm_slew_run = 0;\n    s->hm_slew_wait = 0;\n",
         "ep_hm_restart")
    once("    s->hm_tilt[row] = EP_MATH(hypot)(v[EP_HM_PITCH], v[EP_HM_ROLL]);\n",
         "    s->hm_tilt[row] = EP_MATH(hypot)(v[EP_HM_PITCH], v[EP_HM_ROLL]);\n"
         "    s->hm_slew[row][0] = EP_MATH(sin)(v[EP_HM_PITCH]);  /* health_slew.house_terms */\n"
         "    s->hm_slew[row][1] = EP_MATH(sin)(v[EP_HM_ROLL]);\n"
         "    s->hm_slew[row][2] = EP_MATH(atan2)(s->hm_slew[row][1], s->hm_slew[row][0]);\n"
         "    s->hm_slew[row][3] = v[EP_HM_SLEW_RATE];\n", "the step's per-sample terms")
    once("        if (s->hm_gain_wait[j] > 0) s->hm_gain_wait[j] -= 1;\n",
         "        if (s->hm_gain_wait[j] > 0) s->hm_gain_wait[j] -= 1;\n"
         "    if (s->hm_slew_wait > 0) s->hm_slew_wait -= 1;\n", "the gain waits")
    once("    else if (s->hm_phase == 3 && c >= EP_HM_N_SMOOTH && EP_HM_PITCH >= 0) ep_hm_tilt_offset(s, found);\n",
         "    else if (s->hm_phase == 3 && c >= EP_HM_N_SMOOTH && EP_HM_PITCH >= 0) ep_hm_tilt_offset(s, found);\n"
         "    else if (s->hm_phase == 4 && c >= EP_HM_N_GAIN) ep_hm_slew_gain(s, found);\n", "the stagger")
    once("/* HealthMonitor.step: judge one finite", _C_SLEW + "\n/* HealthMonitor.step: judge one finite", "ep_hm_step")
    return text


_C_SLEW = r"""
/* HealthMonitor._slew_gain's window not judged: the run starts again; a named scale error stays
 * named (below) */
static void ep_hm_slew_unjudged(ep_state *s, unsigned long found[EP_N_FAULT_KINDS])
{
    s->hm_slew_run = 0;
    if (s->hm_age[EP_HM_SLEW_RATE][EP_FAULT_GAIN] >= 0)
        found[EP_FAULT_GAIN] |= EP_HM_BIT(EP_HM_PITCH) | EP_HM_BIT(EP_HM_ROLL) | EP_HM_BIT(EP_HM_SLEW_RATE);
}

/* HealthMonitor._slew_gain (estimators/health_slew.py): over the last EP_HM_N_GAIN samples, the
 * slope of (theta - integrated slew rate) against theta, theta the slew angle the house tilt's
 * direction says, the IMU's leak term (sin roll * rate^2 + sin pitch * slew acceleration) / size^2
 * fitted beside it; judged while the tilt's size stays at least EP_HM_SLEW_TILT_MIN and theta
 * spreads; not while the slew rate or a tilt is named with another kind (nor until the window is
 * free of it). Names gain on the slew rate and both tilts, kept while no window is judged. */
static void ep_hm_slew_gain(ep_state *s, unsigned long found[EP_N_FAULT_KINDS])
{
    const int watched[3] = {EP_HM_PITCH, EP_HM_ROLL, EP_HM_SLEW_RATE};
    enum { M = EP_HM_N_GAIN - 2 * EP_HM_SLEW_ACCEL_HALF };
    ep_real sp[EP_HM_N_GAIN], sr[EP_HM_N_GAIN], size2[EP_HM_N_GAIN], rate[EP_HM_N_GAIN];
    ep_real theta[EP_HM_N_GAIN], turned[EP_HM_N_GAIN], x[M], y[M], z[M];  /* 14 kB of stack in double */
    ep_real mx = EP_C(0.0), my = EP_C(0.0), mz = EP_C(0.0), sxx = EP_C(0.0), szz = EP_C(0.0);
    ep_real sxz = EP_C(0.0), sxy = EP_C(0.0), szy = EP_C(0.0), den, slope, previous = EP_C(0.0);
    int i, k, row, broken = 0;
    for (i = 0; i < 3; ++i)
        for (k = 0; k < EP_N_FAULT_KINDS; ++k)
            if (k != EP_FAULT_GAIN && ((found[k] & EP_HM_BIT(watched[i])) || s->hm_age[watched[i]][k] >= 0)) broken = 1;
    if (broken) s->hm_slew_wait = EP_HM_N_GAIN;
    if (s->hm_slew_wait > 0) {
        s->hm_slew_run = 0;
        return;
    }
    for (i = 0, row = EP_HM_SUM_AT(s, EP_HM_N_GAIN - 1); i < EP_HM_N_GAIN; ++i) {  /* oldest first */
        const ep_real *h = s->hm_slew[row];
        ep_real direction = h[2];
        sp[i] = h[0];
        sr[i] = h[1];
        size2[i] = sp[i] * sp[i] + sr[i] * sr[i];
        if (!(size2[i] >= EP_HM_SLEW_TILT_MIN2)) {  /* the direction of a small tilt is noise */
            ep_hm_slew_unjudged(s, found);
            return;
        }
        rate[i] = h[3];
        if (i == 0) {
            theta[0] = turned[0] = EP_C(0.0);
        } else {
            ep_real step = direction - previous;
            step -= EP_C(2.0) * EP_HM_PI * EP_MATH(floor)((step + EP_HM_PI) / (EP_C(2.0) * EP_HM_PI));
            theta[i] = theta[i - 1] - step;
            turned[i] = turned[i - 1] + EP_HM_HALF_PERIOD * (rate[i] + rate[i - 1]);
        }
        previous = direction;
        if (++row == EP_HM_SUMS) row = 0;
    }
    for (i = 0; i < M; ++i) {
        int j = i + EP_HM_SLEW_ACCEL_HALF;
        ep_real accel = (rate[j + EP_HM_SLEW_ACCEL_HALF] - rate[j - EP_HM_SLEW_ACCEL_HALF]) / EP_HM_SLEW_ACCEL_SPAN;
        x[i] = theta[j];
        y[i] = x[i] - turned[j];
        z[i] = (sr[j] * (rate[j] * rate[j]) + sp[j] * accel) / size2[j];
        mx += x[i];
        my += y[i];
        mz += z[i];
    }
    mx /= (ep_real)M;
    my /= (ep_real)M;
    mz /= (ep_real)M;
    for (i = 0; i < M; ++i) {
        ep_real dx = x[i] - mx, dy = y[i] - my, dz = z[i] - mz;
        sxx += dx * dx;
        szz += dz * dz;
        sxz += dx * dz;
        sxy += dx * dy;
        szy += dz * dy;
    }
    if (sxx / (ep_real)M < EP_HM_GAIN_MIN_VAR) {  /* the house hardly slewed */
        ep_hm_slew_unjudged(s, found);
        return;
    }
    den = sxx * szz - sxz * sxz;
    slope = (szz > EP_C(0.0) && den > EP_HM_SLEW_MIN_INDEPENDENCE * sxx * szz) ? (szz * sxy - sxz * szy) / den : sxy / sxx;
    s->hm_slew_run = EP_MATH(fabs)(slope) > EP_HM_SLEW_GAIN_LIMIT
                     ? (s->hm_slew_run < EP_HM_CAP ? s->hm_slew_run + 1 : EP_HM_CAP) : 0;
    if (s->hm_slew_run >= EP_HM_SLEW_GAIN_EVALUATIONS)
        found[EP_FAULT_GAIN] |= EP_HM_BIT(EP_HM_PITCH) | EP_HM_BIT(EP_HM_ROLL) | EP_HM_BIT(EP_HM_SLEW_RATE);
}
"""
