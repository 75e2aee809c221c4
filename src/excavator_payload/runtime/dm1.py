"""J1939 DM1 (active diagnostic trouble codes, PGN 65226 / 0xFECA) from the sensor health monitor.

While the estimator names a faulty signal (``sensor_fault``, or ``degraded`` while it weighs
without it; :mod:`excavator_payload.estimators.health`), the
payload ECU (source address :data:`~excavator_payload.runtime.dbc.ESTIMATOR_ADDRESS`) sends a
DM1 once a second, and once more at once when the set of active faults changes; after the
last fault clears it sends one DM1 with no active DTC. Layout (J1939-73):

* byte 1: lamp status, two bits each from the top: malfunction indicator, red stop, amber
  warning, protect. A sensor fault turns the amber warning lamp on (``0x04``), else ``0x00``;
* byte 2: flash codes, ``0xFF`` (no flashing);
* then 4 bytes per DTC: SPN bits 1-8, SPN bits 9-16, SPN bits 17-19 in the top 3 bits with the
  5-bit FMI below them, then the conversion-method bit (0) above the 7-bit occurrence count.
  No active DTC is SPN 0, FMI 0, OC 0; a single-DTC DM1 is padded with ``0xFF`` to 8 bytes.

More than one DTC makes the message longer than a frame: it goes by the J1939-21 broadcast
transport protocol (a TP.CM BAM frame, PGN 0xECFF, then TP.DT frames, PGN 0xEBFF).

SPN: the generated DBC's (:func:`~excavator_payload.runtime.dbc.sensor_layout`: 520192 + the
signal's column index, the manufacturer-specific range). FMI: :data:`~excavator_payload.
estimators.health.FMI` (7 stuck: mechanical system not responding; 5 dropout: current below
normal or open circuit; 2 disagree and noise: data erratic; 13 offset and gain: out of
calibration).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import can

from excavator_payload.estimators.health import FMI
from excavator_payload.runtime import dbc

DM1_PGN = 0xFECA
TP_CM_PGN = 0xECFF  # connection management to the global address
TP_DT_PGN = 0xEBFF
BAM = 0x20
AMBER_LAMP_ON = 0x04
#: seconds between two DM1 while a fault is active (J1939-73)
DM1_PERIOD = 1.0
MAX_OC = 126  # 127 = not available


def encode_dm1(dtcs: list[tuple[int, int, int]], lamp: int | None = None) -> bytes:
    """The DM1 data of ``dtcs`` ([(spn, fmi, occurrence count)]); none: "no active DTC".

    Parameters
    ----------
    dtcs : list of (int, int, int)
        Active DTCs as (SPN, FMI, occurrence count); empty: "no active DTC".
    lamp : int, optional
        The lamp status byte (default: amber warning when there is a DTC, else all off).

    Returns
    -------
    bytes
        At least 8 bytes (padded with ``0xFF``).

    Raises
    ------
    ValueError
        An SPN, FMI or occurrence count outside its bit width.
    """
    if lamp is None:
        lamp = AMBER_LAMP_ON if dtcs else 0x00
    data = bytearray([lamp & 0xFF, 0xFF])
    for spn, fmi, oc in dtcs or [(0, 0, 0)]:
        if not (0 <= spn < 1 << 19 and 0 <= fmi < 32 and 0 <= oc < 128):
            raise ValueError(f"DTC out of range: SPN {spn}, FMI {fmi}, OC {oc}")
        data += bytes([spn & 0xFF, (spn >> 8) & 0xFF, ((spn >> 16) & 0x07) << 5 | fmi, oc & 0x7F])
    if len(data) < 8:
        data += b"\xff" * (8 - len(data))
    return bytes(data)


def decode_dm1(data: bytes) -> tuple[int, list[tuple[int, int, int]]]:
    """(lamp status byte, [(spn, fmi, oc)]) of DM1 data; the "no active DTC" entry is dropped.

    Parameters
    ----------
    data : bytes
        DM1 data (a single frame's or a reassembled transport's), at least 6 bytes.

    Raises
    ------
    ValueError
        Fewer than 6 bytes.
    """
    data = bytes(data)
    if len(data) < 6:
        raise ValueError(f"a DM1 has at least 6 bytes, got {len(data)}")
    dtcs = []
    for k in range(2, len(data) - 3, 4):
        b = data[k:k + 4]
        if b == b"\xff\xff\xff\xff":  # padding
            continue
        spn = b[0] | b[1] << 8 | (b[2] >> 5) << 16
        fmi, oc = b[2] & 0x1F, b[3] & 0x7F
        if (spn, fmi) != (0, 0):
            dtcs.append((spn, fmi, oc))
    return data[0], dtcs


def dm1_frames(data: bytes, source: int, timestamp: float) -> list[can.Message]:
    """``data`` as one DM1 frame, or as a BAM transport (TP.CM then TP.DT frames) if longer than 8.

    Parameters
    ----------
    data : bytes
        The DM1 data (:func:`encode_dm1`).
    source : int
        The sender's J1939 source address.
    timestamp : float
        s, the frames' timestamp.
    """
    if len(data) <= 8:
        return [can.Message(arbitration_id=dbc.frame_id(DM1_PGN, source), data=data,
                            is_extended_id=True, timestamp=timestamp)]
    packets = math.ceil(len(data) / 7)
    cm = bytes([BAM, len(data) & 0xFF, len(data) >> 8, packets, 0xFF,
                DM1_PGN & 0xFF, (DM1_PGN >> 8) & 0xFF, DM1_PGN >> 16])
    frames = [can.Message(arbitration_id=dbc.frame_id(TP_CM_PGN, source, 7), data=cm,
                          is_extended_id=True, timestamp=timestamp)]
    for k in range(packets):
        chunk = data[7 * k:7 * k + 7]
        frames.append(can.Message(arbitration_id=dbc.frame_id(TP_DT_PGN, source, 7),
                                  data=bytes([k + 1]) + chunk + b"\xff" * (7 - len(chunk)),
                                  is_extended_id=True, timestamp=timestamp))
    return frames


def reassemble(frames: list[can.Message]) -> list[bytes]:
    """The DM1 data carried by ``frames`` (single frames and BAM transports), in order.

    Parameters
    ----------
    frames : list of can.Message
        Frames of a bus or log; those that are not DM1 or its transport are ignored.
    """
    out, pending = [], None
    for f in frames:
        pgn = (f.arbitration_id >> 8) & 0x3FFFF
        if pgn == DM1_PGN:
            out.append(bytes(f.data))
        elif pgn == TP_CM_PGN and f.data[0] == BAM and f.data[5] | f.data[6] << 8 | f.data[7] << 16 == DM1_PGN:
            pending = [f.data[1] | f.data[2] << 8, f.data[3], bytearray()]
        elif pgn == TP_DT_PGN and pending is not None:
            pending[2] += bytes(f.data[1:8])
            if f.data[0] == pending[1]:
                out.append(bytes(pending[2][:pending[0]]))
                pending = None
    return out


@dataclass
class DtcEpisode:
    """One fault as the bus carried it.

    Parameters
    ----------
    spn : int
        The signal's SPN.
    fmi : int
        The failure mode identifier of the fault kind.
    signal : str
        The faulty signal (column name).
    kind : str
        The fault kind (``stuck``, ``dropout``, ...; :data:`~excavator_payload.estimators.health.FMI`).
    start : float
        s, when it became active.
    end : float, optional
        s, when it cleared; NaN while active.
    sent : int, optional
        How many DM1 messages carried it.
    """

    spn: int
    fmi: int
    signal: str
    kind: str
    start: float
    end: float = math.nan  # NaN while active
    sent: int = 0          # DM1 messages that carried it


class DM1Transmitter:
    """Turns the estimator's fault strings into DM1 messages (see the module docstring).

    Parameters
    ----------
    sensor_set : SensorSet
        The sensor set whose signals' SPNs the DTCs carry.
    source : int, optional
        The J1939 source address the DM1 is sent from.
    """

    def __init__(self, sensor_set, source: int = dbc.ESTIMATOR_ADDRESS) -> None:
        self.source = source
        self.spn = {s.signal: s.spn for m in dbc.sensor_layout(sensor_set) for s in m.signals}
        self.reset()

    def reset(self) -> None:
        """Forget every active and past fault (a new log segment or a restarted sensor)."""
        self.active: dict[tuple[int, int], DtcEpisode] = {}
        self.occurrences: dict[tuple[int, int], int] = {}
        self.episodes: list[DtcEpisode] = []
        self.last_sent: float | None = None
        self.messages = 0

    def dtcs(self, fault: str) -> dict[tuple[int, int], tuple[str, str]]:
        """``"signal:kind,..."`` as {(spn, fmi): (signal, kind)} (unknown signals or kinds skipped).

        Parameters
        ----------
        fault : str
            The estimator's fault string, ``"signal:kind,..."`` (empty: none).
        """
        out = {}
        for item in filter(None, fault.split(",")):
            signal, _, kind = item.partition(":")
            if signal in self.spn and kind in FMI:
                out[(self.spn[signal], FMI[kind])] = (signal, kind)
        return out

    def update(self, time: float, fault: str) -> list[can.Message]:
        """The DM1 frames to send at ``time`` for the active ``fault`` string (often none).

        Parameters
        ----------
        time : float
            s, time of the output the fault string came with.
        fault : str
            The active faults, ``"signal:kind,..."`` (empty: none).
        """
        now = self.dtcs(fault)
        changed = set(now) != set(self.active)
        for key in set(self.active) - set(now):
            self.active.pop(key).end = time
        for key, (signal, kind) in now.items():
            if key not in self.active:
                self.occurrences[key] = min(MAX_OC, self.occurrences.get(key, 0) + 1)
                self.active[key] = DtcEpisode(key[0], key[1], signal, kind, time)
                self.episodes.append(self.active[key])
        if not changed and (not now or time - self.last_sent < DM1_PERIOD):
            return []
        self.last_sent = time
        self.messages += 1
        for episode in self.active.values():
            episode.sent += 1
        data = encode_dm1([(spn, fmi, self.occurrences[(spn, fmi)]) for spn, fmi in sorted(self.active)])
        return dm1_frames(data, self.source, time)

    def summary(self) -> list[str]:
        """One line per fault episode: SPN, FMI, signal, kind, when, how many DM1 carried it."""
        return [f"DM1 SPN {e.spn} FMI {e.fmi} ({e.signal} {e.kind}): active {e.start:.2f}"
                + (f"–{e.end:.2f} s" if math.isfinite(e.end) else " s to the end")
                + f", in {e.sent} DM1" for e in self.episodes]
