"""``excavator-payload can-replay``: a recorded CAN log through the payload sensor.

The log's frames go through the same :class:`~excavator_payload.runtime.can_sensor.PayloadSensor`
as on a live bus (samples on the model's clock from messages at their own rates; frames of
other source addresses are not the sensor's). A silence of the sensor's *own* frames longer
than ``segment_gap`` seconds ends a *segment* (a recording, for example one lift): another
ECU's traffic, or a sensor PGN from another address, does not keep a segment open. The
sensor restarts and the next segment gets the next experiment number, so the estimates of a
log made by ``can-record`` line up with ``estimate`` on the dataset it came from. Columns:
``experiment``, ``time`` (s since the segment's first sample), ``payload_estimate`` (kg),
``status``, plus ``payload_sigma`` (kg), ``log_time`` (the log's own timestamp) and
``stale_signals`` (the signals too old for the sample, comma-separated; empty when none) and
``fault`` (``signal:kind,...`` while the status is ``sensor_fault``). The DM1 messages the sensor
would have sent go through ``sensor.dm1`` (:meth:`~excavator_payload.runtime.dm1.DM1Transmitter.summary`).

Formats: :mod:`~excavator_payload.runtime.logs`. A log in which nothing is the sensor's gets one
line that says what it does hold (frames, ids, PGNs and source addresses, rates).
"""

from __future__ import annotations

import math
import random
from collections import Counter
from pathlib import Path

import numpy as np
import pandas as pd

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.log_watch import SampleWatch
from excavator_payload.errors import DatasetError
from excavator_payload.runtime import dbc
from excavator_payload.runtime.can_sensor import PayloadSensor
from excavator_payload.runtime.logs import UNREADABLE_LOG, LogSummary, read_frames  # noqa: F401

#: Default silence (s) of the sensor's own frames that separates two recordings in one log.
SEGMENT_GAP = 2.0
#: Estimates (and decoded samples) held before they go to their file: a day's log replays in
#: bounded memory (it held ~0.8 kB per sample, ~2 GB for 8 h at 100 Hz).
CHUNK_ROWS = 50_000
#: Frame intervals kept per sensor message for the rate check: a uniform sample of them all.
RATE_SAMPLE = 4096
#: The columns of a replay's estimates.
ESTIMATE_FRAME_COLUMNS = ("experiment", "time", "payload_estimate", "status", "payload_sigma", "log_time",
                          "stale_signals", "fault")


class ReplayEstimates:
    """The estimates of a replay as they come, in chunks of :data:`CHUNK_ROWS`: written to a
    Parquet file as they fill (``writer``: bounded memory) or kept for :meth:`frame`, with the
    counts a summary needs (statuses, stale signals, segments).

    Parameters
    ----------
    writer : ParquetStreamWriter, optional
        Where the chunks go; None keeps them in memory.
    """

    def __init__(self, writer=None) -> None:
        self.writer = writer
        self.count = 0
        self.statuses: Counter = Counter()
        self.stale: Counter = Counter()  # signal name -> samples it was stale in
        self.segments = 0
        self.usable = 0  # estimates neither invalid_input nor stale
        self.last_log_time: float | None = None
        self.attrs: dict = {}
        self._experiment = None
        self._rows: list[tuple] = []
        self._parts: list[pd.DataFrame] = []

    def add(self, row: tuple) -> None:
        """One estimate, in :data:`ESTIMATE_FRAME_COLUMNS` order.

        Parameters
        ----------
        row : tuple
            experiment, time, payload_estimate, status, payload_sigma, log_time, stale_signals, fault.
        """
        self._rows.append(row)
        self.count += 1
        self.statuses[row[3]] += 1
        if row[3] not in ("invalid_input", dbc.STALE):
            self.usable += 1
        if row[6]:
            self.stale.update(row[6].split(","))
        if row[0] != self._experiment:
            self._experiment = row[0]
            self.segments += 1
        self.last_log_time = row[5]
        if len(self._rows) >= CHUNK_ROWS:
            self.flush()

    def flush(self) -> None:
        """Move the held rows to the file (or the kept chunks)."""
        if not self._rows:
            return
        part = pd.DataFrame(self._rows, columns=list(ESTIMATE_FRAME_COLUMNS))
        part["experiment"] = part["experiment"].astype("int64")
        self._rows = []
        if self.writer is not None:
            self.writer.write(part)
        else:
            self._parts.append(part)

    def frame(self) -> pd.DataFrame:
        """Every estimate kept (without a writer), with :attr:`attrs`."""
        self.flush()
        frame = (pd.concat(self._parts, ignore_index=True) if self._parts
                 else pd.DataFrame(columns=list(ESTIMATE_FRAME_COLUMNS)))
        frame["experiment"] = frame["experiment"].astype("int64")
        frame.attrs.update(self.attrs)
        return frame


class ReplaySamples:
    """The samples a replay assembled (SI units, NaN where stale) written as a dataset file
    chunk by chunk (bounded memory): what ``can-replay --samples-out`` writes for ``zero --data``.
    A time that does not increase within a segment stops the file (:attr:`error` says why).

    Parameters
    ----------
    sensor_set : SensorSet
        The sensor set the values belong to.
    log : str or Path
        The CAN log they come from (kept in the file's metadata).
    writer : ParquetStreamWriter
        Where the chunks go (its metadata: :func:`samples_file_meta`).
    """

    def __init__(self, sensor_set, log: str | Path, writer) -> None:
        self.sensor_set = sensor_set
        self.log = log
        self.writer = writer
        self.error = ""
        self.segments = 0
        self._rows: list[tuple] = []
        self._last: tuple[int, float] | None = None  # (experiment, time) of the last sample written

    def append(self, sample: tuple) -> None:
        """One sample ``(experiment, time from the segment's start, values)``.

        Parameters
        ----------
        sample : tuple
            As :func:`replay_log` appends to its ``samples``.
        """
        if self.error:
            return
        if self._last is None or sample[0] != self._last[0]:
            self.segments += 1
        elif not sample[1] > self._last[1]:
            self.error = (f"CAN log '{self.log}': its decoded samples' time does not increase within "
                          f"segment {sample[0]} (at {sample[1]:.4f} s): no --samples-out file written")
            self.writer.abort()
            self._rows = []
            return
        self._last = (sample[0], sample[1])
        self._rows.append(sample)
        if len(self._rows) >= CHUNK_ROWS:
            self.flush()

    def flush(self) -> None:
        """Write the held samples."""
        if self._rows and not self.error:
            self.writer.write(samples_dataset(self._rows, self.sensor_set, self.log).frame)
        self._rows = []

    def close(self) -> int:
        """Finish the file; returns the samples written.

        Raises
        ------
        DatasetError
            A time that went back (:attr:`error`), or no sample assembled.
        """
        self.flush()
        if self.error:
            raise DatasetError(self.error)
        if self.writer.rows == 0:
            self.writer.abort()
            raise DatasetError(f"CAN log '{self.log}': no sample was assembled from it")
        return self.writer.close()


def samples_file_meta(sensor_set, log: str | Path) -> dict:
    """The metadata of a ``--samples-out`` file (as :func:`samples_dataset`'s, written).

    Parameters
    ----------
    sensor_set : SensorSet
        The sensor set of the samples.
    log : str or Path
        The CAN log they come from.
    """
    from excavator_payload.data.io import dataset_file_meta

    return dataset_file_meta({"sensor_set": sensor_set.name, "source": "CAN log", "log": str(log)},
                             sensor_set, ["experiment", "time", *sensor_set.signals])


def read_log(path: str | Path, skipped: list[int] | None = None):
    """Iterate the frames of a CAN log (:func:`~excavator_payload.runtime.logs.read_frames`).

    Parameters
    ----------
    path : str or Path
        The CAN log.
    skipped : list of int, optional
        A one-element counter ``[n]`` the unparsable records are added to.
    """
    return read_frames(path, skipped)


def replay_log(path: str | Path, sensor: PayloadSensor, segment_gap: float = SEGMENT_GAP,
               progress: bool = False, samples: list | None = None,
               estimates: ReplayEstimates | None = None) -> pd.DataFrame | ReplayEstimates:
    """Estimates of every sample in the log ``path`` (see the module docstring).

    Parameters
    ----------
    path : str or Path
        The CAN log.
    sensor : PayloadSensor
        The virtual sensor the frames feed (reset first).
    segment_gap : float, optional
        s of silence of the sensor's own frames that starts a new experiment.
    progress : bool, optional
        Show a progress bar.
    samples : list, optional
        If given, every sample the sensor assembled is appended to it as ``(experiment, time
        from the segment's start, values in the sensor set's signal order)`` (SI units; NaN
        where a signal was stale): what :func:`samples_dataset` turns into a dataset; or a
        :class:`ReplaySamples` that writes them to a file as they come.
    estimates : ReplayEstimates, optional
        Where the estimates go (e.g. to a file as they come, in bounded memory); it is
        returned instead of a frame, its ``attrs`` as the frame's below.

    Returns
    -------
    pandas.DataFrame
        One row per estimate: ``experiment``, ``time`` (s from the segment's start),
        ``payload_estimate`` and ``payload_sigma`` (kg), ``status``, ``log_time`` (s),
        ``stale_signals``, ``fault``; ``attrs["log_end"]``: the line that says the log ends
        early (truncated; :func:`~excavator_payload.runtime.logs.log_end`), empty when it is whole.
        With ``estimates`` given: that object.

    Raises
    ------
    DatasetError
        No sensor frame, frames out of order, wrong rates, or no readable sample.
    """
    kept = estimates if estimates is not None else ReplayEstimates()
    skipped = [0]
    ending: list[str] = []  # the line that says the log ends early (truncated)
    fed = 0
    bad_before = sensor.counters["bad_frames"]
    experiment = -1
    segment_start = 0.0
    last_frame_time: float | None = None
    backwards = 0  # sensor frames earlier than the sensor frame before them
    summary = LogSummary()
    intervals: dict[str, list[float]] = {}  # a uniform sample of each message's (RATE_SAMPLE)
    seen_intervals: Counter = Counter()
    pick = random.Random(0)
    last_of: dict[str, float] = {}
    sensor.reset()
    sensor.dm1.reset()

    def keep(outputs):
        for o in outputs:
            if o is not None:
                kept.add((experiment, o.time - segment_start, o.estimate, o.status, o.sigma, o.time,
                          ",".join(o.stale), o.fault))
                sensor.dm1.update(o.time, o.fault)

    # units and wiring judged on the decoded samples, as a dataset's (data/units.py)
    watch = SampleWatch(sensor.sensor_set, getattr(sensor.estimator, "machine", None))
    step_values = sensor.estimator.step_values

    def watched(t, v):
        watch.add(experiment, t, v)
        if samples is not None:
            samples.append((experiment, t - segment_start, np.array(v, dtype=float)))
        return step_values(t, v)

    sensor.estimator.step_values = watched
    bar = None
    if progress:
        from rich.progress import Progress

        bar = Progress(transient=True)
        bar.start()
        task = bar.add_task("replaying (frames)", total=None)
    try:
        for i, message in enumerate(read_frames(path, skipped, ending)):
            summary.add(message)
            spec = sensor.accepts(message)
            if spec is None:
                sensor.counters["frames"] += 1
                continue
            t = float(message.timestamp)
            if not math.isfinite(t):
                # one 'inf' timestamp started a segment at inf: every later sample of it got
                # time -inf. A frame without a time is an unreadable record.
                skipped[0] += 1
                continue
            if last_frame_time is not None and t < last_frame_time:
                backwards += 1
            if last_frame_time is None or t - last_frame_time > segment_gap:
                if sensor.pending:
                    keep([sensor.flush()])
                if kept.count:
                    sensor.dm1.update(kept.last_log_time, "")  # a new recording: its faults end here
                sensor.reset()
                experiment += 1
                segment_start = t
            last_frame_time = max(t, last_frame_time) if last_frame_time is not None else t
            fed += 1
            duplicates = sensor.counters["duplicates"]
            keep(sensor.feed(message, spec=spec))
            if sensor.counters["duplicates"] == duplicates:  # a frame twice is not a rate
                if spec.name in last_of:
                    _keep_interval(intervals.setdefault(spec.name, []), seen_intervals, spec.name,
                                   t - last_of[spec.name], pick)
                last_of[spec.name] = t
            if bar is not None and i % 1000 == 0:
                bar.update(task, completed=i)
        if sensor.pending:
            keep([sensor.flush()])
    finally:
        del sensor.estimator.step_values
        if bar is not None:
            bar.stop()
    if not kept.count:
        raise DatasetError(f"CAN log '{path}': no frame is the sensor messages ({_expected(sensor)}) of "
                           f"the {sensor.sensor_set.name} sensor set{_foreign(sensor)}; the log holds "
                           f"{summary.describe()}. Another DBC (--dbc, --signal-map)?")
    if backwards > 0.01 * fed:
        # a shuffled log assembles no sample right: it was blamed on another DBC
        raise DatasetError(f"CAN log '{path}': its time goes back between {backwards} of {fed} "
                           f"sensor frames (frames out of order?); sort the log by timestamp")
    check_message_rates(intervals, sensor, path)
    if not kept.usable:
        # The sensor sets' generated DBCs share their PGNs (0xFF00, ...): a log of the machine
        # set replayed with a thesis model (or the reverse) decoded garbage or NaN in every
        # sample and wrote estimates that were all NaN, with exit status 0.
        bad = sensor.counters["bad_frames"] - bad_before
        silent = sorted(set(sensor.codec.message_names) - set(last_of))
        never = f"; never heard: {', '.join(silent)}" if silent else ""
        raise DatasetError(f"CAN log '{path}': no sample in it has all the signals of the model's "
                           f"{sensor.sensor_set.name} sensor set readable ({bad} of {fed} sensor frames "
                           f"out of the DBC's ranges or not available{never}{_foreign(sensor)}{_short(sensor)}); "
                           f"recorded with another DBC or sensor set (--dbc, --signal-map)? The log holds "
                           f"{summary.describe()}")
    watch.check(f"CAN log '{path}'")
    kept.flush()
    kept.attrs.update(skipped_records=skipped[0], log_end=ending[0] if ending else "",
                      summary=summary.describe())
    return kept if estimates is not None else kept.frame()


def _keep_interval(kept: list[float], seen: Counter, name: str, interval: float, pick: random.Random) -> None:
    """Keep a uniform sample of :data:`RATE_SAMPLE` of a message's intervals (reservoir sampling):
    the rate check's median in bounded memory on a log of any length."""
    seen[name] += 1
    if len(kept) < RATE_SAMPLE:
        kept.append(interval)
    else:
        j = pick.randrange(seen[name])
        if j < RATE_SAMPLE:
            kept[j] = interval


def _expected(sensor: PayloadSensor) -> str:
    parts = []
    for name in sensor.codec.message_names:
        message = sensor.codec.messages[name]
        address = sensor.codec.expected_source(name)
        if sensor.codec.j1939 and message.is_extended_frame:
            sender = f" from SA 0x{address:02X}" if address is not None else ""
            parts.append(f"{name}: PGN 0x{dbc._pgn(message.frame_id):04X}{sender}")
        else:
            parts.append(f"{name}: id 0x{message.frame_id:X}")
    return "; ".join(parts)


def _short(sensor: PayloadSensor) -> str:
    """Which sensor messages came in frames shorter than the DBC's (a DBC message of more than 8
    bytes on classic CAN is sent by J1939's transport protocol, which is not reassembled here:
    the line said only "out of the DBC's ranges or not available")."""
    parts = []
    for name, (n, length) in sorted(sensor.short.items()):
        size = sensor.codec.messages[name].length
        tp = (" (more than a classic CAN frame carries: sent by J1939's transport protocol, TP.CM/TP.DT, "
              "which is not reassembled; map the signals to single-frame messages)" if size > 8 else "")
        parts.append(f"{name} is {size} bytes in the DBC, {n} of its frames {length}{tp}")
    return ("; frames shorter than the DBC's messages: " + ", ".join(parts)) if parts else ""


def _foreign(sensor: PayloadSensor) -> str:
    """What the sensor PGNs from other addresses were (a DBC with another sender's address)."""
    if not sensor.foreign:
        return ""
    parts = [f"{name} from SA 0x{address:02X} ({n} frames)" for (name, address), n in
             sorted(sensor.foreign.items(), key=lambda kv: -kv[1])[:4]]
    return ("; frames of the sensor PGNs came from other source addresses: " + ", ".join(parts)
            + " (if that is your sensor, set source_address in the signal map's [messages.<name>])")


def check_message_rates(intervals: dict[str, list[float]], sensor: PayloadSensor, path) -> None:
    """Refuse a log whose sensor messages do not come at the rate the DBC (or the model) says.

    A log at another rate, or with timestamps in ms, was replayed without a word (estimates
    'gap' throughout or silently wrong). Each message with a nominal period (the DBC's
    ``GenMsgCycleTime`` or the signal map's ``period``) must come within 0.8 … 1.25 of it; the
    fastest message must come at least at the model's rate (a slower one gives no sample per
    period). A message faster than the model without a nominal period is fine: the newest value
    is taken each period.

    Parameters
    ----------
    intervals : dict of str to list of float
        s between consecutive frames, per sensor message.
    sensor : PayloadSensor
        Its codec's nominal periods and sensor set's sample rate are the reference.
    path : str or Path
        The log (named in the message).

    Raises
    ------
    DatasetError
        A message off its nominal rate, or the fastest slower than the model's rate.
    """
    expected = sensor.sensor_set.sample_period
    rate = f"{sensor.sensor_set.sample_rate:g} Hz"
    fastest = (math.inf, "", None)
    for name, steps in intervals.items():
        if len(steps) < 3:
            continue
        period = float(np.median(steps))
        nominal = sensor.codec.nominal_period(name)
        if nominal is not None and not 0.8 * nominal <= period <= 1.25 * nominal:
            raise DatasetError(f"CAN log '{path}': its {name} frames are {period:.4g} s apart "
                               f"({_hz(period)}), but the DBC / signal map says {nominal:g} s "
                               f"({1 / nominal:g} Hz); recorded with another DBC or sensor set, at another rate, or with "
                               f"timestamps not in seconds?")
        fastest = min(fastest, (period, name, nominal), key=lambda f: f[0])
    period, name, nominal = fastest
    if math.isfinite(period) and period > 1.25 * expected:
        raise DatasetError(f"CAN log '{path}': its fastest sensor message ({name}) comes every {period:.4g} s "
                           f"({_hz(period)}), but the model's {sensor.sensor_set.name} sensor set samples at "
                           f"{rate} ({expected:g} s); recorded with another DBC or sensor set, at another rate, or "
                           f"with timestamps not in seconds?")


def _hz(period: float) -> str:
    return f"{1 / period:.4g} Hz" if period > 0 else "no time between them"


def samples_dataset(samples: list, sensor_set, log: str | Path) -> Dataset:
    """The samples :func:`replay_log` assembled from a CAN log (its ``samples``) as a dataset
    without payload (a field log): what ``zero``, ``estimate`` and ``plot`` read.

    Parameters
    ----------
    samples : list
        ``(experiment, time, values)`` tuples from :func:`replay_log`.
    sensor_set : SensorSet
        The sensor set the values belong to.
    log : str or Path
        The CAN log they came from (kept in the metadata).
    """
    if not samples:
        raise DatasetError(f"CAN log '{log}': no sample was assembled from it")
    values = np.stack([v for _, _, v in samples])
    frame = pd.DataFrame(values, columns=list(sensor_set.signals))
    frame.insert(0, "time", [t for _, t, _ in samples])
    frame.insert(0, "experiment", np.array([e for e, _, _ in samples], dtype="int64"))
    return Dataset(frame, {"sensor_set": sensor_set.name, "source": "CAN log", "log": str(log)})
