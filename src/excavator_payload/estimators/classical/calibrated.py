r"""Calibrated inverse-dynamics estimator: identify the arm's base parameters, then weigh.

A machine file is never exactly right (the thesis' ``cat345c-3pct`` is 3 % off, which biases a
model-based estimator by up to a few hundred kg). The arm's dynamics are *linear* in a small set
of lumped parameters (see :mod:`~excavator_payload.estimators.classical.inverse_dynamics`), and
so is the payload's contribution:

.. math::

    \tau_k = Y_k\,\theta_0 + m_e\,Y_{k,1:5}\,\theta_1 + \varepsilon_k
           = \underbrace{[\,Y_k \;\; m_e Y_{k,1:5}\,]}_{\Phi_k}
             \begin{bmatrix}\theta_0\\ \theta_1\end{bmatrix} + \varepsilon_k

with :math:`\theta_0` the seven empty-arm base parameters (inertias, first moments, viscous
friction), :math:`\theta_1` the five payload parameters (:math:`l_1^2, l_2^2, l_1l_2, gl_1,
gl_2`) and :math:`m_e` the *known* payload of calibration experiment :math:`e`. Calibration is
Bayesian weighted least squares on the relative deviation :math:`\delta` from the machine file's
parameters :math:`\theta_p` (:math:`\theta = \theta_p \odot (1 + \delta)`, prior
:math:`\delta \sim \mathcal N(0, s^2 I)`, ``--prior-std s``):

.. math::

    \bar\Phi_k &= \Phi_k \operatorname{diag}(\theta_p), \qquad
    W_k = (\Sigma_\tau + J_k\Sigma_x J_k^\top)^{-1} \\
    H &= \sum_k \bar\Phi_k^\top W_k \bar\Phi_k + s^{-2} I, \qquad
    \hat\delta = H^{-1}\sum_k \bar\Phi_k^\top W_k(\tau_k - \Phi_k\theta_p), \qquad
    \operatorname{cov}\hat\theta = \operatorname{diag}(\theta_p) H^{-1}\operatorname{diag}(\theta_p).

The prior matters only for what the data cannot separate: with a single calibration experiment
(one payload) only :math:`\theta_0 + m_e\theta_1` is identifiable, and the prior decides the
split; two or more payloads identify all twelve parameters. The payload is then estimated exactly
as :class:`InverseDynamicsEstimator` does, with the identified :math:`(\theta_0, \theta_1)`.

:func:`calibration_curve` measures accuracy against the number of calibration experiments.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np
import pandas as pd

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.schema import SIGNALS
from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.base import Option, register
from excavator_payload.estimators.classical.machine_calibration.settings import (
    BALANCE_CHOICES, IMU_LEAK_CHOICES, IMU_NUISANCE_CHOICES, NEW_LOAD_CHOICES, OUTSIDE_CALIBRATION_CHOICES, WAIT_FOR_BOOM_CHOICES)
from excavator_payload.estimators.classical.inverse_dynamics import (
    BASE_PARAMETER_NAMES,
    PAYLOAD_PARAMETER_NAMES,
    InverseDynamicsEstimator,
    TorqueKernel,
    base_parameters,
    base_regressor,
    residual_covariance,
    sensor_variances,
    torque_jacobian,
)
from excavator_payload.estimators.classical.pressure_regression import PressureKernel
from excavator_payload.model.machine import Machine, load_machine
from excavator_payload.platforms import HYDRAULIC, THESIS

#: Judged samples: index ≥ 81 of each experiment (the last second, as the thesis judges).
FIRST_JUDGED_SAMPLE = 81


def identify_base_parameters(dataset: Dataset, prior: Machine, variances: np.ndarray,
                             prior_std: float = 0.1, weighting: str = "full"):
    r"""Bayesian weighted least squares of :math:`(\theta_0, \theta_1)` from known-payload data.

    Parameters
    ----------
    dataset : Dataset
        Calibration experiments; the ``payload`` column is the known payload.
    prior : Machine
        The (possibly wrong) machine file: prior mean :math:`\theta_p`.
    variances : ndarray (8,)
        Sensor noise variances in :data:`SIGNALS` order (weights :math:`W_k`).
    prior_std : float
        Relative prior standard deviation :math:`s` of every parameter.
    weighting : {'full', 'diagonal', 'torque'}
        Residual covariance behind :math:`W_k` (see
        :func:`~excavator_payload.estimators.classical.inverse_dynamics.residual_covariance`):
        torque noise plus the kinematic noise through the model, its diagonal, or the torque
        noise alone.

    Returns
    -------
    theta_empty (7,), theta_payload (5,), covariance (12, 12)
    """
    values = dataset.signals(SIGNALS)
    payload = dataset.frame["payload"].to_numpy(dtype=float)
    ok = np.all(np.isfinite(values), axis=1) & np.isfinite(payload)
    lo1, hi1 = prior.boom_angle_range
    lo2, hi2 = prior.dipper_angle_range
    ok &= (values[:, 0] >= lo1) & (values[:, 0] <= hi1) & (values[:, 3] >= lo2) & (values[:, 3] <= hi2)
    if ok.sum() < 12:
        raise EstimatorError("calibration needs at least 12 valid samples with known payloads, "
                             f"the data have {int(ok.sum())}")
    values, payload = values[ok], payload[ok]
    q, qd, qdd = values[:, [0, 3]], values[:, [1, 4]], values[:, [2, 5]]
    tau = values[:, 6:8]
    theta0_p, theta1_p = base_parameters(prior)
    theta_p = np.r_[theta0_p, theta1_p]

    Y = base_regressor(q, qd, qdd)                                       # (n, 2, 7)
    Phi = np.concatenate([Y, payload[:, None, None] * Y[..., :5]], -1)  # (n, 2, 12)
    Phi_bar = Phi * theta_p                                              # columns scaled
    theta_eff = theta0_p + np.c_[payload[:, None] * theta1_p, np.zeros((len(payload), 2))]
    R = residual_covariance(torque_jacobian(q, qd, qdd, theta_eff), variances[:6], variances[6:],
                            weighting)
    W = np.linalg.inv(R)
    residual = tau - Phi @ theta_p
    H = np.einsum("nia,nij,njb->ab", Phi_bar, W, Phi_bar) + np.eye(12) / prior_std**2
    rhs = np.einsum("nia,nij,nj->a", Phi_bar, W, residual)
    delta = np.linalg.solve(H, rhs)
    theta = theta_p * (1.0 + delta)
    cov = np.linalg.inv(H) * np.outer(theta_p, theta_p)
    return theta[:7], theta[7:], cov


class IdentifiedTorqueKernel(TorqueKernel):
    """The thesis' sensor set: :class:`TorqueKernel` weighing with base parameters identified
    from known-payload experiments (:func:`identify_base_parameters`).

    Parameters
    ----------
    machine : Machine
        The machine file calibration starts from (its payload range bounds the weights).
    options : dict
        The estimator's options.
    theta_empty, theta_payload : numpy.ndarray
        Base parameters θ0 (7) and θ1 (5).
    variances : numpy.ndarray
        Sensor variances, :data:`SIGNALS` order.
    noise_name : str
        The noise preset the variances come from.
    parameter_covariance : numpy.ndarray or None
        Covariance of (θ0, θ1), 12×12 (None: zeros, nothing identified yet).
    calibration_experiments : sequence of int
        The experiments the identification used.
    """

    def __init__(self, machine: Machine, options: dict, theta_empty, theta_payload, variances,
                 noise_name: str, parameter_covariance=None, calibration_experiments=()) -> None:
        super().__init__(machine, options, theta_empty, theta_payload, variances, noise_name)
        self.parameter_covariance = (np.zeros((12, 12)) if parameter_covariance is None
                                     else parameter_covariance)
        self.calibration_experiments = [int(i) for i in calibration_experiments]

    @classmethod
    def fit(cls, estimator, dataset: Dataset) -> "IdentifiedTorqueKernel":
        """Identify the base parameters from the calibration experiments ``--experiments`` selects.

        Parameters
        ----------
        estimator : CalibratedEstimator
            The estimator (machine file and options).
        dataset : Dataset
            Thesis-set calibration data with known payloads.
        """
        noise = cls.fitting_noise(estimator, dataset)
        variances = sensor_variances(noise)
        dataset, ids = calibration_subset(estimator, dataset)
        if not np.all(np.isfinite(dataset.payloads)):
            raise EstimatorError(f"{estimator.name}: calibration experiments need known payloads")
        options = estimator.options
        theta_empty, theta_payload, cov = identify_base_parameters(
            dataset, estimator.machine, variances, options["prior_std"], options["weighting"])
        return cls(estimator.machine, options, theta_empty, theta_payload, variances,
                   THESIS.noise(noise).name, cov, ids)

    def config(self) -> dict:
        """:class:`TorqueKernel`'s, and the calibration experiments."""
        return {**super().config(), "calibration_experiments": self.calibration_experiments}

    def arrays(self) -> dict[str, np.ndarray]:
        """:class:`TorqueKernel`'s, and the parameters' covariance."""
        return {**super().arrays(), "parameter_covariance": self.parameter_covariance}

    @classmethod
    def restore(cls, estimator, config: dict, arrays: Mapping[str, np.ndarray]) -> "IdentifiedTorqueKernel":
        """The kernel :meth:`config` and :meth:`arrays` saved (checked).

        Parameters
        ----------
        estimator : CalibratedEstimator
            The estimator being loaded (machine and options).
        config : dict
            The saved state.
        arrays : Mapping[str, numpy.ndarray]
            The saved arrays.
        """
        kernel = super().restore(estimator, config, arrays)
        kernel.parameter_covariance = np.asarray(arrays["parameter_covariance"], float)
        kernel.calibration_experiments = [int(i) for i in config.get("calibration_experiments", [])]
        return kernel


class WeighingKernel(PressureKernel):
    """The machine sensor set: the streaming form of a machine-set calibration
    (:class:`~excavator_payload.estimators.classical.machine_calibration.weighing.MachineWeighing`
    held, its :class:`~excavator_payload.estimators.classical.machine_calibration.kernel.CalibratedKernel`
    built with the estimator's options).

    Parameters
    ----------
    weighing : MachineWeighing
        The identified machine with its outlier scale, noise and calibration experiments.
    options : dict
        The estimator's options (read again when saving: ``balance``).
    """

    TAG = "calibrated_machine"

    def __init__(self, weighing, options: dict) -> None:
        super().__init__(weighing.kernel(options), options, weighing.noise_name,
                         difference_scale=weighing.difference_scale)
        self.weighing = weighing
        self._options = options

    @property
    def calibration_experiments(self) -> list[int]:
        """The experiments the calibration used."""
        return self.weighing.calibration_experiments

    @classmethod
    def fit(cls, estimator, dataset: Dataset) -> "WeighingKernel":
        """Calibrate on machine-sensor-set data (:meth:`MachineWeighing.fit`; its warnings,
        refusals and report go to the estimator's) and weigh with the calibration.

        Parameters
        ----------
        estimator : CalibratedEstimator
            The estimator (machine file and options).
        dataset : Dataset
            Machine-sensor-set calibration data.
        """
        from excavator_payload.estimators.classical.machine_calibration.weighing import (
            MachineWeighing, machine_arm)

        arm = machine_arm(estimator.name, estimator.machine)
        dataset, ids = calibration_subset(estimator, dataset)
        dataset, ids = _without_stubs(estimator, dataset, ids)
        weighing, messages = MachineWeighing.fit(estimator.name, arm, dataset, ids, estimator.options,
                                                 lambda half: estimator._weighing_twin(half, dataset.sensor_set))
        estimator.fit_warnings += messages["warnings"]
        estimator.fit_refusals += messages["refusals"]
        estimator.fit_report += messages["report"]
        return cls(weighing, estimator.options)

    def config(self) -> dict:
        """The calibration's (:meth:`MachineWeighing.config`)."""
        return self.weighing.config(self._options["balance"])

    def arrays(self) -> dict[str, np.ndarray]:
        """The calibration's (:meth:`MachineWeighing.arrays`)."""
        return self.weighing.arrays()

    @classmethod
    def restore(cls, estimator, config: dict, arrays: Mapping[str, np.ndarray]) -> "WeighingKernel":
        """The kernel :meth:`config` and :meth:`arrays` saved (:meth:`MachineWeighing.restore`).

        Parameters
        ----------
        estimator : CalibratedEstimator
            The estimator being loaded (machine and options).
        config : dict
            The saved state.
        arrays : Mapping[str, numpy.ndarray]
            The saved arrays.
        """
        from excavator_payload.estimators.classical.machine_calibration.weighing import (
            MachineWeighing, machine_arm)

        weighing = MachineWeighing.restore(machine_arm(estimator.name, estimator.machine), config, arrays,
                                           estimator.options["balance"])
        return cls(weighing, estimator.options)


@register
class CalibratedEstimator(InverseDynamicsEstimator):
    """Inverse-dynamics estimator whose base parameters are identified from calibration data.

    ``fit(dataset)`` takes experiments with *known* payloads (``--experiments N``: the first N
    only), starts from the machine file (``--machine``, e.g. the wrong ``cat345c-3pct``) and
    identifies the twelve base parameters; estimation then equals ``inverse-dynamics``
    (:class:`IdentifiedTorqueKernel`).

    On machine-sensor-set data (a hydraulic machine file, e.g. ``cat345c-hydraulic-3pct``) it
    identifies the physical parameters, seal friction, sensor offsets and pressure noise instead
    (:mod:`~excavator_payload.estimators.classical.machine_calibration`, :class:`WeighingKernel`);
    ``excavator-payload zero`` re-estimates the offsets later. One-sigma uncertainty of the
    current estimate: :attr:`uncertainty` (kg).

    Parameters
    ----------
    machine : Machine, str or None
        The machine model the estimator believes in (preset name or file; None: ``cat345c``).
    **options
        Estimator options, see the class attribute ``OPTIONS``.
    """

    name = "calibrated"
    # SENSOR_SETS: from its traits (estimators/traits.py)
    #: measured with the momentum balance (the default): degraded error within 2 sigma on 95–99 %
    #: of the samples, tuning and held out (docs/sensor-health.md, "Degraded weighing")
    DEGRADED_RATES = ("boom_rate", "dipper_rate", "bucket_rate")
    #: a cylinder's pressures enter only its own joint's balance: while one is named the kernel
    #: weighs on the other joints' windows (CalibratedKernel.drop; docs/sensor-health.md)
    DEGRADED_PRESSURES = ("boom_head_pressure", "boom_rod_pressure", "dipper_head_pressure",
                          "dipper_rod_pressure", "bucket_head_pressure", "bucket_rod_pressure")
    #: a stuck or dropped-out link angle: the last healthy one plus the integrated rate, for
    #: health.ANGLE_SUBSTITUTE_LIMIT (docs/sensor-health.md)
    DEGRADED_ANGLES = ("boom_angle", "dipper_angle", "bucket_angle")
    #: a named house tilt: its value from before the fault, for health.TILT_SUBSTITUTE_LIMIT
    #: while the house does not slew far (docs/sensor-health.md)
    DEGRADED_TILTS = ("house_pitch", "house_roll")
    OPTIONS = {
        **InverseDynamicsEstimator.OPTIONS,
        "experiments": Option(int, 0, "use only the first N calibration experiments (0: all)"),
        "prior_std": Option(float, 0.1, "relative prior std of each base parameter around the "
                            "machine file's value (machine sensor set: 0.05 is used when left at 0.1)"),
        "low_speed": Option(str, "skip", "machine sensor set: joints near standstill "
                            "(stiction) are modelled, down-weighted or skipped",
                            ("model", "downweight", "skip")),
        "outside_calibration": Option(str, "auto", "machine sensor set: where the bucket's angle "
                                      "leaves the range the calibration motions covered (±5°), "
                                      "skip the bucket joint (its linkage would be extrapolated) "
                                      "or use it; auto: skip in the momentum form, use in the "
                                      "per-sample form",
                                      OUTSIDE_CALIBRATION_CHOICES),
        "wait_for_boom": Option(str, "auto", "machine sensor set: report no estimate until the "
                                "boom has been weighed in 50 windows (0.5 s of boom motion) and the estimate "
                                "then holds still (within 0.1 % of rated over 0.5 s); auto: yes in the "
                                "momentum form, no in the per-sample form", WAIT_FOR_BOOM_CHOICES),
        "new_load": Option(str, "auto", "machine sensor set: restart the weighing when the load "
                           "changes (a dump, the next bucket load), detected as a short memory's "
                           "estimate leaving the whole one by > 10 % of rated and 5 sigma; auto: "
                           "detect in the momentum form, off in the per-sample form", NEW_LOAD_CHOICES),
        "imu_leak": Option(str, "auto", "machine sensor set: the link IMUs' acceleration leak "
                           "(tilt read from acceleration): read off each IMU's own angle and rate "
                           "and held (signals), identified in the calibration fit (fit) or not "
                           "modelled (none); auto: signals in the momentum form, fit in the "
                           "per-sample form", IMU_LEAK_CHOICES),
        "balance": Option(str, "momentum", "machine sensor set: without measured "
                          "accelerations, differentiate the rates (per sample) or balance the "
                          "momentum over 0.5 s windows (no accelerations)",
                          BALANCE_CHOICES),
        "joint_check": Option(str, "on", "machine sensor set, momentum form: name a cylinder whose "
                              "joint's balance disagrees with the other joints' (a pressure offset, drift or "
                              "gain error; status sensor_fault, fault 'PRESSURE:balance', DM1 FMI 13) once two "
                              "joints are weighed (a joint weighed alone, e.g. a boom lift, is ok until its weighing "
                              "moves, then waits for a second); "
                              "nothing new is named while "
                              "the bucket dumps or before the weighing is ready; runs with the sensor "
                              "health monitor (in the C export too; docs/sensor-health.md)",
                              ("on", "off")),
        "imu_nuisance": Option(str, "auto", "machine sensor set, momentum form: re-estimate the IMU "
                               "lag and the house IMU's acceleration sensitivity per load while weighing, the "
                               "calibration's posterior as their prior (docs/findings/nuisance-oracle.md); "
                               "auto: on in the momentum form",
                               IMU_NUISANCE_CHOICES),
        "model_std": Option(str, "cross", "machine sensor set: the model error carried in each "
                            "estimate's sigma: cross (two-fold cross-fit of the calibration "
                            "motions, 95 % of held-out errors within 2 sigma) or none (sensor "
                            "noise only)", ("cross", "none")),
    }

    KERNELS = {THESIS.name: IdentifiedTorqueKernel, HYDRAULIC.name: WeighingKernel}

    def __init__(self, machine=None, **options) -> None:
        super().__init__(machine, **options)
        if self.options["experiments"] < 0:
            raise EstimatorError(f"{self.name}: option --experiments must be >= 0")
        if not self.options["prior_std"] > 0:
            raise EstimatorError(f"{self.name}: option --prior-std must be > 0")
        if self.options.get("imu_nuisance") == "on" and self.options["balance"] != "momentum":
            raise EstimatorError(f"{self.name}: option --imu-nuisance on needs --balance momentum")

    @property
    def parameter_covariance(self) -> np.ndarray:
        """Covariance of the identified (θ0, θ1), 12×12 (thesis sensor set; zeros otherwise)."""
        if isinstance(self.kernel, IdentifiedTorqueKernel):
            return self.kernel.parameter_covariance
        return np.zeros((12, 12))

    @property
    def calibration_experiments(self) -> list[int]:
        """The experiments the calibration used (none before fit)."""
        if isinstance(self.kernel, (IdentifiedTorqueKernel, WeighingKernel)):
            return self.kernel.calibration_experiments
        return []

    @property
    def weighing(self):
        """The machine-set calibration weighed with (a
        :class:`~excavator_payload.estimators.classical.machine_calibration.weighing.MachineWeighing`);
        None otherwise."""
        return self.kernel.weighing if isinstance(self.kernel, WeighingKernel) else None

    @property
    def calibration(self):
        """The identified machine on the machine sensor set (a
        :class:`~excavator_payload.estimators.classical.machine_calibration.solver.MachineCalibration`
        held by :attr:`weighing`); None otherwise."""
        return self.weighing.calibration if self.weighing is not None else None

    # -- the machine sensor set: a MachineWeighing held ------------------------------------
    def _weighing_twin(self, weighing, sensor_set) -> "CalibratedEstimator":
        """A fitted estimator of this machine and these options that weighs with ``weighing``
        (the calibration cross-check's halves): no plausibility limits or borrowed gate of its own."""
        twin = type(self)(self.machine, **self.options)
        twin.gating, twin.health = self.gating, self.health
        twin.sensor_set, twin.fitted = sensor_set, True
        twin.kernel = WeighingKernel(weighing, twin.options)
        twin.reset()
        return twin

    def use_calibration(self, calibration=None) -> None:
        """Weigh with ``calibration`` (default: the one held) and the current options: the
        streaming kernel is built again (after editing :attr:`options` or the calibration's ``z``).

        Parameters
        ----------
        calibration : MachineCalibration, optional
            The machine-set calibration to weigh with.
        """
        weighing = self.weighing
        if weighing is None:
            raise EstimatorError(f"{self.name}: no machine-sensor-set calibration to weigh with")
        if calibration is not None:
            weighing.calibration = calibration
        self.kernel = WeighingKernel(weighing, self.options)

    def degraded_rates(self) -> tuple[str, ...]:
        """Every link's rate with the momentum balance (measured); none with the other balance
        forms (they differentiate the rates: not measured on the substitute).

        Returns
        -------
        tuple of str
            Signal names (empty: no degraded weighing).
        """
        return self.DEGRADED_RATES if self.options.get("balance") == "momentum" else ()

    def degraded_pressures(self) -> tuple[str, ...]:
        """Every link cylinder's pressures on the machine sensor set with the momentum balance
        (measured); none otherwise.

        Returns
        -------
        tuple of str
            Signal names (empty: a named pressure stops the weighing).
        """
        if self.options.get("balance") != "momentum" or not isinstance(self.kernel, WeighingKernel):
            return ()
        return self.DEGRADED_PRESSURES

    def degraded_angles(self) -> tuple[str, ...]:
        """Every link's angle with the momentum balance (measured); none otherwise.

        Returns
        -------
        tuple of str
            Signal names (empty: a named angle stops the weighing).
        """
        return self.DEGRADED_ANGLES if self.options.get("balance") == "momentum" else ()

    def jump_limit(self) -> float | None:
        """With the momentum balance (measured): :data:`.health.JUMP_SHARE` of the rated payload;
        None otherwise.

        Returns
        -------
        float or None
            The largest move of an ``ok`` estimate from the one before, kg, or None.
        """
        if self.options.get("balance") != "momentum" or not self.rated_payload:
            return None
        from excavator_payload.estimators.health import JUMP_SHARE

        return JUMP_SHARE * float(self.rated_payload)

    def degraded_tilts(self) -> tuple[str, ...]:
        """Both house tilts with the momentum balance; none otherwise.

        Returns
        -------
        tuple of str
            Signal names (empty: a named tilt stops the weighing).
        """
        return self.DEGRADED_TILTS if self.options.get("balance") == "momentum" else ()

    def _drop_joints(self, joints: tuple[bool, ...]) -> None:
        """The kernel weighs the next sample's windows without these joints
        (:attr:`CalibratedKernel.drop`).

        Parameters
        ----------
        joints : tuple of bool
            Per joint (boom, dipper, bucket), whether it is dropped.
        """
        if isinstance(self.kernel, WeighingKernel):
            self.kernel.regression.drop = tuple(bool(j) for j in joints)

    def _substituting(self, on: bool) -> None:
        """The kernel weighs the next sample with the monitor's substitutes, or not
        (:attr:`CalibratedKernel.substituting`).

        Parameters
        ----------
        on : bool
            Whether the sample holds substitutes (``degraded``).
        """
        if isinstance(self.kernel, WeighingKernel):
            self.kernel.regression.substituting = bool(on)

    def _forget_joints(self, joints: tuple[bool, ...]) -> None:
        """The kernel weighs none of these joints' windows over the samples it holds now
        (:meth:`CalibratedKernel.forget`).

        Parameters
        ----------
        joints : tuple of bool
            Per joint (boom, dipper, bucket), whether its recent samples are forgotten.
        """
        if isinstance(self.kernel, WeighingKernel):
            self.kernel.regression.forget(joints)

    def zero(self, dataset: Dataset, force: bool = False) -> list[str]:
        """The zero check: re-estimate the machine-set sensor offsets from an empty-bucket motion,
        in place, and weigh with them (:meth:`MachineWeighing.zero`).

        Parameters
        ----------
        dataset : Dataset
            A short empty-bucket motion of the machine sensor set.
        force : bool
            Zero even when the sensor health monitor flags a signal of ``dataset``
            (:class:`EstimatorError` otherwise, the model unchanged: an offset built on a faulty
            signal carries the fault into every later weighing).

        Returns
        -------
        list of str
            Warnings (samples it could not use, cylinders that hardly moved, far offsets).
        """
        from excavator_payload.estimators.classical.machine_calibration.weighing import zero

        weighing = self.weighing
        if weighing is None or not HYDRAULIC.carries(dataset):
            return zero(self, dataset)  # its one clear line
        if not force and self.health:
            from excavator_payload.estimators.health_screen import refuse_flagged

            # every signal feeds the offsets (the rates and angles say which cylinder moved)
            refuse_flagged(self, dataset, dataset.sensor_set.signals, "zero")
        warnings = weighing.zero(dataset, self.options)
        self.kernel = WeighingKernel(weighing, self.options)
        self.reset()
        # the predicted weighing error (one line) and why not to weigh with this zero
        # (``excavator-payload zero`` refuses unless --force), zero_quality.zero_quality
        quality = weighing.zero_quality
        self.zero_quality = quality
        self.zero_report = [quality.report()]
        self.zero_refusals = [f"zero: {reason}" for reason in quality.refusals]
        return warnings

    @property
    def never_zeroed(self) -> bool:
        """A machine-set calibration that still weighs with its calibration session's offsets."""
        return self.calibration is not None and float(getattr(self.calibration, "zero_std", 0.0)) == 0.0

    def estimate_notes(self, dataset: Dataset, estimates: pd.DataFrame | None = None) -> list[str]:
        if self.calibration is not None and HYDRAULIC.carries(dataset):
            from excavator_payload.estimators.classical.machine_calibration.weighing import (
                coverage_notes, waiting_notes)
            from excavator_payload.estimators.offset_drift import never_zeroed_note

            return [*([never_zeroed_note(self.name)] if self.never_zeroed else []),
                    *coverage_notes(self.name, self.kernel.regression, self.calibration, dataset),
                    *waiting_notes(self.name, self.kernel.regression, estimates)]
        return []

    def identified_parameters(self) -> pd.DataFrame:
        """Prior (machine file) and identified base parameters with their standard deviations."""
        prior = np.concatenate(base_parameters(self.machine))
        value = np.r_[self.theta_empty, self.theta_payload]
        return pd.DataFrame({
            "parameter": [*BASE_PARAMETER_NAMES, *(f"payload {p}" for p in PAYLOAD_PARAMETER_NAMES)],
            "prior": prior, "identified": value, "std": np.sqrt(np.diag(self.parameter_covariance)),
        })


def calibration_subset(estimator, dataset: Dataset) -> tuple[Dataset, list]:
    """The calibration experiments ``--experiments`` selects (the first N; 0: all) and their ids.

    Parameters
    ----------
    estimator : CalibratedEstimator
        The estimator (its ``experiments`` option).
    dataset : Dataset
        The calibration data.

    Returns
    -------
    tuple of (Dataset, list)
        The selected data and their experiment ids.
    """
    n = estimator.options["experiments"]
    ids = list(dataset.experiment_ids)
    if n > len(ids):
        raise EstimatorError(f"{estimator.name}: --experiments {n} but the calibration data have only "
                             f"{len(ids)} experiments")
    if n:
        ids = ids[:n]
        dataset = dataset.subset(ids)
    return dataset, ids


#: A machine calibration experiment shorter than this (s) is not a motion: a stray row or two
#: under its own number. Counted as a motion it took a half of the cross-check's motions (four
#: experiments: a good calibration refused, "±104 kg", for one row numbered 99).
SHORTEST_MOTION = 1.0


def _without_stubs(estimator, dataset: Dataset, ids: list) -> tuple[Dataset, list]:
    """The calibration experiments without those shorter than :data:`SHORTEST_MOTION` (each
    named in a warning); all of them when none is left (the calibration then says why)."""
    counts = dataset.frame.groupby("experiment", sort=False).size()
    least = max(2, int(round(SHORTEST_MOTION * dataset.sensor_set.sample_rate)))
    stubs = [k for k in ids if counts.get(k, 0) < least]
    if not stubs or len(stubs) == len(ids):
        return dataset, ids
    shown = ", ".join(f"{k} ({counts.get(k, 0)} samples)" for k in stubs[:5]) + (", …" if len(stubs) > 5 else "")
    estimator.fit_warnings.append(f"{estimator.name}: calibration experiment(s) {shown} shorter than "
                                  f"{SHORTEST_MOTION:g} s: not motions, not used")
    kept = [k for k in ids if k not in stubs]
    return dataset.subset(kept), kept


def judged_errors(dataset: Dataset, estimates: pd.DataFrame,
                  first_judged: int = FIRST_JUDGED_SAMPLE) -> pd.DataFrame:
    """Per test experiment: RMS, max |error| and mean error (kg) over samples ≥ ``first_judged``.

    Parameters
    ----------
    dataset : Dataset
        Test data with the true ``payload`` column, kg.
    estimates : pandas.DataFrame
        What :meth:`Estimator.estimate` returned on ``dataset`` (same rows).
    first_judged : int
        Index of the first judged sample within each experiment.

    Returns
    -------
    pandas.DataFrame
        ``experiment``, ``rms_kg``, ``max_kg``, ``bias_kg``, ``n_judged``.
    """
    err = estimates["payload_estimate"].to_numpy(float) - dataset.frame["payload"].to_numpy(float)
    exp = dataset.frame["experiment"].to_numpy()
    index = dataset.frame.groupby("experiment", sort=False).cumcount().to_numpy()
    judged = index >= first_judged
    frame = pd.DataFrame({"experiment": exp[judged], "error": err[judged]})
    frame["error"] = frame["error"].fillna(np.inf)  # a missing estimate counts as a failure
    g = frame.groupby("experiment", sort=False)["error"]
    return pd.DataFrame({
        "rms_kg": g.apply(lambda e: float(np.sqrt(np.mean(e**2)))),
        "max_kg": g.apply(lambda e: float(np.max(np.abs(e)))),
        "bias_kg": g.mean(),
        "n_judged": g.size(),
    }).reset_index()


def calibration_curve(train_ds: Dataset, test_ds: Dataset, counts: Sequence[int] = (1, 2, 5, 10, 20),
                      machine: Machine | str = "cat345c-3pct", progress: bool = False,
                      **options) -> pd.DataFrame:
    """Accuracy of ``calibrated`` against the number of calibration experiments.

    Parameters
    ----------
    train_ds, test_ds : Dataset
        Calibration experiments (known payloads; the first ``count`` are used) and test data.
    counts : sequence of int
        Numbers of calibration experiments; ``0`` means no calibration (``inverse-dynamics``
        with ``machine`` as it is), the baseline.
    machine : Machine or str
        The machine file calibration starts from.
    progress : bool
        Show a rich progress bar.
    **options
        Further estimator options (``prior_std``, ``weighting`` …).

    Returns
    -------
    pandas.DataFrame
        One row per count: ``calibration_experiments``, ``mean_rms_kg`` (mean over test
        experiments of each one's RMS error on judged samples), ``rms_kg`` (over all judged
        samples), ``max_error_kg`` (largest |error| of any judged sample), ``worst_rms_kg``,
        ``bias_kg`` (mean error), ``n_test``.
    """
    machine = load_machine(machine)
    rows = []
    counts = list(counts)
    if any(c > train_ds.n_experiments for c in counts):
        raise EstimatorError(f"calibration_curve: counts {counts} need {max(counts)} calibration "
                             f"experiments, the data have {train_ds.n_experiments}")

    def run(count: int) -> dict:
        if count == 0:
            id_options = {k: v for k, v in options.items() if k in InverseDynamicsEstimator.OPTIONS}
            est = InverseDynamicsEstimator(machine, **id_options).fit(train_ds)
        else:
            est = CalibratedEstimator(machine, experiments=count, **options).fit(train_ds)
        per_exp = judged_errors(test_ds, est.estimate(test_ds))
        n = per_exp["n_judged"]
        err_all = float(np.sqrt((per_exp["rms_kg"] ** 2 * n).sum() / n.sum()))
        return {"calibration_experiments": count, "mean_rms_kg": per_exp["rms_kg"].mean(),
                "rms_kg": err_all, "max_error_kg": per_exp["max_kg"].max(),
                "worst_rms_kg": per_exp["rms_kg"].max(), "bias_kg": per_exp["bias_kg"].mean(),
                "n_test": len(per_exp)}

    if progress:
        from rich.progress import Progress

        with Progress(transient=True) as bar:
            task = bar.add_task("calibration curve", total=len(counts))
            for c in counts:
                rows.append(run(c))
                bar.advance(task)
    else:
        rows = [run(c) for c in counts]
    return pd.DataFrame(rows)
