"""Benchmark of the hydraulic machine's simulator: CPU and wall time per experiment on one core,
per motion, and the data's own figures (duration, peak pressure, use of the pumps' speed).

Usage: python benchmarks/bench_hydraulic.py [N_EXPERIMENTS_PER_MOTION=50] [SEED=0]
       python benchmarks/bench_hydraulic.py --plausibility [N_PER_SESSION=25] [SESSIONS=8]

``--plausibility`` counts false rejections of the plausibility limits
(:func:`~excavator_payload.estimators.base.plausibility_limits` of the machine file) on field-noise
data of every motion family: ``SESSIONS`` working sessions (their own sensor offsets) of
``N_PER_SESSION`` experiments each, and the largest share of the angle margin used beyond the
machine's angle ranges (0: every angle inside its range), of each joint rate's limit, and the
range of the measured pressures against their limits.
"""

import json
import sys
import time

import numpy as np

from excavator_payload.simulation.machine_sim import simulate_machine_dataset


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 50
    seed = int(sys.argv[2]) if len(sys.argv) > 2 else 0
    build = time.perf_counter()
    simulate_machine_dataset(1, seed=seed + 1000, motion="lifts")  # model build + C compile/load
    simulate_machine_dataset(1, seed=seed + 1000, motion="nmpc")  # controller build
    print(f"model and NMPC build (once per worker; compiled libraries cached on disk): "
          f"{time.perf_counter() - build:.2f} s")
    for motion in ("nmpc", "swing", "work-cycle", "slopes", "lifts"):
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
        if motion == "nmpc":
            reached = np.mean([m["reached"] for m in metas])
            solve = np.array([m["solve_time_median_ms"] for m in metas])
            print(f"{'':10s}  reached target (1°, at rest) by 10 s: {100 * reached:.1f} %; NMPC solve "
                  f"median {np.median(solve):.1f} ms; speed share > 1 in {int((share > 1).sum())} "
                  f"of {len(share)} (max {share.max():.2f}); retries {sum(m['n_retries'] for m in metas)}")


def plausibility(per_session: int = 25, sessions: int = 8) -> None:
    from excavator_payload.data.schema import MACHINE_SENSORS
    from excavator_payload.estimators.base import plausibility_limits
    from excavator_payload.model.machine import load_machine

    machine = load_machine("cat345c-hydraulic")
    low, high = plausibility_limits(MACHINE_SENSORS, machine)
    signals = list(MACHINE_SENSORS.signals)
    for motion in ("swing", "work-cycle", "slopes", "lifts", "nmpc"):
        cpu = time.process_time()
        n = rows = rejected = 0
        used = np.zeros(3)
        rates = [MACHINE_SENSORS.index(r) for r in ("boom_rate", "dipper_rate", "bucket_rate", "slew_rate")]
        rate_used = np.zeros(4)
        pressures = [i for i, s in enumerate(signals) if s.endswith("_pressure")]
        p_range = [np.inf, -np.inf]
        for session in range(sessions):
            ds = simulate_machine_dataset(per_session, seed=5000 + 100 * session, session=100 + session,
                                          motion=motion, workers=1)
            v = ds.frame[signals].to_numpy(float)
            rejected += int(((v < low) | (v > high)).any(axis=1).sum())
            rows, n = rows + len(v), n + ds.n_experiments
            rate_used = np.maximum(rate_used, np.abs(v[:, rates]).max(axis=0) / high[rates])
            p_range = [min(p_range[0], v[:, pressures].min()), max(p_range[1], v[:, pressures].max())]
            for j in range(3):
                lo, hi = machine.angle_ranges[j]
                margin = high[j] - hi
                used[j] = max(used[j], (lo - v[:, j].min()) / margin, (v[:, j].max() - hi) / margin)
        print(json.dumps({"motion": motion, "experiments": n, "samples": rows, "rejected_samples": rejected,
                          "angle_margin_share_used": [round(float(x), 3) for x in used],
                          "rate_limit_share_used": [round(float(x), 3) for x in rate_used],
                          "pressure_range_bar": [round(float(x) / 1e5, 1) for x in p_range],
                          "pressure_limits_bar": [round(float(low[pressures[0]]) / 1e5, 1),
                                                  round(float(high[pressures[0]]) / 1e5, 1)],
                          "cpu_s": round(time.process_time() - cpu, 1)}), flush=True)


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--plausibility":
        plausibility(*(int(a) for a in sys.argv[2:4]))
    else:
        main()
