"""The payload virtual sensor on a CAN bus: frames in, samples to an estimator, estimates out.

:class:`PayloadSensor` wraps any fitted :class:`~excavator_payload.estimators.base.Estimator`.
Its sensor set says which signals it needs; a :class:`~excavator_payload.runtime.codec.SignalCodec`
says in which frames they arrive. The messages may come at their own rates (pressures at 100 Hz,
an inclinometer at 10 Hz) with jitter: a :class:`~excavator_payload.data.assembly.SampleAssembler`
holds each signal with its timestamp and makes one sample per model period from the latest
values, on the model's clock (why the latest and not interpolated: see that module). A signal
older than its message's period × ``stale_tolerance`` goes to the estimator as NaN and the
output is ``stale``, naming it (:attr:`SensorOutput.stale`).

**Senders.** A J1939 sensor message is matched by PGN, and only the frames of its own source
address are it: the signal map's ``source_address`` (``[messages.<name>]``), else the DBC frame
id's. A generic DBC with the null address 0xFE in its ids names no sender: the message then
listens to the first address it hears. Frames of another address (another ECU's proprietary-B
PGN 0xFF01, with its own content) are counted in ``other_senders`` and are not activity:
they neither decode nor keep a recording's segment open (:mod:`~excavator_payload.runtime.replay`).

A frame that repeats the last one of its message (same bytes, less than a quarter of its period
later: a log of two bridged channels, or of the receive and the transmit echo) is a duplicate
and dropped. Frames of other ids are ignored; a frame shorter than its message or with an
out-of-range or not-available raw value gives NaN signals (the sample is then ``invalid_input``),
never an exception. When no sample has arrived for ``stale_after`` seconds the sensor keeps
publishing at the sample rate with status ``stale`` (last estimate kept); the next sample
restarts it as the estimator's gap handling says (:meth:`Estimator._on_gap`). Time-outs are
judged on the receiver's clock (the time a frame was received), so interfaces whose timestamps
count from another epoch (hardware time since boot) work too; the samples carry the frames'
own clock.

:func:`run_bus` is the live loop of ``excavator-payload can-run``.
"""

from __future__ import annotations

import logging
import math
import threading
import time as _time
from dataclasses import dataclass, field

import can
import numpy as np

from excavator_payload.estimators.base import Estimator
from excavator_payload.runtime import dbc
from excavator_payload.data.assembly import STALE_TOLERANCE, Sample, SampleAssembler
from excavator_payload.runtime.codec import SignalCodec

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SensorOutput:
    """One published estimate.

    Parameters
    ----------
    time : float
        s, time of the sample (or of the stale tick).
    estimate : float
        kg, the payload estimate; NaN when none.
    status : str
        A :class:`~excavator_payload.estimators.base.Status` value or ``"stale"``.
    sigma : float
        kg, one-sigma uncertainty; NaN when unknown.
    stale : tuple of str, optional
        The signals too old for this sample (status ``"stale"``).
    fault : str, optional
        ``"signal:kind,..."`` while a signal is named (``sensor_fault``, ``degraded``).
    values : ndarray or None, optional
        The sample's signals (sensor-set order) the estimate was made from; None for a
        ``stale`` output of a silent bus.
    """

    time: float          # s, time of the sample (or of the stale tick)
    estimate: float      # kg, NaN when none
    status: str          # a Status value or "stale"
    sigma: float         # kg, one-sigma uncertainty, NaN when unknown
    stale: tuple[str, ...] = ()  # the signals too old for this sample (status "stale")
    fault: str = ""  # "signal:kind,..." while a signal is named (sensor_fault, degraded; estimators.health)
    #: the sample's signals (sensor-set order) the estimate was made from; None for a 'stale'
    #: output of a silent bus (loadout reads the bucket's moves from them)
    values: np.ndarray | None = field(default=None, repr=False, compare=False)


def estimate_sigma(estimator: Estimator, result) -> float:
    """The estimate's one-sigma uncertainty, kg, where the estimator knows it (else NaN).

    Parameters
    ----------
    estimator : Estimator
        The estimator that made ``result`` (its ``uncertainty`` or ``payload_std``, if any).
    result : object
        The step result; its ``sigma`` attribute is used first when present.

    Returns
    -------
    float
        kg, finite, or NaN.
    """
    for value in (getattr(result, "sigma", None), getattr(estimator, "uncertainty", None),
                  getattr(estimator, "payload_std", None)):
        if value is not None:
            try:
                value = float(value)
            except (TypeError, ValueError):
                continue
            return value if math.isfinite(value) else math.nan
    return math.nan


#: Vehicle Weight's cargo weight resolution (SPN 182), kg/bit.
CARGO_RESOLUTION = 2.0


def j1939_raw(value: float, resolution: float, offset: float, bits: int = 16) -> int:
    """The raw value of a J1939 signal: "not available" for NaN, the "error" indicator for a
    value outside the signal's data range (never clamped into a valid-looking number: a -5 t
    estimate went out as -2000 kg), else the value at ``resolution``.

    Parameters
    ----------
    value : float
        The physical value (signal unit, e.g. kg).
    resolution : float
        Signal unit per bit.
    offset : float
        Physical value of raw 0.
    bits : int, optional
        Width of the signal.

    Returns
    -------
    int
        The raw value to put in the frame.
    """
    if not math.isfinite(value):
        return dbc.not_available(bits)
    raw = round((value - offset) / resolution)
    if not 0 <= raw <= dbc.valid_raw_max(bits):
        return dbc.error_indicator(bits)
    return int(raw)


class EstimateEncoder:
    """Frames of one estimate: ``PayloadEstimate`` and ``VehicleWeight`` (PGN 65258)."""

    def __init__(self) -> None:
        db = dbc.estimate_database()
        self.estimate_message = db.get_message_by_name(dbc.ESTIMATE_MESSAGE)
        self.weight_message = db.get_message_by_name(dbc.VEHICLE_WEIGHT_MESSAGE)
        self.statuses = dbc.status_names()

    def status_code(self, status: str) -> int:
        """The raw bus code of ``status`` (its index in :func:`~excavator_payload.runtime.dbc.status_names`).

        Parameters
        ----------
        status : str
            A status name (``"ok"``, ``"stale"``, ...).
        """
        return self.statuses.index(status)

    def frames(self, output: SensorOutput) -> list[can.Message]:
        """The two frames that publish ``output``.

        Parameters
        ----------
        output : SensorOutput
            The estimate to publish.
        """
        payload = j1939_raw(output.estimate, dbc.PAYLOAD_RESOLUTION, dbc.PAYLOAD_OFFSET)
        sigma = j1939_raw(output.sigma, dbc.PAYLOAD_RESOLUTION, 0.0)
        data = self.estimate_message.encode(
            {"Payload": payload, "PayloadStatus": self.status_code(output.status), "PayloadSigma": sigma},
            scaling=False, padding=True, strict=False)
        # Vehicle Weight has no status: only an 'ok' estimate is a cargo weight. One below 0 by
        # less than the signal's 2 kg step is an empty bucket; further below it is not a weight
        # the signal can carry (error), never a valid-looking 0 kg.
        estimate = output.estimate
        if output.status == "ok" and -CARGO_RESOLUTION < estimate < 0:
            estimate = 0.0
        cargo = j1939_raw(estimate if output.status == "ok" else math.nan, CARGO_RESOLUTION, 0.0)
        weight = self.weight_message.encode(
            {"AxleLocation": dbc.not_available(8), "AxleWeight": dbc.not_available(16), "TrailerWeight": dbc.not_available(16),
             "CargoWeight": cargo}, scaling=False, padding=True, strict=False)
        return [can.Message(arbitration_id=self.estimate_message.frame_id, data=data, is_extended_id=True,
                            timestamp=output.time),
                can.Message(arbitration_id=self.weight_message.frame_id, data=weight, is_extended_id=True,
                            timestamp=output.time)]

    def decode(self, message: can.Message) -> tuple[float, str, float] | None:
        """(payload kg, status, sigma kg) of a ``PayloadEstimate`` frame, else None.

        Parameters
        ----------
        message : can.Message
            Any received frame.
        """
        if message.arbitration_id != self.estimate_message.frame_id or len(message.data) != 8:
            return None
        raw = self.estimate_message.decode(bytes(message.data), scaling=False, decode_choices=False)
        top = dbc.valid_raw_max(16)
        payload = (math.nan if raw["Payload"] > top
                   else raw["Payload"] * dbc.PAYLOAD_RESOLUTION + dbc.PAYLOAD_OFFSET)
        sigma = math.nan if raw["PayloadSigma"] > top else raw["PayloadSigma"] * dbc.PAYLOAD_RESOLUTION
        return payload, self.statuses[raw["PayloadStatus"]], sigma


class PayloadSensor:
    """A fitted estimator behind a CAN interface (see the module docstring).

    Parameters
    ----------
    estimator : Estimator
        Fitted; its ``sensor_set`` names the signals.
    codec : SignalCodec, optional
        Where the signals are in the frames (default: the sensor set's generated DBC).
    stale_after : float, optional
        Seconds without a sample after which the status is ``stale`` (default 3 sample periods).
    stale_tolerance : float, optional
        A signal older than its message's period times this is stale (default
        :data:`~excavator_payload.data.assembly.STALE_TOLERANCE`).
    """

    def __init__(self, estimator: Estimator, codec: SignalCodec | None = None,
                 stale_after: float | None = None, stale_tolerance: float = STALE_TOLERANCE) -> None:
        if not estimator.fitted:
            from excavator_payload.errors import EstimatorError

            raise EstimatorError(f"{estimator.name}: the CAN sensor needs a fitted estimator")
        self.estimator = estimator
        self.sensor_set = estimator.sensor_set
        self.codec = codec or SignalCodec.for_sensor_set(self.sensor_set)
        if self.codec.sensor_set.signals != self.sensor_set.signals:
            raise dbc.CanConfigError(f"the CAN signal map is for the {self.codec.sensor_set.name} sensor "
                                     f"set, the model for {self.sensor_set.name}")
        if not (math.isfinite(stale_tolerance) and stale_tolerance >= 1):
            raise dbc.CanConfigError(f"the staleness tolerance must be at least 1 period, got {stale_tolerance!r}")
        self.period = self.sensor_set.sample_period
        self.stale_after = 3 * self.period if stale_after is None else float(stale_after)
        self.encoder = EstimateEncoder()
        from excavator_payload.runtime.dm1 import DM1Transmitter

        self.dm1 = DM1Transmitter(self.sensor_set)  # the faults on the bus (J1939 DM1)
        names = self.codec.message_names
        self.assembler = SampleAssembler(
            self.sensor_set.signals, self.period,
            {m: [i for i, _ in self.codec._by_message[m]] for m in names},
            {m: self.codec.nominal_period(m) for m in names}, stale_tolerance)
        self.counters = {"frames": 0, "ignored": 0, "samples": 0, "bad_frames": 0, "stale": 0,
                         "duplicates": 0, "other_senders": 0, "other_channels": 0}
        #: (message, source address) -> frames of a sensor PGN from an address not the message's
        self.foreign: dict[tuple[str, int], int] = {}
        self._sender: dict[str, int] = {}  # message -> the address it locked onto (null-address DBC)
        self._channel: dict[str, object] = {}  # message -> the log channel it was first heard on
        #: message -> (frames shorter than the DBC's message, the last one's length)
        self.short: dict[str, tuple[int, int]] = {}
        self.reset()

    def reset(self) -> None:
        """Forget the pending sample and restart the estimator (a new recording)."""
        self.estimator.reset()
        self.assembler.reset()
        self._pending_received: float | None = None
        self.last_output: SensorOutput | None = None
        self.last_sample_received: float | None = None
        self._last_frame: dict[str, tuple[float, bytes]] = {}  # message -> (timestamp, data)

    # -- frames in ---------------------------------------------------------------------------
    def accepts(self, message: can.Message):
        """The sensor message ``message`` is a frame of, if it comes from that message's sender,
        else None (counted: ``ignored`` for other ids, ``other_senders`` for a sensor PGN from
        another address). A generic DBC's message locks onto the first address heard.

        Parameters
        ----------
        message : can.Message
            A received frame.

        Returns
        -------
        cantools Message or None
            The sensor message of the frame, or None when it is not one (from its sender).
        """
        if message.is_error_frame or message.is_remote_frame:
            self.counters["ignored"] += 1
            return None
        spec = self.codec.message_of(message.arbitration_id)
        if spec is None:
            self.counters["ignored"] += 1
            return None
        if self.codec.j1939 and message.is_extended_id and spec.is_extended_frame:
            address = message.arbitration_id & 0xFF
            expected = self.codec.expected_source(spec.name)
            if expected is None:
                expected = self._sender.setdefault(spec.name, address)
            if address != expected:
                self.counters["other_senders"] += 1
                key = (spec.name, address)
                self.foreign[key] = self.foreign.get(key, 0) + 1
                return None
        # A log of two channels that a gateway bridges holds each sensor frame twice, the copy a
        # few ms later: read as a message at twice its rate, the log was refused ("frames 0.006 s
        # apart, but the DBC says 0.01 s"). A message is the frames of the channel it is first
        # heard on (a live bus or a one-channel log: always the same channel).
        channel = getattr(message, "channel", None)
        if channel is not None:
            first = self._channel.setdefault(spec.name, channel)
            if channel != first:
                self.counters["other_channels"] += 1
                return None
        return spec

    def feed(self, message: can.Message, received_at: float | None = None, spec=None) -> list[SensorOutput]:
        """Consume one received frame; returns the estimates it completed (0, 1 or more).

        ``received_at`` is the receiver's clock at reception (default: the frame's timestamp);
        ``spec``: what :meth:`accepts` returned for it, if the caller asked already.

        Parameters
        ----------
        message : can.Message
            The received frame; its ``timestamp`` (s) is the frame's own clock.
        received_at : float, optional
            s, receiver's clock at reception (default: the frame's timestamp).
        spec : cantools Message, optional
            What :meth:`accepts` returned for the frame, if the caller asked already.
        """
        self.counters["frames"] += 1
        if spec is None:
            spec = self.accepts(message)
            if spec is None:
                return []
        stamp, data = float(message.timestamp), bytes(message.data)
        last = self._last_frame.get(spec.name)
        # Without this, a log that holds every frame twice (two channels, or rx and tx echo) was
        # read as a lost frame per message: every sample flushed half-empty, 0 estimates 'ok'.
        if (last is not None and last[1] == data
                and abs(stamp - last[0]) < 0.25 * self.assembler.message_period(spec.name)):
            self.counters["duplicates"] += 1
            return []
        self._last_frame[spec.name] = (stamp, data)
        if len(data) < spec.length:
            self.short[spec.name] = (self.short.get(spec.name, (0, len(data)))[0] + 1, len(data))
        decoded = self.codec.decode(spec, data)
        if any(v != v for _, v in decoded):
            self.counters["bad_frames"] += 1
        received = stamp if received_at is None else float(received_at)
        samples = self.assembler.add(spec.name, stamp, decoded)
        outputs = [self._step(sample) for sample in samples]
        if self.assembler.pending:
            if self._pending_received is None or samples:
                self._pending_received = received
        else:
            self._pending_received = None
        if outputs:
            self.last_sample_received = received
        return outputs

    def _step(self, sample: Sample) -> SensorOutput:
        result = self.estimator.step_values(sample.time, sample.values)
        self.counters["samples"] += 1
        status = dbc.STALE if sample.stale else result.status.value
        output = SensorOutput(sample.time, float(result.estimate), status,
                              estimate_sigma(self.estimator, result), sample.stale, result.fault,
                              sample.values)
        self.last_output = output
        return output

    def flush(self) -> SensorOutput | None:
        """Step the estimator with the pending sample (what has arrived of it), if any."""
        samples = self.assembler.flush()
        received, self._pending_received = self._pending_received, None
        if not samples:
            return None
        self.last_sample_received = received
        return self._step(samples[0])

    @property
    def pending(self) -> bool:
        """Whether part of a sample has arrived."""
        return self.assembler.pending

    # -- time passing (live) -----------------------------------------------------------------
    def poll(self, now: float) -> list[SensorOutput]:
        """Called regularly with the receiver's clock: flush a timed-out partial sample, report
        stale. Returns the outputs to publish now.

        Parameters
        ----------
        now : float
            s, the receiver's clock.
        """
        outputs = []
        if self._pending_received is not None and now - self._pending_received > self.period:
            output = self.flush()
            if output is not None:
                outputs.append(output)
        if self.last_sample_received is None or now - self.last_sample_received > self.stale_after:
            last = self.last_output
            self.counters["stale"] += 1
            outputs.append(SensorOutput(now, last.estimate if last else math.nan, dbc.STALE,
                                        last.sigma if last else math.nan))
        return outputs

    def frames(self, output: SensorOutput) -> list[can.Message]:
        """The frames that publish ``output``: the estimate, and a DM1 while a sensor is faulty
        (once a second) and once after it clears (:mod:`~excavator_payload.runtime.dm1`).

        Parameters
        ----------
        output : SensorOutput
            The estimate to publish.
        """
        return self.encoder.frames(output) + self.dm1.update(output.time, output.fault)


def send_counted(bus: can.BusABC, frame: can.Message, counters: dict, logger: logging.Logger) -> None:
    """Send ``frame``; a failed send is counted in ``counters["bus_errors"]`` and logged, never
    raised (a live run outlasts a full transmit queue), a sent one in ``counters["published"]``.

    Parameters
    ----------
    bus : can.BusABC
        The bus.
    frame : can.Message
        The frame to send.
    counters : dict
        The run's counters (``published``, ``bus_errors``).
    logger : logging.Logger
        Where a failure is logged.
    """
    try:
        bus.send(frame)
        counters["published"] += 1
    except can.CanError as exc:
        counters["bus_errors"] += 1
        logger.warning("CAN send failed: %s", exc)


def receive_counted(bus: can.BusABC, timeout: float, counters: dict, stop: threading.Event,
                    error_pause: float, logger: logging.Logger) -> can.Message | None:
    """The next frame within ``timeout`` s, or None; a failed receive is counted in
    ``counters["bus_errors"]``, logged, and followed by ``error_pause`` s (or until ``stop``)
    so that a dead interface does not spin.

    Parameters
    ----------
    bus : can.BusABC
        The bus.
    timeout : float
        s to wait for a frame.
    counters : dict
        The run's counters (``bus_errors``).
    stop : threading.Event
        Ends the pause early.
    error_pause : float
        s to wait after a failed receive.
    logger : logging.Logger
        Where a failure is logged.
    """
    try:
        return bus.recv(timeout=timeout)
    except can.CanError as exc:
        counters["bus_errors"] += 1
        logger.warning("CAN receive failed: %s", exc)
        stop.wait(error_pause)
        return None


#: s of nothing but failing receives (and at least :data:`LOST_FAILURES` of them) after which
#: the bus is lost: a burst of instant failures (a driver's queue overflowing) is not an outage,
#: nor is one slow failing call.
LOST_AFTER = 0.5
LOST_FAILURES = 3
#: s between attempts to reopen a lost bus (the last one repeats).
REOPEN_DELAYS = (1.0, 1.0, 2.0, 4.0, 5.0)
#: s a reopened bus must receive without an error to be back when no frame arrives (the bus is
#: there but the sensors are silent: it goes on publishing ``stale``).
QUIET_BACK = 1.0
#: s between two log lines of failures that did not lose the bus.
LOG_EVERY = 10.0


class BusLink:
    """The live bus of a run: every failing receive or send is counted, never raised, and
    reported once per outage, not once per failure.

    * **Lost** (a vanished interface, "Network is down", an unplugged adapter): after
      :data:`LOST_AFTER` s of nothing but failing receives the bus is *lost* (one warning:
      ``CAN bus lost on IFACE:CHANNEL (reason); waiting``), shut down, and reopened with
      ``factory`` after 1, 1, 2, 4, then every 5 s (:data:`REOPEN_DELAYS`). A reopened bus is
      *back* (``CAN bus back on ... after X s``) when a frame arrives, or after
      :data:`QUIET_BACK` s of error-free silence; a receive failing before that is the same
      outage. Counted: ``bus_lost`` (outages), ``bus_lost_seconds`` (from the first failure to
      back, or to the end of the run).
    * **Bus-off** (the controller stops transmitting: sends fail with ENOBUFS while frames
      still arrive): after :data:`LOST_AFTER` s of nothing but failing sends, one warning; the
      run goes on receiving and estimating, each publication is tried and lost, and one line
      says when sends work again. Recovering from bus-off is the controller's (socketcan:
      ``ip link set can0 type can restart-ms 100``). Counted: ``bus_off``, ``bus_off_seconds``.
    * Shorter failures: one line when they end, and error frames: one line, at most one per
      :data:`LOG_EVERY` s each (with the number not logged since).

    Parameters
    ----------
    bus : can.BusABC
        The open bus.
    counters : dict
        The run's counters; ``published``, ``bus_errors``, ``bus_lost``, ``bus_lost_seconds``,
        ``bus_off`` and ``bus_off_seconds`` are added.
    stop : threading.Event
        Ends a wait (a pause after a failure, the wait before a reopen).
    factory : callable, optional
        Opens the bus again (``can.Bus(interface=..., channel=..., ...)``); without one the
        same bus is tried again on the same schedule.
    name : str, optional
        What the log lines call the bus (``IFACE:CHANNEL``).
    error_pause : float, optional
        s to wait after a failed receive (a dead interface must not spin).
    monotonic : callable, optional
        The clock of the outages, s.
    logger : logging.Logger, optional
        Where the lines go.
    """

    def __init__(self, bus: can.BusABC, counters: dict, stop: threading.Event, factory=None,
                 name: str = "", error_pause: float = 0.1, monotonic=_time.monotonic,
                 logger: logging.Logger = log) -> None:
        self.bus: can.BusABC | None = bus
        self.own_bus = False  # whether self.bus was opened here (then closed here)
        self.counters = counters
        for key in ("published", "bus_errors", "bus_lost", "bus_off"):
            counters.setdefault(key, 0)
        for key in ("bus_lost_seconds", "bus_off_seconds"):
            counters.setdefault(key, 0.0)
        self.stop = stop
        self.factory = factory
        self.name = name or str(getattr(bus, "channel_info", "CAN bus"))
        self.error_pause = error_pause
        self.monotonic = monotonic
        self.log = logger
        # receive side: a run of failures, the outage, a reopened bus on probation
        self._recv_run: tuple[float, int, str] | None = None  # (first failure, count, reason)
        self.lost_since: float | None = None  # the first failure of the outage going on
        self.lost_reason = ""  # why the bus is lost (the last failure, or the failed reopen)
        self._attempts = 0
        self._next_open = 0.0
        self._probation: float | None = None  # when the reopened bus was opened
        # send side
        self._send_run: tuple[float, int, str] | None = None
        self._bus_off = False
        self._last_log = {"recv": -math.inf, "send": -math.inf, "error": -math.inf}
        self._quiet = {"recv": 0, "send": 0, "error": 0}  # failures not logged (rate limit)

    @property
    def lost(self) -> bool:
        """Whether the bus is lost (no estimates are published until it is back)."""
        return self.lost_since is not None

    # -- receive ------------------------------------------------------------------------------
    def recv(self, timeout: float) -> can.Message | None:
        """The next frame within ``timeout`` s, or None (also while the bus is lost: then this
        waits for the next reopen, at most ``timeout`` s; ``stop`` ends the wait).

        Parameters
        ----------
        timeout : float
            s to wait.
        """
        if self.lost and self._probation is None:
            self._reopen(timeout)
            if self._probation is None:
                return None
        try:
            message = self.bus.recv(timeout=timeout)
        except Exception as exc:  # noqa: BLE001 - a driver may raise anything; the run survives
            self._recv_failed(exc)
            return None
        self._recv_ok(message)
        return message

    def _recv_failed(self, exc: BaseException) -> None:
        now = self.monotonic()
        self.counters["bus_errors"] += 1
        reason = _reason(exc)
        if self.lost:  # a reopened bus fails again: the same outage goes on
            self._close()
            self._probation = None
            self._schedule(now)
            return
        first, count, _ = self._recv_run or (now, 0, reason)
        self._recv_run = (first, count + 1, reason)
        if count + 1 >= LOST_FAILURES and now - first >= LOST_AFTER:
            self._declare_lost(first, reason)
        else:
            self.stop.wait(self.error_pause)

    def _recv_ok(self, message: can.Message | None) -> None:
        if self._recv_run is not None:
            first, count, reason = self._recv_run
            self._recv_run = None
            self._rate_limited("recv", f"CAN receive failed on {self.name}: {reason} ({count} time(s) "
                               "in a row); receiving again", count)
        if self._probation is not None:
            now = self.monotonic()
            if message is not None:
                self._back(now, "")
            elif now - self._probation >= QUIET_BACK:
                self._back(now, " (no frames yet)")

    def _declare_lost(self, first: float, reason: str) -> None:
        self.lost_since = first
        self.lost_reason = reason
        self._recv_run = None
        self.counters["bus_lost"] += 1
        if self._bus_off:  # bus-off ends in the outage: its time so far counts
            self.counters["bus_off_seconds"] += self.monotonic() - self._send_run[0]
            self._bus_off = False
        self._send_run = None
        self.log.warning("CAN bus lost on %s (%s); waiting", self.name, reason)
        self._close()
        self._attempts = 0
        self._schedule(self.monotonic())

    def _schedule(self, now: float) -> None:
        if self.factory is None:  # nothing to reopen with: keep trying the same bus
            self._next_open = now + REOPEN_DELAYS[0]
            return
        self._next_open = now + REOPEN_DELAYS[min(self._attempts, len(REOPEN_DELAYS) - 1)]
        self._attempts += 1

    def _reopen(self, timeout: float) -> None:
        wait = self._next_open - self.monotonic()
        if wait > 0:
            self.stop.wait(min(wait, max(timeout, 0.01)))
            if self.stop.is_set() or self._next_open > self.monotonic():
                return
        if self.factory is not None:
            try:
                self.bus = self.factory()
            except Exception as exc:  # noqa: BLE001 - the interface is still gone
                self.log.debug("reopening CAN bus %s failed: %s", self.name, _reason(exc))
                self.lost_reason = _reason(exc)
                self._schedule(self.monotonic())
                return
            self.own_bus = True
        self._probation = self.monotonic()  # without a factory: try the same bus again

    def _back(self, now: float, note: str) -> None:
        seconds = now - self.lost_since
        self.counters["bus_lost_seconds"] += seconds
        self.lost_since = None
        self._probation = None
        self.log.warning("CAN bus back on %s after %.1f s%s", self.name, seconds, note)

    def _close(self) -> None:
        bus, self.bus = self.bus, None
        if bus is None:
            return
        if self.factory is None:  # cannot open another: keep this one and retry it
            self.bus = bus
            return
        try:
            bus.shutdown()
        except Exception as exc:  # noqa: BLE001 - a vanished interface may fail to close too
            self.log.debug("closing CAN bus %s: %s", self.name, _reason(exc))

    # -- send ---------------------------------------------------------------------------------
    def send(self, frame: can.Message) -> bool:
        """Send ``frame``; False when it could not be (counted in ``bus_errors``, reported as
        the class says).

        Parameters
        ----------
        frame : can.Message
            The frame.
        """
        if self.bus is None:
            return False
        try:
            self.bus.send(frame)
        except Exception as exc:  # noqa: BLE001 - a full queue, bus-off, a vanished interface
            now = self.monotonic()
            self.counters["bus_errors"] += 1
            first, count, _ = self._send_run or (now, 0, _reason(exc))
            self._send_run = (first, count + 1, _reason(exc))
            # sends failing while receives fail too are the bus lost, not bus-off
            if (not self._bus_off and self._recv_run is None and not self.lost
                    and count + 1 >= LOST_FAILURES and now - first >= LOST_AFTER):
                self._bus_off = True
                self.counters["bus_off"] += 1
                self.log.warning("CAN sends failing on %s for %.1f s (%s): bus-off? estimates are "
                                 "not published until sends work again", self.name, now - first,
                                 _reason(exc))
            return False
        self.counters["published"] += 1
        if self._send_run is not None:
            first, count, reason = self._send_run
            self._send_run = None
            if self._bus_off:
                self._bus_off = False
                seconds = self.monotonic() - first
                self.counters["bus_off_seconds"] += seconds
                self.log.warning("CAN sends work again on %s after %.1f s (%d frames not sent)",
                                 self.name, seconds, count)
            else:
                self._rate_limited("send", f"CAN send failed on {self.name}: {reason} ({count} "
                                   "frame(s)); sending again", count)
        return True

    def error_frame(self, message: can.Message) -> None:
        """Count an error frame (``bus_errors``); at most one line per :data:`LOG_EVERY` s.

        Parameters
        ----------
        message : can.Message
            The received error frame.
        """
        self.counters["bus_errors"] += 1
        self._rate_limited("error", f"CAN error frame on {self.name} at {message.timestamp:.3f}", 1)

    def _rate_limited(self, side: str, text: str, count: int) -> None:
        now = self.monotonic()
        if now - self._last_log[side] >= LOG_EVERY:
            quiet, self._quiet[side] = self._quiet[side], 0
            self.log.warning("%s%s", text, f"; {quiet} more failure(s) not logged" if quiet else "")
            self._last_log[side] = now
        else:
            self._quiet[side] += count

    # -- end ----------------------------------------------------------------------------------
    def close(self) -> None:
        """End of the run: an outage still going on counts to its end; a bus opened here is
        shut down (the one given is the caller's)."""
        now = self.monotonic()
        if self.lost_since is not None:
            self.counters["bus_lost_seconds"] += now - self.lost_since
        if self._bus_off and self._send_run is not None:
            self.counters["bus_off_seconds"] += now - self._send_run[0]
        for key in ("bus_lost_seconds", "bus_off_seconds"):
            self.counters[key] = round(self.counters[key], 1)
        if self.own_bus and self.bus is not None:
            try:
                self.bus.shutdown()
            except Exception as exc:  # noqa: BLE001
                self.log.debug("closing CAN bus %s: %s", self.name, _reason(exc))
        self.bus = None


def _reason(exc: BaseException) -> str:
    return str(exc) or type(exc).__name__


def run_bus(bus: can.BusABC, sensor: PayloadSensor, stop: threading.Event,
            clock=_time.time, error_pause: float = 0.1, bus_factory=None, name: str = "") -> dict:
    """Read frames from ``bus`` and publish estimates until ``stop`` is set.

    Publishes each estimate as it completes (at the sensor rate); while the sensors are silent
    it publishes ``stale`` at the sample rate. Bus errors (error frames, a failing ``recv`` or
    ``send``) are counted, never fatal; a lost bus is reopened with ``bus_factory`` and bus-off
    waited out (:class:`BusLink`). While the bus is lost nothing is published and the
    estimator is not stepped: its state is kept, and the first sample after the outage is a
    hole in time like any other (the estimator's gap rule: a restart, or the filters' payload
    belief kept). ``clock`` is the receiver's clock.

    Parameters
    ----------
    bus : can.BusABC
        The open bus, read and written (the caller shuts it down).
    sensor : PayloadSensor
        The virtual sensor the frames feed.
    stop : threading.Event
        Set to end the loop (also ends a wait for a reopen).
    clock : callable, optional
        Returns the receiver's clock, s (default :func:`time.time`).
    error_pause : float, optional
        s, wait after a failing ``recv`` before trying again.
    bus_factory : callable, optional
        Opens the bus again after it was lost (default: none; the same bus is retried).
    name : str, optional
        The bus in log lines (``IFACE:CHANNEL``).

    Returns
    -------
    dict
        Counters: frames, ignored, samples, bad_frames, stale, duplicates, other_senders,
        published, bus_errors, bus_lost, bus_lost_seconds, bus_off, bus_off_seconds.
    """
    counters = sensor.counters
    counters.update(published=0, bus_errors=0, bus_lost=0, bus_lost_seconds=0.0, bus_off=0,
                    bus_off_seconds=0.0)
    link = BusLink(bus, counters, stop, bus_factory, name, error_pause)
    next_tick = clock() + sensor.period

    def publish(outputs):
        for output in outputs:
            for frame in sensor.frames(output):
                link.send(frame)

    try:
        while not stop.is_set():
            timeout = max(0.0, min(next_tick - clock(), sensor.period))
            message = link.recv(timeout)
            if link.lost:  # nothing is published, nothing is stepped, until it is back
                next_tick = clock() + sensor.period
                continue
            if message is not None:
                if message.is_error_frame:
                    link.error_frame(message)
                publish(sensor.feed(message, clock()))
            now = clock()
            if now >= next_tick:
                # silent sensors: stale at the sample rate; a partial sample times out
                last = sensor.last_sample_received
                if last is None or now - last > sensor.period:
                    publish(sensor.poll(now))
                next_tick = max(next_tick + sensor.period, now)
    finally:
        link.close()
    return dict(counters)
