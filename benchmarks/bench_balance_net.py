"""balance-net on the machine set: learned from ≤ 100 logged experiments with known loads (no
machine file), zeroed on an empty swing of the weighing session, judged on motion families.

Training: swings, work cycles (up to the dump) and lifts of session 1 (``--n-train`` in all, in
the ratio 2:2:1), or one or more ``--mixture`` of swings, work cycles, lifts and ``reach``
motions (every joint through its range at once) and ``slopes`` (work cycles on a slope, up to the
dump); each motion kind simulated once, mixtures take
its first experiments, so every mixture draws from the same data). Zero: one empty swing of
session 2 (as ``calibrated``'s README flow). Judged on session-2 families of
``bench_any_motion`` (``nmpc``, ``work-cycle``, ``operator``, and the held-out operator model
``lever`` / ``lever-slope5`` that nothing in ``src/`` is tuned on), on the simulator's 5°
``slopes`` and, with ``--held-out``, on the held-out ``joystick`` and ``multisine`` families of
``held_out_motions``: share within 1 % / 0.25 % of rated (MAX over ``ok`` samples after 1 s),
mean MAX, false alarms, σ coverage, and optionally the efficiency against the Cramér–Rao bound
of the true machine's model.

Usage::

    PYTHONPATH=src python benchmarks/bench_balance_net.py --n-test 20 --out balance-net
    PYTHONPATH=src python benchmarks/bench_balance_net.py --held-out --after-zero-only \
        --mixture old=swing:40,work-cycle:40,lifts:20 \
        --mixture reach30=swing:30,work-cycle:30,lifts:10,reach:30 --out balance-net-mix
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_any_motion import RATED, families, judge  # noqa: E402
from held_out_motions import joystick_trajectory, multisine_trajectory  # noqa: E402

from excavator_payload.evaluation.crb_machine import dataset_machine_bound  # noqa: E402

from excavator_payload.data.dataset import Dataset  # noqa: E402
from excavator_payload.estimators.base import create_estimator  # noqa: E402
from excavator_payload.evaluation import demo_machine as dm  # noqa: E402
from excavator_payload.simulation.generate import simulate_dataset  # noqa: E402

MACHINE = "cat345c-hydraulic"


def joined(parts: list[Dataset]) -> Dataset:
    """The experiments of ``parts`` numbered one after another."""
    frames, k = [], 0
    for d in parts:
        f = d.frame.copy()
        f["experiment"] = f["experiment"] - f["experiment"].min() + k
        k = int(f["experiment"].max()) + 1
        frames.append(f)
    return Dataset(pd.concat(frames, ignore_index=True), parts[0].meta)


#: training motion kinds and the offset of each one's seed from ``--train-seed``
KINDS = {"swing": 0, "work-cycle": 1, "lifts": 2, "reach": 3, "slopes": 4}


def parse_mixture(text: str) -> tuple[str, dict[str, int]]:
    """``NAME=KIND:N,KIND:N,...`` as (name, {kind: count})."""
    name, _, spec = text.partition("=")
    counts = {}
    for part in spec.split(","):
        kind, _, count = part.partition(":")
        if kind not in KINDS or not count.isdigit():
            raise SystemExit(f"--mixture {text!r}: expected NAME=KIND:N,... with KIND in {sorted(KINDS)}")
        counts[kind] = int(count)
    if not name or sum(counts.values()) == 0:
        raise SystemExit(f"--mixture {text!r}: needs a name and at least one experiment")
    return name, counts


def training_motions(counts: dict[str, int], seed: int) -> dict[str, Dataset]:
    """Each motion kind of session 1, as many experiments as ``counts`` asks (experiment ``k`` of
    a kind is the same whatever the count: each comes from the streams of ``(seed, k)``)."""
    common = dict(machine=MACHINE, session=dm.SESSION_CALIBRATION, with_truth=True, workers=1, progress=False)
    out = {}
    for kind, n in counts.items():
        if n > 0:
            d = simulate_dataset(n, seed=seed + KINDS[kind], motion=kind, **common)
            out[kind] = d.until_dump() if kind in ("work-cycle", "slopes") else d
    return out


def mixture(motions: dict[str, Dataset], counts: dict[str, int]) -> Dataset:
    """The first ``counts[kind]`` experiments of each kind, numbered one after another."""
    return joined([motions[k].subset(motions[k].experiment_ids[:n]) for k, n in counts.items() if n > 0])


def default_counts(n: int) -> dict[str, int]:
    """The 2:2:1 swings, work cycles and lifts of ``n`` experiments."""
    k = max(n // 5, 1)
    return {"swing": 2 * k, "work-cycle": 2 * k, "lifts": n - 4 * k}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n-train", type=int, default=100)
    ap.add_argument("--n-test", type=int, default=20)
    ap.add_argument("--seed", type=int, default=9100)
    ap.add_argument("--train-seed", type=int, default=500)
    ap.add_argument("--out", type=Path, default=Path("balance-net"))
    ap.add_argument("--option", action="append", default=[], help="KEY=VALUE estimator option")
    ap.add_argument("--mixture", action="append", default=[], metavar="NAME=KIND:N,...",
                    help="a training mixture (repeatable; KIND swing, work-cycle, lifts, reach or slopes), "
                         "e.g. reach30=swing:30,work-cycle:30,lifts:10,reach:30; default the 2:2:1 "
                         "swings, work cycles and lifts of --n-train")
    ap.add_argument("--held-out", action="store_true",
                    help="also judge on the held-out `joystick` and `multisine` families")
    ap.add_argument("--after-zero-only", action="store_true", help="judge only after the zero")
    ap.add_argument("--figure", type=Path, default=None,
                    help="also a figure of every judged experiment's error over time (after the zero)")
    ap.add_argument("--efficiency", action="store_true",
                    help="also the efficiency: RMS error over the Cramér–Rao bound of the machine's "
                         "model (calibrated from the true machine file on 10 of the training swings "
                         "and zeroed alike: the information a model-based sensor has)")
    ap.add_argument("--constant-floor-too", action="store_true",
                    help="also σ's coverage with the constant model floor of before 2026-11-29 (the same "
                         "estimates; σ = √(κ²/I + s_model² + s_zero²))")
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    mixtures = dict(parse_mixture(m) for m in a.mixture) or {"2:2:1": default_counts(a.n_train)}
    if len(mixtures) > 1 and a.figure is not None:
        raise SystemExit("--figure draws one model: give one --mixture")
    t0 = time.time()
    largest = {k: max(c.get(k, 0) for c in mixtures.values()) for k in KINDS}
    motions = training_motions(largest, a.train_seed)
    tests = families(a.n_test, a.seed)
    tests["slopes"] = dm.before_release(simulate_dataset(  # work cycles on 5° slopes, up to the dump
        a.n_test, seed=a.seed + 5, motion="slopes", machine=MACHINE, session=dm.SESSION_WORK,
        with_truth=True, workers=1, progress=False))
    if a.held_out:  # nothing in src/ is tuned on these
        tests["joystick"] = dm.simulate_trajectory(joystick_trajectory(a.n_test, a.seed + 6), a.seed + 6,
                                                   dm.SESSION_WORK)
        tests["multisine"] = dm.simulate_trajectory(multisine_trajectory(a.n_test, a.seed + 7), a.seed + 7,
                                                    dm.SESSION_WORK)
    zero = dm.zero_data(a.seed + 50)
    print(f"data simulated ({time.time() - t0:.0f} s)", flush=True)
    options = dict(kv.split("=", 1) for kv in a.option)
    bounds = None
    if a.efficiency:
        from excavator_payload.estimators.classical.calibrated import CalibratedEstimator

        swings = motions.get("swing") or next(iter(motions.values()))
        reference = CalibratedEstimator(MACHINE).fit(swings.subset(swings.experiment_ids[:10]))
        reference.zero(zero)
        bounds = {fam: dataset_machine_bound(ds, reference) for fam, ds in tests.items()}
    rows = []
    for name, counts in mixtures.items():
        train = mixture(motions, counts)
        est = create_estimator("balance-net", None, **options)
        t1 = time.time()
        est.fit(train)
        print(f"{name}: trained on {train.n_experiments} experiments in {time.time() - t1:.1f} s", flush=True)
        for zeroed in ((True,) if a.after_zero_only else (False, True)):
            if zeroed:
                est.zero(zero)
            parts = {"kappa": est.kappa, "model_std_kg": est.model_std, "zero_std_kg": est.model.zero_std,
                     "floor_a": est.floor_a, "floor_b": est.floor_b, "floor_c": est.floor_c}
            print(f"{name} σ parts: κ {parts['kappa']:.2f}, model floor {parts['model_std_kg']:.1f} kg RMS, "
                  f"floor² = max({est.floor_a:.1f} + {est.floor_b:.1f}·novelty + {est.floor_c:.2f}·misfit, 0) kg², "
                  f"zero {parts['zero_std_kg']:.1f} kg", flush=True)
            constant = None
            if a.constant_floor_too:
                import copy

                constant = copy.deepcopy(est)
                constant.floor_a, constant.floor_b, constant.floor_c = est.model_std**2, 0.0, 0.0
            for fam, ds in tests.items():
                row = {"mixture": name, "zero": zeroed, "family": fam, **judge(est, ds), **parts}
                if constant is not None:
                    before = judge(constant, ds)
                    row["sigma_covers_constant"] = before["sigma_covers"]
                    row["same_estimates"] = (before["mean_max_kg"] == row["mean_max_kg"]
                                             and before["within_1pct"] == row["within_1pct"])
                if bounds is not None and zeroed:
                    row["efficiency"] = dm.summary_row(dm.judge(est, ds, "m", bounds[fam]), RATED)["efficiency"]
                rows.append(row)
                print(f"{name} zero {str(zeroed):5s} {fam:13s} ≤1 % {row['within_1pct']:4.0%}  "
                      f"≤0.25 % {row['within_0.25pct']:4.0%}  MAX {row['mean_max_kg']:7.1f} kg  "
                      f"alarms {row['false_alarms']:.2%}  σ covers {row['sigma_covers']:.1%}"
                      + (f" (constant floor {row['sigma_covers_constant']:.1%}, same estimates "
                         f"{row['same_estimates']})" if constant is not None else "") + "  "
                      f"efficiency {row.get('efficiency', float('nan')):.2f}  ({time.time() - t0:.0f} s)",
                      flush=True)
        pd.DataFrame(rows).to_csv(a.out / "balance_net.csv", index=False)
    if a.figure is not None:
        figure(est, tests, a.figure)
    print(f"rated {RATED:.0f} kg; total {time.time() - t0:.0f} s")


def figure(est, tests: dict, path: Path) -> None:
    """Each family's experiments: the error of every ``ok`` weight over time, ±1 % of rated."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, (len(tests) + 1) // 2, figsize=(13, 6.5), sharey=True)
    for ax, (fam, ds) in zip(axes.ravel(), tests.items()):
        e = est.estimate(ds)
        f = ds.frame
        ok = e["status"].astype(str).to_numpy() == "ok"
        err = e["payload_estimate"].to_numpy(float) - f["payload"].to_numpy(float)
        for x in f["experiment"].unique():
            sel = (f["experiment"].to_numpy() == x) & ok
            t = f["time"].to_numpy(float)[sel]
            ax.plot(t - f["time"][f["experiment"] == x].min(), err[sel], lw=0.7, alpha=0.7)
        for y in (-0.01 * RATED, 0.01 * RATED):
            ax.axhline(y, color="k", ls="--", lw=0.8)
        ax.set_title(fam)
        ax.set_xlabel("time (s)")
        ax.set_ylim(-1.6 * 0.01 * RATED, 1.6 * 0.01 * RATED)
    axes.ravel()[0].set_ylabel("error of the weight shown (kg)")
    fig.suptitle("balance-net, learned from 100 logged motions (no machine file), after the zero; "
                 "dashed: ±1 % of rated")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
