"""Static C text of the C export and the helpers that write Python values as C.

The fragments here are written once and shared by the kernels' builders: constants and
constant arrays (:func:`c_number`, :func:`c_array`), the networks' tanh layer
(:data:`TANH_LAYER_C`), the networks' filling of gate-rejected slots
(:func:`interpolate_rejected_c`) and the machine kernels' one-frame outlier test
(:func:`one_frame_glitch_c`).
"""

from __future__ import annotations

import math
import re

import numpy as np

#: Maths functions the generated code may call (mapped to their float variants in single).
MATH_FUNCTIONS = ("sin", "cos", "tan", "asin", "acos", "atan", "atan2", "sinh", "cosh", "tanh",
                  "exp", "log", "sqrt", "fabs", "pow", "floor", "ceil", "fmin", "fmax", "erf")

#: The hidden layer of every exported network (net1/ffnn and net2 share it).
TANH_LAYER_C = """
/* a_out = tanh(W a_in + b), W row-major (rows x cols) */
static void ep_tanh_layer(const ep_real *W, const ep_real *b, int rows, int cols,
                          const ep_real *a_in, ep_real *a_out)
{
    int r, c;
    for (r = 0; r < rows; ++r) {
        ep_real z = b[r];
        const ep_real *w = W + r * cols;
        for (c = 0; c < cols; ++c) z += w[c] * a_in[c];
        a_out[r] = EP_MATH(tanh)(z);
    }
}"""


def c_number(value: float, cast: bool = True) -> str:
    """A constant as C text at full double precision.

    Parameters
    ----------
    value : float
        The number (NaN and ±inf become ``EP_NAN``/``EP_INF``).
    cast : bool
        Wrap it in ``EP_C`` (an ``ep_real``: a float constant in single precision); False
        leaves a double constant.

    Returns
    -------
    str
        The C expression.
    """
    value = float(value)
    if math.isnan(value):
        return "EP_NAN"
    if math.isinf(value):
        return "EP_INF" if value > 0 else "(-EP_INF)"
    text = repr(value)
    if "e" not in text and "." not in text:
        text += ".0"
    return f"EP_C({text})" if cast else text


def c_array(name: str, values, per_line: int = 4, kind: str = "static const ep_real") -> str:
    """A constant array definition.

    Parameters
    ----------
    name : str
        The C name of the array.
    values : array_like
        Its values (flattened in C order).
    per_line : int
        Values on each line of the text.
    kind : str
        The declaration before the name; with ``double`` in it the constants are doubles.

    Returns
    -------
    str
        The definition, ending in a newline.
    """
    values = np.asarray(values, dtype=float).ravel()
    if values.size == 0:
        raise ValueError(f"{name}: empty array")
    items = [c_number(v, cast="double" not in kind) for v in values]
    lines = [", ".join(items[i:i + per_line]) for i in range(0, len(items), per_line)]
    body = ",\n    ".join(lines)
    return f"{kind} {name}[{values.size}] = {{\n    {body}\n}};\n"


def c_identifier(text: str) -> str:
    """``text`` with every character that may not appear in a C identifier replaced by ``_``.

    Parameters
    ----------
    text : str
        An estimator's name, say.
    """
    return re.sub(r"\W", "_", text)


def interpolate_rejected_c() -> str:
    """Body of ``ep_model_fill_rejected``: ``Estimator._interpolate_rejected``."""
    return """    /* Estimator._interpolate_rejected: the rejected samples' slots are stepped with values
     * interpolated between the last used sample and this one (a delay line stays evenly
     * spaced); their results are not reported. rint rounds half to even, as Python's round. */
    ep_real slot[EP_N_SIGNALS], ignored, slots, w;
    int i, k, missing;
    if (!s->has_last_used) return;
    slots = EP_MATH(rint)((time - s->last_used_time) / EP_SAMPLE_PERIOD) - EP_C(1.0);
    if (!(slots >= EP_C(1.0))) return;
    if (slots > EP_MAX_CONSECUTIVE_REJECTIONS) slots = EP_MAX_CONSECUTIVE_REJECTIONS;
    missing = (int)slots;
    for (k = 1; k <= missing; ++k) {
        w = (ep_real)k / (ep_real)(missing + 1);
        for (i = 0; i < EP_N_SIGNALS; ++i) slot[i] = s->last_used[i] + w * (v[i] - s->last_used[i]);
        (void)ep_model_step(s, s->last_used_time + (ep_real)k * EP_SAMPLE_PERIOD, slot, &ignored);
    }"""


def one_frame_glitch_c(gating: bool, thresholds) -> list[str]:
    """C lines of ``pressure_regression.judge_frame``: ``EP_GATING`` (overridable with
    ``-DEP_GATING=0``, as ``Estimator.gating = False``), the thresholds and ``ep_spike``.

    Parameters
    ----------
    gating : bool
        The estimator's ``gating`` (the default of ``EP_GATING``).
    thresholds : array_like
        Per-signal thresholds of the sample-to-sample change (``EP_SPIKE_THRESHOLD``).
    """
    return [
        "#ifndef EP_GATING",
        f"#define EP_GATING {1 if gating else 0}",
        "#endif",
        c_array("EP_SPIKE_THRESHOLD", thresholds).rstrip(),
        "",
        "/* pressure_regression.judge_frame: 0 clean, 1 stands out (never regressed), 2 a glitch",
        " * (reported); before2 / after2 may be NULL (not known) */",
        "static int ep_spike(const ep_real *before2, const ep_real *before, const ep_real *mid,",
        "                    const ep_real *after, const ep_real *after2)",
        "{",
        "    int i, out = 0;",
        "    for (i = 0; i < EP_N_SIGNALS; ++i) {",
        "        ep_real d1 = mid[i] - before[i], d2 = mid[i] - after[i], off;",
        "        ep_real smaller = EP_MATH(fabs)(d1) < EP_MATH(fabs)(d2) ? EP_MATH(fabs)(d1) : EP_MATH(fabs)(d2);",
        "        if (!(d1 * d2 > EP_C(0.0) && smaller > EP_SPIKE_THRESHOLD[i]",
        "              && smaller > EP_MATH(fabs)(after[i] - before[i]))) continue;  /* stands out more",
        "                                                                         * than its neighbours differ */",
        "        out = 1;",
        "        if (before2) {  /* off the line through the two samples before it, the same way */",
        "            off = mid[i] - (EP_C(2.0) * before[i] - before2[i]);",
        "            if (!(off * d1 > EP_C(0.0) && EP_MATH(fabs)(off) > EP_SPIKE_THRESHOLD[i])) continue;",
        "        }",
        "        if (after2) {  /* ... and off the line through the two after it */",
        "            off = mid[i] - (EP_C(2.0) * after[i] - after2[i]);",
        "            if (!(off * d1 > EP_C(0.0) && EP_MATH(fabs)(off) > EP_SPIKE_THRESHOLD[i])) continue;",
        "        }",
        "        return 2;",
        "    }",
        "    return out;",
        "}",
    ]
