"""Where the not-``ok`` samples of the multi-load families sit, per load (issue 28).

For each cached chunk of ``bench_false_alarms.py`` (``--cache``, ``--family``, ``--seed``) the
user's default flow (the benchmark's cached ``study`` estimator) is run with the kernel's state
recorded per sample. Each experiment is cut into loads at the truth's changes (the ``payload``
column: a fill's end, where the bucket holds 99 % of its load, or a release's end, the bucket
empty), and per load it reports the time from that change to the first ``ok``, the share of the
wait that is ``load_changing`` / ``warming_up`` / other, which rule holds the ``warming_up`` (the
boom's windows, a steady estimate, a second joint), and the boom windows weighed in the wait
(``low_speed skip``: a boom window is weighed only while the boom moves).

Usage::

    PYTHONPATH=src python benchmarks/wait_after_load.py --cache /work/scratch/alarms --family shift \\
        --chunks 0,1 --out loads.csv
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_false_alarms as bfa  # noqa: E402

from excavator_payload.data.io import read_dataset  # noqa: E402
from excavator_payload.estimators.classical.pressure_regression import PressureKernel  # noqa: E402

#: The kernel's state after each step (``_recording_step``).
RECORD: list[tuple] = []


def _recording_step(original):
    def step(self, time, values, judge=True, joint_check=False):
        result = original(self, time, values, judge, joint_check)
        r = self.regression
        jc = r.joint_check
        RECORD.append((time, r.boom_windows, bool(r.ready), bool(r.steady), self.info >= self.warm_info,
                       bool(r.changing), bool(jc and r.joint_checked), bool(jc and r.joint_pausing),
                       bool(jc and r.joint_suspect), bool(getattr(self, "_lone_moved", False)), r.new_loads,
                       r.settles, float(r.estimate) if r.info > 0 else np.nan))
        return result
    return step


COLUMNS = ("time", "boom_windows", "ready", "steady", "warm", "changing", "checked", "pausing", "suspect",
           "lone_moved", "new_loads", "settles", "kernel_estimate")


def loads_of(meta: dict, end: float) -> list[tuple[float, float, float]]:
    """(start s, end s, load kg) of each constant-truth stretch of one experiment, from its
    meta: a shift's passes (a fill's end to its release's start; the release's end to the next
    fill, empty), a work cycle's load to its release and the empty bucket after it.

    Parameters
    ----------
    meta : dict
        The experiment's metadata (``passes``, or ``release`` and ``payload``).
    end : float
        The experiment's last time from its start, s.
    """
    if "passes" in meta:
        out = []
        passes = meta["passes"]
        for k, p in enumerate(passes):
            out.append((p["fill"][1], p["release"][0], float(p["payload"])))
            after = passes[k + 1]["fill"][0] if k + 1 < len(passes) else end
            out.append((p["release"][1], after, 0.0))
        return out
    if "release" in meta:
        return [(0.0, meta["release"][0], float(meta["payload"])), (meta["release"][1], end, 0.0)]
    return [(0.0, end, float(meta["payload"]))]


def study_chunk(est, path: Path, family: str, chunk: int) -> pd.DataFrame:
    """One row per stretch of one load (and one per experiment for the truth's changes) of a
    cached chunk.

    Parameters
    ----------
    est : Estimator
        The fitted, zeroed ``calibrated`` estimator (its kernel's ``step`` recorded).
    path : pathlib.Path
        The chunk's Parquet file.
    family : str
        The motion family's name (a column).
    chunk : int
        The chunk's number (a column).
    """
    ds = read_dataset(path, validate=False)
    RECORD.clear()
    ef = est.estimate(ds)
    rec = pd.DataFrame(RECORD, columns=COLUMNS)
    frame = ds.frame.reset_index(drop=True)
    status = ef["status"].astype(str).to_numpy()
    estimate = ef["payload_estimate"].to_numpy(float) if "payload_estimate" in ef else np.full(len(ef), np.nan)
    sigma = ef["sigma"].to_numpy(float) if "sigma" in ef else np.full(len(ef), np.nan)
    fault = ef["fault"].astype(str).to_numpy() if "fault" in ef else np.full(len(ef), "")
    rows = []
    # one record row per kernel step, in the frame's order; a sample the monitor kept from the
    # kernel has none (its state NaN)
    t = frame["time"].to_numpy(float)
    ri = 0
    state = np.full((len(frame), len(COLUMNS) - 1), np.nan)
    for fi in range(len(frame)):
        if ri < len(rec) and rec["time"].iat[ri] == t[fi]:
            state[fi] = rec.iloc[ri, 1:].to_numpy(float)
            ri += 1
    st = pd.DataFrame(state, columns=COLUMNS[1:])
    start_rows = frame.groupby("experiment").indices
    for exp, idx in start_rows.items():
        idx = np.asarray(idx)
        t0 = t[idx[0]]
        for ta, tb, load in loads_of(ds.experiment_meta[int(exp)], t[idx[-1]] - t0):
            inside = idx[(t[idx] - t0 >= ta) & (t[idx] - t0 < tb)]
            if len(inside) < 10:
                continue
            ia, ib = inside[0], inside[-1] + 1
            seg = slice(ia, ib)
            s = status[seg]
            ok = np.flatnonzero(s == "ok")
            first_ok = ok[0] if len(ok) else ib - ia
            wait = slice(ia, ia + first_ok)
            ws = s[:first_ok]
            w = st.iloc[ia:ia + first_ok]
            bw = st["boom_windows"].to_numpy()[seg]
            # boom windows weighed during the wait: increments of the counter (restarts reset it)
            prev = np.r_[bw[0], bw[:-1]]
            weighed = (bw > prev) | ((bw < prev) & (bw > 0))  # a boom window (or a restart's first ones)
            boom_moving = int(np.sum(weighed[:first_ok]))
            first_boom = np.flatnonzero(weighed)
            first_boom = min(first_boom[0] if len(first_boom) else first_ok, first_ok)
            warm = ws == "warming_up"
            row = {"family": family, "chunk": chunk, "experiment": int(exp), "load": load,
                   "t_start": t[ia] - t0, "duration": t[ib - 1] - t[ia],
                   "wait": (first_ok) / 100.0, "never_ok": len(ok) == 0,
                   "wait_load_changing": float(np.sum(ws == "load_changing")) / 100,
                   "wait_warming_up": float(np.sum(warm)) / 100,
                   "wait_sensor_fault": float(np.sum(ws == "sensor_fault")) / 100,
                   "wait_other": float(np.sum(~np.isin(ws, ["load_changing", "warming_up", "sensor_fault"]))) / 100,
                   "warm_not_ready": float(np.sum(warm & (w["ready"].to_numpy() == 0))) / 100,
                   "warm_not_steady": float(np.sum(warm & (w["ready"].to_numpy() == 1) & (w["steady"].to_numpy() == 0))) / 100,
                   "warm_lone": float(np.sum(warm & (w["ready"].to_numpy() == 1) & (w["steady"].to_numpy() == 1))) / 100,
                   "boom_windows_in_wait": boom_moving,
                   "wait_boom_still": first_boom / 100.0, "wait_boom_moving": (first_ok - first_boom) / 100.0,
                   "restarts_in_seg": int(np.nanmax(st["new_loads"].to_numpy()[seg]) - np.nanmin(st["new_loads"].to_numpy()[seg])),
                   "not_ok_after_first": int(np.sum(s[first_ok:] != "ok")),
                   "faults": ";".join(sorted(set(fault[seg][s == "sensor_fault"]))),
                   }
            if len(ok):
                k = ia + first_ok
                row.update(first_estimate=estimate[k], first_sigma=sigma[k], first_error=estimate[k] - load)
                # the first second of ok weights: their largest error
                okk = ia + ok[(ok >= first_ok) & (ok < first_ok + 100)]
                row.update(max_err_1s=float(np.nanmax(np.abs(estimate[okk] - load))),
                           cover_1s=float(np.mean(np.abs(estimate[okk] - load) <= 2 * sigma[okk])))
            row["changing_truth"] = False
            rows.append(row)
        covered = np.zeros(len(idx), bool)
        for ta, tb, _ in loads_of(ds.experiment_meta[int(exp)], t[idx[-1]] - t0):
            covered |= (t[idx] - t0 >= ta) & (t[idx] - t0 < tb)
        judged = t[idx] - t0 >= 1.0
        rows.append({"family": family, "chunk": chunk, "experiment": int(exp), "load": np.nan,
                     "t_start": np.nan, "duration": float(np.sum(~covered & judged)) / 100,
                     "wait": float(np.sum(~covered & judged & (status[idx] != "ok"))) / 100,
                     "changing_truth": True, "judged": float(np.sum(judged)) / 100})
    return pd.DataFrame(rows)


def set_kernel(items: list[str]) -> None:
    """Apply ``--set NAME=VALUE`` items to the kernel module's settings for this run."""
    from excavator_payload.estimators.classical.machine_calibration import kernel as kernel_module

    for item in items:
        name, value = item.split("=")
        setattr(kernel_module, name, type(getattr(kernel_module, name))(eval(value)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cache", type=Path, default=Path("/work/scratch/alarms"))
    ap.add_argument("--family", default="shift")
    ap.add_argument("--seed", type=int, default=bfa.SEED)
    ap.add_argument("--chunks", default="0")
    ap.add_argument("--calibration", default="study")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--set", action="append", default=[], help="NAME=VALUE: a kernel setting for this run")
    a = ap.parse_args()
    set_kernel(a.set)
    PressureKernel.step = _recording_step(PressureKernel.step)
    est = bfa.calibrated(a.calibration, a.cache)
    folder = a.cache / a.family if a.seed == bfa.SEED else a.cache / f"seed-{a.seed}" / a.family
    frames = [study_chunk(est, folder / f"chunk{int(k):03d}.parquet", a.family, int(k)) for k in a.chunks.split(",")]
    table = pd.concat(frames, ignore_index=True)
    if a.out:
        table.to_csv(a.out, index=False)
    seg = table[table["changing_truth"] != True]  # noqa: E712
    chg = table[table["changing_truth"] == True]  # noqa: E712
    judged = chg["judged"].sum()
    print(f"judged {judged:.1f} s; not ok while the truth changes (fills, releases): "
          f"{chg['wait'].sum():.1f} s ({100 * chg['wait'].sum() / judged:.1f} %); waits after a change: "
          f"{seg['wait'].sum():.1f} s ({100 * seg['wait'].sum() / judged:.1f} %), of which the boom stood "
          f"{seg['wait_boom_still'].sum():.1f} s and moved {seg['wait_boom_moving'].sum():.1f} s "
          f"(not ready {seg['warm_not_ready'].sum():.1f} s, not steady {seg['warm_not_steady'].sum():.1f} s, "
          f"a lone joint {seg['warm_lone'].sum():.1f} s, load_changing {seg['wait_load_changing'].sum():.1f} s, "
          f"sensor_fault {seg['wait_sensor_fault'].sum():.1f} s); not ok after the first ok "
          f"{seg['not_ok_after_first'].sum() / 100:.1f} s")
    with pd.option_context("display.width", 250, "display.max_columns", 40, "display.max_rows", 400):
        print(seg.drop(columns=["family", "changing_truth", "judged"]).round(2).to_string(index=False))
        print(seg[["wait", "wait_load_changing", "wait_warming_up", "wait_sensor_fault", "warm_not_ready",
                     "warm_not_steady", "warm_lone", "wait_boom_still", "wait_boom_moving", "first_error", "first_sigma",
                   "max_err_1s", "cover_1s"]].describe().round(2).to_string())


if __name__ == "__main__":
    main()
