"""The calibrated estimator's machine-sensor-set side, as one object it holds: :class:`MachineWeighing`.

``calibrated`` on machine-sensor-set data (a hydraulic machine file) identifies the machine
(:func:`~.solver.calibrate`), checks its own model error on the calibration motions
(:func:`~.solver.cross_validated_model_std`), weighs with a :class:`~.kernel.CalibratedKernel`
and re-estimates the sensor offsets later (:func:`zero`). :class:`MachineWeighing` owns that
state — the calibration, the outlier test's scale, the noise's name and the calibration
experiments — with its fit, zero check, save (:meth:`MachineWeighing.config`,
:meth:`MachineWeighing.arrays`) and restore (:meth:`MachineWeighing.restore`); the estimator
holds one and builds its kernel from it (:meth:`MachineWeighing.kernel`). The notes ``estimate``
adds (:func:`coverage_notes`, :func:`waiting_notes`) are here too.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.schema import MACHINE_SENSORS
from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.classical.machine_calibration.data import angle_coverage
from excavator_payload.estimators.classical.machine_calibration.kernel import CalibratedKernel
from excavator_payload.estimators.classical.machine_calibration.settings import (
    BALANCE_HALF_WINDOW, CALIBRATED_PARAMETERS, COVERAGE_JOINTS, DEG, IMU_PARAMETERS, MAX_CALIBRATION_VALUE,
    MIN_CROSS_EXPERIMENTS, MIN_MOVING_SAMPLES, MIN_ZERO_MOVING_SAMPLES, OFFSET_PRIOR_STD, OFFSET_SIGNALS,
    REFUSAL_FOLDS, REFUSAL_FOLDS_SHARE, SIGNALS)
from excavator_payload.estimators.classical.machine_calibration.solver import (
    MachineCalibration, calibrate, cross_validated_model_std, zero_offsets)
from excavator_payload.estimators.classical.pressure_regression import ANGLES, difference_scale, spike_threshold
from excavator_payload.model.hydraulic import HydraulicArmModel
from excavator_payload.platforms import HYDRAULIC


#: A stretch of a joint's range the calibration did not reach is named in the fit report from
#: this size on (rad).
UNCOVERED_REPORTED = 10.0 * DEG


def uncovered_ranges(coverage: np.ndarray, ranges: np.ndarray) -> str:
    """The stretches of the boom's, dipper's and bucket's ranges (the machine file's) that the
    calibration's covered angles leave out, :data:`UNCOVERED_REPORTED` or longer, for humans
    (e.g. ``"dipper -150…-114° and -43…-15°"``; empty: none).

    Parameters
    ----------
    coverage : ndarray
        (3, 2) covered [low, high] per joint, rad (offsets removed).
    ranges : ndarray
        The machine's angle ranges, (≥ 3, 2), rad.
    """
    parts = []
    for j, joint in enumerate(("boom", "dipper", "bucket")):
        (lo, hi), (r_lo, r_hi) = np.asarray(coverage, float)[j], np.asarray(ranges, float)[j]
        gaps = [(a, b) for a, b in ((r_lo, min(lo, r_hi)), (max(hi, r_lo), r_hi)) if b - a >= UNCOVERED_REPORTED]
        if gaps:
            parts.append(f"{joint} " + " and ".join(f"{a / DEG:.0f}…{b / DEG:.0f}°" for a, b in gaps))
    return ", ".join(parts)


def coverage_notes(name: str, kernel, calibration, dataset: Dataset) -> list[str]:
    """A note per arm joint whose angle leaves the range the calibration covered on some of
    ``dataset``'s samples: where ``--outside-calibration`` skips it (a limited joint,
    :data:`COVERAGE_JOINTS`, or with ``arm`` every arm joint) the weighing rests on the other
    joints there; elsewhere it was weighed by extrapolation, which the note says.

    Parameters
    ----------
    name : str
        The estimator's name (the notes begin with it).
    kernel : CalibratedKernel
        The kernel that weighed ``dataset``.
    calibration : MachineCalibration
        Its calibration (the covered range, offsets removed).
    dataset : Dataset
        The data weighed.
    """
    skips = kernel.outside_calibration in ("skip", "arm")
    whole_arm = kernel.whole_arm
    offsets = calibration.offset_vector()[ANGLES]  # raw (measured) = corrected + offset
    notes = []
    for j, joint in enumerate(("boom", "dipper", "bucket")):
        skipped = skips and (whole_arm or COVERAGE_JOINTS[j])
        a = dataset.frame[SIGNALS[ANGLES[j]]].to_numpy(float)
        a = a[np.isfinite(a)]
        if not len(a):
            continue
        # the covered range in raw (measured) units, as the kernel compares it where it skips
        raw_low, raw_high = np.asarray(calibration.angle_coverage[j], float) + offsets[j]
        below, above = a < raw_low, a > raw_high
        outside = float(np.mean(below | above))
        if outside > 0:
            low, high = calibration.angle_coverage[j] / DEG
            # the angles reached, offsets removed, as the calibration's range is given
            reached = [f"{(v - offsets[j]) / DEG:.0f}°" for v, hit in ((a.min(), below.any()), (a.max(), above.any()))
                       if hit]
            if not skipped:
                # weighed there all the same: the calibrated model extrapolates, and its cross-checked
                # error (in sigma) was measured inside the covered range only
                notes.append(f"{name}: the {joint} angle lay outside the range the calibration motions "
                             f"covered ({low:.0f}…{high:.0f}°) on {100 * outside:.1f} % of the samples (it "
                             f"reached {' and '.join(reached)}), and was weighed there by extrapolation: "
                             "the error can exceed its sigma (measured up to 24 kg where swings alone had "
                             "calibrated). Add calibration motions with known loads that take the "
                             f"{joint} there (simulate --motion reach), or weigh with --outside-calibration "
                             "arm to report nothing there")
                continue
            notes.append(f"{name}: the {joint} angle lay outside the range the calibration "
                         f"motions covered ({low:.0f}…{high:.0f}°) on {100 * outside:.1f} % of the samples "
                         f"(it reached {' and '.join(reached)}); "
                         f"{'the arm' if whole_arm else f'the {joint}'} is not weighed there. To weigh there, "
                         f"add calibration motions with known loads that take the {joint} to those angles "
                         "(or train with --outside-calibration use)")
    return notes


def waiting_notes(name: str, kernel, estimates) -> list[str]:
    """A note when ``--wait-for-boom`` kept whole experiments of ``estimates`` (the frame
    ``estimate`` returns) without an estimate: their boom never moved through a 0.5 s window
    without a stop, so the weighing never started. Without the note such a motion's NaN column
    looks like a broken sensor.

    Parameters
    ----------
    name : str
        The estimator's name (the note begins with it).
    kernel : CalibratedKernel
        The kernel that weighed.
    estimates : pandas.DataFrame or None
        What ``estimate`` returned.
    """
    if not kernel.wait_for_boom or estimates is None or not len(estimates):
        return []
    estimate = estimates["payload_estimate"].to_numpy(float)
    status = estimates["status"].astype(str).to_numpy()
    experiments = estimates["experiment"].to_numpy()
    silent = []
    names = list(dict.fromkeys(experiments.tolist()))
    for experiment in names:
        rows = experiments == experiment
        # warming_up on most samples: not an experiment lost to invalid input or one too short
        if not np.isfinite(estimate[rows]).any() and np.mean(status[rows] == "warming_up") > 0.5:
            silent.append(experiment)
    if not silent:
        return []
    shown = ", ".join(str(e) for e in silent[:5]) + (", …" if len(silent) > 5 else "")
    still = 3e3 * float(kernel._v_stribeck[0])  # mm/s: below it a seal's force is not known
    return [f"{name}: no estimate in {len(silent)} of {len(names)} experiments ({shown}): the "
            f"boom never moved for {2 * BALANCE_HALF_WINDOW / MACHINE_SENSORS.sample_rate:.1f} s "
            f"without a stop or faster than its seals' stiction band (boom rod {still:.0f} mm/s), and the "
            "weighing waits until it has weighed the boom (a standing or creeping "
            "boom's seals hold an unknown force). Move the boom while weighing, or train with "
            "--wait-for-boom no to weigh from the dipper and bucket"]


def hardly_moved(moving: np.ndarray, minimum: int) -> list[tuple[str, int]]:
    """(joint, moving samples) of the arm cylinders that moved on fewer than ``minimum`` samples
    (:meth:`MachineCalibration.moving_samples`): what fit and zero warn about.

    Parameters
    ----------
    moving : ndarray
        Moving samples of the boom, dipper and bucket cylinders.
    minimum : int
        Fewest moving samples that count as moved.
    """
    return [(joint, int(k)) for joint, k in zip(("boom", "dipper", "bucket"), moving) if k < minimum]


def machine_arm(name: str, machine) -> HydraulicArmModel:
    """The arm model of ``machine`` for estimator ``name``; one clear line unless it is hydraulic.

    Parameters
    ----------
    name : str
        The estimator's name (for the message).
    machine : Machine or HydraulicMachine
        The machine file the estimator believes in.
    """
    if not HYDRAULIC.owns(machine):
        raise EstimatorError(f"{name}: data of the machine sensor set need a hydraulic "
                             f"machine file, not '{machine.name}' (e.g. --machine "
                             "cat345c-hydraulic-3pct)")
    return HydraulicArmModel(machine, compiled=False)


def imu_nuisance_on(options: dict, balance: str) -> bool:
    """Whether the kernel re-estimates the IMU dynamics while weighing (``--imu-nuisance``):
    ``on`` or ``auto`` in the momentum form (with or without the joint check, which judges the
    kernel's own sums); never in another form.

    Parameters
    ----------
    options : dict
        The estimator's options (``imu_nuisance``).
    balance : str
        The kernel's form (``momentum`` or ``differentiated``).
    """
    return balance == "momentum" and options.get("imu_nuisance", "auto") != "off"


#: A calibration that moves the machine file's link masses and cylinder areas by more than this
#: share (their median; the prior allows 5 %, calibrations from a file 3 % off moved them by at
#: most 4 %) was given known loads in another unit, or another machine's file.
MAX_FORCE_SCALE = 0.25


def force_scale(cal) -> float:
    """The factor the calibration ``cal`` scaled the machine file's forces by: the median of
    ``1 + δ`` over the link masses and cylinder areas (1 when it kept them).

    Parameters
    ----------
    cal : MachineCalibration
        A fitted calibration (its ``z`` starts with the relative changes δ of
        :data:`CALIBRATED_PARAMETERS`).
    """
    deltas = [float(cal.z[i]) for i, n in enumerate(CALIBRATED_PARAMETERS) if n.endswith(("_mass", "_area"))]
    return 1.0 + float(np.median(deltas)) if deltas else 1.0


class MachineWeighing:
    """What a ``calibrated`` estimator holds on the machine sensor set, with its save and restore.

    Parameters
    ----------
    calibration : MachineCalibration
        The identified machine (parameters, offsets, IMU dynamics, noise, covered angles).
    difference_scale : ndarray
        Per-signal scale of the one-frame outlier test (from the calibration data).
    noise_name : str
        The noise preset named for the weights, or ``estimated`` (from the data).
    calibration_experiments : list of int
        The experiments the calibration used.
    """

    #: Its kernels weigh motions that keep their load (:attr:`~.kernel.CalibratedKernel.loads_stay`):
    #: the cross-check's halves, whose held-out motions carry known loads that stay in the bucket.
    loads_stay = False

    def __init__(self, calibration: MachineCalibration, difference_scale, noise_name: str = "estimated",
                 calibration_experiments=()):
        self.calibration = calibration
        self.difference_scale = difference_scale
        self.noise_name = noise_name
        self.calibration_experiments = [int(i) for i in calibration_experiments]

    def kernel(self, options: dict) -> CalibratedKernel:
        """A streaming kernel weighing with this calibration.

        Parameters
        ----------
        options : dict
            The estimator's options (``half_window``, ``forgetting``, ``low_speed``,
            ``outside_calibration``, ``wait_for_boom``, ``new_load``, ``imu_nuisance``).
        """
        kernel = self.calibration.kernel(options["half_window"], options["forgetting"], options["low_speed"],
                                         options["outside_calibration"], options["wait_for_boom"],
                                         options["new_load"])
        kernel.spike_threshold = spike_threshold(self.difference_scale)
        kernel.loads_stay = self.loads_stay
        if imu_nuisance_on(options, kernel.balance):
            kernel.use_imu_nuisance(self.calibration)
        if kernel.balance == "momentum" and float(getattr(self.calibration, "zero_std", 0.0)) > 0.0:
            kernel.use_offset_share(self.calibration)  # zeroed: the zero's share per estimate
        return kernel

    # -- fit ----------------------------------------------------------------------------------
    @classmethod
    def fit(cls, name: str, arm: HydraulicArmModel, dataset: Dataset, ids, options: dict,
            weigh_with: Callable[["MachineWeighing"], object]) -> tuple["MachineWeighing", dict]:
        """Calibrate on known-payload motions and check the model error on them.

        Parameters
        ----------
        name : str
            The estimator's name (its messages begin with it).
        arm : HydraulicArmModel
            The machine file calibration starts from.
        dataset : Dataset
            The calibration experiments (known payloads).
        ids : list
            Their experiment ids.
        options : dict
            The estimator's options.
        weigh_with : callable
            ``weigh_with(weighing) -> estimator``: a fitted estimator weighing with another
            :class:`MachineWeighing` (the cross-check's halves).

        Returns
        -------
        weighing : MachineWeighing
        messages : dict
            ``warnings``, ``refusals`` and ``report``: lines for the estimator's
            ``fit_warnings``, ``fit_refusals`` and ``fit_report``.
        """
        warnings, refusals, report = [], [], []
        if "payload" not in dataset.frame or not np.all(np.isfinite(dataset.frame["payload"].to_numpy(float))):
            raise EstimatorError(f"{name}: calibration experiments need known payloads")
        noise = options["noise"]
        pressure_std = None
        if noise != "auto":  # a preset named explicitly overrides the noise estimated from the data
            pressure_std = HYDRAULIC.noise(noise).pressure_noise
        prior = options["prior_std"]
        prior = 0.05 if prior == 0.1 else prior  # 0.1 is the thesis set's default

        def calibrate_on(subset: Dataset) -> MachineCalibration:
            """The calibration of ``subset`` with the estimator's options, and the angles it covers
            (all the motions, and each half of them for the cross-check)."""
            fitted = calibrate(arm, subset, prior, options["low_speed"], pressure_std, options["balance"],
                               options["imu_leak"])
            fitted.angle_coverage = angle_coverage(subset, fitted.offset_vector())
            return fitted

        cal = calibrate_on(dataset)
        # a cylinder the calibration motions hardly moved keeps the file's numbers (e.g. lifts that
        # move the boom only): say so rather than weigh with them silently
        moving, n_valid = cal.moving
        if n_valid < len(dataset.frame):  # dropped rows: not finite, or outside the angle ranges
            warnings.append(
                f"{name}: {len(dataset.frame) - n_valid} of {len(dataset.frame)} calibration "
                "samples not used (a signal not finite, or an angle outside the machine's range)")
        still = [f"{joint} {k}" for joint, k in hardly_moved(moving, MIN_MOVING_SAMPLES)]
        if still:
            refusals.append(
                f"{name}: cylinders that hardly moved in the calibration data (moving samples: "
                f"{', '.join(still)} of {n_valid}; {MIN_MOVING_SAMPLES} or more wanted): what it "
                "learned of them is mostly the machine file's. Calibrate with motions that move the "
                "boom, dipper and bucket (and slew)")

        scale = force_scale(cal)
        if abs(math.log(scale)) > math.log(1.0 + MAX_FORCE_SCALE):
            # known loads in pounds (2.2 times kg, below the 2x-the-largest-load limit) were
            # calibrated into a machine twice as heavy with cylinders twice as large: saved, zeroed
            # (±34 kg said) and weighed 2.2 times every load, `ok`
            refusals.append(
                f"{name}: the calibration had to scale the machine file's link masses and cylinder "
                f"areas by {scale:.2f} (median of them; its prior allows ±{100 * prior:.0f} %, a right file "
                f"needs a few %): the known loads look {scale:.2f} times {'too heavy' if scale > 1 else 'too light'} "
                "for this machine: is column 'payload' in kg (pounds are 2.2 times as many), and is "
                "--machine this machine's file?")

        weighing = cls(cal, difference_scale(dataset), "estimated" if pressure_std is None else noise, ids)
        if options["model_std"] == "cross":
            def held_out(half: MachineCalibration) -> object:
                """A half's weighing of the other half's motions: their known loads stay in the
                bucket, so a fast turn of it is no dump (restarts there, which the weighing of work
                never sees on a kept load, moved s by chance on `reach` motions, -0.09 to +2.05 kg;
                docs/findings/any-motion.md, session 19)."""
                twin = cls(half, weighing.difference_scale, weighing.noise_name, ids)
                twin.loads_stay = True
                return weigh_with(twin)

            cal.model_std = cross_validated_model_std(dataset, calibrate_on, held_out)
            rated = float(arm.machine.rated_payload)
            if len(ids) >= MIN_CROSS_EXPERIMENTS:
                report.append(
                    f"calibration: each half of the calibration motions weighs the other within "
                    f"±{2 * cal.model_std:.0f} kg (95 %) beyond the sensor noise; that model error is "
                    "carried in every estimate's sigma")
            folds_std = None
            if 2 * cal.model_std > 0.01 * rated and len(ids) > 2:
                # halves of a 5-motion calibration (2-3 motions) calibrate far worse than all five:
                # they refused calibrations that weigh every family within 1 % (s 65 and 41 kg,
                # with 5 folds 7-8 kg). Only the decision asks the folds; σ keeps the halves' s
                # (a narrower s raised the joint check's false alarms: any-motion.md, session 21)
                folds_std = cross_validated_model_std(dataset, calibrate_on, held_out, folds=REFUSAL_FOLDS)
                k = min(REFUSAL_FOLDS, len(ids))
                folds_text = (f"with each motion weighed by a calibration of the other {len(ids) - 1}"
                              if k == len(ids) else
                              f"with {k} folds (each weighed by a calibration of the other {k - 1})")
                if 2 * folds_std <= REFUSAL_FOLDS_SHARE * rated:
                    warnings.append(
                        f"{name}: each half of the calibration motions weighs the other only within "
                        f"±{2 * cal.model_std:.0f} kg (95 %), but {folds_text} within ±{2 * folds_std:.0f} kg, "
                        f"inside ±{REFUSAL_FOLDS_SHARE * rated:.0f} kg (a motion's worst error runs to about "
                        f"twice that band, 1 % of the rated payload is {0.01 * rated:.0f} kg): accepted; every "
                        f"estimate's sigma carries the halves' wider model error. More calibration motions "
                        "with known loads would narrow it")
            if 2 * cal.model_std > 0.01 * rated and (folds_std is None or 2 * folds_std > REFUSAL_FOLDS_SHARE * rated):
                # the per-sample form differentiates the rates: the recommended mix's fast reach
                # motions spoil it (±130 kg measured) where the default form weighs within 1 %
                per_sample = ("; the per-sample form (--balance differentiated) differentiates the rates, "
                              "and fast motions such as the recommended `reach` ones spoil it: calibrate it "
                              "from swings, or use the default momentum form"
                              if options.get("balance") == "differentiated" else "")
                folds_said = (f" and {folds_text} only within ±{2 * folds_std:.0f} kg (accepted inside "
                              f"±{REFUSAL_FOLDS_SHARE * rated:.0f} kg)" if folds_std is not None else "")
                refusals.append(
                    f"{name}: each half of the calibration motions weighs the other only within "
                    f"±{2 * cal.model_std:.0f} kg (95 %){folds_said}, more than 1 % of the rated payload "
                    f"({0.01 * rated:.0f} kg): add calibration motions with known loads that move the boom, "
                    f"dipper and bucket through the poses you work at, while slewing{per_sample}")
            if len(ids) < MIN_CROSS_EXPERIMENTS:
                warnings.append(
                    f"{name}: {len(ids)} calibration motions cannot check themselves (the σ "
                    f"of each estimate then carries the sensor noise only; {MIN_CROSS_EXPERIMENTS} or "
                    "more calibrate a model error into it)")
        low, high = cal.angle_coverage[:, 0] / DEG, cal.angle_coverage[:, 1] / DEG
        mode = options.get("outside_calibration", "auto")
        if mode == "auto":
            mode = "skip" if options.get("balance") == "momentum" else "use"
        beyond = {"arm": "the arm is not weighed", "use": "the model extrapolates"}.get(mode, "the bucket is not weighed")
        report.append(
            "calibration covers boom {:.0f}…{:.0f}°, dipper {:.0f}…{:.0f}°, bucket {:.0f}…{:.0f}° "
            "(beyond, {})".format(low[0], high[0], low[1], high[1], low[2], high[2], beyond))
        gaps = uncovered_ranges(cal.angle_coverage, arm.machine.angle_ranges)
        if gaps:
            report.append(
                f"calibration: of the machine's ranges the calibration motions did not reach {gaps}: "
                "to weigh loads carried there, add calibration motions with known loads that take "
                "those joints there, every joint moving at once (simulated: --motion reach)")
        return weighing, {"warnings": warnings, "refusals": refusals, "report": report}

    # -- zero check ---------------------------------------------------------------------------
    def zero(self, dataset: Dataset, options: dict) -> list[str]:
        """Re-estimate the sensor offsets from an empty-bucket motion, in place.

        Parameters
        ----------
        dataset : Dataset
            A short empty-bucket motion of the machine sensor set.
        options : dict
            The estimator's options (``low_speed``, ``half_window``).

        Returns
        -------
        list of str
            Warnings: samples it could not use, cylinders that hardly moved (offsets beyond a
            working session's are a refusal: :func:`~excavator_payload.estimators.classical.zero_quality.zero_quality`).
        """
        from excavator_payload.estimators.classical.zero_quality import zero_quality

        used, moving = zero_offsets(self.calibration, dataset, options["low_speed"])
        #: the zero's predicted weighing error and its reasons not to weigh with it
        self.zero_quality = zero_quality(self.calibration, dataset, moving)
        # the zero motion's noise stays in its offsets for the whole session: a shared error the
        # cross-checked s (measured with the calibration's own offsets) does not hold
        self.calibration.zero_std = float(self.zero_quality.offset_part)
        n = len(dataset.frame)
        warnings = []
        if used < n:
            warnings.append(f"zero: {n - used} of {n} samples not used (a signal not finite, or an angle "
                            "outside the machine's range)")
        # a cylinder that stood still tells nothing of its pressure offsets: they keep the values of
        # the calibration's session (one zero swing whose dipper moved 1.8° left the dipper's
        # offsets 2.9 bar off and the weighing 40 kg off, with the true machine file)
        rate = MACHINE_SENSORS.sample_rate
        still = [f"{joint} ({k / rate:.1f} s of motion)" for joint, k in hardly_moved(moving, MIN_ZERO_MOVING_SAMPLES)]
        if still:
            warnings.append(f"zero: cylinders that hardly moved: {', '.join(still)}; "
                            f"{MIN_ZERO_MOVING_SAMPLES / rate:.0f} s or more wanted. Their pressure offsets "
                            "were not checked and keep the calibration's values: repeat the zero check "
                            "moving the boom, dipper and bucket")
        return warnings

    # -- save and restore ---------------------------------------------------------------------
    def config(self, balance: str) -> dict:
        """The JSON-able part to save: kernel, noise, calibration experiments, parameter names,
        balance form and pressure noise (Pa).

        Parameters
        ----------
        balance : str
            The estimator's ``--balance`` (the form the calibration was fitted in).
        """
        return {"kernel": "calibrated_machine", "noise": self.noise_name,
                "calibration_experiments": self.calibration_experiments,
                "calibrated_parameters": list(CALIBRATED_PARAMETERS),
                "offset_signals": list(OFFSET_SIGNALS),
                "imu_parameters": list(IMU_PARAMETERS), "balance": balance,
                "pressure_std": self.calibration.pressure_std}

    def arrays(self) -> dict[str, np.ndarray]:
        """The arrays to save: the identified ``z`` and its covariance, the noise, the window
        inflation, the covered angle range, the model error, the zero's and the outlier test's scale."""
        cal = self.calibration
        return {"z": cal.z, "z_covariance": cal.covariance, "pressure_std": np.array([cal.pressure_std]),
                "rate_var": np.array([cal.rate_var]), "window_inflation": cal.window_inflation,
                "angle_coverage": cal.angle_coverage, "model_std": np.array([cal.model_std]),
                "zero_std": np.array([cal.zero_std]),
                "difference_scale": np.asarray(self.difference_scale, float)}

    @classmethod
    def restore(cls, arm: HydraulicArmModel, cfg: dict, saved, balance: str) -> "MachineWeighing":
        """Rebuild what :meth:`config` (``cfg``) and :meth:`arrays` (``saved``) wrote;
        :class:`EstimatorError` when they are corrupt or of another version.

        Parameters
        ----------
        arm : HydraulicArmModel
            The machine file the estimator believes in.
        cfg : dict
            The saved configuration.
        saved : mapping
            The saved arrays.
        balance : str
            The estimator's ``--balance``; must be the form the calibration was fitted in.
        """
        from excavator_payload.estimators.classical.pressure_regression import restore_difference_scale

        cal = MachineCalibration(arm)
        z = np.asarray(saved["z"], float)
        cov = np.asarray(saved["z_covariance"], float)
        std = np.asarray(saved["pressure_std"], float)
        if (z.shape != cal.z.shape or cov.shape != (len(z), len(z)) or std.shape != (1,)
                or not np.all(np.isfinite(z)) or not np.isfinite(std[0]) or std[0] < 0
                # parameter moves, offsets (Pa, rad) and IMU terms: a real calibration's are < 1e6;
                # 1e300 passed, left every state non-finite and broke the C export with casadi_inf
                or not np.all(np.abs(z) < MAX_CALIBRATION_VALUE)
                or list(cfg.get("calibrated_parameters", [])) != list(CALIBRATED_PARAMETERS)
                or list(cfg.get("offset_signals", OFFSET_SIGNALS)) != list(OFFSET_SIGNALS)
                or list(cfg.get("imu_parameters", IMU_PARAMETERS)) != list(IMU_PARAMETERS)):
            raise EstimatorError("saved machine calibration is corrupt or of another version")
        # The calibration belongs to the balance form it was fitted in: a momentum calibration
        # read as the per-sample form weighed a 2.5 t mean as 3.4 t, 'ok' (an edited option).
        if cfg.get("balance", balance) != balance:
            raise EstimatorError(f"saved machine calibration was fitted with --balance {cfg.get('balance')!r}, "
                                 f"the options say {balance!r}")
        cal.z, cal.covariance, cal.pressure_std = z, cov, float(std[0])
        cal.balance = balance
        if "rate_var" in saved:
            rate_var = np.asarray(saved["rate_var"], float).ravel()
            # a negative variance left every estimate warming_up, blamed on a boom that never moved
            if rate_var.shape != (1,) or not np.isfinite(rate_var[0]) or rate_var[0] < 0:
                raise EstimatorError("saved machine calibration is corrupt or of another version")
            cal.rate_var = float(rate_var[0])
        if "window_inflation" in saved:
            inflation = np.asarray(saved["window_inflation"], float).ravel()
            if inflation.shape != (3,) or not np.all(np.isfinite(inflation)) or np.any(inflation < 1):
                raise EstimatorError("saved machine calibration is corrupt or of another version")
            cal.window_inflation = inflation
        if "model_std" in saved:  # absent in models saved before it: σ from the sensor noise only
            model_std = np.asarray(saved["model_std"], float).ravel()
            if model_std.shape != (1,) or not np.isfinite(model_std[0]) or model_std[0] < 0:
                raise EstimatorError("saved machine calibration is corrupt or of another version")
            cal.model_std = float(model_std[0])
        if "zero_std" in saved:  # absent in models saved before it (or never zeroed): 0
            zero_std = np.asarray(saved["zero_std"], float).ravel()
            if zero_std.shape != (1,) or not np.isfinite(zero_std[0]) or zero_std[0] < 0:
                raise EstimatorError("saved machine calibration is corrupt or of another version")
            cal.zero_std = float(zero_std[0])
        if "angle_coverage" in saved:  # absent in models saved before it: no limit
            coverage = np.asarray(saved["angle_coverage"], float)
            if (coverage.shape != (3, 2) or not np.all(np.isfinite(coverage))
                    or np.any(coverage[:, 0] >= coverage[:, 1])):
                raise EstimatorError("saved machine calibration is corrupt or of another version")
            cal.angle_coverage = coverage
        noise_name = str(cfg.get("noise", "estimated"))
        experiments = [int(i) for i in cfg.get("calibration_experiments", [])]
        return cls(cal, restore_difference_scale(saved), noise_name, experiments)


def zero(estimator, dataset: Dataset, force: bool = False) -> list[str]:
    """Re-estimate a fitted machine-set ``calibrated`` estimator's sensor offsets, in place.
    Returns warnings (samples it could not use), as fit's ``fit_warnings``.

    Parameters
    ----------
    estimator : Estimator
        A loaded or fitted estimator (anything but a machine-set ``calibrated`` one gets one
        clear line).
    dataset : Dataset
        A short empty-bucket motion of the machine sensor set.
    force : bool
        Zero even on a signal the sensor health monitor flags (refused otherwise).
    """
    if getattr(estimator, "calibration", None) is None:
        raise EstimatorError(f"zero needs a 'calibrated' model fitted on machine-sensor-set data, "
                             f"not a '{estimator.name}' model")
    if not HYDRAULIC.carries(dataset):
        raise EstimatorError(f"zero needs machine-sensor-set data, these are of the "
                             f"{dataset.sensor_set.name} sensor set")
    return estimator.zero(dataset, force=force)
