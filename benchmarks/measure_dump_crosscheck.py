"""Where the dump rule (a dump restarts the weighing) fires: in the calibration's two-fold
cross-check (which moves the cross-checked model error s) and on the test families.

Builds draw 0 of ``bench_machine_draws.py`` (the same calibration, zero and test sets for a
seed), fits the default (momentum) form, and logs every dump restart of the kernel with the
experiment and the time it happened at. The cross-check is recomputed here per held-out
experiment (the same numbers as :func:`~.solver.cross_validated_model_std`, which resets the
kernel at each experiment too) so each restart is attributed to its motion (swing or `reach`).

Usage::

    PYTHONPATH=src python benchmarks/measure_dump_crosscheck.py --seed 16101 --motions 10 --reach 3 \
        --zero empty-swing --n-test 12 [--set DUMP_RESTARTS=False] [--no-tests]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_machine_draws import judge, zero_motion  # noqa: E402
from held_out_motions import joystick_trajectory, lever_trajectory, multisine_trajectory  # noqa: E402

from excavator_payload.estimators.classical.calibrated import CalibratedEstimator
from excavator_payload.estimators.classical.machine_calibration import kernel as kernel_module
from excavator_payload.estimators.classical.machine_calibration import solver, weighing
from excavator_payload.evaluation import demo_machine as dm
from excavator_payload.evaluation.crb_machine import dataset_machine_bound

EVENTS: list = []  # (label, experiment, sample) of each dump restart
LABEL = {"label": "", "experiment": -1}
_accumulate = kernel_module.CalibratedKernel._accumulate


def _logged(self, *args, **kwargs):
    before = self.dump_restarts
    out = _accumulate(self, *args, **kwargs)
    if self.dump_restarts > before and (LABEL.get("kernel") is None or LABEL["kernel"] is self):
        EVENTS.append((LABEL["label"], LABEL["experiment"], self._count))
    return out


kernel_module.CalibratedKernel._accumulate = _logged
CROSS: dict = {}


def per_experiment(est, ds, label):
    """``est.estimate(ds)`` one experiment at a time, its restarts labelled."""
    frames = []
    for e in ds.experiment_ids:
        LABEL.update(label=label, experiment=int(e))
        frames.append(est.estimate(ds.subset([e])))
    return pd.concat(frames, ignore_index=True)


def logged_cross(dataset, calibrate_fold, weigh_with, folds=2):
    """:func:`~.solver.cross_validated_model_std`, logging each held-out experiment of the halves
    (train's second check before a refusal, ``folds`` > 2, runs unlogged)."""
    if folds != 2:
        return solver.cross_validated_model_std(dataset, calibrate_fold, weigh_with, folds=folds)
    ids = list(dataset.experiment_ids)
    rows = []
    for fold_no, (train, test) in enumerate(((ids[0::2], ids[1::2]), (ids[1::2], ids[0::2]))):
        fold = weigh_with(calibrate_fold(dataset.subset(train)))
        held = dataset.subset(test)
        out = per_experiment(fold, held, f"cross{fold_no}")
        f = held.frame.reset_index(drop=True)
        t = f["time"].to_numpy(float)
        start = f.groupby("experiment", sort=False)["time"].transform("min").to_numpy(float)
        sigma = out["sigma"].to_numpy(float)
        ok = (out["status"].astype(str).to_numpy() == "ok") & (t - start >= 1.0) & np.isfinite(sigma)
        err = out["payload_estimate"].to_numpy(float) - f["payload"].to_numpy(float)
        rows.append(pd.DataFrame({"experiment": f["experiment"].to_numpy(), "ok": ok, "e": err, "v": sigma ** 2}))
    table = pd.concat(rows, ignore_index=True)
    CROSS["table"] = table
    s = solver.cross_validated_model_std.__wrapped_original__(dataset, calibrate_fold, weigh_with) \
        if CROSS.get("check") else None
    ok = table[table["ok"]]
    e, v = np.abs(ok["e"].to_numpy()), ok["v"].to_numpy()
    low, high = 0.0, float(e.max())
    if np.mean(e <= 2 * np.sqrt(v)) >= solver.SIGMA_COVERAGE:
        return 0.0
    for _ in range(40):
        mid = 0.5 * (low + high)
        low, high = (low, mid) if np.mean(e <= 2 * np.sqrt(v + mid * mid)) >= solver.SIGMA_COVERAGE else (mid, high)
    if s is not None:
        print(f"check: s here {high:.4f}, the solver's {s:.4f}")
    return high


solver.cross_validated_model_std.__wrapped_original__ = solver.cross_validated_model_std
weighing.cross_validated_model_std = logged_cross


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=16101)
    ap.add_argument("--motions", type=int, default=10)
    ap.add_argument("--reach", type=int, default=3)
    ap.add_argument("--zero", default="empty-swing", choices=["empty-swing", "slow-lever"])
    ap.add_argument("--n-test", type=int, default=12)
    ap.add_argument("--sets", nargs="+", default=["nmpc", "work-cycle", "slope-5deg", "lever", "joystick",
                                                   "multisine"])
    ap.add_argument("--no-tests", action="store_true", help="the cross-check only")
    ap.add_argument("--check", action="store_true", help="also run the solver's cross-check (equal s)")
    ap.add_argument("--set", action="append", default=[], help="NAME=VALUE: a kernel setting for this run")
    a = ap.parse_args()
    for item in a.set:
        name, value = item.split("=")
        setattr(kernel_module, name, type(getattr(kernel_module, name))(eval(value)))
    CROSS["check"] = a.check
    t0 = time.time()
    cal = dm.calibration_mix(a.motions, a.seed, reach=a.reach)
    kinds = {e: ("reach" if k >= a.motions - a.reach else "swing") for k, e in enumerate(cal.experiment_ids)}
    zero = zero_motion(a.zero, a.seed)
    est = CalibratedEstimator("cat345c-hydraulic-3pct", balance="momentum").fit(cal)
    s = est.calibration.model_std
    table = CROSS["table"]
    loads = cal.frame.groupby("experiment")["payload"].first()
    print(f"seed {a.seed} ({a.motions} motions, {a.reach} reach) settings {a.set or 'main'}: s = {s:.2f} kg "
          f"({time.time() - t0:.0f} s)")
    for e in cal.experiment_ids:
        ev = [n / 100 for lab, x, n in EVENTS if lab.startswith("cross") and x == e]
        g = table[(table["experiment"] == e) & table["ok"]]
        print(f"  cross-check held-out {kinds[e]:5s} exp {e:3d} load {loads[e]:6.0f} kg: restarts at "
              f"{', '.join(f'{x:.1f}' for x in ev) or '-':24s} ok {len(g) / 100:5.1f} s  "
              f"RMS err {np.sqrt(np.mean(g['e'] ** 2)) if len(g) else np.nan:6.1f} kg  "
              f"max |e| {np.abs(g['e']).max() if len(g) else np.nan:6.1f} kg")
    if a.no_tests:
        return
    est.zero(zero)
    tests = {k: v for k, v in dm.test_sets(a.n_test, a.seed + 2).items() if k in a.sets}
    makers = {"lever": (lever_trajectory, 4), "joystick": (joystick_trajectory, 5),
              "multisine": (multisine_trajectory, 6)}
    for name, (make, k) in makers.items():
        if name in a.sets:
            tests[name] = dm.simulate_trajectory(make(a.n_test, a.seed + k), a.seed + k, dm.SESSION_WORK)
    reset = est.reset

    def counted_reset():  # estimate() resets at each experiment: count them
        LABEL["experiment"] += 1
        reset()

    est.reset = counted_reset
    LABEL["kernel"] = est.kernel.regression  # not the twins judge() weighs σ without the zero's part with
    for name, ds in tests.items():
        del EVENTS[:]
        bound = dataset_machine_bound(ds, est)
        LABEL.update(label=name, experiment=-1)
        # the bench's judged stretch (work cycles to the dump)
        row = judge(est, ds, "momentum", bound)
        ids = list(ds.experiment_ids)
        EVENTS[:] = [(lab, ids[x], t) for lab, x, t in EVENTS]
        n = len(EVENTS)
        where = [f"{x}@{t / 100:.1f}s" for _, x, t in EVENTS][:8]
        print(f"  {name:12s} dump restarts {n} in {len({x for _, x, _ in EVENTS})} of "
              f"{len(ds.experiment_ids)} motions {where}  2σ covers {row['sigma_covers']:.1%}  "
              f"MAX {row['mean_max_kg']:.1f} kg  eff {row['efficiency']:.2f}  ({time.time() - t0:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
