"""``can-run`` on a bus that fails: a vanished interface is declared lost once, reopened and said
back; bus-off is waited out; the estimates after an outage are what the gap rule makes them.

The failing bus is python-can's own ``virtual`` interface with one change
(:class:`FailingVirtualBus`, registered as the interface ``failing-virtual`` as a python-can
plugin's entry point registers one): during a scheduled window its ``recv`` and/or ``send`` raise ``can.CanOperationError``
and opening it raises ``can.CanInitializationError``. That is what socketcan raises for a
vanished or downed interface ("Network is down", ENETDOWN; "No such device" when reopened) and
for bus-off (a full transmit queue, ENOBUFS). This sandbox has no ``vcan`` kernel module, so the
raised exception is the boundary of the real dependency; everything above it (the run loop, the
sensor, the estimator, the frames on the bus) is the real code.
"""

import logging
from pathlib import Path
import re
import threading
import time

import can
import numpy as np
import pytest
from can.interfaces.virtual import VirtualBus

from excavator_payload.cli import main
from excavator_payload.data.dataset import Dataset
from excavator_payload.estimators.base import create_estimator
from excavator_payload.runtime.can_sensor import EstimateEncoder, PayloadSensor, run_bus
from excavator_payload.runtime.codec import SignalCodec
from excavator_payload.simulation.minimum_jerk import simulate_minimum_jerk

LOGGER = "excavator_payload.runtime.can_sensor"

#: channel -> {"recv"/"send"/"open": (start, end) s after the channel's first open}
WINDOWS: dict[str, dict[str, tuple[float, float]]] = {}
FIRST_OPEN: dict[str, float] = {}
DELIVERED: dict[str, list] = {}   # channel -> frames its recv returned
SENT: dict[str, list] = {}        # channel -> frames its send put on the bus


def _down(channel: str, what: str) -> bool:
    start, end = WINDOWS.get(channel, {}).get(what, (np.inf, np.inf))
    return start <= time.monotonic() - FIRST_OPEN[channel] < end


class FailingVirtualBus(VirtualBus):
    """A ``virtual`` bus whose receive, send and open fail inside :data:`WINDOWS` (see the
    module docstring)."""

    def __init__(self, channel, **kwargs):
        FIRST_OPEN.setdefault(channel, time.monotonic())
        if _down(channel, "open"):
            raise can.CanInitializationError(f"No such device: {channel}")
        super().__init__(channel=channel, **kwargs)
        self.name = channel

    def _recv_internal(self, timeout):
        if _down(self.name, "recv"):
            while not self.queue.empty():  # frames of a downed interface are lost
                self.queue.get_nowait()
            raise can.CanOperationError("Error receiving: Network is down", 100)
        msg, filtered = super()._recv_internal(timeout)
        if msg is not None:
            DELIVERED.setdefault(self.name, []).append(msg)
        return msg, filtered

    def send(self, msg, timeout=None):
        if _down(self.name, "send"):
            raise can.CanOperationError("Failed to transmit: No buffer space available", 105)
        super().send(msg, timeout)
        SENT.setdefault(self.name, []).append(msg)


@pytest.fixture(autouse=True)
def failing_interface(monkeypatch):
    # what a plugin's "can.interface" entry point does when python-can is imported
    monkeypatch.setitem(can.interfaces.BACKENDS, "failing-virtual", (__name__, "FailingVirtualBus"))
    monkeypatch.setattr(can.util, "VALID_INTERFACES", can.util.VALID_INTERFACES | {"failing-virtual"})


@pytest.fixture(scope="module")
def swings():
    return simulate_minimum_jerk(2, seed=5, noise="thesis")


@pytest.fixture(scope="module")
def estimator(swings):
    est = create_estimator("inverse-dynamics").fit(swings)
    est.estimate(swings)  # the first step imports scipy.stats (seconds on a loaded machine)
    return est


def _frames(codec, values, t):
    return [can.Message(timestamp=t, arbitration_id=fid, data=data, is_extended_id=ext)
            for fid, data, ext in codec.encode(values)]


def _live(swings, estimator, windows):
    """One experiment's frames sent in real time (20 Hz) to ``run_bus`` on a failing bus;
    returns (channel, counters, the published estimates decoded, the experiment)."""
    channel = f"recovery-{time.monotonic_ns()}"
    WINDOWS[channel] = windows
    codec = SignalCodec.for_sensor_set(swings.sensor_set)
    one = swings.subset(swings.experiment_ids[:1])
    ecu = can.Bus(interface="failing-virtual", channel=channel)
    machine = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)

    def factory():
        return can.Bus(interface="failing-virtual", channel=channel)

    sensor = PayloadSensor(estimator)
    stop = threading.Event()
    result = {}
    thread = threading.Thread(target=lambda: result.update(
        run_bus(ecu, sensor, stop, bus_factory=factory, name=f"failing-virtual:{channel}")))
    thread.start()
    try:
        values, times = one.signals(), one.frame["time"].to_numpy()
        start = time.monotonic()
        t0 = time.time()
        for k in range(len(values)):
            time.sleep(max(0.0, start + times[k] - times[0] - time.monotonic()))
            for f in _frames(codec, values[k], t0 + times[k]):
                machine.send(f)
        time.sleep(0.3)
    finally:
        stop.set()
        thread.join(timeout=10)
        ecu.shutdown()
        machine.shutdown()
    assert not thread.is_alive()
    decoder = EstimateEncoder()
    published = [(m.timestamp, *d) for m in SENT.get(channel, []) if (d := decoder.decode(m)) is not None]
    return channel, result, published, one, codec


def _offline(estimator, frames):
    """The estimates of the same frames, fed to a sensor with no bus at all (a run without the
    outage), as the bus carries them."""
    sensor = PayloadSensor(estimator)
    decoder = EstimateEncoder()
    outputs = [o for f in frames for o in sensor.feed(f, f.timestamp)]
    return [(o.time, *decoder.decode(sensor.frames(o)[0])) for o in outputs]


def _quantised(dataset, codec):
    frame = dataset.frame.copy()
    frame[list(dataset.sensor_set.signals)] = codec.quantise(dataset.signals())
    return Dataset(frame, dataset.meta)


def test_vanished_interface_is_lost_once_reopened_and_back(swings, estimator, caplog):
    """The interface is gone from 1 s to 3 s of a 5 s swing: one 'lost' line, one 'back' line,
    nothing published while lost, and the estimates after it are the gap rule's: equal to the
    same frames without a bus, and to batch ``estimate`` of the samples after the outage
    (inverse dynamics bridges a hole of up to 1 s and restarts after a longer one)."""
    caplog.set_level(logging.DEBUG, logger=LOGGER)
    channel, counters, published, one, codec = _live(
        swings, estimator, {"recv": (1.0, 3.0), "send": (1.0, 3.0), "open": (1.0, 3.0)})
    lines = [r for r in caplog.records if r.name == LOGGER and r.levelno >= logging.WARNING]
    assert len(lines) == 2, ([r.getMessage() for r in lines], counters, len(published))
    assert re.fullmatch(rf"CAN bus lost on failing-virtual:{channel} \(Error receiving: Network is "
                        r"down \[Error Code 100\]\); waiting", lines[0].getMessage())
    back = re.fullmatch(rf"CAN bus back on failing-virtual:{channel} after ([0-9.]+) s", lines[1].getMessage())
    assert back and 2.0 <= float(back.group(1)) <= 4.5
    assert counters["bus_lost"] == 1 and 2.0 <= counters["bus_lost_seconds"] <= 4.5
    assert counters["bus_off"] == 0 and counters["bus_errors"] >= 3
    # reopened at 1, 1, 2 s after the loss (0.5 s into the outage): failed at 2.5 s, back at 3.5 s
    frames = DELIVERED[channel]
    stamps = np.array([f.timestamp for f in frames])
    hole = np.diff(stamps).argmax()
    assert 2.0 <= stamps[hole + 1] - stamps[hole] <= 4.0
    live = [p for p in published if p[2] != "stale"]
    # nothing published while lost: no frame sent between the two halves
    sent_at = np.array([m.timestamp for m in SENT[channel]])
    assert not ((sent_at > stamps[hole] + 0.6) & (sent_at < stamps[hole + 1] - 0.1)).any()
    # the same frames without a bus: the same estimates, sample by sample; missing only the
    # one or two made from the last frames before the outage, whose sends failed with it
    reference = {p[0]: p[1:] for p in _offline(estimator, frames)}
    assert len(reference) > 40 and all(reference[p[0]] == p[1:] for p in live)
    missing = sorted(set(reference) - {p[0] for p in live})
    assert len(missing) <= 2 and all(stamps[hole] - 0.11 < t <= stamps[hole] + 1e-6 for t in missing)
    # the gap rule (inverse dynamics restarts): the samples after the outage are a new experiment
    times = one.frame["time"].to_numpy()
    t0 = stamps[0] - times[0]
    after = times >= stamps[hole + 1] - t0 - 1e-6
    batch = estimator.estimate(_quantised(Dataset(one.frame[after].reset_index(drop=True), one.meta), codec))
    resumed = [p for p in live if p[0] >= stamps[hole + 1] - 1e-6]
    assert len(resumed) == after.sum() > 15
    assert resumed[0][2] == "gap"
    assert [p[2] for p in resumed[1:]] == list(batch["status"])[1:]
    got = np.array([p[1] for p in resumed])
    assert np.abs(got - batch["payload_estimate"].to_numpy()).max() <= 0.25 + 1e-9  # bus resolution


def test_bus_off_is_waited_out(swings, estimator, caplog):
    """Sends fail for 1 s while frames still arrive (bus-off): the estimator runs on, nothing
    is published in that second, one line says so and one that sends work again."""
    caplog.set_level(logging.DEBUG, logger=LOGGER)
    channel, counters, published, one, codec = _live(swings, estimator, {"send": (1.5, 2.5)})
    lines = [r.getMessage() for r in caplog.records if r.name == LOGGER and r.levelno >= logging.WARNING]
    assert len(lines) == 2, lines
    assert lines[0].startswith(f"CAN sends failing on failing-virtual:{channel} for 0.")
    assert "No buffer space available" in lines[0]
    again = re.fullmatch(rf"CAN sends work again on failing-virtual:{channel} after ([0-9.]+) s "
                         r"\((\d+) frames not sent\)", lines[1])
    assert again and 0.8 <= float(again.group(1)) <= 1.5 and int(again.group(2)) >= 30
    assert counters["bus_off"] == 1 and 0.8 <= counters["bus_off_seconds"] <= 1.5
    assert counters["bus_lost"] == 0 and counters["samples"] == len(one.frame)
    # every sample was estimated; the published ones are those of the same frames without a bus
    reference = {p[0]: p[1:] for p in _offline(estimator, DELIVERED[channel])}
    live = [p for p in published if p[2] != "stale"]
    assert len(reference) == len(one.frame)
    assert all(reference[p[0]] == p[1:] for p in live)
    assert len(reference) - 25 <= len(live) <= len(reference) - 15   # about 1 s at 20 Hz not sent


def test_cli_bus_never_back_stops_on_time(tmp_path, estimator, caplog, capsys):
    """The interface vanishes 0.3 s into a 3 s run and never comes back: can-run keeps trying
    to reopen it, stops at --duration with exit 0 and prints the outage in its counters."""
    model = tmp_path / "model"
    estimator.save(model)
    channel = f"recovery-cli-{time.monotonic_ns()}"
    WINDOWS[channel] = {what: (0.3, np.inf) for what in ("recv", "send", "open")}
    caplog.set_level(logging.DEBUG, logger=LOGGER)
    assert main(["can-run", "--interface", "failing-virtual", "--channel", channel, "--model",
                 str(model), "--duration", "3"]) == 0
    elapsed = time.monotonic() - FIRST_OPEN[channel]
    assert elapsed < 3.6
    out = capsys.readouterr().out
    counters = dict(re.findall(r"(\w+) ([0-9.]+)", out.split("stopped: ")[1]))
    assert counters["bus_lost"] == "1" and 2.4 <= float(counters["bus_lost_seconds"]) <= 3.0
    lines = [r.getMessage() for r in caplog.records if r.name == LOGGER and r.levelno >= logging.WARNING]
    assert lines == [f"CAN bus lost on failing-virtual:{channel} (Error receiving: Network is down [Error Code 100]); waiting"]
    reopens = [r for r in caplog.records if r.name == LOGGER and "reopening" in r.getMessage()]
    assert 1 <= len(reopens) <= 3   # after 1 s and 1 s more: not a busy loop
    # while it was up: stale at 20 Hz (no sensors on the bus); nothing after
    assert 3 <= int(counters["stale"]) <= 12


def test_stop_ends_the_wait_for_a_reopen(estimator):
    """A stop (Ctrl-C, SIGTERM or --duration) while the bus is lost ends the run at once, not
    after the next reopen attempt."""
    channel = f"recovery-stop-{time.monotonic_ns()}"
    WINDOWS[channel] = {what: (0.0, np.inf) for what in ("recv", "send")}
    bus = can.Bus(interface="failing-virtual", channel=channel)
    WINDOWS[channel]["open"] = (0.0, np.inf)
    stop = threading.Event()
    done = {}
    thread = threading.Thread(target=lambda: done.update(run_bus(
        bus, PayloadSensor(estimator), stop, bus_factory=lambda: can.Bus(interface="failing-virtual",
                                                                         channel=channel))))
    thread.start()
    time.sleep(1.7)  # lost at 0.5 s, reopen failed at 1.5 s, the next at 2.5 s
    stopped = time.monotonic()
    stop.set()
    thread.join(timeout=5)
    bus.shutdown()
    assert time.monotonic() - stopped < 0.3
    assert done["bus_lost"] == 1 and 1.4 <= done["bus_lost_seconds"] <= 2.0


def test_short_failures_and_error_frames_are_one_line_each(estimator, caplog):
    """0.2 s of failing receives is not an outage, and 50 error frames are not 50 warnings: one
    line each, every one counted."""
    channel = f"recovery-short-{time.monotonic_ns()}"
    WINDOWS[channel] = {"recv": (0.3, 0.5)}
    bus = can.Bus(interface="failing-virtual", channel=channel)
    machine = can.Bus(interface="virtual", channel=channel)
    caplog.set_level(logging.DEBUG, logger=LOGGER)
    stop = threading.Event()
    done = {}
    thread = threading.Thread(target=lambda: done.update(run_bus(
        bus, PayloadSensor(estimator), stop, bus_factory=lambda: pytest.fail("reopened"), name="x:y")))
    thread.start()
    try:
        time.sleep(0.7)
        for _ in range(50):
            machine.send(can.Message(is_error_frame=True, timestamp=time.time()))
        time.sleep(0.5)
    finally:
        stop.set()
        thread.join(timeout=5)
        bus.shutdown()
        machine.shutdown()
    lines = [r.getMessage() for r in caplog.records if r.name == LOGGER and r.levelno >= logging.WARNING]
    assert len(lines) == 2, lines
    assert re.fullmatch(r"CAN receive failed on x:y: Error receiving: Network is down \[Error Code 100\] "
                        r"\(\d time\(s\) in a row\); receiving again", lines[0])
    assert lines[1].startswith("CAN error frame on x:y at ")
    assert done["bus_lost"] == 0 and done["bus_errors"] >= 50 + 2


def test_ctrl_c_while_waiting_for_a_reopen(tmp_path, estimator):
    """SIGINT to a ``can-run`` process whose bus is lost ends it at once: exit 0 and the
    counters, not a traceback, and not after the next reopen attempt."""
    import os
    import signal
    import subprocess
    import sys

    model = tmp_path / "model"
    estimator.save(model)
    here = Path(__file__).resolve().parent
    script = f"""
import sys
sys.path.insert(0, {str(here)!r})
import can
import test_can_recovery as t
can.interfaces.BACKENDS["failing-virtual"] = ("test_can_recovery", "FailingVirtualBus")
can.util.VALID_INTERFACES = can.util.VALID_INTERFACES | {{"failing-virtual"}}
t.WINDOWS["can0"] = {{w: (0.3, float("inf")) for w in ("recv", "send", "open")}}
from excavator_payload.cli import main
sys.exit(main(["can-run", "--interface", "failing-virtual", "--channel", "can0", "--model", {str(model)!r}]))
"""
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env={**os.environ, "COLUMNS": "200"})
    try:
        for line in proc.stderr:  # wait for the loss (the imports take seconds on a loaded machine)
            if "CAN bus lost on failing-virtual:can0" in line:
                break
        time.sleep(1.3)  # lost at 0.8 s; the first reopen failed at 1.8 s, the next at 2.8 s
        sent = time.monotonic()
        proc.send_signal(signal.SIGINT)
        out = ""
        for line in proc.stdout:  # the counters' line is printed when the run has stopped
            out += line
            if line.startswith("stopped: "):
                break
        took = time.monotonic() - sent  # (the interpreter's exit after it is not the run's)
        rest, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    assert took < 0.5 and "Traceback" not in err
    counters = dict(re.findall(r"(\w+) ([0-9.]+)", (out + rest).split("stopped: ")[1]))
    assert counters["bus_lost"] == "1" and 1.5 <= float(counters["bus_lost_seconds"]) <= 2.5

