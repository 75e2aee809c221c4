"""``excavator-payload can-record``: a dataset as a CAN log, to exercise the CAN path without a machine.

Every sample becomes the frames of its sensor set's DBC (or of a user DBC and signal map);
experiment ``k`` starts :data:`EXPERIMENT_GAP` seconds after the end of experiment ``k-1``, so a
replay sees each experiment as one continuous recording
(:func:`~excavator_payload.runtime.replay.replay_log` splits at gaps). A NaN signal is sent as
J1939 "not available", a value outside the DBC range as the J1939 error indicator.

Each message goes out at its own period where the signal map or the DBC gives one
(``GenMsgCycleTime``; a multiple of the sample period: every n-th sample's values), else with
every sample: a DBC whose inclinometer message says 100 ms gives a log with it at 10 Hz beside
the 100 Hz pressures, as on a machine. ``jitter`` (s, standard deviation, clipped at 3 σ and
at a third of the sample period) moves each frame's timestamp; ``burst_every`` (s) holds one
message's frames back now and then and sends ``burst_length`` of them back to back, stamped
when they go out (a gateway's queue). Frames are written in time order.
"""

from __future__ import annotations

import os
from pathlib import Path

import can
import numpy as np

from excavator_payload.data.dataset import Dataset
from excavator_payload.errors import DatasetError
from excavator_payload.runtime.codec import SignalCodec
from excavator_payload.runtime.logs import check_suffix

#: Silence between two experiments in a recorded log, s.
EXPERIMENT_GAP = 5.0
#: Log formats python-can writes (by file suffix) that ``can-replay`` reads back (.mf4: asammdf).
LOG_SUFFIXES = (".asc", ".blf", ".log", ".csv", ".trc", ".mf4")


def check_log_suffix(path: Path) -> None:
    """Raise :class:`DatasetError` unless ``path`` ends in a CAN log format of
    :data:`LOG_SUFFIXES` (any case).

    Parameters
    ----------
    path : Path
        The log file to write.
    """
    check_suffix(path, LOG_SUFFIXES)


def message_strides(codec: SignalCodec, period: float) -> dict[str, int]:
    """Every how many samples each message goes out (its period / the sample period).

    Parameters
    ----------
    codec : SignalCodec
        Its messages' nominal periods (None: every sample).
    period : float
        s, the data's sample period.

    Raises
    ------
    DatasetError
        A message period that is not a whole number of sample periods.
    """
    strides = {}
    for name in codec.message_names:
        nominal = codec.nominal_period(name)
        if nominal is None:
            strides[name] = 1
            continue
        n = nominal / period
        if n < 0.5 or abs(n - round(n)) > 0.05 * n:
            raise DatasetError(f"message {name}'s period {nominal:g} s is not a multiple of the data's "
                               f"sample period {period:g} s: can-record sends every n-th sample")
        strides[name] = int(round(n))
    return strides


#: Share of a signal's values beyond its DBC signal's range (sent as the error indicator, or
#: clipped) above which the DBC cannot carry the data: a range or raw width too small for the
#: signal, or a factor in the signal map off by a unit. A few glitches stay glitches.
BEYOND_RANGE_SHARE = 0.01


def _check_ranges(codec: SignalCodec, values: np.ndarray) -> None:
    """Refuse a log whose DBC cannot carry the data: the frames would hold the error indicator
    (or clipped values) where the data had numbers, and the log be written without a word."""
    beyond = {k: v for k, v in codec.beyond_range(values).items() if v[0] > BEYOND_RANGE_SHARE * v[1]}
    if beyond:
        name, (count, finite, low, high) = next(iter(beyond.items()))
        src = codec.sources[name]
        sig = codec.messages[src.message].get_signal_by_name(src.signal)
        more = f"; {len(beyond)} signals alike ({', '.join(beyond)})" if len(beyond) > 1 else ""
        raise DatasetError(f"{name}: {count} of {finite} values ({low:.4g} … {high:.4g} in the DBC's unit) lie "
                           f"beyond what DBC signal {src.message}.{src.signal} carries ([{sig.minimum}, "
                           f"{sig.maximum}], {sig.length} bits × {sig.scale:g}); widen the signal in the DBC or "
                           f"check the signal map's factor{more}")


def record_dataset(dataset: Dataset, out: str | Path, codec: SignalCodec | None = None,
                   start_time: float = 0.0, channel: int | str = 1, progress: bool = False,
                   jitter: float = 0.0, burst_every: float = 0.0, burst_length: int = 3,
                   seed: int = 0) -> dict:
    """Write ``dataset`` as a CAN log ``out`` (format by suffix), atomically.

    Parameters
    ----------
    dataset : Dataset
        The samples to send; experiments follow one another :data:`EXPERIMENT_GAP` s apart.
    out : str or Path
        The log file; its suffix (:data:`LOG_SUFFIXES`) says the format.
    codec : SignalCodec, optional
        How the signals go into frames (default: the sensor set's generated DBC).
    start_time : float, optional
        s, timestamp of the first sample in the log.
    channel : int or str, optional
        The frames' channel.
    progress : bool, optional
        Show a progress bar.
    jitter : float, optional
        s, standard deviation of the normal timing jitter added to each frame (clipped at
        three standard deviations and at a third of the sample period); 0: none.
    burst_every : float, optional
        s between bursts: one message's next ``burst_length`` frames are held back and sent
        back to back; 0: none.
    burst_length : int, optional
        Frames per burst.
    seed : int, optional
        Seed of the jitter and of the choice of burst message.

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
    period = dataset.sensor_set.sample_period
    if not (np.isfinite(jitter) and jitter >= 0 and np.isfinite(burst_every) and burst_every >= 0):
        raise DatasetError("--jitter and --burst-every must be non-negative numbers of seconds")
    strides = message_strides(codec, period)
    rng = np.random.default_rng(seed)
    frame = dataset.frame
    times = frame["time"].to_numpy(dtype=float)
    values = dataset.signals()
    _check_ranges(codec, values)
    exp = frame["experiment"].to_numpy()
    starts = np.flatnonzero(np.r_[True, exp[1:] != exp[:-1]])
    bounds = np.r_[starts, len(exp)]
    tmp = out.with_name(f".{out.stem}.partial{out.suffix}")
    n_frames = 0
    offset = start_time
    limit = min(3 * jitter, period / 3)
    names = codec.message_names
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
                pending = []  # (stamp, order, message) of this experiment
                held: list = []  # a burst's frames held back
                next_burst = float(times[a] + shift) + burst_every if burst_every else np.inf
                victim = names[int(rng.integers(len(names)))]
                for i in range(a, b):
                    stamp = float(times[i] + shift)
                    for k, (fid, data, extended) in enumerate(codec.encode(values[i])):
                        name = names[k]
                        if (i - a) % strides[name]:
                            continue
                        t = stamp + (float(np.clip(rng.normal(0, jitter), -limit, limit)) if jitter else 0.0)
                        msg = can.Message(timestamp=t, arbitration_id=fid, is_extended_id=extended,
                                          data=data, channel=channel)
                        if name == victim and stamp >= next_burst:
                            held.append(msg)
                            if len(held) == burst_length:  # the queue goes out back to back
                                for n, h in enumerate(held):
                                    h.timestamp = t + 1e-4 * n
                                    pending.append((h.timestamp, len(pending), h))
                                held = []
                                next_burst = stamp + burst_every
                                victim = names[int(rng.integers(len(names)))]
                            continue
                        pending.append((t, len(pending), msg))
                for h in held:
                    pending.append((h.timestamp, len(pending), h))
                pending.sort(key=lambda p: (p[0], p[1]))
                for _, _, msg in pending:
                    writer.on_message_received(msg)
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
