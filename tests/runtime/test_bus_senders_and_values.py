"""Source addresses, values outside a signal's range on the bus, and 'implausible' (issue 30)."""

import math

import can
import numpy as np
import pytest

from excavator_payload.data.dataset import Dataset
from excavator_payload.estimators.base import PLAUSIBLE_PAYLOAD, Status, create_estimator
from excavator_payload.runtime import dbc
from excavator_payload.runtime.can_sensor import EstimateEncoder, PayloadSensor, SensorOutput
from excavator_payload.runtime.codec import MessageOptions, SignalCodec
from excavator_payload.runtime.record import record_dataset
from excavator_payload.runtime.replay import replay_log
from excavator_payload.simulation.minimum_jerk import simulate_minimum_jerk


@pytest.fixture(scope="module")
def swings():
    return simulate_minimum_jerk(2, seed=9, noise="thesis")


@pytest.fixture(scope="module")
def estimator(swings):
    return create_estimator("inverse-dynamics").fit(swings)


def test_another_ecus_frames_do_not_bridge_a_recording_gap(tmp_path, swings, estimator):
    """Two recordings 5 s apart, and another ECU (SA 0x21) sending PGN 0xFF01 all along: the
    gap still splits them (it merged them, and the first load was lost)."""
    clean = tmp_path / "clean.blf"
    record_dataset(swings, clean)
    frames = list(can.LogReader(str(clean)))
    t0, t1 = frames[0].timestamp, frames[-1].timestamp
    foreign = [can.Message(timestamp=t, arbitration_id=dbc.frame_id(0xFF01, 0x21), is_extended_id=True,
                           data=bytes([0x11] * 8)) for t in np.arange(t0, t1, 0.1)]
    mixed = tmp_path / "mixed.blf"
    with can.Logger(str(mixed)) as w:
        for m in sorted(frames + foreign, key=lambda m: m.timestamp):
            w.on_message_received(m)
    sensor = PayloadSensor(estimator)
    got = replay_log(mixed, sensor)
    want = replay_log(clean, PayloadSensor(estimator))
    assert got["experiment"].nunique() == 2
    assert list(got["status"]) == list(want["status"])
    np.testing.assert_array_equal(got["payload_estimate"], want["payload_estimate"])
    assert sensor.counters["other_senders"] == len(foreign)


def _moved(frames, address):
    return [can.Message(timestamp=f.timestamp, arbitration_id=(f.arbitration_id & ~0xFF) | address,
                        is_extended_id=True, data=f.data) for f in frames]


def test_a_sensor_at_another_address_is_named_and_the_map_moves_it(tmp_path, swings, estimator):
    from excavator_payload.errors import DatasetError

    clean = tmp_path / "clean.blf"
    record_dataset(swings, clean)
    moved = tmp_path / "moved.blf"
    with can.Logger(str(moved)) as w:
        for m in _moved(can.LogReader(str(clean)), 0x42):
            w.on_message_received(m)
    with pytest.raises(DatasetError, match="from SA 0x42") as info:
        replay_log(moved, PayloadSensor(estimator))
    assert "source_address" in str(info.value)
    codec = SignalCodec.for_sensor_set(swings.sensor_set)
    there = SignalCodec(codec.sensor_set, codec.database, codec.sources,
                        {m: MessageOptions(source_address=0x42) for m in codec.message_names})
    got = replay_log(moved, PayloadSensor(estimator, there))
    want = replay_log(clean, PayloadSensor(estimator))
    np.testing.assert_array_equal(got["payload_estimate"], want["payload_estimate"])


def test_a_generic_dbc_locks_onto_the_first_sender(swings, estimator):
    """A DBC whose ids carry the null address 0xFE (a generic J1939 DBC) listens to the first
    address it hears for each message; a second sender of the PGN is not data."""
    text = dbc.generate_dbc("thesis")
    for m in dbc.sensor_layout(swings.sensor_set):
        text = text.replace(str(m.frame_id | 0x80000000), str(dbc.frame_id(m.pgn, dbc.NULL_ADDRESS) | 0x80000000))
    import cantools

    database = cantools.database.load_string(text, database_format="dbc")
    codec = SignalCodec.for_sensor_set(swings.sensor_set)
    generic = SignalCodec(codec.sensor_set, database, codec.sources)
    assert all(generic.expected_source(m) is None for m in generic.message_names)
    sensor = PayloadSensor(estimator, generic)
    out = []
    for k, row in enumerate(swings.signals()[:30]):
        frames = [can.Message(timestamp=0.05 * k, arbitration_id=fid, data=d, is_extended_id=e)
                  for fid, d, e in codec.encode(row)]
        out += [o for f in _moved(frames, 0x30) + _moved(frames, 0x31)[:1] for o in sensor.feed(f)]
    assert len(out) == 30 and sensor.counters["other_senders"] == 30


def test_signal_map_message_table_is_checked(tmp_path, swings):
    from excavator_payload.runtime.dbc import CanConfigError
    from excavator_payload.runtime.codec import read_message_map

    path = tmp_path / "map.toml"
    path.write_text('[messages.Inclinometer]\nsource_address = 0x21\nperiod = 0.1\n')
    assert read_message_map(path) == {"Inclinometer": MessageOptions(0x21, 0.1)}
    for body, said in (("source_address = 300", "0 … 253"), ("period = -1", "positive"), ("adress = 3", "adress")):
        path.write_text(f"[messages.X]\n{body}\n")
        with pytest.raises(CanConfigError, match=said):
            read_message_map(path)
    codec = SignalCodec.for_sensor_set(swings.sensor_set)
    with pytest.raises(CanConfigError, match="Nope"):
        SignalCodec(codec.sensor_set, codec.database, codec.sources, {"Nope": MessageOptions(1)})


def test_values_outside_a_signals_range_are_error_not_clamped():
    enc = EstimateEncoder()
    db = dbc.estimate_database()
    frames = enc.frames(SensorOutput(0.0, -5000.0, "implausible", 0.8))
    raw = enc.estimate_message.decode(bytes(frames[0].data), scaling=False, decode_choices=False)
    assert raw["Payload"] == dbc.error_indicator(16)          # not -2000 kg
    payload, status, sigma = enc.decode(frames[0])
    assert math.isnan(payload) and status == "implausible" and sigma == pytest.approx(1.0)
    cargo = db.decode_message(frames[1].arbitration_id, frames[1].data, scaling=False)["CargoWeight"]
    assert cargo == dbc.not_available(16)                      # not 0 kg as valid
    # an 'ok' negative weight beyond the cargo step is an error, within it an empty bucket
    for estimate, want in ((-30.0, dbc.error_indicator(16)), (-1.0, 0), (2501.0, round(2501 / 2))):
        frames = enc.frames(SensorOutput(0.0, estimate, "ok", 5.0))
        got = db.decode_message(frames[1].arbitration_id, frames[1].data, scaling=False)["CargoWeight"]
        assert got == want, estimate
    huge = enc.frames(SensorOutput(0.0, 40000.0, "ok", 1e6))
    raw = enc.estimate_message.decode(bytes(huge[0].data), scaling=False, decode_choices=False)
    assert raw["Payload"] == raw["PayloadSigma"] == dbc.error_indicator(16)


def test_an_impossible_estimate_is_implausible_in_step_and_batch(swings, estimator):
    """Torques scaled by 3 (a wrong factor in a signal map): the estimate leaves -10 ... 150 %
    of the rated payload, and every such sample is 'implausible', never 'ok'."""
    rated = estimator.rated_payload
    assert rated == estimator.machine.rated_payload > 0
    frame = swings.frame.copy()
    frame[["boom_torque", "dipper_torque"]] *= 3.0
    batch = estimator.estimate(Dataset(frame, swings.meta))
    low, high = (f * rated for f in PLAUSIBLE_PAYLOAD)
    est = batch["payload_estimate"].to_numpy()
    outside = (est < low) | (est > high)
    assert outside.sum() > 50
    assert set(batch["status"][outside]) <= {"implausible", "warming_up", "gap", "rejected_outlier",
                                             "reinitialised", "out_of_range", "invalid_input"}
    assert (batch["status"][outside] == "implausible").sum() > 50
    assert not (batch["status"][~outside] == "implausible").any()
    # streaming gives the same
    estimator.reset()
    first = batch[batch["experiment"] == batch["experiment"].iloc[0]]
    values = Dataset(frame, swings.meta).signals()
    streamed = [estimator.step_values(t, v).status.value for t, v in zip(first["time"], values[:len(first)])]
    assert streamed == list(first["status"])


def test_rated_payload_is_saved_and_networks_take_their_datas(tmp_path, swings, estimator):
    from excavator_payload.estimators.base import load_estimator

    estimator.save(tmp_path / "m")
    assert load_estimator(tmp_path / "m").rated_payload == estimator.rated_payload
    net = create_estimator("ffnn", epochs=1, train_experiments=1).fit(swings)
    assert net.machine is None and net.rated_payload == swings.machine().rated_payload
    assert Status("implausible") is Status.IMPLAUSIBLE
