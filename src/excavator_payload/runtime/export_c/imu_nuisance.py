"""C port of ``calibrated --imu-nuisance on`` (``machine_calibration/imu_nuisance.py``,
``ImuNuisanceFilter``): the IMU dynamics re-estimated per load beside the momentum kernel.

:func:`imu_nuisance_c` gives the generated Jacobian function and patches the machine set's
C pieces (``pressure_regression.py``): per sample the whitened Jacobian of the balance terms
into a ring beside the terms, per window the sums S, t (and their short memory), the new
load's restart and the settle, the solve, and the reported estimate, information and sigma.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from excavator_payload.runtime.export_c.c_text import c_number


def imu_nuisance_functions(kernel) -> dict:
    """``{"ep_imu_jacobian": f}``: one sample's balance terms' Jacobian (12 × n, column-major)
    in the whitened nuisances, the fitted machine as constants; inputs ``x``, ``qdd``.

    Parameters
    ----------
    kernel : CalibratedKernel
        The kernel with its ``_imu_nuisance`` filter.
    """
    from excavator_payload.estimators.classical.machine_calibration.settings import IMU_PARAMETERS, SIGNALS
    from excavator_payload.estimators.classical.machine_calibration.symbolic import _momentum_terms

    nz = kernel._imu_nuisance
    x = ca.SX.sym("x", len(SIGNALS))
    qdd = ca.SX.sym("qdd", 4)
    imu = ca.SX.sym("imu", len(IMU_PARAMETERS))
    A = _momentum_terms(x, qdd, ca.DM(np.asarray(kernel._p, float)), ca.DM(np.asarray(kernel._offset, float)),
                        imu)[0]
    free = ca.vertcat(*[imu[IMU_PARAMETERS.index(name)] for name in nz.names])
    J = ca.mtimes(ca.jacobian(A, free), ca.DM(nz.L))
    J = ca.substitute(J, imu, ca.DM(np.asarray(kernel._imu, float)))
    return {"ep_imu_jacobian": ca.Function("ep_imu_jacobian", [x, qdd], [ca.densify(J)], ["x", "qdd"], ["jac"])}


def _replace(text: str, old: str, new: str) -> str:
    if text.count(old) != 1:
        raise RuntimeError(f"imu_nuisance C port: the machine set's C changed near {old[:40]!r}")
    return text.replace(old, new)


def imu_nuisance_c(kernel, call: str, step: str, fields: list, reset: str, sigma_var: str) -> dict:
    """The machine set's C pieces with the filter in.

    Parameters
    ----------
    kernel : CalibratedKernel
        The kernel with its ``_imu_nuisance`` filter.
    call : str
        C statements calling ``ep_imu_jacobian`` (``casadi_call``) into ``jac``.
    step, reset : str
        The model's step and reset bodies.
    fields : list of str
        The state's fields.
    sigma_var : str
        The model error's variance (C number).

    Returns
    -------
    dict
        ``header`` (defines), ``defs`` (constants, the solve), ``step``, ``fields``, ``reset``,
        ``sigma``.
    """
    nz = kernel._imu_nuisance
    n, d, p = nz.n, 1 + 2 * nz.n, 1 + nz.n
    defs = "\n".join([
        "/* --imu-nuisance on (ImuNuisanceFilter): the IMU dynamics re-estimated per load */",
        f"#define EP_NZ_HALF_RATED {c_number(0.5 * nz.rated)}",
        f"#define EP_NZ_KNOWN_INFO {c_number(1.0 / 50.0**2)}",
        "#define EP_NZ_INFO(s) ((s)->info > EP_C(0.0) ? (s)->nz_info : EP_C(0.0))",
    ])
    fields = fields + [
        "ep_real nz_terms[EP_BALANCE * 12 * EP_NZ];  /* whitened d(terms)/du per slot, column-major */",
        "ep_real nz_S[EP_NZ_D * EP_NZ_D];  /* sum w a a^T */",
        "ep_real nz_t[EP_NZ_D];            /* sum w a r0 */",
        "ep_real nz_Ss[EP_NZ_D * EP_NZ_D]; /* the short memory's */",
        "ep_real nz_ts[EP_NZ_D];",
        "ep_real nz_w[3];     /* the window's weights */",
        "ep_real nz_mlin;     /* payload the Jacobian is taken at */",
        "ep_real nz_payload;  /* the filter's payload */",
        "ep_real nz_info;     /* 1 / its marginal variance (0: none) */",
        "unsigned int nz_restarts, nz_restarts_seen, nz_settles, nz_settles_seen;",
    ]
    reset = reset + """
    {
    int i;
    for (i = 0; i < EP_NZ_D * EP_NZ_D; ++i) s->nz_S[i] = s->nz_Ss[i] = EP_C(0.0);
    for (i = 0; i < EP_NZ_D; ++i) s->nz_t[i] = s->nz_ts[i] = EP_C(0.0);
    for (i = 0; i < EP_BALANCE * 12 * EP_NZ; ++i) s->nz_terms[i] = EP_C(0.0);
    s->nz_mlin = EP_NZ_HALF_RATED;
    s->nz_payload = EP_NAN;
    s->nz_info = EP_C(0.0);
    s->nz_restarts = s->nz_restarts_seen = s->nz_settles = s->nz_settles_seen = 0;
    }"""
    sample = f"""        {{  /* ImuNuisanceFilter.sample: the whitened Jacobian of this sample's terms */
            ep_real jac[12 * EP_NZ];
{call}
            for (i = 0; i < 12 * EP_NZ; ++i) s->nz_terms[slot * 12 * EP_NZ + i] = jac[i];
        }}
"""
    window = """            {  /* ImuNuisanceFilter.window: the window's a = [phi, dr0, dphi] per joint into S, t */
                ep_real dS[EP_NZ_D * EP_NZ_D], dt[EP_NZ_D], a[EP_NZ_D], dint[6 * EP_NZ], dmom[6 * EP_NZ];
                int q, r, ok = 1;
                for (i = 0; i < 6 * EP_NZ; ++i) dint[i] = dmom[i] = EP_C(0.0);
                for (i = 0; i < EP_NZ_D * EP_NZ_D; ++i) dS[i] = EP_C(0.0);
                for (i = 0; i < EP_NZ_D; ++i) dt[i] = EP_C(0.0);
                for (k = 0; k < EP_BALANCE; ++k) {
                    const ep_real *jt = s->nz_terms + ((s->terms_next + k) % EP_BALANCE) * 12 * EP_NZ;
                    for (q = 0; q < EP_NZ; ++q)
                        for (j = 0; j < 6; ++j) {
                            dint[j * EP_NZ + q] += EP_BALANCE_W[k] * jt[q * 12 + 6 + j];
                            dmom[j * EP_NZ + q] += EP_BALANCE_U[k] * jt[q * 12 + j];
                        }
                }
                for (j = 0; j < 3; ++j) {
                    if (!(s->nz_w[j] > EP_C(0.0))) continue;
                    a[0] = bal[3 + j];
                    for (q = 0; q < EP_NZ; ++q) {
                        a[1 + q] = (dint[j * EP_NZ + q] - dmom[j * EP_NZ + q]) / EP_BALANCE_SPAN;
                        a[1 + EP_NZ + q] = (dmom[(3 + j) * EP_NZ + q] - dint[(3 + j) * EP_NZ + q]) / EP_BALANCE_SPAN;
                    }
                    for (q = 0; q < EP_NZ_D; ++q) {
                        for (r = 0; r < EP_NZ_D; ++r) dS[q * EP_NZ_D + r] += (a[q] * s->nz_w[j]) * a[r];
                        dt[q] += (a[q] * s->nz_w[j]) * bal[j];
                    }
                }
                for (q = 0; q < EP_NZ_D * EP_NZ_D; ++q) ok = ok && isfinite(dS[q]);
                for (q = 0; q < EP_NZ_D; ++q) ok = ok && isfinite(dt[q]);
                if (!ok) {  /* a hostile sample's Jacobian: the window adds nothing */
                    for (q = 0; q < EP_NZ_D * EP_NZ_D; ++q) dS[q] = EP_C(0.0);
                    for (q = 0; q < EP_NZ_D; ++q) dt[q] = EP_C(0.0);
                }
                for (q = 0; q < EP_NZ_D * EP_NZ_D; ++q) {
                    s->nz_S[q] = EP_FORGETTING * s->nz_S[q] + dS[q];
#if EP_NEW_LOAD
                    s->nz_Ss[q] = EP_SHORT_FORGETTING * s->nz_Ss[q] + dS[q];
#endif
                }
                for (q = 0; q < EP_NZ_D; ++q) {
                    s->nz_t[q] = EP_FORGETTING * s->nz_t[q] + dt[q];
#if EP_NEW_LOAD
                    s->nz_ts[q] = EP_SHORT_FORGETTING * s->nz_ts[q] + dt[q];
#endif
                }
                if (s->nz_restarts != s->nz_restarts_seen) {  /* a new load: per load */
                    s->nz_restarts_seen = s->nz_restarts;
                    for (q = 0; q < EP_NZ_D * EP_NZ_D; ++q) s->nz_S[q] = s->nz_Ss[q] = EP_C(0.0);
                    for (q = 0; q < EP_NZ_D; ++q) s->nz_t[q] = s->nz_ts[q] = EP_C(0.0);
                    s->nz_mlin = EP_NZ_HALF_RATED;
                } else if (s->nz_settles != s->nz_settles_seen) {  /* the settle: the short memory */
                    s->nz_settles_seen = s->nz_settles;
                    for (q = 0; q < EP_NZ_D * EP_NZ_D; ++q) s->nz_S[q] = s->nz_Ss[q];
                    for (q = 0; q < EP_NZ_D; ++q) s->nz_t[q] = s->nz_ts[q];
                }
                ep_nz_solve(s);
            }
"""
    step = _replace(step, "        s->terms_next = (slot + 1) % EP_BALANCE;\n",
                    sample + "        s->terms_next = (slot + 1) % EP_BALANCE;\n")
    step = _replace(step, "d_num += wt * (bal[3 + j] * bal[j]);",
                    "s->nz_w[j] = wt;\n                d_num += wt * (bal[3 + j] * bal[j]);")
    step = _replace(step, "restarted = 1;", "restarted = 1;\n                    s->nz_restarts += 1;")
    step = _replace(step, "s->info = s->info_short;",
                    "s->info = s->info_short;\n                        s->nz_settles += 1;")
    marker = "        }\n    }\n    if (s->info <= EP_C(0.0)"
    step = _replace(step, marker, window + marker)
    step = _replace(step, "    if (s->info <= EP_C(0.0)", "    if (EP_NZ_INFO(s) <= EP_C(0.0)")
    step = _replace(step, "    *estimate = s->num / s->info;", "    *estimate = s->nz_payload;")
    step = _replace(step, "    if (s->info < EP_WARM_INFO)", "    if (EP_NZ_INFO(s) < EP_WARM_INFO)")
    solve = """/* ImuNuisanceFilter.solve: (T^T S T + diag(0, I)) theta = T^T t at the previous payload */
static void ep_nz_solve(ep_state *s)
{
    ep_real T[EP_NZ_D * EP_NZ_P], ST[EP_NZ_D * EP_NZ_P], H[EP_NZ_P * EP_NZ_P], g[EP_NZ_P], L[EP_NZ_P * EP_NZ_P];
    ep_real y[EP_NZ_P], e[EP_NZ_P], var;
    int i, j, k;
    if (!(s->nz_S[0] > EP_C(0.0))) {
        s->nz_payload = EP_NAN;
        s->nz_info = EP_C(0.0);
        return;
    }
    for (i = 0; i < EP_NZ_D * EP_NZ_P; ++i) T[i] = EP_C(0.0);
    T[0] = EP_C(1.0);
    for (i = 0; i < EP_NZ; ++i) {
        T[(1 + i) * EP_NZ_P + 1 + i] = EP_C(-1.0);
        T[(1 + EP_NZ + i) * EP_NZ_P + 1 + i] = s->nz_mlin;
    }
    for (i = 0; i < EP_NZ_D; ++i)
        for (j = 0; j < EP_NZ_P; ++j) {
            ep_real acc = EP_C(0.0);
            for (k = 0; k < EP_NZ_D; ++k) acc += s->nz_S[i * EP_NZ_D + k] * T[k * EP_NZ_P + j];
            ST[i * EP_NZ_P + j] = acc;
        }
    for (i = 0; i < EP_NZ_P; ++i) {
        ep_real acc = EP_C(0.0);
        for (k = 0; k < EP_NZ_D; ++k) acc += T[k * EP_NZ_P + i] * s->nz_t[k];
        g[i] = acc;
        for (j = 0; j < EP_NZ_P; ++j) {
            acc = EP_C(0.0);
            for (k = 0; k < EP_NZ_D; ++k) acc += T[k * EP_NZ_P + i] * ST[k * EP_NZ_P + j];
            H[i * EP_NZ_P + j] = acc + ((i == j && i > 0) ? EP_C(1.0) : EP_C(0.0));
        }
    }
    for (j = 0; j < EP_NZ_P; ++j) {  /* Cholesky H = L L^T */
        ep_real diag = H[j * EP_NZ_P + j];
        for (k = 0; k < j; ++k) diag -= L[j * EP_NZ_P + k] * L[j * EP_NZ_P + k];
        if (!(diag > EP_C(0.0))) {
            s->nz_payload = EP_NAN;
            s->nz_info = EP_C(0.0);
            return;
        }
        L[j * EP_NZ_P + j] = EP_MATH(sqrt)(diag);
        for (i = j + 1; i < EP_NZ_P; ++i) {
            ep_real acc = H[i * EP_NZ_P + j];
            for (k = 0; k < j; ++k) acc -= L[i * EP_NZ_P + k] * L[j * EP_NZ_P + k];
            L[i * EP_NZ_P + j] = acc / L[j * EP_NZ_P + j];
        }
    }
    for (i = 0; i < EP_NZ_P; ++i) {  /* L y = g, L e = e_0 */
        ep_real a = g[i], b = i == 0 ? EP_C(1.0) : EP_C(0.0);
        for (k = 0; k < i; ++k) {
            a -= L[i * EP_NZ_P + k] * y[k];
            b -= L[i * EP_NZ_P + k] * e[k];
        }
        y[i] = a / L[i * EP_NZ_P + i];
        e[i] = b / L[i * EP_NZ_P + i];
    }
    for (i = EP_NZ_P - 1; i >= 0; --i) {  /* L^T theta = y (theta into y) */
        ep_real a = y[i];
        for (k = i + 1; k < EP_NZ_P; ++k) a -= L[k * EP_NZ_P + i] * y[k];
        y[i] = a / L[i * EP_NZ_P + i];
    }
    var = EP_C(0.0);
    for (i = 0; i < EP_NZ_P; ++i) var += e[i] * e[i];
    if (!(var > EP_C(0.0)) || !isfinite(y[0])) {
        s->nz_payload = EP_NAN;
        s->nz_info = EP_C(0.0);
        return;
    }
    s->nz_payload = y[0];
    s->nz_info = isfinite(var) ? EP_C(1.0) / var : EP_C(0.0);
    if (s->nz_info > EP_NZ_KNOWN_INFO) s->nz_mlin = s->nz_payload;
}
"""
    sigma = ("    /* _estimate_sigma: sqrt(1/I + s_model^2), I the payload's marginal information */\n"
             f"    return EP_NZ_INFO(s) > EP_C(0.0) ? EP_MATH(sqrt)(EP_C(1.0) / EP_NZ_INFO(s) + {sigma_var}) : EP_NAN;")
    header = [f"#define EP_NZ {n}  /* --imu-nuisance on: nuisances re-estimated */",
              f"#define EP_NZ_D {d}  /* a = [phi, dr0 (n), dphi (n)] */",
              f"#define EP_NZ_P {p}  /* theta = (m, u) */"]
    return {"header": header, "defs": defs + "\n" + solve, "step": step, "fields": fields, "reset": reset,
            "sigma": sigma}
