"""How good a zero check is: the weighing error its offsets leave, and when to refuse it.

``zero`` (:mod:`~excavator_payload.estimators.classical.calibrated_machine`) re-estimates the
sensor offsets from one empty-bucket motion. What a user needs to know of the result is not the
offsets but how far the weighing can be off because of them. This module carries the zero's
posterior covariance of the offsets into the payload estimate, through the symbolic model's
regressor at the poses the calibration covered (:func:`weighing_sensitivity`), and says when
that — with the calibration's own model error — is worse than 1 % of the rated payload, or
when the motion could not determine the offsets at all (:func:`zero_quality`).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from excavator_payload.data.schema import MACHINE_SENSORS
from excavator_payload.estimators.classical.machine_calibration.data import calibration_arrays
from excavator_payload.estimators.classical.machine_calibration.settings import (
    CALIBRATED_PARAMETERS, CALIBRATION_HALF_WINDOW, HELD_IN_MOMENTUM, MIN_ZERO_BOOM_TRAVEL,
    MIN_ZERO_MOVING_SAMPLES, OFFSET_PRIOR_STD, OFFSET_SIGNALS, ZERO_OFFSET_CHI2)
from excavator_payload.estimators.classical.pressure_regression import ANGLES, PRESSURES
from excavator_payload.estimators.offset_drift import offsets_beyond_drift

if TYPE_CHECKING:  # annotations only: the solver (and its kernel) is not needed at run time
    from excavator_payload.estimators.classical.machine_calibration.solver import MachineCalibration

#: Arm-angle grid points per joint (boom × dipper × bucket) inside the calibration's coverage at
#: which the weighing's sensitivity to the offsets is evaluated.
GRID_POINTS = 5
#: Share of the rated payload a zero may leave as its predicted weighing error (95 %) before it
#: is refused: the weighing's target, 1 % of rated.
MAX_ERROR_SHARE = 0.01
#: Rod pressure (Pa) of the chamber that does not hold the load at the grid's static poses (the
#: tank side's back pressure); the other chamber's pressure balances the arm.
BACK_PRESSURE = 2.0e6
#: A cylinder's weighing-relevant offset combination (head minus rod force, :math:`A_h o_h -
#: A_r o_r`) counts as determined by the zero motion when its posterior std is below this share of
#: its prior std (the drift since calibration). Zero motions that moved the cylinder: 0.02-0.06;
#: a cylinder held still: 1.0 (20 zero motions, docs/findings/any-motion.md).
DETERMINED_SHARE = 0.5

JOINTS = ("boom", "dipper", "bucket")


def grid_poses(cal: "MachineCalibration", points: int = GRID_POINTS) -> np.ndarray:
    """Arm poses (n, 3: boom, dipper, bucket, rad) on a regular grid over the angles the
    calibration covered (:func:`~excavator_payload.estimators.classical.calibrated_machine.
    angle_coverage`), clipped to the machine's ranges.

    Parameters
    ----------
    cal : MachineCalibration
        The calibration (its ``angle_coverage`` and machine).
    points : int
        Grid points per joint.
    """
    ranges = np.asarray(cal.arm.machine.angle_ranges, float)[:3]
    cover = np.asarray(cal.angle_coverage, float)
    low = np.maximum(cover[:, 0], ranges[:, 0])
    high = np.minimum(cover[:, 1], ranges[:, 1])
    axes = [np.linspace(lo, hi, points) for lo, hi in zip(low, high)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def _static_samples(cal: "MachineCalibration", poses: np.ndarray, payload: float) -> np.ndarray:
    """Raw signals (n, 15) of the arm standing at ``poses`` on level ground with ``payload``,
    as the sensors with the calibration's offsets would read them: the pressures balance the
    model's arm (one chamber at :data:`BACK_PRESSURE`, the other solved, the model being linear
    in each pressure)."""
    n = len(poses)
    offsets = cal.offset_vector()
    values = np.tile(offsets, (n, 1))
    values[:, ANGLES] += poses
    work = copy.copy(cal)  # evaluate() leaves scratch attributes behind
    qdd = np.zeros((n, 4))
    m = np.full(n, float(payload))
    heads = [PRESSURES[2 * j] for j in range(3)]
    rods = [PRESSURES[2 * j + 1] for j in range(3)]
    values[:, heads] += BACK_PRESSURE
    values[:, rods] += BACK_PRESSURE
    r0 = work.evaluate(values, qdd, m, cal.z)[0]
    step = 1.0e7
    for j in range(3):
        probe = values.copy()
        probe[:, heads[j]] += step
        slope = (work.evaluate(probe, qdd, m, cal.z)[0][:, j] - r0[:, j]) / step
        head = -r0[:, j] / slope  # head pressure above the back pressure that balances joint j
        use_head = head >= 0
        values[use_head, heads[j]] += head[use_head]
        probe = values.copy()
        probe[:, rods[j]] += step
        slope_rod = (work.evaluate(probe, qdd, m, cal.z)[0][:, j] - r0[:, j]) / step
        rod = -r0[:, j] / slope_rod
        values[~use_head, rods[j]] += rod[~use_head]
    return values


def weighing_sensitivity(cal: "MachineCalibration", poses: np.ndarray | None = None,
                         payloads: tuple[float, ...] | None = None, columns: np.ndarray | None = None) -> np.ndarray:
    r"""How the payload estimate at each pose moves per unit of each offset (kg per SI unit).

    At a pose the streaming estimate combines the joints as :math:`\hat m = \sum_j w_j\varphi_j
    r_j / \sum_j w_j\varphi_j^2` (weights of the pressures' noise through each joint's lever), so
    an offset error :math:`\delta o` moves it by :math:`g\,\delta o`,
    :math:`g = \sum_j w_j\varphi_j\,\partial r_j/\partial o / \sum_j w_j\varphi_j^2`, with
    :math:`\partial r/\partial o` and :math:`\varphi` from the symbolic model's regressor
    (``residual_function``) at the calibrated parameters.

    Parameters
    ----------
    cal : MachineCalibration
        The calibration whose offsets are judged.
    poses : ndarray, optional
        Arm poses (n, 3); default :func:`grid_poses`.
    payloads : tuple of float, optional
        Payloads (kg) at which each pose is evaluated; default empty and rated.
    columns : ndarray, optional
        Entries of ``z`` to differentiate by; default the offsets.

    Returns
    -------
    ndarray
        (n · len(payloads), number of offsets): one row per pose and payload.
    """
    poses = grid_poses(cal) if poses is None else np.asarray(poses, float)
    if payloads is None:
        payloads = (0.0, float(cal.arm.machine.rated_payload))
    n_delta, n_off = len(CALIBRATED_PARAMETERS), len(OFFSET_SIGNALS)
    rows = []
    work = copy.copy(cal)
    for m in payloads:
        values = _static_samples(cal, poses, m)
        mass = np.full(len(poses), float(m))
        _, J, lever, _, _ = work.evaluate(values, np.zeros((len(poses), 4)), mass, cal.z)
        phi = -work._payload_sensitivity  # ∂r/∂m = -φ
        w = 1.0 / (lever**2 * (cal._head**2 + cal._rod**2) * cal.pressure_std**2)
        Jo = J[:, :, n_delta:n_delta + n_off] if columns is None else J[:, :, columns]
        rows.append(np.einsum("nj,nj,njk->nk", w, phi, Jo) / np.sum(w * phi**2, axis=1)[:, None])
    return np.concatenate(rows)


def offset_covariance(cal: "MachineCalibration") -> np.ndarray:
    """The offsets' block of the calibration's posterior covariance (SI units).

    Parameters
    ----------
    cal : MachineCalibration
        Calibration (after ``zero``: the zero's posterior).
    """
    n_delta, n_off = len(CALIBRATED_PARAMETERS), len(OFFSET_SIGNALS)
    return cal.covariance[n_delta:n_delta + n_off, n_delta:n_delta + n_off]


def predicted_error(sensitivity: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """Std (kg) of the weighing error the offsets' uncertainty leaves at each row of
    ``sensitivity``: :math:`\\sqrt{g\\,\\Sigma\\,g^\\top}`.

    Parameters
    ----------
    sensitivity : ndarray
        (n, offsets) from :func:`weighing_sensitivity`.
    covariance : ndarray
        (offsets, offsets) from :func:`offset_covariance`.
    """
    return np.sqrt(np.maximum(np.einsum("nk,kl,nl->n", sensitivity, covariance, sensitivity), 0.0))



@dataclass
class ZeroQuality:
    """What a zero check is good for (:func:`zero_quality`).

    Parameters
    ----------
    predicted_error : float
        Weighing error the zero leaves, kg, 95 % (2 × the RMS over the calibrated poses).
    offset_part : float
        Its share from the offsets' own posterior (the zero motion's noise), kg (1 σ, RMS).
    model_part : float
        Its share from the calibration's parameter posterior as the zero's offsets take it up,
        kg (1 σ, RMS).
    determined : ndarray
        Per cylinder (boom, dipper, bucket): posterior / prior std of its force offset.
    refusals : list of str
        Reasons not to weigh with this zero (empty: accept).
    """

    predicted_error: float
    offset_part: float
    model_part: float
    determined: np.ndarray
    refusals: list[str] = field(default_factory=list)

    def report(self) -> str:
        """One line for the user."""
        return (f"zero: predicted weighing error ±{self.predicted_error:.0f} kg (95 %) over the poses the "
                f"calibration covered (the zero motion's noise {self.offset_part:.0f} kg, each estimate's σ "
                f"carrying its own share of it; the "
                f"calibration's model as these offsets take it up {self.model_part:.0f} kg, 1 σ)")


def _zero_jacobians(cal: "MachineCalibration", dataset, columns: np.ndarray):
    """The zero motion's windows (or samples) as the zero weighs them: Jacobian by ``columns``
    of z (n, 3, k) and weights (n, 3)."""
    values, qdd, payload, runs = calibration_arrays(dataset, CALIBRATION_HALF_WINDOW, cal.arm.machine)
    work = copy.copy(cal)
    if cal.balance == "momentum":
        r, J, lever, speed, stiction, _ = work.evaluate_windows(values, qdd, payload, cal.z, runs)
        w = work.weights(lever, speed, stiction, "skip", cal.pressure_std) / cal.window_inflation
    else:
        r, J, lever, speed, stiction = work.evaluate(values, qdd, payload, cal.z)
        w = work.weights(lever, speed, stiction, "skip", cal.pressure_std)
    J = J[:, :, columns]
    ok = np.isfinite(r) & np.isfinite(w) & np.all(np.isfinite(J), axis=2)
    return np.where(ok[..., None], J, 0.0), np.where(ok, w, 0.0)


def zero_quality(cal: "MachineCalibration", dataset, moving: np.ndarray,
                 drift_std: np.ndarray = OFFSET_PRIOR_STD) -> ZeroQuality:
    r"""Predict the weighing error a zero leaves and say whether to refuse it.

    Two parts, both from posteriors, both carried to the payload estimate at the calibrated
    poses by :func:`weighing_sensitivity`:

    * the offsets' posterior after the zero (:math:`\Sigma_o`): the zero motion's noise, and
      what it did not determine;
    * the calibration's parameter posterior :math:`\Sigma_\delta`, taken up by the offsets:
      the zero fits its offsets with the calibrated parameters held, so a parameter error
      :math:`\delta` moves them by :math:`-M\delta`, :math:`M = (J_o^\top W J_o + P_o^{-1})^{-1}
      J_o^\top W J_\delta` (the zero motion's own windows and weights), and the weighing at a
      pose by :math:`(g_\delta - g_o M)\,\delta`. The offsets absorb the model's error at the
      zero motion's poses and speeds and carry it to every later weighing — the measured reason
      why zeros on different empty motions weigh differently.

    Refused (reasons in ``refusals``): a boom that travelled less than
    :data:`~excavator_payload.estimators.classical.machine_calibration.settings.MIN_ZERO_BOOM_TRAVEL`
    (:func:`boom_travel`), a cylinder the motion did not move (``moving`` below
    :data:`~excavator_payload.estimators.classical.calibrated_machine.MIN_ZERO_MOVING_SAMPLES`)
    or whose force offset it did not determine (:data:`DETERMINED_SHARE`), a predicted error
    above :data:`MAX_ERROR_SHARE` of the rated payload, and offsets beyond a working session's
    drift (:func:`far_offsets`: a load left in the bucket, or a sensor that changed).

    Parameters
    ----------
    cal : MachineCalibration
        The calibration after ``zero_offsets`` (its covariance holds the zero's offsets
        posterior and the calibration's parameter posterior).
    dataset : Dataset
        The zero motion.
    moving : ndarray
        Samples on which each arm cylinder moved (``zero_offsets``' second result).
    drift_std : ndarray
        The zero's prior std of the offsets (SI units).
    """
    n_delta, n_off = len(CALIBRATED_PARAMETERS), len(OFFSET_SIGNALS)
    offsets = np.arange(n_delta, n_delta + n_off)
    held = [CALIBRATED_PARAMETERS.index(n) for n in HELD_IN_MOMENTUM]
    deltas = np.r_[np.setdiff1d(np.arange(n_delta), held), n_delta + n_off]  # parameters and IMU lag
    deltas = deltas[np.diag(cal.covariance)[deltas] > 0]
    G = weighing_sensitivity(cal, columns=np.r_[deltas, offsets])
    g_delta, g_off = G[:, :len(deltas)], G[:, len(deltas):]
    cov_off = offset_covariance(cal)
    noise = predicted_error(g_off, cov_off)
    J, w = _zero_jacobians(cal, dataset, np.r_[deltas, offsets])
    J_delta, J_off = J[:, :, :len(deltas)], J[:, :, len(deltas):]
    H_oo = np.einsum("nja,nj,njb->ab", J_off, w, J_off) + np.diag(1.0 / np.asarray(drift_std, float) ** 2)
    H_od = np.einsum("nja,nj,njb->ab", J_off, w, J_delta)
    effective = g_delta - g_off @ np.linalg.solve(H_oo, H_od)
    model = predicted_error(effective, cal.covariance[np.ix_(deltas, deltas)])
    offset_part = float(np.sqrt(np.mean(noise**2)))
    model_part = float(np.sqrt(np.mean(model**2)))
    predicted = 2.0 * math.hypot(offset_part, model_part)
    # each cylinder's force offset A_h o_h - A_r o_r: what its joint's weighing sees
    force = np.zeros((3, n_off))
    for j in range(3):
        force[j, 2 * j], force[j, 2 * j + 1] = cal._head[j], -cal._rod[j]
    prior = np.diag(np.asarray(drift_std, float) ** 2)
    determined = np.sqrt(np.diag(force @ cov_off @ force.T) / np.diag(force @ prior @ force.T))
    refusals = []
    rate = MACHINE_SENSORS.sample_rate
    still = [JOINTS[j] for j in range(3)
             if moving[j] < MIN_ZERO_MOVING_SAMPLES or determined[j] > DETERMINED_SHARE]
    if still:
        seconds = ", ".join(f"{j} {moving[JOINTS.index(j)] / rate:.1f} s" for j in still)
        refusals.append(
            f"the zero motion did not determine the pressure offsets of the {' and '.join(still)} "
            f"cylinder{'s' if len(still) > 1 else ''} (moving: {seconds}): repeat it with the empty "
            f"bucket, moving the {' and '.join(still)} up and down through "
            f"{'their' if len(still) > 1 else 'its'} range, {MIN_ZERO_MOVING_SAMPLES / rate:.0f} s or "
            "more each, at a steady speed")
    travel = boom_travel(dataset)
    if "boom" not in still and travel < MIN_ZERO_BOOM_TRAVEL:  # a still boom is named above
        refusals.append(
            f"the zero motion moved the boom through only {math.degrees(travel):.0f}° "
            f"({math.degrees(MIN_ZERO_BOOM_TRAVEL):.0f}° or more wanted: its offsets would take up the "
            "model's error at that one boom pose): repeat it with the empty bucket, raising and lowering "
            f"the boom through {math.degrees(MIN_ZERO_BOOM_TRAVEL):.0f}° or more while you move the dipper "
            "and bucket, as in an empty swing (lift, slew, lower)")
    rated = float(cal.arm.machine.rated_payload)
    if predicted > MAX_ERROR_SHARE * rated:
        refusals.append(
            f"it would weigh within ±{predicted:.0f} kg (95 %), worse than {MAX_ERROR_SHARE:.0%} of the "
            f"rated payload ({MAX_ERROR_SHARE * rated:.0f} kg): repeat the zero check with an empty "
            "swing that moves the boom, dipper and bucket through the poses you work at"
            + (" (the calibration's own model error dominates: recalibrate with more motions)"
               if model_part > offset_part else ""))
    far = far_offsets(cal.offsets, drift_std)
    if far:
        refusals.append(far)
    return ZeroQuality(predicted, offset_part, model_part, determined, refusals)


def boom_travel(dataset) -> float:
    """How far the zero motion moved the boom (rad): the 2nd to 98th percentile of its measured
    angle (a glitch or a few stray samples do not count as travel; 0 without finite samples).

    Parameters
    ----------
    dataset : Dataset
        The zero motion (machine sensor set).
    """
    boom = dataset.frame["boom_angle"].to_numpy(float)
    boom = boom[np.isfinite(boom)]
    if len(boom) == 0:
        return 0.0
    low, high = np.percentile(boom, [2.0, 98.0])
    return float(high - low)


def far_offsets(offsets: np.ndarray, drift_std: np.ndarray = OFFSET_PRIOR_STD) -> str:
    """Why the zero's offsets are beyond a working session's drift (their χ² past
    :data:`ZERO_OFFSET_CHI2`; :func:`~excavator_payload.estimators.offset_drift.offsets_beyond_drift`),
    or ``""``. Clean zeros: χ² 1.3–16.3; 300 kg left in the bucket: 73–333.

    Parameters
    ----------
    offsets : ndarray
        The zero's offsets (:data:`OFFSET_SIGNALS`, SI units).
    drift_std : ndarray
        Their prior std (SI units).
    """
    return offsets_beyond_drift(OFFSET_SIGNALS, offsets, drift_std, ZERO_OFFSET_CHI2)
