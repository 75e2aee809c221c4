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
