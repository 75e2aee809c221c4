"""Samples decoded from a CAN log after the signal map, judged like a dataset's experiments:
per-experiment units (:mod:`~excavator_payload.data.units`) and, with a hydraulic machine, the
arm's balance (:mod:`~excavator_payload.data.wiring`), in bounded memory."""

from __future__ import annotations

import numpy as np
import pandas as pd

from excavator_payload.data.units import check_peaks, check_signal_units
from excavator_payload.data.wiring import check_wiring


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

    Parameters
    ----------
    sensors : SensorSet
        The sensor set the samples are in.
    machine : Machine, optional
        The machine for the balance (wiring) check; None: no wiring check.
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
        """One assembled sample (the signal vector in the sensor set's order) of ``experiment``.

        Parameters
        ----------
        experiment : int
            The log segment the sample belongs to.
        time : float
            The sample's time, s.
        values : array_like
            The signal vector in the sensor set's order (SI units; NaN where missing).
        """
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
        """Judge what was seen; :class:`DatasetError` (one line) on a unit or wiring mistake.

        Parameters
        ----------
        source : str
            The log's name, the start of the error message.
        """
        what = f"{source} (decoded through the signal map)"
        if self._peaks:
            peaks = pd.DataFrame.from_dict(self._peaks, orient="index", columns=self._peak_columns)
            check_peaks(peaks, self.sensors, what)
        frame = self.frame()
        if len(frame) == 0:
            return
        check_signal_units(frame, self.sensors, what)
        if self.machine is not None:
            check_wiring(frame, self.sensors, self.machine, what)
