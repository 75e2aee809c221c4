"""``calibrated --imu-nuisance on`` against off, on the nuisance oracle's cells
(``nuisance_oracle_prep.py``: the same calibrated and zeroed machines).

Tuning families (``--families nmpc work-cycle operator``, seeds ``families(n, 9100)``'s) first;
the held-out ones (``lever``, ``lever-slope5``, ``joystick``) once, on fresh seeds (``--seed``).
Per cell and family: share of experiments within 1 % of rated (MAX ≤ 50 kg), mean MAX, mean
final |error|, σ coverage (|e| ≤ 2σ share), false alarms (share of clean samples after the
first second not ``ok``), judged on ``ok`` samples after the first second.

    PYTHONPATH=src nice -n 5 python benchmarks/bench_imu_nuisance.py --cache /tmp/imunuis_cache \
        --families nmpc work-cycle operator --n 8
    PYTHONPATH=src nice -n 5 python benchmarks/bench_imu_nuisance.py --cache /tmp/imunuis_cache \
        --families lever lever-slope5 joystick --n 8 --seed 9700
"""

from __future__ import annotations

import argparse
import copy
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_any_motion import MACHINE  # noqa: E402
from held_out_motions import joystick_trajectory, lever_trajectory  # noqa: E402
from nuisance_oracle_prep import CELLS, cached, estimator  # noqa: E402

from excavator_payload.evaluation import demo_machine as dm  # noqa: E402
from excavator_payload.simulation.generate import simulate_dataset  # noqa: E402


def family(name: str, n: int, seed: int):
    """The test family ``name`` (``bench_any_motion.families``' seeds offsets; joystick +5)."""
    common = dict(machine=MACHINE, session=dm.SESSION_WORK, with_truth=True, workers=1, progress=False)
    if name == "nmpc":
        return simulate_dataset(n, seed=seed, motion="nmpc", **common)
    if name == "work-cycle":
        return dm.before_release(simulate_dataset(n, seed=seed + 1, motion="work-cycle", **common))
    if name == "operator":
        return simulate_dataset(n, seed=seed + 2, motion="operator", **common)
    if name == "lever":
        return dm.simulate_trajectory(lever_trajectory(n, seed + 3), seed + 3, dm.SESSION_WORK)
    if name == "lever-slope5":
        return dm.simulate_trajectory(lever_trajectory(n, seed + 4, slope_deg=5.0), seed + 4, dm.SESSION_WORK)
    if name == "joystick":
        return dm.simulate_trajectory(joystick_trajectory(n, seed + 5), seed + 5, dm.SESSION_WORK)
    raise ValueError(name)


def judge(frame: pd.DataFrame, ds) -> dict:
    """The cell's figures from ``estimate``'s frame on ``ds``."""
    f = ds.frame
    maxes, finals, cover, alarms = [], [], [], []
    for e in f["experiment"].unique():
        sel = (f["experiment"] == e).to_numpy()
        t = f.loc[sel, "time"].to_numpy(float)
        truth = float(f.loc[sel, "payload"].iloc[0])
        fe = frame[sel]
        est = fe["payload_estimate"].to_numpy(float)
        sig = fe["sigma"].to_numpy(float)
        status = fe["status"].astype(str).to_numpy()
        late = t - t[0] >= 1.0
        judged = late & (status == "ok") & np.isfinite(est)
        alarms.append(np.mean(~np.isin(status[late], ("ok", "warming_up", "load_changing"))))
        if not judged.any():
            maxes.append(np.inf)
            finals.append(np.inf)
            continue
        err = est[judged] - truth
        maxes.append(float(np.max(np.abs(err))))
        finals.append(float(abs(err[-1])))
        cover.append(np.abs(err) <= 2 * sig[judged])
    maxes = np.array(maxes)
    return {"within_1pct": float(np.mean(maxes <= 50.0)), "mean_max": float(np.mean(maxes)),
            "mean_final": float(np.mean(finals)),
            "cover_2sigma": float(np.mean(np.concatenate(cover))) if cover else np.nan,
            "alarms": float(np.mean(alarms))}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cache", type=Path, default=Path("/tmp/imunuis_cache"))
    ap.add_argument("--n", type=int, default=8)
    ap.add_argument("--seed", type=int, default=9100)
    ap.add_argument("--cells", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--families", nargs="+", default=["nmpc", "work-cycle", "operator"])
    ap.add_argument("--out", type=Path, default=None, help="CSV of the table")
    ap.add_argument("--all-five", action="store_true",
                    help="re-estimate all five IMU dynamics (lag and four sensitivities), not the default two")
    ap.add_argument("--data-only", action="store_true", help="only simulate the families into the cache")
    a = ap.parse_args()
    a.cache.mkdir(parents=True, exist_ok=True)
    data = {fam: cached(a.cache, f"fam_{fam}_{a.n}_{a.seed}", lambda fam=fam: family(fam, a.n, a.seed))
            for fam in a.families}
    if a.data_only:
        return
    rows = []
    for c in a.cells:
        base = estimator(a.cache, *CELLS[c])
        for mode in ("on",) if a.all_five else ("off", "on"):
            est = copy.deepcopy(base)
            est.options["imu_nuisance"] = mode
            est.use_calibration()
            if mode == "on" and a.all_five:
                from excavator_payload.estimators.classical.machine_calibration.imu_nuisance import (
                    ImuNuisanceFilter)
                from excavator_payload.estimators.classical.machine_calibration.settings import IMU_PARAMETERS

                kernel = est.kernel.regression
                kernel._imu_nuisance = ImuNuisanceFilter(est.calibration, kernel._balance_len, IMU_PARAMETERS)
            for fam, ds in data.items():
                t0 = time.process_time()
                frame = est.estimate(ds)
                spent = time.process_time() - t0
                row = {"calibration": CELLS[c][0], "zero": CELLS[c][1], "family": fam, "imu_nuisance": mode,
                       **judge(frame, ds), "us_per_sample": 1e6 * spent / len(ds.frame)}
                rows.append(row)
                print(" · ".join(f"{k} {v:.3g}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()),
                      flush=True)
    table = pd.DataFrame(rows)
    if a.out:
        table.to_csv(a.out, index=False)
    print(table.to_string(float_format=lambda v: f"{v:.3g}"))


if __name__ == "__main__":
    main()
