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

from pathlib import Path

import can
import pandas as pd

from excavator_payload.errors import DatasetError
from excavator_payload.runtime.can_sensor import PayloadSensor
from excavator_payload.runtime.record import check_log_suffix

#: Default silence (s) that separates two recordings in one log.
SEGMENT_GAP = 2.0


def read_log(path: str | Path):
    """Iterate the frames of a CAN log (python-can formats by suffix), one clear line on errors."""
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"CAN log '{path}' does not exist")
    check_log_suffix(path)
    try:
        yield from can.LogReader(str(path))
    except (ValueError, OSError, KeyError, IndexError, can.CanError) as exc:
        raise DatasetError(f"CAN log '{path}' could not be read: {exc}") from None


def replay_log(path: str | Path, sensor: PayloadSensor, segment_gap: float = SEGMENT_GAP,
               progress: bool = False) -> pd.DataFrame:
    """Estimates of every sample in the log ``path`` (see the module docstring)."""
    rows: list[tuple] = []
    experiment = -1
    segment_start = 0.0
    last_frame_time: float | None = None
    sensor.reset()

    def keep(outputs):
        for o in outputs:
            rows.append((experiment, o.time - segment_start, o.estimate, o.status, o.sigma, o.time))

    bar = None
    if progress:
        from rich.progress import Progress

        bar = Progress(transient=True)
        bar.start()
        task = bar.add_task("replaying (frames)", total=None)
    try:
        for i, message in enumerate(read_log(path)):
            if message.is_error_frame or message.is_remote_frame:
                continue
            if sensor.codec.message_of(message.arbitration_id) is None:
                sensor.counters["ignored"] += 1
                continue
            t = float(message.timestamp)
            if last_frame_time is None or t - last_frame_time > segment_gap:
                if sensor.pending:
                    keep([sensor.flush()])
                sensor.reset()
                experiment += 1
                segment_start = t
            last_frame_time = t
            keep(sensor.feed(message))
            if bar is not None and i % 1000 == 0:
                bar.update(task, completed=i)
        if sensor.pending:
            keep([sensor.flush()])
    finally:
        if bar is not None:
            bar.stop()
    if not rows:
        names = ", ".join(sensor.codec.message_names)
        raise DatasetError(f"CAN log '{path}': no frame carries the sensor messages ({names}) of "
                           f"the {sensor.sensor_set.name} sensor set; another DBC (--dbc, "
                           f"--signal-map)?")
    frame = pd.DataFrame(rows, columns=["experiment", "time", "payload_estimate", "status",
                                        "payload_sigma", "log_time"])
    frame["experiment"] = frame["experiment"].astype("int64")
    return frame
