"""``excavator-payload can-record``: a dataset as a CAN log, to exercise the CAN path without a machine.

Every sample becomes the frames of its sensor set's DBC (or of a user DBC and signal map), all
stamped with the sample's time; experiment ``k`` starts :data:`EXPERIMENT_GAP` seconds after
the end of experiment ``k-1``, so a replay sees each experiment as one continuous recording
(:func:`~excavator_payload.runtime.replay.replay_log` splits at gaps). A NaN signal is sent as
J1939 "not available", a value outside the DBC range as the J1939 error indicator.
"""

from __future__ import annotations

import os
from pathlib import Path

import can
import numpy as np

from excavator_payload.data.dataset import Dataset
from excavator_payload.errors import DatasetError
from excavator_payload.runtime.dbc import SignalCodec

#: Silence between two experiments in a recorded log, s.
EXPERIMENT_GAP = 5.0
#: Log formats python-can writes (by file suffix) that ``can-replay`` reads back.
LOG_SUFFIXES = (".asc", ".blf", ".log", ".csv", ".trc")


def check_log_suffix(path: Path) -> None:
    """Raise :class:`DatasetError` unless ``path`` ends in a CAN log format of
    :data:`LOG_SUFFIXES` (any case)."""
    if path.suffix.lower() not in LOG_SUFFIXES:
        raise DatasetError(f"'{path}': unknown CAN log format {path.suffix!r}; use one of "
                           f"{', '.join(LOG_SUFFIXES)}")


def record_dataset(dataset: Dataset, out: str | Path, codec: SignalCodec | None = None,
                   start_time: float = 0.0, channel: int | str = 1, progress: bool = False) -> dict:
    """Write ``dataset`` as a CAN log ``out`` (format by suffix), atomically.

    Returns
    -------
    dict
        ``frames``, ``samples``, ``experiments`` written and the log's ``duration`` (s).
    """
    out = Path(out)
    check_log_suffix(out)
    codec = codec or SignalCodec.for_sensor_set(dataset.sensor_set)
    if codec.sensor_set.signals != dataset.sensor_set.signals:
        raise DatasetError(f"the dataset holds the {dataset.sensor_set.name} sensor set, the CAN "
                           f"signal map is for {codec.sensor_set.name}")
    frame = dataset.frame
    times = frame["time"].to_numpy(dtype=float)
    values = dataset.signals()
    exp = frame["experiment"].to_numpy()
    starts = np.flatnonzero(np.r_[True, exp[1:] != exp[:-1]])
    bounds = np.r_[starts, len(exp)]
    tmp = out.with_name(f".{out.stem}.partial{out.suffix}")
    n_frames = 0
    offset = start_time
    bar = None
    if progress:
        from rich.progress import Progress

        bar = Progress(transient=True)
        bar.start()
        task = bar.add_task("recording", total=len(bounds) - 1)
    try:
        with can.Logger(str(tmp)) as writer:
            for a, b in zip(bounds[:-1], bounds[1:]):
                shift = offset - float(times[a])
                for i in range(a, b):
                    stamp = float(times[i] + shift)
                    for fid, data, extended in codec.encode(values[i]):
                        writer.on_message_received(can.Message(
                            timestamp=stamp, arbitration_id=fid, is_extended_id=extended,
                            data=data, channel=channel))
                        n_frames += 1
                offset = float(times[b - 1] + shift) + EXPERIMENT_GAP
                if bar is not None:
                    bar.advance(task)
        os.replace(tmp, out)
    finally:
        if bar is not None:
            bar.stop()
        if tmp.exists():
            tmp.unlink()
    return {"frames": n_frames, "samples": len(frame), "experiments": len(bounds) - 1,
            "duration": offset - EXPERIMENT_GAP - start_time}
