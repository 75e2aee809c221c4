"""Validation of a sample table (a dataset's or a field log's): columns, types, grouping, the
sample rate, and the units (:mod:`excavator_payload.data.units`)."""

from __future__ import annotations

import difflib

import numpy as np
import pandas as pd

from excavator_payload.data.schema import SENSOR_SETS, SensorSet, detect_sensor_set, get_sensor_set
from excavator_payload.data.units import _check_rates, check_signal_units
from excavator_payload.errors import DatasetError
from excavator_payload.model.machine import MAX_PAYLOAD


def _sensor_set_of(frame: pd.DataFrame, meta: dict, source: str) -> SensorSet:
    """The sensor set a file declares, or the one its columns match (files written by others)."""
    if meta.get("sensor_set") is not None:
        return get_sensor_set(meta["sensor_set"])
    found = detect_sensor_set(frame.columns)
    if found is None:
        hint = (" (this looks like an estimates file, not a dataset)"
                if "payload_estimate" in frame.columns else "")
        closest = max(SENSOR_SETS.values(), key=lambda s: len(set(s.signals) & set(frame.columns)))
        missing = [c for c in closest.columns if c != "payload" and c not in frame.columns]
        unknown = [str(c) for c in frame.columns if c not in closest.columns]
        raise DatasetError(f"{source}: missing column(s) {', '.join(missing)} of the "
                           f"{closest.name} sensor set{hint}{_misspelt(missing, unknown)}")
    return found


def validate_frame(frame: pd.DataFrame, source: str = "dataset",
                   sensor_set: SensorSet | str | None = None) -> None:
    """Check columns, types, units (plausible magnitudes) and values of a sample table.

    ``payload`` may be absent (a field log); where present it must be a finite, non-negative
    mass, constant within each experiment.

    Parameters
    ----------
    frame : pandas.DataFrame
        The sample table (``experiment``, ``time``, signals, optional ``payload`` and truth columns).
    source : str, default "dataset"
        Where the table came from (a file name), the start of every error message.
    sensor_set : SensorSet or str, optional
        Its sensor set or the set's name; None: detected from the columns.

    Raises
    ------
    DatasetError
        One line saying what is wrong.
    """
    sensors = (get_sensor_set(sensor_set) if sensor_set is not None
               else _sensor_set_of(frame, {}, source))
    required = [c for c in sensors.columns if c != "payload"]
    missing = [c for c in required if c not in frame.columns]
    unknown = [str(c) for c in frame.columns
               if c not in sensors.columns and c not in sensors.truth_columns]
    if missing:
        hint = ""
        if "payload_estimate" in frame.columns:
            hint = " (this looks like an estimates file, not a dataset)"
        raise DatasetError(f"{source}: missing column(s) {', '.join(missing)}{hint}{_misspelt(missing, unknown)}")
    if "payload" not in frame.columns:
        # a misspelt payload column made a calibration file a field log without a word
        close = difflib.get_close_matches("payload", [u.lower() for u in unknown], n=1, cutoff=0.8)
        if close:
            name = next(u for u in unknown if u.lower() == close[0])
            raise DatasetError(f"{source}: column '{name}' looks like 'payload' misspelt; rename it "
                               "(a field log has no payload column at all)")
    if len(frame) == 0:
        raise DatasetError(f"{source}: has no rows")
    has_payload = "payload" in frame.columns
    for c in required + (["payload"] if has_payload else []):
        if not pd.api.types.is_numeric_dtype(frame[c]) or pd.api.types.is_bool_dtype(frame[c]):
            raise DatasetError(f"{source}: column '{c}' must be numeric, found {frame[c].dtype}"
                               + (" (true/false, not a measurement)" if pd.api.types.is_bool_dtype(frame[c]) else ""))
    exp = frame["experiment"].to_numpy()
    if not np.all(np.isfinite(exp)) or not np.all(exp == np.round(exp)):
        raise DatasetError(f"{source}: column 'experiment' must hold whole numbers")
    for c in ("time", "payload") if has_payload else ("time",):
        if not np.all(np.isfinite(frame[c].to_numpy(dtype=float))):
            raise DatasetError(f"{source}: column '{c}' has NaN or infinite values")
    if has_payload and (frame["payload"] < 0).any():
        raise DatasetError(f"{source}: column 'payload' has negative masses (kg)")
    if has_payload and (frame["payload"] > MAX_PAYLOAD).any():
        raise DatasetError(f"{source}: column 'payload' reaches {frame['payload'].max():.4g} kg, more "
                           f"than any excavator lifts ({MAX_PAYLOAD:g} kg)")
    # Every experiment's rows must be one block: estimators reset where the number changes.
    changes = int(np.count_nonzero(exp[1:] != exp[:-1])) + 1
    if changes != len(pd.unique(exp)):
        raise DatasetError(f"{source}: rows are not grouped by experiment (an experiment's samples "
                           "are split by another's); sort by experiment, then time")
    check_signal_units(frame, sensors, source, rates=False)
    grouped = frame.groupby("experiment", sort=False)
    times = grouped["time"]
    if not (times.apply(lambda t: bool(np.all(np.diff(t.to_numpy()) > 0)))).all():
        raise DatasetError(f"{source}: 'time' must increase strictly within each experiment"
                           + _where_time_goes_back(frame))
    # Time in milliseconds, or data of another rate labelled as this sensor set, would pass
    # every column check and give every sample a "gap" (or wrong physics): check the rate.
    same = exp[1:] == exp[:-1]
    steps = np.diff(frame["time"].to_numpy(dtype=float))[same]
    if steps.size:
        period = float(np.median(steps))
        if not 0.8 * sensors.sample_period <= period <= 1.25 * sensors.sample_period:
            raise DatasetError(f"{source}: samples are {period:.4g} s apart, but the {sensors.name} "
                               f"sensor set samples at {sensors.sample_rate:g} Hz "
                               f"({sensors.sample_period:g} s); is 'time' in seconds?")
        _check_experiment_periods(exp[1:][same], steps, sensors, source)
    if has_payload and (grouped["payload"].nunique() > 1).any():
        raise DatasetError(f"{source}: 'payload' must be constant within an experiment")
    _check_rates(frame, sensors, source)


def _where_time_goes_back(frame: pd.DataFrame) -> str:
    """``"; in experiment 3 it goes from 7.2 s back to 0 s (row 812): …"`` for the first step of
    ``time`` that does not increase within an experiment (a time back at the experiment's start
    is two recordings under one number)."""
    exp = frame["experiment"].to_numpy()
    t = frame["time"].to_numpy(dtype=float)
    same = exp[1:] == exp[:-1]
    bad = np.flatnonzero(same & (np.diff(t) <= 0))
    if not bad.size:
        return ""
    i = int(bad[0])
    first = t[np.flatnonzero(exp == exp[i])[0]]
    what = "repeats" if t[i + 1] == t[i] else f"goes from {t[i]:.6g} s back to {t[i + 1]:.6g} s"
    if t[i + 1] <= first + 0.5 * (t[i] - first):
        hint = ": two recordings under one experiment number? Number each its own"
    elif t[i + 1] == t[i]:
        hint = ": a sample logged twice? Drop the repeated rows"
    else:
        hint = ": rows out of order? Sort by experiment, then time"
    return f"; in experiment {exp[i]:g} (row {i + 1}, counted from 0) it {what}{hint}"


#: An experiment with fewer sample intervals than this is not judged on its own interval (too
#: short to weigh anyway; a logger's jitter could tip a median of two).
PERIOD_MIN_STEPS = 10


def _check_experiment_periods(owner: np.ndarray, steps: np.ndarray, sensors: SensorSet,
                              source: str) -> None:
    """Each experiment's median sample interval at the sensor set's period (±20 %), not only the
    file's: one experiment resampled to another rate, or its time in milliseconds, passed the
    file-wide check and was read as samples with a gap between every two (no estimate, no word)."""
    period = sensors.sample_period
    order = np.argsort(owner, kind="stable")
    ids, starts = np.unique(owner[order], return_index=True)
    bad = []
    for k, chunk in zip(ids, np.split(steps[order], starts[1:])):
        if chunk.size >= PERIOD_MIN_STEPS:
            median = float(np.median(chunk))
            if not 0.8 * period <= median <= 1.25 * period:
                bad.append((k, median))
    if bad:
        k, median = bad[0]
        ratio = median / period
        why = ("is its 'time' in milliseconds?" if 300.0 <= ratio <= 3000.0
               else f"it is sampled at {1.0 / median:.4g} Hz: resample it to {sensors.sample_rate:g} Hz "
                    "(or record it at that rate)")
        more = f"; {len(bad)} experiments alike" if len(bad) > 1 else ""
        raise DatasetError(f"{source}: experiment {int(k)}: samples are {median:.4g} s apart (median), "
                           f"but the {sensors.name} sensor set samples at {sensors.sample_rate:g} Hz "
                           f"({period:g} s) as the other experiments do; {why}{more}")


def _misspelt(missing: list[str], unknown: list[str]) -> str:
    """``"; found 'house_pich' (misspelt 'house_pitch'?)"`` for the unknown columns close to missing ones."""
    pairs = []
    for c in missing:
        close = difflib.get_close_matches(c, unknown, n=1, cutoff=0.75)
        if close:
            pairs.append(f"'{close[0]}' (misspelt '{c}'?)")
    return f"; found {', '.join(pairs)}" if pairs else ""
