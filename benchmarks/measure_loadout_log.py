"""Compare two loadout records pass by pass: a shift weighed from its dataset and from a CAN log.

Usage (after `loadout --data … --db data.sqlite` and `loadout --log … --truth … --db log.sqlite`,
docs/loadout.md, "From a CAN log"):

    python benchmarks/measure_loadout_log.py data.sqlite log.sqlite [RATED_KG]

Prints the pass counts, the largest and mean difference of pass weights and truck totals, and
each record's errors against the truth (passes within 1 % of rated, trucks within 0.5 %).
"""

from __future__ import annotations

import sys

import numpy as np

from excavator_payload.runtime.loadout import read_record, shift_summary


def main(data_db: str, log_db: str, rated: float | None = None) -> None:
    dp, dt = read_record(data_db)
    lp, lt = read_record(log_db)
    rated = rated or dp.attrs.get("rated")
    pairs = dp.merge(lp, on=["truck", "pass"], how="outer", suffixes=("_data", "_log"), indicator=True)
    only = pairs[pairs["_merge"] != "both"]
    both = pairs[pairs["_merge"] == "both"]
    dw = (both["weight_log"] - both["weight_data"]).abs().to_numpy(float)
    trucks = dt.merge(lt, on="truck", suffixes=("_data", "_log"))
    dtot = (trucks["total_log"] - trucks["total_data"]).abs().to_numpy(float)
    print(f"trucks data / log: {len(dt)} / {len(lt)}; passes data / log: {len(dp)} / {len(lp)}; "
          f"passes in one record only: {len(only)}")
    print(f"status equal: {int((both['status_data'] == both['status_log']).sum())} of {len(both)}")
    print(f"pass weight |log - data| kg: max {np.nanmax(dw):.2f}, mean {np.nanmean(dw):.3f}, "
          f"median {np.nanmedian(dw):.3f}")
    print(f"truck total |log - data| kg: max {np.nanmax(dtot):.2f}, mean {np.nanmean(dtot):.3f}")
    for name, (p, t) in (("data", (dp, dt)), ("log", (lp, lt))):
        print(name, shift_summary(p, t, rated))
    print("| truck | pass | data kg | log kg | diff kg | true kg |")
    print("|---:|---:|---:|---:|---:|---:|")
    for r in both.rename(columns={"pass": "n"}).itertuples():
        print(f"| {r.truck} | {r.n} | {r.weight_data:,.1f} | {r.weight_log:,.1f} | "
              f"{r.weight_log - r.weight_data:+.2f} | {r.true_weight_log:,.1f} |")
    print("| truck | data total kg | log total kg | diff kg | true kg |")
    print("|---:|---:|---:|---:|---:|")
    for r in trucks.itertuples():
        print(f"| {r.truck} | {r.total_data:,.1f} | {r.total_log:,.1f} | {r.total_log - r.total_data:+.2f} | "
              f"{r.true_total_log:,.1f} |")


if __name__ == "__main__":
    if len(sys.argv) < 3:
        sys.exit(__doc__)  # the usage: too few arguments
    main(sys.argv[1], sys.argv[2], float(sys.argv[3]) if len(sys.argv) > 3 else None)
