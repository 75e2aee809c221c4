"""The protocol every payload estimator follows, and the registry that names them.

Every estimator (classical filters and neural networks alike) has

* ``fit(dataset)``: learn or calibrate from a :class:`~excavator_payload.data.Dataset`;
* ``estimate(dataset)``: batch, one estimate per sample (a DataFrame with ``experiment``,
  ``time``, ``payload_estimate`` in kg and ``status``);
* ``reset()`` + ``step(sample)``: streaming, one sample at a time; the batch result
  equals resetting at each experiment and stepping through its samples;
* ``save(dir)`` / ``load(dir)``: a readable ``estimator.json`` plus ``arrays.npz``.

Each estimator declares the sensor sets it runs on (:attr:`Estimator.SENSOR_SETS`, see
:mod:`excavator_payload.data.schema`); ``fit`` takes the set of its dataset, and from then on
signal vectors are in that set's column order and a dataset of another set gets one clear line.

Input checking is done once, here, so every estimator reacts the same way: a sample with a
missing or NaN signal, or an angle outside the machine's range, is *not* used and the step
returns the last estimate with a status saying why; a gap in time (more than 1.5 sample
periods) calls :meth:`Estimator._on_gap` (by default a reset) and is reported as ``gap``.
"""

from __future__ import annotations

import importlib
import json
import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Any, ClassVar, Mapping

import numpy as np
import pandas as pd

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.schema import THESIS_SENSORS, SensorSet, get_sensor_set
from excavator_payload.errors import EstimatorError
from excavator_payload.model.machine import Machine, load_machine

SAVE_FORMAT = "excavator-payload-estimator"
SAVE_VERSION = 1
CONFIG_FILE = "estimator.json"
ARRAYS_FILE = "arrays.npz"


class Status(str, Enum):
    """What the estimate beside it means."""

    OK = "ok"                    #: a valid estimate
    WARMING_UP = "warming_up"    #: not enough samples yet (delay lines filling, filter converging)
    NO_DATA = "no_data"          #: no sample seen since the last reset
    GAP = "gap"                  #: time jumped; the estimator restarted
    INVALID = "invalid_input"    #: a signal was missing, NaN or infinite: sample ignored
    OUT_OF_RANGE = "out_of_range"  #: an angle outside the machine's range: sample ignored


@dataclass(frozen=True)
class StepResult:
    estimate: float  # kg; NaN when there is no estimate yet
    status: Status


@dataclass(frozen=True)
class Option:
    """A command-line option of an estimator (``--name value`` after ``train NAME``)."""

    type: type
    default: Any
    help: str
    choices: tuple | None = None

    def parse(self, name: str, raw: Any) -> Any:
        try:
            if self.type is bool and isinstance(raw, str):
                if raw.lower() not in ("1", "0", "true", "false", "yes", "no"):
                    raise ValueError
                value = raw.lower() in ("1", "true", "yes")
            elif self.type in (list, tuple) and isinstance(raw, str):
                value = [int(v) if v.strip().lstrip("-").isdigit() else v.strip()
                         for v in raw.replace("[", "").replace("]", "").split(",") if v.strip()]
            else:
                value = self.type(raw)
        except (TypeError, ValueError):
            raise EstimatorError(f"option --{name.replace('_', '-')}: {raw!r} is not a valid "
                                 f"{self.type.__name__}") from None
        if self.choices is not None and value not in self.choices:
            raise EstimatorError(f"option --{name.replace('_', '-')}: {value!r} is not one of "
                                 f"{', '.join(map(str, self.choices))}")
        return value


class Estimator(ABC):
    """Base class of all payload estimators. Subclasses implement the ``_``-methods.

    Parameters
    ----------
    machine : Machine, str or None
        The machine model the estimator believes in (preset name or file); some estimators
        (neural networks) need none.
    **options
        Estimator options, see the class attribute ``OPTIONS``.
    """

    #: Registry name, as used on the command line.
    name: ClassVar[str] = ""
    #: Options with their types, defaults and help.
    OPTIONS: ClassVar[dict[str, Option]] = {}
    #: Whether the estimator needs a machine model.
    NEEDS_MACHINE: ClassVar[bool] = True
    #: Names of the sensor sets (:data:`~excavator_payload.data.schema.SENSOR_SETS`) it runs on.
    SENSOR_SETS: ClassVar[tuple[str, ...]] = ("thesis",)

    def __init__(self, machine: Machine | str | None = None, **options: Any) -> None:
        unknown = sorted(set(options) - set(self.OPTIONS))
        if unknown:
            known = ", ".join("--" + k.replace("_", "-") for k in self.OPTIONS) or "none"
            raise EstimatorError(f"{self.name}: unknown option(s) "
                                 f"{', '.join('--' + u.replace('_', '-') for u in unknown)}; known: {known}")
        self.options = {k: (o.parse(k, options[k]) if k in options and isinstance(options[k], str)
                            and o.type is not str else options.get(k, o.default))
                        for k, o in self.OPTIONS.items()}
        for k, o in self.OPTIONS.items():
            if o.choices is not None and self.options[k] not in o.choices:
                raise EstimatorError(f"{self.name}: option --{k.replace('_', '-')} must be one of "
                                     f"{', '.join(map(str, o.choices))}, got {self.options[k]!r}")
        if machine is None and self.NEEDS_MACHINE:
            machine = "cat345c"
        self.machine: Machine | None = load_machine(machine) if machine is not None else None
        if getattr(self.machine, "kind", None) == "hydraulic" and "machine" not in self.SENSOR_SETS:
            # issue 11: a hydraulic machine file only serves estimators of the machine sensor set
            raise EstimatorError(f"{self.name} does not run on the hydraulic machine "
                                 f"'{self.machine.name}' (it runs on: {', '.join(self.SENSOR_SETS)})")
        #: The sensor set of the data it was fitted on (the thesis set until then).
        self.sensor_set: SensorSet = THESIS_SENSORS
        self.fitted = False
        self._last_time: float | None = None
        self._last_estimate = math.nan
        self._n_seen = 0

    # -- to implement ----------------------------------------------------------------------
    @abstractmethod
    def _fit(self, dataset: Dataset) -> None:
        """Learn from ``dataset`` (may do nothing for model-based filters)."""

    @abstractmethod
    def _reset(self) -> None:
        """Forget everything of the current experiment."""

    @abstractmethod
    def _step(self, time: float, values: np.ndarray) -> StepResult:
        """Consume one valid sample (``values`` in ``self.sensor_set.signals`` order, SI units)."""

    def _config(self) -> dict:
        """Extra JSON-able state to save (options and machine are saved by the base class)."""
        return {}

    def _arrays(self) -> dict[str, np.ndarray]:
        """Arrays to save (weights, maps, covariances)."""
        return {}

    def _restore(self, config: dict, arrays: Mapping[str, np.ndarray]) -> None:
        """Restore what :meth:`_config` and :meth:`_arrays` saved."""

    def _on_gap(self, time: float, values: np.ndarray) -> None:
        """Called when time jumps by more than 1.5 sample periods: restart by default."""
        self._reset()

    # -- protocol --------------------------------------------------------------------------
    def fit(self, dataset: Dataset) -> "Estimator":
        """Fit to ``dataset`` and return ``self``."""
        self.sensor_set = self._check_sensor_set(dataset)
        self._fit(dataset)
        self.fitted = True
        self.reset()
        return self

    def _check_sensor_set(self, dataset: Dataset) -> SensorSet:
        """The dataset's sensor set, if this estimator runs on it (one clear line otherwise)."""
        sensors = dataset.sensor_set
        if sensors.name not in self.SENSOR_SETS:
            raise EstimatorError(f"{self.name} does not run on the {sensors.name} sensor set "
                                 f"(it runs on: {', '.join(self.SENSOR_SETS)})")
        return sensors

    def reset(self) -> None:
        """Start a new experiment (streaming)."""
        self._last_time = None
        self._last_estimate = math.nan
        self._n_seen = 0
        self._reset()

    def step(self, sample: Mapping[str, float]) -> StepResult:
        """Consume one sample (a mapping with ``time`` and the signals of the sensor set).

        Never raises for bad data: the status says what happened.
        """
        if not self.fitted:
            raise EstimatorError(f"{self.name}: call fit() (or load a trained model) before step()")
        try:
            time = float(sample["time"])
            values = np.array([float(sample[s]) for s in self.sensor_set.signals])
        except (KeyError, TypeError, ValueError):
            return StepResult(self._last_estimate, Status.INVALID)
        return self.step_values(time, values)

    def step_values(self, time: float, values: np.ndarray) -> StepResult:
        """:meth:`step` for a sample given as ``time`` and an array in ``sensor_set.signals`` order."""
        if not self.fitted:
            raise EstimatorError(f"{self.name}: call fit() (or load a trained model) before step()")
        if not (math.isfinite(time) and np.all(np.isfinite(values))):
            return StepResult(self._last_estimate, Status.INVALID)
        if self.machine is not None and not self._in_range(values):
            return StepResult(self._last_estimate, Status.OUT_OF_RANGE)
        gap = False
        if self._last_time is not None:
            dt = time - self._last_time
            if dt <= 0 or dt > 1.5 * self.sensor_set.sample_period:
                self._on_gap(time, values)
                gap = True
        self._last_time = time
        self._n_seen += 1
        result = self._step(time, values)
        self._last_estimate = result.estimate
        if gap:
            return StepResult(result.estimate, Status.GAP)
        return result

    def _in_range(self, values: np.ndarray) -> bool:
        m, sensors = self.machine, self.sensor_set
        return (m.boom_angle_range[0] <= values[sensors.index("boom_angle")] <= m.boom_angle_range[1]
                and m.dipper_angle_range[0] <= values[sensors.index("dipper_angle")]
                <= m.dipper_angle_range[1])

    def estimate(self, dataset: Dataset) -> pd.DataFrame:
        """Batch estimates: reset at each experiment and step through its samples.

        Returns
        -------
        pandas.DataFrame
            ``experiment``, ``time``, ``payload_estimate`` (kg, NaN where none yet), ``status``.
        """
        if not self.fitted:
            raise EstimatorError(f"{self.name}: call fit() (or load a trained model) before estimate()")
        missing = [c for c in self.sensor_set.signals if c not in dataset.frame.columns]
        if missing:
            raise EstimatorError(f"{self.name} was fitted on the {self.sensor_set.name} sensor set; "
                                 f"the data lack its column(s) {', '.join(missing)}")
        est = np.full(len(dataset.frame), np.nan)
        status = np.empty(len(dataset.frame), dtype=object)
        times = dataset.frame["time"].to_numpy(dtype=float)
        values = dataset.signals(self.sensor_set.signals)
        exp = dataset.frame["experiment"].to_numpy()
        starts = np.flatnonzero(np.r_[True, exp[1:] != exp[:-1]])
        bounds = np.r_[starts, len(exp)]
        for a, b in zip(bounds[:-1], bounds[1:]):
            self.reset()
            for i in range(a, b):
                r = self.step_values(times[i], values[i])
                est[i], status[i] = r.estimate, r.status.value
        return pd.DataFrame({"experiment": exp, "time": times, "payload_estimate": est,
                             "status": status})

    # -- persistence -----------------------------------------------------------------------
    def save(self, directory: str | Path) -> Path:
        """Save to ``directory`` (created): ``estimator.json`` (readable) + ``arrays.npz``."""
        if not self.fitted:
            raise EstimatorError(f"{self.name}: nothing to save, the estimator is not fitted")
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        config = {
            "format": SAVE_FORMAT,
            "version": SAVE_VERSION,
            "estimator": self.name,
            "options": _jsonable(self.options),
            "machine": self.machine.to_dict() if self.machine is not None else None,
            "sensor_set": self.sensor_set.name,
            "state": _jsonable(self._config()),
        }
        arrays = self._arrays()
        tmp = directory / (ARRAYS_FILE + ".tmp.npz")
        np.savez(tmp, **arrays)
        tmp.replace(directory / ARRAYS_FILE)
        (directory / (CONFIG_FILE + ".tmp")).write_text(json.dumps(config, indent=2))
        (directory / (CONFIG_FILE + ".tmp")).replace(directory / CONFIG_FILE)
        return directory

    @classmethod
    def load(cls, directory: str | Path) -> "Estimator":
        """Load an estimator saved with :meth:`save` (any registered kind)."""
        return load_estimator(directory, expected=cls if cls is not Estimator else None)

    def __repr__(self) -> str:
        machine = self.machine.name if self.machine else None
        return f"{type(self).__name__}(machine={machine!r}, fitted={self.fitted}, options={self.options})"


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


def load_estimator(directory: str | Path, expected: type | None = None) -> Estimator:
    """Load any saved estimator from ``directory``; clear errors for foreign or corrupt folders."""
    directory = Path(directory)
    cfg_path = directory / CONFIG_FILE
    if not directory.is_dir():
        raise EstimatorError(f"model folder '{directory}' does not exist")
    if not cfg_path.is_file():
        raise EstimatorError(f"'{directory}' is not a saved estimator (no {CONFIG_FILE})")
    try:
        config = json.loads(cfg_path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise EstimatorError(f"'{cfg_path}' is corrupt: {exc}") from None
    if not isinstance(config, dict) or config.get("format") != SAVE_FORMAT:
        raise EstimatorError(f"'{directory}' was not saved by excavator-payload")
    if config.get("version") != SAVE_VERSION:
        raise EstimatorError(f"'{directory}' has save format version {config.get('version')}, "
                             f"this software reads {SAVE_VERSION}")
    klass = estimator_class(str(config.get("estimator")))
    if expected is not None and not issubclass(klass, expected):
        raise EstimatorError(f"'{directory}' holds a {klass.name} estimator, not {expected.name}")
    try:
        with np.load(directory / ARRAYS_FILE, allow_pickle=False) as npz:
            arrays = {k: npz[k] for k in npz.files}
    except (OSError, ValueError) as exc:
        raise EstimatorError(f"'{directory / ARRAYS_FILE}' is missing or corrupt: {exc}") from None
    machine = _machine_from_dict(config["machine"]) if config.get("machine") else None
    try:
        est = klass(machine=machine, **config.get("options", {}))
        # Files saved before sensor sets existed hold the thesis set.
        est.sensor_set = get_sensor_set(config.get("sensor_set", "thesis"))
        est._restore(config.get("state", {}), arrays)
    except EstimatorError:
        raise
    except (KeyError, ValueError, TypeError) as exc:
        raise EstimatorError(f"'{directory}' is corrupt or incomplete: {exc!r}") from None
    est.fitted = True
    est.reset()
    return est


def _machine_from_dict(data: dict):
    """A saved machine: the thesis' 2-link arm or a hydraulic machine (issue 11)."""
    if data.get("kind") == "hydraulic":
        from excavator_payload.model.hydraulic_machine import HydraulicMachine

        return HydraulicMachine.from_dict(data)
    return Machine.from_dict(data)


# -- registry ------------------------------------------------------------------------------
#: Command-line name -> module that defines it (imported on demand, so torch loads only for nets).
ESTIMATOR_MODULES: dict[str, str] = {
    "ekf": "excavator_payload.estimators.classical.ekf",
    "ukf": "excavator_payload.estimators.classical.ukf",
    "inverse-dynamics": "excavator_payload.estimators.classical.inverse_dynamics",
    "calibrated": "excavator_payload.estimators.classical.calibrated",
    "quasi-static": "excavator_payload.estimators.classical.quasi_static",
    "net1": "excavator_payload.estimators.dvs.networks",
    "net2": "excavator_payload.estimators.dvs.recurrent",
    "ffnn": "excavator_payload.estimators.dvs.networks",
    "dtdnn": "excavator_payload.estimators.dvs.networks",
    "lrn": "excavator_payload.estimators.dvs.recurrent",
}

_REGISTRY: dict[str, type[Estimator]] = {}


def register(klass: type[Estimator]) -> type[Estimator]:
    """Class decorator: make an estimator available by its ``name``."""
    if not klass.name:
        raise TypeError(f"{klass.__name__} has no name")
    _REGISTRY[klass.name] = klass
    return klass


def estimator_names() -> list[str]:
    return list(ESTIMATOR_MODULES)


def estimator_class(name: str) -> type[Estimator]:
    """The class registered as ``name`` (importing its module on demand)."""
    if name not in _REGISTRY:
        module = ESTIMATOR_MODULES.get(name)
        if module is None:
            raise EstimatorError(f"unknown estimator '{name}': choose one of {', '.join(ESTIMATOR_MODULES)}")
        try:
            importlib.import_module(module)
        except ModuleNotFoundError as exc:
            if exc.name and exc.name.startswith("excavator_payload"):
                raise EstimatorError(f"estimator '{name}' is not available in this installation") from None
            raise
    if name not in _REGISTRY:
        raise EstimatorError(f"estimator '{name}' is not available in this installation")
    return _REGISTRY[name]


def create_estimator(name: str, machine: Machine | str | None = None, **options: Any) -> Estimator:
    """A new, unfitted estimator called ``name`` with the given options."""
    return estimator_class(name)(machine=machine, **options)
