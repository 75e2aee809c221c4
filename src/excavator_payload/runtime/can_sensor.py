"""The payload virtual sensor on a CAN bus: frames in, samples to an estimator, estimates out.

:class:`PayloadSensor` wraps any fitted :class:`~excavator_payload.estimators.base.Estimator`.
Its sensor set says which signals it needs; a :class:`~excavator_payload.runtime.dbc.SignalCodec`
says in which frames they arrive. One sample period's signals usually come in several messages:
the sensor collects them and steps the estimator once per sample,

* when every sensor message of the period has arrived, or
* when a message arrives a second time before that (a frame was lost: the sample goes to the
  estimator with the missing signals as NaN, which it reports as ``invalid_input``), or
* when the period times out (:meth:`PayloadSensor.poll`, live only).

The sample's time is the timestamp of its first frame. A frame that repeats the last one of its
message (same bytes, less than a quarter period later: a log of two bridged channels, or of the
receive and the transmit echo) is a duplicate and dropped. J1939 sensor messages are matched by
PGN from any source address, but each message listens to one sender: the DBC's own address as
soon as it is heard, else the first address heard (a proprietary-B PGN such as 0xFF00 is sent by
other ECUs of the machine too, with their own content). Frames of other ids are ignored; a
frame of the wrong length or with an out-of-range or not-available raw value gives NaN signals,
never an exception. When no sample has arrived for ``stale_after`` seconds the sensor keeps
publishing at the sample rate with status ``stale`` (last estimate kept); the next sample
restarts it as the estimator's gap handling says (:meth:`Estimator._on_gap`). When only some
sensors fall silent, the samples lack their signals (the estimator keeps its last estimate)
and are published as ``stale`` too once a missing message has not been seen for
``stale_after`` seconds (``invalid_input`` before: one lost frame is not a silent sensor). Staleness and
time-outs are judged on the receiver's clock (the time a frame was received), so interfaces
whose timestamps count from another epoch (hardware time since boot) work too; the estimator
sees the frames' own timestamps.

:func:`run_bus` is the live loop of ``excavator-payload can-run``.
"""

from __future__ import annotations

import logging
import math
import threading
import time as _time
from dataclasses import dataclass

import can
import numpy as np

from excavator_payload.estimators.base import Estimator
from excavator_payload.runtime import dbc
from excavator_payload.runtime.dbc import SignalCodec

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SensorOutput:
    """One published estimate."""

    time: float          # s, time of the sample (or of the stale tick)
    estimate: float      # kg, NaN when none
    status: str          # a Status value or "stale"
    sigma: float         # kg, one-sigma uncertainty, NaN when unknown


def estimate_sigma(estimator: Estimator, result) -> float:
    """The estimate's one-sigma uncertainty, kg, where the estimator knows it (else NaN)."""
    for value in (getattr(result, "sigma", None), getattr(estimator, "uncertainty", None),
                  getattr(estimator, "payload_std", None)):
        if value is not None:
            try:
                value = float(value)
            except (TypeError, ValueError):
                continue
            return value if math.isfinite(value) else math.nan
    return math.nan


class EstimateEncoder:
    """Frames of one estimate: ``PayloadEstimate`` and ``VehicleWeight`` (PGN 65258)."""

    def __init__(self) -> None:
        db = dbc.estimate_database()
        self.estimate_message = db.get_message_by_name(dbc.ESTIMATE_MESSAGE)
        self.weight_message = db.get_message_by_name(dbc.VEHICLE_WEIGHT_MESSAGE)
        self.statuses = dbc.status_names()

    def status_code(self, status: str) -> int:
        """The raw bus code of ``status`` (its index in :func:`~excavator_payload.runtime.dbc.status_names`)."""
        return self.statuses.index(status)

    def frames(self, output: SensorOutput) -> list[can.Message]:
        """The two frames that publish ``output``."""
        na16 = dbc.not_available(16)
        top = dbc.valid_raw_max(16)

        def raw(value: float, resolution: float, offset: float) -> int:
            if not math.isfinite(value):
                return na16
            return int(min(max(round((value - offset) / resolution), 0), top))

        payload = raw(output.estimate, dbc.PAYLOAD_RESOLUTION, dbc.PAYLOAD_OFFSET)
        sigma = raw(output.sigma, dbc.PAYLOAD_RESOLUTION, 0.0)
        data = self.estimate_message.encode(
            {"Payload": payload, "PayloadStatus": self.status_code(output.status), "PayloadSigma": sigma},
            scaling=False, padding=True, strict=False)
        cargo = raw(max(output.estimate, 0.0) if output.status == "ok" else math.nan, 2.0, 0.0)
        weight = self.weight_message.encode(
            {"AxleLocation": dbc.not_available(8), "AxleWeight": na16, "TrailerWeight": na16,
             "CargoWeight": cargo}, scaling=False, padding=True, strict=False)
        return [can.Message(arbitration_id=self.estimate_message.frame_id, data=data, is_extended_id=True,
                            timestamp=output.time),
                can.Message(arbitration_id=self.weight_message.frame_id, data=weight, is_extended_id=True,
                            timestamp=output.time)]

    def decode(self, message: can.Message) -> tuple[float, str, float] | None:
        """(payload kg, status, sigma kg) of a ``PayloadEstimate`` frame, else None."""
        if message.arbitration_id != self.estimate_message.frame_id or len(message.data) != 8:
            return None
        raw = self.estimate_message.decode(bytes(message.data), scaling=False, decode_choices=False)
        na16 = dbc.not_available(16)
        payload = (math.nan if raw["Payload"] == na16
                   else raw["Payload"] * dbc.PAYLOAD_RESOLUTION + dbc.PAYLOAD_OFFSET)
        sigma = math.nan if raw["PayloadSigma"] == na16 else raw["PayloadSigma"] * dbc.PAYLOAD_RESOLUTION
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
    """

    def __init__(self, estimator: Estimator, codec: SignalCodec | None = None,
                 stale_after: float | None = None) -> None:
        if not estimator.fitted:
            from excavator_payload.errors import EstimatorError

            raise EstimatorError(f"{estimator.name}: the CAN sensor needs a fitted estimator")
        self.estimator = estimator
        self.sensor_set = estimator.sensor_set
        self.codec = codec or SignalCodec.for_sensor_set(self.sensor_set)
        if self.codec.sensor_set.signals != self.sensor_set.signals:
            raise dbc.CanConfigError(f"the CAN signal map is for the {self.codec.sensor_set.name} sensor "
                                     f"set, the model for {self.sensor_set.name}")
        self.period = self.sensor_set.sample_period
        self.stale_after = 3 * self.period if stale_after is None else float(stale_after)
        self.encoder = EstimateEncoder()
        self._needed = frozenset(self.codec.message_names)
        self.counters = {"frames": 0, "ignored": 0, "samples": 0, "bad_frames": 0, "stale": 0,
                         "duplicates": 0, "other_senders": 0}
        self.reset()

    def reset(self) -> None:
        """Forget the pending sample and restart the estimator."""
        self.estimator.reset()
        self._values = np.full(len(self.sensor_set.signals), np.nan)
        self._received: set[str] = set()
        self._pending_time: float | None = None
        self._pending_received: float | None = None
        self.last_output: SensorOutput | None = None
        self.last_sample_received: float | None = None
        self._last_seen: dict[str, float] = {}  # message -> receiver time it last arrived
        self._last_frame: dict[str, tuple[float, bytes]] = {}  # message -> (timestamp, data)
        self._sender: dict[str, int] = {}  # message -> the source address it listens to (J1939)

    # -- frames in ---------------------------------------------------------------------------
    def feed(self, message: can.Message, received_at: float | None = None) -> list[SensorOutput]:
        """Consume one received frame; returns the estimates it completed (0, 1 or 2).

        ``received_at`` is the receiver's clock at reception (default: the frame's timestamp).
        """
        self.counters["frames"] += 1
        if message.is_error_frame or message.is_remote_frame:
            self.counters["ignored"] += 1
            return []
        spec = self.codec.message_of(message.arbitration_id)
        if spec is None:
            self.counters["ignored"] += 1
            return []
        if self.codec.j1939 and message.is_extended_id and not self._from_sender(spec, message):
            self.counters["other_senders"] += 1
            return []
        stamp, data = float(message.timestamp), bytes(message.data)
        last = self._last_frame.get(spec.name)
        # Without this, a log that holds every frame twice (two channels, or rx and tx echo) was
        # read as a lost frame per message: every sample flushed half-empty, 0 estimates 'ok'.
        if last is not None and last[1] == data and abs(stamp - last[0]) < 0.25 * self.period:
            self.counters["duplicates"] += 1
            return []
        self._last_frame[spec.name] = (stamp, data)
        outputs = []
        if spec.name in self._received:  # a new period began before the last was complete
            outputs.append(self.flush())
        if self._pending_time is None:
            self._pending_time = float(message.timestamp)
            self._pending_received = float(message.timestamp if received_at is None else received_at)
        self._received.add(spec.name)
        self._last_seen[spec.name] = float(message.timestamp if received_at is None else received_at)
        decoded = self.codec.decode(spec, bytes(message.data))
        if any(v != v for _, v in decoded):
            self.counters["bad_frames"] += 1
        for i, value in decoded:
            self._values[i] = value
        if self._received >= self._needed:
            outputs.append(self.flush())
        return outputs

    def _from_sender(self, spec, message: can.Message) -> bool:
        """Whether a J1939 frame of ``spec`` comes from the address this message listens to.

        Matching the PGN alone let another ECU's proprietary-B frames of the same PGN in as
        sensor data (every sample invalid, or worse, plausible garbage)."""
        address = message.arbitration_id & 0xFF
        own = spec.frame_id & 0xFF
        if address == own:
            self._sender[spec.name] = own  # the DBC's sender, once heard, is the one
            return True
        return self._sender.setdefault(spec.name, address) == address

    def flush(self) -> SensorOutput:
        """Step the estimator with the pending sample (missing signals NaN) and clear it."""
        time = self._pending_time if self._pending_time is not None else math.nan
        now = self._pending_received
        silent = [m for m in self._needed - self._received
                  if now is None or now - self._last_seen.get(m, -math.inf) > self.stale_after]
        values = self._values
        self._values = np.full(len(self.sensor_set.signals), np.nan)
        self._received = set()
        self._pending_time = None
        self.last_sample_received = self._pending_received
        self._pending_received = None
        result = self.estimator.step_values(time, values)
        self.counters["samples"] += 1
        status = dbc.STALE if silent else result.status.value
        output = SensorOutput(time, float(result.estimate), status,
                              estimate_sigma(self.estimator, result))
        self.last_output = output
        return output

    @property
    def pending(self) -> bool:
        """Whether part of a sample has arrived."""
        return self._pending_time is not None

    # -- time passing (live) -----------------------------------------------------------------
    def poll(self, now: float) -> list[SensorOutput]:
        """Called regularly with the receiver's clock: flush a timed-out partial sample, report
        stale. Returns the outputs to publish now.
        """
        outputs = []
        if self._pending_received is not None and now - self._pending_received > self.period:
            outputs.append(self.flush())
        if self.last_sample_received is None or now - self.last_sample_received > self.stale_after:
            last = self.last_output
            self.counters["stale"] += 1
            outputs.append(SensorOutput(now, last.estimate if last else math.nan, dbc.STALE,
                                        last.sigma if last else math.nan))
        return outputs

    def frames(self, output: SensorOutput) -> list[can.Message]:
        """The frames that publish ``output``."""
        return self.encoder.frames(output)


def run_bus(bus: can.BusABC, sensor: PayloadSensor, stop: threading.Event,
            clock=_time.time, error_pause: float = 0.1) -> dict:
    """Read frames from ``bus`` and publish estimates until ``stop`` is set.

    Publishes each estimate as it completes (at the sensor rate); while the sensors are silent
    it publishes ``stale`` at the sample rate. Bus errors (error frames, a failing ``recv`` or
    ``send``) are logged and counted, never fatal. ``clock`` is the receiver's clock.

    Returns
    -------
    dict
        Counters: frames, ignored, samples, bad_frames, stale, published, bus_errors.
    """
    counters = sensor.counters
    counters.update(published=0, bus_errors=0)
    next_tick = clock() + sensor.period

    def publish(outputs):
        for output in outputs:
            for frame in sensor.frames(output):
                try:
                    bus.send(frame)
                    counters["published"] += 1
                except can.CanError as exc:
                    counters["bus_errors"] += 1
                    log.warning("CAN send failed: %s", exc)

    while not stop.is_set():
        timeout = max(0.0, min(next_tick - clock(), sensor.period))
        try:
            message = bus.recv(timeout=timeout)
        except can.CanError as exc:
            counters["bus_errors"] += 1
            log.warning("CAN receive failed: %s", exc)
            stop.wait(error_pause)
            message = None
        if message is not None:
            if message.is_error_frame:
                counters["bus_errors"] += 1
                log.warning("CAN error frame at %.3f", message.timestamp)
            publish(sensor.feed(message, clock()))
        now = clock()
        if now >= next_tick:
            # silent sensors: stale at the sample rate; a partial sample times out
            last = sensor.last_sample_received
            if last is None or now - last > sensor.period:
                publish(sensor.poll(now))
            next_tick = max(next_tick + sensor.period, now)
    return dict(counters)
