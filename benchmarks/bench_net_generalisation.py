"""The thesis' Net₁ trained on one motion family (or a mixture) and judged on every family.

Thesis setting (2-link arm, torque sensors, 20 Hz). Families: the thesis' ``nmpc`` swings,
``minimum-jerk`` swings and ``lifts``; ``mixture`` trains on a third of each. Every network has
the thesis' structure and training (``trainbr``, 700 epochs, 100 training and 51 validation
experiments); the test sets are other seeds. Prints and writes a Markdown table: share of test
experiments with MAX ≤ 1 % of rated (50 kg) and mean MAX, after the thesis' 81 discarded samples.

Usage::

    PYTHONPATH=src python benchmarks/bench_net_generalisation.py --out net-generalisation
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import pandas as pd

from excavator_payload.data.dataset import Dataset
from excavator_payload.estimators.base import create_estimator
from excavator_payload.evaluation.metrics import evaluate_estimates
from excavator_payload.simulation.generate import simulate_dataset

FAMILIES = ("nmpc", "minimum-jerk", "lifts")
N_TRAIN, N_VALIDATION = 100, 51


def simulate(motion: str, n: int, seed: int) -> Dataset:
    return simulate_dataset(n, seed=seed, motion=motion, workers=1, progress=False)


def renumbered(parts: list[pd.DataFrame]) -> pd.DataFrame:
    """Experiments of ``parts`` in that order, numbered 0, 1, …"""
    out, k = [], 0
    for frame in parts:
        for _, g in frame.groupby("experiment", sort=True):
            g = g.copy()
            g["experiment"] = k
            out.append(g)
            k += 1
    return pd.concat(out, ignore_index=True)


def mixture(train_sets: dict[str, Dataset]) -> Dataset:
    """A third of each family's training and validation experiments, interleaved by family."""
    def take(ds, lo, n):
        ids = ds.experiment_ids[lo:lo + n]
        return ds.frame[ds.frame["experiment"].isin(ids)]
    shares = [34, 33, 33]
    val = [17, 17, 17]
    train = [take(ds, 0, n) for ds, n in zip(train_sets.values(), shares)]
    validation = [take(ds, N_TRAIN, n) for ds, n in zip(train_sets.values(), val)]
    first = next(iter(train_sets.values()))
    return Dataset(renumbered(train + validation), dict(first.meta))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed", type=int, default=8100)
    ap.add_argument("--n-test", type=int, default=30)
    ap.add_argument("--epochs", type=int, default=700)
    ap.add_argument("--out", type=Path, default=Path("net-generalisation"))
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    train = {f: simulate(f, N_TRAIN + N_VALIDATION, a.seed + 10 * i) for i, f in enumerate(FAMILIES)}
    tests = {f: simulate(f, a.n_test, a.seed + 500 + 10 * i) for i, f in enumerate(FAMILIES)}
    train["mixture"] = mixture({f: train[f] for f in FAMILIES})
    print(f"simulated ({time.time() - t0:.0f} s)", flush=True)
    rows = []
    for name, ds in train.items():
        est = create_estimator("net1", epochs=a.epochs, progress=False).fit(ds)
        for fam, test in tests.items():
            ev = evaluate_estimates(test, est.estimate(test), label="net1", with_bound=False)
            max_err = ev.per_experiment["max_error"].to_numpy(float)
            rows.append({"trained on": name, "tested on": fam, "within_1pct": float(np.mean(max_err <= 50.0)),
                         "mean_max_kg": float(np.mean(max_err))})
            print(rows[-1], f"({time.time() - t0:.0f} s)", flush=True)
        pd.DataFrame(rows).to_csv(a.out / "net_generalisation.csv", index=False)
    table = pd.DataFrame(rows)
    lines = ["| trained on \\ tested on | " + " | ".join(FAMILIES) + " |", "|---|" + "---|" * len(FAMILIES)]
    for name in train:
        cells = [f"{r.within_1pct:.0%} · {r.mean_max_kg:.0f} kg"
                 for r in table[table["trained on"] == name].itertuples()]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    (a.out / "net_generalisation.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    print(f"total {time.time() - t0:.0f} s")


if __name__ == "__main__":
    main()
