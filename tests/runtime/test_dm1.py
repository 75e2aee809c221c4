"""J1939 DM1 from the sensor health monitor: the bytes per J1939-73, the BAM transport of
several DTCs, once a second while active and once after clearing, and the CAN sensor's frames."""

import can
import numpy as np
import pytest

from excavator_payload.data.schema import MACHINE_SENSORS
from excavator_payload.runtime import dbc
from excavator_payload.runtime.dm1 import (DM1_PGN, DM1Transmitter, decode_dm1, dm1_frames, encode_dm1,
                                           reassemble)


def test_dm1_bytes_follow_j1939_73():
    # SPN 520201 = 0x7F009: low byte 0x09, middle 0xF0, top 3 bits 0b111 above FMI 7
    data = encode_dm1([(520201, 7, 3)])
    assert data == bytes([0x04, 0xFF, 0x09, 0xF0, (0b111 << 5) | 7, 3, 0xFF, 0xFF])
    assert decode_dm1(data) == (0x04, [(520201, 7, 3)])
    # no active DTC: lamps off, SPN 0 FMI 0 OC 0
    assert encode_dm1([]) == bytes([0x00, 0xFF, 0, 0, 0, 0, 0xFF, 0xFF])
    assert decode_dm1(encode_dm1([])) == (0x00, [])
    for spn, fmi, oc in [(1, 31, 126), (0x7FFFF, 0, 1), (182, 2, 0)]:
        assert decode_dm1(encode_dm1([(spn, fmi, oc)]))[1] == [(spn, fmi, oc)]
    with pytest.raises(ValueError):
        encode_dm1([(1 << 19, 2, 0)])


def test_several_dtcs_go_by_bam():
    dtcs = [(520192, 2, 1), (520195, 2, 1), (520201, 7, 2)]
    data = encode_dm1(dtcs)
    assert len(data) == 2 + 4 * 3
    frames = dm1_frames(data, dbc.ESTIMATOR_ADDRESS, 1.0)
    assert [(f.arbitration_id >> 8) & 0x3FFFF for f in frames] == [0xECFF, 0xEBFF, 0xEBFF]
    assert frames[0].data[0] == 0x20 and frames[0].data[1] == len(data) and frames[0].data[3] == 2
    assert all(f.is_extended_id and f.arbitration_id & 0xFF == dbc.ESTIMATOR_ADDRESS for f in frames)
    assert reassemble(frames) == [data]
    assert decode_dm1(reassemble(frames)[0])[1] == dtcs


def test_transmitter_once_a_second_and_cleared_once():
    tx = DM1Transmitter(MACHINE_SENSORS)
    spn = {s.signal: s.spn for m in dbc.sensor_layout(MACHINE_SENSORS) for s in m.signals}
    sent = []
    for k in range(600):  # 6 s at 100 Hz; the pressure stuck from 1 s to 3.5 s
        t = k / 100
        fault = "boom_head_pressure:stuck" if 100 <= k < 350 else ""
        sent += [(t, f) for f in tx.update(t, fault)]
    times = [t for t, _ in sent]
    assert times == pytest.approx([1.0, 2.0, 3.0, 3.5])
    decoded = [decode_dm1(f.data) for _, f in sent]
    assert all(d == (0x04, [(spn["boom_head_pressure"], 7, 1)]) for d in decoded[:3])
    assert decoded[3] == (0x00, [])
    assert all((f.arbitration_id >> 8) & 0x3FFFF == DM1_PGN for _, f in sent)
    assert tx.summary() == [f"DM1 SPN {spn['boom_head_pressure']} FMI 7 (boom_head_pressure stuck): "
                            "active 1.00–3.50 s, in 3 DM1"]
    # a second occurrence counts up; a new fault is sent at once
    assert decode_dm1(tx.update(7.0, "boom_head_pressure:stuck")[0].data)[1][0][2] == 2
    assert len(tx.update(7.01, "boom_head_pressure:stuck,dipper_angle:dropout")) == 3  # BAM


def test_can_sensor_sends_dm1_while_a_signal_is_stuck():
    from excavator_payload.estimators.base import create_estimator
    from excavator_payload.runtime.can_sensor import PayloadSensor, SensorOutput
    from excavator_payload.simulation.machine_sim import simulate_machine_dataset

    data = simulate_machine_dataset(1, seed=5)
    est = create_estimator("inverse-dynamics", machine="cat345c-hydraulic").fit(data)
    sensor = PayloadSensor(est)
    out = sensor.frames(SensorOutput(1.0, 500.0, "sensor_fault", 10.0, (), "dipper_rate:stuck"))
    dm1 = [f for f in out if (f.arbitration_id >> 8) & 0x3FFFF == DM1_PGN]
    assert len(out) == 3 and len(dm1) == 1
    assert decode_dm1(dm1[0].data)[1][0][:2] == (dbc.FIRST_PROPRIETARY_SPN
                                                 + MACHINE_SENSORS.index("dipper_rate"), 7)
    assert len(sensor.frames(SensorOutput(1.01, 500.0, "ok", 10.0))) == 3  # the clearing DM1
    assert len(sensor.frames(SensorOutput(1.02, 500.0, "ok", 10.0))) == 2
    assert isinstance(dm1[0], can.Message) and np.isfinite(dm1[0].timestamp)


def test_a_joint_balance_fault_is_fmi_13_on_both_pressures_of_the_cylinder():
    """The calibrated kernel's joint check names a cylinder's head and rod pressures ``balance``:
    out of calibration (FMI 13), one DTC per pressure, at that signal's SPN."""
    tx = DM1Transmitter(MACHINE_SENSORS)
    dtcs = tx.dtcs("boom_head_pressure:balance,boom_rod_pressure:balance")
    spn = {s.signal: s.spn for m in dbc.sensor_layout(MACHINE_SENSORS) for s in m.signals}
    assert dtcs == {(spn["boom_head_pressure"], 13): ("boom_head_pressure", "balance"),
                    (spn["boom_rod_pressure"], 13): ("boom_rod_pressure", "balance")}
