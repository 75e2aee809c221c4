"""How many folds should the calibration's cross-check use? (issue 28; docs/findings/any-motion.md,
"The cross-check's folds").

s, the model error carried in σ = √(1/I + s² + s₀²), is fitted by
:func:`~excavator_payload.estimators.classical.machine_calibration.solver.cross_validated_model_std`
on calibrations of part of the calibration motions. With two folds a half calibrates far worse
than the whole on 5-motion draws (s 13.8–23.6 kg against errors' RMS 3–10 kg). This script fits
s with K folds for each K of ``--folds`` (``0``: leave one motion out) on one draw of
``bench_machine_draws`` (draw 0 of ``--seed``: its calibration; the fit is the estimator's own,
momentum form) and times each; ``--analyse`` puts each K's s into the per-cell errors and σ
saved by ``measure_param_share.py`` for the same draw (σ² − s_today² + s_K², the estimates and
statuses as they were) and prints each cell's 2σ coverage.

Usage::

    PYTHONPATH=src python benchmarks/measure_kfold_s.py --seed 101201 --motions 5 --reach 2 \\
        --folds 2 3 0 --out k101201.json
    PYTHONPATH=src python benchmarks/measure_kfold_s.py --analyse /tmp/ps28 k101201.json ...
    # bench_machine_draws.py (its own options after --) with s fitted by K folds, K = 5 here:
    PYTHONPATH=src python benchmarks/measure_kfold_s.py --bench 5 -- --draws 1 --motions 5 ...
"""

from __future__ import annotations

import argparse
import json
import runpy
import sys
import time
from pathlib import Path

import numpy as np

SETS = ("nmpc", "work-cycle", "slope-5deg", "lever", "joystick", "multisine")


def kfold_model_std(dataset, calibrate_fold, weigh_with, folds: int) -> float:
    """:func:`~excavator_payload.estimators.classical.machine_calibration.solver.cross_validated_model_std`
    with ``folds`` folds (motion i held out in fold i mod K; K = 2 is today's two halves).

    Parameters
    ----------
    dataset : Dataset
        The calibration motions (known payloads).
    calibrate_fold : callable
        ``calibrate_fold(subset) -> MachineCalibration``.
    weigh_with : callable
        ``weigh_with(calibration) -> estimator`` weighing with it.
    folds : int
        K, at most the number of motions (then leave-one-motion-out).
    """
    from excavator_payload.estimators.classical.machine_calibration.settings import SIGMA_COVERAGE

    ids = list(dataset.experiment_ids)
    k = min(folds, len(ids))
    errors, variances = [], []
    for i in range(k):
        test = ids[i::k]
        fold = weigh_with(calibrate_fold(dataset.subset([e for e in ids if e not in test])))
        held = dataset.subset(test)
        out = fold.estimate(held)
        f = held.frame
        t = f["time"].to_numpy(float)
        start = f.groupby("experiment", sort=False)["time"].transform("min").to_numpy(float)
        sigma = out["sigma"].to_numpy(float)
        ok = (out["status"].astype(str).to_numpy() == "ok") & (t - start >= 1.0) & np.isfinite(sigma)
        errors.append((out["payload_estimate"].to_numpy(float) - f["payload"].to_numpy(float))[ok])
        variances.append(sigma[ok] ** 2)
    e, v = np.abs(np.concatenate(errors)), np.concatenate(variances)

    def covered(s: float) -> float:
        return float(np.mean(e <= 2.0 * np.sqrt(v + s * s)))

    if not len(e) or covered(0.0) >= SIGMA_COVERAGE:
        return 0.0
    low, high = 0.0, float(e.max())
    for _ in range(40):  # the least s covering SIGMA_COVERAGE, as the solver bisects it
        mid = 0.5 * (low + high)
        low, high = (low, mid) if covered(mid) >= SIGMA_COVERAGE else (mid, high)
    return high


def measure(a) -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import bench_machine_draws as bmd

    from excavator_payload.estimators.classical.calibrated import CalibratedEstimator
    from excavator_payload.estimators.classical.machine_calibration import solver, weighing

    res = {"seed": a.seed, "motions": a.motions, "s": {}, "seconds": {}}

    def cross_check(dataset, calibrate_fold, weigh_with):
        n = len(dataset.experiment_ids)
        for k in a.folds:
            k = n if k == 0 or k > n else k
            t0 = time.time()
            res["s"][str(k)] = kfold_model_std(dataset, calibrate_fold, weigh_with, k)
            res["seconds"][str(k)] = time.time() - t0
            print(f"K={k}: s {res['s'][str(k)]:.2f} kg ({res['seconds'][str(k)]:.0f} s)", flush=True)
        t0 = time.time()
        today = solver.cross_validated_model_std(dataset, calibrate_fold, weigh_with)
        res["seconds"]["today"] = time.time() - t0
        assert "2" not in res["s"] or abs(today - res["s"]["2"]) < 1e-9, (today, res["s"]["2"])  # K = 2: today's
        return today

    weighing.cross_validated_model_std = cross_check
    cal = bmd.calibration(a.motions, a.seed, a.reach)
    t0 = time.time()
    CalibratedEstimator("cat345c-hydraulic-3pct", balance="momentum").fit(cal)
    res["fit_seconds"] = time.time() - t0 - sum(res["seconds"].values())
    a.out.write_text(json.dumps(res, indent=1))
    print(json.dumps(res))


def analyse(a) -> None:
    schemes = ("2", "3", "4", "5", "LOMO")  # K = 5 on a 5-motion draw is LOMO; K > n counts as n
    rows, count = [], {k: [0, 0, 0, 1.0] for k in schemes}
    for path in a.analyse[1:]:
        r = json.loads(Path(path).read_text())
        d = np.load(Path(a.analyse[0]) / f"p{r['seed']}.npz")
        today, n = float(d["s"]), r["motions"]
        for k in schemes:
            key = str(n) if k == "LOMO" else str(min(int(k), n))
            if key not in r["s"]:
                continue
            s, cells = r["s"][key], []
            for name in SETS:
                e, v = d[name + "_e"], d[name + "_v"]
                v = np.maximum(v - today**2, 0.0) + s**2
                cov = float(np.mean(np.abs(e) <= 2 * np.sqrt(v)))
                cells.append(cov)
                c = count[k]
                c[0 if 0.90 <= cov <= 0.99 else (1 if cov > 0.99 else 2)] += 1
                c[3] = min(c[3], cov)
            rows.append(f"{r['seed']} ({n}) K={k:>4}: s {s:5.1f} kg ({r['seconds'][key]:4.0f} s) "
                        + " ".join(f"{100 * c:5.1f}" for c in cells))
    print("\n".join(rows))
    for k, c in count.items():
        print(f"K={k}: in 90-99 % / above / below: {c[0]} / {c[1]} / {c[2]}; lowest {100 * c[3]:.1f} %")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed", type=int, default=101201, help="bench_machine_draws' --seed (its draw 0)")
    ap.add_argument("--motions", type=int, default=5)
    ap.add_argument("--reach", type=int, default=2)
    ap.add_argument("--folds", type=int, nargs="+", default=[2, 3, 0], help="K of each fit (0: one per motion)")
    ap.add_argument("--out", type=Path, default=Path("kfold.json"))
    ap.add_argument("--analyse", nargs="+", help="the directory of measure_param_share's p<seed>.npz, then json files")
    ap.add_argument("--bench", type=int, metavar="K", help="run bench_machine_draws.py (the arguments after --) "
                    "with s fitted by K folds")
    a, rest = ap.parse_known_args()
    if a.bench:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from excavator_payload.estimators.classical.machine_calibration import weighing

        weighing.cross_validated_model_std = lambda d, c, w: kfold_model_std(d, c, w, a.bench)
        sys.argv = [str(Path(__file__).resolve().parent / "bench_machine_draws.py")] + [r for r in rest if r != "--"]
        runpy.run_path(sys.argv[0], run_name="__main__")
    elif a.analyse:
        analyse(a)
    else:
        measure(a)


if __name__ == "__main__":
    main()
