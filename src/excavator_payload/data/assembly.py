"""Samples on the model's clock from signals that arrive at their own rates.

On a real machine the messages come at their own rates (pressures at 100 Hz, an inclinometer at
10 Hz, a status at 2 Hz), with jitter, and now and then in bursts; the estimators want one
sample every model period. :class:`SampleAssembler` holds each message's decoded signals with
the frame's timestamp and emits samples on the model's clock:

* **The clock** ticks every model period ``T``. It starts at the first frame and is phase-locked
  (gain :data:`PHASE_GAIN` per frame) to the frames of the messages at the model's rate or
  faster, so its ticks sit in the middle of their jitter and follow a sender's drifting crystal.
  A frame belongs to the tick nearest its timestamp (window ``±T/2``).
* **The values**: a sample holds, for each signal, the *latest* value received up to the end of
  its tick's window (zero-order hold). Not interpolated, because interpolating needs the frame
  *after* the tick: the output would wait one period of the slowest signal (100 ms behind a
  10 Hz inclinometer) on a live bus, and across a lost frame it invents a line the sensor
  never measured. The slow signals are slow because they change slowly: holding one costs at
  most its rate of change times its period, which the measurement in ``docs/field-bus.md``
  puts in numbers.
* **When**: a tick's sample goes out as soon as every message *due* in it has arrived (a
  message is due when its next frame should fall in this window, from its period), else when
  a frame of a later tick arrives (or :meth:`SampleAssembler.flush` / the live time-out). A tick
  in which no message arrived is skipped: the estimator sees the hole as a gap instead of a
  sample made of held values only.
* **Late frames**: a frame of an earlier tick updates the held value if it is the newest of its
  message, else it is dropped; time going back by more than :data:`RESTART_BACK` (a sender's
  clock restarted) starts a new clock.
* **Stale**: a signal whose value is older than its message's period × ``tolerance`` (default
  :data:`STALE_TOLERANCE`: two lost or queued frames and jitter pass, three do not;
  2.5 made a gateway's queue of three frames stale and cost up to 37 kg, see
  ``docs/field-bus.md``) is *stale*: it goes to the estimator as NaN and the sample names it (:attr:`Sample.stale`). A
  signal never heard since the start counts from the first frame.

A message's period is the signal map's / DBC's (``GenMsgCycleTime``) where given, else the
median of its last :data:`LEARN_INTERVALS` intervals (the model period until two frames came).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

#: A signal older than its period times this is stale.
STALE_TOLERANCE = 3.5
#: Share of a frame's offset from its tick that moves the clock (phase lock).
PHASE_GAIN = 0.02
#: Time going back by more than this (s) restarts the clock (else: a late frame, held if newest).
RESTART_BACK = 1.0
#: Intervals a message's period is learnt over when no DBC or map gives it.
LEARN_INTERVALS = 16


@dataclass(frozen=True)
class Sample:
    """One sample on the model's clock.

    Parameters
    ----------
    time : float
        The tick's time on the model's clock, s.
    values : numpy.ndarray
        The signals in sensor-set order; NaN where stale, never heard or bad.
    stale : tuple of str
        Names of the signals that are stale in this sample.
    """

    time: float                  # s, the tick
    values: np.ndarray           # signals in sensor-set order; NaN: stale, never heard or bad
    stale: tuple[str, ...]       # the signals that are stale in it


class SampleAssembler:
    """Samples at ``period`` from messages at their own rates (see the module docstring).

    Parameters
    ----------
    signals : names of the sample's signals, in order.
    period : the model's sample period, s.
    messages : message name -> the indices of the signals it carries.
    periods : message name -> its nominal period, s (None or absent: learnt).
    tolerance : staleness tolerance in periods of the signal's message.
    """

    def __init__(self, signals: Sequence[str], period: float, messages: Mapping[str, Sequence[int]],
                 periods: Mapping[str, float | None] | None = None,
                 tolerance: float = STALE_TOLERANCE) -> None:
        if not (period > 0 and math.isfinite(period)):
            raise ValueError("the model period must be positive")
        if not (tolerance >= 1 and math.isfinite(tolerance)):
            raise ValueError("the staleness tolerance must be at least 1 period")
        self.signals = tuple(signals)
        self.period = float(period)
        self.messages = {name: tuple(idx) for name, idx in messages.items()}
        self.nominal = {name: (periods or {}).get(name) for name in self.messages}
        self.tolerance = float(tolerance)
        self.reset()

    def reset(self) -> None:
        """Forget everything: the next frame starts the clock."""
        n = len(self.signals)
        self._values = np.full(n, np.nan)
        self._stamp: dict[str, float] = {}        # message -> timestamp of its held values
        self._intervals = {name: deque(maxlen=LEARN_INTERVALS) for name in self.messages}
        self._origin: float | None = None          # time of tick 0 (phase-locked)
        self._start: float | None = None           # the first frame's time
        self._tick: int | None = None              # the open tick
        self._fresh: set[str] = set()              # messages that arrived in the open tick
        self._closed = False                       # the open tick's sample went out

    # -- periods ---------------------------------------------------------------------------
    def message_period(self, name: str) -> float:
        """Message ``name``'s period, s: nominal, else learnt, else the model's.

        Parameters
        ----------
        name : str
            The message's name (a key of ``messages``).

        Returns
        -------
        float
            The period, s.
        """
        nominal = self.nominal.get(name)
        if nominal:
            return float(nominal)
        intervals = self._intervals[name]
        if len(intervals) >= 2:
            return float(np.median(intervals))
        return self.period

    def tick_time(self, tick: int) -> float:
        """The time of ``tick`` on the (phase-locked) clock.

        Parameters
        ----------
        tick : int
            Tick number, 0 at the first frame's tick.

        Returns
        -------
        float
            The tick's time, s.
        """
        return self._origin + tick * self.period

    def _index(self, stamp: float) -> int:
        return int(math.floor((stamp - self._origin) / self.period + 0.5))

    # -- frames in -----------------------------------------------------------------------------
    def add(self, message: str, stamp: float, decoded: Sequence[tuple[int, float]]) -> list[Sample]:
        """One decoded frame of ``message`` at ``stamp``; returns the samples it completed.

        Parameters
        ----------
        message : str
            The frame's message name (a key of ``messages``).
        stamp : float
            The frame's timestamp, s.
        decoded : sequence of (int, float)
            ``(signal index, value)`` pairs decoded from the frame (NaN: a bad value).

        Returns
        -------
        list of Sample
            The samples this frame completed (often none or one).
        """
        out: list[Sample] = []
        if self._origin is not None and stamp < self.tick_time(self._tick) - RESTART_BACK:
            # the sender's clock went back (an ECU restarted): a new clock, not a late frame
            out += self.flush()
            self.reset()
        if self._origin is None:
            self._origin = self._start = stamp
            self._tick = 0
        j = self._index(stamp)
        if j > self._tick:
            if not self._closed and self._fresh:
                out.append(self._emit())
            self._tick, self._fresh, self._closed = j, set(), False
        last = self._stamp.get(message)
        if last is None or stamp >= last:
            if last is not None and stamp > last:
                self._intervals[message].append(stamp - last)
            for i, value in decoded:
                self._values[i] = value
            self._stamp[message] = stamp
        if j == self._tick and not self._closed:
            self._fresh.add(message)
            if self.message_period(message) <= 1.5 * self.period:
                # phase lock on the messages at the model's rate (or faster)
                self._origin += PHASE_GAIN * (stamp - self.tick_time(j))
            if self._complete():
                out.append(self._emit())
                self._closed = True
        return out

    def _due(self, message: str) -> bool:
        """Whether a frame of ``message`` should arrive in the open tick's window."""
        last = self._stamp.get(message)
        if last is None:
            return True
        return self.tick_time(self._tick) + 0.5 * self.period - last >= self.message_period(message)

    def _complete(self) -> bool:
        return all(m in self._fresh or not self._due(m) for m in self.messages)

    @property
    def pending(self) -> bool:
        """Whether the open tick has frames whose sample has not gone out."""
        return bool(self._fresh) and not self._closed

    def flush(self) -> list[Sample]:
        """The open tick's sample, if it has frames and has not gone out."""
        if not self.pending:
            return []
        self._closed = True
        return [self._emit()]

    def _emit(self) -> Sample:
        now = self.tick_time(self._tick)
        values = self._values.copy()
        stale: list[str] = []
        for name, indices in self.messages.items():
            last = self._stamp.get(name)
            age = now - (self._start if last is None else last)
            if age > self.tolerance * self.message_period(name):
                values[list(indices)] = np.nan
                stale += [self.signals[i] for i in indices]
            elif last is None:
                values[list(indices)] = np.nan  # not heard yet: no value (not stale yet)
        return Sample(now, values, tuple(s for s in self.signals if s in stale))
