r"""Extended Kalman filter with the payload as a fifth state (thesis §6.1, appendices A.4–A.5).

Model and tunings: see :mod:`excavator_payload.estimators.classical._kalman`. Every step (one
20 Hz sample: measurements :math:`y_k`, torque input :math:`u_k`) is an update followed by a
prediction.

Update (Joseph form, so P stays symmetric positive semi-definite), for the angle/rate group
:math:`(h^{(1)}, R^{(1)})` and then, ``consistent`` tuning only, the torque group
:math:`(h^{(2)}, R^{(2)}_k)` linearised at the result of the first:

.. math::

    \nu &= y_k - h(x), \qquad H = \partial h/\partial x\,|_{x} \\
    S &= H P H^\top + R, \qquad K = P H^\top S^{-1} \\
    x &\leftarrow x + K\nu, \qquad
    P \leftarrow (I - KH) P (I - KH)^\top + K R K^\top

Prediction (Euler step of the arm model with the measured torques,
:math:`F = \partial f_d/\partial x`, :math:`G = \partial f_d/\partial u` from CasADi)

.. math::

    \bar x_{k+1} &= f_d(\hat x_k, u_k) + D_k (\tau^{meas}_k - h^{(2)}(\hat x_k)) \\
    \bar P_{k+1} &= (F - D_k H^{(2)}) P_k (F - D_k H^{(2)})^\top + G \Sigma_\tau G^\top + Q
                    - D_k S_k^\top

with :math:`S_k = -G\Sigma_\tau` and :math:`D_k = S_k (R^{(2)}_k)^{-1}` the decorrelation of the
torque noise shared by input and torque measurement (``consistent`` only; for ``thesis``
:math:`D = 0`, :math:`\Sigma_\tau = 0` and :math:`Q` is the thesis' constant).

The whole step is one CasADi function (``_kalman.ekf_step_function``), compiled to C when a C
compiler is available (≈5 µs instead of ≈60 µs in CasADi's virtual machine).

The estimate is the payload of :math:`\hat x_k`. It carries status ``warming_up`` during the
first ``warmup_samples`` samples and, for the ``consistent`` tuning (whose P is calibrated),
while the payload's posterior standard deviation exceeds ``converged_std`` kg. A step whose
result is not finite is discarded (state kept) and reported ``invalid_input``. A time gap up
to ``max_gap`` seconds keeps the payload estimate (see :meth:`KalmanEstimatorBase._on_gap`).

The filters run on the thesis sensor set only. On the machine sensor set (pressures and IMUs)
they weighed far outside 1 % of rated with a σ that did not cover their error, so they were
taken out of that set's roster (issue 28, docs/findings/machine-filters.md); ``calibrated`` is
the estimator there. :attr:`KalmanEstimatorBase.payload_std` is the payload's posterior
standard deviation.
"""

from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from excavator_payload.data.dataset import Dataset
from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.base import Estimator, Option, Status, StepResult, register
from excavator_payload.estimators.classical import _kalman as kf

COMMON_OPTIONS = {
    "tuning": Option(str, "consistent", "covariances: 'thesis' (§6.1 Q, R, P0, x0) or 'consistent' "
                     "(from the training data's sensor noise preset)", ("thesis", "consistent")),
    "payload_walk": Option(float, 0.2, "consistent: payload random walk, kg/√s (how fast the filter "
                           "may believe the payload changes)"),
    "noise": Option(str, "", "consistent: noise preset to tune for (default: the training dataset's)",
                    ("", "thesis", "none", "field")),
    "warmup_samples": Option(int, 5, "samples reported as warming_up after a (re)start"),
    "converged_std": Option(float, 50.0, "consistent: warming_up until the payload's posterior "
                            "standard deviation is below this, kg"),
    # the machine sensor set's low-speed rule; no effect since the filters left that set
    # (issue 28), kept so that the models saved with it load
    "low_speed": Option(str, "skip", "no effect (it served the machine sensor set, which the Kalman "
                        "filters no longer run on)", ("skip", "downweight")),
    "max_gap": Option(float, 1.0, "a time gap up to this long (s) keeps the payload estimate "
                      "(angles and rates restart from the new sample); a longer one restarts the filter"),
}


class KalmanEstimatorBase(Estimator):
    """What EKF and UKF share: options, fitting (tuning), status, persistence.

    Parameters
    ----------
    machine : Machine, str or None
        The machine model the estimator believes in (preset name or file; None: ``cat345c``).
    **options
        Estimator options, see the class attribute ``OPTIONS``.
    """

    OPTIONS = COMMON_OPTIONS
    NEEDS_MACHINE = True
    # SENSOR_SETS: from its traits (estimators/traits.py): the thesis set only

    def __init__(self, machine=None, **options):
        super().__init__(machine, **options)
        for key in ("payload_walk", "warmup_samples", "max_gap"):
            if not self.options[key] >= 0:
                raise EstimatorError(f"{self.name}: --{key.replace('_', '-')} must not be negative, "
                                     f"got {self.options[key]}")
        if not self.options["converged_std"] > 0:
            raise EstimatorError(f"{self.name}: --converged-std must be positive")
        self.tuning: kf.Tuning | None = None
        self._x: np.ndarray | None = None
        self._P: np.ndarray | None = None
        self._n_filtered = 0
        self._posterior_std = math.nan
        self._bounds = kf.payload_bounds(self.machine)

    # -- fitting ---------------------------------------------------------------------------
    def _fit(self, dataset: Dataset) -> None:
        if self.options["tuning"] == "thesis":
            self.tuning = kf.thesis_tuning(self.machine)
        else:
            noise = kf.dataset_noise(dataset, self.options["noise"])
            angle_trunc, rate_trunc = kf.euler_truncation_std(dataset)
            self.tuning = kf.consistent_tuning(self.machine, noise, angle_trunc, rate_trunc,
                                               self.options["payload_walk"])
        self._build_gate()

    def _reset(self) -> None:
        self._x = None
        self._P = None
        self._n_filtered = 0  # samples since the filter (re)started (a gap restarts it too)
        self._posterior_std = math.nan

    def _on_gap(self, time: float, values: np.ndarray) -> None:
        """Bridge a short gap (missing or rejected samples); restart after a long one.

        Without the torques of the missing samples the arm's motion cannot be predicted, but
        the payload does not need to be: the kinematic states restart from the new sample
        (broad prior, no correlation), the payload keeps its estimate and its variance grows by
        the random walk over the gap, :math:`P_{mm} \\mathrel{+}= \\sigma_w^2 \\Delta t`.
        """
        dt = time - self._last_time if self._last_time is not None else math.inf
        if self._x is None or not 0.0 < dt <= self.options["max_gap"]:
            self._reset()
            return
        x0, P0 = kf.initial_state(self.tuning, values)
        x0[:4] = values[kf.MEASURED]  # mid-experiment the sample is the best start (thesis tuning too)
        payload, payload_var = self._x[kf.PAYLOAD], self._P[kf.PAYLOAD, kf.PAYLOAD]
        self._x = x0
        self._x[kf.PAYLOAD] = payload
        self._P = P0
        self._P[kf.PAYLOAD, kf.PAYLOAD] = payload_var + self.tuning.Q[kf.PAYLOAD, kf.PAYLOAD] * dt / kf.TS

    # -- status ----------------------------------------------------------------------------
    def _result(self) -> StepResult:
        """The estimate of the posterior just computed, with its status."""
        self._n_filtered += 1
        self._posterior_std = math.sqrt(max(self._P[kf.PAYLOAD, kf.PAYLOAD], 0.0))
        estimate = float(self._x[kf.PAYLOAD])
        if self._n_filtered <= self.options["warmup_samples"]:
            return StepResult(estimate, Status.WARMING_UP)
        if self.tuning.torque_channel and self._posterior_std > self.options["converged_std"]:
            return StepResult(estimate, Status.WARMING_UP)
        return StepResult(estimate, Status.OK)

    def _accept(self, x: np.ndarray, P: np.ndarray) -> bool:
        """Keep a new state only if it is finite with a non-negative diagonal covariance."""
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(P)) and np.all(np.diag(P) >= 0)):
            return False
        x[kf.PAYLOAD] = min(max(x[kf.PAYLOAD], self._bounds[0]), self._bounds[1])
        return True

    # -- gate, uncertainty, state watch (see estimators.base) --------------------------------
    def _innovation(self, time: float, values: np.ndarray) -> tuple[float, int] | None:
        r"""Normalised innovation squared of all the filter's measurements at the prior.

        :math:`\nu^\top S^{-1}\nu` with :math:`\nu = y_k - h(\bar x_k)` and
        :math:`S = H\bar P H^\top + R` (angles and rates; with the ``consistent`` tuning also the
        torques, :math:`R^{(2)} = \Sigma_\tau + M\Sigma_a M^\top`); chi-square with 4 or 6
        degrees of freedom for a sample the noise model describes.
        """
        if self._x is None:
            return None
        nis = float(self._gate.evaluate(self._x, self._P, values[self._gate_y], values[kf.ACCELS])[0])
        return nis, len(self._gate_y)

    def _borrows_gate(self) -> bool:
        # Q = 10⁶·I makes S enormous and the torques are inputs, not measurements: the thesis
        # tuning has no usable noise model, so it borrows the gate of inverse dynamics.
        return self.options["tuning"] == "thesis"

    def _estimate_sigma(self) -> float:
        """Square root of the payload's posterior variance, kg (thesis tuning: not calibrated)."""
        return self._posterior_std

    def _state_finite(self) -> bool:
        return self._x is None or bool(np.all(np.isfinite(self._x)) and np.all(np.isfinite(self._P)))

    @property
    def payload_std(self) -> float:
        """The filter's posterior standard deviation of the payload (kg) at the last sample."""
        return self._posterior_std

    # -- persistence -----------------------------------------------------------------------
    #: Compiled functions and their buffers: rebuilt, not pickled (multiprocessing, deepcopy).
    _RUNTIME = ("_step_function", "_sigma", "_terms", "_gate")

    def __getstate__(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k not in self._RUNTIME}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._build_runtime()

    def _build_runtime(self) -> None:
        """(Re)create the compiled functions the filter steps with."""
        self._build_gate()

    def _build_gate(self) -> None:
        """The compiled statistical gate, with its constant covariances written once."""
        tuning = self.tuning
        if tuning is None:
            return
        self._gate = kf.BufferedFunction(kf.gate_function(self.machine, self.options["tuning"] == "thesis",
                                                          tuning.torque_channel))
        for i, value in enumerate((tuning.R, tuning.torque_cov, tuning.accel_cov)):
            self._gate.set_input(4 + i, value)
        self._gate_y = np.array(kf.MEASURED + kf.TORQUES if tuning.torque_channel else kf.MEASURED)

    def _config(self) -> dict:
        return self.tuning.config()

    def _arrays(self) -> dict[str, np.ndarray]:
        return self.tuning.arrays()

    def _restore(self, config: dict, arrays: Mapping[str, np.ndarray]) -> None:
        self.tuning = kf.Tuning.restore(config, arrays)
        if self.tuning.name != self.options["tuning"]:
            raise EstimatorError(f"saved {self.name} is inconsistent: option --tuning "
                                 f"{self.options['tuning']} but covariances of '{self.tuning.name}'")
        self._build_gate()


@register
class ExtendedKalmanFilter(KalmanEstimatorBase):
    """EKF on x = [q1, q2, q̇1, q̇2, payload]; Jacobians from the symbolic arm model.

    Parameters
    ----------
    machine : Machine or str
        The model the filter believes in (``cat345c-1pct``/``-3pct`` give the thesis' EKF₁%/EKF₃%).
    tuning : {'consistent', 'thesis'}
    payload_walk, noise, warmup_samples, converged_std, max_gap : see ``OPTIONS``.

    Examples
    --------
    >>> ekf = ExtendedKalmanFilter("cat345c", tuning="consistent").fit(train)   # doctest: +SKIP
    >>> ekf.estimate(test)                                                     # doctest: +SKIP
    """

    name = "ekf"

    def _fit(self, dataset: Dataset) -> None:
        super()._fit(dataset)
        self._build_runtime()

    def _restore(self, config: dict, arrays: Mapping[str, np.ndarray]) -> None:
        super()._restore(config, arrays)
        self._build_runtime()

    def _build_runtime(self) -> None:
        tuning = self.tuning
        if tuning is None:
            return
        self._step_function = kf.BufferedFunction(kf.ekf_step_function(
            self.machine, self.options["tuning"] == "thesis", tuning.torque_channel))
        # Constant inputs (Q, R, Σ_τ, Σ_a) are written into the buffers once, not every step.
        for i, value in enumerate((tuning.Q, tuning.R, tuning.torque_cov, tuning.accel_cov)):
            self._step_function.set_input(5 + i, value)
        self._y_index = np.array(kf.MEASURED + kf.TORQUES if tuning.torque_channel else kf.MEASURED)
        self._build_gate()

    # Positions in the packed step output [x_post, P_post, x_next, P_next].
    _POST_DIAG = np.array([5 + 6 * i for i in range(5)])
    _NEXT_DIAG = _POST_DIAG + 30

    def _step(self, time: float, values: np.ndarray) -> StepResult:
        if self._x is None:
            self._x, self._P = kf.initial_state(self.tuning, values)
        packed = self._step_function.evaluate(self._x, self._P, values[self._y_index],
                                              values[kf.TORQUES], values[kf.ACCELS])
        # One finiteness check for everything; a bad posterior discards the sample, a bad
        # prediction keeps the posterior as the next prior (one missed step, not a lost filter).
        if not (np.isfinite(packed).all() and (packed[self._POST_DIAG] >= 0).all()):
            return StepResult(self._last_estimate, Status.INVALID)
        low, high = self._bounds
        packed[4] = min(max(packed[4], low), high)
        self._x, self._P = packed[0:5], packed[5:30].reshape(5, 5)  # P symmetric: order irrelevant
        result = self._result()
        if (packed[self._NEXT_DIAG] >= 0).all():
            packed[34] = min(max(packed[34], low), high)
            self._x, self._P = packed[30:35], packed[35:60].reshape(5, 5)
        return result
