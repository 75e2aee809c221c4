r"""``excavator-payload export --format c``: a trained estimator as one C99 ``.c``/``.h`` pair.

Every exported model has the same interface (the header documents it)::

    #define EP_N_SIGNALS ...            /* inputs, in the sensor set's column order */
    extern const char *const EP_SIGNAL_NAMES[EP_N_SIGNALS];
    typedef struct { ... } ep_state;    /* fixed size */
    void ep_reset(ep_state *s);
    int  ep_step(ep_state *s, ep_real time, const ep_real signals[EP_N_SIGNALS],
                 ep_real *estimate);    /* a status code, 0 = ok, as the Status enum */
    ep_real ep_sigma(const ep_state *s);  /* one-sigma uncertainty of that estimate, kg */
    unsigned long ep_faults(const ep_state *s, int kind);  /* machine set: the signals the
                                        sensor health monitor names with EP_FAULT_<kind> */

Rules: C99, no heap (work arrays live on the stack of ``ep_step``), nothing beyond
``<math.h>``, no warning under ``-std=c99 -Wall -Wextra -Werror -pedantic``. ``ep_real`` is
``double``, or ``float`` when compiled with ``-DEP_SINGLE=1`` (the default of an export with
``--precision float32``); in single precision every constant is a ``float`` and the maths
functions are the ``f`` variants, so a single-precision FPU never touches a double.

The rooms of this package:

* :mod:`.c_text`: static C fragments and Python values as C text;
* :mod:`.casadi_code`: CasADi's generated C, trimmed and called, and the shared symbolic
  helpers (the ground tilt, the float builds' scalar Kalman updates);
* :mod:`.cmodel`: :class:`CModel`, what a builder hands to the template, and the borrowed gate;
* :mod:`.template`: :func:`render`, the interface and ``Estimator.step_values``' status logic;
* :mod:`.registry`: the builders, registered against the estimator and sensor set they export;
* :mod:`.health`: the sensor health monitor of every machine-set export (``EP_HEALTH``);
* one builder per kernel: :mod:`.inverse_dynamics`, :mod:`.ekf`, :mod:`.networks` (thesis
  sensor set), :mod:`.pressure_regression` (machine sensor set).
"""

from __future__ import annotations

import os
from pathlib import Path

from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.base import Estimator
from excavator_payload.platforms import HYDRAULIC
from excavator_payload.runtime.export_c.c_text import (
    MATH_FUNCTIONS,
    c_array,
    c_identifier,
    c_number,
)
from excavator_payload.runtime.export_c.casadi_code import casadi_c_code, casadi_call
from excavator_payload.runtime.export_c.cmodel import BorrowedGate, CModel
# the builders register themselves (registry.c_builder) when their modules are imported
from excavator_payload.runtime.export_c import (  # noqa: F401
    balance_net,
    inverse_dynamics,
    networks,
    pressure_regression,
)
from excavator_payload.runtime.export_c.ekf import _ekf_single_functions  # noqa: F401 (tests)
from excavator_payload.runtime.export_c.registry import builder_for
from excavator_payload.runtime.export_c.template import render
from excavator_payload.runtime.exportable import (
    C_EXPORTABLE,
    C_EXPORTABLE_MACHINE,
    per_sample_refusal,
)

__all__ = ["BorrowedGate", "CModel", "MATH_FUNCTIONS", "c_array", "c_identifier", "c_number",
           "casadi_c_code", "casadi_call", "export_c", "render"]


def export_c(estimator: Estimator, out: str | Path, precision: str = "float64") -> list[Path]:
    """Write ``ep_<name>.h`` and ``ep_<name>.c`` for a fitted estimator.

    Parameters
    ----------
    estimator : Estimator
        A fitted estimator with a C export on its sensor set.
    out : str or Path
        The folder to write into (made if missing).
    precision : str
        ``float64`` or ``float32`` (the default of ``EP_SINGLE``).

    Returns
    -------
    list of Path
        The header and the source.
    """
    if not estimator.fitted:
        raise EstimatorError(f"{estimator.name}: nothing to export, the estimator is not fitted")
    builder = builder_for(estimator.name, estimator.sensor_set.name)
    if builder is None and HYDRAULIC.carries(estimator):
        raise EstimatorError(f"{estimator.name} on the machine sensor set has no C export; "
                             f"exportable there: {', '.join(C_EXPORTABLE_MACHINE)}")
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
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, path)
        paths.append(path)
    return paths
