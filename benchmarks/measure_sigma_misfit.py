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
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import sigma_terms  # noqa: E402
from sigma_terms import SETS, band, least_s  # noqa: E402


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


def measure(a) -> None:
    """Draw 0 weighed with the misfit term off and on (``sigma_terms.measure``), saved as ``*_chi``."""
    patch_kernel()

    def set_term(est, value):
        est.kernel.regression.misfit_coef = value

    def describe(e, v, chi):
        return f"2σ {np.mean(np.abs(e) <= 2 * np.sqrt(v)):.1%}  χ̄² median {np.median(chi):.2f}"

    sigma_terms.measure(a, set_term, "chi", describe)


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
