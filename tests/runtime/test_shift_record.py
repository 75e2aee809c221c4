"""The shift record (``loadout --db``, ``report --db``) against databases it did not make:
another program's, a newer layout, locked, read-only, damaged, edited by hand. Each is one line
naming the record (exit status 2 through the command line), never an internal error, and the
trucks already written stay."""

import sqlite3

import pytest

from excavator_payload.cli import main
from excavator_payload.errors import DatasetError
from excavator_payload.runtime import shift_record
from excavator_payload.runtime.loadout import Pass, Truck
from excavator_payload.runtime.shift_record import SCHEMA_VERSION, ShiftRecord, read_record


def _truck(number: int = 1, target: float | None = 8000.0) -> Truck:
    passes = [Pass(number, k, 10.0 * k, 10.0 * k + 5, 10.0 * k + 4, 4000.0 + k, 20.0, "ok", "", 4000.0)
              for k in (1, 2)]
    return Truck(number, passes, target=target)


def _record(path, trucks=(1,)):
    record = ShiftRecord(path)
    run = record.start_run("src", "shift.parquet", "model")
    for number in trucks:
        record.write_truck("src", run, _truck(number))
    record.finish_run(run)
    record.close()
    return path


def test_a_new_record_carries_its_layout_version(tmp_path):
    with sqlite3.connect(_record(tmp_path / "s.sqlite")) as db:
        assert db.execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION


@pytest.mark.parametrize("table", ["trucks", "passes"])
def test_another_programs_table_of_the_same_name_is_refused_and_kept(tmp_path, table):
    path = tmp_path / "theirs.sqlite"
    with sqlite3.connect(path) as db:
        db.execute(f"CREATE TABLE {table} (id INTEGER PRIMARY KEY, plate TEXT)")
        db.execute(f"INSERT INTO {table} VALUES (1, 'AB-123')")
    with pytest.raises(DatasetError, match=f"table '{table}' without the shift record's column"):
        ShiftRecord(path)
    with sqlite3.connect(path) as db:  # their rows untouched, no table of ours added
        assert db.execute(f"SELECT plate FROM {table}").fetchall() == [("AB-123",)]
        assert db.execute("SELECT COUNT(*) FROM sqlite_master WHERE name = 'runs'").fetchone()[0] == 0


def test_a_record_of_a_newer_version_is_refused_by_loadout_and_report(tmp_path, capsys):
    path = _record(tmp_path / "s.sqlite")
    with sqlite3.connect(path) as db:
        db.execute("PRAGMA user_version = 99")
    with pytest.raises(DatasetError, match="newer excavator-payload .layout version 99"):
        ShiftRecord(path)
    assert main(["report", "--db", str(path), "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip()
    assert "layout version 99" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "r" / "shift.md").exists()


def test_an_older_record_without_the_version_is_read_and_stamped(tmp_path):
    path = tmp_path / "old.sqlite"
    with sqlite3.connect(path) as db:  # a record made before trucks had a start time
        db.executescript(shift_record.SCHEMA.replace("matched INTEGER, start REAL", "matched INTEGER"))
    _record(path)
    passes, trucks = read_record(path)
    assert len(passes) == 2 and trucks["total"].iloc[0] == pytest.approx(8003.0)
    with sqlite3.connect(path) as db:
        assert db.execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION


def test_a_locked_record_is_one_line_and_the_written_trucks_stay(tmp_path, monkeypatch):
    path = _record(tmp_path / "s.sqlite")
    record = ShiftRecord(path)
    record.db.execute("PRAGMA busy_timeout = 50")  # do not wait SQLite's 5 s in a test
    other = sqlite3.connect(path, isolation_level=None)
    other.execute("BEGIN EXCLUSIVE")
    try:
        with pytest.raises(DatasetError, match="another program holds it locked"):
            record.write_truck("src", 1, _truck(2))
    finally:
        other.execute("ROLLBACK")
        other.close()
        record.close()
    passes, trucks = read_record(path)
    assert list(trucks["truck"]) == [1] and len(passes) == 2


def test_a_read_only_record_is_one_line_before_anything_is_weighed(tmp_path, monkeypatch):
    path = _record(tmp_path / "s.sqlite")
    connect = sqlite3.connect
    # as root chmod does not stop a write: open it read-only the way a read-only file is
    monkeypatch.setattr(shift_record.sqlite3, "connect",
                        lambda p, *a, **k: connect(f"file:{p}?mode=ro", uri=True) if "file:" not in str(p)
                        else connect(p, *a, **k))
    record = ShiftRecord(path)
    with pytest.raises(DatasetError, match="could not record the run in the shift record: it is read-only"):
        record.start_run("src2", "x", "m")
    record.close()


def test_damaged_pages_are_one_line(tmp_path):
    path = _record(tmp_path / "s.sqlite", trucks=range(1, 40))
    raw = bytearray(path.read_bytes())
    raw[4096:] = bytes(len(raw) - 4096)  # header intact, every other page zeroed
    path.write_bytes(bytes(raw))
    with pytest.raises(DatasetError, match="damaged or not SQLite"):
        record = ShiftRecord(path)
        record.write_truck("src", 1, _truck(1))


@pytest.mark.parametrize("edit, words", [
    ("UPDATE passes SET weight = 'heavy' WHERE pass = 1", "column 'weight' holds 'heavy' (row 1)"),
    ("UPDATE trucks SET total = 'n/a'", "column 'total' holds 'n/a'"),
    ("UPDATE passes SET status = NULL WHERE pass = 2", "has an empty 'status' (row 2)"),
])
def test_a_record_edited_by_hand_is_one_line_in_the_report(tmp_path, capsys, edit, words):
    path = _record(tmp_path / "s.sqlite")
    with sqlite3.connect(path) as db:
        if "NULL" in edit:  # another tool's copy of the table without NOT NULL
            db.executescript("CREATE TABLE p2 AS SELECT * FROM passes; DROP TABLE passes; "
                             "ALTER TABLE p2 RENAME TO passes;")
        db.execute(edit)
    assert main(["report", "--db", str(path), "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip()
    assert words in err and len(err.splitlines()) == 1, err


def test_a_good_record_still_reports(tmp_path, capsys):
    path = _record(tmp_path / "s.sqlite", trucks=(1, 2))
    assert main(["report", "--db", str(path), "--out", str(tmp_path / "r")]) == 0
    text = (tmp_path / "r" / "shift.md").read_text(encoding="utf-8")
    assert "- trucks: 2" in text and "- total loaded: 16,006 kg" in text


def _read_only(path):
    return sqlite3.connect(f"file:{path}?mode=ro", uri=True)


def test_a_live_record_that_fails_mid_shift_keeps_the_trucks_in_a_file_and_catches_up(tmp_path, caplog):
    """The record turns read-only after truck 1 (a real SQLite 'attempt to write a readonly
    database'): truck 2's passes are kept in ``<record>.unsaved.json`` (said once, naming the
    file), the shift goes on; when the record takes writes again (after RETRY_SECONDS) the kept
    truck is written to it, the file removed, and the run finished."""
    import json

    from excavator_payload.runtime.shift_record import RETRY_SECONDS, KeptRecord

    path = tmp_path / "s.sqlite"
    now = [0.0]
    kept = KeptRecord(ShiftRecord(path), clock=lambda: now[0])
    run = kept.start_run("live", "bus", "model")
    kept.write_truck("live", run, _truck(1))
    writable, kept.record.db = kept.record.db, _read_only(path)
    truck = _truck(2)
    with caplog.at_level("WARNING"):
        kept.write_truck("live", run, Truck(2, truck.passes[:1], target=8000.0))  # its first pass
        now[0] += 1.0
        kept.write_truck("live", run, truck)  # its second: not tried yet, kept
    fallback = path.with_name("s.sqlite.unsaved.json")
    assert kept.fallback == fallback and fallback.is_file()
    warned = [r.getMessage() for r in caplog.records if "unsaved" in r.getMessage()]
    assert len(warned) == 1 and "read-only" in warned[0] and str(fallback) in warned[0]
    body = json.loads(fallback.read_text())
    assert [t["truck"] for t in body["trucks"]] == [2] and len(body["trucks"][0]["passes"]) == 2
    assert body["trucks"][0]["total"] == pytest.approx(8003.0) and body["record"] == str(path)
    assert "kept in" in kept.lost_line() and "1 truck(s) not in it (2 passes, 8,003 kg)" in kept.lost_line()
    kept.record.db.close()
    kept.record.db = writable
    now[0] += RETRY_SECONDS
    kept.write_truck("live", run, _truck(3))
    kept.finish_run(run)
    kept.close()
    assert kept.lost_line() is None and not fallback.exists()
    passes, trucks = read_record(path)
    assert list(trucks["truck"]) == [1, 2, 3] and len(passes) == 6
    with sqlite3.connect(path) as db:
        assert db.execute("SELECT COUNT(*) FROM runs WHERE finished IS NOT NULL").fetchone() == (1,)


@pytest.mark.parametrize("failure", ["database or disk is full", "database is locked", "folder gone"])
def test_a_record_that_never_comes_back_leaves_the_trucks_in_a_file(tmp_path, monkeypatch, failure):
    """Disk full, locked beyond the timeout, or the record's folder deleted mid-shift: every
    truck not in the record is in the fallback file at the end (beside the record, or in the
    temporary folder when its folder is gone) and the end's one line names it."""
    import json
    import shutil

    from excavator_payload.runtime.shift_record import KeptRecord

    import tempfile

    folder = tmp_path / "shift"
    folder.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    path = folder / "s.sqlite"
    kept = KeptRecord(ShiftRecord(path))
    run = kept.start_run("live", "bus", "model")
    kept.write_truck("live", run, _truck(1))
    if failure == "folder gone":  # a real failure: SQLite refuses to write a file that was deleted
        shutil.rmtree(folder)
    else:
        def fail(*args, text=failure):
            raise shift_record.record_error(path, sqlite3.OperationalError(text), "write truck 2 to")

        monkeypatch.setattr(kept.record, "write_truck", fail)
        monkeypatch.setattr(kept.record, "finish_run", fail)
    kept.write_truck("live", run, _truck(2))
    kept.write_truck("live", run, _truck(3))
    kept.finish_run(run)
    lost = kept.lost_line()
    assert lost.startswith(f"--db '{path}': could not write truck 2 to the shift record")
    assert "2 truck(s) not in it (4 passes, 16,006 kg)" in lost and str(kept.fallback) in lost
    where = path.parent if path.parent.exists() else tmp_path / "tmp"
    assert kept.fallback.parent == where
    assert [t["truck"] for t in json.loads(kept.fallback.read_text())["trucks"]] == [2, 3]
