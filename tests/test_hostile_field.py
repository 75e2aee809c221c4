"""Hostile field input, fifth round (2026-11-29, session 20): one test per class of failure found,
each failing on the code before its fix (docs/findings/hardening.md, "session 20").

* a named pipe (or device) given as a dataset hung for ever; as any other input it "did not exist";
* a write-ahead log beside a shift record that is not the record's own was applied to it by
  SQLite: ``loadout`` wrote into the other database, the record's trucks lost;
* a DBC saved with a byte-order mark (Notepad, PowerShell) was refused;
* a rate of the wrong sign passed every check (no estimate, or a weighing without it, and no word
  why); two swapped rates were called "in °/s";
* a log of two bridged channels (each sensor frame twice, the copy a few ms later) was refused
  as a log at the wrong rate; a DBC message longer than its frames (J1939 TP) was "out of range";
* one frame's glitched timestamp refused the whole log; a CSV log with hex data was refused;
* known loads in pounds were calibrated into a machine twice as heavy and weighed 2.2 times.
"""

from __future__ import annotations

import codecs
import os
import shutil
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from excavator_payload.cli import main
from excavator_payload.data.io import read_dataset, write_dataset
from excavator_payload.errors import DatasetError

pytestmark = pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="named pipes need a POSIX system")


def _cli_process(*args: str, timeout: float = 60.0) -> subprocess.CompletedProcess:
    """The command in a real process (a hang is a failed test, not a stuck suite)."""
    import excavator_payload

    src = str(Path(excavator_payload.__file__).resolve().parents[1])  # the code this test runs on
    env = {**os.environ, "PYTHONPATH": src + os.pathsep + os.environ.get("PYTHONPATH", "")}
    return subprocess.run([sys.executable, "-c", "import sys; from excavator_payload.cli import main; "
                           "sys.exit(main(sys.argv[1:]))", *args], capture_output=True, text=True,
                          timeout=timeout, env=env)


@pytest.fixture(scope="module")
def swings(tmp_path_factory):
    """Two hydraulic-machine swings (field noise, 100 Hz) and their Parquet file."""
    from excavator_payload.simulation.machine_sim import simulate_machine_dataset

    data = simulate_machine_dataset(2, seed=4)
    path = tmp_path_factory.mktemp("swings") / "swings.parquet"
    write_dataset(data, path)
    return data, path


# -- a named pipe as an input file ------------------------------------------------------------
def test_a_named_pipe_as_a_dataset_is_one_line_not_a_hang(tmp_path):
    pipe = tmp_path / "data.parquet"
    os.mkfifo(pipe)
    try:
        done = _cli_process("evaluate", "--model", str(tmp_path / "no-model"), "--data", str(pipe), timeout=60)
    except subprocess.TimeoutExpired:
        pytest.fail("reading a named pipe as a dataset hung")
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert done.returncode == 2 and len(lines) == 1, done.stderr
    assert "named pipe" in lines[0] and "Traceback" not in done.stderr


@pytest.mark.parametrize("what", ["dbc", "signal map", "log", "machine file", "trajectory"])
def test_a_named_pipe_as_another_input_is_named_as_one(tmp_path, what):
    """They said "does not exist" of a path that does."""
    from excavator_payload.errors import ExcavatorPayloadError
    from excavator_payload.model.machine import load_machine
    from excavator_payload.runtime.codec import read_signal_map
    from excavator_payload.runtime.dbc import load_dbc
    from excavator_payload.runtime.logs import read_frames
    from excavator_payload.simulation.trajectory import read_trajectory

    readers = {"dbc": ("m.dbc", load_dbc), "signal map": ("m.toml", read_signal_map),
               "log": ("l.blf", lambda p: list(read_frames(p))), "machine file": ("m.toml", load_machine),
               "trajectory": ("t.parquet", read_trajectory)}
    name, reader = readers[what]
    pipe = tmp_path / name
    os.mkfifo(pipe)
    with pytest.raises(ExcavatorPayloadError, match="named pipe") as info:
        reader(pipe)
    assert "does not exist" not in str(info.value)


# -- a write-ahead log that is not the record's -----------------------------------------------
def _foreign_wal(beside: Path) -> None:
    """Leave another database's write-ahead log as ``<beside>-wal`` (its writer never closed)."""
    code = ("import sqlite3, shutil, os, sys; d = sys.argv[1]; con = sqlite3.connect(d + '.other'); "
            "con.execute('pragma journal_mode=wal'); con.execute('create table t(a)'); "
            "con.execute('insert into t values (1)'); con.commit(); "
            "shutil.copy(d + '.other-wal', d + '-wal'); os._exit(0)")
    subprocess.run([sys.executable, "-c", code, str(beside)], check=True, timeout=60)


def test_a_foreign_wal_beside_the_record_is_refused_and_the_record_kept(tmp_path, capsys):
    from excavator_payload.runtime.shift_record import ShiftRecord, read_record

    db = tmp_path / "shift.sqlite"
    record = ShiftRecord(db)
    run = record.start_run("abc", "shift.parquet", "model")
    record.finish_run(run)
    record.close()
    before = db.read_bytes()
    _foreign_wal(db)
    assert (tmp_path / "shift.sqlite-wal").stat().st_size > 0
    # loadout opened it and wrote its passes into the other database (the record's runs gone)
    with pytest.raises(DatasetError, match="write-ahead log that is not this record's"):
        ShiftRecord(db)
    with pytest.raises(DatasetError, match="write-ahead log"):
        read_record(db)
    assert main(["report", "--db", str(db), "--out", str(tmp_path / "report")]) == 2
    assert "shift.sqlite-wal" in capsys.readouterr().err
    assert db.read_bytes() == before
    (tmp_path / "shift.sqlite-wal").unlink()
    with sqlite3.connect(db) as con:
        assert con.execute("SELECT COUNT(*) FROM runs").fetchone()[0] == 1


def test_a_foreign_wal_where_the_record_is_to_be_made_is_refused(tmp_path):
    from excavator_payload.runtime.shift_record import ShiftRecord

    db = tmp_path / "new.sqlite"
    _foreign_wal(db)
    with pytest.raises(DatasetError, match="does not exist yet"):
        ShiftRecord(db)
    assert not db.exists()


def test_the_records_own_wal_is_read(tmp_path):
    from excavator_payload.runtime.shift_record import ShiftRecord

    db = tmp_path / "wal.sqlite"
    ShiftRecord(db).close()
    with sqlite3.connect(db) as con:  # a record another tool put in WAL mode, its log still open
        con.execute("PRAGMA journal_mode=wal")
    keep = sqlite3.connect(db)
    keep.execute("INSERT INTO runs (source, data, model, rated, started) VALUES ('x', 'd', 'm', NULL, 0)")
    keep.commit()
    try:
        assert (tmp_path / "wal.sqlite-wal").is_file()
        ShiftRecord(db).close()
    finally:
        keep.close()


# -- a DBC saved with a byte-order mark -------------------------------------------------------
@pytest.mark.parametrize("encoding", ["utf-8-sig", "utf-16"])
def test_a_dbc_saved_with_a_byte_order_mark_is_read(tmp_path, encoding):
    from excavator_payload.runtime.dbc import generate_dbc, load_dbc

    text = generate_dbc("machine")
    path = tmp_path / "machine.dbc"
    path.write_bytes(text.replace("\n", "\r\n").encode(encoding))
    assert path.read_bytes().startswith((codecs.BOM_UTF8, codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE))
    plain = tmp_path / "plain.dbc"
    plain.write_text(text)
    assert [m.frame_id for m in load_dbc(path).messages] == [m.frame_id for m in load_dbc(plain).messages]


# -- a rate that is not its angle's -----------------------------------------------------------
def _unchecked(frame, like: Path, path: Path) -> Path:
    """``frame`` written as a Parquet dataset with ``like``'s metadata, unchecked (a file made
    by another tool)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    meta = {k: v for k, v in (pq.read_schema(like).metadata or {}).items() if k != b"pandas"}
    table = pa.Table.from_pandas(frame, preserve_index=False)
    pq.write_table(table.replace_schema_metadata({**(table.schema.metadata or {}), **meta}), path)
    return path


@pytest.mark.parametrize("rate", ["boom_rate", "dipper_rate", "bucket_rate"])
def test_a_rate_of_the_wrong_sign_is_one_line(swings, tmp_path, rate):
    data, _ = swings
    frame = data.frame.copy()
    frame[rate] = -frame[rate]
    path = _unchecked(frame, swings[1], tmp_path / "flipped.parquet")
    with pytest.raises(DatasetError, match=f"'{rate}' runs against .*wrong sign.*Flip its sign"):
        read_dataset(path)


def test_two_swapped_rates_are_not_called_degrees(swings, tmp_path):
    data, _ = swings
    frame = data.frame.copy()
    frame["dipper_rate"], frame["bucket_rate"] = data.frame["bucket_rate"], data.frame["dipper_rate"]
    path = _unchecked(frame, swings[1], tmp_path / "swapped.parquet")
    with pytest.raises(DatasetError, match="another joint's rate") as info:
        read_dataset(path)
    assert "instead of rad/s" not in str(info.value)


def test_a_valid_dataset_still_reads(swings):
    _, path = swings
    assert len(read_dataset(path).frame) > 0


# -- the field bus: a log of two bridged channels, a DBC message longer than a frame -----------
@pytest.fixture(scope="module")
def model_and_log(swings, tmp_path_factory):
    """inverse-dynamics fitted on the swings (saved) and the swings as a BLF log."""
    from excavator_payload.estimators.base import create_estimator

    data, path = swings
    folder = tmp_path_factory.mktemp("bus")
    model = folder / "model"
    create_estimator("inverse-dynamics", machine="cat345c-hydraulic").fit(data).save(model)
    log = folder / "one.blf"
    assert main(["can-record", "--data", str(path), "--out", str(log)]) == 0
    return model, log


def test_a_log_of_two_bridged_channels_weighs_as_the_one_channel_log(model_and_log, tmp_path, capsys):
    import can

    from excavator_payload.data.io import read_estimates

    model, log = model_and_log
    frames = list(can.LogReader(str(log)))
    # a gateway forwards every sensor frame onto the logger's second channel 4 ms later
    echo = [can.Message(timestamp=m.timestamp + 0.004, arbitration_id=m.arbitration_id, is_extended_id=True,
                        data=m.data, channel=5) for m in frames]
    both = tmp_path / "two.blf"
    with can.Logger(str(both)) as writer:
        for m in sorted(frames + echo, key=lambda m: m.timestamp):
            writer.on_message_received(m)
    capsys.readouterr()
    assert main(["can-replay", "--log", str(log), "--model", str(model), "--out", str(tmp_path / "a.parquet")]) == 0
    assert main(["can-replay", "--log", str(both), "--model", str(model), "--out", str(tmp_path / "b.parquet")]) == 0
    said = " ".join(capsys.readouterr().out.split())
    assert f"{len(echo)} frames of the sensor messages on a second log channel" in said, said
    one, two = read_estimates(tmp_path / "a.parquet"), read_estimates(tmp_path / "b.parquet")
    assert list(one["status"]) == list(two["status"]) and (one["status"] == "ok").sum() > 500
    # the same estimates (the log's timestamps are rounded to the ns alike, not identically)
    np.testing.assert_allclose(one["payload_estimate"].to_numpy(), two["payload_estimate"].to_numpy(), atol=1e-3)


def test_a_dbc_message_longer_than_its_frames_is_named_with_the_transport_protocol(model_and_log, tmp_path, capsys):
    from excavator_payload.data.schema import get_sensor_set
    from excavator_payload.runtime.dbc import generate_dbc, sensor_layout

    model, log = model_and_log
    text = generate_dbc("machine").replace("MachineSensors8: 8", "MachineSensors8: 12")
    (tmp_path / "m.dbc").write_text(text)
    (tmp_path / "m.toml").write_text("".join(f'[signals.{s.signal}]\nmessage = "{s.message}"\nsignal = "{s.name}"\n'
                                             for m in sensor_layout(get_sensor_set("machine")) for s in m.signals))
    assert main(["can-replay", "--log", str(log), "--model", str(model), "--out", str(tmp_path / "e.parquet"),
                 "--dbc", str(tmp_path / "m.dbc"), "--signal-map", str(tmp_path / "m.toml")]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert "MachineSensors8 is 12 bytes in the DBC" in err and "transport protocol" in err, err


def test_one_frame_with_a_glitched_timestamp_is_skipped_not_the_whole_log(model_and_log, tmp_path, capsys):
    import can

    from excavator_payload.data.io import read_estimates

    model, log = model_and_log
    frames = list(can.LogReader(str(log)))
    k = len(frames) // 2
    bad = frames[k]
    frames[k] = can.Message(timestamp=bad.timestamp + 1e9, arbitration_id=bad.arbitration_id, is_extended_id=True,
                            data=bad.data, channel=bad.channel)
    glitched = tmp_path / "glitch.asc"
    with can.Logger(str(glitched)) as writer:
        for m in frames:
            writer.on_message_received(m)
    capsys.readouterr()
    # the whole log was refused: "its time goes back between … sensor frames"
    assert main(["can-replay", "--log", str(glitched), "--model", str(model), "--out", str(tmp_path / "g.parquet")]) == 0
    said = " ".join(capsys.readouterr().out.split())
    assert "1 unreadable log records skipped" in said, said
    got = read_estimates(tmp_path / "g.parquet")
    assert got["experiment"].nunique() == 2 and (got["status"] == "ok").sum() > 500


def test_two_clocks_interleaved_are_still_refused(tmp_path):
    import can

    from excavator_payload.runtime.logs import read_frames

    path = tmp_path / "two-clocks.asc"
    with can.Logger(str(path)) as writer:
        for k in range(200):  # a channel on epoch time between the frames of one counting from 0
            writer.on_message_received(can.Message(timestamp=0.01 * k + (1.7e9 if k % 2 else 0.0),
                                                   arbitration_id=0x18FF00A0, data=bytes(8), channel=1))
    with pytest.raises(DatasetError, match="two clocks"):
        list(read_frames(path))


# -- known loads in pounds --------------------------------------------------------------------
def test_known_loads_in_pounds_are_refused_by_the_calibration(machine_calibration):
    """2.2 times the loads stay below the 2x-the-largest-load check: the calibration scaled the
    machine file's masses and cylinder areas by 1.5-2, was saved, zeroed (±34 kg said) and weighed
    every load 2.2 times, `ok`."""
    from excavator_payload.data.dataset import Dataset
    from excavator_payload.estimators.base import create_estimator

    full = machine_calibration["cal"]  # 0, 2500 and 5000 kg: 11 t in pounds, caught by the 2x limit
    cal = Dataset(full.frame[full.frame["experiment"] < 2].reset_index(drop=True), full.meta)
    right = create_estimator("calibrated", "cat345c-hydraulic-3pct").fit(cal)
    assert not any("scale the machine file" in r for r in right.fit_refusals), right.fit_refusals
    frame = cal.frame.copy()
    frame["payload"] = frame["payload"] * 2.2046  # lb per kg
    pounds = create_estimator("calibrated", "cat345c-hydraulic-3pct").fit(Dataset(frame, cal.meta))
    said = " ".join(pounds.fit_refusals)
    assert "scale the machine file's link masses and cylinder areas" in said and "pounds" in said, said


def test_a_csv_log_with_hex_data_is_read_as_hex(model_and_log, tmp_path, capsys):
    """python-can's CSV holds base64; hex text is valid base64 too, so every 8-byte frame read as
    12 bytes of garbage and the log was refused as "out of the DBC's ranges"."""
    import base64

    from excavator_payload.data.io import read_estimates

    model, log = model_and_log
    assert main(["can-replay", "--log", str(log), "--model", str(model), "--out", str(tmp_path / "a.parquet")]) == 0
    written = tmp_path / "b64.csv"
    import can

    with can.Logger(str(written)) as writer:
        for m in can.LogReader(str(log)):
            writer.on_message_received(m)
    lines = written.read_text().splitlines()
    hexed = [lines[0]] + [",".join(f[:-1] + [base64.b64decode(f[-1]).hex()]) for f in (x.split(",") for x in lines[1:])]
    (tmp_path / "hex.csv").write_text("\n".join(hexed) + "\n")
    assert main(["can-replay", "--log", str(tmp_path / "hex.csv"), "--model", str(model),
                 "--out", str(tmp_path / "b.parquet")]) == 0
    one, two = read_estimates(tmp_path / "a.parquet"), read_estimates(tmp_path / "b.parquet")
    assert list(one["status"]) == list(two["status"]) and (one["status"] == "ok").sum() > 500
    np.testing.assert_allclose(one["payload_estimate"].to_numpy(), two["payload_estimate"].to_numpy(), atol=1e-3)
