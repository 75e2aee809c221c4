"""The options every DVS network has and how their text is read: hidden layers, delays, input
signals (by name, ``all``, ``default`` or MATLAB's 1-based column numbers), and the limits that
keep a typo from asking for terabytes.
"""

from __future__ import annotations

import re
from typing import Any

import numpy as np

from excavator_payload.data.schema import MACHINE_SENSORS, THESIS_SENSORS, SensorSet
from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.base import Option
from excavator_payload.estimators.dvs.scaling import SCALINGS

#: The thesis' network inputs (appendix A.3 ``Input='[1 2 4 5 7 8]'``): angles, rates, torques.
THESIS_INPUTS: tuple[str, ...] = ("boom_angle", "boom_rate", "dipper_angle", "dipper_rate",
                                  "boom_torque", "dipper_torque")
#: Default inputs per sensor set: the thesis' six signals; on a machine every signal it has
#: (angles, rates, slew rate, inclinations and all six pressures).
DEFAULT_INPUTS: dict[str, tuple[str, ...]] = {THESIS_SENSORS.name: THESIS_INPUTS,
                                               MACHINE_SENSORS.name: MACHINE_SENSORS.signals}
#: The training algorithms ``--trainer`` accepts.
TRAINERS = ("trainbr", "adam")

#: Longest list an option may expand to (delays, layers).
MAX_LIST = 1000
#: Largest layer and largest delay accepted: far beyond any payload network, small enough that
#: a typo cannot ask for terabytes.
MAX_LAYER_SIZE = 1000
MAX_DELAY = 1000
#: Most weights a network may have: trainbr solves an (n × n) system per epoch (8·n² bytes).
MAX_WEIGHTS = {"trainbr": 5000, "adam": 1_000_000}

#: Largest ``--decimation``: 10 s between network samples at 100 Hz, beyond any use.
MAX_DECIMATION = 1000


def parse_int_list(raw: Any, what: str) -> list[int]:
    """``"10,10,10"``, ``"[10 10 10]"``, ``"0:5"`` (MATLAB range), ``"0:2:6"``, ``[0, 1]`` or an int.

    Parameters
    ----------
    raw : Any
        The option's value (text, int or sequence of them).
    what : str
        What the list is, for error messages.

    Returns
    -------
    list of int
        The integers, in the order given.
    """
    if isinstance(raw, (int, np.integer)):
        return [int(raw)]
    if isinstance(raw, (list, tuple, np.ndarray)):
        out = []
        for v in raw:
            out.extend(parse_int_list(v, what))
        return out
    text = str(raw).strip().strip("[]()").strip()
    if not text:
        return []
    out: list[int] = []
    try:
        for part in re.split(r"[,\s;]+", text):
            if not part:
                continue
            if ":" in part:
                bits = [int(b) for b in part.split(":")]
                if len(bits) == 2:
                    lo, step, hi = bits[0], 1, bits[1]
                elif len(bits) == 3:
                    lo, step, hi = bits
                else:
                    raise ValueError
                if step <= 0:
                    raise ValueError
                if (hi - lo) // step > MAX_LIST:
                    raise EstimatorError(f"{what}: {raw!r} has more than {MAX_LIST} entries")
                out.extend(range(lo, hi + 1, step))
            else:
                out.append(int(part))
    except ValueError:
        raise EstimatorError(f"{what}: cannot read {raw!r} (use e.g. '10,10,10' or '0:5')") from None
    return out


def parse_hidden(raw: Any) -> list[int]:
    """Hidden-layer sizes from the ``--hidden`` option (any form :func:`parse_int_list` reads):
    at most 20 layers of 1 to ``MAX_LAYER_SIZE`` neurons each, else :class:`EstimatorError`.

    Parameters
    ----------
    raw : Any
        The ``--hidden`` value.
    """
    sizes = parse_int_list(raw, "--hidden")
    if any(s <= 0 for s in sizes):
        raise EstimatorError(f"--hidden: layer sizes must be positive, got {raw!r}")
    if any(s > MAX_LAYER_SIZE for s in sizes) or len(sizes) > 20:
        raise EstimatorError(f"--hidden: at most 20 layers of at most {MAX_LAYER_SIZE} neurons, got {raw!r}")
    return sizes


def parse_delays(raw: Any) -> list[int]:
    """Tapped-delay-line delays in samples from the ``--delays`` option (e.g. ``'0:5'``), sorted:
    at least one, distinct, between 0 and ``MAX_DELAY``, else :class:`EstimatorError`.

    Parameters
    ----------
    raw : Any
        The ``--delays`` value.
    """
    delays = parse_int_list(raw, "--delays")
    if not delays:
        raise EstimatorError("--delays: give at least one delay (e.g. '0:5')")
    if any(d < 0 for d in delays) or len(set(delays)) != len(delays):
        raise EstimatorError(f"--delays: delays must be distinct and non-negative, got {raw!r}")
    if max(delays) > MAX_DELAY:
        raise EstimatorError(f"--delays: at most {MAX_DELAY} samples, got {raw!r}")
    return sorted(delays)


def parse_inputs(raw: Any, sensor_set: SensorSet = THESIS_SENSORS) -> list[str]:
    """Signal names (comma separated), ``all``, ``default`` or MATLAB's 1-based column numbers
    (``'1,2,4'``), of the signals of ``sensor_set``.

    Parameters
    ----------
    raw : Any
        The ``--inputs`` value (text or sequence).
    sensor_set : SensorSet
        Sensor set whose signals are chosen from.

    Returns
    -------
    list of str
        Signal names.
    """
    signals = sensor_set.signals
    items = list(raw) if isinstance(raw, (list, tuple)) else \
        [p for p in re.split(r"[,\s;]+", str(raw).strip().strip("[]")) if p]
    if items == ["all"]:
        return list(signals)
    if items == ["default"]:
        return list(DEFAULT_INPUTS.get(sensor_set.name, signals))
    names: list[str] = []
    for item in items:
        item = str(item).strip()
        if item.isdigit():
            k = int(item)
            if not 1 <= k <= len(signals):
                raise EstimatorError(f"--inputs: column number {k} is not in 1…{len(signals)} "
                                     f"(the {sensor_set.name} sensor set)")
            item = signals[k - 1]
        if item not in signals:
            raise EstimatorError(f"--inputs: unknown signal {item!r} of the {sensor_set.name} sensor "
                                 f"set; choose from {', '.join(signals)}")
        names.append(item)
    if not names or len(set(names)) != len(names):
        raise EstimatorError(f"--inputs: give distinct signal names, got {raw!r}")
    return names


def neural_options(hidden: str = "10,10,10", delays: str = "0:5", **extra: Option) -> dict[str, Option]:
    """The options every network has (with per-network defaults) plus ``extra``.

    Parameters
    ----------
    hidden : str
        Default of ``--hidden``.
    delays : str
        Default of ``--delays``.
    **extra : Option
        The network's own options.
    """
    options = {
        "hidden": Option(str, hidden, "hidden layer sizes, e.g. '10,10,10'"),
        "delays": Option(str, delays, "input delays in samples, MATLAB style, e.g. '0:5' or '0,1,2'"),
        "inputs": Option(str, "default",
                         "input signals of the data's sensor set (comma separated names, 'all', "
                         "1-based column numbers, or 'default': the thesis' six signals on the "
                         "thesis set, every signal on the machine set)"),
        "scaling": Option(str, "mapminmax", "input/output scaling", SCALINGS),
        "trainer": Option(str, "trainbr", "training algorithm", TRAINERS),
        "decimation": Option(int, 1, "the network runs on every K-th sample of the data (samples), "
                             "each input the mean of the last K samples; --delays then count the "
                             "network's samples and the estimate is held in between (1: every "
                             "sample; 5 on the machine set's 100 Hz gives the thesis nets' 20 Hz)"),
        "smoothing": Option(float, 0.0, "time constant of a first-order low-pass on the "
                            "network's estimate, seconds (a payload is constant while carried; "
                            "0: none, the thesis nets)"),
        "epochs": Option(int, 700, "maximum training epochs (MATLAB: 1000; capped to keep net1 on "
                                   "100 experiments near 70 s of CPU on a 2-core machine)"),
        "max_time": Option(float, 0.0, "stop training after this many seconds (0: no limit)"),
        "learning_rate": Option(float, 1e-3, "Adam learning rate (trainer adam only)"),
        "seed": Option(int, 0, "seed of the initial weights"),
        "train_experiments": Option(int, 100, "the first N experiments of the data train"),
        "validation_experiments": Option(int, 51, "the next N experiments validate"),
        "best_validation": Option(bool, True, "return the weights of the epoch with the lowest "
                                  "validation error, as MATLAB's train does with a validation set "
                                  "(false: the last epoch's, trainbr alone)"),
        "validation_patience": Option(int, 0, "stop when the validation error has not improved "
                                      "for this many epochs (MATLAB max_fail; 0: never, as trainbr)"),
        "progress": Option(bool, True, "show a progress bar while training"),
    }
    options.update(extra)
    return options


__all__ = ["THESIS_INPUTS", "DEFAULT_INPUTS", "TRAINERS", "MAX_LIST", "MAX_LAYER_SIZE", "MAX_DELAY",
           "MAX_WEIGHTS", "MAX_DECIMATION", "parse_int_list", "parse_hidden", "parse_delays",
           "parse_inputs", "neural_options"]
