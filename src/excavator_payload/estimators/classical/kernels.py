"""The kernel interface of the classical least-squares estimators: one kernel per platform.

A classical estimator (``inverse-dynamics``, ``calibrated``) weighs with one *kernel*, picked
once: at construction for the machine it is given, again at ``fit`` for the platform of the
fitting data, and at ``load`` from what was saved. The kernel owns everything that differs
between the platforms — its parameters, its streaming state, its statuses, what it saves and
how it is restored — so the estimator delegates without asking which platform it is on:

* ``inverse-dynamics``: :class:`~.inverse_dynamics.TorqueKernel` on the thesis' arm (joint
  torques), :class:`~.pressure_regression.PressureKernel` on the hydraulic machine (pressures);
* ``calibrated``: :class:`~.calibrated.IdentifiedTorqueKernel` and
  :class:`~.calibrated.WeighingKernel`.

Adding a platform to an estimator is one more kernel class and one more entry in its
``KERNELS`` table.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from typing import Mapping

import numpy as np

from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.status import StepResult


class PayloadKernel(ABC):
    """One platform's weighing: recursive least squares on the payload with its state.

    Subclasses hold the accumulated information :attr:`info` (kg⁻², 1/σ² of the estimate)
    and implement the streaming step and their save and restore.
    """

    #: ``kernel`` entry of the saved state that names this kernel (None: the default one).
    TAG: str | None = None
    #: The noise preset the weights were set from (``estimated``: from the data).
    noise_name: str = ""
    #: Information of the current estimate, kg⁻² (0 before any sample).
    info: float = 0.0

    @abstractmethod
    def reset(self) -> None:
        """Forget the current experiment (sums, windows, detectors)."""

    @abstractmethod
    def step(self, time: float, values: np.ndarray, judge: bool = True,
             joint_check: bool = False) -> StepResult:
        """Consume one sample and return the estimate with its status.

        Parameters
        ----------
        time : float
            Sample time, s.
        values : numpy.ndarray
            The sample in its sensor set's signal order, SI units.
        judge : bool
            Whether the kernel's own outlier test runs (the estimator's ``gating``).
        joint_check : bool
            Whether the joints' balances may be checked against each other (the ``calibrated``
            option with the health monitor on; kernels that cannot check ignore it).
        """

    def innovation(self, values: np.ndarray) -> tuple[float, int] | None:
        """Normalised squared innovation of a sample and its degrees of freedom, or None (the
        kernel judges its samples itself, or cannot yet).

        Parameters
        ----------
        values : numpy.ndarray
            The sample in its sensor set's signal order, SI units.
        """
        return None

    @property
    def model_std(self) -> float:
        """Model error carried in the estimate's sigma beside I^-1/2, kg (0: sensor noise only)."""
        return 0.0

    @property
    def extra_std(self) -> float:
        """The current estimate's own share of σ beside 1/I and the model error, kg (the
        calibrated machine's zero share; 0 here)."""
        return 0.0

    def sigma(self) -> float:
        """One-sigma uncertainty of the current estimate, kg: √(1/I + s_model² + s_extra²); NaN
        before any information."""
        if self.info <= 0:
            return math.nan
        model_std, extra = self.model_std, self.extra_std
        return math.sqrt(1.0 / self.info + model_std * model_std + extra * extra)

    def bridge_gap(self) -> None:
        """A short gap in the data (sums kept): restart what needs evenly spaced samples."""

    def state_finite(self) -> bool:
        """Whether the streaming state is still finite (the estimator resets it otherwise)."""
        return math.isfinite(self.info)

    @abstractmethod
    def config(self) -> dict:
        """The JSON-able state to save (the estimator's ``state`` entry)."""

    @abstractmethod
    def arrays(self) -> dict[str, np.ndarray]:
        """The arrays to save (``arrays.npz``)."""

    @classmethod
    @abstractmethod
    def restore(cls, estimator, config: dict, arrays: Mapping[str, np.ndarray]) -> "PayloadKernel":
        """The kernel :meth:`config` and :meth:`arrays` saved, for ``estimator``'s machine and options.

        Parameters
        ----------
        estimator : Estimator
            The estimator being loaded (its machine and options).
        config : dict
            The saved state.
        arrays : Mapping[str, numpy.ndarray]
            The saved arrays.
        """


class UnfittedKernel(PayloadKernel):
    """The kernel of an estimator of a hydraulic machine before ``fit``: the machine's kernel
    needs the fitting data (their noise and the outlier test's scale). Nothing to weigh with.

    Parameters
    ----------
    noise_name : str
        The platform's default noise preset (what :attr:`noise_name` says until fit).
    """

    def __init__(self, noise_name: str) -> None:
        self.noise_name = noise_name

    def reset(self) -> None:
        """Nothing to forget."""

    def step(self, time: float, values: np.ndarray, judge: bool = True,
             joint_check: bool = False) -> StepResult:
        """Never called: the estimator refuses to step before fit.

        Parameters
        ----------
        time : float
            Sample time, s.
        values : numpy.ndarray
            The sample.
        judge : bool
            Unused.
        joint_check : bool
            Unused.
        """
        raise EstimatorError("the estimator is not fitted: call fit() (or load a trained model) first")

    def config(self) -> dict:
        """Nothing to save (the estimator refuses to save before fit)."""
        raise EstimatorError("the estimator is not fitted: nothing to save")

    def arrays(self) -> dict[str, np.ndarray]:
        """Nothing to save."""
        raise EstimatorError("the estimator is not fitted: nothing to save")

    @classmethod
    def restore(cls, estimator, config: dict, arrays: Mapping[str, np.ndarray]) -> "PayloadKernel":
        """Never restored: a saved model always names its kernel.

        Parameters
        ----------
        estimator : Estimator
            Unused.
        config : dict
            Unused.
        arrays : Mapping[str, numpy.ndarray]
            Unused.
        """
        raise EstimatorError("saved model names no kernel (corrupt model folder)")


def saved_kernel(kernels: Mapping[str, type[PayloadKernel]], config: dict) -> type[PayloadKernel]:
    """The kernel class among ``kernels`` that wrote ``config`` (by its ``kernel`` tag; the
    untagged one when it has none).

    Parameters
    ----------
    kernels : Mapping[str, type]
        An estimator's kernels by platform (its ``KERNELS``).
    config : dict
        The saved state.
    """
    tag = config.get("kernel")
    for kernel in kernels.values():
        if kernel.TAG == tag:
            return kernel
    raise EstimatorError(f"saved model names an unknown kernel {tag!r} (corrupt model folder)")
