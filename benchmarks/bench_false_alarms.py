"""False alarms of the user's default flow over ≥ 10⁶ clean samples per motion family.

The flow is the README's: ``calibrated`` on ``cat345c-hydraulic-3pct`` (momentum form, the
sensor-health monitor on, as by default), calibrated from the study's 10 swings (or the
README's 10 planned swings: ``--calibration readme``), then ``zero`` on the project's empty
swing. Every clean sample more than 1 s after its experiment's start is judged; a sample that
is not ``ok`` is a false alarm, except the documented wait for the boom's first 50 windows
(``warming_up`` from the start until the first other status, as in ``bench_any_motion``).
Reported per family: samples judged, share not ``ok`` by status, ``sensor_fault`` by
``signal:kind``, ``warming_up`` after the documented wait.

Families (simulated in chunks, cached as Parquet under ``--cache``): the simulator's ``nmpc``,
``work-cycle`` (up to the dump), ``operator`` and NMPC swings replayed on a 5° slope
(``nmpc-slope5``, as the README's slope test); ``lever`` / ``lever-slope5`` (now tuning
families: their false alarms were diagnosed) and the held-out ``joystick`` / ``joystick-slope7``
of :mod:`held_out_motions` (judge only: ``--families joystick,joystick-slope7``).

Usage::

    PYTHONPATH=src nice -n 10 python benchmarks/bench_false_alarms.py --samples 1000000 \\
        --families nmpc,work-cycle,operator,lever,lever-slope5,nmpc-slope5 --out false-alarms
    # simulate only (fill the cache), e.g. in another process:
    PYTHONPATH=src python benchmarks/bench_false_alarms.py --generate-only --families nmpc
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
import held_out_motions  # noqa: E402

from excavator_payload.data.io import read_dataset, write_dataset  # noqa: E402
from excavator_payload.evaluation import demo_machine as dm  # noqa: E402
from excavator_payload.simulation.generate import simulate_dataset  # noqa: E402

MACHINE = "cat345c-hydraulic"
RATED = 5000.0
#: Experiments per cached chunk.
CHUNK = 40
#: Seeds: far from bench_any_motion's (9100…) and the calibration's (9200…).
SEED = 40_000
FAMILY_NAMES = ("nmpc", "work-cycle", "operator", "nmpc-slope5", "lever", "lever-slope5",
                "joystick", "joystick-slope7", "slopes", "shift")


def feasible(table: pd.DataFrame) -> pd.DataFrame:
    """The experiments of a trajectory table that the replay accepts (the lever generator now
    and then asks a bucket for more than its cylinder gives at the relief pressure: refused by
    ``check_trajectory_motion``; dropped here, counted in the chunk's json), renumbered."""
    from excavator_payload.errors import DatasetError
    from excavator_payload.model.machine import load_machine
    from excavator_payload.simulation.trajectory import check_trajectory_motion, trajectory_from_frame

    machine = load_machine(MACHINE)
    keep = []
    for _, sub in table.groupby("experiment", sort=True):
        try:
            check_trajectory_motion(trajectory_from_frame(sub), machine, allow_overspeed=True)
        except DatasetError:
            continue
        keep.append(sub.assign(experiment=len(keep)))
    FEASIBLE_DROPPED.append(table["experiment"].nunique() - len(keep))
    return pd.concat(keep, ignore_index=True)


FEASIBLE_DROPPED: list[int] = []


def simulate_family(family: str, n: int, seed: int):
    common = dict(machine=MACHINE, session=dm.SESSION_WORK, with_truth=True, workers=1, progress=False)
    if family in ("nmpc", "operator", "slopes"):
        return simulate_dataset(n, seed=seed, motion=family, **common)
    if family == "shift":  # truck loadings: their digs and dumps say load_changing / warming_up
        return simulate_dataset(max(1, n // 8), seed=seed, motion=family, **common)
    if family == "work-cycle":
        return dm.before_release(simulate_dataset(n, seed=seed, motion="work-cycle", **common))
    if family == "nmpc-slope5":
        payloads = np.random.default_rng(seed).uniform(0, RATED, n)
        return dm.simulate_trajectory(dm.motion_trajectory(n, seed, payloads, MACHINE, motion="nmpc",
                                                           slope_deg=5.0), seed, dm.SESSION_WORK)
    if family in ("lever", "lever-slope5"):
        slope = 5.0 if family == "lever-slope5" else None
        return dm.simulate_trajectory(feasible(held_out_motions.lever_trajectory(n, seed, slope_deg=slope)), seed,
                                    dm.SESSION_WORK)
    if family in ("joystick", "joystick-slope7"):
        slope = 7.0 if family == "joystick-slope7" else None
        return dm.simulate_trajectory(feasible(held_out_motions.joystick_trajectory(n, seed, slope_deg=slope)), seed,
                                    dm.SESSION_WORK)
    raise SystemExit(f"unknown family {family!r}; choose from {', '.join(FAMILY_NAMES)}")


def _judged_count(frame: pd.DataFrame) -> int:
    t = frame["time"].to_numpy(float)
    first = frame.groupby("experiment")["time"].transform("min").to_numpy(float)
    return int(((t - first) >= 1.0).sum())


def chunks(family: str, samples: int, cache: Path, generate: bool = True, seed: int = SEED):
    """Yield (index, path) of cached chunks until ``samples`` judged samples are covered (the
    chunks of another ``seed`` than :data:`SEED` under ``cache/seed-SEED``)."""
    folder = cache / family if seed == SEED else cache / f"seed-{seed}" / family
    folder.mkdir(parents=True, exist_ok=True)
    seed0 = seed + 1000 * FAMILY_NAMES.index(family)
    total, k = 0, 0
    while total < samples:
        path = folder / f"chunk{k:03d}.parquet"
        count = folder / f"chunk{k:03d}.json"
        if not path.exists():
            if not generate:
                return
            FEASIBLE_DROPPED.clear()
            ds = simulate_family(family, CHUNK, seed0 + k)
            write_dataset(ds, path)
            count.write_text(json.dumps({"judged": _judged_count(ds.frame),
                                         "experiments": int(ds.frame["experiment"].nunique()),
                                         "refused_motions": int(sum(FEASIBLE_DROPPED))}))
        total += json.loads(count.read_text())["judged"]
        yield k, path
        k += 1


def alarms_of(est_frame: pd.DataFrame, frame: pd.DataFrame):
    """(judged mask, alarm mask, beyond-the-wait warming_up mask) of one dataset."""
    t = frame["time"].to_numpy(float)
    exp = frame["experiment"].to_numpy()
    first = pd.Series(t).groupby(exp).transform("min").to_numpy()
    status = est_frame["status"].astype(str).to_numpy()
    judged = (t - first) >= 1.0
    # the wait for the boom's first 50 windows is a documented silence, not an alarm
    waiting = pd.Series(status == "warming_up").groupby(exp).cummin().to_numpy()
    return judged, judged & ~waiting & (status != "ok"), waiting


def in_truth(frame: pd.DataFrame, rows: np.ndarray, threshold: np.ndarray) -> np.ndarray:
    """Whether the noise-free truth alone (the ``true_*`` columns) is a one-frame glitch at the
    sample each ``rejected_outlier`` row reports (the kernel judges the sample two before, with
    two neighbours on each side: ``judge_frame``)."""
    from excavator_payload.estimators.classical.pressure_regression import SIGNALS, judge_frame

    cols = ["true_" + s for s in SIGNALS]
    if not all(c in frame for c in cols):
        return np.zeros(len(rows), bool)
    x = frame[cols].to_numpy(float)
    exp = frame["experiment"].to_numpy()
    out = np.zeros(len(rows), bool)
    for k, i in enumerate(rows):
        c = i - 2
        if c - 2 < 0 or exp[c - 2] != exp[i]:
            continue
        out[k] = judge_frame(x[c - 1], x[c], x[c + 1], threshold, x[c - 2], x[c + 2])[1]
    return out


def bar(done: int, total: int, label: str, t0: float) -> None:
    w = 30
    f = min(done / max(total, 1), 1.0)
    sys.stderr.write(f"\r{label:16s} [{'#' * int(w * f):{w}s}] {done:>9,d}/{total:,d} "
                     f"({time.time() - t0:.0f} s)")
    sys.stderr.flush()


def calibrated(variant: str, cache: Path):
    """The user's default flow: calibrated on the 3 % machine file, zeroed on the empty swing
    (fitted once per variant and kept under the cache)."""
    from excavator_payload.estimators import load_estimator
    from excavator_payload.estimators.classical.calibrated import CalibratedEstimator

    folder = cache / f"estimator-{variant}"
    if (folder / "estimator.json").exists() or any(folder.glob("*")):
        return load_estimator(folder)
    if variant == "study":  # bench_any_motion's first row
        calibration = dm.calibration_data(10, 9200)
    elif variant == "readme":  # the README's 10 planned swings
        calibration = simulate_dataset(10, seed=9202, motion="swing", machine=MACHINE,
                                       session=dm.SESSION_CALIBRATION, with_truth=True, workers=1,
                                       progress=False)
    else:
        raise SystemExit(f"unknown calibration {variant!r}: study or readme")
    est = CalibratedEstimator("cat345c-hydraulic-3pct").fit(calibration)
    est.zero(dm.zero_data(9150))
    folder.mkdir(parents=True, exist_ok=True)
    est.save(folder)
    return est


def judge_chunk(est, threshold: np.ndarray, family: str, k: int, path: Path) -> tuple[dict, pd.DataFrame]:
    """Counts of one cached chunk, and its alarms (one row each)."""
    ds = read_dataset(path, validate=False)
    ef = est.estimate(ds)
    judged, alarm, waiting = alarms_of(ef, ds.frame)
    status = ef["status"].astype(str).to_numpy()
    fault = ef["fault"].astype(str).to_numpy() if "fault" in ef else np.full(len(ef), "")
    a = np.flatnonzero(alarm)
    truth = np.zeros(len(a), bool)
    outlier = status[a] == "rejected_outlier"
    truth[outlier] = in_truth(ds.frame, a[outlier], threshold)
    record = {"family": family, "chunk": k, "experiments": int(ds.frame["experiment"].nunique()),
              "judged": int(judged.sum()), "waiting": int((judged & waiting).sum()),
              "alarms": int(alarm.sum()), "outlier_in_truth": int(truth.sum()),
              "status": {str(s): int(c) for s, c in zip(*np.unique(status[alarm], return_counts=True))},
              "faults": {}}
    for text in fault[alarm & (status == "sensor_fault")]:
        for item in text.split(","):
            record["faults"][item] = record["faults"].get(item, 0) + 1
    alarms = pd.DataFrame({"family": family, "chunk": k, "experiment": ds.frame["experiment"].to_numpy()[a],
                           "time": ds.frame["time"].to_numpy(float)[a], "status": status[a],
                           "fault": fault[a], "in_truth": truth})
    return record, alarms


def run(est, families: list[str], samples: int, cache: Path, out: Path, generate: bool, seed: int = SEED) -> None:
    """Judge the families' chunks round-robin (every family grows alike; whatever is judged when
    stopped is reported), one JSON line per chunk in ``out/chunks.jsonl`` (resumed: chunks
    already there are skipped)."""
    from excavator_payload.estimators.classical.pressure_regression import spike_threshold

    threshold = spike_threshold(est.kernel.difference_scale)
    log = out / "chunks.jsonl"
    done = {}
    if log.exists():
        for line in log.read_text().splitlines():
            r = json.loads(line)
            done[(r["family"], r["chunk"])] = r
    streams = {f: chunks(f, samples, cache, generate, seed) for f in families}
    judged = {f: sum(r["judged"] for (g, _), r in done.items() if g == f) for f in families}
    t0 = time.time()
    while streams:
        for f in list(streams):
            try:
                k, path = next(streams[f])
            except StopIteration:
                del streams[f]
                continue
            if (f, k) in done:
                continue
            record, alarms = judge_chunk(est, threshold, f, k, path)
            record["seconds"] = round(time.time() - t0, 1)
            with log.open("a") as fh:
                fh.write(json.dumps(record) + "\n")
            alarms.to_csv(out / "alarms.csv", mode="a", header=not (out / "alarms.csv").exists(), index=False)
            judged[f] += record["judged"]
            bar(judged[f], samples, f, t0)
    sys.stderr.write("\n")


def report(out: Path) -> pd.DataFrame:
    """Per family: samples judged, false alarms by status, sensor faults by signal:kind."""
    rows = {}
    for line in (out / "chunks.jsonl").read_text().splitlines():
        r = json.loads(line)
        row = rows.setdefault(r["family"], {"family": r["family"], "experiments": 0, "judged": 0, "waiting": 0,
                                            "alarms": 0, "outlier_in_truth": 0, "status": {}, "faults": {}})
        for key in ("experiments", "judged", "waiting", "alarms", "outlier_in_truth"):
            row[key] += r[key]
        for key in ("status", "faults"):
            for name, c in r[key].items():
                row[key][name] = row[key].get(name, 0) + c
    table = []
    for row in rows.values():
        n = max(row["judged"], 1)
        table.append({"family": row["family"], "experiments": row["experiments"], "judged": row["judged"],
                      "judged_after_wait": row["judged"] - row["waiting"],
                      "false_alarms": row["alarms"] / n,
                      **{f"{s}": c / n for s, c in sorted(row["status"].items())},
                      "outlier_in_truth": row["outlier_in_truth"] / n,
                      "faults": "; ".join(f"{k} {v}" for k, v in sorted(row["faults"].items(), key=lambda kv: -kv[1]))})
    return pd.DataFrame(table)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--samples", type=float, default=1e6, help="judged samples per family")
    ap.add_argument("--families", default="nmpc,work-cycle,operator,nmpc-slope5,lever,lever-slope5")
    ap.add_argument("--calibration", default="study", help="study (10 swings) or readme (10 planned swings)")
    ap.add_argument("--cache", type=Path, default=Path("/work/scratch/alarms"))
    ap.add_argument("--out", type=Path, default=Path("false-alarms"))
    ap.add_argument("--generate-only", action="store_true", help="only fill the cache")
    ap.add_argument("--no-generate", action="store_true", help="judge only the chunks already cached")
    ap.add_argument("--report", action="store_true", help="only print the table of what --out holds")
    ap.add_argument("--seed", type=int, default=SEED, help="first seed of the data (families 1000 apart; "
                    "another than the default: fresh data, cached apart)")
    a = ap.parse_args()
    families = [f for f in a.families.split(",") if f]
    for f in families:
        if f not in FAMILY_NAMES:
            print(f"unknown family {f!r}; choose from {', '.join(FAMILY_NAMES)}", file=sys.stderr)
            raise SystemExit(2)
    if a.calibration not in ("study", "readme"):
        print(f"unknown calibration {a.calibration!r}: study or readme", file=sys.stderr)
        raise SystemExit(2)
    samples = int(a.samples)
    t0 = time.time()
    if a.generate_only:
        for f in families:
            n = sum(1 for _ in chunks(f, samples, a.cache, seed=a.seed))
            print(f"{f}: {n} chunks cached ({time.time() - t0:.0f} s)", flush=True)
        return
    out = a.out / a.calibration
    if not a.report:
        out.mkdir(parents=True, exist_ok=True)
        run(calibrated(a.calibration, a.cache), families, samples, a.cache, out, not a.no_generate, a.seed)
    table = report(out)
    table.to_csv(out / "false_alarms.csv", index=False)
    with pd.option_context("display.width", 200, "display.max_columns", 30):
        print(table.to_string(index=False))
    print(f"total {time.time() - t0:.0f} s")


if __name__ == "__main__":
    main()
