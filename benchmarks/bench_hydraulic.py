"""Benchmark of the hydraulic machine's simulator: CPU and wall time per experiment on one core,
per motion, and the data's own figures (duration, peak pressure, use of the pumps' speed).

Usage: python benchmarks/bench_hydraulic.py [N_EXPERIMENTS_PER_MOTION=50] [SEED=0]
"""

import sys
import time

import numpy as np

from excavator_payload.simulation.machine_sim import simulate_machine_dataset


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 50
    seed = int(sys.argv[2]) if len(sys.argv) > 2 else 0
    build = time.perf_counter()
    simulate_machine_dataset(1, seed=seed + 1000, motion="lifts")  # model build + C compile/load
    print(f"model build (once per worker, compiled library cached on disk): {time.perf_counter() - build:.2f} s")
    for motion in ("swing", "work-cycle", "slopes", "lifts"):
        wall, cpu = time.perf_counter(), time.process_time()
        ds = simulate_machine_dataset(n, seed=seed, motion=motion, workers=1)
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        metas = ds.meta["experiments"]
        durations = np.array([m["duration"] for m in metas])
        peaks = np.array([m["peak_pressure"] for m in metas]) / 1e5
        share = np.array([m["speed_share"] for m in metas])
        draws = np.array([m["draws"] for m in metas])
        print(f"{motion:10s}: {cpu / n:.3f} s CPU / experiment ({wall / n:.3f} s wall), "
              f"{len(ds.frame) / n:.0f} samples (100 Hz) each; duration median {np.median(durations):.1f} s "
              f"[{durations.min():.1f}, {durations.max():.1f}]; peak pressure median {np.median(peaks):.0f} bar, "
              f"max {peaks.max():.0f} bar; pump speed share max {share.max():.2f}; "
              f"redrawn over relief: {int((draws > 1).sum())}; skipped {len(ds.meta['skipped'])}")


if __name__ == "__main__":
    main()
