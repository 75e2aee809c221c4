"""CasADi ``sqpmethod`` solvers generated as C, compiled with their model, called from numpy.

The NMPCs solve a small quadratic program per SQP iteration with ``qrqp`` and evaluate their
compiled interval model through CasADi's virtual machine; CasADi can also write the whole solver
as C (the SQP loop, ``qrqp``, the constraint Jacobian's assembly), the same algorithm from the
same runtime templates. :func:`compiled_sqp` compiles that C together with the C of the interval
model and its Jacobian into one library (cached like :func:`~.codegen.native`), so that a solve
is one C call. The results are CasADi's own to the bit (a test compares them).

What the generated C does not do, it is given here by a few edits of the source, each checked
to apply exactly once per solver (otherwise nothing is compiled and the caller keeps CasADi's
solver):

* **return status**: the generated solver returns 0 whether it converged, reached
  ``max_iter`` or stopped on a tiny step; CasADi's reports ``Solve_Succeeded``,
  ``Maximum_Iterations_Exceeded`` or ``Search_Direction_Becomes_Too_Small`` (a failure for the
  NMPCs). Each of the three exits records its reason in a global the caller reads with
  :mod:`ctypes`.
* **non-finite evaluations**: CasADi's solver treats a NaN or infinite value of the
  objective, constraints or their derivatives as a failed evaluation (a line-search trial is
  then shortened; at an iterate the solve stops with ``Non_Regular_Sensitivities``); the
  generated C would carry the NaN on. The edits add the same checks.

Without a C compiler, with ``EXCAVATOR_PAYLOAD_NATIVE=0``, or if generating or compiling fails,
:func:`compiled_sqp` returns None and the caller uses CasADi's solver: the same numbers, slower.
"""

from __future__ import annotations

import ctypes
import logging
import re
import subprocess
import weakref

import casadi as ca
import numpy as np

from excavator_payload.model.codegen import SOLVER_SLOTS, BufferedCall, compiled_library, compiler

log = logging.getLogger(__name__)

#: The global the edited solvers write their exit reason to.
STATUS_SYMBOL = "excavator_payload_sqp_status"
#: Exit reason codes (the global's values) and CasADi's ``return_status`` for each.
STATUSES = {
    0: "Generated_Solver_Error",
    1: "Solve_Succeeded",
    2: "Maximum_Iterations_Exceeded",
    3: "Search_Direction_Becomes_Too_Small",
    4: "Non_Regular_Sensitivities",
}

_PRELUDE = f"""
int {STATUS_SYMBOL} = 0;
static int excavator_payload_finite(const casadi_real* x, casadi_int n) {{
  casadi_int i;
  for (i = 0; i < n; ++i) if (!isfinite(x[i])) return 0;
  return 1;
}}
"""
_CONVERGED = re.compile(r"if \(iter_count >= \d+ && pr_inf < [^&]+ && du_inf < [^)]+\) break;")
_MAX_ITER = re.compile(r"if \(iter_count >= \d+\) break;")
_SMALL_STEP = re.compile(r"if \(iter_count >= 1 && iter_count >= \d+ && dx_norminf <= [^)]+\) break;")
_JAC_FG = re.compile(r"(d->res\[3\] = d->Jk;\n\s*)if \((casadi_f\d+\(d->arg, d->res, d->iw, d->w, 0\))\) return 1;")
_LINE_SEARCH_FG = re.compile(r"(d->res\[1\] = d->z_cand\+\d+;\n\s*)if \((casadi_f\d+\(d->arg, d->res, d->iw, d->w, 0\))\) \{")


def _status_edit(solvers: list[ca.Function]):
    """The source edit of the module docstring for ``solvers`` (all of one size)."""
    sizes = {(s.nnz_in("x0"), s.nnz_out("g"), s.get_function("nlp_jac_fg").sparsity_out(3).nnz())
             for s in solvers}
    if len(sizes) != 1:
        raise ValueError("compiled_sqp: the solvers must share one problem size")
    n_x, n_g, n_jac = sizes.pop()
    count = len(solvers)

    def replace(pattern, replacement, source):
        source, n = pattern.subn(replacement, source)
        if n != count:
            raise ValueError(f"compiled_sqp: {pattern.pattern!r} found {n} times, expected {count}")
        return source

    def edit(source: str) -> str:
        marker = "/* Symbol visibility in DLLs */"
        if source.count(marker) != 1:
            raise ValueError("compiled_sqp: unexpected layout of the generated C")
        source = source.replace(marker, _PRELUDE + marker)
        for code, pattern in ((1, _CONVERGED), (2, _MAX_ITER), (3, _SMALL_STEP)):
            exit_with = f"{{ {STATUS_SYMBOL} = {code}; break; }}"
            source = replace(pattern, lambda m, e=exit_with: m.group(0).replace("break;", e), source)
        finite_iterate = (f"!excavator_payload_finite(&d_nlp.objective, 1) || !excavator_payload_finite(d->gf, {n_x})"
                          f" || !excavator_payload_finite(d_nlp.z+{n_x}, {n_g})"
                          f" || !excavator_payload_finite(d->Jk, {n_jac})")
        source = replace(_JAC_FG, lambda m: (f"{m.group(1)}if ({m.group(2)}) return 1;\n"
                                             f"    if ({finite_iterate}) {{ {STATUS_SYMBOL} = 4; break; }}"), source)
        finite_trial = (f"!excavator_payload_finite(&fk_cand, 1) || "
                        f"!excavator_payload_finite(d->z_cand+{n_x}, {n_g})")
        source = replace(_LINE_SEARCH_FG, lambda m: f"{m.group(1)}if ({m.group(2)} || {finite_trial}) {{", source)
        return source

    return edit


class CompiledSQPCall:
    """One generated solver, called like :class:`~.codegen.BufferedCall`, with CasADi's status.
    Not thread-safe (its buffers, and one status global per library): one per controller.

    Parameters
    ----------
    function : casadi.Function
        The solver loaded from the library with :func:`casadi.external`.
    status : ctypes.c_int
        The library's exit-reason global (:data:`STATUS_SYMBOL`).
    """

    def __init__(self, function: ca.Function, status: ctypes.c_int):
        self._call = BufferedCall(function)
        self._status = status
        self._stats: dict = {}

    def __call__(self, **inputs) -> dict[str, np.ndarray]:
        """The solver's outputs by name for its inputs by name (as :class:`~.codegen.BufferedCall`).

        Parameters
        ----------
        **inputs : numpy.ndarray or float
            ``x0``, ``p``, ``lbx``, ``ubx``, ``lbg``, ``ubg``, ``lam_x0``, ``lam_g0``.
        """
        self._status.value = 0
        out = self._call(**inputs)
        code = self._status.value
        self._stats = {"return_status": STATUSES.get(code, STATUSES[0]), "success": code == 1}
        return out

    def stats(self) -> dict:
        """``return_status`` and ``success`` of the last call, as CasADi's solver reports them."""
        return self._stats


#: Live controllers per generated library (each holds one of its :data:`SOLVER_SLOTS` memories).
_LIVE: dict[str, int] = {}


def _release(library: str) -> None:
    _LIVE[library] -= 1


def compiled_sqp(solvers: list[ca.Function], model: list[ca.Function], name: str) -> dict | None:
    """``solvers`` (``sqpmethod`` of one problem) as generated C compiled with ``model``, or None.

    Parameters
    ----------
    solvers : list of casadi.Function
        ``sqpmethod`` solvers of one NLP (e.g. warm-started and cold, differing in ``max_iter``)
        whose NLP calls ``model`` as a :func:`casadi.external` function.
    model : list of casadi.Function
        The SX functions behind that external (the interval model and its ``jac_`` function),
        compiled into the same library under their names.
    name : str
        The library's base name.

    Returns
    -------
    dict of str to CompiledSQPCall or None
        The compiled solvers by name; None without a compiler or if any step failed (the caller
        then calls CasADi's solvers).
    """
    if compiler() is None:
        return None
    try:
        library = compiled_library(solvers, name, edit=_status_edit(solvers), linked=model)
        if _LIVE.get(str(library), 0) >= SOLVER_SLOTS:  # its static memories all taken
            log.warning("generated solver %s: %d controllers alive in this process, using CasADi's",
                        name, SOLVER_SLOTS)
            return None
        handle = ctypes.CDLL(str(library))
        status = ctypes.c_int.in_dll(handle, STATUS_SYMBOL)
        calls = {s.name(): CompiledSQPCall(ca.external(s.name(), str(library)), status) for s in solvers}
        _LIVE[str(library)] = _LIVE.get(str(library), 0) + 1
        # a controller's memory slot goes back when its solvers are collected (measured)
        weakref.finalize(next(iter(calls.values())), _release, str(library))
        return calls
    except (OSError, RuntimeError, ValueError, subprocess.SubprocessError) as exc:
        log.warning("generating the solver %s as C failed, using CasADi's: %s", name, exc)
        return None
