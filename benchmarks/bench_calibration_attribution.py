"""Which of the calibrated parameters carry the calibrated weighing's excess over the oracle.

``bench_efficiency_gap.py`` showed that weighing with the simulator's true machine meets the
efficiency target and the calibrated machine does not. This benchmark takes each tuning draw's
calibration (as that benchmark caches it) and swaps one group of the calibrated vector at a
time between calibrated and true, then zeroes again on the draw's own zero motion (the offsets
take up whatever the swapped group changes, as they would in the field) and weighs the same
test motions:

* ``G→true``: the calibration with group G set to the machine's true values;
* ``only G``: the true machine (every parameter and the lag true) with group G calibrated;
  ``all true``: the true machine with the calibration's offsets, zeroed.

The true values are the simulator's machine file in the calibration's coordinates (relative
deviations from the ``-3pct`` file the calibration starts from). Parameters the calibration
does not fit (house, back pressure, static ratio, Stribeck velocities, bucket length) stay at
the ``-3pct`` file in every variant (``untouched→true`` swaps them in the file itself).

Offsets: ``all δ→true + true offsets`` (and only the pressure or only the angle offsets) sets
the working session's offsets to the simulator's instead of the zero's. ``--refit`` instead
calibrates again with one block of z known (held at the truth, the rest fitted), then zeroes:
what knowing that block would buy, with the fit free to use the rest.

It also prints, per group, the calibration's error against its posterior: the Mahalanobis
distance of the group's error per dimension (≈ 1 when the posterior is honest) and the
largest |error| / posterior σ.

Usage (docs/findings/any-motion.md, "What the calibration gets wrong")::

    PYTHONPATH=src python benchmarks/bench_calibration_attribution.py --cache /tmp/gap --out attribution
    PYTHONPATH=src python benchmarks/bench_calibration_attribution.py --cache /tmp/gap --draws 2 \
        --families nmpc joystick multisine --refit none areas friction inertia geometry lag untouched "all δ"
"""

from __future__ import annotations

import argparse
import copy
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_efficiency_gap import FIELD, N_DELTA, N_OFFSETS, cached, draw_arguments, draws, calibrated, family, per_motion, split  # noqa: E402
from held_out_motions import lever_trajectory  # noqa: E402

from excavator_payload.estimators.classical.calibrated import CalibratedEstimator
from excavator_payload.estimators.classical.machine_calibration import solver
from excavator_payload.estimators.classical.machine_calibration.settings import (
    _PARAM_INDEX, CALIBRATED_PARAMETERS, OFFSET_SIGNALS)
from excavator_payload.evaluation import demo_machine as dm
from excavator_payload.evaluation.crb_machine import machine_bound
from excavator_payload.model.hydraulic import HydraulicArmModel
from excavator_payload.model.machine import load_machine
from excavator_payload.platforms.hydraulic import session_offsets
from excavator_payload.simulation.machine_sensors import lag_delay


def _names(*prefixes: str, exact: tuple[str, ...] = ()) -> tuple[str, ...]:
    return tuple(p for p in CALIBRATED_PARAMETERS if p.startswith(prefixes) or p in exact)


#: The groups of the calibrated vector swapped together.
GROUPS: dict[str, tuple[str, ...]] = {
    "arm geometry": ("boom_length", "dipper_length", "boom_foot_x", "boom_foot_z",
                     *_names("boom_cylinder_parent", "boom_cylinder_child", "dipper_cylinder_parent",
                             "dipper_cylinder_child")),
    "bucket linkage": _names("bucket_cylinder_parent", "rocker_", "link_length", "bucket_point"),
    "boom inertia": _names("boom_mass", "boom_com", "boom_inertia"),
    "dipper inertia": _names("dipper_mass", "dipper_com", "dipper_inertia"),
    "bucket inertia": _names("bucket_mass", "bucket_com", "bucket_inertia"),
    "payload position": ("payload_u", "payload_w"),
    **{f"{c} areas": (f"{c}_cylinder_head_area", f"{c}_cylinder_rod_area") for c in ("boom", "dipper", "bucket")},
    **{f"{c} friction": tuple(f"{c}_cylinder_{k}" for k in ("coulomb", "load_coefficient", "viscous"))
       for c in ("boom", "dipper", "bucket")},
}
LAG = N_DELTA + N_OFFSETS  # index of the IMU lag in z


def true_delta(start: str = "cat345c-hydraulic-3pct", truth: str = "cat345c-hydraulic") -> np.ndarray:
    """The true machine's calibrated parameters as relative deviations from ``start``'s.

    Parameters
    ----------
    start, truth : str
        Machine presets: the file the calibration starts from and the simulator's.
    """
    p0 = np.asarray(HydraulicArmModel(load_machine(start), compiled=False).p, float)[_PARAM_INDEX]
    p1 = np.asarray(HydraulicArmModel(load_machine(truth), compiled=False).p, float)[_PARAM_INDEX]
    return p1 / p0 - 1.0


def group_index(group: str) -> np.ndarray:
    """Indices in z of a group of :data:`GROUPS`.

    Parameters
    ----------
    group : str
        A key of :data:`GROUPS`.
    """
    return np.array([CALIBRATED_PARAMETERS.index(n) for n in GROUPS[group]])


def posterior_check(z: np.ndarray, covariance: np.ndarray, truth: np.ndarray) -> pd.DataFrame:
    """Per group: Mahalanobis distance² of the calibration's error per dimension, the largest
    |error| / posterior σ and the RMS relative error.

    Parameters
    ----------
    z : numpy.ndarray
        The calibration's z (before the zero).
    covariance : numpy.ndarray
        Its posterior covariance.
    truth : numpy.ndarray
        The true relative deviations (:func:`true_delta`).
    """
    rows = []
    for group in GROUPS:
        i = group_index(group)
        err = z[i] - truth[i]
        c = covariance[np.ix_(i, i)]
        keep = np.diag(c) > 0  # held parameters (boom foot) have no posterior
        e, c = err[keep], c[np.ix_(keep, keep)]
        d2 = float(e @ np.linalg.solve(c, e) / len(e)) if len(e) else float("nan")
        rows.append({"group": group, "mahalanobis2_per_dim": d2,
                     "max_abs_z": float(np.max(np.abs(e) / np.sqrt(np.diag(c)))) if len(e) else float("nan"),
                     "rms_rel_error": float(np.sqrt(np.mean(err**2))),
                     "posterior_over_prior": float(np.sqrt(np.mean(np.diag(c)))) / 0.05 if len(e) else float("nan")})
    return pd.DataFrame(rows)


def zero_motion(cache: Path, seed: int, zero_kind: str):
    """The draw's zero motion, as ``bench_machine_draws.py`` makes it."""
    def make():
        if zero_kind == "empty-swing":
            return dm.zero_data(seed + 1)
        return dm.simulate_trajectory(lever_trajectory(1, seed + 1, payloads=[0.0], slow=True), seed + 1,
                                      dm.SESSION_WORK)
    return cached(cache, f"zero_{seed}_{zero_kind}", make)


def variant(est, before_zero: np.ndarray, zero, swap: np.ndarray, truth: np.ndarray, lag: float | None,
            untouched_true: bool = False):
    """``est`` with z before its zero, the entries ``swap`` set to ``truth`` (and the lag to
    ``lag`` unless None), zeroed again on ``zero``.

    Parameters
    ----------
    est : CalibratedEstimator
        The draw's zeroed estimator.
    before_zero : numpy.ndarray
        Its calibration's z before the zero.
    zero : Dataset
        The draw's zero motion.
    swap : numpy.ndarray
        Indices of z (calibrated parameters) to set to the truth.
    truth : numpy.ndarray
        True relative deviations of the calibrated parameters.
    lag : float or None
        The IMU lag to set (s), or None to keep the calibrated one.
    untouched_true : bool
        Also set the parameters the calibration does not fit to the true machine file's.
    """
    out = copy.deepcopy(est)
    cal = out.calibration
    z = before_zero.copy()
    z[swap] = truth[swap]
    if lag is not None:
        z[LAG] = lag
    cal.z = z
    if untouched_true:
        p_true = np.asarray(HydraulicArmModel(load_machine("cat345c-hydraulic"), compiled=False).p, float)
        p = p_true.copy()
        p[_PARAM_INDEX] = cal.p_file[_PARAM_INDEX]
        cal.p_file = p
    out.zero(zero, force=True)
    return out


def true_offsets() -> np.ndarray:
    """The working session's true offsets (:data:`OFFSET_SIGNALS`, SI units)."""
    b = session_offsets(dm.SESSION_WORK, FIELD)
    return np.array([b[name] for name in OFFSET_SIGNALS])


def with_offsets(est, which: np.ndarray):
    """``est`` with the offsets ``which`` (indices into :data:`OFFSET_SIGNALS`) set to the truth.

    Parameters
    ----------
    est : CalibratedEstimator
        A zeroed estimator.
    which : numpy.ndarray
        Offsets to set.
    """
    out = copy.deepcopy(est)
    z = out.calibration.z.copy()
    z[N_DELTA + which] = true_offsets()[which]
    out.calibration.z = z
    out.use_calibration()
    return out


#: ``--refit`` blocks: z entries held at the truth while the rest is calibrated.
REFIT = {"areas": ("boom areas", "dipper areas", "bucket areas"),
         "friction": ("boom friction", "dipper friction", "bucket friction"),
         "inertia": ("boom inertia", "dipper inertia", "bucket inertia"),
         "geometry": ("arm geometry", "bucket linkage"), "all δ": tuple(GROUPS), "lag": (),
         "untouched": ()}


def refit(motions: int, reach: int, seed: int, zero, known: str, truth: np.ndarray):
    """The draw's calibration again with the block ``known`` of :data:`REFIT` held at the truth
    (its prior mean the truth, its prior std 1e-6), zeroed on ``zero``. ``untouched``: the
    parameters the calibration does not fit set to the true file's in the machine it starts from.

    Parameters
    ----------
    motions, reach, seed : int
        The draw (``dm.calibration_mix``).
    zero : Dataset
        Its zero motion.
    known : str
        A key of :data:`REFIT`.
    truth : numpy.ndarray
        True relative deviations of the calibrated parameters.
    """
    idx = np.array(sorted({int(i) for g in REFIT[known] for i in group_index(g)} | ({LAG} if known == "lag" else set())),
                   dtype=int)
    target = np.r_[truth, np.zeros(N_OFFSETS), lag_delay(FIELD.imu_lag, 0.01), np.zeros(4)]
    original = solver.MachineCalibration.solve

    def solve(self, values, qdd, payload, free, prior_mean, prior_std, *args, **kw):
        if len(free) > N_OFFSETS and known == "untouched":
            p = np.asarray(HydraulicArmModel(load_machine("cat345c-hydraulic"), compiled=False).p, float)
            p[_PARAM_INDEX] = self.p_file[_PARAM_INDEX]
            self.p_file = p
        elif len(free) > N_OFFSETS:  # the calibration's solves, not the zero's: the caller's arrays
            prior_mean[idx], prior_std[idx] = target[idx], 1e-6  # (the second pass restarts from them)
            z = self.z.copy()
            z[idx] = target[idx]
            self.z = z
        return original(self, values, qdd, payload, free, prior_mean, prior_std, *args, **kw)

    solver.MachineCalibration.solve = solve
    try:
        est = CalibratedEstimator("cat345c-hydraulic-3pct", balance="momentum", model_std="none").fit(
            dm.calibration_mix(motions, seed, reach=reach))
    finally:
        solver.MachineCalibration.solve = original
    est.zero(zero, force=True)
    return est


def main() -> None:
    ap = draw_arguments(argparse.ArgumentParser(), "attribution", 4)
    ap.add_argument("--variants", nargs="+", default=None, help="labels to run (default: all)")
    ap.add_argument("--refit", nargs="+", default=None, choices=["none", *REFIT],
                    help="instead of the swaps: calibrate again with these blocks known")
    a = ap.parse_args()
    a.cache.mkdir(parents=True, exist_ok=True)
    a.out.mkdir(parents=True, exist_ok=True)
    truth = true_delta()
    true_lag = lag_delay(FIELD.imu_lag, 0.01)
    all_delta = np.arange(N_DELTA)
    t0 = time.time()
    rows, checks = [], []
    for motions, reach, seed, draw, s, zero_kind in draws(a.runs, a.draws):
        est, before_zero = calibrated(a.cache, motions, reach, s, zero_kind)
        zero = zero_motion(a.cache, s, zero_kind)
        check = posterior_check(before_zero, est.calibration.covariance, truth)
        checks.append(check.assign(seed=seed, draw=draw))
        print(check.round(3).to_string(index=False), flush=True)
        ways = {"calibrated (re-zeroed)": (np.array([], int), None, False),
                "all δ→true": (all_delta, None, False),
                "all δ + lag→true": (all_delta, true_lag, False),
                "lag→true": (np.array([], int), true_lag, False)}
        for g in GROUPS:
            ways[f"{g}→true"] = (group_index(g), None, False)
            ways[f"only {g}"] = (np.setdiff1d(all_delta, group_index(g)), true_lag, True)
        ways["only lag"] = (all_delta, None, True)
        ways["all true"] = (all_delta, true_lag, True)
        ways["untouched→true"] = (np.array([], int), None, True)
        for label, which in (("all δ→true + true offsets", np.arange(N_OFFSETS)),
                             ("all δ→true + true pressure offsets", np.arange(6)),
                             ("all δ→true + true angle offsets", np.arange(6, N_OFFSETS))):
            ways[label] = (all_delta, None, False, which)
        if a.refit:
            ways = {f"refit, {k} known": (k, None) for k in a.refit}
            if "all δ" in a.refit:  # what the working session's offsets leave with every parameter exact
                for label, which in (("offsets", np.arange(N_OFFSETS)), ("pressure offsets", np.arange(6)),
                                     ("angle offsets", np.arange(6, N_OFFSETS))):
                    ways[f"refit, all δ known + true {label}"] = ("all δ", which)
        if a.variants:
            ways = {k: v for k, v in ways.items() if k in a.variants}
        for label, way in ways.items():
            if isinstance(way[0], str):
                known, which = way
                out = cached(a.cache, f"refit_{known}_{motions}_{reach}_{s}_{zero_kind}",
                             lambda: est if known == "none" else refit(motions, reach, s, zero, known, truth))
                if which is not None:
                    out = with_offsets(out, which)
            else:
                out = variant(est, before_zero, zero, way[0], truth, way[1], way[2])
                if len(way) > 3:
                    out = with_offsets(out, way[3])
            for name in a.families:
                ds = family(a.cache, name, a.n_test, seed)
                bound = cached(a.cache, f"bound_{name}_{seed}_{draw}",
                               lambda: machine_bound(ds, est.calibration, pressure_std=FIELD.pressure_noise))
                row = {"seed": seed, "draw": draw, "family": name, "label": label,
                       **split(per_motion(out, ds, bound))}
                rows.append(row)
            print(f"{seed} draw {draw} {label:28s} " + "  ".join(
                f"{r['family']} {r['efficiency']:.2f}" for r in rows[-len(a.families):])
                  + f"  ({time.time() - t0:.0f} s)", flush=True)
        pd.DataFrame(rows).to_csv(a.out / "attribution.csv", index=False)
        pd.concat(checks).to_csv(a.out / "posterior.csv", index=False)
    table = pd.DataFrame(rows)
    print("\nmedian efficiency over draws:")
    print(table.pivot_table(index="label", columns="family", values="efficiency", aggfunc="median",
                            sort=False).round(2).to_string())
    print("\nposterior check, median over draws:")
    print(pd.concat(checks).groupby("group", sort=False).median(numeric_only=True).round(3).to_string())
    print(f"total {time.time() - t0:.0f} s")


if __name__ == "__main__":
    main()
