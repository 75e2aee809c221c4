"""Benchmark of the NMPC simulator: wall time per experiment on one core, NMPC solve times,
share of experiments that reach the target (within 1° and at rest by t = 5 s).

Usage: python benchmarks/bench_simulate.py [N_EXPERIMENTS=200] [SEED=0]
"""

import sys
import time

import numpy as np

from excavator_payload.simulation.generate import simulate_dataset


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 200
    seed = int(sys.argv[2]) if len(sys.argv) > 2 else 0
    start = time.perf_counter()
    build = time.perf_counter()
    from excavator_payload.model.machine import load_machine
    from excavator_payload.simulation.generate import _simulator

    _simulator(load_machine("cat345c"))  # controller construction, once per worker process
    build = time.perf_counter() - build  # includes compiling the model unless cached
    run = time.perf_counter()
    run_cpu = time.process_time()
    ds = simulate_dataset(n, seed=seed, workers=1, progress=False)
    run = time.perf_counter() - run
    run_cpu = time.process_time() - run_cpu
    cpu = time.process_time()
    metas = ds.meta["experiments"]
    skipped = ds.meta["skipped"]
    walls = np.array([m["wall_time"] for m in metas])
    medians = np.array([m["solve_time_median_ms"] for m in metas])
    maxima = np.array([m["solve_time_max_ms"] for m in metas])
    reached = np.array([m["reached"] for m in metas])
    settle = np.array([m["settle_time"] for m in metas if m["settle_time"] is not None])
    fallbacks = np.array([m["n_fallbacks"] for m in metas])
    err = np.abs(np.array([m["final_error_deg"] for m in metas]))
    print(f"experiments: {n} requested, {len(metas)} written, {len(skipped)} skipped")
    for s in skipped:
        print(f"  skipped #{s['experiment']}: {s['reason']}")
    print(f"controller build (once per worker): {build:.2f} s")
    print(f"wall per experiment (1 worker): mean {walls.mean():.3f} s, median {np.median(walls):.3f} s, "
          f"max {walls.max():.3f} s; whole run {run:.1f} s ({run / n:.3f} s/experiment incl. noise/frames)")
    print(f"CPU time per experiment (1 worker): {run_cpu / n:.3f} s "
          "(wall exceeds it when other jobs share the cores)")
    print(f"NMPC solve time per control step: median of medians {np.median(medians):.2f} ms, "
          f"worst {maxima.max():.1f} ms")
    print(f"IPOPT fallbacks: {fallbacks.sum()} in {np.count_nonzero(fallbacks)} experiments")
    print(f"reached target (1°, at rest) by 5 s: {100 * reached.mean():.1f} % "
          f"({reached.sum()}/{len(reached)} written; {100 * reached.sum() / n:.1f} % of requested)")
    print(f"settle time: median {np.median(settle):.2f} s, 95th pct {np.percentile(settle, 95):.2f} s, "
          f"max {settle.max():.2f} s")
    print(f"final angle error: max {err.max():.4f} deg")
    peak = np.degrees(np.abs(ds.stacked(["boom_rate", "dipper_rate"])).max(axis=1))
    torque = np.abs(ds.stacked(["boom_torque", "dipper_torque"])).max(axis=1)
    limits = ds.machine().torque_limits
    print(f"peak rates (deg/s): boom median {np.median(peak[:, 0]):.0f} max {peak[:, 0].max():.0f}, "
          f"dipper median {np.median(peak[:, 1]):.0f} max {peak[:, 1].max():.0f}")
    print(f"peak |torque| / limit: boom median {np.median(torque[:, 0]) / limits[0]:.2f} "
          f"max {torque[:, 0].max() / limits[0]:.2f}, dipper median {np.median(torque[:, 1]) / limits[1]:.2f} "
          f"max {torque[:, 1].max() / limits[1]:.2f}")
    print(f"process CPU time {cpu:.1f} s, total wall {time.perf_counter() - start:.1f} s")


if __name__ == "__main__":
    main()
