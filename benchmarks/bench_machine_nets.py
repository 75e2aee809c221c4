"""The networks on the machine sensor set (issue 12): training data of several sessions, training,
and judging on the test sets of ``bench_machine_study.py`` beside the model-based estimators.

Usage::

    # training + validation data: NMPC swings, planned swings and work cycles (each work cycle
    # up to the dump), sessions 3…8 for training, 9…11 for validation (the tests are session 2)
    PYTHONPATH=src python benchmarks/bench_machine_nets.py data --out nets-data
    # the same count from ONE session (1, the calibration session), to see what sessions teach
    PYTHONPATH=src python benchmarks/bench_machine_nets.py data --out nets-data-1 --sessions 1 --per-motion 54 \\
        --seed 40000
    # train (any estimator options after --; threads: execution.job_threads), then judge on
    # the tests of bench_machine_study.py
    PYTHONPATH=src python benchmarks/bench_machine_nets.py train net1 nets-data/train_val.parquet \\
        net1-d5 -- --decimation 5 --delays 0:5
    PYTHONPATH=src python benchmarks/bench_machine_nets.py judge net1-d5 machine-study --n-test 200
    # --smoothing chosen on the validation experiments (the last 54 of the data file), not the tests
    PYTHONPATH=src python benchmarks/bench_machine_nets.py judge net1-d5 nets-data/train_val.parquet \\
        --last 54 --smoothing 0,0.5,1,2,4

``judge`` uses the study's own rows (``demo_machine.judge`` / ``summary_row``: first second
discarded, mean MAX / RMS, shares within 1 / 0.5 / 0.25 % of the rated 5 t) and also prints the
mean per-experiment bias and what an output tare from the study's zero motion (``zero.parquet``,
the empty-bucket swing of the test session) would do, so a network's error can be told apart
from an offset it cannot see.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.io import read_dataset, write_dataset
from excavator_payload.evaluation import demo_machine as dm

MOTIONS = ("nmpc", "swing", "work-cycle")
TEST_SETS = ("nmpc", "swing", "work-cycle", "slope-5deg", "hand-made trajectory")


def simulate(n: int, seed: int, motion: str, session: int) -> Dataset:
    """``n`` experiments of one motion family in one session (work cycles up to the dump)."""
    from excavator_payload.simulation.generate import simulate_dataset

    ds = simulate_dataset(n, seed=seed, machine="cat345c-hydraulic", motion=motion, session=session,
                          with_truth=False, workers=1, progress=False)
    return dm.before_release(ds) if motion == "work-cycle" else ds


def concat(parts: list[Dataset]) -> Dataset:
    """One dataset of several, experiments renumbered 0, 1, … in order."""
    frames, experiments, k = [], [], 0
    for ds in parts:
        frame = ds.frame.copy()
        ids = list(dict.fromkeys(frame["experiment"].tolist()))
        renumber = {old: k + i for i, old in enumerate(ids)}
        frame["experiment"] = frame["experiment"].map(renumber)
        meta = ds.experiment_meta
        for old in ids:
            experiments.append({**meta[old], "experiment": renumber[old],
                                "session": meta[old].get("session", ds.meta.get("session"))})
        frames.append(frame)
        k += len(ids)
    meta = {**parts[0].meta, "experiments": experiments, "motion": "mixed"}
    return Dataset(pd.concat(frames, ignore_index=True), meta)


def sessions_block(sessions, per_motion: int, seed: int) -> list[Dataset]:
    return [simulate(per_motion, seed + 100 * s + 10 * j, motion, s)
            for s in sessions for j, motion in enumerate(MOTIONS)]


def make_data(a) -> None:
    a.out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    train = concat(sessions_block(a.sessions, a.per_motion, a.seed))
    val = concat(sessions_block(a.val_sessions, a.val_per_motion, a.val_seed))
    both = concat([train, val])
    write_dataset(both, a.out / "train_val.parquet")
    print(f"{a.out / 'train_val.parquet'}: {train.n_experiments} training experiments (sessions "
          f"{a.sessions}), then {val.n_experiments} validation experiments (sessions {a.val_sessions}); "
          f"train with --train-experiments {train.n_experiments} --validation-experiments "
          f"{val.n_experiments} ({time.perf_counter() - t0:.0f} s)")


def train(a) -> None:
    from excavator_payload.estimators.base import create_estimator

    ds = read_dataset(a.data)
    n_train = sum(1 for e in ds.meta.get("experiments", []) if e.get("session") not in a.val_sessions)
    options = dict(zip([o.lstrip("-").replace("-", "_") for o in a.options[::2]], a.options[1::2]))
    options.setdefault("train_experiments", n_train)
    options.setdefault("validation_experiments", ds.n_experiments - int(options["train_experiments"]))
    est = create_estimator(a.name, **options)
    t0 = time.perf_counter()
    est.fit(ds)
    est.save(a.out)
    log = est.training_log
    print(f"{a.name}: {log.epoch[-1]} epochs ({log.stop_reason}), {log.seconds:.0f} s training, "
          f"{log.n_errors} targets × {log.n_parameters} weights, {log.seconds / max(log.epoch[-1], 1):.2f} s/epoch; "
          f"fit + judging the validation set {time.perf_counter() - t0:.0f} s; saved to {a.out}")


def judge(a) -> None:
    from excavator_payload.estimators.base import load_estimator

    est = load_estimator(a.model)
    if a.tests.is_dir():
        paths = {name: a.tests / f"{name}.parquet" for name in TEST_SETS}
        zero_path = a.tests / "zero.parquet"
    else:  # one file, e.g. the validation experiments (to choose --smoothing without the tests)
        paths, zero_path = {a.tests.stem: a.tests}, None
    sets = {}
    for name, path in paths.items():
        if path.exists():
            ds = read_dataset(path)
            sets[name] = ds.subset(ds.experiment_ids[-a.last:]) if a.last else \
                ds.subset(ds.experiment_ids[:a.n_test]) if a.n_test else ds
    rows = []
    for smoothing in a.smoothing:
        # a streaming-time option: the trained weights are the same
        est.smoothing = est.options["smoothing"] = smoothing
        est.reset()
        tare = math.nan
        if zero_path is not None and zero_path.exists():
            zero = read_dataset(zero_path)
            z = est.estimate(zero)
            ok = (z["status"] == "ok").to_numpy()
            tare = float(np.mean(z["payload_estimate"].to_numpy(float)[ok]
                                 - zero.frame["payload"].to_numpy(float)[ok]))
        print(f"{a.model} smoothing {smoothing:g} s", flush=True)
        for name, ds in sets.items():
            rows.append(_judge_one(est, ds, name, a.model, smoothing, tare))
    if a.csv:
        pd.DataFrame(rows).to_csv(a.csv, index=False)


def _judge_one(est, ds, name, model, smoothing, tare) -> dict:
    """One row: the study's figures, the mean per-experiment bias, and the MAX after a tare."""
    t0 = time.perf_counter()
    evaluation = dm.judge(est, ds, est.name, None)
    row = {"test": name, "estimator": est.name, "model": str(model), "smoothing_s": smoothing,
           **dm.summary_row(evaluation, dm.RATED_PAYLOAD)}
    # per-experiment mean error: the part of the error a constant tare could remove
    errors = pd.DataFrame({"experiment": ds.frame["experiment"].to_numpy(),
                           "k": ds.frame.groupby("experiment").cumcount().to_numpy(),
                           "error": np.asarray(evaluation.estimates, float)
                           - ds.frame["payload"].to_numpy(float)})
    judged = errors[errors["k"] >= dm.DISCARD]
    bias = judged.groupby("experiment")["error"].mean()
    tared_max = judged.assign(e=(judged["error"] - tare).abs()).groupby("experiment")["e"].max()
    row.update(mean_bias_kg=float(bias.mean()), mean_abs_bias_kg=float(bias.abs().mean()),
               zero_tare_kg=tare, tared_mean_max_kg=float(tared_max.mean()),
               tared_within_1pct=float((tared_max <= 0.01 * dm.RATED_PAYLOAD).mean()),
               seconds=time.perf_counter() - t0)
    print(f"{name:22s} MAX {row['mean_max_kg']:7.0f}  RMS {row['mean_rms_kg']:6.0f}  within 1 % "
          f"{100 * row['within_1pct']:3.0f} %  mean bias {row['mean_bias_kg']:+6.0f} (|·| "
          f"{row['mean_abs_bias_kg']:5.0f})  tared by {tare:+.0f} kg: MAX {row['tared_mean_max_kg']:7.0f}, "
          f"{100 * row['tared_within_1pct']:3.0f} %  ({row['seconds']:.0f} s, {row['n_test']} experiments)",
          flush=True)
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="command", required=True)
    d = sub.add_parser("data", help="simulate training + validation data")
    d.add_argument("--out", type=Path, required=True)
    d.add_argument("--sessions", type=lambda s: [int(x) for x in s.split(",")], default=[3, 4, 5, 6, 7, 8])
    d.add_argument("--per-motion", type=int, default=9, help="experiments per motion family and session")
    d.add_argument("--val-sessions", type=lambda s: [int(x) for x in s.split(",")], default=[9, 10, 11])
    d.add_argument("--val-per-motion", type=int, default=6)
    d.add_argument("--seed", type=int, default=50000)
    d.add_argument("--val-seed", type=int, default=60000)
    t = sub.add_parser("train", help="train a network on a data file (options after --)")
    t.add_argument("name")
    t.add_argument("data", type=Path)
    t.add_argument("out", type=Path)
    t.add_argument("--val-sessions", type=lambda s: [int(x) for x in s.split(",")], default=[9, 10, 11])
    j = sub.add_parser("judge", help="judge a trained model on the study's test sets")
    j.add_argument("model", type=Path)
    j.add_argument("tests", type=Path, help="the --out folder of bench_machine_study.py")
    j.add_argument("--n-test", type=int, default=0, help="first N experiments of each set (0: all)")
    j.add_argument("--last", type=int, default=0, help="the last N experiments of the file instead")
    j.add_argument("--smoothing", type=lambda s: [float(x) for x in s.split(",")], default=[0.0],
                   help="--smoothing values (s) to judge the model with, comma separated")
    j.add_argument("--csv", type=Path, default=None)
    argv = sys.argv[1:]
    # estimator options (train) follow "--", passed through as they are
    split = argv.index("--") if "--" in argv else len(argv)
    a = ap.parse_args(argv[:split])
    a.options = argv[split + 1:]
    {"data": make_data, "train": train, "judge": judge}[a.command](a)


if __name__ == "__main__":
    main()
