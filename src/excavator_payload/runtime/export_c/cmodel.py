"""What a kernel's builder hands to the template (:class:`CModel`), and the borrowed gate a
model without a noise model of its own carries (:class:`BorrowedGate`, base.py's
``Estimator._borrows_gate``).

The borrowed gate: an estimator without a noise model of its own (``net1``/``ffnn``/``net2``,
``ekf`` with the thesis tuning) or one that believes another machine than its training data's
(``calibrated`` on a wrong machine) is judged by its sentinel, inverse-dynamics least squares
on the training data's machine and noise. The C runs the sentinel beside the model
(``ep_gate_step``, information form) with its base parameters and sensor variances as constant
arrays, and CasADi generates its ``information_terms`` and ``residual_nis`` (2 degrees of
freedom) from those very functions; like the Python sentinel (never stepped through
``step_values``, so it keeps no time) it restarts on every gap and on a re-initialisation.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from excavator_payload.runtime.export_c.c_text import c_array, c_number
from excavator_payload.runtime.export_c.casadi_code import casadi_call


@dataclass
class CModel:
    """The model-specific parts of an export; the rest is the common template
    (:func:`~excavator_payload.runtime.export_c.template.render`).

    Parameters
    ----------
    description : str
        One line on the model, in the header.
    state_fields : list of str
        C declarations inside ``ep_state``.
    definitions : str
        Constants, generated code and helper functions.
    reset : str
        Body of ``ep_model_reset(ep_state *s)``.
    step : str
        Body of ``ep_model_step(s, time, v, estimate)``, returning a status.
    on_gap : str or None
        Body of ``ep_model_on_gap(s, time, v)``; None: reset.
    header_defines : list of str
        ``#define`` lines the state struct needs (sizes).
    sigma : str
        Body of ``ep_model_sigma(s)``: ``Estimator._estimate_sigma``.
    state_finite : str
        Body of ``ep_model_state_finite(s)``.
    innovation : str or None
        Body of ``ep_model_innovation(s, time, v, &nis)``; None: no gate.
    gate_dof : int
        The innovation's degrees of freedom.
    on_skip : str or None
        Body of ``ep_model_on_skip(s, time, v)``; None: the gap handling.
    fill_rejected : str or None
        Body of ``ep_model_fill_rejected(s, time, v)``; None: nothing.
    borrowed_gate : bool
        Whether ``ep_gate_reset``/``ep_gate_step`` exist (the borrowed gate).
    """

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
    are emitted once); :meth:`apply` adds the rest to the model.

    Parameters
    ----------
    functions : dict of str to casadi.Function
        The sentinel's information terms and residual NIS, by C name.
    real : str
        The type the sentinel computes in.
    definitions : str
        Its constants (C text).
    innovation_call : casadi.Function
        The residual NIS function the innovation calls.
    """

    functions: dict[str, ca.Function]
    real: str
    definitions: str
    innovation_call: ca.Function

    def apply(self, model: CModel, code: str) -> None:
        """Add the gate to ``model`` in place: its state fields, ``ep_gate_reset`` and
        ``ep_gate_step``, and the innovation body that judges samples by the gate's residual NIS.

        Parameters
        ----------
        model : CModel
            The model the gate judges for.
        code : str
            The CasADi-generated C the calls are sized against (:func:`casadi_call`).
        """
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


def borrowed_gate(est, real: str = "ep_real") -> BorrowedGate | None:
    """The C parts of an estimator's borrowed gate.

    Parameters
    ----------
    est : Estimator
        A fitted estimator.
    real : str
        The type the sentinel computes in.

    Returns
    -------
    BorrowedGate or None
        None when ``est`` judges samples itself (or not at all).
    """
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
