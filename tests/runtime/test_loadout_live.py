"""Loadout on a live bus (issue 30): truck changes by a 30 s gap in the arm's frames, the API
and the operator's button; the J1939 pass and truck messages on a python-can virtual bus."""

import math
import sys
import threading
import time
from pathlib import Path

import can
import pytest

from excavator_payload.estimators.base import load_estimator
from excavator_payload.runtime import dbc
from excavator_payload.runtime.can_sensor import PayloadSensor
from excavator_payload.runtime.codec import SignalCodec
from excavator_payload.runtime.loadout import _truth_match
from excavator_payload.runtime.loadout_bus import BusLoadout, TruckButton, decode_loadout
from excavator_payload.runtime.loadout_live import run_live
from excavator_payload.runtime.logs import read_frames

sys.path.insert(0, str(Path(__file__).parent))
from field_bus import DROPOUT, field_shift_log, foreign_frames, make_shift  # noqa: E402



@pytest.fixture(scope="module")
def shift(tmp_path_factory):
    """A calibrated model, a shift of two trucks (a dropout of bucket_rod_pressure after truck
    1's last dump), and the field layout's DBC and map."""
    return make_shift(tmp_path_factory.mktemp("loadout"))



def _sensor_frames(shift, tmp_path, experiment):
    """The field layout's frames of one truck (no button, no foreign traffic)."""
    folder, trucks, dbc_path, map_path = shift
    one = trucks.subset([experiment])
    log = tmp_path / f"truck{experiment}.blf"
    field_shift_log(one, log, dbc_path, map_path, jitter=0.0, press=False, foreign=False)
    return list(read_frames(log))



def _loadout(shift, **kwargs):
    folder, trucks, dbc_path, map_path = shift
    estimator = load_estimator(folder / "model")
    sensor = PayloadSensor(estimator, SignalCodec.from_files(estimator.sensor_set, dbc_path, map_path))
    return BusLoadout(sensor, target=8000.0, **kwargs)




def _quit(keys, run) -> None:
    """Type `q` at the live command's keyboard and wait for it to end."""
    keys.write("q\n")
    keys.flush()
    run.join(60)


def _close(keys, run, feeder) -> None:
    """Whatever happened: the keyboard closed, the command's thread joined, the feeder stopped."""
    keys.close()
    run.join(60)
    feeder.shutdown()

def test_a_30s_gap_in_the_arms_frames_or_the_api_starts_a_truck(shift, tmp_path):
    """Truck 1's log with a 31 s silence of the arm between its passes, another ECU's traffic
    all through it: two trucks of one pass each; the API call at the same place: the same."""
    frames = _sensor_frames(shift, tmp_path, 0)
    meta = shift[1].experiment_meta[0]["passes"]
    split = frames[0].timestamp + 0.5 * (meta[0]["release"][1] + meta[1]["fill"][0])
    moved = [can.Message(timestamp=f.timestamp + (31.0 if f.timestamp > split else 0.0),
                         arbitration_id=f.arbitration_id, is_extended_id=True, data=f.data) for f in frames]
    traffic = foreign_frames(frames[0].timestamp, moved[-1].timestamp)
    by_gap = _loadout(shift)
    for f in sorted(moved + traffic, key=lambda m: m.timestamp):
        by_gap.feed(f, f.timestamp)
    trucks = by_gap.finish()
    assert by_gap.gaps == 1 and [len(t.passes) for t in trucks] == [1, 1]
    by_api = _loadout(shift)
    for f in frames:
        if f.timestamp > split and len(by_api.trucks) == 0:
            by_api.new_truck()
        by_api.feed(f, f.timestamp)
    api = by_api.finish()
    assert [len(t.passes) for t in api] == [1, 1]
    assert all(abs(a.total - b.total) < 1e-6 for a, b in zip(trucks, api))



def test_the_button_press_is_an_edge():
    button = TruckButton.default()
    presses = [button.press(button.frame(pressed, t)) for t, pressed in
               [(0.0, True), (0.1, True), (0.2, False), (0.3, True), (5.0, True), (9.0, False)]]
    # held (0.1) is the same press; released and pressed again is a new one; an event message
    # repeated after PRESS_HOLD is a new one
    assert presses == [True, False, False, True, True, False]
    other = button.frame(True, 10.0)
    other.arbitration_id = (other.arbitration_id & ~0xFF) | 0x33  # another ECU's PGN 0xFF83
    assert not button.matches(other)



def test_live_virtual_bus_sends_pass_and_truck_messages(shift, tmp_path):
    """Truck 2's frames played onto a python-can virtual bus (timestamps kept), the operator's
    button at the end: the loadout on the same bus locks each pass and sends LoadoutPass and
    LoadoutTruck with what it locked; the passes are the true ones, weighed within 150 kg."""
    frames = _sensor_frames(shift, tmp_path, 1)
    button = TruckButton.default()
    channel = f"loadout-test-{id(frames)}"
    feeder = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
    listener = can.Bus(interface="virtual", channel=channel)
    bus = can.Bus(interface="virtual", channel=channel)
    loadout = _loadout(shift, send=True)
    stop = threading.Event()
    result = {}
    worker = threading.Thread(target=lambda: result.update(run_live(bus, loadout, stop)))
    worker.start()
    try:
        for f in frames + [button.frame(True, frames[-1].timestamp + 1.0)]:
            feeder.send(f)
        deadline = time.monotonic() + 60
        while len(loadout.trucks) < 1 and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        stop.set()
        worker.join(10)
        bus.shutdown()
    sent = []
    while (m := listener.recv(timeout=0.2)) is not None:
        decoded = decode_loadout(m)
        if decoded is not None:
            sent.append(decoded)
    feeder.shutdown()
    listener.shutdown()
    assert len(loadout.trucks) == 1 and result["bus_errors"] == 0
    truck = loadout.trucks[0]
    passes = [d for d in sent if d["message"] == dbc.LOADOUT_PASS_MESSAGE]
    totals = [d for d in sent if d["message"] == dbc.LOADOUT_TRUCK_MESSAGE]
    assert [int(d["PassNumber"]) for d in passes] == [p.index for p in truck.passes]
    for d, p in zip(passes, truck.passes):
        assert abs(d["PassWeight"] - p.weight) <= 0.25 and d["PassStatus"] == 0
    assert abs(totals[-1]["TruckTotal"] - truck.total) <= 1.0 and totals[-1]["TruckTarget"] == 8000.0
    truth = shift[1].experiment_meta[1]["passes"]
    assert _truth_match(truck.passes, truth) == len(truth) == len(truck.passes)
    # a 4-swing calibration (docs/loadout.md measures the 1 % on a 10-swing one)
    assert all(abs(p.weight - p.true_weight) < 150.0 for p in truck.passes)



def test_loadout_messages_in_the_dbc_keep_the_old_ids_and_flag_bad_values():
    db = dbc.estimate_database()
    assert db.get_message_by_name("PayloadEstimate").frame_id == 0x18FF80A1
    assert db.get_message_by_name("VehicleWeight").frame_id == 0x18FEEAA1
    assert db.get_message_by_name("LoadoutControl").frame_id & 0xFF == dbc.OPERATOR_ADDRESS
    from excavator_payload.runtime.loadout import Pass, Truck
    from excavator_payload.runtime.loadout_bus import _Publisher

    truck = Truck(3, target=None)
    truck.passes = [Pass(3, 1, 1.0, 2.0, None, None, None, "not_weighed"),
                    Pass(3, 2, 3.0, 4.0, 3.5, -9000.0, 5.0, "ok"),
                    Pass(3, 3, 5.0, 6.0, 5.5, 2100.0, 12.0, "degraded", "weighed without boom_rate:dropout")]
    pub = _Publisher()
    unweighed, impossible, degraded = (decode_loadout(pub.pass_frames(truck, p)[0]) for p in truck.passes)
    assert degraded["PassStatus"] == 2 and degraded["PassWeight"] == 2100.0
    assert math.isnan(unweighed["PassWeight"]) and unweighed["PassStatus"] == 1
    assert math.isnan(impossible["PassWeight"]) and impossible["PassSigma"] == 5.0
    total = decode_loadout(pub.truck_frame(truck))
    assert math.isnan(total["TruckTarget"]) and total["TruckUnweighed"] == 1


def test_the_live_command_runs_on_a_virtual_bus_and_stops(shift, tmp_path):
    """`loadout --interface virtual --channel … --duration`: one truck's first seconds played on
    the bus while it runs; it stops by itself, closes the truck and records the run."""
    import sqlite3

    from excavator_payload.cli import main

    frames = _sensor_frames(shift, tmp_path, 0)[:4000]  # the first ~0.5 s of the truck
    channel = f"loadout-cli-{id(frames)}"
    feeder = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)

    def play():
        from can.interfaces.virtual import channels

        deadline = time.monotonic() + 60
        while len(channels.get(channel, ())) < 2 and time.monotonic() < deadline:
            time.sleep(0.05)  # until the command has opened its bus (frames before are lost)
        for f in frames:
            feeder.send(f)

    player = threading.Thread(target=play)
    player.start()
    try:
        code = main(["loadout", "--model", str(shift[0] / "model"), "--interface", "virtual", "--channel", channel,
                     "--duration", "6", "--db", str(tmp_path / "live.sqlite"), "--target", "8000"])
    finally:
        player.join()
        feeder.shutdown()
    assert code == 0
    with sqlite3.connect(tmp_path / "live.sqlite") as con:
        runs = con.execute("SELECT source, finished FROM runs").fetchall()
        trucks = con.execute("SELECT truck, passes, target, start FROM trucks").fetchall()
    assert len(runs) == 1 and runs[0][0].startswith(f"live virtual:{channel}") and runs[0][1] is not None
    # no pass in half a second, but the truck that began is recorded, with its start on the bus's clock
    assert trucks == [(1, 0, 8000.0, pytest.approx(frames[0].timestamp, abs=0.05))]


def _first_pass(shift, tmp_path, experiment, offset):
    """The field frames of one truck up to 1 s after its first pass's dump, ``offset`` s later."""
    frames = _sensor_frames(shift, tmp_path, experiment)
    start = frames[0].timestamp
    end = start + shift[1].experiment_meta[experiment]["passes"][0]["release"][1] + 1.0
    return [can.Message(timestamp=f.timestamp - start + offset, arbitration_id=f.arbitration_id,
                        is_extended_id=True, data=f.data) for f in frames if f.timestamp <= end]


def test_the_operator_closes_a_truck_and_ends_the_shift_from_the_terminal(shift, tmp_path, monkeypatch, capsys):
    """`loadout --interface virtual …` with its stdin a pipe: truck 1's first pass, then `t` +
    Enter, truck 2's first pass 5 s later on the bus's clock (no 30 s gap, no button: only the
    command separates them), then `q` + Enter: two trucks of one pass each, recorded, the run
    finished long before --duration."""
    import os
    import sqlite3

    from can.interfaces.virtual import channels

    from excavator_payload.cli import main

    first = _first_pass(shift, tmp_path, 0, 0.0)
    second = _first_pass(shift, tmp_path, 1, first[-1].timestamp + 5.0)
    channel = f"loadout-keys-{id(first)}"
    feeder = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
    read_end, write_end = os.pipe()
    monkeypatch.setattr(sys, "stdin", os.fdopen(read_end, "r"))
    keys = os.fdopen(write_end, "w")
    db = tmp_path / "keys.sqlite"
    result = {}
    run = threading.Thread(target=lambda: result.update(code=main([
        "loadout", "--model", str(shift[0] / "model"), "--interface", "virtual", "--channel", channel,
        "--dbc", str(shift[2]), "--signal-map", str(shift[3]), "--duration", "300", "--db", str(db),
        "--target", "8000"])))

    def wait(condition, what):
        deadline = time.monotonic() + 120
        while not condition():
            assert time.monotonic() < deadline and run.is_alive(), f"waited for {what}"
            time.sleep(0.05)

    def drained():  # every frame played has been read by the command's bus
        return all(q.empty() for q in channels.get(channel, ()) if q is not feeder.queue)

    closed = [0]  # LoadoutTruck frames the command has sent (at each pass lock and truck change)

    def truck_frames():
        while (m := feeder.recv(timeout=0)) is not None:
            decoded = decode_loadout(m)
            closed[0] += decoded is not None and decoded["message"] == dbc.LOADOUT_TRUCK_MESSAGE
        return closed[0]

    def trucks():
        if not db.exists():
            return []
        with sqlite3.connect(db) as con:
            return con.execute("SELECT truck, passes FROM trucks ORDER BY truck").fetchall()

    started = time.monotonic()
    run.start()
    try:
        wait(lambda: len(channels.get(channel, ())) >= 2, "the command's bus")
        for f in first:
            feeder.send(f)
        wait(drained, "truck 1's frames")
        wait(lambda: trucks() == [(1, 1)], "truck 1's pass")
        wait(lambda: truck_frames() == 1, "truck 1's LoadoutTruck at its pass")
        keys.write("t\n")
        keys.flush()
        # the command taken: truck 1 closed and its total sent before truck 2's frames come
        wait(lambda: truck_frames() == 2, "truck 1's LoadoutTruck at the command")
        for f in second:
            feeder.send(f)
        wait(drained, "truck 2's frames")
        wait(lambda: [t for t, _ in trucks()] == [1, 2] and trucks()[1][1] == 1, "truck 2's pass")
        _quit(keys, run)
    finally:
        _close(keys, run, feeder)
    assert not run.is_alive() and result["code"] == 0 and time.monotonic() - started < 300
    assert trucks() == [(1, 1), (2, 1)]
    with sqlite3.connect(db) as con:
        assert con.execute("SELECT COUNT(*) FROM runs WHERE finished IS NOT NULL").fetchone() == (1,)
        statuses = con.execute("SELECT status FROM passes").fetchall()
    assert statuses == [("ok",), ("ok",)]
    out = " ".join(capsys.readouterr().out.split())
    assert "t + Enter: next truck · q + Enter: end the shift (recorded)" in out  # the view's footer
    assert "0 button presses, 0 gaps of 30 s or more, 1 from the terminal" in out


def test_a_live_run_without_a_terminal_runs_as_before(shift, tmp_path, monkeypatch, capsys):
    """stdin at its end (a service, `< /dev/null`): no commands, no error; the view's footer
    says only Ctrl-C; an unknown line from a pipe is one line of help, not an error."""
    import io

    from excavator_payload.cli import main

    monkeypatch.setattr(sys, "stdin", io.StringIO(""))
    code = main(["loadout", "--model", str(shift[0] / "model"), "--interface", "virtual", "--channel",
                 f"loadout-nokeys-{id(tmp_path)}", "--duration", "1", "--db", str(tmp_path / "n.sqlite")])
    out = capsys.readouterr().out
    footers = [line.strip() for line in out.splitlines() if "Ctrl-C" in line]
    assert code == 0 and footers[-1] == "Ctrl-C: stop", out
    monkeypatch.setattr(sys, "stdin", io.StringIO("x\n"))
    code = main(["loadout", "--model", str(shift[0] / "model"), "--interface", "virtual", "--channel",
                 f"loadout-nokeys-{id(tmp_path)}", "--duration", "1", "--db", str(tmp_path / "n.sqlite")])
    out = " ".join(capsys.readouterr().out.split())
    assert code == 0 and "unknown command 'x': t = next truck, q = end the shift" in out


def test_a_fault_ended_by_a_silent_bus_ends_on_the_frames_clock(shift, tmp_path):
    """Live, the receiver's clock (monotonic) is not the frames' (the logger's or the bus's
    epoch): truck 1's frames up to the middle of its bucket_rod_pressure dropout, received 5000 s
    "later", then the bus silent for 2 s (a stale tick ends the fault). The fault episodes lie
    within the truck's own time, not 5000 s after it."""
    frames = _sensor_frames(shift, tmp_path, 0)
    last = frames[-1].timestamp
    frames = [f for f in frames if f.timestamp <= last - 0.5 * sum(DROPOUT)]  # the bus falls silent in it
    loadout = _loadout(shift, send=True)
    skew = 5000.0
    for f in frames:
        loadout.feed(f, f.timestamp + skew)
    end = frames[-1].timestamp + skew
    for k in range(1, 21):
        loadout.poll(end + 0.1 * k)
    (truck,) = loadout.finish()
    length = frames[-1].timestamp - frames[0].timestamp
    assert truck.faults and all(-1.0 <= f["start"] <= f["end"] <= length + 3.0 for f in truck.faults), truck.faults


def test_commands_are_read_only_from_a_stream_that_can_give_them():
    """A pipe or a text stream gives commands; no stdin or a closed one does not (a terminal of a
    background job neither: reading it would stop the process, and the bus with it)."""
    import io
    import os
    import queue

    from excavator_payload.runtime.loadout_live import read_commands, readable_commands, terminal_keys

    read_end, write_end = os.pipe()
    pipe = os.fdopen(read_end)
    os.close(write_end)
    assert readable_commands(pipe) and terminal_keys(pipe) is None  # a pipe: lines, no cbreak
    commands = queue.Queue()
    read_commands(pipe, commands)  # at its end at once: no command, the end marked
    assert commands.get_nowait() is None
    pipe.close()
    assert not readable_commands(pipe) and not readable_commands(None)
    commands = queue.Queue()
    unknown = []
    read_commands(io.StringIO("T\n\nquit\nx\ntruck\n"), commands, unknown.append)
    assert [commands.get_nowait() for _ in range(4)] == ["truck", "quit", "truck", None] and unknown == ["x"]


def test_one_key_is_one_command():
    """In cbreak mode (``keys``) every key is a command, read from the file descriptor as it is
    pressed: case does not matter, a space or Enter is nothing, any other key is unknown."""
    import os
    import queue

    from excavator_payload.runtime.loadout_live import read_commands

    read_end, write_end = os.pipe()
    os.write(write_end, b"tQX \nT\xff")
    os.close(write_end)
    commands, unknown = queue.Queue(), []
    with os.fdopen(read_end) as pipe:
        read_commands(pipe, commands, unknown.append, keys=True)
    assert [commands.get_nowait() for _ in range(4)] == ["truck", "quit", "truck", None]
    assert unknown == ["x", "\ufffd"] and commands.empty()


def test_live_loadout_bus_lost_and_back(shift, caplog):
    """``loadout --interface`` runs on the same link as can-run: an interface gone for 1.5 s is
    one "lost" and one "back" line, counted, and nothing is sent while it is lost (the failing
    bus of ``test_can_recovery``: python-can's virtual bus raising what socketcan raises)."""
    import logging

    from tests.runtime.test_can_recovery import SENT, WINDOWS, FailingVirtualBus

    channel = f"recovery-loadout-{time.monotonic_ns()}"
    WINDOWS[channel] = {"recv": (0.0, 1.5), "open": (0.1, 1.5)}
    bus = FailingVirtualBus(channel=channel)
    loadout = _loadout(shift, send=True)
    stop = threading.Event()
    caplog.set_level(logging.WARNING)
    timer = threading.Timer(3.5, stop.set)
    timer.start()
    try:
        counters = run_live(bus, loadout, stop, bus_factory=lambda: FailingVirtualBus(channel=channel),
                            name=f"virtual:{channel}")
    finally:
        timer.cancel()
        bus.shutdown()
    lines = [r.getMessage() for r in caplog.records
             if r.levelno >= logging.WARNING and channel in r.getMessage()]
    assert len(lines) == 2 and "lost" in lines[0] and "back" in lines[1]
    assert counters["bus_lost"] == 1 and 1.0 <= counters["bus_lost_seconds"] <= 3.0
    # stale estimates at the sample rate while the bus was up (≤ 2 s of 3.5 s), none while lost
    rate = loadout.sensor.estimator.sensor_set.sample_rate
    assert 0 < len(SENT.get(channel, [])) <= 2 * 2.0 * rate


def test_a_live_shift_whose_record_fails_keeps_the_truck_in_hand(shift, tmp_path, monkeypatch, capsys):
    """`loadout --interface virtual …` whose record cannot be written once the shift runs (every
    truck write raises SQLite's "database or disk is full"): the shift goes on, truck 1's pass is
    weighed, shown and kept in ``<record>.unsaved.json``; the end (`q`) is one error line (exit 2)
    naming the record, the failure, the truck's totals and the file (the run stopped at the
    first pass and the truck in hand was lost)."""
    import json
    import os
    import sqlite3

    from can.interfaces.virtual import channels

    from excavator_payload.cli import main
    from excavator_payload.runtime import shift_record

    def full(self, source, run, truck):
        raise shift_record.record_error(self.path, sqlite3.OperationalError("database or disk is full"),
                                        f"write truck {truck.truck} to")

    monkeypatch.setattr(shift_record.ShiftRecord, "write_truck", full)
    read_end, write_end = os.pipe()
    monkeypatch.setattr(sys, "stdin", os.fdopen(read_end, "r"))
    keys = os.fdopen(write_end, "w")
    first = _first_pass(shift, tmp_path, 0, 0.0)
    channel = f"loadout-full-{id(first)}"
    feeder = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
    db = tmp_path / "full.sqlite"
    result = {}
    run = threading.Thread(target=lambda: result.update(code=main([
        "loadout", "--model", str(shift[0] / "model"), "--interface", "virtual", "--channel", channel,
        "--dbc", str(shift[2]), "--signal-map", str(shift[3]), "--duration", "300", "--db", str(db),
        "--target", "8000"])))
    weighed = [0]

    def wait(condition, what):
        deadline = time.monotonic() + 120
        while not condition():
            assert time.monotonic() < deadline and run.is_alive(), f"waited for {what}"
            time.sleep(0.05)

    def pass_sent():  # the LoadoutPass frame the command sends when it weighs the pass
        while (m := feeder.recv(timeout=0)) is not None:
            decoded = decode_loadout(m)
            weighed[0] += decoded is not None and decoded["message"] == dbc.LOADOUT_PASS_MESSAGE
        return weighed[0] >= 1

    run.start()
    try:
        wait(lambda: len(channels.get(channel, ())) >= 2, "the command's bus")
        for f in first:
            feeder.send(f)
        wait(pass_sent, "truck 1's pass")  # the shift went on after the failed write
        _quit(keys, run)
    finally:
        _close(keys, run, feeder)
    assert not run.is_alive() and result["code"] == 2
    fallback = tmp_path / "full.sqlite.unsaved.json"
    body = json.loads(fallback.read_text())
    (truck,) = body["trucks"]
    assert truck["truck"] == 1 and len(truck["passes"]) == 1 and truck["passes"][0]["status"] == "ok"
    assert truck["total"] == pytest.approx(truck["passes"][0]["weight"]) and truck["total"] > 1000
    out = capsys.readouterr()
    lines = [line for line in out.err.splitlines()
             if line.strip() and not line.startswith("--db") and "never zeroed" not in line]  # unzeroed model
    assert len(lines) == 1 and lines[0].startswith("error: --db"), out.err
    assert "the disk failed or is full" in lines[0] and f"kept in '{fallback}'" in lines[0]
    assert f"1 truck(s) not in it (1 passes, {truck['total']:,.0f} kg)" in lines[0]
    assert f"truck 1: 1 passes, total {truck['total']:,.0f} kg" in " ".join(out.out.split())  # shown


def test_the_cab_view_says_when_the_record_fails(shift, tmp_path):
    """A live record that cannot be written: the view's first line says so in red, with where the
    trucks are kept."""
    import sqlite3

    from rich.console import Console

    from excavator_payload.runtime.loadout_live import live_view
    from excavator_payload.runtime.shift_record import KeptRecord, ShiftRecord

    record = KeptRecord(ShiftRecord(tmp_path / "v.sqlite"))
    loadout = _loadout(shift, record=record, source="live")
    console = Console(width=400, record=True)
    console.print(live_view(loadout))
    assert "NOT RECORDED" not in console.export_text()
    record.record.db.close()
    record.record.db = sqlite3.connect(f"file:{tmp_path / 'v.sqlite'}?mode=ro", uri=True)
    loadout.new_truck()  # nothing loaded: no truck, no write
    from excavator_payload.runtime.loadout import Truck

    record.write_truck("live", loadout.run, Truck(1, [], target=8000.0))
    console.print(live_view(loadout))
    text = " ".join(console.export_text().split())
    assert "NOT RECORDED: --db" in text and "read-only" in text and "v.sqlite.unsaved.json" in text
    record.close()
