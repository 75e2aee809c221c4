"""Would the calibration's parameter posterior, carried per estimate through the estimate's own
sensitivity as ``OffsetShare`` carries the zero's offsets, make the momentum form's σ cover its
error per cell (family × calibration draw)? Measured 2026-11-30 (issue 28), not built:
docs/findings/any-motion.md, "The calibration's parameter share per estimate".

σ today is √(1/I + s² + s₀²). The candidate adds k²·s_p², s_p the calibration's share: the running
sums of :class:`~excavator_payload.estimators.classical.machine_calibration.offset_share.OffsetShare`
with the per-sample Jacobian of the balance terms by the calibrated parameters δ
(∂p/∂δ = p_file) and by the offsets, mapped by M = [[I, 0], [D, K]]·L: L Lᵀ the calibration's
joint posterior of (δ, o) (before the zero replaced its offsets' block); after a zero the offsets
are the zero's, ô(δ, o_cal), and follow as ∂ô = D ∂δ + K ∂o_cal, D = −H⁻¹J_oᵀWJ_δ, K = H⁻¹P,
H = J_oᵀWJ_o + P over the zero motion's windows (:func:`zero_response`); before a zero (the
cross-check's halves) D = 0, K = I. ``--variant naive``: the offsets held (M = [[I, 0], [0, 0]]·L,
δ's marginal posterior alone); ``inertias``: the links' inertias alone.

The share is hooked into ``MachineWeighing.kernel`` (in the kernel's ``_offset_share`` slot, beside
the zero's share: :class:`Shares`) and the zero's response into ``MachineWeighing.zero`` at run
time (src/ unchanged). One draw of ``bench_machine_draws`` (same calibration, zero and test sets)
is weighed twice per set — k = 0 and k = 1, the estimates and statuses asserted identical — and
per judged ``ok`` sample the error, σ² today and s_p² are recorded, on the test sets and on the
calibration's two-fold cross-check. ``--analyse`` fits (s, k) on the cross-check by rules
(``today``; ``added``: s today and k = 1; ``refit``: k = 1 and s fitted beside it; ``minmean``:
the least mean σ covering 95 % over a grid of k) and prints each cell's 2σ coverage and median σ,
the correlations and k chosen on the test cells (an oracle). ``--lift``: the lift's first ``ok``
after a fill (``lift_start_windows --first-ok``'s passes). ``--check``: the sums against finite
differences of the whole weighing, and D against zeroing again with moved parameters.

Usage::

    PYTHONPATH=src python benchmarks/measure_param_share.py --seed 100101 --motions 10 --reach 3 \\
        --zero empty-swing --n-test 8 --out p100101.npz
    PYTHONPATH=src python benchmarks/measure_param_share.py --analyse p100101.npz ...
    PYTHONPATH=src python benchmarks/measure_param_share.py --lift
    PYTHONPATH=src python benchmarks/measure_param_share.py --check
"""

from __future__ import annotations

import argparse
import math
import sys
from functools import lru_cache
from pathlib import Path

import casadi as ca
import numpy as np
import pandas as pd

from excavator_payload.estimators.classical.machine_calibration.offset_share import OffsetShare
from excavator_payload.estimators.classical.machine_calibration.settings import (
    _OFFSET_COLUMNS, _PARAM_INDEX, CALIBRATED_PARAMETERS, IMU_PARAMETERS, OFFSET_PRIOR_STD, OFFSET_SIGNALS,
    SIGNALS)
from excavator_payload.estimators.classical.machine_calibration.symbolic import _momentum_terms
from excavator_payload.model.codegen import native
from excavator_payload.model.hydraulic import HYDRAULIC_PARAMETER_NAMES

sys.path.insert(0, str(Path(__file__).resolve().parent))
import sigma_terms  # noqa: E402
from sigma_terms import SETS, band, least_s  # noqa: E402

_N_DELTA, _N_OFF = len(CALIBRATED_PARAMETERS), len(OFFSET_SIGNALS)


@lru_cache(maxsize=1)
def parameter_jacobian_function() -> ca.Function:
    """One streaming sample's momentum-balance terms' Jacobian (12 × 66) by the calibrated
    entries of the model's parameter vector p (:data:`CALIBRATED_PARAMETERS`, in p's units) and
    by the offsets :data:`OFFSET_SIGNALS`, compiled; the inputs of
    :func:`~.symbolic.kernel_function` (momentum form)."""
    x = ca.SX.sym("x", len(SIGNALS))
    qdd = ca.SX.sym("qdd", 4)
    p = ca.SX.sym("p", len(HYDRAULIC_PARAMETER_NAMES))
    offsets = ca.SX.sym("offsets", len(SIGNALS))
    imu = ca.SX.sym("imu", len(IMU_PARAMETERS))
    A = _momentum_terms(x, qdd, p, offsets, imu)[0]
    free = ca.vertcat(*[p[int(i)] for i in _PARAM_INDEX], *[offsets[int(i)] for i in _OFFSET_COLUMNS])
    jac = ca.densify(ca.jacobian(A, free))
    return native(ca.Function("cal_machine_parameter_jacobian", [x, qdd, p, offsets, imu], [jac]))


def zero_response(cal, values, qdd, payload, runs, drift_std=OFFSET_PRIOR_STD) -> np.ndarray:
    """(D | K) (11 × 66): how the zero's offsets follow the calibrated parameters δ and the
    calibration's offsets (its prior mean), to first order, on the zero motion's windows (the
    module doc); the windows' weights as ``zero_offsets`` holds them.

    Parameters
    ----------
    cal : MachineCalibration
        The zeroed calibration (momentum form; its z the zero's result).
    values, qdd, payload, runs : numpy.ndarray
        The zero motion's arrays (``calibration_arrays``).
    drift_std : numpy.ndarray
        The offsets' prior std in the zero (their drift between sessions), Pa or rad.
    """
    r, J, lever, speed, stiction, _ = cal.evaluate_windows(values, qdd, payload, cal.z, runs)
    w = cal.weights(lever, speed, stiction, "skip", cal.pressure_std) / cal.window_inflation
    ok = np.isfinite(r) & np.isfinite(w) & np.all(np.isfinite(J), axis=2)
    w = np.where(ok, w, 0.0)
    J = np.where(ok[..., None], J, 0.0)
    Jd, Jo = J[:, :, :_N_DELTA], J[:, :, _N_DELTA:_N_DELTA + _N_OFF]
    P = np.diag(1.0 / np.asarray(drift_std, float) ** 2)
    H = np.einsum("nja,nj,njb->ab", Jo, w, Jo) + P
    D = -np.linalg.solve(H, np.einsum("nja,nj,njb->ab", Jo, w, Jd))
    K = np.linalg.solve(H, P)
    return np.hstack([D, K])


def parameter_map(cal, names=None, compensated: bool = True) -> np.ndarray:
    """M (66 × k): the per-sample Jacobian by (p's calibrated entries, offsets) to the whitened
    calibration errors (the module doc): p_file scales δ into p; after a zero (``cal.zero_response``
    set) the offsets follow as (D | K); L whitens the calibration's joint posterior of (δ, o)
    (``cal.fit_covariance``, else ``cal.covariance``).

    Parameters
    ----------
    cal : MachineCalibration
        The calibration weighed with.
    names : sequence of str or None
        Carry the errors of these :data:`CALIBRATED_PARAMETERS` only (None: all, and the
        calibration's offsets).
    compensated : bool
        The offsets follow the parameters (the module doc); False: the offsets held, the
        parameters' marginal posterior alone (measured: docs/findings/any-motion.md).
    """
    n = _N_DELTA + _N_OFF
    C = np.asarray(getattr(cal, "fit_covariance", None) if getattr(cal, "fit_covariance", None) is not None
                   else cal.covariance, float)[:n, :n]
    lam, V = np.linalg.eigh(0.5 * (C + C.T))
    keep = lam > 1e-12 * max(lam.max(), 1e-300)
    L = V[:, keep] * np.sqrt(lam[keep])
    response = getattr(cal, "zero_response", None)
    A = np.eye(n)
    if not compensated:
        A[_N_DELTA:, :] = 0.0
    elif response is not None:  # zeroed: the offsets are the zero's, following δ and o_cal
        A[_N_DELTA:, :] = np.asarray(response, float)
    if names is not None:  # the other entries' errors not carried
        A[:, [i for i in range(n) if i >= _N_DELTA or CALIBRATED_PARAMETERS[i] not in names]] = 0.0
    A[:_N_DELTA, :] *= np.asarray(cal.p_file, float)[_PARAM_INDEX][:, None]  # ∂p/∂δ
    return A @ L


class ParameterShare(OffsetShare):
    """The calibration's parameter share of the current estimate's σ (kg), beside a
    momentum-form :class:`~.kernel.CalibratedKernel` (see the module doc); the sums and the
    solve are :class:`~.offset_share.OffsetShare`'s.

    Parameters
    ----------
    cal : MachineCalibration
        The calibration weighed with (its joint posterior; after a zero, its response).
    balance_len : int
        Samples of the kernel's momentum window.
    regressors : int
        Entries of the weighing's regressor a per joint (1, or 1 + 2n with the IMU filter).
    **options
        :func:`parameter_map`'s ``names`` and ``compensated``.
    """

    columns = _N_DELTA + _N_OFF  # the Jacobian's: the calibrated parameters, then the offsets

    def __init__(self, cal, balance_len: int, regressors: int = 1, **options):
        self.L = parameter_map(cal, **options)
        self.k = self.L.shape[1]
        self.d = int(regressors)
        self._balance_len = balance_len
        self._jac = self._jacobian_function()
        self._trigger = None
        self.reset()

    def _jacobian_function(self):
        return parameter_jacobian_function()

    def _gradient(self, kernel):
        """OffsetShare's, kept (``--check`` reads it)."""
        self.gradient = super()._gradient(kernel)
        return self.gradient


class Shares:
    """The kernel's ``_offset_share`` slot holding the zero's share (after a zero; else None)
    and the parameter share: every call forwarded, std = hypot(zero's, scale × parameters')."""

    def __init__(self, offset, param, scale: float):
        self.offset, self.param, self.scale = offset, param, float(scale)

    def reset(self) -> None:
        for s in (self.offset, self.param):
            if s is not None:
                s.reset()

    def sample(self, kernel, slot) -> None:
        for s in (self.offset, self.param):
            if s is not None:
                s.sample(kernel, slot)

    def window(self, kernel, start, w, a, residual) -> None:
        for s in (self.offset, self.param):
            if s is not None:
                s.window(kernel, start, w, a, residual)

    def restart(self, kernel) -> None:
        for s in (self.offset, self.param):
            if s is not None:
                s.restart(kernel)

    @property
    def std(self) -> float:
        return math.hypot(self.offset.std if self.offset is not None else 0.0, self.scale * self.param.std)


STATE = {"scale": 0.0, "options": {}}
#: --variant: what the share carries (param_share.parameter_map's options)
INERTIAS = tuple(f"{link}_inertia_{k}" for link in ("boom", "dipper", "bucket") for k in ("u", "y", "w"))
VARIANTS = {"compensated": {}, "naive": {"compensated": False},
            "inertias-naive": {"compensated": False, "names": INERTIAS},
            "inertias": {"names": INERTIAS}}


def patch() -> None:
    """The share in every momentum kernel (its factor ``STATE['scale']`` at construction, then
    its :class:`Shares`' ``scale``), and the calibration's joint posterior and the zero's response
    stored on the calibration at a zero."""
    from excavator_payload.estimators.classical.machine_calibration import weighing as w
    from excavator_payload.estimators.classical.machine_calibration.data import calibration_arrays
    from excavator_payload.estimators.classical.machine_calibration.settings import CALIBRATION_HALF_WINDOW

    kernel, zero = w.MachineWeighing.kernel, w.MachineWeighing.zero

    def _kernel(self, options):
        k = kernel(self, options)
        if k.balance == "momentum":
            regressors = 1 + 2 * k._imu_nuisance.n if k._imu_nuisance is not None else 1
            share = ParameterShare(self.calibration, k._balance_len, regressors, **STATE["options"])
            k._offset_share = Shares(k._offset_share, share, STATE["scale"])
        return k

    def _zero(self, dataset, options):
        cal = self.calibration
        if getattr(cal, "fit_covariance", None) is None:
            cal.fit_covariance = np.array(cal.covariance, float)
        out = zero(self, dataset, options)
        values, qdd, payload, runs = calibration_arrays(dataset, CALIBRATION_HALF_WINDOW, cal.arm.machine)
        cal.zero_response = zero_response(cal, values, qdd, payload, runs)
        return out

    w.MachineWeighing.kernel, w.MachineWeighing.zero = _kernel, _zero


def set_share(est, value: float) -> None:
    """The parameter share's scale k in σ² (0: σ as today)."""
    est.kernel.regression._offset_share.scale = value


def measure(a) -> None:
    """Draw 0 weighed with the parameter share off and on (``sigma_terms.measure``), saved as ``*_sp``."""
    patch()
    STATE["options"] = VARIANTS[a.variant]

    def describe(e, v, sp):
        return (f"2σ today {np.mean(np.abs(e) <= 2 * np.sqrt(v)):.1%}, with the share "
                f"{np.mean(np.abs(e) <= 2 * np.sqrt(v + sp)):.1%}; RMS error {np.sqrt(np.mean(e ** 2)):.1f} kg, "
                f"median σ today {np.median(np.sqrt(v)):.1f} kg, median s_p {np.median(np.sqrt(np.maximum(sp, 0))):.1f} kg")

    sigma_terms.measure(a, set_share, "sp", describe)


def lift(a) -> None:
    """The lift's first ``ok`` after a fill (``lift_start_windows --first-ok``'s passes after a
    truck's first): its error against 2σ today and with the share as each rule sets it. The
    study's estimator (``bench_false_alarms.calibrated('study')``) is fitted and zeroed again here
    with the share hooked in; the ``shift`` chunks are read from ``--lift-cache``."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import wait_after_load as wal

    from excavator_payload.estimators.classical.calibrated import CalibratedEstimator
    from excavator_payload.estimators.classical.pressure_regression import PressureKernel
    from excavator_payload.evaluation import demo_machine as dm

    patch()
    STATE["options"] = VARIANTS[a.variant]
    PressureKernel.step = wal._recording_step(PressureKernel.step)
    cross = sigma_terms.record_cross_check(set_share)
    est = CalibratedEstimator("cat345c-hydraulic-3pct").fit(dm.calibration_data(10, 9200))
    est.zero(dm.zero_data(9150))
    e, v, sp = cross[-1]
    s_today = est.calibration.model_std
    runs = []
    for k in (0.0, 1.0):  # σ today, and with the share: s_p per pass
        rows = []
        for seed in (int(x) for x in a.lift_seeds.split(",")):
            est.kernel.regression._offset_share.scale = k
            t = wal.study_chunk(est, a.lift_cache / f"shift_{seed}_field_0.parquet", "shift", 0)
            t = t[(t["changing_truth"] != True) & (t["load"] > 0)]  # noqa: E712
            rows.append(t[t.groupby("experiment").cumcount() > 0])  # after a truck's first pass
        runs.append(pd.concat(rows))
    err = runs[0]["first_error"].to_numpy(float)
    assert np.array_equal(err, runs[1]["first_error"].to_numpy(float), equal_nan=True)
    v0 = runs[0]["first_sigma"].to_numpy(float) ** 2
    sp_first = runs[1]["first_sigma"].to_numpy(float) ** 2 - v0
    print(f"{len(err)} first ok; s_p there median {np.nanmedian(np.sqrt(np.maximum(sp_first, 0))):.1f} kg, "
          f"largest {np.nanmax(np.sqrt(np.maximum(sp_first, 0))):.1f} kg; the study's test samples' s_p "
          f"on its cross-check median {np.median(np.sqrt(np.maximum(sp, 0))):.1f} kg")
    rules = [(rule, *fit(rule, e, v, sp)) for rule in ("today", "refit", "minmean")]
    rules += [(f"oracle k={k}", s_today, k) for k in (2.0, 4.0, 8.0, 16.0, 32.0)]
    for rule, s, k in rules:
        sd = np.sqrt(np.maximum(v0 - s_today**2, 0.0) + s * s + k * k * np.maximum(sp_first, 0))
        print(f"{rule:12s} s {s:5.2f} (today {s_today:.2f}) k {k:5.2f}: within 2σ "
              f"{np.mean(np.abs(err) <= 2 * sd):.0%}, median σ {np.nanmedian(sd):.1f} kg, |error| median "
              f"{np.nanmedian(np.abs(err)):.1f} kg", flush=True)


def check(a) -> None:
    """The share's sums against finite differences of the whole weighing along random whitened
    directions of M (the calibration moved by h·M u, weighed again), and D against zeroing again
    with the parameters moved; the tests' fixture (three swings, no cross-check, the empty swing
    of seed 6, one swing of seed 7)."""
    import copy

    from excavator_payload.data.schema import MACHINE_SENSORS
    from excavator_payload.estimators.base import create_estimator
    from excavator_payload.evaluation import demo_machine as dm
    from excavator_payload.simulation.generate import simulate_dataset
    from excavator_payload.simulation.machine_sim import simulate_machine_dataset

    patch()
    STATE["options"] = VARIANTS[a.variant]
    fitted = create_estimator("calibrated", machine="cat345c-hydraulic-3pct", model_std="none",
                              imu_nuisance=a.nuisance).fit(simulate_machine_dataset(3, seed=3))
    fitted.health = False
    zd = dm.zero_data(seed=6)
    est = copy.deepcopy(fitted)
    est.zero(zd)
    ds = simulate_dataset(1, seed=7, motion="swing", machine="cat345c-hydraulic", session=dm.SESSION_WORK,
                          with_truth=True, workers=1, progress=False)
    est.reset()
    f = ds.frame
    G, std = [], []
    for t, v in zip(f["time"].to_numpy(float), f[list(MACHINE_SENSORS.signals)].to_numpy(float)):
        r = est.step_values(t, v)
        share = est.kernel.regression._offset_share.param
        G.append(getattr(share, "gradient", np.zeros(share.k)) if r.status.value == "ok" else np.full(share.k, np.nan))
        std.append(share.std)
    G = np.array(G)
    ok = np.all(np.isfinite(G), axis=1)
    cal = est.calibration
    Mz = parameter_map(cal, **STATE["options"])
    Mz[:_N_DELTA] /= np.asarray(cal.p_file, float)[_PARAM_INDEX][:, None]  # in z's units
    z0, h = cal.z.copy(), 0.5
    rng = np.random.default_rng(0)
    print(f"{a.variant}, IMU nuisances {a.nuisance}: s_p median {np.median(np.array(std)[ok]):.2f} kg on {ok.sum()} ok samples")
    for trial in range(3):
        u = rng.standard_normal(Mz.shape[1])
        u /= np.linalg.norm(u)
        moved = []
        for sign in (1.0, -1.0):
            cal.z = z0.copy()
            cal.z[:Mz.shape[0]] += sign * h * (Mz @ u)
            est.use_calibration()
            moved.append(est.estimate(ds)["payload_estimate"].to_numpy(float))
        fd = (moved[0] - moved[1]) / (2 * h)
        use = ok & np.isfinite(fd)
        pred = G[use] @ u
        print(f"  direction {trial}: |∂m̂| median, finite differences {np.median(np.abs(fd[use])):.3f} kg, sums "
              f"{np.median(np.abs(pred)):.3f} kg; relative difference median "
              f"{np.median(np.abs(fd[use] - pred) / np.maximum(np.abs(pred), 1e-9)):.3f}")
    cal.z = z0
    D = cal.zero_response[:, :_N_DELTA]
    C = np.asarray(fitted.calibration.covariance, float)
    units = np.r_[[1e5] * 6, [math.pi / 180] * 5]  # bar, degrees
    for trial in range(2):
        dz = rng.standard_normal(_N_DELTA) * np.sqrt(np.diag(C)[:_N_DELTA]) * 0.3
        offsets = []
        for sign in (1.0, -1.0):
            b = copy.deepcopy(fitted)
            b.calibration.z[:_N_DELTA] += sign * dz
            b.zero(zd)
            offsets.append(b.calibration.z[_N_DELTA:_N_DELTA + _N_OFF].copy())
        fd = (offsets[0] - offsets[1]) / 2
        print(f"  zero's offsets, δ moved ({trial}), bar / °: zeroed again " + " ".join(f"{x:+.3f}" for x in fd / units))
        print("                                      D δ          " + " ".join(f"{x:+.3f}" for x in (D @ dz) / units))


def fit(rule, e, v, sp):
    """(s, k) by ``rule`` on one cross-check (v: σ² there with s = 0, i.e. 1/I)."""
    if rule == "today":
        return least_s(e, v), 0.0
    if rule == "added":  # today's s and the share on top
        return least_s(e, v), 1.0
    if rule == "refit":  # k = 1, s fitted beside it
        return least_s(e, v + sp), 1.0
    best = None  # minmean: the least mean σ covering 95 % over a grid of k
    for k in np.r_[0.0, np.geomspace(0.02, 50.0, 60)]:
        s = least_s(e, v + k * k * sp)
        mean = np.mean(np.sqrt(v + k * k * sp + s * s))
        if best is None or mean < best[0]:
            best = (mean, s, k)
    return best[1], best[2]


def analyse(paths) -> None:
    data = [np.load(p) for p in paths]
    rules = ("today", "added", "refit", "minmean")
    totals = {r: [] for r in rules}
    sig = {r: [] for r in rules}
    for p, d in zip(paths, data):
        s_today = float(d["s"])
        keys = [k for k in SETS if k + "_e" in d]
        print(f"{p}: s {s_today:.2f} kg; cross-check median s_p {np.median(np.sqrt(np.maximum(d['cross_sp'], 0))):.1f} kg, "
              f"RMS error {np.sqrt(np.mean(d['cross_e'] ** 2)):.1f} kg")
        print("  cells                        | " + " ".join(f"{k[:9]:>9s}" for k in keys))
        print("  RMS error / median s_p       | " + " ".join(
            f"{np.sqrt(np.mean(d[k + '_e'] ** 2)):4.1f}/{np.median(np.sqrt(np.maximum(d[k + '_sp'], 0))):4.1f}" for k in keys))
        for rule in rules:
            s, k = fit(rule, d["cross_e"], d["cross_v"], d["cross_sp"])
            cells, meds = [], []
            for key in keys:
                var = np.maximum(d[key + "_v"] - s_today**2, 0.0) + s * s + k * k * np.maximum(d[key + "_sp"], 0)
                cells.append(np.mean(np.abs(d[key + "_e"]) <= 2 * np.sqrt(var)))
                meds.append(np.median(np.sqrt(var)))
            totals[rule] += cells
            sig[rule] += meds
            print(f"  {rule:8s} s {s:5.2f} k {k:5.2f}     | " + " ".join(f"{x:9.1%}" for x in cells)
                  + "   median σ " + " ".join(f"{m:.1f}" for m in meds))
    for rule in rules:
        print(f"{rule:8s} {band(totals[rule])}; median σ over cells {np.median(sig[rule]):.1f} kg")
    from scipy.stats import spearmanr

    motions = [(np.mean(np.sqrt(np.maximum(d[k + "_sp"][d[k + "_exp"] == x], 0))),
                np.sqrt(np.mean(d[k + "_e"][d[k + "_exp"] == x] ** 2)))
               for d in data for k in SETS if k + "_e" in d for x in np.unique(d[k + "_exp"])]
    sp_m, rms = np.array(motions).T
    print(f"test motions ({len(sp_m)}): Spearman(mean s_p, RMS error) {spearmanr(sp_m, rms)[0]:.2f}")
    cells = [(np.median(np.sqrt(np.maximum(d[k + "_sp"], 0))), np.sqrt(np.mean(d[k + "_e"] ** 2)))
             for d in data for k in SETS if k + "_e" in d]
    sp_c, rms_c = np.array(cells).T
    print(f"cells ({len(sp_c)}): Spearman(median s_p, RMS error) {spearmanr(sp_c, rms_c)[0]:.2f}")
    ce = np.concatenate([d["cross_e"] for d in data])
    cs = np.concatenate([np.sqrt(np.maximum(d["cross_sp"], 0)) for d in data])
    print(f"cross-check samples ({len(ce)}): Spearman(s_p, |e|) {spearmanr(cs, np.abs(ce))[0]:.2f}")
    for keep in (1.0, 0.5, 0.0):  # oracle: k chosen on the test cells, s kept, halved or dropped
        for k in (0.0, 0.1, 0.2, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0):
            cells = []
            for d in data:
                s_today = float(d["s"])
                for key in [k_ for k_ in SETS if k_ + "_e" in d]:
                    var = np.maximum(d[key + "_v"] - (1 - keep**2) * s_today**2, 0.0) + k * k * np.maximum(d[key + "_sp"], 0)
                    cells.append(np.mean(np.abs(d[key + "_e"]) <= 2 * np.sqrt(var)))
            print(f"oracle s×{keep} k {k:.1f}: {band(cells)}")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed", type=int, default=100101, help="bench_machine_draws' --seed (its draw 0)")
    ap.add_argument("--motions", type=int, default=10)
    ap.add_argument("--reach", type=int, default=3)
    ap.add_argument("--zero", choices=["empty-swing", "slow-lever"], default="empty-swing")
    ap.add_argument("--n-test", type=int, default=8)
    ap.add_argument("--out", type=Path, default=Path("param-share.npz"))
    ap.add_argument("--variant", choices=list(VARIANTS), default="compensated")
    ap.add_argument("--analyse", nargs="+", type=Path, help="analyse these saved measurements instead")
    ap.add_argument("--lift", action="store_true", help="the lift's first ok instead (lift())")
    ap.add_argument("--lift-cache", type=Path, default=Path("/work/scratch/lift28"))
    ap.add_argument("--lift-seeds", default="97000,97100,97200")
    ap.add_argument("--check", action="store_true", help="finite-difference checks instead (check())")
    ap.add_argument("--nuisance", choices=["off", "on"], default="off", help="--check: the IMU nuisance filter")
    a = ap.parse_args()
    if a.check:
        check(a)
    elif a.lift:
        lift(a)
    elif a.analyse:
        analyse(a.analyse)
    else:
        measure(a)


if __name__ == "__main__":
    main()
