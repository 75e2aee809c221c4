"""The shift's SQLite record (``loadout --db``) and its reader (``report --db``).

Split from :mod:`excavator_payload.runtime.loadout` (the weighing): the tables, the layout
version kept in ``PRAGMA user_version``, and the checks that a database is a shift record of
a version this package reads before anything is written to it or reported from it. SQLite
failures (locked, read-only, damaged) are one line naming the record, never a traceback; each
truck is one transaction, so the trucks written before a failure stay.
"""

from __future__ import annotations

import logging
import math
import sqlite3
import time as _time
from pathlib import Path

import numpy as np
import pandas as pd

from excavator_payload.errors import DatasetError

_log = logging.getLogger(__name__)

SCHEMA = """
CREATE TABLE IF NOT EXISTS runs (
    run INTEGER PRIMARY KEY AUTOINCREMENT, source TEXT NOT NULL, data TEXT, model TEXT,
    rated REAL, started REAL, finished REAL);
CREATE TABLE IF NOT EXISTS passes (
    source TEXT NOT NULL, run INTEGER NOT NULL, truck INTEGER NOT NULL, pass INTEGER NOT NULL,
    time_dig REAL, time_dump REAL, time_lock REAL, weight REAL, sigma REAL, status TEXT NOT NULL,
    reason TEXT, true_weight REAL,
    UNIQUE (source, truck, pass));
CREATE TABLE IF NOT EXISTS trucks (
    source TEXT NOT NULL, run INTEGER NOT NULL, truck INTEGER NOT NULL, passes INTEGER NOT NULL,
    total REAL NOT NULL, target REAL, unweighed INTEGER NOT NULL, true_total REAL,
    true_passes INTEGER, matched INTEGER, start REAL,
    UNIQUE (source, truck));
CREATE TABLE IF NOT EXISTS faults (
    source TEXT NOT NULL, run INTEGER NOT NULL, truck INTEGER NOT NULL, spn INTEGER NOT NULL,
    fmi INTEGER NOT NULL, signal TEXT, kind TEXT, start REAL, "end" REAL);
"""


#: The record's layout version (``PRAGMA user_version``): a record written by a newer version of
#: the package (a higher number) is refused, never half-understood; 0 is a record made before
#: the number was kept (read as version 1).
SCHEMA_VERSION = 1

#: The columns each table of a shift record must have (the reader and writer use them all).
RECORD_COLUMNS = {
    "runs": ("run", "source", "data", "model", "rated", "started", "finished"),
    "passes": ("source", "run", "truck", "pass", "time_dig", "time_dump", "time_lock", "weight", "sigma",
               "status", "reason", "true_weight"),
    "trucks": ("source", "run", "truck", "passes", "total", "target", "unweighed", "true_total",
               "true_passes", "matched"),
    "faults": ("source", "run", "truck", "spn", "fmi", "signal", "kind", "start", "end"),
}


def record_error(path: str | Path, exc: sqlite3.Error, what: str) -> DatasetError:
    """One line for an SQLite failure on the shift record ``path`` (what it means, not the
    library's words alone).

    Parameters
    ----------
    path : str or Path
        The record.
    exc : sqlite3.Error
        What SQLite raised.
    what : str
        What was being done, e.g. ``"open"`` or ``"write truck 3 to"``.
    """
    text = str(exc)
    if "locked" in text or "busy" in text:
        why = "another program holds it locked (a loadout or report still running on it?); try again when it ends"
    elif "readonly" in text or "read-only" in text:
        why = "it is read-only (the file's or its folder's permissions); give a writable --db"
    elif "malformed" in text or "not a database" in text or "corrupt" in text:
        why = f"the file is damaged or not SQLite ({text}); restore a copy or give a new --db"
    elif "unable to open" in text:
        why = "the file cannot be created or opened (does its folder exist, and may you write there?)"
    elif "disk is full" in text or "disk I/O" in text:
        why = f"the disk failed or is full ({text})"
    else:
        why = text
    return DatasetError(f"--db '{path}': could not {what} the shift record: {why}")


def check_record_schema(db: sqlite3.Connection, path: str | Path) -> None:
    """Refuse a database that is another program's (a table of ours with other columns) or a
    shift record of a newer version, before anything is written or read.

    Parameters
    ----------
    db : sqlite3.Connection
        The open database.
    path : str or Path
        Its file (for the message).

    Raises
    ------
    DatasetError
        A newer record, a table named as ours without our columns, or tables that are all
        another program's.
    """
    version = db.execute("PRAGMA user_version").fetchone()[0]
    if version > SCHEMA_VERSION:
        raise DatasetError(f"--db '{path}' is a shift record of a newer excavator-payload (layout version "
                           f"{version}, this one reads up to {SCHEMA_VERSION}); upgrade, or give a new --db")
    tables = [row[0] for row in db.execute("SELECT name FROM sqlite_master WHERE type = 'table' "
                                            "AND name NOT LIKE 'sqlite_%' ORDER BY name")]
    if tables and not set(tables) & set(RECORD_COLUMNS):
        # an application's database given as --db: loadout added the record's tables to it
        shown = ", ".join(tables[:5]) + (", …" if len(tables) > 5 else "")
        raise DatasetError(f"--db '{path}' holds another program's table(s) ({shown}) and no shift record: "
                           "a shift record is a file of its own; give a new --db")
    for table, needed in RECORD_COLUMNS.items():
        have = {row[1] for row in db.execute(f"PRAGMA table_info({table})")}
        missing = [c for c in needed if c not in have]
        if have and missing:
            raise DatasetError(f"--db '{path}' has a table '{table}' without the shift record's column(s) "
                               f"{', '.join(missing)}: it is another program's database (or another "
                               f"record layout); give a new --db")


#: The first bytes of an SQLite write-ahead log (either checksum byte order).
_WAL_MAGIC = (b"\x37\x7f\x06\x82", b"\x37\x7f\x06\x83")


def check_record_files(path: str | Path) -> None:
    """Refuse a shift record SQLite would read wrongly: a named pipe or device (SQLite said "disk
    I/O error"), or a record beside which lies a write-ahead log (``<record>-wal``) that is not its
    own. SQLite applies any ``-wal`` file it finds beside a database to it, whoever wrote it: a
    stale one left by another database of that name (a record deleted without its ``-wal``, a
    copy of one machine's record next to another's log) replaced the record's pages with the
    other database's: ``report`` called it "not a shift record" and the next ``loadout`` wrote
    its passes into the other database, the record's earlier trucks gone. A record that is not in
    WAL mode (or has no pages yet) has no log of its own, so such a file is foreign.

    Parameters
    ----------
    path : str or Path
        The shift record (it may not exist yet).

    Raises
    ------
    DatasetError
        The path is a special file, or a foreign write-ahead log lies beside it.
    """
    from excavator_payload.textfiles import is_special, not_a_file

    path = Path(path)
    if is_special(path):
        raise DatasetError(not_a_file(path, "--db"))
    wal = Path(f"{path}-wal")
    try:
        with open(wal, "rb") as f:
            magic = f.read(4)
    except OSError:
        return  # none (or unreadable: SQLite says so itself)
    if magic not in _WAL_MAGIC:
        return  # an empty or reset log: nothing SQLite would apply
    header = b""
    if path.is_file():
        with open(path, "rb") as f:
            header = f.read(20)
    in_wal_mode = len(header) == 20 and header.startswith(b"SQLite format 3\x00") and header[18:20] == b"\x02\x02"
    if not in_wal_mode:
        state = "does not exist yet" if not path.is_file() or not header else "is not in WAL mode"
        raise DatasetError(f"--db '{path}': beside it lies '{wal.name}', a write-ahead log that is not this "
                           f"record's (the record {state}): SQLite would apply another database's pages to it; "
                           f"move '{wal.name}' (and '{path.name}-shm') away, then run again")


class ShiftRecord:
    """The shift's SQLite record (module doc): rerunning the same data replaces, never doubles.

    Parameters
    ----------
    path : str or Path
        The SQLite file (created if missing; an older record gains the newer columns).
    """

    def __init__(self, path: str | Path):
        path = Path(path)
        self.path = path
        if path.is_dir():
            raise DatasetError(f"--db '{path}' is a folder; give a file name such as shift.sqlite")
        check_record_files(path)
        try:
            self.db = sqlite3.connect(path)
            check_record_schema(self.db, path)
            self.db.executescript(SCHEMA)
            columns = {row[1] for row in self.db.execute("PRAGMA table_info(trucks)")}
            if "start" not in columns:  # a record made before trucks had a start time
                with self.db:
                    self.db.execute("ALTER TABLE trucks ADD COLUMN start REAL")
            if self.db.execute("PRAGMA user_version").fetchone()[0] == 0:
                self.db.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")
        except sqlite3.Error as exc:
            raise record_error(path, exc, "open") from None

    def _write(self, what: str, statements) -> sqlite3.Cursor:
        """Run ``statements(db)`` in one transaction; an SQLite failure (locked, read-only, full
        disk, corrupt pages) is one :class:`DatasetError` line naming the record: the trucks
        written before stay, the transaction that failed is rolled back whole."""
        try:
            with self.db:
                return statements(self.db)
        except sqlite3.Error as exc:
            raise record_error(self.path, exc, what) from None

    def start_run(self, source: str, data: str, model: str, rated: float | None = None) -> int:
        """Record the start of a loadout run over ``source`` (the data's hash); returns its id.

        Parameters
        ----------
        source : str
            SHA-256 of the data file (:func:`file_key`).
        data : str
            The data's name as given (for the record's reader).
        model : str
            The model's name as given.
        rated : float, optional
            kg, the model's rated payload, if any.
        """
        cur = self._write("record the run in", lambda db: db.execute(
            "INSERT INTO runs (source, data, model, rated, started) VALUES (?, ?, ?, ?, ?)",
            (source, data, model, rated, _time.time())))
        return int(cur.lastrowid)

    def finish_run(self, run: int) -> None:
        """Mark run ``run`` finished (a run without it was interrupted).

        Parameters
        ----------
        run : int
            The id :meth:`start_run` returned.
        """
        self._write("finish the run in", lambda db: db.execute("UPDATE runs SET finished = ? WHERE run = ?",
                                                                (_time.time(), run)))

    def write_truck(self, source: str, run: int, truck) -> None:
        """One truck, its passes and faults in one transaction; an earlier run's rows of it replaced
        (a live truck is written again with each pass: the latest state of it, never twice).

        Parameters
        ----------
        source : str
            SHA-256 of the data file.
        run : int
            The run that weighed it.
        truck : excavator_payload.runtime.loadout.Truck
            The truck, its passes and faults.
        """
        def statements(db):
            db.execute("DELETE FROM passes WHERE source = ? AND truck = ?", (source, truck.truck))
            db.execute("DELETE FROM faults WHERE source = ? AND truck = ?", (source, truck.truck))
            db.executemany(
                'INSERT INTO faults (source, run, truck, spn, fmi, signal, kind, start, "end") '
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                [(source, run, truck.truck, f["spn"], f["fmi"], f["signal"], f["kind"], f["start"],
                  f["end"] if math.isfinite(f["end"]) else None) for f in truck.faults])
            db.executemany(
                "INSERT INTO passes (source, run, truck, pass, time_dig, time_dump, time_lock, weight, "
                "sigma, status, reason, true_weight) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                [(source, run, p.truck, p.index, p.time_dig, p.time_dump, p.time_lock, p.weight, p.sigma,
                  p.status, p.reason, p.true_weight) for p in truck.passes])
            db.execute(
                "INSERT INTO trucks (source, run, truck, passes, total, target, unweighed, true_total, "
                "true_passes, matched, start) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?) ON CONFLICT (source, truck) "
                "DO UPDATE SET run = excluded.run, passes = excluded.passes, total = excluded.total, "
                "target = excluded.target, unweighed = excluded.unweighed, true_total = excluded.true_total, "
                "true_passes = excluded.true_passes, matched = excluded.matched, start = excluded.start",
                (source, run, truck.truck, len(truck.passes), truck.total, truck.target, truck.unweighed,
                 truck.true_total, truck.true_passes, truck.matched, truck.start))

        self._write(f"write truck {truck.truck} to", statements)

    def close(self) -> None:
        """Close the database."""
        self.db.close()


#: s between two attempts to write a failing record again on a live bus (each attempt may wait
#: SQLite's 5 s lock timeout while the bus queues up); the shift's end always tries.
RETRY_SECONDS = 30.0


def _plain(value):
    """``value`` (a truck as dicts and lists) with NaN and ±inf as None: strict JSON."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


class KeptRecord:
    """A live shift's record that never loses the trucks in hand (``loadout --interface``).

    A write to the :class:`ShiftRecord` that fails mid-shift (the disk full, the file made
    read-only, locked beyond SQLite's timeout, its folder deleted) stopped the shift with one
    line and the truck in hand was lost. Here the failure is said once (a logged warning naming
    the record and the fallback file) and the shift goes on: every truck not yet in the record
    is kept, in memory and in a JSON file (:attr:`fallback`: ``<record>.unsaved.json`` beside the
    record, or in the temporary folder when that cannot be written), with the record's columns;
    the record is tried again at most every :data:`RETRY_SECONDS` and at the shift's end. Once it takes them all the file is removed. Opening the record and starting the
    run still fail at once, before anything is weighed.

    Parameters
    ----------
    record : ShiftRecord
        The open record.
    clock : callable, optional
        s, monotonic: when to try again.
    """

    def __init__(self, record: ShiftRecord, clock=_time.monotonic) -> None:
        self.record, self.path, self.clock = record, record.path, clock
        #: the first failure's line (None while every write succeeded, or after it recovered)
        self.failure: str | None = None
        #: the trucks not in the record (by number: their latest state)
        self.unsaved: dict = {}
        #: where they are kept (None: nowhere but memory, or nothing to keep)
        self.fallback: Path | None = None
        self.recovered = 0  # trucks written to the record after a failure
        self._next_try = -math.inf
        self._where: tuple[str, int] | None = None
        self._finish: int | None = None

    def start_run(self, source: str, data: str, model: str, rated: float | None = None) -> int:
        """:meth:`ShiftRecord.start_run` (a failure is an error: nothing is weighed yet).

        Parameters
        ----------
        source, data, model : str
            The session's key, the data's and the model's names.
        rated : float, optional
            kg, the model's rated payload.
        """
        return self.record.start_run(source, data, model, rated)

    def write_truck(self, source: str, run: int, truck) -> None:
        """Keep ``truck``'s latest state and write every kept truck to the record (if it is time
        to try); a failure is kept, not raised.

        Parameters
        ----------
        source : str
            The session's key.
        run : int
            The run that weighed it.
        truck : excavator_payload.runtime.loadout.Truck
            The truck (copied: a live truck keeps growing).
        """
        from dataclasses import replace

        self._where = (source, run)
        self.unsaved[truck.truck] = replace(truck, passes=[replace(p) for p in truck.passes],
                                            faults=[dict(f) for f in truck.faults])
        self._flush(force=False)

    def finish_run(self, run: int) -> None:
        """Write what is kept and mark the run finished (always tried).

        Parameters
        ----------
        run : int
            The id :meth:`start_run` returned.
        """
        self._finish = run
        self._flush(force=True)

    def _flush(self, force: bool) -> None:
        if self.failure is not None and not force and self.clock() < self._next_try:
            self._keep()
            return
        try:
            for number in sorted(self.unsaved):
                self.record.write_truck(*self._where, self.unsaved[number])
                del self.unsaved[number]
                self.recovered += self.failure is not None
            if self._finish is not None:
                self.record.finish_run(self._finish)
                self._finish = None
        except DatasetError as exc:
            first = self.failure is None
            self.failure = self.failure or str(exc)
            self._next_try = self.clock() + RETRY_SECONDS
            self._keep()
            if first:
                _log.warning("%s; the shift goes on: its trucks not in the record are kept %s and written "
                             "to the record when it takes them", exc, self.kept_where())
            return
        if self.failure is not None:
            _log.warning("--db '%s': the shift record takes writes again: %d kept truck(s) written to it",
                         self.path, self.recovered)
            if self.fallback is not None:
                self.fallback.unlink(missing_ok=True)
            self.failure, self.fallback = None, None

    def kept_where(self) -> str:
        """``in '/x/shift.sqlite.unsaved.json'`` or ``in memory only (…)``: where the trucks are."""
        return f"in '{self.fallback}'" if self.fallback is not None else "in memory only (no file could be written)"

    def _keep(self) -> None:
        """Write the kept trucks to the fallback file (beside the record, else the temp folder)."""
        import json
        import os
        import tempfile
        from dataclasses import asdict

        body = json.dumps(_plain({
            "record": str(self.path), "error": self.failure, "source": self._where and self._where[0],
            "run": self._where and self._where[1], "saved": _time.time(),
            "columns": {"trucks": list(RECORD_COLUMNS["trucks"]) + ["start"], "passes": list(RECORD_COLUMNS["passes"])},
            "trucks": [{**asdict(t), "total": t.total, "unweighed": t.unweighed}
                       for _, t in sorted(self.unsaved.items())]}), indent=1)
        places = [unsaved_beside(self.path),
                  Path(tempfile.gettempdir()) / f"{self.path.stem}-{os.getpid()}.unsaved.json"]
        if self.fallback is not None and self.fallback != places[0]:
            places.insert(0, self.fallback)
        for place in places:
            tmp = place.with_name(f".{place.name}.tmp")
            try:
                tmp.write_text(body, encoding="utf-8")
                tmp.replace(place)
            except OSError:
                try:
                    tmp.unlink(missing_ok=True)
                except OSError:
                    pass
                continue
            self.fallback = place
            return
        self.fallback = None

    def lost_line(self) -> str | None:
        """The one line for the end of a shift whose record still fails (None when all is in it)."""
        if self.failure is None:
            return None
        trucks = [t for _, t in sorted(self.unsaved.items())]
        passes = sum(len(t.passes) for t in trucks)
        total = sum(t.total for t in trucks)
        what = f"the shift's {len(trucks)} truck(s) not in it ({passes} passes, {total:,.0f} kg)" if trucks else \
            "the run is not marked finished in it"
        line = f"{self.failure}; {what} kept {self.kept_where()}"
        if trucks and self.fallback is not None:
            line += (f" (the next `loadout --db` or `report --db` on the record takes them in"
                     if self.fallback == unsaved_beside(self.path) else
                     f" (`report --db '{self.path}' --kept '{self.fallback}'` takes them in") + ")"
        return line

    def close(self) -> None:
        """Close the record."""
        self.record.close()


def unsaved_beside(path: str | Path) -> Path:
    """``<record>.unsaved.json``: where a live shift keeps the trucks its record did not take.

    Parameters
    ----------
    path : str or Path
        The shift record.
    """
    path = Path(path)
    return path.with_name(path.name + ".unsaved.json")


_KEPT_PASS = ("truck", "index", "time_dig", "time_dump", "time_lock", "weight", "sigma", "status")


def take_in_unsaved(record: ShiftRecord, kept: str | Path) -> str:
    """Write the trucks a live shift kept in ``kept`` (:class:`KeptRecord`'s fallback file) into
    ``record``, then remove the file; returns the one line that says what was taken in.

    A truck that a later run of the same source has written since is left as the record has it
    (the file's copy is older) and said. The file is checked whole before anything is written:
    a damaged or foreign file is one line and the record is untouched.

    Parameters
    ----------
    record : ShiftRecord
        The open record to write to.
    kept : str or Path
        The fallback file (``<record>.unsaved.json``, or the one in the temporary folder that the
        shift's last line named).

    Raises
    ------
    DatasetError
        The file is missing, not a kept-trucks file, or holds a run this record does not have.
    """
    import json
    from types import SimpleNamespace

    kept = Path(kept)
    where = f"kept trucks '{kept}'"
    try:
        body = json.loads(kept.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DatasetError(f"{where}: no such file") from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise DatasetError(f"{where}: not a file of a live shift's kept trucks ({exc})") from None
    if not (isinstance(body, dict) and isinstance(body.get("trucks"), list) and isinstance(body.get("source"), str)
            and isinstance(body.get("run"), int) and not isinstance(body.get("run"), bool)):
        raise DatasetError(f"{where}: not a file of a live shift's kept trucks (needs 'source', 'run' and "
                           "'trucks', as `loadout --interface` writes it)")
    source, run = body["source"], body["run"]
    found = record.db.execute("SELECT 1 FROM runs WHERE run = ? AND source = ?", (run, source)).fetchone()
    if found is None:
        raise DatasetError(f"{where} holds run {run} of the record '{body.get('record')}', which --db "
                           f"'{record.path}' does not have: give that record")

    def number(value, what):
        if value is None:
            return None
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise DatasetError(f"{where}: {what} is {value!r}, not a number")
        return value

    trucks = []
    for t, truck in enumerate(body["trucks"]):
        if not (isinstance(truck, dict) and isinstance(truck.get("truck"), int) and truck["truck"] >= 1
                and isinstance(truck.get("passes"), list) and isinstance(truck.get("faults", []), list)):
            raise DatasetError(f"{where}: truck entry {t + 1} is not a kept truck (a number ≥ 1 and its passes)")
        passes = []
        for p in truck["passes"]:
            missing = [k for k in _KEPT_PASS if not isinstance(p, dict) or k not in p]
            if missing:
                raise DatasetError(f"{where}: a pass of truck {truck['truck']} lacks {', '.join(missing)}")
            if p["status"] not in ("ok", "degraded", "not_weighed"):
                raise DatasetError(f"{where}: a pass of truck {truck['truck']} has the status {p['status']!r}")
            values = {k: number(p.get(k), f"truck {truck['truck']}'s pass {p.get('index')} '{k}'")
                      for k in ("time_dig", "time_dump", "time_lock", "weight", "sigma", "true_weight")}
            if isinstance(p["index"], bool) or not isinstance(p["index"], int) or p["index"] < 1:
                raise DatasetError(f"{where}: a pass of truck {truck['truck']} has the number {p['index']!r}")
            passes.append(SimpleNamespace(truck=truck["truck"], index=p["index"], status=p["status"],
                                          reason=str(p.get("reason") or ""), **values))
        faults = []
        for f in truck.get("faults", []):
            if not (isinstance(f, dict) and all(k in f for k in ("spn", "fmi", "signal", "kind", "start"))):
                raise DatasetError(f"{where}: a fault of truck {truck['truck']} lacks spn, fmi, signal, kind or start")
            if not all(isinstance(f[k], int) and not isinstance(f[k], bool) for k in ("spn", "fmi")):
                raise DatasetError(f"{where}: a fault of truck {truck['truck']} has spn {f['spn']!r}, fmi {f['fmi']!r}")
            number(f["start"], f"truck {truck['truck']}'s fault start")
            end = number(f.get("end"), f"truck {truck['truck']}'s fault end")
            faults.append({**f, "end": math.nan if end is None else float(end)})
        weights = [p.weight for p in passes if p.weight is not None]
        trucks.append(SimpleNamespace(
            truck=truck["truck"], passes=passes, faults=faults, total=float(sum(weights)),
            unweighed=sum(p.weight is None for p in passes),
            **{k: number(truck.get(k), f"truck {truck['truck']}'s '{k}'")
               for k in ("target", "true_total", "true_passes", "matched", "start")}))
    newer = []
    for truck in trucks:
        later = record.db.execute("SELECT run FROM trucks WHERE source = ? AND truck = ? AND run > ?",
                                  (source, truck.truck, run)).fetchone()
        if later is not None:
            newer.append(truck.truck)
            continue
        record.write_truck(source, run, truck)
    kept.unlink(missing_ok=True)
    taken = [t for t in trucks if t.truck not in newer]
    line = (f"{len(taken)} kept truck(s) of run {run} ({sum(len(t.passes) for t in taken)} passes, "
            f"{sum(t.total for t in taken):,.0f} kg) taken into --db '{record.path}' from '{kept}'")
    if newer:
        line += f"; truck(s) {', '.join(map(str, newer))} left as a later run recorded them"
    return line


def open_record(path: str | Path, kept: str | Path | None = None, say=print) -> ShiftRecord:
    """Open the shift record ``path`` and take in the trucks a live shift kept outside it:
    ``<record>.unsaved.json`` when it lies beside the record, and ``kept`` when given (each
    said in one line through ``say``).

    Parameters
    ----------
    path : str or Path
        The shift record (created if missing).
    kept : str or Path, optional
        A kept-trucks file elsewhere (the temporary folder's, named by the shift's last line).
    say : callable, optional
        Where the line goes (the console).

    Raises
    ------
    DatasetError
        The record cannot be opened, or a kept file cannot be taken in (the record is closed).
    """
    record = ShiftRecord(path)
    try:
        files = [Path(kept)] if kept is not None else []
        beside = unsaved_beside(path)
        if beside.is_file() and not any(f.resolve() == beside.resolve() for f in files if f.exists()):
            files.insert(0, beside)
        for file in files:
            say(take_in_unsaved(record, file))
    except BaseException:
        record.close()
        raise
    return record


def read_record(path: str | Path) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The ``passes`` and ``trucks`` tables of a shift record (``attrs["rated"]``: the rated
    payload the runs' models had, kg, if one; ``attrs["faults"]``: the ``faults`` table's rows
    as dicts, none for a record made before it had one — a list, not a frame: pandas compares
    attrs when frames are merged, and a frame there made every merge raise).

    Parameters
    ----------
    path : str or Path
        A shift record made by ``loadout --db``.

    Raises
    ------
    DatasetError
        The file is missing or not a shift record.
    """
    path = Path(path)
    if not path.is_file():
        from excavator_payload.textfiles import not_a_file

        raise DatasetError(not_a_file(path, "--db"))
    check_record_files(path)
    try:
        with sqlite3.connect(f"file:{path}?mode=ro", uri=True) as db:
            check_record_schema(db, path)
            passes = pd.read_sql_query("SELECT * FROM passes ORDER BY source, truck, pass", db)
            trucks = pd.read_sql_query("SELECT * FROM trucks ORDER BY source, truck", db)
            rated = db.execute("SELECT MAX(rated) FROM runs").fetchone()[0]
            has_faults = db.execute("SELECT 1 FROM sqlite_master WHERE name = 'faults'").fetchone()
            faults = (pd.read_sql_query("SELECT * FROM faults ORDER BY source, truck, start", db)
                      if has_faults else pd.DataFrame(columns=["source", "truck", "spn", "fmi", "signal",
                                                               "kind", "start", "end"]))
    except (sqlite3.DatabaseError, pd.errors.DatabaseError) as exc:
        text = str(exc).split("': ")[-1] if str(exc).startswith("Execution failed on sql") else str(exc)
        if "locked" in text or "busy" in text:
            raise DatasetError(f"--db '{path}' is locked by another program (a loadout still writing it?); "
                               "try again when it ends") from None
        raise DatasetError(f"--db '{path}' is not a shift record (made by `loadout --db`): {text}") from None
    _check_record_values(path, passes, trucks, faults)
    passes.attrs["rated"] = rated
    passes.attrs["faults"] = faults.to_dict("records")
    return passes, trucks


#: Per table, the columns that must be numbers (or empty) and those that may not be empty.
_RECORD_NUMBERS = {
    "passes": ("truck", "pass", "time_dig", "time_dump", "time_lock", "weight", "sigma", "true_weight"),
    "trucks": ("truck", "passes", "total", "target", "unweighed", "true_total", "true_passes", "matched"),
    "faults": ("truck", "spn", "fmi", "start", "end"),
}
_RECORD_REQUIRED = {"passes": ("source", "truck", "pass", "status"),
                    "trucks": ("source", "truck", "passes", "total", "unweighed"),
                    "faults": ("source", "truck", "spn", "fmi")}


def _check_record_values(path, passes: pd.DataFrame, trucks: pd.DataFrame, faults: pd.DataFrame) -> None:
    """A record edited by hand or by another tool (SQLite stores any value in any column): text
    where a number belongs, or an empty key, is one line naming the table, column, row and value
    (it was an internal error in the report, or an empty status counted as a pass not weighed)."""
    for name, table in (("passes", passes), ("trucks", trucks), ("faults", faults)):
        for column in _RECORD_REQUIRED[name]:
            if column in table and table[column].isna().any():
                row = int(np.flatnonzero(table[column].isna().to_numpy())[0])
                raise DatasetError(f"--db '{path}': table '{name}' has an empty '{column}' (row {row + 1}); "
                                   "the record was edited by another tool: fix or delete that row")
        for column in _RECORD_NUMBERS[name]:
            if column not in table:
                continue
            values = table[column]
            numeric = pd.to_numeric(values, errors="coerce")
            bad = numeric.isna() & values.notna()
            if bool(bad.any()):
                row = int(np.flatnonzero(bad.to_numpy())[0])
                raise DatasetError(f"--db '{path}': table '{name}' column '{column}' holds {values.iloc[row]!r} "
                                   f"(row {row + 1}) where a number belongs; the record was edited by another "
                                   "tool: fix or delete that row")
            table[column] = numeric
        for column in ("source", "status"):
            if column in table:
                table[column] = table[column].astype(str).where(table[column].notna(), None)
