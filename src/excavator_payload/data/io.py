"""Reading and writing datasets as Parquet, with validation.

Layout: one Parquet file, one row per sample with the columns of
:data:`~excavator_payload.data.schema.COLUMNS` (SI units), and the file-level and
per-experiment metadata as JSON in the Parquet schema metadata under the key
``excavator_payload`` (readable with ``pyarrow.parquet.read_schema(path).metadata``).
Writes are atomic: a temporary file in the same folder is renamed over the target.
"""

from __future__ import annotations

import difflib
import json
import math
import os
import tempfile
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.schema import (
    ESTIMATE_COLUMNS,
    FORMAT_VERSION,
    METADATA_KEY,
    SENSOR_SETS,
    SensorSet,
    detect_sensor_set,
    get_sensor_set,
)
from excavator_payload.errors import DatasetError
from excavator_payload.model.machine import MAX_PAYLOAD


#: A pressure column whose largest value stays below this (Pa, 1 bar) is not in Pa.
MIN_PEAK_PRESSURE = 1.0e5

#: Largest house pitch or roll of a working machine, rad: 35° (70 %, the gradeability of a tracked
#: excavator, far beyond its working limits). Tighter than the sensor set's 1 rad (which also
#: spans the DBC's range): a tilt in degrees reads as that many radians.
HOUSE_TILT_LIMIT = math.radians(35.0)

#: Each rate is checked against the change of the signal it is the rate of (the change over a
#: window vs the rate's integral over it): (signal, its rate, unit of the rate, least change of
#: the signal over a window for the window to be judged, in the signal's unit).
RATE_PAIRS: dict[str, tuple[tuple[str, str, str, float], ...]] = {
    "machine": (("boom_angle", "boom_rate", "rad/s", 0.02), ("dipper_angle", "dipper_rate", "rad/s", 0.02),
                ("bucket_angle", "bucket_rate", "rad/s", 0.02)),
    "thesis": (("boom_angle", "boom_rate", "rad/s", 0.02), ("dipper_angle", "dipper_rate", "rad/s", 0.02),
               ("boom_rate", "boom_accel", "rad/s^2", 0.05), ("dipper_rate", "dipper_accel", "rad/s^2", 0.05)),
}
#: Length of the windows the rate check compares over, s.
RATE_WINDOW = 0.5
#: Moving windows an experiment needs to be judged by the rate check.
RATE_MIN_WINDOWS = 2
#: A rate whose integral is more than this times its signal's change (median over the moving
#: windows) is in degrees: 180/π = 57.3 ≫ √57.3 ≈ 7.6 ≫ 1 (the geometric middle).
RATE_RATIO_LIMIT = math.sqrt(180.0 / math.pi)


def check_output_path(path: str | Path, *, inputs: Sequence[str | Path] = (), kind: str = "file",
                      option: str = "--out", replaces: Sequence[str] = ()) -> Path:
    """Refuse, before any work is done, an output path that cannot be written or would destroy data.

    Parameters
    ----------
    path : output file or folder.
    inputs : files and folders the command reads: the output must be none of them, nor inside
        an input folder, nor contain an input.
    kind : ``"file"`` (must not be an existing folder) or ``"folder"`` (must not be a file).
    option : the option's name, for the message.
    replaces : for a folder, the names inside it the command overwrites or deletes (an input
        there is refused too).

    Raises
    ------
    DatasetError
        With one line saying what is wrong.
    """
    path = Path(path)
    if str(path).strip() == "":
        raise DatasetError(f"{option}: give a path")
    target = path.resolve()
    for raw in inputs:
        if raw is None:
            continue
        source = Path(raw).resolve()
        same = target == source or (path.exists() and Path(raw).exists() and os.path.samefile(path, raw))
        inside_replaced = any(source == target / name or (target / name) in source.parents
                              for name in replaces)
        if same or source in target.parents or inside_replaced:
            raise DatasetError(f"{option} '{path}' is (or overlaps) the input '{raw}': refusing to "
                               "overwrite it; choose another path")
    if kind == "file" and path.is_dir():
        raise DatasetError(f"{option} '{path}' is a folder; give a file name")
    if kind == "folder" and path.exists() and not path.is_dir():
        raise DatasetError(f"{option} '{path}' is a file; give a folder")
    # The nearest existing ancestor must be a writable folder (checked now, not after training).
    parent = target if kind == "folder" else target.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise DatasetError(f"{option} '{path}': '{parent}' is a file, not a folder")
    if not os.access(parent, os.W_OK | os.X_OK) or (path.exists() and not os.access(path, os.W_OK)):
        raise DatasetError(f"{option} '{path}': no permission to write there")
    return path


def new_file_mode() -> int:
    """The mode a newly created file gets under this process's umask (0o644 under 022).

    Read from ``/proc/self/status`` where Linux has it: setting the umask to read it back (the
    portable way) races with any other thread writing a file at that moment, which then gets
    0o666."""
    try:
        with open("/proc/self/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("Umask:"):
                    return 0o666 & ~int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    umask = os.umask(0o022)
    os.umask(umask)
    return 0o666 & ~umask


def atomic_write_table(table: pa.Table, path: str | Path) -> None:
    """Write a Parquet table atomically (temporary file + rename): never a half-written file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        pq.write_table(table, tmp, compression="zstd")
        os.chmod(tmp, new_file_mode())  # mkstemp makes 0600; a data file is as readable as any other
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_dataset(dataset: Dataset, path: str | Path) -> None:
    """Validate and write ``dataset`` to ``path`` (Parquet, atomic)."""
    sensors = dataset.sensor_set
    validate_frame(dataset.frame, source="dataset to write", sensor_set=sensors)
    cols = [c for c in sensors.columns if c in dataset.frame.columns]
    cols += [c for c in sensors.truth_columns if c in dataset.frame.columns]
    frame = dataset.frame[cols].copy()
    frame["experiment"] = frame["experiment"].astype("int64")
    table = pa.Table.from_pandas(frame, preserve_index=False)
    meta = dict(dataset.meta)
    meta.setdefault("format_version", FORMAT_VERSION)
    meta["sensor_set"] = sensors.name
    meta["units"] = {c: sensors.unit(c) for c in cols}
    table = table.replace_schema_metadata({**(table.schema.metadata or {}),
                                           METADATA_KEY: json.dumps(meta).encode()})
    atomic_write_table(table, path)


def read_metadata(path: str | Path) -> dict:
    """The excavator_payload metadata of a Parquet file (empty dict if it has none)."""
    schema = _read_schema(Path(path))
    raw = (schema.metadata or {}).get(METADATA_KEY)
    if raw is None:
        return {}
    try:
        return json.loads(raw)
    except json.JSONDecodeError:
        raise DatasetError(f"{path}: its excavator_payload metadata is not valid JSON") from None


def _read_schema(path: Path) -> pa.Schema:
    if not path.exists():
        raise DatasetError(f"dataset file '{path}' does not exist")
    if path.is_dir():
        raise DatasetError(f"'{path}' is a folder, not a Parquet dataset file")
    try:
        return pq.read_schema(path)
    except (pa.ArrowInvalid, OSError) as exc:
        raise DatasetError(f"'{path}' is not a readable Parquet file (truncated or another format?): {exc}") from None


def read_dataset(path: str | Path, *, validate: bool = True, machine=None) -> Dataset:
    """Read and validate a dataset written by ``excavator-payload simulate`` (or by you).

    A dataset of the machine sensor set is also checked against the arm's balance for swapped
    head and rod pressures (:func:`excavator_payload.data.wiring.check_wiring`) with ``machine``
    (the machine the reading model believes in: a machine, preset name or file) or else the
    machine in the file's metadata.

    Raises
    ------
    DatasetError
        If the file is missing, not Parquet, truncated, or violates the schema, with a
        message that says what is wrong.
    """
    path = Path(path)
    from excavator_payload.data.field_log import is_field_table, read_field_table  # issue 30

    if is_field_table(path):  # a logger's CSV / Parquet without experiments: split at gaps
        return read_field_table(path, validate=validate)
    meta = read_metadata(path)
    _check_metadata(meta, str(path))
    try:
        frame = pq.read_table(path).to_pandas()
    except (pa.ArrowInvalid, OSError) as exc:
        raise DatasetError(f"'{path}' could not be read (truncated or corrupt?): {exc}") from None
    sensors = _sensor_set_of(frame, meta, str(path))
    if validate:
        validate_frame(frame, source=str(path), sensor_set=sensors)
    meta = {**meta, "sensor_set": sensors.name}
    dataset = Dataset(frame.reset_index(drop=True), meta, source=path)
    if validate and sensors.name == "machine":
        from excavator_payload.data.wiring import check_wiring
        from excavator_payload.model.machine import load_machine

        believed = load_machine(machine) if machine is not None else dataset.machine()
        check_wiring(dataset.frame, sensors, believed, str(path))
    return dataset


def _check_metadata(meta: dict, source: str) -> None:
    """The shape of the metadata the commands read (an edited file crashed train and evaluate:
    a 'machine' that was a string, 'experiments' that were not a list of tables)."""
    if not isinstance(meta, dict):
        raise DatasetError(f"{source}: its excavator_payload metadata must be a JSON object")
    if meta.get("machine") is not None and not isinstance(meta["machine"], dict):
        raise DatasetError(f"{source}: metadata 'machine' must be the machine's tables (a JSON object), "
                           f"got {type(meta['machine']).__name__}")
    experiments = meta.get("experiments")

    def numbered(e) -> bool:
        if not isinstance(e, dict) or isinstance(e.get("experiment"), bool):
            return False
        try:
            int(e["experiment"])  # as Dataset.experiment_meta reads it
        except (KeyError, TypeError, ValueError, OverflowError):
            return False
        return True

    if experiments is not None and not (isinstance(experiments, list) and all(map(numbered, experiments))):
        raise DatasetError(f"{source}: metadata 'experiments' must be a list of objects, each with its "
                           "'experiment' number")
    for key in ("noise", "sensor_set", "motion"):
        if meta.get(key) is not None and not isinstance(meta[key], str):
            raise DatasetError(f"{source}: metadata '{key}' must be a name (a string), got {meta[key]!r}")


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
        if not pd.api.types.is_numeric_dtype(frame[c]):
            raise DatasetError(f"{source}: column '{c}' must be numeric, found {frame[c].dtype}")
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
        raise DatasetError(f"{source}: 'time' must increase strictly within each experiment")
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
    if has_payload and (grouped["payload"].nunique() > 1).any():
        raise DatasetError(f"{source}: 'payload' must be constant within an experiment")
    _check_rates(frame, sensors, source)


def _misspelt(missing: list[str], unknown: list[str]) -> str:
    """``"; found 'house_pich' (misspelt 'house_pitch'?)"`` for the unknown columns close to missing ones."""
    pairs = []
    for c in missing:
        close = difflib.get_close_matches(c, unknown, n=1, cutoff=0.75)
        if close:
            pairs.append(f"'{close[0]}' (misspelt '{c}'?)")
    return f"; found {', '.join(pairs)}" if pairs else ""


def check_signal_units(frame: pd.DataFrame, sensors: SensorSet, source: str, rates: bool = True) -> None:
    """The unit checks of :func:`validate_frame` on a sample table (``experiment``, ``time`` and
    the signals): magnitudes, house tilt and boom angle in radians, every experiment's pressures
    and torques against the others' (:func:`excavator_payload.data.units.check_experiment_units`),
    pressures in Pa, and (``rates``) rates against their angles. Also run on the samples decoded
    from a CAN log (:class:`excavator_payload.data.units.SampleWatch`).
    """
    from excavator_payload.data.units import check_experiment_units

    for c in sensors.signals:
        values = np.abs(frame[c].to_numpy(dtype=float))
        values = np.where(np.isfinite(values), values, np.nan)
        if np.any(values > sensors.plausible_abs[c]):
            top = int(np.nanargmax(values))
            unit = sensors.units[c]
            # a pressure of 5e8 Pa was asked whether it was in degrees
            hint = ("are the units degrees instead of SI?" if unit.startswith("rad")
                    else f"a glitch, or not in {unit}?")
            raise DatasetError(
                f"{source}: column '{c}' reaches {values[top]:.4g} (experiment "
                f"{frame['experiment'].iloc[top]:.0f}), implausible in {unit} ({hint}); "
                f"the sensor set allows ±{sensors.plausible_abs[c]:g} {unit}"
            )
    # A house tilt in degrees passes the 1 rad limit up to 1°: 0.8° read as 46° weighed ~200 kg off.
    for c in ("house_pitch", "house_roll"):
        if c not in sensors.signals:
            continue
        values = np.abs(frame[c].to_numpy(dtype=float))
        values = values[np.isfinite(values)]
        if values.size and values.max() > HOUSE_TILT_LIMIT:
            raise DatasetError(f"{source}: column '{c}' reaches {values.max():.4g}, implausible in rad "
                               f"(more than 35° of tilt; are the units degrees instead of radians?)")
    # One experiment (or one signal of it) in another unit among others in SI passes the file-wide
    # checks (-8960 kg 'ok'): each experiment is judged against the others.
    check_experiment_units(frame, sensors, source)
    # Pressures in bar, kPa, MPa or psi pass the magnitude check above and were weighed as Pa
    # without a word (-6200 kg 'ok' for a 1900 kg payload): the boom cylinder of a working arm
    # holds the arm's weight, tens of bar, and no cylinder line stays below 1 bar for a whole file.
    for c in sensors.signals:
        if sensors.units[c] != "Pa":
            continue
        values = np.abs(frame[c].to_numpy(dtype=float))
        values = values[np.isfinite(values)]
        if values.size and values.max() < MIN_PEAK_PRESSURE:
            raise DatasetError(f"{source}: column '{c}' never exceeds {values.max():.4g} Pa (1 bar = "
                               f"1e5 Pa); are the pressures in bar, kPa, MPa or psi instead of Pa?")
    # Angles in degrees are the most likely unit mistake: a boom never swings ±3 rad.
    for c in ("boom_angle",):
        values = np.abs(frame[c].to_numpy(dtype=float))
        values = values[np.isfinite(values)]  # a NaN or inf is a bad sample, not a unit
        if values.size and values.max() > 2 * np.pi:
            raise DatasetError(f"{source}: column '{c}' exceeds 2π; angles must be in radians")
    if rates:
        _check_rates(frame, sensors, source)


def _rate_ratios(frame: pd.DataFrame, signal: str, rate: str, period: float,
                 min_change: float) -> tuple[pd.Series, float]:
    """How many times its signal's change each rate's integral is, per experiment.

    Each experiment is cut into windows of :data:`RATE_WINDOW`; over a window where the signal
    changes by more than ``min_change`` (a moving one) and which has no NaN and no time gap,
    the ratio is (integral of the rate, trapezoidal) / (last - first value of the signal): 1 if
    both are in the same unit, whatever the noise, offsets or an IMU lag (both lag alike).
    Returns the median ratio of every experiment with :data:`RATE_MIN_WINDOWS` moving windows
    or more, and the median of all moving windows of the file (NaN if fewer): a still
    experiment cannot be judged and is not.
    """
    width = max(2, int(round(RATE_WINDOW / period)))
    codes = pd.factorize(frame["experiment"].to_numpy())[0]
    t = frame["time"].to_numpy(dtype=float)
    x = frame[signal].to_numpy(dtype=float)
    r = frame[rate].to_numpy(dtype=float)
    window = pd.Series(codes).groupby(codes).cumcount().to_numpy() // width
    first = np.ones(len(t), dtype=bool)
    first[1:] = (codes[1:] != codes[:-1]) | (window[1:] != window[:-1])
    step = np.zeros(len(t))
    step[1:] = np.diff(t)
    increment = np.zeros(len(t))
    increment[1:] = 0.5 * (r[1:] + r[:-1]) * step[1:]
    increment[first] = 0.0
    bad = ~np.isfinite(x) | ~np.isfinite(r) | (~first & ((step > 2.5 * period) | ~np.isfinite(increment)))
    windows = pd.DataFrame({"e": codes, "w": window, "i": np.where(bad, 0.0, increment), "x": x,
                            "bad": bad}).groupby(["e", "w"], sort=False).agg(
        integral=("i", "sum"), x0=("x", "first"), x1=("x", "last"), bad=("bad", "any"), n=("x", "size"))
    change = windows["x1"] - windows["x0"]
    moving = ~windows["bad"] & (windows["n"] >= 2) & (change.abs() > min_change)
    ratio = (windows["integral"] / change)[moving]
    by_experiment = ratio.groupby(level="e")
    judged = by_experiment.median()[by_experiment.size() >= RATE_MIN_WINDOWS]
    judged.index = pd.unique(frame["experiment"].to_numpy())[judged.index.to_numpy()]
    pooled = float(ratio.median()) if ratio.size >= RATE_MIN_WINDOWS else math.nan
    return judged, pooled


def _check_rates(frame: pd.DataFrame, sensors: SensorSet, source: str) -> None:
    """Refuse a rate in degrees (°/s, °/s²) whose signal is in radians.

    Rates in °/s pass every magnitude check (an arm turns at < 3 rad/s, 170 °/s) and were
    weighed as rad/s without a word (-3700 kg 'ok' for a 1890 kg payload).
    """
    for signal, rate, unit, min_change in RATE_PAIRS.get(sensors.name, ()):
        judged, pooled = _rate_ratios(frame, signal, rate, sensors.sample_period, min_change)
        worst = judged[judged.abs() > RATE_RATIO_LIMIT]
        where = f" (experiment {worst.index[0]})" if len(worst) else ""
        ratio = float(worst.iloc[0]) if len(worst) else pooled
        if np.isfinite(ratio) and abs(ratio) > RATE_RATIO_LIMIT:
            degrees = unit.replace("rad", "°")
            raise DatasetError(f"{source}: column '{rate}' is {ratio:.3g} times the rate of change of "
                               f"'{signal}'{where}; is it in {degrees} instead of {unit}?")


def read_estimates(path: str | Path) -> pd.DataFrame:
    """Read an estimates file (``experiment``, ``time``, ``payload_estimate``, optional ``status``)."""
    path = Path(path)
    _read_schema(path)
    try:
        frame = pq.read_table(path).to_pandas()
    except (pa.ArrowInvalid, OSError) as exc:
        raise DatasetError(f"'{path}' could not be read (truncated or corrupt?): {exc}") from None
    missing = [c for c in ESTIMATE_COLUMNS if c not in frame.columns]
    if missing:
        raise DatasetError(f"{path}: not an estimates file, missing column(s) {', '.join(missing)}")
    return frame


def write_estimates(frame: pd.DataFrame, path: str | Path, meta: dict | None = None) -> None:
    """Write an estimates table atomically as Parquet."""
    missing = [c for c in ESTIMATE_COLUMNS if c not in frame.columns]
    if missing:
        raise DatasetError(f"estimates are missing column(s) {', '.join(missing)}")
    table = pa.Table.from_pandas(frame.reset_index(drop=True), preserve_index=False)
    if meta:
        table = table.replace_schema_metadata({**(table.schema.metadata or {}),
                                               METADATA_KEY: json.dumps(meta).encode()})
    atomic_write_table(table, path)
