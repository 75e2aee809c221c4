"""A live shift's kept trucks (``<record>.unsaved.json``, written when the record failed mid-shift)
are taken back into the record: by the next ``loadout --db`` or ``report --db`` unasked, or by
``report --db --kept FILE`` for a file elsewhere — every pass, fault and total as the shift had
it; a damaged or foreign file is one line and the record is untouched."""

import json
import math
import sqlite3

import pytest

from excavator_payload.cli import main
from excavator_payload.errors import DatasetError
from excavator_payload.runtime.loadout import Pass, Truck
from excavator_payload.runtime.shift_record import (KeptRecord, ShiftRecord, open_record, read_record,
                                                    take_in_unsaved, unsaved_beside)


def _truck(number, fault_end=math.nan):
    passes = [Pass(number, k, 10.0 * k, 10.0 * k + 5, 10.0 * k + 4, 4000.0 + 10 * number + k, 20.0, "ok", "", 4000.0)
              for k in (1, 2)] + [Pass(number, 3, 40.0, 45.0, None, None, None, "not_weighed", "moving")]
    faults = [{"spn": 520300, "fmi": 2, "signal": "boom_head_pressure", "kind": "stuck", "start": 12.0,
               "end": fault_end}]
    return Truck(number, passes, target=8000.0, start=100.0 * number, faults=faults)


def _failed_shift(tmp_path):
    """A live shift whose record turned read-only after truck 1: trucks 2 and 3 kept in the file."""
    path = tmp_path / "s.sqlite"
    kept = KeptRecord(ShiftRecord(path))
    run = kept.start_run("live can0", "bus", "model")
    kept.write_truck("live can0", run, _truck(1))
    writable, kept.record.db = kept.record.db, sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    kept.write_truck("live can0", run, _truck(2, fault_end=15.0))
    kept.write_truck("live can0", run, _truck(3))
    kept.finish_run(run)
    line = kept.lost_line()
    kept.record.db.close()
    writable.close()
    assert kept.fallback == unsaved_beside(path) and "takes them in" in line
    return path


def test_the_next_report_takes_the_kept_trucks_in_as_the_shift_had_them(tmp_path, capsys):
    path = _failed_shift(tmp_path)
    assert list(read_record(path)[1]["truck"]) == [1]
    assert main(["report", "--db", str(path), "--out", str(tmp_path / "r")]) == 0
    out = capsys.readouterr().out
    assert "2 kept truck(s) of run 1 (6 passes, 16,106 kg) taken into" in out
    assert not unsaved_beside(path).exists()
    passes, trucks = read_record(path)
    assert list(trucks["truck"]) == [1, 2, 3] and len(passes) == 9
    assert list(trucks["total"]) == pytest.approx([8023.0, 8043.0, 8063.0])
    assert list(trucks["unweighed"]) == [1, 1, 1] and list(trucks["start"]) == [100.0, 200.0, 300.0]
    faults = passes.attrs["faults"]
    assert [f["truck"] for f in faults] == [1, 2, 3] and [f["kind"] for f in faults] == ["stuck"] * 3
    assert math.isnan(faults[0]["end"]) and faults[1]["end"] == 15.0 and math.isnan(faults[2]["end"])
    assert "- trucks: 3" in (tmp_path / "r" / "shift.md").read_text(encoding="utf-8")


def test_a_file_elsewhere_is_taken_in_by_kept_and_a_later_runs_truck_is_left(tmp_path, capsys):
    path = _failed_shift(tmp_path)
    elsewhere = tmp_path / "tmp" / "s-123.unsaved.json"
    elsewhere.parent.mkdir()
    unsaved_beside(path).replace(elsewhere)
    record = ShiftRecord(path)  # a later run of the same session wrote truck 3 since
    later = record.start_run("live can0", "bus", "model")
    record.write_truck("live can0", later, Truck(3, [Pass(3, 1, 1.0, 2.0, 1.5, 1234.0, 9.0, "ok")]))
    record.close()
    assert main(["report", "--db", str(path), "--kept", str(elsewhere), "--out", str(tmp_path / "r")]) == 0
    out = capsys.readouterr().out
    assert "1 kept truck(s) of run 1" in out and "truck(s) 3 left as a later run recorded them" in out
    _, trucks = read_record(path)
    assert list(trucks["total"]) == pytest.approx([8023.0, 8043.0, 1234.0]) and not elsewhere.exists()


def test_loadout_takes_the_kept_trucks_in_before_it_weighs(tmp_path):
    path = _failed_shift(tmp_path)
    lines = []
    open_record(path, say=lines.append).close()
    assert len(lines) == 1 and "taken into" in lines[0] and not unsaved_beside(path).exists()


@pytest.mark.parametrize("body, message", [
    ("{not json", "not a file of a live shift's kept trucks"),
    ('{"trucks": []}', "needs 'source', 'run' and 'trucks'"),
    ('{"source": "live can0", "run": 7, "trucks": [], "record": "/x/other.sqlite"}',
     "holds run 7 of the record '/x/other.sqlite', which --db"),
    ('{"source": "live can0", "run": 1, "trucks": [{"truck": 2, "passes": [{"index": 1}]}]}', "lacks truck, time_dig"),
    ('{"source": "live can0", "run": 1, "trucks": [{"truck": 2, "passes": [{"truck": 2, "index": 1, "time_dig": 1, '
     '"time_dump": 2, "time_lock": 1.5, "weight": "heavy", "sigma": 1, "status": "ok"}]}]}', "'weight' is 'heavy'"),
    ('{"source": "live can0", "run": 1, "trucks": [{"truck": 0, "passes": []}]}', "truck entry 1 is not a kept truck"),
    ('{"source": "live can0", "run": 1, "trucks": [{"truck": 2, "passes": [{"truck": 2, "index": "x", "time_dig": 1, '
     '"time_dump": 2, "time_lock": 1.5, "weight": 1, "sigma": 1, "status": "ok"}]}]}', "has the number 'x'"),
    ('{"source": "live can0", "run": 1, "trucks": [{"truck": 2, "passes": [], "faults": [{"spn": "a", "fmi": 2, '
     '"signal": "s", "kind": "stuck", "start": 1}]}]}', "has spn 'a'"),
    ('[1, 2]', "needs 'source', 'run' and 'trucks'"),
])
def test_a_damaged_or_foreign_kept_file_is_one_line_and_the_record_untouched(tmp_path, capsys, body, message):
    path = tmp_path / "s.sqlite"
    record = ShiftRecord(path)
    run = record.start_run("live can0", "bus", "model")
    record.write_truck("live can0", run, _truck(1))
    record.close()
    bad = tmp_path / "bad.unsaved.json"
    bad.write_text(body, encoding="utf-8")
    with pytest.raises(DatasetError, match=message.replace("(", r"\(").replace(")", r"\)")):
        take_in_unsaved(ShiftRecord(path), bad)
    assert main(["report", "--db", str(path), "--kept", str(bad), "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and bad.exists()
    assert list(read_record(path)[1]["truck"]) == [1]


def test_kept_without_db_is_refused(tmp_path, capsys):
    assert main(["report", "--data", str(tmp_path / "x.parquet"), "--kept", str(tmp_path / "k.json"),
                 "--out", str(tmp_path / "r")]) == 2
    assert "--kept goes with --db" in capsys.readouterr().err


def test_a_read_only_record_with_a_kept_file_still_reports_and_keeps_the_file(tmp_path, capsys):
    path = _failed_shift(tmp_path)
    bad = unsaved_beside(path)
    body = json.loads(bad.read_text())
    body["trucks"][0]["passes"][0]["status"] = "great"  # cannot be taken in: the report goes on
    bad.write_text(json.dumps(body))
    assert main(["report", "--db", str(path), "--out", str(tmp_path / "r")]) == 0
    captured = capsys.readouterr()
    assert "warning:" in captured.err and "'great'" in captured.err and bad.exists()
    assert "- trucks: 1" in (tmp_path / "r" / "shift.md").read_text(encoding="utf-8")
