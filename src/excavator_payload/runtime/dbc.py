r"""CAN database (DBC) of a sensor set, J1939 style (the codec between frames and signals:
:mod:`excavator_payload.runtime.codec`).

The DBC is *generated* from a :class:`~excavator_payload.data.schema.SensorSet` (never kept by
hand), so every sensor set gets one (``runtime/dbc/<set>.dbc`` ship with the package; a test
checks they equal what :func:`generate_dbc` writes now).

J1939 conventions (as cantools reads them)
------------------------------------------
* 29-bit extended frame ids ``priority << 26 | PGN << 8 | source address``; database attribute
  ``ProtocolType "J1939"``, message attribute ``VFrameFormat`` = ``J1939PG``, node attribute
  ``NmStationAddress``; little-endian (Intel) unsigned signals with an offset.
* Sensor signals go in *proprietary B* PGNs 0xFF00, 0xFF01, … (PDU format 0xFF: broadcast,
  group extension = the message number) from the node ``ArmSensors`` (source address
  :data:`SENSOR_ADDRESS`). No standard SPN exists for joint angles, rates, accelerations,
  torques or cylinder pressures of an excavator arm, so each gets an SPN from the range J1939
  reserves for manufacturer-specific parameters (520192–524287), in column order.
* The payload goes out from ``PayloadEcu`` (:data:`ESTIMATOR_ADDRESS`) twice:
  ``PayloadEstimate`` (proprietary B PGN :data:`ESTIMATE_PGN`: payload 0.5 kg/bit, status, one-
  sigma uncertainty 0.5 kg/bit) and the standard ``VehicleWeight`` PGN 65258 (0xFEEA), whose
  layout is SPN 928 axle location (8 bit), SPN 180 axle weight (0.5 kg/bit), SPN 181 trailer
  weight and SPN 182 cargo weight (2 kg/bit each). The payload is the *cargo* weight there
  (never negative: clamped at 0); axle and trailer weight are sent as "not available".
* Loadout (``excavator-payload loadout`` on a live bus), event messages: ``LoadoutPass`` (PGN
  :data:`LOADOUT_PASS_PGN`: truck and pass number, the weight locked before the dump and its σ,
  0.5 kg/bit as the payload, status ok / not_weighed) and ``LoadoutTruck``
  (:data:`LOADOUT_TRUCK_PGN`: truck number, passes, unweighed passes, running total and target,
  2 kg/bit) from ``PayloadEcu``; ``LoadoutControl`` (:data:`LOADOUT_CONTROL_PGN`) from the cab's
  ``OperatorPanel`` (:data:`OPERATOR_ADDRESS`): ``NewTruck`` 0 → 1 starts the next truck.
* Raw values at the top of a J1939 signal's range are indicators, not data: for an ``n``-bit
  signal, raw values above ``0xFA·2^(n-8) + 2^(n-8) - 1`` (``0xFAFF`` for 16 bits) mean "error"
  (``0xFE..``) or "not available" (``0xFF..``). The codec decodes them, and any value outside
  the signal's ``[min|max]``, as NaN: the estimator then reports the sample as invalid.

Scale and offset
----------------
Each SI unit has a documented resolution (:data:`RESOLUTION`, chosen so that quantisation is at
least ten times below the thesis sensor noise: angles 10⁻⁵ rad against 1.7·10⁻⁴ rad of noise,
torques 1 N·m against 1000 N·m). A signal spans ``±plausible_abs`` of its sensor set (offset
``-plausible_abs``), and is 16 bits long if that range fits the 16-bit J1939 data range at the
resolution, else 32 bits. Messages are filled with signals in column order, 8 bytes each.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources
from pathlib import Path

import cantools

from excavator_payload.data.schema import RESOLUTION, SensorSet, get_sensor_set  # noqa: F401 (dbc.RESOLUTION)
from excavator_payload.errors import ExcavatorPayloadError


class CanConfigError(ExcavatorPayloadError):
    """A DBC file or signal map is missing, malformed or does not fit the sensor set."""


#: J1939 priority of the sensor and estimate messages (6: the default of broadcast data).
PRIORITY = 6
#: Source addresses (J1939 self-configurable address range 128–247).
SENSOR_ADDRESS = 0xA0
#: J1939 "null address": generic DBCs (one message per PGN, for any sender) put it in the frame id.
NULL_ADDRESS = 0xFE
ESTIMATOR_ADDRESS = 0xA1
SENSOR_NODE = "ArmSensors"
ESTIMATOR_NODE = "PayloadEcu"
#: First proprietary B PGN of the sensor messages; the estimate's own PGN.
FIRST_SENSOR_PGN = 0xFF00
ESTIMATE_PGN = 0xFF80
ESTIMATE_MESSAGE = "PayloadEstimate"
#: Standard J1939 "Vehicle Weight" PGN.
VEHICLE_WEIGHT_PGN = 65258
VEHICLE_WEIGHT_MESSAGE = "VehicleWeight"
#: Loadout (``excavator-payload loadout`` on a live bus): a pass's locked weight and a truck's
#: running total from the payload ECU, and the operator's "new truck" button.
LOADOUT_PASS_PGN = 0xFF81
LOADOUT_PASS_MESSAGE = "LoadoutPass"
#: A pass's status on the bus, by code (``PassStatus``): a degraded pass was weighed without a
#: sensor the health monitor named (its σ widened); appended, so older codes keep their numbers.
PASS_STATUSES = ("ok", "not_weighed", "degraded")
LOADOUT_TRUCK_PGN = 0xFF82
LOADOUT_TRUCK_MESSAGE = "LoadoutTruck"
LOADOUT_CONTROL_PGN = 0xFF83
LOADOUT_CONTROL_MESSAGE = "LoadoutControl"
#: The operator panel (the cab's buttons) that sends LoadoutControl.
OPERATOR_NODE = "OperatorPanel"
OPERATOR_ADDRESS = 0xA2
#: A truck's total and target, kg/bit (16 bits: up to 128.5 t).
TRUCK_RESOLUTION = 2.0
#: First manufacturer-specific SPN (J1939-71 reserves 520192–524287).
FIRST_PROPRIETARY_SPN = 520192
#: Payload estimate: resolution and the lowest value it can carry (estimates may be negative).
PAYLOAD_RESOLUTION = 0.5
PAYLOAD_OFFSET = -2000.0
DBC_FOLDER = "dbc"


def valid_raw_max(bits: int) -> int:
    """Largest raw value that is data (not an error / not-available indicator), J1939-71.

    Parameters
    ----------
    bits : int
        Width of the signal.
    """
    if bits < 8:
        return (1 << bits) - 1
    if bits == 8:
        return 0xFA
    return (0xFA << (bits - 8)) | ((1 << (bits - 8)) - 1)


def not_available(bits: int) -> int:
    """The raw value meaning "not available" (all ones).

    Parameters
    ----------
    bits : int
        Width of the signal.
    """
    return (1 << bits) - 1


def error_indicator(bits: int) -> int:
    """The raw value meaning "error" (0xFE followed by zeros... as J1939-71: 0xFE00 for 16 bits).

    Parameters
    ----------
    bits : int
        Width of the signal (below 8 bits: all ones, as "not available").
    """
    if bits < 8:
        return (1 << bits) - 1
    return 0xFE << (bits - 8)


def dbc_name(signal: str) -> str:
    """CamelCase DBC name of a column name: ``boom_angle`` -> ``BoomAngle``.

    Parameters
    ----------
    signal : str
        A snake_case column name of a sensor set.
    """
    return "".join(part.capitalize() for part in signal.split("_"))


def frame_id(pgn: int, source_address: int, priority: int = PRIORITY) -> int:
    """29-bit J1939 frame id of a PDU2 (broadcast) PGN.

    Parameters
    ----------
    pgn : int
        The parameter group number (PDU2, so no destination address).
    source_address : int
        The sender's J1939 address, 0 to 255.
    priority : int, optional
        J1939 priority, 0 (highest) to 7.
    """
    return (priority << 26) | (pgn << 8) | source_address


# -- layout ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SignalLayout:
    """Where one sensor-set signal sits in the generated DBC.

    Parameters
    ----------
    signal : str
        The sensor set's column name.
    name : str
        The signal's CamelCase DBC name.
    message : str
        Name of the message that carries it.
    start : int
        First bit in the message's 8 data bytes (little-endian).
    bits : int
        Width (16 or 32).
    scale : float
        SI unit per bit.
    offset : float
        SI value of raw 0 (minus the plausible limit).
    minimum, maximum : float
        The DBC range, SI unit (the sensor set's plausible limits).
    unit : str
        The SI unit.
    spn : int
        Its manufacturer-specific J1939 SPN.
    """

    signal: str          # column name
    name: str            # DBC name
    message: str
    start: int           # bit
    bits: int
    scale: float
    offset: float
    minimum: float
    maximum: float
    unit: str
    spn: int


@dataclass(frozen=True)
class MessageLayout:
    """One message of the generated DBC: its name, J1939 PGN, 29-bit frame id and the signals it
    carries.

    Parameters
    ----------
    name : str
        The message's DBC name.
    pgn : int
        Its J1939 parameter group number.
    frame_id : int
        Its 29-bit frame id (without the DBC's extended-id flag).
    signals : tuple of SignalLayout
        The signals it carries, in order.
    """

    name: str
    pgn: int
    frame_id: int
    signals: tuple[SignalLayout, ...]


def signal_bits(span: float, resolution: float) -> int:
    """16 if ``span / resolution`` raw steps fit the 16-bit J1939 data range, else 32.

    Parameters
    ----------
    span : float
        Range the signal must carry, SI unit (maximum minus minimum).
    resolution : float
        SI unit per bit.

    Raises
    ------
    CanConfigError
        When even 32 bits are not enough.
    """
    steps = math.ceil(span / resolution - 1e-9)
    for bits in (16, 32):
        if steps <= valid_raw_max(bits):
            return bits
    raise CanConfigError(f"a span of {span:g} at resolution {resolution:g} needs more than 32 bits")


def sensor_layout(sensor_set: SensorSet) -> list[MessageLayout]:
    """Messages of the sensor set's signals, in column order (see the module docstring).

    Parameters
    ----------
    sensor_set : SensorSet
        Its signals, units and plausible limits give the layout.
    """
    messages: list[MessageLayout] = []
    current: list[SignalLayout] = []
    used = 0

    def close() -> None:
        nonlocal current, used
        k = len(messages)
        name = f"{sensor_set.name.capitalize()}Sensors{k + 1}"
        pgn = FIRST_SENSOR_PGN + k
        fixed = tuple(SignalLayout(**{**s.__dict__, "message": name}) for s in current)
        messages.append(MessageLayout(name, pgn, frame_id(pgn, SENSOR_ADDRESS), fixed))
        current, used = [], 0

    for i, signal in enumerate(sensor_set.signals):
        unit = sensor_set.units[signal]
        if unit not in RESOLUTION:
            raise CanConfigError(f"no CAN resolution defined for unit {unit!r} (signal {signal})")
        resolution = RESOLUTION[unit]
        limit = float(sensor_set.plausible_abs[signal])
        bits = signal_bits(2 * limit, resolution)
        if used + bits > 64:
            close()
        current.append(SignalLayout(signal, dbc_name(signal), "", used, bits, resolution, -limit,
                                    -limit, limit, unit, FIRST_PROPRIETARY_SPN + i))
        used += bits
    if current:
        close()
    return messages


def status_names() -> list[str]:
    """Status codes on the bus: the estimators' :class:`Status` enum in order (it holds
    ``stale`` at code 9, the code the bus gave it before the enum had it, and the statuses
    added later after it), then ``stale`` unless the enum has it."""
    from excavator_payload.estimators.base import Status

    names = [s.value for s in Status]
    if STALE not in names:
        names.append(STALE)
    return names


STALE = "stale"


# -- DBC text ------------------------------------------------------------------------------------
def _g(x: float) -> str:
    """A number as DBC text (shortest round-trip repr, no trailing .0 for integers)."""
    text = repr(float(x))
    return text[:-2] if text.endswith(".0") else text


def _sg(s: SignalLayout | tuple, receiver: str) -> str:
    name, start, bits, scale, offset, lo, hi, unit = s
    return (f' SG_ {name} : {start}|{bits}@1+ ({_g(scale)},{_g(offset)}) [{_g(lo)}|{_g(hi)}] '
            f'"{unit}" {receiver}')


def generate_dbc(sensor_set: SensorSet | str) -> str:
    """The DBC text of a sensor set (deterministic: the same set gives the same text).

    Parameters
    ----------
    sensor_set : SensorSet or str
        The sensor set, or its name (``thesis``, ``machine``).
    """
    sensors = get_sensor_set(sensor_set)
    layout = sensor_layout(sensors)
    statuses = status_names()
    lines = [
        'VERSION ""',
        "",
        "NS_ :",
        "\tCM_",
        "\tBA_DEF_",
        "\tBA_",
        "\tVAL_",
        "\tBA_DEF_DEF_",
        "",
        "BS_:",
        "",
        f"BU_: {SENSOR_NODE} {ESTIMATOR_NODE} {OPERATOR_NODE}",
        "",
    ]
    cycle_ms = int(round(1000.0 / sensors.sample_rate))
    comments = [f'CM_ "Generated by excavator-payload from the {sensors.name} sensor set: '
                f'{sensors.description}. Do not edit: regenerate.";',
                f'CM_ BU_ {SENSOR_NODE} "The sensors of the {sensors.name} set, sampled at '
                f'{_g(sensors.sample_rate)} Hz.";',
                f'CM_ BU_ {ESTIMATOR_NODE} "The payload virtual sensor.";',
                f'CM_ BU_ {OPERATOR_NODE} "The cab\'s loadout buttons.";']
    attributes = []
    spns = []
    for m in layout:
        lines.append(f"BO_ {m.frame_id | 0x80000000} {m.name}: 8 {SENSOR_NODE}")
        for s in m.signals:
            lines.append(_sg((s.name, s.start, s.bits, s.scale, s.offset, s.minimum, s.maximum,
                              s.unit), ESTIMATOR_NODE))
            comments.append(f'CM_ SG_ {m.frame_id | 0x80000000} {s.name} "{s.signal} ({s.unit}), '
                            f'{_g(s.scale)} {s.unit}/bit; raw above {valid_raw_max(s.bits):#x} '
                            f'= error / not available.";')
            spns.append(f'BA_ "SPN" SG_ {m.frame_id | 0x80000000} {s.name} {s.spn};')
        attributes.append(f'BA_ "VFrameFormat" BO_ {m.frame_id | 0x80000000} 3;')
        attributes.append(f'BA_ "GenMsgCycleTime" BO_ {m.frame_id | 0x80000000} {cycle_ms};')
        lines.append("")

    est_id = frame_id(ESTIMATE_PGN, ESTIMATOR_ADDRESS) | 0x80000000
    payload_max = PAYLOAD_OFFSET + PAYLOAD_RESOLUTION * valid_raw_max(16)
    sigma_max = PAYLOAD_RESOLUTION * valid_raw_max(16)
    lines += [f"BO_ {est_id} {ESTIMATE_MESSAGE}: 8 {ESTIMATOR_NODE}",
              _sg(("Payload", 0, 16, PAYLOAD_RESOLUTION, PAYLOAD_OFFSET, PAYLOAD_OFFSET, payload_max,
                   "kg"), SENSOR_NODE),
              _sg(("PayloadStatus", 16, 8, 1, 0, 0, len(statuses) - 1, ""), SENSOR_NODE),
              _sg(("PayloadSigma", 24, 16, PAYLOAD_RESOLUTION, 0, 0, sigma_max, "kg"), SENSOR_NODE),
              ""]
    comments += [
        f'CM_ SG_ {est_id} Payload "Payload estimate, {_g(PAYLOAD_RESOLUTION)} kg/bit; 0xFFFF = no '
        f'estimate yet.";',
        f'CM_ SG_ {est_id} PayloadStatus "What the estimate means (see the value table).";',
        f'CM_ SG_ {est_id} PayloadSigma "One-sigma uncertainty of the estimate; 0xFFFF = not '
        f'available.";',
    ]
    vw_id = frame_id(VEHICLE_WEIGHT_PGN, ESTIMATOR_ADDRESS) | 0x80000000
    lines += [f"BO_ {vw_id} {VEHICLE_WEIGHT_MESSAGE}: 8 {ESTIMATOR_NODE}",
              _sg(("AxleLocation", 0, 8, 1, 0, 0, 250, ""), SENSOR_NODE),
              _sg(("AxleWeight", 8, 16, 0.5, 0, 0, 0.5 * valid_raw_max(16), "kg"), SENSOR_NODE),
              _sg(("TrailerWeight", 24, 16, 2, 0, 0, 2.0 * valid_raw_max(16), "kg"), SENSOR_NODE),
              _sg(("CargoWeight", 40, 16, 2, 0, 0, 2.0 * valid_raw_max(16), "kg"), SENSOR_NODE),
              ""]
    comments.append(f'CM_ SG_ {vw_id} CargoWeight "The payload in the bucket (never negative).";')
    for msg_id in (est_id, vw_id):
        attributes.append(f'BA_ "VFrameFormat" BO_ {msg_id} 3;')
        attributes.append(f'BA_ "GenMsgCycleTime" BO_ {msg_id} {cycle_ms};')
    # loadout: event messages (GenMsgCycleTime 0), sent when a pass is locked / a truck changes
    pass_id = frame_id(LOADOUT_PASS_PGN, ESTIMATOR_ADDRESS) | 0x80000000
    truck_id = frame_id(LOADOUT_TRUCK_PGN, ESTIMATOR_ADDRESS) | 0x80000000
    control_id = frame_id(LOADOUT_CONTROL_PGN, OPERATOR_ADDRESS) | 0x80000000
    truck_max = TRUCK_RESOLUTION * valid_raw_max(16)
    lines += [f"BO_ {pass_id} {LOADOUT_PASS_MESSAGE}: 8 {ESTIMATOR_NODE}",
              _sg(("PassTruck", 0, 16, 1, 0, 0, valid_raw_max(16), ""), OPERATOR_NODE),
              _sg(("PassNumber", 16, 8, 1, 0, 0, valid_raw_max(8), ""), OPERATOR_NODE),
              _sg(("PassWeight", 24, 16, PAYLOAD_RESOLUTION, PAYLOAD_OFFSET, PAYLOAD_OFFSET, payload_max,
                   "kg"), OPERATOR_NODE),
              _sg(("PassSigma", 40, 16, PAYLOAD_RESOLUTION, 0, 0, sigma_max, "kg"), OPERATOR_NODE),
              _sg(("PassStatus", 56, 8, 1, 0, 0, len(PASS_STATUSES) - 1, ""), OPERATOR_NODE),
              "",
              f"BO_ {truck_id} {LOADOUT_TRUCK_MESSAGE}: 8 {ESTIMATOR_NODE}",
              _sg(("TruckNumber", 0, 16, 1, 0, 0, valid_raw_max(16), ""), OPERATOR_NODE),
              _sg(("TruckPasses", 16, 8, 1, 0, 0, valid_raw_max(8), ""), OPERATOR_NODE),
              _sg(("TruckUnweighed", 24, 8, 1, 0, 0, valid_raw_max(8), ""), OPERATOR_NODE),
              _sg(("TruckTotal", 32, 16, TRUCK_RESOLUTION, 0, 0, truck_max, "kg"), OPERATOR_NODE),
              _sg(("TruckTarget", 48, 16, TRUCK_RESOLUTION, 0, 0, truck_max, "kg"), OPERATOR_NODE),
              "",
              f"BO_ {control_id} {LOADOUT_CONTROL_MESSAGE}: 8 {OPERATOR_NODE}",
              _sg(("NewTruck", 0, 2, 1, 0, 0, 3, ""), ESTIMATOR_NODE),
              ""]
    comments += [
        f'CM_ BO_ {pass_id} "A bucket pass weighed before its dump (sent when it is locked).";',
        f'CM_ SG_ {pass_id} PassTruck "The truck the pass went into (1, 2, ... in the shift; rolls over).";',
        f'CM_ SG_ {pass_id} PassWeight "The pass weight locked before the dump; 0xFFFF = not weighed, '
        f'0xFE00 = out of range.";',
        f'CM_ BO_ {truck_id} "A truck\'s running total (sent with each pass and when the truck leaves); '
        f'what the last pass should carry is TruckTarget - TruckTotal.";',
        f'CM_ SG_ {truck_id} TruckUnweighed "Passes of the truck that could not be weighed (not in '
        f'TruckTotal).";',
        f'CM_ SG_ {truck_id} TruckTarget "The truck\'s target load; 0xFFFF = none given.";',
        f'CM_ BO_ {control_id} "The operator\'s loadout buttons.";',
        f'CM_ SG_ {control_id} NewTruck "Press (0 -> 1) to start the next truck; 2 error, 3 not '
        f'available.";',
    ]
    for msg_id in (pass_id, truck_id, control_id):
        attributes.append(f'BA_ "VFrameFormat" BO_ {msg_id} 3;')
    spns += [f'BA_ "SPN" SG_ {pass_id} PassTruck {FIRST_PROPRIETARY_SPN + 4010};',
             f'BA_ "SPN" SG_ {pass_id} PassNumber {FIRST_PROPRIETARY_SPN + 4011};',
             f'BA_ "SPN" SG_ {pass_id} PassWeight {FIRST_PROPRIETARY_SPN + 4012};',
             f'BA_ "SPN" SG_ {pass_id} PassSigma {FIRST_PROPRIETARY_SPN + 4013};',
             f'BA_ "SPN" SG_ {pass_id} PassStatus {FIRST_PROPRIETARY_SPN + 4014};',
             f'BA_ "SPN" SG_ {truck_id} TruckNumber {FIRST_PROPRIETARY_SPN + 4020};',
             f'BA_ "SPN" SG_ {truck_id} TruckPasses {FIRST_PROPRIETARY_SPN + 4021};',
             f'BA_ "SPN" SG_ {truck_id} TruckUnweighed {FIRST_PROPRIETARY_SPN + 4022};',
             f'BA_ "SPN" SG_ {truck_id} TruckTotal {FIRST_PROPRIETARY_SPN + 4023};',
             f'BA_ "SPN" SG_ {truck_id} TruckTarget {FIRST_PROPRIETARY_SPN + 4024};',
             f'BA_ "SPN" SG_ {control_id} NewTruck {FIRST_PROPRIETARY_SPN + 4030};']
    spns += [f'BA_ "SPN" SG_ {est_id} Payload {FIRST_PROPRIETARY_SPN + 4000};',
             f'BA_ "SPN" SG_ {est_id} PayloadStatus {FIRST_PROPRIETARY_SPN + 4001};',
             f'BA_ "SPN" SG_ {est_id} PayloadSigma {FIRST_PROPRIETARY_SPN + 4002};',
             f'BA_ "SPN" SG_ {vw_id} AxleLocation 928;',
             f'BA_ "SPN" SG_ {vw_id} AxleWeight 180;',
             f'BA_ "SPN" SG_ {vw_id} TrailerWeight 181;',
             f'BA_ "SPN" SG_ {vw_id} CargoWeight 182;']
    lines += comments
    lines += [
        'BA_DEF_  "ProtocolType" STRING ;',
        'BA_DEF_ BO_  "VFrameFormat" ENUM  "StandardCAN","ExtendedCAN","reserved","J1939PG";',
        'BA_DEF_ BO_  "GenMsgCycleTime" INT 0 65535;',
        'BA_DEF_ SG_  "SPN" INT 0 524287;',
        'BA_DEF_ BU_  "NmStationAddress" INT 0 255;',
        'BA_DEF_DEF_  "ProtocolType" "";',
        'BA_DEF_DEF_  "VFrameFormat" "J1939PG";',
        'BA_DEF_DEF_  "GenMsgCycleTime" 0;',
        'BA_DEF_DEF_  "SPN" 0;',
        'BA_DEF_DEF_  "NmStationAddress" 254;',
        'BA_ "ProtocolType" "J1939";',
        f'BA_ "NmStationAddress" BU_ {SENSOR_NODE} {SENSOR_ADDRESS};',
        f'BA_ "NmStationAddress" BU_ {ESTIMATOR_NODE} {ESTIMATOR_ADDRESS};',
        f'BA_ "NmStationAddress" BU_ {OPERATOR_NODE} {OPERATOR_ADDRESS};',
        *attributes,
        *spns,
        f"VAL_ {est_id} PayloadStatus " + " ".join(f'{i} "{n}"' for i, n in enumerate(statuses)) + " ;",
        f"VAL_ {pass_id} PassStatus " + " ".join(f'{i} "{n}"' for i, n in enumerate(PASS_STATUSES)) + " ;",
        f'VAL_ {control_id} NewTruck 0 "released" 1 "pressed" 2 "error" 3 "not_available" ;',
        "",
    ]
    return "\n".join(lines)


def shipped_dbc_path(sensor_set: SensorSet | str) -> Path:
    """Path of the DBC shipped in the package for a sensor set.

    Parameters
    ----------
    sensor_set : SensorSet or str
        The sensor set, or its name.
    """
    name = get_sensor_set(sensor_set).name
    return Path(str(resources.files("excavator_payload.runtime") / DBC_FOLDER / f"{name}.dbc"))


def write_shipped_dbcs() -> list[Path]:
    """Regenerate the shipped DBC files (developers: after changing a sensor set)."""
    from excavator_payload.data.schema import SENSOR_SETS

    paths = []
    for sensors in SENSOR_SETS.values():
        path = shipped_dbc_path(sensors)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(generate_dbc(sensors), encoding="utf-8")
        paths.append(path)
    return paths


def load_dbc(path: str | Path) -> cantools.database.can.Database:
    """A DBC file as a cantools database (one clear line if it cannot be read).

    Parameters
    ----------
    path : str or Path
        The DBC file.

    Raises
    ------
    CanConfigError
        The file is missing, unreadable, or defines a message twice.
    """
    path = Path(path)
    if not path.is_file():
        from excavator_payload.textfiles import not_a_file

        raise CanConfigError(not_a_file(path, "DBC file"))
    # cantools only logs a message defined twice (same name or frame id) and keeps the last:
    # two lines on stderr, then frames decoded by whichever definition won
    logger = logging.getLogger("cantools.database")
    overwritten = _Collect()
    logger.addHandler(overwritten)
    propagate, logger.propagate = logger.propagate, False
    try:
        database = cantools.database.load_string(dbc_text(path), database_format="dbc", strict=True)
    except Exception as exc:  # cantools raises many types for bad files
        raise CanConfigError(f"'{path}' is not a readable DBC file: {exc}") from None
    finally:
        logger.removeHandler(overwritten)
        logger.propagate = propagate
    twice = sorted({str(r.args[0]) for r in overwritten.records
                    if r.levelno >= logging.WARNING and "Overwriting message" in str(r.msg) and r.args})
    if twice:
        raise CanConfigError(f"'{path}' defines message(s) {', '.join(map(repr, twice))} twice (the same "
                             "name or frame id): keep one definition")
    return database


def dbc_text(path: str | Path) -> str:
    """The text of a DBC file: UTF-8 or UTF-16 when it starts with their byte-order mark (a DBC
    saved by Notepad or PowerShell: cantools read the mark as text and refused the file with
    "Invalid syntax at line 1, column 1"), else cp1252, the encoding of Vector's tools (and
    cantools' default), which reads any byte.

    Parameters
    ----------
    path : str or Path
        The DBC file.
    """
    import codecs

    raw = Path(path).read_bytes()
    if raw.startswith(codecs.BOM_UTF8):
        return raw[len(codecs.BOM_UTF8):].decode("utf-8", errors="replace")
    if raw.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)):
        return raw.decode("utf-16", errors="replace")
    return raw.decode("cp1252", errors="replace")


class _Collect(logging.Handler):
    """Keeps the log records it is handed."""

    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)


@lru_cache(maxsize=8)
def sensor_set_database(name: str) -> cantools.database.can.Database:
    """The generated DBC of a sensor set (by name), parsed."""
    return cantools.database.load_string(generate_dbc(name), database_format="dbc", strict=True)


def is_j1939(db) -> bool:
    """Whether the database declares ``ProtocolType "J1939"``.

    Parameters
    ----------
    db : cantools Database
        A parsed DBC.
    """
    try:
        attr = db.dbc.attributes.get("ProtocolType") if db.dbc is not None else None
    except AttributeError:
        return False
    return attr is not None and str(attr.value) == "J1939"


def _pgn(arbitration_id: int) -> int:
    """PGN of a 29-bit J1939 id (PDU1: destination address dropped)."""
    pgn = (arbitration_id >> 8) & 0x3FFFF
    if ((pgn >> 8) & 0xFF) < 240:
        pgn &= 0x3FF00
    return pgn


def estimate_database():
    """The database that holds the PayloadEstimate and VehicleWeight messages (any set's)."""
    return sensor_set_database("thesis")

