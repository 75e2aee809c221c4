"""The codec between CAN frames and a sensor set's signals, through a DBC and a signal map.

:class:`SignalCodec` decodes frames into samples (each signal held with its timestamp, samples
emitted on the model's clock) and encodes samples and estimates into frames;
:func:`read_signal_map` and :func:`read_message_map` read the user's map from their DBC's
signals to ours. The DBC's layout and text are :mod:`excavator_payload.runtime.dbc`'s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from excavator_payload.data.schema import SensorSet, get_sensor_set
from excavator_payload.textfiles import not_a_file, read_config_text
from excavator_payload.runtime.dbc import (
    NULL_ADDRESS, CanConfigError, _pgn, error_indicator, is_j1939, load_dbc, not_available,
    sensor_layout, sensor_set_database, valid_raw_max)


@dataclass(frozen=True)
class SignalSource:
    """Where one of our signals comes from: ``value_SI = factor * dbc_value + offset``.

    Parameters
    ----------
    message : str
        Name of the DBC message that carries the signal.
    signal : str
        Name of the signal in that message.
    factor : float, optional
        SI unit per DBC unit.
    offset : float, optional
        SI value added after the factor.
    """

    message: str
    signal: str
    factor: float = 1.0
    offset: float = 0.0


@dataclass(frozen=True)
class MessageOptions:
    """What the signal map's ``[messages.<name>]`` table says of one DBC message.

    Parameters
    ----------
    source_address : int or None, optional
        The only J1939 source address (0 to 253) whose frames are this message (None: the
        DBC's frame id says it, see :meth:`SignalCodec.expected_source`).
    period : float or None, optional
        Its nominal period, s (None: the DBC's ``GenMsgCycleTime``, else learnt from the log).
    """

    source_address: int | None = None
    period: float | None = None


class SignalCodec:
    """Frames <-> signals of a sensor set, through a DBC and a signal map.

    Parameters
    ----------
    sensor_set : SensorSet
    database : cantools Database
        The DBC that describes the sensor frames.
    sources : mapping
        Our signal name -> :class:`SignalSource` in that DBC (for the generated DBC: each
        signal's own message and CamelCase name, factor 1).
    message_options : mapping, optional
        DBC message name -> :class:`MessageOptions` (the signal map's ``[messages.<name>]``:
        its sender's source address, its period).
    """

    def __init__(self, sensor_set: SensorSet, database, sources: Mapping[str, SignalSource],
                 message_options: Mapping[str, MessageOptions] | None = None):
        self.sensor_set = sensor_set
        self.database = database
        self.sources = dict(sources)
        missing = [s for s in sensor_set.signals if s not in self.sources]
        unknown = [s for s in self.sources if s not in sensor_set.signals]
        if missing:
            import difflib

            from excavator_payload.data.schema import SENSOR_SETS

            other = next((o for o in SENSOR_SETS.values() if o.name != sensor_set.name
                          and set(o.signals) <= set(self.sources)), None)
            if other is not None:  # a thesis model with a machine map (or the reverse)
                raise CanConfigError(f"the signal map maps the {other.name} sensor set's signals, but the "
                                     f"model weighs from the {sensor_set.name} set's ({', '.join(missing)} "
                                     "unmapped): a model of the other sensor set?")
            hints = [f"{u!r} (misspelt {c[0]!r}?)" for u in unknown
                     for c in [difflib.get_close_matches(u, missing, n=1, cutoff=0.75)] if c]
            raise CanConfigError(f"the signal map does not say where {', '.join(missing)} come from"
                                 + (f"; it names {', '.join(hints)}" if hints else ""))
        if unknown:  # a misspelt name (its signal is then missing, or mapped twice)
            raise CanConfigError(f"the signal map names {', '.join(map(repr, unknown))}, not signals of the "
                                 f"{sensor_set.name} sensor set ({', '.join(sensor_set.signals)})")
        shared: dict[tuple[str, str], str] = {}
        for signal in sensor_set.signals:
            key = (self.sources[signal].message, self.sources[signal].signal)
            if key in shared:
                # a copy-paste slip: the dipper angle read the boom's, -786 kg 'ok'
                raise CanConfigError(f"the signal map reads {shared[key]} and {signal} from the same DBC "
                                     f"signal {key[0]}.{key[1]}")
            shared[key] = signal
        self.j1939 = is_j1939(database)
        self.messages: dict[str, object] = {}
        self._by_message: dict[str, list[tuple[int, SignalSource]]] = {}
        for i, signal in enumerate(sensor_set.signals):
            src = self.sources[signal]
            try:
                message = database.get_message_by_name(src.message)
            except KeyError:
                raise CanConfigError(f"{signal}: message {src.message!r} is not in the DBC") from None
            try:
                dbc_signal = message.get_signal_by_name(src.signal)
            except KeyError:
                raise CanConfigError(f"{signal}: message {src.message!r} has no signal "
                                     f"{src.signal!r}") from None
            if dbc_signal.multiplexer_ids:
                # a multiplexed signal is in one page of its message's frames: decoded as missing
                # from every other page (no sample ever whole), recorded in none but page 0
                selector = next((s.name for s in message.signals if s.is_multiplexer), "?")
                raise CanConfigError(f"{signal}: DBC signal {src.message}.{src.signal} is multiplexed (sent only "
                                     f"when {selector} = {', '.join(map(str, dbc_signal.multiplexer_ids))}); "
                                     "multiplexed messages are not read: map signals of messages that carry "
                                     "them in every frame")
            scale = float(dbc_signal.conversion.scale)
            if not (math.isfinite(scale) and scale != 0):
                # a scale of 0 decodes every frame as the signal's offset: a constant boom angle
                # weighed 2640 kg 'ok' for 2455 kg
                raise CanConfigError(f"{signal}: the DBC's scale (factor) of {src.message}.{src.signal} "
                                     f"must be finite and non-zero, got {dbc_signal.conversion.scale!r}")
            if not (math.isfinite(src.factor) and src.factor != 0 and math.isfinite(src.offset)):
                raise CanConfigError(f"{signal}: the unit factor must be finite and non-zero")
            self.messages[src.message] = message
            self._by_message.setdefault(src.message, []).append((i, src))
        self.message_options = dict(message_options or {})
        strays = [name for name in self.message_options if name not in self.messages]
        if strays:  # a misspelt message name: its source address would silently not apply
            raise CanConfigError(f"the signal map's [messages.{strays[0]}] is not a message the map reads "
                                 f"signals from ({', '.join(self.messages)})")
        self._by_id = {m.frame_id: m for m in self.messages.values()}
        self._by_pgn: dict[int, list] = {}
        if self.j1939:
            for m in self.messages.values():
                if m.is_extended_frame:
                    self._by_pgn.setdefault(_pgn(m.frame_id), []).append(m)

    @classmethod
    def for_sensor_set(cls, sensor_set: SensorSet | str) -> "SignalCodec":
        """The codec of the generated (shipped) DBC of a sensor set.

        Parameters
        ----------
        sensor_set : SensorSet or str
            The sensor set, or its name.
        """
        sensors = get_sensor_set(sensor_set)
        db = sensor_set_database(sensors.name)
        sources = {s.signal: SignalSource(s.message, s.name)
                   for m in sensor_layout(sensors) for s in m.signals}
        return cls(sensors, db, sources)

    @classmethod
    def from_files(cls, sensor_set: SensorSet, dbc: str | Path | None,
                   signal_map: str | Path | None) -> "SignalCodec":
        """Codec of a user's DBC and TOML signal map (both None: the generated DBC).

        Parameters
        ----------
        sensor_set : SensorSet
            The sensor set whose signals the files map.
        dbc : str or Path or None
            The user's DBC file (``--dbc``).
        signal_map : str or Path or None
            The TOML signal map (``--signal-map``); given together with ``dbc``.

        Raises
        ------
        CanConfigError
            Only one of the two given, or a file that cannot be read.
        """
        if dbc is None and signal_map is None:
            return cls.for_sensor_set(sensor_set)
        if dbc is None or signal_map is None:
            raise CanConfigError("--dbc and --signal-map go together (the map says which DBC signal "
                                 "is which of ours)")
        return cls(sensor_set, load_dbc(dbc), read_signal_map(signal_map), read_message_map(signal_map))

    # -- which frames ------------------------------------------------------------------------
    @property
    def message_names(self) -> list[str]:
        """The messages that carry the sensor set's signals."""
        return list(self.messages)

    def message_of(self, arbitration_id: int):
        """The sensor message with this frame id (J1939: its PGN, from any source address), or None.

        Whether the frame's sender is the message's is :meth:`expected_source`'s to say.

        Parameters
        ----------
        arbitration_id : int
            The frame id of a received frame.
        """
        message = self._by_id.get(arbitration_id)
        if message is None and self._by_pgn:
            candidates = self._by_pgn.get(_pgn(arbitration_id))
            if candidates:
                # two sensors of one PGN at two addresses (two inclinometers of one make):
                # the one whose address this is, else the first
                address = arbitration_id & 0xFF
                message = next((m for m in candidates if self.expected_source(m.name) == address),
                               candidates[0])
        return message

    def expected_source(self, name: str) -> int | None:
        """The J1939 source address whose frames are message ``name``: the signal map's
        ``source_address``, else the DBC frame id's; None where that is the null address 0xFE
        (a generic DBC: the sensor then listens to the first address it hears) or the DBC is
        not J1939 (11-bit ids carry no address).

        Parameters
        ----------
        name : str
            A DBC message name among :attr:`message_names`.
        """
        option = self.message_options.get(name)
        if option is not None and option.source_address is not None:
            return option.source_address
        message = self.messages[name]
        if not (self.j1939 and message.is_extended_frame):
            return None
        address = message.frame_id & 0xFF
        return None if address == NULL_ADDRESS else address

    def nominal_period(self, name: str) -> float | None:
        """Message ``name``'s period, s: the signal map's ``period``, else the DBC's
        ``GenMsgCycleTime``; None when neither says (the sensor learns it from the frames).

        Parameters
        ----------
        name : str
            A DBC message name among :attr:`message_names`.
        """
        option = self.message_options.get(name)
        if option is not None and option.period is not None:
            return option.period
        cycle = getattr(self.messages[name], "cycle_time", None)
        return float(cycle) / 1000.0 if cycle else None

    # -- decoding ------------------------------------------------------------------------------
    def decode(self, message, data: bytes) -> list[tuple[int, float]]:
        """(signal index, SI value) of every one of our signals in a frame of ``message``.

        A frame shorter than the message (a longer one is read by the message's bytes), a J1939
        error / not-available raw value or a value outside the signal's DBC range gives NaN for
        the signals concerned (never an exception).

        Parameters
        ----------
        message : cantools Message
            The sensor message the frame is (:meth:`message_of`).
        data : bytes
            The frame's data bytes.
        """
        targets = self._by_message[message.name]
        if len(data) < message.length:
            return [(i, math.nan) for i, _ in targets]
        try:
            # bytes beyond the DBC's length: a CAN FD frame padded to its next length (12 … 64
            # bytes), or a classic frame padded to 8; every signal lies in the DBC's bytes
            raw = message.decode(bytes(data[:message.length]), decode_choices=False, scaling=False)
        except Exception:  # a frame cantools cannot decode is a bad frame, not a crash
            return [(i, math.nan) for i, _ in targets]
        out = []
        for i, src in targets:
            sig = message.get_signal_by_name(src.signal)
            value = raw.get(src.signal)
            if value is None:
                out.append((i, math.nan))
                continue
            if self.j1939 and not sig.is_float and int(value) > valid_raw_max(sig.length):
                out.append((i, math.nan))
                continue
            phys = float(value) * sig.scale + sig.offset
            if ((sig.minimum is not None and phys < sig.minimum - 0.5 * abs(sig.scale))
                    or (sig.maximum is not None and phys > sig.maximum + 0.5 * abs(sig.scale))):
                out.append((i, math.nan))
                continue
            out.append((i, src.factor * phys + src.offset))
        return out

    # -- encoding ------------------------------------------------------------------------------
    def encode(self, values: Sequence[float]) -> list[tuple[int, bytes, bool]]:
        """Frames ``(frame id, data, extended)`` of one sample (signals in column order).

        A non-finite value is sent as "not available", a value outside the DBC range as the
        J1939 error indicator (or clipped in a non-J1939 DBC).

        Parameters
        ----------
        values : sequence of float
            One sample's signals in SI units, in the sensor set's column order.
        """
        frames = []
        for name, message in self.messages.items():
            raw: dict[str, int | float] = {}
            for i, src in self._by_message[name]:
                sig = message.get_signal_by_name(src.signal)
                raw[src.signal] = self._raw(sig, (float(values[i]) - src.offset) / src.factor)
            for sig in message.signals:  # signals of the message that are not ours
                if sig.name not in raw:
                    raw[sig.name] = not_available(sig.length) if self.j1939 else 0
            data = message.encode(raw, scaling=False, strict=False, padding=True)
            frames.append((message.frame_id, data, message.is_extended_frame))
        return frames

    def _raw(self, sig, value: float) -> int | float:
        if sig.is_float:
            return value
        if sig.is_signed:
            bottom, top = -(1 << (sig.length - 1)), (1 << (sig.length - 1)) - 1
        else:
            bottom, top = 0, valid_raw_max(sig.length) if self.j1939 else (1 << sig.length) - 1
        if not math.isfinite(value):
            return not_available(sig.length) if self.j1939 and not sig.is_signed else 0
        raw = round((value - sig.offset) / sig.scale)
        lo = sig.minimum if sig.minimum is not None else -math.inf
        hi = sig.maximum if sig.maximum is not None else math.inf
        if raw < bottom or raw > top or value < lo - abs(sig.scale) / 2 or value > hi + abs(sig.scale) / 2:
            if self.j1939 and not sig.is_signed:
                return error_indicator(sig.length)
            raw = min(max(raw, bottom), top)
        return int(raw)

    def beyond_range(self, values: np.ndarray) -> dict[str, tuple[int, int, float, float]]:
        """Per signal, how many finite values cannot go on the bus as themselves: outside the DBC
        signal's ``[minimum, maximum]`` or its raw width (sent as the J1939 error indicator, or
        clipped in another DBC).

        Parameters
        ----------
        values : array_like
            Samples (rows) of signals in SI units, sensor-set column order.

        Returns
        -------
        dict
            Our signal name -> (values beyond, finite values, the data's min and max in the DBC's
            unit), for the signals with any beyond.
        """
        values = np.atleast_2d(np.asarray(values, dtype=float))
        out = {}
        for name, message in self.messages.items():
            for i, src in self._by_message[name]:
                sig = message.get_signal_by_name(src.signal)
                v = values[:, i]
                finite = np.isfinite(v)
                with np.errstate(all="ignore"):
                    dbc_value = (v - src.offset) / src.factor
                    half = 0.5 * abs(float(sig.scale))
                    lo = -math.inf if sig.minimum is None else sig.minimum - half
                    hi = math.inf if sig.maximum is None else sig.maximum + half
                    bad = (dbc_value < lo) | (dbc_value > hi) | ~np.isfinite(dbc_value)
                    if not sig.is_float:
                        raw = np.round((dbc_value - sig.offset) / sig.scale)
                        if sig.is_signed:
                            bottom, top = -float(1 << (sig.length - 1)), float((1 << (sig.length - 1)) - 1)
                        else:
                            bottom = 0.0
                            top = float(valid_raw_max(sig.length) if self.j1939 else (1 << sig.length) - 1)
                        bad |= (raw < bottom) | (raw > top)
                count = int(np.count_nonzero(bad & finite))
                if count:
                    shown = dbc_value[finite]
                    out[self.sensor_set.signals[i]] = (count, int(finite.sum()), float(shown.min()),
                                                       float(shown.max()))
        return out

    def quantise(self, values: np.ndarray) -> np.ndarray:
        """What the receiver decodes from ``values`` (rows of samples): encode then decode.

        Parameters
        ----------
        values : array_like
            Samples (rows) of signals in SI units, sensor-set column order.

        Returns
        -------
        ndarray
            The decoded values, same shape (2-D); NaN where the bus carries none.
        """
        values = np.atleast_2d(np.asarray(values, dtype=float))
        out = np.full_like(values, np.nan)
        for r, row in enumerate(values):
            for fid, data, _ in self.encode(row):
                message = self._by_id[fid]
                for i, v in self.decode(message, data):
                    out[r, i] = v
        return out


#: The top-level tables of a signal map (``truck_button``: ``loadout``'s new-truck button).
MAP_TABLES = ("signals", "messages", "truck_button")


def read_signal_map(path: str | Path) -> dict[str, SignalSource]:
    """Read a TOML signal map.

    Format (one table per signal of the sensor set; ``factor``/``offset`` convert the DBC's
    unit to SI, ``SI = factor * dbc_value + offset``, default 1 and 0)::

        [signals.boom_angle]
        message = "ArmAngles"
        signal = "BoomAngleDeg"
        factor = 0.017453292519943295   # deg -> rad

    Parameters
    ----------
    path : str or Path
        The TOML file.

    Returns
    -------
    dict
        Our signal name -> :class:`SignalSource`.
    """
    import tomllib

    path = Path(path)
    if not path.is_file():
        raise CanConfigError(not_a_file(path, "signal map"))
    try:
        data = tomllib.loads(read_config_text(path))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise CanConfigError(f"signal map '{path}' is not valid TOML: {exc}") from None
    strays = [k for k in data if k not in MAP_TABLES]
    if strays:  # a misspelt [messages.X] table: its source address or period silently not applied
        import difflib

        close = difflib.get_close_matches(strays[0], MAP_TABLES, n=1, cutoff=0.6)
        raise CanConfigError(f"signal map '{path}': unknown table or key {strays[0]!r}"
                             + (f" (misspelt {close[0]!r}?)" if close else "")
                             + f"; a signal map has {', '.join(MAP_TABLES)}")
    table = data.get("signals")
    if not isinstance(table, dict) or not table:
        raise CanConfigError(f"signal map '{path}' has no [signals.<name>] tables")
    out = {}
    for name, entry in table.items():
        if not isinstance(entry, dict) or not {"message", "signal"} <= set(entry):
            raise CanConfigError(f"signal map '{path}': [signals.{name}] needs 'message' and 'signal'")
        extra = [k for k in entry if k not in ("message", "signal", "factor", "offset")]
        if extra:  # a misspelt 'factor' was ignored: the DBC's unit read as SI
            raise CanConfigError(f"signal map '{path}': [signals.{name}] has unknown key(s) "
                                 f"{', '.join(map(repr, extra))} (known: message, signal, factor, offset)")
        for key in ("factor", "offset"):
            value = entry.get(key)
            if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))):
                raise CanConfigError(f"signal map '{path}': [signals.{name}] {key} must be a number, got "
                                     f"{value!r} (write {key} = 0.01745, without quotes)")
        try:
            out[name] = SignalSource(str(entry["message"]), str(entry["signal"]),
                                     float(entry.get("factor", 1.0)), float(entry.get("offset", 0.0)))
        except (TypeError, ValueError):
            raise CanConfigError(f"signal map '{path}': [signals.{name}] factor/offset must be "
                                 "numbers") from None
    return out


def read_message_map(path: str | Path) -> dict[str, MessageOptions]:
    """The ``[messages.<name>]`` tables of a TOML signal map (optional)::

        [messages.HouseInclination]
        source_address = 0x21   # only this J1939 sender's frames are the message
        period = 0.1            # s, when the DBC has no GenMsgCycleTime for it

    Parameters
    ----------
    path : str or Path
        The TOML signal map.

    Returns
    -------
    dict
        DBC message name -> :class:`MessageOptions` (empty without ``[messages]``).
    """
    import tomllib

    path = Path(path)
    try:
        data = tomllib.loads(read_config_text(path))
    except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise CanConfigError(f"signal map '{path}' is not valid TOML: {exc}") from None
    table = data.get("messages", {})
    if not isinstance(table, dict):
        raise CanConfigError(f"signal map '{path}': 'messages' must be [messages.<name>] tables")
    out = {}
    for name, entry in table.items():
        if not isinstance(entry, dict):
            raise CanConfigError(f"signal map '{path}': [messages.{name}] must be a table")
        extra = [k for k in entry if k not in ("source_address", "period")]
        if extra:
            raise CanConfigError(f"signal map '{path}': [messages.{name}] has unknown key(s) "
                                 f"{', '.join(map(repr, extra))} (known: source_address, period)")
        address, period = entry.get("source_address"), entry.get("period")
        if address is not None and (isinstance(address, bool) or not isinstance(address, int)
                                    or not 0 <= address <= 0xFD):
            raise CanConfigError(f"signal map '{path}': [messages.{name}] source_address must be a J1939 "
                                 f"address 0 … 253 (0x00 … 0xFD), got {address!r}")
        if period is not None and (isinstance(period, bool) or not isinstance(period, (int, float))
                                   or not math.isfinite(period) or period <= 0):
            raise CanConfigError(f"signal map '{path}': [messages.{name}] period must be a positive number "
                                 f"of seconds, got {period!r}")
        out[name] = MessageOptions(address, None if period is None else float(period))
    return out
