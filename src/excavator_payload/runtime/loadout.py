"""A day of loading: one weight per bucket pass, a total per truck, a shift's record.

What a scale in the cab shows (issue 30, "A day of loading"): every pass weighed before its
dump, the truck's running total against its target and what the last pass should carry, and
a record of every pass and truck of the shift.

Phases, from the signals alone
------------------------------
The bucket's own motion says where a pass is (:func:`bucket_moves`): a **dig** ends with the
bucket curling in by more than :data:`DIG_CURL` (the cut fills it), a **dump** is the bucket
opening by more than :data:`DUMP_OPEN` after a dig (the load leaves). Between them the arm
lifts while slewing (**lift-swing**: boom rising or slewing), after the dump it **returns**.
A state machine (empty → dig → loaded → dump → empty) keeps the moves an operator makes in
between from counting: an opening while empty (moving the bucket to the next cut) is no dump,
a second curl while loaded (a correction) restarts the pass's dig.

One weight per pass
-------------------
The estimator (the ``calibrated`` one restarts on a new load by itself: statuses
``load_changing`` while a load leaves or enters, ``warming_up`` until the boom has been
weighed again) runs over the whole log; a pass's weight is its **last** ``ok`` estimate and σ
between the dig's end and the dump's start, locked at that time. A pass with no ``ok``
estimate there takes its last ``degraded`` one (weighed without a sensor the health monitor
named, σ widened; status ``degraded``, the sensor in the reason) and is counted in the truck's
total; a pass with neither is reported with status ``not_weighed`` and the reason (the
statuses it had instead), never skipped or guessed.

Trucks
------
In a dataset each experiment is one truck; within one, a gap of :data:`TRUCK_GAP` s or more
between samples starts a new truck (a log of the arm's frames).

Record
------
:class:`ShiftRecord`: SQLite tables ``passes(source, truck, pass, time_lock, weight, sigma,
status, …)`` and ``trucks(source, truck, passes, total, target, …)``, unique by
``(source, truck[, pass])`` where ``source`` is the SHA-256 of the data file: a rerun on the
same data replaces its rows (never doubles them) and each truck is written in one
transaction (a crash loses at most the truck being written; a rerun completes it).
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from excavator_payload.errors import DatasetError
from excavator_payload.estimators.status import Status
from excavator_payload.runtime.shift_record import (  # noqa: F401  (the record's home; kept importable here)
    SCHEMA, SCHEMA_VERSION, ShiftRecord, check_record_schema, read_record, record_error)

#: A pass weighed without a sensor the health monitor named (:func:`lock_weight`).
DEGRADED = Status.DEGRADED.value
SENSOR_FAULT = Status.SENSOR_FAULT.value

#: A curl of the bucket by more than this (rad) ends a dig: the cut fills the bucket. Work
#: cycles curl 65-125° (halved near the end of the bucket's range); the bucket's "ready" curl
#: on the return is 10-40°.
DIG_CURL = math.radians(45.0)
#: An opening by more than this (rad) after a dig is a dump: work cycles open 100-120°, or
#: half that near the end of the bucket's range (60° missed 4 of 50 passes in a 10-truck shift).
DUMP_OPEN = math.radians(40.0)
#: A bucket move is where its smoothed rate exceeds this (rad/s) in one direction (the
#: operator's corrections over the truck: 2° in 0.5 s, below it).
MOVE_RATE = 0.15
#: Smoothing of the rates before the phases are read (s, moving mean).
SMOOTHING = 0.2
#: A gap of at least this (s) without samples starts a new truck.
TRUCK_GAP = 30.0
#: The phase of each sample (:func:`phases`).
PHASES = ("dig", "lift-swing", "dump", "return")


@dataclass
class Pass:
    """One bucket pass: its phases' times (s), its locked weight (kg) and σ, its status.

    Parameters
    ----------
    truck : int
        Number of the truck the pass went into (1, 2, ...).
    index : int
        1, 2, ... within the truck.
    time_dig : float
        s, when the dig's curl ends (the bucket is full).
    time_dump : float
        s, when the dump starts.
    time_lock : float or None
        s, the sample the weight was locked at; None when not weighed.
    weight : float or None
        kg, the locked weight; None when not weighed.
    sigma : float or None
        kg, its one-sigma uncertainty (NaN when the estimator gives none); None when not weighed.
    status : str
        ``"ok"``, ``"degraded"`` (weighed without a sensor the health monitor named, σ widened)
        or ``"not_weighed"``.
    reason : str, optional
        Why it was not weighed (the statuses it had instead), or which sensors a degraded weight
        was weighed without.
    true_weight : float or None, optional
        kg, the simulated truth of the pass, where the data has it.
    """

    truck: int
    index: int  # 1, 2, … within the truck
    time_dig: float  # the dig's curl ends (the bucket is full)
    time_dump: float  # the dump starts
    time_lock: float | None  # the sample the weight was locked at
    weight: float | None
    sigma: float | None
    status: str  # "ok", "degraded" or "not_weighed"
    reason: str = ""
    true_weight: float | None = None


@dataclass
class Truck:
    """One truck: its passes and total (kg); ``target`` as given or from the data.

    Parameters
    ----------
    truck : int
        The truck's number (1, 2, ...).
    passes : list of Pass, optional
        Its passes, in order.
    target : float or None, optional
        kg, its target load; None when none is given.
    true_total : float or None, optional
        kg, the true load, where the data has it.
    true_passes : int or None, optional
        How many passes the truth holds.
    matched : int or None, optional
        How many of them were found by one detected pass each.
    start : float or None, optional
        s, the log's / bus's time of its first sample.
    faults : list of dict, optional
        The sensor faults (DM1 episodes) that began in this truck (:func:`episode_row`).
    """

    truck: int
    passes: list[Pass] = field(default_factory=list)
    target: float | None = None
    true_total: float | None = None
    true_passes: int | None = None  # passes the truth holds
    matched: int | None = None  # of them, found by one detected pass each
    start: float | None = None  # the log's / bus's time of its first sample (pass times count from it)
    #: sensor faults (J1939 DM1 episodes) that began in this truck: dicts of spn, fmi, signal,
    #: kind, start, end (s, the truck's time; end NaN: active to the truck's end)
    faults: list[dict] = field(default_factory=list)

    @property
    def total(self) -> float:
        return float(sum(p.weight for p in self.passes if p.weight is not None))

    @property
    def unweighed(self) -> int:
        return sum(p.weight is None for p in self.passes)

    @property
    def degraded(self) -> int:
        """Passes weighed without a sensor the health monitor named (in the total, σ widened)."""
        return sum(p.status == DEGRADED for p in self.passes)

    @property
    def remaining(self) -> float | None:
        """What the last pass should carry: the target less the total so far."""
        return None if self.target is None else self.target - self.total


def _smooth(x: np.ndarray, period: float) -> np.ndarray:
    n = max(1, int(round(SMOOTHING / period)))
    return np.convolve(x, np.ones(n) / n, mode="same")


def bucket_moves(time: np.ndarray, angle: np.ndarray, rate: np.ndarray | None = None) -> list[tuple[int, int, float]]:
    """The bucket's moves: (first sample, last sample, change of angle in rad) of each run where
    its smoothed rate stays beyond :data:`MOVE_RATE` in one direction (+: opening, −: curling).

    The rate is the bucket angle's own slope: a dig and a dump are defined by the angle, and a
    lost rate sensor (at 0 or frozen) read as the rate lost 11 of 25 passes of a shift, silently,
    and put its trucks' totals up to 11 t short. The rate sensor serves only where the angle is
    not finite.

    Parameters
    ----------
    time : ndarray
        s, sample times (evenly spaced: the median step is the period).
    angle : ndarray
        rad, the bucket angle per sample.
    rate : ndarray, optional
        rad/s, the bucket's measured angular rate per sample (where the angle is not finite).
    """
    time, angle = np.asarray(time, float), np.asarray(angle, float)
    period = float(np.median(np.diff(time))) if len(time) > 1 else 0.01
    if len(angle) < 2:
        slope = np.zeros(len(angle))
    else:  # over the samples' own times where they rise (a gap is not a fast move)
        slope = np.gradient(angle, time if np.all(np.diff(time) > 0) else period)
    if rate is not None:
        slope = np.where(np.isfinite(slope), slope, np.asarray(rate, float))
    r = _smooth(np.where(np.isfinite(slope), slope, 0.0), period)
    sign = np.where(r > MOVE_RATE, 1, np.where(r < -MOVE_RATE, -1, 0))
    moves = []
    edges = np.flatnonzero(np.diff(np.r_[0, sign, 0]))
    for a, b in zip(edges[:-1], edges[1:]):
        if sign[a] != 0:
            moves.append((int(a), int(b - 1), float(angle[b - 1] - angle[a])))
    return moves


def find_passes(time: np.ndarray, angle: np.ndarray, rate: np.ndarray | None = None) -> list[tuple[int, int]]:
    """(dig end, dump start) sample of each pass, from the bucket's moves (module doc).

    Parameters
    ----------
    time : ndarray
        s, sample times.
    angle : ndarray
        rad, the bucket angle per sample.
    rate : ndarray, optional
        rad/s, the bucket's measured angular rate per sample (where the angle is not finite;
        :func:`bucket_moves`).
    """
    passes, dig = [], None
    for a, b, change in bucket_moves(time, angle, rate):
        if change < -DIG_CURL:
            dig = b  # a new cut, or a correction of the last one: the latest curl counts
        elif change > DUMP_OPEN and dig is not None:
            passes.append((dig, a))
            dig = None
    return passes


def phases(frame: pd.DataFrame) -> np.ndarray:
    """Phase of each sample of one truck (:data:`PHASES`; "" before the first dig): the dig's
    curl, lift-swing until the dump, the dump's opening, then return (and the wait before the
    next cut) until the next curl.

    Parameters
    ----------
    frame : pandas.DataFrame
        One truck's samples, with ``time``, ``bucket_angle`` and ``bucket_rate`` columns.
    """
    time = frame["time"].to_numpy(float)
    out = np.full(len(time), "", dtype=object)
    angle, rate = frame["bucket_angle"].to_numpy(float), frame["bucket_rate"].to_numpy(float)
    moves = bucket_moves(time, angle, rate)
    found = find_passes(time, angle, rate)
    for k, (dig, dump) in enumerate(found):
        curl = next(a for a, b, c in moves if b == dig)
        end = next(b for a, b, c in moves if a == dump)
        following = (next(a for a, b, c in moves if b == found[k + 1][0]) if k + 1 < len(found)
                     else len(time))
        out[curl:dig + 1] = "dig"
        out[dig + 1:dump] = "lift-swing"
        out[dump:end + 1] = "dump"
        out[end + 1:following] = "return"
    return out


def lock_weight(time: np.ndarray, estimate: np.ndarray, sigma: np.ndarray, status: np.ndarray,
                start: int, stop: int, fault: np.ndarray | None = None
                ) -> tuple[float | None, float | None, float | None, str, str]:
    """The pass's weight from samples ``start … stop-1``: (time, weight, σ, reason, status).

    The last ``ok`` estimate, status ``ok``, unless a ``sensor_fault`` follows it in the pass
    (the weighing withheld): the health monitor names a fault some samples after it starts, so
    that ``ok`` may already hold it (an unzeroed model's offsets weighed a pass 400 kg off as
    ``ok`` 0.3 s before the pressures were named). Then, and without an ``ok`` one, the last
    ``degraded`` estimate after it (weighed without the named sensor, its σ widened), status
    ``degraded`` and the reason naming the sensors; without either, nothing, status
    ``not_weighed`` and why. An ``ok`` followed only by ``degraded`` samples stays the weight
    (measured in docs/loadout.md). A pass weighed on an ``ok`` sample is never reported degraded because a
    fault came earlier.

    Parameters
    ----------
    time : ndarray
        s, sample times.
    estimate : ndarray
        kg, the estimates per sample.
    sigma : ndarray
        kg, their one-sigma uncertainties.
    status : ndarray of str
        The estimates' statuses.
    start, stop : int
        Samples ``start`` to ``stop - 1`` are searched (the dig's end to the dump's start).
    fault : ndarray of str, optional
        The estimates' ``fault`` column (the named sensors, ``signal:kind;…``), for a degraded
        pass's reason.
    """
    status = np.asarray(status[start:stop])
    finite = np.isfinite(estimate[start:stop])

    def named(i: int) -> str:
        return str(fault[i]) if fault is not None and fault[i] not in (None, "") else "a sensor"

    ok = np.flatnonzero((status == "ok") & finite)
    first = 0
    distrust = ""
    if len(ok):
        after = np.flatnonzero(status[ok[-1] + 1:] == SENSOR_FAULT)
        if not len(after):
            i = start + int(ok[-1])
            return float(time[i]), float(estimate[i]), float(sigma[i]), "", "ok"
        first = int(ok[-1]) + 1
        k = start + first + int(after[0])
        distrust = (f"its last ok estimate ({estimate[start + ok[-1]]:,.0f} kg) came before {named(k)} "
                    f"was named at {time[k]:.2f} s")
    found = first + np.flatnonzero((status[first:] == DEGRADED) & finite[first:])
    if len(found):
        i = start + int(found[-1])
        return float(time[i]), float(estimate[i]), float(sigma[i]), f"weighed without {named(i)} (σ widened)", DEGRADED
    if distrust:
        return None, None, None, f"no trusted estimate between the dig and the dump: {distrust}", "not_weighed"
    seen = pd.Series(status).value_counts()
    what = ", ".join(f"{k} {100 * v / max(stop - start, 1):.0f} %" for k, v in seen.items()) or "no samples"
    return None, None, None, f"no ok estimate between the dig and the dump ({what})", "not_weighed"


def split_trucks(frame: pd.DataFrame) -> list[pd.DataFrame]:
    """One frame per truck: per experiment, cut where :data:`TRUCK_GAP` s pass without a sample.

    Parameters
    ----------
    frame : pandas.DataFrame
        A dataset's samples, with ``experiment`` and ``time`` columns.
    """
    out = []
    for _, rows in frame.groupby("experiment", sort=False):
        t = rows["time"].to_numpy(float)
        cuts = np.flatnonzero(np.diff(t) >= TRUCK_GAP) + 1
        for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(t)]):
            out.append(rows.iloc[a:b].reset_index(drop=True))
    return out


def _truth_match(passes: list[Pass], truth: list[dict]) -> int:
    """Each detected pass's true weight: the true pass whose release follows its dump start
    within 3 s (the load starts to leave part-way through the bucket's opening). Returns how
    many true passes were found (a second detection of the same one gets no true weight)."""
    found: set[int] = set()
    for p in passes:
        for i, t in enumerate(truth):
            if t["release"][0] - 3.0 <= p.time_dump <= t["release"][1] and i not in found:
                p.true_weight = float(t["payload"])
                found.add(i)
                break
    return len(found)


def weigh_truck(estimator, rows: pd.DataFrame, truck: int, target: float | None,
                truth: list[dict] | None = None) -> Truck:
    """The passes of one truck's samples ``rows`` weighed by ``estimator`` (reset first).

    Parameters
    ----------
    estimator : Estimator
        A fitted estimator (reset, then run over ``rows``).
    rows : pandas.DataFrame
        One truck's samples (its sensor-set signals and ``time``).
    truck : int
        The truck's number.
    target : float or None
        kg, its target load, if any.
    truth : list of dict, optional
        The simulated passes (``release`` interval, s, and ``payload``, kg) to match against.
    """
    from excavator_payload.data.dataset import Dataset

    rows = rows.copy()
    rows["experiment"] = 0
    est = estimator.estimate(Dataset(rows, {"sensor_set": estimator.sensor_set.name}))
    time = rows["time"].to_numpy(float)
    estimate, sigma = est["payload_estimate"].to_numpy(float), est["sigma"].to_numpy(float)
    status = est["status"].to_numpy(object)
    out = Truck(truck, target=target, start=float(time[0]) if len(time) else None)
    if "fault" in est:
        out.faults = fault_episodes(estimator.sensor_set, time, est["fault"].to_numpy(object))
    for k, (dig, dump) in enumerate(find_passes(time, rows["bucket_angle"].to_numpy(float),
                                                rows["bucket_rate"].to_numpy(float)), start=1):
        t_lock, w, s, reason, pass_status = lock_weight(
            time, estimate, sigma, status, dig, dump, est["fault"].to_numpy(object) if "fault" in est else None)
        out.passes.append(Pass(truck, k, float(time[dig]), float(time[dump]), t_lock, w, s, pass_status, reason))
    if truth:
        out.matched = _truth_match(out.passes, truth)
        out.true_passes = len(truth)
        out.true_total = float(sum(t["payload"] for t in truth))
    return out


def fault_episodes(sensor_set, time: np.ndarray, faults: np.ndarray) -> list[dict]:
    """The DM1 episodes (:class:`~excavator_payload.runtime.dm1.DM1Transmitter`) of one truck's
    ``faults`` (the estimates' ``signal:kind,...`` column at ``time``), as dicts.

    Parameters
    ----------
    sensor_set : SensorSet
        The estimator's sensor set (the SPNs of its signals).
    time : ndarray
        s, sample times.
    faults : ndarray of str
        The estimates' ``fault`` column (empty or None: no fault).
    """
    from excavator_payload.runtime.dm1 import DM1Transmitter

    dm1 = DM1Transmitter(sensor_set)
    for t, f in zip(time, faults):
        dm1.update(float(t), f or "")
    return [episode_row(e) for e in dm1.episodes]


def episode_row(episode) -> dict:
    """One :class:`~excavator_payload.runtime.dm1.DtcEpisode` as a record row.

    Parameters
    ----------
    episode : DtcEpisode
        A fault as the bus carried it.
    """
    return {"spn": episode.spn, "fmi": episode.fmi, "signal": episode.signal, "kind": episode.kind,
            "start": float(episode.start), "end": float(episode.end)}


def fault_line(fault: dict) -> str:
    """``DM1 SPN 520195 FMI 7 (boom_angle stuck): 12.30-14.10 s`` (end: "to the truck's end").

    Parameters
    ----------
    fault : dict
        A record row of a fault (:func:`episode_row`).
    """
    end = f"-{fault['end']:.2f} s" if math.isfinite(fault["end"]) else " s to the truck's end"
    return (f"DM1 SPN {fault['spn']} FMI {fault['fmi']} ({fault['signal']} {fault['kind']}): "
            f"{fault['start']:.2f}{end}")


def file_key(path: str | Path) -> str:
    """SHA-256 of a file's bytes: the same data, wherever it lies, is the same source.

    Parameters
    ----------
    path : str or Path
        The file to hash.
    """
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def passes_frame(trucks: list[Truck]) -> pd.DataFrame:
    """Every pass of ``trucks`` as a table (the Parquet export).

    Parameters
    ----------
    trucks : list of Truck
        The trucks whose passes are listed.
    """
    rows = [asdict(p) for t in trucks for p in t.passes]
    cols = [f.name for f in Pass.__dataclass_fields__.values()]
    return pd.DataFrame(rows, columns=cols).rename(columns={"index": "pass"})


def truck_table(truck: Truck):
    """A rich table of one truck's passes, with the running total and what is left.

    Parameters
    ----------
    truck : Truck
        The truck shown.
    """
    from rich.table import Table
    from rich.text import Text

    title = f"truck {truck.truck}"
    if truck.target is not None:
        title += f" — target {truck.target:,.0f} kg"
    table = Table(title=title)
    for col in ("pass", "weight kg", "σ kg", "status", "total kg", "left kg"):
        table.add_column(col, justify="right" if col != "status" else "left")
    running = 0.0
    for p in truck.passes:
        running += p.weight or 0.0
        left = "" if truck.target is None else f"{truck.target - running:,.0f}"
        table.add_row(str(p.index), "—" if p.weight is None else f"{p.weight:,.0f}",
                      "—" if p.sigma is None else f"{p.sigma:.1f}",
                      # a reason quotes "[signals.x]": text, not rich markup
                      Text(p.status if not p.reason else f"{p.status}: {p.reason}"), f"{running:,.0f}", left)
    return table


def run_loadout(estimator, dataset, record: ShiftRecord | None, source: str, target: float | None,
                on_truck=None, data_name: str = "", model_name: str = "") -> list[Truck]:
    """Weigh every truck of ``dataset`` and record each as it is done (``on_truck(truck)``
    after each, for a live view). ``target`` (kg) overrides the data's truck targets.

    Parameters
    ----------
    estimator : Estimator
        A fitted estimator.
    dataset : Dataset
        The samples; each experiment is one truck, or several cut at :data:`TRUCK_GAP`.
    record : ShiftRecord or None
        Where each truck is written as it is done; None: nowhere.
    source : str
        SHA-256 of the data file (the record's key).
    target : float or None
        kg, every truck's target; None: the data's ``truck_target`` per experiment.
    on_truck : callable, optional
        Called with each :class:`Truck` once weighed.
    data_name, model_name : str, optional
        The data's and model's names as given, for the record.

    Returns
    -------
    list of Truck
        The trucks, numbered 1, 2, ... in the data's order.
    """
    metas = dataset.experiment_meta
    run = (record.start_run(source, data_name, model_name, getattr(estimator, "rated_payload", None))
           if record is not None else 0)
    trucks: list[Truck] = []
    for rows in split_trucks(dataset.frame):
        meta = metas.get(int(rows["experiment"].iloc[0]), {})
        truck_target = target if target is not None else meta.get("truck_target")
        # trucks numbered 1, 2, … in the order of the data: the same data, the same numbers
        truth = meta.get("passes") if len(split_trucks_of(rows, dataset)) == 1 else None
        truck = weigh_truck(estimator, rows, len(trucks) + 1, truck_target, truth)
        trucks.append(truck)
        if record is not None:
            record.write_truck(source, run, truck)
        if on_truck is not None:
            on_truck(truck)
    if record is not None:
        record.finish_run(run)
    return trucks


def split_trucks_of(rows: pd.DataFrame, dataset) -> list[int]:
    """How many trucks the experiment of ``rows`` was split into (truth only for whole ones).

    Parameters
    ----------
    rows : pandas.DataFrame
        Samples of one experiment (or of part of it).
    dataset : Dataset
        The dataset they come from.
    """
    k = int(rows["experiment"].iloc[0])
    t = dataset.frame.loc[dataset.frame["experiment"] == k, "time"].to_numpy(float)
    return list(range(int(np.sum(np.diff(t) >= TRUCK_GAP)) + 1))


def shift_summary(passes: pd.DataFrame, trucks: pd.DataFrame, rated: float | None = None) -> dict:
    """Counts and, where the record has the truth, errors: passes within 1 % of ``rated`` (kg;
    without it not counted), trucks within 0.5 % of their load. Degraded passes are weighed
    passes (counted in ``degraded`` too).

    Parameters
    ----------
    passes, trucks : pandas.DataFrame
        The record's tables (:func:`read_record`).
    rated : float, optional
        kg, the rated payload (the 1 % pass criterion is left out without it).
    """
    weighed = passes[passes["status"].isin(["ok", DEGRADED])]
    out = {"trucks": int(len(trucks)), "passes": int(len(passes)), "not_weighed": int(len(passes) - len(weighed)),
           "degraded": int((passes["status"] == DEGRADED).sum()), "total": float(trucks["total"].sum())}
    known = weighed.dropna(subset=["true_weight"])
    if len(known):
        err = (known["weight"] - known["true_weight"]).to_numpy(float)
        out["pass_error_rms"] = float(np.sqrt(np.mean(err**2)))
        out["pass_error_max"] = float(np.max(np.abs(err)))
        if rated:
            out["passes_within_1pct"] = float(np.mean(np.abs(err) <= 0.01 * rated))
    tk = trucks.dropna(subset=["true_total"])
    if len(tk):
        terr = (tk["total"] - tk["true_total"]).to_numpy(float)
        out["truck_error_max"] = float(np.max(np.abs(terr)))
        out["trucks_within_half_pct"] = float(np.mean(np.abs(terr) <= 0.005 * tk["true_total"].to_numpy(float)))
    tp = trucks.dropna(subset=["true_passes"])
    if len(tp):
        out["missed"] = int((tp["true_passes"] - tp["matched"]).sum())
        out["extra"] = int((tp["passes"] - tp["matched"]).sum())
    return out


def plot_shift(passes: pd.DataFrame, trucks: pd.DataFrame, rated: float | None = None):
    """The shift at a glance: each truck's passes stacked against its target, and each pass's
    weight — against the truth with the 1 % band where the record has it — with its 2σ.

    Parameters
    ----------
    passes, trucks : pandas.DataFrame
        The record's tables (:func:`read_record`).
    rated : float, optional
        kg, the rated payload: draws the ±1 % band on the errors.

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    fig, (ax_t, ax_p) = plt.subplots(2, 1, figsize=(8, 6.5))
    weighed = passes["status"].isin(["ok", DEGRADED]).to_numpy()
    # trucks: one bar each, its weighed passes stacked; a truck's key is (source, truck)
    keys = list(zip(trucks["source"], trucks["truck"]))
    several = len(set(trucks["source"])) > 1
    labels = [f"{s[:6]}:{n}" if several else str(n) for s, n in keys]
    x = np.arange(len(keys))
    colours = ("#4477aa", "#66ccee")
    for i, (source, truck) in enumerate(keys):
        rows = passes[(passes["source"] == source) & (passes["truck"] == truck)]
        bottom = 0.0
        for j, r in enumerate(rows.itertuples()):
            if r.status not in ("ok", DEGRADED) or not math.isfinite(r.weight):
                continue
            ax_t.bar(i, r.weight, bottom=bottom, width=0.7, color=colours[j % 2], edgecolor="white",
                     hatch="//" if r.status == DEGRADED else None)
            bottom += r.weight
        unweighed = int((~rows["status"].isin(["ok", DEGRADED])).sum())
        if unweighed:
            ax_t.annotate(f"{unweighed} not\nweighed", (i, bottom), ha="center", va="bottom", fontsize=7,
                          color="#cc3311")
    target = trucks["target"].to_numpy(float)
    if np.isfinite(target).any():
        ax_t.scatter(x, target, marker="_", s=400, color="black", zorder=3, label="target")
    true_total = trucks["true_total"].to_numpy(float)
    if np.isfinite(true_total).any():
        ax_t.scatter(x, true_total, marker="o", s=14, color="#ee7733", zorder=4, label="true load")
    ax_t.set_xticks(x, labels, fontsize=7 if len(x) > 20 else None)
    ax_t.set_xlabel("truck")
    ax_t.set_ylabel("load, kg")
    ax_t.set_title(f"{len(keys)} truck{'s' * (len(keys) != 1)}, {int(weighed.sum())} passes weighed of {len(passes)}")
    tops = [v for v in (ax_t.get_ylim()[1], np.nanmax(target, initial=0.0), np.nanmax(true_total, initial=0.0))
            if math.isfinite(v)]
    ax_t.set_ylim(0.0, 1.2 * max(tops))  # room for the legend above the bars
    if ax_t.get_legend_handles_labels()[0]:
        ax_t.legend(loc="upper right", fontsize=8, ncol=2)
    if passes.empty:  # a record whose trucks had no pass yet: say so rather than draw empty axes
        ax_p.text(0.5, 0.5, "no passes in the record", ha="center", va="center", transform=ax_p.transAxes)
        ax_p.set_axis_off()
        fig.tight_layout()
        return fig
    # passes in the record's order
    order = np.arange(1, len(passes) + 1)
    w = passes["weight"].to_numpy(float)
    sig = passes["sigma"].to_numpy(float)
    truth = passes["true_weight"].to_numpy(float)
    known = weighed & np.isfinite(truth) & np.isfinite(w)
    if known.any():
        err = w - truth
        ax_p.errorbar(order[known], err[known], yerr=2 * sig[known], fmt="o", ms=3, color="#4477aa",
                      ecolor="#99bbdd", label="weight − truth, ± 2σ")
        if rated:
            ax_p.axhspan(-0.01 * rated, 0.01 * rated, color="#ccddaa", alpha=0.5, zorder=0,
                         label=f"± 1 % of rated ({0.01 * rated:g} kg)")
        ax_p.axhline(0.0, color="black", lw=0.6)
        ax_p.set_ylabel("error, kg")
    else:
        ok = weighed & np.isfinite(w)
        ax_p.errorbar(order[ok], w[ok], yerr=2 * sig[ok], fmt="o", ms=3, color="#4477aa",
                      ecolor="#99bbdd", label="weight ± 2σ")
        ax_p.set_ylabel("pass weight, kg")
    if (~weighed).any():
        ax_p.scatter(order[~weighed], np.zeros(int((~weighed).sum())), marker="x", color="#cc3311",
                     label="not weighed")
    ax_p.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax_p.set_xlabel("pass (in the record's order)")
    ax_p.legend(loc="best", fontsize=8)
    fig.tight_layout()
    return fig


def write_shift_report(db: str | Path, out: str | Path, rated: float | None = None) -> Path:
    """A shift report from a record: ``shift.md`` (trucks, passes, totals, against the truth
    where recorded) and ``pass_weights.png`` (:func:`plot_shift`). Returns the Markdown.

    Parameters
    ----------
    db : str or Path
        The shift record.
    out : str or Path
        The folder written into (created if missing).
    rated : float, optional
        kg, the rated payload (default: the record's).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    passes, trucks = read_record(db)
    rated = rated if rated is not None else passes.attrs.get("rated")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    s = shift_summary(passes, trucks, rated)
    fig = plot_shift(passes, trucks, rated)
    png = out / "pass_weights.png"
    tmp = out / ".pass_weights.tmp.png"
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    tmp.replace(png)

    def num(v, fmt=",.0f"):
        return "—" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, fmt)

    lines = ["# Shift report", "", f"Record: `{db}`", "",
             f"- trucks: {s['trucks']}",
             f"- passes: {s['passes']} ({s['not_weighed']} not weighed"
             + (f", {s['degraded']} weighed without a faulty sensor, σ widened)" if s["degraded"] else ")"),
             f"- total loaded: {num(s['total'])} kg"]
    if "pass_error_rms" in s:
        lines += [f"- pass weight error against the truth: RMS {s['pass_error_rms']:.1f} kg, "
                  f"largest {s['pass_error_max']:.1f} kg"]
    if "passes_within_1pct" in s:
        lines += [f"- passes within 1 % of rated ({0.01 * rated:g} kg): {100 * s['passes_within_1pct']:.1f} %"]
    if "trucks_within_half_pct" in s:
        lines += [f"- trucks within 0.5 % of their load: {100 * s['trucks_within_half_pct']:.1f} % "
                  f"(largest error {s['truck_error_max']:.1f} kg)"]
    if "missed" in s:
        lines += [f"- true passes missed: {s['missed']}; detected passes that match no true one "
                  f"(doubled or spurious): {s['extra']}"]
    lines += ["", "![pass weights](pass_weights.png)", "", "## Trucks", "",
              "| source | truck | passes | not weighed | total kg | target kg | true kg |",
              "|---|---:|---:|---:|---:|---:|---:|"]
    for r in trucks.itertuples():
        lines.append(f"| {r.source[:8]} | {r.truck} | {r.passes} | {r.unweighed} | {num(r.total)} | "
                     f"{num(r.target)} | {num(r.true_total)} |")
    lines += ["", "## Passes", "", "| source | truck | pass | locked at s | weight kg | σ kg | status | true kg |",
              "|---|---:|---:|---:|---:|---:|---|---:|"]
    for r in passes.rename(columns={"pass": "n"}).itertuples():
        status = r.status if not r.reason else f"{r.status}: {r.reason}"
        lines.append(f"| {r.source[:8]} | {r.truck} | {r.n} | {num(r.time_lock, '.2f')} | {num(r.weight)} | "
                     f"{num(r.sigma, '.1f')} | {status} | {num(r.true_weight)} |")
    faults = passes.attrs.get("faults") or []
    if faults:
        lines += ["", "## Sensor faults (J1939 DM1)", "",
                  "| source | truck | SPN | FMI | signal | fault | from s | to s |",
                  "|---|---:|---:|---:|---|---|---:|---:|"]
        for r in faults:
            end = r["end"]
            until = "the truck's end" if end is None or end != end else num(end, ".2f")
            lines.append(f"| {r['source'][:8]} | {r['truck']} | {r['spn']} | {r['fmi']} | {r['signal']} | "
                         f"{r['kind']} | {num(r['start'], '.2f')} | {until} |")
    md = out / "shift.md"
    tmp = out / ".shift.md.tmp"
    tmp.write_text("\n".join(lines) + "\n", encoding="utf-8")
    tmp.replace(md)
    return md
