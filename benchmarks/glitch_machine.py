"""One-frame glitches on the machine sensor set: what the outlier test rejects and what it saves.

Calibrates ``calibrated`` (or ``--estimator``) as ``demo --machine`` does (10 calibration motions from the 3 % file,
zero check), simulates ``--test`` NMPC swings, swings and work cycles of session 2, then puts one
glitch into every experiment (sample 300, t = 3 s) of each kind below and compares the final
estimate with the clean run, with the test on and off (``Estimator.gating``). Also counts the
rejections on the clean data (false alarms).

Usage::

    python benchmarks/glitch_machine.py [--test 200] [--seed 11] [--estimator inverse-dynamics]
"""

from __future__ import annotations

import argparse

import numpy as np

from excavator_payload.data.dataset import Dataset
from excavator_payload.evaluation import demo_machine as dm
from excavator_payload.simulation.generate import simulate_dataset

#: (signal, size in SI units): 10× and 100× the field preset's white noise of a pressure
#: transmitter, a large rate spike, an angle spike.
GLITCHES = (("boom_head_pressure", 3e5), ("boom_head_pressure", 3e6), ("dipper_rod_pressure", 3e6),
            ("boom_rate", 0.2), ("boom_angle", 0.05), ("bucket_angle", 0.5))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--test", type=int, default=200)
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--estimator", default="calibrated", choices=["calibrated", "inverse-dynamics"],
                    help="fitted as demo --machine fits it (the 3 %% file)")
    a = ap.parse_args()
    cal, zero = dm.calibration_data(10, a.seed), dm.zero_data(a.seed + 1)
    est = dm.fit_estimators(cal, zero, [a.estimator])["fitted"][a.estimator]
    common = dict(machine="cat345c-hydraulic", session=dm.SESSION_WORK, with_truth=False, workers=1,
                  progress=False)
    sets = {"nmpc": simulate_dataset(a.test, seed=a.seed + 2, motion="nmpc", **common),
            "swing": simulate_dataset(a.test, seed=a.seed + 3, motion="swing", **common),
            "work-cycle": dm.before_release(simulate_dataset(a.test, seed=a.seed + 4, motion="work-cycle",
                                                             **common))}
    print("| test motions | clean samples | false rejections | glitch | detected | final change with "
          "the test, mean / max kg | without |")
    print("|---|---|---|---|---|---|---|")
    for name, ds in sets.items():
        clean = est.estimate(ds)
        false = int((clean["status"].astype(str) == "rejected_outlier").sum())
        last = ds.frame.groupby("experiment").tail(1).index
        for signal, size in GLITCHES:
            frame = ds.frame.copy()
            hit = frame.index[frame.groupby("experiment").cumcount() == 300]
            frame.loc[hit, signal] += size
            data = Dataset(frame, ds.meta)
            changes = []
            for gating in (True, False):
                est.gating = gating
                out = est.estimate(data)
                if gating:
                    detected = int((out["status"].astype(str).to_numpy()[hit + 1] == "rejected_outlier").sum())
                changes.append(np.abs(out["payload_estimate"].to_numpy()[last]
                                      - clean["payload_estimate"].to_numpy()[last]))
            est.gating = True
            print(f"| {name} | {len(ds.frame)} | {false} | {signal} + {size:g} | {detected}/{len(hit)} | "
                  f"{np.nanmean(changes[0]):.2f} / {np.nanmax(changes[0]):.2f} | "
                  f"{np.nanmean(changes[1]):.2f} / {np.nanmax(changes[1]):.2f} |", flush=True)


if __name__ == "__main__":
    main()
