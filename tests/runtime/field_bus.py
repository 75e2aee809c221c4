"""A machine's bus laid out as in the field, for the tests and ``benchmarks/measure_field_bus.py``;
and a CANedge logger's MF4 layout (:func:`write_canedge_mf4`).

The machine sensor set's signals in J1939 proprietary-B messages at 100 Hz from the arm's
sensor ECU (source address 0xA0), except the house inclination: a separate inclinometer
(source address 0x21) sending PGN 0xFF21 at 10 Hz, as a slow tilt sensor does.
"""

from __future__ import annotations

from datetime import datetime, timezone
from pathlib import Path

import numpy as np
from asammdf import MDF, Signal, Source
from asammdf.blocks.v4_constants import BUS_TYPE_CAN, FLAG_CG_BUS_EVENT, SOURCE_BUS

from excavator_payload.data.schema import get_sensor_set
from excavator_payload.runtime import dbc

SLOW = ("house_pitch", "house_roll")
INCLINOMETER_ADDRESS = 0x21
INCLINOMETER_PGN = 0xFF21


def field_dbc_text(slow_ms: int = 100) -> str:
    """The DBC (with GenMsgCycleTime: 10 ms for the arm, ``slow_ms`` for the inclinometer)."""
    sensors = get_sensor_set("machine")
    layout = [s for m in dbc.sensor_layout(sensors) for s in m.signals]
    fast = [s for s in layout if s.signal not in SLOW]
    slow = [s for s in layout if s.signal in SLOW]
    messages = []  # (name, frame id, cycle ms, signals)
    for k in range(0, len(fast), 2):
        fid = dbc.frame_id(0xFF00 + k // 2, dbc.SENSOR_ADDRESS)
        messages.append((f"Arm{k // 2 + 1}", fid, 10, fast[k:k + 2]))
    messages.append(("HouseInclination", dbc.frame_id(INCLINOMETER_PGN, INCLINOMETER_ADDRESS), slow_ms, slow))
    lines = ['VERSION ""', "", "NS_ :", "", "BS_:", "", "BU_: ArmSensors Inclinometer PayloadEcu", ""]
    attributes = []
    for name, fid, cycle, signals in messages:
        sender = "Inclinometer" if name == "HouseInclination" else "ArmSensors"
        lines.append(f"BO_ {fid | 0x80000000} {name}: 8 {sender}")
        for i, s in enumerate(signals):
            lines.append(f' SG_ {s.name} : {32 * i}|32@1+ ({s.scale!r},{s.offset!r}) [{s.minimum!r}|{s.maximum!r}] '
                         f'"{s.unit}" PayloadEcu')
        lines.append("")
        attributes.append(f'BA_ "GenMsgCycleTime" BO_ {fid | 0x80000000} {cycle};')
        attributes.append(f'BA_ "VFrameFormat" BO_ {fid | 0x80000000} 3;')
    lines += ['BA_DEF_  "ProtocolType" STRING ;',
              'BA_DEF_ BO_  "VFrameFormat" ENUM  "StandardCAN","ExtendedCAN","reserved","J1939PG";',
              'BA_DEF_ BO_  "GenMsgCycleTime" INT 0 65535;',
              'BA_DEF_DEF_  "ProtocolType" "";', 'BA_DEF_DEF_  "VFrameFormat" "J1939PG";',
              'BA_DEF_DEF_  "GenMsgCycleTime" 0;', 'BA_ "ProtocolType" "J1939";', *attributes, ""]
    return "\n".join(lines)


def field_map_text() -> str:
    """The signal map of :func:`field_dbc_text` (factor 1: the DBC is in SI)."""
    sensors = get_sensor_set("machine")
    layout = [s for m in dbc.sensor_layout(sensors) for s in m.signals]
    fast = [s for s in layout if s.signal not in SLOW]
    out = []
    for k, s in enumerate(fast):
        out.append(f'[signals.{s.signal}]\nmessage = "Arm{k // 2 + 1}"\nsignal = "{s.name}"\n')
    for s in layout:
        if s.signal in SLOW:
            out.append(f'[signals.{s.signal}]\nmessage = "HouseInclination"\nsignal = "{s.name}"\n')
    return "\n".join(out)


def write_field_files(folder: Path, slow_ms: int = 100) -> tuple[Path, Path]:
    """``field.dbc`` and ``field-map.toml`` in ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    dbc_path, map_path = folder / "field.dbc", folder / "field-map.toml"
    dbc_path.write_text(field_dbc_text(slow_ms))
    map_path.write_text(field_map_text())
    return dbc_path, map_path


def foreign_frames(start: float, stop: float, seed: int = 0) -> list:
    """Another ECU's traffic over ``start … stop`` (s): an engine controller's EEC1 (PGN 0xF004
    from SA 0x00) at 100 Hz, and a proprietary PGN 0xFF01 — one of the arm's — from SA 0x21 at
    20 Hz with its own content, as a foreign ECU on the same bus sends."""
    import can
    import numpy as np

    rng = np.random.default_rng(seed)
    out = []
    for period, fid in ((0.01, dbc.frame_id(0xF004, 0x00, 3)), (0.05, dbc.frame_id(0xFF01, 0x21))):
        for t in np.arange(start, stop, period):
            out.append(can.Message(timestamp=float(t + rng.uniform(0, 0.002)), arbitration_id=fid,
                                   is_extended_id=True, data=bytes(rng.integers(0, 256, 8).tolist())))
    return out


def field_shift_log(dataset, out: Path, dbc_path: Path, map_path: Path, jitter: float = 0.001,
                    press: bool = True, foreign: bool = True, seed: int = 0) -> dict:
    """``dataset`` (a shift) as the field layout's CAN log ``out`` (format by suffix): the arm at
    100 Hz, the inclinometer at 10 Hz, ``jitter`` s of timestamp jitter; with ``foreign`` another
    ECU's traffic all along (:func:`foreign_frames`), and with ``press`` the operator's new-truck
    button pressed 2 s after each experiment's last frame (experiments are 5 s apart)."""
    import can

    from excavator_payload.runtime.codec import SignalCodec
    from excavator_payload.runtime.loadout_bus import TruckButton
    from excavator_payload.runtime.logs import read_frames
    from excavator_payload.runtime.record import record_dataset

    codec = SignalCodec.from_files(dataset.sensor_set, dbc_path, map_path)
    lock = out.with_name(out.stem + ".sensors.blf")
    record_dataset(dataset, lock, codec, jitter=jitter, seed=seed)
    frames = list(read_frames(lock))
    lock.unlink()
    extra = []
    if press:
        button = TruckButton.default()
        stamps = [f.timestamp for f in frames]
        for a, b in zip(stamps, stamps[1:]):
            if b - a > 2.5:  # between two experiments
                extra += [button.frame(True, a + 2.0), button.frame(False, a + 2.2)]
    if foreign:
        extra += foreign_frames(frames[0].timestamp - 1.0, frames[-1].timestamp + 1.0, seed)
    merged = sorted(frames + extra, key=lambda m: m.timestamp)
    with can.Logger(str(out)) as writer:
        for m in merged:
            m.channel = 1
            writer.on_message_received(m)
    return {"frames": len(merged), "sensor_frames": len(frames), "other_frames": len(extra)}


#: the faulty pressure's dropout in truck 1 of :func:`make_shift` (after its last dump): s before
#: the truck's end, from and to
DROPOUT = (1.6, 1.0)


def make_shift(folder: Path):
    """A calibrated model (``folder/model``, 4 swings), a shift of two trucks of 2 passes
    (``folder/shift.parquet``; bucket_rod_pressure drops out to 0 after truck 1's last dump, a
    J1939 DM1 fault), and the field layout's DBC and map. Returns (folder, shift, dbc, map)."""
    from excavator_payload.data.io import write_dataset
    from excavator_payload.estimators.base import create_estimator
    from excavator_payload.simulation.machine_sim import simulate_machine_dataset

    calibration = simulate_machine_dataset(4, seed=4, session=1)
    create_estimator("calibrated", machine="cat345c-hydraulic-3pct").fit(calibration).save(folder / "model")
    trucks = simulate_machine_dataset(2, seed=3, session=1, motion="shift", truck_target=8000.0)
    frame = trucks.frame
    first = frame["experiment"] == 0
    end = frame.loc[first, "time"].max()
    assert trucks.experiment_meta[0]["passes"][-1]["release"][1] < end - DROPOUT[0] - 1.0
    frame.loc[first & frame["time"].between(end - DROPOUT[0], end - DROPOUT[1]), "bucket_rod_pressure"] = 0.0
    write_dataset(trucks, folder / "shift.parquet")
    dbc_path, map_path = write_field_files(folder)
    return folder, trucks, dbc_path, map_path


def rescaled_dbc(text: str, changes: dict) -> str:
    """``text`` (a DBC) with some signals in another unit: ``{"BoomHeadPressure": (1e-5, "bar")}``
    multiplies that signal's scale, offset and range by 1e-5 and names its unit "bar" — the same
    frames then decode in bar, as a user's DBC in bar does (mapped with factor 1)."""
    import re

    out = text
    for name, (k, unit) in changes.items():
        def scaled(m, k=k, unit=unit):
            scale, offset, low, high = (float(x) * k for x in m.group(2, 3, 4, 5))
            return f'{m.group(1)}({scale!r},{offset!r}) [{low!r}|{high!r}] "{unit}"'

        out, n = re.subn(rf'( SG_ {name} : \S+ )\(([^,]+),([^)]+)\) \[([^|]+)\|([^\]]+)\] "[^"]*"', scaled, out)
        assert n == 1, name
    return out


def write_canedge_mf4(frames, path: Path) -> Path:
    """``frames`` (python-can messages) as a CANedge-style MDF 4.11 bus log; returns the path written."""
    start = frames[0].timestamp
    dtype = np.dtype([("CAN_DataFrame.BusChannel", "<u1"), ("CAN_DataFrame.ID", "<u4"),
                      ("CAN_DataFrame.IDE", "<u1"), ("CAN_DataFrame.DLC", "<u1"),
                      ("CAN_DataFrame.DataLength", "<u1"), ("CAN_DataFrame.DataBytes", "(8,)u1"),
                      ("CAN_DataFrame.Dir", "<u1")])
    records = np.zeros(len(frames), dtype=dtype)
    records["CAN_DataFrame.BusChannel"] = 1
    records["CAN_DataFrame.ID"] = [f.arbitration_id for f in frames]
    records["CAN_DataFrame.IDE"] = [int(f.is_extended_id) for f in frames]
    records["CAN_DataFrame.DLC"] = [len(f.data) for f in frames]
    records["CAN_DataFrame.DataLength"] = [len(f.data) for f in frames]
    records["CAN_DataFrame.DataBytes"] = np.array([list(bytes(f.data).ljust(8, b"\0")[:8]) for f in frames],
                                                  dtype="u1")
    mdf = MDF(version="4.11")
    mdf.header.start_time = datetime.fromtimestamp(start, timezone.utc)
    source = Source(name="CAN1", path="CAN1", comment="", source_type=SOURCE_BUS, bus_type=BUS_TYPE_CAN)
    mdf.append(Signal(samples=records, timestamps=np.array([f.timestamp - start for f in frames]),
                      name="CAN_DataFrame", source=source, flags=Signal.Flags.stream_sync),
               acq_name="CAN1", acq_source=source)
    mdf.groups[-1].channel_group.flags |= FLAG_CG_BUS_EVENT
    return Path(mdf.save(path, overwrite=True))  # asammdf may lower the suffix
