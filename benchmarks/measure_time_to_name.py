"""Where the sensor health monitor's time to name goes, per detector (docs/sensor-health.md,
section "Time to name").

    python benchmarks/measure_time_to_name.py --dir faults --seed 9300 --n 3

Replays the monitor alone (``HealthMonitor.step``, no estimator: seconds, not minutes) over the
cases of ``bench_faults.py`` (the same clean files under ``--dir``, the same draws: every kind
and group of the full run), and per case records the first time each kind names the faulty
signal after the onset, and, for the cases that are never named within 0.5 s, why: the joint
(or, for the unpartnered signals, any arm joint) at rest for the stuck rule, or the statistic
of the slow rules (offset error, gain slope) below its limit. ``--clean`` instead counts the
samples after each experiment's first second the monitor names or holds as suspect on the
clean data (the monitor's own false alarms).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_faults import GROUPS, KINDS, inject  # noqa: E402

from excavator_payload.data.io import read_dataset  # noqa: E402
from excavator_payload.estimators.base import load_estimator  # noqa: E402
from excavator_payload.estimators.health import for_sensor_set  # noqa: E402


def replay(monitor, times: np.ndarray, values: np.ndarray, low: np.ndarray, high: np.ndarray):
    """The monitor's fault string and suspect string per sample ("" where skipped or healthy)."""
    monitor.reset()
    faults, suspects = [""] * len(times), [""] * len(times)
    suspect = getattr(monitor, "suspect", lambda: "")  # the monitor before the suspect state: none
    for k, (t, x) in enumerate(zip(times, values)):
        if not (np.all(x >= low) and np.all(x <= high)):
            continue  # the estimator skips these (out_of_range) before the monitor
        faults[k] = monitor.step(float(t), x)
        suspects[k] = suspect()
    return faults, suspects


def first_times(faults, suspects, signal: str, a: int, t: np.ndarray) -> dict:
    """Per kind: the first time after sample a the signal is named with it (s after the onset);
    and the first time it is named or suspect."""
    out: dict = {}
    for k in range(a, len(faults)):
        for item in filter(None, faults[k].split(",")):
            s, _, kind = item.partition(":")
            if s == signal and kind not in out:
                out[kind] = t[k] - t[a]
        if "any" not in out and (f"{signal}:" in faults[k] or f"{signal}:" in suspects[k]):
            out["any"] = t[k] - t[a]
    return out


def fault_cases(est, files: list[Path], seed: int) -> pd.DataFrame:
    monitor = for_sensor_set(est.sensor_set, est.health_reference)
    signals = list(est.sensor_set.signals)
    low, high = est.plausible_low, est.plausible_high
    rng = np.random.default_rng(seed)
    rows = []
    for path in files:
        frame = read_dataset(path).frame
        for e in frame["experiment"].unique():
            one = frame[frame["experiment"] == e].reset_index(drop=True)
            t = one["time"].to_numpy(float)
            n = len(one)
            if n < 500:
                continue
            for kind in KINDS:
                for group, names in GROUPS.items():
                    signal = names[rng.integers(len(names))]
                    a = int(rng.integers(150, n - 200))
                    b = min(n, a + int(rng.integers(50, 301)))
                    bad = one.copy()
                    bad[signal] = inject(one[signal].to_numpy(float), t, kind, group, a, b, rng)
                    faults, suspects = replay(monitor, t, bad[signals].to_numpy(float), low, high)
                    first = first_times(faults, suspects, signal, a, t)
                    named = [v for k, v in first.items() if k != "any"]
                    rows.append({"file": path.name, "experiment": e, "kind": kind, "group": group,
                                 "signal": signal, "length_s": (b - a) * 0.01,
                                 "flag_s": min(named) if named else np.nan,
                                 "first_kind": min((v, k) for k, v in first.items() if k != "any")[1]
                                 if named else "",
                                 "suspect_or_named_s": first.get("any", np.nan),
                                 **{f"t_{k}": v for k, v in first.items() if k != "any"}})
    return pd.DataFrame(rows)


def summary(rows: pd.DataFrame) -> str:
    lines = ["| fault | group | cases | named (monitor) | ≤ 0.5 s | median s | p90 s | first kind | "
             "suspect or named ≤ 0.5 s |", "|---|---|---|---|---|---|---|---|---|"]
    for (kind, group), g in rows.groupby(["kind", "group"], sort=False):
        f = g["flag_s"].dropna()
        s = g["suspect_or_named_s"]
        kinds = g.loc[g["first_kind"] != "", "first_kind"].value_counts().to_dict()
        med = f"{f.median():.2f}" if len(f) else "–"
        p90 = f"{f.quantile(0.9):.2f}" if len(f) else "–"
        lines.append(f"| {kind} | {group} | {len(g)} | {len(f)} | {(f <= 0.5).sum()} | {med} | {p90} | "
                     f"{', '.join(f'{k} {v}' for k, v in kinds.items()) or '–'} | {(s <= 0.5).sum()} |")
    return "\n".join(lines)


def clean_counts(est, files: list[Path]) -> pd.DataFrame:
    monitor = for_sensor_set(est.sensor_set, est.health_reference)
    signals = list(est.sensor_set.signals)
    rows = []
    for path in files:
        frame = read_dataset(path).frame
        for e in frame["experiment"].unique():
            one = frame[frame["experiment"] == e]
            t = one["time"].to_numpy(float)
            faults, suspects = replay(monitor, t, one[signals].to_numpy(float), est.plausible_low,
                                      est.plausible_high)
            late = t - t[0] >= 1.0
            named = np.array([bool(f) for f in faults]) & late
            sus = np.array([bool(s) for s in suspects]) & late & ~named
            rows.append({"file": path.name, "experiment": e, "late": int(late.sum()),
                         "named": int(named.sum()), "suspect": int(sus.sum()),
                         "names": ";".join(sorted({f for f in np.array(faults)[named]})),
                         "suspects": ";".join(sorted({s for s in np.array(suspects)[sus]}))[:200]})
    return pd.DataFrame(rows)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dir", type=Path, required=True, help="bench_faults.py's --out (its model and clean files)")
    ap.add_argument("--seed", type=int, default=9300)
    ap.add_argument("--n", type=int, default=3)
    ap.add_argument("--model", type=Path, help="the model (default: DIR/model-calibrated-SEED)")
    ap.add_argument("--clean", nargs="*", type=Path, help="count the monitor's names on these clean files")
    ap.add_argument("--csv", type=Path, help="write the per-case rows here")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="try another value of a constant of estimators/health.py (tuning only)")
    a = ap.parse_args()
    from excavator_payload.estimators import health

    for item in a.set:
        name, _, value = item.partition("=")
        if not hasattr(health, name):
            raise SystemExit(f"error: estimators/health.py has no constant {name}")
        setattr(health, name, float(value))
    est = load_estimator(a.model or a.dir / f"model-calibrated-{a.seed}")
    from excavator_payload.estimators.checks import plausibility_limits

    est.plausible_low, est.plausible_high = plausibility_limits(est.sensor_set, est.machine)
    if a.clean is not None:
        rows = clean_counts(est, a.clean)
        print(rows.to_string())
        print(f"named {rows['named'].sum()} / suspect {rows['suspect'].sum()} of {rows['late'].sum()} samples "
              f"after 1 s")
        return
    files = [a.dir / f"clean-{f}-{a.n}-{a.seed}.parquet" for f in ("operator", "work-cycle", "nmpc", "lever")]
    rows = fault_cases(est, files, a.seed)
    if a.csv:
        rows.to_csv(a.csv, index=False)
    print(summary(rows))


if __name__ == "__main__":
    main()
