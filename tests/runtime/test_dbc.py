"""Generated J1939 DBCs: conventions, shipped files up to date, encode/decode round trip."""

import math

import numpy as np
import pytest

from excavator_payload.data.schema import MACHINE_SENSORS, SENSOR_SETS, THESIS_SENSORS
from excavator_payload.estimators.base import Status
from excavator_payload.runtime import dbc
from excavator_payload.runtime.codec import SignalCodec, read_signal_map


@pytest.mark.parametrize("name", list(SENSOR_SETS))
def test_shipped_dbc_equals_generator(name):
    """The DBC files in the package are exactly what the generator writes from the sensor set."""
    assert dbc.shipped_dbc_path(name).read_text() == dbc.generate_dbc(name), (
        "the shipped DBC is out of date (sensor set or Status enum changed): regenerate with "
        "python -c 'from excavator_payload.runtime.dbc import write_shipped_dbcs; write_shipped_dbcs()'")


@pytest.mark.parametrize("sensors", [THESIS_SENSORS, MACHINE_SENSORS], ids=lambda s: s.name)
def test_j1939_conventions(sensors):
    db = dbc.sensor_set_database(sensors.name)
    assert dbc.is_j1939(db)
    assert db.dbc.attributes["ProtocolType"].value == "J1939"
    layout = dbc.sensor_layout(sensors)
    # every signal of the set, in column order, in proprietary-B PGNs from the sensor node
    assert [s.signal for m in layout for s in m.signals] == list(sensors.signals)
    spns = []
    for m in layout:
        message = db.get_message_by_name(m.name)
        assert message.is_extended_frame and message.protocol == "j1939"
        assert message.length == 8 and sum(s.length for s in message.signals) <= 64
        pgn = (message.frame_id >> 8) & 0x3FFFF
        assert 0xFF00 <= pgn <= 0xFFFF
        assert message.frame_id & 0xFF == dbc.SENSOR_ADDRESS
        for s in message.signals:
            assert s.byte_order == "little_endian" and not s.is_signed
            assert s.scale == dbc.RESOLUTION[s.unit]
            assert s.minimum <= -sensors.plausible_abs[_column(m, s.name)] + 1e-9
            spns.append(s.dbc.attributes["SPN"].value)
    assert len(set(spns)) == len(spns) and all(520192 <= v <= 524287 for v in spns)
    est = db.get_message_by_name("PayloadEstimate")
    assert est.get_signal_by_name("Payload").scale == 0.5
    vw = db.get_message_by_name("VehicleWeight")
    assert (vw.frame_id >> 8) & 0x3FFFF == 65258
    assert {s.name: s.dbc.attributes["SPN"].value for s in vw.signals} == {
        "AxleLocation": 928, "AxleWeight": 180, "TrailerWeight": 181, "CargoWeight": 182}
    assert vw.get_signal_by_name("CargoWeight").scale == 2.0
    # status codes are the Status enum's order; 'stale' keeps code 9, the one it had before the
    # enum held it, and the statuses added since come after it
    choices = est.get_signal_by_name("PayloadStatus").choices
    assert [str(choices[i]) for i in range(len(choices))] == [s.value for s in Status]
    assert str(choices[9]) == "stale" and str(choices[10]) == "implausible"


def _column(message_layout, name):
    return next(s.signal for s in message_layout.signals if s.name == name)


@pytest.mark.parametrize("sensors", [THESIS_SENSORS, MACHINE_SENSORS], ids=lambda s: s.name)
def test_round_trip_within_resolution(sensors):
    codec = SignalCodec.for_sensor_set(sensors)
    rng = np.random.default_rng(3)
    limits = np.array([sensors.plausible_abs[s] for s in sensors.signals])
    values = rng.uniform(-1, 1, (50, len(limits))) * limits
    values[0] = limits          # the ends of the range are data
    values[1] = -limits
    decoded = codec.quantise(values)
    resolution = np.array([dbc.RESOLUTION[sensors.units[s]] for s in sensors.signals])
    assert np.all(np.abs(decoded - values) <= resolution / 2 * (1 + 1e-6) + 1e-9 * limits)


@pytest.mark.parametrize("sensors", [THESIS_SENSORS, MACHINE_SENSORS], ids=lambda s: s.name)
def test_missing_and_out_of_range_values_decode_as_nan(sensors):
    codec = SignalCodec.for_sensor_set(sensors)
    n = len(sensors.signals)
    row = np.zeros(n)
    row[0] = math.nan                                            # not available
    row[1] = 3 * sensors.plausible_abs[sensors.signals[1]]       # error indicator
    decoded = codec.quantise(row)[0]
    assert math.isnan(decoded[0]) and math.isnan(decoded[1])
    assert np.all(np.isfinite(decoded[2:]))


def test_valid_raw_ranges():
    assert dbc.valid_raw_max(8) == 0xFA
    assert dbc.valid_raw_max(16) == 0xFAFF
    assert dbc.valid_raw_max(32) == 0xFAFFFFFF
    assert dbc.error_indicator(16) == 0xFE00 and dbc.not_available(16) == 0xFFFF


def test_signal_map_errors(tmp_path):
    bad = tmp_path / "map.toml"
    bad.write_text("[signals.boom_angle]\nmessage = 'X'\n")
    with pytest.raises(dbc.CanConfigError, match="needs 'message' and 'signal'"):
        read_signal_map(bad)
    with pytest.raises(dbc.CanConfigError, match="does not exist"):
        dbc.load_dbc(tmp_path / "none.dbc")
    junk = tmp_path / "junk.dbc"
    junk.write_text("BO_ this is not a dbc")
    with pytest.raises(dbc.CanConfigError, match="not a readable DBC"):
        dbc.load_dbc(junk)


@pytest.mark.parametrize("encoding", ["utf-8-sig", "utf-16"])
def test_a_signal_map_saved_by_a_windows_editor_is_read(tmp_path, encoding):
    """Notepad's UTF-8 with a byte-order mark, PowerShell's UTF-16 and CRLF line ends: were
    "not valid TOML: Invalid statement (at line 1, column 1)"."""
    text = "# Schaufel\r\n[signals.boom_angle]\r\nmessage = 'Arm1'\r\nsignal = 'BoomAngle'\r\nfactor = 0.01745\r\n"
    path = tmp_path / "map.toml"
    path.write_bytes(text.encode(encoding))
    assert read_signal_map(path)["boom_angle"].factor == pytest.approx(0.01745)


@pytest.mark.parametrize("value", ['"0.01745"', "true"])
def test_a_signal_map_factor_in_quotes_is_refused(tmp_path, value):
    path = tmp_path / "map.toml"
    path.write_text(f"[signals.boom_angle]\nmessage = 'Arm1'\nsignal = 'BoomAngle'\nfactor = {value}\n")
    with pytest.raises(dbc.CanConfigError, match="factor must be a number"):
        read_signal_map(path)
