"""Loadout from CAN frames: a log replayed or a live bus, pass by pass as the samples arrive.

:class:`BusLoadout` puts the frames through a :class:`~excavator_payload.runtime.can_sensor.PayloadSensor`
(samples on the model's clock from messages at their own rates, other ECUs' frames not the
sensor's) and follows each truck with a :class:`TruckTracker`, which finds the passes with the
same rules as a dataset's (:func:`~excavator_payload.runtime.loadout.find_passes`,
:func:`~excavator_payload.runtime.loadout.lock_weight`): every :data:`EVALUATE_EVERY` samples
it reads the bucket's moves of the truck so far, and a pass is locked as soon as its dump has
opened the bucket by :data:`~excavator_payload.runtime.loadout.DUMP_OPEN` — its weight is the
last ``ok`` estimate *before* the dump started. When the truck ends the whole truck is read
once more, so a dump at the very end of a log is not lost.

Truck changes
-------------
* a gap of :data:`~excavator_payload.runtime.loadout.TRUCK_GAP` s or more in the sensor's
  *own* frames (another ECU's traffic does not bridge it; on a live bus the receiver's clock
  says so without waiting for the next frame);
* the operator's button: a frame of :class:`TruckButton`'s message whose signal goes to
  "pressed" (default: the shipped DBC's ``LoadoutControl.NewTruck`` from the operator panel,
  source address 0xA2; a signal map's ``[truck_button]`` table names another);
* the API: :meth:`BusLoadout.new_truck`.

The sensor (and its estimator) restarts at each truck, as a dataset's experiment does.

Units
-----
With a :class:`~excavator_payload.runtime.loadout_guard.UnitGuard` every few seconds of decoded
samples are judged for signals in another unit (pressures in bar, angles in degrees, rates in
°/s: a DBC mapped with the wrong factor). A log is refused with one line
(:func:`check_log_units` on its first seconds before anything is recorded, then the guard
throughout, ``refuse_units``); on a live bus, while the guard is flagged no estimate is published
``ok`` (``out_of_range`` instead) and a pass locked then is ``not_weighed`` with the guard's
finding as its reason; the live view shows it in red.

Operator commands and the live view: :mod:`excavator_payload.runtime.loadout_live`.

On a live bus (``send=True``) the frames to send are returned: every estimate
(``PayloadEstimate``, ``VehicleWeight``), a DM1 while a sensor is faulty, and for each locked
pass ``LoadoutPass`` then ``LoadoutTruck`` (its running total), and ``LoadoutTruck`` again when
the truck leaves.
"""

from __future__ import annotations

import logging
import math
import time as _time
from dataclasses import dataclass, replace

import can
import numpy as np

from excavator_payload.errors import DatasetError
from excavator_payload.runtime import dbc
from excavator_payload.textfiles import read_config_text
from excavator_payload.runtime.loadout import (
    DEGRADED, TRUCK_GAP, Pass, ShiftRecord, Truck, _truth_match, episode_row, find_passes, lock_weight)

#: The truck's passes are looked for again every this many samples (0.1 s at 100 Hz): a pass
#: is locked at most this late after its dump opened the bucket by DUMP_OPEN.
EVALUATE_EVERY = 10
#: A second "pressed" frame within this time (s) is the same press (a panel that sends the
#: button's state periodically while it is held).
PRESS_HOLD = 1.0
#: The status an ``ok`` estimate is published with while the unit guard is flagged.
GUARDED = "out_of_range"
#: Windows of a log's first samples :func:`check_log_units` judges at most, waiting for the arm to move.
PREPASS_WINDOWS = 12

_log = logging.getLogger(__name__)


# -- the operator's button ---------------------------------------------------------------------
@dataclass
class TruckButton:
    """The "new truck" button: ``signal`` of DBC ``message`` equal to ``pressed`` is a press.

    Parameters
    ----------
    message : cantools message
        The button's message (its frame id says its PGN and, J1939, its sender).
    signal : str
        The signal in it.
    pressed : float
        The decoded value that means "pressed".
    source : int or None
        The J1939 source address whose frames are the button (None: the frame id's).
    """

    message: object
    signal: str
    pressed: float = 1.0
    source: int | None = None

    def __post_init__(self) -> None:
        self._last: tuple[float, bool] | None = None  # (time, pressed) of the last frame

    @classmethod
    def default(cls) -> "TruckButton":
        """The shipped DBC's ``LoadoutControl.NewTruck`` (value 1) from the operator panel."""
        db = dbc.estimate_database()
        return cls(db.get_message_by_name(dbc.LOADOUT_CONTROL_MESSAGE), "NewTruck", 1.0, dbc.OPERATOR_ADDRESS)

    @classmethod
    def from_signal_map(cls, path, database) -> "TruckButton":
        """The signal map's ``[truck_button]`` table (``message``, ``signal`` in ``database``;
        optional ``pressed``, default 1, and ``source_address``), else :meth:`default`::

            [truck_button]
            message = "CabSwitches"
            signal = "NextTruck"
            pressed = 1
            source_address = 0x28

        Parameters
        ----------
        path : str or Path or None
            The TOML signal map (None: :meth:`default`).
        database : cantools Database
            The DBC the button's message is looked up in.

        Raises
        ------
        CanConfigError
            An unreadable map, or a ``[truck_button]`` table that is wrong or names what the DBC lacks.
        """
        import tomllib

        if path is None:
            return cls.default()
        try:
            table = tomllib.loads(read_config_text(path)).get("truck_button")
        except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise dbc.CanConfigError(f"signal map '{path}' is not valid TOML: {exc}") from None
        if table is None:
            return cls.default()
        if not isinstance(table, dict) or not {"message", "signal"} <= set(table):
            raise dbc.CanConfigError(f"signal map '{path}': [truck_button] needs 'message' and 'signal'")
        extra = [k for k in table if k not in ("message", "signal", "pressed", "source_address")]
        if extra:
            raise dbc.CanConfigError(f"signal map '{path}': [truck_button] has unknown key(s) "
                                     f"{', '.join(map(repr, extra))} (known: message, signal, pressed, "
                                     "source_address)")
        try:
            message = database.get_message_by_name(str(table["message"]))
            message.get_signal_by_name(str(table["signal"]))
        except KeyError:
            raise dbc.CanConfigError(f"signal map '{path}': [truck_button] {table['message']}.{table['signal']} "
                                     "is not in the DBC") from None
        address = table.get("source_address")
        if address is not None and (isinstance(address, bool) or not isinstance(address, int)
                                    or not 0 <= address <= 0xFD):
            raise dbc.CanConfigError(f"signal map '{path}': [truck_button] source_address must be a J1939 "
                                     f"address 0 … 253, got {address!r}")
        pressed = table.get("pressed", 1)
        if isinstance(pressed, bool) or not isinstance(pressed, (int, float)):
            raise dbc.CanConfigError(f"signal map '{path}': [truck_button] pressed must be a number")
        return cls(message, str(table["signal"]), float(pressed), address)

    def matches(self, frame: can.Message) -> bool:
        """Whether ``frame`` is the button's message from the button's sender.

        Parameters
        ----------
        frame : can.Message
            Any received frame.
        """
        mine = self.message.frame_id
        if not (frame.is_extended_id and self.message.is_extended_frame):
            return frame.arbitration_id == mine and frame.is_extended_id == self.message.is_extended_frame
        if dbc._pgn(frame.arbitration_id) != dbc._pgn(mine):
            return False
        return (frame.arbitration_id & 0xFF) == (self.source if self.source is not None else mine & 0xFF)

    def press(self, frame: can.Message) -> bool:
        """Whether ``frame`` (one of :meth:`matches`) is a new press: pressed now, and released
        or silent for :data:`PRESS_HOLD` s before.

        Parameters
        ----------
        frame : can.Message
            A frame of the button; its timestamp (s) is remembered for the next.
        """
        try:
            value = self.message.decode(bytes(frame.data), decode_choices=False).get(self.signal)
        except Exception:  # a frame the DBC cannot decode is no press
            return False
        now = value is not None and float(value) == self.pressed
        t = float(frame.timestamp)
        last, self._last = self._last, (t, now)
        return now and (last is None or not last[1] or t - last[0] > PRESS_HOLD)

    def frame(self, pressed: bool = True, timestamp: float = 0.0) -> can.Message:
        """A frame of the button (tests, and a panel that is a computer).

        Parameters
        ----------
        pressed : bool, optional
            Send the "pressed" value (else 0).
        timestamp : float, optional
            s, the frame's timestamp.
        """
        values = {s.name: 0 for s in self.message.signals}
        values[self.signal] = self.pressed if pressed else 0
        data = self.message.encode(values, padding=True, strict=False)
        fid = self.message.frame_id
        if self.source is not None and self.message.is_extended_frame:
            fid = (fid & ~0xFF) | self.source
        return can.Message(timestamp=timestamp, arbitration_id=fid, is_extended_id=self.message.is_extended_frame,
                           data=data)


# -- one truck, sample by sample ---------------------------------------------------------------
class TruckTracker:
    """The passes of one truck found while its samples arrive (module doc).

    Parameters
    ----------
    truck : int
        The truck's number in the shift.
    target : float or None
        Its target load, kg.
    signals : sequence of str
        The sensor set's signals (the samples' order); ``bucket_angle`` and ``bucket_rate`` are read.
    """

    def __init__(self, truck: int, target: float | None, signals) -> None:
        signals = list(signals)
        self.angle_index, self.rate_index = signals.index("bucket_angle"), signals.index("bucket_rate")
        self.truck = Truck(truck, target=target)
        # the truck's samples so far, in arrays grown by doubling (a list per sample made each
        # look for passes copy the whole truck)
        self._num = np.empty((5, 4096))  # time, angle, rate, estimate, sigma
        self._status = np.empty(4096, dtype=object)
        self._fault = np.empty(4096, dtype=object)  # the named sensors, for a degraded pass's reason
        self.samples = 0
        self._held = (0.0, 0.0)  # the last finite bucket angle and rate (a stale sample holds them)

    def add(self, output) -> list[Pass]:
        """One estimate with its sample's values; returns the passes locked by it (0 or 1, rarely 2).

        Parameters
        ----------
        output : SensorOutput
            A published estimate whose ``values`` hold its sample (a NaN bucket signal holds the last
            finite one).
        """
        if self.truck.start is None:
            self.truck.start = float(output.time)
        angle, rate = float(output.values[self.angle_index]), float(output.values[self.rate_index])
        held_angle, held_rate = self._held
        angle = angle if math.isfinite(angle) else held_angle
        rate = rate if math.isfinite(rate) else held_rate
        self._held = (angle, rate)
        n = self.samples
        if n == self._num.shape[1]:
            self._num = np.concatenate([self._num, np.empty_like(self._num)], axis=1)
            self._status = np.concatenate([self._status, np.empty_like(self._status)])
            self._fault = np.concatenate([self._fault, np.empty_like(self._fault)])
        self._num[:, n] = (float(output.time) - self.truck.start, angle, rate, float(output.estimate),
                           float(output.sigma))
        self._status[n] = output.status
        self._fault[n] = getattr(output, "fault", "") or ""
        self.samples = n + 1
        if self.samples % EVALUATE_EVERY:
            return []
        return self._evaluate()

    def _evaluate(self) -> list[Pass]:
        if self.samples < 3:
            return []
        time, angle, rate, estimate, sigma = self._num[:, :self.samples]
        found = find_passes(time, angle, rate)
        new = []
        for dig, dump in found[len(self.truck.passes):]:
            # locked passes stay as sent; a new one is weighed on the estimates before its dump
            t_lock, w, s, reason, status = lock_weight(time, estimate, sigma, self._status[:self.samples], dig,
                                                       dump, self._fault[:self.samples])
            p = Pass(self.truck.truck, len(self.truck.passes) + 1, float(time[dig]), float(time[dump]),
                     t_lock, w, s, status, reason)
            self.truck.passes.append(p)
            new.append(p)
        return new

    def close(self) -> list[Pass]:
        """The truck has left: read it whole once more; returns the passes found only now."""
        return self._evaluate()


# -- the shift on a bus ------------------------------------------------------------------------
class BusLoadout:
    """Frames in, passes and trucks out (module doc).

    Parameters
    ----------
    sensor : PayloadSensor
        The payload sensor (its estimator fitted on the machine sensor set).
    record : ShiftRecord or None
        Where each truck is written (with each locked pass and when it leaves).
    source : str
        The record's source key of this log / bus session.
    target : float or None
        Each truck's target load, kg.
    button : TruckButton or None
        The operator's "new truck" button (None: :meth:`TruckButton.default`).
    send : bool
        Return the frames to send (live bus); else only follow the faults.
    truths : list of list of dict, optional
        The true passes of truck 1, 2, … (a dataset's experiment metadata ``passes``): the
        record then has each pass's true weight.
    on_pass, on_truck : callable, optional
        ``on_pass(truck, pass)`` after a pass is locked, ``on_truck(truck)`` after a truck left.
    data_name, model_name : str
        What the record's ``runs`` table says was weighed (the log, the bus) and by which model.
    guard : UnitGuard or None
        Judges the decoded samples' units (module doc); None: no check.
    refuse_units : bool
        A guard finding raises :class:`DatasetError` (a log) instead of flagging (a live bus).
    """

    def __init__(self, sensor, record: ShiftRecord | None = None, source: str = "", target: float | None = None,
                 button: TruckButton | None = None, send: bool = False, truths: list | None = None,
                 on_pass=None, on_truck=None, data_name: str = "", model_name: str = "", guard=None,
                 refuse_units: bool = False) -> None:
        if "bucket_angle" not in sensor.sensor_set.signals or "bucket_rate" not in sensor.sensor_set.signals:
            raise DatasetError(f"loadout reads the bucket's moves: the {sensor.sensor_set.name} sensor set "
                               "has no bucket_angle and bucket_rate")
        self.sensor, self.record, self.source, self.target = sensor, record, source, target
        self.button = button or TruckButton.default()
        self.send, self.truths = send, truths
        self.on_pass, self.on_truck = on_pass, on_truck
        self.trucks: list[Truck] = []
        self.tracker: TruckTracker | None = None
        self.last_frame: float | None = None       # the sensor's own last frame (its time)
        self.last_received: float | None = None    # ... on the receiver's clock
        self.presses = 0
        self.gaps = 0
        self.samples = 0
        self._episodes = 0
        self.summary = ""  # what a replayed log held (LogSummary.describe)
        self.log_end = ""  # ... and the line that says it ends early (truncated), if it does
        self.publisher = _Publisher()
        self.guard, self.refuse_units = guard, refuse_units
        self.guard_source = data_name or source  # names the log / bus in the guard's line
        sensor.reset()
        sensor.dm1.reset()
        self.run = (record.start_run(source, data_name, model_name, getattr(sensor.estimator, "rated_payload", None))
                    if record is not None else 0)

    # -- frames in ---------------------------------------------------------------------------
    def feed(self, message: can.Message, received_at: float | None = None) -> list[can.Message]:
        """One frame from the bus or a log; returns the frames to send (``send``) for it.

        Parameters
        ----------
        message : can.Message
            The frame; its timestamp (s) is the sensor's clock.
        received_at : float, optional
            s, the receiver's clock at reception (None: the truck gap is timed on
            ``time.monotonic()``, the sensor's time-outs on the frame's timestamp).
        """
        out: list[can.Message] = []
        if self.button.matches(message):
            if self.button.press(message):
                self.presses += 1
                out += self.new_truck()
            return out
        spec = self.sensor.accepts(message)
        if spec is None:
            self.sensor.counters["frames"] += 1
            return out
        t = float(message.timestamp)
        if not math.isfinite(t):
            return out
        if self.last_frame is not None and t - self.last_frame >= TRUCK_GAP and self.tracker is not None:
            self.gaps += 1
            out += self.new_truck()
        self.last_frame = t if self.last_frame is None else max(t, self.last_frame)
        self.last_received = _time.monotonic() if received_at is None else float(received_at)
        for output in self.sensor.feed(message, received_at, spec):
            out += self._output(output)
        return out

    def _output(self, output) -> list[can.Message]:
        if output.values is None and self.last_frame is not None and self.last_received is not None:
            # a stale tick of a silent bus is timed on the receiver's clock (monotonic), the
            # faults on the frames' (a fault ended at "24095.8 s" of a 20 s truck): move it over
            output = replace(output, time=float(output.time) - self.last_received + self.last_frame)
        if output.values is not None and self.guard is not None:
            was = self.guard.flagged
            if self.guard.add(output.time, output.values):
                self._judged(was)
            if self.guard.flagged and output.status in ("ok", DEGRADED):
                output = replace(output, status=GUARDED)  # no weight while a signal's unit is wrong
        out = self.sensor.frames(output) if self.send else []
        if not self.send:
            self.sensor.dm1.update(output.time, output.fault)
        if output.values is None:
            return out
        self.samples += 1
        if self.tracker is None:
            self.tracker = TruckTracker(len(self.trucks) + 1, self.target, self.sensor.sensor_set.signals)
        self._note_faults()
        for p in self.tracker.add(output):
            out += self._locked(self._guarded(p))
        return out

    def _judged(self, was: bool) -> None:
        """The guard judged a window: refuse (a log), or say loudly that the flag rose or fell."""
        guard = self.guard
        if guard.flagged and self.refuse_units:
            raise DatasetError(guard.message(self.guard_source))
        if guard.flagged and not was:
            _log.warning("%s; no pass is weighed until the units look right", guard.message(self.guard_source))
        elif was and not guard.flagged:
            _log.warning("%s: the signals' units look right again; passes are weighed", self.guard_source)

    def _guarded(self, p: Pass) -> Pass:
        """A pass locked while the unit guard is flagged is not weighed (its weight came from
        samples in the wrong unit, perhaps before the window that showed it)."""
        if self.guard is not None and self.guard.flagged:
            p.time_lock = p.weight = p.sigma = None
            p.status, p.reason = "not_weighed", "signal units: " + ", ".join(self.guard.short)
        return p

    def _note_faults(self) -> None:
        """Fault episodes that began since the last sample belong to the current truck."""
        episodes = self.sensor.dm1.episodes
        for e in episodes[self._episodes:]:
            self.tracker.truck.faults.append(e)
        self._episodes = len(episodes)

    def _locked(self, p: Pass) -> list[can.Message]:
        truck = self.tracker.truck
        self._write(truck)
        if self.on_pass is not None:
            self.on_pass(truck, p)
        return self.publisher.pass_frames(truck, p) if self.send else []

    def _write(self, truck: Truck) -> None:
        if self.record is None:
            return
        rows = Truck(truck.truck, truck.passes, truck.target, truck.true_total, truck.true_passes, truck.matched,
                     truck.start, [_fault_row(f, truck.start) for f in truck.faults])
        self.record.write_truck(self.source, self.run, rows)

    # -- trucks ------------------------------------------------------------------------------
    def new_truck(self) -> list[can.Message]:
        """The truck has left (operator button, gap, or this API call): weigh what is pending,
        close and record it; the next sample starts the next truck. Returns the frames to send."""
        out: list[can.Message] = []
        if self.sensor.pending:
            output = self.sensor.flush()
            if output is not None:
                out += self._output(output)
        tracker, self.tracker = self.tracker, None
        self.sensor.reset()
        if tracker is None:  # nothing loaded since the last change: no empty truck
            return out
        truck = tracker.truck
        for p in tracker.close():
            out += self._locked_closing(truck, self._guarded(p))
        k = len(self.trucks)
        if self.truths is not None and k < len(self.truths) and self.truths[k]:
            truth = self.truths[k]
            truck.matched = _truth_match(truck.passes, truth)
            truck.true_passes = len(truth)
            truck.true_total = float(sum(t["payload"] for t in truth))
        truck.faults = [_fault_row(f, truck.start) for f in truck.faults]
        self.trucks.append(truck)
        self._write(truck)
        if self.send:
            out += [self.publisher.truck_frame(truck)]
        if self.on_truck is not None:
            self.on_truck(truck)
        return out

    def _locked_closing(self, truck: Truck, p: Pass) -> list[can.Message]:
        if self.on_pass is not None:
            self.on_pass(truck, p)
        return self.publisher.pass_frames(truck, p) if self.send else []

    def poll(self, now: float) -> list[can.Message]:
        """Live: called regularly with the receiver's clock (``time.monotonic``-like, the clock
        of ``received_at``): the sensor's time-outs, and a truck that left by a gap without
        waiting for the next frame.

        Parameters
        ----------
        now : float
            s, the receiver's clock.
        """
        out: list[can.Message] = []
        for output in self.sensor.poll(now):
            out += self._output(output)
        if self.tracker is not None and self.last_received is not None and now - self.last_received >= TRUCK_GAP:
            self.gaps += 1
            out += self.new_truck()
        return out

    def finish(self) -> list[Truck]:
        """End of the log / session: the last truck closed and the run marked finished."""
        self.new_truck()
        if self.record is not None:
            self.record.finish_run(self.run)
        return self.trucks

    # -- what the cab shows --------------------------------------------------------------------
    @property
    def current(self) -> Truck | None:
        """The truck being loaded (None between trucks)."""
        return None if self.tracker is None else self.tracker.truck


def _fault_row(f, start: float | None) -> dict:
    row = episode_row(f) if not isinstance(f, dict) else dict(f)
    if start is not None and not isinstance(f, dict):  # the truck's time, as the passes'
        row["start"] -= start
        row["end"] -= start
    return row


class _Publisher:
    """The LoadoutPass / LoadoutTruck frames of the shipped DBC."""

    def __init__(self) -> None:
        db = dbc.estimate_database()
        self.pass_message = db.get_message_by_name(dbc.LOADOUT_PASS_MESSAGE)
        self.truck_message = db.get_message_by_name(dbc.LOADOUT_TRUCK_MESSAGE)

    def pass_frames(self, truck: Truck, p: Pass) -> list[can.Message]:
        from excavator_payload.runtime.can_sensor import j1939_raw

        weight = math.nan if p.weight is None else p.weight
        sigma = math.nan if p.sigma is None else p.sigma
        data = self.pass_message.encode(
            {"PassTruck": truck.truck % (dbc.valid_raw_max(16) + 1), "PassNumber": min(p.index, dbc.valid_raw_max(8)),
             "PassWeight": j1939_raw(weight, dbc.PAYLOAD_RESOLUTION, dbc.PAYLOAD_OFFSET),
             "PassSigma": j1939_raw(sigma, dbc.PAYLOAD_RESOLUTION, 0.0),
             "PassStatus": dbc.PASS_STATUSES.index(p.status) if p.status in dbc.PASS_STATUSES else 1}, scaling=False, padding=True, strict=False)
        return [can.Message(arbitration_id=self.pass_message.frame_id, is_extended_id=True, data=data),
                self.truck_frame(truck)]

    def truck_frame(self, truck: Truck) -> can.Message:
        """The truck's running total (and target: what is left is their difference)."""
        from excavator_payload.runtime.can_sensor import j1939_raw

        target = math.nan if truck.target is None else truck.target
        data = self.truck_message.encode(
            {"TruckNumber": truck.truck % (dbc.valid_raw_max(16) + 1),
             "TruckPasses": min(len(truck.passes), dbc.valid_raw_max(8)),
             "TruckUnweighed": min(truck.unweighed, dbc.valid_raw_max(8)),
             "TruckTotal": j1939_raw(truck.total, dbc.TRUCK_RESOLUTION, 0.0),
             "TruckTarget": j1939_raw(target, dbc.TRUCK_RESOLUTION, 0.0)},
            scaling=False, padding=True, strict=False)
        return can.Message(arbitration_id=self.truck_message.frame_id, is_extended_id=True, data=data)


def decode_loadout(frame: can.Message) -> dict | None:
    """A LoadoutPass or LoadoutTruck frame as SI values (NaN: not available / error), else None.

    Parameters
    ----------
    frame : can.Message
        Any frame.
    """
    db = dbc.estimate_database()
    for name in (dbc.LOADOUT_PASS_MESSAGE, dbc.LOADOUT_TRUCK_MESSAGE):
        message = db.get_message_by_name(name)
        if frame.arbitration_id == message.frame_id:
            raw = message.decode(bytes(frame.data), scaling=False, decode_choices=False)
            out = {"message": name}
            for sig in message.signals:
                value = raw[sig.name]
                bad = sig.length >= 8 and value > dbc.valid_raw_max(sig.length)
                out[sig.name] = math.nan if bad else value * sig.scale + sig.offset
            return out
    return None


# -- a log -------------------------------------------------------------------------------------
def replay_loadout(path, loadout: BusLoadout, progress: bool = False) -> list[Truck]:
    """Every frame of the CAN log ``path`` through ``loadout``; the trucks (one line if nothing
    in the log is the sensor's, saying what it holds). A log that ends early is weighed up to
    where it ends; ``loadout.log_end`` is then the line that says so.

    Parameters
    ----------
    path : str or Path
        The CAN log (a format :func:`~excavator_payload.runtime.logs.read_frames` reads).
    loadout : BusLoadout
        Fed every frame, then finished.
    progress : bool, optional
        Show a progress bar.

    Raises
    ------
    DatasetError
        No frame of the log is one of the sensor's.
    """
    from excavator_payload.runtime.logs import LogSummary, read_frames
    from excavator_payload.runtime.replay import _expected, _foreign

    summary = LogSummary()
    ending: list[str] = []
    bar = None
    if progress:
        from rich.progress import Progress

        bar = Progress(transient=True)
        bar.start()
        task = bar.add_task("replaying (frames)", total=None)
    try:
        for i, message in enumerate(read_frames(path, ending=ending)):
            summary.add(message)
            loadout.feed(message, float(message.timestamp))
            if bar is not None and i % 5000 == 0:
                bar.update(task, completed=i)
    finally:
        if bar is not None:
            bar.stop()
    sensor = loadout.sensor
    if loadout.guard is not None:
        was = loadout.guard.flagged
        if loadout.guard.finish():  # the log's last seconds
            loadout._judged(was)
    if loadout.samples == 0:
        raise DatasetError(f"CAN log '{path}': no frame is the sensor messages ({_expected(sensor)}) of "
                           f"the {sensor.sensor_set.name} sensor set{_foreign(sensor)}; the log holds "
                           f"{summary.describe()}. Another DBC (--dbc, --signal-map)?")
    trucks = loadout.finish()
    loadout.summary = summary.describe()
    loadout.log_end = ending[0] if ending else ""
    return trucks


def check_log_units(path, sensor, guard, source: str) -> None:
    """Judge the units of a log's first decoded seconds before anything is recorded: windows
    of ``guard`` until one in which the arm moves (at most :data:`PREPASS_WINDOWS`), or the
    log's end.

    Parameters
    ----------
    path : str or Path
        The CAN log.
    sensor : PayloadSensor
        A sensor of the log's codec, for this check only (its estimator is reset after).
    guard : UnitGuard
        Judges the samples.
    source : str
        Names the log in the message.

    Raises
    ------
    DatasetError
        One line naming each signal in another unit, its DBC source and the likely unit.
    """
    from excavator_payload.runtime.logs import read_frames
    from excavator_payload.runtime.replay import _short

    from excavator_payload.runtime import dbc

    sensor.reset()
    readable, judged, fed = False, False, 0
    try:
        for message in read_frames(path):
            spec = sensor.accepts(message)
            if spec is None or not math.isfinite(float(message.timestamp)):
                continue
            fed += 1
            for output in sensor.feed(message, spec=spec):
                readable = readable or output.status not in ("invalid_input", dbc.STALE)
                if not judged and output.values is not None and guard.add(output.time, output.values):
                    if guard.flagged:
                        raise DatasetError(guard.message(source))
                    judged = guard.moving or guard.judged >= PREPASS_WINDOWS
            if judged and readable:
                return
        if not judged and guard.finish() and guard.flagged:
            raise DatasetError(guard.message(source))
        if fed and not readable:
            # frames shorter than the DBC says, or all out of its ranges: every sample was
            # invalid, and an empty truck of 0 passes was recorded with exit status 0
            raise DatasetError(f"{source}: no sample in it has all the signals of the model's "
                               f"{sensor.sensor_set.name} sensor set readable ({sensor.counters['bad_frames']} "
                               f"of {fed} sensor frames shorter than the DBC's messages, out of its ranges or "
                               f"not available{_short(sensor)}); recorded with another DBC (--dbc, --signal-map)?")
    finally:
        sensor.reset()
