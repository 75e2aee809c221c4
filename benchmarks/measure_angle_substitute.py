"""The lost-angle substitute's bound (docs/sensor-health.md, "A lost link angle"): on clean
tuning data, (1) the drift of the reference + integrated rate against the measured angle, and
(2) the degraded weighing error against the time since the angle was named, the bound lifted.

    python benchmarks/bench_faults.py --n 8 --seed 9300 --families operator,work-cycle,nmpc --out faults
    python benchmarks/measure_angle_substitute.py faults --seed 9300

Reads the bench's cached model and clean data (``faults/model-calibrated-SEED``,
``faults/clean-FAMILY-N-SEED.parquet``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.io import read_dataset
from excavator_payload.estimators import health
from excavator_payload.estimators.base import load_estimator

LINKS = ("boom", "dipper", "bucket")
HORIZONS = (0.5, 1.0, 2.0, 3.0, 5.0, 8.0, 12.0)
BINS = [0, 1, 2, 3, 5, 8, 12, 20]


def drift(frames: list[pd.DataFrame], dt: float, n_stuck: int, n_sub: int) -> pd.DataFrame:
    """|y(t + T) − reference(t)| per link and horizon (degrees), y = angle − integrated rate."""
    out = {(link, h): [] for link in LINKS for h in HORIZONS}
    for f in frames:
        for _, g in f.groupby("experiment"):
            for link in LINKS:
                a, r = g[f"{link}_angle"].to_numpy(), g[f"{link}_rate"].to_numpy()
                y = a - np.concatenate([[0.0], np.cumsum(0.5 * dt * (r[1:] + r[:-1]))])
                for t0 in range(151, len(y), 10):
                    ref = y[t0 - n_stuck - n_sub:t0 - n_stuck].mean()
                    for h in HORIZONS:
                        k = t0 + int(round(h / dt))
                        if k < len(y):
                            out[(link, h)].append(abs(y[k] - ref))
    rows = [{"link": link, "T_s": h, "p50_deg": np.degrees(np.median(v)), "p99_deg": np.degrees(np.quantile(v, 0.99))}
            for (link, h), v in out.items()]
    return pd.DataFrame(rows)


def by_age(est, datasets: list, seed: int) -> pd.DataFrame:
    """Degraded error per sample with its time since the first degraded sample of the case."""
    health.ANGLE_SUBSTITUTE_LIMIT = 1e6  # unbounded (a fresh monitor reads it)
    est._health_for = None
    rng = np.random.default_rng(1)
    rows = []
    for ds in datasets:
        for e in ds.frame["experiment"].unique():
            one = ds.frame[ds.frame["experiment"] == e].reset_index(drop=True)
            n, truth, t = len(one), one["payload"].to_numpy(), one["time"].to_numpy()
            for link in LINKS:
                for kind in ("stuck", "dropout"):
                    a = int(rng.integers(150, n // 2))
                    bad = one.copy()
                    v = bad[f"{link}_angle"].to_numpy().copy()
                    v[a:] = v[a - 1] if kind == "stuck" else 0.0
                    bad[f"{link}_angle"] = v
                    out = est.estimate(Dataset(bad, ds.meta))
                    deg = np.flatnonzero(out["status"].to_numpy() == "degraded")
                    for k in deg:
                        rows.append({"link": link, "kind": kind, "age": t[k] - t[deg[0]],
                                     "err": abs(out["payload_estimate"].iloc[k] - truth[k]),
                                     "sigma": out["sigma"].iloc[k]})
    return pd.DataFrame(rows)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path, help="bench_faults.py's --out folder")
    ap.add_argument("--seed", type=int, default=9300)
    ap.add_argument("--n", type=int, default=8)
    ap.add_argument("--families", default="operator,work-cycle,nmpc")
    a = ap.parse_args()
    datasets = [read_dataset(a.folder / f"clean-{f}-{a.n}-{a.seed}.parquet") for f in a.families.split(",")]
    est = load_estimator(a.folder / f"model-calibrated-{a.seed}")
    m = health.for_sensor_set(est.sensor_set)
    print(drift([d.frame for d in datasets], m.period, m.n_stuck, m.n_sub).round(2).to_string(index=False))
    g = by_age(est, datasets, a.seed)
    g["bin"] = pd.cut(g["age"], BINS, right=False)
    table = g.groupby("bin", observed=True).apply(lambda h: pd.Series({
        "samples": len(h), "worst_kg": h["err"].max(), "p99_kg": np.quantile(h["err"], 0.99),
        "within_2sigma": np.mean(h["err"] <= 2 * h["sigma"])}), include_groups=False)
    print(table.round(3).to_string())


if __name__ == "__main__":
    main()
