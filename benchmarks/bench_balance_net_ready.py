"""balance-net's readiness rules, judged on one trace per test motion.

The rule that says when balance-net shows a weight (``ok``) changes nothing of the weighing
itself: the sums, the gate and the new-load rule run the same whatever it is. So each test
motion is weighed once with a weight shown from the first window on (``--option ready`` tiny),
the weighing's state is recorded after every sample (information, the estimate, σ's parts), and
every candidate rule is applied to the trace afterwards. Per family: share of experiments whose
MAX over the ``ok`` samples after the first second is within 1 % of rated (never ``ok``: not
within), the share of samples ``ok`` after the first second, 2σ's coverage of the ``ok``
samples and the median first ``ok`` time.

Training: *reach30* (25 swings, 25 work cycles, 20 lifts, 30 reach motions of ``--train-seed``,
as ``bench_machine_draws.py --balance-net``), zeroed on the empty swing of ``--seed`` + 50 (as
``bench_balance_net.py``). Test sets (``--n-test`` each, seeds from ``--seed`` as
``bench_balance_net.py --held-out``, then ``trench`` / ``grade`` / ``jerky`` at ``--seed`` + 9, 10, 11):
the eight families of docs/balance-net.md and the three of session 22.

Session 22 judged ``stat:0.3|info:0.3`` (2κ/√I ≤ 0.3 % of the largest trained payload, or the
current share) on fresh seeds and did not keep it (docs/balance-net.md, "When the weight is
shown"); ``check`` runs the estimator at its defaults (or ``--option``) against a rule.

Usage::

    PYTHONPATH=src python benchmarks/bench_balance_net_ready.py trace --train-seed 147500 \
        --seed 147100 --n-test 8 --out ready-tuning
    PYTHONPATH=src python benchmarks/bench_balance_net_ready.py judge --out ready-tuning \
        --rule info:0.3 --rule sigma:0.5
    PYTHONPATH=src python benchmarks/bench_balance_net_ready.py channels --train-seed 147630 \
        --zero-seed 147350 --trench-seed 147309     # trench's error per channel
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_any_motion import families  # noqa: E402
from bench_balance_net import MACHINE, mixture, training_motions  # noqa: E402
from held_out_motions import (grade_trajectory, jerky_trajectory, joystick_trajectory,  # noqa: E402
                               multisine_trajectory, trench_trajectory)

from excavator_payload.estimators.base import create_estimator  # noqa: E402
from excavator_payload.estimators.learned.balance_net import BalanceNet  # noqa: E402
from excavator_payload.evaluation import demo_machine as dm  # noqa: E402
from excavator_payload.simulation.generate import simulate_dataset  # noqa: E402

RATED = dm.RATED_PAYLOAD
NEW = {"trench": trench_trajectory, "grade": grade_trajectory, "jerky": jerky_trajectory}


class Traced(BalanceNet):
    """balance-net that records its weighing's state after every sample."""

    trace: list

    def step_values(self, time, values):  # noqa: D102 - the base step, recorded
        result = super().step_values(time, values)
        self.trace.append((self.num, self.info, self.novelty, self.misfit))
        return result


def test_sets(n: int, seed: int) -> dict:
    """The eleven test families of ``seed``.

    Parameters
    ----------
    n : int
        Experiments per family.
    seed : int
        The test seed (families at ``seed`` + 0 … 11, as the module docstring says).
    """
    tests = families(n, seed)
    tests["slopes"] = dm.before_release(simulate_dataset(
        n, seed=seed + 5, motion="slopes", machine=MACHINE, session=dm.SESSION_WORK,
        with_truth=True, workers=1, progress=False))
    tests["joystick"] = dm.simulate_trajectory(joystick_trajectory(n, seed + 6), seed + 6, dm.SESSION_WORK)
    tests["multisine"] = dm.simulate_trajectory(multisine_trajectory(n, seed + 7), seed + 7, dm.SESSION_WORK)
    for k, name in enumerate(NEW):
        tests[name] = dm.simulate_trajectory(NEW[name](n, seed + 9 + k), seed + 9 + k, dm.SESSION_WORK)
    return tests


def trace(a) -> None:
    """Train, zero, and record every test family's trace in ``a.out``.

    Parameters
    ----------
    a : argparse.Namespace
        ``train_seed``, ``seed``, ``n_test`` and ``out`` (a folder).
    """
    t0 = time.time()
    counts = {"swing": 25, "work-cycle": 25, "lifts": 20, "reach": 30}
    est = create_estimator("balance-net", None).fit(mixture(training_motions(counts, a.train_seed), counts))
    est.zero(dm.zero_data(a.seed + 50))
    print(f"trained and zeroed ({time.time() - t0:.0f} s)", flush=True)
    traced = est
    traced.__class__ = Traced  # the same weighing, recorded; a weight from the first window on
    traced.options = {**est.options, "ready": 1e-12}
    if "ready_sigma" in traced.options:  # no wait on the information's part of σ either
        traced.options["ready_sigma"] = 1e12
    constants = {"kappa": est.kappa, "floor_a": est.floor_a, "floor_b": est.floor_b, "floor_c": est.floor_c,
                 "zero_std": est.model.zero_std, "typical_info": est.typical_info,
                 "payload_scale": est.payload_scale, "train_seed": a.train_seed, "seed": a.seed, "n_test": a.n_test}
    (a.out / "constants.json").write_text(json.dumps(constants, indent=1))
    tests = test_sets(a.n_test, a.seed)
    print(f"test sets simulated ({time.time() - t0:.0f} s)", flush=True)
    for name, ds in tests.items():
        traced.trace = []
        frame = traced.estimate(ds)
        f = ds.frame
        num, info, novelty, misfit = np.array(traced.trace, float).T
        out = pd.DataFrame({"experiment": f["experiment"].to_numpy(), "time": f["time"].to_numpy(float),
                            "payload": f["payload"].to_numpy(float),
                            "status": frame["status"].astype(str).to_numpy(), "sigma": frame["sigma"].to_numpy(float),
                            "num": num, "info": info, "novelty": novelty, "misfit": misfit})
        out.to_parquet(a.out / f"{name}.parquet")
        print(f"{name}: {ds.n_experiments} traced ({time.time() - t0:.0f} s)", flush=True)


def check(a) -> None:
    """The estimator as it is (its default rule, or ``--option``), trained, zeroed and tested as
    ``trace`` did: its ``ok`` samples against ``a.rule`` applied to the recorded trace."""
    c = json.loads((a.out / "constants.json").read_text())
    counts = {"swing": 25, "work-cycle": 25, "lifts": 20, "reach": 30}
    options = dict(kv.split("=", 1) for kv in a.option)
    est = create_estimator("balance-net", None, **options).fit(
        mixture(training_motions(counts, c["train_seed"]), counts))
    est.zero(dm.zero_data(c["seed"] + 50))
    for name, ds in test_sets(c["n_test"], c["seed"]).items():
        t = pd.read_parquet(a.out / f"{name}.parquet")
        frame = est.estimate(ds)
        ok = frame["status"].astype(str).to_numpy() == "ok"
        rule = (t["status"].to_numpy() == "ok") & ready_of(a.rule, c, t)
        same = np.array_equal(ok, rule)
        e = frame["payload_estimate"].to_numpy(float)[ok]
        diff = float(np.max(np.abs(e - (t["num"] / t["info"]).to_numpy(float)[ok]))) if ok.any() else 0.0
        print(f"{name}: ok {ok.mean():.3f}, rule {rule.mean():.3f}, same samples {same}, "
              f"largest estimate difference {diff:.2e} kg", flush=True)


def channels(a) -> None:
    """Each ``trench`` motion's error per channel at its end: the weighing's own windows summed
    per channel (``Σ w φ r / Σ w φ²`` of each cylinder; the new-load test's windows left out).

    Parameters
    ----------
    a : argparse.Namespace
        ``train_seed``, ``zero_seed`` (the empty swing), ``trench_seed`` and ``n_test``.
    """
    import excavator_payload.estimators.learned.balance_net as bn

    counts = {"swing": 25, "work-cycle": 25, "lifts": 20, "reach": 30}
    est = create_estimator("balance-net", None).fit(mixture(training_motions(counts, a.train_seed), counts))
    est.zero(dm.zero_data(a.zero_seed))
    windows, add = [], bn._add_window

    def recorded(sums, w, phi, r, novelty):
        if sums[0] == est.num and sums[1] == est.info:  # the weighing's own sums
            windows.append((w * phi * r, w * phi * phi))
        return add(sums, w, phi, r, novelty)

    bn._add_window = recorded
    try:
        ds = dm.simulate_trajectory(trench_trajectory(a.n_test, a.trench_seed), a.trench_seed, dm.SESSION_WORK)
        rows = []
        for k in ds.experiment_ids:
            windows.clear()
            est.estimate(ds.subset([k]))
            num, info = (np.sum([x[i] for x in windows], axis=0) for i in (0, 1))
            load = float(ds.subset([k]).frame["payload"].iloc[0])
            rows.append([load, est.num / est.info - load, *(n / i - load if i > 0 else np.nan for n, i in zip(num, info)),
                         *(info / info.sum())])
    finally:
        bn._add_window = add
    n = (len(rows[0]) - 2) // 2
    names = [est.sensor_set.signals[i] for i in est.model.layout.q]
    df = pd.DataFrame(rows, columns=["load", "error", *(f"{q}_error" for q in names[:n]),
                                     *(f"{q}_info_share" for q in names[:n])])
    print(df.round(2).to_string(index=False))
    for col in ["error", *(f"{q}_error" for q in names[:n])]:
        ok = np.isfinite(df[col])
        if ok.sum() >= 2:
            slope, offset = np.polyfit(df["load"][ok], df[col][ok], 1)
            print(f"{col}: {100 * slope:+.2f} % of the load {offset:+.1f} kg")


def sigma_of(c: dict, info, novelty, misfit):
    """σ as ``BalanceNet._estimate_sigma`` from the recorded state, and the model floor's part.

    Parameters
    ----------
    c : dict
        The training's constants (``constants.json``).
    info, novelty, misfit : numpy.ndarray
        The weighing's sums after every sample.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        floor = np.maximum(c["floor_a"] + c["floor_b"] * novelty / info + c["floor_c"] * misfit / info, 0.0)
        return np.sqrt(c["kappa"] ** 2 / info + floor + c["zero_std"] ** 2), np.sqrt(floor)


def ready_of(rule: str, c: dict, t: pd.DataFrame) -> np.ndarray:
    """Where the rule holds, per sample.

    ``info:S`` the current rule; ``sigma:P`` 2σ ≤ P % of rated;
    ``floor:R`` κ/√I ≤ R × the model's floor and the zero's; ``floorA:R`` the same with the
    floor's constant part; ``stat:P`` 2κ/√I ≤ P % of rated; ``or``: ``A|B``)."""
    if "|" in rule:
        return np.logical_or.reduce([ready_of(r, c, t) for r in rule.split("|")])
    kind, value = rule.split(":")
    v = float(value)
    info = t["info"].to_numpy(float)
    pos = info > 0
    if kind == "info":
        return pos & (info >= v * c["typical_info"])
    sigma, floor = sigma_of(c, info, t["novelty"].to_numpy(float), t["misfit"].to_numpy(float))
    if kind == "sigma":
        return pos & (2.0 * sigma <= v / 100.0 * RATED)
    if kind == "floor":
        with np.errstate(divide="ignore"):
            stat = c["kappa"] / np.sqrt(info)
        return pos & (stat <= v * np.sqrt(floor ** 2 + c["zero_std"] ** 2))
    if kind == "stat":  # the information's part of σ alone: 2κ/√I ≤ P % of rated
        return pos & (info >= (2.0 * c["kappa"] / (v / 100.0 * RATED)) ** 2)
    if kind == "floorA":  # the constant part of the floor alone: a fixed information
        return pos & (info >= c["kappa"] ** 2 / (v * v * (max(c["floor_a"], 0.0) + c["zero_std"] ** 2)))
    raise SystemExit(f"unknown rule {rule!r}")


def latched(ready: np.ndarray, t: pd.DataFrame) -> np.ndarray:
    """Once ready, ready until the weighing restarts (its information falls)."""
    out = np.zeros(len(ready), bool)
    exp = t["experiment"].to_numpy()
    info = t["info"].to_numpy(float)
    on = False
    for i in range(len(ready)):
        if i == 0 or exp[i] != exp[i - 1] or info[i] < info[i - 1]:
            on = False
        on = on or bool(ready[i])
        out[i] = on
    return out


def judge_rule(rule: str, c: dict, t: pd.DataFrame, latch: bool) -> dict:
    """The family's row under ``rule``.

    Parameters
    ----------
    rule : str
        See :func:`ready_of`.
    c : dict
        The training's constants.
    t : pandas.DataFrame
        The family's trace.
    latch : bool
        Once ready, ready until the weighing restarts.
    """
    ready = ready_of(rule, c, t)
    if latch:
        ready = latched(ready, t)
    ok = (t["status"].to_numpy() == "ok") & ready
    est = np.where(ok, t["num"].to_numpy(float) / np.where(t["info"] > 0, t["info"], np.nan), np.nan)
    err = est - t["payload"].to_numpy(float)
    sigma, _ = sigma_of(c, t["info"].to_numpy(float), t["novelty"].to_numpy(float), t["misfit"].to_numpy(float))
    tt = t["time"].to_numpy(float)
    first = t.groupby("experiment")["time"].transform("min").to_numpy(float)
    judged = (tt - first) >= 1.0 - 1e-9
    within, maxes, first_ok = [], [], []
    for k, idx in t.groupby("experiment").indices.items():
        sel = idx[judged[idx] & ok[idx]]
        if len(sel):
            m = float(np.max(np.abs(err[sel])))
            maxes.append(m)
            within.append(m <= 0.01 * RATED)
            first_ok.append(tt[sel[0]] - first[idx[0]])
        else:
            within.append(False)
            first_ok.append(math.inf)
    okj = ok & judged
    return {"within_1pct": float(np.mean(within)), "never_ok": int(sum(math.isinf(x) for x in first_ok)),
            "mean_max_kg": float(np.mean(maxes)) if maxes else math.nan,
            "worst_max_kg": float(np.max(maxes)) if maxes else math.nan,
            "ok_share": float(okj.sum() / judged.sum()),
            "sigma_covers": float(np.mean(np.abs(err[okj]) <= 2 * sigma[okj])) if okj.any() else math.nan,
            "first_ok_median_s": float(np.median(first_ok))}


def judge(a) -> None:
    """Every rule on every family traced in each ``a.out``."""
    rows = []
    for out in a.out_dirs:
        c = json.loads((out / "constants.json").read_text())
        for path in sorted(out.glob("*.parquet")):
            t = pd.read_parquet(path)
            for rule in a.rule:
                rows.append({"trace": out.name, "family": path.stem, "rule": rule,
                             **judge_rule(rule, c, t, a.latch)})
    df = pd.DataFrame(rows)
    pd.set_option("display.width", 250)
    pd.set_option("display.max_rows", 2000)
    print(df.to_string(index=False, float_format=lambda x: f"{x:.3f}"))
    if a.csv:
        df.to_csv(a.csv, index=False)


def main() -> None:
    ap = argparse.ArgumentParser()
    sub = ap.add_subparsers(dest="cmd", required=True)
    tr = sub.add_parser("trace")
    tr.add_argument("--train-seed", type=int, required=True)
    tr.add_argument("--seed", type=int, required=True)
    tr.add_argument("--n-test", type=int, default=8)
    tr.add_argument("--out", type=Path, required=True)
    ju = sub.add_parser("judge")
    ju.add_argument("--out", dest="out_dirs", type=Path, nargs="+", required=True)
    ju.add_argument("--rule", action="append", required=True)
    ju.add_argument("--latch", action="store_true", help="once ready, ready until the weighing restarts")
    ju.add_argument("--csv", type=Path, default=None)
    ch = sub.add_parser("check")
    ch.add_argument("--out", type=Path, required=True)
    ch.add_argument("--rule", required=True)
    ch.add_argument("--option", action="append", default=[], help="KEY=VALUE estimator option")
    cn = sub.add_parser("channels")
    cn.add_argument("--train-seed", type=int, required=True)
    cn.add_argument("--zero-seed", type=int, required=True)
    cn.add_argument("--trench-seed", type=int, required=True)
    cn.add_argument("--n-test", type=int, default=16)
    a = ap.parse_args()
    if a.cmd == "channels":
        channels(a)
    elif a.cmd == "check":
        check(a)
    elif a.cmd == "trace":
        a.out.mkdir(parents=True, exist_ok=True)
        trace(a)
    else:
        judge(a)


if __name__ == "__main__":
    main()
