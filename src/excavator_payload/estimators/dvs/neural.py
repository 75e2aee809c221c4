"""The :class:`NeuralEstimator` base of every data-driven virtual sensor (DVS) network: it
reads the shared options, scales, trains (``trainbr`` or Adam), measures its typical error,
saves and restores, and streams a network at its own rate (``--decimation``, ``--smoothing``).

Conventions (MATLAB's, as the thesis used them, appendix A.3): inputs and the output are
scaled (:mod:`~excavator_payload.estimators.dvs.scaling`) on the training experiments; the first
``train_experiments`` experiments of the dataset train, the next ``validation_experiments``
validate (appendix A.3: 100 and 51).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np
import torch

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.schema import SENSOR_SETS, THESIS_SENSORS, SensorSet
from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.base import Estimator, Status, StepResult
from excavator_payload.estimators.dvs.mlp import n_weights, nguyen_widrow_init
from excavator_payload.estimators.dvs.options import (
    MAX_DECIMATION,
    MAX_WEIGHTS,
    neural_options,
    parse_delays,
    parse_hidden,
    parse_inputs,
)
from excavator_payload.estimators.dvs.scaling import Scaler
from excavator_payload.estimators.dvs.trainbr import LOG_COLUMNS, TrainingLog, train_adam, train_br
from excavator_payload.estimators.dvs.windows import block_means, experiment_arrays

TrainingProblem = tuple[Callable[[torch.Tensor], torch.Tensor], Callable[[torch.Tensor], torch.Tensor] | None]


class NeuralEstimator(Estimator):
    """Base of all DVS networks: options, scaling, training, persistence.

    Subclasses implement

    * ``_n_weights() -> int`` and optionally ``_init_weights(generator)`` (default Nguyen–Widrow
      of :meth:`_layer_sizes`);
    * ``_training_problem(inputs, targets) -> (residuals, jacobian or None)``: ``inputs`` are
      per-experiment scaled ``(T_i, k)`` arrays, ``targets`` scaled ``(T_i,)``;
      ``residuals(w)`` returns the flat target − output errors of all samples that get an
      estimate (``preparets``), ``jacobian(w)`` their ``∂e/∂w`` (None: generic forward AD);
    * ``_use_weights(w)``: pre-extract numpy matrices for streaming;
    * ``_reset_network`` and ``_network_step`` (streaming at the network's rate, see
      :class:`~excavator_payload.estimators.base.Estimator`'s ``_reset``/``_step``; the base
      feeds them every sample, or block means with ``--decimation``).

    After :meth:`fit`: ``weights`` (numpy float64), ``input_scaler``, ``output_scaler``,
    ``training_log``; ``input_names`` / ``input_index`` say which signals feed the network.

    Parameters
    ----------
    machine : Machine, str or None
        Optional: a network needs none (its plausibility limits then come from the data's machine).
    **options
        Estimator options, see the class attribute ``OPTIONS``.
    """

    NEEDS_MACHINE = False
    OPTIONS = neural_options()
    #: The inputs are resolved against the sensor set of the data (:meth:`_use_sensor_set`).
    # SENSOR_SETS: from its traits (estimators/traits.py)
    #: A network has no noise model: it borrows the gate of its training data's physics.
    BORROWS_GATE = True

    def __init__(self, machine=None, **options: Any) -> None:
        super().__init__(machine=machine, **options)
        o = self.options
        self.hidden_sizes = parse_hidden(o["hidden"])
        self.delay_list = parse_delays(o["delays"])
        # Until fit() names the sensor set, the inputs are those of the thesis set, or of the
        # first set that has them all (unknown everywhere: one clear error now, not at fit).
        error = None
        for sensors in (THESIS_SENSORS, *(s for s in SENSOR_SETS.values() if s is not THESIS_SENSORS)):
            try:
                self.input_names = parse_inputs(o["inputs"], sensors)
                self.input_index = np.array(sensors.indices(self.input_names))
                break
            except EstimatorError as exc:
                error = error or exc
        else:
            raise error
        self.decimation = int(o["decimation"])
        if not 1 <= self.decimation <= MAX_DECIMATION:
            raise EstimatorError(f"{self.name}: --decimation must be in 1 … {MAX_DECIMATION} samples, "
                                 f"got {o['decimation']}")
        self.smoothing = float(o["smoothing"])
        if not (math.isfinite(self.smoothing) and 0.0 <= self.smoothing <= 3600.0):
            raise EstimatorError(f"{self.name}: --smoothing must be 0 … 3600 s, got {o['smoothing']}")
        self._smoothed = math.nan
        self._block_sum: np.ndarray | None = None
        self._block_count = 0
        self._held: StepResult | None = None
        for key in ("epochs", "train_experiments"):
            if int(o[key]) < 1:
                raise EstimatorError(f"{self.name}: --{key.replace('_', '-')} must be at least 1")
        if int(o["validation_experiments"]) < 0 or not float(o["max_time"]) >= 0:
            raise EstimatorError(f"{self.name}: --validation-experiments and --max-time must be ≥ 0")
        if not 0 <= int(o["seed"]) < 2**63:
            raise EstimatorError(f"{self.name}: --seed must be in 0 … 2⁶³−1, got {o['seed']}")
        if not (math.isfinite(float(o["learning_rate"])) and float(o["learning_rate"]) > 0):
            raise EstimatorError(f"{self.name}: --learning-rate must be a positive number, got "
                                 f"{o['learning_rate']}")
        if int(o["epochs"]) > 10**7 or int(o["validation_patience"]) < 0:
            raise EstimatorError(f"{self.name}: --epochs must be at most 10⁷ and "
                                 "--validation-patience ≥ 0")
        self.weights: np.ndarray | None = None
        self.input_scaler: Scaler | None = None
        self.output_scaler: Scaler | None = None
        self.training_log: TrainingLog | None = None
        #: RMS error (kg) on the validation (else training) experiments: the ``sigma`` of a step.
        self.residual_std = math.nan
        self.residual_source = ""

    def _check_size(self) -> None:
        """One clear line instead of an attempt to allocate gigabytes."""
        n, limit = self._n_weights(), MAX_WEIGHTS[self.options["trainer"]]
        if n > limit:
            raise EstimatorError(f"{self.name}: {n} weights is more than the {limit} that "
                                 f"--trainer {self.options['trainer']} can train here; use smaller "
                                 "--hidden / --delays (the thesis' nets have a few hundred)")

    def _use_sensor_set(self, sensors: SensorSet) -> None:
        """Resolve ``--inputs`` against the signals of ``sensors`` (the data's sensor set)."""
        names = parse_inputs(self.options["inputs"], sensors)
        changed = names != self.input_names
        self.input_names = names
        self.input_index = np.array(sensors.indices(names))
        if changed:
            self._inputs_changed()

    def _inputs_changed(self) -> None:
        """Hook: the number of inputs changed (subclasses rebuild what depends on it)."""


    # -- hooks -----------------------------------------------------------------------------
    @property
    def n_inputs(self) -> int:
        return len(self.input_names)

    def _layer_sizes(self) -> list[int]:
        raise NotImplementedError

    def _n_weights(self) -> int:
        return n_weights(self._layer_sizes())

    def _init_weights(self, generator: torch.Generator) -> torch.Tensor:
        return nguyen_widrow_init(self._layer_sizes(), generator)

    def _training_problem(self, inputs: list[np.ndarray], targets: list[np.ndarray]) -> TrainingProblem:
        raise NotImplementedError

    def _use_weights(self, w: np.ndarray) -> None:
        raise NotImplementedError

    # -- training --------------------------------------------------------------------------
    def split_experiments(self, dataset: Dataset) -> tuple[Dataset, Dataset | None]:
        """Training and validation parts (thesis A.3: the first 100, the next 51).

        Parameters
        ----------
        dataset : Dataset
            The training data.

        Returns
        -------
        tuple of (Dataset, Dataset or None)
            Training part and validation part (None when there is none).
        """
        n_train = int(self.options["train_experiments"])
        n_val = int(self.options["validation_experiments"])
        n = dataset.n_experiments
        if n < n_train:
            raise EstimatorError(f"{self.name}: the dataset has {n} experiments but "
                                 f"--train-experiments is {n_train}; pass --train-experiments {n} "
                                 f"(or fewer) or use a bigger dataset")
        n_val = min(n_val, n - n_train)
        ids = list(dataset.experiment_ids)
        train = dataset.subset(ids[:n_train])
        val = dataset.subset(ids[n_train:n_train + n_val]) if n_val > 0 else None
        return train, val

    def _scaled(self, dataset: Dataset) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """Scaled per-experiment inputs and targets at the network's rate.

        With ``--decimation K`` the inputs are the means of blocks of K samples and the target
        of a block is the payload at its last sample, exactly what :meth:`_step` feeds the
        network while streaming (the mean is taken of the raw values, then scaled, as there).
        """
        xs, ys = experiment_arrays(dataset, self.input_names)
        bad = [i for i, x in enumerate(xs) if not np.all(np.isfinite(x))]
        if bad or not all(np.all(np.isfinite(y)) for y in ys):
            raise EstimatorError(f"{self.name}: training data contain NaN or infinite values "
                                 f"(e.g. experiment row block {bad[:3]}); clean them first")
        K = self.decimation
        if K > 1:
            xs = [block_means(x, K) for x in xs]
            ys = [y[K - 1::K][:len(x)] for x, y in zip(xs, ys)]
        return ([self.input_scaler.transform(x) for x in xs],
                [self.output_scaler.transform(y[:, None])[:, 0] for y in ys])

    def _fit(self, dataset: Dataset) -> None:
        self._use_sensor_set(self.sensor_set)
        self._check_size()  # after the inputs are known: their number sizes the first layer
        train, val = self.split_experiments(dataset)
        o = self.options
        scaling = o["scaling"]
        x_train = train.signals(self.input_names)
        self.input_scaler = Scaler(scaling).fit(x_train)
        self.output_scaler = Scaler(scaling).fit(train.frame["payload"].to_numpy(float)[:, None])
        inputs, targets = self._scaled(train)
        residuals, jacobian = self._training_problem(inputs, targets)
        validation = None
        if val is not None:
            v_inputs, v_targets = self._scaled(val)
            v_residuals, _ = self._training_problem(v_inputs, v_targets)

            def validation_error(w):
                e = v_residuals(w)
                return float(e @ e)

            validation = validation_error

        generator = torch.Generator().manual_seed(int(o["seed"]))
        w0 = self._init_weights(generator)
        max_time = float(o["max_time"]) or None
        desc = f"{self.name} {o['trainer']}"
        if o["trainer"] == "trainbr":
            w, log = train_br(residuals, w0, epochs=int(o["epochs"]), validation=validation,
                              progress=bool(o["progress"]), description=desc, jacobian=jacobian,
                              max_seconds=max_time, best_validation=bool(o["best_validation"]),
                              validation_patience=int(o["validation_patience"]))
        else:
            w, log = train_adam(residuals, w0, epochs=int(o["epochs"]), lr=float(o["learning_rate"]),
                                validation=validation, progress=bool(o["progress"]),
                                description=desc, max_seconds=max_time,
                                best_validation=bool(o["best_validation"]),
                                validation_patience=int(o["validation_patience"]))
        weights = w.detach().numpy().astype(np.float64)
        if not np.all(np.isfinite(weights)):
            raise EstimatorError(f"{self.name}: training diverged ({log.stop_reason}); try "
                                 f"--trainer trainbr or a smaller --learning-rate")
        self.training_log = log
        self.weights = weights
        self._use_weights(weights)
        if o["progress"]:
            from rich.console import Console

            Console(stderr=True).print(
                f"{self.name}: {log.trainer} stopped after {log.epoch[-1]} epochs ({log.stop_reason}) "
                f"in {log.seconds:.1f} s; training SSE {log.sse[-1]:.4g} over {log.n_errors} targets "
                f"(scaled), effective parameters γ {log.gamma[-1]:.1f} of {log.n_parameters}, "
                + (f"validation SSE {log.returned_validation_sse:.4g}"
                   if math.isfinite(log.returned_validation_sse) else
                   "no validation experiments (every experiment was used for training, so "
                   "nothing guards against overfitting: give more experiments than "
                   "--train-experiments)")
                + (f" (weights of epoch {log.best_epoch}, the lowest validation error)"
                   if log.best_epoch >= 0 else ""))

    def fit(self, dataset: Dataset) -> "NeuralEstimator":
        """Train (see :meth:`_fit`), then measure the spread of the net's errors for ``sigma``.

        Parameters
        ----------
        dataset : Dataset
            Training data with the true ``payload``, kg.

        Returns
        -------
        NeuralEstimator
            ``self``, trained.
        """
        super().fit(dataset)
        train, val = self.split_experiments(dataset)
        judged = val if val is not None else train
        frame = self.estimate(judged)
        truth = judged.frame["payload"].to_numpy(float)
        ok = (frame["status"] == "ok").to_numpy()
        errors = frame["payload_estimate"].to_numpy(float)[ok] - truth[ok]
        self.residual_std = float(np.sqrt(np.mean(errors**2))) if errors.size else math.nan
        self.residual_source = "validation" if val is not None else "training"
        self.reset()
        return self

    # -- streaming at the network's rate ----------------------------------------------------
    def _reset(self) -> None:
        self._smoothed = math.nan
        self._block_sum = None
        self._block_count = 0
        self._held = None
        self._reset_network()

    def _step(self, time: float, values: np.ndarray) -> StepResult:
        """Feed the network every sample, or with ``--decimation K`` the mean of each block of
        K samples (counted from the start of the experiment, as in training) and hold its
        last estimate in between."""
        K = self.decimation
        if K == 1:
            result = self._network_step(time, values)
            return result if self.smoothing == 0.0 else self._smooth(result)
        if self._block_sum is None:
            self._block_sum = np.array(values, dtype=float)
        else:
            self._block_sum += values
        self._block_count += 1
        if self._block_count == K:
            mean = self._block_sum / K
            self._block_sum, self._block_count = None, 0
            result = self._network_step(time, mean)
            self._held = result if self.smoothing == 0.0 else self._smooth(result)
        return self._held if self._held is not None else StepResult(math.nan, Status.WARMING_UP)

    def _smooth(self, result: StepResult) -> StepResult:
        r"""First-order low-pass of the estimate at the network's rate,
        :math:`\hat m_k = \hat m_{k-1} + (1 - e^{-\Delta t/\tau})(y_k - \hat m_{k-1})`, started
        at the first estimate of the experiment (``--smoothing`` :math:`\tau`)."""
        y = result.estimate
        if result.status is not Status.OK or not math.isfinite(y):
            return result
        if math.isnan(self._smoothed):
            self._smoothed = y
        else:
            period = self.decimation * self.sensor_set.sample_period
            self._smoothed += -math.expm1(-period / self.smoothing) * (y - self._smoothed)
        return StepResult(self._smoothed, result.status, result.sigma)

    def _reset_network(self) -> None:
        """Forget the network's delay lines and states (subclasses)."""
        raise NotImplementedError

    def _network_step(self, time: float, values: np.ndarray) -> StepResult:
        """One sample at the network's rate (``values`` in sensor-set order, raw)."""
        raise NotImplementedError

    def _on_skip(self, time: float, values: np.ndarray) -> None:
        """Nothing before the next sample is judged; see :meth:`_fill_rejected`."""

    def _fill_rejected(self, time: float, values: np.ndarray) -> None:
        """Samples the gate rejected: the delay lines get values interpolated between their
        neighbours in their place (a net's window must stay evenly spaced), not a restart."""
        self._interpolate_rejected(time, values)

    def _estimate_sigma(self) -> float:
        """RMS error of the net on its validation experiments (training experiments when it had
        none: then optimistic), kg; a net has no uncertainty of its own, this is its typical
        error on data like its training data."""
        return self.residual_std

    # -- persistence -----------------------------------------------------------------------
    def _config(self) -> dict:
        log = self.training_log
        return {"input_names": list(self.input_names), "n_weights": int(self.weights.size),
                "training": log.summary() if log is not None else None,
                "residual_std": self.residual_std if math.isfinite(self.residual_std) else None,
                "residual_source": self.residual_source}

    def _arrays(self) -> dict[str, np.ndarray]:
        arrays = {"weights": self.weights, **self.input_scaler.to_arrays("input"),
                  **self.output_scaler.to_arrays("output")}
        if self.training_log is not None:
            frame = self.training_log.to_frame()
            for c in LOG_COLUMNS:
                arrays[f"log_{c}"] = frame[c].to_numpy(dtype=float)
        return arrays

    def _restore(self, config: dict, arrays: Mapping[str, np.ndarray]) -> None:
        self._use_sensor_set(self.sensor_set)
        scaling = self.options["scaling"]
        weights = np.asarray(arrays["weights"], dtype=np.float64)
        if weights.shape != (self._n_weights(),):
            raise EstimatorError(f"{self.name}: saved weights have shape {weights.shape}, the options "
                                 f"need ({self._n_weights()},)")
        self.input_scaler = Scaler.from_arrays(arrays, "input", scaling)
        self.output_scaler = Scaler.from_arrays(arrays, "output", scaling)
        if self.input_scaler.center.shape != (self.n_inputs,):
            raise EstimatorError(f"{self.name}: saved input scaling does not match the inputs")
        if not (np.all(np.isfinite(self.input_scaler.center)) and np.all(np.isfinite(self.input_scaler.gain))
                and np.all(np.isfinite(self.output_scaler.center))
                and np.all(np.isfinite(self.output_scaler.gain))):
            raise EstimatorError(f"{self.name}: saved scaling is not finite")
        self.weights = weights
        spread = config.get("residual_std")
        self.residual_std = float(spread) if isinstance(spread, (int, float)) and spread >= 0 else math.nan
        self.residual_source = str(config.get("residual_source", ""))
        summary = config.get("training") or {}
        if "log_epoch" in arrays:
            import pandas as pd

            frame = pd.DataFrame({c: arrays[f"log_{c}"] for c in LOG_COLUMNS if f"log_{c}" in arrays})
            self.training_log = TrainingLog.from_frame(
                frame, summary.get("stop_reason", ""), summary.get("seconds", 0.0),
                summary.get("n_errors", 0), summary.get("n_parameters", 0), summary.get("trainer", ""),
                summary.get("best_epoch", -1))
        self._use_weights(weights)

    def save(self, directory: str | Path) -> Path:
        """Save (see :meth:`Estimator.save`) plus ``training_log.csv`` and ``training.png``.

        Parameters
        ----------
        directory : str or Path
            Model folder (created if missing).

        Returns
        -------
        Path
            ``directory``.
        """
        directory = super().save(directory)
        if self.training_log is not None:
            tmp = directory / "training_log.csv.tmp"
            self.training_log.to_frame().to_csv(tmp, index=False)
            tmp.replace(directory / "training_log.csv")
            self.training_log.plot(directory / "training.png")
        return directory

    # -- helpers for subclasses --------------------------------------------------------------
    def _scale_input(self, values: np.ndarray) -> np.ndarray:
        """The network's input vector from a sample in sensor-set order (scaled)."""
        return (values[self.input_index] - self.input_scaler.center) * self.input_scaler.gain

    def _unscale_output(self, y: float) -> float:
        return float(y / self.output_scaler.gain[0] + self.output_scaler.center[0])


__all__ = ["TrainingProblem", "NeuralEstimator"]
