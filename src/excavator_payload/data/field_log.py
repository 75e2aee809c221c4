"""Field logs as tables: a CSV or Parquet of signals from a logger, without an ``experiment`` column.

A logger (or a CAN log decoded to a table elsewhere) writes one continuous table: a ``time``
column in seconds (or ``timestamp``) and the sensor set's signal columns in SI units, no
``experiment``. It is read the way ``can-replay`` reads a CAN log:

* a silence longer than :data:`SEGMENT_GAP` seconds (no row with a signal) ends a recording:
  the next rows are the next experiment, their ``time`` counted from its first sample;
* a table whose signals come at their own rates (rows where only some signals are filled, the
  others empty, as loggers write one message per row) or at another rate than the sensor set's
  is put on the model's clock by the CAN sensor's
  :class:`~excavator_payload.data.assembly.SampleAssembler` (each column, or group of columns
  filled together, is a message: latest value held, too old -> NaN). A table already at the
  sensor set's rate with every signal in every row is taken as it is.

A CSV *with* an ``experiment`` column is read as a dataset table. The result is validated as
any dataset (units, rates, ranges) by :func:`~excavator_payload.data.validation.validate_frame`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.schema import SENSOR_SETS, detect_sensor_set
from excavator_payload.errors import DatasetError

#: Silence (s) that separates two recordings (as ``can-replay``'s default).
SEGMENT_GAP = 2.0
TIME_COLUMNS = ("time", "timestamp")
TABLE_SUFFIXES = (".csv", ".parquet", ".pq")


def is_field_table(path: str | Path) -> bool:
    """Whether ``path`` is a field log table: a CSV, or a Parquet file with a time column and no
    ``experiment`` column (a dataset written by this package always has one).

    Parameters
    ----------
    path : str or pathlib.Path
        The file to look at.
    """
    path = Path(path)
    if not path.is_file():
        return False
    suffix = path.suffix.lower()
    if suffix == ".csv":
        return True
    if suffix not in (".parquet", ".pq"):
        return False
    try:
        import pyarrow.parquet as pq

        names = pq.read_schema(path).names
    except Exception:  # not Parquet: the dataset reader says so
        return False
    return "experiment" not in names and any(c in names for c in TIME_COLUMNS)


def _csv_dialect(path: Path) -> dict:
    """``pandas.read_csv`` arguments for the file's separator: ``;`` (with decimal commas, as a
    spreadsheet in a German or French locale saves "CSV") or a tab, when its header holds no
    comma; else the default. Read as one column, such a file was "missing" every signal."""
    with open(path, encoding="utf-8-sig", errors="replace") as f:
        header, first = f.readline(), f.readline()
    if "," in header:
        return {}
    sep = max((";", "\t"), key=header.count)
    if not header.count(sep):
        return {}
    return {"sep": sep, "decimal": "," if "," in first else "."}


def _read_table(path: Path) -> pd.DataFrame:
    try:
        if path.suffix.lower() == ".csv":
            return pd.read_csv(path, **_csv_dialect(path))
        return pd.read_parquet(path)
    except (ValueError, OSError, UnicodeDecodeError, pd.errors.ParserError) as exc:
        raise DatasetError(f"'{path}' could not be read as a table: {str(exc).splitlines()[0]}") from None


def read_field_table(path: str | Path, *, validate: bool = True, segment_gap: float = SEGMENT_GAP) -> Dataset:
    """A field log table as a :class:`Dataset` (see the module docstring).

    Parameters
    ----------
    path : str or pathlib.Path
        The CSV or Parquet log: a time column (s) and the signals of a sensor set.
    validate : bool, default True
        Validate the resulting frame against the sensor set's schema.
    segment_gap : float, default 2.0
        Silence, s, that separates two recordings (each becomes one experiment).

    Returns
    -------
    Dataset
        One experiment per recording, on the sensor set's sample clock.
    """
    from excavator_payload.data.validation import validate_frame

    path = Path(path)
    frame = _read_table(path)
    sensors = detect_sensor_set(frame.columns)
    if sensors is None:
        closest = max(SENSOR_SETS.values(), key=lambda s: len(set(s.signals) & set(frame.columns)))
        missing = [c for c in closest.signals if c not in frame.columns]
        raise DatasetError(f"{path}: a table of signals needs the columns of a sensor set; missing "
                           f"{', '.join(missing)} of the {closest.name} set")
    if "experiment" in frame.columns:  # a dataset as CSV
        if validate:
            validate_frame(frame, source=str(path), sensor_set=sensors)
        return Dataset(frame.reset_index(drop=True), {"sensor_set": sensors.name}, source=path)
    time_column = next((c for c in TIME_COLUMNS if c in frame.columns), None)
    if time_column is None:
        raise DatasetError(f"{path}: a field log needs a 'time' column (s), or 'experiment' and 'time' "
                           "columns of a dataset")
    signals = list(sensors.signals)
    extra = [c for c in ("payload",) if c in frame.columns]
    for c in [time_column, *signals, *extra]:
        if not pd.api.types.is_numeric_dtype(frame[c]) or pd.api.types.is_bool_dtype(frame[c]):
            raise DatasetError(f"{path}: column '{c}' must be numeric, found {frame[c].dtype}"
                               + (" (true/false, not a measurement)" if pd.api.types.is_bool_dtype(frame[c]) else ""))
    times = frame[time_column].to_numpy(dtype=float)
    values = frame[signals + extra].to_numpy(dtype=float)
    keep = np.isfinite(times) & np.isfinite(values[:, :len(signals)]).any(axis=1)
    times, values = times[keep], values[keep]
    if times.size == 0:
        raise DatasetError(f"{path}: no row has a time and a signal")
    back = int(np.count_nonzero(np.diff(times) < 0))
    if back:
        raise DatasetError(f"{path}: '{time_column}' goes back {back} time(s); sort the log by time")
    cuts = np.flatnonzero(np.diff(times) > segment_gap) + 1
    bounds = np.r_[0, cuts, times.size]
    period = sensors.sample_period
    steps = np.diff(times)
    steps = steps[steps <= segment_gap]
    lock_step = (np.isfinite(values[:, :len(signals)]).all()
                 and (steps.size == 0 or 0.8 * period <= float(np.median(steps)) <= 1.25 * period))
    parts = []
    for k, (a, b) in enumerate(zip(bounds[:-1], bounds[1:])):
        if lock_step:
            t, v = times[a:b] - times[a], values[a:b]
        else:
            t, v = _on_the_clock(times[a:b], values[a:b], period, [*signals, *extra])
        part = pd.DataFrame(v, columns=signals + extra)
        part.insert(0, "time", t)
        part.insert(0, "experiment", k)
        parts.append(part)
    out = pd.concat(parts, ignore_index=True)
    if "payload" in out.columns and out["payload"].isna().any():
        out = out.drop(columns="payload")  # a truth column not on every sample is no truth
    if validate:
        validate_frame(out, source=str(path), sensor_set=sensors)
    meta = {"sensor_set": sensors.name, "source": "field log", "segment_gap": segment_gap}
    return Dataset(out, meta, source=path)


def _on_the_clock(times: np.ndarray, values: np.ndarray, period: float,
                  names: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """One recording's rows on the model's clock: columns filled together are one message."""
    from excavator_payload.data.assembly import SampleAssembler

    filled = np.isfinite(values)
    groups: dict[bytes, list[int]] = {}
    for i in range(values.shape[1]):
        groups.setdefault(filled[:, i].tobytes(), []).append(i)
    messages = {f"m{n}": idx for n, idx in enumerate(groups.values())}
    assembler = SampleAssembler(names, period, messages)
    samples = []
    for r in range(times.size):
        for name, idx in messages.items():
            if filled[r, idx[0]]:
                samples += assembler.add(name, float(times[r]), [(i, values[r, i]) for i in idx])
    samples += assembler.flush()
    if not samples:
        return np.empty(0), np.empty((0, values.shape[1]))
    t = np.array([s.time for s in samples]) - samples[0].time
    return t, np.vstack([s.values for s in samples])
