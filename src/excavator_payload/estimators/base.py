"""The protocol every payload estimator follows (:class:`Estimator`).

Every estimator (classical filters and neural networks alike) has

* ``fit(dataset)``: learn or calibrate from a :class:`~excavator_payload.data.Dataset`;
* ``estimate(dataset)``: batch, one estimate per sample (a DataFrame with ``experiment``,
  ``time``, ``payload_estimate`` in kg and ``status``);
* ``reset()`` + ``step(sample)``: streaming, one sample at a time; the batch result
  equals resetting at each experiment and stepping through its samples;
* ``save(dir)`` / ``load(dir)``: a readable ``estimator.json`` plus ``arrays.npz``.

The protocol's parts have rooms of their own, and this module re-exports their names:
:mod:`.status` (:class:`Status`, :class:`StepResult`), :mod:`.options` (:class:`Option`),
:mod:`.checks` (plausibility limits and the gate's tables), :mod:`.persistence` (the model
folder, :func:`load_estimator`) and :mod:`.registry` (:func:`register`,
:func:`create_estimator`).

Each estimator runs on the sensor sets its traits declare (:attr:`Estimator.SENSOR_SETS`, see
:mod:`excavator_payload.data.schema`); ``fit`` takes the set of its dataset, and from then on
signal vectors are in that set's column order and a dataset of another set gets one clear line.

Input checking is done once, here, so every estimator reacts the same way. A streaming
:meth:`Estimator.step` never raises on bad data and never returns a non-finite estimate as
``ok``; every result carries the estimate's one-sigma uncertainty (``StepResult.sigma``, kg).

Outlier rejection (table-driven, so that it ports to C as three small tables)
------------------------------------------------------------------------------
Every sample passes three checks, in this order; a sample that fails one is *not used*: the
step returns the last estimate (and its sigma) with the status of the check.

1. **Readable** (``invalid_input``): every signal present and finite, time finite.
2. **Plausible** (``out_of_range``): each signal inside ``[low, high]`` of
   :func:`plausibility_limits`: ``±SensorSet.plausible_abs`` tightened by the machine file
   through :data:`MACHINE_RULES`: the angle ranges, and ``|torque| ≤``
   :data:`TORQUE_LIMIT_FACTOR` ``×`` the joint's torque limit; for a hydraulic machine file
   through :data:`HYDRAULIC_RULES`: the links' angle ranges widened by the sensor margin
   (:func:`angle_sensor_margins`), and each joint rate within :data:`RATE_LIMIT_FACTOR` ``×``
   the fastest the hydraulics turn it (pump flow, cylinder areas, moment arms; the slew's
   ``max_slew_rate``) plus the rate sensors' margin (:func:`sensor_margin`), and each
   cylinder pressure between a vacuum and :data:`PRESSURE_LIMIT_FACTOR` ``×`` the relief
   pressure, widened by the pressure sensors' (:func:`sensor_margin`). Estimators without a machine
   model (the networks) take the machine of their training data. The limits are saved with the
   model (``estimator.json``, key ``plausibility``).
3. **Statistically consistent** (``rejected_outlier``): an estimator with a noise model
   returns the normalised squared innovation of the sample from :meth:`Estimator._innovation`
   (Kalman filters: :math:`\nu^\top S^{-1}\nu` of all their measurements at the prior;
   inverse-dynamics least squares: the torque residual at the current estimate against its
   covariance; estimators without a noise model of their own, networks, the quasi-static
   map and the thesis' EKF tuning, and any estimator that believes another machine than the
   one its training data came from, *borrow* the inverse-dynamics residual on the training
   data's machine and noise preset, see :meth:`Estimator._borrows_gate`); the sample is
   rejected when it exceeds the chi-square quantile of
   :data:`GATE_PROBABILITY` (10⁻⁶ per sample: about one false rejection in 14 hours at 20 Hz).
   The filter state is not updated; the next used sample bridges the hole like a short gap
   (the filters restart their kinematic states and keep the payload; delay lines and running
   means get the rejected slots interpolated between the neighbouring samples). After
   :data:`MAX_REJECTED_DURATION` of rejections in a row the estimator does not lock itself
   out: it re-initialises (the payload may really have changed), uses the sample, reports
   ``reinitialised`` and widens its gate to the data. The gate also widens slowly
   (:data:`GATE_SCALE_RATE`) while accepted innovations run larger than the noise model says,
   so a machine model a few percent wrong costs a few rejections, not a lock-out; it never
   narrows below the chi-square quantile. ``Estimator.gating = False`` turns the gate off (to
   study the bare estimator).

The state itself is watched too: an estimator whose state is no longer finite
(:meth:`Estimator._state_finite`) or that produced a non-finite ``ok`` estimate restarts and
reports ``state_reset``.

Samples that fail checks 1 or 2 leave a hole in time, so the next used sample sees a gap: a gap in
time (more than 1.5 sample periods, or time going back) calls :meth:`Estimator._on_gap` (by
default a reset; the filters and least squares keep their payload belief over a short gap)
and is reported as ``gap``.
"""

from __future__ import annotations

import json
import math
import os
from abc import ABC, abstractmethod
from pathlib import Path
from typing import Any, ClassVar, Mapping

import numpy as np
import pandas as pd

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.units import check_payload_unit
from excavator_payload.data.schema import THESIS_SENSORS, SensorSet
from excavator_payload.errors import EstimatorError, ExcavatorPayloadError
from excavator_payload.estimators.traits import EstimatorTraits, traits_of
# The rooms the protocol is built from, re-exported so that ``estimators.base`` keeps every
# public name it had: statuses, options, the checks' tables, saving/loading and the registry.
from excavator_payload.estimators.checks import (  # noqa: F401
    ANGLE_MARGIN_SIGMAS, GATE_PROBABILITY, GATE_SCALE_HEADROOM, GATE_SCALE_RATE, HYDRAULIC_RATES,
    HYDRAULIC_RULES, MACHINE_RULES, MAX_CONSECUTIVE_REJECTIONS, MAX_REJECTED_DURATION,
    PLAUSIBLE_PAYLOAD, PRESSURE_LIMIT_FACTOR, RATE_LIMIT_FACTOR, TORQUE_LIMIT_FACTOR, VACUUM,
    angle_sensor_margins, gate_threshold, max_consecutive_rejections, plausibility_limits,
    sensor_margin)
from excavator_payload.estimators.options import Option  # noqa: F401
from excavator_payload.estimators.persistence import (  # noqa: F401
    ARRAYS_FILE, CONFIG_FILE, DIGEST_KEY, SAVE_FORMAT, SAVE_VERSION, _jsonable, _machine_from_dict,
    _saved_limits, arrays_digest, load_estimator)
from excavator_payload.estimators.registry import (  # noqa: F401
    _REGISTRY, ESTIMATOR_MODULES, create_estimator, estimator_class, estimator_names, register)
from excavator_payload.estimators.degraded import DegradedWeighing
from excavator_payload.estimators.status import Status, StepResult  # noqa: F401
from excavator_payload.model.machine import Machine, load_machine
from excavator_payload.platforms import HYDRAULIC, THESIS


#: Statuses that give no trusted estimate; when more than :data:`UNUSABLE_SHARE` of a dataset's
#: estimates have them and the inputs hold NaN or infinite values, ``estimate`` says so.
UNUSABLE_STATUSES = ("warming_up", "invalid_input", "gap", "no_data")
UNUSABLE_SHARE = 0.2
#: Share of ``out_of_range`` estimates above which ``estimate`` names the signals outside their
#: plausibility limits (a glitch now and then is the check working; this many is the data's
#: units or the machine file).
OUT_OF_RANGE_SHARE = 0.01

#: Where the plausibility limits come from, for the notes that name them.
LIMITS_SOURCE = ("the sensor set's limits, tightened by the machine file's (angle ranges; on a hydraulic "
                 "machine the joint rates through pump_flow, the cylinders and max_slew_rate, the pressures "
                 "through relief_pressure)")


def _outside_limits(dataset: Dataset, sensor_set: SensorSet, low: np.ndarray,
                    high: np.ndarray) -> tuple[list[str], int]:
    """Per signal of ``sensor_set`` with finite values outside ``[low, high]``: a phrase naming
    it, how many samples, the limits and the values seen; and how many rows hold any."""
    parts, rows = [], np.zeros(len(dataset.frame), bool)
    for i, c in enumerate(sensor_set.signals):
        if c not in dataset.frame.columns:
            continue
        v = dataset.frame[c].to_numpy(dtype=float)
        out = np.isfinite(v) & ((v < low[i]) | (v > high[i]))
        if out.any():
            rows |= out
            seen = v[np.isfinite(v)]
            parts.append(f"{c} on {int(out.sum())} samples (limits {low[i]:.4g} … {high[i]:.4g} "
                         f"{sensor_set.units.get(c, '')}, seen {seen.min():.4g} … {seen.max():.4g})")
    return parts, int(rows.sum())


class Estimator(DegradedWeighing, ABC):
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
    #: Names of the sensor sets (:data:`~excavator_payload.data.schema.SENSOR_SETS`) it runs on
    #: (from its traits).
    SENSOR_SETS: ClassVar[tuple[str, ...]] = (THESIS.sensors.name,)
    #: Its facts, declared once in :mod:`~excavator_payload.estimators.traits` (set from
    #: ``name`` when the class is defined; None for a class not in that table).
    TRAITS: ClassVar[EstimatorTraits | None] = None
    #: Whether it borrows its statistical gate (it has no noise model of its own), see
    #: :meth:`_borrows_gate`.
    BORROWS_GATE: ClassVar[bool] = False

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        traits = traits_of(vars(cls).get("name", ""))
        if traits is not None:  # the class's facts, from the one table
            cls.TRAITS = traits
            cls.SENSOR_SETS = traits.sensor_sets

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
            value = self.options[k]
            if o.type is float and not (isinstance(value, (int, float)) and not isinstance(value, bool)
                                        and math.isfinite(value)):
                raise EstimatorError(f"{self.name}: option --{k.replace('_', '-')} must be a finite "
                                     f"number, got {value!r}")
            if o.choices is not None and self.options[k] not in o.choices:
                raise EstimatorError(f"{self.name}: option --{k.replace('_', '-')} must be one of "
                                     f"{', '.join(map(str, o.choices))}, got {self.options[k]!r}")
        if machine is None and self.NEEDS_MACHINE:
            machine = "cat345c"
        self.machine: Machine | None = load_machine(machine) if machine is not None else None
        if HYDRAULIC.owns(self.machine) and not HYDRAULIC.runs(self):
            # issue 11: a hydraulic machine file only serves estimators of the machine sensor set
            raise EstimatorError(f"{self.name} does not run on the hydraulic machine "
                                 f"'{self.machine.name}' (it runs on: {', '.join(self.SENSOR_SETS)})"
                                 f"{self._refusal(HYDRAULIC.sensors.name)}")
        #: The sensor set of the data it was fitted on (the thesis set until then).
        self.sensor_set: SensorSet = THESIS_SENSORS
        self.fitted = False
        #: Doubts about the fit (too little data …), one line each; the CLI prints them.
        self.fit_warnings: list[str] = []
        # why the fit would weigh worse than the industry's 1 % (train refuses to save it unless
        # --force), and what the fit says of its own quality (printed by train)
        self.fit_refusals: list[str] = []
        self.fit_report: list[str] = []
        #: Whether the statistical gate is on (turn off only to study the bare estimator).
        self.gating = True
        #: Inverse dynamics on the training data's machine and noise, run beside an estimator
        #: without a noise model of its own only to gate its samples (None: no borrowed gate).
        self._sentinel: Estimator | None = None
        self._sentinel_source: dict | None = None
        self._last_used: tuple[float, np.ndarray] | None = None
        #: Plausibility limits per signal (see :func:`plausibility_limits`), set by fit/load.
        self.plausible_low: np.ndarray | None = None
        self.plausible_high: np.ndarray | None = None
        #: The rated payload, kg, of the machine it believes in (networks: of their training
        #: data's machine; None: unknown, no plausibility rule), see :meth:`_judged`.
        self.rated_payload: float | None = _rated(self.machine)
        self._last_time: float | None = None
        self._last_estimate = math.nan
        self._last_sigma = math.nan
        self._n_seen = 0
        self._degraded_from = math.nan  # the estimate when the degraded weighing began (_use)
        self._n_rejected = 0
        self._gate_scale = 1.0
        #: Whether the per-signal health monitor runs (machine sensor set; see :mod:`.health`).
        self.health = True
        self._health = None
        self._health_for = None
        #: The fitting data's noise per signal for the monitor (see :func:`.health.noise_reference`).
        self.health_reference: dict[str, float] | None = None

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

    def _substituting(self, on: bool) -> None:
        """Told before each sample the model weighs whether it weighs substitutes (``degraded``);
        nothing here (``calibrated``: its joint check restarts no weighing then).

        Parameters
        ----------
        on : bool
            Whether the sample holds the monitor's substitutes.
        """

    def _on_gap(self, time: float, values: np.ndarray) -> None:
        """Called when time jumps by more than 1.5 sample periods: restart by default."""
        self._reset()

    def _innovation(self, time: float, values: np.ndarray) -> tuple[float, int] | None:
        """Normalised squared innovation of a sample and its degrees of freedom, or None.

        Called before :meth:`_step` on every plausible sample; the base class rejects the
        sample when the value exceeds :func:`gate_threshold`. None means the estimator cannot
        judge the sample (yet), the default. An estimator that borrows its gate (see
        :meth:`_borrows_gate`) is judged by the sentinel instead.
        """
        return None

    def _gate_innovation(self, time: float, values: np.ndarray) -> tuple[float, int] | None:
        """The borrowed gate's innovation if there is one, else the estimator's own."""
        if self._sentinel is not None:
            return self._sentinel._innovation(time, values)
        return self._innovation(time, values)

    def _borrows_gate(self) -> bool:
        """Whether this instance gates its samples with a sentinel: inverse-dynamics least
        squares on the machine and noise preset of the training data, run beside it. For
        estimators that have no noise model of their own (networks, the quasi-static map, the
        thesis' EKF tuning), and for any estimator that believes another machine than the one
        its training data came from. Only on the thesis sensor set (torques measured)."""
        return self.BORROWS_GATE

    def _on_skip(self, time: float, values: np.ndarray) -> None:
        """Called before the sample that follows samples the gate rejected (before that sample
        is judged itself): bridge the hole like a short gap by default."""
        self._on_gap(time, values)

    def _fill_rejected(self, time: float, values: np.ndarray) -> None:
        """Called once a sample is accepted after samples the gate rejected, before it is
        used; nothing by default (see :meth:`_interpolate_rejected`)."""

    def _interpolate_rejected(self, time: float, values: np.ndarray) -> None:
        """Step the rejected samples' slots with values interpolated between the last used
        sample and this one: for estimators whose state needs evenly spaced samples (delay
        lines) or every sample (running means). The slots' results are not reported."""
        if self._last_used is None:
            return
        last_time, last = self._last_used
        period = self.sensor_set.sample_period
        missing = min(int(round((time - last_time) / period)) - 1,
                      max_consecutive_rejections(self.sensor_set))
        for k in range(1, missing + 1):
            w = k / (missing + 1)
            self._step(last_time + k * period, last + w * (values - last))

    def _estimate_sigma(self) -> float:
        """One-sigma uncertainty of the current estimate, kg (NaN: unknown)."""
        return math.nan

    def _state_finite(self) -> bool:
        """Whether the internal state is still finite (a NaN/inf state is reset by the base)."""
        return True

    # -- protocol --------------------------------------------------------------------------
    def fit(self, dataset: Dataset) -> "Estimator":
        """Fit to ``dataset`` and return ``self``.

        Parameters
        ----------
        dataset : Dataset
            Training / calibration data on a sensor set in :attr:`SENSOR_SETS`.

        Returns
        -------
        Estimator
            ``self``, fitted.
        """
        self.sensor_set = self._check_sensor_set(dataset)
        self.fit_warnings = []
        self.fit_refusals = []
        self.fit_report = []
        # noise-free simulated data hold exact constants (a rod chamber at the back pressure, no
        # slew) that look like stuck sensors; the health monitor judges signals with noise
        self.health = str(dataset.meta.get("noise")) != "none"
        # the fitting data's sample-to-sample spread: the family the health monitor's noise
        # check compares with (machine set; see .health)
        if HYDRAULIC.carries(self.sensor_set):
            from excavator_payload.estimators.health import noise_reference

            self.health_reference = noise_reference(dataset.frame, self.sensor_set.signals)
        if dataset.has_payload:  # loads in tonnes calibrate a model 1000 times off, refused for its error
            check_payload_unit(dataset.frame["payload"].to_numpy(float), self.machine or _dataset_machine(dataset),
                               f"{self.name}: training data")
        # a work cycle's payload column is the load carried: after its dump the bucket is empty
        self._fit(dataset.until_dump())
        self._sentinel_source = None
        data_machine = _dataset_machine(dataset)
        # The gate judges the data, so it uses the physics the data came from: an estimator
        # that believes another machine (EKF₃%, uncalibrated inverse dynamics) borrows it.
        believes_other = (self.machine is not None and data_machine is not None
                          and data_machine.to_dict() != self.machine.to_dict())
        if THESIS.carries(self.sensor_set) and (self._borrows_gate() or believes_other):
            machine = data_machine if data_machine is not None else self.machine
            noise = dataset.meta.get("noise")
            if machine is not None and noise:
                self._sentinel_source = {"machine": machine.to_dict(), "noise": str(noise)}
        self._build_sentinel()
        # Networks have no machine of their own: their limits come from the data's machine.
        self.rated_payload = _rated(self.machine if self.machine is not None else _dataset_machine(dataset))
        self.plausible_low, self.plausible_high = plausibility_limits(
            self.sensor_set, self.machine if self.machine is not None else _dataset_machine(dataset))
        parts, rows = _outside_limits(dataset, self.sensor_set, self.plausible_low, self.plausible_high)
        if rows > OUT_OF_RANGE_SHARE * len(dataset.frame):  # streaming will skip these samples
            self.fit_warnings.append(
                f"{self.name}: {rows} of {len(dataset.frame)} training samples lie outside the "
                f"plausibility limits, which step() and estimate() skip as out_of_range: {'; '.join(parts)}. "
                f"The limits are {LIMITS_SOURCE}: check the data's units and the machine file")
        self.fitted = True
        self.reset()
        return self

    def _build_sentinel(self) -> None:
        """(Re)create the borrowed gate from :attr:`_sentinel_source` (see :meth:`_borrows_gate`)."""
        self._sentinel = None
        if not self._sentinel_source:
            return
        # by name through the registry: the protocol does not import an estimator of its own
        sentinel = estimator_class("inverse-dynamics")(Machine.from_dict(self._sentinel_source["machine"]))
        sentinel._set_noise(self._sentinel_source["noise"])
        sentinel.sensor_set = self.sensor_set
        sentinel.fitted = True
        sentinel.reset()
        self._sentinel = sentinel

    def _refusal(self, sensor_set: str) -> str:
        """Why its traits say it does not run on ``sensor_set``, and what to use (or nothing)."""
        return self.TRAITS.refusal(sensor_set) if self.TRAITS is not None else ""

    def _check_sensor_set(self, dataset: Dataset) -> SensorSet:
        """The dataset's sensor set, if this estimator runs on it (one clear line otherwise)."""
        sensors = dataset.sensor_set
        if sensors.name not in self.SENSOR_SETS:
            raise EstimatorError(f"{self.name} does not run on the {sensors.name} sensor set "
                                 f"(it runs on: {', '.join(self.SENSOR_SETS)}){self._refusal(sensors.name)}")
        if not HYDRAULIC.carries(sensors) and HYDRAULIC.owns(self.machine):
            # calibrated fitted the thesis set's parameters of a hydraulic file: an AttributeError
            raise EstimatorError(f"{self.name}: the hydraulic machine '{self.machine.name}' goes with "
                                 f"machine-sensor-set data, these are of the {sensors.name} sensor set "
                                 "(use a 2-link machine file, e.g. --machine cat345c)")
        return sensors

    def reset(self) -> None:
        """Start a new experiment (streaming)."""
        self._last_time = None
        self._last_estimate = math.nan
        self._last_sigma = math.nan
        self._n_seen = 0
        self._degraded_from = math.nan  # the estimate when the degraded weighing began (_use)
        self._n_rejected = 0
        self._gate_scale = 1.0
        self._last_used = None
        if self._health is not None:
            self._health.reset()
        if self._sentinel is not None:
            self._sentinel.reset()
        self._reset()

    def step(self, sample: Mapping[str, float]) -> StepResult:
        """Consume one sample (a mapping with ``time`` and the signals of the sensor set).

        Never raises for bad data: the status says what happened (see the module docstring).

        Parameters
        ----------
        sample : Mapping[str, float]
            ``time`` (s) and one value per signal of the sensor set (SI units).

        Returns
        -------
        StepResult
            The estimate (kg), its status and sigma.
        """
        if not self.fitted:
            raise EstimatorError(f"{self.name}: call fit() (or load a trained model) before step()")
        try:
            time = float(sample["time"])
            values = np.array([float(sample[s]) for s in self.sensor_set.signals])
        except (KeyError, TypeError, ValueError, OverflowError, AttributeError, IndexError):
            return self._kept(Status.INVALID)
        return self.step_values(time, values)

    def _kept(self, status: Status) -> StepResult:
        """The last estimate again, with ``status`` (the sample was not used)."""
        return StepResult(self._last_estimate, status, self._last_sigma)

    def step_values(self, time: float, values: np.ndarray) -> StepResult:
        """:meth:`step` for a sample given as ``time`` and an array in ``sensor_set.signals`` order.

        Parameters
        ----------
        time : float
            Sample time, s.
        values : numpy.ndarray
            One value per signal, in ``sensor_set.signals`` order (SI units).

        Returns
        -------
        StepResult
            The estimate (kg), its status and sigma.
        """
        if not self.fitted:
            raise EstimatorError(f"{self.name}: call fit() (or load a trained model) before step()")
        try:
            time = float(time)
            values = np.asarray(values, dtype=float).reshape(-1)
        except (TypeError, ValueError, OverflowError):
            return self._kept(Status.INVALID)
        if values.shape != (len(self.sensor_set.signals),):
            return self._kept(Status.INVALID)
        if not (math.isfinite(time) and np.all(np.isfinite(values))):
            return self._kept(Status.INVALID)
        if self.plausible_low is None:
            self.plausible_low, self.plausible_high = plausibility_limits(self.sensor_set, self.machine)
        if not (np.all(values >= self.plausible_low) and np.all(values <= self.plausible_high)):
            return self._kept(Status.OUT_OF_RANGE)
        if self.health:
            if self._health_for is not self.sensor_set:
                from excavator_payload.estimators.health import for_sensor_set

                self._health = for_sensor_set(self.sensor_set, self.health_reference)
                self._health_for = self.sensor_set
            fault = self._health.step(time, values) if self._health is not None else ""
            pressures = self.degraded_pressures()
            if pressures and self._health is not None:
                cleared = self._health.cleared_joints(pressures)
                if any(cleared):  # a substitute ends: the windows that mix it with the signal
                    self._forget_joints(cleared)
            if fault:
                substituted = self._health.substitute(values, self.degraded_rates(), pressures,
                                                      self.degraded_angles(), self.degraded_tilts())
                if substituted is None:
                    # not used: the next healthy sample sees a hole in time and bridges it as a gap
                    return StepResult(self._last_estimate, Status.SENSOR_FAULT, self._last_sigma, fault)
                # degraded weighing: the named rates replaced by their angles' slopes, the named
                # pressures' joints dropped from the weighing
                dropped = self._health.named_joints(pressures) if pressures else ()
                forgotten = self._health.newly_named_joints(pressures) if pressures else ()
                if any(forgotten):  # the samples before the name carry the fault too
                    self._forget_joints(forgotten)
                if any(dropped):
                    self._drop_joints(dropped)
                    try:
                        result = self._use(time, substituted, degraded=True)
                    finally:
                        self._drop_joints((False, False, False))
                else:
                    result = self._use(time, substituted, degraded=True)
                status = Status.DEGRADED if result.status is Status.OK else result.status
                return StepResult(result.estimate, status, result.sigma,
                                  ",".join(filter(None, (fault, result.fault))))
        return self._use(time, values)

    def _use(self, time: float, values: np.ndarray, degraded: bool = False) -> StepResult:
        """The rest of :meth:`step_values` for a sample the monitor let through (``degraded``:
        with substitutes; sigma widened by :data:`.health.DEGRADED_SIGMA_FACTOR`, plus the
        estimate's move since the degraded samples began)."""
        self._substituting(degraded)
        gap = False
        if self._last_time is not None:
            dt = time - self._last_time
            if dt <= 0 or dt > 1.5 * self.sensor_set.sample_period:
                gap = True
        if gap:
            # A hole in the data: the estimator bridges it (filters restart their kinematics
            # and keep the payload) or restarts.
            self._on_gap(time, values)
            if self._sentinel is not None:
                self._sentinel._on_gap(time, values)
        elif self._n_rejected:
            self._on_skip(time, values)  # samples the gate rejected just before this one
        reinitialised = False
        try:
            nis = self._gate_innovation(time, values) if self.gating else None
        except (ArithmeticError, ValueError, np.linalg.LinAlgError):
            nis = (math.inf, 1)
        if nis is not None:
            threshold = gate_threshold(nis[1]) * self._gate_scale
            if not nis[0] <= threshold:
                self._n_rejected += 1
                if self._n_rejected <= max_consecutive_rejections(self.sensor_set):
                    if not gap:
                        self._last_time = time  # the sample's slot is used up: no gap after it
                    return self._kept(Status.REJECTED)
                # Not one glitch but data the noise model does not describe (the payload
                # changed, or the model is wrong): start again and widen the gate to it.
                self._reset()
                if self._sentinel is not None:
                    self._sentinel._reset()
                reinitialised = True
                if math.isfinite(nis[0]):
                    self._gate_scale = max(self._gate_scale, 2.0 * nis[0] / gate_threshold(nis[1]))
            elif math.isfinite(nis[0]):
                # Track how consistent the accepted data are (1 = as the noise model says):
                # a slightly wrong model widens the gate instead of rejecting good data.
                ratio = nis[0] / gate_threshold(nis[1]) * GATE_SCALE_HEADROOM
                self._gate_scale = max(1.0, (1 - GATE_SCALE_RATE) * self._gate_scale
                                       + GATE_SCALE_RATE * ratio)
        if self._n_rejected and not reinitialised:
            self._fill_rejected(time, values)
        self._n_rejected = 0
        self._last_time = time
        self._n_seen += 1
        result = self._step(time, values)
        self._last_used = (time, values)
        if self._sentinel is not None:
            self._sentinel._step(time, values)
        sigma = self._estimate_sigma()
        if degraded:
            from excavator_payload.estimators.health import DEGRADED_SIGMA_FACTOR

            sigma *= DEGRADED_SIGMA_FACTOR
            # plus the move since the degraded samples began (the load taken to hold still)
            if not math.isfinite(self._degraded_from):
                self._degraded_from = result.estimate
            elif math.isfinite(result.estimate):
                sigma += abs(result.estimate - self._degraded_from)
        else:
            self._degraded_from = math.nan
        if self.health and self._health is not None and result.status is Status.OK:
            limit = self.jump_limit()  # a jump no load makes in one sample: a sensor not yet named
            if limit is not None and math.isfinite(self._last_estimate) and math.isfinite(result.estimate) \
                    and abs(result.estimate - self._last_estimate) > limit:
                result = StepResult(result.estimate, Status.LOAD_CHANGING, result.sigma, result.fault)
        if not self._state_finite() or (result.status is Status.OK and not math.isfinite(result.estimate)):
            self._reset()
            self._last_time = None
            result, sigma = StepResult(math.nan, Status.STATE_RESET), math.nan
        elif not math.isfinite(result.estimate):
            sigma = math.nan
        self._last_estimate, self._last_sigma = result.estimate, sigma
        if reinitialised:
            return StepResult(result.estimate, Status.REINITIALISED, sigma)
        if gap and result.status is not Status.STATE_RESET:
            return StepResult(result.estimate, Status.GAP, sigma)
        return self._judged(StepResult(result.estimate, result.status, sigma, result.fault))

    def _judged(self, result: StepResult) -> StepResult:
        """``result``, its ``ok`` turned ``implausible`` when the estimate lies outside
        :data:`PLAUSIBLE_PAYLOAD` of :attr:`rated_payload`: the one place every estimator's
        streaming and batch output passes (``estimate`` steps through :meth:`step_values`)."""
        rated = self.rated_payload
        if result.status is Status.OK and rated is not None:
            low, high = PLAUSIBLE_PAYLOAD
            if not low * rated <= result.estimate <= high * rated:
                return StepResult(result.estimate, Status.IMPLAUSIBLE, result.sigma)
        return result

    def estimate_notes(self, dataset: Dataset, estimates: pd.DataFrame | None = None) -> list[str]:
        """What a user should know about estimating on ``dataset`` beyond the per-sample status
        (printed by ``estimate``); ``estimates``: what :meth:`estimate` returned on it, if at
        hand. None by default (an estimator adds its own; :meth:`all_estimate_notes` adds the
        notes every estimator shares).

        Parameters
        ----------
        dataset : Dataset
            The data estimated on.
        estimates : pandas.DataFrame or None
            What :meth:`estimate` returned on ``dataset``, if at hand.

        Returns
        -------
        list of str
            One note per line to print.
        """
        return []

    def all_estimate_notes(self, dataset: Dataset, estimates: pd.DataFrame | None = None) -> list[str]:
        """The notes ``estimate`` prints: :meth:`non_finite_notes`, :meth:`out_of_range_notes`,
        then :meth:`estimate_notes`.

        Parameters
        ----------
        dataset : Dataset
            The data estimated on.
        estimates : pandas.DataFrame or None
            What :meth:`estimate` returned on ``dataset``, if at hand.

        Returns
        -------
        list of str
            One note per line to print.
        """
        return [*self.non_finite_notes(dataset, estimates), *self.out_of_range_notes(dataset, estimates),
                *self.estimate_notes(dataset, estimates)]

    def out_of_range_notes(self, dataset: Dataset, estimates: pd.DataFrame | None = None) -> list[str]:
        """A note when more than :data:`OUT_OF_RANGE_SHARE` of the estimates are ``out_of_range``:
        which signals lie outside their plausibility limits, on how many samples, the limits and
        the values seen, and where the limits come from. The status alone left a user with a
        machine file whose pump flow was too low guessing why 72 % of the samples were skipped.

        Parameters
        ----------
        dataset : Dataset
            The data estimated on.
        estimates : pandas.DataFrame or None
            What :meth:`estimate` returned on ``dataset``; no note without it.

        Returns
        -------
        list of str
            The note, or empty.
        """
        if (estimates is None or "status" not in estimates.columns or len(estimates) == 0
                or self.plausible_low is None):
            return []
        rejected = int((estimates["status"] == Status.OUT_OF_RANGE.value).sum())
        if rejected <= OUT_OF_RANGE_SHARE * len(estimates):
            return []
        parts, _ = _outside_limits(dataset, self.sensor_set, self.plausible_low, self.plausible_high)
        if not parts:
            return []
        return [f"{rejected} of {len(estimates)} estimates ({100 * rejected / len(estimates):.0f} %) are "
                f"out_of_range: {'; '.join(parts)}. The limits are {LIMITS_SOURCE}: check the data's units "
                "and the machine file"]

    def non_finite_notes(self, dataset: Dataset, estimates: pd.DataFrame | None = None) -> list[str]:
        """A note when more than :data:`UNUSABLE_SHARE` of the estimates are ``warming_up``,
        ``invalid_input``, ``gap`` or ``no_data`` and the estimator's input columns hold NaN or
        infinite values: which columns, how many. A sparse NaN (one every 50 samples) makes an
        estimator restart its warm-up at every one and leaves a whole dataset without an
        estimate; the per-sample statuses alone do not say why.

        Parameters
        ----------
        dataset : Dataset
            The data estimated on.
        estimates : pandas.DataFrame or None
            What :meth:`estimate` returned on ``dataset``; no note without it.

        Returns
        -------
        list of str
            The note, or empty.
        """
        if estimates is None or "status" not in estimates.columns or len(estimates) == 0:
            return []
        unusable = int(estimates["status"].isin(UNUSABLE_STATUSES).sum())
        if unusable <= UNUSABLE_SHARE * len(estimates):
            return []
        columns = [c for c in self.sensor_set.signals if c in dataset.frame.columns]
        values = dataset.frame[columns].to_numpy(dtype=float)
        counts = (~np.isfinite(values)).sum(axis=0)
        bad = [(c, int(n)) for c, n in zip(columns, counts) if n]
        if not bad:
            return []
        total = len(dataset.frame)
        listed = ", ".join(f"{c} {n} (1 sample in {total / n:.0f})" if n * 2 < total else f"{c} {n}"
                           for c, n in bad)
        seen = [s for s in UNUSABLE_STATUSES if (estimates["status"] == s).any()]
        named = " or ".join(seen) if len(seen) < 3 else ", ".join(seen[:-1]) + " or " + seen[-1]
        return [f"{unusable} of {len(estimates)} estimates ({100 * unusable / len(estimates):.0f} %) are "
                f"{named}, and the data have NaN or infinite values: {listed} of "
                f"{total} samples; each one makes the estimator skip the sample and wait again: fill or "
                "interpolate them (or drop the column's bad rows) to get estimates"]

    def estimate(self, dataset: Dataset) -> pd.DataFrame:
        """Batch estimates: reset at each experiment and step through its samples.

        Parameters
        ----------
        dataset : Dataset
            Data with the columns of the fitted sensor set, rows grouped by experiment.

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
        sigma = np.full(len(dataset.frame), np.nan)
        status = np.empty(len(dataset.frame), dtype=object)
        fault = np.full(len(dataset.frame), "", dtype=object)
        times = dataset.frame["time"].to_numpy(dtype=float)
        values = dataset.signals(self.sensor_set.signals)
        exp = dataset.frame["experiment"].to_numpy()
        starts = np.flatnonzero(np.r_[True, exp[1:] != exp[:-1]])
        bounds = np.r_[starts, len(exp)]
        if len(starts) != len(pd.unique(exp)):
            raise EstimatorError("the rows are not grouped by experiment (an experiment's samples "
                                 "are split by another's); sort them by experiment and time")
        for a, b in zip(bounds[:-1], bounds[1:]):
            self.reset()
            for i in range(a, b):
                r = self.step_values(times[i], values[i])
                est[i], status[i], sigma[i], fault[i] = r.estimate, r.status.value, r.sigma, r.fault
        frame = pd.DataFrame({"experiment": exp, "time": times, "payload_estimate": est,
                              "status": status, "sigma": sigma})
        if HYDRAULIC.carries(self.sensor_set):
            frame["fault"] = fault  # "signal:kind,..." while sensor_fault (see .health)
        return frame

    # -- persistence -----------------------------------------------------------------------
    def save(self, directory: str | Path) -> Path:
        """Save to ``directory`` (created): ``estimator.json`` (readable) + ``arrays.npz``.

        Parameters
        ----------
        directory : str or Path
            Model folder (created if missing).

        Returns
        -------
        Path
            ``directory``.
        """
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
            "plausibility": ({"low": self.plausible_low.tolist(), "high": self.plausible_high.tolist()}
                             if self.plausible_low is not None else None),
            "gate_sentinel": self._sentinel_source,
            "rated_payload": self.rated_payload,
            "health": bool(self.health),
            "health_reference": self.health_reference,
            "state": _jsonable(self._config()),
        }
        arrays = self._arrays()
        config[DIGEST_KEY] = arrays_digest(arrays)  # the arrays belong to this file alone
        text = json.dumps(config, indent=2)
        # estimator.json is what makes a folder a model: it goes first and comes back last, so
        # an interrupted save never leaves old settings beside new arrays (or the reverse).
        (directory / CONFIG_FILE).unlink(missing_ok=True)
        tag = f".{os.getpid()}.tmp"  # private temporary names: concurrent saves never share one
        tmp = directory / (ARRAYS_FILE + tag + ".npz")
        np.savez(tmp, **arrays)
        tmp.replace(directory / ARRAYS_FILE)
        (directory / (CONFIG_FILE + tag)).write_text(text, encoding="utf-8")
        (directory / (CONFIG_FILE + tag)).replace(directory / CONFIG_FILE)
        return directory

    @classmethod
    def load(cls, directory: str | Path) -> "Estimator":
        """Load an estimator saved with :meth:`save` (any registered kind).

        Parameters
        ----------
        directory : str or Path
            A model folder written by :meth:`save`.

        Returns
        -------
        Estimator
            The fitted estimator (of ``cls`` when called on a subclass).
        """
        return load_estimator(directory, expected=cls if cls is not Estimator else None)

    def __repr__(self) -> str:
        machine = self.machine.name if self.machine else None
        return f"{type(self).__name__}(machine={machine!r}, fitted={self.fitted}, options={self.options})"


def _rated(machine) -> float | None:
    """A machine's rated payload, kg (None without a machine or a positive rating)."""
    rated = getattr(machine, "rated_payload", None)
    try:
        rated = float(rated)
    except (TypeError, ValueError):
        return None
    return rated if math.isfinite(rated) and rated > 0 else None


def _dataset_machine(dataset: Dataset) -> Machine | None:
    """The machine recorded in a dataset's metadata, if any and valid."""
    try:
        return dataset.machine()
    except (ExcavatorPayloadError, TypeError, ValueError):
        return None
