"""The calibrated kernel's joint consistency check (issue 31; docs/sensor-health.md): false
alarms on clean data, and pressure offset, gain and drift named or not.

    python benchmarks/bench_joint_check.py MODEL clean-a.parquet [clean-b.parquet ...] --draws 1 --seed 1

MODEL: a fitted, zeroed ``calibrated`` model of the machine sensor set (momentum form; the bench
turns its ``joint_check`` option on, a model saved before it was the default has it off) (bench_faults.py
makes one: ``--out DIR`` writes ``DIR/model-SEED``); ``--option KEY=VALUE`` sets another option (the
kernel is built again with them: ``--option imu_nuisance=on``, as the defaults weigh); the parquet
files: clean test data (their ``payload`` column the truth), one family each (the name is the
file's). Per file:

* false alarms: samples after each experiment's first second that are ``sensor_fault`` with a
  ``balance`` fault (and any ``sensor_fault``), and the samples ``ok``;
* per experiment and fault, ``--draws`` cases on a pressure drawn at random, onset uniform in
  1.5 s … end − 3 s, lasting to the end (a wrong zero or scale does not go away): offset
  ±2, 5, 10 bar; gain ±5 %, ±10 %; drift ±2 bar/s. Per case: named (its cylinder's pair named
  ``balance``, or the signal by any kind), time to name from the onset, another cylinder named,
  the worst |ok − payload| from the onset on with the check on, with it off (``health`` off:
  what the weighing said before), and on the clean run over the same samples; the worst
  |estimate − payload| of the degraded ``sensor_fault`` estimates (weighed without the joint).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.io import read_dataset
from excavator_payload.estimators.base import load_estimator

BAR = 1e5
PRESSURES = ["boom_head_pressure", "boom_rod_pressure", "dipper_head_pressure",
             "dipper_rod_pressure", "bucket_head_pressure", "bucket_rod_pressure"]
FAULTS = {"offset 2 bar": ("offset", 2 * BAR), "offset 5 bar": ("offset", 5 * BAR),
          "offset 10 bar": ("offset", 10 * BAR), "gain 5 %": ("gain", 0.05), "gain 10 %": ("gain", 0.10),
          "drift 2 bar/s": ("drift", 2 * BAR)}


def run(est, frame: pd.DataFrame, meta, health: bool = True) -> pd.DataFrame:
    est.health = health
    try:
        return est.estimate(Dataset(frame, meta))
    finally:
        est.health = True


def worst(out: pd.DataFrame, truth: np.ndarray, a: int, status: str = "ok") -> float:
    st = out["status"].astype(str).to_numpy()
    e = out["payload_estimate"].to_numpy(float)
    use = (st == status) & np.isfinite(e)
    use[:a] = False
    return float(np.max(np.abs(e[use] - truth[use]))) if use.any() else np.nan


def false_alarms(est, ds: Dataset) -> dict:
    out = run(est, ds.frame, ds.meta)
    f = ds.frame
    t = f["time"].to_numpy(float)
    first = pd.Series(t).groupby(f["experiment"].to_numpy()).transform("min").to_numpy()
    late = t - first >= 1.0
    st = out["status"].astype(str).to_numpy()
    balance = out["fault"].astype(str).str.contains(":balance", regex=False).to_numpy()
    return {"samples": int(late.sum()), "balance": int((late & balance).sum()),
            "sensor_fault": int((late & (st == "sensor_fault")).sum()), "ok": int((late & (st == "ok")).sum())}


def cases(est, family: str, ds: Dataset, draws: int, rng, off: bool) -> list[dict]:
    rows = []
    for e in ds.frame["experiment"].unique():
        one = ds.frame[ds.frame["experiment"] == e].reset_index(drop=True)
        t = one["time"].to_numpy(float)
        truth = one["payload"].to_numpy(float)
        n = len(one)
        if n < 500:
            continue
        clean = run(est, one, ds.meta)
        for name, (kind, size) in FAULTS.items():
            for _ in range(draws):
                signal = PRESSURES[rng.integers(len(PRESSURES))]
                a = int(rng.integers(150, n - 300))
                sign = rng.choice([-1.0, 1.0])
                bad = one.copy()
                v = one[signal].to_numpy(float).copy()
                if kind == "offset":
                    v[a:] += sign * size
                elif kind == "gain":
                    v[a:] *= 1 + sign * size
                else:
                    v[a:] += sign * size * (t[a:] - t[a])
                bad[signal] = v
                on = run(est, bad, ds.meta)
                faults = on["fault"].astype(str).to_numpy()
                cylinder = signal.split("_")[0]
                named = np.array([f"{signal}:" in f for f in faults])
                other = np.array([any(item.split("_")[0] != cylinder for item in f.split(",") if
                                      item.endswith(":balance")) for f in faults])
                named[:a] = other[:a] = False
                hit = np.flatnonzero(named)
                rows.append({
                    "family": family, "experiment": e, "onset": a, "fault": name, "signal": signal, "sign": sign,
                    "flag_s": (t[hit[0]] - t[a]) if len(hit) else np.nan,
                    "other_named": bool(other.any()),
                    "worst_ok_on": worst(on, truth, a),
                    "worst_ok_off": worst(run(est, bad, ds.meta, False), truth, a) if off else np.nan,
                    "worst_ok_clean": worst(clean, truth, a),
                    "worst_degraded": worst(on, truth, a, "sensor_fault"),
                })
    return rows


def table(rows: pd.DataFrame) -> str:
    fmt = lambda x: "–" if not np.isfinite(x) else f"{x:.0f}"  # noqa: E731
    lines = ["| fault | cases | named | time to name s (median, max) | other cylinder named | "
             "worst ok error kg: on | off (before) | clean | degraded estimate error kg |",
             "|---|---|---|---|---|---|---|---|---|"]
    for name, g in rows.groupby("fault", sort=False):
        flagged = g["flag_s"].notna()
        ts = g.loc[flagged, "flag_s"]
        tt = f"{ts.median():.2f}, {ts.max():.2f}" if len(ts) else "–"
        lines.append(f"| {name} | {len(g)} | {flagged.sum()} | {tt} | {int(g['other_named'].sum())} | "
                     f"{fmt(g['worst_ok_on'].max())} | {fmt(g['worst_ok_off'].max())} | "
                     f"{fmt(g['worst_ok_clean'].max())} | {fmt(g['worst_degraded'].max())} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model")
    ap.add_argument("data", nargs="+")
    ap.add_argument("--draws", type=int, default=1, help="cases per experiment and fault")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--no-faults", action="store_true", help="false alarms only")
    ap.add_argument("--off", action="store_true",
                    help="also run each case with the health monitor and the check off")
    ap.add_argument("--out", type=Path, default=None, help="CSV of the cases")
    ap.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                    help="an option of the estimator (repeatable), e.g. imu_nuisance=on")
    a = ap.parse_args()
    est = load_estimator(a.model)
    est.options["joint_check"] = "on"  # the estimator's option
    est.options.update(dict(o.split("=", 1) for o in a.option))
    est.use_calibration()  # the kernel built again with these options
    rng = np.random.default_rng(a.seed)
    rows = []
    for path in a.data:
        ds = read_dataset(path)
        family = Path(path).stem
        fa = false_alarms(est, ds)
        print(f"{family}: {fa['balance']} balance / {fa['sensor_fault']} sensor_fault of {fa['samples']} "
              f"samples after 1 s ({fa['ok']} ok)", flush=True)
        if not a.no_faults:
            rows += cases(est, family, ds, a.draws, rng, a.off)
    if rows:
        frame = pd.DataFrame(rows)
        if a.out:
            frame.to_csv(a.out, index=False)
        print(table(frame))


if __name__ == "__main__":
    main()
