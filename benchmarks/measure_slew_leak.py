"""Level ground: could the house IMU's centripetal leak be the slew rate's partner? (issue 31;
docs/sensor-health.md, "The slew rate's scale error on a slope"). A measurement, not a rule of the monitor.

The simulator's house IMU sits ``house_imu_radius`` off the slew axis and leaks a share of its
centripetal acceleration r·ψ̇² into the pitch it reports (``simulation/machine_sensors.py``). Over
each 2 s window (every 5 samples) with the measured ψ̇²'s spread at least 0.05 (rad/s)², the
least-squares slope K of pitch against ψ̇² (both centred); K of the calibration swings
(``bench_false_alarms``' study calibration) is the reference. A slew rate scaled by g moves K to
K/g². Per family of the cached clean chunks (``--seed``): K's spread on clean windows and the share
of windows whose K/K_ref leaves the clean 0.5…99.5 % range for each gain.

    PYTHONPATH=src python benchmarks/measure_slew_leak.py --seed 93100
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_false_alarms as bfa  # noqa: E402

from excavator_payload.data.io import read_dataset  # noqa: E402
from excavator_payload.evaluation import demo_machine as dm  # noqa: E402

WINDOW, EVERY, MIN_SPREAD = 201, 5, 0.05


def window_k(frame, gain: float = 1.0) -> np.ndarray:
    """K of every judged window of every experiment of ``frame`` (slew rate × ``gain``)."""
    out = []
    for _, g in frame.groupby("experiment"):
        p = g["house_pitch"].to_numpy(float)
        u = (g["slew_rate"].to_numpy(float) * gain) ** 2
        for end in range(WINDOW, len(p) + 1, EVERY):
            uu = u[end - WINDOW:end] - u[end - WINDOW:end].mean()
            if uu.std() < MIN_SPREAD:
                continue
            pp = p[end - WINDOW:end] - p[end - WINDOW:end].mean()
            out.append(float(uu @ pp) / float(uu @ uu))
    return np.array(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, required=True, help="the bench_false_alarms chunks' seed")
    ap.add_argument("--families", default="nmpc,work-cycle,operator,lever,joystick")
    ap.add_argument("--gains", default="0.8,0.85,0.9,1.1,1.15,1.2")
    ap.add_argument("--cache", type=Path, default=Path("/work/scratch/alarms"))
    a = ap.parse_args()
    ref = float(np.median(window_k(dm.calibration_data(10, 9200).frame)))
    print(f"K of the calibration swings (median of windows): {ref:.5f} rad/(rad/s)^2")
    gains = [float(g) for g in a.gains.split(",")]
    print("| family | windows | K/K_ref median | clean 0.5-99.5 % | " + " | ".join(f"x{g:g} out" for g in gains) + " |")
    print("|---|---|---|---|" + "---|" * len(gains))
    for family in a.families.split(","):
        path = next(bfa.chunks(family, 1, a.cache, generate=True, seed=a.seed))[1]
        frame = read_dataset(path, validate=False).frame
        clean = window_k(frame) / ref
        lo, hi = np.quantile(clean, [0.005, 0.995])
        shares = []
        for g in gains:
            r = window_k(frame, g) / ref
            shares.append(f"{np.mean((r < lo) | (r > hi)):.0%}")
        print(f"| {family} | {len(clean)} | {np.median(clean):.3f} | {lo:.3f}–{hi:.3f} | " + " | ".join(shares) + " |")


if __name__ == "__main__":
    main()
