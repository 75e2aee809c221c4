"""Reading and writing datasets as Parquet, with validation.

Layout: one Parquet file, one row per sample with the columns of
:data:`~excavator_payload.data.schema.COLUMNS` (SI units), and the file-level and
per-experiment metadata as JSON in the Parquet schema metadata under the key
``excavator_payload`` (readable with ``pyarrow.parquet.read_schema(path).metadata``).
Writes are atomic: a temporary file in the same folder is renamed over the target.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Sequence

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.schema import ESTIMATE_COLUMNS, FORMAT_VERSION, METADATA_KEY
from excavator_payload.errors import DatasetError
from excavator_payload.textfiles import is_special, not_a_file

# Validation and unit checks live in validation.py and units.py; named here too.
from excavator_payload.data.units import (  # noqa: F401
    HOUSE_TILT_LIMIT,
    MIN_PEAK_PRESSURE,
    RATE_MIN_WINDOWS,
    RATE_RATIO_LIMIT,
    RATE_WINDOW,
    check_signal_units,
)
from excavator_payload.data.validation import _sensor_set_of, validate_frame  # noqa: F401


def check_output_path(path: str | Path, *, inputs: Sequence[str | Path] = (), kind: str = "file",
                      option: str = "--out", replaces: Sequence[str] = (), suffixes: Sequence[str] = ()) -> Path:
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
    suffixes : for a file, the suffixes its format may have (``.parquet``: ``--out e.csv`` wrote
        a Parquet file named .csv without a word); empty: any.

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
    if suffixes and path.suffix.lower() not in suffixes:
        raise DatasetError(f"{option} must end in {' or '.join(suffixes)} (the file is written in that format), "
                           f"got '{path.name}'")
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
    """Write a Parquet table atomically (temporary file + rename): never a half-written file.

    Parameters
    ----------
    table : pyarrow.Table
        The table to write (zstd-compressed).
    path : str or pathlib.Path
        Destination file; its folder is created if missing.
    """
    path = Path(path)
    tmp = _temporary_beside(path)
    try:
        pq.write_table(table, tmp, compression="zstd")
        _put_in_place(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _temporary_beside(path: Path) -> str:
    """A new empty temporary file in ``path``'s folder (created if missing), to rename over it."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    return tmp


def _put_in_place(tmp: str, path: Path) -> None:
    """Rename the finished temporary file ``tmp`` over ``path``."""
    os.chmod(tmp, new_file_mode())  # mkstemp makes 0600; a data file is as readable as any other
    os.replace(tmp, path)


class ParquetStreamWriter:
    """Write a Parquet table chunk by chunk (one row group per chunk) in bounded memory, and
    atomically: the rows go to a temporary file in the destination's folder that :meth:`close`
    renames over it; :meth:`abort` (or leaving a ``with`` block without :meth:`close`) removes
    it, so the destination is never half-written.

    Parameters
    ----------
    path : str or pathlib.Path
        Destination Parquet file; its folder is created if missing.
    meta : dict, optional
        Metadata stored as JSON in the file's schema metadata (as :func:`write_estimates`).
    """

    def __init__(self, path: str | Path, meta: dict | None = None) -> None:
        self.path = Path(path)
        self.meta = meta
        self.rows = 0
        self._writer: pq.ParquetWriter | None = None
        self._tmp = _temporary_beside(self.path)

    def write(self, frame: pd.DataFrame) -> None:
        """Append ``frame``'s rows (the first chunk sets the columns and their types).

        Parameters
        ----------
        frame : pandas.DataFrame
            The next rows; the same columns as the first chunk's.
        """
        table = pa.Table.from_pandas(frame.reset_index(drop=True), preserve_index=False)
        if self._writer is None:
            schema = table.schema
            if self.meta:
                schema = schema.with_metadata({**(schema.metadata or {}),
                                               METADATA_KEY: json.dumps(self.meta).encode()})
            self._writer = pq.ParquetWriter(self._tmp, schema, compression="zstd")
        self._writer.write_table(table.cast(self._writer.schema))
        self.rows += len(frame)

    def close(self) -> int:
        """Finish the file and put it in place; returns the rows written."""
        if self._writer is None:
            self.abort()
            raise DatasetError(f"no rows to write to '{self.path}'")
        self._writer.close()
        self._writer = None
        _put_in_place(self._tmp, self.path)
        return self.rows

    def abort(self) -> None:
        """Drop what was written (the destination is left as it was)."""
        if self._writer is not None:
            try:
                self._writer.close()
            except Exception:  # noqa: BLE001 - the file goes anyway
                pass
            self._writer = None
        if os.path.exists(self._tmp):
            os.unlink(self._tmp)

    def __enter__(self) -> "ParquetStreamWriter":
        return self

    def __exit__(self, kind, value, traceback) -> None:
        self.abort()  # not closed (an exception, or close never called): nothing is put in place


def write_dataset(dataset: Dataset, path: str | Path) -> None:
    """Validate and write ``dataset`` to ``path`` (Parquet, atomic).

    Parameters
    ----------
    dataset : Dataset
        The dataset to write; its metadata and units go into the file's schema metadata.
    path : str or pathlib.Path
        Destination Parquet file.
    """
    sensors = dataset.sensor_set
    validate_frame(dataset.frame, source="dataset to write", sensor_set=sensors)
    cols = [c for c in sensors.columns if c in dataset.frame.columns]
    cols += [c for c in sensors.truth_columns if c in dataset.frame.columns]
    frame = dataset.frame[cols].copy()
    frame["experiment"] = frame["experiment"].astype("int64")
    table = pa.Table.from_pandas(frame, preserve_index=False)
    meta = dataset_file_meta(dataset.meta, sensors, cols)
    table = table.replace_schema_metadata({**(table.schema.metadata or {}),
                                           METADATA_KEY: json.dumps(meta).encode()})
    atomic_write_table(table, path)


def dataset_file_meta(meta: dict, sensors, columns: Sequence[str]) -> dict:
    """The metadata a dataset file carries: ``meta`` with the format version, the sensor set's
    name and each column's unit.

    Parameters
    ----------
    meta : dict
        The dataset's own metadata (source, machine, ...).
    sensors : SensorSet
        The sensor set of its signals.
    columns : sequence of str
        The file's columns.
    """
    meta = dict(meta)
    meta.setdefault("format_version", FORMAT_VERSION)
    meta["sensor_set"] = sensors.name
    meta["units"] = {c: sensors.unit(c) for c in columns}
    return meta


def read_metadata(path: str | Path) -> dict:
    """The excavator_payload metadata of a Parquet file (empty dict if it has none).

    Parameters
    ----------
    path : str or pathlib.Path
        The Parquet file.
    """
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
    if is_special(path):  # a named pipe: pyarrow waited for a writer for ever
        raise DatasetError(not_a_file(path, "dataset file"))
    try:
        schema = pq.read_schema(path)
    except (pa.ArrowInvalid, OSError) as exc:
        raise DatasetError(f"'{path}' is not a readable Parquet file (truncated or another format?): {exc}") from None
    twice = sorted({n for n in schema.names if schema.names.count(n) > 1})
    if twice:  # pyarrow's "Multiple matches for FieldRef" was called a truncated or corrupt file
        raise DatasetError(f"'{path}': column(s) {', '.join(map(repr, twice))} appear more than once; "
                           "keep one of each (which one holds the signal?)")
    return schema


#: Suffixes of the Parquet files the commands write.
PARQUET_SUFFIXES = (".parquet", ".pq")


def read_dataset(path: str | Path, *, validate: bool = True, machine=None) -> Dataset:
    """Read and validate a dataset written by ``excavator-payload simulate`` (or by you).

    A dataset of the machine sensor set is also checked against the arm's balance for swapped
    head and rod pressures (:func:`excavator_payload.data.wiring.check_wiring`) with ``machine``
    (the machine the reading model believes in: a machine, preset name or file) or else the
    machine in the file's metadata.

    Parameters
    ----------
    path : str or pathlib.Path
        The Parquet dataset, or a field log table (CSV / Parquet without experiments).
    validate : bool, default True
        Check the schema (and, for the machine sensor set, the pressure wiring).
    machine : Machine, str or pathlib.Path, optional
        The machine the reading model believes in, for the wiring check; None: the file's.

    Returns
    -------
    Dataset
        The dataset, with ``source`` set to ``path``.

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
    if validate and sensors.cylinder_chambers:  # head and rod pressures: are they swapped?
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


def read_estimates(path: str | Path) -> pd.DataFrame:
    """Read an estimates file (``experiment``, ``time``, ``payload_estimate``, optional ``status``).

    Parameters
    ----------
    path : str or pathlib.Path
        The Parquet estimates file.
    """
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
    """Write an estimates table atomically as Parquet.

    Parameters
    ----------
    frame : pandas.DataFrame
        The estimates: ``experiment``, ``time``, ``payload_estimate`` (kg), optional ``status``.
    path : str or pathlib.Path
        Destination Parquet file.
    meta : dict, optional
        Metadata stored as JSON in the file's schema metadata.
    """
    missing = [c for c in ESTIMATE_COLUMNS if c not in frame.columns]
    if missing:
        raise DatasetError(f"estimates are missing column(s) {', '.join(missing)}")
    table = pa.Table.from_pandas(frame.reset_index(drop=True), preserve_index=False)
    if meta:
        table = table.replace_schema_metadata({**(table.schema.metadata or {}),
                                               METADATA_KEY: json.dumps(meta).encode()})
    atomic_write_table(table, path)
