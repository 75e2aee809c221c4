"""``excavator-payload can-replay``: a recorded CAN log through the payload sensor.

The log's frames go through the same :class:`~excavator_payload.runtime.can_sensor.PayloadSensor`
as on a live bus. A silence longer than ``segment_gap`` seconds ends a *segment* (a recording,
for example one lift): the sensor restarts and the next segment gets the next experiment
number, so the estimates of a log made by ``can-record`` line up with ``estimate`` on the
dataset it came from. Columns: ``experiment``, ``time`` (s since the segment's first sample),
``payload_estimate`` (kg), ``status``, plus ``payload_sigma`` (kg) and ``log_time`` (the
log's own timestamp).
"""

from __future__ import annotations

import logging
import math
import struct
import zlib
from pathlib import Path

import can
import numpy as np
import pandas as pd
from can.io.blf import BLFParseError

from excavator_payload.data.units import SampleWatch
from excavator_payload.errors import DatasetError
from excavator_payload.runtime import dbc
from excavator_payload.runtime.can_sensor import PayloadSensor
from excavator_payload.runtime.record import check_log_suffix

#: Default silence (s) that separates two recordings in one log.
SEGMENT_GAP = 2.0


#: What python-can's readers raise on a file that is not the format its suffix says: a
#: truncated or foreign BLF raises struct.error, zlib.error or BLFParseError, an unsupported TRC
#: version NotImplementedError (all of them escaped as an internal error before).
UNREADABLE_LOG = (ValueError, OSError, KeyError, IndexError, TypeError, EOFError, NotImplementedError,
                  struct.error, zlib.error, BLFParseError, can.CanError)


class _SkippedRecords(logging.Handler):
    """Counts the records python-can's readers skip with a logged warning (a TRC or ASC line
    they cannot parse): they were printed on stderr, breaking the one-line rule, and the lines
    were lost without a count."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.count = 0

    def emit(self, record: logging.LogRecord) -> None:
        self.count += 1


def read_log(path: str | Path, skipped: list[int] | None = None):
    """Iterate the frames of a CAN log (python-can formats by suffix), one clear line on errors.

    ``skipped``, if given (a list ``[n]``), has the records the reader could not parse and
    skipped added to ``n``.
    """
    path = Path(path)
    if path.is_dir():
        raise DatasetError(f"CAN log '{path}' is a folder, not a log file")
    if not path.is_file():
        raise DatasetError(f"CAN log '{path}' does not exist")
    check_log_suffix(path)
    readers = logging.getLogger("can.io")
    handler = _SkippedRecords()
    propagate = readers.propagate
    readers.addHandler(handler)
    readers.propagate = False
    try:
        yield from can.LogReader(str(path))
    except UNREADABLE_LOG as exc:
        kind = ("truncated or not a BLF file" if isinstance(exc, (struct.error, zlib.error, BLFParseError))
                else type(exc).__name__)
        raise DatasetError(f"CAN log '{path}' could not be read ({kind}): {exc}") from None
    finally:
        readers.removeHandler(handler)
        readers.propagate = propagate
        if skipped is not None:
            skipped[0] += handler.count


def replay_log(path: str | Path, sensor: PayloadSensor, segment_gap: float = SEGMENT_GAP,
               progress: bool = False) -> pd.DataFrame:
    """Estimates of every sample in the log ``path`` (see the module docstring)."""
    rows: list[tuple] = []
    skipped = [0]
    fed = 0
    bad_before = sensor.counters["bad_frames"]
    experiment = -1
    segment_start = 0.0
    last_frame_time: float | None = None
    backwards = 0  # frames earlier than the frame before them
    sensor.reset()

    def keep(outputs):
        for o in outputs:
            rows.append((experiment, o.time - segment_start, o.estimate, o.status, o.sigma, o.time))

    # units and wiring judged on the decoded samples, as a dataset's (data/units.py)
    watch = SampleWatch(sensor.sensor_set, getattr(sensor.estimator, "machine", None))
    step_values = sensor.estimator.step_values
    sensor.estimator.step_values = lambda t, v: (watch.add(experiment, t, v), step_values(t, v))[1]
    bar = None
    if progress:
        from rich.progress import Progress

        bar = Progress(transient=True)
        bar.start()
        task = bar.add_task("replaying (frames)", total=None)
    try:
        for i, message in enumerate(read_log(path, skipped)):
            if message.is_error_frame or message.is_remote_frame:
                continue
            if sensor.codec.message_of(message.arbitration_id) is None:
                sensor.counters["ignored"] += 1
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
                sensor.reset()
                experiment += 1
                segment_start = t
            last_frame_time = t
            fed += 1
            keep(sensor.feed(message))
            if bar is not None and i % 1000 == 0:
                bar.update(task, completed=i)
        if sensor.pending:
            keep([sensor.flush()])
    finally:
        del sensor.estimator.step_values
        if bar is not None:
            bar.stop()
    if not rows:
        names = ", ".join(sensor.codec.message_names)
        raise DatasetError(f"CAN log '{path}': no frame carries the sensor messages ({names}) of "
                           f"the {sensor.sensor_set.name} sensor set; another DBC (--dbc, "
                           f"--signal-map)?")
    if all(row[3] in ("invalid_input", dbc.STALE) for row in rows):
        if backwards > 0.01 * fed:
            # a shuffled log assembles no sample whole: it was blamed on another DBC
            raise DatasetError(f"CAN log '{path}': its time goes back between {backwards} of {fed} "
                               f"sensor frames (frames out of order?); sort the log by timestamp")
        # The sensor sets' generated DBCs share their PGNs (0xFF00, ...): a log of the machine
        # set replayed with a thesis model (or the reverse) decoded garbage or NaN in every
        # sample and wrote estimates that were all NaN, with exit status 0.
        bad = sensor.counters["bad_frames"] - bad_before
        raise DatasetError(f"CAN log '{path}': no sample in it has all the signals of the model's "
                           f"{sensor.sensor_set.name} sensor set readable ({bad} of {fed} sensor frames "
                           f"out of the DBC's ranges or not available); recorded with another DBC or "
                           f"sensor set (--dbc, --signal-map)?")
    watch.check(f"CAN log '{path}'")
    frame = pd.DataFrame(rows, columns=["experiment", "time", "payload_estimate", "status",
                                        "payload_sigma", "log_time"])
    frame["experiment"] = frame["experiment"].astype("int64")
    check_sample_rate(frame, sensor, path)
    frame.attrs["skipped_records"] = skipped[0]
    return frame


def check_sample_rate(frame: pd.DataFrame, sensor: PayloadSensor, path) -> None:
    """Refuse a log whose samples are not at the sensor set's rate (as ``read_dataset`` does).

    A log at another rate, or with timestamps in ms, was replayed without a word: the estimators
    differentiate against the timestamps or judge gaps by the sample period, so the estimates
    were 'gap' throughout or silently wrong (a 40 Hz log weighed by a 20 Hz model as if it were
    right; a log in ms made every sample its own segment, each one 'ok')."""
    steps = np.diff(frame["log_time"].to_numpy(dtype=float))
    same = frame["experiment"].to_numpy()[1:] == frame["experiment"].to_numpy()[:-1]
    steps = steps[same] if same.any() else steps
    steps = steps[np.isfinite(steps)]
    if steps.size == 0:
        return
    back = int(np.count_nonzero(steps < 0))
    if back > 0.01 * steps.size:
        # frames out of time order (a multi-channel logger's BLF, a merged log): samples are
        # assembled from frames of different periods, the estimates are mixed up
        raise DatasetError(f"CAN log '{path}': its time goes back between {back} of {steps.size} "
                           f"samples (frames out of order?); sort the log by timestamp")
    period = float(np.median(steps))
    expected = sensor.sensor_set.sample_period
    if not 0.8 * expected <= period <= 1.25 * expected:
        raise DatasetError(f"CAN log '{path}': its samples are {period:.4g} s apart, but the model's "
                           f"{sensor.sensor_set.name} sensor set samples at "
                           f"{sensor.sensor_set.sample_rate:g} Hz ({expected:g} s); a log of "
                           f"another rate, or timestamps not in seconds?")
