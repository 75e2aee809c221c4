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


def measure(a) -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import bench_machine_draws as bmd

    from excavator_payload.estimators.classical.calibrated import CalibratedEstimator
    from excavator_payload.estimators.classical.machine_calibration import solver, weighing

    res = {"seed": a.seed, "motions": a.motions, "s": {}, "seconds": {}}

    def cross_check(dataset, calibrate_fold, weigh_with, folds=2):
        if folds != 2:  # train's second check before a refusal: not what is measured here
            return solver.cross_validated_model_std(dataset, calibrate_fold, weigh_with, folds=folds)
        n = len(dataset.experiment_ids)
        for k in a.folds:
            k = n if k == 0 or k > n else k
            t0 = time.time()
            res["s"][str(k)] = solver.cross_validated_model_std(dataset, calibrate_fold, weigh_with, folds=k)
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
        from excavator_payload.estimators.classical.machine_calibration import solver, weighing

        def bench_folds(d, c, w, folds=2):  # σ's s from K folds; train's refusal check as it is
            return solver.cross_validated_model_std(d, c, w, folds=a.bench if folds == 2 else folds)

        weighing.cross_validated_model_std = bench_folds
        sys.argv = [str(Path(__file__).resolve().parent / "bench_machine_draws.py")] + [r for r in rest if r != "--"]
        runpy.run_path(sys.argv[0], run_name="__main__")
    elif a.analyse:
        analyse(a)
    else:
        measure(a)


if __name__ == "__main__":
    main()
