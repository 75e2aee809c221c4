r"""``excavator-payload export --format c``: a trained estimator as one C99 ``.c``/``.h`` pair.

Every exported model has the same interface (the header documents it)::

    #define EP_N_SIGNALS ...            /* inputs, in the sensor set's column order */
    extern const char *const EP_SIGNAL_NAMES[EP_N_SIGNALS];
    typedef struct { ... } ep_state;    /* fixed size */
    void ep_reset(ep_state *s);
    int  ep_step(ep_state *s, ep_real time, const ep_real signals[EP_N_SIGNALS],
                 ep_real *estimate);    /* a status code, 0 = ok, as the Status enum */
    ep_real ep_sigma(const ep_state *s);  /* one-sigma uncertainty of that estimate, kg */

Rules: C99, no heap (work arrays live on the stack of ``ep_step``), nothing beyond
``<math.h>``, no warning under ``-std=c99 -Wall -Wextra -Werror -pedantic``. ``ep_real`` is
``double``, or ``float`` when compiled with ``-DEP_SINGLE=1`` (the default of an export with
``--precision float32``); in single precision every constant is a ``float`` and the maths
functions are the ``f`` variants, so a single-precision FPU never touches a double.

What is generated from what
---------------------------
* ``EP_N_SIGNALS``, ``EP_SIGNAL_NAMES``: the estimator's sensor set.
* ``EP_STATUS_*``: :class:`~excavator_payload.estimators.base.Status` in its order.
* ``ep_step`` is :meth:`Estimator.step_values` (base.py) line by line: non-finite input ->
  ``invalid_input``; a signal outside the fitted estimator's plausibility limits (its
  ``plausible_low``/``plausible_high``, emitted as two constant tables) -> ``out_of_range``;
  a time step <= 0 or > 1.5 sample periods (or gate-rejected samples just before) -> the
  model's gap handling; the statistical gate (``EP_GATING``, default
  ``Estimator.gating``): the model's normalised squared innovation against the chi-square
  quantile of :data:`~excavator_payload.estimators.base.GATE_PROBABILITY` (computed with scipy
  at export time by :func:`~excavator_payload.estimators.base.gate_threshold`), times a gate
  width that follows :data:`GATE_SCALE_RATE`/:data:`GATE_SCALE_HEADROOM`, ->
  ``rejected_outlier``, and after :func:`~excavator_payload.estimators.base.max_consecutive_rejections` in a row a restart,
  ``reinitialised``; a state that is no longer finite -> restart, ``state_reset``. A sample
  not used returns the last estimate and sigma. ``ep_sigma`` is ``StepResult.sigma``.
* ``inverse-dynamics``, ``calibrated``: the per-sample information terms
  (:func:`~excavator_payload.estimators.classical.inverse_dynamics.information_terms`, the very
  function Python steps with, evaluated on CasADi symbols) and the gate's
  :func:`~excavator_payload.estimators.classical.inverse_dynamics.residual_nis` are generated
  by CasADi's C code generator; the recursive least-squares update around them is written
  once here.
* ``inverse-dynamics`` and ``calibrated`` fitted on the *machine* sensor set (pressures + IMUs):
  the kernel :class:`~excavator_payload.estimators.classical.pressure_regression.PressureRegression`
  (``calibrated``: ``calibrated_machine.CalibratedKernel``). One sample of the weighing
  regression is CasADi's code of ``HydraulicSymbolic.functions["pressure_regression"]`` with the
  fitted parameter vector as constants, behind the kernel's sensor correction (``calibrated``:
  ``calibrated_machine._corrected_signals`` with the identified offsets and IMU dynamics as
  constants; ``inverse-dynamics``: the ground tilt from the house IMU); the ring buffer of
  ``2·half_window + 1`` samples, the centred least-squares slope of the rates, the weights and
  ``--low-speed`` rule, the recursive sums, status, sigma and gap rule (a short gap restarts
  the window) are ported here (``calibrated --balance momentum``: one sample's momentum-balance
  terms from ``HydraulicSymbolic.functions["momentum_regression"]``, and a second ring holding
  the balance's window), and so is the kernels' one-frame outlier test in place of the
  chi-square gate (``pressure_regression``: the sample before the newest judged between its
  neighbours against per-signal thresholds from the fit data, its slot repaired and never
  regressed, ``rejected_outlier``; ``-DEP_GATING=0`` turns it off).
* ``ekf`` fitted on the machine sensor set: one step of
  :class:`~excavator_payload.estimators.classical._kalman_machine.MachineKalman` (update with
  angles and rates, update with the piston forces of ``force_measurement_symbolic`` with the
  machine's parameters as constants, low-speed rule, payload clamp, white-jerk prediction) is
  one CasADi-generated function (:func:`_machine_ekf_functions`); initialisation, status and
  gap bridging are written here. No gate (none in Python on this set).
* ``ekf``: the whole filter step (update + prediction) is CasADi's code of
  :func:`~excavator_payload.estimators.classical._kalman.ekf_step_symbolic`, built from the
  symbolic arm model, and so is its gate
  (:func:`~excavator_payload.estimators.classical._kalman.gate_symbolic`); initialisation,
  clamping, status and gap bridging are written here, mirroring
  :mod:`~excavator_payload.estimators.classical.ekf`. The float build computes the whole step
  in float with an equivalent step (:func:`_ekf_single_functions`: the measurement updates as
  sequential scalar Joseph updates of whitened measurements, no ill-conditioned matrix solve).
* The borrowed gate (base.py, :meth:`Estimator._borrows_gate`): an estimator without a noise
  model of its own (``net1``/``ffnn``/``net2``, ``ekf`` with the thesis tuning) or one that
  believes another machine than its training data's (``calibrated`` on a wrong machine) is
  judged by its sentinel, inverse-dynamics least squares on the training data's machine and
  noise. The C runs the sentinel beside the model (``ep_gate_step``, information form) with its
  base parameters and sensor variances as constant arrays, and CasADi generates its
  :func:`~excavator_payload.estimators.classical.inverse_dynamics.information_terms` and
  :func:`~excavator_payload.estimators.classical.inverse_dynamics.residual_nis` (2 degrees of
  freedom) from those very functions; like the Python sentinel (never stepped through
  ``step_values``, so it keeps no time) it restarts on every gap and on a re-initialisation.
  The sentinel computes in ``ep_real``.
* ``Estimator._on_skip``/``_fill_rejected``: before the sample after gate-rejected ones the
  model bridges the hole like a gap (filters, least squares), or, for the networks, does
  nothing and, once that sample is accepted, steps the rejected slots (at most
  :func:`~excavator_payload.estimators.base.max_consecutive_rejections`) with values interpolated between the last used sample
  and this one (``Estimator._interpolate_rejected``), so their delay lines stay evenly spaced.
* ``net1``/``ffnn``/``net2``: their sigma is the constant RMS validation error the fit
  measured (``residual_std``).
* ``net1`` (and ``ffnn``): weights as constant arrays, the input scaling folded into the first
  layer and the output scaling into the last (as the Python streaming code does), the delay
  line a doubled ring buffer in the state.
* ``net2``: weights as constant arrays, input scaling, the input delay line and the fed-back
  estimates in the state (as :class:`~excavator_payload.estimators.dvs.recurrent.RecurrentStepper`).
"""

from __future__ import annotations

import math
import os
import re
import textwrap
from dataclasses import dataclass, field
from pathlib import Path

import casadi as ca
import numpy as np

from excavator_payload import __version__
from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.base import (
    GATE_PROBABILITY,
    PLAUSIBLE_PAYLOAD,
    GATE_SCALE_HEADROOM,
    GATE_SCALE_RATE,
    Estimator,
    Status,
    gate_threshold,
    max_consecutive_rejections,
    plausibility_limits,
)
from excavator_payload.runtime.exportable import (
    C_EXPORTABLE,
    C_EXPORTABLE_MACHINE,
    per_sample_refusal,
)

#: Maths functions the generated code may call (mapped to their float variants in single).
MATH_FUNCTIONS = ("sin", "cos", "tan", "asin", "acos", "atan", "atan2", "sinh", "cosh", "tanh",
                  "exp", "log", "sqrt", "fabs", "pow", "floor", "ceil", "fmin", "fmax", "erf")


# -- C text helpers ---------------------------------------------------------------------------------

#: The hidden layer of every exported network (net1/ffnn and net2 share it).
_TANH_LAYER_C = """
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
    """A constant as C text: full double precision, cast to ep_real (float constant in single)
    unless ``cast`` is False (a double constant)."""
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
    """A constant array definition (``kind`` with ``double``: double constants)."""
    values = np.asarray(values, dtype=float).ravel()
    if values.size == 0:
        raise ValueError(f"{name}: empty array")
    items = [c_number(v, cast="double" not in kind) for v in values]
    lines = [", ".join(items[i:i + per_line]) for i in range(0, len(items), per_line)]
    body = ",\n    ".join(lines)
    return f"{kind} {name}[{values.size}] = {{\n    {body}\n}};\n"


def c_identifier(text: str) -> str:
    """``text`` with every character that may not appear in a C identifier replaced by ``_``."""
    return re.sub(r"\W", "_", text)


def casadi_c_code(functions: dict[str, ca.Function], real: str = "ep_real") -> str:
    """CasADi's generated C for ``functions`` (C name -> Function), trimmed to what we need.

    Keeps the evaluation functions (renamed to the given names, ``static``) and the helpers
    they call; drops CasADi's public API (memory management, sparsity tables, names), so the
    result compiles without warnings under our flags and exports no symbol. Types become
    ``real``/``ep_int``; with ``real="ep_real"`` maths calls go through ``EP_MATH`` (float
    variants in single precision), with ``real="double"`` they stay double.
    """
    generator = ca.CodeGenerator("ep_generated.c", {"with_header": False, "verbose": False})
    order = list(functions)
    for name in order:
        generator.add(functions[name])
    source = generator.dump()
    blocks = _top_level_blocks(source)
    kept = []
    for head, text in blocks:
        m = re.match(r"static int casadi_f(\d+)\(", head)
        if m:
            index = int(m.group(1))
            body_start = text.index("{") + 1
            text = (text[:body_start] + "\n  (void)iw; (void)w; (void)mem;" + text[body_start:])
            text = text.replace(f"casadi_f{index}(", f"{order[index]}(", 1)
            kept.append(text)
        elif re.match(r"(casadi_real|casadi_int|void|int) casadi_[a-z]\w*\(", head) and \
                not re.match(r"\w+ casadi_f\d+\(", head):
            kept.append("static " + text)
    code = "\n\n".join(kept)
    code = re.sub(r"\bcasadi_real\b", real, code)
    code = re.sub(r"\bcasadi_int\b", "ep_int", code)
    code = re.sub(r"\bcasadi_(?!f\d)(\w+)\(", r"ep_cas_\1(", code)
    if real == "ep_real":
        code = re.sub(r"(?<![\w.])(" + "|".join(MATH_FUNCTIONS) + r")\(", r"EP_MATH(\1)(", code)
        # floating-point literals become ep_real constants (a float build does no double maths)
        code = re.sub(r"(?<![\w.])(\d+\.\d*(?:e[+-]?\d+)?|\d+e[+-]?\d+)(?![\w.])", r"EP_C(\1)", code)
    if "casadi_" in code:
        leftover = sorted(set(re.findall(r"casadi_\w+", code)))
        raise EstimatorError(f"unexpected CasADi symbols in generated code: {leftover[:5]}")
    return code


def _top_level_blocks(source: str) -> list[tuple[str, str]]:
    """Function definitions at file level: ``(first line, full text)``, by brace matching."""
    blocks = []
    lines = source.splitlines()
    i = 0
    while i < len(lines):
        line = lines[i]
        if re.match(r"(static )?(casadi_real|casadi_int|int|void|const \w+\*?) \**\w+\(.*\)\s*\{", line):
            depth = 0
            chunk = []
            while True:
                chunk.append(lines[i])
                depth += lines[i].count("{") - lines[i].count("}")
                if depth <= 0:
                    break
                i += 1
            blocks.append((line, "\n".join(chunk)))
        i += 1
    return blocks


def casadi_call(name: str, function: ca.Function, inputs: list[str], outputs: list[str],
                code: str, real: str = "ep_real") -> str:
    """C statements calling generated function ``name`` with stack work arrays (sized as CasADi
    says, or 1 element where the generated ``code`` keeps everything in local variables)."""
    sz_arg, sz_res = function.sz_arg(), function.sz_res()
    uses_iw = re.search(r"(?<![\w])iw\s*[\[+]", code) is not None
    uses_w = re.search(r"(?<![\w])w\s*[\[+]", code) is not None
    sz_iw = max(function.sz_iw(), 1) if uses_iw else 1
    sz_w = max(function.sz_w(), 1) if uses_w else 1
    lines = ["{",
             f"    const {real} *arg[{sz_arg}];",
             f"    {real} *res[{sz_res}];",
             f"    ep_int iw[{sz_iw}];",
             f"    {real} w[{sz_w}];"]
    for k, expr in enumerate(inputs):
        lines.append(f"    arg[{k}] = {expr};")
    for k in range(len(inputs), sz_arg):
        lines.append(f"    arg[{k}] = 0;")
    for k, expr in enumerate(outputs):
        lines.append(f"    res[{k}] = {expr};")
    for k in range(len(outputs), sz_res):
        lines.append(f"    res[{k}] = 0;")
    lines.append(f"    {name}(arg, res, iw, w, 0);")
    lines.append("}")
    return "\n".join("    " + ln for ln in lines)


# -- the model parts -------------------------------------------------------------------------------
@dataclass
class CModel:
    """The model-specific parts of an export (the rest is the common template)."""

    description: str
    state_fields: list[str]          # C declarations inside ep_state
    definitions: str                 # constants, generated code, helper functions
    reset: str                       # body of ep_model_reset(ep_state *s)
    step: str                        # body of ep_model_step(s, time, v, estimate) -> status
    on_gap: str | None = None        # body of ep_model_on_gap(s, time, v); None: reset
    header_defines: list[str] = field(default_factory=list)  # sizes the state struct needs
    sigma: str = "    (void)s;\n    return EP_NAN;"  # body of ep_model_sigma(s): Estimator._estimate_sigma
    state_finite: str = "    (void)s;\n    return 1;"  # body of ep_model_state_finite(s)
    #: Body of ep_model_innovation(s, time, v, &nis) -> 1 with the normalised squared innovation
    #: written, 0 for none (Estimator._innovation), and its degrees of freedom; None: no gate.
    innovation: str | None = None
    gate_dof: int = 0
    #: Body of ep_model_on_skip(s, time, v), before the sample after gate-rejected ones
    #: (Estimator._on_skip); None: the gap handling, as the base class.
    on_skip: str | None = None
    #: Body of ep_model_fill_rejected(s, time, v), once a sample is accepted after rejected
    #: ones (Estimator._fill_rejected); None: nothing. Needs the last used sample in the state.
    fill_rejected: str | None = None
    #: Whether the gate is borrowed (Estimator._sentinel): ep_gate_reset/ep_gate_step exist.
    borrowed_gate: bool = False


@dataclass
class BorrowedGate:
    """The C of an estimator's borrowed gate (base.py, ``Estimator._sentinel``): inverse-dynamics
    least squares on the training data's machine and noise, run beside the model only to judge
    its samples. ``functions`` go into the model's one CasADi code generation (so the helpers
    are emitted once); :meth:`apply` adds the rest to the model."""

    functions: dict[str, ca.Function]
    real: str
    definitions: str
    innovation_call: ca.Function

    def apply(self, model: CModel, code: str) -> None:
        """Add the gate to ``model`` in place: its state fields, ``ep_gate_reset`` and
        ``ep_gate_step``, and the innovation body that judges samples by the gate's residual NIS.
        ``code`` is the CasADi-generated C the calls are sized against (:func:`casadi_call`)."""
        real = self.real
        zero = "0.0" if real == "double" else "EP_C(0.0)"
        one = "1.0" if real == "double" else "EP_C(1.0)"
        model.state_fields += [f"{real} gate_num;   /* borrowed gate (inverse dynamics): N */",
                               f"{real} gate_info;  /* borrowed gate: I */"]
        terms = self.functions["ep_gate_information_terms"]
        model.definitions += "\n".join([
            "",
            "/* The borrowed gate (base.py, Estimator._borrows_gate): this model has no noise model of",
            " * its own, so inverse-dynamics least squares on the training data's machine and noise",
            " * preset runs beside it (information form, as InverseDynamicsEstimator._step) and judges",
            " * each sample by its residual_nis; generated by CasADi above. */",
            self.definitions,
            "",
            "static void ep_gate_reset(ep_state *s)",
            "{",
            f"    s->gate_num = {zero};",
            f"    s->gate_info = {zero};",
            "}",
            "",
            "/* InverseDynamicsEstimator._step of the sentinel (its estimate is not reported) */",
            "static void ep_gate_step(ep_state *s, const ep_real v[EP_N_SIGNALS])",
            "{",
            f"    {real} gv[EP_N_SIGNALS], m_w, terms[2];",
            "    int i;",
            f"    for (i = 0; i < EP_N_SIGNALS; ++i) gv[i] = ({real})v[i];",
            f"    if (s->gate_info > {zero}) {{  /* weights use the current estimate, kept physical */",
            "        m_w = s->gate_num / s->gate_info;",
            f"        if (m_w < {zero}) m_w = {zero};",
            "        if (m_w > EP_GATE_MAX_PAYLOAD) m_w = EP_GATE_MAX_PAYLOAD;",
            "    } else {",
            "        m_w = EP_GATE_DEFAULT_WEIGHT_PAYLOAD;",
            "    }",
            casadi_call("ep_gate_information_terms", terms,
                        ["gv", "EP_GATE_THETA_EMPTY", "EP_GATE_THETA_PAYLOAD", "EP_GATE_VARIANCES", "&m_w"],
                        ["terms"], code, real=real),
            "    s->gate_num = EP_GATE_FORGETTING * s->gate_num + terms[0];",
            "    s->gate_info = EP_GATE_FORGETTING * s->gate_info + terms[1];",
            "}",
        ])
        nis_call = casadi_call("ep_gate_residual_nis", self.innovation_call,
                               ["gv", "EP_GATE_THETA_EMPTY", "EP_GATE_THETA_PAYLOAD", "EP_GATE_VARIANCES",
                                "&payload", "&payload_var"], ["&value"], code, real=real)
        model.innovation = f"""    /* Estimator._gate_innovation, borrowed: the sentinel's residual_nis at its current
     * estimate (kept physical) with that estimate's variance 1/I; none before any information */
    {real} gv[EP_N_SIGNALS], payload, payload_var, value;
    int i;
    (void)time;
    if (s->gate_info <= {zero}) return 0;
    for (i = 0; i < EP_N_SIGNALS; ++i) gv[i] = ({real})v[i];
    payload = s->gate_num / s->gate_info;
    if (payload < {zero}) payload = {zero};
    if (payload > EP_GATE_MAX_PAYLOAD) payload = EP_GATE_MAX_PAYLOAD;
    payload_var = {one} / s->gate_info;
{nis_call}
    *nis = (ep_real)value;
    return 1;"""
        model.gate_dof = 2
        model.borrowed_gate = True


def _borrowed_gate(est, real: str = "ep_real") -> BorrowedGate | None:
    """The C parts of ``est``'s borrowed gate, or None when it judges samples itself (or not at
    all). ``real``: the type the sentinel computes in (the EKF's ``double``, else ``ep_real``)."""
    sentinel = getattr(est, "_sentinel", None)
    if sentinel is None:
        return None
    from excavator_payload.estimators.classical.inverse_dynamics import information_terms, residual_nis

    n = len(est.sensor_set.signals)
    theta_empty = np.asarray(sentinel.theta_empty, dtype=float)
    theta_payload = np.asarray(sentinel.theta_payload, dtype=float)
    variances = np.asarray(sentinel.variances, dtype=float)
    v = ca.SX.sym("v", n)
    th0 = ca.SX.sym("theta_empty", theta_empty.size)
    th1 = ca.SX.sym("theta_payload", theta_payload.size)
    var = ca.SX.sym("variances", variances.size)
    m_w, payload, payload_var = ca.SX.sym("m_w"), ca.SX.sym("payload"), ca.SX.sym("payload_var")
    vs, th0s, th1s, vars_ = ([x[i] for i in range(x.numel())] for x in (v, th0, th1, var))
    d_num, d_info = information_terms(vs, th0s, th1s, vars_, m_w, sentinel.options["weighting"],
                                      bool(sentinel.options["eiv_correction"]), trig=ca)
    terms = ca.Function("ep_gate_information_terms", [v, th0, th1, var, m_w],
                        [ca.cse(ca.vertcat(d_num, d_info))])
    nis = residual_nis(vs, th0s, th1s, vars_, payload, payload_var, trig=ca)
    nis_fn = ca.Function("ep_gate_residual_nis", [v, th0, th1, var, payload, payload_var], [ca.cse(nis)])
    cast = real != "double"
    max_payload = float(sentinel.machine.max_payload)
    kind = f"static const {real}"
    definitions = "\n".join([
        f"/* sentinel: machine {sentinel.machine.name}, noise {sentinel.noise_name} */",
        c_array("EP_GATE_THETA_EMPTY", theta_empty, kind=kind).rstrip(),
        c_array("EP_GATE_THETA_PAYLOAD", theta_payload, kind=kind).rstrip(),
        c_array("EP_GATE_VARIANCES", variances, kind=kind).rstrip(),
        f"#define EP_GATE_FORGETTING {c_number(sentinel.options['forgetting'], cast)}",
        f"#define EP_GATE_MAX_PAYLOAD {c_number(max_payload, cast)}",
        f"#define EP_GATE_DEFAULT_WEIGHT_PAYLOAD {c_number(0.5 * max_payload, cast)}",
    ])
    return BorrowedGate({"ep_gate_information_terms": terms, "ep_gate_residual_nis": nis_fn},
                        real, definitions, nis_fn)


def _interpolate_rejected() -> str:
    """Body of ep_model_fill_rejected: ``Estimator._interpolate_rejected``."""
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


def _network_gate(est, model: CModel) -> CModel:
    """A network's borrowed gate (NeuralEstimator: rejected slots interpolated, no bridging)."""
    gate = _borrowed_gate(est)
    if gate is None:
        return model
    code = casadi_c_code(gate.functions)
    model.definitions = code + "\n\n" + model.definitions
    gate.apply(model, code)
    model.on_skip = "    /* NeuralEstimator._on_skip: nothing; see ep_model_fill_rejected */\n" \
                    "    (void)s;\n    (void)time;\n    (void)v;"
    model.fill_rejected = _interpolate_rejected()
    return model


def _inverse_dynamics_model(est) -> CModel:
    from excavator_payload.estimators.classical.inverse_dynamics import (
        MAX_BRIDGED_GAP,
        information_terms,
        residual_nis,
    )

    n = len(est.sensor_set.signals)
    v = ca.SX.sym("v", n)
    m_w = ca.SX.sym("m_w")
    d_num, d_info = information_terms(
        [v[i] for i in range(n)], [float(x) for x in est.theta_empty],
        [float(x) for x in est.theta_payload], [float(x) for x in est.variances], m_w,
        est.options["weighting"], bool(est.options["eiv_correction"]), trig=ca)
    terms = ca.Function("ep_information_terms", [v, m_w], [ca.cse(ca.vertcat(d_num, d_info))],
                        ["v", "m_w"], ["terms"])
    payload, payload_var = ca.SX.sym("payload"), ca.SX.sym("payload_var")
    nis = residual_nis([v[i] for i in range(n)], [float(x) for x in est.theta_empty],
                       [float(x) for x in est.theta_payload], [float(x) for x in est.variances],
                       payload, payload_var, trig=ca)
    nis_fn = ca.Function("ep_residual_nis", [v, payload, payload_var], [ca.cse(nis)],
                         ["v", "payload", "payload_var"], ["nis"])
    lam = float(est.options["forgetting"])
    warm_info = 1.0 / float(est.options["warmup_std"]) ** 2
    max_payload = float(est.machine.max_payload)
    gate = _borrowed_gate(est)
    functions = {"ep_information_terms": terms}
    if gate is None:
        functions["ep_residual_nis"] = nis_fn
    else:  # it believes another machine than its data's: the data's physics judges them
        functions.update(gate.functions)
    code = casadi_c_code(functions)
    definitions = "\n".join([
        "/* Information terms (dN, dI) of one sample, generated by CasADi from",
        " * inverse_dynamics.information_terms (weighted, errors-in-variables corrected):",
        " *   dN = phi' W r + tr(Jphi' W J0 Sx),  dI = phi' W phi - tr(Jphi' W Jphi Sx);",
        " * and the gate's normalised squared torque residual from inverse_dynamics.residual_nis:",
        " *   r' (R + phi phi' sigma_m^2)^-1 r,  r = tau - tau0 - m phi. */",
        code,
        "",
        f"#define EP_FORGETTING {c_number(lam)}          /* lambda */",
        f"#define EP_WARM_INFO {c_number(warm_info)}      /* 1 / warmup_std^2 */",
        f"#define EP_MAX_PAYLOAD {c_number(max_payload)}",
        f"#define EP_DEFAULT_WEIGHT_PAYLOAD {c_number(0.5 * max_payload)}",
        f"#define EP_MAX_BRIDGED_GAP {c_number(MAX_BRIDGED_GAP)}  /* s: a longer gap restarts */",
    ])
    innovation = f"""    /* InverseDynamicsEstimator._innovation: residual_nis at the current estimate (kept
     * physical) with the estimate's variance 1/I; none before any information */
    ep_real payload, payload_var;
    (void)time;
    if (s->info <= EP_C(0.0)) return 0;
    payload = s->num / s->info;
    if (payload < EP_C(0.0)) payload = EP_C(0.0);
    if (payload > EP_MAX_PAYLOAD) payload = EP_MAX_PAYLOAD;
    payload_var = EP_C(1.0) / s->info;
{casadi_call("ep_residual_nis", nis_fn, ["v", "&payload", "&payload_var"], ["nis"], code)}
    return 1;"""
    on_gap = """    /* InverseDynamicsEstimator._on_gap: samples are independent equations, a short gap keeps
     * the sums; a long one (or time going back) restarts */
    ep_real dt = time - s->last_time;
    (void)v;
    if (!s->has_last_time || !(EP_C(0.0) < dt && dt <= EP_MAX_BRIDGED_GAP)) ep_model_reset(s);"""
    step = f"""    /* InverseDynamicsEstimator._step: information-form recursive least squares
     *   N_k = lambda N_(k-1) + dN_k,  I_k = lambda I_(k-1) + dI_k,  m_k = N_k / I_k */
    ep_real m_w, terms[2];
    if (s->info > EP_C(0.0)) {{  /* weights use the current estimate, kept physical */
        m_w = s->num / s->info;
        if (m_w < EP_C(0.0)) m_w = EP_C(0.0);
        if (m_w > EP_MAX_PAYLOAD) m_w = EP_MAX_PAYLOAD;
    }} else {{
        m_w = EP_DEFAULT_WEIGHT_PAYLOAD;
    }}
{casadi_call("ep_information_terms", terms, ["v", "&m_w"], ["terms"], code)}
    (void)time;
    s->num = EP_FORGETTING * s->num + terms[0];
    s->info = EP_FORGETTING * s->info + terms[1];
    if (s->info <= EP_C(0.0)) {{
        *estimate = EP_NAN;
        return EP_STATUS_WARMING_UP;
    }}
    *estimate = s->num / s->info;
    return s->info >= EP_WARM_INFO ? EP_STATUS_OK : EP_STATUS_WARMING_UP;"""
    model = CModel(
        description=f"{est.name}: recursive weighted least squares on the payload through the arm's "
                    f"inverse dynamics (machine {est.machine.name}, noise {est.noise_name})",
        state_fields=["ep_real num;   /* N: information-weighted sum */",
                      "ep_real info;  /* I: information, 1/variance of the estimate */"],
        definitions=definitions,
        reset="    s->num = EP_C(0.0);\n    s->info = EP_C(0.0);",
        step=step, on_gap=on_gap, innovation=innovation, gate_dof=2,
        sigma="    /* _estimate_sigma: I^(-1/2) */\n"
              "    return s->info > EP_C(0.0) ? EP_C(1.0) / EP_MATH(sqrt)(s->info) : EP_NAN;",
        state_finite="    return isfinite(s->num) && isfinite(s->info);")
    if gate is not None:
        gate.apply(model, code)
    return model


def _cholesky(A: ca.SX) -> ca.SX:
    """Lower-triangular L with L Lᵀ = A (symmetric positive definite, small), symbolically."""
    n = A.shape[0]
    L = ca.SX.zeros(n, n)
    for j in range(n):
        L[j, j] = ca.sqrt(A[j, j] - sum((L[j, k] ** 2 for k in range(j)), ca.SX(0)))
        for i in range(j + 1, n):
            L[i, j] = (A[i, j] - sum((L[i, k] * L[j, k] for k in range(j)), ca.SX(0))) / L[j, j]
    return L


def _whiten(L: ca.SX, B: ca.SX) -> ca.SX:
    """L⁻¹ B by forward substitution (L lower triangular)."""
    rows = []
    for i in range(L.shape[0]):
        row = B[i, :]
        for k in range(i):
            row = row - L[i, k] * rows[k]
        rows.append(row / L[i, i])
    return ca.vertcat(*rows)


def _scalar_updates(x, P, nu, H, R, nis: bool = False):
    """The Kalman update with innovation ``nu``, Jacobian ``H`` and noise ``R`` as sequential
    scalar Joseph-form updates of the whitened measurements (L⁻¹ with R = L Lᵀ).

    In exact arithmetic this is :func:`~excavator_payload.estimators.classical._kalman.
    joseph_update` (a linear measurement model: each scalar's innovation is corrected by the
    state change of the ones before it). In float it needs no matrix solve: the joint
    innovation covariance S = H P Hᵀ + R is nearly singular when one state is far less known
    than the measurements (consistent tuning: payload variance × φ² / torque noise ≈ 10⁹;
    thesis tuning: P0 / R ≈ 10²⁰, and its W S W overflows float), beyond float's 10⁷.
    With ``nis``: returns the normalised innovation squared νᵀS⁻¹ν (the sum of the scalar
    ones) instead of the update.
    """
    L = _cholesky(R)
    nu_w, H_w = _whiten(L, nu), _whiten(L, H)
    x0, total = x, ca.SX(0)
    for i in range(nu_w.shape[0]):
        h = H_w[i, :]
        innovation = nu_w[i] - h @ (x - x0)
        PHt = P @ h.T
        s = h @ PHt + 1
        k = PHt / s
        total = total + innovation**2 / s
        x = x + k * innovation
        # Joseph form (I - k h) P (I - k h)ᵀ + k kᵀ, the product taken in O(n²) for a rank-one
        # update: B = (I - k h) P, then B (I - k h)ᵀ = B - (B hᵀ) kᵀ
        B = P - k @ PHt.T
        P = B - (B @ h.T) @ k.T + k @ k.T
        P = 0.5 * (P + P.T)
    return total if nis else (x, P)


def _ekf_single_functions(est, torque_channel: bool) -> tuple[ca.Function, ca.Function]:
    """The EKF step and gate of a single-precision build: those of ``_kalman.ekf_step_symbolic``
    and ``_kalman.gate_symbolic`` (same inputs and outputs, same model functions, prediction
    line by line), with every measurement update done by :func:`_scalar_updates`."""
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
    x_post, P_post = _scalar_updates(x, P, y[0:4] - x[0:4], H1, R_qqd)
    if torque_channel:
        xs = ca.SX.sym("xs", n)
        torque_at = torque_terms(xs)
        h_1, H_1, R_1 = (ca.substitute(e, xs, x_post) for e in torque_at)
        x_post, P_post = _scalar_updates(x_post, P_post, y[4:6] - h_1, H_1, R_1)
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
    nis = _scalar_updates(x, P, y - h_all, ca.jacobian(h_all, x), R_all, nis=True)
    gate = ca.Function("ep_ekf_gate", [x, P, y, a, R_qqd, torque_cov, accel_cov], [ca.cse(nis)])
    return step, gate


def _ekf_model(est) -> CModel:
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
    gate = _borrowed_gate(est)
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


def _network_sigma(est) -> str:
    """``NeuralEstimator._estimate_sigma``: the net's RMS validation error, a constant."""
    source = est.residual_source or "validation"
    return (f"    /* NeuralEstimator._estimate_sigma: RMS error on its {source} experiments */\n"
            f"    (void)s;\n    return {c_number(est.residual_std)};")


def _time_delay_model(est) -> CModel:
    from excavator_payload.estimators.dvs.common import mlp_layers

    sensors = est.sensor_set
    n_sig = len(sensors.signals)
    L = max(est.delay_list) + 1
    layers = mlp_layers(np.asarray(est.weights, dtype=float), est._layer_sizes())
    # fold the input scaling into the first layer, reading all signals of the last L samples
    # (oldest first): W1 ((x - c) * g) + b1 = (W1 diag g) x + (b1 - W1 (c * g))
    W1, b1 = layers[0]
    gain, center = est.input_scaler.gain, est.input_scaler.center
    W1s = np.zeros((W1.shape[0], L * n_sig))
    b1s = np.array(b1, dtype=float)
    for j, d in enumerate(est.delay_list):
        for c, signal in enumerate(est.input_index):
            column = W1[:, j * est.n_inputs + c]
            W1s[:, (L - 1 - d) * n_sig + signal] = column * gain[c]
            b1s -= column * gain[c] * center[c]
    WL, bL = layers[-1]
    g_out, c_out = float(est.output_scaler.gain[0]), float(est.output_scaler.center[0])
    stream = [(W1s, b1s), *[(np.asarray(W), np.asarray(b)) for W, b in layers[1:-1]]]
    w_out, b_out = np.asarray(WL[0]) / g_out, float(bL[0]) / g_out + c_out
    hidden = [W.shape[0] for W, _ in stream]
    defs = ["/* Layers of the streaming network (tanh hidden layers, linear output), input and",
            " * output scaling folded in; layer 1 reads the last EP_WINDOW samples, oldest first. */",
            f"#define EP_MAX_HIDDEN {max(hidden)}"]
    for k, (W, b) in enumerate(stream):
        defs.append(c_array(f"EP_W{k + 1}", W))
        defs.append(c_array(f"EP_B{k + 1}", b))
    defs.append(c_array("EP_W_OUT", w_out))
    defs.append(f"#define EP_B_OUT {c_number(b_out)}")
    defs.append(_TANH_LAYER_C)
    calls = []
    sizes = [L * n_sig, *hidden]
    for k in range(len(stream)):
        src = "window" if k == 0 else ("a" if k % 2 == 1 else "b")
        dst = "a" if k % 2 == 0 else "b"
        calls.append(f"    ep_tanh_layer(EP_W{k + 1}, EP_B{k + 1}, {hidden[k]}, {sizes[k]}, {src}, {dst});")
    last = "a" if (len(stream) - 1) % 2 == 0 else "b"
    step = f"""    /* TimeDelayNetwork._step: each sample is written twice, EP_WINDOW blocks apart, so the
     * last EP_WINDOW samples are always one contiguous slice (oldest first) */
    ep_real a[EP_MAX_HIDDEN], b[EP_MAX_HIDDEN], y;
    const ep_real *window;
    int i, p;
    (void)time;
    p = s->newest = (s->newest + 1) % EP_WINDOW;
    for (i = 0; i < EP_N_SIGNALS; ++i) {{
        s->buffer[p * EP_N_SIGNALS + i] = v[i];
        s->buffer[(p + EP_WINDOW) * EP_N_SIGNALS + i] = v[i];
    }}
    s->count += 1;
    if (s->count < EP_WINDOW) {{
        *estimate = EP_NAN;
        return EP_STATUS_WARMING_UP;
    }}
    if (s->count > EP_WINDOW) s->count = EP_WINDOW;  /* no overflow on long runs */
    window = s->buffer + (p + 1) * EP_N_SIGNALS;
{chr(10).join(calls)}
    y = EP_B_OUT;
    for (i = 0; i < {hidden[-1]}; ++i) y += EP_W_OUT[i] * {last}[i];
    (void)b;
    *estimate = y;
    return EP_STATUS_OK;"""
    return _network_gate(est, CModel(
        description=f"{est.name}: time-delay network, delays {est.delay_list}, hidden {hidden}, "
                    f"inputs {', '.join(est.input_names)}",
        state_fields=["ep_real buffer[2 * EP_WINDOW * EP_N_SIGNALS];  /* doubled ring of raw samples */",
                      "int newest;  /* ring position of the newest sample */",
                      "int count;   /* samples since the reset (saturates at EP_WINDOW) */"],
        definitions="\n".join(defs),
        reset="    int i;\n    s->newest = -1;\n    s->count = 0;\n"
              "    for (i = 0; i < 2 * EP_WINDOW * EP_N_SIGNALS; ++i) s->buffer[i] = EP_C(0.0);",
        step=step, header_defines=[f"#define EP_WINDOW {L}  /* samples in the delay line */"],
        sigma=_network_sigma(est)))


def _narx_model(est) -> CModel:
    from excavator_payload.estimators.dvs.recurrent import unpack_weights

    st = est.structure
    if st.layer_delays and st.recurrent_layers:
        raise EstimatorError(f"{est.name}: networks with layer feedback (lrn) have no C export yet")
    layers = unpack_weights(np.asarray(est.weights, dtype=float), st)
    n_in = est.n_inputs
    max_in = max(st.input_delays)
    fb = st.feedback_delays
    n_fb = max(fb, default=0)
    g_out, c_out = float(est.output_scaler.gain[0]), float(est.output_scaler.center[0])
    hidden = list(st.hidden)
    defs = ["/* NARX network (closed loop): layer 1 sees the input delay line and the fed-back",
            " * estimates (scaled); tanh hidden layers; linear output. */",
            f"#define EP_WARMUP {st.warmup}",
            f"#define EP_MAX_HIDDEN {max(hidden)}",
            f"#define EP_N_X {st.n_tdl + len(fb)}",
            f"static const int EP_INPUT_INDEX[{n_in}] = {{{', '.join(str(int(i)) for i in est.input_index)}}};",
            c_array("EP_INPUT_CENTER", est.input_scaler.center),
            c_array("EP_INPUT_GAIN", est.input_scaler.gain),
            f"#define EP_OUTPUT_CENTER {c_number(c_out)}",
            f"#define EP_OUTPUT_GAIN {c_number(g_out)}",
            f"#define EP_INITIAL_OUTPUT {c_number(est._initial_scaled)}  /* scaled initial payload */",
            f"static const int EP_INPUT_DELAYS[{len(st.input_delays)}] = "
            f"{{{', '.join(map(str, st.input_delays))}}};"]
    if fb:
        defs.append(f"static const int EP_FEEDBACK_DELAYS[{len(fb)}] = {{{', '.join(map(str, fb))}}};")
    for k, (W, b) in enumerate(layers):
        defs.append(c_array(f"EP_W{k + 1}", W))
        defs.append(c_array(f"EP_B{k + 1}", b))
    defs.append(_TANH_LAYER_C)
    calls = [f"    ep_tanh_layer(EP_W1, EP_B1, {hidden[0]}, EP_N_X, x, a);"]
    for k in range(1, len(hidden)):
        src, dst = ("a", "b") if k % 2 == 1 else ("b", "a")
        calls.append(f"    ep_tanh_layer(EP_W{k + 1}, EP_B{k + 1}, {hidden[k]}, {hidden[k - 1]}, {src}, {dst});")
    last = "a" if (len(hidden) - 1) % 2 == 0 else "b"
    n_out_layer = len(layers)
    fb_code = ""
    if fb:
        fb_code = f"""    for (j = 0; j < {len(fb)}; ++j)
        x[k++] = s->y_past[EP_N_FEEDBACK - EP_FEEDBACK_DELAYS[j]];  /* y(t - f), newest last */"""
    push_fb = ""
    if fb:
        push_fb = """    for (j = 0; j + 1 < EP_N_FEEDBACK; ++j) s->y_past[j] = s->y_past[j + 1];
    s->y_past[EP_N_FEEDBACK - 1] = y;"""
    step = f"""    /* RecurrentStepper.step on the scaled input u = (v[index] - center) * gain */
    ep_real x[EP_N_X], a[EP_MAX_HIDDEN], b[EP_MAX_HIDDEN], y;
    int i, j, k = 0;
    (void)time;
    for (j = 0; j < EP_MAX_INPUT_DELAY; ++j)          /* shift the input line, newest last */
        for (i = 0; i < EP_N_INPUTS; ++i)
            s->u_past[j * EP_N_INPUTS + i] = s->u_past[(j + 1) * EP_N_INPUTS + i];
    for (i = 0; i < EP_N_INPUTS; ++i)
        s->u_past[EP_MAX_INPUT_DELAY * EP_N_INPUTS + i] =
            (v[EP_INPUT_INDEX[i]] - EP_INPUT_CENTER[i]) * EP_INPUT_GAIN[i];
    if (s->n < EP_WARMUP + 1) s->n += 1;
    if (s->n <= EP_WARMUP) {{
        *estimate = EP_NAN;
        return EP_STATUS_WARMING_UP;
    }}
    for (j = 0; j < {len(st.input_delays)}; ++j)       /* u(t - d) for d in the input delays */
        for (i = 0; i < EP_N_INPUTS; ++i)
            x[k++] = s->u_past[(EP_MAX_INPUT_DELAY - EP_INPUT_DELAYS[j]) * EP_N_INPUTS + i];
{fb_code}
{chr(10).join(calls)}
    y = EP_B{n_out_layer}[0];
    for (i = 0; i < {hidden[-1]}; ++i) y += EP_W{n_out_layer}[i] * {last}[i];
{push_fb}
    (void)b;
    *estimate = y / EP_OUTPUT_GAIN + EP_OUTPUT_CENTER;
    return EP_STATUS_OK;"""
    return _network_gate(est, CModel(
        description=f"{est.name}: closed-loop NARX network, input delays {list(st.input_delays)}, "
                    f"feedback delays {list(fb)}, hidden {hidden}, inputs {', '.join(est.input_names)}",
        state_fields=["ep_real u_past[(EP_MAX_INPUT_DELAY + 1) * EP_N_INPUTS];  /* scaled inputs, newest last */",
                      "ep_real y_past[EP_N_FEEDBACK];  /* fed-back scaled estimates, newest last */",
                      "int n;  /* samples since the reset (saturates) */"],
        definitions="\n".join(defs),
        reset="    int i;\n    s->n = 0;\n"
              "    for (i = 0; i < (EP_MAX_INPUT_DELAY + 1) * EP_N_INPUTS; ++i) s->u_past[i] = EP_C(0.0);\n"
              "    for (i = 0; i < EP_N_FEEDBACK; ++i) s->y_past[i] = EP_INITIAL_OUTPUT;",
        step=step, header_defines=[f"#define EP_N_INPUTS {n_in}  /* network inputs */",
                                   f"#define EP_MAX_INPUT_DELAY {max_in}",
                                   f"#define EP_N_FEEDBACK {max(n_fb, 1)}  /* fed-back estimates kept */"],
        sigma=_network_sigma(est)))


def _pressure_regression_model(est) -> CModel:
    """``inverse-dynamics`` and ``calibrated`` fitted on machine-sensor-set data: the kernel
    :class:`~excavator_payload.estimators.classical.pressure_regression.PressureRegression`
    (for ``calibrated`` its subclass ``calibrated_machine.CalibratedKernel``), ported to C.

    The physics is CasADi's code of ``HydraulicSymbolic.functions["pressure_regression"]``
    with the fitted parameter vector baked in as constants, behind the ground tilt each
    kernel computes from the house IMU; the rest (ring buffer, centred slope, weights,
    low-speed rule, recursive sums, status, sigma, gap rule) is written here, line by line
    after the Python.
    """
    from excavator_payload.estimators.classical.calibrated_machine import (
        CHANGING_SIGMAS, NEW_LOAD_SIGMAS, CalibratedKernel)
    from excavator_payload.estimators.classical.inverse_dynamics import MAX_BRIDGED_GAP
    from excavator_payload.estimators.classical.pressure_regression import (
        ANGLES, PITCH, PRESSURES, RATES, ROLL)
    from excavator_payload.model.hydraulic import hydraulic_symbolic

    kernel = est._pressure
    model_var = float(getattr(kernel, "model_std", 0.0)) ** 2
    if kernel is None:
        raise EstimatorError(f"{est.name}: fitted on machine-sensor-set data but has no kernel")
    calibrated = isinstance(kernel, CalibratedKernel)
    momentum = calibrated and kernel.balance == "momentum"
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
        ratio = ca.sin(x[PITCH]) / ca.fmax(ca.cos(x[ROLL]), 1e-9)
        tilt = ca.vertcat(ca.asin(ca.fmin(1.0, ca.fmax(-1.0, ratio))), x[ROLL])
        pressures = ca.vertcat(*[x[i] for i in PRESSURES])
    if momentum:  # calibrated_machine.kernel_function("momentum"): the balance terms of one sample
        from excavator_payload.estimators.classical.calibrated_machine import _momentum_terms

        A, lever_s, speed_s, stiction_s, gain_s = _momentum_terms(
            x, qdd, ca.DM(p), ca.DM(np.asarray(kernel._offset, float)), ca.DM(np.asarray(kernel._imu, float)))
        outputs = [A, lever_s, speed_s, stiction_s, gain_s]
    else:
        outputs = hydraulic_symbolic().functions["pressure_regression"](q, qd, qdd, tilt, pressures, ca.DM(p))
    kernel_fn = ca.Function("ep_pressure_regression", [x, qdd], [ca.vertcat(*outputs)], ["x", "qdd"], ["out"])
    code = casadi_c_code({"ep_pressure_regression": kernel_fn})

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
        f"#define EP_WARM_INFO {c_number(est._warm_info)}      /* 1 / warmup_std^2 */",
        f"#define EP_MAX_BRIDGED_GAP {c_number(MAX_BRIDGED_GAP)}  /* s: a longer gap restarts */",
        "/* pressure_regression's one-frame outlier test: the sample before the newest is rejected",
        " * when some signal moves away from both neighbours, in the same direction, by more than",
        " * z sigma_delta (z: GATE_PROBABILITY two-sided; sigma_delta: the fit data's sample-to-sample",
        " * change); its slot gets the neighbours' mean and is never regressed. Off with",
        " * -DEP_GATING=0 (Estimator.gating = False). */",
        *_c_one_frame_glitch(est.gating, kernel.spike_threshold),
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
            "/* CalibratedKernel.ready (--wait-for-boom): no estimate until the boom joint has been",
            " * weighed once */",
            f"#define EP_WAIT_FOR_BOOM {1 if kernel.wait_for_boom else 0}",
            "/* CalibratedKernel._accumulate (--new-load): a short memory's estimate leaving the",
            " * whole one by more than EP_NEW_LOAD_MIN kg and EP_NEW_LOAD_SIGMAS of the difference's",
            " * sigma is a new load: the weighing restarts */",
            f"#define EP_NEW_LOAD {1 if kernel.new_load else 0}",
            f"#define EP_SHORT_FORGETTING {c_number(kernel._short_forgetting)}",
            f"#define EP_NEW_LOAD_MIN {c_number(kernel._new_load_min)}",
            f"#define EP_NEW_LOAD_SIGMAS {c_number(NEW_LOAD_SIGMAS)}",
            f"#define EP_CHANGING_MIN {c_number(kernel._changing_min)}  /* ... load_changing before it */",
            f"#define EP_CHANGING_SIGMAS {c_number(CHANGING_SIGMAS)}",
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
        if (j == 0 && wt > EP_C(0.0)) s->boom_weighed = 1;
        d_num += wt * (out[3 + j] * out[j]);
        d_info += wt * (out[3 + j] * out[3 + j]);
    }}"""
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
    s->num_short = EP_SHORT_FORGETTING * s->num_short + d_num;
    s->info_short = EP_SHORT_FORGETTING * s->info_short + d_info;
    s->changing = 0;
    if ((!EP_WAIT_FOR_BOOM || s->boom_weighed) && s->info_short > EP_C(0.0) && s->info_short < s->info) {
        change = s->num_short / s->info_short - s->num / s->info;
        spread = EP_C(1.0) / s->info_short - EP_C(1.0) / s->info;
        if (spread < EP_C(0.0)) spread = EP_C(0.0);
        limit = EP_NEW_LOAD_SIGMAS * EP_MATH(sqrt)(spread);
        if (limit < EP_NEW_LOAD_MIN) limit = EP_NEW_LOAD_MIN;
        if (EP_MATH(fabs)(change) > limit) {  /* a new load: restart the weighing */
            s->num = s->info = s->num_short = s->info_short = EP_C(0.0);
            s->boom_weighed = 0;
        } else {  /* CalibratedKernel.changing: the load is changing (status load_changing) */
            limit = EP_CHANGING_SIGMAS * EP_MATH(sqrt)(spread);
            if (limit < EP_CHANGING_MIN) limit = EP_CHANGING_MIN;
            s->changing = EP_MATH(fabs)(change) > limit;
        }
    }
}
#endif"""
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
            "if (!bal_inside[j]) wt")
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
        for (j = 0; j < 3; ++j)
            s->terms_inside[slot * 3 + j] = (unsigned char)(x[EP_ANGLES[j]] >= EP_COVERAGE_LOW[j]
                                                            && x[EP_ANGLES[j]] <= EP_COVERAGE_HIGH[j]);
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
    not_ready = " || (EP_WAIT_FOR_BOOM && !s->boom_weighed)" if calibrated else ""
    changing_status = "s->changing ? EP_STATUS_LOAD_CHANGING : EP_STATUS_OK" if calibrated else "EP_STATUS_OK"
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
#if EP_GATING
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
    on_gap = """    /* InverseDynamicsEstimator._on_gap: a short gap keeps the sums and restarts the window
     * (the differentiator needs evenly spaced samples), a long one (or time going back)
     * restarts */
    ep_real dt = time - s->last_time;
    (void)v;
    if (!s->has_last_time || !(EP_C(0.0) < dt && dt <= EP_MAX_BRIDGED_GAP)) ep_model_reset(s);
    else s->ring_filled = 0;"""
    if momentum:  # CalibratedKernel.restart_window: both rings restart
        on_gap = on_gap[:-len("s->ring_filled = 0;")] + "{ s->ring_filled = 0; s->terms_filled = 0; s->terms_next = 0; }"
    fields = ["ep_real num;   /* sum of w phi r */",
              "ep_real info;  /* sum of w phi^2: information, 1/variance of the estimate */",
              "ep_real ring[EP_RING * EP_N_SIGNALS];  /* the last samples, as measured (outliers repaired) */"]
    if not calibrated:
        fields.append("ep_real ring_time[EP_RING];  /* their times */")
    fields += ["unsigned char ring_used[EP_RING];  /* 0: a rejected sample's slot */",
               "int ring_next;    /* slot the next sample goes to (the oldest once full) */",
               "int ring_filled;  /* samples in the ring (saturates at EP_RING) */"]
    reset = "    s->num = EP_C(0.0);\n    s->info = EP_C(0.0);\n    s->ring_next = 0;\n    s->ring_filled = 0;"
    if calibrated:
        fields.append("unsigned char boom_weighed;  /* a window with weight on the boom seen */")
        fields += ["ep_real num_short;   /* the new-load test's short memory: sum of w phi r */",
                   "ep_real info_short;  /* ... and of w phi^2 */"]
        fields.append("unsigned char changing;  /* the short memory has left the whole one */")
        reset += ("\n    s->boom_weighed = 0;\n    s->num_short = EP_C(0.0);\n    s->info_short = EP_C(0.0);"
                  "\n    s->changing = 0;")
    defines = [f"#define EP_HALF_WINDOW {h}  /* samples each side of the centred differentiator */",
               f"#define EP_WINDOW {width}  /* 2 EP_HALF_WINDOW + 1 */",
               "#define EP_RING (EP_WINDOW + 2)  /* the window and the two newest, unjudged samples */"]
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
    return CModel(
        description=description,
        state_fields=fields,
        definitions="\n".join(defs),
        reset=reset,
        step=step, on_gap=on_gap,
        header_defines=defines,
        sigma=("    /* _estimate_sigma: sqrt(1/I + s_model^2), the calibration's cross-checked model error */\n"
               f"    return s->info > EP_C(0.0) ? EP_MATH(sqrt)(EP_C(1.0) / s->info + {c_number(model_var)}) : EP_NAN;"),
        # InverseDynamicsEstimator._state_finite: on this set its N stays 0 (the kernel keeps
        # the sum), so only I is watched
        state_finite="    return isfinite(s->info);")


def _c_one_frame_glitch(gating: bool, thresholds) -> list[str]:
    """C lines of ``pressure_regression.one_frame_glitch``: ``EP_GATING`` (overridable with
    -DEP_GATING=0, as ``Estimator.gating = False``), the thresholds and ``ep_spike``."""
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


def _machine_ekf_functions(est, single: bool) -> ca.Function:
    """One step of ``_kalman_machine.MachineKalman`` (EKF) as a CasADi function of the prior
    ``x`` (12), ``P`` (12×12) and the sample (15), everything else constant:
    ``[x_post (12), vec P_post (144), x_next (12), vec P_next (144)]``, the posterior's payload
    clamped (the prediction starts from it). The force model is
    ``force_measurement_symbolic`` (the symbolic hydraulic model) with the machine's parameter
    vector as constants. ``single``: the measurement updates as :func:`_scalar_updates`
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
        x1, P1 = _scalar_updates(x, P, measured - x[:km.N_KIN], H1, ca.SX(R_kin))
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
    ratio = ca.sin(v[km.PITCH]) / ca.fmax(ca.cos(v[km.ROLL]), 1e-9)  # pressure_regression.ground_tilt
    tilt = ca.vertcat(ca.asin(ca.fmin(1.0, ca.fmax(-1.0, ratio))), v[km.ROLL])
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
        x2, P2 = _scalar_updates(x1, P1, force - h, H, R)
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


def _machine_ekf_model(est) -> CModel:
    """``ekf`` fitted on the machine sensor set: ``_kalman_machine.MachineKalman`` with the
    status rules of ``KalmanEstimatorBase._machine_step`` (no statistical gate on this set; the
    one-frame glitch test with its undo, as the Python)."""
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
        *_c_one_frame_glitch(est.gating, np.minimum(mk.tuning.spike_threshold, NO_LIMIT)),
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


#: Builders for estimators fitted on machine-sensor-set data.
_MACHINE_BUILDERS = {
    "inverse-dynamics": _pressure_regression_model,
    "calibrated": _pressure_regression_model,
    "ekf": _machine_ekf_model,
}


_BUILDERS = {
    "inverse-dynamics": _inverse_dynamics_model,
    "calibrated": _inverse_dynamics_model,
    "ekf": _ekf_model,
    "net1": _time_delay_model,
    "ffnn": _time_delay_model,
    "net2": _narx_model,
}


# -- the common template ---------------------------------------------------------------------------
def _status_defines() -> str:
    lines = [f"#define EP_STATUS_{s.name} {i}  /* {s.value} */" for i, s in enumerate(Status)]
    lines.append(f"#define EP_N_STATUSES {len(Status)}")
    return "\n".join(lines)


def render(est: Estimator, model: CModel, base: str, single: bool) -> tuple[str, str]:
    """Header and source text of an export."""
    sensors = est.sensor_set
    guard = f"{base.upper()}_H"
    last_used_fields = ("    ep_real last_used_time;  /* the last used sample (rejected slots are interpolated) */\n"
                        "    ep_real last_used[EP_N_SIGNALS];\n"
                        "    int has_last_used;\n") if model.fill_rejected is not None else ""
    names = ", ".join(f'"{s}"' for s in sensors.signals)
    units = ", ".join(f"{s} [{sensors.units[s]}]" for s in sensors.signals)
    header = f"""/* {base}.h: payload virtual sensor for an excavator ECU.
 * Generated by excavator-payload {__version__} -- do not edit; re-export instead.
 * Model: {model.description}.
 * Sensor set "{sensors.name}", {sensors.sample_rate:g} Hz: {units}.
 *
 * Usage: ep_state s; ep_reset(&s); then once per sample
 *     status = ep_step(&s, time_s, signals, &payload_kg);
 *     sigma_kg = ep_sigma(&s);   (one-sigma uncertainty of that estimate, NaN if unknown)
 * Statuses (EP_STATUS_*) follow excavator_payload.estimators.base.Status; the estimate is NaN
 * where there is none yet. A sample that is unreadable, implausible or (gate) inconsistent
 * with the noise model is not used: the last estimate comes back with the status saying why.
 * C99, no heap, only <math.h>. Build with -DEP_SINGLE=1 for float, -DEP_GATING=0 to turn the
 * statistical gate off (as Estimator.gating = False).
 * In single precision pass `time` relative to a recent epoch (float resolves 1 ms only up to
 * about 8000 s; the gap check needs a few ms).
 */
#ifndef {guard}
#define {guard}

#ifndef EP_SINGLE
#define EP_SINGLE {1 if single else 0}
#endif
#if EP_SINGLE
typedef float ep_real;
#else
typedef double ep_real;
#endif
typedef int ep_int;

#define EP_N_SIGNALS {len(sensors.signals)}  /* inputs, in the dataset's column order */
#define EP_SAMPLE_RATE {sensors.sample_rate!r}  /* Hz */
{_status_defines()}
{chr(10).join(model.header_defines)}

extern const char *const EP_SIGNAL_NAMES[EP_N_SIGNALS];
extern const char *const EP_STATUS_NAMES[EP_N_STATUSES];

typedef struct {{
    ep_real last_time;      /* time of the last used (or gate-rejected) sample, s */
    int has_last_time;
    ep_real last_estimate;  /* kg, NaN before the first */
    ep_real last_sigma;     /* kg, its one-sigma uncertainty (NaN: unknown) */
    int n_rejected;         /* consecutive samples the gate rejected */
    ep_real gate_scale;     /* the gate's width, >= 1 times the chi-square quantile */
{last_used_fields}{chr(10).join("    " + f for f in model.state_fields)}
}} ep_state;

/* Start a new experiment (forget everything). */
void ep_reset(ep_state *s);

/* Consume one sample; writes the payload estimate (kg, NaN if none) and returns its status. */
int ep_step(ep_state *s, ep_real time, const ep_real signals[EP_N_SIGNALS], ep_real *estimate);

/* One-sigma uncertainty (kg) of the estimate the last ep_step wrote; NaN where unknown. */
ep_real ep_sigma(const ep_state *s);

#endif /* {guard} */
"""
    statuses = ", ".join(f'"{s.value}"' for s in Status)
    judged = ""
    if est.rated_payload is not None:  # Estimator._judged: the one plausibility rule of the output
        lo, hi = (f * est.rated_payload for f in PLAUSIBLE_PAYLOAD)
        judged = (f"    /* Estimator._judged (base.py): outside {PLAUSIBLE_PAYLOAD[0]:g} … {PLAUSIBLE_PAYLOAD[1]:g} x "
                  f"the rated payload is not ok */\n"
                  f"    if (status == EP_STATUS_OK && !(EP_C({lo!r}) <= result && result <= EP_C({hi!r})))\n"
                  f"        return EP_STATUS_IMPLAUSIBLE;\n")
    fills = model.fill_rejected is not None
    gate_reset = "\n    ep_gate_reset(s);" if model.borrowed_gate else ""
    gap_body = model.on_gap if model.on_gap is not None else "    (void)time;\n    (void)v;\n    ep_model_reset(s);"
    skip_body = model.on_skip if model.on_skip is not None else "    ep_model_on_gap(s, time, v);"
    fill_fn = (f"""
/* Estimator._fill_rejected: once a sample is accepted after gate-rejected ones */
static void ep_model_fill_rejected(ep_state *s, ep_real time, const ep_real v[EP_N_SIGNALS])
{{
{model.fill_rejected}
}}
""" if model.fill_rejected is not None else "")
    if est.plausible_low is not None:
        low, high = est.plausible_low, est.plausible_high
    else:  # as Estimator.step_values: computed from the tables when the fit set none
        low, high = plausibility_limits(sensors, est.machine)
    max_step = 1.5 * sensors.sample_period
    sentinel_gap = ("\n        /* the sentinel's _on_gap: it keeps no time of its own (it is never stepped\n"
                    "         * through step_values), so every gap restarts it */\n"
                    "        ep_gate_reset(s);") if model.borrowed_gate else ""
    fill_call = ("    if (s->n_rejected && !reinitialised) ep_model_fill_rejected(s, time, v);\n"
                 if fills else "")
    after_step = ""
    if fills:
        after_step += ("    s->last_used_time = time;\n    s->has_last_used = 1;\n"
                       "    for (i = 0; i < EP_N_SIGNALS; ++i) s->last_used[i] = v[i];\n")
    if model.borrowed_gate:
        after_step += "    ep_gate_step(s, v);  /* the sentinel follows every used sample */\n"
    if model.innovation is not None:
        threshold = gate_threshold(model.gate_dof)
        gate_defs = f"""/* base.py's statistical gate: chi-square quantile of 1 - GATE_PROBABILITY ({GATE_PROBABILITY:g})
 * with {model.gate_dof} degrees of freedom, and how the gate widens */
#ifndef EP_GATING
#define EP_GATING {1 if est.gating else 0}
#endif
#define EP_GATE_THRESHOLD {c_number(threshold)}
#define EP_MAX_CONSECUTIVE_REJECTIONS {int(max_consecutive_rejections(sensors))}
#define EP_GATE_SCALE_RATE {c_number(GATE_SCALE_RATE)}
#define EP_GATE_SCALE_HEADROOM {c_number(GATE_SCALE_HEADROOM)}"""
        innovation_fn = f"""
/* Normalised squared innovation of a plausible sample (Estimator._innovation): 1 with *nis
 * written, 0 when the model cannot judge the sample yet */
static int ep_model_innovation(const ep_state *s, ep_real time, const ep_real v[EP_N_SIGNALS], ep_real *nis)
{{
{model.innovation}
}}
"""
        gate = f"""#if EP_GATING
    {{
        ep_real nis;
        if (ep_model_innovation(s, time, v, &nis)) {{
            if (!(nis <= EP_GATE_THRESHOLD * s->gate_scale)) {{
                s->n_rejected += 1;
                if (s->n_rejected <= EP_MAX_CONSECUTIVE_REJECTIONS) {{
                    if (!gap) {{  /* the sample's slot is used up: no gap after it */
                        s->last_time = time;
                        s->has_last_time = 1;
                    }}
                    *estimate = s->last_estimate;
                    return EP_STATUS_REJECTED;
                }}
                /* not one glitch but data the noise model does not describe: start again
                 * and widen the gate to it */
                ep_model_reset(s);{gate_reset.replace(chr(10), chr(10) + " " * 12)}
                reinitialised = 1;
                if (isfinite(nis)) {{
                    ep_real widened = EP_C(2.0) * nis / EP_GATE_THRESHOLD;
                    if (widened > s->gate_scale) s->gate_scale = widened;
                }}
            }} else if (isfinite(nis)) {{
                /* track how consistent the accepted data are: a slightly wrong model widens
                 * the gate instead of rejecting good data; never narrower than 1 */
                ep_real ratio = nis / EP_GATE_THRESHOLD * EP_GATE_SCALE_HEADROOM;
                s->gate_scale = (EP_C(1.0) - EP_GATE_SCALE_RATE) * s->gate_scale
                                + EP_GATE_SCALE_RATE * ratio;
                if (!(s->gate_scale >= EP_C(1.0))) s->gate_scale = EP_C(1.0);
            }}
        }}
    }}
#else
    (void)ep_model_innovation;  /* compiled but unused: the gate is off */
#endif"""
    else:
        gate_defs = "/* no noise model: no statistical gate (Estimator._innovation is None) */"
        innovation_fn = ""
        gate = "    /* no statistical gate for this model */"
    source = f"""/* {base}.c: see {base}.h. Generated by excavator-payload {__version__} -- do not edit. */
#include <math.h>
#include "{base}.h"

#if EP_SINGLE
#define EP_C(x) ((float)(x))
#define EP_MATH(name) name##f
#else
#define EP_C(x) (x)
#define EP_MATH(name) name
#endif
#define EP_NAN ((ep_real)NAN)
#define EP_INF ((ep_real)INFINITY)
/* base.py: a time step above 1.5 sample periods is a gap */
#define EP_MAX_STEP {c_number(max_step)}
#define EP_SAMPLE_PERIOD {c_number(sensors.sample_period)}
{gate_defs}

const char *const EP_SIGNAL_NAMES[EP_N_SIGNALS] = {{{names}}};
const char *const EP_STATUS_NAMES[EP_N_STATUSES] = {{{statuses}}};

/* base.plausibility_limits, as saved with the model: a signal outside [low, high] is not used */
{c_array("EP_PLAUSIBLE_LOW", low)}{c_array("EP_PLAUSIBLE_HIGH", high)}
static void ep_model_reset(ep_state *s);

{model.definitions}

static void ep_model_reset(ep_state *s)
{{
{model.reset}
}}

static int ep_model_step(ep_state *s, ep_real time, const ep_real v[EP_N_SIGNALS], ep_real *estimate)
{{
{model.step}
}}

static void ep_model_on_gap(ep_state *s, ep_real time, const ep_real v[EP_N_SIGNALS])
{{
{gap_body}
}}

/* Estimator._on_skip: before the sample that follows gate-rejected ones */
static void ep_model_on_skip(ep_state *s, ep_real time, const ep_real v[EP_N_SIGNALS])
{{
{skip_body}
}}
{fill_fn}
/* Estimator._estimate_sigma: one-sigma uncertainty of the current estimate, kg */
static ep_real ep_model_sigma(const ep_state *s)
{{
{model.sigma}
}}

/* Estimator._state_finite */
static int ep_model_state_finite(const ep_state *s)
{{
{model.state_finite}
}}
{innovation_fn}
void ep_reset(ep_state *s)
{{
    s->last_time = EP_C(0.0);
    s->has_last_time = 0;
    s->last_estimate = EP_NAN;
    s->last_sigma = EP_NAN;
    s->n_rejected = 0;
    s->gate_scale = EP_C(1.0);{chr(10) + "    s->has_last_used = 0;" if fills else ""}{gate_reset}
    ep_model_reset(s);
}}

ep_real ep_sigma(const ep_state *s)
{{
    return s->last_sigma;
}}

int ep_step(ep_state *s, ep_real time, const ep_real signals[EP_N_SIGNALS], ep_real *estimate)
{{
    /* Estimator.step_values (base.py): readable, plausible, consistent; then the model */
    const ep_real *v = signals;
    ep_real result, sigma;
    int i, status, gap = 0, reinitialised = 0;
    if (!isfinite(time)) {{
        *estimate = s->last_estimate;
        return EP_STATUS_INVALID;
    }}
    for (i = 0; i < EP_N_SIGNALS; ++i) {{
        if (!isfinite(v[i])) {{
            *estimate = s->last_estimate;
            return EP_STATUS_INVALID;
        }}
    }}
    for (i = 0; i < EP_N_SIGNALS; ++i) {{
        if (!(EP_PLAUSIBLE_LOW[i] <= v[i] && v[i] <= EP_PLAUSIBLE_HIGH[i])) {{
            *estimate = s->last_estimate;
            return EP_STATUS_OUT_OF_RANGE;
        }}
    }}
    if (s->has_last_time) {{
        ep_real dt = time - s->last_time;
        if (dt <= EP_C(0.0) || dt > EP_MAX_STEP) gap = 1;
    }}
    if (gap) {{
        /* a hole in the data: the model bridges it or restarts */
        ep_model_on_gap(s, time, v);{sentinel_gap}
    }} else if (s->n_rejected) {{
        ep_model_on_skip(s, time, v);  /* samples the gate rejected just before this one */
    }}
{gate}
{fill_call}    s->n_rejected = 0;
    s->last_time = time;
    s->has_last_time = 1;
    status = ep_model_step(s, time, v, &result);
{after_step}    sigma = ep_model_sigma(s);
    if (!ep_model_state_finite(s) || (status == EP_STATUS_OK && !isfinite(result))) {{
        ep_model_reset(s);  /* the state went non-finite: restart */
        s->has_last_time = 0;
        result = EP_NAN;
        sigma = EP_NAN;
        status = EP_STATUS_STATE_RESET;
    }} else if (!isfinite(result)) {{
        sigma = EP_NAN;
    }}
    s->last_estimate = result;
    s->last_sigma = sigma;
    *estimate = result;
    if (reinitialised) return EP_STATUS_REINITIALISED;
    if (gap && status != EP_STATUS_STATE_RESET) return EP_STATUS_GAP;
{judged}    return status;
}}
"""
    return header, source


def export_c(estimator: Estimator, out: str | Path, precision: str = "float64") -> list[Path]:
    """Write ``ep_<name>.h`` and ``ep_<name>.c`` for a fitted estimator into folder ``out``."""
    if not estimator.fitted:
        raise EstimatorError(f"{estimator.name}: nothing to export, the estimator is not fitted")
    if estimator.sensor_set.name == "machine":
        builder = _MACHINE_BUILDERS.get(estimator.name)
        if builder is None:
            raise EstimatorError(f"{estimator.name} on the machine sensor set has no C export; "
                                 f"exportable there: {', '.join(C_EXPORTABLE_MACHINE)}")
    else:
        builder = _BUILDERS.get(estimator.name)
    if builder is None:
        raise EstimatorError(f"{estimator.name} has no C export; exportable: {', '.join(C_EXPORTABLE)}")
    if precision not in ("float64", "float32"):
        raise EstimatorError("precision must be float64 or float32")
    refusal = per_sample_refusal(estimator, "C")
    if refusal:
        raise EstimatorError(refusal)
    model = builder(estimator)
    base = "ep_" + c_identifier(estimator.name)
    header, source = render(estimator, model, base, precision == "float32")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, text in ((f"{base}.h", header), (f"{base}.c", source)):
        path = out / name
        tmp = out / (name + ".tmp")
        tmp.write_text(text)
        os.replace(tmp, path)
        paths.append(path)
    return paths
