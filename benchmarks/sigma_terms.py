"""What the σ measurements share (``measure_sigma_misfit.py``, ``measure_param_share.py``): one
draw of ``bench_machine_draws`` weighed twice per test set — a candidate term of σ² off and on,
the estimates and statuses asserted identical, so the term per sample is σ²(on) − σ²(off) — with
the calibration's own two-fold cross-check recorded the same way; and the coverage arithmetic.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Callable

import numpy as np

SETS = ["nmpc", "work-cycle", "slope-5deg", "lever", "joystick", "multisine"]
COVERAGE = 0.95  # as SIGMA_COVERAGE


def judged_ok(ds, out) -> np.ndarray:
    """``ok`` samples after each experiment's first second with a finite σ (as the cross-check)."""
    f = ds.frame
    t = f["time"].to_numpy(float)
    start = f.groupby("experiment", sort=False)["time"].transform("min").to_numpy(float)
    return (out["status"].astype(str).to_numpy() == "ok") & (t - start >= 1.0) & np.isfinite(out["sigma"].to_numpy(float))


def two_runs(est, ds, set_term: Callable[[object, float], None]):
    """(estimates, σ² without the term, the term) per sample: ``est`` weighs ``ds`` with
    ``set_term(est, 0)`` and ``set_term(est, 1)``.

    Parameters
    ----------
    est : CalibratedEstimator
        Fitted (and zeroed) estimator, its kernel patched with the candidate term.
    ds : Dataset
        The motions to weigh.
    set_term : callable
        ``set_term(est, value)`` switches the candidate term's coefficient.
    """
    set_term(est, 0.0)
    o0 = est.estimate(ds)
    set_term(est, 1.0)
    o1 = est.estimate(ds)
    set_term(est, 0.0)
    assert np.array_equal(o0["payload_estimate"].to_numpy(), o1["payload_estimate"].to_numpy(), equal_nan=True)
    assert (o0["status"].astype(str) == o1["status"].astype(str)).all()
    s0, s1 = o0["sigma"].to_numpy(float), o1["sigma"].to_numpy(float)
    return o0, s0**2, s1**2 - s0**2


def record_cross_check(set_term: Callable[[object, float], None]) -> list:
    """Make ``train``'s two-fold cross-check record, per calibration, its held-out judged samples'
    errors, σ² without the term and the term (three arrays appended to the list returned); s is
    computed as today (the term off).

    Parameters
    ----------
    set_term : callable
        ``set_term(est, value)``: the candidate term's coefficient.
    """
    from excavator_payload.estimators.classical.machine_calibration import solver, weighing

    cross = []

    def cross_check(dataset, calibrate_fold, weigh_with, folds=2):
        if folds != 2:  # train's second check before a refusal: not recorded
            return solver.cross_validated_model_std(dataset, calibrate_fold, weigh_with, folds=folds)
        ids = list(dataset.experiment_ids)
        parts = ([], [], [])
        for train, test in ((ids[0::2], ids[1::2]), (ids[1::2], ids[0::2])):
            fold = weigh_with(calibrate_fold(dataset.subset(train)))
            held = dataset.subset(test)
            out, v, term = two_runs(fold, held, set_term)
            ok = judged_ok(held, out)
            parts[0].append((out["payload_estimate"].to_numpy(float) - held.frame["payload"].to_numpy(float))[ok])
            parts[1].append(v[ok])
            parts[2].append(term[ok])
        cross.append([np.concatenate(p) for p in parts])
        return solver.cross_validated_model_std(dataset, calibrate_fold, weigh_with)

    weighing.cross_validated_model_std = cross_check
    return cross


def measure(a, set_term: Callable[[object, float], None], key: str,
            describe: Callable[[np.ndarray, np.ndarray, np.ndarray], str]) -> None:
    """Weigh draw 0 of ``bench_machine_draws`` (``a.seed``, ``a.motions``, ``a.reach``, ``a.zero``)
    on ``a.n_test`` motions of each of :data:`SETS` with the term off and on, and save per set the
    judged samples' errors, σ² without the term and the term (``<set>_e``, ``_v``, ``_<key>``,
    ``_exp``) and the cross-check's (``cross_*``) to ``a.out``.

    Parameters
    ----------
    a : argparse.Namespace
        The draw and ``out`` (an .npz path).
    set_term : callable
        ``set_term(est, value)``: the candidate term's coefficient (the kernel already patched).
    key : str
        The term's name in the saved file.
    describe : callable
        ``describe(e, v, term)`` of one set's judged samples: the line printed after its name.
    """
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import bench_machine_draws as bmd
    from held_out_motions import joystick_trajectory, lever_trajectory, multisine_trajectory

    from excavator_payload.estimators.classical.calibrated import CalibratedEstimator
    from excavator_payload.evaluation import demo_machine as dm

    cross = record_cross_check(set_term)
    t0 = time.time()
    tests = {k: v for k, v in dm.test_sets(a.n_test, a.seed + 2).items() if k in SETS}
    for name, make, off in (("lever", lever_trajectory, 4), ("joystick", joystick_trajectory, 5),
                            ("multisine", multisine_trajectory, 6)):
        tests[name] = dm.simulate_trajectory(make(a.n_test, a.seed + off), a.seed + off, dm.SESSION_WORK)
    print(f"test sets simulated ({time.time() - t0:.0f} s)", flush=True)
    cal = bmd.calibration(a.motions, a.seed, a.reach)
    zero = bmd.zero_motion(a.zero, a.seed)
    est = CalibratedEstimator("cat345c-hydraulic-3pct", balance="momentum").fit(cal)
    print(f"calibrated ({time.time() - t0:.0f} s)", flush=True)
    est.zero(zero)
    res = {"cross_e": cross[-1][0], "cross_v": cross[-1][1], f"cross_{key}": cross[-1][2],
           "s": est.calibration.model_std}
    for name, ds in tests.items():
        out, v, term = two_runs(est, ds, set_term)
        ok = judged_ok(ds, out)
        e = out["payload_estimate"].to_numpy(float) - ds.frame["payload"].to_numpy(float)
        res[name + "_e"], res[name + "_v"], res[f"{name}_{key}"] = e[ok], v[ok], term[ok]
        res[name + "_exp"] = ds.frame["experiment"].to_numpy()[ok]
        print(f"{name:11s} {describe(e[ok], v[ok], term[ok])} ({time.time() - t0:.0f} s)", flush=True)
        np.savez(a.out, **res)


def least_s(e, v) -> float:
    """The least s with |e| ≤ 2√(v + s²) on COVERAGE of the samples (as the cross-check)."""
    def covered(s):
        return np.mean(np.abs(e) <= 2 * np.sqrt(v + s * s))
    if covered(0.0) >= COVERAGE:
        return 0.0
    low, high = 0.0, float(np.abs(e).max())
    for _ in range(40):
        mid = 0.5 * (low + high)
        low, high = (low, mid) if covered(mid) >= COVERAGE else (mid, high)
    return high


def band(cells) -> str:
    """Cells (2σ coverages) in the 90–99 % band, above and below it, the lowest and the mean."""
    x = np.array(cells)
    return (f"in 90-99 % {np.sum((x >= .9) & (x <= .99))}, above {np.sum(x > .99)}, below {np.sum(x < .9)} "
            f"of {len(x)}; lowest {x.min():.1%}, mean {x.mean():.1%}")
