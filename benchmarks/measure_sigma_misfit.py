"""Would a model error that grows with the windows' misfit make the momentum form's σ cover its
error per motion family? Measured, not built (docs/findings/any-motion.md, session 19).

σ today is √(1/I + s² + s₀²): s the calibration's cross-checked constant, s₀ the zero's share per
estimate. The candidate replaces s² by s_c² + c·χ̄², with χ̄² the weighed windows' χ² at the
estimate m̂, their mean weighted by their information,
Σ wφ²·w(r − m̂φ)² / Σ wφ² = (A − 2m̂B + m̂²C)/I, A = Σ(wφr)², B = Σ(wφr)(wφ²), C = Σ(wφ²)² per joint
and window, forgotten, restarted and settled as N and I. This script adds those sums to
:class:`~excavator_payload.estimators.classical.machine_calibration.kernel.CalibratedKernel` at run
time (src/ is not changed), weighs ``bench_machine_draws``'s draw 0 (same calibration, zero and
test sets) twice — χ̄² per sample is σ² with c = 1 less σ² with c = 0, the estimates and statuses
asserted identical — and records the calibration's own two-fold cross-check (held-out error,
1/I, χ̄²) the same way. ``--analyse`` then fits (s_c, c ≥ 0) on each cross-check — ``minmean``:
the least mean σ with 2σ ⊇ 95 % of the held-out errors over a grid of c; ``ls``: c by least
squares of e² − 1/I on [1, χ̄²], then the least s_c covering 95 % — and prints each test cell's
2σ coverage, the correlations, and c chosen on the test cells themselves (an oracle).

Usage::

    PYTHONPATH=src python benchmarks/measure_sigma_misfit.py --seed 16101 --motions 10 --reach 3 \
        --zero empty-swing --n-test 12 --out t16101.npz
    PYTHONPATH=src python benchmarks/measure_sigma_misfit.py --analyse t16101.npz ...
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

SETS = ["nmpc", "work-cycle", "slope-5deg", "lever", "joystick", "multisine"]
COVERAGE = 0.95  # as SIGMA_COVERAGE


def patch_kernel() -> None:
    """Add the misfit sums and ``misfit_coef`` (kg² per unit χ̄², 0 by default) to the kernel."""
    from excavator_payload.estimators.classical.machine_calibration.kernel import CalibratedKernel as K

    accumulate, restart, settle, reset = K._accumulate, K._restart_load, K._settle, K.reset
    extra = K.extra_std.fget

    def _accumulate(self, d_num, d_info):
        d = (sum(n * n for n in d_num), sum(n * i for n, i in zip(d_num, d_info)), sum(i * i for i in d_info))
        self._mf = [self.forgetting * s + x for s, x in zip(self._mf, d)]
        if self.new_load:
            self._mf_short = [self._short_forgetting * s + x for s, x in zip(self._mf_short, d)]
        accumulate(self, d_num, d_info)  # its restart or settle then resets or copies the sums

    def _restart_load(self):
        restart(self)
        self._mf, self._mf_short = [0.0] * 3, [0.0] * 3

    def _settle(self):
        settle(self)
        self._mf = list(self._mf_short)

    def _reset(self):
        reset(self)
        self._mf, self._mf_short = [0.0] * 3, [0.0] * 3

    def misfit(self):
        if not self.info > 0.0:
            return 0.0
        m = self.estimate
        a, b, c = self._mf
        value = (a - 2.0 * m * b + m * m * c) / self.info
        return value if value > 0.0 and math.isfinite(value) else 0.0

    def extra_std(self):
        zero = extra(self)
        return math.sqrt(zero * zero + getattr(self, "misfit_coef", 0.0) * misfit(self))

    K._accumulate, K._restart_load, K._settle, K.reset = _accumulate, _restart_load, _settle, _reset
    K.extra_std = property(extra_std)


def judged_ok(ds, out) -> np.ndarray:
    """``ok`` samples after each experiment's first second with a finite σ (as the cross-check)."""
    f = ds.frame
    t = f["time"].to_numpy(float)
    start = f.groupby("experiment", sort=False)["time"].transform("min").to_numpy(float)
    return (out["status"].astype(str).to_numpy() == "ok") & (t - start >= 1.0) & np.isfinite(out["sigma"].to_numpy(float))


def two_runs(est, ds):
    """(estimates, σ² as today, χ̄²) per sample: weighed with c = 0 and c = 1."""
    reg = est.kernel.regression
    reg.misfit_coef = 0.0
    o0 = est.estimate(ds)
    reg.misfit_coef = 1.0
    o1 = est.estimate(ds)
    reg.misfit_coef = 0.0
    assert np.array_equal(o0["payload_estimate"].to_numpy(), o1["payload_estimate"].to_numpy(), equal_nan=True)
    assert (o0["status"].astype(str) == o1["status"].astype(str)).all()
    s0, s1 = o0["sigma"].to_numpy(float), o1["sigma"].to_numpy(float)
    return o0, s0**2, s1**2 - s0**2


def measure(a) -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import bench_machine_draws as bmd
    from held_out_motions import joystick_trajectory, lever_trajectory, multisine_trajectory

    from excavator_payload.estimators.classical.calibrated import CalibratedEstimator
    from excavator_payload.estimators.classical.machine_calibration import solver
    from excavator_payload.estimators.classical.machine_calibration import weighing
    from excavator_payload.evaluation import demo_machine as dm

    patch_kernel()
    cross = []

    def cross_check(dataset, calibrate_fold, weigh_with):
        ids = list(dataset.experiment_ids)
        parts = ([], [], [])
        for train, test in ((ids[0::2], ids[1::2]), (ids[1::2], ids[0::2])):
            fold = weigh_with(calibrate_fold(dataset.subset(train)))
            held = dataset.subset(test)
            out, v, chi = two_runs(fold, held)
            ok = judged_ok(held, out)
            parts[0].append((out["payload_estimate"].to_numpy(float) - held.frame["payload"].to_numpy(float))[ok])
            parts[1].append(v[ok])
            parts[2].append(chi[ok])
        cross.append([np.concatenate(p) for p in parts])
        return solver.cross_validated_model_std(dataset, calibrate_fold, weigh_with)  # s as today

    weighing.cross_validated_model_std = cross_check
    t0 = time.time()
    tests = {k: v for k, v in dm.test_sets(a.n_test, a.seed + 2).items() if k in SETS}
    for name, make, off in (("lever", lever_trajectory, 4), ("joystick", joystick_trajectory, 5),
                            ("multisine", multisine_trajectory, 6)):
        tests[name] = dm.simulate_trajectory(make(a.n_test, a.seed + off), a.seed + off, dm.SESSION_WORK)
    cal = bmd.calibration(a.motions, a.seed, a.reach)
    zero = bmd.zero_motion(a.zero, a.seed)
    est = CalibratedEstimator("cat345c-hydraulic-3pct", balance="momentum").fit(cal)
    est.zero(zero)
    res = {"cross_e": cross[-1][0], "cross_v": cross[-1][1], "cross_chi": cross[-1][2],
           "s": est.calibration.model_std}
    for name, ds in tests.items():
        out, v, chi = two_runs(est, ds)
        ok = judged_ok(ds, out)
        e = out["payload_estimate"].to_numpy(float) - ds.frame["payload"].to_numpy(float)
        res[name + "_e"], res[name + "_v"], res[name + "_chi"] = e[ok], v[ok], chi[ok]
        res[name + "_exp"] = ds.frame["experiment"].to_numpy()[ok]
        print(f"{name:11s} 2σ {np.mean(np.abs(e[ok]) <= 2 * np.sqrt(v[ok])):.1%}  χ̄² median {np.median(chi[ok]):.2f}  "
              f"({time.time() - t0:.0f} s)", flush=True)
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


def fit(rule, e, v, chi):
    """(s_c, c) by ``rule`` on one cross-check."""
    if rule == "today":
        return least_s(e, v), 0.0
    if rule == "minmean":
        best = None
        for c in np.r_[0.0, np.geomspace(0.1, 1000.0, 60)]:
            s = least_s(e, v + c * chi)
            mean = np.mean(np.sqrt(v + c * chi + s * s))
            if best is None or mean < best[0]:
                best = (mean, s, c)
        return best[1], best[2]
    a_c = np.linalg.lstsq(np.c_[np.ones_like(chi), chi], e**2 - v, rcond=None)[0]
    c = max(float(a_c[1]), 0.0)
    return least_s(e, v + c * chi), c


def band(cells) -> str:
    x = np.array(cells)
    return (f"in 90-99 % {np.sum((x >= .9) & (x <= .99))}, above {np.sum(x > .99)}, below {np.sum(x < .9)} "
            f"of {len(x)}; lowest {x.min():.1%}")


def analyse(paths) -> None:
    from scipy.stats import spearmanr

    data = [np.load(p) for p in paths]
    totals = {r: [] for r in ("today", "minmean", "ls")}
    for p, d in zip(paths, data):
        s_today = float(d["s"])
        print(f"{p}: s {s_today:.2f} kg; cross-check χ̄² median {np.median(d['cross_chi']):.2f}")
        for rule in totals:
            s, c = fit(rule, d["cross_e"], d["cross_v"], d["cross_chi"])
            cells = [np.mean(np.abs(d[k + "_e"]) <= 2 * np.sqrt(np.maximum(d[k + "_v"] - s_today**2, 0.0)
                                                               + s * s + c * d[k + "_chi"])) for k in SETS]
            totals[rule] += cells
            print(f"  {rule:8s} s_c {s:5.2f} c {c:6.1f} | " + " ".join(f"{x:6.1%}" for x in cells))
        print("  χ̄² median per cell       | " + " ".join(f"{np.median(d[k + '_chi']):6.2f}" for k in SETS))
    for rule, cells in totals.items():
        print(f"{rule:8s} {band(cells)}")
    motions = [(np.mean(d[k + "_chi"][d[k + "_exp"] == x]), np.sqrt(np.mean(d[k + "_e"][d[k + "_exp"] == x] ** 2)))
               for d in data for k in SETS for x in np.unique(d[k + "_exp"])]
    chi, rms = np.array(motions).T
    print(f"test motions ({len(chi)}): r(mean χ̄², RMS error) {np.corrcoef(chi, rms)[0, 1]:.2f}, "
          f"Spearman {spearmanr(chi, rms)[0]:.2f}")
    ce, cc = np.concatenate([d["cross_e"] for d in data]), np.concatenate([d["cross_chi"] for d in data])
    print(f"cross-check samples ({len(ce)}): Spearman(χ̄², |e|) {spearmanr(cc, np.abs(ce))[0]:.2f}")
    for keep in (1.0, 0.5, 0.0):  # oracle: c chosen on the test cells, s kept, halved or dropped
        for c in (0, 10, 20, 40, 80, 160):
            cells = [np.mean(np.abs(d[k + "_e"]) <= 2 * np.sqrt(d[k + "_v"] - (1 - keep**2) * float(d["s"]) ** 2
                                                               + c * d[k + "_chi"])) for d in data for k in SETS]
            print(f"oracle s×{keep} c {c:4d}: {band(cells)}")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed", type=int, default=1401, help="bench_machine_draws' --seed (its draw 0)")
    ap.add_argument("--motions", type=int, default=10)
    ap.add_argument("--reach", type=int, default=3)
    ap.add_argument("--zero", choices=["empty-swing", "slow-lever"], default="empty-swing")
    ap.add_argument("--n-test", type=int, default=8)
    ap.add_argument("--out", type=Path, default=Path("sigma-misfit.npz"))
    ap.add_argument("--analyse", nargs="+", type=Path, help="analyse these saved measurements instead")
    a = ap.parse_args()
    if a.analyse:
        analyse(a.analyse)
    else:
        measure(a)


if __name__ == "__main__":
    main()
