"""Screening a dataset with the sensor health monitor before a command builds on it.

``zero`` must not store an offset built on a signal the monitor flags: these functions run a
fresh :class:`~excavator_payload.estimators.health.HealthMonitor` over a whole dataset and name
what it flags.
"""

from __future__ import annotations

import numpy as np

from excavator_payload.estimators.health import for_sensor_set


def flagged_signals(estimator, dataset) -> dict[str, str]:
    """The signals a fresh monitor flags anywhere in ``dataset`` (per experiment), each with its
    kinds and the first time, e.g. ``{"boom_head_pressure": "stuck at 3.20 s"}``; for commands
    that must not build on a faulty signal (``zero``).

    Parameters
    ----------
    estimator : Estimator
        A fitted estimator of the machine sensor set (its noise reference is used).
    dataset : Dataset
        The data to judge (machine sensor set).
    """
    monitor = for_sensor_set(dataset.sensor_set, getattr(estimator, "health_reference", None))
    if monitor is None:
        return {}
    frame = dataset.frame
    signals = list(dataset.sensor_set.signals)
    values = frame[signals].to_numpy(dtype=float)
    times = frame["time"].to_numpy(dtype=float)
    exps = frame["experiment"].to_numpy() if "experiment" in frame.columns else np.zeros(len(frame))
    low, high = getattr(estimator, "plausible_low", None), getattr(estimator, "plausible_high", None)
    seen: dict[str, tuple[set, float]] = {}
    last = None
    for t, x, e in zip(times, values, exps):
        if e != last:
            monitor.reset()
            last = e
        if not np.all(np.isfinite(x)) or (low is not None and not (np.all(x >= low) and np.all(x <= high))):
            continue  # the estimator skips these samples itself
        fault = monitor.step(float(t), x)
        for item in filter(None, fault.split(",")):
            signal, _, kind = item.partition(":")
            kinds, when = seen.setdefault(signal, (set(), float(t)))
            kinds.add(kind)
    return {s: f"{'/'.join(sorted(k))} at {t:.2f} s" for s, (k, t) in seen.items()}


def refuse_flagged(estimator, dataset, used_signals, command: str = "zero") -> None:
    """Raise :class:`~excavator_payload.errors.EstimatorError` (one line) when the monitor flags
    any of ``used_signals`` in ``dataset``: a result built on it would carry the fault.

    Parameters
    ----------
    estimator : Estimator
        The fitted estimator whose noise reference the monitor uses.
    dataset : Dataset
        The data the command would build on.
    used_signals : sequence of str
        The signals the command's result depends on.
    command : str
        The command's name, for the message.
    """
    from excavator_payload.errors import EstimatorError

    flagged = flagged_signals(estimator, dataset)
    bad = [f"{s} ({flagged[s]})" for s in used_signals if s in flagged]
    if bad:
        raise EstimatorError(f"{command}: the sensor health monitor flags {', '.join(bad)}; an offset "
                             f"built on it would carry the fault (fix the sensor and record again, "
                             f"or --force)")

