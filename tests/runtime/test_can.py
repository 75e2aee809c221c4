"""The CAN payload sensor: record -> replay equals batch estimates; bad frames; live virtual bus."""

import math
import threading
import time

import can
import numpy as np
import pandas as pd
import pytest

from excavator_payload.cli import main
from excavator_payload.data.dataset import Dataset
from excavator_payload.data.io import read_estimates, write_dataset
from excavator_payload.estimators.base import Status, create_estimator
from excavator_payload.estimators.commands import STATUS_MEANING
from excavator_payload.runtime import dbc
from excavator_payload.runtime.can_sensor import EstimateEncoder, PayloadSensor, run_bus
from excavator_payload.runtime.codec import MessageOptions, SignalCodec
from excavator_payload.runtime.record import record_dataset
from excavator_payload.runtime.replay import replay_log
from excavator_payload.simulation.minimum_jerk import simulate_minimum_jerk


@pytest.fixture(scope="module")
def swings():
    return simulate_minimum_jerk(3, seed=5, noise="thesis")


@pytest.fixture(scope="module")
def estimator(swings):
    return create_estimator("inverse-dynamics").fit(swings)


def quantised(dataset, codec):
    """The dataset as the sensor receives it over CAN (values at the DBC's resolution)."""
    frame = dataset.frame.copy()
    frame[list(dataset.sensor_set.signals)] = codec.quantise(dataset.signals())
    return Dataset(frame, dataset.meta)


@pytest.mark.parametrize("suffix", [".asc", ".blf", ".log", ".csv", ".trc"])
def test_record_replay_equals_batch(tmp_path, swings, estimator, suffix):
    codec = SignalCodec.for_sensor_set(swings.sensor_set)
    log = tmp_path / f"swings{suffix}"
    info = record_dataset(swings, log)
    assert info["frames"] == 4 * len(swings.frame) and info["experiments"] == 3
    out = replay_log(log, PayloadSensor(estimator))
    batch = estimator.estimate(quantised(swings, codec))
    assert list(out["experiment"]) == list(np.repeat([0, 1, 2], 101))
    np.testing.assert_allclose(out["time"], batch["time"], atol=1e-5)
    np.testing.assert_allclose(out["payload_estimate"], batch["payload_estimate"], rtol=1e-12)
    assert list(out["status"]) == list(batch["status"])
    # and against the unquantised data: within the payload's resolution once converged
    exact = estimator.estimate(swings)
    ok = (exact["status"] == "ok").to_numpy()
    assert ok.sum() > 250
    assert np.abs(out["payload_estimate"].to_numpy()[ok]
                  - exact["payload_estimate"].to_numpy()[ok]).max() < dbc.PAYLOAD_RESOLUTION


def test_replay_equals_batch_with_the_gate_and_publishes_sigma(tmp_path, swings, estimator):
    """Torque glitches through the CAN sensor: the same rejections, re-initialisation and sigma
    as batch ``estimate``, and ``PayloadSigma`` in the published frame."""
    codec = SignalCodec.for_sensor_set(swings.sensor_set)
    frame = swings.frame.copy()
    ids = list(swings.experiment_ids)
    first = frame.index[frame["experiment"] == ids[0]]
    second = frame.index[frame["experiment"] == ids[1]]
    frame.loc[first[[40, 60]], "boom_torque"] += 1e5                 # 100 sigma of torque noise
    frame.loc[second[30:38], "dipper_torque"] -= 1e5                 # a run: lock-out guard
    glitched = Dataset(frame, swings.meta)
    log = tmp_path / "glitched.blf"
    record_dataset(glitched, log)
    sensor = PayloadSensor(estimator)
    out = replay_log(log, sensor)
    batch = estimator.estimate(quantised(glitched, codec))
    assert list(out["status"]) == list(batch["status"])
    assert {"rejected_outlier", "reinitialised"} <= set(batch["status"])
    np.testing.assert_allclose(out["payload_estimate"], batch["payload_estimate"], rtol=1e-12)
    np.testing.assert_allclose(out["payload_sigma"], batch["sigma"], rtol=1e-12)
    assert np.isfinite(batch["sigma"]).sum() > 250
    # the last output goes out with its sigma, at the DBC's resolution
    last = sensor.last_output
    payload, status, sigma = sensor.encoder.decode(sensor.frames(last)[0])
    assert status == last.status and math.isfinite(last.sigma)
    assert abs(sigma - last.sigma) <= dbc.PAYLOAD_RESOLUTION


def _frames(codec, values, t):
    return [can.Message(timestamp=t, arbitration_id=fid, data=data, is_extended_id=ext)
            for fid, data, ext in codec.encode(values)]


def test_bad_frames_change_status_never_crash(swings, estimator):
    codec = SignalCodec.for_sensor_set(swings.sensor_set)
    sensor = PayloadSensor(estimator)
    values = swings.signals()
    outputs = []
    for k in range(20):
        frames = _frames(codec, values[k], 0.05 * k)
        if k == 5:
            frames.insert(1, can.Message(timestamp=0.05 * k, arbitration_id=0x123, data=b"\x01\x02"))
            frames.insert(2, can.Message(timestamp=0.05 * k, arbitration_id=0x18FF77A0,
                                         is_extended_id=True, data=bytes(8)))
        if k == 8:   # wrong length
            frames[2] = can.Message(timestamp=0.05 * k, arbitration_id=frames[2].arbitration_id,
                                    is_extended_id=True, data=bytes(frames[2].data[:5]))
        if k == 11:  # a raw value in the J1939 error range
            data = bytearray(frames[0].data)
            data[0:4] = (0xFE000000).to_bytes(4, "little")
            frames[0] = can.Message(timestamp=0.05 * k, arbitration_id=frames[0].arbitration_id,
                                    is_extended_id=True, data=bytes(data))
        if k == 14:  # one message lost: its signals are held from the sample before (not stale)
            del frames[3]
        for f in frames:
            outputs += sensor.feed(f)
    status = [o.status for o in outputs]
    assert len(outputs) == 20
    assert status[8] == status[11] == Status.INVALID.value
    assert status[14] not in (Status.INVALID.value, "stale") and outputs[14].stale == ()
    assert status[5] != Status.INVALID.value  # unknown ids are ignored
    assert sensor.counters["ignored"] == 2 and sensor.counters["bad_frames"] == 2
    assert outputs[9].status in ("ok", "warming_up", "gap")
    assert math.isfinite(outputs[19].estimate)


def test_source_address_is_the_dbcs(swings, estimator):
    """Issue 30: only the DBC's source address is the sensor (another ECU's frames of the same
    PGN are not data); the signal map's source_address moves it."""
    codec = SignalCodec.for_sensor_set(swings.sensor_set)
    frames = _frames(codec, swings.signals()[0], 0.0)
    moved = [can.Message(timestamp=0.0, arbitration_id=(f.arbitration_id & ~0xFF) | 0x42,
                         is_extended_id=True, data=f.data) for f in frames]
    sensor = PayloadSensor(estimator)
    assert [o for f in moved for o in sensor.feed(f)] == []
    assert sensor.counters["other_senders"] == 4
    options = {m: MessageOptions(source_address=0x42) for m in codec.message_names}
    there = SignalCodec(codec.sensor_set, codec.database, codec.sources, options)
    sensor = PayloadSensor(estimator, there)
    outputs = [o for f in moved for o in sensor.feed(f)]
    assert len(outputs) == 1 and outputs[0].status != Status.INVALID.value


def test_estimate_frames_round_trip():
    from excavator_payload.runtime.can_sensor import SensorOutput

    enc = EstimateEncoder()
    frames = enc.frames(SensorOutput(1.0, 2501.3, "ok", 12.2))
    assert enc.decode(frames[0]) == (2501.5, "ok", 12.0)
    vw = dbc.estimate_database().decode_message(frames[1].arbitration_id, frames[1].data)
    assert vw["CargoWeight"] == 2502
    nothing = enc.frames(SensorOutput(1.0, math.nan, "stale", math.nan))
    payload, status, sigma = enc.decode(nothing[0])
    assert math.isnan(payload) and status == "stale" and math.isnan(sigma)
    assert nothing[1].data[5:7] == b"\xff\xff"  # cargo weight not available


def test_live_virtual_bus_equals_batch_goes_stale_and_recovers(swings, estimator):
    """Frames of simulated swings in on python-can's virtual bus, payload frames out."""
    channel = f"rt-test-{time.monotonic_ns()}"
    codec = SignalCodec.for_sensor_set(swings.sensor_set)
    one = swings.subset(swings.experiment_ids[:1])
    sensor = PayloadSensor(estimator, stale_after=0.3)
    stop = threading.Event()
    ecu_bus = can.Bus(interface="virtual", channel=channel)
    machine = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
    result = {}
    thread = threading.Thread(target=lambda: result.update(run_bus(ecu_bus, sensor, stop)))
    thread.start()
    received = []
    decoder = EstimateEncoder()

    def drain(timeout):
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            msg = machine.recv(timeout=0.05)
            if msg is not None:
                decoded = decoder.decode(msg)
                if decoded is not None:
                    received.append(decoded)

    try:
        # one experiment, sent faster than real time (stamps are the sample times)
        t0 = time.time()
        values = one.signals()
        times = one.frame["time"].to_numpy()
        for k in range(len(values)):
            for f in _frames(codec, values[k], t0 + times[k]):
                machine.send(f)
        drain(2.0)
        live = [r for r in received if r[1] != "stale"]
        batch = estimator.estimate(quantised(one, codec))
        assert len(live) == len(batch)
        assert [r[1] for r in live] == list(batch["status"])
        got = np.array([r[0] for r in live])
        want = batch["payload_estimate"].to_numpy()
        both = np.isfinite(want)
        assert np.array_equal(np.isfinite(got), both)
        assert np.abs(got[both] - want[both]).max() <= dbc.PAYLOAD_RESOLUTION / 2 + 1e-9
        # silence: stale at the sample rate (judged on the receiver's clock)
        received.clear()
        # the frames keep their stamps: samples 50 ms apart on the sensor's clock (sent at once,
        # they would all be one tick of the model's clock)
        machine2 = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
        drain(0.2)
        now = time.time()
        for k in range(3):  # samples stamped now, then silence
            for f in _frames(codec, values[k], now + 0.05 * k):
                machine2.send(f)
        received.clear()
        drain(0.8)
        assert any(r[1] == "stale" for r in received)
        # the sensors come back: it recovers by itself
        received.clear()
        now = time.time()
        for k in range(10):
            for f in _frames(codec, values[k], now + 0.05 * k):
                machine2.send(f)
        drain(0.3)
        after = [r[1] for r in received if r[1] != "stale"]
        assert len(after) == 10 and after[-1] in ("ok", "warming_up")
        machine2.shutdown()
    finally:
        stop.set()
        thread.join(timeout=5)
        ecu_bus.shutdown()
        machine.shutdown()
    assert not thread.is_alive()
    assert result["samples"] >= len(one.frame) + 13


class FlakyBus(can.BusABC):
    """A bus whose recv and send fail now and then."""

    def __init__(self, messages):
        self.messages = list(messages)
        self.calls = 0
        self.sent = []
        super().__init__(channel="flaky")

    def _recv_internal(self, timeout):
        self.calls += 1
        if self.calls % 3 == 0:
            raise can.CanOperationError("bus off")
        if self.messages:
            return self.messages.pop(0), False
        time.sleep(timeout or 0.0)
        return None, False

    def send(self, msg, timeout=None):
        if len(self.sent) % 4 == 3:
            self.sent.append(None)
            raise can.CanOperationError("tx buffer full")
        self.sent.append(msg)


def test_bus_errors_are_logged_and_survived(swings, estimator, caplog):
    codec = SignalCodec.for_sensor_set(swings.sensor_set)
    t0 = time.time() + 30
    frames = [f for k in range(10) for f in _frames(codec, swings.signals()[k], t0 + 0.05 * k)]
    frames.insert(5, can.Message(is_error_frame=True, timestamp=t0))
    bus = FlakyBus(frames)
    sensor = PayloadSensor(estimator)
    stop = threading.Event()
    timer = threading.Timer(0.6, stop.set)
    timer.start()
    counters = run_bus(bus, sensor, stop, error_pause=0.0)
    assert counters["bus_errors"] > 3
    assert counters["samples"] == 10
    assert "CAN receive failed" in caplog.text


def test_cli_record_replay_with_user_dbc(tmp_path, swings, estimator):
    """A user's own DBC (11-bit ids, degrees, other names) through --dbc and --signal-map."""
    data = tmp_path / "swings.parquet"
    write_dataset(swings, data)
    model = tmp_path / "model"
    estimator.save(model)
    user_dbc = tmp_path / "machine.dbc"
    user_dbc.write_text("""VERSION ""

NS_ :

BS_:

BU_: Imu Ecu

BO_ 256 Angles: 8 Imu
 SG_ BoomDeg : 0|32@1- (1e-05,0) [-360|360] "deg" Ecu
 SG_ DipperDeg : 32|32@1- (1e-05,0) [-360|360] "deg" Ecu

BO_ 257 Rates: 8 Imu
 SG_ BoomDegS : 0|32@1- (1e-05,0) [-3000|3000] "deg/s" Ecu
 SG_ DipperDegS : 32|32@1- (1e-05,0) [-3000|3000] "deg/s" Ecu

BO_ 258 Accels: 8 Imu
 SG_ BoomDegS2 : 0|32@1- (1e-04,0) [-100000|100000] "deg/s^2" Ecu
 SG_ DipperDegS2 : 32|32@1- (1e-04,0) [-100000|100000] "deg/s^2" Ecu

BO_ 259 Torques: 8 Ecu
 SG_ BoomKNm : 0|32@1- (0.001,0) [-1000000|1000000] "kN*m" Ecu
 SG_ DipperKNm : 32|32@1- (0.001,0) [-1000000|1000000] "kN*m" Ecu
""")
    deg = math.pi / 180
    entries = {"boom_angle": ("Angles", "BoomDeg", deg), "dipper_angle": ("Angles", "DipperDeg", deg),
               "boom_rate": ("Rates", "BoomDegS", deg), "dipper_rate": ("Rates", "DipperDegS", deg),
               "boom_accel": ("Accels", "BoomDegS2", deg), "dipper_accel": ("Accels", "DipperDegS2", deg),
               "boom_torque": ("Torques", "BoomKNm", 1000.0),
               "dipper_torque": ("Torques", "DipperKNm", 1000.0)}
    signal_map = tmp_path / "map.toml"
    signal_map.write_text("".join(f'[signals.{k}]\nmessage = "{m}"\nsignal = "{s}"\nfactor = {f!r}\n\n'
                                  for k, (m, s, f) in entries.items()))
    log = tmp_path / "machine.blf"
    out = tmp_path / "estimates.parquet"
    opts = ["--dbc", str(user_dbc), "--signal-map", str(signal_map)]
    assert main(["can-record", "--data", str(data), "--out", str(log), *opts]) == 0
    assert main(["can-replay", "--log", str(log), "--model", str(model), "--out", str(out), *opts]) == 0
    got = read_estimates(out)
    exact = estimator.estimate(swings)
    ok = (exact["status"] == "ok").to_numpy()
    assert list(got["status"]) == list(exact["status"])
    assert np.abs(got["payload_estimate"].to_numpy()[ok] - exact["payload_estimate"].to_numpy()[ok]).max() < 0.5
    # our own DBC by default; the two logs decode to the same estimates within resolution
    log2 = tmp_path / "ours.asc"
    out2 = tmp_path / "ours.parquet"
    assert main(["can-record", "--data", str(data), "--out", str(log2)]) == 0
    assert main(["can-replay", "--log", str(log2), "--model", str(model), "--out", str(out2)]) == 0
    assert pd.Series(read_estimates(out2)["status"]).equals(got["status"])
    # user errors: one line, exit 2
    assert main(["can-replay", "--log", str(log2), "--model", str(model), "--out", str(out2),
                 "--dbc", str(user_dbc)]) == 2
    assert main(["can-replay", "--log", str(tmp_path / "none.asc"), "--model", str(model),
                 "--out", str(out2)]) == 2
    assert main(["can-record", "--data", str(data), "--out", str(tmp_path / "x.mp3")]) == 2
    assert main(["can-replay", "--log", str(log2), "--model", str(model), "--out", str(log2)]) == 2


def test_cli_can_run_publishes_and_stops(tmp_path, estimator):
    model = tmp_path / "model"
    estimator.save(model)
    channel = f"rt-cli-{time.monotonic_ns()}"
    listener = can.Bus(interface="virtual", channel=channel)
    try:
        assert main(["can-run", "--interface", "virtual", "--channel", channel, "--model", str(model),
                     "--duration", "0.5"]) == 0
        statuses = []
        decoder = EstimateEncoder()
        while (msg := listener.recv(timeout=0.05)) is not None:
            if (d := decoder.decode(msg)) is not None:
                statuses.append(d[1])
    finally:
        listener.shutdown()
    assert 5 <= len(statuses) <= 12 and set(statuses) == {"stale"}  # 20 Hz, no sensors on the bus
    assert main(["can-run", "--interface", "no-such-interface", "--channel", "x", "--model",
                 str(model), "--duration", "0.1"]) == 2


def test_machine_sensor_set_log_round_trip(tmp_path):
    """can-record works for any sensor set: the machine set's 15 signals through its own DBC."""
    from excavator_payload.data.schema import MACHINE_SENSORS

    rng = np.random.default_rng(2)
    n = 30
    frame = pd.DataFrame({"experiment": np.repeat([0, 1], n // 2),
                          "time": np.tile(np.arange(n // 2) / MACHINE_SENSORS.sample_rate, 2)})
    for s in MACHINE_SENSORS.signals:
        frame[s] = rng.uniform(-0.5, 0.5, n) * (2e7 if s.endswith("pressure") else 1.0)
    dataset = Dataset(frame, {"sensor_set": "machine"})
    codec = SignalCodec.for_sensor_set(MACHINE_SENSORS)
    log = tmp_path / "machine.log"
    info = record_dataset(dataset, log)
    assert info["frames"] == n * len(codec.message_names) == n * 8
    decoded = np.full((n, len(MACHINE_SENSORS.signals)), np.nan)
    stamps = []
    row = -1
    for message in can.LogReader(str(log)):
        spec = codec.message_of(message.arbitration_id)
        if spec.name == codec.message_names[0]:
            row += 1
            stamps.append(message.timestamp)
        for i, v in codec.decode(spec, bytes(message.data)):
            decoded[row, i] = v
    np.testing.assert_allclose(decoded, codec.quantise(dataset.signals()), rtol=0, atol=1e-12)
    resolution = np.array([dbc.RESOLUTION[MACHINE_SENSORS.units[s]] for s in MACHINE_SENSORS.signals])
    assert np.all(np.abs(decoded - dataset.signals()) <= resolution / 2 + 1e-9)
    assert np.diff(stamps)[n // 2 - 1] == pytest.approx(5.0)  # experiments apart in bus time


def test_one_silent_sensor_makes_the_status_stale(swings, estimator):
    """One message missing for longer than its period x the tolerance (3.5): 'stale', naming
    its signals; held before that (one lost frame is not a silent sensor); it recovers when the
    message comes back."""
    codec = SignalCodec.for_sensor_set(swings.sensor_set)
    sensor = PayloadSensor(estimator, stale_after=0.16)
    values = swings.signals()
    outputs = []
    for k in range(40):
        frames = _frames(codec, values[k], 0.05 * k)
        if 10 <= k < 20:
            frames = frames[:3]  # the torque message falls silent for 0.5 s
        for f in frames:
            outputs += sensor.feed(f)
    status = [o.status for o in outputs]
    assert len(outputs) == 40
    assert status[:10] == list(estimator.estimate(swings.subset(swings.experiment_ids[:1]))["status"][:10])
    assert "stale" not in status[10:13]               # 0.05 ... 0.15 s old: held
    assert set(status[13:20]) == {"stale"}            # 0.2 s > 3.5 x 0.05 s
    assert {o.stale for o in outputs[13:20]} == {("boom_torque", "dipper_torque")}
    assert "stale" not in status[20:]


def test_cli_can_dbc(tmp_path):
    out = tmp_path / "machine.dbc"
    assert main(["can-dbc", "--sensor-set", "machine", "--out", str(out)]) == 0
    assert out.read_text() == dbc.generate_dbc("machine")
    assert main(["can-dbc", "--sensor-set", "nope"]) == 2


def test_replay_of_a_foreign_log_is_one_clear_error(tmp_path, estimator):
    log = tmp_path / "other.asc"
    with can.Logger(str(log)) as writer:
        for k in range(5):
            writer.on_message_received(can.Message(timestamp=0.1 * k, arbitration_id=0x100, data=bytes(8)))
    model = tmp_path / "model"
    estimator.save(model)
    assert main(["can-replay", "--log", str(log), "--model", str(model),
                 "--out", str(tmp_path / "e.parquet")]) == 2
    assert not (tmp_path / "e.parquet").exists()


@pytest.fixture(scope="module")
def machine_swings():
    """Two swings of the hydraulic machine (pressures + IMUs, field noise, 100 Hz)."""
    from excavator_payload.simulation.machine_sim import simulate_machine_dataset

    return simulate_machine_dataset(2, seed=4)


@pytest.mark.parametrize("name,machine", [("calibrated", "cat345c-hydraulic-3pct"),
                                          ("inverse-dynamics", "cat345c-hydraulic")])
def test_machine_set_cli_record_replay_equals_batch(tmp_path, machine_swings, name, machine, capsys):
    """A machine-set model end to end: can-record -> can-replay equals batch ``estimate`` on
    the data at the DBC's resolution (and within it of the unquantised data once converged);
    its summary counts every status, as ``estimate``'s does (it said '(9244 ok)' alone)."""
    est = create_estimator(name, machine=machine).fit(machine_swings)
    data, model = tmp_path / "swings.parquet", tmp_path / "model"
    write_dataset(machine_swings, data)
    est.save(model)
    log, out = tmp_path / "swings.blf", tmp_path / "estimates.parquet"
    assert main(["can-record", "--data", str(data), "--out", str(log)]) == 0
    capsys.readouterr()
    assert main(["can-replay", "--log", str(log), "--model", str(model), "--out", str(out)]) == 0
    got = read_estimates(out)
    summary = " ".join(capsys.readouterr().out.split())
    counts = got["status"].value_counts()
    assert counts.get("warming_up", 0) > 0
    assert "(" + ", ".join(f"{n} {status}" for status, n in counts.items()) + ")" in summary
    assert f"warming_up: {STATUS_MEANING['warming_up']}" in summary
    codec = SignalCodec.for_sensor_set(machine_swings.sensor_set)
    batch = est.estimate(quantised(machine_swings, codec))
    assert list(got["status"]) == list(batch["status"])
    assert (batch["status"] == "ok").sum() > 1000
    # inverse-dynamics differentiates the rates against the sample times, which the log
    # stores to its clock's resolution (calibrated uses fixed slope weights: exact)
    np.testing.assert_allclose(got["payload_estimate"], batch["payload_estimate"],
                               rtol=1e-12 if name == "calibrated" else 1e-7)
    np.testing.assert_allclose(got["time"], batch["time"], atol=1e-5)
    exact = est.estimate(machine_swings)
    ok = (exact["status"] == "ok").to_numpy()
    assert np.abs(got["payload_estimate"].to_numpy()[ok]
                  - exact["payload_estimate"].to_numpy()[ok]).max() < dbc.PAYLOAD_RESOLUTION


def test_machine_set_live_virtual_bus_equals_batch(machine_swings):
    """Machine-set frames in on python-can's virtual bus, payload frames out, equal to batch."""
    est = create_estimator("calibrated", machine="cat345c-hydraulic-3pct").fit(machine_swings)
    channel = f"rt-machine-{time.monotonic_ns()}"
    codec = SignalCodec.for_sensor_set(machine_swings.sensor_set)
    one = machine_swings.subset(machine_swings.experiment_ids[:1])
    sensor = PayloadSensor(est, stale_after=5.0)
    stop = threading.Event()
    ecu_bus = can.Bus(interface="virtual", channel=channel)
    machine = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
    # the receiver's clock runs 20 times slower than real time: at 100 Hz a partial sample
    # times out after 10 ms of it, which a loaded test machine can exceed between two frames
    start = time.time()
    thread = threading.Thread(target=lambda: run_bus(ecu_bus, sensor, stop,
                                                     clock=lambda: start + (time.time() - start) / 20))
    thread.start()
    received = []
    decoder = EstimateEncoder()
    try:
        t0 = time.time()
        values, times = one.signals(), one.frame["time"].to_numpy()
        for k in range(len(values)):
            for f in _frames(codec, values[k], t0 + times[k]):
                machine.send(f)
        end = time.monotonic() + 10.0
        while time.monotonic() < end and len(received) < len(values):
            msg = machine.recv(timeout=0.05)
            decoded = decoder.decode(msg) if msg is not None else None
            if decoded is not None and decoded[1] != "stale":
                received.append(decoded)
    finally:
        stop.set()
        thread.join(timeout=5)
        ecu_bus.shutdown()
        machine.shutdown()
    batch = est.estimate(quantised(one, codec))
    assert [r[1] for r in received] == list(batch["status"])
    got, want = np.array([r[0] for r in received]), batch["payload_estimate"].to_numpy()
    both = np.isfinite(want)
    assert np.array_equal(np.isfinite(got), both) and both.sum() > 500
    assert np.abs(got[both] - want[both]).max() <= dbc.PAYLOAD_RESOLUTION / 2 + 1e-9


def test_log_of_another_sensor_set_is_refused(tmp_path, machine_swings, estimator):
    """The generated DBCs of both sensor sets use PGNs 0xFF00...: a machine-set log replayed with
    a thesis model decoded garbage in every sample (all NaN estimates, exit status 0 before)."""
    from excavator_payload.errors import DatasetError

    log = tmp_path / "machine.blf"
    record_dataset(Dataset(machine_swings.frame.iloc[:300].copy(), machine_swings.meta), log)
    with pytest.raises(DatasetError, match="another DBC or sensor set"):
        replay_log(log, PayloadSensor(estimator))


def test_other_sender_of_the_same_pgn_is_ignored(swings, estimator):
    """Another ECU's proprietary-B frames with a sensor PGN are not sensor data (before, each
    one flushed a garbage sample: no estimate was ever 'ok')."""
    codec = SignalCodec.for_sensor_set(swings.sensor_set)
    import copy

    clean, mixed = PayloadSensor(estimator), PayloadSensor(copy.deepcopy(estimator))
    out_clean, out_mixed = [], []
    for k, row in enumerate(swings.signals()[:40]):
        frames = _frames(codec, row, 0.05 * k)
        foreign = [can.Message(timestamp=f.timestamp, arbitration_id=(f.arbitration_id & ~0xFF) | 0x00,
                               is_extended_id=True, data=bytes([0x11] * 8)) for f in frames]
        for f in frames:
            out_clean += clean.feed(f)
        for f in frames + foreign:
            out_mixed += mixed.feed(f)
    assert mixed.counters["other_senders"] == 4 * 40
    assert [o.status for o in out_mixed] == [o.status for o in out_clean]
    assert [o.estimate for o in out_mixed] == [o.estimate for o in out_clean]


def test_a_shuffled_machine_set_log_says_out_of_order(tmp_path, machine_swings):
    """A machine-set log whose lines are not in time order (merged, never sorted) assembles no
    sample whole: it was refused as "recorded with another DBC or sensor set?"."""
    import random

    from excavator_payload.errors import DatasetError

    est = create_estimator("inverse-dynamics", machine="cat345c-hydraulic").fit(machine_swings)
    clean = tmp_path / "clean.log"
    record_dataset(machine_swings, clean)
    lines = clean.read_text().splitlines()
    random.Random(0).shuffle(lines)
    log = tmp_path / "shuffled.log"
    log.write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError, match="out of order"):
        replay_log(log, PayloadSensor(est))
