"""A zero that moves the calibrated parameters too, under the calibration's posterior.

The default zero (``zero_offsets``) re-estimates the eleven sensor offsets alone, the calibrated
parameters frozen at values fitted together with the calibration session's offsets
(docs/findings/any-motion.md, "What the calibration gets wrong"). Here the zero also frees a
set of parameters (``zero_offsets(parameters=…)``): prior N(calibrated z, the calibration's
posterior covariance, the parameters' block × ``inflation``), the offsets' prior the
calibration's offsets with their posterior plus the drift's variance (``correlated``: with the
calibration's parameter–offset correlations). Each tuning draw of ``bench_efficiency_gap.py``
is calibrated once (cached before its zero), zeroed on its own zero motion per variant, and
weighs the same test motions against the same bound.

Variants (``--variants``): ``offsets`` (main's zero), ``all×K`` (every fitted parameter and
the lag, inflation K), ``all×K-indep`` (without the correlations), ``areas+geometry×K``,
``areas×K``, ``geometry×K``, ``inertia×K``, ``friction×K`` (a block freed alone: its prior
conditioned on the rest held), ``none×1`` (the offsets alone, their prior the calibration's
offsets posterior given the parameters plus the drift, where main's zero takes the drift alone).

Usage (docs/findings/any-motion.md, "A zero that moves the parameters")::

    PYTHONPATH=src python benchmarks/bench_zero_parameters.py --cache /tmp/gap --runs 10:3:1401 \
        --draws 2 --variants offsets all×1 all×4 areas+geometry×1
"""

from __future__ import annotations

import argparse
import copy
import sys
import time
from functools import partial
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_calibration_attribution import GROUPS, group_index, zero_motion  # noqa: E402
from bench_efficiency_gap import FIELD, N_DELTA, N_OFFSETS, cached, draw_arguments, draws, family, per_motion, split  # noqa: E402

from excavator_payload.estimators.classical.calibrated import CalibratedEstimator
from excavator_payload.estimators.classical.machine_calibration import solver, weighing
from excavator_payload.estimators.classical.machine_calibration.settings import (
    CALIBRATED_PARAMETERS, HELD_IN_MOMENTUM)
from excavator_payload.evaluation import demo_machine as dm
from excavator_payload.evaluation.crb_machine import machine_bound

LAG = N_DELTA + N_OFFSETS
#: Parameter sets a variant may free (indices of z).
SETS = {
    "all": np.r_[np.setdiff1d(np.arange(N_DELTA), [CALIBRATED_PARAMETERS.index(n) for n in HELD_IN_MOMENTUM]),
                 LAG],
    "areas": np.concatenate([group_index(g) for g in GROUPS if g.endswith("areas")]),
    "geometry": np.r_[group_index("arm geometry"), group_index("bucket linkage")],
}
SETS["geometry"] = np.setdiff1d(SETS["geometry"], [CALIBRATED_PARAMETERS.index(n) for n in HELD_IN_MOMENTUM])
SETS["areas+geometry"] = np.r_[SETS["areas"], SETS["geometry"]]
SETS["inertia"] = np.concatenate([group_index(g) for g in GROUPS if g.endswith("inertia")])
SETS["friction"] = np.concatenate([group_index(g) for g in GROUPS if g.endswith("friction")])
SETS["none"] = np.array([], int)  # the offsets alone, their prior the calibration's posterior plus the drift


def parse(label: str) -> dict | None:
    """``zero_offsets`` keywords of a variant label (None: main's zero).

    Parameters
    ----------
    label : str
        ``offsets`` or ``SET×K[-indep]``.
    """
    if label == "offsets":
        return None
    name, rest = label.split("×")
    k, _, indep = rest.partition("-")
    return {"parameters": SETS[name], "inflation": float(k), "correlated": indep != "indep"}


def zeroed(fitted, zero, keywords: dict | None):
    """A copy of the fitted (not yet zeroed) estimator, zeroed on ``zero`` by the variant.

    Parameters
    ----------
    fitted : CalibratedEstimator
        The draw's calibration before its zero.
    zero : Dataset
        The draw's zero motion.
    keywords : dict or None
        ``zero_offsets`` keywords (None: the default zero).
    """
    est = copy.deepcopy(fitted)
    original = weighing.zero_offsets
    if keywords is not None:
        weighing.zero_offsets = partial(solver.zero_offsets, **keywords)
    try:
        est.zero(zero, force=True)
    finally:
        weighing.zero_offsets = original
    return est


def main() -> None:
    ap = draw_arguments(argparse.ArgumentParser(), "zero-parameters", 2)
    ap.add_argument("--variants", nargs="+", default=["offsets", "all×1", "all×4", "areas+geometry×1"])
    a = ap.parse_args()
    a.cache.mkdir(parents=True, exist_ok=True)
    a.out.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    rows = []
    for motions, reach, seed, draw, s, zero_kind in draws(a.runs, a.draws):
        fitted = cached(a.cache, f"fitted_{motions}_{reach}_{s}", lambda: CalibratedEstimator(
            "cat345c-hydraulic-3pct", balance="momentum").fit(dm.calibration_mix(motions, s, reach=reach)))
        zero = zero_motion(a.cache, s, zero_kind)
        for label in a.variants:
            est = zeroed(fitted, zero, parse(label))
            chi2 = est.zero_quality
            dz = est.calibration.z - fitted.calibration.z
            for name in a.families:
                ds = family(a.cache, name, a.n_test, seed)
                bound = cached(a.cache, f"bound_{name}_{seed}_{draw}",
                               lambda: machine_bound(ds, est.calibration, pressure_std=FIELD.pressure_noise))
                rows.append({"motions": motions, "seed": seed, "draw": draw, "zero": zero_kind, "family": name,
                             "label": label, "refused": len(est.zero_refusals),
                             **split(per_motion(est, ds, bound))})
            print(f"{s} {zero_kind:11s} {label:22s} " + "  ".join(
                f"{r['family']} {r['efficiency']:.2f}" for r in rows[-len(a.families):])
                  + f"  |Δδ| {np.sqrt(np.mean(dz[:N_DELTA] ** 2)):.4f}  refusals {est.zero_refusals}"
                  f"  {getattr(chi2, 'report', lambda: '')()[:90]}  ({time.time() - t0:.0f} s)", flush=True)
            pd.DataFrame(rows).to_csv(a.out / "zero_parameters.csv", index=False)
    table = pd.DataFrame(rows)
    print("\nmedian efficiency over draws:")
    print(table.pivot_table(index="label", columns="family", values="efficiency", aggfunc="median",
                            sort=False).round(2).to_string())
    cells = table.groupby("label", sort=False)["efficiency"]
    print(pd.DataFrame({"median": cells.median(), "worst": cells.max()}).round(2).to_string())
    print(f"total {time.time() - t0:.0f} s")


if __name__ == "__main__":
    main()
