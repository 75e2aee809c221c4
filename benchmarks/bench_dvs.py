"""Benchmark the feed-forward DVS networks (net1 by default): training time, streaming speed,
accuracy on fresh experiments, and efficiency against the window Cramér–Rao bound.

    python benchmarks/bench_dvs.py                      # net1, trainbr, thesis noise
    python benchmarks/bench_dvs.py --epochs 100 --motion minimum-jerk --threads 1

Protocol (thesis appendix A.3 and chapter 7): train on experiments 0–99, validate on 100–150
(logged only), test on 200 fresh experiments of another seed; errors after discarding the first
81 samples of every experiment; per experiment the MAX and RMS |error|, then their mean and std
over experiments (Tables 7.1 and 7.2). Efficiency: RMS over all judged samples of
error / σ_CRB where σ_CRB is the bound for the 6 samples the network sees
(``cramer_rao_bound(ds, window=6)``).
"""

from __future__ import annotations

import os
import sys

if "--threads" not in " ".join(sys.argv) or "--threads 1" in " ".join(sys.argv):
    # pin numpy's BLAS before numpy loads: single-threaded measurements (trainbr itself runs
    # BLAS single-threaded and parallelises its own normal equations, execution.job_threads)
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from excavator_payload.estimators.base import create_estimator
from excavator_payload.evaluation.crb import cramer_rao_bound

DISCARD = 81  # samples, thesis chapter 7


CACHE = Path(os.environ.get("EXCAVATOR_PAYLOAD_BENCH_CACHE",
                            Path(tempfile.gettempdir()) / "excavator_payload_bench"))


def make_data(n: int, seed: int, noise: str, motion: str, first: int = 0):
    """Dataset with truth columns; NMPC data are cached as Parquet (they take minutes to make)."""
    if motion == "nmpc":
        from excavator_payload.data.io import read_dataset, write_dataset
        from excavator_payload.simulation.generate import simulate_dataset

        path = CACHE / f"nmpc_n{n}_seed{seed}_first{first}_{noise}.parquet"
        if path.is_file():
            return read_dataset(path)
        ds = simulate_dataset(n, seed, noise=noise, with_truth=True, first_experiment=first)
        CACHE.mkdir(parents=True, exist_ok=True)
        write_dataset(ds, path)
        return ds
    from excavator_payload.simulation.minimum_jerk import simulate_minimum_jerk

    return simulate_minimum_jerk(n, seed=seed, noise=noise, with_truth=True, first_experiment=first)


def judged_errors(frame, dataset, discard: int = DISCARD) -> tuple[np.ndarray, np.ndarray]:
    """Errors (kg) and row mask of the judged samples (sample index ≥ ``discard``)."""
    err = frame["payload_estimate"].to_numpy() - dataset.frame["payload"].to_numpy()
    index = dataset.frame.groupby("experiment", sort=False).cumcount().to_numpy()
    return err, index >= discard


def accuracy(frame, dataset, window: int | None, discard: int = DISCARD) -> dict:
    """Table 7.1/7.2 statistics and the CRB efficiency ratio."""
    err, judged = judged_errors(frame, dataset, discard)
    exp = dataset.frame["experiment"].to_numpy()
    mx, rms = [], []
    for e in dataset.experiment_ids:
        sel = judged & (exp == e)
        mx.append(np.nanmax(np.abs(err[sel])))
        rms.append(np.sqrt(np.nanmean(err[sel] ** 2)))
    mx, rms = np.array(mx), np.array(rms)
    out = {"max_mean": mx.mean(), "max_std": mx.std(), "rms_mean": rms.mean(), "rms_std": rms.std(),
           "n_nan": int(np.isnan(err[judged]).sum())}
    bound = cramer_rao_bound(dataset, window=window)[judged]
    e = err[judged]
    out["crb_rms"] = float(np.sqrt(np.mean(bound**2)))
    out["efficiency"] = float(np.sqrt(np.mean((e / bound) ** 2)))  # RMS of error / bound
    out["efficiency_rms_over_rms"] = float(np.sqrt(np.mean(e**2)) / out["crb_rms"])
    return out


def print_accuracy(label: str, acc: dict) -> None:
    print(f"{label}: MAX |err| mean {acc['max_mean']:.2f} kg (std {acc['max_std']:.2f}), "
          f"RMS |err| mean {acc['rms_mean']:.2f} kg (std {acc['rms_std']:.2f}); "
          f"window CRB RMS {acc['crb_rms']:.2f} kg, efficiency RMS(err/CRB) {acc['efficiency']:.2f}, "
          f"RMS(err)/RMS(CRB) {acc['efficiency_rms_over_rms']:.2f}")


def time_streaming(est, dataset, n_samples: int = 20_000) -> tuple[float, float]:
    """µs per sample for step_values() and step(mapping), on one experiment repeated."""
    values = dataset.signals()
    times = dataset.frame["time"].to_numpy()
    rows = dataset.frame.to_dict("records")
    n = min(n_samples, len(values))
    est.reset()
    t0 = time.perf_counter()
    for i in range(n):
        if i and times[i] <= times[i - 1]:
            est.reset()
        est.step_values(times[i], values[i])
    per_values = (time.perf_counter() - t0) / n * 1e6
    est.reset()
    t0 = time.perf_counter()
    for i in range(n):
        if i and times[i] <= times[i - 1]:
            est.reset()
        est.step(rows[i])
    per_mapping = (time.perf_counter() - t0) / n * 1e6
    return per_values, per_mapping


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--network", default="net1", choices=["net1", "ffnn", "dtdnn"])
    p.add_argument("--trainer", default="trainbr", choices=["trainbr", "adam"])
    p.add_argument("--epochs", type=int, default=None, help="default: the network's default")
    p.add_argument("--noise", default="thesis")
    p.add_argument("--motion", default="nmpc", choices=["nmpc", "minimum-jerk"])
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--n-test", type=int, default=200)
    p.add_argument("--save", default=None, help="save the trained model here")
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    motion = args.motion
    t0 = time.perf_counter()
    train = make_data(151, 1, args.noise, motion)
    test = make_data(args.n_test, 2, args.noise, motion, first=1000)
    print(f"data: {motion} motions, {args.noise} noise, 151 train/validation + {args.n_test} test "
          f"experiments ({time.perf_counter() - t0:.1f} s)")
    options = {"trainer": args.trainer, "progress": True}
    if args.epochs is not None:
        options["epochs"] = args.epochs
    est = create_estimator(args.network, **options)
    t0 = time.perf_counter()
    est.fit(train)
    seconds = time.perf_counter() - t0
    log = est.training_log
    n_ep = log.epoch[-1]
    print(f"training {args.network}/{args.trainer} on 100 experiments: {seconds:.1f} s, {n_ep} epochs "
          f"({seconds / max(n_ep, 1):.3f} s/epoch), stop: {log.stop_reason}; final SSE {log.sse[-1]:.4g}, "
          f"γ {log.gamma[-1]:.1f} of {log.n_parameters}, validation SSE {log.validation_sse[-1]:.4g}")
    if args.save:
        est.save(args.save)
    t0 = time.perf_counter()
    frame = est.estimate(test)
    print(f"estimate(): {len(frame)} samples in {time.perf_counter() - t0:.2f} s")
    # samples the output depends on: the input delay line, or for dtdnn all layers' delay lines
    n_layers = len(est.hidden_sizes) + 1 if args.network == "dtdnn" else 1
    window = n_layers * max(est.delay_list) + 1
    print_accuracy(f"test ({args.n_test} fresh experiments, samples ≥ {DISCARD})",
                   accuracy(frame, test, window=window))
    print(f"  (thesis Table 7.1/7.2 Net1: MAX mean 0.50 kg std 0.43, RMS mean 0.30 kg std 0.29)")
    per_values, per_mapping = time_streaming(est, test)
    print(f"step(): {per_values:.1f} µs/sample via step_values(), {per_mapping:.1f} µs/sample via "
          f"step(mapping) (target ≤ 50 µs)")


if __name__ == "__main__":
    main()
