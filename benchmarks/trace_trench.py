"""Why ``calibrated`` weighs the held-out ``trench`` family (boom nearly held) worse than 1 %.

A trace, not a judgement (tuning seeds only). One calibration draw as
``bench_machine_draws.py --seed SEED`` makes its draw 0 (``--motions`` motions, the recommended
`reach` share, zeroed on the empty swing), weighing the first ``--n-test`` motions of that
bench's ``trench`` set (seed SEED + 9) in the momentum form with the estimator ``--option``\\ s
(e.g. ``wait_for_boom=no``). Variants of the same estimator, each re-zeroed on the same zero
motion (as ``bench_calibration_attribution.py``):

* ``calibrated``: the draw's calibration;
* ``G→true``: the calibrated parameters of the groups G (``--groups``) set to the true machine's;
* ``all δ→true``: every calibrated parameter true (offsets from the zero);
* ``all δ→true + true offsets``: and the working session's true sensor offsets;
* ``oracle``: the simulator's machine file, offsets and IMU dynamics (``bench_efficiency_gap``).

Per motion and variant it prints the error at the end and the worst error over the ``ok``
samples after the first second, the σ the estimator reports and the share of those samples
2σ covers; per joint, the weighing's windows summed without forgetting (their share of the
information and their estimate's error: the momentum windows' ``φ r`` and ``φ²`` per joint,
before the IMU filter). It also prints where the calibration motions moved the dipper, against
where the trench pulls it: the angle ranges, and the distance in (boom, dipper, bucket) angle
from each moving trench sample to the nearest moving calibration sample.

Usage (docs/findings/any-motion.md, "Why `calibrated` cannot weigh the trench without the boom")::

    PYTHONPATH=src python benchmarks/trace_trench.py --seed 146101 --motions 10 --n-test 8 \\
        --option wait_for_boom=no --out trace-trench

``--readiness``: instead of the variants, readiness rules applied after the fact (the estimator is
not changed) on ``--sets`` (``trench`` and the old families: NMPC swings, work cycles, the 5°
slope, `lever`), the draw's calibration weighing each set twice, with main's defaults (today's
rule: ``ok`` once the boom has its 50 windows and the estimate holds still) and with
``wait_for_boom=no`` (every weight shown, with its σ and status). Per rule and family: motions
within 1 % (MAX over the ``ok`` samples after the first second), ``ok`` share and first ``ok``
(:func:`readiness_rules`). Usage (docs/findings/any-motion.md, "A readiness on σ when the boom is
held")::

    PYTHONPATH=src python benchmarks/trace_trench.py --readiness --seed 146301 --motions 10 \\
        --n-test 8 --out ready-a
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
from bench_calibration_attribution import GROUPS, group_index, true_delta, variant, with_offsets  # noqa: E402
from bench_efficiency_gap import N_DELTA, N_OFFSETS, oracle  # noqa: E402
from held_out_motions import lever_trajectory, trench_trajectory  # noqa: E402

from excavator_payload.estimators.classical.calibrated import CalibratedEstimator
from excavator_payload.estimators.classical.kernels import PayloadKernel
from excavator_payload.estimators.classical.machine_calibration.kernel import CalibratedKernel
from excavator_payload.evaluation import demo_machine as dm

JOINTS = ("boom", "dipper", "bucket")
#: a joint counts as moving above this rate, rad/s (the dipper's pulls run at ~0.3 rad/s)
MOVING_RATE = 0.05
#: σ at which 2σ is 1 % of the rated 5000 kg, kg
SIGMA_READY = 25.0
#: ``--readiness``: the boom counts as held while its 0.5 s mean rate stays below this, rad/s
#: (the trench's corrections reach 0.03-0.05 rad/s, a work cycle's lift several times that)
BOOM_HELD_RATE = 0.1
#: ``--readiness``: samples (100 Hz) σ ≤ X must have held before the rule ``σ≤X for 1 s`` shows a weight
HOLD_SAMPLES = 100
#: the steady rule on the shown estimate: moved by at most STEADY_KG over STEADY_SAMPLES (0.5 s)
STEADY_KG, STEADY_SAMPLES = 5.0, 50


class WindowLog:
    """Records every momentum window's per-joint ``φ r`` and ``φ²`` the kernel sums, with the
    time of the sample that closed it, and each σ's terms (1/√I, the model error, the zero's
    share) with its sample's time (patches of :meth:`CalibratedKernel.update`,
    :meth:`CalibratedKernel._accumulate` and :meth:`PayloadKernel.sigma`, removed on exit)."""

    def __enter__(self):
        self.rows, self.sigmas, self.time = [], [], np.nan
        self._originals = CalibratedKernel.update, CalibratedKernel._accumulate, PayloadKernel.sigma
        update, accumulate, sigma = self._originals
        log = self

        def logged_sigma(kernel):
            if kernel.info > 0:
                log.sigmas.append([log.time, kernel.info ** -0.5, kernel.model_std, kernel.extra_std])
            return sigma(kernel)

        def logged_update(kernel, time, values):
            log.time = float(time)
            return update(kernel, time, values)

        def logged_accumulate(kernel, d_num_joint, d_info_joint):
            log.rows.append([log.time, *d_num_joint, *d_info_joint])
            return accumulate(kernel, d_num_joint, d_info_joint)

        CalibratedKernel.update, CalibratedKernel._accumulate = logged_update, logged_accumulate
        PayloadKernel.sigma = logged_sigma
        return self

    def __exit__(self, *exc):
        CalibratedKernel.update, CalibratedKernel._accumulate, PayloadKernel.sigma = self._originals


def weigh(est, ds) -> pd.DataFrame:
    """Per motion of ``ds``: the estimate's errors, σ and coverage, and per joint the windows'
    information share and their summed estimate's error.

    Besides the estimator's own ``ok`` samples it reports two readiness rules applied after
    the fact (the estimator is not changed): ``max_err_s25``, the worst error over the ``ok``
    samples whose σ is at most :data:`SIGMA_READY` (2σ within 1 % of the rated payload), and
    ``max_err_steady``, the worst error once the shown estimate has moved by at most
    :data:`STEADY_KG` over the last :data:`STEADY_SAMPLES` samples (``--wait-for-boom``'s
    steady rule on the shown estimate; kept from then on). At the worst ``ok`` sample: its time
    after the first ``ok``, its σ, and the joints' windows summed up to it.

    Parameters
    ----------
    est : CalibratedEstimator
        A zeroed estimator.
    ds : Dataset
        The test motions (known payloads).
    """
    rows = []
    for e in ds.experiment_ids:
        one = ds.subset([e])
        with WindowLog() as log:
            frame = est.estimate(one)
        f = one.frame
        payload = float(f["payload"].iloc[0])
        t = f["time"].to_numpy(float)
        judged = (t - t[0]) >= 1.0
        ok = (frame["status"].astype(str).to_numpy() == "ok") & judged
        err = frame["payload_estimate"].to_numpy(float) - payload
        sigma = frame["sigma"].to_numpy(float)
        row = {"experiment": int(e), "payload": payload, "ok_share": float(ok[judged].mean())}
        w = np.asarray(log.rows, float).reshape(-1, 7)
        if ok.any():
            row.update(_worst_and_readiness(t, ok, err, sigma, w, np.asarray(log.sigmas, float), payload))
        w = w[:, 1:]
        num, info = w[:, :3].sum(axis=0), w[:, 3:].sum(axis=0)
        for j, joint in enumerate(JOINTS):
            row[f"{joint}_windows"] = int(np.count_nonzero(w[:, 3 + j] > 0))
            row[f"{joint}_info_share"] = float(info[j] / info.sum()) if info.sum() > 0 else np.nan
            row[f"{joint}_err"] = float(num[j] / info[j] - payload) if info[j] > 0 else np.nan
        row["all_err"] = float(num.sum() / info.sum() - payload) if info.sum() > 0 else np.nan
        rows.append(row)
    return pd.DataFrame(rows)


def _worst_and_readiness(t, ok, err, sigma, w, terms, payload) -> dict:
    """One motion's columns of :func:`weigh` that need an ``ok`` sample: the first ``ok``, the
    worst ``ok`` sample (its σ's terms, the dipper's share and the joints' errors up to it), and
    the two readiness rules applied after the fact.

    Parameters
    ----------
    t, ok, err, sigma : numpy.ndarray
        Per sample: time (s), ``ok`` after the first second, error and σ of the estimate (kg).
    w : numpy.ndarray
        The motion's windows (rows: time, φ r ×3, φ² ×3; :class:`WindowLog`).
    terms : numpy.ndarray
        σ's terms per sample (rows: time, 1/√I, model error, zero's share; kg).
    payload : float
        The true load, kg.
    """
    idx = np.flatnonzero(ok)
    worst = idx[np.argmax(np.abs(err[ok]))]
    moved = np.abs(err[STEADY_SAMPLES:] - err[:-STEADY_SAMPLES]) <= STEADY_KG  # the estimate moved
    steady_from = np.flatnonzero(moved & ok[STEADY_SAMPLES:])
    steady = ok & (np.arange(len(ok)) >= (steady_from[0] + STEADY_SAMPLES if len(steady_from) else len(ok)))
    s25 = ok & (sigma <= SIGMA_READY)
    upto = w[w[:, 0] <= t[worst]]
    terms = terms.reshape(-1, 4)
    before = np.flatnonzero(terms[:, 0] <= t[worst])
    at = terms[before[-1]] if len(before) else np.full(4, np.nan)

    def worst_of(mask):
        return float(np.max(np.abs(err[mask]))) if mask.any() else np.nan

    def first(mask):
        return float(t[np.flatnonzero(mask)[0]] - t[0]) if mask.any() else np.nan

    return {"first_ok_s": first(ok), "max_err": worst_of(ok), "end_err": float(err[idx[-1]]),
            "end_sigma": float(sigma[idx[-1]]), "covers": float(np.mean(np.abs(err[ok]) <= 2 * sigma[ok])),
            "worst_after_ok_s": float(t[worst] - t[idx[0]]), "worst_err": float(err[worst]),
            "worst_sigma": float(sigma[worst]), "worst_info_std": float(at[1]), "worst_model_std": float(at[2]),
            "worst_zero_std": float(at[3]),
            "worst_dipper_share": float(upto[:, 5].sum() / upto[:, 4:].sum()) if len(upto) else np.nan,
            "worst_dipper_err": _joint_err(upto, 1, payload), "worst_bucket_err": _joint_err(upto, 2, payload),
            "max_err_s25": worst_of(s25), "s25_from_s": first(s25),
            "max_err_steady": worst_of(steady), "steady_from_s": first(steady)}


def _joint_err(w: np.ndarray, j: int, payload: float) -> float:
    """The error of joint ``j``'s windows ``w`` (rows: time, φ r ×3, φ² ×3) summed, kg."""
    info = w[:, 4 + j].sum()
    return float(w[:, 1 + j].sum() / info - payload) if info > 0 else np.nan


def moving_poses(ds, joint: int) -> np.ndarray:
    """(boom, dipper, bucket) angles, degrees, of the samples where ``joint`` moves faster than
    :data:`MOVING_RATE` (true angles and rates where the data carry them).

    Parameters
    ----------
    ds : Dataset
        Motions.
    joint : int
        0 boom, 1 dipper, 2 bucket.
    """
    f = ds.frame
    angles = [f"true_{a}" if f"true_{a}" in f else a for a in ("boom_angle", "dipper_angle", "bucket_angle")]
    rates = [f"true_{a}" if f"true_{a}" in f else a for a in ("boom_rate", "dipper_rate", "bucket_rate")]
    moving = np.abs(f[rates[joint]].to_numpy(float)) > MOVING_RATE
    return np.degrees(f[angles].to_numpy(float)[moving])


def coverage_report(cal, tests) -> None:
    """Print where calibration and test motions move each joint, and how far each moving test
    pose lies from the nearest moving calibration pose.

    Parameters
    ----------
    cal, tests : Dataset
        The calibration motions and the test motions.
    """
    from scipy.spatial import cKDTree

    for j, joint in enumerate(JOINTS):
        c, s = moving_poses(cal, j), moving_poses(tests, j)
        if not len(c) or not len(s):
            print(f"{joint} moving: calibration {len(c)} samples, trench {len(s)}")
            continue
        d, _ = cKDTree(c).query(s)
        ranges = lambda a: " ".join(f"{n} {np.percentile(a[:, k], 1):.0f}…{np.percentile(a[:, k], 99):.0f}°"
                                    for k, n in enumerate(JOINTS))
        print(f"{joint} moving (> {MOVING_RATE} rad/s): calibration {len(c)} samples ({ranges(c)}); "
              f"trench {len(s)} ({ranges(s)}); nearest calibration pose: median {np.median(d):.1f}°, "
              f"90 % {np.percentile(d, 90):.1f}°, > 10° on {np.mean(d > 10):.0%}", flush=True)


def readiness_rules(today_frame, nowait_frame, ds, thresholds) -> pd.DataFrame:
    """Per motion of ``ds`` and readiness rule: the worst error over the rule's ``ok`` samples
    after the first second (``max_err``; NaN if never ``ok``), the share of those samples that are
    ``ok`` and the first ``ok`` (s after the motion's start).

    Rules: ``today`` (main's: the boom's 50 windows, then a steady estimate), ``no wait``
    (``wait_for_boom=no``: every weight shown), and per X in ``thresholds`` ``today or σ≤X`` (also
    ``ok`` where the weighing without the wait is ``ok`` and reports σ ≤ X) and ``today or σ≤X
    latched`` (``ok`` from the first such sample until the status without the wait leaves ``ok``:
    a restart, a load change) and ``today or σ≤X, boom held`` (σ ≤ X only while the boom's 0.5 s
    mean measured rate has stayed below :data:`BOOM_HELD_RATE` since the motion's start) and
    ``today or σ≤X for 1 s`` (σ ≤ X on each of the last :data:`HOLD_SAMPLES` samples). Where
    today's rule shows a weight its estimate is used, elsewhere the estimate without the wait.

    Parameters
    ----------
    today_frame, nowait_frame : pandas.DataFrame
        The estimates of ``ds`` with main's defaults and with ``wait_for_boom=no``.
    ds : Dataset
        The test motions (known payloads).
    thresholds : sequence of float
        The σ thresholds X, kg.
    """
    f = ds.frame
    rows = []
    for e in ds.experiment_ids:
        m = (f["experiment"] == e).to_numpy()
        t = f["time"].to_numpy(float)[m]
        judged = (t - t[0]) >= 1.0
        payload = float(f["payload"].to_numpy(float)[m][0])
        ok_today = today_frame["status"].astype(str).to_numpy()[m] == "ok"
        ok_free = nowait_frame["status"].astype(str).to_numpy()[m] == "ok"
        sigma = nowait_frame["sigma"].to_numpy(float)[m]
        estimate = np.where(ok_today, today_frame["payload_estimate"].to_numpy(float)[m],
                            nowait_frame["payload_estimate"].to_numpy(float)[m])
        # the boom held so far: its measured rate, averaged over 0.5 s, never above BOOM_HELD_RATE
        boom = pd.Series(f["boom_rate"].to_numpy(float)[m]).rolling(STEADY_SAMPLES, min_periods=1).mean().abs()
        held = np.maximum.accumulate(boom.to_numpy()) <= BOOM_HELD_RATE
        rules = {"today": ok_today, "no wait": ok_free}
        for x in thresholds:
            below = ok_free & (sigma <= x)
            latched = np.zeros_like(below)
            on = False
            for i in range(len(below)):  # on from σ ≤ X until the status leaves ok
                on = ok_free[i] and (on or below[i])
                latched[i] = on
            rules[f"today or σ≤{x:g}"] = ok_today | below
            rules[f"today or σ≤{x:g} latched"] = ok_today | latched
            rules[f"today or σ≤{x:g}, boom held"] = ok_today | (below & held)
            # σ ≤ X on every sample of the last HOLD_SAMPLES (the first weights are the worst)
            run = np.convolve(below.astype(float), np.ones(HOLD_SAMPLES), "full")[:len(below)]
            rules[f"today or σ≤{x:g} for {HOLD_SAMPLES / 100:g} s"] = ok_today | (run >= HOLD_SAMPLES)
        # today's and the free weighing's estimates where both are ok (they should be equal)
        both = ok_today & ok_free
        diff = float(np.max(np.abs(today_frame["payload_estimate"].to_numpy(float)[m][both]
                                   - nowait_frame["payload_estimate"].to_numpy(float)[m][both]))) if both.any() else 0.0
        for rule, ok in rules.items():
            ok = ok & judged
            err = np.abs(estimate - payload)
            worst = np.flatnonzero(ok)[np.argmax(err[ok])] if ok.any() else None
            rows.append({"experiment": int(e), "payload": payload, "rule": rule,
                         "max_err": float(err[worst]) if ok.any() else np.nan,
                         "ok_share": float(ok[judged].mean()),
                         "first_ok_s": float(t[np.flatnonzero(ok)[0]] - t[0]) if ok.any() else np.nan,
                         # the worst sample: its time after the start and the σ without the wait there
                         "worst_s": float(t[worst] - t[0]) if ok.any() else np.nan,
                         "worst_sigma": float(sigma[worst]) if ok.any() else np.nan,
                         "today_vs_free_kg": diff})
    return pd.DataFrame(rows)


def readiness_sets(names, n: int, seed: int) -> dict:
    """The test sets of ``bench_machine_draws.py --seed SEED --n-test N``: NMPC swings, work cycles
    and the 5° slope (:func:`dm.test_sets`, seed + 2), `lever` (seed + 4), `trench` (seed + 9).

    Parameters
    ----------
    names : sequence of str
        Which sets.
    n : int
        Motions per set.
    seed : int
        The bench's seed.
    """
    tests = {k: v for k, v in dm.test_sets(n, seed + 2).items() if k in names} if set(names) - {"lever", "trench"} \
        else {}
    if "lever" in names:
        tests["lever"] = dm.simulate_trajectory(lever_trajectory(n, seed + 4), seed + 4, dm.SESSION_WORK)
    if "trench" in names:
        tests["trench"] = dm.simulate_trajectory(trench_trajectory(n, seed + 9), seed + 9, dm.SESSION_WORK)
    return tests


def run_readiness(a, est, t0: float) -> None:
    """``--readiness``: :func:`readiness_rules` on ``a.sets`` with ``est`` (main's defaults, zeroed)
    and its twin without the boom wait; writes ``OUT/readiness.csv`` and prints the summary."""
    free = copy.deepcopy(est)
    free.options["wait_for_boom"] = "no"
    free.use_calibration()
    tests = readiness_sets(a.sets, a.n_test, a.seed)
    print(f"test sets simulated ({time.time() - t0:.0f} s)", flush=True)
    tables = []
    for name, ds in tests.items():
        table = readiness_rules(est.estimate(ds), free.estimate(ds), ds, a.sigma_ready).assign(family=name)
        tables.append(table)
        pd.concat(tables).to_csv(a.out / "readiness.csv", index=False)
        print(f"\n{name} ({time.time() - t0:.0f} s; today's and the free estimate differ by at most "
              f"{table['today_vs_free_kg'].max():.2g} kg where both are ok)", flush=True)
        summary = table.groupby("rule", sort=False).agg(
            within=("max_err", lambda s: int((s <= 0.01 * dm.RATED_PAYLOAD).sum())), motions=("max_err", "size"),
            never_ok=("max_err", lambda s: int(s.isna().sum())), max_kg=("max_err", "max"),
            ok_share=("ok_share", "mean"), first_ok_median_s=("first_ok_s", "median"))
        print(summary.round(3).to_string(), flush=True)
    print(f"total {time.time() - t0:.0f} s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=146101, help="bench_machine_draws.py --seed (tuning seeds)")
    ap.add_argument("--motions", type=int, default=10, help="calibration motions (recommended reach share)")
    ap.add_argument("--n-test", type=int, default=8, help="first motions of the trench set")
    ap.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                    help="an option of the calibrated estimator (repeatable), e.g. wait_for_boom=no")
    ap.add_argument("--groups", nargs="+", default=["dipper areas", "dipper friction", "dipper inertia",
                                                     "arm geometry", "bucket linkage"],
                    choices=list(GROUPS), help="parameter groups swapped to the truth one at a time")
    ap.add_argument("--variants", nargs="+", default=None, help="labels to run (default: all)")
    ap.add_argument("--out", type=Path, default=Path("trace-trench"))
    ap.add_argument("--readiness", action="store_true",
                    help="readiness rules after the fact on --sets instead of the variants (main's defaults "
                         "and wait_for_boom=no; --option is ignored)")
    ap.add_argument("--sets", nargs="+", default=["trench", "nmpc", "work-cycle", "slope-5deg", "lever"],
                    choices=["trench", "nmpc", "work-cycle", "slope-5deg", "lever"], help="--readiness's test sets")
    ap.add_argument("--sigma-ready", type=float, nargs="+", default=[12.5, SIGMA_READY], metavar="KG",
                    help="--readiness: the σ thresholds X of the rules 'today or σ ≤ X'")
    a = ap.parse_args()
    options = dict(o.split("=", 1) for o in a.option)
    a.out.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    if a.readiness:
        est = CalibratedEstimator("cat345c-hydraulic-3pct", balance="momentum").fit(
            dm.calibration_mix(a.motions, a.seed, reach=None))
        est.zero(dm.zero_data(a.seed + 1))
        print(f"calibrated and zeroed ({time.time() - t0:.0f} s)", flush=True)
        return run_readiness(a, est, t0)
    tests = dm.simulate_trajectory(trench_trajectory(a.n_test, a.seed + 9), a.seed + 9, dm.SESSION_WORK)
    cal = dm.calibration_mix(a.motions, a.seed, reach=None)
    zero = dm.zero_data(a.seed + 1)
    est = CalibratedEstimator("cat345c-hydraulic-3pct", balance="momentum", **options).fit(cal)
    before_zero = est.calibration.z.copy()
    est.zero(zero)
    print(f"calibrated and zeroed ({time.time() - t0:.0f} s); angle coverage (deg): "
          f"{np.degrees(np.asarray(est.calibration.angle_coverage, float)).round(0).tolist()}", flush=True)
    coverage_report(cal, tests)
    truth = true_delta()
    ways = {"calibrated": est, **{f"{g}→true": variant(est, before_zero, zero, group_index(g), truth, None)
                                 for g in a.groups}}
    ways["all δ→true"] = variant(est, before_zero, zero, np.arange(N_DELTA), truth, None)
    ways["all δ→true + true offsets"] = with_offsets(ways["all δ→true"], np.arange(N_OFFSETS))
    ways["oracle"] = oracle(est)
    if a.variants:
        ways = {k: v for k, v in ways.items() if k in a.variants}
    tables = []
    for label, e in ways.items():
        table = weigh(e, tests).assign(variant=label)
        tables.append(table)
        pd.concat(tables).to_csv(a.out / "trace.csv", index=False)
        within = {c: int((table[c] <= 0.01 * dm.RATED_PAYLOAD).sum()) if c in table else 0
                  for c in ("max_err", "max_err_s25", "max_err_steady")}
        print(f"\n{label}: within 1 % {within['max_err']} of {len(table)} (σ ≤ {SIGMA_READY:.0f} kg: "
              f"{within['max_err_s25']}, steady: {within['max_err_steady']}) ({time.time() - t0:.0f} s)")
        cols = ["experiment", "payload", "first_ok_s", "max_err", "end_err", "end_sigma", "covers", "all_err",
                *(f"{j}_{k}" for j in JOINTS for k in ("info_share", "err"))]
        later = ["experiment", "worst_after_ok_s", "worst_err", "worst_sigma", "worst_info_std", "worst_model_std",
                 "worst_zero_std", "worst_dipper_share",
                 "worst_dipper_err", "worst_bucket_err", "max_err_s25", "s25_from_s", "max_err_steady",
                 "steady_from_s"]
        for c in (cols, later):
            print(table[[k for k in c if k in table]].round(2).to_string(index=False), flush=True)
    print(f"total {time.time() - t0:.0f} s")


if __name__ == "__main__":
    main()
