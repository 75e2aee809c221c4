"""Units of the signals a CAN log or a live bus delivers, judged on the decoded samples (loadout).

A user's DBC and signal map decide the units the estimator gets. A DBC whose pressures are in
bar (or angles in degrees, rates in °/s) mapped with factor 1 passed silently: the loadout
weighed nothing and blamed a "stuck" or "disagreeing" sensor in its DM1 list, with exit code 0.
:class:`UnitGuard` judges every :data:`GUARD_WINDOW` s of decoded samples (after the signal map,
before the estimator's verdict is used) with the rules of a dataset's unit checks
(:mod:`excavator_payload.data.units`) and the platform's plausibility (the arm's balance, a
cylinder's head and rod swapped):

* a signal beyond its sensor set's plausible magnitude (an angle above 2π: degrees);
* a house tilt above 35° (degrees);
* while the arm moves (a working machine's cylinder lines carry at least the return line's
  back pressure, tens of bar): a pressure line whose peak is above 0 and below 1 bar; the unit
  named is the DBC's own unit string when it is one, else every unit that puts the peak within
  the machine's back to relief pressure;
* an angle's rate whose integral is :data:`~excavator_payload.data.units.RATE_RATIO_LIMIT`
  times (or its inverse) the angle's change: the rate in °/s, or the angle in degrees; an angle
  that changes π/180 times what its rate integrates to and never leaves ±2π·π/180: scaled to
  radians twice (:func:`~excavator_payload.data.units.shrunk_angle`; it was blamed on the
  cylinder lines by the balance check);
* no unit finding: the platform's own plausibility (:meth:`Platform.check_plausible`).

Only what was seen is blamed: an idle window (the arm still: the engine may be off) judges
magnitudes and tilt, not the pressures' unit. A log is refused (:class:`DatasetError`, one line
naming the signal, its DBC source and the likely unit); on a live bus the guard is *flagged*
while the last window judged was wrong (the loadout then publishes no ``ok`` estimate and weighs
no pass) and clears on the next window judged right.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pandas as pd

from excavator_payload.data.units import (
    HOUSE_TILT_LIMIT, MIN_PEAK_PRESSURE, PRESSURE_UNITS, RATE_MIN_WINDOWS, RATE_RATIO_LIMIT, shrunk_angle,
    window_ratios)
from excavator_payload.errors import DatasetError

#: Length of the windows the guard judges, s (the first of a log before anything is recorded).
GUARD_WINDOW = 5.0
#: An arm angle whose range over a window exceeds this (rad) means the arm works there.
MOVING = 0.05
#: A working line's peak lies within this share of the machine's back pressure ...
LOW_SHARE = 0.3
#: ... and this multiple of its relief pressure (for naming the unit of a quiet line).
HIGH_SHARE = 1.5
#: Units a DBC names for angles, and their size in rad.
DEGREE_NAMES = ("deg", "°", "degree", "degrees")
#: The DBC unit strings understood as a pressure unit (lower case) -> size in Pa.
PRESSURE_NAMES = {"bar": 1.0e5, "kpa": 1.0e3, "mpa": 1.0e6, "psi": 6894.757, "mbar": 100.0, "hpa": 100.0}


class UnitGuard:
    """Judge every :data:`GUARD_WINDOW` s of decoded samples (module doc).

    Parameters
    ----------
    sensor_set : SensorSet
        The samples' sensor set (signal order, units, plausible magnitudes, rate pairs).
    codec : SignalCodec or None
        Where each signal comes from (named in the message); None: not named.
    machine : machine object or None
        The machine (back and relief pressures, the platform's balance check).
    platform : Platform or None
        Its :meth:`check_plausible` runs on windows with no unit finding.
    window : float
        s per judged window.
    """

    def __init__(self, sensor_set, codec=None, machine=None, platform=None, window: float = GUARD_WINDOW) -> None:
        self.sensors, self.codec, self.machine, self.platform = sensor_set, codec, machine, platform
        self.signals = list(sensor_set.signals)
        self.size = max(10, int(round(window / sensor_set.sample_period)))
        self._block = np.empty((self.size, 1 + len(self.signals)))
        self._n = 0
        #: the findings of the last window judged (empty: right, or none judged yet)
        self.findings: list[str] = []
        #: the same, short (``boom_head_pressure in bar?``): a pass's reason
        self.short: list[str] = []
        self.judged = 0          # windows judged
        self.moving = 0          # ... of which the arm moved in
        self.flagged_windows = 0  # ... of which had a finding
        self.since: float | None = None  # time of the window that raised the current flag
        self._motion_flag = False  # the current flag needs a moving arm to be cleared

    @property
    def flagged(self) -> bool:
        """Whether the last window judged found a unit (or balance) mistake."""
        return bool(self.findings)

    def add(self, time: float, values) -> bool:
        """One decoded sample (SI after the signal map; NaN where missing). Returns True when it
        completed a window, which was judged (see :attr:`findings`).

        Parameters
        ----------
        time : float
            s, the sample's time.
        values : array_like
            The signals in the sensor set's order.
        """
        self._block[self._n, 0] = time
        self._block[self._n, 1:] = values
        self._n += 1
        if self._n < self.size:
            return False
        self._n = 0
        self._judge(self._block)
        return True

    def finish(self) -> bool:
        """Judge the samples of an unfinished window (the end of a short log), if at least a
        second's worth; returns whether it judged."""
        n, self._n = self._n, 0
        if n * self.sensors.sample_period < 1.0:
            return False
        self._judge(self._block[:n])
        return True

    def message(self, source: str) -> str:
        """The one line that says what was found (empty when nothing).

        Parameters
        ----------
        source : str
            Where the samples came from (the log, the bus), the start of the line.
        """
        if not self.findings:
            return ""
        window = self.size * self.sensors.sample_period
        return (f"{source}: {'; '.join(self.findings)} (judged on {window:g} s of decoded samples from "
                f"{self.since:.1f} s)")

    # -- the rules ---------------------------------------------------------------------------
    def _judge(self, block: np.ndarray) -> None:
        frame = pd.DataFrame(block[:, 1:], columns=self.signals)
        frame.insert(0, "time", block[:, 0])
        frame.insert(0, "experiment", 0)
        moving = self._moving(frame)
        named: dict[str, tuple[str, str]] = {}  # signal -> finding (the first rule that blames it)
        for rule in (self._magnitudes, self._pressures, self._rates) if moving else (self._magnitudes,):
            for signal, text, unit in rule(frame):
                named.setdefault(signal, (text, f"{signal} {unit}"))
        found = [text for text, _ in named.values()]
        short = [s for _, s in named.values()]
        if moving and not found and self.platform is not None:
            try:
                self.platform.check_plausible(frame, self.machine, "")
            except DatasetError as exc:
                # "…: experiment 0: the boom cylinder's net force …": the window has no experiment
                text = re.sub(r"^:?\s*experiment \S+:\s*", "", str(exc))
                angle = re.match(r"column '(\w+_angle)'", text) if "π/180" in text else None
                if angle:  # an angle scaled to radians twice (wiring.check_angle_scale), not the lines
                    text = f"{self._where(angle.group(1))}{text[angle.end():]} ({self._factor(angle.group(1), 180 / math.pi)})"
                found.append(text)
                short.append("scaled by π/180 twice?" if angle else "head and rod pressures swapped?")
        self.judged += 1
        self.moving += int(moving)
        if found:
            self.flagged_windows += 1
            if not self.findings:
                self.since = float(block[0, 0])
            self.findings, self.short, self._motion_flag = found, short, moving
        elif moving or not self._motion_flag:
            # an idle window cannot clear what only a moving arm shows
            self.findings, self.short, self.since, self._motion_flag = [], [], None, False

    def _moving(self, frame: pd.DataFrame) -> bool:
        ranges = [np.nanmax(v) - np.nanmin(v) for c in ("boom_angle", "dipper_angle", "bucket_angle")
                  if c in frame and np.isfinite(v := frame[c].to_numpy(dtype=float)).any()]
        return bool(ranges) and max(ranges) > MOVING

    def _where(self, signal: str) -> str:
        """``boom_head_pressure (DBC Arm1.BoomHeadPressure in "bar", factor 1)``: the signal and its source."""
        src = None if self.codec is None else self.codec.sources.get(signal)
        if src is None:
            return signal
        unit = self._dbc_unit(signal)
        shown = f' in "{unit}"' if unit else ""
        return f"{signal} (DBC {src.message}.{src.signal}{shown}, factor {src.factor:g})"

    def _dbc_unit(self, signal: str) -> str:
        src = None if self.codec is None else self.codec.sources.get(signal)
        if src is None:
            return ""
        try:
            unit = self.codec.database.get_message_by_name(src.message).get_signal_by_name(src.signal).unit
        except KeyError:
            return ""
        return (unit or "").strip()

    def _factor(self, signal: str, size: float) -> str:
        """``set factor = 100000 in [signals.boom_head_pressure]``: the signal map's factor that
        converts the unit (the DBC's own scale left as it is)."""
        src = None if self.codec is None else self.codec.sources.get(signal)
        factor = size if src is None else src.factor * size
        return f"set factor = {factor:.10g} in [signals.{signal}]"

    def _magnitudes(self, frame: pd.DataFrame) -> list[tuple[str, str, str]]:
        found = []
        for c in self.signals:
            values = np.abs(frame[c].to_numpy(dtype=float))
            values = values[np.isfinite(values)]
            if not values.size:
                continue
            peak, unit = float(values.max()), self.sensors.units[c]
            tilt = c in ("house_pitch", "house_roll")
            limit = min(self.sensors.plausible_abs[c], HOUSE_TILT_LIMIT) if tilt else self.sensors.plausible_abs[c]
            if peak <= limit:
                continue
            if unit.startswith("rad"):
                degrees = unit.replace("rad", "°")
                found.append((c, f"{self._where(c)} reaches {peak:.4g}, beyond ±{limit:.3g} {unit}: in {degrees} "
                             f"instead of {unit}? ({self._factor(c, math.pi / 180)})", f"in {degrees}?"))
            else:
                found.append((c, f"{self._where(c)} reaches {peak:.4g}, beyond the ±{limit:g} {unit} the "
                                 f"{self.sensors.name} sensor set allows: not in {unit}?", f"not in {unit}?"))
        return found

    def _pressures(self, frame: pd.DataFrame) -> list[tuple[str, str, str]]:
        found = []
        for c in self.signals:
            if self.sensors.units[c] != "Pa":
                continue
            values = np.abs(frame[c].to_numpy(dtype=float))
            values = values[np.isfinite(values)]
            # 0 everywhere is a dead line (a sensor fault, DM1), not a unit
            if not values.size or not 0 < values.max() < MIN_PEAK_PRESSURE:
                continue
            peak = float(values.max())
            named = PRESSURE_NAMES.get(self._dbc_unit(c).lower())
            if named is not None:
                units = [(self._dbc_unit(c), named)]
            else:
                low, high = 0.0, math.inf
                hydraulics = getattr(self.machine, "hydraulics", None)
                if hydraulics is not None:
                    low, high = LOW_SHARE * hydraulics.back_pressure, HIGH_SHARE * hydraulics.relief_pressure
                units = [u for u in PRESSURE_UNITS if low <= peak * u[1] <= high] or list(PRESSURE_UNITS)
            names = " or ".join(name for name, _ in units)
            src = None if self.codec is None else self.codec.sources.get(c)
            factors = " or ".join(f"{size * (1.0 if src is None else src.factor):.10g}" for _, size in units)
            found.append((c, f"{self._where(c)} peaks at {peak:.4g} Pa while the arm works (its lines carry tens "
                             f"of bar, 1 bar = 1e5 Pa): in {names} instead of Pa? (set factor = {factors} in "
                             f"[signals.{c}])", f"in {names}?"))
        return found

    def _rates(self, frame: pd.DataFrame) -> list[tuple[str, str, str]]:
        found = []
        for signal, rate, unit, min_change in self.sensors.rate_pairs:
            if signal not in frame or rate not in frame:
                continue
            time, angle = frame["time"].to_numpy(dtype=float), frame[signal].to_numpy(dtype=float)
            shrunk = None if self.sensors.units[signal] != "rad" else shrunk_angle(
                time, angle, frame[rate].to_numpy(dtype=float), self.sensors.sample_period, min_change,
                self.sensors.plausible_abs[signal])
            if shrunk is not None:  # before the rate (°/s?) and the wiring (swapped?) are blamed
                peak = float(np.nanmax(np.abs(angle)))
                found.append((signal, f"{self._where(signal)} changes {shrunk:.3g} times less than {rate} "
                                      f"integrates to and never leaves ±{peak:.3g} rad: scaled by π/180 once "
                                      f"more (a degree factor on a signal already in rad)? "
                                      f"({self._factor(signal, 180 / math.pi)})", "scaled by π/180 twice?"))
                continue
            ratio = rate_ratio(frame["time"].to_numpy(dtype=float), frame[signal].to_numpy(dtype=float),
                               frame[rate].to_numpy(dtype=float), self.sensors.sample_period, min_change)
            if not math.isfinite(ratio) or 1 / RATE_RATIO_LIMIT <= abs(ratio) <= RATE_RATIO_LIMIT:
                continue
            angle_unit = self.sensors.units[signal]
            if abs(ratio) > RATE_RATIO_LIMIT:
                degrees = unit.replace("rad", "°")
                found.append((rate, f"{self._where(rate)} integrates to {abs(ratio):.3g} times the change of "
                                    f"{signal}: in {degrees} instead of {unit}? "
                                    f"({self._factor(rate, math.pi / 180)})", f"in {degrees}?"))
            else:
                found.append((signal, f"{self._where(signal)} changes {1 / abs(ratio):.3g} times what {rate} "
                                      f"integrates to: in ° instead of {angle_unit}? "
                                      f"({self._factor(signal, math.pi / 180)})", "in °?"))
        return found


def rate_ratio(time: np.ndarray, angle: np.ndarray, rate: np.ndarray, period: float, min_change: float) -> float:
    """How many times its angle's change a rate's integral is over one window: the median of
    its moving sub-windows' ratios (:func:`~excavator_payload.data.units.window_ratios`, the
    dataset check's rule); NaN with fewer than
    :data:`~excavator_payload.data.units.RATE_MIN_WINDOWS` of them.

    Parameters
    ----------
    time, angle, rate : ndarray
        s, the angle and its rate, one value per sample.
    period : float
        s, the sample period.
    min_change : float
        The angle's change over a sub-window that makes it moving.
    """
    ratios = window_ratios(time, angle, rate, period, min_change)
    return float(np.median(ratios)) if len(ratios) >= RATE_MIN_WINDOWS else math.nan
