"""Accuracy and step() cost of the estimators on the machine sensor set (issue 12, helper mfilt).

Judges one estimator on a swing and a work-cycle test file (first second discarded; work cycles
only up to the moment the load starts to leave the bucket, ``release[0]`` of the experiment
metadata, because their ``payload`` column is the loaded payload throughout) and times
``step_values`` on one swing (CPU µs per sample, median of 5 passes over 1000 samples).

Usage::

    python benchmarks/bench_machine_filters.py NAME FIT N_TEST [SWING.parquet WORK.parquet] [--opt value …]

``NAME`` an estimator; ``FIT`` the dataset(s) to fit on, comma separated (``model:DIR`` for a
trained model);
``N_TEST`` experiments of each test file (default files ``test_swing.parquet``,
``test_work.parquet``). Example (the report's numbers)::

    excavator-payload simulate --machine cat345c-hydraulic --motion swing --session 3 -n 50 \\
        --seed 1000 --out test_swing.parquet
    excavator-payload simulate --machine cat345c-hydraulic --motion work-cycle --session 3 -n 50 \\
        --seed 2000 --out test_work.parquet
    excavator-payload simulate --machine cat345c-hydraulic --motion swing --session 1 -n 10 \\
        --seed 4000 --out fit_swing.parquet
    excavator-payload simulate --machine cat345c-hydraulic --motion work-cycle --session 2 -n 10 \\
        --seed 5000 --out fit_work.parquet
    excavator-payload simulate --machine cat345c-hydraulic --motion lifts --session 1 -n 10 \\
        --seed 3000 --out lifts.parquet
    python benchmarks/bench_machine_filters.py inverse-dynamics fit_swing.parquet,fit_work.parquet 50
    python benchmarks/bench_machine_filters.py quasi-static lifts.parquet 50
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.io import read_dataset
from excavator_payload.estimators.base import create_estimator, load_estimator
from excavator_payload.evaluation.metrics import evaluate_estimates

FIGURES = ("n_experiments", "mean_max", "mean_rms", "mean_max_pct", "mean_rms_pct",
           "meets_requirement_share", "estimated_share")


def loaded_part(ds: Dataset) -> Dataset:
    """The samples before the load starts to leave the bucket (experiments without a release
    are kept whole)."""
    release = {k: (v.get("release") or [np.inf])[0] for k, v in ds.experiment_meta.items()}
    f = ds.frame
    keep = f["time"].to_numpy() < f["experiment"].map(release).fillna(np.inf).to_numpy()
    return Dataset(f[keep].reset_index(drop=True), ds.meta)


def step_cpu_us(est, data: Dataset, n: int = 1000) -> float:
    one = data.subset([data.experiment_ids[0]])
    t = one.frame["time"].to_numpy()
    v = one.signals(est.sensor_set.signals)
    n = min(n, len(t))
    runs = []
    for _ in range(5):
        est.reset()
        t0 = time.process_time()
        for i in range(n):
            est.step_values(t[i], v[i])
        runs.append((time.process_time() - t0) / n * 1e6)
    return float(np.median(runs))


def main(argv: list[str]) -> None:
    positional = [a for a in argv if not a.startswith("--")][:5]
    rest = argv[len(positional):]
    options = {rest[i].lstrip("-").replace("-", "_"): rest[i + 1] for i in range(0, len(rest), 2)}
    name, fit_on, n_test = positional[0], positional[1], int(positional[2])
    files = positional[3:5] or ["test_swing.parquet", "test_work.parquet"]
    if fit_on.startswith("model:"):
        est = load_estimator(fit_on[6:])
    else:  # FIT may be several files, comma separated (experiments renumbered)
        parts = [read_dataset(path) for path in fit_on.split(",")]
        frames, offset = [], 0
        for part in parts:
            frame = part.frame.copy()
            frame["experiment"] = frame["experiment"].map(
                {e: offset + i for i, e in enumerate(part.experiment_ids)})
            offset += part.n_experiments
            frames.append(frame)
        import pandas as pd

        meta = {k: v for k, v in parts[0].meta.items() if k != "experiments"}
        fit = Dataset(pd.concat(frames, ignore_index=True), meta)
        est = create_estimator(name, fit.meta.get("machine", {}).get("name", "cat345c-hydraulic"),
                               **options).fit(fit)
    out = {"estimator": name, "fit_on": fit_on, "options": options}
    for label, path in zip(("swing", "work-cycle"), files):
        ds = read_dataset(path)
        ds = loaded_part(ds.subset(list(ds.experiment_ids)[:n_test]))
        summary = evaluate_estimates(ds, est.estimate(ds), discard=100, with_bound=False,
                                     label=name).summary
        out[label] = {k: summary[k] for k in FIGURES}
    out["step_cpu_us"] = step_cpu_us(est, read_dataset(files[0]))
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main(sys.argv[1:])
