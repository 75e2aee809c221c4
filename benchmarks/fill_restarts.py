"""Per pass of a cached ``shift`` chunk: where the weighing restarts around the fill (issue 28).

For each pass of each truck in a chunk of ``bench_false_alarms.py`` (``--cache``, ``--seed``,
``--chunks``) the user's default flow (the benchmark's cached ``study`` estimator) is run with
the kernel's state recorded per sample (``wait_after_load._recording_step``), and per pass it
prints, in seconds from the fill's end (the bucket's curl, ``passes[k]["fill"][1]``): the last
sample whose bucket rate closes faster than ``--closing`` °/s, each restart of the weighing
(``new_loads``) from 3 s before the fill to the release, the first boom window weighed after the
fill's end, and the first ``ok`` before the release with its error (kg) and σ.

Usage::

    PYTHONPATH=src python benchmarks/fill_restarts.py --cache /work/scratch/alarms --seed 95000 \\
        --chunks 0 [--set NAME=VALUE]
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_false_alarms as bfa  # noqa: E402
import wait_after_load as wal  # noqa: E402

from excavator_payload.data.io import read_dataset  # noqa: E402
from excavator_payload.estimators.classical.pressure_regression import PressureKernel  # noqa: E402


def passes_of(est, path: Path, closing: float) -> pd.DataFrame:
    """One row per pass of a cached ``shift`` chunk (times in s from the pass's fill's end).

    Parameters
    ----------
    est : Estimator
        The fitted, zeroed ``calibrated`` estimator (its kernel's ``step`` recorded).
    path : pathlib.Path
        The chunk's Parquet file.
    closing : float
        The bucket's closing rate that counts as fast, rad/s.
    """
    ds = read_dataset(path, validate=False)
    wal.RECORD.clear()
    ef = est.estimate(ds)
    rec = pd.DataFrame(wal.RECORD, columns=wal.COLUMNS)
    frame = ds.frame.reset_index(drop=True)
    if len(rec) != len(frame):
        raise SystemExit("a sample was kept from the kernel: this trace needs one record per sample")
    status = ef["status"].astype(str).to_numpy()
    estimate = ef["payload_estimate"].to_numpy(float)
    sigma = ef["sigma"].to_numpy(float)
    t = frame["time"].to_numpy(float)
    rate = frame["bucket_rate"].to_numpy(float)
    rows = []
    for exp, idx in frame.groupby("experiment").indices.items():
        idx = np.asarray(idx)
        tt = t[idx] - t[idx[0]]
        loads = rec["new_loads"].to_numpy()[idx]
        booms = rec["boom_windows"].to_numpy()[idx]
        boom_weighed = np.r_[False, np.diff(booms) > 0]
        for p in ds.experiment_meta[int(exp)].get("passes", []):
            fill_start, fill_end = p["fill"]
            release = p["release"][0]
            near = (tt >= fill_start - 3.0) & (tt < release)
            restarts = tt[1:][(np.diff(loads) > 0) & near[1:]]
            fast = (tt >= fill_start - 0.5) & (tt <= fill_end + 0.5) & (rate[idx] < -closing)
            after = (tt >= fill_end) & (tt < release)
            ok = np.flatnonzero(after & (status[idx] == "ok"))
            boom = tt[after & boom_weighed]
            row = {"experiment": int(exp), "pass": p["pass"], "load": round(float(p["payload"])),
                   "fill": f"{fill_start:.2f}-{fill_end:.2f}",
                   "last_fast": round(tt[fast].max() - fill_end, 2) if fast.any() else np.nan,
                   "restarts": " ".join(f"{r - fill_end:+.2f}" for r in restarts),
                   "boom_from": round(boom[0] - fill_end, 2) if len(boom) else np.nan,
                   "first_ok": np.nan, "error": np.nan, "sigma": np.nan}
            if len(ok):
                k = idx[ok[0]]
                row.update(first_ok=round(tt[ok[0]] - fill_end, 2), error=round(estimate[k] - p["payload"], 1),
                           sigma=round(sigma[k], 1))
            rows.append(row)
    return pd.DataFrame(rows)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cache", type=Path, default=Path("/work/scratch/alarms"))
    ap.add_argument("--seed", type=int, default=bfa.SEED)
    ap.add_argument("--chunks", default="0")
    ap.add_argument("--calibration", default="study")
    ap.add_argument("--closing", type=float, default=20.0, help="the bucket's fast closing, °/s")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--set", action="append", default=[], help="NAME=VALUE: a kernel setting for this run")
    a = ap.parse_args()
    wal.set_kernel(a.set)
    PressureKernel.step = wal._recording_step(PressureKernel.step)
    est = bfa.calibrated(a.calibration, a.cache)
    folder = a.cache / "shift" if a.seed == bfa.SEED else a.cache / f"seed-{a.seed}" / "shift"
    table = pd.concat([passes_of(est, folder / f"chunk{int(k):03d}.parquet", math.radians(a.closing))
                       for k in a.chunks.split(",")], ignore_index=True)
    if a.out:
        table.to_csv(a.out, index=False)
    with pd.option_context("display.width", 200, "display.max_rows", 400):
        print(table.to_string(index=False))
        later = table[table["pass"] > 1]  # a truck's first pass lies in the excused first wait
        print("passes after the first:", later[["last_fast", "boom_from", "first_ok", "error", "sigma"]]
              .describe().round(2).to_string(), sep="\n")


if __name__ == "__main__":
    main()
