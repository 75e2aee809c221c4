"""Units judged per experiment and per signal, on datasets and on decoded CAN samples.

A file-wide check (a column's largest value over the whole file) lets one experiment in another
unit through among others in SI: one experiment's pressures logged in bar beside the rest in Pa
weighed −8960 kg ``ok``; one calibration experiment in bar calibrated without a word, then read
2822 kg for 1890. Here every experiment is judged on its own, and each signal against the same
signal in the other experiments:

* **pressures** (Pa): no cylinder line of a working arm stays below 1 bar in *every* line for a
  whole experiment (the boom cylinders hold the arm's weight, tens of bar); and a line whose peak
  in one experiment is below 1 bar and :data:`SCALE_RATIO_LIMIT` times below its peak in the
  other experiments is in another unit (bar 10⁵, kPa 10³, MPa 10⁶, psi 6895: the nearest is
  named);
* **torques** (N·m, the thesis set): an experiment's peak :data:`SCALE_RATIO_LIMIT` times below
  the other experiments' is in kN·m (the arm's own weight loads both joints in every pose, so the
  peaks of two experiments never differ that much).

:class:`SampleWatch` applies the same checks (and the rate-unit check of
:mod:`excavator_payload.data.io`) to samples decoded from a CAN log after the signal map: a user
DBC whose pressures are in bar with factor 1 is refused as a dataset in bar is.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from excavator_payload.errors import DatasetError

#: Below this peak (Pa, 1 bar) a pressure line is suspected of another unit.
MIN_PEAK_PRESSURE = 1.0e5
#: An experiment's peak of a signal this many times below the same signal's median peak over the
#: other experiments is in another unit (the smallest unit factor checked is kN·m's and kPa's 1000;
#: a real idle line at 0.5 bar beside 300 bar elsewhere is 600 times, so the 1-bar condition
#: guards pressures as well).
SCALE_RATIO_LIMIT = 300.0
#: Units a pressure column is found in, with their size in Pa.
PRESSURE_UNITS = (("bar", 1.0e5), ("kPa", 1.0e3), ("MPa", 1.0e6), ("psi", 6894.757))
#: Units a torque column is found in, with their size in N·m.
TORQUE_UNITS = (("kN·m", 1.0e3),)
#: A suspected unit is named when the ratio is within this factor of its size (else all are listed).
UNIT_NAMING_TOLERANCE = 4.0


def _unit_hint(ratio: float, units: tuple[tuple[str, float], ...], si: str) -> str:
    """``"in bar instead of Pa"``: the unit whose size is nearest ``ratio`` (log scale), or all."""
    name, size = min(units, key=lambda u: abs(math.log(ratio / u[1])))
    if abs(math.log(ratio / size)) < math.log(UNIT_NAMING_TOLERANCE) or len(units) == 1:
        return f"in {name} instead of {si}"
    return f"in {', '.join(u for u, _ in units)} instead of {si}"


def experiment_peaks(frame: pd.DataFrame, columns) -> pd.DataFrame:
    """Largest finite ``|value|`` of each column in each experiment (experiments in file order;
    NaN where an experiment has no finite value)."""
    values = frame[list(columns)].abs()
    values = values.where(np.isfinite(values))
    experiments = frame["experiment"].to_numpy()
    if np.all(np.isfinite(experiments)) and np.all(experiments == np.round(experiments)):
        experiments = experiments.astype(np.int64)  # named in messages as 3, not 3.0
    return values.groupby(experiments, sort=False).max()


def check_experiment_units(frame: pd.DataFrame, sensors, source: str) -> None:
    """Refuse an experiment (or one signal of it) in another unit than the rest (see the module
    docstring). ``frame`` has ``experiment`` and the sensor set's signals.

    Raises
    ------
    DatasetError
        One line naming the experiment, the column and the unit it looks to be in.
    """
    columns = [c for c in sensors.signals if sensors.units[c] in ("Pa", "N*m") and c in frame.columns]
    if columns:
        check_peaks(experiment_peaks(frame, columns), sensors, source)


def check_peaks(peaks: pd.DataFrame, sensors, source: str) -> None:
    """:func:`check_experiment_units` on the per-experiment peaks (:func:`experiment_peaks`) of
    the pressure and torque columns."""
    pressures = [c for c in peaks.columns if sensors.units.get(c) == "Pa"]
    torques = [c for c in peaks.columns if sensors.units.get(c) == "N*m"]
    if pressures:
        loudest = peaks[pressures].max(axis=1)
        quiet = loudest[loudest < MIN_PEAK_PRESSURE]
        others = loudest.drop(quiet.index).dropna()
        if len(quiet) and len(others):
            k, top = quiet.index[0], float(quiet.iloc[0])
            ratio = float(others.median()) / max(top, 1e-300)
            where = (f"{len(quiet)} of {len(loudest)} experiments, first experiment {k}"
                     if len(quiet) > 1 else f"experiment {k}")
            raise DatasetError(
                f"{source}: {where}: no pressure exceeds {top:.4g} Pa (1 bar = 1e5 Pa) while the "
                f"other experiments reach {float(others.median()):.4g} Pa; are its pressures "
                f"{_unit_hint(ratio, PRESSURE_UNITS, 'Pa')} (or all its pressure sensors unplugged)?")
        # every experiment quiet: the file-wide message of io.validate_frame says it
        _check_scale(peaks[pressures], "Pa", PRESSURE_UNITS, source, ceiling=MIN_PEAK_PRESSURE)
    if torques:
        _check_scale(peaks[torques], "N·m", TORQUE_UNITS, source, ceiling=math.inf)


def _check_scale(peaks: pd.DataFrame, si: str, units, source: str, ceiling: float) -> None:
    """A column whose peak in one experiment is below ``ceiling`` and far below its median peak
    over the other experiments."""
    if len(peaks) < 2:
        return
    for column in peaks.columns:
        series = peaks[column].dropna()
        if len(series) < 2:
            continue
        for k, peak in series.items():
            if not 0 < peak < ceiling:
                continue  # 0: a dead line (all zeros) is a sensor fault, not a unit
            rest = float(series.drop(k).median())
            ratio = rest / peak
            if ratio > SCALE_RATIO_LIMIT:
                raise DatasetError(
                    f"{source}: experiment {k}: column '{column}' peaks at {peak:.4g}, {ratio:.3g} times "
                    f"below its peak in the other experiments ({rest:.4g} {si}); is this experiment's "
                    f"'{column}' {_unit_hint(ratio, units, si)}?")


#: Segments of a CAN log whose samples :class:`SampleWatch` keeps for the rate and balance checks
#: (the peaks of every segment are kept).
WATCH_SEGMENTS = 50
#: Samples kept per segment (10 s at the machine set's 100 Hz).
WATCH_SAMPLES = 1000


class SampleWatch:
    """Samples decoded from a CAN log after the signal map, judged like a dataset's experiments
    (one experiment per log segment): per-experiment units (:func:`check_peaks` on the peaks of
    every segment), rate units and, with a hydraulic machine, the arm's balance
    (:func:`excavator_payload.data.wiring.check_wiring`) on the first :data:`WATCH_SAMPLES`
    samples of the first :data:`WATCH_SEGMENTS` segments. Memory stays bounded on any log.
    """

    def __init__(self, sensors, machine=None) -> None:
        self.sensors = sensors
        self.machine = machine
        self._peak_columns = [c for c in sensors.signals if sensors.units[c] in ("Pa", "N*m")]
        self._peak_index = np.array(sensors.indices(self._peak_columns), dtype=int)
        self._peaks: dict[int, np.ndarray] = {}
        self._samples: dict[int, np.ndarray] = {}
        self._counts: dict[int, int] = {}

    def add(self, experiment: int, time: float, values) -> None:
        """One assembled sample (the signal vector in the sensor set's order) of ``experiment``."""
        values = np.asarray(values, dtype=float)
        if self._peak_index.size:
            magnitude = np.abs(values[self._peak_index])
            magnitude = np.where(np.isfinite(magnitude), magnitude, np.nan)
            old = self._peaks.get(experiment)
            self._peaks[experiment] = magnitude if old is None else np.fmax(old, magnitude)
        if experiment not in self._samples:
            if len(self._samples) >= WATCH_SEGMENTS:
                return
            self._samples[experiment] = np.empty((WATCH_SAMPLES, 1 + len(values)))
            self._counts[experiment] = 0
        n = self._counts[experiment]
        if n < WATCH_SAMPLES:
            self._samples[experiment][n, 0] = time
            self._samples[experiment][n, 1:] = values
            self._counts[experiment] = n + 1

    def frame(self) -> pd.DataFrame:
        """The kept samples as a dataset table (``experiment``, ``time``, signals)."""
        parts = [pd.DataFrame(block[: self._counts[k]], columns=["time", *self.sensors.signals])
                 .assign(experiment=k) for k, block in self._samples.items()]
        if not parts:
            return pd.DataFrame(columns=["experiment", "time", *self.sensors.signals])
        frame = pd.concat(parts, ignore_index=True)
        return frame[["experiment", "time", *self.sensors.signals]]

    def check(self, source: str) -> None:
        """Judge what was seen; :class:`DatasetError` (one line) on a unit or wiring mistake."""
        from excavator_payload.data.io import check_signal_units

        what = f"{source} (decoded through the signal map)"
        if self._peaks:
            peaks = pd.DataFrame.from_dict(self._peaks, orient="index", columns=self._peak_columns)
            check_peaks(peaks, self.sensors, what)
        frame = self.frame()
        if len(frame) == 0:
            return
        check_signal_units(frame, self.sensors, what)
        if self.machine is not None:
            from excavator_payload.data.wiring import check_wiring

            check_wiring(frame, self.sensors, self.machine, what)
