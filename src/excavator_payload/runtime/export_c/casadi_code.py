"""CasADi's generated C, trimmed and called, and the symbolic helpers shared by the kernels.

:func:`casadi_c_code` turns CasADi functions into static C (no public symbol, ``ep_real``
types, ``EP_MATH`` maths); :func:`casadi_call` calls one with work arrays on the stack.
:func:`ground_tilt_symbolic` is the ground tilt (:func:`excavator_payload.model.ground_tilt.ground_tilt`)
on CasADi symbols, the one rendering every kernel's C uses; :func:`scalar_updates` is the
Kalman update of the float builds (sequential scalar Joseph updates of whitened measurements).
"""

from __future__ import annotations

import re

import casadi as ca

from excavator_payload.errors import EstimatorError
from excavator_payload.model.ground_tilt import ground_tilt
from excavator_payload.runtime.export_c.c_text import MATH_FUNCTIONS


def casadi_c_code(functions: dict[str, ca.Function], real: str = "ep_real") -> str:
    """CasADi's generated C for ``functions``, trimmed to what we need.

    Keeps the evaluation functions (renamed to the given names, ``static``) and the helpers
    they call; drops CasADi's public API (memory management, sparsity tables, names), so the
    result compiles without warnings under our flags and exports no symbol.

    Parameters
    ----------
    functions : dict of str to casadi.Function
        C name -> function, generated in this order.
    real : str
        The floating type: ``"ep_real"`` (maths calls through ``EP_MATH``, float variants in
        single precision; literals become ``EP_C`` constants) or ``"double"`` (stays double).
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
    """C statements calling a generated function with work arrays on the stack.

    Parameters
    ----------
    name : str
        The generated function's C name.
    function : casadi.Function
        The function (its work array sizes).
    inputs : list of str
        C expressions of its arguments, in order (missing ones are null).
    outputs : list of str
        C expressions of its results, in order (missing ones are null).
    code : str
        The generated C: work arrays it does not index get 1 element only.
    real : str
        The floating type of the arrays.
    """
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


def ground_tilt_symbolic(house_pitch, house_roll) -> ca.SX:
    """The ground tilt [pitch, roll] (:func:`~excavator_payload.model.ground_tilt.ground_tilt`,
    clamped) of CasADi symbols, as one column.

    Parameters
    ----------
    house_pitch : casadi.SX
        The house IMU's pitch, rad.
    house_roll : casadi.SX
        The house IMU's roll, rad.
    """
    return ca.vertcat(*ground_tilt(house_pitch, house_roll, trig=ca))


def scalar_updates(x, P, nu, H, R, nis: bool = False):
    """The Kalman update as sequential scalar Joseph-form updates of the whitened measurements
    (L⁻¹ with R = L Lᵀ).

    In exact arithmetic this is :func:`~excavator_payload.estimators.classical._kalman.
    joseph_update` (a linear measurement model: each scalar's innovation is corrected by the
    state change of the ones before it). In float it needs no matrix solve: the joint
    innovation covariance S = H P Hᵀ + R is nearly singular when one state is far less known
    than the measurements (consistent tuning: payload variance × φ² / torque noise ≈ 10⁹;
    thesis tuning: P0 / R ≈ 10²⁰, and its W S W overflows float), beyond float's 10⁷.

    Parameters
    ----------
    x : casadi.SX
        The prior state.
    P : casadi.SX
        Its covariance.
    nu : casadi.SX
        The innovation.
    H : casadi.SX
        The measurement Jacobian.
    R : casadi.SX
        The measurement noise covariance.
    nis : bool
        Return the normalised innovation squared νᵀS⁻¹ν (the sum of the scalar ones) instead
        of the update ``(x, P)``.
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
