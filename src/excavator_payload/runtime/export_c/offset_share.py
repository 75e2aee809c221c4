"""C port of the zero's share of σ per estimate (``machine_calibration/offset_share.py``,
``OffsetShare``): after a zero, the momentum form's σ carries the zero's offsets posterior
through the estimate's own sensitivity.

:func:`offset_share_functions` gives the generated Jacobian function; :func:`offset_share_c`
patches the machine set's C pieces (after ``imu_nuisance.py``'s, when that is on): per sample
the whitened Jacobian of the balance terms by the offsets into a ring beside the terms, per
window the sums G_r, G_phi, c (and their short memory), the new load's restart and the
settle, and the share ``os_std`` that σ adds.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from excavator_payload.runtime.export_c.c_text import c_number


def offset_share_functions(kernel) -> dict:
    """``{"ep_offset_jacobian": f}``: one sample's balance terms' Jacobian (12 × k,
    column-major) in the whitened offsets, the fitted machine as constants; inputs ``x``, ``qdd``.

    Parameters
    ----------
    kernel : CalibratedKernel
        The kernel with its ``_offset_share``.
    """
    from excavator_payload.estimators.classical.machine_calibration.settings import (
        _OFFSET_COLUMNS, SIGNALS)
    from excavator_payload.estimators.classical.machine_calibration.symbolic import _momentum_terms

    share = kernel._offset_share
    x = ca.SX.sym("x", len(SIGNALS))
    qdd = ca.SX.sym("qdd", 4)
    offsets = ca.SX.sym("offsets", len(SIGNALS))
    A = _momentum_terms(x, qdd, ca.DM(np.asarray(kernel._p, float)), offsets, ca.DM(np.asarray(kernel._imu, float)))[0]
    free = ca.vertcat(*[offsets[int(i)] for i in _OFFSET_COLUMNS])
    J = ca.mtimes(ca.jacobian(A, free), ca.DM(share.L))
    J = ca.substitute(J, offsets, ca.DM(np.asarray(kernel._offset, float)))
    return {"ep_offset_jacobian": ca.Function("ep_offset_jacobian", [x, qdd], [ca.densify(J)], ["x", "qdd"], ["jac"])}


def _replace(text: str, old: str, new: str) -> str:
    if text.count(old) != 1:
        raise RuntimeError(f"offset_share C port: the machine set's C changed near {old[:40]!r}")
    return text.replace(old, new)


def offset_share_c(kernel, call: str, step: str, fields: list, reset: str, defs: list, nuisance: bool) -> dict:
    """The machine set's C pieces with the zero's share in.

    Parameters
    ----------
    kernel : CalibratedKernel
        The kernel with its ``_offset_share``.
    call : str
        C statements calling ``ep_offset_jacobian`` (``casadi_call``) into ``jac``.
    step, reset : str
        The model's step and reset bodies (the IMU nuisance filter's in, if on).
    fields : list of str
        The state's fields.
    defs : list of str
        The model's definitions (with the IMU nuisance filter on, its solve is patched to keep
        what the share differentiates: its regressors per joint, T h0 and T theta).
    nuisance : bool
        Whether the IMU nuisance filter is on.

    Returns
    -------
    dict
        ``header`` (defines), ``step``, ``fields``, ``reset``, ``defs``.
    """
    share = kernel._offset_share
    k, d = share.k, share.d
    fields = fields + [
        "ep_real os_terms[EP_BALANCE * 12 * EP_OS];  /* whitened d(terms)/dv per slot, column-major */",
        "ep_real os_Gr[EP_OS_D * EP_OS];    /* sum w a dr0 (row-major d x k) */",
        "ep_real os_Gphi[EP_OS_D * EP_OS];  /* sum w a dphi */",
        "ep_real os_c[EP_OS];               /* sum w r0 dphi */",
        "ep_real os_Grs[EP_OS_D * EP_OS];   /* the short memory's */",
        "ep_real os_Gphis[EP_OS_D * EP_OS];",
        "ep_real os_cs[EP_OS];",
        "ep_real os_w[3];    /* the window's weights */",
        "ep_real os_std;     /* the zero's share of sigma, kg */",
        "unsigned int os_restarts, os_restarts_seen, os_settles, os_settles_seen;",
    ]
    reset = reset + """
    {
    int i;
    for (i = 0; i < EP_OS_D * EP_OS; ++i) s->os_Gr[i] = s->os_Gphi[i] = s->os_Grs[i] = s->os_Gphis[i] = EP_C(0.0);
    for (i = 0; i < EP_OS; ++i) s->os_c[i] = s->os_cs[i] = EP_C(0.0);
    for (i = 0; i < EP_BALANCE * 12 * EP_OS; ++i) s->os_terms[i] = EP_C(0.0);
    s->os_std = EP_C(0.0);
    s->os_restarts = s->os_restarts_seen = s->os_settles = s->os_settles_seen = 0;
    }"""
    sample = f"""        {{  /* OffsetShare.sample: the whitened Jacobian of this sample's terms by the offsets */
            ep_real jac[12 * EP_OS];
{call}
            for (i = 0; i < 12 * EP_OS; ++i) s->os_terms[slot * 12 * EP_OS + i] = jac[i];
        }}
"""
    regressor = ("for (q = 0; q < EP_OS_D; ++q) a[q] = s->nz_a[j * EP_OS_D + q];" if nuisance
                 else "a[0] = bal[3 + j];")
    if nuisance:
        solve = """                if (EP_NZ_INFO(s) > EP_C(0.0)) {  /* the filter's solve: g = (T h0)^T V */
                    ep_real mm = s->nz_Ttheta[0], acc;
                    for (q = 0; q < EP_OS; ++q) {
                        acc = s->os_c[q];
                        for (r = 0; r < EP_OS_D; ++r) acc -= s->os_Gphi[r * EP_OS + q] * s->nz_Ttheta[r];
                        g[q] = s->nz_Th0[0] * acc;
                        for (r = 0; r < EP_OS_D; ++r)
                            g[q] += s->nz_Th0[r] * (s->os_Gr[r * EP_OS + q] - mm * s->os_Gphi[r * EP_OS + q]);
                    }
                    have = 1;
                }"""
    else:
        solve = """                if (s->info > EP_C(0.0)) {  /* N / I: g = (G_r + c - 2 m G_phi) / I */
                    ep_real mm = s->num / s->info;
                    for (q = 0; q < EP_OS; ++q)
                        g[q] = (s->os_Gr[q] + s->os_c[q] - EP_C(2.0) * mm * s->os_Gphi[q]) / s->info;
                    have = 1;
                }"""
    window = """            {  /* OffsetShare.window: the window's d(r0, phi)/dv per joint into G_r, G_phi, c */
                ep_real dGr[EP_OS_D * EP_OS], dGphi[EP_OS_D * EP_OS], dc[EP_OS], a[EP_OS_D], g[EP_OS];
                ep_real dint[6 * EP_OS], dmom[6 * EP_OS], dr, dp, ss = EP_C(0.0);
                int q, r, ok = 1, have = 0;
                for (i = 0; i < 6 * EP_OS; ++i) dint[i] = dmom[i] = EP_C(0.0);
                for (i = 0; i < EP_OS_D * EP_OS; ++i) dGr[i] = dGphi[i] = EP_C(0.0);
                for (i = 0; i < EP_OS; ++i) dc[i] = EP_C(0.0);
                for (k = 0; k < EP_BALANCE; ++k) {
                    const ep_real *jt = s->os_terms + ((s->terms_next + k) % EP_BALANCE) * 12 * EP_OS;
                    for (q = 0; q < EP_OS; ++q)
                        for (j = 0; j < 6; ++j) {
                            dint[j * EP_OS + q] += EP_BALANCE_W[k] * jt[q * 12 + 6 + j];
                            dmom[j * EP_OS + q] += EP_BALANCE_U[k] * jt[q * 12 + j];
                        }
                }
                for (j = 0; j < 3; ++j) {
                    if (!(s->os_w[j] > EP_C(0.0))) continue;
                    @REGRESSOR@
                    for (q = 0; q < EP_OS; ++q) {
                        dr = (dint[j * EP_OS + q] - dmom[j * EP_OS + q]) / EP_BALANCE_SPAN;
                        dp = (dmom[(3 + j) * EP_OS + q] - dint[(3 + j) * EP_OS + q]) / EP_BALANCE_SPAN;
                        for (r = 0; r < EP_OS_D; ++r) {
                            dGr[r * EP_OS + q] += (a[r] * s->os_w[j]) * dr;
                            dGphi[r * EP_OS + q] += (a[r] * s->os_w[j]) * dp;
                        }
                        dc[q] += (s->os_w[j] * bal[j]) * dp;
                    }
                }
                for (q = 0; q < EP_OS_D * EP_OS; ++q) ok = ok && isfinite(dGr[q]) && isfinite(dGphi[q]);
                for (q = 0; q < EP_OS; ++q) ok = ok && isfinite(dc[q]);
                if (!ok) {  /* a hostile sample's Jacobian: the window adds nothing */
                    for (q = 0; q < EP_OS_D * EP_OS; ++q) dGr[q] = dGphi[q] = EP_C(0.0);
                    for (q = 0; q < EP_OS; ++q) dc[q] = EP_C(0.0);
                }
                for (q = 0; q < EP_OS_D * EP_OS; ++q) {
                    s->os_Gr[q] = EP_FORGETTING * s->os_Gr[q] + dGr[q];
                    s->os_Gphi[q] = EP_FORGETTING * s->os_Gphi[q] + dGphi[q];
#if EP_NEW_LOAD
                    s->os_Grs[q] = EP_SHORT_FORGETTING * s->os_Grs[q] + dGr[q];
                    s->os_Gphis[q] = EP_SHORT_FORGETTING * s->os_Gphis[q] + dGphi[q];
#endif
                }
                for (q = 0; q < EP_OS; ++q) {
                    s->os_c[q] = EP_FORGETTING * s->os_c[q] + dc[q];
#if EP_NEW_LOAD
                    s->os_cs[q] = EP_SHORT_FORGETTING * s->os_cs[q] + dc[q];
#endif
                }
                if (s->os_restarts != s->os_restarts_seen) {  /* a new load */
                    s->os_restarts_seen = s->os_restarts;
                    for (q = 0; q < EP_OS_D * EP_OS; ++q) s->os_Gr[q] = s->os_Gphi[q] = s->os_Grs[q] = s->os_Gphis[q] = EP_C(0.0);
                    for (q = 0; q < EP_OS; ++q) s->os_c[q] = s->os_cs[q] = EP_C(0.0);
                } else if (s->os_settles != s->os_settles_seen) {  /* the settle: the short memory */
                    s->os_settles_seen = s->os_settles;
                    for (q = 0; q < EP_OS_D * EP_OS; ++q) {
                        s->os_Gr[q] = s->os_Grs[q];
                        s->os_Gphi[q] = s->os_Gphis[q];
                    }
                    for (q = 0; q < EP_OS; ++q) s->os_c[q] = s->os_cs[q];
                }
@SOLVE@
                if (have)
                    for (q = 0; q < EP_OS; ++q) ss += g[q] * g[q];
                s->os_std = isfinite(ss) ? EP_MATH(sqrt)(ss) : EP_C(0.0);
            }
""".replace("@REGRESSOR@", regressor).replace("@SOLVE@", solve)
    step = _replace(step, "        s->terms_next = (slot + 1) % EP_BALANCE;\n",
                    sample + "        s->terms_next = (slot + 1) % EP_BALANCE;\n")
    step = _replace(step, "d_num += wt * (bal[3 + j] * bal[j]);",
                    "s->os_w[j] = wt;\n                d_num += wt * (bal[3 + j] * bal[j]);")
    step = _replace(step, "restarted = 1;", "restarted = 1;\n                    s->os_restarts += 1;")
    step = _replace(step, "s->info = s->info_short;",
                    "s->info = s->info_short;\n                        s->os_settles += 1;")
    marker = "        }\n    }\n    if (" + ("EP_NZ_INFO(s)" if nuisance else "s->info") + " <= EP_C(0.0)"
    step = _replace(step, marker, window + marker)
    header = [f"#define EP_OS {k}  /* the zero's offsets, whitened by their posterior */",
              f"#define EP_OS_D {d}  /* the weighing's regressor per joint */"]
    if nuisance:  # the filter keeps its regressors per joint and, per solve, T h0 and T theta
        fields += ["ep_real nz_a[3 * EP_NZ_D];  /* the window's regressors per joint (OffsetShare) */",
                   "ep_real nz_Th0[EP_NZ_D];    /* T (H^-1 e_0) of the last solve */",
                   "ep_real nz_Ttheta[EP_NZ_D]; /* T theta of the last solve */"]
        step = _replace(step, "                    for (q = 0; q < EP_NZ_D; ++q) {\n"
                              "                        for (r = 0; r < EP_NZ_D; ++r) dS[",
                        "                    for (q = 0; q < EP_NZ_D; ++q) s->nz_a[j * EP_NZ_D + q] = a[q];\n"
                        "                    for (q = 0; q < EP_NZ_D; ++q) {\n"
                        "                        for (r = 0; r < EP_NZ_D; ++r) dS[")
        keep = """    {  /* OffsetShare: h0 = H^-1 e_0 (L^T h0 = e), then T h0 and T theta */
        ep_real h0[EP_NZ_P];
        for (i = EP_NZ_P - 1; i >= 0; --i) {
            ep_real a = e[i];
            for (k = i + 1; k < EP_NZ_P; ++k) a -= L[k * EP_NZ_P + i] * h0[k];
            h0[i] = a / L[i * EP_NZ_P + i];
        }
        for (i = 0; i < EP_NZ_D; ++i) {
            ep_real th = EP_C(0.0), tt = EP_C(0.0);
            for (j = 0; j < EP_NZ_P; ++j) {
                th += T[i * EP_NZ_P + j] * h0[j];
                tt += T[i * EP_NZ_P + j] * y[j];
            }
            s->nz_Th0[i] = th;
            s->nz_Ttheta[i] = tt;
        }
    }
"""
        anchor = "    s->nz_payload = y[0];\n    s->nz_info = isfinite(var)"
        defs = [_replace(x, anchor, keep + anchor) if anchor in x else x for x in defs]
    return {"header": header, "step": step, "fields": fields, "reset": reset, "defs": defs}


def with_offset_share(sigma: str, model_var: float) -> str:
    """A σ body with the zero's share added to the model variance.

    Parameters
    ----------
    sigma : str
        The σ body (its one ``+ model_var)``).
    model_var : float
        The model variance written in it, kg².
    """
    return _replace(sigma, f"+ {c_number(model_var)})", f"+ {c_number(model_var)} + s->os_std * s->os_std)")
