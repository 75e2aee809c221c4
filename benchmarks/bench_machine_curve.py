"""The calibration-count curve of the default (momentum) form, over several calibration draws.

How many calibration motions does a technician need? ``bench_machine_study.py`` answers it for
the per-sample form on one draw. This benchmark repeats the technician's procedure for
``--draws`` independent draws (ten calibration motions with known payloads 0 / half rated /
rated, cycled, in session 1; a zero check in session 2), keeps the first 0, 1, 2, 3, 5 and 10
of each draw's motions (0: the 3 % machine file as it is, zeroed), and judges each calibrated
machine on the same session-2 test sets (draw 0 is the study's calibration, as in
``bench_machine_draws.py``).

Usage::

    PYTHONPATH=src python benchmarks/bench_machine_curve.py --draws 3 --n-test 100 --out curve

Writes ``OUT/curve.csv`` (one row per draw, form, count and test set) and
``OUT/calibration_curve.png``, and prints mean, worst and best draw per count.
"""

from __future__ import annotations

import argparse
import copy
import time
from pathlib import Path

import numpy as np
import pandas as pd

from excavator_payload.estimators.classical import calibrated_machine as cm
from excavator_payload.estimators.classical.calibrated import CalibratedEstimator
from excavator_payload.evaluation import demo_machine as dm

COUNTS = (0, 1, 2, 3, 5, 10)
PRIOR = "cat345c-hydraulic-3pct"


def uncalibrated(reference: CalibratedEstimator) -> CalibratedEstimator:
    """The 3 % file as it is: a calibrated estimator's structure with every parameter back at
    the file's value and the prior's covariance (the zero check then sets the offsets)."""
    est = copy.deepcopy(reference)
    est.calibration.z[:] = 0.0
    est.calibration.covariance = np.diag(est.calibration.prior_std(0.05) ** 2)
    est.calibration.angle_coverage = np.tile([-cm.NO_LIMIT, cm.NO_LIMIT], (3, 1))  # no motions seen
    est.use_calibration()
    return est


def figure(frame: pd.DataFrame, path: Path, sets: list[str], titles: dict[str, str]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(sets), figsize=(4.2 * len(sets), 6.2), sharex=True, squeeze=False)
    for k, name in enumerate(sets):
        for form, colour in (("momentum", "C0"), ("differentiated", "C1")):
            rows = frame[(frame["test"] == name) & (frame["balance"] == form)]
            if rows.empty:
                continue
            g = rows.groupby("calibration_motions")
            counts = np.array(sorted(g.groups))
            label = "momentum (default)" if form == "momentum" else "per-sample (differentiated)"
            for row, (column, scale) in enumerate((("mean_max_kg", 1.0), ("within_1pct", 100.0))):
                ax = axes[row, k]
                values = g[column].agg(["mean", "min", "max"]).loc[counts] * scale
                ax.plot(counts, values["mean"], "o-", color=colour, label=label)
                ax.fill_between(counts, values["min"], values["max"], color=colour, alpha=0.15, lw=0)
        axes[0, k].set_title(titles.get(name, name))
        axes[0, k].axhline(50.0, color="k", ls=":", lw=1)
        axes[0, k].set_yscale("log")
        ticks = [t for t in (5, 10, 20, 50, 100, 200, 500, 1000, 2000)
                 if frame["mean_max_kg"].min() / 2 <= t <= frame["mean_max_kg"].max() * 2]
        axes[0, k].set_yticks(ticks, [str(t) for t in ticks])
        axes[0, k].minorticks_off()
        axes[1, k].set_ylim(-3, 103)
        axes[1, k].set_xlabel("calibration motions (plus one zero check)")
        axes[1, k].set_xticks(COUNTS)
    axes[0, 0].set_ylabel("mean MAX error (kg; dotted: 1 % of 5 t)")
    axes[1, 0].set_ylabel("experiments with MAX ≤ 1 % (%)")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle("How many calibration motions: mean over draws, band = worst to best draw", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--draws", type=int, default=3)
    ap.add_argument("--n-test", type=int, default=100)
    ap.add_argument("--seed", type=int, default=7, help="the study's seed (draw 0 = its calibration)")
    ap.add_argument("--sets", nargs="+", default=["nmpc", "work-cycle"], choices=["nmpc", "work-cycle",
                    "slope-5deg", "swing"])
    ap.add_argument("--balance", choices=cm.BALANCE_CHOICES, action="append",
                    help="the form(s) to calibrate (default: momentum)")
    ap.add_argument("--out", type=Path, default=Path("machine-curve"))
    a = ap.parse_args()
    forms = a.balance or ["momentum"]
    a.out.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    tests = {k: v for k, v in dm.test_sets(a.n_test, a.seed + 2).items() if k in a.sets}
    print(f"test sets simulated in {time.time() - t0:.0f} s", flush=True)
    rows = []
    for draw in range(a.draws):
        seed = a.seed + 1000 * draw  # draw 0: the study's calibration and zero check
        cal, zero = dm.calibration_data(max(COUNTS), seed), dm.zero_data(seed + 1)
        for form in forms:
            for count in COUNTS:
                t1 = time.time()
                if count == 0:
                    est = uncalibrated(CalibratedEstimator(PRIOR, balance=form, experiments=1).fit(cal))
                else:
                    est = CalibratedEstimator(PRIOR, balance=form, experiments=count).fit(cal)
                est.zero(zero)
                for name, ds in tests.items():
                    row = dm.summary_row(dm.judge(est, ds, est.name, None), dm.RATED_PAYLOAD, None)
                    rows.append({"draw": draw, "balance": form, "calibration_motions": count, "test": name,
                                 **row})
                    print(f"draw {draw} {form} {count:2d} motions {name}: MAX {row['mean_max_kg']:.1f} kg, "
                          f"RMS {row['mean_rms_kg']:.1f} kg, within 1 % {row['within_1pct']:.1%} "
                          f"({time.time() - t1:.0f} s)", flush=True)
                pd.DataFrame(rows).to_csv(a.out / "curve.csv", index=False)
    frame = pd.DataFrame(rows)
    print("\nmean [worst draw, best draw] over", a.draws, "draws")
    for (form, name, count), g in frame.groupby(["balance", "test", "calibration_motions"]):
        print(f"{form:15s} {name:11s} {count:2d}: MAX {g['mean_max_kg'].mean():6.1f} "
              f"[{g['mean_max_kg'].max():6.1f}, {g['mean_max_kg'].min():6.1f}] kg, within 1 % "
              f"{g['within_1pct'].mean():.1%} [{g['within_1pct'].min():.1%}, {g['within_1pct'].max():.1%}]")
    figure(frame, a.out / "calibration_curve.png", list(tests), dict(dm.SET_TITLES))
    print(f"total {time.time() - t0:.0f} s")


if __name__ == "__main__":
    main()
