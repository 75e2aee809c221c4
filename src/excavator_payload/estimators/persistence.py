"""Saving and loading estimators: the model folder's format (``estimator.json`` + ``arrays.npz``)
and :func:`load_estimator`, which rebuilds any registered estimator from one.

:meth:`~excavator_payload.estimators.base.Estimator.save` writes the folder; each estimator's
own state goes through its ``_config`` / ``_arrays`` / ``_restore``.
"""

from __future__ import annotations

import hashlib
import json
import math
from enum import Enum
from pathlib import Path

import numpy as np

from excavator_payload.data.schema import get_sensor_set
from excavator_payload.errors import EstimatorError, ExcavatorPayloadError
from excavator_payload.estimators.checks import plausibility_limits
from excavator_payload.estimators.registry import estimator_class
from excavator_payload.model.machine import machine_from_dict
from excavator_payload.platforms import THESIS

SAVE_FORMAT = "excavator-payload-estimator"
SAVE_VERSION = 1
CONFIG_FILE = "estimator.json"
ARRAYS_FILE = "arrays.npz"
#: The key of ``estimator.json`` holding :func:`arrays_digest` of the arrays saved with it (files
#: saved before 2026-11-30 have none and are read as before).
DIGEST_KEY = "arrays_sha256"


def arrays_digest(arrays: dict) -> str:
    """SHA-256 of a model's arrays (names, dtypes, shapes and values), independent of the zip
    container: ``estimator.json`` keeps it so that an ``arrays.npz`` edited, re-saved with other
    types, or copied in from another model folder is refused instead of weighed with.

    Parameters
    ----------
    arrays : dict of str to numpy.ndarray
        The arrays as saved to (or read from) ``arrays.npz``.

    Returns
    -------
    str
        The hex digest.
    """
    digest = hashlib.sha256()
    for key in sorted(arrays):
        value = np.asarray(arrays[key])  # as np.savez stores it; tobytes() is C order
        digest.update(f"{key}|{value.dtype.str}|{value.shape}|".encode())
        digest.update(value.tobytes())
    return digest.hexdigest()


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Enum):
        return obj.value
    return obj


def load_estimator(directory: str | Path, expected: type | None = None):
    """Load any saved estimator (an :class:`~excavator_payload.estimators.base.Estimator`) from
    ``directory``; clear errors for foreign or corrupt folders.

    Parameters
    ----------
    directory : str or Path
        Model folder written by :meth:`Estimator.save`.
    expected : type or None
        Estimator class the folder must hold (None: any registered one).

    Returns
    -------
    Estimator
        The fitted estimator.
    """
    directory = Path(directory)
    cfg_path = directory / CONFIG_FILE
    if directory.exists() and not directory.is_dir():
        raise EstimatorError(f"'{directory}' is a file, not a saved model folder")
    if not directory.is_dir():
        raise EstimatorError(f"model folder '{directory}' does not exist")
    if not cfg_path.is_file():
        raise EstimatorError(f"'{directory}' is not a saved estimator (no {CONFIG_FILE})")
    try:
        # utf-8-sig: an estimator.json opened and saved in Notepad starts with a byte-order mark
        config = json.loads(cfg_path.read_text(encoding="utf-8-sig"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise EstimatorError(f"'{cfg_path}' is corrupt: {exc}") from None
    if not isinstance(config, dict) or config.get("format") != SAVE_FORMAT:
        raise EstimatorError(f"'{directory}' was not saved by excavator-payload")
    if config.get("version") != SAVE_VERSION:
        raise EstimatorError(f"'{directory}' has save format version {config.get('version')!r}, "
                             f"this software reads {SAVE_VERSION}")
    name = config.get("estimator")
    if not isinstance(name, str):
        raise EstimatorError(f"'{cfg_path}' names no estimator")
    klass = estimator_class(name)
    if expected is not None and not issubclass(klass, expected):
        raise EstimatorError(f"'{directory}' holds a {klass.name} estimator, not {expected.name}")
    saved_on = config.get("sensor_set")
    if isinstance(saved_on, str) and klass.TRAITS is not None and klass.TRAITS.refusal(saved_on):
        # a model of a sensor set the estimator left (ekf and ukf on the machine set, issue 28)
        raise EstimatorError(f"'{directory}' holds {klass.name} fitted on the {saved_on} sensor set, which it no "
                             f"longer runs on{klass.TRAITS.refusal(saved_on)}")
    arrays_path = directory / ARRAYS_FILE
    if not arrays_path.is_file():
        raise EstimatorError(f"'{arrays_path}' is missing (incomplete model folder)")
    try:
        with np.load(arrays_path, allow_pickle=False) as npz:
            arrays = {k: npz[k] for k in npz.files}
    except Exception as exc:  # zip, zlib, EOF, header and pickle errors all mean: corrupt file
        raise EstimatorError(f"'{arrays_path}' is corrupt ({type(exc).__name__}); save the model "
                             "again") from None
    for key, value in arrays.items():
        # Training logs may hold NaN (no validation set); everything the estimator computes
        # with must be finite: NaN weights would estimate NaN forever.
        if key.startswith("log_"):
            continue
        if value.dtype.kind not in "fiubUS" or (value.dtype.kind == "f" and not np.all(np.isfinite(value))):
            raise EstimatorError(f"'{arrays_path}': array '{key}' is not finite numbers (corrupt or "
                                 "tampered model folder)")
    options, state = config.get("options", {}), config.get("state", {})
    if not isinstance(options, dict) or not isinstance(state, dict):
        raise EstimatorError(f"'{cfg_path}': 'options' and 'state' must be JSON objects")
    try:
        machine = _machine_from_dict(config["machine"]) if config.get("machine") else None
        est = klass(machine=machine, **options)
        # Files saved before sensor sets existed hold the thesis set.
        est.sensor_set = get_sensor_set(config.get("sensor_set", THESIS.sensors.name))
        est._restore(state, arrays)
        est.plausible_low, est.plausible_high = _saved_limits(config.get("plausibility"), est)
        rated = config.get("rated_payload", est.rated_payload)  # older files: the machine's
        if rated is not None and (isinstance(rated, bool) or not isinstance(rated, (int, float))
                                  or not math.isfinite(rated) or rated <= 0):
            raise EstimatorError(f"its rated_payload must be a positive number of kg, got {rated!r}")
        est.rated_payload = None if rated is None else float(rated)
        est.health = config.get("health", True) is not False  # fitted on noise-free data: off
        reference = config.get("health_reference")  # older files: none (no noise check)
        if reference is not None:
            if not (isinstance(reference, dict) and all(
                    isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                    for v in reference.values())):
                raise EstimatorError("its 'health_reference' must map signals to finite numbers")
            est.health_reference = {str(k): float(v) for k, v in reference.items()}
        source = config.get("gate_sentinel")
        if source is not None:
            if not (isinstance(source, dict) and isinstance(source.get("machine"), dict)
                    and isinstance(source.get("noise"), str)):
                raise EstimatorError("its 'gate_sentinel' must hold a machine and a noise preset")
            est._sentinel_source = source
            est._build_sentinel()
    except ExcavatorPayloadError as exc:
        raise EstimatorError(f"'{directory}' is corrupt or incomplete: {exc}") from None
    except Exception as exc:  # any other failure to rebuild it from the files: corrupt files
        raise EstimatorError(f"'{directory}' is corrupt or incomplete: "
                             f"{type(exc).__name__}: {exc}") from None
    saved = config.get(DIGEST_KEY)
    if saved is not None and saved != arrays_digest(arrays):
        # checked after the folder rebuilt: the specific reasons above keep their own lines
        raise EstimatorError(f"'{arrays_path}' is not the arrays.npz saved with its estimator.json (edited, "
                             "re-saved, or copied in from another model folder): the model folder is corrupt; "
                             "use the folder as saved, or train (and zero) again")
    est.fitted = True
    est.reset()
    return est


def _machine_from_dict(data: dict):
    """A saved machine: the thesis' 2-link arm or a hydraulic machine (issue 11)."""
    return machine_from_dict(data)  # the model tells the two kinds apart


def _saved_limits(saved, est) -> tuple[np.ndarray, np.ndarray]:
    """Plausibility limits from ``estimator.json`` (older files: computed from the machine)."""
    n = len(est.sensor_set.signals)
    if saved is None:
        return plausibility_limits(est.sensor_set, est.machine)
    low = np.asarray(saved["low"], dtype=float)
    high = np.asarray(saved["high"], dtype=float)
    if low.shape != (n,) or high.shape != (n,) or not (np.all(np.isfinite(low)) and np.all(np.isfinite(high))
                                                      and np.all(low < high)):
        raise EstimatorError("its plausibility limits are not finite [low, high] pairs")
    return low, high
